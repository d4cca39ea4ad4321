r"""The barrier step's incremental potential, its gradient and its Gauss-Newton Hessian (numba kernels).

One step of ``method: ipc`` is the minimiser over the free particles x and the tool's dofs q = (x, y, yaw, jaw)
(``core/contact/collider.py``) of

    E(x, q) = 1/2 sum_i m_i |x_i - x*_i|^2
              + dt^2 [ sum_t V0 Psi(F_t)  +  sum_t (1/alpha_H,t) b(J_t; J_hat)          (material; no inversion)
                       + sum_k 1/(2 c) |x_k - T(q) l_k|^2                              (the grasp's springs)
                       + kappa sum_pairs b(d_pair; dhat)                               (contact barriers)
                       + sum_pairs mu lambda f0(|u_pair|)                              (friction, lagged)
                       + 1/2 sum_j k_j (q_j - q*_j)^2 ]                                (the tool held to its command)

with x* = x + dt damp v + dt^2 g, Psi the neo-Hookean density of ``core/physics/material.py``, b the IPC barrier
(``core/contact/barrier.py``) on each pair's gap: boundary vertex against boundary edge of the tissue, boundary
vertex against an edge of the tool's core and a core vertex against a boundary edge (gap = distance - the core's
radius), and each free particle against the boundary lines and walls. The element's inversion barrier
b(J; J_hat), zero for J >= J_hat, keeps every triangle's area positive (the material's density is finite at J =
0); the tool's spring is stiff, so the tool reaches its command unless the tissue cannot make room.

The Hessian the solver factors is the Gauss-Newton part of each term (positive semi-definite, no eigen
decompositions): the deviatoric part of an element exactly (it is quadratic), grad J grad J^T / alpha_H for its
volume, b'' grad d grad d^T for a pair; the curvature terms (J - 1) grad^2 J and b' grad^2 d are left to the
solver's quasi-Newton updates. Its sparsity is the mesh's plus four dense rows for the tool: a pair between
particles the mesh does not connect keeps only its diagonal blocks there.

Bundles (tuples, unpacked at the top of each kernel):

* ``model`` = (mass (N,), triangles (T, 3), packed rest data (T, 6), J_hat, boundary vertices (Nb,), boundary
  edges (Ne, 2), the vertices never paired with each (``solvers/ipc.py``'s ``edge_neighbours``), rollers (N,) bool: particles at or past a line in the rest
  shape (their y does not move), bodies: the tissue's boundary repels itself);
* ``contact`` = (dhat between tissues [m], dhat against the tool [m], kappa [N/m], lines (y_top, y_bottom,
  wall_bottom, wall_top) [m]);
* ``tool`` = (its core's bundle ``ToolGeometry.arrays``, spring stiffness per dof (4,), present);
* ``step`` = (x* (N, 2), free (2N,) 1.0 where a coordinate may move, q* (4,) the command, dt^2, attachments
  (idx (K,) int64, tool-frame places (K, 2), stiffness [N/m]), friction (``core/physics/ipc_friction.py``));
* ``pairs`` = (tissue pairs (P, 2) (vertex, edge), vertex-tool pairs (P, 2) (vertex, core edge), tool-vertex
  pairs (Q, 2) (core vertex, edge), counts (3,) int64);
* ``scratch`` = (core vertex positions (V, 2), their Jacobian (V, 2, 4), the grasp's world targets (K, 2)).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..contact.barrier import barrier, point_segment
from ..contact.collider import tool_vertices
from .ipc_friction import friction_part
from .material import _deformation_gradient, _element_rest, neo_hookean_element


@njit(cache=True, inline="always")
def element_j(x: np.ndarray, tris: np.ndarray, elastic: np.ndarray, t: int):
    """Element t's area ratio J = det F and its gradient cof(F) c_p at the corners: (a, b, c, J, six comps)."""
    a = tris[t, 0]
    b = tris[t, 1]
    c = tris[t, 2]
    cbx, cby, ccx, ccy, cax, cay = _element_rest(elastic, t)
    f00, f01, f10, f11 = _deformation_gradient(x, a, b, c, cbx, cby, ccx, ccy)
    return (a, b, c, f00 * f11 - f01 * f10,
            (f11 * cax - f10 * cay, -f01 * cax + f00 * cay, f11 * cbx - f10 * cby, -f01 * cbx + f00 * cby,
             f11 * ccx - f10 * ccy, -f01 * ccx + f00 * ccy))


