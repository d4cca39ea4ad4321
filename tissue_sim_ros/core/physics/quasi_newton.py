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
from .kernels import apply_boundary_lines, update_velocity
from .material import neo_hookean_element
from .prefactor import Prefactor, active_key, apply_inverse  # noqa: F401
from .step_kernels import predict_step

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


# ----------------------------------------------------------------------------- the minimisation, in parts


@njit(cache=True, nogil=True)
def _release(kind: np.ndarray, normal: np.ndarray, g: np.ndarray, once: np.ndarray) -> int:
    """Free the held particles whose force points away from their surface (-g . n > 0); with ``once`` (N,) int8
    (not empty) at most once per particle and step, marked there. Returns how many were freed."""
    released = 0
    for i in range(kind.shape[0]):
        if (kind[i] == TOOL or kind[i] == LINE or kind[i] == EDGE) and (once.shape[0] == 0 or once[i] == 0):
            if -(g[2 * i] * normal[i, 0] + g[2 * i + 1] * normal[i, 1]) > 0.0:
                kind[i] = FREE
                if once.shape[0]:
                    once[i] = 1
                released += 1
    return released


@njit(cache=True, nogil=True)
def _potential(x: np.ndarray, x_pred: np.ndarray, w: np.ndarray, mat: tuple, attach: tuple, dt2: float,
               g: np.ndarray) -> float:
    """:func:`potential_and_gradient` on the solve's bundles."""
    mass, _inv_mass, tris, elastic, _in_factor = mat
    attach_idx, attach_target, attach_k = attach
    return potential_and_gradient(x, x_pred, mass, w, tris, elastic, dt2, attach_idx, attach_target, attach_k, g)


@njit(cache=True, nogil=True)
def _build(mat: tuple, factor: tuple, ws: tuple, elim: tuple, attach: tuple, dt2: float) -> int:
    """The active set's rows for the preconditioner (:func:`build_constraints` on the solve's bundles)."""
    _mass, inv_mass, _tris, _elastic, in_factor = mat
    kind, normal = ws[4], ws[5]
    z = ws[9][4]
    attach_idx, _attach_target, attach_k = attach
    return build_constraints(kind, normal, inv_mass, in_factor, factor, elim, ws[10], z, attach_idx,
                             1.0 / (dt2 * attach_k) if attach_k > 0.0 else 0.0)


@njit(cache=True, nogil=True)
def _start(x: np.ndarray, x_pred: np.ndarray, w: np.ndarray, guess: np.ndarray, mat: tuple, lines: tuple,
           tool: tuple, attach: tuple, ws: tuple, opts: tuple) -> tuple[float, float, int]:
    """The solve's start: the active set (FIXED where ``w`` is 0; the particles on the tool's surface, then those
    the guess puts past the tool, a line or a wall), x = the guess, the load (the gradient at x*, gravity's
    dt^2 m g, or what the contacts carry at the start) and the gradient at x, projected. Returns (E(x), load,
    free particles)."""
    _hist_s, _hist_y, _hist_rho, _alpha_buf, kind, normal, released_once, turns, scratch, vectors, _b, _out = ws
    g = vectors[0]
    dt2, gravity, _tolerance, _max_iterations, _floor_rms = opts
    _x_start, candidates, _shape0, shape1, contact_dx, _surface_edges, _side_tol = tool
    mass = mat[0]
    n = x.shape[0]
    n_free = 0
    for i in range(n):
        released_once[i] = 0
        turns[i] = 0
        kind[i] = FIXED if w[i] == 0.0 else FREE
        if w[i] != 0.0:
            n_free += 1
            x[i, 0] = guess[i, 0]
            x[i, 1] = guess[i, 1]
        normal[i, 0] = 0.0
        normal[i, 1] = 0.0
        contact_dx[i, 0] = 0.0
        contact_dx[i, 1] = 0.0
    if candidates.shape[0] > 0:
        touching(x, kind, normal, candidates, shape1, TOUCH_EPS)
    enforce_bounds(x, w, kind, normal, tool, lines, scratch, turns)
    # the load: the gradient at x* (inertia is zero there: strain + attachments), or gravity's dt^2 m g
    _potential(x_pred, x_pred, w, mat, attach, dt2, g)
    project_vector(g, kind, normal)
    load = _norm(g)
    grav = 0.0
    for i in range(n):
        if w[i] != 0.0:
            grav += (mass[i] * dt2 * gravity) ** 2
    load = max(load, math.sqrt(grav))
    f = _potential(x, x_pred, w, mat, attach, dt2, g)
    # ... or what the contacts carry at the start (the gradient before their normal parts are taken out)
    load = max(load, _norm(g))
    _release(kind, normal, g, released_once[:0])  # a particle whose force points away from its surface
    project_vector(g, kind, normal)
    return f, load, n_free


