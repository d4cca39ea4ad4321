"""Pictures of a controlled run (``tissue-sim control``): the goal error over time, the tool's path over
the tissue, snapshots. matplotlib, Agg."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
from matplotlib.patches import Polygon

from ..core.contact.tool import ToolPose, ToolShape
from ..core.physics.model import Model
from . import _save, draw_scene, plt, tool_outline


def plot_control(path: str | Path, model: Model, shots: Sequence[tuple[str, np.ndarray, ToolPose | None, float]],
                 tool: ToolShape, time_s: np.ndarray, error: np.ndarray, tool_xy: np.ndarray,
                 start: tuple[float, float], goal: tuple[float, float], tolerance: float, goal_particle: int, *,
                 title: str | None = None, dpi: int = 120) -> Path:
    """Top row: the goal error [mm] against time [s] with the tolerance, and the tool's path over the final tissue
    (start and goal marked); bottom row: snapshots (label, positions, tool pose, jaw) with the goal point."""
    n = len(shots)
    fig = plt.figure(figsize=(max(3.0 * n, 8.0), 6.0))
    gs = fig.add_gridspec(2, max(n, 2))
    half = max(n, 2) // 2
    ax = fig.add_subplot(gs[0, :half])
    ax.semilogy(time_s, np.maximum(error, 1e-6) * 1e3, color="#c62828", lw=1.5, label="goal point to goal")
    ax.axhline(tolerance * 1e3, color="#2e7d32", ls="--", lw=1.0, label=f"tolerance {tolerance * 1e3:g} mm")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("error [mm]")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    lo = np.minimum(tool_xy.min(axis=0), np.minimum(start, goal)) - 0.015
    hi = np.maximum(tool_xy.max(axis=0), np.maximum(start, goal)) + 0.015
    q0 = model.particle_q0
    bounds = (min(lo[0], q0[:, 0].min() - 0.005), max(hi[0], q0[:, 0].max() + 0.005), min(lo[1], 0.0), hi[1])
    ax = fig.add_subplot(gs[0, half:])
    last = shots[-1]
    draw_scene(ax, model, last[1], bounds=bounds, colour="strain", strain_max=0.3)
    ax.plot(tool_xy[:, 0], tool_xy[:, 1], color="#1565c0", lw=1.2, label="tool tip")
    ax.plot(*start, "s", color="#6a1b9a", ms=5, label="start")
    ax.plot(*goal, "*", color="#ffb300", ms=10, mec="#8d6e00", label="goal")
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title("tool path", fontsize=9)
    for k, (label, x, pose, jaw) in enumerate(shots):
        ax = fig.add_subplot(gs[1, k])
        draw_scene(ax, model, x, bounds=bounds, colour="strain", strain_max=0.3)
        if pose is not None:
            ax.add_patch(Polygon(tool_outline(tool, pose, jaw=jaw), closed=True, facecolor="#37474f",
                                 edgecolor="#111111", lw=0.6, zorder=5))
        ax.plot(*x[goal_particle], "o", color="#6a1b9a", ms=3, zorder=6)
        ax.plot(*goal, "*", color="#ffb300", ms=8, mec="#8d6e00", zorder=6)
        ax.set_title(label, fontsize=8)
    if title:
        fig.suptitle(title, fontsize=11)
    return _save(fig, path, dpi)


def plot_control_sweep(path: str | Path, sweep: Sequence[dict], timing: Sequence[dict], *, tolerance: float,
                       title: str | None = None, dpi: int = 120) -> Path:
    """Left: the final error [mm] against the model's error in E (|world E / model E - 1|, %), one line per noise,
    unreached runs hollow; right: one replan's wall time [ms] against the number of candidates (alone when
    ``sweep`` is empty)."""
    fig, grid = plt.subplots(1, 2 if sweep else 1, figsize=(10.0, 4.0) if sweep else (6.0, 4.0), squeeze=False)
    axes = grid[0]  # without a sweep, the timing alone
    if sweep:
        ax = axes[0]
        for noise in sorted({r["noise_mm"] for r in sweep}):
            rows = sorted((r for r in sweep if r["noise_mm"] == noise), key=lambda r: r["world_e_factor"])
            err = [100.0 * (r["world_e_factor"] - 1.0) for r in rows]
            fin = [r["final_error_mm"] for r in rows]
            line, = ax.plot(err, fin, "-", lw=1.0, label=f"noise {noise:g} mm")
            for e, f, r in zip(err, fin, rows):
                ax.plot(e, f, "o", color=line.get_color(), mfc=line.get_color() if r["reached"] else "none")
        ax.axhline(tolerance * 1e3, color="#2e7d32", ls="--", lw=1.0, label="tolerance")
        ax.set_xlabel("world E over the model's E - 1 [%]")
        ax.set_ylabel("final error [mm] (hollow: not reached)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    ax = axes[-1]
    for particles, workers in sorted({(r.get("particles", 0), r["workers"]) for r in timing}):
        rows = [r for r in timing if r["workers"] == workers and r.get("particles", 0) == particles]
        model = f"{particles}-particle model, " if particles else ""
        ax.plot([r["candidates"] for r in rows], [r["total_ms"] for r in rows], "o-" if workers else "s--",
                label=f"{model}{'serial' if workers == 0 else f'{workers} workers'}, {rows[0]['horizon']} steps")
    ax.axhline(100.0, color="#c62828", ls=":", lw=1.0, label="100 ms (replan every 10 steps at 100 Hz)")
    ax.set_xlabel("candidates per replan")
    ax.set_ylabel("replan wall time [ms]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    if title:
        fig.suptitle(title, fontsize=11)
    return _save(fig, path, dpi)
