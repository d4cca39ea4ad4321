"""``tissue-sim bench node``'s results: one scene's measurement (:class:`SceneResult`), how the report groups
them and the chart (:mod:`~tissue_sim_ros.bench.node` runs the node and measures)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.timing.stamps import stamp_to_seconds

SCENES: dict[str, dict[str, Any]] = {
    "paper": {},
    "5k": {"spacing": 0.0165},
}


@dataclass
class SceneResult:
    scene: str
    mode: str = "timer"
    phase_lock: bool = False
    phase_ms: float = math.nan
    """Where the poses were put, after the node's ticks [ms] (before the lock moved them); NaN = not placed."""
    phase_shifts: int = 0
    """Shifts the node's phase lock made during the measurement (its settling before is not counted)."""
    node_wait_ms: float = math.nan
    """The node's own median wait from a pose's reception to its next scheduled tick (/diagnostics
    pose_wait_median_ms, median over the window's reports): the phase part of the latency, whatever the
    load does to the callbacks."""
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
    step_scheduling: str = ""
    """The node's step thread's scheduling policy, from /diagnostics (``--set step_rt_priority=N``)."""
    soak: list[dict[str, Any]] = field(default_factory=list)
    latency_rows: list[list[str]] = field(default_factory=list)
    """Per pose: its stamp [s], markers and points latency [ms] (written to node_latency_*.csv)."""

    def row(self, dt: float) -> dict[str, Any]:
        lm = np.array(self.latency_markers_ms) if self.latency_markers_ms else np.array([math.nan])
        lp = np.array(self.latency_points_ms) if self.latency_points_ms else np.array([math.nan])
        budget = 1e3 * dt + 2.0
        return {
            "scene": self.scene, "mode": self.mode, "phase_lock": self.phase_lock if self.mode == "timer" else "",
            "phase_ms": "" if math.isnan(self.phase_ms) else round(self.phase_ms, 2), "phase_shifts": self.phase_shifts,
            "node_wait_ms": round(self.node_wait_ms, 2),
            "particles": self.particles, "triangles": self.triangles,
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
            "step_scheduling": self.step_scheduling,
        }


def phase_tag(result: SceneResult) -> str:
    return "" if math.isnan(result.phase_ms) else f"_phase{result.phase_ms:.2f}"


def tick_phase(stamps_ns: np.ndarray, period_ns: int) -> int:
    """The phase of a timer's scheduled ticks [ns in 0..period) from its callbacks' times.

    Callbacks come after their scheduled time by the dispatch delay: the 10th
    percentile of the phases, unwrapped around their circular mean.
    """
    phase = (stamps_ns % period_ns).astype(np.float64)
    angle = phase * (2.0 * math.pi / period_ns)
    centre = math.atan2(float(np.sin(angle).mean()), float(np.cos(angle).mean())) * period_ns / (2.0 * math.pi)
    unwrapped = centre + (phase - centre + period_ns / 2.0) % period_ns - period_ns / 2.0
    return int(np.percentile(unwrapped, 10.0)) % period_ns


def fill(result: SceneResult, d0: dict[str, str], d1: dict[str, str], seconds: float, params: dict[str, Any],
          sizes: dict[str, int], counts: dict[str, int], markers: list, points: list, applied: list,
          sent: list, by_x: dict) -> None:
    """The measurements of one window: counters from two /diagnostics readings, latencies from the series."""
    from ..ros import messages  # noqa: PLC0415

    # the steps between the two diagnostics readings (each covers up to its publication)
    result.seconds = seconds
    result.steps = int(d1["steps"]) - int(d0["steps"])
    result.rate_hz = result.steps / result.seconds
    result.overruns = int(d1["overruns"]) - int(d0["overruns"])
    result.missed_ticks = int(d1["missed_ticks"]) - int(d0["missed_ticks"])
    result.missed_fraction = (result.overruns + result.missed_ticks) / max(result.steps + result.missed_ticks, 1)
    result.divergences = int(d1["divergences"]) - int(d0["divergences"])
    result.markers_skipped = int(d1.get("markers_skipped", 0)) - int(d0.get("markers_skipped", 0))
    result.marker_rate = float(params["marker_rate"])
    result.marker_ms_mean = float(d1.get("marker_encode_ms_mean", "nan"))
    result.phase_shifts = int(d1.get("phase_shifts", 0)) - int(d0.get("phase_shifts", 0))
    result.step_time_mean_ms = float(d1["step_time_mean_ms"])
    result.sim_step_ms_mean = float(d1["sim_step_ms_mean"])
    result.step_scheduling = d1.get("step_thread_scheduling", "")
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
    for stamp in sent:
        s = stamp_to_seconds(stamp)
        lm = 1e3 * (first_markers[stamp] - s) if stamp in first_markers else math.nan
        lp = 1e3 * (first_points[stamp] - s) if stamp in first_points else math.nan
        result.latency_rows.append([f"{s:.9f}", f"{lm:.3f}", f"{lp:.3f}"])
        if stamp in first_markers:
            result.latency_markers_ms.append(lm)
        if stamp in first_points:
            result.latency_points_ms.append(lp)
    result.poses_shown = len(result.latency_points_ms)


