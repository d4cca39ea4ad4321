"""The material's step as the minimisation it is: quasi-Newton on the incremental potential, prefactored.

One implicit Euler step of the neo-Hookean membrane (``material: neo_hookean``,
``method: quasi_newton``) is the minimiser of the step's incremental potential

    E(x) = 1/2 sum_i m_i |x_i - x*_i|^2 + dt^2 sum_t V0_t Psi(F_t(x))
           (+ dt^2 sum_k 1/(2 c) |x_k - t_k|^2 for attachments: particle k held to target t_k, compliance c)

over the free particles, subject to the contacts: a particle may not end inside
the tool, past a boundary line or a wall (x* = x + dt damp v + dt^2 g; Psi and
its packed rest data: :mod:`~tissue_sim_ros.core.physics.material`). Its
optimality condition is grad E = 0 on the free coordinates, with the contact
forces taking up the normal components where a particle touches.

The solve is L-BFGS (Liu, Bouaziz and Kavan 2017) whose initial inverse Hessian
is a fixed, prefactored matrix: A0 = M + dt^2 K0, with K0 the exact Hessian of
the strain energy at the rest shape (``material.element_hessians`` at q0). The
deviatoric part of Psi is exactly quadratic in x, so K0 holds it exactly at
every shape; only the hydrostatic term (det F - 1)^2 departs from it, by the
strain and the rotation, and the quasi-Newton updates take that up. A0 is
factored once per (model, dt) by SuperLU (SciPy, a symmetric minimum-degree
ordering, no pivoting: A0 is symmetric positive definite) and applied by two
triangular solves in the compiled loop. Pinned particles are eliminated (their
rows of A0 are the identity).

Measured (``tissue-sim bench material``): 3-6 iterations per 10 ms step at
tolerance 1e-3 on the hanging strip at h = 2 mm and 1 mm: the count does not
grow with the mesh, unlike Gauss-Seidel sweeps.

Contacts, lines and walls are an active set. After each update the tool
projection (``contact.kernels.project_tool`` / ``project_edges``), the lines and
the walls put back every particle that went past them; such a particle is
then held in the direction n it was pushed (its normal): the normal
components of its gradient and of the search direction are removed, so it
slides along the surface (frictionless), until its force points away from the
surface (-grad E . n > 0), when it is released. At the end the tool's force on
a touching particle is the normal part of its gradient over dt^2, which is
what the Simulation's reaction expects as ``contact_dx = (g . n) n / m``.
Particles with zero effective inverse mass (pinned, held by the paper contact,
asleep) stay at x*.

Convergence, reported on every step (``SolveInfo.solve_residual``, the
``StepReport`` and ``/diagnostics``): the estimated relative error of the step,
the last correction ||x_k - x_k-1|| against the step's motion ||x - x_n|| (the
optimality residual grad E preconditioned into a position, so it reads as "how
far from the exact step, as a fraction of the step"; motion below 1 nm RMS per
particle counts as 1 nm). The loop stops when it falls to ``solve_tolerance``
or after ``iterations`` iterations; ``solve_converged`` says which. It starts
from x_n + dt damp v_n (the motion continued, gravity aside): at rest that is
the answer, and a resting tissue costs one iteration. """
from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla
from numba import njit

from ..contact.kernels import _rounded_box_sdf, project_edges, project_tool
from .material import _deformation_gradient, element_hessians

#: Constraint kinds per particle in the solve.
FREE, TOOL, FIXED, LINE, EDGE, CORNER = 0, 1, 2, 3, 4, 5
#: Backtracking halvings of the line search at most.
MAX_HALVINGS = 12
#: Armijo constant of the line search.
ARMIJO = 1e-4
#: Motion below this RMS per particle [m] counts as none when the error is measured against the step's motion.
FLOOR_RMS = 1e-9
#: A held particle pushed along a direction this far (cosine) from its normal is held in both directions.
CORNER_COS = 0.9
#: A held particle's normal that turns (cosine below this) changes the active set.
NORMAL_SAME = 1.0 - 1e-9
#: Turns of one particle's normal within a step after which it is held in both directions.
MAX_TURNS = 3
#: A particle this close to the tool's surface [m] at a step's start is held along it from the first iteration.
TOUCH_EPS = 1e-9
#: Pushes of the contacts at or below this [m] are round-off and hold nothing.
PUSH_EPS = 1e-12
#: Stiffness along a held particle's normal in the preconditioner, relative to its row's diagonal.
HELD_STIFFNESS = 1e4
#: Normals are compared to 1/NORMAL_QUANTUM when deciding whether the active set changed.
NORMAL_QUANTUM = 20.0


def active_key(held: np.ndarray | None, normal: np.ndarray | None) -> bytes:
    """A signature of an active set: the held particles and their normals to 1/NORMAL_QUANTUM."""
    if held is None or len(held) == 0:
        return b""
    q = np.round(np.asarray(normal, dtype=np.float64).reshape(-1, 2) * NORMAL_QUANTUM).astype(np.int64)
    return np.asarray(held, dtype=np.int64).tobytes() + q.tobytes()


# ----------------------------------------------------------------------------- the prefactored matrix