@njit(cache=True, nogil=True)
def material_part(x: np.ndarray, model: tuple, dt2: float, g: np.ndarray) -> float:
    """dt^2 (strain + inversion barrier) and its gradient added into ``g`` (2N,)."""
    _mass, tris, elastic, j_hat = model[0], model[1], model[2], model[3]
    strain = 0.0
    inv = 0.0
    for t in range(tris.shape[0]):
        if elastic[t, 4] <= 0.0 or elastic[t, 5] <= 0.0:
            continue
        a, b, c, energy, gax, gay, gbx, gby, gcx, gcy = neo_hookean_element(x, tris, elastic, t, dt2)
        strain += energy
        g[2 * a] += gax
        g[2 * a + 1] += gay
        g[2 * b] += gbx
        g[2 * b + 1] += gby
        g[2 * c] += gcx
        g[2 * c + 1] += gcy
        if j_hat > 0.0:
            _, _, _, jj, gj = element_j(x, tris, elastic, t)
            if jj < j_hat:
                bb, b1, _b2 = barrier(jj, j_hat)
                wt = dt2 / elastic[t, 5]
                inv += wt * bb
                s = wt * b1
                g[2 * a] += s * gj[0]
                g[2 * a + 1] += s * gj[1]
                g[2 * b] += s * gj[2]
                g[2 * b + 1] += s * gj[3]
                g[2 * c] += s * gj[4]
                g[2 * c + 1] += s * gj[5]
    return dt2 * strain + inv


@njit(cache=True, nogil=True)
def line_part(x: np.ndarray, free: np.ndarray, lines: tuple, dhat: float, kappa_dt2: float, g: np.ndarray) -> float:
    """The free y-coordinates against the boundary lines and walls (a barrier on the gap to each present one)."""
    y_top, y_bottom, wall_bottom, wall_top = lines
    e = 0.0
    for i in range(x.shape[0]):
        if free[2 * i + 1] == 0.0:
            continue
        for line, up in ((y_bottom, 1.0), (wall_bottom, 1.0), (y_top, -1.0), (wall_top, -1.0)):
            if math.isnan(line):
                continue
            bb, b1, _ = barrier(up * (x[i, 1] - line), dhat)
            if bb != 0.0:
                e += kappa_dt2 * bb
                g[2 * i + 1] += kappa_dt2 * b1 * up
    return e


@njit(cache=True, nogil=True)
def _add_tool_grad(gq: np.ndarray, jac: np.ndarray, v: int, s: float, nx: float, ny: float) -> None:
    """gq += s J_v^T n: a core vertex's pull on the tool's dofs."""
    for k in range(4):
        gq[k] += s * (jac[v, 0, k] * nx + jac[v, 1, k] * ny)


@njit(cache=True, nogil=True)
def contact_part(x: np.ndarray, model: tuple, contact: tuple, tool: tuple, pairs: tuple, scratch: tuple,
                 dt2: float, g: np.ndarray, gq: np.ndarray) -> float:
    """dt^2 kappa sum b over the candidate pairs (those closer than dhat count) and its gradient into ``g`` and
    ``gq`` (the tool's dofs); the core's vertices must be in ``scratch`` (:func:`~.collider.tool_vertices`)."""
    edges = model[5]
    dhat_t, dhat_tool, kappa, _lines = contact
    geom = tool[0]
    tool_edges, edge_radius, vertex_radius = geom[3], geom[4], geom[5]
    tt, vt, tv, counts = pairs
    pos, jac = scratch[0], scratch[1]
    k2 = kappa * dt2
    e = 0.0
    for k in range(counts[0]):
        p = tt[k, 0]
        a = edges[tt[k, 1], 0]
        b = edges[tt[k, 1], 1]
        d, t, cx, cy = point_segment(x[p, 0], x[p, 1], x[a, 0], x[a, 1], x[b, 0], x[b, 1])
        bb, b1, _ = barrier(d, dhat_t)
        if bb == 0.0:
            continue
        e += k2 * bb
        if d <= 0.0:
            continue  # (touching: E is inf, the line search refuses the state)
        s = k2 * b1 / d
        nx, ny = s * (x[p, 0] - cx), s * (x[p, 1] - cy)
        g[2 * p] += nx
        g[2 * p + 1] += ny
        g[2 * a] -= (1.0 - t) * nx
        g[2 * a + 1] -= (1.0 - t) * ny
        g[2 * b] -= t * nx
        g[2 * b + 1] -= t * ny
    for k in range(counts[1]):
        p = vt[k, 0]
        ta = tool_edges[vt[k, 1], 0]
        tb = tool_edges[vt[k, 1], 1]
        d, t, cx, cy = point_segment(x[p, 0], x[p, 1], pos[ta, 0], pos[ta, 1], pos[tb, 0], pos[tb, 1])
        bb, b1, _ = barrier(d - edge_radius[vt[k, 1]], dhat_tool)
        if bb == 0.0:
            continue
        e += k2 * bb
        if d <= 0.0:
            continue  # (touching: E is inf, the line search refuses the state)
        s = k2 * b1 / d
        nx, ny = x[p, 0] - cx, x[p, 1] - cy
        g[2 * p] += s * nx
        g[2 * p + 1] += s * ny
        _add_tool_grad(gq, jac, ta, -s * (1.0 - t), nx, ny)
        _add_tool_grad(gq, jac, tb, -s * t, nx, ny)
    for k in range(counts[2]):
        w = tv[k, 0]
        a = edges[tv[k, 1], 0]
        b = edges[tv[k, 1], 1]
        d, t, cx, cy = point_segment(pos[w, 0], pos[w, 1], x[a, 0], x[a, 1], x[b, 0], x[b, 1])
        bb, b1, _ = barrier(d - vertex_radius[w], dhat_tool)
        if bb == 0.0:
            continue
        e += k2 * bb
        if d <= 0.0:
            continue  # (touching: E is inf, the line search refuses the state)
        s = k2 * b1 / d
        nx, ny = pos[w, 0] - cx, pos[w, 1] - cy
        _add_tool_grad(gq, jac, w, s, nx, ny)
        g[2 * a] -= s * (1.0 - t) * nx
        g[2 * a + 1] -= s * (1.0 - t) * ny
        g[2 * b] -= s * t * nx
        g[2 * b + 1] -= s * t * ny
    return e