@njit(cache=True, nogil=True)
def _direction(factor: tuple, ws: tuple, elim: tuple, n_rows: int, n_hist: int, head: int) -> tuple[float, int]:
    """The quasi-Newton direction d = -H g (two-loop recursion, H0 = A0^-1 on the active set's null space), or,
    when that is not a descent direction (a history spoilt by the active set), the preconditioned gradient with
    the history dropped. Returns (slope g . d, pairs kept); a slope >= 0 means no descent is left."""
    hist_s, hist_y, hist_rho, alpha_buf, kind, normal, _once, _turns, _scratch, vectors, _b, _out = ws
    g, g_new, d, _x_old, z = vectors
    n_dof = g.shape[0]
    m_hist = hist_rho.shape[0]
    for k in range(n_dof):
        d[k] = g[k]
    for jj in range(n_hist):
        j = (head - 1 - jj + 2 * m_hist) % m_hist
        a = hist_rho[j] * _dot(hist_s[j], d)
        alpha_buf[j] = a
        for k in range(n_dof):
            d[k] -= a * hist_y[j, k]
    apply_preconditioner(factor, elim, d, z, g_new, n_rows)
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
        apply_preconditioner(factor, elim, g, z, d, n_rows)
        project_vector(d, kind, normal)
        for k in range(n_dof):
            d[k] = -d[k]
        slope = _dot(g, d)
    return slope, n_hist


@njit(cache=True, nogil=True)
def _line_search(x: np.ndarray, x_pred: np.ndarray, w: np.ndarray, mat: tuple, attach: tuple, ws: tuple,
                 dt2: float, f: float, slope: float) -> float:
    """Backtracking (Armijo) along d from x (kept in x_old): x moved, E there returned, its gradient in g_new."""
    _g, g_new, d, x_old, _z = ws[9]
    n = x.shape[0]
    for i in range(n):
        x_old[2 * i] = x[i, 0]
        x_old[2 * i + 1] = x[i, 1]
    step = 1.0
    f_new = f
    for _ in range(MAX_HALVINGS):
        for i in range(n):
            x[i, 0] = x_old[2 * i] + step * d[2 * i]
            x[i, 1] = x_old[2 * i + 1] + step * d[2 * i + 1]
        f_new = _potential(x, x_pred, w, mat, attach, dt2, g_new)
        if f_new <= f + ARMIJO * step * slope:
            break
        step *= 0.5
    return f_new


@njit(cache=True, nogil=True)
def _bounds_after(x: np.ndarray, x_pred: np.ndarray, w: np.ndarray, mat: tuple, lines: tuple, tool: tuple,
                  attach: tuple, ws: tuple, dt2: float, f_new: float) -> tuple[float, int]:
    """The contacts after a line search: a particle that went past the tool, a line or a wall joins the active
    set (always), and E and its gradient are taken again where that moved one. Returns (E(x), joined)."""
    _hs, _hy, _hr, _ab, kind, normal, _once, turns, scratch, vectors, _b, _out = ws
    g_new, z = vectors[1], vectors[4]
    n = x.shape[0]
    for i in range(n):  # (z is free until the next direction: x as the line search left it)
        z[2 * i] = x[i, 0]
        z[2 * i + 1] = x[i, 1]
    joined = enforce_bounds(x, w, kind, normal, tool, lines, scratch, turns)
    moved_back = False
    for i in range(n):
        if x[i, 0] != z[2 * i] or x[i, 1] != z[2 * i + 1]:
            moved_back = True
            break
    if moved_back:  # else f_new and g_new are the line search's last evaluation, at this x
        f_new = _potential(x, x_pred, w, mat, attach, dt2, g_new)
    return f_new, joined


@njit(cache=True, nogil=True)
def _contact_push(x: np.ndarray, x_pred: np.ndarray, w: np.ndarray, mat: tuple, tool: tuple, attach: tuple,
                  ws: tuple, dt2: float) -> None:
    """The tool's push on each touching particle: the normal part of its gradient (all of it at a corner), as a
    PBD correction (g . n) n / m, into the tool bundle's ``dx_accum``."""
    _x_start, candidates, _shape0, _shape1, contact_dx, surface_edges, _side_tol = tool
    if candidates.shape[0] == 0 and surface_edges.shape[0] == 0:
        return
    kind, normal = ws[4], ws[5]
    g_new = ws[9][1]
    mass = mat[0]
    _potential(x, x_pred, w, mat, attach, dt2, g_new)
    for i in range(x.shape[0]):
        if kind[i] == TOOL or kind[i] == EDGE:
            s = g_new[2 * i] * normal[i, 0] + g_new[2 * i + 1] * normal[i, 1]
            if s > 0.0:
                contact_dx[i, 0] = s * normal[i, 0] / mass[i]
                contact_dx[i, 1] = s * normal[i, 1] / mass[i]
        elif kind[i] == CORNER:  # held in both directions: the tool takes its whole gradient
            contact_dx[i, 0] = g_new[2 * i] / mass[i]
            contact_dx[i, 1] = g_new[2 * i + 1] / mass[i]


