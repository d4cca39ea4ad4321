r"""The barrier step's minimisation (``method: ipc``): quasi-Newton on the incremental potential with contact
barriers, every line search capped so that no pair crosses and no triangle inverts.

The potential, its gradient and its Gauss-Newton Hessian are in :mod:`.ipc_energy` and :mod:`.ipc_hessian`. The
minimisation is L-BFGS (Liu, Bouaziz and Kavan 2017) whose initial inverse Hessian is the LDL^T factor of a
Gauss-Newton Hessian (``core/physics/ldlt.py``), lagged: it is refactored at the current iterate when the solve
has not converged after ``refresh`` iterations, and kept across steps otherwise (a smoothly moving or resting
tissue solves in one to three iterations with the last factor; a factor of the rest shape would lose under large
rotation). Each iteration:

1. the direction d = -H g (two-loop recursion over the last pairs, H0 = A^-1);
2. the pairs that may come within dhat along the whole step (``core/contact/broadphase.py``), and the largest
   step alpha_max <= 1 that keeps every pair apart (CCD, ``core/contact/barrier.py``: exact where the points move
   on straight lines, the tissue's and a sliding tool's; additive where the tool turns or its jaw moves), every free particle off
   the lines and walls, and every triangle's area positive (the smaller root of a quadratic in alpha);
3. backtracking from alpha_max until the potential falls (Armijo), then x += alpha d.

The state is intersection-free and inversion-free after every iteration, from the step's start (which is), so the
solve may stop at any iteration with a valid state; it stops when its estimated relative error (the last
correction over the step's motion, as ``core/physics/quasi_newton.py`` measures it) is at most ``tolerance`` or
after ``iterations``. It starts from the motion continued (x_n + dt damp v_n, the tool where it was), capped the
same way; at rest that is the answer.

Bundles: those of :mod:`.ipc_energy` (``model``, ``contact``, ``tool``, ``step``, ``pairs``, ``scratch``) and
:mod:`.ipc_hessian` (``lin``), and

* ``ws`` = (hist_s (m, n), hist_y (m, n), rho (m,), alpha (m,), g, g_new, d, x_old (n,) each (n = 2N + 4), dx
  (N, 2), the core's vertices at the sweep's end (V, 2), the broad phase's workspace, out (6,): iterations,
  estimated error, refactorisations, alpha_min, status (0 ok, 1 a pair buffer overflowed), pairs watched);
* ``opts`` = (tolerance, iterations at most, motion floor [m] RMS, refresh after this many iterations, grid cell
  [m], tool reach [m], jaw reach [m]).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..contact.barrier import CCD_KEEP, CCD_MAX_STEPS, ccd_pair, point_segment, toi_point_segment
from ..contact.broadphase import tissue_pairs, tool_pairs
from ..contact.collider import tool_vertices
from .ipc_energy import potential
from .ipc_hessian import assemble
from .ldlt import ldlt_factor, ldlt_solve

#: Backtracking halvings of the line search at most.
MAX_HALVINGS = 20
#: Armijo constant of the line search.
ARMIJO = 1e-4
#: A triangle's area may fall to this fraction of the way to zero in one line-search step at most.
INVERSION_KEEP = 0.9


@njit(cache=True, inline="always")
def _tool_point(q: np.ndarray, dq: np.ndarray, t: float, geom: tuple, v: int) -> tuple[float, float]:
    """Core vertex v's world position with the tool's dofs at q + t dq."""
    hinge, arm, sign = geom[0], geom[1], geom[2]
    yaw = q[2] + t * dq[2]
    a = sign[v] * 0.5 * (q[3] + t * dq[3])
    ca, sa = math.cos(a), math.sin(a)
    lx = hinge[v, 0] + ca * arm[v, 0] - sa * arm[v, 1]
    ly = hinge[v, 1] + sa * arm[v, 0] + ca * arm[v, 1]
    c, s = math.cos(yaw), math.sin(yaw)
    return q[0] + t * dq[0] + c * lx - s * ly, q[1] + t * dq[1] + s * lx + c * ly


@njit(cache=True, nogil=True)
def _accd_tool(x: np.ndarray, dxv: np.ndarray, q: np.ndarray, dq: np.ndarray, geom: tuple, kind: int, i: int,
               j: int, k: int, xi: float, lt: float, t_max: float) -> float:
    """Additive CCD of a tissue point i against core edge (j, k) (kind 1), or of core vertex i against tissue
    edge (j, k) (kind 2), the tool moving rigidly (and its jaw turning) from q to q + dq: the conservative time
    of impact in [0, t_max]. ``lt`` bounds how fast a point of the core moves per unit t relative to the tool's
    translation (dq[0], dq[1]): the gap's rate is bounded in the frame that translates with the tool (distances
    do not change there), so a tissue pressed along with the tool is not held to tiny steps."""
    cx, cy = dq[0], dq[1]
    # the tool slides (its turn moves no point by a hundredth of the gap CCD keeps): its points move on straight
    # lines, the time is exact
    if kind == 1:
        ax, ay = _tool_point(q, dq, 0.0, geom, j)
        bx, by = _tool_point(q, dq, 0.0, geom, k)
        gap0 = point_segment(x[i, 0], x[i, 1], ax, ay, bx, by)[0] - xi
    else:
        ax, ay = _tool_point(q, dq, 0.0, geom, i)
        bx, by = 0.0, 0.0
        gap0 = point_segment(ax, ay, x[j, 0], x[j, 1], x[k, 0], x[k, 1])[0] - xi
    if gap0 <= 0.0:
        return 0.0
    if lt * t_max <= 0.01 * CCD_KEEP * gap0:
        if kind == 1:
            return toi_point_segment(x[i, 0], x[i, 1], dxv[i, 0], dxv[i, 1], ax, ay, cx, cy, bx, by, cx, cy,
                                     xi + CCD_KEEP * gap0, t_max)
        return toi_point_segment(ax, ay, cx, cy, x[j, 0], x[j, 1], dxv[j, 0], dxv[j, 1], x[k, 0], x[k, 1],
                                 dxv[k, 0], dxv[k, 1], xi + CCD_KEEP * gap0, t_max)
    if kind == 1:
        lp = math.sqrt((dxv[i, 0] - cx) ** 2 + (dxv[i, 1] - cy) ** 2) + lt
    else:
        lp = lt + max(math.sqrt((dxv[j, 0] - cx) ** 2 + (dxv[j, 1] - cy) ** 2),
                      math.sqrt((dxv[k, 0] - cx) ** 2 + (dxv[k, 1] - cy) ** 2))
    if lp <= 0.0:
        return t_max
    t = 0.0
    gap0 = 0.0
    keep = 0.0
    tl = 0.0
    for it in range(CCD_MAX_STEPS + 1):
        tn = t + tl
        if kind == 1:
            ax, ay = _tool_point(q, dq, tn, geom, j)
            bx, by = _tool_point(q, dq, tn, geom, k)
            d = point_segment(x[i, 0] + tn * dxv[i, 0], x[i, 1] + tn * dxv[i, 1], ax, ay, bx, by)[0]
        else:
            px, py = _tool_point(q, dq, tn, geom, i)
            d = point_segment(px, py, x[j, 0] + tn * dxv[j, 0], x[j, 1] + tn * dxv[j, 1], x[k, 0] + tn * dxv[k, 0],
                              x[k, 1] + tn * dxv[k, 1])[0]
        gap = d - xi
        if it == 0:
            if gap <= 0.0:
                return 0.0
            gap0 = gap
            keep = CCD_KEEP * gap0
            tl = (1.0 - CCD_KEEP) * gap0 / lp
            continue
        if t > 0.0 and gap < keep:  # (the first advance is safe by construction: lp bounds the closing)
            return t
        t = tn
        if t > t_max:
            return t_max
        tl = 0.9 * gap / lp
    return t


@njit(cache=True, nogil=True)
def _inversion_cap(x: np.ndarray, dxv: np.ndarray, tris: np.ndarray, t_max: float) -> float:
    """The largest step in [0, t_max] along dxv that keeps every triangle's area above 1 - INVERSION_KEEP of the
    way to zero: the smaller positive root of the area's quadratic in the step."""
    for t in range(tris.shape[0]):
        a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
        e1x, e1y = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1]
        e2x, e2y = x[c, 0] - x[a, 0], x[c, 1] - x[a, 1]
        f1x, f1y = dxv[b, 0] - dxv[a, 0], dxv[b, 1] - dxv[a, 1]
        f2x, f2y = dxv[c, 0] - dxv[a, 0], dxv[c, 1] - dxv[a, 1]
        c0 = e1x * e2y - e1y * e2x
        c1 = e1x * f2y - e1y * f2x + f1x * e2y - f1y * e2x
        c2 = f1x * f2y - f1y * f2x
        if c0 <= 0.0:
            continue  # (a degenerate rest triangle carries no element)
        # smallest alpha > 0 with c0 + c1 alpha + c2 alpha^2 = 0
        root = math.inf
        if abs(c2) < 1e-30 * c0:
            if c1 < 0.0:
                root = -c0 / c1
        else:
            disc = c1 * c1 - 4.0 * c2 * c0
            if disc >= 0.0:
                sq = math.sqrt(disc)
                for r in ((-c1 - sq) / (2.0 * c2), (-c1 + sq) / (2.0 * c2)):
                    if 0.0 < r < root:
                        root = r
        if INVERSION_KEEP * root < t_max:
            t_max = INVERSION_KEEP * root
    return t_max