class Prefactor:
    """A0 = M + dt^2 K0 (rest Hessian) over the model's free coordinates, factored (SuperLU: Pr A0 Pc = L U).

    Parameters
    ----------
    q0 : (N, 2) rest positions [m]; tris (T, 3); elastic (T, 6) packed rest data; mass (N,) [kg];
    inv_mass : (N,) (0 = pinned: an identity row); dt : the step [s].
    """

    def __init__(self, q0: np.ndarray, tris: np.ndarray, elastic: np.ndarray, mass: np.ndarray,
                 inv_mass: np.ndarray, dt: float, held: np.ndarray | None = None,
                 held_normal: np.ndarray | None = None) -> None:
        n = q0.shape[0]
        self.dt = float(dt)
        t = tris.shape[0]
        he = np.zeros((t, 6, 6))
        if t:
            element_hessians(np.ascontiguousarray(q0, dtype=np.float64), np.ascontiguousarray(tris, dtype=np.int32),
                             np.ascontiguousarray(elastic, dtype=np.float64), he)
        dofs = np.stack([2 * tris[:, k].astype(np.int64) + d for k in range(3) for d in range(2)], axis=1)
        rows = np.repeat(dofs, 6, axis=1).ravel()
        cols = np.tile(dofs, (1, 6)).ravel()
        pinned = np.repeat(np.asarray(inv_mass) == 0.0, 2)
        keep = ~(pinned[rows] | pinned[cols])
        diag = np.where(pinned, 1.0, np.repeat(mass, 2))
        a = sp.csc_matrix((np.concatenate([diag, (dt * dt) * he.ravel()[keep]]),
                           (np.concatenate([np.arange(2 * n), rows[keep]]),
                            np.concatenate([np.arange(2 * n), cols[keep]]))), shape=(2 * n, 2 * n))
        if held is not None and held.size:
            # particles the contacts hold along a normal n: A0 + kappa n n^T there, so the preconditioner is
            # (nearly) the constrained system's (kappa: HELD_STIFFNESS times the particle's row)
            idx = np.asarray(held, dtype=np.int64)
            nn = np.asarray(held_normal, dtype=np.float64).reshape(-1, 2)
            kappa = HELD_STIFFNESS * np.asarray(a.diagonal()).reshape(-1, 2)[idx].max(axis=1)
            r = np.stack([2 * idx, 2 * idx, 2 * idx + 1, 2 * idx + 1], axis=1).ravel()
            c = np.stack([2 * idx, 2 * idx + 1, 2 * idx, 2 * idx + 1], axis=1).ravel()
            v = (kappa[:, None] * np.stack([nn[:, 0] * nn[:, 0], nn[:, 0] * nn[:, 1], nn[:, 1] * nn[:, 0],
                                            nn[:, 1] * nn[:, 1]], axis=1)).ravel()
            a = (a + sp.csc_matrix((v, (r, c)), shape=a.shape)).tocsc()
        self.held_key = active_key(held, held_normal)
        lu = sla.splu(a, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        lo, up = lu.L.tocsc(), lu.U.tocsc()
        lo.sort_indices()
        up.sort_indices()
        self.l_ptr, self.l_idx, self.l_val = (lo.indptr.astype(np.int64), lo.indices.astype(np.int64),
                                              lo.data.astype(np.float64))
        self.u_ptr, self.u_idx, self.u_val = (up.indptr.astype(np.int64), up.indices.astype(np.int64),
                                              up.data.astype(np.float64))
        self.perm_r = lu.perm_r.astype(np.int64)
        self.perm_c = lu.perm_c.astype(np.int64)
        self.nnz = int(lo.nnz + up.nnz)
        self.matrix = a
        self.scratch = np.zeros(2 * n)

    def solve(self, b: np.ndarray) -> np.ndarray:
        """A0^-1 b for a (2N,) vector (the compiled loop's own triangular solves, from Python; for tests)."""
        out = np.zeros_like(b, dtype=np.float64)
        apply_inverse(self.l_ptr, self.l_idx, self.l_val, self.u_ptr, self.u_idx, self.u_val, self.perm_r,
                      self.perm_c, np.ascontiguousarray(b, dtype=np.float64), self.scratch, out)
        return out


@njit(cache=True, nogil=True)
def apply_inverse(l_ptr: np.ndarray, l_idx: np.ndarray, l_val: np.ndarray, u_ptr: np.ndarray, u_idx: np.ndarray,
                  u_val: np.ndarray, perm_r: np.ndarray, perm_c: np.ndarray, b: np.ndarray, z: np.ndarray,
                  out: np.ndarray) -> None:
    """out = A0^-1 b with Pr A0 Pc = L U (SuperLU's convention): z = Pr b, L y = z, U w = y, out = Pc w.

    L, U in CSC with sorted row indices; L's diagonal is each column's first entry, U's its last.
    ``z`` (2N,) is scratch.
    """
    n = b.shape[0]
    for j in range(n):
        z[perm_r[j]] = b[j]
    for j in range(n):  # forward: L y = z (column-oriented)
        start = l_ptr[j]
        yj = z[j] / l_val[start]
        z[j] = yj
        for k in range(start + 1, l_ptr[j + 1]):
            z[l_idx[k]] -= l_val[k] * yj
    for j in range(n - 1, -1, -1):  # backward: U w = y
        stop = u_ptr[j + 1] - 1
        wj = z[j] / u_val[stop]
        z[j] = wj
        for k in range(u_ptr[j], stop):
            z[u_idx[k]] -= u_val[k] * wj
    for j in range(n):
        out[j] = z[perm_c[j]]


# ----------------------------------------------------------------------------- energy and gradient


@njit(cache=True, nogil=True)
def potential_and_gradient(x: np.ndarray, x_pred: np.ndarray, mass: np.ndarray, w: np.ndarray, tris: np.ndarray,
                           elastic: np.ndarray, dt2: float, attach_idx: np.ndarray, attach_target: np.ndarray,
                           attach_k: float, g: np.ndarray) -> float:
    """E(x) [kg m^2] of the module docstring and its gradient into ``g`` (2N,) [kg m] (zero where w == 0)."""
    n = x.shape[0]
    e = 0.0
    for i in range(n):
        rx = x[i, 0] - x_pred[i, 0]
        ry = x[i, 1] - x_pred[i, 1]
        e += 0.5 * mass[i] * (rx * rx + ry * ry)
        g[2 * i] = mass[i] * rx
        g[2 * i + 1] = mass[i] * ry
    strain = 0.0
    for t in range(tris.shape[0]):
        ad = elastic[t, 4]
        ah = elastic[t, 5]
        if ad <= 0.0 or ah <= 0.0:
            continue
        a = tris[t, 0]
        b = tris[t, 1]
        c = tris[t, 2]
        cbx = elastic[t, 0]
        cby = elastic[t, 1]
        ccx = elastic[t, 2]
        ccy = elastic[t, 3]
        cax = -cbx - ccx
        cay = -cby - ccy
        f00, f01, f10, f11 = _deformation_gradient(x, a, b, c, cbx, cby, ccx, ccy)
        g0 = f00 - f11
        g1 = f01 + f10
        ch = f00 * f11 - f01 * f10 - 1.0
        strain += 0.5 * ((g0 * g0 + g1 * g1) / ad + ch * ch / ah)
        kd = dt2 * g0 / ad
        kd1 = dt2 * g1 / ad
        kh = dt2 * ch / ah
        g[2 * a] += kd * cax + kd1 * cay + kh * (f11 * cax - f10 * cay)
        g[2 * a + 1] += kd1 * cax - kd * cay + kh * (-f01 * cax + f00 * cay)
        g[2 * b] += kd * cbx + kd1 * cby + kh * (f11 * cbx - f10 * cby)
        g[2 * b + 1] += kd1 * cbx - kd * cby + kh * (-f01 * cbx + f00 * cby)
        g[2 * c] += kd * ccx + kd1 * ccy + kh * (f11 * ccx - f10 * ccy)
        g[2 * c + 1] += kd1 * ccx - kd * ccy + kh * (-f01 * ccx + f00 * ccy)
    e += dt2 * strain
    for k in range(attach_idx.shape[0]):
        i = attach_idx[k]
        rx = x[i, 0] - attach_target[k, 0]
        ry = x[i, 1] - attach_target[k, 1]
        e += 0.5 * dt2 * attach_k * (rx * rx + ry * ry)
        g[2 * i] += dt2 * attach_k * rx
        g[2 * i + 1] += dt2 * attach_k * ry
    for i in range(n):
        if w[i] == 0.0:
            g[2 * i] = 0.0
            g[2 * i + 1] = 0.0
    return e


@njit(cache=True, nogil=True)
def project_vector(v: np.ndarray, kind: np.ndarray, normal: np.ndarray) -> None:
    """Remove from ``v`` (2N,) what the active set forbids: all of a FIXED or CORNER particle, the normal part at
    TOOL, LINE and EDGE particles."""
    for i in range(kind.shape[0]):
        k = kind[i]
        if k == FIXED or k == CORNER:
            v[2 * i] = 0.0
            v[2 * i + 1] = 0.0
        elif k == TOOL or k == LINE or k == EDGE:
            s = v[2 * i] * normal[i, 0] + v[2 * i + 1] * normal[i, 1]
            v[2 * i] -= s * normal[i, 0]
            v[2 * i + 1] -= s * normal[i, 1]


@njit(cache=True, nogil=True)
def _norm(v: np.ndarray) -> float:
    s = 0.0
    for i in range(v.shape[0]):
        s += v[i] * v[i]
    return math.sqrt(s)


@njit(cache=True, nogil=True)
def _motion(x: np.ndarray, x_start: np.ndarray, w: np.ndarray) -> float:
    """||x - x_start|| over the free particles [m]: the step's motion."""
    s = 0.0
    for i in range(x.shape[0]):
        if w[i] != 0.0:
            dx = x[i, 0] - x_start[i, 0]
            dy = x[i, 1] - x_start[i, 1]
            s += dx * dx + dy * dy
    return math.sqrt(s)


@njit(cache=True, nogil=True)
def _dot(a: np.ndarray, b: np.ndarray) -> float:
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i] * b[i]
    return s


