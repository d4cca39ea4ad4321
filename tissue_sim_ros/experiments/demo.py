"""``tissue-sim demo``: the main job, end to end through the real ROS graph.

Starts, on a private ROS domain with localhost-only discovery, three separate
processes: the simulator node (``tissue_sim_node``, lock-step so every tool
pose is one step), the recorder (``tissue-sim record``, rosbag2 MCAP) and the
tool driver (``tool_driver`` playing experiment a). When the driver is done
and the recorder has everything, both are stopped with SIGINT, and the
figures of experiment a (like the paper's Fig. 2) are drawn from the bag alone:
snapshots from ``tissue/points``, energy and its terms per tissue from
``tissue/energy/bodies``, contact from ``tissue/markers``.
"""
from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import IO, Any

import numpy as np
from tqdm import tqdm

from ..core.contact.tool import yaw_from_quaternion
from ..core.errors import InputError
from ..core.resources import scene_params_file
from ..core.timing import trajectories as tr
from ..core.timing.stamps import stamp_to_ns
from ..ros.domain import free_domain_id


class _Process:
    """A child process whose stdout lines are collected by a thread (so its pipe never fills)."""

    def __init__(self, name: str, cmd: list[str], env: dict[str, str], log: Path) -> None:
        self.name = name
        self.lines: "queue.Queue[str]" = queue.Queue()
        self._log: IO[str] = open(log, "w")
        self.proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                     bufsize=1, start_new_session=True)
        self._thread = threading.Thread(target=self._pump, daemon=True)
        self._thread.start()

    def _pump(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self._log.write(line)
            self._log.flush()
            self.lines.put(line.rstrip("\n"))

    def wait_for_line(self, predicate, timeout: float) -> str:
        """Wait for an output line matching ``predicate``; InputError with the log's tail if it never comes."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=0.1)
            except queue.Empty:
                if self.proc.poll() is not None:
                    raise InputError(f"{self.name} exited with code {self.proc.returncode} before it was ready "
                                     f"(see {self._log.name})") from None
                continue
            if predicate(line):
                return line
        raise InputError(f"{self.name} was not ready after {timeout:.0f} s (see {self._log.name})")

    def drain(self) -> None:
        """Forget the lines printed so far."""
        while True:
            try:
                self.lines.get_nowait()
            except queue.Empty:
                return

    def stop(self, timeout: float = 10.0) -> int:
        """SIGINT, then SIGKILL if it does not end in ``timeout`` seconds; returns the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._thread.join(timeout=2.0)
        self._log.close()
        return self.proc.returncode


def _script(name: str) -> str:
    """A console script of this install (beside the running interpreter, so the same venv is used)."""
    path = Path(sys.executable).parent / name
    if not path.exists():
        raise InputError(f"console script {name!r} not found beside {sys.executable}: install the package (make demo)")
    return str(path)


class _Monitor:
    """Counts tissue/energy messages (raw) in this process: the demo's progress bar and its end of run."""

    def __init__(self, domain: int) -> None:
        import rclpy  # noqa: PLC0415
        from rclpy.executors import SingleThreadedExecutor  # noqa: PLC0415
        from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: PLC0415
        from std_msgs.msg import Float64  # noqa: PLC0415

        self._rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(args=[], context=self.context, domain_id=domain)  # not tissue-sim's command line
        self.node = rclpy.create_node("tissue_sim_demo_monitor", context=self.context)
        self.count = 0
        self.last_time = time.monotonic()
        self.node.create_subscription(Float64, "tissue/energy", self._on_energy,
                                      QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE), raw=True)
        from diagnostic_msgs.msg import DiagnosticArray  # noqa: PLC0415

        self.step_ms: list[tuple[float, int]] = []  # the node's mean step time [ms] and steps per diagnostics window
        self.steps_reported = 0
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics,
                                      QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def _on_energy(self, _raw: bytes) -> None:
        self.count += 1
        self.last_time = time.monotonic()

    def _on_diagnostics(self, msg: Any) -> None:
        for status in msg.status:
            kv = {v.key: v.value for v in status.values}
            if "step_time_mean_ms" in kv and "steps" in kv:
                steps = int(kv["steps"])
                if steps > self.steps_reported:
                    self.step_ms.append((float(kv["step_time_mean_ms"]), steps - self.steps_reported))
                    self.steps_reported = steps

    def node_step_ms(self) -> float | None:
        """The node's mean step time over the run (simulation + messages) [ms], from its diagnostics."""
        if not self.step_ms:
            return None
        ms = np.array(self.step_ms)
        return float((ms[:, 0] * ms[:, 1]).sum() / ms[:, 1].sum())

    def wait_for_subscribers(self, topics: dict[str, int], timeout: float) -> None:
        """Wait until each topic has at least the given number of subscribers in the graph."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if all(self.node.count_subscribers(t) >= n for t, n in topics.items()):
                return
            self.executor.spin_once(timeout_sec=0.05)
        have = {t: self.node.count_subscribers(t) for t in topics}
        raise InputError(f"subscribers did not appear in {timeout:.0f} s: {have} (wanted {topics})")

    def spin(self, expected: int, done, quiet_after: float, timeout: float, bar: tqdm | None = None) -> int:
        """Spin until ``expected`` messages, or ``done()`` and nothing new for ``quiet_after`` s, or timeout."""
        deadline = time.monotonic() + timeout
        shown = 0
        while self.count < expected and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.05)
            if bar is not None:
                bar.update(self.count - shown)
            shown = self.count
            if done() and time.monotonic() - self.last_time > quiet_after:
                break
        return self.count

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.try_shutdown(context=self.context)


def read_demo_bag(path: Path) -> dict[str, Any]:
    """Series of a recorded run from the bag alone: energy terms, snapshots by step, contact per body, stamps.

    Every series comes from a topic the node publishes once per step (energy, contact, points at
    points_rate 1000): the k-th message is step k. Contact is ``tissue/contact``'s per-body ``in_contact``,
    the Simulation's own flag; the markers are a display stream (newest state only) that may skip steps.
    """
    from ..ros.bags import Bag  # noqa: PLC0415
    from ..ros.messages import CONTACT_FIELDS, decode_float64_multiarray, decode_point_cloud, decode_pose_stamped  # noqa: PLC0415

    poses: dict[int, np.ndarray] = {}
    energy: list[np.ndarray] = []
    energy_t: list[int] = []
    contact: list[np.ndarray] = []
    points: list[tuple[int, np.ndarray]] = []
    with Bag(path) as bag:
        for topic, _msgtype, t_ns, raw in bag.messages():
            if topic == "/tool/pose":
                stamp, _frame, pos, q = decode_pose_stamped(raw)
                yaw = yaw_from_quaternion(*map(float, q))
                poses[stamp_to_ns(stamp)] = np.array([pos[0], pos[1], yaw])
            elif topic == "/tissue/energy/bodies":
                data, _labels = decode_float64_multiarray(raw)
                energy.append(np.asarray(data, dtype=np.float64))
                energy_t.append(t_ns)
            elif topic == "/tissue/contact":
                data, _labels = decode_float64_multiarray(raw)
                contact.append(np.asarray(data, dtype=np.float64)[:, CONTACT_FIELDS.index("in_contact")] > 0.5)
            elif topic == "/tissue/points":
                stamp, _frame, pts = decode_point_cloud(raw)
                points.append((stamp_to_ns(stamp), np.stack([pts["x"], pts["y"]], axis=1).astype(np.float64)))
    # lock-step with points at every step: the k-th points message is step k, stamped with the stamp of the
    # tool pose that step used (energy and contact messages carry no stamp: the k-th is step k as well)
    step_stamp = {k + 1: t for k, (t, _x) in enumerate(points)}
    terms = np.array(energy).reshape(len(energy), -1, 4) if energy else np.zeros((0, 0, 4))
    in_contact = np.zeros((len(energy), terms.shape[1]), dtype=bool)
    n = min(len(contact), len(energy))
    if n:
        in_contact[:n] = np.array(contact[:n])
    return {
        "steps": np.arange(1, len(energy) + 1),
        "inertial": terms[:, :, 0], "spring": terms[:, :, 1], "area": terms[:, :, 2],
        "points": {k: x for k, (_t, x) in enumerate(points, start=1)},
        "contact": in_contact,
        "contact_steps": len(contact),
        "tool": {k: poses[t] for k, t in step_stamp.items() if t in poses},
        "energy_time_ns": np.array(energy_t, dtype=np.int64),
    }


def run(out: str | Path, *, scene: str = "paper", params_file: str | Path | None = None,
        domain_id: int | None = None, timeout: float = 120.0, trajectory: str = "experiment_a",
        contact_model: str = "projection") -> int:
    """The demo end to end: node, recorder and driver as processes, figures from the bag; the exit status (0).

    Parameters
    ----------
    out : str or Path
        Output directory for the bag, figures and logs (created).
    scene : str
        Shipped scene: the node's parameter file (config/scenes/NAME.yaml; paper: config/tissue_sim.yaml) and
        the driver's experiment a for it.
    params_file : str or Path, optional
        Parameter YAML for the node, over the shipped config/tissue_sim.yaml (default: the scene's).
    domain_id : int, optional
        ROS_DOMAIN_ID, 0..232 (default: a free-looking one derived from the process id).
    timeout : float
        Give up after this many seconds.
    trajectory : str
        The driver's trajectory: a preset or a .csv/.yaml trajectory file.
    contact_model : str
        The node's contact model, ``"paper"`` or ``"projection"``.

    Raises
    ------
    InputError
        A bad domain id, trajectory or parameter, or a node or recorder that does not deliver every step.
    """
    from ..core.config import resolve_config  # noqa: PLC0415
    from ..core.contact.tool import ToolPose  # noqa: PLC0415
    from ..core.physics.model import Model  # noqa: PLC0415
    from ..render import plot_energy, save_snapshots  # noqa: PLC0415

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    scene_name = scene
    params_file = Path(params_file) if params_file else scene_params_file(scene_name)
    scene = tr.scene_experiments(scene_name)
    # the node resolves the same file and -p contact_model through the same front door
    cfg = resolve_config({"contact_model": contact_model}, params_file=params_file, source="--contact-model")
    params, tool = cfg.sim, cfg.tool
    spec = trajectory
    if spec not in tr.PRESETS:
        spec = str(Path(spec).resolve())  # the driver runs in another directory
    n_steps = tr.resolve_trajectory(spec, tool, params.dt, scene_name).n_steps(params.dt)
    domain = domain_id if domain_id is not None else free_domain_id(120)
    if not 0 <= domain <= 232:
        raise InputError(f"--domain-id {domain}: expected 0..232")
    env = os.environ.copy()
    env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")
    bag_path = out / "demo_bag"
    if bag_path.exists():
        import shutil  # noqa: PLC0415

        shutil.rmtree(bag_path)
    print(f"demo: ROS domain {domain} (localhost only); writing to {out}/", flush=True)

    procs: list[_Process] = []
    t_start = time.monotonic()
    try:
        node = _Process("tissue_sim_node", [_script("tissue_sim_node"), "--ros-args", "--params-file", str(params_file),
                                            "-p", "lock_step:=true", "-p", "points_rate:=1000.0",
                                            "-p", "marker_rate:=1000.0", "-p", f"contact_model:={contact_model}"],
                            env, out / "node.log")
        procs.append(node)
        recorder = _Process("recorder", [_script("tissue-sim"), "record", "--output", str(bag_path)], env,
                            out / "record.log")
        procs.append(recorder)
        # the driver starts only when the recorder subscribes to the node's outputs, so no step is missed
        wanted = {"/tissue/energy/bodies", "/tissue/contact", "/tissue/points", "/tissue/markers", "/tissue/energy"}
        seen: set[str] = set()

        def ready(line: str) -> bool:
            parts = line.split()
            if len(parts) >= 2 and parts[0] == "+":
                seen.add(parts[1])
            return wanted <= seen

        recorder.wait_for_line(ready, timeout=timeout)
        monitor = _Monitor(domain)
        # the recorder's and this monitor's subscriptions are matched before the first pose is sent
        monitor.wait_for_subscribers({"/tissue/energy": 2, "/tissue/energy/bodies": 1, "/tissue/contact": 1,
                                      "/tissue/points": 1, "/tissue/markers": 1, "/tool/pose": 2, "/tool/twist": 2},
                                     timeout=timeout)
        driver = _Process("tool_driver", [_script("tool_driver"), "--ros-args", "-p", f"trajectory:={spec}",
                                          "-p", f"scene:={scene_name}", "-p", f"dt:={params.dt!r}",
                                          "-p", f"tool_shape:={tool.kind}", "-p", f"tool_length:={tool.length!r}",
                                          "-p", f"tool_width:={tool.width!r}", "-p", f"tool_radius:={tool.radius!r}",
                                          "-p", "lock_step:=true", "-p", "exit_when_done:=true",
                                          "-p", "min_subscribers:=2"], env,
                          out / "driver.log")
        procs.append(driver)
        try:
            with tqdm(total=n_steps, desc="experiment a through ROS", unit="step") as bar:
                got = monitor.spin(n_steps, lambda: driver.proc.poll() is not None, 3.0, timeout, bar)
            # the node reports its step times on /diagnostics once a second: take the last window too
            monitor.spin(10**9, lambda: monitor.steps_reported >= got, 0.0, 2.5)
            node_ms = monitor.node_step_ms()
        finally:
            monitor.close()
        driver.proc.wait(timeout=timeout)
        # the recorder prints its message count every second: stop it once two fresh counts agree
        recorder.drain()
        last = None
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            line = recorder.wait_for_line(lambda s: s.strip().endswith("messages"), timeout=5.0)
            count = int(line.split()[-2])
            if count == last:
                break
            last = count
    finally:
        codes = {p.name: p.stop() for p in reversed(procs)}
    if got < n_steps:
        raise InputError(f"the node published {got} of {n_steps} steps (logs in {out}/)")

    run_ = read_demo_bag(bag_path)
    if len(run_["steps"]) != n_steps or len(run_["points"]) != n_steps or run_["contact_steps"] != n_steps:
        raise InputError(f"the bag {bag_path} holds {len(run_['steps'])} energy, {run_['contact_steps']} contact and "
                         f"{len(run_['points'])} point messages of {n_steps} steps: the recorder lost messages (see "
                         f"{out}/record.log)")
    model = Model.from_mesh(cfg.scene.build_mesh(), params)
    snaps = []
    for s in scene.a_snapshots:
        x = model.particle_q0 if s == 0 else run_["points"].get(s)
        if x is None:
            continue
        p = run_["tool"].get(s)
        snaps.append((s, x, None if p is None else ToolPose(*map(float, p))))
    files = [
        save_snapshots(out / "demo_snapshots.png", model, snaps, tool=tool,
                       title=f"Demo (through ROS): trajectory {Path(trajectory).name} ({contact_model} contact)"),
        plot_energy(out / "demo_energy.png", run_["steps"],
                    {"inertial": run_["inertial"], "spring": run_["spring"], "area": run_["area"]},
                    body_names=model.body_names,
                    markers=[s for s in scene.a_snapshots if s > 0],
                    contact=run_["contact"],
                    title="Demo: implicit Euler energy per tissue, recorded through ROS"),
    ]
    total = run_["inertial"] + run_["spring"] + run_["area"]
    touched = run_["contact"].any(axis=1)
    sim_time = len(run_["steps"]) * params.dt
    # from the first step to the last, as the recorder received them (the driver's start-up is not the run)
    wall = float(run_["energy_time_ns"][-1] - run_["energy_time_ns"][0]) * 1e-9 + params.dt
    peak_b = total.max(axis=0)
    print()
    # "8.21 ms on average (1x real time)" read as a contradiction: say the share of the step period it used
    node_time = (f"took {node_ms:.2f} ms on average, {100 * node_ms / (params.dt * 1e3):.0f}% of the "
                 f"{params.dt * 1e3:g} ms step period" if node_ms else "was not reported")
    print(f"Ran trajectory {trajectory} through ROS: {len(run_['steps'])} steps ({sim_time:.2f} s simulated) in {wall:.2f} s "
          f"wall (real-time factor {sim_time / wall:.2f}: the driver paces the lock-step node at 1/dt so the recorder "
          f"keeps every message); the node's own step, simulation and messages, {node_time}. "
          f"Driver, node and recorder ran as separate processes on ROS domain {domain}. "
          f"Peak implicit Euler energy "
          + ", ".join(f"{n} {v:.3g}" for n, v in zip(model.body_names, peak_b))
          + f" at steps {', '.join(str(int(run_['steps'][i])) for i in total.argmax(axis=0))}; the tool touched "
          f"the tissue in {int(touched.sum())} steps (first at step "
          f"{int(np.argmax(touched)) + 1 if touched.any() else '-'}). "
          f"Contact model: {contact_model}. Setup and shutdown took {time.monotonic() - t_start - wall:.1f} s.")
    print()
    print("wrote:")
    for f in [bag_path, *files, out / "node.log", out / "record.log", out / "driver.log"]:
        print(f"  {f}")
    bad = {k: v for k, v in codes.items() if v not in (0, -2, 130)}
    if bad:
        print(f"warning: processes exited with {bad}", file=sys.stderr)
    return 0

