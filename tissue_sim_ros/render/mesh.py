"""A mesh as a picture (``tissue-sim mesh --png``): its triangles coloured by body over the image it was meshed
from, the boundary vertices marked, a graded mesh's fine region outlined, in world axes [m]."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.collections import PolyCollection

from ..core.mesh import Grading, TissueMesh
from . import _save, plt

#: How opaque a body's triangles are over the image (faint: the image shows through)
BODY_ALPHA = 0.18


def draw_mesh(mesh: TissueMesh, path: Path, *, image: np.ndarray | None = None, scale: float = 0.002,
              origin: tuple[float, float] = (0.0, 0.0), grading: Grading | None = None, title: str = "") -> None:
    """PNG of the mesh (triangles coloured by body, boundary vertices marked) over the image, world axes [m]."""
    colours = ["#1f77b4", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#17becf"]
    fig, ax = plt.subplots(figsize=(7, 7), dpi=120)
    if image is not None:
        rgb = image[:, :, ::-1] if image.ndim == 3 else image
        h, w = image.shape[:2]
        ax.imshow(rgb, cmap="gray" if image.ndim == 2 else None, origin="upper", zorder=0, alpha=0.55,
                  extent=(origin[0], origin[0] + w * scale, origin[1], origin[1] + h * scale))
    tb = mesh.tri_body
    face = [colours[b % len(colours)] for b in tb]
    ax.add_collection(PolyCollection(mesh.vertices[mesh.triangles], facecolors=face, alpha=BODY_ALPHA, zorder=1))
    for b, name in enumerate(mesh.names):  # the legend's swatch as the triangles are filled, alpha and all
        ax.fill([], [], color=colours[b % len(colours)], alpha=BODY_ALPHA, label=f"body {b}: {name}")
    ax.add_collection(PolyCollection(mesh.vertices[mesh.triangles], facecolors="none", edgecolors="#263238",
                                     linewidths=0.45, zorder=1))
    bv = mesh.vertices[mesh.boundary]
    ax.plot(bv[:, 0], bv[:, 1], "o", ms=2.2, color="#c62828", zorder=2, label="boundary vertices")
    if grading is not None:
        ax.add_patch(plt.Circle((grading.x, grading.y), grading.radius, fill=False, ls="--", color="#333333",
                                zorder=3, label="fine region"))
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    if image is not None:
        h, w = image.shape[:2]
        lo = np.minimum(lo, origin)
        hi = np.maximum(hi, (origin[0] + w * scale, origin[1] + h * scale))
    pad = 0.02 * float(np.max(hi - lo))
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title, fontsize=9)
    ax.legend(loc="upper right", fontsize=7)
    _save(fig, path, dpi=120)