@njit(cache=True, nogil=True)
def _join(i: int, k: int, kind: np.ndarray, normal: np.ndarray, scratch: np.ndarray, turns: np.ndarray) -> int:
    """Particle i was pushed by ``scratch[i]``: held along that direction as kind ``k``; 1 if the active set
    changed (it was not held, or its normal turned).

    A held particle whose push turns from its normal by more than acos(CORNER_COS), or turns at all for the
    MAX_TURNS-th time in the step (an edge's normal rocking between two tool faces), is held in both directions
    where it is (CORNER) for the rest of the step: so the set settles and the solve converges."""
    dx = scratch[i, 0]
    dy = scratch[i, 1]
    scratch[i, 0] = 0.0
    scratch[i, 1] = 0.0
    d = math.sqrt(dx * dx + dy * dy)
    if d <= PUSH_EPS or kind[i] == FIXED or kind[i] == CORNER:
        return 0  # (a push of round-off size, an edge already on the tool's face, has no direction to hold)
    nx = dx / d
    ny = dy / d
    joined = 1 if (kind[i] == FREE or kind[i] == LINE) else 0
    if kind[i] == TOOL or kind[i] == EDGE:
        c = nx * normal[i, 0] + ny * normal[i, 1]
        if c < NORMAL_SAME:
            turns[i] += 1
            if c < CORNER_COS or turns[i] >= MAX_TURNS:
                kind[i] = CORNER
                return 1
            joined = 1
    normal[i, 0] = nx
    normal[i, 1] = ny
    kind[i] = k  # the last push decides: an edge push moves a particle off the tool's surface
    return joined


@njit(cache=True, nogil=True)
def touching(x: np.ndarray, kind: np.ndarray, normal: np.ndarray, candidates: np.ndarray, shape1: np.ndarray,
             eps: float) -> None:
    """The active set's start: a free candidate within ``eps`` [m] of the tool's surface (``shape1``; a particle
    the last step left on it) is held along the surface's normal there from the first iteration."""
    for k in range(candidates.shape[0]):
        i = candidates[k]
        if kind[i] != FREE:
            continue
        d, gx, gy = _rounded_box_sdf(x[i, 0], x[i, 1], shape1)
        if abs(d) <= eps:
            kind[i] = TOOL
            normal[i, 0] = gx
            normal[i, 1] = gy


