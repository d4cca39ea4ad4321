"""``tissue-sim bench plan``: batch rollouts per second, serial and on 1 and 2 workers; the planner service live.

Library part: ``--candidates`` insertions (default 64: 16 approach angles x 4
speeds toward experiment b's target, each exactly ``--steps`` steps, default
100, so the batch is 64 x 100 steps plus the 100-step tool-free baseline) on
the paper scene (the shipped configuration with experiment b's 0.3 m box;
``--set`` overrides), from a snapshot 20 steps in. Each backend runs the same
batch ``--repeats`` times (median wall time):

* ``solve all``: :func:`~tissue_sim_ros.core.sim.batch.rollout_batch` in this
  process solving every step (``reuse_baseline=False``), alternating with
* ``serial``: the same, the shipped way: each candidate's steps with the tool
  still beyond reach taken from the tool-free baseline
  (:class:`~tissue_sim_ros.core.sim.batch.BaselineTrack`);
* ``pool 1``, ``pool 2``: a :class:`~tissue_sim_ros.core.sim.batch.RolloutPool`
  of that many warm workers (their start-up is reported apart, not timed in).

Reported: wall time, candidates/s, steps/s (steps rolled out, solved or
taken from the baseline), the share of steps taken from the baseline, the
ratio to serial and to one worker, and whether every number is bit-identical
to the serial ones (they must be). Goals: <= 1 s for 64 x 100 on 2 cores, >= 1.7x the
one-worker speed, on an idle machine.

Node part (skip with ``--no-node``): ``tissue_sim_node`` (timer mode, 100 Hz,
markers and points every step, ``plan_workers`` 2) in its own process on a
private ROS domain; for ``--seconds`` without requests, then for ``--seconds``
with ``~/plan_insertion`` requests back to back (64 candidates: 16 angle
offsets from the request's -30 deg to -5 deg, every entry clear of the
tissue, x 4 speeds; the table says how many each answer rolled out), the
node's own step rate and overruns from
``/diagnostics``, and each request's request-to-answer latency measured by
the client (the first request, which starts the workers, apart). Goals: 100
Hz and < 1% missed deadlines while planning.

Writes ``plan_bench.csv`` (one row per backend), ``plan_node.csv``,
``plan_bench.png`` and prints the tables with the machine's load average.
"""
from __future__ import annotations

import csv
import math
import os
import subprocess
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..core.config import Config
from ..core.errors import InputError
from ..core.timing import trajectories as tr
from ..ros.domain import free_domain_id

#: the scene's defaults under the parameter file: experiment b's 0.3 m box, as the planner uses
SCENE_DEFAULTS = {"tool_shape": tr.B_TOOL.kind, "tool_length": tr.B_TOOL.length, "tool_width": tr.B_TOOL.width}


def _load() -> str:
    try:
        return Path("/proc/loadavg").read_text().split(" ")[0]
    except OSError:
        return "n/a"


def batch_candidates(sim: Any, n: int, steps: int) -> list:
    """``n`` insertions toward experiment b's target, each exactly ``steps`` steps (angles x 4 speeds)."""
    from ..core.sim.batch import ToolPath  # noqa: PLC0415

    n_speeds = 4 if n >= 4 else 1
    n_angles = math.ceil(n / n_speeds)
    angles = np.linspace(-5.0, -40.0, n_angles)
    speeds = np.linspace(0.0015, 0.003, n_speeds)  # m per step
    out = []
    for s in speeds:
        for a in angles:
            traj = tr.experiment_b(sim.tool, sim.params.dt, float(a), speed=float(s), distance=float(s) * steps)
            path = ToolPath.from_trajectory(traj, sim.params.dt)
            out.append(ToolPath(path.poses[:steps], path.twists[:steps], path.start))
            if len(out) == n:
                return out
    return out


