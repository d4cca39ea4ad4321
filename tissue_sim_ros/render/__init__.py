"""Pictures of a run: mesh frames, snapshot strips, energy curves, videos.

Matplotlib with the Agg backend (no screen needed). Colours: the mesh is
shaded by strain (white -> red) or by body; the tool is drawn dark grey; a
target is a yellow circle as in the paper's Fig. 3.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Mapping, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection, PolyCollection  # noqa: E402
from matplotlib.patches import Circle, Polygon  # noqa: E402

from ..core.contact.tool import ToolPose, ToolShape, rounded_box_outline  # noqa: E402
from ..core.physics.model import Model  # noqa: E402
from ..core.physics.strain import vertex_strain  # noqa: E402

BODY_COLOURS = ["#e58fa0", "#d9667d", "#f2b8c6", "#c94f6d"]
TERM_STYLES = {"inertial": ("#1f77b4", "--"), "spring": ("#2ca02c", "-."), "area": ("#9467bd", ":")}


def tool_outline(shape: ToolShape, pose: ToolPose, segments: int = 8, jaw: float | None = None) -> np.ndarray:
    """Polygon of the tool's outline in world coordinates, shape (K, 2) (:meth:`ToolShape.outline`: a grasper's
    envelope, or with ``jaw`` [rad] its shaft and jaws)."""
    local = shape.outline(jaw, segments=segments) if shape.kind == "grasper" else rounded_box_outline(
        *shape.rounded_box(), segments=segments)
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    return local @ np.array([[c, s], [-s, c]]) + np.array([pose.x, pose.y])


def draw_scene(ax, model: Model, x: np.ndarray, *, tool: ToolShape | None = None, pose: ToolPose | None = None,
               colour: str = "strain", strain_max: float = 0.05, contact: np.ndarray | None = None,
               target: tuple[float, float] | None = None, wire: bool = True, lines: bool = True,
               bounds: tuple[float, float, float, float] | None = None) -> None:
    """Draw the deformed mesh (and tool, contact particles, target, boundary lines) on ``ax``."""
    tris = model.tri_indices
    polys = x[tris]
    if colour == "strain":
        s = vertex_strain(model, x, absolute=True)[tris].mean(axis=1)  # shade how much, either way
        cmap = plt.get_cmap("Reds")
        facecolors = cmap(0.25 + 0.75 * np.clip(s / strain_max, 0.0, 1.0))
    else:
        facecolors = [BODY_COLOURS[b % len(BODY_COLOURS)] for b in model.tri_body]
    ax.add_collection(PolyCollection(polys, facecolors=facecolors, edgecolors="none", zorder=1))
    if wire:
        segs = x[model.edge_indices]
        ax.add_collection(LineCollection(segs, colors="#7a2838", linewidths=0.3, zorder=2))
    if contact is not None and len(contact):
        ax.plot(x[contact, 0], x[contact, 1], "o", ms=2.0, color="#1565c0", zorder=4)
    p = model.params
    xmin, ymin = model.particle_q0.min(axis=0)
    xmax, ymax = model.particle_q0.max(axis=0)
    if bounds is None:
        pad = 0.05 * max(xmax - xmin, ymax - ymin)
        bounds = (xmin - pad, xmax + pad, ymin - pad, ymax + pad)
    if lines:
        for y in (p.boundary_y_top, p.boundary_y_bottom):
            if math.isfinite(y):
                ax.axhline(y, color="#444444", lw=0.8, ls="-", zorder=0)
    if tool is not None and pose is not None:
        ax.add_patch(Polygon(tool_outline(tool, pose), closed=True, facecolor="#37474f", edgecolor="#111111",
                             lw=0.6, zorder=5))
    if target is not None:
        ax.add_patch(Circle(target, radius=0.012 * (bounds[1] - bounds[0]), facecolor="#ffd600",
                            edgecolor="#8d6e00", lw=0.8, zorder=6))
    ax.set_xlim(bounds[0], bounds[1])
    ax.set_ylim(bounds[2], bounds[3])
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])


def _save(fig, path: str | Path, dpi: int) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return Path(path)


def save_frame(path: str | Path, model: Model, x: np.ndarray, *, title: str | None = None, size: float = 5.0,
               dpi: int = 100, **kwargs) -> Path:
    """Write one frame of the scene as PNG."""
    fig, ax = plt.subplots(figsize=(size, size))
    draw_scene(ax, model, x, **kwargs)
    if title:
        ax.set_title(title, fontsize=10)
    return _save(fig, path, dpi)


def save_snapshots(path: str | Path, model: Model, snapshots: Sequence[tuple[int, np.ndarray, ToolPose | None]], *,
                   tool: ToolShape | None = None, target: tuple[float, float] | None = None,
                   title: str | None = None, dpi: int = 120) -> Path:
    """A strip of snapshots (step, positions, tool pose), like the top row of the paper's Fig. 2."""
    n = len(snapshots)
    fig, axes = plt.subplots(1, n, figsize=(3.0 * n, 3.2), squeeze=False)
    for ax, (step, x, pose) in zip(axes[0], snapshots):
        draw_scene(ax, model, x, tool=tool, pose=pose, target=target)
        ax.set_title(f"step {step}", fontsize=10)
    if title:
        fig.suptitle(title, fontsize=11)
    return _save(fig, path, dpi)