@njit(cache=True, nogil=True)
def _line_cap(x: np.ndarray, dxv: np.ndarray, free: np.ndarray, lines: tuple, t_max: float) -> float:
    """The largest step in [0, t_max] that keeps every free particle's gap to each line and wall above CCD_KEEP
    of what it is."""
    y_top, y_bottom, wall_bottom, wall_top = lines
    for i in range(x.shape[0]):
        if free[2 * i + 1] == 0.0 or dxv[i, 1] == 0.0:
            continue
        for line, up in ((y_bottom, 1.0), (wall_bottom, 1.0), (y_top, -1.0), (wall_top, -1.0)):
            if math.isnan(line):
                continue
            gap = up * (x[i, 1] - line)
            rate = -up * dxv[i, 1]
            if gap > 0.0 and rate > 0.0 and (1.0 - CCD_KEEP) * gap / rate < t_max:
                t_max = (1.0 - CCD_KEEP) * gap / rate
    return t_max


@njit(cache=True, nogil=True)
def sweep(x: np.ndarray, q: np.ndarray, dvec: np.ndarray, model: tuple, contact: tuple, tool: tuple, pairs: tuple,
          scratch: tuple, ws: tuple, opts: tuple) -> bool:
    """The candidate pairs of the step x -> x + dvec (``ws``'s dx holds it as (N, 2)), the tool q -> q + dq;
    False when a pair buffer overflowed."""
    bverts, bedges, near, bodies = model[4], model[5], model[6], model[8]
    dhat_t, dhat_tool, _kappa, _lines = contact
    geom, _servo, present = tool
    tt, vt, tv, counts = pairs
    dxv, tool_end, bp_ws = ws[8], ws[9], ws[10]
    n = x.shape[0]
    for i in range(n):
        dxv[i, 0] = dvec[2 * i]
        dxv[i, 1] = dvec[2 * i + 1]
    counts[0] = tissue_pairs(x, dxv, bverts, bedges, near, dhat_t, opts[4], tt, bp_ws) if bodies else 0
    counts[1] = 0
    counts[2] = 0
    if present:
        dq = dvec[2 * n:]
        tool_vertices(q, geom, scratch[0], scratch[1])
        for v in range(geom[0].shape[0]):
            tool_end[v, 0], tool_end[v, 1] = _tool_point(q, dq, 1.0, geom, v)
        bulge = abs(dq[2]) * opts[5] + 0.5 * abs(dq[3]) * opts[6]
        radius = 0.0
        for r in geom[5]:
            radius = max(radius, r)
        nv = geom[0].shape[0]
        counts[1], counts[2] = tool_pairs(x, dxv, bverts, bedges, scratch[0][:nv], tool_end[:nv], geom[3], bulge,
                                          dhat_tool + radius, vt, tv)
    return counts[0] >= 0 and counts[1] >= 0 and counts[2] >= 0


