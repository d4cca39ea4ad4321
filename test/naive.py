"""Slow, obvious NumPy references for the numba kernels of ``tissue_sim_ros.core.physics.kernels``.

Written from the equations (textbook gradient form), not from the kernels:
each projection computes C, its gradient per particle, the denominator
sum w |grad|^2 + alpha and the correction dx_i = w_i s grad_i. Inputs are
copied; results are returned. Tests compare these with the kernels on random
and degenerate inputs.
"""
from __future__ import annotations

import math

import numpy as np

#: Same degeneracy threshold as the kernels (squared length [m^2]).
EPS_LEN2 = 1e-30


def cross2(a: np.ndarray, b: np.ndarray) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


def predict(x, v, inv_mass, dt, gravity, damp):
    """x* = x + dt damp v + dt^2 (0, g) where inv_mass > 0, else x."""
    x_pred = x + dt * damp * v + dt * dt * np.array([0.0, gravity])
    return np.where((inv_mass > 0)[:, None], x_pred, x)


def hold_displaced(x_pred, inv_mass, held_idx, held_dx, scale):
    """(x_pred with held free particles moved by scale*held_dx, inverse masses with held zeroed)."""
    x = x_pred.copy()
    w = inv_mass.copy()
    for k, i in enumerate(held_idx):
        if inv_mass[i] > 0:
            x[i] += scale * held_dx[k]
        w[i] = 0.0
    return x, w


def edge_projection(x, w, i, j, d0, k, alpha, lam):
    """One distance projection: returns (dx_i, dx_j, dlam) or None when skipped."""
    d = x[i] - x[j]
    if w[i] + w[j] == 0 or d @ d <= EPS_LEN2:
        return None
    length = np.linalg.norm(d)
    grad_i = d / length
    grad_j = -grad_i
    C = length - d0
    denom = w[i] * grad_i @ grad_i + w[j] * grad_j @ grad_j + alpha
    s = k * (-C - alpha * lam) / denom
    return w[i] * s * grad_i, w[j] * s * grad_j, s


def area_value(x, a, b, c):
    return 0.5 * cross2(x[b] - x[a], x[c] - x[a])


def area_projection(x, w, a, b, c, A0, k, alpha, lam, signed):
    """One area projection: returns ((dx_a, dx_b, dx_c), dlam) or None when skipped."""
    if w[a] + w[b] + w[c] == 0:
        return None
    A = area_value(x, a, b, c)
    rot = np.array([[0.0, 1.0], [-1.0, 0.0]])  # rot @ (u, v) = (v, -u)
    # dA/dx_b = 1/2 (e2_y, -e2_x), dA/dx_c = 1/2 (-e1_y, e1_x), dA/dx_a = -(dA/dx_b + dA/dx_c)
    e1 = x[b] - x[a]
    e2 = x[c] - x[a]
    g_b = 0.5 * (rot @ e2)
    g_c = -0.5 * (rot @ e1)
    g_a = -(g_b + g_c)
    if signed:
        C = A - A0
        sign = 1.0
    else:
        C = abs(A) - abs(A0)
        sign = float(np.sign(A))
    grads = [sign * g_a, sign * g_b, sign * g_c]
    if sum(g @ g for g in grads) <= EPS_LEN2:
        return None
    denom = sum(w[p] * g @ g for p, g in zip((a, b, c), grads)) + alpha
    if denom <= 0:
        return None
    s = k * (-C - alpha * lam) / denom
    return tuple(w[p] * s * g for p, g in zip((a, b, c), grads)), s


def solve_edges(x, inv_mass, edges, rest, k, alpha, lam):
    """Gauss-Seidel sweep in array order; returns (x, lam)."""
    x = x.copy()
    lam = lam.copy()
    for e, (i, j) in enumerate(edges):
        r = edge_projection(x, inv_mass, i, j, rest[e], k, alpha, lam[e])
        if r is None:
            continue
        x[i] += r[0]
        x[j] += r[1]
        lam[e] += r[2]
    return x, lam


def solve_areas(x, inv_mass, tris, area0, k, alpha, lam, signed):
    """Gauss-Seidel sweep in array order; returns (x, lam)."""
    x = x.copy()
    lam = lam.copy()
    for t, (a, b, c) in enumerate(tris):
        r = area_projection(x, inv_mass, a, b, c, area0[t], k, alpha, lam[t], signed)
        if r is None:
            continue
        for p, dx in zip((a, b, c), r[0]):
            x[p] += dx
        lam[t] += r[1]
    return x, lam


def jacobi_edges(x, inv_mass, edges, rest, k, alpha, lam, omega):
    """Jacobi pass: (summed corrections (N, 2), new lam); multiplier increments scaled by omega."""
    dx = np.zeros_like(x)
    lam = lam.copy()
    for e, (i, j) in enumerate(edges):
        r = edge_projection(x, inv_mass, i, j, rest[e], k, alpha, lam[e])
        if r is None:
            continue
        dx[i] += omega[e] * r[0]
        dx[j] += omega[e] * r[1]
        lam[e] += omega[e] * r[2]
    return dx, lam


def jacobi_areas(x, inv_mass, tris, area0, k, alpha, lam, signed, omega):
    dx = np.zeros_like(x)
    lam = lam.copy()
    for t, (a, b, c) in enumerate(tris):
        r = area_projection(x, inv_mass, a, b, c, area0[t], k, alpha, lam[t], signed)
        if r is None:
            continue
        for p, d in zip((a, b, c), r[0]):
            dx[p] += omega[t] * d
        lam[t] += omega[t] * r[1]
    return dx, lam


def jacobi_relaxation(x, inv_mass, edges, alpha_e, tris, alpha_t, signed, scale):
    """Per-constraint omega = scale / r_c, r_c the Gershgorin bound of sweeps.jacobi_relaxation.

    Built as explicit per-constraint gradient-norm lists |g_cp| (edges 1, triangle
    vertex |opposite edge| / 2, 0 when degenerate), then the two sums.
    """
    n = x.shape[0]
    cons = []  # (particles, gradient norms, alpha)
    for i, j in edges:
        d = x[i] - x[j]
        g = 1.0 if d @ d > EPS_LEN2 else 0.0
        cons.append(((i, j), (g, g), alpha_e))
    for a, b, c in tris:
        norms = (0.5 * np.linalg.norm(x[c] - x[b]), 0.5 * np.linalg.norm(x[c] - x[a]), 0.5 * np.linalg.norm(x[b] - x[a]))
        if not signed and cross2(x[b] - x[a], x[c] - x[a]) == 0.0:
            norms = (0.0, 0.0, 0.0)
        cons.append(((a, b, c), norms, alpha_t))
    D = np.array([sum(inv_mass[p] * g * g for p, g in zip(ps, gs)) + al for ps, gs, al in cons])
    G = np.zeros(n)
    for (ps, gs, _), d in zip(cons, D):
        if d > 0:
            for p, g in zip(ps, gs):
                G[p] += g / math.sqrt(d)
    omega = np.zeros(len(cons))
    for m, ((ps, gs, al), d) in enumerate(zip(cons, D)):
        if d <= 0:
            continue
        r = al / d + sum(inv_mass[p] * g * G[p] for p, g in zip(ps, gs)) / math.sqrt(d)
        omega[m] = scale / r if r > 0 else scale
    return omega[:len(edges)], omega[len(edges):]


def update_velocity(x, x_start, dt):
    return (x - x_start) / dt


def apply_boundary_lines(x, v, inv_mass, y_top, y_bottom):
    """Clamp free particles at/past a line onto it with zero velocity; returns (x, v, n_held)."""
    x = x.copy()
    v = v.copy()
    free = inv_mass != 0
    top = free & (x[:, 1] >= y_top) if not math.isnan(y_top) else np.zeros(len(x), bool)
    bottom = free & ~top & (x[:, 1] <= y_bottom) if not math.isnan(y_bottom) else np.zeros(len(x), bool)
    x[top, 1] = y_top
    x[bottom, 1] = y_bottom
    v[top | bottom] = 0.0
    return x, v, int((top | bottom).sum())