@njit(cache=True, nogil=True)
def enforce_bounds(x: np.ndarray, x_start: np.ndarray, w: np.ndarray, kind: np.ndarray, normal: np.ndarray,
                   candidates: np.ndarray, surface_edges: np.ndarray, shape0: np.ndarray, shape1: np.ndarray,
                   side_tol: float, scratch: np.ndarray, y_top: float, y_bottom: float, wall_bottom: float,
                   wall_top: float, turns: np.ndarray) -> int:
    """Put back every free particle past the tool, a line or a wall, and hold it along the push (its normal).

    The tool: ``project_tool`` / ``project_edges`` (swept from ``x_start`` and ``shape0`` to ``x`` and
    ``shape1``), the push's direction its normal (kind TOOL). Lines and walls: y clamped, normal +-y (LINE).
    Returns how many particles joined the active set (a particle already held is moved back but not counted).
    """
    n = x.shape[0]
    moved = 0
    if candidates.shape[0] > 0:
        for k in range(candidates.shape[0]):
            i = candidates[k]
            scratch[i, 0] = 0.0
            scratch[i, 1] = 0.0
        project_tool(x, x_start, w, candidates, shape0, shape1, scratch)
        for k in range(candidates.shape[0]):
            i = candidates[k]
            moved += _join(i, TOOL, kind, normal, scratch, turns)
    if surface_edges.shape[0] > 0:
        for k in range(surface_edges.shape[0]):
            for j in range(2):
                i = surface_edges[k, j]
                scratch[i, 0] = 0.0
                scratch[i, 1] = 0.0
        project_edges(x, x_start, w, surface_edges, shape0, shape1, side_tol, scratch)
        for k in range(surface_edges.shape[0]):
            for j in range(2):
                moved += _join(surface_edges[k, j], EDGE, kind, normal, scratch, turns)
    has_top = not math.isnan(y_top)
    has_bottom = not math.isnan(y_bottom)
    has_wb = not math.isnan(wall_bottom)
    has_wt = not math.isnan(wall_top)
    if has_top or has_bottom or has_wb or has_wt:
        for i in range(n):
            if w[i] == 0.0:
                continue
            y = x[i, 1]
            if has_top and y > y_top:
                x[i, 1] = y_top
                ny = -1.0
            elif has_wt and y > wall_top:
                x[i, 1] = wall_top
                ny = -1.0
            elif has_bottom and y < y_bottom:
                x[i, 1] = y_bottom
                ny = 1.0
            elif has_wb and y < wall_bottom:
                x[i, 1] = wall_bottom
                ny = 1.0
            else:
                continue
            if kind[i] == FREE:
                kind[i] = LINE
                normal[i, 0] = 0.0
                normal[i, 1] = ny
                moved += 1
    return moved


@njit(cache=True, nogil=True)
def build_constraints(kind: np.ndarray, normal: np.ndarray, inv_mass: np.ndarray, in_factor: np.ndarray,
                      l_ptr: np.ndarray, l_idx: np.ndarray, l_val: np.ndarray, u_ptr: np.ndarray, u_idx: np.ndarray,
                      u_val: np.ndarray, perm_r: np.ndarray, perm_c: np.ndarray, wcol: np.ndarray,
                      wkey: np.ndarray, cur_slot: np.ndarray, cur_i: np.ndarray, cur_n: np.ndarray,
                      smat: np.ndarray, sinv: np.ndarray, used: np.ndarray, b: np.ndarray, z: np.ndarray) -> int:
    """The active set's rows C for the preconditioner's exact elimination (:func:`apply_preconditioner`).

    Rows, in particle order: n_i at a TOOL or LINE particle the factor does not already hold
    (``in_factor``), and the unit x and y rows at a FIXED particle that is not pinned (``inv_mass > 0``: held
    by the paper contact, asleep); pinned ones are identity rows of A0. Each row's column W = A0^-1 c is kept in
    ``wcol`` under its key (particle, n_x, n_y) in ``wkey`` and reused while the factor is the same (its value
    is a function of the key alone, so reuse changes no bit). S = C W and its inverse go to ``smat``, ``sinv``.
    Returns the number of rows k, or -1 when they would exceed the workspace (no elimination then).
    """
    n = kind.shape[0]
    cap = wcol.shape[0]
    k = 0
    for i in range(n):
        k_rows = 0
        if (kind[i] == TOOL or kind[i] == LINE or kind[i] == EDGE) and not in_factor[i]:
            k_rows = 1
        elif (kind[i] == FIXED and inv_mass[i] > 0.0) or kind[i] == CORNER:
            k_rows = 2
        for r in range(k_rows):
            if k == cap:
                return -1
            cur_i[k] = i
            if k_rows == 1:
                cur_n[k, 0] = normal[i, 0]
                cur_n[k, 1] = normal[i, 1]
            else:
                cur_n[k, 0] = 1.0 if r == 0 else 0.0
                cur_n[k, 1] = 0.0 if r == 0 else 1.0
            k += 1
    for s in range(cap):
        used[s] = False
    for a in range(k):
        cur_slot[a] = -1
        for s in range(cap):
            if (not used[s] and wkey[s, 0] == cur_i[a] and wkey[s, 1] == cur_n[a, 0]
                    and wkey[s, 2] == cur_n[a, 1]):
                cur_slot[a] = s
                used[s] = True
                break
    free = 0
    for a in range(k):
        if cur_slot[a] >= 0:
            continue
        while used[free]:
            free += 1
        i = cur_i[a]
        b[2 * i] = cur_n[a, 0]
        b[2 * i + 1] = cur_n[a, 1]
        apply_inverse(l_ptr, l_idx, l_val, u_ptr, u_idx, u_val, perm_r, perm_c, b, z, wcol[free])
        b[2 * i] = 0.0
        b[2 * i + 1] = 0.0
        wkey[free, 0] = i
        wkey[free, 1] = cur_n[a, 0]
        wkey[free, 2] = cur_n[a, 1]
        cur_slot[a] = free
        used[free] = True
    if k == 0:
        return 0
    for a in range(k):
        ia = cur_i[a]
        for c in range(k):
            col = wcol[cur_slot[c]]
            smat[a, c] = cur_n[a, 0] * col[2 * ia] + cur_n[a, 1] * col[2 * ia + 1]
    sinv[:k, :k] = np.linalg.inv(smat[:k, :k])
    return k