def bench_library(cfg: Config, n: int, steps: int, repeats: int, workers: list[int]) -> list[dict[str, Any]]:
    """One row per backend: serial, then a pool of each size."""
    from ..core.sim.batch import BatchScene, RolloutPool, rollout_batch  # noqa: PLC0415
    from ..core.sim.simulation import Simulation  # noqa: PLC0415

    sim = Simulation.from_config(cfg)
    for _ in range(20):
        sim.step(None)
    snap = sim.snapshot()
    scene = BatchScene.from_simulation(sim)
    cands = batch_candidates(sim, n, steps)
    total_steps = sum(c.n_steps for c in cands) + max(c.n_steps for c in cands)
    rows: list[dict[str, Any]] = []
    rollout_batch(snap, cands[:2], scene=scene)  # warm this process's kernels
    walls, walls_all = [], []
    for _ in range(repeats):  # alternating: every step solved, then the shipped path (the approach from the baseline)
        solved = rollout_batch(snap, cands, scene=scene, reuse_baseline=False)
        walls_all.append(solved.wall_s)
        reference = rollout_batch(snap, cands, scene=scene)
        walls.append(reference.wall_s)
    same = all(a.metrics() == b.metrics() and np.array_equal(a.energy, b.energy)
               for a, b in zip(solved.candidates, reference.candidates))
    reused = sum(c.baseline_steps for c in reference.candidates) / sum(c.steps for c in reference.candidates)
    rows.append(_row("solve all", 0, walls_all, n, total_steps, math.nan, same, 0.0))
    rows.append(_row("serial", 0, walls, n, total_steps, math.nan, True, reused))
    for w in workers:
        t0 = time.perf_counter()
        with RolloutPool(scene, w) as pool:
            start = time.perf_counter() - t0
            walls = []
            same = True
            for _ in range(repeats):
                res = pool.run(snap, cands)
                walls.append(res.wall_s)
                same = same and np.array_equal(res.costs, reference.costs) and all(
                    np.array_equal(a.energy, b.energy) for a, b in zip(res.candidates, reference.candidates))
        rows.append(_row(f"pool {w}", w, walls, n, total_steps, start, same, reused))
    serial = next(r["wall_s"] for r in rows if r["backend"] == "serial")
    one = next((r["wall_s"] for r in rows if r["workers"] == 1), math.nan)
    for r in rows:
        r["speedup_vs_serial"] = serial / r["wall_s"]
        r["speedup_vs_1_worker"] = one / r["wall_s"]
    return rows


def _row(name: str, workers: int, walls: list[float], n: int, steps: int, start: float, same: bool,
         reused: float) -> dict[str, Any]:
    wall = float(np.median(walls))
    return {"backend": name, "workers": workers, "candidates": n, "steps_total": steps, "repeats": len(walls),
            "from_baseline": reused,
            "wall_s": wall, "wall_s_min": float(np.min(walls)), "wall_s_max": float(np.max(walls)),
            "candidates_per_s": n / wall, "steps_per_s": steps / wall, "ms_per_step": 1e3 * wall / steps,
            "pool_start_s": start, "identical_to_serial": bool(same)}