def signed_areas(x, tris):
    a, b, c = x[tris[:, 0]], x[tris[:, 1]], x[tris[:, 2]]
    return 0.5 * np.cross(np.c_[b - a, np.zeros(len(a))], np.c_[c - a, np.zeros(len(a))])[:, 2]


def energy_terms(x, x_pred, mass, particle_body, edges, rest, edge_body, tris, area0, tri_body,
                 k_spring, k_area, dt, signed, n_bodies):
    """(inertial, spring, area) per body, vectorised."""
    inertial = np.bincount(particle_body, 0.5 * mass * ((x - x_pred) ** 2).sum(axis=1), minlength=n_bodies)
    C_e = np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1) - rest
    spring = dt ** 2 * np.bincount(edge_body, 0.5 * k_spring * C_e ** 2, minlength=n_bodies)
    A = signed_areas(x, tris)
    C_t = A - area0 if signed else np.abs(A) - np.abs(area0)
    area = dt ** 2 * np.bincount(tri_body, 0.5 * k_area * C_t ** 2, minlength=n_bodies)
    return inertial, spring, area


def constraint_residual(x, edges, rest, tris, area0, signed):
    C_e = np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1) - rest
    C_e = np.where(rest > 0, C_e / np.where(rest > 0, rest, 1.0), C_e)
    A = signed_areas(x, tris) if len(tris) else np.zeros(0)
    C_t = A - area0 if signed else np.abs(A) - np.abs(area0)
    C_t = np.where(area0 != 0, C_t / np.where(area0 != 0, np.abs(area0), 1.0), C_t)
    allc = np.concatenate([C_e, C_t])
    return float(np.sqrt(np.mean(allc ** 2))) if allc.size else 0.0


def greedy_colour(indices, n_particles):
    """Smallest colour not used at any particle of the constraint, constraints in array order."""
    used = [set() for _ in range(n_particles)]
    colour = np.zeros(len(indices), dtype=np.int64)
    for m, ps in enumerate(indices):
        taken = set().union(*(used[p] for p in ps))
        c = 0
        while c in taken:
            c += 1
        colour[m] = c
        for p in ps:
            used[p].add(c)
    return colour, int(colour.max()) + 1 if len(indices) else 0


# =========================================================================== contact (helper H3)
# References for tissue_sim_ros.core.contact.collision's kernels. Written from the
# geometry, not from the kernels: the rounded box's signed distance by clamping
# to the core box, path crossings by golden-section minimisation of that
# (convex) distance along the path and bisection for the entry point, instead
# of the kernels' exact line/primitive intersections.


def tool_local(p, shape):
    """World point(s) p (..., 2) into the frame of a packed tool shape (7,)."""
    c, s = shape[2], shape[3]
    d = np.asarray(p, dtype=float) - shape[:2]
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)


def tool_world(p, shape):
    """Tool-frame point p (2,) back into the world."""
    c, s = shape[2], shape[3]
    return np.array([shape[0] + c * p[0] - s * p[1], shape[1] + s * p[0] + c * p[1]])


def rounded_box_sdf_local(p, hx, hy, r):
    """Signed distance of tool-frame point p (2,) to the rounded box: distance to the core box minus r."""
    core = np.array([hx, hy])
    clamped = np.clip(p, -core, core)
    if np.any(np.abs(p) > core):
        return float(np.linalg.norm(p - clamped)) - r
    return float(np.max(np.abs(p) - core)) - r


def rounded_box_normal_local(p, hx, hy):
    """Outward unit normal at tool-frame point p: from the nearest core point, or the nearest face inside (ties: y)."""
    core = np.array([hx, hy])
    clamped = np.clip(p, -core, core)
    if np.any(np.abs(p) > core):
        d = p - clamped
        return d / np.linalg.norm(d)
    q = np.abs(p) - core
    n = np.array([1.0, 0.0]) if q[0] > q[1] else np.array([0.0, 1.0])
    return n * np.where(p < 0, -1.0, 1.0)


def rounded_box_sdf(points, shape):
    """Signed distance of world points (N, 2) to the posed tool (7,), shape (N,) (vectorised form of the above)."""
    loc = tool_local(np.asarray(points, dtype=float).reshape(-1, 2), shape)
    core = np.array([shape[4], shape[5]])
    q = np.abs(loc) - core
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    inside = np.minimum(q.max(axis=1), 0.0)
    return outside + inside - shape[6]


def _golden_min(f, a, b, iters=100):
    """Minimiser of a convex function on [a, b] by golden-section search."""
    g = (math.sqrt(5.0) - 1.0) / 2.0
    c, d = b - g * (b - a), a + g * (b - a)
    for _ in range(iters):
        if f(c) < f(d):
            b = d
        else:
            a = c
        c, d = b - g * (b - a), a + g * (b - a)
    return 0.5 * (a + b)


def _bisect_root(f, a, b, iters=80):
    """A root of f on [a, b] with f(a) and f(b) of opposite signs (or zero)."""
    fa = f(a)
    for _ in range(iters):
        m = 0.5 * (a + b)
        fm = f(m)
        if (fm > 0) == (fa > 0):
            a, fa = m, fm
        else:
            b = m
    return 0.5 * (a + b)


def project_tool(x, x_start, inv_mass, candidates, shape0, shape1, inside_tol=1e-9):
    """Reference of contact.kernels.project_tool: returns (x, dx_accum, moved) with x and dx_accum new arrays.

    Path p(s) = p0 + s (p1 - p0) in the tool frame (p0 = x_start vs shape0, p1 = x vs shape1).
    Started inside (f(p0) < -tol): nearest surface point of p1. Otherwise, if
    min_s f(p(s)) < 0 (the path enters the shape): entry point e (first root),
    outward normal n there, and p1 moved along n to where the line leaves the
    shape (largest root of f(p1 + t n)), or to e if that line misses the shape.
    """
    x = np.array(x, dtype=float)
    acc = np.zeros_like(x)
    hx, hy, r = shape1[4], shape1[5], shape1[6]
    moved = 0
    for i in candidates:
        if inv_mass[i] == 0:
            continue
        p0 = tool_local(x_start[i], shape0)
        p1 = tool_local(x[i], shape1)
        f = lambda p: rounded_box_sdf_local(p, hx, hy, r)  # noqa: E731
        f0, f1 = f(p0), f(p1)
        if f0 < -inside_tol:
            if f1 >= 0:
                continue
            core = np.array([hx, hy])
            if np.all(np.abs(p1) <= core):
                # inside the core box: out through the face with the least slack (ties: y)
                slack = core - np.abs(p1) + r
                axis = 0 if slack[0] < slack[1] else 1
                target = p1.copy()
                target[axis] = (core[axis] + r) * (1.0 if p1[axis] >= 0 else -1.0)
            else:
                c = np.clip(p1, -core, core)
                target = c + r * (p1 - c) / np.linalg.norm(p1 - c)
        else:
            d = p1 - p0
            path = lambda s: f(p0 + s * d)  # noqa: E731
            s_min = _golden_min(path, 0.0, 1.0)
            if min(path(s_min), f1) >= 0.0:
                continue
            if f1 < path(s_min):
                s_min = 1.0
            s_e = 0.0 if f0 <= 0.0 else _bisect_root(path, 0.0, s_min)
            e = p0 + s_e * d
            n = rounded_box_normal_local(e, hx, hy)
            span = 4.0 * (hx + hy + r) + np.linalg.norm(d) + 1.0
            line = lambda t: f(p1 + t * n)  # noqa: E731
            t_min = _golden_min(line, -span, span)
            if line(t_min) < 0.0:
                t_out = _bisect_root(line, t_min, span)
                if t_out <= inside_tol:
                    continue
                target = p1 + t_out * n
            else:
                target = e
        w = tool_world(target, shape1)
        acc[i] += w - x[i]
        x[i] = w
        moved += 1
    return x, acc, moved


