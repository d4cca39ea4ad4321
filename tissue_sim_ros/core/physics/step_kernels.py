"""One compiled call per step: the solver's whole step (prediction, substeps, sweeps, velocities, boundary lines,
residual) as one numba function, and the step's post-solve numbers (finite check, energy sums, inverted triangles)
as another.

:meth:`~tissue_sim_ros.core.physics.solvers.Solver.step` calls :func:`solve_step` for the constraint methods (PBD and
XPBD, Gauss-Seidel serial or Jacobi, either contact model, walls, damping modes); the material, the authors'
violated-constraint Jacobi and the parallel Gauss-Seidel keep the Python loop around the kernels
(:meth:`~tissue_sim_ros.core.physics.solvers.Solver.step_reference`, which is also the reference the tests compare
with, bit for bit: ``test/test_step_kernels.py``). The body is the reference's loop, line for line, calling the
same kernels in the same order with the same scalars, so no floating-point operation changes; what goes is the
interpreter between the kernels. One change inside: the paper's PBD sweeps skip the multipliers
(``skip_multipliers``, :func:`~tissue_sim_ros.core.physics.kernels.solve_edges_pbd_range`), which its projections
never read (alpha = 0), so the positions are the same bit for bit. The tool's shape per substep
(:meth:`~tissue_sim_ros.core.physics.solvers.Solver._interpolate_shape`, Python's ``math.hypot``) is computed by the
caller, ``substeps + 1`` rows, so its rounding is the reference's.

Every kernel a Python caller enters is compiled ``nogil=True``: while a step runs its compiled calls the node's
marker thread can encode on the other core instead of waiting for the GIL (``docs/benchmarks.md``, the node).
Loop indices are unsigned where they only count (``numba.uint32``): no sign checks in the wrapped indexing.
The NumPy twin of :func:`solve_step` is the reference step itself (``Solver.step_reference``: the same kernels,
each with its twin in ``test/naive.py``), and :func:`finish_step`'s is ``Simulation.step_reference``'s
NumPy finite check with :func:`~tissue_sim_ros.core.physics.energy.energy_terms` and ``count_inverted``.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, uint32

from .attach import project_attachments
from .kernels import (
    apply_boundary_lines,
    constraint_residual,
    count_inverted,
    energy_terms_kernel,
    hold_displaced,
    place_held,
    predict,
    update_velocity,
)
from .sweeps import gauss_seidel_iterations, jacobi_iterations, jacobi_relaxation
from .walls import apply_walls


@njit(cache=True, nogil=True)
def solve_step(x0: np.ndarray, v0: np.ndarray, x: np.ndarray, v: np.ndarray, inv_mass: np.ndarray,
               w: np.ndarray, x_pred: np.ndarray, x_start: np.ndarray, held_idx: np.ndarray, held_dx: np.ndarray,
               dt: float, n_sub: int, gravity: float, damp_dt: float, damp_h: float,
               walls: bool, wall_y_bottom: float, wall_y_top: float, y_top: float, y_bottom: float,
               edges: np.ndarray, rest: np.ndarray, edge_offsets: np.ndarray,
               tris: np.ndarray, area0: np.ndarray, tri_offsets: np.ndarray, res_edges: np.ndarray, res_rest: np.ndarray,
               res_tris: np.ndarray, res_area0: np.ndarray,
               k_e: float, alpha_e: float, lam_e: np.ndarray, omega_e: np.ndarray,
               k_t: float, alpha_t: float, lam_t: np.ndarray, omega_t: np.ndarray, lam_m: np.ndarray,
               signed: bool, iterations: int, gs_mode: int,
               jacobi: bool, stiffness_relaxation: bool, relaxation_scale: float, node_sum: np.ndarray,
               particle_scale: np.ndarray, dx_acc: np.ndarray,
               candidates: np.ndarray, surface_edges: np.ndarray, edge_side_tol: float, shapes: np.ndarray,
               shape0: np.ndarray, shape1: np.ndarray, contact_dx: np.ndarray,
               attach_idx: np.ndarray, attach_target: np.ndarray, alpha_attach: float, lam_attach: np.ndarray) -> float:
    """One step of ``Solver.step_reference`` (constraint methods) in one call; returns the residual.

    ``x0, v0`` in, ``x, v`` out; ``w``, ``x_pred``, ``x_start``, the multipliers, ``node_sum``, ``omega_*``,
    ``dx_acc``, ``shape0/1`` and ``contact_dx`` are the solver's workspaces (written as the reference writes
    them). ``edges, rest, edge_offsets`` and ``tris, area0, tri_offsets`` are the active constraints (empty
    when off), ``res_*`` all of them (the residual). Arguments are arrays and scalars only, no tuples: the
    dispatcher types those in C, a tuple's items in Python (~1 us each, per call). ``shapes`` (substeps + 1, 7): the tool at fraction s / substeps of the step (projection contact;
    (0, 7) without). ``candidates`` and ``surface_edges`` empty: no projection contact. ``attach_idx`` (K,) int64,
    ``attach_target`` (K, 2) [m], ``alpha_attach`` = compliance / h^2 and the multipliers ``lam_attach`` (K, 2):
    the attachments (``core/physics/attach.py``), after the tool in every iteration; K = 0: none.
    """
    edge_set = (edges, rest, edge_offsets)
    tri_set = (tris, area0, tri_offsets)
    predict(x0, v0, inv_mass, dt, gravity, damp_dt, x_pred)
    hold_displaced(x_pred, inv_mass, held_idx, held_dx, 1.0, w)
    if walls:
        apply_walls(x_pred, wall_y_bottom, wall_y_top)
    n = x.shape[0]
    for i in range(uint32(n)):
        v[i, 0] = v0[i, 0]
        v[i, 1] = v0[i, 1]
        x[i, 0] = x0[i, 0]
        x[i, 1] = x0[i, 1]
    projection = shapes.shape[0] > 0
    h = dt / n_sub
    for sub in range(n_sub):
        for i in range(uint32(n)):
            x_start[i, 0] = x[i, 0]
            x_start[i, 1] = x[i, 1]
        if n_sub == 1:
            for i in range(uint32(n)):
                x[i, 0] = x_pred[i, 0]
                x[i, 1] = x_pred[i, 1]
        else:
            predict(x_start, v, inv_mass, h, gravity, damp_h, x)
            place_held(x, x0, x_pred, inv_mass, held_idx, (sub + 1) / n_sub)
            if walls:
                apply_walls(x, wall_y_bottom, wall_y_top)
        lam_e[:] = 0.0
        lam_t[:] = 0.0
        lam_m[:] = 0.0
        lam_attach[:] = 0.0
        if projection:
            for k in range(uint32(7)):
                shape0[k] = shapes[sub, k]
                shape1[k] = shapes[sub + 1, k]
        tool = (x_start, candidates, shape0, shape1, contact_dx, surface_edges, edge_side_tol)
        if jacobi and stiffness_relaxation:
            jacobi_relaxation(x, w, edges, alpha_e, tris, alpha_t, signed, relaxation_scale, node_sum,
                              omega_e, omega_t)
        # with walls or attachments: one iteration per kernel call, the attachments and walls after each
        attached = attach_idx.shape[0] > 0
        n_calls = iterations if (walls or attached) else 1
        per_call = 1 if (walls or attached) else iterations
        for _ in range(n_calls):
            if jacobi:
                jacobi_iterations(x, w, edge_set, tri_set, tool, k_e, alpha_e, lam_e, omega_e, k_t, alpha_t,
                                  lam_t, omega_t, signed, per_call, particle_scale, dx_acc)
            else:
                gauss_seidel_iterations(x, w, edge_set, tri_set, tool, k_e, alpha_e, lam_e, k_t, alpha_t, lam_t,
                                        signed, per_call, gs_mode, True)
            if attached:
                project_attachments(x, w, attach_idx, attach_target, alpha_attach, lam_attach)
            if walls:
                apply_walls(x, wall_y_bottom, wall_y_top)
        update_velocity(x, x_start, h, v)
        apply_boundary_lines(x, v, inv_mass, y_top, y_bottom)
    return constraint_residual(x, res_edges, res_rest, res_tris, res_area0, signed)


@njit(cache=True, nogil=True)
def all_finite(a: np.ndarray, b: np.ndarray) -> bool:
    """True when every entry of the two (N, 2) arrays is finite."""
    for i in range(uint32(a.shape[0])):
        if not (math.isfinite(a[i, 0]) and math.isfinite(a[i, 1]) and math.isfinite(b[i, 0])
                and math.isfinite(b[i, 1])):
            return False
    return True


@njit(cache=True, nogil=True)
def finish_step(x: np.ndarray, v: np.ndarray, x_pred: np.ndarray, mass: np.ndarray, particle_body: np.ndarray,
                edges: np.ndarray, rest: np.ndarray, edge_body: np.ndarray, tris: np.ndarray, area0: np.ndarray,
                tri_body: np.ndarray, k_spring: float, k_area: float, dt: float, signed: bool, energy: bool,
                inertial: np.ndarray, spring: np.ndarray, area: np.ndarray) -> tuple[bool, int]:
    """After a solve: (all of ``x`` and ``v`` finite, triangles with signed area <= 0 in ``x``); when finite and
    ``energy``, the constraint energy terms (:func:`~tissue_sim_ros.core.physics.kernels.energy_terms_kernel`, as
    :func:`~tissue_sim_ros.core.physics.energy.energy_terms` calls it) into ``inertial``, ``spring``, ``area``."""
    finite = all_finite(x, v)
    if finite and energy:
        energy_terms_kernel(x, x_pred, mass, particle_body, edges, rest, edge_body, tris, area0, tri_body,
                            k_spring, k_area, dt, signed, inertial, spring, area)
    return finite, count_inverted(x, tris)
