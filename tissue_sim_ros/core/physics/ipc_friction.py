r"""Friction of the barrier contact (``method: ipc``): IPC's smoothed, lagged Coulomb friction (Li et al. 2020,
section 5) in 2D.

At a step's start each pair closer than its dhat becomes a friction pair, with what the step's start lags: its
normal force lambda = -kappa b'(gap) [N], its tangent t (the unit normal's perpendicular), where along the edge
it touches (s in [0, 1]) and the tool's point there. Over the step the pair's slip is the tangential relative
displacement (a scalar in 2D)

    u(x, q) = t . [ (p(x, q) - p_n) - (c(x, q) - c_n) ]

with p the vertex and c the point at s on the edge (the tool's material points move with q), and the step's
potential gains dt^2 sum_k mu_k lambda_k f0(|u_k|), f0 the smoothed Coulomb profile of
``core/contact/barrier.py`` with eps = friction_velocity x dt: the force mu lambda in the slip's opposite
direction when sliding (|u| >= eps), a stiff spring 2 mu lambda / eps when sticking. Lagging the normal force and
the tangent keeps the potential smooth and convex in u (one lag per step, as real-time IPC does: the contact's
normal force is the last step's).

Bundle ``friction`` (``step[5]``) = (x_n (N, 2), q_n (4,), pair ids (F, 4) int64 (kind 0 tissue vertex / edge,
1 tissue vertex / tool edge, 2 tool vertex / tissue edge; then the vertex, the edge's ends), pair data (F, 6)
(s, t_x, t_y, mu lambda, the tool's point at the start (2)), counts (1,) int64, (mu tool, mu tissue, eps) (3,)).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..contact.barrier import barrier, friction_f0, friction_f1_over_y, friction_f2, point_segment


def friction_workspace(n_particles: int, n_pairs: int) -> tuple:
    """A friction bundle with room for ``n_pairs`` pairs (its x_n and q_n are set per step)."""
    return (np.zeros((n_particles, 2)), np.zeros(4), np.zeros((n_pairs, 4), dtype=np.int64), np.zeros((n_pairs, 6)),
            np.zeros(1, dtype=np.int64), np.zeros(3))


@njit(cache=True, inline="always")
def _entry(ids: np.ndarray, data: np.ndarray, m: int, kind: int, ends: tuple, s: float, d: float, p: tuple,
           c: tuple, lam: float, anchor: tuple) -> None:
    """Pair m: its kind and ends (vertex, edge's ends), where along the edge it touches, its tangent (the unit
    normal (p - c) / d turned by +90 degrees), mu lambda and the tool's point at the start."""
    ids[m, 0], ids[m, 1], ids[m, 2], ids[m, 3] = kind, ends[0], ends[1], ends[2]
    data[m, 0] = s
    data[m, 1] = -(p[1] - c[1]) / d
    data[m, 2] = (p[0] - c[0]) / d
    data[m, 3] = lam
    data[m, 4] = anchor[0]
    data[m, 5] = anchor[1]


@njit(cache=True, nogil=True)
def friction_lag(x: np.ndarray, q: np.ndarray, model: tuple, contact: tuple, tool: tuple, pairs: tuple,
                 scratch: tuple, friction: tuple) -> None:
    """The step's friction pairs from the candidate pairs at its start (x, q) (module docstring); the core's
    vertices must be in ``scratch`` for q."""
    edges = model[5]
    dhat_t, dhat_tool, kappa, _lines = contact
    geom = tool[0]
    tool_edges, edge_radius, vertex_radius = geom[3], geom[4], geom[5]
    tt, vt, tv, counts = pairs
    x_n, q_n, ids, data, count, mus = friction
    pos = scratch[0]
    for i in range(x.shape[0]):
        x_n[i, 0] = x[i, 0]
        x_n[i, 1] = x[i, 1]
    for j in range(4):
        q_n[j] = q[j]
    m = 0
    if mus[1] > 0.0:
        for k in range(counts[0]):
            p, a, b = tt[k, 0], edges[tt[k, 1], 0], edges[tt[k, 1], 1]
            d, s, cx, cy = point_segment(x[p, 0], x[p, 1], x[a, 0], x[a, 1], x[b, 0], x[b, 1])
            b1 = barrier(d, dhat_t)[1]
            if b1 == 0.0 or d <= 0.0 or m == ids.shape[0]:
                continue
            _entry(ids, data, m, 0, (p, a, b), s, d, (x[p, 0], x[p, 1]), (cx, cy), mus[1] * kappa * -b1, (0.0, 0.0))
            m += 1
    if mus[0] > 0.0 and tool[2]:
        for k in range(counts[1]):
            p, te = vt[k, 0], vt[k, 1]
            ta, tb = tool_edges[te, 0], tool_edges[te, 1]
            d, s, cx, cy = point_segment(x[p, 0], x[p, 1], pos[ta, 0], pos[ta, 1], pos[tb, 0], pos[tb, 1])
            b1 = barrier(d - edge_radius[te], dhat_tool)[1]
            if b1 == 0.0 or d <= 0.0 or m == ids.shape[0]:
                continue
            _entry(ids, data, m, 1, (p, ta, tb), s, d, (x[p, 0], x[p, 1]), (cx, cy), mus[0] * kappa * -b1, (cx, cy))
            m += 1
        for k in range(counts[2]):
            w, e = tv[k, 0], tv[k, 1]
            a, b = edges[e, 0], edges[e, 1]
            d, s, cx, cy = point_segment(pos[w, 0], pos[w, 1], x[a, 0], x[a, 1], x[b, 0], x[b, 1])
            b1 = barrier(d - vertex_radius[w], dhat_tool)[1]
            if b1 == 0.0 or d <= 0.0 or m == ids.shape[0]:
                continue
            _entry(ids, data, m, 2, (w, a, b), s, d, (pos[w, 0], pos[w, 1]), (cx, cy), mus[0] * kappa * -b1,
                   (pos[w, 0], pos[w, 1]))
            m += 1
    count[0] = m