@njit(cache=True, nogil=True)
def sweep_fitting(x: np.ndarray, q: np.ndarray, dvec: np.ndarray, model: tuple, contact: tuple, tool: tuple,
                  pairs: tuple, scratch: tuple, ws: tuple, opts: tuple) -> float:
    """:func:`sweep` of dvec, halved (in place) until its candidate pairs fit the buffers (a long first direction
    sweeps past many pairs it will never reach): the scale kept, 0 when not even 2^-40 of it fits."""
    scale = 1.0
    for _ in range(40):
        if sweep(x, q, dvec, model, contact, tool, pairs, scratch, ws, opts):
            return scale
        scale *= 0.5
        for k in range(dvec.shape[0]):
            dvec[k] *= 0.5
    return 0.0


@njit(cache=True, nogil=True)
def step_bound(x: np.ndarray, q: np.ndarray, dvec: np.ndarray, model: tuple, contact: tuple, tool: tuple,
               step: tuple, pairs: tuple, ws: tuple, opts: tuple) -> float:
    """alpha_max in [0, 1]: no candidate pair crosses (CCD), no free particle reaches a line or wall, no
    triangle inverts along alpha dvec (``sweep`` must have found the candidates of this dvec)."""
    edges = model[5]
    geom = tool[0]
    tool_edges, edge_radius, vertex_radius = geom[3], geom[4], geom[5]
    tt, vt, tv, counts = pairs
    dxv = ws[8]
    n = x.shape[0]
    dq = dvec[2 * n:]
    t_max = 1.0
    t_max = _inversion_cap(x, dxv, model[1], t_max)
    t_max = _line_cap(x, dxv, step[1], contact[3], t_max)
    for k in range(counts[0]):
        p, a, b = tt[k, 0], edges[tt[k, 1], 0], edges[tt[k, 1], 1]
        t_max = min(t_max, ccd_pair(x[p], x[a], x[b], dxv[p], dxv[a], dxv[b], 0.0, t_max))
    lt = abs(dq[2]) * opts[5] + 0.5 * abs(dq[3]) * opts[6]  # (the turn's and the jaw's part: see _accd_tool)
    for k in range(counts[1]):
        te = vt[k, 1]
        t_max = min(t_max, _accd_tool(x, dxv, q, dq, geom, 1, vt[k, 0], tool_edges[te, 0], tool_edges[te, 1],
                                      edge_radius[te], lt, t_max))
    for k in range(counts[2]):
        w, e = tv[k, 0], tv[k, 1]
        t_max = min(t_max, _accd_tool(x, dxv, q, dq, geom, 2, w, edges[e, 0], edges[e, 1], vertex_radius[w], lt,
                                      t_max))
    return t_max


