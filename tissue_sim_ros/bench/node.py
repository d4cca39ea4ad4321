"""``tissue-sim bench node``: sustained rate, overruns and pose-to-mesh latency of the ROS node.

One harness around one node process: its start, warm-up, the measuring loop of :func:`bench_scene` and the
latency pairing share that process's state; a scene's result, the report's groups and the chart are
:mod:`~tissue_sim_ros.bench.node_results`, the soak's memory readers and report
:mod:`~tissue_sim_ros.bench.node_memory`.

For each scene (the paper's: the default image at spacing 0.05 and Table I;
and the same image meshed to ~5,000 triangles) the benchmark starts
``tissue_sim_node`` as a separate process on a private ROS domain (localhost
discovery), publishes tool poses at 1/dt from this process - the paper's box
tool in the gap between the two tissues, pushing the lower one down 4 cm and
back every 3 s - and listens to ``tissue/points``, ``tool/applied_pose``,
``tissue/markers`` (raw CDR bytes) and ``/diagnostics``. Points, energy and
wrench go out every step; markers (wireframe on) at the node's ``marker_rate``
(default 30 Hz, encoded and published off the step thread; ``--marker-rate``
changes it, e.g. 100 to see what markers at every step cost).

Measured, over ``--seconds`` after a warm-up:

* sustained step rate: steps taken / wall time (the node's own counter on /diagnostics);
* missed deadlines: steps whose work took longer than dt (``overruns``) plus
  timer ticks skipped (``missed_ticks``), over the ticks due;
* step time: mean and max wall time of step + encoding + publishing (node side);
* latency pose -> points: each pose is stamped with its send time and carries
  its sequence number in the last digits of x (1e-9 m apart: nothing the
  physics notices); ``tool/applied_pose`` tells which pose each step used, in
  the step's stamp, and the ``tissue/points`` of that stamp's arrival - the
  pose's send time is the latency. The tool marker in ``tissue/markers``
  carries the stamp of the pose its step used, so the markers' latency is
  measured likewise. Poses overwritten before a step used them are not shown
  (the node uses only the newest).

Publisher phase (timer mode): a pose waits for the node's next tick, between 0
and one period depending on the phase between the two timers. ``--phases N``
(default 8) puts the publisher in turn at (k + 1/2)/N of a period after the
node's ticks (read from the steps' stamps; the publisher's timer is moved by
stretching one of its intervals), lets the node settle ``--settle`` s and
measures each for ``--seconds``; ``--phase-lock both`` (default) measures
each phase with the node's ``phase_lock`` off, then on (set at run time: one
node process, the two side by side under the same load). With the lock on the
phase is where the publisher started: the node then moves its ticks.

Targets: 100 Hz held, < 1 % missed deadlines, pose -> points
latency (median; the 95th percentile is reported too) < one period + 2 ms. Writes ``node.csv`` (one row per
scene), ``node_latency_<scene>.csv`` (every pose), ``node.png`` and prints a table.

``--set NAME=VALUE`` (repeatable): a node parameter for every run, checked as
the node checks it, to compare settings side by side (e.g.
``step_rt_priority=50`` against the default 0); the CSV's ``step_scheduling``
is the policy the node's step thread actually ran under (``/diagnostics``).

``--soak SECONDS``: one long timer-mode run of one scene (default 5k) with
markers, sampling the node's resident memory (``/proc/PID/status`` VmRSS) and
its counters every few seconds; reports RSS growth from the end of the warm-up
and the overruns, writes ``node_soak.csv`` and ``node_soak.png``. The warm-up
first fills the node's reliable histories to their depth: a second reader
process is stopped for STALL_SECONDS (:mod:`~tissue_sim_ros.bench.stall_reader`:
Fast DDS keeps each history's high-water mark, 5.5 MB for the 5k scene's
points, which a run otherwise meets whenever a reader first falls 1 s behind).
"""
from __future__ import annotations

import csv
import math
import os
import signal
import struct
import subprocess
import sys
import time
from collections import deque
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from ..core.errors import InputError
from ..core.timing.stamps import stamp_from_ns
from ..ros.domain import free_domain_id
from . import node_memory
from .node_memory import soak_row, write_soak_report

SCENES: dict[str, dict[str, Any]] = {
    "paper": {},
    "5k": {"spacing": 0.0165},
}