@njit(cache=True, inline="always")
def friction_slip(x: np.ndarray, pos: np.ndarray, friction: tuple, m: int) -> float:
    """Pair m's slip u (module docstring) at x and the core's vertices ``pos``."""
    x_n, _q_n, ids, data = friction[0], friction[1], friction[2], friction[3]
    kind, i, j, k = ids[m, 0], ids[m, 1], ids[m, 2], ids[m, 3]
    s, tx, ty = data[m, 0], data[m, 1], data[m, 2]
    if kind == 0:
        dx = (x[i, 0] - x_n[i, 0]) - (1.0 - s) * (x[j, 0] - x_n[j, 0]) - s * (x[k, 0] - x_n[k, 0])
        dy = (x[i, 1] - x_n[i, 1]) - (1.0 - s) * (x[j, 1] - x_n[j, 1]) - s * (x[k, 1] - x_n[k, 1])
    elif kind == 1:
        dx = (x[i, 0] - x_n[i, 0]) - ((1.0 - s) * pos[j, 0] + s * pos[k, 0] - data[m, 4])
        dy = (x[i, 1] - x_n[i, 1]) - ((1.0 - s) * pos[j, 1] + s * pos[k, 1] - data[m, 5])
    else:
        dx = (pos[i, 0] - data[m, 4]) - (1.0 - s) * (x[j, 0] - x_n[j, 0]) - s * (x[k, 0] - x_n[k, 0])
        dy = (pos[i, 1] - data[m, 5]) - (1.0 - s) * (x[j, 1] - x_n[j, 1]) - s * (x[k, 1] - x_n[k, 1])
    return tx * dx + ty * dy


@njit(cache=True, nogil=True)
def friction_gradient_row(friction: tuple, jac: np.ndarray, m: int, n_dof: int, dofs: np.ndarray,
                          v: np.ndarray) -> int:
    """du/d(dofs) of pair m: its dofs and coefficients into ``dofs`` and ``v`` (the tool's dofs, n_dof.., through
    the core's Jacobian ``jac``); returns how many."""
    ids, data = friction[2], friction[3]
    kind, i, j, k = ids[m, 0], ids[m, 1], ids[m, 2], ids[m, 3]
    s, tx, ty = data[m, 0], data[m, 1], data[m, 2]
    c = 0
    if kind != 2:  # the tissue vertex
        dofs[0], dofs[1], v[0], v[1] = 2 * i, 2 * i + 1, tx, ty
        c = 2
    if kind != 1:  # the tissue edge
        dofs[c], dofs[c + 1], dofs[c + 2], dofs[c + 3] = 2 * j, 2 * j + 1, 2 * k, 2 * k + 1
        v[c], v[c + 1], v[c + 2], v[c + 3] = -(1.0 - s) * tx, -(1.0 - s) * ty, -s * tx, -s * ty
        c += 4
    if kind == 1:  # the tool's point on its edge, subtracted
        for r in range(4):
            dofs[c + r] = n_dof + r
            v[c + r] = -((1.0 - s) * (jac[j, 0, r] * tx + jac[j, 1, r] * ty)
                         + s * (jac[k, 0, r] * tx + jac[k, 1, r] * ty))
        c += 4
    elif kind == 2:  # the tool's vertex
        for r in range(4):
            dofs[c + r] = n_dof + r
            v[c + r] = jac[i, 0, r] * tx + jac[i, 1, r] * ty
        c += 4
    return c


@njit(cache=True, nogil=True)
def friction_part(x: np.ndarray, friction: tuple, scratch: tuple, dt2: float, g: np.ndarray) -> float:
    """dt^2 sum mu lambda f0(|u|) and its gradient into ``g`` (2N + 4,: the tool's dofs last); the core's vertices
    and Jacobian must be in ``scratch``."""
    data, count, mus = friction[3], friction[4], friction[5]
    eps = mus[2]
    pos, jac = scratch[0], scratch[1]
    n_dof = 2 * x.shape[0]
    dofs = np.empty(10, dtype=np.int64)
    v = np.empty(10)
    e = 0.0
    for m in range(count[0]):
        u = friction_slip(x, pos, friction, m)
        y = abs(u)
        ml = data[m, 3]
        e += dt2 * ml * friction_f0(y, eps)
        coef = dt2 * ml * friction_f1_over_y(y, eps) * u
        c = friction_gradient_row(friction, jac, m, n_dof, dofs, v)
        for r in range(c):
            g[dofs[r]] += coef * v[r]
    return e


@njit(cache=True, inline="always")
def friction_stiffness(x: np.ndarray, friction: tuple, pos: np.ndarray, m: int, dt2: float) -> float:
    """The Hessian's weight of pair m along its slip: dt^2 mu lambda f0''(|u|) (exact in 2D, where the slip is a
    scalar linear in the tissue's coordinates: 2 (1 - |u|/eps) / eps sticking, 0 sliding)."""
    y = abs(friction_slip(x, pos, friction, m))
    return dt2 * friction[3][m, 3] * friction_f2(y, friction[5][2])