@njit(cache=True, nogil=True)
def refactor(x: np.ndarray, q: np.ndarray, model: tuple, contact: tuple, tool: tuple, step: tuple, pairs: tuple,
             scratch: tuple, lin: tuple) -> int:
    """The Gauss-Newton Hessian at (x, q) assembled and factored (LDL^T); 0, or the pivot that failed after a
    diagonal shift was tried (the matrix is positive definite by construction: mass + semi-definite terms)."""
    if tool[2]:
        tool_vertices(q, tool[0], scratch[0], scratch[1])
    assemble(x, q, model, contact, tool, step, pairs, scratch, lin)
    pattern, values, l_values, dvals, fwork = lin[0], lin[1], lin[2], lin[3], lin[4]
    status = ldlt_factor(pattern, values, l_values, dvals, fwork)
    return status


@njit(cache=True, nogil=True)
def _dot(a: np.ndarray, b: np.ndarray) -> float:
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i] * b[i]
    return s


@njit(cache=True, nogil=True)
def _direction(lin: tuple, ws: tuple, n_hist: int, head: int) -> tuple[float, int]:
    """d = -H g: the two-loop recursion over the kept pairs with H0 = A^-1 (the factor); when that is not a
    descent direction, -A^-1 g with the history dropped. Returns (g . d, pairs kept)."""
    hist_s, hist_y, rho, alpha, g, _g_new, d, _x_old = ws[:8]
    tmp = ws[12]
    m_hist = rho.shape[0]
    for k in range(g.shape[0]):
        d[k] = g[k]
    for jj in range(n_hist):
        j = (head - 1 - jj + 2 * m_hist) % m_hist
        a = rho[j] * _dot(hist_s[j], d)
        alpha[j] = a
        for k in range(d.shape[0]):
            d[k] -= a * hist_y[j, k]
    ldlt_solve(lin[0], lin[2], lin[3], d, tmp, lin[5])
    for k in range(d.shape[0]):
        d[k] = tmp[k]
    for jj in range(n_hist):
        j = (head - n_hist + jj + 2 * m_hist) % m_hist
        b = rho[j] * _dot(hist_y[j], d)
        for k in range(d.shape[0]):
            d[k] += (alpha[j] - b) * hist_s[j, k]
    for k in range(d.shape[0]):
        d[k] = -d[k]
    slope = _dot(g, d)
    if slope < 0.0:
        return slope, n_hist
    ldlt_solve(lin[0], lin[2], lin[3], g, tmp, lin[5])
    for k in range(d.shape[0]):
        d[k] = -tmp[k]
    return _dot(g, d), 0