def groups(results: list[SceneResult]) -> dict[tuple[str, str, bool], list[SceneResult]]:
    """Results by (scene, mode, phase lock), in run order."""
    groups: dict[tuple[str, str, bool], list[SceneResult]] = {}
    for r in results:
        groups.setdefault((r.scene, r.mode, r.phase_lock), []).append(r)
    return groups


def label(key: tuple[str, str, bool]) -> str:
    scene, mode, lock = key
    return f"{scene} {mode.replace('_', '-')}" + ("" if mode != "timer" else ", lock on" if lock else ", lock off")


def plot(results: list[SceneResult], dt: float, path: Path) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, axes = plt.subplots(1, 2, figsize=(13, 4.8))
    budget = 1e3 * dt + 2.0
    grouped = groups(results)
    colours = dict(zip(sorted({k[0] for k in grouped}), ("tab:blue", "tab:orange", "tab:green", "tab:red")))
    for key, rs in grouped.items():
        scene, mode, lock = key
        colour = colours[scene]
        med = [float(np.median(r.latency_points_ms)) if r.latency_points_ms else math.nan for r in rs]
        p95 = [float(np.percentile(r.latency_points_ms, 95)) if r.latency_points_ms else math.nan for r in rs]
        missed = [100 * r.missed_fraction for r in rs]
        x = [r.phase_ms for r in rs]
        if mode != "timer" or any(math.isnan(v) for v in x):
            for ax, v in ((axes[0], med[0]), (axes[1], missed[0])):
                ax.axhline(v, color=colour, linestyle=":", label=f"{label(key)} ({rs[0].triangles} tri): {v:.1f}")
            continue
        style = "-o" if lock else "--s"
        axes[0].plot(x, med, style, color=colour, label=f"{label(key)} ({rs[0].triangles} tri): median, "
                                                          f"worst {np.nanmax(med):.1f} ms")
        axes[0].plot(x, p95, style, color=colour, alpha=0.3, markersize=3)
        axes[0].plot(x, [r.node_wait_ms for r in rs], ":" + style[-1], color=colour, alpha=0.6, markersize=3)
        axes[1].plot(x, missed, style, color=colour, label=f"{label(key)}: worst {max(missed):.2f} %")
    axes[0].axhline(budget, color="k", linestyle="--", label=f"target: period + 2 ms = {budget:.0f} ms")
    axes[0].set_xlabel("publisher phase after the node's ticks at the start [ms]")
    axes[0].set_ylabel("pose -> tissue/points latency [ms]")
    axes[0].set_title("median latency by publisher phase (faint: p95; dotted: the node's wait to its tick)",
                      fontsize=9)
    axes[0].legend(fontsize=7)
    axes[1].axhline(1.0, color="k", linestyle="--", label="target < 1 %")
    axes[1].set_xlabel("publisher phase after the node's ticks at the start [ms]")
    axes[1].set_ylabel("missed deadlines [%]")
    axes[1].set_title("missed deadlines (overruns + skipped ticks); markers at "
                      + ", ".join(sorted({f"{r.marker_rate:g}" for r in results})) + " Hz")
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
