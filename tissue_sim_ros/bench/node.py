"""``tissue-sim bench node``: sustained rate, overruns and pose-to-mesh latency of the ROS node.

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

Targets (issues 5, 13): 100 Hz held, < 1 % missed deadlines, pose -> points
latency (median; the 95th percentile is reported too) < one period + 2 ms. Writes ``node.csv`` (one row per
scene), ``node_latency_<scene>.csv`` (every pose), ``node.png`` and prints a table.

``--soak SECONDS``: one long timer-mode run of one scene (default 5k) with
markers, sampling the node's resident memory (``/proc/PID/status`` VmRSS) and
its counters every few seconds; reports RSS growth from the end of the warm-up
and the overruns, writes ``node_soak.csv`` and ``node_soak.png``.
"""
from __future__ import annotations

import argparse
import csv
import math
import os
import signal
import struct
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import InputError
from ..core.stamps import stamp_from_ns, stamp_to_seconds

HELP = "sustained rate, overruns and pose-to-mesh latency of the ROS node"
DESCRIPTION = __doc__

SCENES: dict[str, dict[str, Any]] = {
    "paper": {},
    "5k": {"spacing": 0.0165},
}


MODES = ("timer", "lock_step")


@dataclass
class SceneResult:
    scene: str
    mode: str = "timer"
    particles: int = 0
    triangles: int = 0
    marker_bytes: int = 0
    points_bytes: int = 0
    seconds: float = 0.0
    steps: int = 0
    rate_hz: float = 0.0
    overruns: int = 0
    missed_ticks: int = 0
    missed_fraction: float = 0.0
    step_time_mean_ms: float = 0.0
    step_time_max_ms: float = 0.0
    sim_step_ms_mean: float = 0.0
    poses_sent: int = 0
    poses_shown: int = 0
    latency_markers_ms: list[float] = field(default_factory=list)
    latency_points_ms: list[float] = field(default_factory=list)
    markers_received: int = 0
    points_received: int = 0
    divergences: int = 0
    markers_skipped: int = 0
    marker_rate: float = 0.0
    marker_ms_mean: float = 0.0
    soak: list[dict[str, Any]] = field(default_factory=list)

    def row(self, dt: float) -> dict[str, Any]:
        lm = np.array(self.latency_markers_ms) if self.latency_markers_ms else np.array([math.nan])
        lp = np.array(self.latency_points_ms) if self.latency_points_ms else np.array([math.nan])
        budget = 1e3 * dt + 2.0
        return {
            "scene": self.scene, "mode": self.mode, "particles": self.particles, "triangles": self.triangles,
            "marker_kB": round(self.marker_bytes / 1024, 1), "points_kB": round(self.points_bytes / 1024, 1),
            "seconds": round(self.seconds, 2), "steps": self.steps, "rate_hz": round(self.rate_hz, 2),
            "target_hz": round(1.0 / dt, 2), "overruns": self.overruns, "missed_ticks": self.missed_ticks,
            "missed_pct": round(100 * self.missed_fraction, 3),
            "step_ms_mean": round(self.step_time_mean_ms, 3), "step_ms_max": round(self.step_time_max_ms, 3),
            "sim_ms_mean": round(self.sim_step_ms_mean, 3),
            "marker_rate": self.marker_rate,
            "markers_hz": round(self.markers_received / max(self.seconds, 1e-9), 2),
            "markers_skipped": self.markers_skipped,
            "marker_ms_mean": round(self.marker_ms_mean, 3),
            "lat_markers_ms_median": round(float(np.median(lm)), 3),
            "lat_markers_ms_p95": round(float(np.percentile(lm, 95)), 3),
            "lat_markers_ms_max": round(float(np.max(lm)), 3),
            "lat_points_ms_median": round(float(np.median(lp)), 3),
            "lat_points_ms_p95": round(float(np.percentile(lp, 95)), 3),
            "latency_budget_ms": round(budget, 3),
            "poses_sent": self.poses_sent, "poses_shown": self.poses_shown, "divergences": self.divergences,
            "rate_ok": self.rate_hz >= 0.99 / dt, "missed_ok": self.missed_fraction < 0.01,
            "latency_ok": float(np.median(lp)) < budget,
        }


def _write_params(path: Path, values: dict[str, Any]) -> None:
    import yaml  # noqa: PLC0415

    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": values}}, sort_keys=False))