@njit(cache=True, inline="always")
def _set(x: np.ndarray, q: np.ndarray, base: np.ndarray, d: np.ndarray, a: float) -> None:
    """(x, q) = base + a d (base and d flat: the particles' coordinates, then the tool's dofs)."""
    n = x.shape[0]
    for i in range(n):
        x[i, 0] = base[2 * i] + a * d[2 * i]
        x[i, 1] = base[2 * i + 1] + a * d[2 * i + 1]
    for j in range(4):
        q[j] = base[2 * n + j] + a * d[2 * n + j]


@njit(cache=True, nogil=True)
def _line_search(x: np.ndarray, q: np.ndarray, f: float, slope: float, a_max: float, model: tuple, contact: tuple,
                 tool: tuple, step: tuple, pairs: tuple, scratch: tuple, ws: tuple) -> tuple[float, float]:
    """Backtracking (Armijo) from a_max along d: (x, q) moved, (E there, the step taken); its gradient in g_new.
    The step is 0 (and (x, q) back where they were) when no fraction lowers E."""
    g_new, d, x_old = ws[5], ws[6], ws[7]
    n = x.shape[0]
    for i in range(n):
        x_old[2 * i] = x[i, 0]
        x_old[2 * i + 1] = x[i, 1]
    for j in range(4):
        x_old[2 * n + j] = q[j]
    a = a_max
    for _ in range(MAX_HALVINGS):
        if a <= 0.0:
            break
        _set(x, q, x_old, d, a)
        f_new = potential(x, q, model, contact, tool, step, pairs, scratch, g_new)
        if f_new <= f + ARMIJO * a * slope:
            return f_new, a
        a *= 0.5
    _set(x, q, x_old, d, 0.0)
    f_new = potential(x, q, model, contact, tool, step, pairs, scratch, g_new)
    return f_new, 0.0


@njit(cache=True, inline="always")
def _norm(v: np.ndarray, n: int, scale: float, reach: tuple) -> float:
    """|v| over the particles' coordinates plus the tool's dofs as the distance they move a point of it."""
    s = 0.0
    for i in range(n):
        s += v[i] * v[i]
    return scale * (math.sqrt(s) + math.hypot(v[n], v[n + 1]) + reach[0] * abs(v[n + 2])
                    + 0.5 * reach[1] * abs(v[n + 3]))


@njit(cache=True, nogil=True)
def _motion(x: np.ndarray, q: np.ndarray, x0: np.ndarray, q0: np.ndarray, free: np.ndarray, reach: tuple) -> float:
    """How far the step moved: |x - x0| over the free coordinates plus the tool's motion."""
    s = 0.0
    for i in range(x.shape[0]):
        for c in range(2):
            if free[2 * i + c] != 0.0:
                s += (x[i, c] - x0[i, c]) ** 2
    return (math.sqrt(s) + math.hypot(q[0] - q0[0], q[1] - q0[1]) + reach[0] * abs(q[2] - q0[2])
            + 0.5 * reach[1] * abs(q[3] - q0[3]))


@njit(cache=True, nogil=True)
def touching(x: np.ndarray, q: np.ndarray, model: tuple, contact: tuple, tool: tuple, pairs: tuple,
             scratch: tuple) -> bool:
    """True when a candidate pair is within its activation distance at (x, q) (``scratch`` holds the core's
    vertices at q)."""
    edges = model[5]
    dhat_t, dhat_tool = contact[0], contact[1]
    geom = tool[0]
    tt, vt, tv, counts = pairs
    pos = scratch[0]
    for k in range(counts[0]):
        p, a, b = tt[k, 0], edges[tt[k, 1], 0], edges[tt[k, 1], 1]
        if point_segment(x[p, 0], x[p, 1], x[a, 0], x[a, 1], x[b, 0], x[b, 1])[0] < dhat_t:
            return True
    for k in range(counts[1]):
        p, te = vt[k, 0], vt[k, 1]
        ta, tb = geom[3][te, 0], geom[3][te, 1]
        if point_segment(x[p, 0], x[p, 1], pos[ta, 0], pos[ta, 1], pos[tb, 0], pos[tb, 1])[0] - geom[4][te] < dhat_tool:
            return True
    for k in range(counts[2]):
        w, e = tv[k, 0], tv[k, 1]
        if point_segment(pos[w, 0], pos[w, 1], x[edges[e, 0], 0], x[edges[e, 0], 1], x[edges[e, 1], 0],
                         x[edges[e, 1], 1])[0] - geom[5][w] < dhat_tool:
            return True
    return False