from .node_results import SceneResult, fill, groups, label, phase_tag, plot, tick_phase  # noqa: E402

MODES = ("timer", "lock_step")


def _write_params(path: Path, cfg: Any) -> None:
    """Every parameter of ``cfg`` (a resolved Config) as the node's ``--params-file``, in its ``/**`` section."""
    path.write_text(cfg.to_yaml(node_name="/**"))


def _isolated_env(domain_id: int) -> dict[str, str]:
    env = os.environ.copy()
    env.update({"ROS_DOMAIN_ID": str(domain_id), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
                "PYTHONUNBUFFERED": "1", "RCUTILS_COLORIZED_OUTPUT": "0"})
    env.pop("ROS_LOCALHOST_ONLY", None)
    return env


def _node_command() -> list[str]:
    script = Path(sys.executable).parent / "tissue_sim_node"
    return [str(script)] if script.exists() else [sys.executable, "-m", "tissue_sim_ros.ros.node"]


def end_with_parent() -> None:
    """``preexec_fn`` of a benchmark's or a test's child (Linux): SIGTERM when its parent dies, however it dies.

    A soak stopped with SIGTERM (or killed) otherwise left its node stepping on the cores: the
    benchmark's ``finally`` that stops the node does not run on a signal (a test's node was once found
    spinning 20 minutes after its pytest was killed)."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes  # noqa: PLC0415

    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _stop_node(proc: subprocess.Popen) -> None:
    """End a node process started by a benchmark: SIGTERM (a clean shutdown), SIGKILL after 15 s."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _tool_y(t: float) -> float:
    """The tool centre's y [m]: from the gap (0.5) down to 0.36 (4 cm into the lower tissue) and back, 3 s period."""
    return 0.43 + 0.07 * math.cos(2.0 * math.pi * t / 3.0)


#: Seconds between memory samples of a soak.
SOAK_SAMPLE_PERIOD = 5.0

#: Seconds the soak's warm-up keeps its second reader stopped: longer than the deepest reliable history
#: (100 steps at 100 Hz) lasts, so every history fills to its depth.
STALL_SECONDS = node_memory.STALL_SECONDS


def _fill_histories(env: dict[str, str], log: Path, spin_until: Any, spin_for: Any, timeout: float) -> None:
    """Start :mod:`~tissue_sim_ros.bench.stall_reader`, stop it STALL_SECONDS once it hears every per-step topic,
    let it go and end it: the node's reliable histories have then held their depth once (see that module)."""
    import threading  # noqa: PLC0415

    with open(log, "wb") as err:
        reader = subprocess.Popen([sys.executable, "-m", "tissue_sim_ros.bench.stall_reader", "tissue_sim_node"],
                                  env=env, stdout=subprocess.PIPE, stderr=err, text=True, preexec_fn=end_with_parent)
    line: list[str] = []
    threading.Thread(target=lambda: line.append(reader.stdout.readline()), daemon=True).start()
    try:
        spin_until(lambda: line, timeout, "the stall reader")
        if not line[0].startswith("ready"):
            raise InputError(f"the stall reader did not hear the node: {line[0].strip()!r}; see {log}")
        reader.send_signal(signal.SIGSTOP)
        try:
            spin_for(STALL_SECONDS)
        finally:
            reader.send_signal(signal.SIGCONT)
        spin_for(0.5)  # it catches up (acknowledges) before it goes
    finally:
        _stop_node(reader)

SEQ_STEP = 1e-9
"""x offset per pose sequence number [m]: identifies the pose in tool/applied_pose."""


#: What starting one node and meeting it in the graph takes, about [s] (meshing, discovery): the plan's estimate
STARTUP_S = 6.0