def near_triangles(x, tris, sdf, grad, reach, tol=1e-9):
    """Indices of triangles whose tangent-plane lower bound max_k [f_k + min_j g_k.(v_j - v_k)] <= reach + tol."""
    keep = []
    for t, tri in enumerate(tris):
        v = x[tri]
        bounds = [sdf[k] + min(0.0, float(np.min((v - x[k]) @ grad[k]))) for k in tri]
        if max(bounds) <= reach + tol:
            keep.append(t)
    return np.array(keep, dtype=np.int64)


def compact_triangles(x, tris, sel):
    """(vertices (V, 3) with z = 0, their particle ids (V,), triangles renumbered) of tris[sel], ids in first-use order."""
    flat = tris[sel].ravel()
    _, first = np.unique(flat, return_index=True)
    ids = flat[np.sort(first)]
    lookup = {int(p): k for k, p in enumerate(ids)}
    new_tris = np.array([[lookup[int(p)] for p in tri] for tri in tris[sel]], dtype=np.int64).reshape(-1, 3)
    verts = np.zeros((len(ids), 3))
    verts[:, :2] = x[ids]
    return verts, ids, new_tris


def swept_candidates(x, inv_mass, shape0, shape1, reach):
    """Free particles with min(sdf0, sdf1) <= reach + sweep / 2 (sweep: centre travel + rotation x bounding radius)."""
    dang = abs(math.atan2(shape0[2] * shape1[3] - shape0[3] * shape1[2], shape0[2] * shape1[2] + shape0[3] * shape1[3]))
    radius = math.hypot(shape1[4], shape1[5]) + shape1[6]
    sweep = math.hypot(*(shape1[:2] - shape0[:2])) + dang * radius
    d = np.minimum(rounded_box_sdf(x, shape0), rounded_box_sdf(x, shape1))
    return np.flatnonzero((d <= reach + 0.5 * sweep) & (inv_mass > 0))


def paper_displacement(x, body_particles, q, d_star, v, r):
    """Eq. (3) of the paper for one body: (indices, displacements) of particles within r of x_q.

    dx_i = (r - |x_q - x_i|) / r * d_star * v / |v| for |x_q - x_i| <= r; nothing for |v| = 0.
    """
    speed = float(np.hypot(*v))
    if speed == 0.0:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 2))
    idx, dx = [], []
    for i in body_particles:
        dist = float(np.hypot(*(x[q] - x[i])))
        if r - dist >= 0.0:
            idx.append(i)
            dx.append((r - dist) / r * d_star * np.asarray(v) / speed)
    return np.array(idx, dtype=np.int64), np.array(dx).reshape(-1, 2)


