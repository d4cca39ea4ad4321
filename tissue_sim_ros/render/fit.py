"""Pictures of a material fit: observed against simulated points over time, error per point, cost slices."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
from matplotlib.ticker import MaxNLocator

from . import _save, plt

OBS_COLOUR = "#1f77b4"
SIM_COLOUR = "#d62728"


def plot_tracks(path: str | Path, t: np.ndarray, observed: np.ndarray, simulated: np.ndarray, n_fit: int, *,
                n_show: int = 4, title: str = "") -> Path:
    """Displacement from the first frame [mm] of the points that move most: observed dots, simulated lines.

    ``t`` [s] (F,), observed/simulated [m] (F, P, 2); frames from ``n_fit`` on are the held-out part (shaded).
    """
    disp_obs = (observed - observed[:1]) * 1e3
    disp_sim = (simulated - simulated[:1]) * 1e3
    motion = np.nanmax(np.linalg.norm(disp_sim, axis=2), axis=0)
    order = np.argsort(-motion)[:n_show]
    fig, axes = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True)
    colours = plt.cm.tab10(np.arange(len(order)) % 10)
    for ax, c, name in ((axes[0], 0, "x"), (axes[1], 1, "y")):
        for k, p in enumerate(order):
            ax.plot(t, disp_obs[:, p, c], ".", ms=3, color=colours[k], alpha=0.6)
            ax.plot(t, disp_sim[:, p, c], "-", lw=1.4, color=colours[k], label=f"point {p}")
        if n_fit < len(t):
            ax.axvspan(t[n_fit], t[-1], color="0.9", zorder=-1, label="held out" if c == 0 else None)
        ax.set_ylabel(f"{name} displacement [mm]")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, ncol=3, loc="best")
    axes[1].set_xlabel("time since the first frame [s]  (dots: observed, lines: simulated with the fitted values)")
    if title:
        axes[0].set_title(title, fontsize=10)
    return _save(fig, path, 110)


def point_errors(observed: np.ndarray, simulated: np.ndarray, frames: slice) -> np.ndarray:
    """RMS 2D error of each point over ``frames`` [mm], shape (P,) (NaN for a point never seen there)."""
    d2 = ((simulated[frames] - observed[frames]) ** 2).sum(axis=2)
    with np.errstate(invalid="ignore"):
        return np.sqrt(np.nanmean(d2, axis=0)) * 1e3


def plot_point_errors(path: str | Path, observed: np.ndarray, simulated: np.ndarray, n_fit: int, *,
                      vertices: np.ndarray | None = None, triangles: np.ndarray | None = None,
                      noise_mm: float | None = None, title: str = "") -> Path:
    """RMS error per point on the fitted and the held-out part (bars), and where the points are (map)."""
    fit_err = point_errors(observed, simulated, slice(1, n_fit))
    hold = n_fit < observed.shape[0]
    hold_err = point_errors(observed, simulated, slice(n_fit, None)) if hold else None
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), gridspec_kw={"width_ratios": [1.4, 1]})
    ax = axes[0]
    idx = np.arange(fit_err.size)
    w = 0.4 if hold else 0.8
    ax.bar(idx - (w / 2 if hold else 0), fit_err, w, label="fitted part", color=OBS_COLOUR)
    if hold_err is not None:
        ax.bar(idx + w / 2, hold_err, w, label="held-out part", color="#ff7f0e")
    if noise_mm is not None:
        ax.axhline(noise_mm, color="k", ls="--", lw=1, label=f"noise alone ({noise_mm:.2f} mm)")
    ax.set_xlabel("tracked point")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_ylabel("RMS error [mm]")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, axis="y")
    ax = axes[1]
    if vertices is not None and triangles is not None:
        ax.triplot(vertices[:, 0] * 1e3, vertices[:, 1] * 1e3, triangles, color="0.8", lw=0.5)
    sc = ax.scatter(observed[0, :, 0] * 1e3, observed[0, :, 1] * 1e3, c=fit_err, cmap="viridis", s=30, zorder=3)
    for p in idx:
        ax.annotate(str(p), (observed[0, p, 0] * 1e3, observed[0, p, 1] * 1e3), fontsize=6, xytext=(2, 2),
                    textcoords="offset points")
    fig.colorbar(sc, ax=ax, label="RMS error, fitted part [mm]")
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_title("points at the first frame on the fit's mesh", fontsize=9)
    if title:
        axes[0].set_title(title, fontsize=10)
    return _save(fig, path, 110)


def plot_cost_slices(path: str | Path, slices: Sequence, estimates: dict, truth: dict | None = None) -> Path:
    """The cost 0.5 sum r^2 [mm^2] along each fitted parameter through the optimum, with the 95% interval."""
    n = max(1, len(slices))
    fig, axes = plt.subplots(1, n, figsize=(4.2 * n, 3.4), squeeze=False)
    for ax, s in zip(axes[0], slices):
        ax.plot(s.values, s.cost, "o-", color=OBS_COLOUR, ms=4)
        e = estimates.get(s.name)
        if e is not None and e.value is not None:
            ax.axvline(e.value, color=SIM_COLOUR, lw=1.2, label="fitted")
            if e.low95 is not None and e.high95 is not None:
                ax.axvspan(e.low95, e.high95, color=SIM_COLOUR, alpha=0.15, label="95% interval")
        if truth and s.name in truth:
            ax.axvline(truth[s.name], color="k", ls="--", lw=1, label="truth")
        ax.set_xlabel(s.name)
        ax.set_ylabel("cost [mm^2]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    return _save(fig, path, 110)
