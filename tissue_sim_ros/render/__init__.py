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
from ..core.series import energy_total  # noqa: E402

BODY_COLOURS = ["#e58fa0", "#d9667d", "#f2b8c6", "#c94f6d"]
TERM_STYLES = {"inertial": ("#1f77b4", "--"), "spring": ("#2ca02c", "-."), "area": ("#9467bd", ":"),
               "strain": ("#ff7f0e", "-."), "attach": ("#00838f", ":")}
#: A term the styles do not name (a per-body remainder such as "strain + attach")
OTHER_TERM_STYLE = ("#6d4c41", "--")
#: What the strain shading of :func:`draw_scene` shows: each triangle is coloured by the mean over its corners of
#: the mean |edge strain| at a corner (edge length over rest length minus 1: no unit, 0.1 = 10 %)
STRAIN_LABEL = "strain |L/L0 - 1| (no unit; 0.1 = 10 %)"


def energy_label(params) -> str:
    """The energy axis' label with its unit: kg m^2 (= J s^2) when the terms are physical (XPBD's stiffnesses, the
    material), else the paper's PBD, whose per-iteration coefficients k make the spring and area terms no
    physical energy (core/physics/energy.py)."""
    if params.method == "pbd" and params.material != "neo_hookean":
        return "implicit Euler energy [kg m^2; PBD's k: not J s^2]"
    return "implicit Euler energy [kg m^2 = J s^2]"


def _strain_colours(values: np.ndarray, strain_max: float) -> np.ndarray:
    """The strain shading: white-ish to red over [0, strain_max], clipped above (the colour bar's map)."""
    return plt.get_cmap("Reds")(0.25 + 0.75 * np.clip(values / strain_max, 0.0, 1.0))


def strain_colour_bar(fig, axes, strain_max: float) -> None:
    """A colour bar beside ``axes`` for the strain shading of :func:`draw_scene` (0 to ``strain_max``, more clipped)."""
    from matplotlib.cm import ScalarMappable  # noqa: PLC0415
    from matplotlib.colors import ListedColormap, Normalize  # noqa: PLC0415

    cmap = ListedColormap(plt.get_cmap("Reds")(np.linspace(0.25, 1.0, 256)))
    bar = fig.colorbar(ScalarMappable(norm=Normalize(0.0, strain_max), cmap=cmap), ax=axes, extend="max",
                       fraction=0.025, pad=0.02)
    bar.set_label(STRAIN_LABEL, fontsize=8)
    bar.ax.tick_params(labelsize=7)


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
        facecolors = _strain_colours(s, strain_max)
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


def _save(fig, path: str | Path, dpi: int, tight: bool = True) -> Path:
    if tight:  # a figure with a colour bar lays itself out (constrained layout): tight_layout would undo it
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


def snapshot_bounds(model: Model, positions: Sequence[np.ndarray],
                    tool_points: Sequence[np.ndarray] = ()) -> tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax) holding the rest shape, every snapshot's positions and the given tool outlines,
    padded: a lifted flap or a tool above the tissue stays in the frame."""
    pts = np.concatenate([model.particle_q0, *[np.asarray(x) for x in positions],
                          *[np.asarray(t) for t in tool_points]])
    pts = pts[np.isfinite(pts).all(axis=1)]
    (xmin, ymin), (xmax, ymax) = pts.min(axis=0), pts.max(axis=0)
    pad = 0.05 * max(xmax - xmin, ymax - ymin)
    return float(xmin - pad), float(xmax + pad), float(ymin - pad), float(ymax + pad)


def save_snapshots(path: str | Path, model: Model, snapshots: Sequence[tuple[int, np.ndarray, ToolPose | None]], *,
                   tool: ToolShape | None = None, target: tuple[float, float] | None = None,
                   title: str | None = None, dpi: int = 120, strain_max: float = 0.05,
                   bounds: tuple[float, float, float, float] | None = None) -> Path:
    """A strip of snapshots (step, positions, tool pose), like the top row of the paper's Fig. 2, with the strain
    shading's colour bar."""
    n = len(snapshots)
    fig, axes = plt.subplots(1, n, figsize=(3.0 * n + 0.8, 3.4), squeeze=False, layout="constrained")
    for ax, (step, x, pose) in zip(axes[0], snapshots):
        draw_scene(ax, model, x, tool=tool, pose=pose, target=target, strain_max=strain_max, bounds=bounds)
        ax.set_title(f"step {step}", fontsize=10)
    strain_colour_bar(fig, axes[0].tolist(), strain_max)
    if title:
        fig.suptitle(title, fontsize=11)
    return _save(fig, path, dpi, tight=False)


