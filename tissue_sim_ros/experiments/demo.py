"""``tissue-sim demo``: the main job, end to end through the real ROS graph.

Starts, on a private ROS domain with localhost-only discovery, three separate
processes: the simulator node (``tissue_sim_node``, lock-step so every tool
pose is one step), the recorder (``tissue-sim record``, rosbag2 MCAP) and the
tool driver (``tool_driver`` playing experiment a). When the driver is done
and the recorder has everything, both are stopped with SIGINT, and the
figures of experiment a (like the paper's Fig. 2) are drawn from the bag alone:
snapshots from ``tissue/points``, energy and every one of its terms per tissue
from ``tissue/energy/bodies`` (its total, and the terms its layout names) with
the strain and attach topics, contact from ``tissue/contact`` and, for a
grasper, ``tool/grasped``; ``demo_energy.csv`` holds the series the energy plot
draws. The summary says whether the run held (:class:`~tissue_sim_ros.core.health.RunHealth`
over the recorded points): a collapsed run exits 1.
"""
from __future__ import annotations

import math
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import IO, Any, Mapping, Sequence

import numpy as np
from tqdm import tqdm

from ..core.contact.tool import yaw_from_quaternion
from ..core.errors import InputError
from ..core.resources import scene_params_file
from ..core.series import split_remainder
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
    points_rate 1000; a grasper's held count, attach energy and applied jaw): the k-th message is step k.
    Contact is ``tissue/contact``'s per-body ``in_contact``, the Simulation's own flag; the markers are a
    display stream (newest state only) that may skip steps. The energy terms are the ones the bag says it
    has: ``tissue/energy/bodies``' columns by its ``term:`` label, its ``total`` column the total (the terms
    it leaves out, strain, attach and the contact barriers', come from their scene topics: :func:`~tissue_sim_ros.core.series.split_remainder`).
    """
    from ..ros.bags import Bag  # noqa: PLC0415
    from ..ros.messages import (  # noqa: PLC0415
        CONTACT_FIELDS,
        decode_float64,
        decode_float64_multiarray,
        decode_point_cloud,
        decode_pose_stamped,
        decode_uint32,
    )
    from ..ros.tool_applied import decode_applied_jaw  # noqa: PLC0415

    poses: dict[int, np.ndarray] = {}
    energy: list[np.ndarray] = []
    labels: list[str] = []
    energy_t: list[int] = []
    contact: list[np.ndarray] = []
    points: list[tuple[int, np.ndarray]] = []
    scene: dict[str, list[float]] = {"strain": [], "attach": [], "contact": []}
    grasped: list[int] = []
    jaw: list[float] = []
    with Bag(path) as bag:
        for topic, _msgtype, t_ns, raw in bag.messages():
            if topic == "/tool/pose":
                stamp, _frame, pos, q = decode_pose_stamped(raw)
                yaw = yaw_from_quaternion(*map(float, q))
                poses[stamp_to_ns(stamp)] = np.array([pos[0], pos[1], yaw])
            elif topic == "/tissue/energy/bodies":
                data, labels = decode_float64_multiarray(raw)
                energy.append(np.asarray(data, dtype=np.float64))
                energy_t.append(t_ns)
            elif topic in ("/tissue/energy/strain", "/tissue/energy/attach", "/tissue/energy/contact"):
                scene[topic.rsplit("/", 1)[1]].append(decode_float64(raw))
            elif topic == "/tool/grasped":
                grasped.append(decode_uint32(raw))
            elif topic == "/tool/applied_jaw":
                value = decode_applied_jaw(raw)[1]
                jaw.append(math.nan if value is None else value)
            elif topic == "/tissue/contact":
                data, _labels = decode_float64_multiarray(raw)
                contact.append(np.asarray(data, dtype=np.float64)[:, CONTACT_FIELDS.index("in_contact")] > 0.5)
            elif topic == "/tissue/points":
                stamp, _frame, pts = decode_point_cloud(raw)
                points.append((stamp_to_ns(stamp), np.stack([pts["x"], pts["y"]], axis=1).astype(np.float64)))
    # lock-step with points at every step: the k-th points message is step k, stamped with the stamp of the
    # tool pose that step used (energy and contact messages carry no stamp: the k-th is step k as well)
    step_stamp = {k + 1: t for k, (t, _x) in enumerate(points)}
    names = _term_names(labels)
    table = np.array(energy).reshape(len(energy), -1, len(names)) if energy else np.zeros((0, 0, len(names)))
    in_contact = np.zeros((len(energy), table.shape[1]), dtype=bool)
    n = min(len(contact), len(energy))
    if n:
        in_contact[:n] = np.array(contact[:n])
    total = table[:, :, names.index("total")]
    terms = {name: table[:, :, i] for i, name in enumerate(names) if name != "total"}
    terms.update(split_remainder(terms, total, {k: np.array(v[: len(energy)]) for k, v in scene.items()
                                                if len(v) >= len(energy)}))
    return {
        "steps": np.arange(1, len(energy) + 1),
        "terms": terms,
        "total": total,
        "points": {k: x for k, (_t, x) in enumerate(points, start=1)},
        "contact": in_contact,
        "contact_steps": len(contact),
        "grasped": np.array(grasped, dtype=np.int64),
        "jaw": {k: v for k, v in enumerate(jaw, start=1)},
        "tool": {k: poses[t] for k, t in step_stamp.items() if t in poses},
        "energy_time_ns": np.array(energy_t, dtype=np.int64),
    }


def _term_names(labels: Sequence[str]) -> list[str]:
    """The columns of ``tissue/energy/bodies`` from its second dimension's label ``term:inertial,...,total``."""
    for label in labels[1:]:
        if label.startswith("term:"):
            return label[len("term:"):].split(",")
    return ["inertial", "spring", "area", "total"]  # a bag without labels: the layout msg_docs/topics.md gives


