"""The barrier step's Gauss-Newton Hessian, assembled into a fixed sparsity pattern for the LDL^T factor.

The pattern (:func:`hessian_pattern`, made once per model) is the mesh's: each particle's 2 x 2 block with itself
and with every particle it shares a triangle with, plus four dense rows and columns for the tool's dofs, last.
Assembly (:func:`assemble`) adds each term's Gauss-Newton block (``core/physics/ipc_energy.py``) through the
slot tables; a coupling the pattern does not hold (two particles in contact that the mesh does not connect) is
dropped, its diagonal blocks kept: the factor is then a preconditioner, exact where it matters most, and the
quasi-Newton updates of the solve take up the rest. A coordinate that may not move gets a unit row.

Bundle ``lin`` = (LDL^T pattern bundle, A's values (nnz_a,), L's values (nnz_l,), D (n,), the factor's
workspace, the solve's workspace, adjacency pointers (N + 1,), adjacent particles (M,), their 2 x 2 slots
(M, 4), the tool's slots (2N + 4, 4), each triangle's slots (T, 21): the upper triangle of its 6 x 6 block, row
by row, from :func:`element_slots`).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..contact.barrier import barrier, point_segment
from .ipc_energy import element_j
from .ipc_friction import friction_gradient_row, friction_stiffness
from .material import _element_rest


def hessian_pattern(n_particles: int, tris: np.ndarray) -> tuple[np.ndarray, np.ndarray, tuple]:
    """(rows, cols, slot builder) of the pattern: every coupling a triangle makes, both orders of the same pair
    once, and the tool's rows. Returns the entry coordinates and (adjacency pointers, adjacent particles) to map
    the slots with :func:`slot_tables` once the pattern is analysed."""
    n = int(n_particles)
    tris = np.asarray(tris, dtype=np.int64).reshape(-1, 3)
    pairs = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    pairs = np.sort(pairs, axis=1)
    pairs = np.unique(np.concatenate([pairs, np.stack([np.arange(n), np.arange(n)], axis=1)]), axis=0)
    # both directions for the lookup
    both = np.concatenate([pairs, pairs[pairs[:, 0] != pairs[:, 1]][:, ::-1]])
    order = np.lexsort((both[:, 1], both[:, 0]))
    both = both[order]
    adj_ptr = np.zeros(n + 1, dtype=np.int64)
    np.add.at(adj_ptr, both[:, 0] + 1, 1)
    adj_ptr = np.cumsum(adj_ptr)
    adj_v = np.ascontiguousarray(both[:, 1], dtype=np.int64)
    rows, cols = [], []
    for a, b in pairs:  # one 2 x 2 block per unordered pair (3 entries on the diagonal)
        for i in range(2):
            for j in range(2):
                if a == b and j < i:
                    continue
                rows.append(2 * a + i)
                cols.append(2 * b + j)
    nd = 2 * n
    for i in range(nd):
        for k in range(4):
            rows.append(i)
            cols.append(nd + k)
    for k in range(4):
        for m in range(k, 4):
            rows.append(nd + k)
            cols.append(nd + m)
    return np.array(rows, dtype=np.int64), np.array(cols, dtype=np.int64), (adj_ptr, adj_v, pairs)


def slot_tables(n_particles: int, slot: np.ndarray, adjacency: tuple) -> tuple[np.ndarray, np.ndarray]:
    """The slots of :func:`hessian_pattern`'s entries as the kernels look them up: (adj_slot (M, 4): the entries
    (2a + i, 2b + j) of each adjacency (a, b) in row-major i, j order; tool_slot (2N + 4, 4))."""
    adj_ptr, adj_v, pairs = adjacency
    n = int(n_particles)
    k = 0
    block: dict[tuple[int, int], list[int]] = {}
    for a, b in pairs:
        s = [0, 0, 0, 0]
        for i in range(2):
            for j in range(2):
                if a == b and j < i:
                    s[2 * i + j] = s[2 * j + i]
                    continue
                s[2 * i + j] = int(slot[k])
                k += 1
        block[(int(a), int(b))] = s
    adj_slot = np.zeros((adj_v.shape[0], 4), dtype=np.int64)
    for a in range(n):
        for m in range(adj_ptr[a], adj_ptr[a + 1]):
            b = int(adj_v[m])
            s = block[(a, b)] if (a, b) in block else [block[(b, a)][t] for t in (0, 2, 1, 3)]
            adj_slot[m] = s
    nd = 2 * n
    tool_slot = np.zeros((nd + 4, 4), dtype=np.int64)
    for i in range(nd):
        for m in range(4):
            tool_slot[i, m] = slot[k]
            k += 1
    for m in range(4):
        for j in range(m, 4):
            tool_slot[nd + m, j] = slot[k]
            tool_slot[nd + j, m] = slot[k]
            k += 1
    return adj_slot, tool_slot


@njit(cache=True, inline="always")
def _slot(lin: tuple, i: int, j: int) -> int:
    """Where entry (i, j) of the symmetric matrix lives, -1 when the pattern does not hold it."""
    adj_ptr, adj_v, adj_slot, tool_slot = lin[6], lin[7], lin[8], lin[9]
    nd = adj_ptr.shape[0] * 2 - 2
    if j >= nd:
        return tool_slot[i, j - nd]
    if i >= nd:
        return tool_slot[j, i - nd]
    a = i // 2
    b = j // 2
    for m in range(adj_ptr[a], adj_ptr[a + 1]):
        if adj_v[m] == b:
            return adj_slot[m, 2 * (i % 2) + (j % 2)]
    return -1


@njit(cache=True, nogil=True)
def add_outer(lin: tuple, free: np.ndarray, dofs: np.ndarray, v: np.ndarray, m: int, scale: float) -> None:
    """A += scale v v^T over the first ``m`` dofs ``dofs`` (the upper triangle once; a coupling the pattern does
    not hold, or a coordinate that may not move, is left out)."""
    values = lin[1]
    nfree = free.shape[0]
    for p in range(m):
        i = dofs[p]
        if i < nfree and free[i] == 0.0:
            continue
        for r in range(p, m):
            j = dofs[r]
            if j < nfree and free[j] == 0.0:
                continue
            if i == j and r != p:
                # the same dof twice (a point against an edge through it): both products land on the diagonal
                s = _slot(lin, i, i)
                values[s] += 2.0 * scale * v[p] * v[r]
                continue
            s = _slot(lin, i, j)
            if s >= 0:
                values[s] += scale * v[p] * v[r]


@njit(cache=True, nogil=True)
def element_slots(tris: np.ndarray, lin: tuple, out: np.ndarray) -> None:
    """Each triangle's 21 slots (the upper triangle of its 6 x 6 block over (a_x, a_y, b_x, b_y, c_x, c_y), row by
    row) into ``out`` (T, 21): assembly then writes a triangle's block without a lookup."""
    for t in range(tris.shape[0]):
        m = 0
        for p in range(6):
            i = 2 * tris[t, p // 2] + p % 2
            for r in range(p, 6):
                j = 2 * tris[t, r // 2] + r % 2
                out[t, m] = _slot(lin, min(i, j), max(i, j))
                m += 1


@njit(cache=True, nogil=True)
def _elements(x: np.ndarray, model: tuple, free: np.ndarray, dt2: float, lin: tuple) -> None:
    """Each element's Gauss-Newton block: its deviatoric part (exact: (dt^2 / alpha_D) (u u^T + w w^T) with u, w
    the gradients of F's two deviatoric directions) and (dt^2 / alpha_H) (1 + b''(J)) grad J grad J^T for its
    volume and the inversion barrier; written through the triangle's slot table."""
    tris, elastic, j_hat = model[1], model[2], model[3]
    values, slots = lin[1], lin[10]
    u = np.empty(6)
    w = np.empty(6)
    gv = np.empty(6)
    fr = np.empty(6)
    for t in range(tris.shape[0]):
        ad = elastic[t, 4]
        ah = elastic[t, 5]
        if ad <= 0.0 or ah <= 0.0:
            continue
        cbx, cby, ccx, ccy, cax, cay = _element_rest(elastic, t)
        a, b, c, jj, gj = element_j(x, tris, elastic, t)
        u[0], u[1], u[2], u[3], u[4], u[5] = cax, -cay, cbx, -cby, ccx, -ccy
        w[0], w[1], w[2], w[3], w[4], w[5] = cay, cax, cby, cbx, ccy, ccx
        for k in range(6):
            gv[k] = gj[k]
        fr[0] = fr[1] = 0.0
        for k, p in enumerate((a, b, c)):
            fr[2 * k] = free[2 * p]
            fr[2 * k + 1] = free[2 * p + 1]
        sd = dt2 / ad
        sh = dt2 / ah
        if jj < j_hat:
            sh *= 1.0 + barrier(jj, j_hat)[2]
        m = 0
        for p in range(6):
            for r in range(p, 6):
                if fr[p] != 0.0 and fr[r] != 0.0:
                    values[slots[t, m]] += sd * (u[p] * u[r] + w[p] * w[r]) + sh * gv[p] * gv[r]
                m += 1


@njit(cache=True, nogil=True)
def _pairs(x: np.ndarray, model: tuple, contact: tuple, tool: tuple, pairs: tuple, scratch: tuple, free: np.ndarray,
           dt2: float, lin: tuple, dofs: np.ndarray, v: np.ndarray) -> None:
    """Each active pair's b'' grad d grad d^T (the tool's dofs through its core vertices' Jacobian)."""
    edges = model[5]
    dhat_t, dhat_tool, kappa, _lines = contact
    geom = tool[0]
    tool_edges, edge_radius, vertex_radius = geom[3], geom[4], geom[5]
    tt, vt, tv, counts = pairs
    pos, jac = scratch[0], scratch[1]
    nd = 2 * x.shape[0]
    for kind in range(3):
        for k in range(counts[kind]):
            if kind == 0:
                p, a, b = tt[k, 0], edges[tt[k, 1], 0], edges[tt[k, 1], 1]
                d, t, cx, cy = point_segment(x[p, 0], x[p, 1], x[a, 0], x[a, 1], x[b, 0], x[b, 1])
                b2 = barrier(d, dhat_t)[2]
                px, py = x[p, 0], x[p, 1]
            elif kind == 1:
                p, ta, tb = vt[k, 0], tool_edges[vt[k, 1], 0], tool_edges[vt[k, 1], 1]
                d, t, cx, cy = point_segment(x[p, 0], x[p, 1], pos[ta, 0], pos[ta, 1], pos[tb, 0], pos[tb, 1])
                b2 = barrier(d - edge_radius[vt[k, 1]], dhat_tool)[2]
                px, py = x[p, 0], x[p, 1]
            else:
                w, a, b = tv[k, 0], edges[tv[k, 1], 0], edges[tv[k, 1], 1]
                d, t, cx, cy = point_segment(pos[w, 0], pos[w, 1], x[a, 0], x[a, 1], x[b, 0], x[b, 1])
                b2 = barrier(d - vertex_radius[w], dhat_tool)[2]
                px, py = pos[w, 0], pos[w, 1]
            if b2 == 0.0 or d <= 0.0 or not math.isfinite(b2):
                continue
            nx, ny = (px - cx) / d, (py - cy) / d
            m = 0
            if kind != 2:  # the tissue point
                dofs[0], dofs[1], v[0], v[1] = 2 * p, 2 * p + 1, nx, ny
                m = 2
            if kind != 1:  # the tissue edge
                dofs[m], dofs[m + 1], dofs[m + 2], dofs[m + 3] = 2 * a, 2 * a + 1, 2 * b, 2 * b + 1
                v[m], v[m + 1], v[m + 2], v[m + 3] = -(1.0 - t) * nx, -(1.0 - t) * ny, -t * nx, -t * ny
                m += 4
            if kind != 0:  # the tool's dofs
                for j in range(4):
                    if kind == 1:
                        gj = -(1.0 - t) * (jac[ta, 0, j] * nx + jac[ta, 1, j] * ny) - t * (jac[tb, 0, j] * nx
                                                                                          + jac[tb, 1, j] * ny)
                    else:
                        gj = jac[w, 0, j] * nx + jac[w, 1, j] * ny
                    dofs[m + j] = nd + j
                    v[m + j] = gj
                m += 4
            add_outer(lin, free, dofs, v, m, dt2 * kappa * b2)


@njit(cache=True, nogil=True)
def assemble(x: np.ndarray, q: np.ndarray, model: tuple, contact: tuple, tool: tuple, step: tuple, pairs: tuple,
             scratch: tuple, lin: tuple) -> None:
    """A = the Gauss-Newton Hessian of E at (x, q) (module docstring) into ``lin``'s values; the core's vertices
    must be in ``scratch`` for q (``collider.tool_vertices``)."""
    mass = model[0]
    x_pred, free, _q_cmd, dt2, attach, friction = step
    values = lin[1]
    n = x.shape[0]
    nd = 2 * n
    for s in range(values.shape[0]):
        values[s] = 0.0
    dofs = np.empty(14, dtype=np.int64)
    v = np.empty(14)
    for i in range(nd):
        s = _slot(lin, i, i)
        values[s] += mass[i // 2] if free[i] != 0.0 else 1.0
    _elements(x, model, free, dt2, lin)
    _pairs(x, model, contact, tool, pairs, scratch, free, dt2, lin, dofs, v)
    for m in range(friction[4][0]):
        c = friction_gradient_row(friction, scratch[1], m, nd, dofs, v)
        add_outer(lin, free, dofs, v, c, friction_stiffness(x, friction, scratch[0], m, dt2))
    y_top, y_bottom, wall_bottom, wall_top = contact[3]
    for i in range(n):
        if free[2 * i + 1] == 0.0:
            continue
        for line, up in ((y_bottom, 1.0), (wall_bottom, 1.0), (y_top, -1.0), (wall_top, -1.0)):
            if not math.isnan(line):
                values[_slot(lin, 2 * i + 1, 2 * i + 1)] += dt2 * contact[2] * barrier(up * (x[i, 1] - line),
                                                                                       contact[0])[2]
    servo = tool[1]
    for j in range(4):
        values[_slot(lin, nd + j, nd + j)] += dt2 * servo[j] if tool[2] else 1.0
    idx, local, k_att = attach
    c = math.cos(q[2])
    sn = math.sin(q[2])
    for k in range(idx.shape[0]):
        i = idx[k]
        # the spring's residual x_i - T(q) l_k: d/dx = I, d/dq = -(1, 0; 0, 1; R' l; 0)
        for comp in range(2):
            dofs[0], dofs[1], dofs[2], dofs[3] = 2 * i + comp, nd, nd + 1, nd + 2
            v[0] = 1.0
            v[1] = -1.0 if comp == 0 else 0.0
            v[2] = 0.0 if comp == 0 else -1.0
            v[3] = (sn * local[k, 0] + c * local[k, 1]) if comp == 0 else -(c * local[k, 0] - sn * local[k, 1])
            add_outer(lin, free, dofs, v, 4 if tool[2] else 1, dt2 * k_att)
