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
- against the barrier contact's outline (:func:`outline_checks`, its polygons): tunnelling when the first and
  the last edge a loop's crossed edges along the chord face apart (normals with a negative dot product; a chord
  cutting a corner of the polygon the particle slid around crosses two edges facing the same way), and the
  Simulation follows the barrier step part by part (its ``tool_path``), so a tool moving farther than its
  width in one step is not judged by one chord through the tip the particles slid around;
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



@njit(cache=True, inline="always")
def _in_loop(px: float, py: float, pos: np.ndarray, edges: np.ndarray, k0: int, k1: int) -> tuple[bool, float]:
    """(inside, distance to the boundary) of a point and the closed polygon of edges k0..k1 (even-odd rule)."""
    inside = False
    dist = np.inf
    for k in range(k0, k1):
        ax, ay = pos[edges[k, 0], 0], pos[edges[k, 0], 1]
        bx, by = pos[edges[k, 1], 0], pos[edges[k, 1], 1]
        if (ay > py) != (by > py) and px < ax + (py - ay) * (bx - ax) / (by - ay):
            inside = not inside
        ex, ey = bx - ax, by - ay
        ll = ex * ex + ey * ey
        s = 0.0 if ll == 0.0 else min(1.0, max(0.0, ((px - ax) * ex + (py - ay) * ey) / ll))
        dist = min(dist, np.hypot(px - ax - s * ex, py - ay - s * ey))
    return inside, dist


@njit(cache=True, inline="always")
def _crosses(ax: float, ay: float, bx: float, by: float, cx: float, cy: float, dx: float, dy: float) -> bool:
    """Segments a-b and c-d cross (proper crossing)."""
    d1 = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    d2 = (bx - ax) * (dy - ay) - (by - ay) * (dx - ax)
    d3 = (dx - cx) * (ay - cy) - (dy - cy) * (ax - cx)
    d4 = (dx - cx) * (by - cy) - (dy - cy) * (bx - cx)
    return d1 * d2 < 0.0 and d3 * d4 < 0.0


@njit(cache=True, nogil=True)
def outline_checks(x0: np.ndarray, x1: np.ndarray, frame0: np.ndarray, frame1: np.ndarray, pos1: np.ndarray,
                   edges: np.ndarray, loop_ptr: np.ndarray, tris: np.ndarray,
                   inside_tol: float) -> tuple[int, float, int, int, bool]:
    """The checks of :func:`tool_checks` against the tool's true outline, its closed polygons (the barrier
    contact's tool, ``core/contact/collider.py``): ``pos1`` (V, 2) its vertices at the step's end, ``edges`` (E,
    2) their loops' edges, loop l's edges ``loop_ptr[l]:loop_ptr[l + 1]``; ``frame0``, ``frame1`` = (x, y, cos,
    sin) of the tool's pose at the step's start and end (a particle's chord is taken in the tool's frame, its start
    carried by the tool's motion). Returns (n_inside, deepest [m], deepest particle or -1, n_tunnelled, buried)."""
    n_inside = 0
    deepest = 0.0
    arg = -1
    n_tunnel = 0
    n_loops = loop_ptr.shape[0] - 1
    lox, loy, hix, hiy = np.inf, np.inf, -np.inf, -np.inf
    for v in range(pos1.shape[0]):
        lox, loy = min(lox, pos1[v, 0]), min(loy, pos1[v, 1])
        hix, hiy = max(hix, pos1[v, 0]), max(hiy, pos1[v, 1])
    for i in range(x1.shape[0]):
        # the start carried into the end's frame: local in frame0, then placed by frame1
        rx, ry = x0[i, 0] - frame0[0], x0[i, 1] - frame0[1]
        lx, ly = frame0[2] * rx + frame0[3] * ry, -frame0[3] * rx + frame0[2] * ry
        sx = frame1[0] + frame1[2] * lx - frame1[3] * ly
        sy = frame1[1] + frame1[3] * lx + frame1[2] * ly
        ex, ey = x1[i, 0], x1[i, 1]
        if (max(sx, ex) < lox or min(sx, ex) > hix or max(sy, ey) < loy or min(sy, ey) > hiy):
            continue
        inside_end = False
        for lp in range(n_loops):
            inside, dist = _in_loop(ex, ey, pos1, edges, loop_ptr[lp], loop_ptr[lp + 1])
            if inside and dist > inside_tol:
                inside_end = True
                n_inside += 1
                if dist > deepest:
                    deepest = dist
                    arg = i
                break
        if inside_end:
            continue
        started_inside = False
        for lp in range(n_loops):
            if _in_loop(sx, sy, pos1, edges, loop_ptr[lp], loop_ptr[lp + 1])[0]:
                started_inside = True
        if started_inside:
            continue
        for lp in range(n_loops):
            # the first and the last edge the chord crosses: through the tool when their normals point apart
            # (a chord that cuts a corner of the polygon the particle slid around crosses two edges that face
            # the same way)
            t_first, t_last = np.inf, -np.inf
            n_first_x = n_first_y = n_last_x = n_last_y = 0.0
            for k in range(loop_ptr[lp], loop_ptr[lp + 1]):
                a, b = edges[k, 0], edges[k, 1]
                ax, ay, bx, by = pos1[a, 0], pos1[a, 1], pos1[b, 0], pos1[b, 1]
                if _crosses(sx, sy, ex, ey, ax, ay, bx, by):
                    denom = (ex - sx) * (by - ay) - (ey - sy) * (bx - ax)
                    t = ((ax - sx) * (by - ay) - (ay - sy) * (bx - ax)) / denom
                    if t < t_first:
                        t_first, n_first_x, n_first_y = t, by - ay, ax - bx
                    if t > t_last:
                        t_last, n_last_x, n_last_y = t, by - ay, ax - bx
            if t_last > t_first and n_first_x * n_last_x + n_first_y * n_last_y < 0.0:
                n_tunnel += 1
                break
    # buried: a vertex of the outline inside a triangle of the deformed tissue
    buried = False
    for t in range(tris.shape[0]):
        a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
        if (max(x1[a, 0], x1[b, 0], x1[c, 0]) < lox or min(x1[a, 0], x1[b, 0], x1[c, 0]) > hix
                or max(x1[a, 1], x1[b, 1], x1[c, 1]) < loy or min(x1[a, 1], x1[b, 1], x1[c, 1]) > hiy):
            continue
        for v in range(pos1.shape[0]):
            px, py = pos1[v, 0], pos1[v, 1]
            d1 = (x1[b, 0] - x1[a, 0]) * (py - x1[a, 1]) - (x1[b, 1] - x1[a, 1]) * (px - x1[a, 0])
            d2 = (x1[c, 0] - x1[b, 0]) * (py - x1[b, 1]) - (x1[c, 1] - x1[b, 1]) * (px - x1[b, 0])
            d3 = (x1[a, 0] - x1[c, 0]) * (py - x1[c, 1]) - (x1[a, 1] - x1[c, 1]) * (px - x1[c, 0])
            if (d1 > 0.0 and d2 > 0.0 and d3 > 0.0) or (d1 < 0.0 and d2 < 0.0 and d3 < 0.0):
                buried = True
                break
        if buried:
            break
    return n_inside, deepest, arg, n_tunnel, buried