@njit(cache=True, nogil=True)
def apply_preconditioner(l_ptr: np.ndarray, l_idx: np.ndarray, l_val: np.ndarray, u_ptr: np.ndarray,
                         u_idx: np.ndarray, u_val: np.ndarray, perm_r: np.ndarray, perm_c: np.ndarray, q: np.ndarray,
                         z: np.ndarray, out: np.ndarray, k: int, wcol: np.ndarray, cur_slot: np.ndarray,
                         cur_i: np.ndarray, cur_n: np.ndarray, sinv: np.ndarray, t: np.ndarray) -> None:
    """out = (A0^-1 - W S^-1 W^T) q with W = A0^-1 C^T, S = C W: the inverse of A0 on the active set's null
    space (the Newton step of the quadratic model min 1/2 d^T A0 d - q^T d subject to C d = 0), from the
    rows :func:`build_constraints` made (k <= 0: A0^-1 q)."""
    apply_inverse(l_ptr, l_idx, l_val, u_ptr, u_idx, u_val, perm_r, perm_c, q, z, out)
    if k <= 0:
        return
    for a in range(k):
        i = cur_i[a]
        t[a] = cur_n[a, 0] * out[2 * i] + cur_n[a, 1] * out[2 * i + 1]
    for a in range(k):
        u = 0.0
        for c in range(k):
            u += sinv[a, c] * t[c]
        col = wcol[cur_slot[a]]
        for j in range(out.shape[0]):
            out[j] -= u * col[j]