@njit(cache=True, nogil=True)
def _record(ws: tuple, j: int) -> float:
    """The history's new pair j: y = g_new - g (projected) and rho = 1 / (s . y); returns s . y (the pair is kept
    only when it is positive)."""
    hist_s, hist_y, hist_rho, _ab, kind, normal, _once, _turns, _scratch, vectors, _b, _out = ws
    g, g_new = vectors[0], vectors[1]
    for k in range(g.shape[0]):
        hist_y[j, k] = g_new[k] - g[k]
    project_vector(hist_y[j], kind, normal)
    sy = _dot(hist_s[j], hist_y[j])
    if sy > 1e-300:
        hist_rho[j] = 1.0 / sy
    return sy


@njit(cache=True, nogil=True)
def quasi_newton_solve(x: np.ndarray, x_pred: np.ndarray, w: np.ndarray, guess: np.ndarray, mat: tuple,
                       factor: tuple, lines: tuple, tool: tuple, attach: tuple, ws: tuple, elim: tuple,
                       opts: tuple) -> None:
    """One step's minimisation (module docstring), from ``guess`` (free particles; the others stay at ``x`` = x*
    on entry) to the minimiser in ``x``.

    Bundles: ``mat`` = (mass (N,) [kg], the model's inverse masses (N,) (0: pinned, an identity row of A0),
    triangles (T, 3), packed rest data (T, 6), in_factor (N,) bool: particles A0 already holds along their
    normal); ``factor``: A0's (:attr:`~tissue_sim_ros.core.physics.prefactor.Prefactor.arrays`); ``lines`` =
    (y_top, y_bottom, wall_bottom, wall_top) [m]; ``tool`` as ``sweeps.tool_contact`` takes it, with x_start the
    step's start (the tool's swept test) and dx_accum the push written at the end, (g . n) n / m per touching
    particle; ``attach`` = (attach_idx (K,) int64, targets (K, 2) [m], stiffness [N/m]); ``ws`` = (hist_s (m,
    2N), hist_y (m, 2N), hist_rho (m,), alpha (m,), kind (N,) int8, normal (N, 2), released_once (N,) int8,
    turns (N,) int8, scratch (N, 2), vectors (g, g_new, d, x_old, z) (2N,) each, b (2N,), out (3,)): the L-BFGS
    history, the active set and scratch; ``elim``: the active set's elimination (:func:`build_constraints`, kept
    across calls while the factor is the same); ``opts`` = (dt^2, gravity, tolerance, iterations at most, the
    motion floor [m] RMS). ``out``: iterations, the relative residual at the end, and the load it is relative to
    [kg m].
    """
    hist_s, _hist_y, hist_rho, _alpha_buf, kind, normal, released_once, _turns, _scratch, vectors, _b, out = ws
    g, g_new, d, x_old, _z = vectors
    dt2, _gravity, tolerance, max_iterations, floor_rms = opts
    x_start = tool[0]
    n = x.shape[0]
    m_hist = hist_rho.shape[0]
    f, load, n_free = _start(x, x_pred, w, guess, mat, lines, tool, attach, ws, opts)
    n_rows = _build(mat, factor, ws, elim, attach, dt2)
    floor = floor_rms * math.sqrt(max(n_free, 1))
    res = math.inf
    n_hist = 0
    head = 0
    it = 0
    while it < max_iterations and load > 0.0:
        slope, n_hist = _direction(factor, ws, elim, n_rows, n_hist, head)
        if slope >= 0.0:
            break
        f_new = _line_search(x, x_pred, w, mat, attach, ws, dt2, f, slope)
        f_new, joined = _bounds_after(x, x_pred, w, mat, lines, tool, attach, ws, dt2, f_new)
        # the correction just made (its free, tangential part) against the step's motion: the estimate of the
        # step's relative error (the whole direction, not the line search's fraction of it: a short step is no
        # sign of convergence)
        j = head
        for i in range(n):
            hist_s[j, 2 * i] = x[i, 0] - x_old[2 * i]
            hist_s[j, 2 * i + 1] = x[i, 1] - x_old[2 * i + 1]
        project_vector(hist_s[j], kind, normal)
        res = max(_norm(hist_s[j]), _norm(d)) / max(_motion(x, x_start, w), floor)
        it += 1
        released = 0
        if res <= tolerance and joined == 0:
            # converged with this active set: release the particles whose force points away from their surface,
            # one active-set step at a time (so the set does not flicker within the quasi-Newton updates), at
            # most once per particle and step (so it cannot cycle between a release and the projection that
            # undoes it)
            released = _release(kind, normal, g_new, released_once)
        project_vector(g_new, kind, normal)
        if joined or released:
            n_hist = 0  # the pairs belong to another set's subspace: start the history again
            n_rows = _build(mat, factor, ws, elim, attach, dt2)
        elif _record(ws, j) > 1e-300:
            head = (head + 1) % m_hist
            n_hist = min(n_hist + 1, m_hist)
        for k in range(g.shape[0]):
            g[k] = g_new[k]
        f = f_new
        if res <= tolerance and joined == 0 and released == 0:
            break
    _contact_push(x, x_pred, w, mat, tool, attach, ws, dt2)
    out[0] = it
    out[1] = res if load > 0.0 and it > 0 else 0.0
    out[2] = load