def _isolated_env(domain_id: int) -> dict[str, str]:
    env = os.environ.copy()
    env.update({"ROS_DOMAIN_ID": str(domain_id), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
                "PYTHONUNBUFFERED": "1", "RCUTILS_COLORIZED_OUTPUT": "0"})
    env.pop("ROS_LOCALHOST_ONLY", None)
    return env


def _node_command() -> list[str]:
    script = Path(sys.executable).parent / "tissue_sim_node"
    return [str(script)] if script.exists() else [sys.executable, "-m", "tissue_sim_ros.ros.node"]


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


def _rss_kib(pid: int) -> int:
    """Resident set size of a process [KiB] (Linux /proc)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise InputError(f"no VmRSS for process {pid}")


#: Seconds between memory samples of a soak.
SOAK_SAMPLE_PERIOD = 5.0

SEQ_STEP = 1e-9
"""x offset per pose sequence number [m]: identifies the pose in tool/applied_pose."""


def bench_scene(name: str, overrides: dict[str, Any], seconds: float, warmup: float, out: Path,
                domain_id: int, mode: str = "timer", discovery_timeout: float = 30.0,
                marker_rate: float | None = None, soak: bool = False) -> SceneResult:
    """Run one scene: node process + driving client; return the measurements.

    ``soak``: sample the node's RSS and counters every SOAK_SAMPLE_PERIOD s into ``node_soak.csv``.
    """
    import rclpy  # noqa: PLC0415
    from diagnostic_msgs.msg import DiagnosticArray  # noqa: PLC0415
    from geometry_msgs.msg import PoseStamped  # noqa: PLC0415
    from rclpy.context import Context  # noqa: PLC0415
    from rclpy.executors import SingleThreadedExecutor  # noqa: PLC0415
    from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: PLC0415
    from sensor_msgs.msg import PointCloud2  # noqa: PLC0415
    from visualization_msgs.msg import MarkerArray  # noqa: PLC0415

    from ..core.config import resolve_config  # noqa: PLC0415
    from ..ros import messages, qos  # noqa: PLC0415

    extra = {"marker_rate": marker_rate} if marker_rate is not None else {}
    params = resolve_config({**overrides, "points_rate": 1000.0,
                             "markers_wireframe": True, "diagnostics_rate": 1.0, "max_tool_jump": 1.0,
                             "lock_step": mode == "lock_step", **extra}, source="bench node").flat()
    dt = float(params["dt"])
    tag = f"{name}_{mode}"
    params_file = out / f"node_{tag}.yaml"
    _write_params(params_file, params)
    log_path = out / f"node_{tag}.log"
    result = SceneResult(name, mode)
    env = _isolated_env(domain_id)
    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(_node_command() + ["--ros-args", "--params-file", str(params_file)],
                                env=env, stdout=log, stderr=subprocess.STDOUT)
    context = Context()
    rclpy.init(context=context, domain_id=domain_id)
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

    def on_markers(data: bytes) -> None:
        arrival = time.time()
        sizes["markers"] = len(data)
        if not measuring["on"]:
            return
        counts["markers"] += 1
        r = messages.CdrReader(data)
        r.u32()
        tool = messages._read_marker(r)  # the tool marker comes first; small
        step_stamp = r.header()[0]
        markers.append((arrival, tool.stamp, step_stamp, tool.action))

    def on_points(data: bytes) -> None:
        arrival = time.time()
        sizes["points"] = len(data)
        if measuring["on"]:
            counts["points"] += 1
            points.append((arrival, struct.unpack_from("<iI", data, 4)))

    def on_applied(data: bytes) -> None:
        if measuring["on"]:
            step_stamp, _, position, _ = messages.decode_pose_stamped(data)
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
    t_start = {"t": 0.0}

    seq = {"k": 0}
    by_x: dict[float, tuple[int, int]] = {}

    def publish_pose() -> None:
        now_ns = time.time_ns()
        stamp = stamp_from_ns(now_ns)
        y = _tool_y(time.monotonic() - t_start["t"])
        seq["k"] = (seq["k"] + 1) % 100_000
        x = 0.5 + SEQ_STEP * seq["k"]
        pose_pub.publish(messages.encode_pose_stamped(stamp, params.get("frame_id", "world"), x, y, 0.0))
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

    try:
        spin_until(lambda: pose_pub.get_subscription_count() > 0 and node.count_publishers("tissue/markers") > 0,
                   discovery_timeout, "the node's topics")
        t_start["t"] = time.monotonic()
        node.create_timer(dt, publish_pose)  # ROS clock of this process (system time)
        # in lock-step the node publishes only once poses come
        spin_until(lambda: sizes["markers"] > 0 and sizes["points"] > 0, discovery_timeout, "the first markers")
        end = time.monotonic() + warmup
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.01)
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
                    d = diagnostics[-1]
                    soak_rows.append({"t_s": round(now - t0, 2), "rss_kib": _rss_kib(proc.pid),
                                      "steps": int(d["steps"]) - int(d0["steps"]),
                                      "overruns": int(d["overruns"]) - int(d0["overruns"]),
                                      "missed_ticks": int(d["missed_ticks"]) - int(d0["missed_ticks"]),
                                      "markers_published": int(d.get("markers_published", 0)),
                                      "load1": os.getloadavg()[0]})  # the machine's load beside the soak
                    next_sample += SOAK_SAMPLE_PERIOD
                if soak:  # keep the collected series small over an hour: only counts are needed
                    markers.clear()
                    points.clear()
                    applied.clear()
                    sent.clear()
                    by_x.clear()
        measuring["on"] = False
        diagnostics.clear()
        spin_until(lambda: diagnostics, 5.0, "diagnostics")
        d1, t1 = diagnostics[-1], time.monotonic()
        if soak:
            soak_rows.append({"t_s": round(t1 - t0, 2), "rss_kib": _rss_kib(proc.pid),
                              "steps": int(d1["steps"]) - int(d0["steps"]),
                              "overruns": int(d1["overruns"]) - int(d0["overruns"]),
                              "missed_ticks": int(d1["missed_ticks"]) - int(d0["missed_ticks"]),
                              "markers_published": int(d1.get("markers_published", 0)),
                              "load1": os.getloadavg()[0]})
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        _stop_node(proc)

    # the steps between the two diagnostics readings (each covers up to its publication)
    result.seconds = t1 - t0
    result.steps = int(d1["steps"]) - int(d0["steps"])
    result.rate_hz = result.steps / result.seconds
    result.overruns = int(d1["overruns"]) - int(d0["overruns"])
    result.missed_ticks = int(d1["missed_ticks"]) - int(d0["missed_ticks"])
    result.missed_fraction = (result.overruns + result.missed_ticks) / max(result.steps + result.missed_ticks, 1)
    result.divergences = int(d1["divergences"]) - int(d0["divergences"])
    result.markers_skipped = int(d1.get("markers_skipped", 0)) - int(d0.get("markers_skipped", 0))
    result.marker_rate = float(params["marker_rate"])
    result.marker_ms_mean = float(d1.get("marker_encode_ms_mean", "nan"))
    result.soak = soak_rows
    result.step_time_mean_ms = float(d1["step_time_mean_ms"])
    result.sim_step_ms_mean = float(d1["sim_step_ms_mean"])
    result.step_time_max_ms = max(float(d["step_time_max_ms"]) for d in (d1,))
    result.marker_bytes, result.points_bytes = sizes["markers"], sizes["points"]
    result.markers_received, result.points_received = counts["markers"], counts["points"]
    result.poses_sent = len(sent)
    # pose stamp -> first arrival of markers showing it; step stamp -> pose stamp
    first_markers: dict[tuple[int, int], float] = {}
    step_to_pose: dict[tuple[int, int], tuple[int, int]] = {}
    for arrival, tool_stamp, step_stamp, action in markers:
        if action == messages.ACTION_ADD:
            first_markers.setdefault(tool_stamp, arrival)
            step_to_pose[step_stamp] = tool_stamp
    # the pose each step used, from tool/applied_pose (x carries the pose's sequence number)
    for step_stamp, x in applied:
        if x in by_x:
            step_to_pose[step_stamp] = by_x[x]
    first_points: dict[tuple[int, int], float] = {}
    for arrival, step_stamp in points:
        pose_stamp = step_to_pose.get(step_stamp)
        if pose_stamp is not None:
            first_points.setdefault(pose_stamp, arrival)
    with open(out / f"node_latency_{tag}.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["pose_stamp_s", "markers_latency_ms", "points_latency_ms"])
        for stamp in sent:
            s = stamp_to_seconds(stamp)
            lm = 1e3 * (first_markers[stamp] - s) if stamp in first_markers else math.nan
            lp = 1e3 * (first_points[stamp] - s) if stamp in first_points else math.nan
            writer.writerow([f"{s:.9f}", f"{lm:.3f}", f"{lp:.3f}"])
            if stamp in first_markers:
                result.latency_markers_ms.append(lm)
            if stamp in first_points:
                result.latency_points_ms.append(lp)
    result.poses_shown = len(result.latency_points_ms)
    info = [line for line in log_path.read_text(errors="replace").splitlines() if "particles," in line]
    if info:
        words = info[0].split("]: ")[-1].split()
        result.particles, result.triangles = int(words[0]), int(words[2])
    return result


def _plot(results: list[SceneResult], dt: float, path: Path) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    ax = axes[0]
    budget = 1e3 * dt + 2.0
    hi = max([budget * 1.5] + [float(np.percentile(r.latency_points_ms, 99)) for r in results if r.latency_points_ms])
    bins = np.linspace(0, hi, 60)
    for r in results:
        if r.latency_points_ms:
            ax.hist(np.clip(r.latency_points_ms, 0, hi), bins=bins, alpha=0.5,
                    label=f"{r.scene} {r.mode} ({r.triangles} tri): median {np.median(r.latency_points_ms):.1f} ms, "
                          f"p95 {np.percentile(r.latency_points_ms, 95):.1f} ms")
    ax.axvline(budget, color="k", linestyle="--", label=f"target: period + 2 ms = {budget:.0f} ms")
    ax.set_xlabel("latency tool pose -> tissue/points [ms]")
    ax.set_ylabel("poses")
    ax.legend(fontsize=8)
    ax.set_title("pose-to-points latency")
    ax = axes[1]
    x = np.arange(len(results))
    ax.bar(x - 0.2, [r.rate_hz for r in results], 0.4, label="sustained step rate [Hz]")
    ax.bar(x + 0.2, [r.markers_received / max(r.seconds, 1e-9) for r in results], 0.4, label="markers received [Hz]")
    ax.axhline(1.0 / dt, color="k", linestyle="--", label=f"target {1 / dt:.0f} Hz")
    for i, r in enumerate(results):
        ax.text(i, 1.0 / dt * 1.02, f"{100 * r.missed_fraction:.1f}% missed", ha="center", fontsize=8)
    ax.set_xticks(x, [f"{r.scene} {r.mode}\n{r.triangles} triangles" for r in results])
    ax.set_ylim(0, 1.2 / dt)
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title("rate: points every step, markers at " + ", ".join(sorted({f"{r.marker_rate:g}" for r in results}))
                 + " Hz")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="bench_out/node", help="output directory (CSV, PNG, node logs)")
    parser.add_argument("--seconds", type=float, default=10.0, help="measured time per scene [s]")
    parser.add_argument("--warmup", type=float, default=2.0, help="time driven before measuring [s]")
    parser.add_argument("--scene", action="append", choices=sorted(SCENES),
                        help="scene to run (repeatable; default all)")
    parser.add_argument("--mode", action="append", choices=MODES,
                        help="timer (1/dt timer, newest pose) or lock_step (one step per pose); repeatable; default both")
    parser.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID of the private graph (default 1 + pid %% 100)")
    parser.add_argument("--marker-rate", type=float, default=None,
                        help="the node's marker_rate [Hz] (default: the node's default, a display rate)")
    parser.add_argument("--soak", type=float, default=None, metavar="SECONDS",
                        help="one long timer-mode run instead (scene 5k unless --scene): RSS growth and overruns")


def run(args: argparse.Namespace) -> int:
    if not (math.isfinite(args.seconds) and args.seconds >= 1):
        raise InputError(f"--seconds={args.seconds}: expected at least 1 s")
    if not (math.isfinite(args.warmup) and args.warmup >= 0):
        raise InputError(f"--warmup={args.warmup}: expected a time >= 0 s")
    domain_id = args.domain_id if args.domain_id is not None else 1 + os.getpid() % 100
    if not 0 <= domain_id <= 101:
        raise InputError(f"--domain-id={domain_id}: expected 0..101")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from ..core.config import resolve_config  # noqa: PLC0415

    dt = resolve_config().sim.dt
    if args.marker_rate is not None and not (math.isfinite(args.marker_rate) and args.marker_rate > 0):
        raise InputError(f"--marker-rate={args.marker_rate}: expected a rate > 0 Hz")
    if args.soak is not None:
        return _run_soak(args, out, domain_id)
    results = []
    for name in args.scene or list(SCENES):
        for mode in args.mode or list(MODES):
            results.append(bench_scene(name, SCENES[name], args.seconds, args.warmup, out, domain_id, mode,
                                       marker_rate=args.marker_rate))
    rows = [r.row(dt) for r in results]
    with open(out / "node.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    _plot(results, dt, out / "node.png")
    cols = [("scene", 6), ("mode", 9), ("particles", 9), ("triangles", 9), ("marker_kB", 9), ("rate_hz", 7), ("target_hz", 9),
            ("missed_pct", 10), ("step_ms_mean", 12), ("step_ms_max", 11), ("sim_ms_mean", 11), ("markers_hz", 10), ("marker_ms_mean", 14),
            ("lat_points_ms_median", 20), ("lat_points_ms_p95", 17), ("lat_markers_ms_median", 21),
            ("latency_budget_ms", 17)]
    print("  ".join(f"{c:>{w}}" for c, w in cols))
    for row in rows:
        print("  ".join(f"{row[c]!s:>{w}}" for c, w in cols))
    for row in rows:
        verdict = ", ".join(f"{k[:-3]} {'met' if row[k] else 'MISSED'}" for k in ("rate_ok", "missed_ok", "latency_ok"))
        print(f"{row['scene']} {row['mode']}: {verdict}; {row['poses_shown']}/{row['poses_sent']} poses shown, "
              f"{row['divergences']} divergences")
    print(f"wrote {out / 'node.csv'}, {out / 'node.png'}, node_latency_*.csv")
    return 0


def _run_soak(args: argparse.Namespace, out: Path, domain_id: int) -> int:
    """``--soak SECONDS``: one long run; RSS samples and counters to node_soak.csv/png and a summary."""
    if not (math.isfinite(args.soak) and args.soak >= 2 * SOAK_SAMPLE_PERIOD):
        raise InputError(f"--soak={args.soak}: expected at least {2 * SOAK_SAMPLE_PERIOD:g} s")
    scenes = args.scene or ["5k"]
    modes = args.mode or ["timer"]
    if len(scenes) != 1 or len(modes) != 1:
        raise InputError("--soak runs one scene in one mode: give at most one --scene and one --mode")
    r = bench_scene(scenes[0], SCENES[scenes[0]], args.soak, max(args.warmup, 5.0), out, domain_id, modes[0],
                    marker_rate=args.marker_rate, soak=True)
    rows = r.soak
    with open(out / "node_soak.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    rss = np.array([row["rss_kib"] for row in rows], dtype=float) / 1024.0
    t = np.array([row["t_s"] for row in rows], dtype=float)
    growth = float(rss[-1] - rss[0])
    # the trend, robust to one allocation burst: least-squares slope over the run
    slope = float(np.polyfit(t, rss, 1)[0]) * 3600.0 if len(t) > 2 else math.nan
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, ax = plt.subplots(figsize=(8, 4))
    ax.plot(t / 60.0, rss, label="node RSS [MiB]")
    ax.set_xlabel("time since warm-up [min]")
    ax.set_ylabel("RSS [MiB]")
    ax2 = ax.twinx()
    ax2.plot(t / 60.0, [row["overruns"] + row["missed_ticks"] for row in rows], color="tab:red",
             label="overruns + missed ticks")
    ax2.set_ylabel("missed deadlines (cumulative)")
    ax.set_title(f"soak: {r.scene} {r.mode}, {r.triangles} triangles, markers at {r.marker_rate:g} Hz: "
                 f"RSS {growth:+.2f} MiB")
    fig.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "node_soak.png", dpi=120)
    plt.close(fig)
    print(f"soak {r.scene} {r.mode}: {r.seconds:.0f} s, {r.steps} steps at {r.rate_hz:.2f} Hz, {r.triangles} triangles, "
          f"markers at {r.marker_rate:g} Hz ({r.markers_received} received, {r.markers_skipped} skipped by the node)")
    print(f"RSS {rss[0]:.2f} MiB after warm-up -> {rss[-1]:.2f} MiB at the end: growth {growth:+.2f} MiB "
          f"(max {rss.max():.2f} MiB; trend {slope:+.2f} MiB/h); target < 5 MiB: "
          f"{'met' if growth < 5.0 else 'MISSED'}")
    load = np.array([row["load1"] for row in rows], dtype=float)
    print(f"load average (1 min) beside it: median {np.median(load):.2f}, min {load.min():.2f}, max {load.max():.2f}")
    print(f"overruns {r.overruns}, missed ticks {r.missed_ticks} of {r.steps + r.missed_ticks} ticks "
          f"({100 * r.missed_fraction:.3f} %), divergences {r.divergences}")
    print(f"wrote {out / 'node_soak.csv'}, {out / 'node_soak.png'}")
    return 0
