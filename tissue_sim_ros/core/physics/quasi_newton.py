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

The solve is L-BFGS (Liu, Bouaziz and Kavan 2017, five pairs) whose initial
inverse Hessian is a fixed, prefactored matrix A0 = M + dt^2 K0, K0 the exact
Hessian of the strain energy at the rest shape
(:mod:`~tissue_sim_ros.core.physics.prefactor`), with a backtracking (Armijo)
line search. Measured (``tissue-sim bench material-speed``): one iteration
per step at rest and 3-8 while the tissue moves, on meshes of 700 to 8,000
particles: the count does not grow with the mesh, unlike Gauss-Seidel sweeps.

Contacts, lines and walls are an active set
(:mod:`~tissue_sim_ros.core.physics.active_set`): after each update the tool's
projection, the lines and the walls put back every particle that went past
them, and such a particle is held along the direction it was pushed (its
normal), sliding along the surface (frictionless), until the solve has
converged with that set and its force points away from the surface, when it
is released (once per step). The preconditioner eliminates the held rows
exactly. At the end the tool's force on a touching particle is the normal
part of its gradient over dt^2: what the Simulation's reaction expects as
``contact_dx = (g . n) n / m``. Particles with zero effective inverse mass
(pinned, held by the paper contact, asleep) stay at x*.

Convergence, reported on every step (``SolveInfo.solve_residual``, the
``StepReport`` and ``/diagnostics``): the estimated relative error of the
step, the last quasi-Newton direction against the step's motion ||x - x_n||
(the optimality residual grad E preconditioned into a position, so it reads as
"how far from the exact step, as a fraction of the step"; a motion below 1e-6
of the tissue's size, RMS per particle, counts as that much). The loop stops when it falls to
``solve_tolerance`` with no change of the active set, or after ``iterations``
iterations; ``solve_converged`` says which. It starts from x_n + dt damp v_n
(the motion continued, gravity aside): at rest that is the answer, and a
resting tissue costs one iteration.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .active_set import (  # noqa: F401
    CORNER,
    EDGE,
    FIXED,
    FREE,
    LINE,
    TOOL,
    TOUCH_EPS,
    apply_preconditioner,
    build_constraints,
    enforce_bounds,
    project_vector,
    touching,
)
from .material import neo_hookean_element
from .prefactor import Prefactor, active_key, apply_inverse  # noqa: F401

#: Backtracking halvings of the line search at most.
MAX_HALVINGS = 12
#: Armijo constant of the line search.
ARMIJO = 1e-4
#: Motion below this fraction of the tissue's size (RMS per particle) counts as that much when a step's error is
#: measured against its motion: a resting tissue's step is judged to 1e-6 of its size, not to nanometres.
FLOOR_REL = 1e-6


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
                       b_unit: np.ndarray, t: np.ndarray, released_once: np.ndarray, turns: np.ndarray,
                       cur_c: np.ndarray, floor_rms: float) -> None:
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
                               perm_c, wcol, wkey, cur_slot, cur_i, cur_n, smat, sinv, used, b_unit, z,
                               attach_idx, 1.0 / (dt2 * attach_k) if attach_k > 0.0 else 0.0, cur_c)
    floor = floor_rms * math.sqrt(max(n_free, 1))
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
        for i in range(n):  # (z is free until the next direction: x as the line search left it)
            z[2 * i] = x[i, 0]
            z[2 * i + 1] = x[i, 1]
        joined = enforce_bounds(x, x_start, w, kind, normal, candidates, surface_edges, shape0, shape1, side_tol,
                                scratch, y_top, y_bottom, wall_bottom, wall_top, turns)
        moved_back = False
        for i in range(n):
            if x[i, 0] != z[2 * i] or x[i, 1] != z[2 * i + 1]:
                moved_back = True
                break
        if moved_back:  # else f_new and g_new are the line search's last evaluation, at this x
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
                                       perm_r, perm_c, wcol, wkey, cur_slot, cur_i, cur_n, smat, sinv, used, b_unit, z,
                               attach_idx, 1.0 / (dt2 * attach_k) if attach_k > 0.0 else 0.0, cur_c)
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
                     perm_c: np.ndarray, kind: np.ndarray, g: np.ndarray, z: np.ndarray, e: np.ndarray,
                     floor_rms: float) -> float:
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
    return _norm(e) / max(_motion(x, x_start, w), floor_rms * math.sqrt(max(n_free, 1)))


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
        self.cur_c = np.zeros(cap)
        self.smat = np.zeros((cap, cap))
        self.sinv = np.zeros((cap, cap))
        self.used = np.zeros(cap, dtype=np.bool_)
        self.b = np.zeros(2 * n)
        self.t = np.zeros(cap)
        self.released_once = np.zeros(n, dtype=np.int8)
        self.turns = np.zeros(n, dtype=np.int8)
        self._columns_of: Prefactor | None = None
        self.factors: dict[tuple[float, bytes], Prefactor] = {}
        q0 = np.asarray(model.particle_q0)
        size = float(np.hypot(*np.ptp(q0, axis=0))) if len(q0) else 0.0
        self.floor_rms = max(FLOOR_REL * size, 1e-12)
        """Motion below this RMS per particle [m] counts as this much when a step's error is measured against its
        motion: FLOOR_REL of the rest shape's diagonal (0.1 um for a 10 cm tissue)."""
        self.rest_lines = self.line_set(np.asarray(model.particle_q0), np.asarray(model.particle_inv_mass))
        """The free particles at or past a line or a wall in the rest shape, and their normals: in the factor."""
        self.in_factor = np.zeros(n, dtype=np.bool_)
        self.in_factor[self.rest_lines[0]] = True
        """(N,) True for those particles: the factor holds them, so the active set needs no rows for them."""
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

    def step_factor(self, dt: float) -> Prefactor:
        """The factor a step of ``dt`` solves with, its kept columns made its own.

        It is A0 for this dt with the particles that rest on a line or a wall (from the rest shape: a function of
        the model alone) stiffened along their normals; the others the tool, a line or a wall holds are the active
        set's rows, eliminated on it (their columns kept), so a set that changes as the tissue settles costs a few
        solves, not a factorisation (40 ms at 2,748 particles)."""
        pre = self.prefactor(dt, *self.rest_lines)
        if pre is not self._columns_of:  # the kept columns A0^-1 c belong to the factor they were solved with
            self.wkey.fill(-1.0)
            self._columns_of = pre
        return pre

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
        pre = self.step_factor(dt)
        g, g_new, d, x_old, z = self.vectors
        quasi_newton_solve(
            x, x0, x_pred, m.particle_mass, w, self.tris, self.elastic, dt * dt, p.gravity, pre.l_ptr, pre.l_idx,
            pre.l_val, pre.u_ptr, pre.u_idx, pre.u_val, pre.perm_r, pre.perm_c, self.hist_s, self.hist_y,
            self.hist_rho, self.alpha, self.kind, self.normal, candidates, surface_edges, shape0, shape1, side_tol,
            self.scratch, contact_dx, p.boundary_y_top, p.boundary_y_bottom, p.wall_y_bottom, p.wall_y_top,
            *attachments(contacts), p.solve_tolerance, p.iterations, self.guess, g, g_new, d, x_old, z, self.out,
            m.particle_inv_mass, self.in_factor, self.wcol, self.wkey, self.cur_slot, self.cur_i, self.cur_n,
            self.smat, self.sinv, self.used, self.b, self.t, self.released_once, self.turns, self.cur_c,
            self.floor_rms)
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
            g, z, e, self.floor_rms))