class MeasurementPlan:
    """The measurement windows a run will take and about how long, said before it starts and counted as it goes:
    ``--seconds`` is the length of one window, and a default run measures many (every phase, both phase-lock
    settings, each scene and mode)."""

    def __init__(self, scenes: Sequence[str], modes: Sequence[str], *, phases: int, locks: Sequence[bool],
                 seconds: float, settle: float, warmup: float) -> None:
        timer = max(phases, 1) * len(locks)
        self.windows = sum(timer if mode == "timer" else 1 for _ in scenes for mode in modes)
        self.nodes = len(scenes) * len(modes)
        settling = sum(timer * settle if mode == "timer" and phases else 0.0 for _ in scenes for mode in modes)
        self.estimate = self.windows * seconds + settling + self.nodes * (warmup + STARTUP_S)
        self.seconds = seconds
        self.done = 0
        self._start = time.monotonic()
        per = [f"timer {max(phases, 1)} phase{'s' if max(phases, 1) > 1 else ''} x {len(locks)} phase_lock "
               f"setting{'s' if len(locks) > 1 else ''}" if m == "timer" else "lock_step 1" for m in modes]
        self.text = (f"bench node: {_count(self.windows, 'measurement')} of {seconds:g} s "
                     f"({_count(len(scenes), 'scene')} x [{', '.join(per)}]) plus settling and "
                     f"{_count(self.nodes, 'node start-up')}: about {_duration(self.estimate)} in all")

    def announce(self, what: str) -> None:
        """Say which measurement starts now, and about how long the run has left."""
        self.done += 1
        elapsed = time.monotonic() - self._start
        left = max(0.0, self.estimate - elapsed) if self.done == 1 else elapsed / (self.done - 1) * (
            self.windows - self.done + 1)
        print(f"bench node: measurement {self.done} of {self.windows}: {what} ({self.seconds:g} s; about "
              f"{_duration(left)} left)", flush=True)


def _count(n: int, word: str) -> str:
    return f"{n} {word}{'' if n == 1 else 's'}"


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.1f} min"