@njit(cache=True, nogil=True)
def quasi_newton_solve(x: np.ndarray, x_start: np.ndarray, x_pred: np.ndarray, mass: np.ndarray, w: np.ndarray,
                       tris: np.ndarray, elastic: np.ndarray, dt2: float, gravity: float,
                       l_ptr: np.ndarray, l_idx: np.ndarray, l_val: np.ndarray, u_ptr: np.ndarray,
                       u_idx: np.ndarray, u_val: np.ndarray, perm_r: np.ndarray, perm_c: np.ndarray,
                       hist_s: np.ndarray, hist_y: np.ndarray, hist_rho: np.ndarray, alpha_buf: np.ndarray,
                       kind: np.ndarray, normal: np.ndarray, candidates: np.ndarray, surface_edges: np.ndarray,
                       shape0: np.ndarray, shape1: np.ndarray, side_tol: float, scratch: np.ndarray,
                       contact_dx: np.ndarray, y_top: float, y_bottom: float, wall_bottom: float, wall_top: float,
                       attach_idx: np.ndarray, attach_target: np.ndarray, attach_k: float,
                       tolerance: float, max_iterations: int, x_guess: np.ndarray, g: np.ndarray, g_new: np.ndarray,
                       d: np.ndarray, x_old: np.ndarray, z: np.ndarray, out: np.ndarray, inv_mass: np.ndarray,
                       in_factor: np.ndarray, wcol: np.ndarray, wkey: np.ndarray, cur_slot: np.ndarray,
                       cur_i: np.ndarray, cur_n: np.ndarray, smat: np.ndarray, sinv: np.ndarray, used: np.ndarray,
                       b_unit: np.ndarray, t: np.ndarray, released_once: np.ndarray, turns: np.ndarray) -> None:
    """One step's minimisation (module docstring), from ``x_guess`` (free particles; the others stay at ``x`` = x*
    on entry) to the minimiser in ``x``.

    ``x_start`` (N, 2): positions at the start of the step (the tool's swept test). ``inv_mass`` (N,): the model's
    (0: pinned, an identity row of A0); ``in_factor`` (N,) bool: particles A0 already holds along their normal;
    ``wcol`` ... ``t``: the active set's elimination (:func:`build_constraints`, kept across calls while the
    factor is the same). ``kind`` (N,) int8,
    ``normal`` (N, 2): the active set, set here (FIXED where ``w == 0``). ``hist_*``: L-BFGS history, (m, 2N),
    (m,), and ``alpha_buf`` (m,). ``contact_dx`` (N, 2) is written: the tool's push per particle as
    (g . n) n / m. ``g``, ``g_new``, ``d``, ``x_old``, ``z`` (2N,) scratch. ``out`` (3,): iterations, the
    relative residual at the end, and the load it is relative to [kg m].
    """
    n = x.shape[0]
    n_dof = 2 * n
    m_hist = hist_rho.shape[0]
    n_free = 0
    for i in range(n):
        released_once[i] = 0
        turns[i] = 0
        kind[i] = FIXED if w[i] == 0.0 else FREE
        if w[i] != 0.0:
            n_free += 1
            x[i, 0] = x_guess[i, 0]
            x[i, 1] = x_guess[i, 1]
        normal[i, 0] = 0.0
        normal[i, 1] = 0.0
        contact_dx[i, 0] = 0.0
        contact_dx[i, 1] = 0.0
    if candidates.shape[0] > 0:
        touching(x, kind, normal, candidates, shape1, TOUCH_EPS)
    enforce_bounds(x, x_start, w, kind, normal, candidates, surface_edges, shape0, shape1, side_tol, scratch,
                   y_top, y_bottom, wall_bottom, wall_top, turns)
    # the load: the gradient at x* (inertia is zero there: strain + attachments), or gravity's dt^2 m g
    f = potential_and_gradient(x_pred, x_pred, mass, w, tris, elastic, dt2, attach_idx, attach_target, attach_k, g)
    project_vector(g, kind, normal)
    load = _norm(g)
    grav = 0.0
    for i in range(n):
        if w[i] != 0.0:
            grav += (mass[i] * dt2 * gravity) ** 2
    load = max(load, math.sqrt(grav))
    f = potential_and_gradient(x, x_pred, mass, w, tris, elastic, dt2, attach_idx, attach_target, attach_k, g)
    # ... or what the contacts carry at the start (the gradient before their normal parts are taken out)
    load = max(load, _norm(g))
    for i in range(n):  # release a particle whose force points away from its surface
        if kind[i] == TOOL or kind[i] == LINE or kind[i] == EDGE:
            if -(g[2 * i] * normal[i, 0] + g[2 * i + 1] * normal[i, 1]) > 0.0:
                kind[i] = FREE
    project_vector(g, kind, normal)
    n_rows = build_constraints(kind, normal, inv_mass, in_factor, l_ptr, l_idx, l_val, u_ptr, u_idx, u_val, perm_r,
                               perm_c, wcol, wkey, cur_slot, cur_i, cur_n, smat, sinv, used, b_unit, z)
    floor = FLOOR_RMS * math.sqrt(max(n_free, 1))
    res = math.inf
    n_hist = 0
    head = 0
    it = 0
    while it < max_iterations and load > 0.0:
        # two-loop recursion: d = -H g, H0 = A0^-1 (projected)
        for k in range(n_dof):
            d[k] = g[k]
        for jj in range(n_hist):
            j = (head - 1 - jj + 2 * m_hist) % m_hist
            a = hist_rho[j] * _dot(hist_s[j], d)
            alpha_buf[j] = a
            for k in range(n_dof):
                d[k] -= a * hist_y[j, k]
        apply_preconditioner(l_ptr, l_idx, l_val, u_ptr, u_idx, u_val, perm_r, perm_c, d, z, g_new, n_rows, wcol,
                             cur_slot, cur_i, cur_n, sinv, t)
        for k in range(n_dof):
            d[k] = g_new[k]
        project_vector(d, kind, normal)
        for jj in range(n_hist):
            j = (head - n_hist + jj + 2 * m_hist) % m_hist
            b = hist_rho[j] * _dot(hist_y[j], d)
            for k in range(n_dof):
                d[k] += (alpha_buf[j] - b) * hist_s[j, k]
        project_vector(d, kind, normal)
        for k in range(n_dof):
            d[k] = -d[k]
        slope = _dot(g, d)
        if slope >= 0.0:  # not a descent direction (history spoilt by the active set): start it again
            n_hist = 0
            apply_preconditioner(l_ptr, l_idx, l_val, u_ptr, u_idx, u_val, perm_r, perm_c, g, z, d, n_rows, wcol,
                                 cur_slot, cur_i, cur_n, sinv, t)
            project_vector(d, kind, normal)
            for k in range(n_dof):
                d[k] = -d[k]
            slope = _dot(g, d)
            if slope >= 0.0:
                break
        # backtracking (Armijo) line search
        for i in range(n):
            x_old[2 * i] = x[i, 0]
            x_old[2 * i + 1] = x[i, 1]
        step = 1.0
        for _ in range(MAX_HALVINGS):
            for i in range(n):
                x[i, 0] = x_old[2 * i] + step * d[2 * i]
                x[i, 1] = x_old[2 * i + 1] + step * d[2 * i + 1]
            f_new = potential_and_gradient(x, x_pred, mass, w, tris, elastic, dt2, attach_idx, attach_target,
                                           attach_k, g_new)
            if f_new <= f + ARMIJO * step * slope:
                break
            step *= 0.5
        # the contacts: a particle that went past the tool, a line or a wall joins the active set (always)
        joined = enforce_bounds(x, x_start, w, kind, normal, candidates, surface_edges, shape0, shape1, side_tol,
                                scratch, y_top, y_bottom, wall_bottom, wall_top, turns)

        f_new = potential_and_gradient(x, x_pred, mass, w, tris, elastic, dt2, attach_idx, attach_target,
                                       attach_k, g_new)
        # the correction just made (its free, tangential part) against the step's motion: the estimate of the
        # step's relative error
        j = head
        for i in range(n):
            hist_s[j, 2 * i] = x[i, 0] - x_old[2 * i]
            hist_s[j, 2 * i + 1] = x[i, 1] - x_old[2 * i + 1]
        project_vector(hist_s[j], kind, normal)
        # (the whole direction, not the line search's fraction of it: a short step is no sign of convergence)
        res = max(_norm(hist_s[j]), _norm(d)) / max(_motion(x, x_start, w), floor)
        it += 1
        released = 0
        if res <= tolerance and joined == 0:
            # converged with this active set: release the particles whose force points away from their surface
            # (one active-set step at a time, so the set does not flicker within the quasi-Newton updates)
            # (at most once per particle and step: one that comes back is held to the end, so the set cannot
            # cycle between a release and the projection that undoes it)
            for i in range(n):
                if (kind[i] == TOOL or kind[i] == LINE or kind[i] == EDGE) and released_once[i] == 0:
                    if -(g_new[2 * i] * normal[i, 0] + g_new[2 * i + 1] * normal[i, 1]) > 0.0:
                        kind[i] = FREE
                        released_once[i] = 1
                        released += 1
        project_vector(g_new, kind, normal)
        if joined or released:
            n_hist = 0  # the pairs belong to another set's subspace: start the history again
            n_rows = build_constraints(kind, normal, inv_mass, in_factor, l_ptr, l_idx, l_val, u_ptr, u_idx, u_val,
                                       perm_r, perm_c, wcol, wkey, cur_slot, cur_i, cur_n, smat, sinv, used, b_unit, z)
        else:
            # history: s = x_new - x_old, y = g_new - g (both projected)
            for k in range(n_dof):
                hist_y[j, k] = g_new[k] - g[k]
            project_vector(hist_y[j], kind, normal)
            sy = _dot(hist_s[j], hist_y[j])
            if sy > 1e-300:
                hist_rho[j] = 1.0 / sy
                head = (head + 1) % m_hist
                n_hist = min(n_hist + 1, m_hist)
        for k in range(n_dof):
            g[k] = g_new[k]
        f = f_new
        if res <= tolerance and joined == 0 and released == 0:
            break
    # the tool's push on each touching particle: the normal part of its gradient, as a PBD correction
    if candidates.shape[0] > 0 or surface_edges.shape[0] > 0:
        f = potential_and_gradient(x, x_pred, mass, w, tris, elastic, dt2, attach_idx, attach_target, attach_k,
                                   g_new)
        for i in range(n):
            if kind[i] == TOOL or kind[i] == EDGE:
                s = g_new[2 * i] * normal[i, 0] + g_new[2 * i + 1] * normal[i, 1]
                if s > 0.0:
                    contact_dx[i, 0] = s * normal[i, 0] / mass[i]
                    contact_dx[i, 1] = s * normal[i, 1] / mass[i]
            elif kind[i] == CORNER:  # held in both directions: the tool takes its whole gradient
                contact_dx[i, 0] = g_new[2 * i] / mass[i]
                contact_dx[i, 1] = g_new[2 * i + 1] / mass[i]
    out[0] = it
    out[1] = res if load > 0.0 and it > 0 else 0.0
    out[2] = load