@njit(cache=True, nogil=True)
def ipc_solve(x: np.ndarray, q: np.ndarray, x0: np.ndarray, q0: np.ndarray, model: tuple, contact: tuple,
              tool: tuple, step: tuple, pairs: tuple, scratch: tuple, lin: tuple, ws: tuple, opts: tuple) -> None:
    """The step's minimisation (module docstring) from (x, q), intersection-free, with the candidate pairs of x in
    ``pairs``; (x0, q0) the step's start (the motion the error is measured against). Results in ``ws``'s out."""
    tolerance, max_iterations, floor_rms, refresh, _cell, reach_t, reach_j = opts
    hist_s, hist_y, rho, _alpha, g, g_new, d = ws[:7]
    out = ws[11]
    free = step[1]
    n = x.shape[0]
    nd = 2 * n
    reach = (reach_t, reach_j)
    m_hist = rho.shape[0]
    f = potential(x, q, model, contact, tool, step, pairs, scratch, g)
    n_free = 0
    for i in range(n):
        if free[2 * i] != 0.0 or free[2 * i + 1] != 0.0:
            n_free += 1
    floor = floor_rms * math.sqrt(max(n_free, 1))
    res = math.inf
    n_hist = 0
    head = 0
    it = 0
    out[3] = 1.0
    out[4] = 0.0
    fresh = out[2] > 0.0  # the caller refactored at this x
    since = 0
    while it < max_iterations:
        # a fresh factor when the lagged one stops helping: every ``refresh`` iterations, after a step cut short
        # in contact, after a failed search
        if not fresh and since >= refresh:
            refactor(x, q, model, contact, tool, step, pairs, scratch, lin)
            out[2] += 1
            n_hist = 0
            fresh = True
            since = 0
        slope, n_hist = _direction(lin, ws, n_hist, head)
        if not slope < 0.0:
            if fresh:
                break
            fresh = False
            since = refresh
            continue
        scale = sweep_fitting(x, q, d, model, contact, tool, pairs, scratch, ws, opts)
        if scale == 0.0:
            out[4] = 1.0
            break
        slope *= scale
        a_max = step_bound(x, q, d, model, contact, tool, step, pairs, ws, opts)
        f_new, a = _line_search(x, q, f, slope, a_max, model, contact, tool, step, pairs, scratch, ws)
        if a == 0.0 and not fresh:
            since = refresh  # no decrease along the lagged direction: refactor here and try again
            continue
        fresh = False
        since += 1
        if a < 1.0 and touching(x, q, model, contact, tool, pairs, scratch):
            # a cut step in contact: the barriers' curvature has moved away from the factor's (it changes by
            # orders of magnitude with the gap): a fresh factor next (Newton's step; a lagged one takes many
            # small ones into a contact that closes)
            since = refresh
        out[3] = min(out[3], a)
        it += 1
        j = head
        for k in range(nd + 4):
            hist_s[j, k] = a * d[k]
        res = max(_norm(d, nd, a, reach), _norm(d, nd, 1.0, reach)) / max(_motion(x, q, x0, q0, free, reach), floor)
        for k in range(nd + 4):
            hist_y[j, k] = g_new[k] - g[k]
            g[k] = g_new[k]
        sy = _dot(hist_s[j], hist_y[j])
        if sy > 1e-300:
            rho[j] = 1.0 / sy
            head = (head + 1) % m_hist
            n_hist = min(n_hist + 1, m_hist)
        f = f_new
        if res <= tolerance or a == 0.0:
            break
    out[0] = it
    out[1] = res if it > 0 else 0.0
    out[5] = pairs[3][0] + pairs[3][1] + pairs[3][2]