def wavefront_levels(indices, n_particles, block):
    """Per block of constraints: level(c) = 1 + max(level(d) for earlier d of the block sharing a particle), else 0."""
    level = np.zeros(len(indices), dtype=np.int64)
    for m, ps in enumerate(indices):
        first = (m // block) * block
        earlier = [level[d] for d in range(first, m) if set(indices[d]) & set(ps)]
        level[m] = max(earlier) + 1 if earlier else 0
    return level, int(level.max()) + 1 if len(indices) else 0


def body_nearest(sdf, particle_body, n_bodies):
    """Per body: (smallest signed distance, its particle, first on ties); (inf, -1) for an empty body."""
    out_min = np.full(n_bodies, np.inf)
    out_arg = np.full(n_bodies, -1)
    for b in range(n_bodies):
        idx = np.flatnonzero(particle_body == b)
        if idx.size:
            out_arg[b] = idx[np.argmin(sdf[idx])]
            out_min[b] = sdf[out_arg[b]]
    return out_min, out_arg


def count_inverted(x, tris):
    return int(np.count_nonzero(signed_areas(x, tris) <= 0)) if len(tris) else 0


# ----------------------------------------------------------------------------- surface (boundary-edge) contact
# References of collision.boundary_edges_ccw, edge_depth, project_edges and swept_edge_candidates.


def boundary_edges_ccw(tris):
    """Directed edges (a, b) of CCW triangles whose undirected edge is used once, sorted by (a, b)."""
    count = {}
    for tri in np.asarray(tris).reshape(-1, 3):
        for k in range(3):
            a, b = int(tri[k]), int(tri[(k + 1) % 3])
            count.setdefault(frozenset((a, b)), []).append((a, b))
    return np.array(sorted(v[0] for v in count.values() if len(v) == 1), dtype=np.int64).reshape(-1, 2)


def deepest_on_line(q, n, shape, span=None):
    """Largest t with sdf(q + t n) <= 0 (the tool's far point on the line q + t n), or -inf when the line misses."""
    hx, hy, r = shape[4], shape[5], shape[6]
    span = span or 4.0 * (hx + hy + r) + 1.0 + float(np.linalg.norm(q - shape[:2]))
    f = lambda t: rounded_box_sdf_local(tool_local(q + t * n, shape), hx, hy, r)  # noqa: E731
    t_min = _golden_min(f, -span, span)
    if f(t_min) > 0.0:
        return -np.inf
    return _bisect_root(f, t_min, span)


def edge_depth(a, b, shape, samples=0):
    """(depth, t, line_depth) of contact.kernels.edge_depth by another route.

    The deepest tool point over the edge's span is max_u g(u), g(u) the tool's
    far point on the normal line at u (root finding on the SDF). g is concave,
    so the maximum is at the support point's u (from the four core corners)
    when that lies in the span, else at the nearer span end. ``samples`` > 0
    also evaluates g on that many points of the span (a check of the maximum).
    """
    a, b = np.asarray(a, float), np.asarray(b, float)
    e = b - a
    length = float(np.linalg.norm(e))
    if length * length <= 1e-24:
        return -np.inf, 0.0, -np.inf
    u_hat = e / length
    n = np.array([-u_hat[1], u_hat[0]])
    corners = np.array([tool_world(np.array([sx * shape[4], sy * shape[5]]), shape)
                        for sx in (-1.0, 1.0) for sy in (-1.0, 1.0)])
    dots = corners @ n
    best = dots.max()
    support = corners[dots >= best - 1e-12 * max(1.0, abs(best))]  # a corner, or a face parallel to the edge
    line_depth = float(best + shape[6] - a @ n)
    us = (support - a) @ u_hat
    lo, hi = max(us.min(), 0.0), min(us.max(), length)
    g = lambda u: deepest_on_line(a + u * u_hat, n, shape)  # noqa: E731
    if lo <= hi:
        u_best = 0.5 * (lo + hi)
        depth = line_depth
    else:
        u_best = 0.0 if us.max() < 0.0 else length
        depth = g(u_best)
        if depth == -np.inf:
            return -np.inf, 0.0, line_depth
    if samples:
        sampled = max(g(u) for u in np.linspace(0.0, length, samples))
        assert sampled <= depth + 1e-9, (sampled, depth)
    return float(depth), u_best / length, line_depth


def project_edges(x, x_start, inv_mass, edges, shape0, shape1, side_tol, turn_cos=0.7071):
    """Reference of contact.kernels.project_edges: returns (x, dx_accum, moved) as new arrays (edges in order)."""
    x = np.array(x, dtype=float)
    acc = np.zeros_like(x)
    ddx = shape1[:2] - shape0[:2]
    dang = abs(math.atan2(shape0[2] * shape1[3] - shape0[3] * shape1[2], shape0[2] * shape1[2] + shape0[3] * shape1[3]))
    sweep = float(np.hypot(*ddx)) + dang * (math.hypot(shape1[4], shape1[5]) + shape1[6])
    moved = 0
    for a, b in edges:
        wa, wb = inv_mass[a], inv_mass[b]
        if wa == 0 and wb == 0:
            continue
        depth, t, _ = edge_depth(x[a], x[b], shape1)
        if not depth > 0:
            continue
        depth0, _, line0 = edge_depth(x_start[a], x_start[b], shape0)
        if depth0 > side_tol or (depth0 == -np.inf and line0 > side_tol):
            continue
        e, e0 = x[b] - x[a], x_start[b] - x_start[a]
        if e @ e0 <= turn_cos * np.linalg.norm(e) * np.linalg.norm(e0):
            continue
        motion = max(np.linalg.norm(x[a] - x_start[a]), np.linalg.norm(x[b] - x_start[b]))
        if depth > max(depth0, 0.0) + sweep + motion + side_tol:
            continue
        denom = (1 - t) ** 2 * wa + t ** 2 * wb
        if denom <= 0:
            continue
        n = np.array([-e[1], e[0]]) / np.linalg.norm(e)
        s = depth / denom
        for i, f in ((a, (1 - t) * wa * s), (b, t * wb * s)):
            x[i] += f * n
            acc[i] += f * n
        moved += 1
    return x, acc, moved


def swept_edge_candidates(x, inv_mass, edges, shape0, shape1, reach):
    """Rows of ``edges`` with a free particle whose Lipschitz lower bound on the tool distance is <= reach + sweep / 2."""
    dang = abs(math.atan2(shape0[2] * shape1[3] - shape0[3] * shape1[2], shape0[2] * shape1[2] + shape0[3] * shape1[3]))
    sweep = math.hypot(*(shape1[:2] - shape0[:2])) + dang * (math.hypot(shape1[4], shape1[5]) + shape1[6])
    a, b = x[edges[:, 0]], x[edges[:, 1]]
    length = np.linalg.norm(b - a, axis=1)
    mid = 0.5 * (a + b)
    lower = np.full(len(edges), np.inf)
    for s in (shape0, shape1):
        bound = np.maximum.reduce([rounded_box_sdf(a, s) - length, rounded_box_sdf(b, s) - length,
                                   rounded_box_sdf(mid, s) - 0.5 * length])
        lower = np.minimum(lower, bound)
    free = (inv_mass[edges[:, 0]] > 0) | (inv_mass[edges[:, 1]] > 0)
    return np.flatnonzero((lower <= reach + 0.5 * sweep) & free)


def gather_surface_edges(edges, sel, inv_mass, cand):
    """(edges[sel], cand followed by the free particles of those edges not in it, in edge order)."""
    out = list(cand)
    for a, b in edges[sel]:
        for p in (a, b):
            if inv_mass[p] > 0 and p not in out:
                out.append(p)
    return edges[sel], np.array(out, dtype=np.int64)


# ----------------------------------------------------------------------------- the paper authors' forward()
#
# Written from y8han/2DPBD_Interface, Surgical_spring_IROS_workshop.py (commit a0ff238), function by
# function (old_posi, substep, Position_update, collision_check, star_posi, find_constraint,
# find_area_constraint, stretch_constraint, area_constraint, apply_position_deltas,
# updata_velosity), in float64 instead of their float32, for the twin tests of
# tissue_sim_ros.core.physics.violated_jacobi and the solver's walls, pins and exponential damping.

#: Their mass of a pinned ("actuation type -1") particle [kg] (and of every other: 1e-4 kg).
AUTHORS_PINNED_MASS = 1e8


def apply_walls(x, y_bottom, y_top):
    """Their collision_check on positions: y < bottom -> bottom, y > top -> top (NaN = no wall), every particle."""
    x = x.copy()
    for i in range(len(x)):
        if not math.isnan(y_bottom) and x[i, 1] < y_bottom:
            x[i, 1] = y_bottom
        if not math.isnan(y_top) and x[i, 1] > y_top:
            x[i, 1] = y_top
    return x


def authors_setup(vertices, triangles, pinned, mass=1e-4):
    """What their main() builds: the rest-length matrix (every triangle's 3 pairs), |rest area| per triangle,
    masses (pinned: 1e8) and actuation types (1 free, -1 pinned)."""
    n = len(vertices)
    rest_length = np.zeros((n, n))
    for tri in triangles:
        for a in range(3):
            for b in range(a + 1, 3):
                i, j = int(tri[a]), int(tri[b])
                d = float(np.linalg.norm(vertices[i] - vertices[j]))
                rest_length[i, j] = d
                rest_length[j, i] = d
    rest_area = []
    for p1, p2, p3 in (vertices[list(t)] for t in triangles):
        rest_area.append(0.5 * abs((p1[0] - p2[0]) * (p1[1] - p3[1]) - (p1[1] - p2[1]) * (p1[0] - p3[0])))
    masses = np.where(pinned, AUTHORS_PINNED_MASS, mass)
    actuation = np.where(pinned, -1, 1)
    return rest_length, np.array(rest_area), masses, actuation


def authors_forward(x, v, rest_length, triangles, rest_area, masses, actuation, *, stiffness, damping, dt,
                    gravity, iterations, wall_bottom, wall_top, epsilon=1e-4, area_epsilon=1e-11, delta=None):
    """One call of their forward(n, number_triangles); returns (x, v, star_x) as new arrays."""
    n = len(x)
    x = np.array(x, dtype=np.float64)
    v = np.array(v, dtype=np.float64)
    delta = np.zeros((n, 2)) if delta is None else delta
    old_x = x.copy()                                                    # old_posi
    for i in range(n):                                                  # substep
        if actuation[i] == 1:
            v[i] *= math.exp(-dt * damping)
            v[i] += dt * np.array([0.0, gravity])
        if actuation[i] == 2:
            x[i] += delta[i]
    for i in range(n):                                                  # Position_update
        if actuation[i] == 1:
            x[i] += v[i] * dt
    x = apply_walls(x, wall_bottom, wall_top)                           # collision_check
    star_x = x.copy()                                                   # star_posi
    neighbours_all = [[j for j in range(n) if rest_length[i, j] != 0] for i in range(n)]
    for _ in range(iterations):
        # find_constraint: the springs of i that are off by at least epsilon
        neighbours = [[j for j in neighbours_all[i]
                       if abs(np.linalg.norm(x[i] - x[j]) - rest_length[i, j]) >= epsilon] for i in range(n)]
        # find_area_constraint: violated triangles keep their signed area, and count at their corners
        count = np.zeros(n, dtype=np.int64)
        violated = np.zeros(len(triangles))
        for t, (i1, i2, i3) in enumerate(triangles):
            p1, p2, p3 = x[i1], x[i2], x[i3]
            area = 0.5 * ((p1[0] - p2[0]) * (p1[1] - p3[1]) - (p1[1] - p2[1]) * (p1[0] - p3[0]))
            if abs(abs(area) - rest_area[t]) > area_epsilon:
                violated[t] = area
                count[i1] += 1
                count[i2] += 1
                count[i3] += 1
        # stretch_constraint: the average over i's violated springs
        delta_tmp = np.zeros((n, 2))
        for i in range(n):
            posi = np.zeros(2)
            wi = 1.0 / masses[i]
            for j in neighbours[i]:
                x_ij = x[i] - x[j]
                dist_diff = np.linalg.norm(x_ij) - rest_length[i, j]
                grad = x_ij / np.linalg.norm(x_ij)
                wj = 1.0 / masses[j]
                posi += -stiffness * wi * (1.0 / (wi + wj)) * dist_diff * grad / len(neighbours[i])
            delta_tmp[i] = posi
        # area_constraint: grad |A| (the sign branch of their code), full correction over the corner's count
        for t, (i1, i2, i3) in enumerate(triangles):
            if violated[t] == 0.0:
                continue
            diff = abs(violated[t]) - rest_area[t]
            (p10, p11), (p20, p21), (p30, p31) = x[i1], x[i2], x[i3]
            if violated[t] < 0:
                g = [np.array([p31 / 2 - p21 / 2, p20 / 2 - p30 / 2]), np.array([p11 / 2 - p31 / 2, p30 / 2 - p10 / 2]),
                     np.array([p21 / 2 - p11 / 2, p10 / 2 - p20 / 2])]
            else:
                g = [np.array([p21 / 2 - p31 / 2, p30 / 2 - p20 / 2]), np.array([p31 / 2 - p11 / 2, p10 / 2 - p30 / 2]),
                     np.array([p11 / 2 - p21 / 2, p20 / 2 - p10 / 2])]
            idx = (i1, i2, i3)
            w = [1.0 / masses[p] for p in idx]
            lam = diff / sum(w[k] * float(g[k] @ g[k]) for k in range(3))
            for k in range(3):
                delta_tmp[idx[k]] += -lam * w[k] * g[k] / count[idx[k]]
        for i in range(n):                                              # apply_position_deltas
            if actuation[i] == 1:
                x[i] += delta_tmp[i]
        x = apply_walls(x, wall_bottom, wall_top)                       # collision_check
    v = (x - old_x) / dt                                                # updata_velosity
    return x, v, star_x


# ----------------------------------------------------------------------------- material (core/physics/material.py)
#
# Written from the continuum form with 2x2 matrices: F = D_s D_m^-1, a scalar phi(F) with
# dphi/dF = P has gradient P D_m^-T per vertex (columns: vertices b, c; vertex a minus their sum).

def material_lame(young_modulus, poisson_ratio):
    """(mu, lambda') with lambda' = E nu / (1 - nu^2) + mu (the shifted plane-stress lambda)."""
    mu = young_modulus / (2.0 * (1.0 + poisson_ratio))
    return mu, young_modulus * poisson_ratio / (1.0 - poisson_ratio ** 2) + mu


def material_rest(q0, tri):
    """(D_m^-1, A0) of one triangle, or (None, A0) when it has no area."""
    dm = np.column_stack([q0[tri[1]] - q0[tri[0]], q0[tri[2]] - q0[tri[0]]])
    a0 = 0.5 * np.linalg.det(dm)
    if abs(a0) < 1e-300:
        return None, a0
    return np.linalg.inv(dm), a0


def elastic_table(q0, tris, young_modulus, poisson_ratio, thickness, rel_eps=1e-12):
    """Packed rows [D_m^-1 (row-major), 1/(mu V0), 1/(lambda' V0)]; zero for degenerate triangles."""
    mu, lam = material_lame(young_modulus, poisson_ratio)
    areas = [abs(material_rest(q0, t)[1]) for t in tris]
    scale = np.mean(areas) if areas else 0.0
    out = np.zeros((len(tris), 6))
    for k, t in enumerate(tris):
        dinv, a0 = material_rest(q0, t)
        if dinv is None or abs(a0) <= rel_eps * scale:
            continue
        v0 = abs(a0) * thickness
        out[k] = [*dinv.ravel(), 1.0 / (mu * v0), 1.0 / (lam * v0)]
    return out


def _grads(P, dinv):
    """Per-vertex gradients (a, b, c) of phi with dphi/dF = P."""
    h = P @ dinv.T
    return [-(h[:, 0] + h[:, 1]), h[:, 0], h[:, 1]]


def element_constraints(x, tri, row):
    """[(C, grads) for g_0, g_1, C_H] of one element at x."""
    dinv = row[:4].reshape(2, 2)
    ds = np.column_stack([x[tri[1]] - x[tri[0]], x[tri[2]] - x[tri[0]]])
    F = ds @ dinv
    cof = np.array([[F[1, 1], -F[1, 0]], [-F[0, 1], F[0, 0]]])
    return [(F[0, 0] - F[1, 1], _grads(np.array([[1.0, 0.0], [0.0, -1.0]]), dinv)),
            (F[0, 1] + F[1, 0], _grads(np.array([[0.0, 1.0], [1.0, 0.0]]), dinv)),
            (np.linalg.det(F) - 1.0, _grads(cof, dinv))]


def _element_step(x, w, tri, row, inv_h2, lam, rows):
    """XPBD increments of constraint ``rows`` from the same x: list of (dlam, dx per vertex) or None."""
    out = []
    cons = element_constraints(x, tri, row)
    for r in rows:
        C, grads = cons[r]
        s = sum(w[p] * g @ g for p, g in zip(tri, grads))
        if s <= 1e-300:
            out.append(None)
            continue
        alpha = row[4 if r < 2 else 5] * inv_h2
        dl = (-C - alpha * lam[r]) / (s + alpha)
        out.append((dl, [w[p] * dl * g for p, g in zip(tri, grads)]))
    return out


def solve_elements(x, inv_mass, tris, elastic, inv_h2, lam):
    """Gauss-Seidel sweep in array order: per element the pair (g_0, g_1) jointly, then C_H; returns (x, lam)."""
    x = x.copy()
    lam = lam.copy()
    for t, tri in enumerate(tris):
        if inv_mass[tri].sum() == 0 or not elastic[t, :4].any():
            continue
        for rows in ((0, 1), (2,)):
            steps = _element_step(x, inv_mass, tri, elastic[t], inv_h2, lam[t], rows)
            for r, st in zip(rows, steps):
                if st is None:
                    continue
                lam[t, r] += st[0]
                for p, d in zip(tri, st[1]):
                    x[p] += d
    return x, lam


def jacobi_elements(x, inv_mass, tris, elastic, inv_h2, lam, omega):
    """Jacobi pass: (summed corrections (N, 2), new lam); increments scaled by omega[t, 0] (pair), omega[t, 1] (C_H)."""
    dx = np.zeros_like(x)
    lam = lam.copy()
    for t, tri in enumerate(tris):
        if inv_mass[tri].sum() == 0 or not elastic[t, :4].any():
            continue
        for r, st in zip((0, 1, 2), _element_step(x, inv_mass, tri, elastic[t], inv_h2, lam[t], (0, 1, 2))):
            if st is None:
                continue
            om = omega[t, 0 if r < 2 else 1]
            lam[t, r] += om * st[0]
            for p, d in zip(tri, st[1]):
                dx[p] += om * d
    return dx, lam


def jacobi_relaxation_elements(x, inv_mass, tris, elastic, inv_h2, scale):
    """omega (T, 2) = scale / r per row group, r the Gershgorin bound (rows: g_0, g_1, C_H; the pair shares omega)."""
    n = x.shape[0]
    rows = []  # (element, group, vertices, gradient norms, alpha)
    for t, tri in enumerate(tris):
        cons = element_constraints(x, tri, elastic[t])
        for r, (_, grads) in enumerate(cons):
            rows.append((t, 0 if r < 2 else 1, tri, [np.linalg.norm(g) for g in grads],
                         elastic[t, 4 if r < 2 else 5] * inv_h2))
    D = []
    for _, _, tri, norms, al in rows:
        s = sum(inv_mass[p] * g * g for p, g in zip(tri, norms))
        D.append(s + al if s > 1e-300 else 0.0)
    G = np.zeros(n)
    for (_, _, tri, norms, _), d in zip(rows, D):
        if d > 0:
            for p, g in zip(tri, norms):
                G[p] += g / math.sqrt(d)
    omega = np.zeros((len(tris), 2))
    for (t, grp, tri, norms, al), d in zip(rows, D):
        if d <= 0:
            continue
        r = al / d + sum(inv_mass[p] * g * G[p] for p, g in zip(tri, norms)) / math.sqrt(d)
        omega[t, grp] = scale / r if r > 0 else scale
    return omega


def strain_energy(x, q0, tris, tri_body, n_bodies, young_modulus, poisson_ratio, thickness):
    """Per body sum_t |A0| t [mu/2 (|F|^2 - 2 det F) + lambda'/2 (det F - 1)^2] [J], from E and nu directly."""
    mu, lam = material_lame(young_modulus, poisson_ratio)
    out = np.zeros(n_bodies)
    scale = np.mean([abs(material_rest(q0, t)[1]) for t in tris]) if len(tris) else 0.0
    for t, tri in enumerate(tris):
        dinv, a0 = material_rest(q0, tri)
        if dinv is None or abs(a0) <= 1e-12 * scale:  # degenerate at rest: no element (as the kernels)
            continue
        F = np.column_stack([x[tri[1]] - x[tri[0]], x[tri[2]] - x[tri[0]]]) @ dinv
        J = np.linalg.det(F)
        out[tri_body[t]] += abs(a0) * thickness * (0.5 * mu * (np.sum(F * F) - 2.0 * J) + 0.5 * lam * (J - 1.0) ** 2)
    return out


def element_hessian(x, q0, tri, young_modulus, poisson_ratio, thickness):
    """Hessian (6, 6) of one element's V0 Psi in (a_x, a_y, b_x, b_y, c_x, c_y), written in F space.

    vec F = (F00, F01, F10, F11) = B x_local with dF_ij/dx_(a,i) = c_a[j];
    d2Psi/dF2 = mu (I - K) + lambda' cof cof^T + lambda' (J - 1) K, K = d2J/dF2
    (K[0,3] = K[3,0] = 1, K[1,2] = K[2,1] = -1); the element Hessian is V0 B^T (d2Psi/dF2) B.
    """
    mu, lam = material_lame(young_modulus, poisson_ratio)
    dinv, a0 = material_rest(q0, tri)
    if dinv is None:
        return np.zeros((6, 6))
    c = [-(dinv[0] + dinv[1]), dinv[0], dinv[1]]
    B = np.zeros((4, 6))
    for i in range(2):
        for j in range(2):
            for a in range(3):
                B[2 * i + j, 2 * a + i] = c[a][j]
    F = np.column_stack([x[tri[1]] - x[tri[0]], x[tri[2]] - x[tri[0]]]) @ dinv
    J = np.linalg.det(F)
    cof = np.array([F[1, 1], -F[1, 0], -F[0, 1], F[0, 0]])
    K = np.zeros((4, 4))
    K[0, 3] = K[3, 0] = 1.0
    K[1, 2] = K[2, 1] = -1.0
    H = mu * (np.eye(4) - K) + lam * np.outer(cof, cof) + lam * (J - 1.0) * K
    return abs(a0) * thickness * B.T @ H @ B


def tool_checks(x0, x1, shape0, shape1, tris, inside_tol=1e-9, samples=4001):
    """(n_inside, deepest, deepest particle, n_tunnelled, buried) of core/contact/tool_checks.py, by brute force.

    Tunnelling: the chord in the tool frame sampled at ``samples`` points; it tunnels when it has a point
    deeper than ``inside_tol`` and the outward normals where it enters and leaves (bisected) point apart.
    Buried: 9 points along the tool's axis (1 for a sphere) tested against every triangle by barycentric signs.
    """
    hx, hy, r = shape1[4], shape1[5], shape1[6]
    d1 = rounded_box_sdf(x1, shape1)
    d0 = rounded_box_sdf(x0, shape0)
    inside = d1 < -inside_tol
    n_inside = int(inside.sum())
    deepest, arg = (float(-d1[inside].min()), int(np.flatnonzero(inside)[np.argmin(d1[inside])])) if n_inside else (0.0, -1)
    n_tunnel = 0
    s = np.linspace(0.0, 1.0, samples)
    for i in np.flatnonzero(~inside & (d0 >= -inside_tol)):
        a, b = tool_local(x0[i], shape0), tool_local(x1[i], shape1)
        pts = a + s[:, None] * (b - a)
        sd = np.array([rounded_box_sdf_local(p, hx, hy, r) for p in pts])
        if not (sd < -inside_tol).any():
            continue
        k_in = np.flatnonzero(sd < 0)[0]
        k_out = np.flatnonzero(sd < 0)[-1]
        f = lambda t: rounded_box_sdf_local(a + t * (b - a), hx, hy, r)  # noqa: E731
        t_in = _bisect_root(f, s[max(k_in - 1, 0)], s[k_in])
        t_out = _bisect_root(f, s[k_out], s[min(k_out + 1, samples - 1)])
        n_in = rounded_box_normal_local(a + t_in * (b - a), hx, hy)
        n_out = rounded_box_normal_local(a + t_out * (b - a), hx, hy)
        if n_in @ n_out < 0:
            n_tunnel += 1
    axis = np.array([shape1[2], shape1[3]])
    ks = np.linspace(-hx, hx, 9) if hx > 0 else np.array([0.0])
    buried = False
    for sk in ks:
        p = shape1[:2] + sk * axis
        for ta, tb, tc in tris:
            signs = [cross2(x1[tb] - x1[ta], p - x1[ta]), cross2(x1[tc] - x1[tb], p - x1[tb]),
                     cross2(x1[ta] - x1[tc], p - x1[tc])]
            if all(v >= 0 for v in signs) or all(v <= 0 for v in signs):  # on an edge or corner counts
                buried = True
    return n_inside, deepest, arg, n_tunnel, buried


def vertex_strain_kernel(x, a, b, inv_l0, one, inv_count, absolute, out):
    """Twin of core.strain.vertex_strain_kernel: edge strain |x_b - x_a| / l0 - 1, averaged at each vertex."""
    d = x[b] - x[a]
    s = np.hypot(d[:, 0], d[:, 1]) * inv_l0 - one
    if absolute:
        s = np.abs(s)
    out[:] = np.bincount(np.concatenate([a, b]), weights=np.concatenate([s, s]), minlength=len(out)) * inv_count


def strain_mesh_arrays(q, tri_flat, edge_flat, strain, strain_color_max, lut, tri_points, tri_rgba, wire_points,
                       wireframe):
    """Twin of core.strain.strain_mesh_arrays: corner points, strain colours from the table, wireframe ends."""
    q3 = np.zeros((len(q), 3))
    q3[:, :2] = q
    tri_points[:] = q3[tri_flat]
    top = len(lut) - 1
    k = np.clip(((strain / strain_color_max) * 0.5 + 0.5) * top, 0, top).astype(np.int64)
    tri_rgba[:] = lut[k][tri_flat]
    if wireframe:
        wire_points[:] = q3[edge_flat]


def project_attachments(x, inv_mass, attach_idx, attach_target, alpha_tilde, lam):
    """One XPBD pass over zero-length springs E = |x_i - t_i|^2 / (2 c), alpha~ = c / h^2, as vector constraints.

    Written from the energy: per attachment the constraint C = x_i - t_i (a 2-vector, gradient the identity),
    d lambda = -(C + alpha~ lambda) / (w + alpha~) (2-vector), x_i += w d lambda. Returns (x, lam), copies.
    """
    x = np.array(x, dtype=np.float64, copy=True)
    lam = np.array(lam, dtype=np.float64, copy=True)
    for k, i in enumerate(attach_idx):
        w = inv_mass[i]
        if w == 0.0:
            continue
        c = x[i] - attach_target[k]
        dlam = -(c + alpha_tilde * lam[k]) / (w + alpha_tilde)
        lam[k] += dlam
        x[i] += w * dlam
    return x, lam


# ----------------------------------------------------------------------------- the quasi-Newton step


def incremental_potential(x, x_pred, mass, inv_mass, q0, tris, young_modulus, poisson_ratio, thickness, dt,
                          attach_idx=(), attach_target=(), attach_k=0.0):
    """(E, grad E) of one implicit Euler step, from the formula (E and nu directly, per triangle)::

        E = 1/2 sum m |x - x*|^2 + dt^2 sum_t |A0| t Psi(F_t) + dt^2 sum_k k/2 |x_k - t_k|^2
        Psi = mu/2 (|F|^2 - 2 det F) + lambda'/2 (det F - 1)^2,   dPsi/dF = mu (F - cof F) + lambda' (J - 1) cof F

    grad E is zero at particles with inv_mass 0. Returns (float, (N, 2)).
    """
    mu, lam = material_lame(young_modulus, poisson_ratio)
    r = x - x_pred
    e = 0.5 * float(np.sum(mass[:, None] * r * r))
    g = mass[:, None] * r
    scale = np.mean([abs(material_rest(q0, t)[1]) for t in tris]) if len(tris) else 0.0
    for tri in tris:
        dinv, a0 = material_rest(q0, tri)
        if dinv is None or abs(a0) <= 1e-12 * scale:
            continue
        F = np.column_stack([x[tri[1]] - x[tri[0]], x[tri[2]] - x[tri[0]]]) @ dinv
        J = np.linalg.det(F)
        cof = np.array([[F[1, 1], -F[1, 0]], [-F[0, 1], F[0, 0]]])
        v0 = abs(a0) * thickness
        e += dt * dt * v0 * (0.5 * mu * (np.sum(F * F) - 2.0 * J) + 0.5 * lam * (J - 1.0) ** 2)
        P = mu * (F - cof) + lam * (J - 1.0) * cof
        for p, gr in zip(tri, _grads(P, dinv)):
            g[p] += dt * dt * v0 * gr
    for i, t in zip(attach_idx, attach_target):
        d = x[i] - np.asarray(t)
        e += 0.5 * dt * dt * attach_k * float(d @ d)
        g[i] += dt * dt * attach_k * d
    g[np.asarray(inv_mass) == 0.0] = 0.0
    return e, g


def project_vector(v, kind, normal):
    """v (N, 2) with FIXED (2) rows zeroed and the normal part removed at TOOL (1) and LINE (3) rows."""
    v = np.array(v, dtype=np.float64).reshape(-1, 2)
    for i, k in enumerate(kind):
        if k == 2:
            v[i] = 0.0
        elif k in (1, 3):
            v[i] -= (v[i] @ normal[i]) * normal[i]
    return v


def rollout_stepped(sim, snap, poses, start):
    """Twin of core/sim/fused.py:fused_quasi_newton_rollout: the path stepped one Simulation.step at a time (each
    step's kernels have their own twins above). Returns (positions, velocities, per-step scene energy, force (S, 2),
    penetration (S,) as max -sdf of the margin-free tool)."""
    from tissue_sim_ros.core.contact.kernels import points_sdf
    from tissue_sim_ros.core.contact.tool import ToolPose, tool_shape_array

    sim.restore(snap)
    sim.place_tool(start)
    n = snap.particle_q.shape[0]
    sdf, grad = np.empty(n), np.empty((n, 2))
    energy, force, pen = [], [], []
    for p in poses:
        pose = ToolPose(float(p[0]), float(p[1]), float(p[2]))
        r = sim.step(pose)
        energy.append(r.energy.scene_total)
        force.append(r.reaction_force.copy())
        points_sdf(sim.state.particle_q, tool_shape_array(sim.tool, pose, 0.0), sdf, grad)
        pen.append(-sdf.min())
    return (sim.state.particle_q.copy(), sim.state.particle_qd.copy(), np.array(energy), np.array(force),
            np.array(pen))


def solver_step_reference(solver, state_in, state_out, contacts, dt):
    """Twin of the solvers' compiled steps (core/physics/step_kernels.py, quasi_newton.quasi_newton_step): the same
    loop in Python, calling the building blocks (prediction, sweeps, tool, attachments, walls, velocities, lines)
    one at a time with the same scalars, so the positions must come out the same bit for bit. Works on the
    solver's own workspaces and returns its SolveInfo, as ``solver.step`` does."""
    from tissue_sim_ros.core.physics import kernels, material, sweeps
    from tissue_sim_ros.core.physics.attach import project_attachments
    from tissue_sim_ros.core.physics.quasi_newton import quasi_newton_solve
    from tissue_sim_ros.core.physics.solvers import ConstraintSolver, MaterialXPBDSolver, QuasiNewtonSolver
    from tissue_sim_ros.core.physics.solvers.base import interpolate_shape
    from tissue_sim_ros.core.physics.solvers.quasi_newton import attachments
    from tissue_sim_ros.core.physics.step_kernels import SWEEP_JACOBI, SWEEP_VIOLATED
    from tissue_sim_ros.core.physics.violated_jacobi import violated_jacobi_iterations
    from tissue_sim_ros.core.physics.walls import apply_walls

    p = solver.params
    model = solver.model
    step = solver.check_step(state_in, state_out, contacts, dt)
    inv_mass = model.particle_inv_mass
    x0, v0 = state_in.particle_q, state_in.particle_qd
    x, v = state_out.particle_q, state_out.particle_qd
    walls = solver.walls
    # the full-step prediction x* and the held set
    kernels.predict(x0, v0, inv_mass, dt, p.gravity, solver.damp_factor(dt), solver.x_pred)
    kernels.hold_displaced(solver.x_pred, inv_mass, step.held_idx, step.held_dx, 1.0, solver.inv_mass_eff)
    if walls:
        apply_walls(solver.x_pred, p.wall_y_bottom, p.wall_y_top)
    w = solver.inv_mass_eff
    if isinstance(solver, QuasiNewtonSolver):
        ms = solver.material_solve
        shape0, shape1 = solver._shape0, solver._shape1
        if step.projection:
            np.copyto(shape0, contacts.tool_shape0)
            np.copyto(shape1, contacts.tool_shape1)
        np.copyto(x, solver.x_pred)
        guess = v0 * (dt * solver.damp_factor(dt))
        guess += x0
        quasi_newton_solve(x, solver.x_pred, w, guess, ms.mat, ms.step_factor(dt).arrays, ms.lines,
                           (x0, step.candidates, shape0, shape1, solver.contact_dx, step.surface_edges,
                            float(contacts.edge_side_tol)), attachments(contacts), ms.ws, ms.elim,
                           (dt * dt, p.gravity) + solver.solve_options)
        kernels.update_velocity(x, x0, dt, v)
        kernels.apply_boundary_lines(x, v, inv_mass, p.boundary_y_top, p.boundary_y_bottom)
        info = solver.finish(contacts, step, kernels.constraint_residual(x, solver.edges, solver.rest, solver.tris,
                                                                          solver.area0, solver.signed))
        info.solve_iterations, info.solve_residual = int(ms.out[0]), float(ms.out[1])
        info.solve_converged = info.solve_residual <= p.solve_tolerance
        return info
    n_sub = p.substeps
    h = dt / n_sub
    if step.projection:
        solver.contact_dx.fill(0.0)
        s0 = np.asarray(contacts.tool_shape0, dtype=np.float64)
        s1 = np.asarray(contacts.tool_shape1, dtype=np.float64)
    a_idx, a_target, a_compliance = solver.attachments(contacts)
    alpha_a = a_compliance / (h * h)
    is_material = isinstance(solver, MaterialXPBDSolver)
    np.copyto(v, v0)
    np.copyto(x, x0)
    for sub in range(n_sub):
        np.copyto(solver.x_start, x)
        if n_sub == 1:
            np.copyto(x, solver.x_pred)
        else:
            kernels.predict(solver.x_start, v, inv_mass, h, p.gravity, solver.damp_factor(h), x)
            kernels.place_held(x, x0, solver.x_pred, inv_mass, step.held_idx, (sub + 1) / n_sub)
            if walls:
                apply_walls(x, p.wall_y_bottom, p.wall_y_top)
        solver.lam_a.fill(0.0)
        if step.projection:
            interpolate_shape(s0, s1, sub / n_sub, solver._shape0)
            interpolate_shape(s0, s1, (sub + 1) / n_sub, solver._shape1)
            cand, surf = step.candidates, step.surface_edges
        else:
            cand, surf = np.zeros(0, np.int32), np.zeros((0, 2), np.int32)
        tool = sweeps.tool_pack(solver.x_start, cand, solver._shape0, solver._shape1, solver.contact_dx, surf,
                                contacts.edge_side_tol)
        calls = [1] * p.iterations if a_idx.shape[0] else [p.iterations]
        if is_material:
            solver.lam_m.fill(0.0)
            if sub == n_sub - 1:
                np.copyto(solver.material_solve.x_pred_h, x)
            jac, stiff, _, relaxation, scale, lam_m, omega_m, node_sum, dx_acc = solver._sweep
            inv_h2 = 1.0 / (h * h)
            if jac and stiff:
                material.jacobi_relaxation_elements(x, w, solver.tris, solver.elastic, inv_h2, scale, node_sum, omega_m)
            elif jac:
                omega_m[:] = relaxation
            for iters in calls:
                if jac:
                    material.material_jacobi(x, w, solver.tris, solver.elastic, inv_h2, lam_m, omega_m, iters, dx_acc,
                                             tool)
                else:
                    material.material_gauss_seidel(x, w, solver.tris, solver.elastic, inv_h2, lam_m,
                                                   solver._elements[2], solver._elements[3], iters, tool)
                if a_idx.shape[0]:
                    project_attachments(x, w, a_idx, a_target, alpha_a, solver.lam_a)
            if walls:
                apply_walls(x, p.wall_y_bottom, p.wall_y_top)
        else:
            assert isinstance(solver, ConstraintSolver)
            sw = solver.sweep
            sw.lam_e.fill(0.0)
            sw.lam_t.fill(0.0)
            edge_set, tri_set, _, signed = solver._sets
            coeffs = solver.coefficients(h)
            if sw.mode == SWEEP_VIOLATED:
                tol_e, tol_a, dxa, ns, na = sw.violated
                violated_jacobi_iterations(x, inv_mass, w, (edge_set[0], edge_set[1], coeffs[0], tol_e, tri_set[0],
                                                            tri_set[1], coeffs[2], tol_a, signed),
                                           p.iterations, (p.wall_y_bottom, p.wall_y_top),
                                           (sw.jac[4], dxa, ns, na), tool)
                if a_idx.shape[0]:
                    project_attachments(x, w, a_idx, a_target, alpha_a, solver.lam_a)
            else:
                if sw.mode == SWEEP_JACOBI and sw.jac[0]:
                    sweeps.jacobi_relaxation(x, w, edge_set[0], coeffs[1], tri_set[0], coeffs[3], signed, sw.jac[1],
                                             sw.jac[2], sw.omega_e, sw.omega_t)
                for iters in ([1] * p.iterations if walls else calls):
                    if sw.mode == SWEEP_JACOBI:
                        sweeps.jacobi_iterations(x, w, edge_set, tri_set, tool, coeffs, sw.mults, signed, iters,
                                                 sw.jac[3], sw.jac[4])
                    else:
                        sweeps.gauss_seidel_iterations(x, w, edge_set, tri_set, tool, coeffs, sw.mults, signed, iters,
                                                       sw.mode)
                    if a_idx.shape[0]:
                        project_attachments(x, w, a_idx, a_target, alpha_a, solver.lam_a)
                    if walls:
                        apply_walls(x, p.wall_y_bottom, p.wall_y_top)
        kernels.update_velocity(x, solver.x_start, h, v)
        kernels.apply_boundary_lines(x, v, inv_mass, p.boundary_y_top, p.boundary_y_bottom)
    info = solver.finish(contacts, step, kernels.constraint_residual(x, solver.edges, solver.rest, solver.tris,
                                                                      solver.area0, solver.signed))
    if is_material:
        info.solve_iterations = p.iterations
        info.solve_residual = solver.material_solve.sweep_residual(
            x, solver.x_start, w, h, solver.contact_dx if step.projection else None, contacts)
        info.solve_converged = info.solve_residual <= p.solve_tolerance
    return info


def finish_reference(model, x, v, x_pred, contacts, dt):
    """Twin of step_kernels.finish_step: NumPy's finite check, the energy terms of energy_terms (below) with the
    attachments' springs, and count_inverted. Returns (finite, n_inverted, terms (6, B))."""
    finite = bool(np.isfinite(x).all() and np.isfinite(v).all())
    p = model.params
    nb = model.n_bodies
    terms = np.zeros((6, nb))
    if finite:
        if model.is_material:
            e = energy_terms(x, x_pred, model.particle_mass, model.particle_body, model.edge_indices[:0],
                             model.edge_rest_length[:0], model.edge_body[:0], model.tri_indices[:0],
                             model.tri_rest_area[:0], model.tri_body[:0], 0.0, 0.0, p.dt, True, nb)
            terms[0] = e[0]
            pot = strain_energy(x, model.particle_q0, model.tri_indices, model.tri_body, nb, p.young_modulus,
                                p.poisson_ratio, p.thickness)
            terms[4] = pot
            terms[3] = dt * dt * pot
        else:
            e = energy_terms(x, x_pred, model.particle_mass, model.particle_body, model.edge_indices,
                             model.edge_rest_length, model.edge_body, model.tri_indices, model.tri_rest_area,
                             model.tri_body, p.k_spring_effective, p.k_area_effective, p.dt, p.area_mode == "signed",
                             nb)
            terms[0], terms[1], terms[2] = e
            terms[4] = (terms[1] + terms[2]) / (dt * dt)
        idx = np.asarray(contacts.attach_idx)
        if idx.size:
            d = x[idx] - contacts.attach_target
            np.add.at(terms[5], model.particle_body[idx], 0.5 * (d * d).sum(axis=1) / contacts.attach_compliance)
            terms[5] *= dt * dt
    return finite, count_inverted(x, model.tri_indices), terms


def outline_checks(x0, x1, frame0, frame1, pos1, edges, loop_ptr, tris, inside_tol=1e-9):
    """Twin of core.contact.tool_checks.outline_checks, by other means: inside by the winding number (not the
    even-odd rule), distances and crossings vectorised over every edge of a loop, buried by barycentric signs.

    A particle's chord runs from its start carried by the tool's motion (local in frame0, placed by frame1) to its
    end; it tunnels when it starts and ends outside the outline and the first and last edges of a loop it properly
    crosses face apart (normals with a negative dot product). Returns (n_inside, deepest, deepest particle or -1, n_tunnelled, buried)."""
    x0 = np.asarray(x0, float)
    x1 = np.asarray(x1, float)
    loops = [np.asarray(edges[loop_ptr[k]:loop_ptr[k + 1]]) for k in range(len(loop_ptr) - 1)]

    def winding(p, loop):
        a, b = pos1[loop[:, 0]] - p, pos1[loop[:, 1]] - p
        ang = np.arctan2(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0], (a * b).sum(axis=1))
        return abs(round(ang.sum() / (2 * np.pi))) % 2 == 1

    def distance(p, loop):
        a, b = pos1[loop[:, 0]], pos1[loop[:, 1]]
        e = b - a
        ll = (e * e).sum(axis=1)
        s = np.where(ll > 0, np.clip(((p - a) * e).sum(axis=1) / np.where(ll > 0, ll, 1.0), 0, 1), 0.0)
        return float(np.hypot(*(p - a - s[:, None] * e).T).min())

    c0, s0, c1, s1 = frame0[2], frame0[3], frame1[2], frame1[3]
    r = x0 - frame0[:2]
    local = np.stack([c0 * r[:, 0] + s0 * r[:, 1], -s0 * r[:, 0] + c0 * r[:, 1]], axis=1)
    start = frame1[:2] + np.stack([c1 * local[:, 0] - s1 * local[:, 1], s1 * local[:, 0] + c1 * local[:, 1]], axis=1)
    n_inside, deepest, arg, n_tunnel = 0, 0.0, -1, 0
    for i in range(len(x1)):
        end_in = [(winding(x1[i], lp), distance(x1[i], lp)) for lp in loops]
        deep = [d for w, d in end_in if w and d > inside_tol]
        if deep:
            n_inside += 1
            if deep[0] > deepest:
                deepest, arg = deep[0], i
            continue
        if any(winding(start[i], lp) for lp in loops):
            continue
        p, q = start[i], x1[i]
        for lp in loops:
            a, b = pos1[lp[:, 0]], pos1[lp[:, 1]]
            def cx(u, w):
                return u[..., 0] * w[..., 1] - u[..., 1] * w[..., 0]

            d1 = cx(q - p, a - p)
            d2 = cx(q - p, b - p)
            d3 = cx(b - a, p - a)
            d4 = cx(b - a, q - a)
            hit = np.flatnonzero((d1 * d2 < 0) & (d3 * d4 < 0))
            if hit.size < 2:
                continue
            # where along the chord each crossed edge is met (the chord's own parameter), and the edges' normals
            t = np.array([np.linalg.solve(np.column_stack([q - p, a[k] - b[k]]), a[k] - p)[0] for k in hit])
            e = b[hit] - a[hit]
            normals = np.stack([e[:, 1], -e[:, 0]], axis=1)
            if normals[np.argmin(t)] @ normals[np.argmax(t)] < 0:
                n_tunnel += 1
                break
    buried = False
    for ta, tb, tc in tris:
        for v in pos1:
            signs = np.array([cross2(x1[tb] - x1[ta], v - x1[ta]), cross2(x1[tc] - x1[tb], v - x1[tb]),
                              cross2(x1[ta] - x1[tc], v - x1[tc])])
            if (signs > 0).all() or (signs < 0).all():
                buried = True
    return n_inside, deepest, arg, n_tunnel, buried