@njit(cache=True, nogil=True)
def grasp_targets(q: np.ndarray, local: np.ndarray, out: np.ndarray) -> None:
    """The held particles' targets T(q) l (the tool's pose frame, as ``core/sim/grasp.py`` places them)."""
    c = math.cos(q[2])
    s = math.sin(q[2])
    for k in range(local.shape[0]):
        out[k, 0] = q[0] + c * local[k, 0] - s * local[k, 1]
        out[k, 1] = q[1] + s * local[k, 0] + c * local[k, 1]


@njit(cache=True, nogil=True)
def tool_part(x: np.ndarray, q: np.ndarray, tool: tuple, step: tuple, scratch: tuple, g: np.ndarray,
              gq: np.ndarray) -> float:
    """dt^2 (the tool's spring + the grasp's springs) and their gradients; the grasp's targets into ``scratch``."""
    servo, present = tool[1], tool[2]
    q_cmd, dt2, attach = step[2], step[3], step[4]
    idx, local, k_att = attach
    targets = scratch[2]
    e = 0.0
    if present:
        for j in range(4):
            r = q[j] - q_cmd[j]
            e += 0.5 * dt2 * servo[j] * r * r
            gq[j] += dt2 * servo[j] * r
    if idx.shape[0]:
        grasp_targets(q, local, targets)
        c = math.cos(q[2])
        s = math.sin(q[2])
        for k in range(idx.shape[0]):
            i = idx[k]
            rx = x[i, 0] - targets[k, 0]
            ry = x[i, 1] - targets[k, 1]
            e += 0.5 * dt2 * k_att * (rx * rx + ry * ry)
            fx, fy = dt2 * k_att * rx, dt2 * k_att * ry
            g[2 * i] += fx
            g[2 * i + 1] += fy
            # the target moves with the tool: d target / d q = (1, 0; 0, 1; R' l)
            gq[0] -= fx
            gq[1] -= fy
            gq[2] -= fx * (-s * local[k, 0] - c * local[k, 1]) + fy * (c * local[k, 0] - s * local[k, 1])
    return e


@njit(cache=True, nogil=True)
def potential(x: np.ndarray, q: np.ndarray, model: tuple, contact: tuple, tool: tuple, step: tuple, pairs: tuple,
              scratch: tuple, g: np.ndarray) -> float:
    """E(x, q) of the module docstring; its gradient into ``g`` (2N + 4,): the particles' coordinates, then the
    tool's dofs; zero at the coordinates that may not move (``step``'s ``free``)."""
    mass = model[0]
    x_pred, free, _q_cmd, dt2, _attach, friction = step
    n = x.shape[0]
    gq = g[2 * n:]
    e = 0.0
    for i in range(n):
        rx = x[i, 0] - x_pred[i, 0]
        ry = x[i, 1] - x_pred[i, 1]
        e += 0.5 * mass[i] * (rx * rx + ry * ry)
        g[2 * i] = mass[i] * rx
        g[2 * i + 1] = mass[i] * ry
    for j in range(4):
        gq[j] = 0.0
    if tool[2]:
        tool_vertices(q, tool[0], scratch[0], scratch[1])
    e += material_part(x, model, dt2, g)
    e += line_part(x, free, contact[3], contact[0], contact[2] * dt2, g)
    e += contact_part(x, model, contact, tool, pairs, scratch, dt2, g, gq)
    e += tool_part(x, q, tool, step, scratch, g, gq)
    e += friction_part(x, friction, scratch, dt2, g)
    for i in range(2 * n):
        if free[i] == 0.0:
            g[i] = 0.0
    if not tool[2]:
        for j in range(4):
            gq[j] = 0.0
    return e