def touched_steps(run: Mapping[str, Any]) -> np.ndarray:
    """Per step, whether the tool touched the tissue: contact with any body, or a grasper holding some of it
    (a grasp holds the tissue at the tip without the contact pushing a particle)."""
    touched = run["contact"].any(axis=1)
    held = run["grasped"]
    if len(held):
        touched = touched.copy()
        touched[: len(held)] |= held[: len(touched)] > 0
    return touched


def write_energy_csv(path: Path, run: Mapping[str, Any], body_names: Sequence[str]) -> Path:
    """The series the energy plot draws, per step: the total and each term per body, contact and held count."""
    names = ["step"]
    cols = [run["steps"].astype(float)]
    for b, body in enumerate(body_names):
        for term, arr in [("total", run["total"]), *run["terms"].items()]:
            names.append(f"{body.replace(',', ' ')}:{term}")
            cols.append(arr[:, b])
    names += ["touched", "grasped"]
    held = np.zeros(len(run["steps"]))
    held[: min(len(held), len(run["grasped"]))] = run["grasped"][: len(held)]
    cols += [touched_steps(run).astype(float), held]
    np.savetxt(path, np.column_stack(cols), delimiter=",", header=",".join(names), comments="", fmt="%.17g")
    return path


def run(out: str | Path, *, scene: str = "paper", params_file: str | Path | None = None,
        domain_id: int | None = None, timeout: float = 120.0, trajectory: str = "experiment_a",
        contact_model: str | None = None) -> int:
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
    contact_model : str, optional
        The node's contact model, ``"paper"``, ``"projection"`` or ``"barrier"`` (default: the scene's own, but
        projection where that is the paper's, which lets the tool into the tissue; the demo of a ``neo_hookean``
        scene forced to projection ran the former default, quasi_newton, and inverted).

    Raises
    ------
    InputError
        A bad domain id, trajectory or parameter, or a node or recorder that does not deliver every step.
    """
    from ..core.config import implausible_values, resolve_config  # noqa: PLC0415
    from ..core.health import RunHealth  # noqa: PLC0415
    from ..core.physics.model import Model  # noqa: PLC0415
    from ..render import energy_label, plot_energy  # noqa: PLC0415

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    scene_name = scene
    params_file = Path(params_file) if params_file else scene_params_file(scene_name)
    scene = tr.scene_experiments(scene_name)
    # the node resolves the same file and -p contact_model through the same front door
    given = {"contact_model": contact_model} if contact_model else {}
    cfg = resolve_config(given, params_file=params_file, source="--contact-model")
    if not contact_model and cfg.sim.contact_model == "paper":
        # the paper's eq. (3) lets the tool into the tissue once it touches: the demo shows the tool pushing it
        given = {"contact_model": "projection"}
        cfg = resolve_config(given, params_file=params_file, source="--contact-model")
    contact_model = cfg.sim.contact_model
    params, tool = cfg.sim, cfg.tool
    for line in implausible_values(cfg):
        print(f"demo: warning: {line}", file=sys.stderr)
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
                                            "-p", "marker_rate:=1000.0",
                                            *(["-p", f"contact_model:={contact_model}"] if given else [])],
                            env, out / "node.log")
        procs.append(node)
        recorder = _Process("recorder", [_script("tissue-sim"), "record", "--output", str(bag_path)], env,
                            out / "record.log")
        procs.append(recorder)
        # the driver starts only when the recorder subscribes to the node's outputs, so no step is missed
        wanted = {"/tissue/energy/bodies", "/tissue/contact", "/tissue/points", "/tissue/markers", "/tissue/energy",
                  "/tissue/energy/strain"}
        if tool.kind == "grasper":  # the summary's contact counts the steps the grasper held tissue
            wanted |= {"/tool/grasped", "/tissue/energy/attach"}
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
            with tqdm(total=n_steps, desc=f"{Path(trajectory).name} through ROS", unit="step") as bar:
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
    health = RunHealth(model, params.dt)
    for k in range(1, n_steps + 1):
        health.observe(k, run_["points"][k])
    files = [_draw_snapshots(out / "demo_snapshots.png", model, run_, scene.a_snapshots, tool,
                             f"Demo (through ROS): trajectory {Path(trajectory).name} ({contact_model} contact)"),
             plot_energy(out / "demo_energy.png", run_["steps"], run_["terms"], total=run_["total"],
                         body_names=model.body_names, markers=[s for s in scene.a_snapshots if s > 0],
                         contact=_shaded(run_),
                         title="Demo: implicit Euler energy per tissue, recorded through ROS",
                         ylabel=energy_label(params)),
             write_energy_csv(out / "demo_energy.csv", run_, model.body_names)]
    total = run_["total"]
    touched = touched_steps(run_)
    held_steps = int((run_["grasped"] > 0).sum())
    sim_time = len(run_["steps"]) * params.dt
    # from the first step to the last, as the recorder received them (the driver's start-up is not the run)
    wall = float(run_["energy_time_ns"][-1] - run_["energy_time_ns"][0]) * 1e-9 + params.dt
    peak_b = total.max(axis=0)
    print()
    # "8.21 ms on average (1x real time)" read as a contradiction: say the share of the step period it used
    node_time = (f"took {node_ms:.2f} ms on average, {100 * node_ms / (params.dt * 1e3):.0f}% of the "
                 f"{params.dt * 1e3:g} ms step period" if node_ms else "was not reported")
    held = f", holding it in {held_steps} of them" if tool.kind == "grasper" else ""
    print(f"Ran trajectory {trajectory} through ROS: {len(run_['steps'])} steps ({sim_time:.2f} s simulated) in {wall:.2f} s "
          f"wall (real-time factor {sim_time / wall:.2f}: the driver paces the lock-step node at 1/dt so the recorder "
          f"keeps every message); the node's own step, simulation and messages, {node_time}. "
          f"Driver, node and recorder ran as separate processes on ROS domain {domain}. "
          f"Peak implicit Euler energy (every term: {', '.join(run_['terms'])}) "
          + ", ".join(f"{n} {v:.4g}" for n, v in zip(model.body_names, peak_b))
          + f" at steps {', '.join(str(int(run_['steps'][i])) for i in total.argmax(axis=0))}; the tool touched "
          f"the tissue in {int(touched.sum())} steps (first at step "
          f"{int(np.argmax(touched)) + 1 if touched.any() else '-'}){held}. "
          f"Contact model: {contact_model}. Run held: {health.verdict()}. "
          f"Setup and shutdown took {time.monotonic() - t_start - wall:.1f} s.")
    print()
    print("wrote:")
    for f in [bag_path, *files, out / "node.log", out / "record.log", out / "driver.log"]:
        print(f"  {f}")
    bad = {k: v for k, v in codes.items() if v not in (0, -2, 130)}
    if bad:
        print(f"warning: processes exited with {bad}", file=sys.stderr)
    if health.failure is not None:
        print(f"demo: the run did not hold ({health.verdict().removeprefix('no: ')}): its figures show a broken "
              "simulation, not tissue", file=sys.stderr)
        return 1
    return 0


def _shaded(run: Mapping[str, Any]) -> np.ndarray:
    """The steps the energy plot shades per body: contact, and every body while a grasper holds tissue (the count
    of held particles is the scene's, not a body's)."""
    held = np.zeros(len(run["steps"]), dtype=bool)
    held[: min(len(held), len(run["grasped"]))] = run["grasped"][: len(held)] > 0
    return run["contact"] | held[:, None]


def _draw_snapshots(path: Path, model: Any, run: Mapping[str, Any], steps: Sequence[int], tool: Any,
                    title: str) -> Path:
    """The snapshot strip of the recorded run, framed to hold everything drawn (a lifted flap, the tool above
    the tissue); a grasper is drawn with its jaws as the node applied them."""
    from ..core.contact.tool import ToolPose  # noqa: PLC0415
    from ..render import save_grasp_snapshots, save_snapshots, snapshot_bounds, tool_outline  # noqa: PLC0415

    snaps = []
    for s in steps:
        x = model.particle_q0 if s == 0 else run["points"].get(s)
        if x is None:
            continue
        p = run["tool"].get(s)
        snaps.append((s, x, None if p is None else ToolPose(*map(float, p))))
    grasper = tool.kind == "grasper"
    outlines = [tool_outline(tool, pose, jaw=run["jaw"].get(s, 0.0) if grasper else None)
                for s, _x, pose in snaps if pose is not None]
    bounds = snapshot_bounds(model, [x for _s, x, _p in snaps], outlines)
    if not grasper:
        return save_snapshots(path, model, snaps, tool=tool, title=title, bounds=bounds)
    shots = [(f"step {s}", x, pose, run["jaw"].get(s), np.zeros(0, dtype=np.int64)) for s, x, pose in snaps]
    return save_grasp_snapshots(path, model, shots, tool=tool, bounds=bounds, title=title)