@njit(cache=True, nogil=True)
def quasi_newton_step(state: tuple, pred: tuple, timing: tuple, bounds: tuple, mat: tuple, factor: tuple,
                      tool: tuple, attach: tuple, ws: tuple, elim: tuple, solve: tuple) -> None:
    """One material step as the minimiser of its incremental potential, in one call: the prediction x* (the paper
    contact's held particles displaced and held, the walls), the minimisation from x_n + dt damp v_n (at rest,
    the answer), v = (x - x_n) / dt and the boundary lines.

    ``state``, ``pred``, ``timing``, ``bounds``: ``step_kernels.predict_step`` (``pred``'s x_start holds the
    guess here); ``mat``, ``factor``, ``tool``, ``attach``, ``ws``, ``elim``: :func:`quasi_newton_solve`;
    ``solve`` = (tolerance, iterations at most, the motion floor [m] RMS).
    """
    x0, v0, x, v = state
    inv_mass, w, x_pred, guess, _held_idx, _held_dx = pred
    dt, _n_sub, gravity, damp, _damp_h = timing
    tolerance, max_iterations, floor_rms = solve
    predict_step(state, pred, timing, bounds)
    n = x.shape[0]
    for i in range(n):
        x[i, 0] = x_pred[i, 0]
        x[i, 1] = x_pred[i, 1]
        guess[i, 0] = v0[i, 0] * (dt * damp)
        guess[i, 1] = v0[i, 1] * (dt * damp)
        guess[i, 0] += x0[i, 0]
        guess[i, 1] += x0[i, 1]
    quasi_newton_solve(x, x_pred, w, guess, mat, factor, (bounds[3], bounds[4], bounds[1], bounds[2]), tool, attach,
                       ws, elim, (dt * dt, gravity, tolerance, max_iterations, floor_rms))
    update_velocity(x, x0, dt, v)
    apply_boundary_lines(x, v, inv_mass, bounds[3], bounds[4])


@njit(cache=True, nogil=True)
def substep_residual(x: np.ndarray, x_start: np.ndarray, x_pred: np.ndarray, w: np.ndarray, mat: tuple, h2: float,
                     contact_dx: np.ndarray, lines: tuple, attach: tuple, factor: tuple, scratch: tuple,
                     floor_rms: float) -> float:
    """The estimated relative error of a (sub)step another method solved, as :func:`quasi_newton_solve` reports
    it: the correction a quasi-Newton iteration would still make, |P A0^-1 P grad E(x)|, against the step's
    motion |x - x_start| (E: the incremental potential of a step h, ``h2`` = h^2, from ``x_pred``; A0 factored
    for that h, ``factor``). ``mat``, ``lines``, ``attach``: :func:`quasi_newton_solve`'s bundles.

    P leaves out the particles the solve may not move (w == 0) and those a contact, a line or a wall held
    (``contact_dx`` nonzero, y at or past a line or wall): their gradient is balanced by a force outside E.
    ``scratch`` = (kind (N,) int8, g, z, e (2N,)).
    """
    kind, g, z, e = scratch
    y_top, y_bottom, wall_bottom, wall_top = lines
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
    _potential(x, x_pred, w, mat, attach, h2, g)
    project_vector(g, kind, x_start)
    apply_inverse(factor, g, z, e)
    project_vector(e, kind, x_start)
    return _norm(e) / max(_motion(x, x_start, w), floor_rms * math.sqrt(max(n_free, 1)))