def plot_energy(path: str | Path, steps: np.ndarray, terms: Mapping[str, np.ndarray], *,
                body_names: Sequence[str] | None = None, markers: Sequence[int] = (), title: str | None = None,
                contact: np.ndarray | None = None, dpi: int = 120, logy: bool = False) -> Path:
    """Energy per body against step: total (thick) and its terms, dashed green lines at ``markers``.

    ``terms`` maps "inertial", "spring", "area" to arrays of shape (S, B); the total is their sum.
    ``contact`` (S, B) bool shades the steps in contact.
    """
    inertial, spring, area = terms["inertial"], terms["spring"], terms["area"]
    total = inertial + spring + area
    nb = total.shape[1]
    names = list(body_names or [f"body {b}" for b in range(nb)])
    fig, axes = plt.subplots(1, nb, figsize=(5.0 * nb, 3.4), squeeze=False)
    for b, ax in enumerate(axes[0]):
        if contact is not None and contact[:, b].any():
            c = contact[:, b]
            ax.fill_between(steps, 0, 1, where=c, transform=ax.get_xaxis_transform(), color="#ffe0b2",
                            alpha=0.6, lw=0, label="contact")
        ax.plot(steps, total[:, b], color="#c62828", lw=2.0, label="total")
        for name, arr in (("inertial", inertial), ("spring", spring), ("area", area)):
            colour, ls = TERM_STYLES[name]
            ax.plot(steps, arr[:, b], color=colour, ls=ls, lw=1.2, label=name)
        for m in markers:
            ax.axvline(m, color="#2e7d32", ls="--", lw=1.0)
        if logy:
            ax.set_yscale("symlog", linthresh=max(1e-12, float(np.nanmax(np.abs(total))) * 1e-4))
        ax.set_title(names[b], fontsize=10)
        ax.set_xlabel("step")
        ax.set_ylabel("implicit Euler energy")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper left")
    if title:
        fig.suptitle(title, fontsize=11)
    return _save(fig, path, dpi)


def save_grasp_snapshots(path: str | Path, model: Model,
                         snapshots: Sequence[tuple[str, np.ndarray, ToolPose | None, float | None, np.ndarray]], *,
                         tool: ToolShape, title: str | None = None, bounds: tuple[float, float, float, float] | None = None,
                         dpi: int = 120) -> Path:
    """Snapshots of a grasp: (label, positions, tool pose, jaw angle [rad], held particles) each; the grasper is
    drawn with its jaws, the held particles in cyan."""
    n = len(snapshots)
    fig, axes = plt.subplots(1, n, figsize=(3.0 * n, 2.8), squeeze=False)
    for ax, (label, x, pose, jaw, held) in zip(axes[0], snapshots):
        draw_scene(ax, model, x, bounds=bounds, colour="strain", strain_max=0.3)
        if pose is not None:
            ax.add_patch(Polygon(tool_outline(tool, pose, jaw=0.0 if jaw is None else jaw), closed=True,
                                 facecolor="#37474f", edgecolor="#111111", lw=0.6, zorder=5))
        if len(held):
            ax.plot(x[held, 0], x[held, 1], "o", ms=3.0, color="#00bcd4", zorder=6)
        ax.set_title(label, fontsize=9)
    if title:
        fig.suptitle(title, fontsize=11)
    return _save(fig, path, dpi)


def plot_grasp(path: str | Path, time_s: np.ndarray, terms: Mapping[str, np.ndarray], force: np.ndarray,
               grasped: np.ndarray, jaw: np.ndarray, *, phases: Sequence[tuple[float, str]] = (),
               title: str | None = None, dpi: int = 120) -> Path:
    """A grasp's energy (total and each term, scene sums, against time [s]), the reaction on the tool [N] and the
    held count with the jaw angle; ``phases`` (time, name) are marked."""
    fig, axes = plt.subplots(3, 1, figsize=(7.0, 7.0), sharex=True)
    total = sum(terms.values())
    axes[0].plot(time_s, total, color="#c62828", lw=2.0, label="total")
    for name, arr in terms.items():
        axes[0].plot(time_s, arr, lw=1.1, label=name)
    axes[0].set_ylabel("implicit Euler energy [J s^2]")
    axes[0].legend(fontsize=8, loc="upper left")
    axes[1].plot(time_s, force[:, 0], label="F_x")
    axes[1].plot(time_s, force[:, 1], label="F_y")
    axes[1].set_ylabel("tissue on tool [N]")
    axes[1].legend(fontsize=8, loc="lower left")
    axes[2].plot(time_s, grasped, color="#00838f", label="particles held")
    axes[2].set_ylabel("held")
    twin = axes[2].twinx()
    twin.plot(time_s, jaw, color="#6d4c41", ls="--", label="jaw [rad]")
    twin.set_ylabel("jaw [rad]")
    axes[2].set_xlabel("time [s]")
    for ax in axes:
        ax.grid(alpha=0.3)
        for t, name in phases:
            ax.axvline(t, color="#2e7d32", ls=":", lw=0.9)
    for t, name in phases:
        axes[0].text(t, 1.0, f" {name}", transform=axes[0].get_xaxis_transform(), fontsize=7, va="top")
    if title:
        fig.suptitle(title, fontsize=11)
    return _save(fig, path, dpi)


def write_video(path: str | Path, frames: Sequence[str | Path], fps: float = 20.0) -> Path:
    """Assemble PNG frames into an mp4 (or .gif); needs the ``video`` extra (imageio)."""
    from ..core.errors import InputError  # noqa: PLC0415

    try:
        import imageio.v2 as imageio  # noqa: PLC0415
    except ImportError:
        raise InputError("writing a video needs imageio: pip install 'tissue_sim_ros[video]'") from None
    path = Path(path)
    with imageio.get_writer(path, fps=fps) as writer:
        for f in frames:
            writer.append_data(imageio.imread(f))
    return path
