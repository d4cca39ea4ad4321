"""Run-time checks of the tool against the tissue after a step: penetration, tunnelling, a buried tool.

All against the tool's own shape (no contact margin), posed at the step's start
(``shape0``) and end (``shape1``), packed by :func:`~tissue_sim_ros.core.contact.tool.tool_shape_array`:

- penetration: particles inside the tool at the end of the step (signed distance
  < -:data:`INSIDE_TOL`), their count and the deepest one's depth [m];
- tunnelling: particles outside the tool at both ends of the step whose path
  relative to the tool (the chord from their start in the frame of ``shape0`` to
  their end in the frame of ``shape1``) runs through it, entering and leaving on
  opposite sides (outward normals at entry and exit with a negative dot product,
  so a particle the projection slid around a corner does not count): the tool
  passed through them within the step, which no end-of-step check sees;
- a buried tool: a point of the tool's axis (9 from end to end; the centre of a
  sphere) lies inside a triangle of the deformed tissue. Projection contact keeps particles out of the tool, but the triangles
  can still close over it (a deep, fast push folds the mesh over the tool), and
  then the tool is inside the tissue while no particle is.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .kernels import _line_interval, _rounded_box_sdf, _sdf_local, _to_local

#: A particle this far inside the tool [m] counts as penetrating (round-off on the surface does not).
INSIDE_TOL = 1e-9
#: Points along the tool's axis tested for lying inside the tissue (a buried tool).
BURIED_SAMPLES = 9


@njit(cache=True, nogil=True)
def tool_checks(x0: np.ndarray, x1: np.ndarray, shape0: np.ndarray, shape1: np.ndarray, tris: np.ndarray,
                inside_tol: float) -> tuple[int, float, int, int, bool]:
    """(n_inside, deepest [m], deepest particle or -1, n_tunnelled, buried) of one step.

    x0, x1 : (N, 2) float64 positions at the start and end of the step [m];
    shape0, shape1 : (7,) packed tool (no margin); tris : (T, 3) int32.
    """
    n_inside = 0
    deepest = 0.0
    arg = -1
    n_tunnel = 0
    for i in range(x1.shape[0]):
        d1, _, _ = _rounded_box_sdf(x1[i, 0], x1[i, 1], shape1)
        if d1 < -inside_tol:
            n_inside += 1
            if -d1 > deepest:
                deepest = -d1
                arg = i
            continue
        d0, _, _ = _rounded_box_sdf(x0[i, 0], x0[i, 1], shape0)
        if d0 < -inside_tol:
            continue
        ax, ay = _to_local(x0[i, 0], x0[i, 1], shape0)
        bx, by = _to_local(x1[i, 0], x1[i, 1], shape1)
        dx, dy = bx - ax, by - ay
        if dx * dx + dy * dy == 0.0:
            continue
        hit, s_in, s_out = _line_interval(ax, ay, dx, dy, shape1[4], shape1[5], shape1[6])
        if hit and s_in > 0.0 and s_out < 1.0 and s_out > s_in:
            s = 0.5 * (s_in + s_out)
            depth, _, _ = _sdf_local(ax + s * dx, ay + s * dy, shape1[4], shape1[5], shape1[6])
            _, nx0, ny0 = _sdf_local(ax + s_in * dx, ay + s_in * dy, shape1[4], shape1[5], shape1[6])
            _, nx1, ny1 = _sdf_local(ax + s_out * dx, ay + s_out * dy, shape1[4], shape1[5], shape1[6])
            if depth < -inside_tol and nx0 * nx1 + ny0 * ny1 < 0.0:
                n_tunnel += 1
    # buried: a point of the tool's axis (BURIED_SAMPLES points from end to end, the centre for a sphere)
    # inside a triangle of the deformed tissue; triangles off the tool's bounding box are skipped
    buried = False
    cs, sn, hx, hy, rr = shape1[2], shape1[3], shape1[4], shape1[5], shape1[6]
    ext = abs(cs) * hx + abs(sn) * hy + rr
    eyt = abs(sn) * hx + abs(cs) * hy + rr
    lox, hix = shape1[0] - ext, shape1[0] + ext
    loy, hiy = shape1[1] - eyt, shape1[1] + eyt
    n_s = BURIED_SAMPLES if hx > 0.0 else 1
    for t in range(tris.shape[0]):
        a = tris[t, 0]
        b = tris[t, 1]
        c = tris[t, 2]
        if (max(x1[a, 0], x1[b, 0], x1[c, 0]) < lox or min(x1[a, 0], x1[b, 0], x1[c, 0]) > hix
                or max(x1[a, 1], x1[b, 1], x1[c, 1]) < loy or min(x1[a, 1], x1[b, 1], x1[c, 1]) > hiy):
            continue
        for k in range(n_s):
            s_k = 0.0 if n_s == 1 else -hx + 2.0 * hx * k / (n_s - 1)
            px = shape1[0] + cs * s_k
            py = shape1[1] + sn * s_k
            d1 = (x1[b, 0] - x1[a, 0]) * (py - x1[a, 1]) - (x1[b, 1] - x1[a, 1]) * (px - x1[a, 0])
            d2 = (x1[c, 0] - x1[b, 0]) * (py - x1[b, 1]) - (x1[c, 1] - x1[b, 1]) * (px - x1[b, 0])
            d3 = (x1[a, 0] - x1[c, 0]) * (py - x1[c, 1]) - (x1[a, 1] - x1[c, 1]) * (px - x1[c, 0])
            if (d1 >= 0.0 and d2 >= 0.0 and d3 >= 0.0) or (d1 <= 0.0 and d2 <= 0.0 and d3 <= 0.0):  # edges count
                buried = True
                break
        if buried:
            break
    return n_inside, deepest, arg, n_tunnel, buried