def bench_node(cfg: Config, seconds: float, out: Path, domain_id: int, workers: int = 2) -> dict[str, Any]:
    """The node's rate and overruns idle and while planning; request-to-answer latency of each request."""
    import rclpy  # noqa: PLC0415
    from diagnostic_msgs.msg import DiagnosticArray  # noqa: PLC0415
    from geometry_msgs.msg import PoseStamped  # noqa: PLC0415
    from nav_msgs.srv import GetPlan  # noqa: PLC0415
    from rclpy.context import Context  # noqa: PLC0415
    from rclpy.executors import SingleThreadedExecutor  # noqa: PLC0415
    from std_msgs.msg import Float64MultiArray  # noqa: PLC0415

    from ..ros import messages, qos  # noqa: PLC0415
    from .node import _isolated_env, _node_command, _stop_node, _write_params, end_with_parent  # noqa: PLC0415

    node_cfg = cfg.replace(**{"marker_rate": 100.0, "points_rate": 100.0, "diagnostics_rate": 1.0,
                               # 16 offsets from the request's -30 deg to -5 deg: every entry clear of the tissue,
                               # so all 64 candidates are rolled out (steeper or flatter, the 0.3 m tool would lie
                               # through the upper or the lower tissue and the planner would skip them)
                               "plan_angle_min": 0.0, "plan_angle_max": 25.0, "plan_angle_step": 25.0 / 15.0,
                               "plan_speed_min": 0.15, "plan_speed_max": 0.3, "plan_speed_count": 4,
                               "plan_workers": workers})
    params = node_cfg.flat()
    params_file = out / "plan_node.yaml"
    _write_params(params_file, node_cfg)
    log_path = out / "plan_node.log"
    env = _isolated_env(domain_id)
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(_node_command() + ["--ros-args", "--params-file", str(params_file)],
                                env=env, stdout=log, stderr=subprocess.STDOUT, preexec_fn=end_with_parent)
    context = Context()
    rclpy.init(args=[], context=context, domain_id=domain_id)
    node = rclpy.create_node("bench_plan_client", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    diagnostics: list[dict[str, str]] = []

    def on_diag(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.startswith("/tissue_sim_node"):
                diagnostics.append({kv.key: kv.value for kv in status.values})

    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, qos.diagnostics())
    rolled: list[int] = []  # rows of each plan/costs: the candidates each answer rolled out

    def on_costs(data: bytes) -> None:
        rolled.append(int(messages.decode_float64_multiarray(data)[0].shape[0]))

    node.create_subscription(Float64MultiArray, "plan/costs", on_costs, qos.latched(), raw=True)
    client = node.create_client(GetPlan, "/tissue_sim_node/plan_insertion")

    def spin_until(predicate: Any, timeout: float, what: str) -> Any:
        end = time.monotonic() + timeout
        while not predicate():
            if proc.poll() is not None:
                raise InputError(f"tissue_sim_node exited with {proc.returncode} while waiting for {what}; see {log_path}")
            if time.monotonic() > end:
                raise InputError(f"timed out after {timeout} s waiting for {what}; see {log_path}")
            executor.spin_once(timeout_sec=0.01)
        return predicate()

    def pose(x: float, y: float) -> PoseStamped:
        ps = PoseStamped()
        ps.header.frame_id = params["frame_id"]
        ps.pose.position.x, ps.pose.position.y = x, y
        ps.pose.orientation.w = 1.0
        return ps

    a = math.radians(-30.0)
    request = GetPlan.Request(start=pose(0.55 - 0.2 * math.cos(a), 0.38 - 0.2 * math.sin(a)), goal=pose(0.55, 0.38))

    def call() -> tuple[float, int]:
        t0 = time.perf_counter()
        future = client.call_async(request)
        spin_until(future.done, 120.0, "a plan")
        return time.perf_counter() - t0, len(future.result().plan.poses)

    def window(plan: bool) -> dict[str, Any]:
        diagnostics.clear()
        spin_until(lambda: diagnostics, 5.0, "diagnostics")
        d0, t0 = diagnostics[-1], time.monotonic()
        lat: list[float] = []
        while time.monotonic() - t0 < seconds:
            if plan:
                wall, n = call()
                if n == 0:
                    raise InputError(f"the planner answered an empty path; see {log_path}")
                lat.append(wall)
            else:
                executor.spin_once(timeout_sec=0.01)
        diagnostics.clear()
        spin_until(lambda: diagnostics, 5.0, "diagnostics")
        d1, t1 = diagnostics[-1], time.monotonic()
        steps = int(d1["steps"]) - int(d0["steps"])
        over = int(d1["overruns"]) - int(d0["overruns"])
        missed = int(d1["missed_ticks"]) - int(d0["missed_ticks"])
        return {"rate_hz": steps / (t1 - t0), "steps": steps, "overruns": over, "missed_ticks": missed,
                "missed_pct": 100.0 * (over + missed) / max(steps + missed, 1), "latencies": lat}

    try:
        spin_until(lambda: client.service_is_ready() and diagnostics, 60.0, "the node's planner service")
        first, _ = call()  # starts the workers
        idle = window(False)
        busy = window(True)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        _stop_node(proc)
    lat = np.array(busy["latencies"])
    from ..ros.planner_service import sweep_values  # noqa: PLC0415

    n_requested = params["plan_speed_count"] * len(sweep_values(params["plan_angle_min"], params["plan_angle_max"],
                                                                params["plan_angle_step"]))
    return {"candidates": n_requested, "rolled_out": min(rolled) if rolled else 0, "plan_workers": workers,
            "first_request_s": first, "requests": int(lat.size),
            "latency_s_median": float(np.median(lat)), "latency_s_min": float(lat.min()),
            "latency_s_max": float(lat.max()),
            "idle_rate_hz": idle["rate_hz"], "idle_missed_pct": idle["missed_pct"],
            "planning_rate_hz": busy["rate_hz"], "planning_steps": busy["steps"],
            "planning_overruns": busy["overruns"], "planning_missed_ticks": busy["missed_ticks"],
            "planning_missed_pct": busy["missed_pct"], "rate_ok": busy["rate_hz"] >= 99.0,
            "missed_ok": busy["missed_pct"] < 1.0}


def _plot(rows: list[dict[str, Any]], node_row: dict[str, Any] | None, path: Path, load: str) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, axes = plt.subplots(1, 2 if node_row else 1, figsize=(11 if node_row else 6, 4), squeeze=False)
    ax = axes[0][0]
    x = np.arange(len(rows))
    ax.bar(x, [r["wall_s"] for r in rows], color=["C7" if r["workers"] == 0 else "C0" for r in rows])
    for i, r in enumerate(rows):
        ax.text(i, r["wall_s"], f"{r['candidates_per_s']:.0f} cand/s\n{r['speedup_vs_serial']:.2f}x serial",
                ha="center", va="bottom", fontsize=8)
    ax.axhline(1.0, color="k", linestyle="--", label="goal on 2 cores: 1 s")
    ax.set_ylim(0, 1.25 * max([1.0] + [r["wall_s"] for r in rows]))
    ax.set_xticks(x, [r["backend"] for r in rows])
    ax.set_ylabel(f"wall time of {rows[0]['candidates']} candidates [s], median")
    ax.set_title(f"batch rollouts, {rows[0]['steps_total']} steps (load {load})", fontsize=10)
    ax.legend(fontsize=8)
    if node_row:
        ax = axes[0][1]
        ax.bar([0, 1], [node_row["idle_rate_hz"], node_row["planning_rate_hz"]], color=["C7", "C0"])
        ax.axhline(100.0, color="k", linestyle="--", label="goal 100 Hz")
        for i, (k, m) in enumerate((("idle_rate_hz", "idle_missed_pct"), ("planning_rate_hz", "planning_missed_pct"))):
            ax.text(i, node_row[k] * 0.5, f"{node_row[k]:.1f} Hz\n{node_row[m]:.2f}% missed", ha="center", fontsize=8)
        ax.set_xticks([0, 1], ["idle", f"planning\n{node_row['latency_s_median']:.2f} s per request"])
        ax.set_ylabel("node step rate [Hz]")
        ax.set_title(f"the node while it plans ({node_row['rolled_out']} of {node_row['candidates']} candidates "
                     "rolled out per request)", fontsize=10)
        ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run(config: Config, out: str | Path, *, candidates: int = 64, steps: int = 100, repeats: int = 5,
        workers: Sequence[int] = (1, 2), seconds: float = 10.0, library_part: bool = True, node_part: bool = True,
        node_workers: int = 2) -> int:
    """The library part and the node part; print the tables, write the CSVs and the chart into ``out``; 0.

    Parameters
    ----------
    config : Config
        The scene (``tissue-sim bench plan`` resolves it over :data:`SCENE_DEFAULTS`).
    out : str or Path
        Output directory (created).
    candidates, steps : int
        Candidates per batch and steps per candidate.
    repeats : int
        Batches per backend; the median is reported.
    workers : sequence of int
        Pool sizes.
    seconds : float
        Node part: seconds idle and planning each.
    library_part, node_part : bool
        Run the library part (batches in this process and in pools) and the node part (the planner service).
    node_workers : int
        Node part: the node's ``plan_workers``.
    """
    for name, value in (("candidates", candidates), ("steps", steps), ("repeats", repeats)):
        if value < 1:
            raise InputError(f"--{name}={value}: expected at least 1")
    workers = list(workers)
    if any(w < 1 for w in workers):
        raise InputError(f"--workers {workers}: expected pool sizes >= 1")
    if not (math.isfinite(seconds) and seconds >= 1):
        raise InputError(f"--seconds={seconds}: expected at least 1 s")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    load_before = _load()
    rows = [] if not library_part else bench_library(config, candidates, steps, repeats, sorted(set(workers)))
    node_row = None if not node_part else bench_node(config, seconds, out, free_domain_id(), node_workers)
    load = f"{load_before} -> {_load()}"
    if rows:
        _library_table(rows, candidates, steps, repeats, load, out)
    if node_row:
        _node_table(node_row, out)
    if rows:
        _plot(rows, node_row, out / "plan_bench.png", load)
        print(f"wrote {out / 'plan_bench.csv'}, {out / 'plan_bench.png'}")
    print(f"load average {load}")
    return 0


def _library_table(rows: list[dict[str, Any]], candidates: int, steps: int, repeats: int, load: str,
                   out: Path) -> None:
    with open(out / "plan_bench.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    print(f"{candidates} candidates x {steps} steps on the paper scene (+ the baseline), "
          f"median of {repeats}; load average {load}; {os.cpu_count()} cores")
    print(f"{'backend':<9} {'wall s':>7} {'min':>6} {'max':>6} {'cand/s':>7} {'steps/s':>8} {'ms/step':>7} "
          f"{'reused':>6} {'vs serial':>9} {'vs 1 wkr':>8} {'start s':>7} identical")
    for r in rows:
        print(f"{r['backend']:<9} {r['wall_s']:>7.3f} {r['wall_s_min']:>6.3f} {r['wall_s_max']:>6.3f} "
              f"{r['candidates_per_s']:>7.1f} {r['steps_per_s']:>8.0f} {r['ms_per_step']:>7.3f} "
              f"{100 * r['from_baseline']:>5.1f}% {r['speedup_vs_serial']:>8.2f}x {r['speedup_vs_1_worker']:>7.2f}x "
              f"{r['pool_start_s']:>7.2f} {'yes' if r['identical_to_serial'] else 'NO'}")


def _node_table(node_row: dict[str, Any], out: Path) -> None:
    if node_row:
        with open(out / "plan_node.csv", "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(node_row))
            writer.writeheader()
            writer.writerow(node_row)
        print(f"node (plan_workers {node_row['plan_workers']}), ~/plan_insertion with {node_row['candidates']} candidates ({node_row['rolled_out']} rolled out): first request {node_row['first_request_s']:.2f} s "
              f"(starts the workers); then {node_row['requests']} requests, latency median "
              f"{node_row['latency_s_median']:.3f} s (min {node_row['latency_s_min']:.3f}, max "
              f"{node_row['latency_s_max']:.3f})")
        print(f"node step rate: idle {node_row['idle_rate_hz']:.2f} Hz ({node_row['idle_missed_pct']:.2f}% missed), "
              f"planning {node_row['planning_rate_hz']:.2f} Hz ({node_row['planning_missed_pct']:.2f}% missed: "
              f"{node_row['planning_overruns']} overruns, {node_row['planning_missed_ticks']} skipped ticks in "
              f"{node_row['planning_steps']} steps); 100 Hz {'met' if node_row['rate_ok'] else 'MISSED'}, "
              f"< 1% missed {'met' if node_row['missed_ok'] else 'MISSED'}; wrote {out / 'plan_node.csv'}")