def bench_scene(name: str, overrides: dict[str, Any], seconds: float, warmup: float, out: Path,
                domain_id: int, mode: str = "timer", discovery_timeout: float = 30.0,
                marker_rate: float | None = None, soak: bool = False, phase_locks: tuple[bool, ...] = (True,),
                phases: int = 0, settle: float = 2.0, plan: MeasurementPlan | None = None) -> list[SceneResult]:
    """Run one scene: node process + driving client; return the measurements (one per phase).

    ``soak``: sample the node's RSS and counters every SOAK_SAMPLE_PERIOD s into ``node_soak.csv``.
    ``phases`` (timer mode): put the poses' publisher at ``phases`` phases after the node's ticks in
    turn ((k + 1/2) / phases of a period), ``settle`` s before measuring each for ``seconds``; 0 = one
    measurement at whatever phase the two timers start with. ``phase_locks``: the node's ``phase_lock``
    for each measurement at a phase, in turn (set at run time): (False, True) measures the lock off, then
    on from the same starting phase, side by side under the same load.
    """
    import rclpy  # noqa: PLC0415
    from diagnostic_msgs.msg import DiagnosticArray  # noqa: PLC0415
    from geometry_msgs.msg import PoseStamped  # noqa: PLC0415
    from rcl_interfaces.msg import Parameter as ParameterMsg  # noqa: PLC0415
    from rcl_interfaces.msg import ParameterType, ParameterValue  # noqa: PLC0415
    from rcl_interfaces.srv import SetParameters  # noqa: PLC0415
    from rclpy.context import Context  # noqa: PLC0415
    from rclpy.executors import SingleThreadedExecutor  # noqa: PLC0415
    from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: PLC0415
    from sensor_msgs.msg import PointCloud2  # noqa: PLC0415
    from visualization_msgs.msg import MarkerArray  # noqa: PLC0415

    from ..core.config import resolve_config  # noqa: PLC0415
    from ..ros import messages, qos  # noqa: PLC0415

    extra = {"marker_rate": marker_rate} if marker_rate is not None else {}
    cfg = resolve_config({**overrides, "points_rate": 1000.0,
                          "markers_wireframe": True, "diagnostics_rate": 1.0, "max_tool_jump": 1.0,
                          "lock_step": mode == "lock_step", "phase_lock": phase_locks[0], **extra},
                         source="bench node")
    params = cfg.flat()
    dt = float(params["dt"])
    tag = f"{name}_{mode}"
    params_file = out / f"node_{tag}.yaml"
    _write_params(params_file, cfg)
    log_path = out / f"node_{tag}.log"
    period_ns = int(round(dt * 1e9))
    step_stamps: deque[int] = deque(maxlen=200)  # the newest steps' stamps: the node's tick phase
    env = _isolated_env(domain_id)
    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(_node_command() + ["--ros-args", "--params-file", str(params_file)],
                                env=env, stdout=log, stderr=subprocess.STDOUT, preexec_fn=end_with_parent)
    context = Context()
    rclpy.init(args=[], context=context, domain_id=domain_id)
    node = rclpy.create_node("bench_node_client", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    markers: list[tuple[float, tuple[int, int], tuple[int, int], int]] = []
    points: list[tuple[float, tuple[int, int]]] = []
    applied: list[tuple[tuple[int, int], float]] = []
    soak_rows: list[dict[str, Any]] = []
    diagnostics: list[dict[str, str]] = []
    sent: list[tuple[int, int]] = []
    sizes = {"markers": 0, "points": 0}
    counts = {"markers": 0, "points": 0}
    measuring = {"on": False}
    results: list[SceneResult] = []

    def on_markers(data: bytes) -> None:
        arrival = time.time()
        sizes["markers"] = len(data)
        if not measuring["on"]:
            return
        counts["markers"] += 1
        r = messages.CdrReader(data)
        r.u32()
        tool = messages.read_marker(r)  # the tool marker comes first; small
        step_stamp = r.header()[0]
        markers.append((arrival, tool.stamp, step_stamp, tool.action))

    def on_points(data: bytes) -> None:
        arrival = time.time()
        sizes["points"] = len(data)
        if measuring["on"]:
            counts["points"] += 1
            points.append((arrival, struct.unpack_from("<iI", data, 4)))

    def on_applied(data: bytes) -> None:
        step_stamp, _, position, _ = messages.decode_pose_stamped(data)
        step_stamps.append(step_stamp[0] * 1_000_000_000 + step_stamp[1])
        if measuring["on"]:
            applied.append((step_stamp, float(position[0])))

    def on_diag(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.startswith("/tissue_sim_node"):
                diagnostics.append({kv.key: kv.value for kv in status.values})

    # reliable readers, like RViz's default: what a viewer actually receives
    reader_qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    node.create_subscription(MarkerArray, "tissue/markers", on_markers, reader_qos, raw=True)
    node.create_subscription(PointCloud2, "tissue/points", on_points, reader_qos, raw=True)
    node.create_subscription(PoseStamped, "tool/applied_pose", on_applied, reader_qos, raw=True)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, qos.diagnostics())
    pose_pub = node.create_publisher(PoseStamped, "tool/pose", qos.tool_output())
    param_client = node.create_client(SetParameters, "/tissue_sim_node/set_parameters")
    t_start = {"t": 0.0}
    published = {"n": 0}

    seq = {"k": 0}
    by_x: dict[float, tuple[int, int]] = {}

    def publish_pose() -> None:
        now_ns = time.time_ns()
        stamp = stamp_from_ns(now_ns)
        y = _tool_y(time.monotonic() - t_start["t"])
        seq["k"] = (seq["k"] + 1) % 100_000
        x = 0.5 + SEQ_STEP * seq["k"]
        pose_pub.publish(messages.encode_pose_stamped(stamp, params.get("frame_id", "world"), x, y, 0.0))
        published["n"] += 1
        if measuring["on"]:
            sent.append(stamp)
            by_x[x] = stamp

    def spin_until(predicate: Any, timeout: float, what: str) -> None:
        end = time.monotonic() + timeout
        while not predicate():
            if proc.poll() is not None:
                raise InputError(f"tissue_sim_node exited with {proc.returncode} while waiting for {what}; "
                                 f"see {log_path}")
            if time.monotonic() > end:
                raise InputError(f"timed out after {timeout} s waiting for {what}; see {log_path}")
            executor.spin_once(timeout_sec=0.05)

    def settle_for(seconds_: float) -> None:
        end = time.monotonic() + seconds_
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.01)

    try:
        spin_until(lambda: pose_pub.get_subscription_count() > 0 and node.count_publishers("tissue/markers") > 0,
                   discovery_timeout, "the node's topics")
        t_start["t"] = time.monotonic()
        pose_timer = node.create_timer(dt, publish_pose)  # ROS clock of this process (system time)
        # in lock-step the node publishes only once poses come
        spin_until(lambda: sizes["markers"] > 0 and sizes["points"] > 0, discovery_timeout, "the first markers")
        if soak:
            _fill_histories(env, out / f"stall_reader_{tag}.log", spin_until, settle_for, discovery_timeout)
        settle_for(warmup)

        def place(offset_ns: int) -> None:
            """Move the pose timer so that it fires offset_ns after the node's ticks (one stretched interval)."""
            spin_until(lambda: len(step_stamps) >= 50, discovery_timeout, "the node's steps")
            tick = tick_phase(np.array(step_stamps, dtype=np.int64), period_ns)
            next_call = time.time_ns() + pose_timer.time_until_next_call()
            delay = (tick + offset_ns - next_call) % period_ns
            n = published["n"]
            pose_timer.timer_period_ns = period_ns + delay  # taken by the next call only
            spin_until(lambda: published["n"] > n, discovery_timeout, "the stretched pose timer")
            pose_timer.timer_period_ns = period_ns

        def set_phase_lock(on: bool) -> None:
            spin_until(param_client.service_is_ready, discovery_timeout, "the node's parameter service")
            value = ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=on)
            future = param_client.call_async(SetParameters.Request(
                parameters=[ParameterMsg(name="phase_lock", value=value)]))
            spin_until(future.done, discovery_timeout, "phase_lock to be set")
            if not future.result().results[0].successful:
                raise InputError(f"the node refused phase_lock={on}: {future.result().results[0].reason}")

        def measure(result: SceneResult) -> None:
            """One window of ``seconds``: counters, latencies (and the soak's samples) into ``result``."""
            for series in (markers, points, applied, sent):
                series.clear()
            by_x.clear()
            counts.update(markers=0, points=0)
            diagnostics.clear()
            spin_until(lambda: diagnostics, 5.0, "diagnostics")
            d0, t0 = diagnostics[-1], time.monotonic()
            measuring["on"] = True
            end = t0 + seconds
            from tqdm import tqdm  # noqa: PLC0415

            next_sample = t0
            with tqdm(total=int(seconds), desc=f"bench node {tag}", unit="s", leave=False) as bar:
                last = t0
                while time.monotonic() < end:
                    executor.spin_once(timeout_sec=0.01)
                    now = time.monotonic()
                    if now - last >= 1.0:
                        bar.update(1)
                        last += 1.0
                    if soak and now >= next_sample and diagnostics:
                        soak_rows.append(soak_row(now - t0, proc.pid, d0, diagnostics[-1]))
                        next_sample += SOAK_SAMPLE_PERIOD
                    if soak:  # keep the collected series small over an hour: only counts are needed
                        markers.clear()
                        points.clear()
                        applied.clear()
                        sent.clear()
                        by_x.clear()
            measuring["on"] = False
            waits = [float(d["pose_wait_median_ms"]) for d in diagnostics if "pose_wait_median_ms" in d]
            result.node_wait_ms = float(np.nanmedian(waits)) if waits and not all(map(math.isnan, waits)) \
                else math.nan
            diagnostics.clear()
            spin_until(lambda: diagnostics, 5.0, "diagnostics")
            d1, t1 = diagnostics[-1], time.monotonic()
            if soak:
                soak_rows.append(soak_row(t1 - t0, proc.pid, d0, d1))
            fill(result, d0, d1, t1 - t0, params, sizes, counts, markers, points, applied, sent, by_x)
            result.soak = soak_rows

        if mode != "timer":
            results.append(SceneResult(name, mode))
            if plan is not None:
                plan.announce(f"{name} {mode}")
            measure(results[-1])
        lock_now = phase_locks[0]
        for k in range(max(phases, 1) if mode == "timer" else 0):
            for j, lock in enumerate(phase_locks):
                result = SceneResult(name, mode, phase_lock=lock)
                results.append(result)
                if lock != lock_now:
                    set_phase_lock(lock)
                    lock_now = lock
                if phases:
                    result.phase_ms = (k + 0.5) * dt * 1e3 / phases
                    if j == 0:  # the other settings start from the same phase (the lock moves the ticks)
                        place(int(result.phase_ms * 1e6))
                    settle_for(settle)
                if plan is not None:
                    plan.announce(f"{name} {mode}" + (f", phase {k + 1} of {phases}" if phases else "")
                                  + f", phase_lock {'on' if lock else 'off'}")
                measure(result)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        _stop_node(proc)

    for result in results:
        lock = "" if result.mode != "timer" else "_lock" if result.phase_lock else "_nolock"
        with open(out / f"node_latency_{tag}{lock}{phase_tag(result)}.csv", "w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(["pose_stamp_s", "markers_latency_ms", "points_latency_ms"])
            writer.writerows(result.latency_rows)
            result.latency_rows = []
    info = [line for line in log_path.read_text(errors="replace").splitlines() if "particles," in line]
    if info:
        words = info[0].split("]: ")[-1].split()
        for result in results:
            result.particles, result.triangles = int(words[0]), int(words[2])
    return results


def run(out: str | Path, *, seconds: float = 10.0, warmup: float = 2.0, scenes: Sequence[str] | None = None,
        modes: Sequence[str] | None = None, domain_id: int | None = None, marker_rate: float | None = None,
        phases: int = 8, settle: float = 2.0, phase_lock: str = "both",
        node_params: Mapping[str, Any] | None = None, soak: float | None = None) -> int:
    """Run the node on each scene and mode; print the table and verdicts, write the CSVs and chart into ``out``; 0.

    Parameters
    ----------
    out : str or Path
        Output directory (CSV, PNG, node logs; created).
    seconds : float
        Measured time per scene (and phase) [s].
    warmup : float
        Time driven before measuring [s].
    scenes : sequence of str, optional
        Names in :data:`SCENES` (default all).
    modes : sequence of str, optional
        ``"timer"`` and/or ``"lock_step"`` (default both).
    domain_id : int, optional
        ROS_DOMAIN_ID of the private graph, 0..101 (default: a free-looking one).
    marker_rate : float, optional
        The node's marker_rate [Hz] (default: the node's default).
    phases : int
        Timer mode: publisher phases measured in turn (0: one run at whatever phase the timers start with).
    settle : float
        Time after placing the publisher at a phase before measuring it [s].
    phase_lock : str
        ``"both"``, ``"on"`` or ``"off"``: the node's phase_lock (the soak: on unless off).
    node_params : mapping, optional
        Node parameters for every run (flat names, as ``--set``), checked as the node checks them; the
        benchmark's own win.
    soak : float, optional
        Instead, one long timer-mode run of this many seconds (scene 5k unless given): RSS growth and overruns.
    """
    if not (math.isfinite(seconds) and seconds >= 1):
        raise InputError(f"--seconds={seconds}: expected at least 1 s")
    if not (math.isfinite(warmup) and warmup >= 0):
        raise InputError(f"--warmup={warmup}: expected a time >= 0 s")
    domain_id = domain_id if domain_id is not None else free_domain_id()
    if not 0 <= domain_id <= 101:
        raise InputError(f"--domain-id={domain_id}: expected 0..101")
    from ..core.config import resolve_config  # noqa: PLC0415

    dt = resolve_config().sim.dt
    if marker_rate is not None and not (math.isfinite(marker_rate) and marker_rate > 0):
        raise InputError(f"--marker-rate={marker_rate}: expected a rate > 0 Hz")
    if not 0 <= phases <= 100:
        raise InputError(f"--phases={phases}: expected 0..100")
    if not (math.isfinite(settle) and settle >= 0):
        raise InputError(f"--settle={settle}: expected a time >= 0 s")
    node_params = dict(node_params or {})
    resolve_config(node_params, source="--set")  # a bad name or value: one line, exit 2, before any node starts
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)  # once every input is checked: bad input creates nothing
    if soak is not None:
        return _run_soak(out, domain_id, node_params, soak=soak, scenes=scenes, modes=modes, warmup=warmup,
                         marker_rate=marker_rate, phase_lock=phase_lock)
    locks = {"both": (False, True), "on": (True,), "off": (False,)}[phase_lock]
    load = [os.getloadavg()[0]]
    results: list[SceneResult] = []
    scenes, modes = list(scenes or SCENES), list(modes or MODES)
    plan = MeasurementPlan(scenes, modes, phases=phases, locks=locks, seconds=seconds, settle=settle, warmup=warmup)
    print(plan.text, flush=True)
    for name in scenes:
        for mode in modes:
            results += bench_scene(name, {**SCENES[name], **node_params}, seconds, warmup, out, domain_id, mode,
                                   marker_rate=marker_rate, phase_locks=locks,
                                   phases=phases if mode == "timer" else 0, settle=settle, plan=plan)
    load.append(os.getloadavg()[0])
    rows = [r.row(dt) for r in results]
    with open(out / "node.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    plot(results, dt, out / "node.png")
    cols = [("scene", 6), ("mode", 9), ("phase_lock", 10), ("phase_ms", 8), ("phase_shifts", 12), ("node_wait_ms", 12), ("particles", 9), ("triangles", 9), ("marker_kB", 9), ("rate_hz", 7), ("target_hz", 9),
            ("missed_pct", 10), ("step_ms_mean", 12), ("step_ms_max", 11), ("sim_ms_mean", 11), ("markers_hz", 10), ("marker_ms_mean", 14),
            ("lat_points_ms_median", 20), ("lat_points_ms_p95", 17), ("lat_markers_ms_median", 21),
            ("latency_budget_ms", 17)]
    print("  ".join(f"{c:>{w}}" for c, w in cols))
    for row in rows:
        print("  ".join(f"{row[c]!s:>{w}}" for c, w in cols))
    print(f"load average (1 min): {load[0]:.2f} at the start, {load[1]:.2f} at the end")
    for key, rs in groups(results).items():
        med = [float(np.median(r.latency_points_ms)) if r.latency_points_ms else math.nan for r in rs]
        p95 = [float(np.percentile(r.latency_points_ms, 95)) if r.latency_points_ms else math.nan for r in rs]
        ticks = sum(r.steps + r.missed_ticks for r in rs)
        missed = sum(r.overruns + r.missed_ticks for r in rs) / max(ticks, 1)
        worst_missed = max(r.missed_fraction for r in rs)
        budget = 1e3 * dt + 2.0
        rate = min(r.rate_hz for r in rs)
        verdict = (f"rate {'met' if rate >= 0.99 / dt else 'MISSED'} (lowest {rate:.2f} Hz), missed "
                   f"{'met' if worst_missed < 0.01 else 'MISSED'} ({100 * missed:.2f} % overall, worst phase "
                   f"{100 * worst_missed:.2f} %), latency {'met' if np.nanmax(med) < budget else 'MISSED'} "
                   f"(median {np.nanmin(med):.1f}-{np.nanmax(med):.1f} ms over {len(rs)} phase(s), p95 up to "
                   f"{np.nanmax(p95):.1f} ms; target {budget:.0f} ms)")
        shown = sum(r.poses_shown for r in rs)
        sent = sum(r.poses_sent for r in rs)
        wait = [r.node_wait_ms for r in rs]
        waits = (f"; the node's own pose-to-tick wait {np.nanmin(wait):.1f}-{np.nanmax(wait):.1f} ms"
                 if not all(map(math.isnan, wait)) else "")
        print(f"{label(key)}: {verdict}; {shown}/{sent} poses shown, {sum(r.divergences for r in rs)} divergences, "
              f"{sum(r.phase_shifts for r in rs)} phase shifts while measuring{waits}"
              + (f"; step thread {rs[-1].step_scheduling}" if rs[-1].step_scheduling else ""))
    print(f"wrote {out / 'node.csv'}, {out / 'node.png'}, node_latency_*.csv")
    return 0


def _run_soak(out: Path, domain_id: int, node_params: dict[str, Any], *, soak: float, scenes: Sequence[str] | None,
              modes: Sequence[str] | None, warmup: float, marker_rate: float | None, phase_lock: str) -> int:
    """``--soak SECONDS``: one long run; RSS samples and counters to node_soak.csv/png and a summary."""
    if not (math.isfinite(soak) and soak >= 2 * SOAK_SAMPLE_PERIOD):
        raise InputError(f"--soak={soak}: expected at least {2 * SOAK_SAMPLE_PERIOD:g} s")
    scenes = list(scenes or ["5k"])
    modes = list(modes or ["timer"])
    if len(scenes) != 1 or len(modes) != 1:
        raise InputError("--soak runs one scene in one mode: give at most one --scene and one --mode")
    r = bench_scene(scenes[0], {**SCENES[scenes[0]], **node_params}, soak, max(warmup, 5.0), out, domain_id, modes[0],
                    marker_rate=marker_rate, soak=True, phase_locks=(phase_lock != "off",))[0]
    write_soak_report(out, r)
    return 0