@njit(cache=True, nogil=True)
def substep_residual(x: np.ndarray, x_start: np.ndarray, x_pred: np.ndarray, mass: np.ndarray, w: np.ndarray,
                     tris: np.ndarray, elastic: np.ndarray, h2: float, contact_dx: np.ndarray, y_top: float,
                     y_bottom: float, wall_bottom: float, wall_top: float, attach_idx: np.ndarray,
                     attach_target: np.ndarray, attach_k: float, l_ptr: np.ndarray, l_idx: np.ndarray,
                     l_val: np.ndarray, u_ptr: np.ndarray, u_idx: np.ndarray, u_val: np.ndarray, perm_r: np.ndarray,
                     perm_c: np.ndarray, kind: np.ndarray, g: np.ndarray, z: np.ndarray, e: np.ndarray) -> float:
    """The estimated relative error of a (sub)step another method solved, as :func:`quasi_newton_solve` reports
    it: the correction a quasi-Newton iteration would still make, |P A0^-1 P grad E(x)|, against the step's
    motion |x - x_start| (E: the incremental potential of a step h, ``h2`` = h^2, from ``x_pred``; A0 factored
    for that h).

    P leaves out the particles the solve may not move (w == 0) and those a contact, a line or a wall held
    (``contact_dx`` nonzero, y at or past a line or wall): their gradient is balanced by a force outside E.
    ``kind``, ``g``, ``z``, ``e`` are scratch.
    """
    n = x.shape[0]
    n_free = 0
    for i in range(n):
        y = x[i, 1]
        held = (w[i] == 0.0 or contact_dx[i, 0] != 0.0 or contact_dx[i, 1] != 0.0
                or (not math.isnan(y_top) and y >= y_top) or (not math.isnan(y_bottom) and y <= y_bottom)
                or (not math.isnan(wall_top) and y >= wall_top)
                or (not math.isnan(wall_bottom) and y <= wall_bottom))
        kind[i] = FIXED if held else FREE
        if w[i] != 0.0:
            n_free += 1
    potential_and_gradient(x, x_pred, mass, w, tris, elastic, h2, attach_idx, attach_target, attach_k, g)
    project_vector(g, kind, x_start)
    apply_inverse(l_ptr, l_idx, l_val, u_ptr, u_idx, u_val, perm_r, perm_c, g, z, e)
    project_vector(e, kind, x_start)
    return _norm(e) / max(_motion(x, x_start, w), FLOOR_RMS * math.sqrt(max(n_free, 1)))


# ----------------------------------------------------------------------------- the Solver's part


#: Factored matrices kept (per dt and set of particles held by a line or a wall at a step's start).
FACTORS_KEPT = 4
#: L-BFGS pairs kept (Liu et al. 2017 use 5-7).
HISTORY = 5
#: Active-set rows the preconditioner eliminates exactly at most (a tool's contacts; more: projected only).
ELIMINATED_ROWS = 256


def attachments(contacts) -> tuple[np.ndarray, np.ndarray, float]:
    """(indices (K,) int64, targets (K, 2) [m], stiffness 1/compliance [N/m]) of the particles held to the tool
    this step, from ``contacts.attach_idx``, ``attach_target``, ``attach_stiffness`` (none: empty, 0)."""
    idx = getattr(contacts, "attach_idx", None)
    k = float(getattr(contacts, "attach_stiffness", 0.0) or 0.0)
    if idx is None or len(idx) == 0 or k <= 0.0:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 2)), 0.0
    return (np.ascontiguousarray(idx, dtype=np.int64),
            np.ascontiguousarray(contacts.attach_target, dtype=np.float64).reshape(-1, 2), k)