def plot_energy(path: str | Path, steps: np.ndarray, terms: Mapping[str, np.ndarray], *,
                body_names: Sequence[str] | None = None, markers: Sequence[int] = (), title: str | None = None,
                contact: np.ndarray | None = None, dpi: int = 120, logy: bool = False,
                ylabel: str = "implicit Euler energy", total: np.ndarray | None = None) -> Path:
    """Energy per body against step: total (thick) and its terms, dashed green lines at ``markers``.

    ``terms`` maps each term's name ("inertial", "spring", "area", "strain", "attach", or another such as a
    per-body "strain + attach") to an array of shape (S, B); the total is ``total`` when given (a recording's
    own), else :func:`~tissue_sim_ros.core.series.energy_total` of them. A term that is zero throughout is
    left out of the legend. ``contact`` (S, B) bool shades the steps in contact; ``ylabel`` names the unit
    (:func:`energy_label`).
    """
    total = energy_total(terms) if total is None else np.asarray(total)
    nb = total.shape[1]
    names = list(body_names or [f"body {b}" for b in range(nb)])
    fig, axes = plt.subplots(1, nb, figsize=(5.0 * nb, 3.4), squeeze=False)
    for b, ax in enumerate(axes[0]):
        if contact is not None and contact[:, b].any():
            c = contact[:, b]
            ax.fill_between(steps, 0, 1, where=c, transform=ax.get_xaxis_transform(), color="#ffe0b2",
                            alpha=0.6, lw=0, label="contact")
        ax.plot(steps, total[:, b], color="#c62828", lw=2.0, label="total")
        for name, arr in terms.items():
            if name == "total" or not np.any(arr[:, b]):
                continue
            colour, ls = TERM_STYLES.get(name, OTHER_TERM_STYLE)
            ax.plot(steps, arr[:, b], color=colour, ls=ls, lw=1.2, label=name)
        for m in markers:
            ax.axvline(m, color="#2e7d32", ls="--", lw=1.0)
        if logy:
            ax.set_yscale("symlog", linthresh=max(1e-12, float(np.nanmax(np.abs(total))) * 1e-4))
        ax.set_title(names[b], fontsize=10)
        ax.set_xlabel("step")
        ax.set_ylabel(ylabel, fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper left")
    if title:
        fig.suptitle(title, fontsize=11)
    return _save(fig, path, dpi)


#: The strain a grasp's snapshots shade up to: a held flap stretches far more than a pushed tissue
GRASP_STRAIN_MAX = 0.3


def save_grasp_snapshots(path: str | Path, model: Model,
                         snapshots: Sequence[tuple[str, np.ndarray, ToolPose | None, float | None, np.ndarray]], *,
                         tool: ToolShape, title: str | None = None, bounds: tuple[float, float, float, float] | None = None,
                         dpi: int = 120) -> Path:
    """Snapshots of a grasp: (label, positions, tool pose, jaw angle [rad], held particles) each; the grasper is
    drawn with its jaws, the held particles in cyan."""
    n = len(snapshots)
    fig, axes = plt.subplots(1, n, figsize=(3.0 * n + 0.8, 3.0), squeeze=False, layout="constrained")
    for ax, (label, x, pose, jaw, held) in zip(axes[0], snapshots):
        draw_scene(ax, model, x, bounds=bounds, colour="strain", strain_max=GRASP_STRAIN_MAX)
        if pose is not None:
            ax.add_patch(Polygon(tool_outline(tool, pose, jaw=0.0 if jaw is None else jaw), closed=True,
                                 facecolor="#37474f", edgecolor="#111111", lw=0.6, zorder=5))
        if len(held):
            ax.plot(x[held, 0], x[held, 1], "o", ms=3.0, color="#00bcd4", zorder=6)
        ax.set_title(label, fontsize=9)
    strain_colour_bar(fig, axes[0].tolist(), GRASP_STRAIN_MAX)
    if title:
        fig.suptitle(title, fontsize=11)
    return _save(fig, path, dpi, tight=False)


def plot_grasp(path: str | Path, time_s: np.ndarray, terms: Mapping[str, np.ndarray], force: np.ndarray,
               grasped: np.ndarray, jaw: np.ndarray, *, phases: Sequence[tuple[float, str]] = (),
               title: str | None = None, dpi: int = 120) -> Path:
    """A grasp's energy (total and each term, scene sums, against time [s]), the reaction on the tool [N] and the
    held count with the jaw angle; ``phases`` (start time, name) are marked, each name over its span."""
    fig, axes = plt.subplots(3, 1, figsize=(7.0, 7.0), sharex=True)
    total = energy_total(terms)
    axes[0].plot(time_s, total, color="#c62828", lw=2.0, label="total")
    for name, arr in terms.items():
        if np.any(arr):  # a term zero throughout (the material's spring and area) is left out of the legend
            colour, ls = TERM_STYLES.get(name, OTHER_TERM_STYLE)
            axes[0].plot(time_s, arr, color=colour, ls=ls, lw=1.1, label=name)
    axes[0].set_ylabel("implicit Euler energy [J s^2]")
    axes[0].legend(fontsize=8, loc="upper left")
    _offset_into_label(fig, axes[0])
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
    # each phase's name above the top panel, at the middle of its span and staggered in two rows: short phases
    # (a 0.1 s close beside a 0.4 s approach) put their names on top of each other when written at their starts
    ends = [t for t, _ in phases[1:]] + [float(time_s[-1]) if len(time_s) else 0.0]
    for k, ((t, name), end) in enumerate(zip(phases, ends)):
        axes[0].text(0.5 * (t + max(end, t)), 1.02 + 0.09 * (k % 2), name, transform=axes[0].get_xaxis_transform(),
                     fontsize=7, ha="center", va="bottom")
    if title:
        fig.suptitle(title, fontsize=11)
    return _save(fig, path, dpi)


def _offset_into_label(fig, ax) -> None:
    """Move the y axis' scale (matplotlib's "1e-7" above the axes, where the phase names go) into its label."""
    fig.canvas.draw()
    offset = ax.yaxis.get_major_formatter().get_offset()
    if offset:
        ax.yaxis.get_offset_text().set_visible(False)
        ax.set_ylabel(f"{ax.get_ylabel()} (x {offset})")


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
