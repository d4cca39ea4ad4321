"""One compiled call per step: each sweeping solver's whole step (prediction, substeps, sweeps, velocities,
boundary lines, residual) as one numba function, and the step's post-solve numbers (finite check, energy terms,
inverted triangles) as another.

:class:`~tissue_sim_ros.core.physics.solvers.constraint.ConstraintSolver` steps with :func:`constraint_step`
(PBD and XPBD on distance and area constraints; Gauss-Seidel serial, partitioned or coloured, Jacobi, the
authors' violated-constraint Jacobi), :class:`~tissue_sim_ros.core.physics.solvers.material_xpbd.MaterialXPBDSolver`
with :func:`material_xpbd_step`; the minimisation's step is
:func:`~tissue_sim_ros.core.physics.quasi_newton.quasi_newton_step`. They share the prediction and the substep's
start (:func:`start_step`, :func:`start_substep`) and the substep's end (:func:`end_substep`). The tool's shape per
substep (Python's ``math.hypot`` in :func:`~tissue_sim_ros.core.physics.solvers.base.substep_shapes`) is computed
by the caller, ``substeps + 1`` rows.

The arguments come as bundles (tuples of arrays and scalars, unpacked at the top of each kernel): numba's
dispatcher types a tuple of arrays in C, so a bundle costs what its arrays would as separate arguments, and a
kernel's signature names what it reads. The layouts are documented where each bundle is made (the solvers'
constructors and ``step``).

Every kernel a Python caller enters is compiled ``nogil=True``: while a step runs its compiled calls the node's
marker thread can encode on the other core instead of waiting for the GIL. Loop indices are unsigned where they
only count (``numba.uint32``): no sign checks in the wrapped indexing. The NumPy twin of the steps is the
reference loop in ``test/naive.py`` (``solver_step_reference``: the same building blocks, called one at a time
from Python), and :func:`finish_step`'s is NumPy's finite check with ``naive.energy_terms`` and
``count_inverted``.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, uint32

from .attach import project_attachments
from .energy import step_energy
from .kernels import (
    apply_boundary_lines,
    constraint_residual,
    count_inverted,
    hold_displaced,
    place_held,
    predict,
    update_velocity,
)
from .material import jacobi_relaxation_elements, material_gauss_seidel, material_jacobi
from .sweeps import gauss_seidel_iterations, jacobi_iterations, jacobi_relaxation
from .violated_jacobi import violated_jacobi_iterations
from .walls import apply_walls

#: Sweep strategies of :func:`constraint_step` (the Gauss-Seidel modes are ``sweeps.GS_*``).
SWEEP_JACOBI = 3
SWEEP_VIOLATED = 4


@njit(cache=True, nogil=True, inline="always")
def _copy(dst: np.ndarray, src: np.ndarray) -> None:
    for i in range(uint32(dst.shape[0])):
        dst[i, 0] = src[i, 0]
        dst[i, 1] = src[i, 1]


@njit(cache=True, nogil=True)
def predict_step(state: tuple, pred: tuple, timing: tuple, bounds: tuple) -> None:
    """The full-step prediction x* (the energy's reference) with the paper contact's held particles displaced and
    held (``w`` zero there), then the walls.

    ``state`` = (x0, v0, x, v) (N, 2) each: the step's start in, its end out; ``pred`` = (inv_mass (N,), w (N,)
    out, x_pred (N, 2) out, x_start (N, 2), held_idx (K,) int32, held_dx (K, 2) [m]); ``timing`` = (dt [s],
    substeps, gravity [m/s^2], damp over dt, damp over a substep); ``bounds`` = (walls, wall_y_bottom,
    wall_y_top, y_top, y_bottom) [m] (NaN: none).
    """
    x0, v0, _x, _v = state
    inv_mass, w, x_pred, _x_start, held_idx, held_dx = pred
    dt, _n_sub, gravity, damp_dt, _damp_h = timing
    walls, wall_bottom, wall_top, _y_top, _y_bottom = bounds
    predict(x0, v0, inv_mass, dt, gravity, damp_dt, x_pred)
    hold_displaced(x_pred, inv_mass, held_idx, held_dx, 1.0, w)
    if walls:
        apply_walls(x_pred, wall_bottom, wall_top)


@njit(cache=True, nogil=True)
def start_step(state: tuple, pred: tuple, timing: tuple, bounds: tuple) -> None:
    """:func:`predict_step`, then ``x, v`` = ``x0, v0`` (the substeps start there)."""
    predict_step(state, pred, timing, bounds)
    x0, v0, x, v = state
    _copy(v, v0)
    _copy(x, x0)


@njit(cache=True, nogil=True)
def start_substep(sub: int, state: tuple, pred: tuple, timing: tuple, bounds: tuple) -> None:
    """Substep ``sub``'s start: ``x_start`` = x, then its prediction (the full step's x* with one substep; with
    several, from the substep's start over h, the held particles at (sub + 1) / substeps of their way), the
    walls."""
    x0, _v0, x, v = state
    inv_mass, _w, x_pred, x_start, held_idx, _held_dx = pred
    dt, n_sub, gravity, _damp_dt, damp_h = timing
    walls, wall_bottom, wall_top, _y_top, _y_bottom = bounds
    _copy(x_start, x)
    if n_sub == 1:
        _copy(x, x_pred)
    else:
        predict(x_start, v, inv_mass, dt / n_sub, gravity, damp_h, x)
        place_held(x, x0, x_pred, inv_mass, held_idx, (sub + 1) / n_sub)
        if walls:
            apply_walls(x, wall_bottom, wall_top)


@njit(cache=True, nogil=True)
def end_substep(state: tuple, pred: tuple, h: float, bounds: tuple) -> None:
    """v = (x - x_start) / h, then the boundary lines clamp and stop the particles past them."""
    _x0, _v0, x, v = state
    inv_mass, _w, _x_pred, x_start, _held_idx, _held_dx = pred
    _walls, _wall_bottom, _wall_top, y_top, y_bottom = bounds
    update_velocity(x, x_start, h, v)
    apply_boundary_lines(x, v, inv_mass, y_top, y_bottom)


@njit(cache=True, nogil=True)
def _substep_tool(sub: int, tool: tuple, x_start: np.ndarray) -> tuple:
    """The tool of substep ``sub`` as ``sweeps.tool_contact`` takes it: the shapes at its start and end (rows of
    ``shapes``) copied into ``shape0``, ``shape1``; empty candidates and edges without projection contact."""
    candidates, surface_edges, edge_side_tol, shapes, shape0, shape1, contact_dx = tool
    if shapes.shape[0] > 0:
        for k in range(uint32(7)):
            shape0[k] = shapes[sub, k]
            shape1[k] = shapes[sub + 1, k]
    return (x_start, candidates, shape0, shape1, contact_dx, surface_edges, edge_side_tol)


@njit(cache=True, nogil=True)
def _constraint_iterations(x: np.ndarray, pred: tuple, sets: tuple, sweep: tuple, substep_tool: tuple,
                           attach: tuple, bounds: tuple) -> None:
    """One substep's sweeps of :func:`constraint_step`'s strategy (its bundles)."""
    inv_mass, w, _x_pred, _x_start, _held_idx, _held_dx = pred
    edge_set, tri_set, _res_set, signed = sets
    mode, iterations, coeffs, mults, jac, violated = sweep
    stiffness_relaxation, relaxation_scale, node_sum, particle_scale, dx_acc = jac
    attach_idx, attach_target, alpha_attach, lam_attach = attach
    walls, wall_bottom, wall_top, _y_top, _y_bottom = bounds
    attached = attach_idx.shape[0] > 0
    if mode == SWEEP_VIOLATED:
        # the authors' Jacobi: weights from the model's inverse masses (held particles keep theirs), only the
        # particles free this step move; the walls after every iteration (inside); the attachments once after
        tol_e, tol_a, dxa, ns, na = violated
        constraints = (edge_set[0], edge_set[1], coeffs[0], tol_e, tri_set[0], tri_set[1], coeffs[2], tol_a, signed)
        violated_jacobi_iterations(x, inv_mass, w, constraints, iterations, (wall_bottom, wall_top),
                                   (dx_acc, dxa, ns, na), substep_tool)
        if attached:
            project_attachments(x, w, attach_idx, attach_target, alpha_attach, lam_attach)
        return
    if mode == SWEEP_JACOBI and stiffness_relaxation:
        jacobi_relaxation(x, w, edge_set[0], coeffs[1], tri_set[0], coeffs[3], signed, relaxation_scale, node_sum,
                          mults[2], mults[3])
    # with walls or attachments: one iteration per kernel call, the attachments and walls after each
    n_calls = iterations if (walls or attached) else 1
    per_call = 1 if (walls or attached) else iterations
    for _ in range(n_calls):
        if mode == SWEEP_JACOBI:
            jacobi_iterations(x, w, edge_set, tri_set, substep_tool, coeffs, mults, signed, per_call,
                              particle_scale, dx_acc)
        else:
            gauss_seidel_iterations(x, w, edge_set, tri_set, substep_tool, coeffs, mults, signed, per_call, mode,
                                    True)
        if attached:
            project_attachments(x, w, attach_idx, attach_target, alpha_attach, lam_attach)
        if walls:
            apply_walls(x, wall_bottom, wall_top)


@njit(cache=True, nogil=True)
def constraint_step(state: tuple, pred: tuple, timing: tuple, bounds: tuple, sets: tuple, sweep: tuple,
                    tool: tuple, attach: tuple) -> float:
    """One step of the constraint methods; returns the residual (RMS of C / rest size over every constraint).

    ``state``, ``pred``, ``timing``, ``bounds``: :func:`start_step`. ``sets`` = (edge_set, tri_set, res_set,
    signed): the active constraints in solve order (``sweeps.gauss_seidel_iterations``' bundles; empty when a
    type is off) and all of them (edges, rest, triangles, rest areas) for the residual. ``sweep`` = (mode,
    iterations, coeffs (k_e, alpha_e, k_t, alpha_t), mults (lam_e, lam_t, omega_e, omega_t), jac
    (stiffness_relaxation, relaxation scale, node_sum (N,), particle_scale (N,), dx_acc (N, 2)), violated (tol_e,
    tol_a, dxa (N, 2), ns (N,), na (N,))): mode ``sweeps.GS_*``, :data:`SWEEP_JACOBI` or :data:`SWEEP_VIOLATED`.
    ``tool`` = (candidates (C,) int32, surface_edges (K, 2) int32, edge_side_tol [m], shapes (substeps + 1, 7)
    ((0, 7): no projection contact), shape0 (7,), shape1 (7,), contact_dx (N, 2) summed corrections out).
    ``attach`` = (attach_idx (K,) int64, attach_target (K, 2) [m], compliance / h^2, multipliers (K, 2)): the
    grasp (``core/physics/attach.py``), after the tool in every iteration; K = 0: none.
    """
    start_step(state, pred, timing, bounds)
    x = state[2]
    x_start = pred[3]
    mults = sweep[3]
    lam_attach = attach[3]
    dt, n_sub = timing[0], timing[1]
    h = dt / n_sub
    for sub in range(n_sub):
        start_substep(sub, state, pred, timing, bounds)
        mults[0][:] = 0.0
        mults[1][:] = 0.0
        lam_attach[:] = 0.0
        _constraint_iterations(x, pred, sets, sweep, _substep_tool(sub, tool, x_start), attach, bounds)
        end_substep(state, pred, h, bounds)
    edges, rest, tris, area0 = sets[2]
    return constraint_residual(x, edges, rest, tris, area0, sets[3])


@njit(cache=True, nogil=True)
def material_xpbd_step(state: tuple, pred: tuple, timing: tuple, bounds: tuple, elements: tuple, sweep: tuple,
                       tool: tuple, attach: tuple, x_pred_h: np.ndarray) -> float:
    """One step of the material's elements solved by XPBD sweeps (Gauss-Seidel or Jacobi); returns the residual of
    the model's constraints (as :func:`constraint_step`). The last substep's prediction is copied into
    ``x_pred_h`` (the step's convergence report measures that substep).

    ``state``, ``pred``, ``timing``, ``bounds``, ``tool``, ``attach``: :func:`constraint_step`. ``elements`` =
    (triangles (T, 3) int32 in solve order, their packed rest data (T, 6), offsets, partitioned, res_set, signed)
    with res_set as in :func:`constraint_step`'s ``sets``. ``sweep`` =
    (jacobi, stiffness_relaxation, iterations, relaxation, relaxation scale, multipliers (T, 3), omega (T, 2),
    node_sum (N,), dx_acc (N, 2)). The attachments run once per iteration, after the tool; the walls after each
    substep's iterations.
    """
    tris, elastic, offsets, partitioned, res_set, signed = elements
    jacobi, stiffness_relaxation, iterations, relaxation, relaxation_scale, lam_m, omega_m, node_sum, dx_acc = sweep
    attach_idx, attach_target, alpha_attach, lam_attach = attach
    walls, wall_bottom, wall_top, _y_top, _y_bottom = bounds
    w = pred[1]
    x_start = pred[3]
    start_step(state, pred, timing, bounds)
    x = state[2]
    dt, n_sub = timing[0], timing[1]
    h = dt / n_sub
    inv_h2 = 1.0 / (h * h)
    attached = attach_idx.shape[0] > 0
    n_calls, per_call = (iterations, 1) if attached else (1, iterations)
    for sub in range(n_sub):
        start_substep(sub, state, pred, timing, bounds)
        lam_m[:] = 0.0
        lam_attach[:] = 0.0
        substep_tool = _substep_tool(sub, tool, x_start)
        if sub == n_sub - 1:
            _copy(x_pred_h, x)
        if jacobi:
            if stiffness_relaxation:
                jacobi_relaxation_elements(x, w, tris, elastic, inv_h2, relaxation_scale, node_sum, omega_m)
            else:
                omega_m[:] = relaxation
        for _ in range(n_calls):
            if jacobi:
                material_jacobi(x, w, tris, elastic, inv_h2, lam_m, omega_m, per_call, dx_acc, substep_tool)
            else:
                material_gauss_seidel(x, w, tris, elastic, inv_h2, lam_m, offsets, partitioned, per_call,
                                      substep_tool)
            if attached:
                project_attachments(x, w, attach_idx, attach_target, alpha_attach, lam_attach)
        if walls:
            apply_walls(x, wall_bottom, wall_top)
        end_substep(state, pred, h, bounds)
    edges, rest, res_tris, area0 = res_set
    return constraint_residual(x, edges, rest, res_tris, area0, signed)


@njit(cache=True, nogil=True)
def all_finite(a: np.ndarray, b: np.ndarray) -> bool:
    """True when every entry of the two (N, 2) arrays is finite."""
    for i in range(uint32(a.shape[0])):
        if not (math.isfinite(a[i, 0]) and math.isfinite(a[i, 1]) and math.isfinite(b[i, 0])
                and math.isfinite(b[i, 1])):
            return False
    return True


@njit(cache=True, nogil=True)
def finish_step(x: np.ndarray, v: np.ndarray, x_pred: np.ndarray, terms: tuple, dt: float, attach: tuple,
                out: tuple) -> tuple[bool, int]:
    """After a solve: (all of ``x`` and ``v`` finite, triangles with signed area <= 0 in ``x``); when finite, every
    energy term into ``out`` (:func:`~tissue_sim_ros.core.physics.energy.step_energy`, whose ``terms``,
    ``attach`` and ``out`` these are)."""
    finite = all_finite(x, v)
    if finite:
        step_energy(x, x_pred, terms, dt, attach, out)
    return finite, count_inverted(x, terms[8])
