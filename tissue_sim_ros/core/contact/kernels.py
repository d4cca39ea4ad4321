r"""Numba kernels of the tool against the tissue, on plain arrays: the tool's signed distance, the
swept projection of particles and boundary edges out of the tool (called inside the solver's
iterations), and the culling that finds candidates. No Model, no python-fcl: the physics calls
them from its solver loop, and :mod:`.collision` from its detection.

Semantics:

* **Projection, swept.** Conservative advancement in the tool's frame: each
  candidate particle's path relative to the tool, from ``x_start`` in the
  frame of ``shape0`` to ``x`` in the frame of ``shape1`` (a straight chord in
  the tool frame), is intersected exactly with the inflated shape (a rounded
  box: two rectangles and four discs). A path that enters the shape puts the
  particle back on the surface on the side it came from: moved along the
  entry point's outward normal to where that line leaves the shape (so it keeps
  its tangential motion and slides along the tool), or onto the entry point
  when that line misses the shape. A particle that started inside the shape is
  pushed out to the nearest surface point. A tool moving many times its
  thickness per step therefore cannot pass through the tissue's particles.
* **Projection, surface** (``contact_surface="edges"``, default). Particles
  alone let a tool thinner than the mesh spacing slip between them into the
  tissue (the authors' 5 mm box on the 5 cm default mesh met its first
  particle only at step 272 of experiment a, its tip inside the lower tissue
  from step 201). So each body's boundary edges (used by one triangle,
  ordered as in their CCW triangle: body on the left) are kept out of the
  tool as well, in the same solver iterations, right after the particles
  (:func:`project_edges`): the tool's deepest point past an edge, within the
  edge's span (:func:`edge_depth`), is put back on the edge by moving its two
  particles along the inward normal with barycentric PBD weights. Which side
  the tool came from is read from the start of the (sub)step: an edge the
  tool was not through then (by more than ``max(contact_margin, 1e-4)``)
  pushes it back out however far it moved (swept); an edge it was already
  through (a tool left inside by the paper model or a pose jump) ignores it
  instead of snapping the tissue over it. Experiment a: contact at step 194,
  the lower tissue indented ~70 mm by step 300, no inverted triangle, the
  tip never inside a triangle. ``contact_surface="particles"`` is the
  particle-only behaviour. Candidate edges (:func:`swept_edge_candidates`)
  put their free particles among the particle candidates, so the solver
  runs the projection whenever either set is non-empty.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

#: A start position this far inside the tool [m] counts as inside (below it, as
#: on the surface: a particle left on the surface by the last step sits there
#: within round-off, and must keep the side it came from).
INSIDE_TOL = 1e-9
#: Round-off allowance of :func:`near_triangles`' lower bound [m].
NEAR_TOL = 1e-9
#: Squared length [m^2] below which a boundary edge has no direction (skipped by the edge contact).
EDGE_EPS2 = 1e-24
#: A tool-frame direction component this small counts as zero: the tool's face is parallel to the edge.
PARALLEL_TOL = 1e-12
#: An edge whose direction turned by more than acos of this within a substep is left to the particles.
EDGE_TURN_COS = 0.7071
#: Smallest start-of-substep depth [m] the edge contact accepts as a solver residual (``contact_margin`` if larger).
EDGE_SIDE_TOL_MIN = 1e-4


@njit(cache=True, nogil=True)
def _sdf_local(lx: float, ly: float, hx: float, hy: float, r: float) -> tuple[float, float, float]:
    """Signed distance from a tool-frame point to the rounded box (half extents hx, hy, corner radius r).

    Returns (d, gx, gy): d < 0 inside; (gx, gy) the outward unit gradient in the
    tool frame. Inside, and at the exact centre, ties go to the y face.
    """
    qx, qy = abs(lx) - hx, abs(ly) - hy
    ox, oy = max(qx, 0.0), max(qy, 0.0)
    outside = math.sqrt(ox * ox + oy * oy)
    if outside > 0.0:
        gx, gy = ox / outside, oy / outside
        d = outside
    elif qx > qy:
        gx, gy = 1.0, 0.0
        d = qx
    else:
        gx, gy = 0.0, 1.0
        d = qy
    if lx < 0.0:
        gx = -gx
    if ly < 0.0:
        gy = -gy
    return d - r, gx, gy


@njit(cache=True, nogil=True)
def _rounded_box_sdf(px: float, py: float, shape: np.ndarray) -> tuple[float, float, float]:
    """Signed distance from world point (px, py) to the posed rounded box, and its outward unit gradient (world)."""
    c, s = shape[2], shape[3]
    dx, dy = px - shape[0], py - shape[1]
    lx, ly = c * dx + s * dy, -s * dx + c * dy  # into the tool frame
    d, gx, gy = _sdf_local(lx, ly, shape[4], shape[5], shape[6])
    return d, c * gx - s * gy, s * gx + c * gy


@njit(cache=True, nogil=True)
def _slab(a: float, d: float, lo: float, hi: float, s_in: float, s_out: float) -> tuple[float, float]:
    """Clip the line parameter interval [s_in, s_out] to lo <= a + s d <= hi (empty: s_in > s_out)."""
    if d == 0.0:
        if a < lo or a > hi:
            return 1.0, 0.0
        return s_in, s_out
    t1, t2 = (lo - a) / d, (hi - a) / d
    if t1 > t2:
        t1, t2 = t2, t1
    return max(s_in, t1), min(s_out, t2)


@njit(cache=True, nogil=True)
def _line_interval(ax: float, ay: float, dx: float, dy: float,
                   hx: float, hy: float, r: float) -> tuple[bool, float, float]:
    """Parameter interval of the line a + s d (tool frame) inside the rounded box.

    The rounded box is the union of two rectangles and four discs; being convex,
    the line meets it in one interval, the hull of the pieces' intervals.
    Returns (hit, s_in, s_out); s may be +-inf when d = 0 and a is inside.
    """
    inf = np.inf
    hit = False
    lo, hi = inf, -inf
    for k in range(2):
        ex = r if k == 0 else 0.0
        ey = 0.0 if k == 0 else r
        s0, s1 = _slab(ax, dx, -hx - ex, hx + ex, -inf, inf)
        s0, s1 = _slab(ay, dy, -hy - ey, hy + ey, s0, s1)
        if s0 <= s1:
            hit = True
            lo, hi = min(lo, s0), max(hi, s1)
    if r > 0.0:
        aa = dx * dx + dy * dy
        for cx in (-hx, hx):
            for cy in (-hy, hy):
                px, py = ax - cx, ay - cy
                cc = px * px + py * py - r * r
                if aa == 0.0:
                    if cc <= 0.0:
                        hit = True
                        lo, hi = -inf, inf
                    continue
                bb = dx * px + dy * py
                disc = bb * bb - aa * cc
                if disc < 0.0:
                    continue
                sq = math.sqrt(disc)
                hit = True
                lo, hi = min(lo, (-bb - sq) / aa), max(hi, (-bb + sq) / aa)
    return hit, lo, hi


@njit(cache=True, nogil=True)
def project_tool(x: np.ndarray, x_start: np.ndarray, inv_mass: np.ndarray, candidates: np.ndarray,
                 shape0: np.ndarray, shape1: np.ndarray, dx_accum: np.ndarray) -> int:
    """Keep candidate particles out of the swept tool; returns how many moved.

    For each candidate i (skipped if ``inv_mass[i] == 0``), its path relative to
    the tool runs from ``x_start[i]`` in the frame of ``shape0`` to ``x[i]`` in
    the frame of ``shape1`` (a chord in the tool frame). If that path enters the
    shape (``shape1``'s extents, inflated radius included), the particle goes
    back to the surface on the side it came from: along the entry point's
    outward normal n, to where the line x + t n (t > 0) leaves the shape, or to
    the entry point if that line misses it. A particle that started inside is
    pushed out to the nearest surface point.

    Parameters
    ----------
    x : ndarray, shape (N, 2), float64
        Current positions [m], updated in place.
    x_start : ndarray, shape (N, 2), float64
        Positions at the start of the (sub)step [m].
    inv_mass : ndarray, shape (N,), float64
        Inverse masses [1/kg]; 0 = not moved.
    candidates : ndarray, shape (M,), int32
        Particles to test.
    shape0, shape1 : ndarray, shape (7,), float64
        Tool at the start and the end of the (sub)step (:func:`tool_shape_array`).
    dx_accum : ndarray, shape (N, 2), float64
        Accumulates each correction [m] (for the reaction force).
    """
    c0, s0 = shape0[2], shape0[3]
    c1, s1 = shape1[2], shape1[3]
    hx, hy, rr = shape1[4], shape1[5], shape1[6]
    moved = 0
    for k in range(candidates.shape[0]):
        i = candidates[k]
        if inv_mass[i] == 0.0:
            continue
        # both ends of the path in the tool's frame
        ux, uy = x_start[i, 0] - shape0[0], x_start[i, 1] - shape0[1]
        p0x, p0y = c0 * ux + s0 * uy, -s0 * ux + c0 * uy
        ux, uy = x[i, 0] - shape1[0], x[i, 1] - shape1[1]
        p1x, p1y = c1 * ux + s1 * uy, -s1 * ux + c1 * uy
        f1, g1x, g1y = _sdf_local(p1x, p1y, hx, hy, rr)
        f0, _, _ = _sdf_local(p0x, p0y, hx, hy, rr)
        ddx, ddy = p1x - p0x, p1y - p0y
        length = math.sqrt(ddx * ddx + ddy * ddy)
        if f0 < -INSIDE_TOL:
            # started inside (spawned in the tissue, or a rotation swept over it): nearest surface
            if f1 >= 0.0:
                continue
            tx, ty = p1x - f1 * g1x, p1y - f1 * g1y
        else:
            if f1 >= 0.0 and length <= f0 + f1:
                continue  # the SDF is 1-Lipschitz: this path cannot reach the shape
            hit, s_in, s_out = _line_interval(p0x, p0y, ddx, ddy, hx, hy, rr)
            if not hit or s_in >= 1.0 or s_out <= 0.0 or s_in >= s_out:
                continue  # the path misses the shape, stops before it, or only grazes it
            s_e = max(s_in, 0.0)
            ex, ey = p0x + s_e * ddx, p0y + s_e * ddy
            _, nx, ny = _sdf_local(ex, ey, hx, hy, rr)
            hit2, t_in, t_out = _line_interval(p1x, p1y, nx, ny, hx, hy, rr)
            if hit2 and t_in < t_out:
                if t_out <= INSIDE_TOL:
                    continue  # already past the shape on the entry side
                tx, ty = p1x + t_out * nx, p1y + t_out * ny
            else:
                tx, ty = ex, ey
        # back to the world frame with the end pose
        wx = shape1[0] + c1 * tx - s1 * ty
        wy = shape1[1] + s1 * tx + c1 * ty
        cx, cy = wx - x[i, 0], wy - x[i, 1]
        x[i, 0] = wx
        x[i, 1] = wy
        dx_accum[i, 0] += cx
        dx_accum[i, 1] += cy
        moved += 1
    return moved


@njit(cache=True, nogil=True)
def _to_local(px: float, py: float, shape: np.ndarray) -> tuple[float, float]:
    """A world point in the frame of the posed tool."""
    c, s = shape[2], shape[3]
    dx, dy = px - shape[0], py - shape[1]
    return c * dx + s * dy, -s * dx + c * dy


@njit(cache=True, nogil=True)
def edge_depth(ax: float, ay: float, bx: float, by: float, shape: np.ndarray) -> tuple[float, float, float]:
    """How far the posed tool reaches past the edge a -> b into the body on its left, within the edge's span.

    The edge's strip is the set of points whose projection on the edge line
    falls between a and b; the result is the largest distance past the line,
    along the inward normal n = (-(by - ay), bx - ax) / |b - a|, of a tool point
    in that strip, and where along the edge (t in [0, 1]) that point projects.
    The tool being convex, its depth profile over the edge's axis is concave,
    so the deepest point in the strip is the tool's support point in direction
    n when it projects inside the span, and otherwise the deepest tool point
    on the normal line through the span's nearer end (t = 0 or 1). A face
    parallel to the edge (support set a segment) is taken at the middle of its
    overlap with the span.

    Returns (depth, t, line_depth): depth [m] > 0 when the tool is past the
    edge line (<= 0: the tool's part in the strip lies outside the body), -inf
    when no tool point lies in the strip or the edge has zero length;
    line_depth [m] how far the tool's support point is past the whole line,
    wherever it projects (-inf for a zero-length edge).
    """
    ex, ey = bx - ax, by - ay
    length2 = ex * ex + ey * ey
    if length2 <= EDGE_EPS2:
        return -np.inf, 0.0, -np.inf
    length = math.sqrt(length2)
    ux, uy = ex / length, ey / length
    nx, ny = -uy, ux
    c, s = shape[2], shape[3]
    hx, hy, rr = shape[4], shape[5], shape[6]
    dlx, dly = c * nx + s * ny, -s * nx + c * ny  # n in the tool frame
    sx = 1.0 if dlx > 0.0 else -1.0
    sy = 1.0 if dly > 0.0 else -1.0
    # support point (tool frame) and, for a face parallel to the edge, the face's other end
    p1x, p1y = sx * hx + rr * dlx, sy * hy + rr * dly
    p2x, p2y = p1x, p1y
    if abs(dlx) <= PARALLEL_TOL:
        p1x, p2x = -hx, hx
        p1y = p2y = sy * (hy + rr)
    elif abs(dly) <= PARALLEL_TOL:
        p1y, p2y = -hy, hy
        p1x = p2x = sx * (hx + rr)
    w1x, w1y = shape[0] + c * p1x - s * p1y, shape[1] + s * p1x + c * p1y
    w2x, w2y = shape[0] + c * p2x - s * p2y, shape[1] + s * p2x + c * p2y
    u1 = (w1x - ax) * ux + (w1y - ay) * uy
    u2 = (w2x - ax) * ux + (w2y - ay) * uy
    lo, hi = min(u1, u2), max(u1, u2)
    lo_c, hi_c = max(lo, 0.0), min(hi, length)
    line_depth = max((w1x - ax) * nx + (w1y - ay) * ny, (w2x - ax) * nx + (w2y - ay) * ny)
    if lo_c <= hi_c:
        # the support set meets the span: its depth, at the middle of the overlap
        return line_depth, 0.5 * (lo_c + hi_c) / length, line_depth
    # beyond the span: the deepest point is on the normal line through the nearer end
    u = 0.0 if hi < 0.0 else length
    qlx, qly = _to_local(ax + u * ux, ay + u * uy, shape)
    hit, s_in, s_out = _line_interval(qlx, qly, dlx, dly, hx, hy, rr)
    if not hit or s_in > s_out:
        return -np.inf, 0.0, line_depth
    return s_out, u / length, line_depth


@njit(cache=True, nogil=True)
def _sweep_bound(shape0: np.ndarray, shape1: np.ndarray) -> float:
    """Upper bound [m] on how far any point of the tool moves from ``shape0`` to ``shape1``."""
    ddx, ddy = shape1[0] - shape0[0], shape1[1] - shape0[1]
    dang = abs(math.atan2(shape0[2] * shape1[3] - shape0[3] * shape1[2], shape0[2] * shape1[2] + shape0[3] * shape1[3]))
    radius = math.sqrt(shape1[4] ** 2 + shape1[5] ** 2) + shape1[6]
    return math.sqrt(ddx * ddx + ddy * ddy) + dang * radius


@njit(cache=True, nogil=True)
def project_edges(x: np.ndarray, x_start: np.ndarray, inv_mass: np.ndarray, edges: np.ndarray,
                  shape0: np.ndarray, shape1: np.ndarray, side_tol: float, dx_accum: np.ndarray) -> int:
    """Keep boundary edges out of the swept tool (point-edge PBD); returns how many edges moved.

    For each edge a -> b (its body on the left), :func:`edge_depth` gives how
    far the tool (``shape1``) reaches past the edge at ``x`` and where (t).
    When that depth is > 0 the edge is pushed into its body along the inward
    normal n until the tool's deepest point lies on it, with barycentric
    weights: s = depth / ((1 - t)^2 w_a + t^2 w_b), dx_a = (1 - t) w_a s n,
    dx_b = t w_b s n (w = ``inv_mass``; an edge that cannot move there is skipped).

    Which side the tool came from is decided at the start of the (sub)step
    (edge at ``x_start``, tool at ``shape0``): the edge acts only if the tool
    was then past it by at most ``side_tol`` (outside it, touching it, or in it
    by a solver residual), measured in the edge's strip when the tool was in
    the strip, and otherwise past the edge's whole line (the tool beside the
    strip must have been on the edge's outer side, not beside it inside the
    body). So a tool that crossed the edge within the substep (any speed) is
    still pushed back to the outside: a swept test. A tool already through
    the edge at the start (a run with the paper model, a pose jump, a switch
    of the contact surface; or an edge turned over inside a crushed body) is
    left alone rather than snapping the tissue over it, and so is a tool that
    ends deeper than it can have come through the edge in the substep (start
    depth + the tool's sweep + the edge's own motion + ``side_tol``): a tool
    inside the tissue moving sideways into the next edge's span. An edge that
    turned by more than acos(:data:`EDGE_TURN_COS`) within the substep (a
    crushed body) is skipped too: measured along its new normal, the tool's
    far end would count as depth and throw the edge across the tool.

    Parameters
    ----------
    x : ndarray, shape (N, 2), float64
        Current positions [m], updated in place.
    x_start : ndarray, shape (N, 2), float64
        Positions at the start of the (sub)step [m].
    inv_mass : ndarray, shape (N,), float64
        Effective inverse masses [1/kg]; 0 = not moved.
    edges : ndarray, shape (K, 2), int32
        Boundary edges, each ordered with its body on the left.
    shape0, shape1 : ndarray, shape (7,), float64
        Tool at the start and the end of the (sub)step (:func:`tool_shape_array`).
    side_tol : float
        Start-of-substep depth [m] up to which the tool still counts as outside.
    dx_accum : ndarray, shape (N, 2), float64
        Accumulates each correction [m] (for the reaction force).
    """
    sweep = _sweep_bound(shape0, shape1)
    moved = 0
    for k in range(edges.shape[0]):
        a, b = edges[k, 0], edges[k, 1]
        wa, wb = inv_mass[a], inv_mass[b]
        if wa == 0.0 and wb == 0.0:
            continue
        depth, t, _ = edge_depth(x[a, 0], x[a, 1], x[b, 0], x[b, 1], shape1)
        if not depth > 0.0:
            continue
        depth0, _, line0 = edge_depth(x_start[a, 0], x_start[a, 1], x_start[b, 0], x_start[b, 1], shape0)
        if depth0 > side_tol or (depth0 == -np.inf and line0 > side_tol):
            continue  # the tool was through this edge (or beside it, inside the body) at the start
        ex, ey = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1]
        e0x, e0y = x_start[b, 0] - x_start[a, 0], x_start[b, 1] - x_start[a, 1]
        if ex * e0x + ey * e0y <= EDGE_TURN_COS * math.sqrt((ex * ex + ey * ey) * (e0x * e0x + e0y * e0y)):
            continue  # the edge turned too far in this substep (a crushed body): its inside is not where it was
        da = math.sqrt((x[a, 0] - x_start[a, 0]) ** 2 + (x[a, 1] - x_start[a, 1]) ** 2)
        db = math.sqrt((x[b, 0] - x_start[b, 0]) ** 2 + (x[b, 1] - x_start[b, 1]) ** 2)
        if depth > max(depth0, 0.0) + sweep + max(da, db) + side_tol:
            continue  # deeper than the tool can have come through this edge: it came from inside the tissue
        denom = (1.0 - t) * (1.0 - t) * wa + t * t * wb
        if denom <= 0.0:
            continue
        length = math.sqrt(ex * ex + ey * ey)
        nx, ny = -ey / length, ex / length
        sc = depth / denom
        fa, fb = (1.0 - t) * wa * sc, t * wb * sc
        x[a, 0] += fa * nx
        x[a, 1] += fa * ny
        x[b, 0] += fb * nx
        x[b, 1] += fb * ny
        dx_accum[a, 0] += fa * nx
        dx_accum[a, 1] += fa * ny
        dx_accum[b, 0] += fb * nx
        dx_accum[b, 1] += fb * ny
        moved += 1
    return moved


@njit(cache=True, nogil=True)
def swept_edge_candidates(x: np.ndarray, inv_mass: np.ndarray, edges: np.ndarray, shape0: np.ndarray,
                          shape1: np.ndarray, reach: float, out: np.ndarray) -> int:
    """Edges with a free particle that come within ``reach`` of the tool swept from ``shape0`` to ``shape1``.

    The signed distance is 1-Lipschitz, so every point of an edge of length L
    is at least max(f(a) - L, f(b) - L, f(mid) - L / 2) from the tool; an edge
    is kept when that bound, at either end pose, is <= reach + sweep / 2 (as
    :func:`swept_candidates`). Returns the count; out[:count] (int32) are row
    indices into ``edges`` (K, 2) int32; x (N, 2) float64 [m].
    """
    limit = reach + 0.5 * _sweep_bound(shape0, shape1)
    n = 0
    for k in range(edges.shape[0]):
        a, b = edges[k, 0], edges[k, 1]
        if inv_mass[a] == 0.0 and inv_mass[b] == 0.0:
            continue
        ex, ey = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1]
        length = math.sqrt(ex * ex + ey * ey)
        mx, my = x[a, 0] + 0.5 * ex, x[a, 1] + 0.5 * ey
        lower = np.inf
        for shape in (shape0, shape1):
            fa, _, _ = _rounded_box_sdf(x[a, 0], x[a, 1], shape)
            fb, _, _ = _rounded_box_sdf(x[b, 0], x[b, 1], shape)
            fm, _, _ = _rounded_box_sdf(mx, my, shape)
            lower = min(lower, max(fa - length, fb - length, fm - 0.5 * length))
        if lower <= limit:
            out[n] = k
            n += 1
    return n


@njit(cache=True, nogil=True)
def gather_surface_edges(edges: np.ndarray, sel: np.ndarray, n_sel: int, inv_mass: np.ndarray,
                         cand: np.ndarray, n_cand: int, mark: np.ndarray, out_edges: np.ndarray) -> int:
    """Gather the selected edges and add their free particles to the particle candidates; returns the new count.

    out_edges[:n_sel] = edges[sel[:n_sel]] ((K, 2) int32). Every free particle
    (``inv_mass`` > 0) of those edges not already in ``cand[:n_cand]`` is
    appended to ``cand`` (int32, room for every particle), in edge order.
    ``mark`` (N,) bool must be all False on entry and is left all False.
    """
    for k in range(n_cand):
        mark[cand[k]] = True
    n = n_cand
    for k in range(n_sel):
        for j in range(2):
            p = edges[sel[k], j]
            out_edges[k, j] = p
            if inv_mass[p] > 0.0 and not mark[p]:
                mark[p] = True
                cand[n] = p
                n += 1
    for k in range(n):
        mark[cand[k]] = False
    return n


@njit(cache=True, nogil=True)
def points_sdf(x: np.ndarray, shape: np.ndarray, out: np.ndarray, grad: np.ndarray) -> None:
    """Signed distance of every point to the posed tool shape, and its outward unit gradient.

    x : (N, 2) float64 positions [m]; shape : (7,) packed tool; out : (N,)
    float64 [m], negative inside; grad : (N, 2) float64 (world frame).
    """
    for i in range(x.shape[0]):
        d, gx, gy = _rounded_box_sdf(x[i, 0], x[i, 1], shape)
        out[i] = d
        grad[i, 0] = gx
        grad[i, 1] = gy


@njit(cache=True, nogil=True)
def body_nearest(sdf: np.ndarray, particle_body: np.ndarray, out_min: np.ndarray, out_arg: np.ndarray) -> None:
    """Per body: the smallest signed distance of its particles and that particle (first on ties).

    sdf : (N,) float64 [m]; particle_body : (N,) int32; out_min : (B,) float64 [m]
    (inf for a body without particles); out_arg : (B,) int32 (-1 likewise).
    """
    for b in range(out_min.shape[0]):
        out_min[b] = np.inf
        out_arg[b] = -1
    for i in range(sdf.shape[0]):
        b = particle_body[i]
        if sdf[i] < out_min[b]:
            out_min[b] = sdf[i]
            out_arg[b] = i


@njit(cache=True, nogil=True)
def near_triangles(x: np.ndarray, tris: np.ndarray, sdf: np.ndarray, grad: np.ndarray, reach: float,
                   out: np.ndarray) -> int:
    """Triangles that may come within ``reach`` of the tool; returns their count, indices in ``out[:count]``.

    The tool's signed distance f is convex (the tool is convex), so each
    vertex's tangent plane bounds it from below over the triangle:
    f(p) >= f(v_k) + g_k . (p - v_k) >= f(v_k) + min_j g_k . (v_j - v_k).
    The largest of the three bounds is a lower bound on the triangle's distance
    to the tool (exact for a face parallel to a tool face); a triangle is kept
    when it is <= reach (+ ``NEAR_TOL``, so that round-off in the bound never
    drops the triangle holding the nearest vertex when reach is that vertex's distance).

    x : (N, 2) float64 [m]; tris : (T, 3) int32; sdf : (N,) float64 signed
    distance [m]; grad : (N, 2) its gradient; out : (T,) int32.
    """
    n = 0
    for t in range(tris.shape[0]):
        lower = -np.inf
        for a in range(3):
            k = tris[t, a]
            m = 0.0
            for b in range(3):
                j = tris[t, b]
                m = min(m, grad[k, 0] * (x[j, 0] - x[k, 0]) + grad[k, 1] * (x[j, 1] - x[k, 1]))
            lower = max(lower, sdf[k] + m)
        if lower <= reach + NEAR_TOL:
            out[n] = t
            n += 1
    return n


@njit(cache=True, nogil=True)
def compact_triangles(x: np.ndarray, tris: np.ndarray, sel: np.ndarray, n_sel: int, vmap: np.ndarray,
                      out_verts: np.ndarray, out_ids: np.ndarray, out_tris: np.ndarray) -> int:
    """Gather triangles ``tris[sel[:n_sel]]`` into a compact mesh; returns the vertex count.

    out_verts[:nv] (float64, (., 3), z = 0) holds the used vertices, out_ids[:nv]
    their particle indices and out_tris[:n_sel] the triangles renumbered.
    ``vmap`` (N,) int32 must be all -1 on entry and is left all -1.
    """
    nv = 0
    for k in range(n_sel):
        t = sel[k]
        for j in range(3):
            p = tris[t, j]
            if vmap[p] < 0:
                vmap[p] = nv
                out_verts[nv, 0] = x[p, 0]
                out_verts[nv, 1] = x[p, 1]
                out_verts[nv, 2] = 0.0
                out_ids[nv] = p
                nv += 1
            out_tris[k, j] = vmap[p]
    for k in range(nv):
        vmap[out_ids[k]] = -1
    return nv


@njit(cache=True, nogil=True)
def paper_displacement(x: np.ndarray, parts: np.ndarray, inv_mass: np.ndarray, q: int, d_star: float,
                       ux: float, uy: float, r: float, out_idx: np.ndarray, out_dx: np.ndarray) -> int:
    """The paper's eq. (3) on one body; returns the count K of displaced particles.

    Every free particle i of ``parts`` with r - |x_q - x_i| >= 0 is displaced by
    (r - |x_q - x_i|) / r * d_star * (ux, uy), (ux, uy) the unit direction of the
    tool's velocity. Writes out_idx[:K] (int32) and out_dx[:K] (float64, (K, 2), [m]).
    """
    n = 0
    qx, qy = x[q, 0], x[q, 1]
    for k in range(parts.shape[0]):
        i = parts[k]
        if inv_mass[i] == 0.0:
            continue
        dist = math.sqrt((x[i, 0] - qx) ** 2 + (x[i, 1] - qy) ** 2)
        if r - dist >= 0.0:
            f = (r - dist) / r * d_star
            out_idx[n] = i
            out_dx[n, 0] = f * ux
            out_dx[n, 1] = f * uy
            n += 1
    return n


@njit(cache=True, nogil=True)
def swept_candidates(x: np.ndarray, inv_mass: np.ndarray, shape0: np.ndarray, shape1: np.ndarray,
                     reach: float, out: np.ndarray) -> int:
    """Free particles within ``reach`` of the tool swept from ``shape0`` to ``shape1``; returns the count.

    Every point of the swept shape lies within half the sweep (``sweep``) of the
    shape at one end or the other, where ``sweep`` bounds how far any point of
    the tool moves: the centre's travel plus the rotation times the shape's
    bounding radius. So a particle is kept when
    min(sdf0, sdf1) <= reach + sweep / 2, which never misses one the swept
    tool comes within ``reach`` of.

    x : (N, 2) float64 positions at the start of the step [m]; inv_mass : (N,);
    shape0, shape1 : (7,) packed tool (margin included); out : (N,) int32.
    """
    ddx, ddy = shape1[0] - shape0[0], shape1[1] - shape0[1]
    dang = abs(math.atan2(shape0[2] * shape1[3] - shape0[3] * shape1[2], shape0[2] * shape1[2] + shape0[3] * shape1[3]))
    radius = math.sqrt(shape1[4] ** 2 + shape1[5] ** 2) + shape1[6]
    sweep = math.sqrt(ddx * ddx + ddy * ddy) + dang * radius
    limit = reach + 0.5 * sweep
    n = 0
    for i in range(x.shape[0]):
        if inv_mass[i] == 0.0:
            continue
        d0, _, _ = _rounded_box_sdf(x[i, 0], x[i, 1], shape0)
        d1, _, _ = _rounded_box_sdf(x[i, 0], x[i, 1], shape1)
        if min(d0, d1) <= limit:
            out[n] = i
            n += 1
    return n


@njit(cache=True, nogil=True)
def projection_candidates(x: np.ndarray, v: np.ndarray, inv_mass: np.ndarray, shape0: np.ndarray,
                          shape1: np.ndarray, pad: tuple, surface: tuple, ws: tuple) -> tuple[int, int]:
    """The projection contact's candidates of one step: the free particles, and the boundary edges, near the tool
    swept from ``shape0`` to ``shape1`` (margin included); returns (particles, edges).

    The reach is the largest plausible particle displacement in the step: free flight (|v|max dt + |g| dt^2)
    plus the tool's own travel (a particle pushed or dragged by the tool moves at most about as far as it);
    ``pad`` = (dt [s], |g| dt^2 [m], travel [m]). ``surface`` = (boundary edges (K, 2) int32, use them): the
    edges' free particles join the particle candidates (:func:`gather_surface_edges`), so the solver runs the
    projection when either set is non-empty and a particle an edge moves is tested against the tool too. ``ws``
    = (candidates (N,) int32 out, selected edges (K,) int32, a mark (N,) bool all False, edges (K, 2) int32 out).
    The one detection the Simulation's step and a fused rollout share.
    """
    dt, free_fall, travel = pad
    boundary_edges, use_edges = surface
    cand, edge_sel, mark, edge_rows = ws
    n = x.shape[0]
    vmax2 = 0.0
    for i in range(n):
        q = v[i, 0] * v[i, 0] + v[i, 1] * v[i, 1]
        if q > vmax2:
            vmax2 = q
    vmax = math.sqrt(vmax2) if n else 0.0
    reach = vmax * dt + free_fall + travel
    n_cand = swept_candidates(x, inv_mass, shape0, shape1, reach, cand)
    n_edges = 0
    if use_edges:
        n_sel = swept_edge_candidates(x, inv_mass, boundary_edges, shape0, shape1, reach, edge_sel)
        if n_sel:
            n_cand = gather_surface_edges(boundary_edges, edge_sel, n_sel, inv_mass, cand, n_cand, mark, edge_rows)
            n_edges = n_sel
    return n_cand, n_edges