class MaterialSolve:
    """The material's step minimised (:meth:`minimise`, ``method: quasi_newton``) and every material step's
    convergence report (:meth:`sweep_residual` for the sweeps), with their workspaces and factors.

    A result is a function of the step's inputs alone: the factor is chosen by dt (with the particles a line or
    a wall holds in the rest shape), never by the steps before (so a replay, a rollout from a snapshot or a pool worker
    gives the live run's bits). The tool's contacts are not stiffened in the factor: their set changes from step
    to step as the tool moves, and a factor per step costs more than the iterations it saves (measured on the
    punch: 10.6 ms against 3.5 ms per step at 1,071 particles).
    """

    def __init__(self, model, tris: np.ndarray, elastic: np.ndarray) -> None:
        n = model.n_particles
        self.model = model
        self.params = model.params
        self.tris = tris
        self.elastic = elastic
        self.kind = np.zeros(n, dtype=np.int8)
        self.normal = np.zeros((n, 2))
        self.vectors = np.zeros((5, 2 * n))  # g, g_new, d, x_old, z
        self.out = np.zeros(3)
        self.x_pred_h = np.zeros((n, 2))
        """The last substep's prediction (the sweeps' report)."""
        self.guess = np.zeros((n, 2))
        self.scratch = np.zeros((n, 2))
        self.hist_s = np.zeros((HISTORY, 2 * n))
        self.hist_y = np.zeros((HISTORY, 2 * n))
        self.hist_rho = np.zeros(HISTORY)
        self.alpha = np.zeros(HISTORY)
        cap = ELIMINATED_ROWS
        self.wcol = np.zeros((cap, 2 * n))
        self.wkey = np.full((cap, 3), -1.0)
        self.cur_slot = np.zeros(cap, dtype=np.int64)
        self.cur_i = np.zeros(cap, dtype=np.int64)
        self.cur_n = np.zeros((cap, 2))
        self.smat = np.zeros((cap, cap))
        self.sinv = np.zeros((cap, cap))
        self.used = np.zeros(cap, dtype=np.bool_)
        self.b = np.zeros(2 * n)
        self.t = np.zeros(cap)
        self.in_factor = np.zeros(n, dtype=np.bool_)
        self.released_once = np.zeros(n, dtype=np.int8)
        self.turns = np.zeros(n, dtype=np.int8)
        self._columns_of: Prefactor | None = None
        self.factors: dict[tuple[float, bytes], Prefactor] = {}
        self.rest_lines = self.line_set(np.asarray(model.particle_q0), np.asarray(model.particle_inv_mass))
        """The free particles at or past a line or a wall in the rest shape, and their normals: in the factor."""
        self.refactors = 0
        """How many times a matrix was factored (the first, a new dt, a new set of held particles)."""

    def prefactor(self, dt: float, held: np.ndarray | None = None, normal: np.ndarray | None = None) -> Prefactor:
        """A0 = M + dt^2 K0 for this dt with ``held`` stiffened along ``normal``; the last FACTORS_KEPT kept."""
        key = (float(dt), active_key(held, normal))
        pre = self.factors.pop(key, None)
        if pre is None:
            m = self.model
            pre = Prefactor(m.particle_q0, self.tris, self.elastic, m.particle_mass, m.particle_inv_mass, dt, held,
                            normal)
            self.refactors += 1
        self.factors[key] = pre  # most recent last
        while len(self.factors) > FACTORS_KEPT:
            self.factors.pop(next(iter(self.factors)))
        return pre

    def line_set(self, x: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Free particles at or past a boundary line or a wall at ``x``, and their normals (+-y)."""
        p = self.params
        y = x[:, 1]
        up = np.zeros(len(y), dtype=bool)
        down = np.zeros(len(y), dtype=bool)
        for line in (p.boundary_y_bottom, p.wall_y_bottom):
            if not math.isnan(line):
                up |= y <= line
        for line in (p.boundary_y_top, p.wall_y_top):
            if not math.isnan(line):
                down |= y >= line
        idx = np.flatnonzero((w != 0.0) & (up | down))
        normal = np.zeros((idx.size, 2))
        normal[:, 1] = np.where(up[idx], 1.0, -1.0)
        return idx, normal

    def minimise(self, x0: np.ndarray, v0: np.ndarray, x: np.ndarray, x_pred: np.ndarray, w: np.ndarray, dt: float,
                 damp: float, candidates: np.ndarray, surface_edges: np.ndarray, shape0: np.ndarray,
                 shape1: np.ndarray, side_tol: float, contact_dx: np.ndarray, contacts) -> tuple[int, float]:
        """One step's minimiser into ``x`` (x* in ``x_pred``, effective inverse masses ``w``); (iterations,
        estimated relative error). Starts from x_n + dt damp v_n: at rest, the answer."""
        p = self.params
        m = self.model
        np.copyto(x, x_pred)
        np.multiply(v0, dt * damp, out=self.guess)
        self.guess += x0
        # the factor is A0 for this dt with the particles that rest on a line or a wall (from the rest shape: a
        # function of the model alone) stiffened along their normals; the others the tool, a line or a wall holds
        # are the active set's rows, eliminated on it (their columns kept), so a set that changes as the tissue
        # settles costs a few solves, not a factorisation (40 ms at 2,748 particles)
        pre = self.prefactor(dt, *self.rest_lines)
        if pre is not self._columns_of:  # the kept columns A0^-1 c belong to the factor they were solved with
            self.wkey.fill(-1.0)
            self._columns_of = pre
        self.in_factor.fill(False)
        self.in_factor[self.rest_lines[0]] = True
        g, g_new, d, x_old, z = self.vectors
        quasi_newton_solve(
            x, x0, x_pred, m.particle_mass, w, self.tris, self.elastic, dt * dt, p.gravity, pre.l_ptr, pre.l_idx,
            pre.l_val, pre.u_ptr, pre.u_idx, pre.u_val, pre.perm_r, pre.perm_c, self.hist_s, self.hist_y,
            self.hist_rho, self.alpha, self.kind, self.normal, candidates, surface_edges, shape0, shape1, side_tol,
            self.scratch, contact_dx, p.boundary_y_top, p.boundary_y_bottom, p.wall_y_bottom, p.wall_y_top,
            *attachments(contacts), p.solve_tolerance, p.iterations, self.guess, g, g_new, d, x_old, z, self.out,
            m.particle_inv_mass, self.in_factor, self.wcol, self.wkey, self.cur_slot, self.cur_i, self.cur_n,
            self.smat, self.sinv, self.used, self.b, self.t, self.released_once, self.turns)
        return int(self.out[0]), float(self.out[1])

    def sweep_residual(self, x: np.ndarray, x_start: np.ndarray, w: np.ndarray, h: float,
                       contact_dx: np.ndarray | None, contacts) -> float:
        """The sweeps' last substep (of length h, from ``x_start``, prediction :attr:`x_pred_h`) as
        :func:`substep_residual` measures it."""
        p = self.params
        m = self.model
        pre = self.prefactor(h)
        if contact_dx is None:
            self.scratch.fill(0.0)
            contact_dx = self.scratch
        g, z, e = self.vectors[:3]
        return float(substep_residual(
            x, x_start, self.x_pred_h, m.particle_mass, w, self.tris, self.elastic, h * h, contact_dx,
            p.boundary_y_top, p.boundary_y_bottom, p.wall_y_bottom, p.wall_y_top, *attachments(contacts),
            pre.l_ptr, pre.l_idx, pre.l_val, pre.u_ptr, pre.u_idx, pre.u_val, pre.perm_r, pre.perm_c, self.kind,
            g, z, e))
