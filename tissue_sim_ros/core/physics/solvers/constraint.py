"""The methods: paper PBD, XPBD (Gauss-Seidel / Jacobi), substepped XPBD.

A Solver is made once per Model (it holds workspaces: multipliers, scratch
arrays, constraint colouring) and steps ``(state_in, state_out, contacts, dt)``.
Nothing in a step creates a Python object per particle: every loop is a numba
kernel of :mod:`~tissue_sim_ros.core.physics.kernels` on arrays allocated here.

One step (the paper's Algorithm 1, with Macklin's multipliers for XPBD)::

    x* = x_t + dt damp v_t + dt^2 (0, g)            free particles; + held_dx (paper contact); walls
    for each of `substeps` substeps of h = dt / substeps:
        predict from the substep's start (h), reset multipliers
        (held particles: the fraction (s+1)/substeps of their way from x_t to x*)
        `iterations` sweeps: edges, triangles, tool (projection contact), attachments (a closed grasper), walls
            (material: neo_hookean: the triangles' elements instead of edges and areas, core/physics/material.py)
        v = (x - x_start) / h; boundary lines clamp and stop particles
    residual = RMS(C / rest size)

damp = max(0, 1 - c h) (``damping_mode: linear``) or exp(-c h) (``exponential``,
the authors' v *= exp(-8 dt)), c = ``damping``. Walls (``wall_y_bottom/top``)
put every particle that crossed them back on them (:func:`~tissue_sim_ros.core.physics.violated_jacobi.apply_walls`).
PBD Jacobi averages each particle's corrections over its violated constraints
per type (``jacobi_averaging: violated``, the authors' code,
:mod:`~tissue_sim_ros.core.physics.violated_jacobi`) or over all of them (``all``).

Orders. Serial Gauss-Seidel gives the result of sweeping the constraints in
mesh order, as the paper does (executed in a wavefront schedule that changes
no bit of it, see :func:`wavefront_order`). The parallel path (``parallel=True``;
off by default, see :data:`PARALLEL_MIN_PARTICLES`) cuts the mesh into one part per
thread (:func:`partition_particles`): each thread sweeps its part's
constraints in mesh order, then the constraints across parts are swept. Optionally (``parallel_mode="colour"``)
constraints are sorted by greedy colour (no two constraints of one colour
share a particle) and each colour runs on all threads. Both are still
Gauss-Seidel, in another order: a result differs from the mesh-order sweep's
by what the iterations have not converged plus XPBD's small path dependence
(measured: 2e-3 of a step's displacement), not bit for bit. Neither depends
on thread timing: within a part or a colour the projections are independent.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from ...contact.collision import Contacts
from ...errors import InputError
from .. import kernels, material, sweeps
from ..attach import project_attachments
from ..model import Model, State
from ..quasi_newton import MaterialSolve
from ..violated_jacobi import violated_jacobi_iterations
from ..walls import apply_walls
from .ordering import (
    JACOBI_RELAXATIONS,
    ORDERS,
    PARALLEL_MODES,
    colour_constraints,
    partition_constraints,
    partition_particles,
    wavefront_order,
)


@dataclass
class SolveInfo:
    """What a solve hands back to the Simulation.

    The arrays are the Solver's workspaces: valid until its next step.
    """

    x_pred: np.ndarray
    """Full-step predicted positions x* [m], shape (N, 2) (including the paper contact's displacement)."""
    contact_dx: np.ndarray | None
    """Sum of the contact model's position corrections per particle over the step [m], shape (N, 2), or None."""
    residual: float
    """RMS constraint violation after the solve (edges relative to rest length, areas relative to rest area)."""
    solve_iterations: int = 0
    """Material: iterations the solve took (quasi_newton; the other methods their fixed count)."""
    solve_residual: float = math.nan
    """Material: the step's estimated relative error against its exact (implicit Euler) step: the correction a
    quasi-Newton iteration would still make, over the step's motion (core/physics/quasi_newton.py; xpbd: of its
    last substep); NaN for the constraint model."""
    solve_converged: bool = True
    """Material: ``solve_residual <= params.solve_tolerance``."""


class Solver:
    """Steps a Model: prediction, constraint solve, velocity update, boundary lines.

    Parameters
    ----------
    model : Model
        Topology and parameters (``model.params``: method, scheme, iterations, substeps, ...).
    parallel : bool, optional
        Gauss-Seidel on all numba threads. Default (None or False): serial, at
        every mesh size; True is an explicit choice for a machine with free
        cores and a mesh of at least :data:`PARALLEL_MIN_PARTICLES` particles,
        where ``tissue-sim bench solver`` shows it pays (Jacobi is always serial).
    parallel_mode : {"partition", "colour"}
        How Gauss-Seidel runs in parallel. ``partition`` (default): the mesh
        is cut into one part per thread (:func:`partition_particles`); each
        thread sweeps its part's constraints (mesh order, wavefront-scheduled),
        then the few constraints across parts are swept on one thread: one fork-join per
        sweep, and the result does not depend on the thread count's timing.
        ``colour``: constraints sorted by greedy colour, each colour on all
        threads (one fork-join per colour, ~16 per iteration).
    order : {"mesh", "colour", "stored"}, optional
        Serial Gauss-Seidel order. ``mesh`` (default): the result of sweeping
        in mesh order, bit for bit, executed in a wavefront schedule
        (:func:`wavefront_order`) so consecutive projections share no particle
        and overlap in the CPU's pipeline instead of waiting on each other's
        stores (~1.5-2x faster on one core). ``colour``: sorted by colour (the
        parallel path's order, on one thread). ``stored``: literally the array
        order (same result as ``mesh``, slower; kept for the benchmark). The
        parallel path uses the order of its ``parallel_mode``.
    jacobi_relaxation : {"stiffness", "uniform"}
        XPBD Jacobi relaxation: per-constraint omega_c = 2 relaxation / r_c from
        a Gershgorin bound r_c (default; stable at any stiffness, see
        :func:`~tissue_sim_ros.core.physics.kernels.jacobi_relaxation`), or the same
        omega = ``params.relaxation`` for every constraint (diverges for stiff
        constraints; kept to show that).
    jacobi_average : bool
        PBD Jacobi: divide each particle's summed correction by its constraint
        count (the paper authors' code; default). False sums them, which blows
        up for stiff constraints (kept for the stability tests).
    """

    def __init__(self, model: Model, *, parallel: bool | None = None, parallel_mode: str = "partition",
                 order: str | None = None, jacobi_relaxation: str = "stiffness", jacobi_average: bool = True) -> None:
        p = model.params
        if order is not None and order not in ORDERS:
            raise InputError(f"solver order={order!r}: expected one of {', '.join(ORDERS)}")
        if parallel_mode not in PARALLEL_MODES:
            raise InputError(f"parallel_mode={parallel_mode!r}: expected one of {', '.join(PARALLEL_MODES)}")
        if jacobi_relaxation not in JACOBI_RELAXATIONS:
            raise InputError(f"jacobi_relaxation={jacobi_relaxation!r}: expected one of {', '.join(JACOBI_RELAXATIONS)}")
        self.model = model
        self.params = p
        n = model.n_particles
        self.jacobi = p.scheme == "jacobi"
        # serial unless asked: the two-thread path loses to it on a shared machine (PARALLEL_MIN_PARTICLES)
        self.parallel = bool(parallel) and not self.jacobi
        self.parallel_mode = parallel_mode if self.parallel else None
        if self.parallel:
            self.order = parallel_mode
        else:
            self.order = order or "mesh"
        self.n_parts = numba.get_num_threads()
        self.jacobi_relaxation = jacobi_relaxation
        self.jacobi_average = jacobi_average
        # Stiffness-aware Jacobi: omega_c = 2 relaxation / r_c; steps below 2 / r_c converge for the
        # linearised system (kernels.jacobi_relaxation), so relaxation in (0, 1) is a fraction of the
        # largest guaranteed step.
        self.relaxation_scale = 2.0 * p.relaxation
        self.signed = p.area_mode == "signed"

        # constraints in solve order (colour-sorted copies when needed)
        edges = np.ascontiguousarray(model.edge_indices, dtype=np.int32)
        rest = np.ascontiguousarray(model.edge_rest_length, dtype=np.float64)
        tris = np.ascontiguousarray(model.tri_indices, dtype=np.int32)
        area0 = np.ascontiguousarray(model.tri_rest_area, dtype=np.float64)
        self.edge_offsets = np.array([0, edges.shape[0]], dtype=np.int64)
        self.tri_offsets = np.array([0, tris.shape[0]], dtype=np.int64)
        perm_e = perm_t = None
        self.gs_mode = sweeps.GS_SERIAL
        if self.order == "partition":
            part = partition_particles(model.particle_q0, self.n_parts, model.edge_indices)
            perm_e, self.edge_offsets = partition_constraints(edges, part, self.n_parts)
            perm_t, self.tri_offsets = partition_constraints(tris, part, self.n_parts)
            self.gs_mode = sweeps.GS_PARTITIONED
        elif self.order == "colour":
            perm_e, self.edge_offsets = colour_constraints(edges, n)
            perm_t, self.tri_offsets = colour_constraints(tris, n)
            self.gs_mode = sweeps.GS_COLOURED if self.parallel else sweeps.GS_SERIAL
        elif self.order == "mesh" and not self.jacobi:
            perm_e, perm_t = wavefront_order(edges, n), wavefront_order(tris, n)
        if perm_e is not None:
            edges, rest = np.ascontiguousarray(edges[perm_e]), np.ascontiguousarray(rest[perm_e])
            tris, area0 = np.ascontiguousarray(tris[perm_t]), np.ascontiguousarray(area0[perm_t])
        self.edges, self.rest, self.tris, self.area0 = edges, rest, tris, area0
        # material: one element per triangle, in the triangles' solve order (core/physics/material.py)
        self.is_material = model.is_material
        elastic = np.ascontiguousarray(model.tri_elastic, dtype=np.float64)
        self.elastic = np.ascontiguousarray(elastic[perm_t]) if (self.is_material and perm_t is not None) else elastic
        self.lam_m = np.zeros((tris.shape[0] if self.is_material else 0, 3))
        """Multipliers (g_0, g_1, C_H) of each element (solve order) of the current substep, (T, 3)."""
        self.omega_m = np.ones((self.lam_m.shape[0], 2))
        self._no_edges = np.zeros((0, 2), dtype=np.int32)
        self._no_tris = np.zeros((0, 3), dtype=np.int32)
        self._no_float = np.zeros(0, dtype=np.float64)
        self._no_index = np.zeros(0, dtype=np.int32)

        # workspaces
        self.x_pred = np.zeros((n, 2))
        """Full-step prediction x* [m], (N, 2)."""
        self.x_start = np.zeros((n, 2))
        """Positions at the start of the current substep [m], (N, 2)."""
        self.inv_mass_eff = np.zeros(n)
        """Inverse masses of this step (held particles zeroed) [1/kg], (N,)."""
        self.lam_e = np.zeros(edges.shape[0])
        """Multiplier of each edge (solve order) of the current substep, (E,)."""
        self.lam_t = np.zeros(tris.shape[0])
        """Multiplier of each triangle (solve order) of the current substep, (T,)."""
        self.contact_dx = np.zeros((n, 2))
        """Summed projection-contact corrections of the step [m], (N, 2)."""
        self._dx_acc = np.zeros((n, 2))
        self._node_sum = np.zeros(n)
        self.omega_e = np.ones(edges.shape[0])
        self.omega_t = np.ones(tris.shape[0])
        self.particle_scale = np.ones(n)
        # the authors' averaging over violated constraints (core/physics/violated_jacobi.py)
        self.violated = self.jacobi and p.method == "pbd" and jacobi_average and p.jacobi_averaging == "violated"
        self.walls = not (math.isnan(p.wall_y_bottom) and math.isnan(p.wall_y_top))
        if self.violated:
            self._dxa = np.zeros((n, 2))
            self._ns = np.zeros(n)
            self._na = np.zeros(n)
        if self.jacobi and p.method == "pbd" and jacobi_average and not self.violated:
            count = np.bincount(model.edge_indices.ravel(), minlength=n) + np.bincount(model.tri_indices.ravel(),
                                                                                      minlength=n)
            self.particle_scale = 1.0 / np.maximum(count, 1).astype(np.float64)
        if self.jacobi and p.method == "xpbd" and jacobi_relaxation == "uniform":
            self.omega_e[:] = p.relaxation
            self.omega_t[:] = p.relaxation
        self._shape0 = np.zeros(7)
        self._shape1 = np.zeros(7)
        self.quasi_newton = p.method == "quasi_newton"
        # the material's step minimised (quasi_newton) and every material step's convergence report
        self.material_solve = MaterialSolve(model, self.tris, self.elastic) if self.is_material else None
        self._shapes = np.zeros((0, 7))
        self._no_shapes = np.zeros((0, 7))
        self._no_edge_set = (self._no_edges, self._no_float, self.edge_offsets)
        self._no_tri_set = (self._no_tris, self._no_float, self.tri_offsets)
        self.lam_a = np.zeros((0, 2))
        """Multipliers of the attachments (contacts.attach_idx, core/physics/attach.py) of the current substep, (K, 2)."""

    @property
    def n_projections_per_step(self) -> int:
        """Constraint projections in one step (iterations x substeps x active constraints)."""
        p = self.params
        if self.is_material:
            return self.tris.shape[0] * p.iterations * p.substeps
        n_c = (self.edges.shape[0] if self._k_alpha(p.k_spring, p.stiffness_spring, 1.0)[2] else 0) \
            + (self.tris.shape[0] if self._k_alpha(p.k_area, p.stiffness_area, 1.0)[2] else 0)
        return n_c * p.iterations * p.substeps

    def damp_factor(self, h: float) -> float:
        """Velocity scale of one (sub)step h: max(0, 1 - c h) (linear) or exp(-c h) (exponential)."""
        c = self.params.damping
        return math.exp(-c * h) if self.params.damping_mode == "exponential" else max(0.0, 1.0 - c * h)

    def _k_alpha(self, k_pbd: float, stiffness: float, h: float) -> tuple[float, float, bool]:
        """(k, alpha, active) of one constraint type for a substep h."""
        if self.params.method == "pbd":
            return k_pbd, 0.0, k_pbd > 0.0
        if stiffness <= 0.0:
            return 1.0, 0.0, False
        return 1.0, 1.0 / (stiffness * h * h), True

    @staticmethod
    def _interpolate_shape(s0: np.ndarray, s1: np.ndarray, f: float, out: np.ndarray) -> None:
        """Tool shape at fraction f of the step: centre linear, angle via the normalised (cos, sin)."""
        out[:] = s0 + f * (s1 - s0)
        norm = math.hypot(out[2], out[3])
        if norm > 1e-12:
            out[2] /= norm
            out[3] /= norm
        else:  # half a turn within one step: take the end orientation
            out[2], out[3] = s1[2], s1[3]

    def _material_iterations(self, x: np.ndarray, w: np.ndarray, h: float, cand: np.ndarray, surf: np.ndarray,
                             edge_side_tol: float, attach: tuple | None = None) -> None:
        """One substep's iterations of the material elements (and the tool), Gauss-Seidel or Jacobi; with
        ``attach`` = (idx, target, alpha~) one iteration per call, the attachments after each."""
        p = self.params
        inv_h2 = 1.0 / (h * h)
        n_calls, per_call = (p.iterations, 1) if attach is not None else (1, p.iterations)
        if self.jacobi:
            if self.jacobi_relaxation == "stiffness":
                material.jacobi_relaxation_elements(x, w, self.tris, self.elastic, inv_h2, self.relaxation_scale,
                                                    self._node_sum, self.omega_m)
            else:
                self.omega_m[:] = p.relaxation
            for _ in range(n_calls):
                material.material_jacobi(x, w, self.tris, self.elastic, inv_h2, self.lam_m, self.omega_m, per_call,
                                         self._dx_acc, self.x_start, cand, self._shape0, self._shape1,
                                         self.contact_dx, surf, edge_side_tol)
                if attach is not None:
                    project_attachments(x, w, attach[0], attach[1], attach[2], self.lam_a)
        else:
            # a parallel colour order runs serially here (the elements have no coloured kernel)
            for _ in range(n_calls):
                material.material_gauss_seidel(x, w, self.tris, self.elastic, inv_h2, self.lam_m, self.tri_offsets,
                                               self.gs_mode == sweeps.GS_PARTITIONED, per_call, self.x_start,
                                               cand, self._shape0, self._shape1, self.contact_dx, surf, edge_side_tol)
                if attach is not None:
                    project_attachments(x, w, attach[0], attach[1], attach[2], self.lam_a)

    @property
    def compiled(self) -> bool:
        """True when :meth:`step` is one compiled call (:func:`~tissue_sim_ros.core.physics.step_kernels.solve_step`):
        the constraint methods, serial Gauss-Seidel or Jacobi; the material, the violated-constraint Jacobi
        and the parallel Gauss-Seidel run :meth:`step_reference`."""
        return not (self.is_material or self.violated or self.parallel)

    def step(self, state_in: State, state_out: State, contacts: Contacts, dt: float) -> SolveInfo:
        """Advance ``state_in`` by ``dt`` into ``state_out`` (which must not alias ``state_in``).

        One compiled call where :attr:`compiled`, else :meth:`step_reference`; the same numbers bit for bit
        (``test/test_step_kernels.py``). Arguments as :meth:`step_reference`.
        """
        if self.quasi_newton:
            return self._step_quasi_newton(state_in, state_out, contacts, dt)
        if not self.compiled:
            return self.step_reference(state_in, state_out, contacts, dt)
        from ..step_kernels import solve_step  # noqa: PLC0415

        p = self.params
        held_idx, held_dx, candidates, surface_edges, projection = self._check_step(state_in, state_out, contacts,
                                                                                    dt)
        n_sub = p.substeps
        h = dt / n_sub
        if projection:
            self.contact_dx.fill(0.0)
            s0 = np.ascontiguousarray(contacts.tool_shape0, dtype=np.float64)
            s1 = np.ascontiguousarray(contacts.tool_shape1, dtype=np.float64)
            shapes = self._shapes if self._shapes.shape[0] == n_sub + 1 else np.zeros((n_sub + 1, 7))
            self._shapes = shapes
            for sub in range(n_sub + 1):
                self._interpolate_shape(s0, s1, sub / n_sub, shapes[sub])
            cand, surf = candidates, surface_edges
        else:
            shapes, cand, surf = self._no_shapes, self._no_index, self._no_edges
        a_idx, a_target, a_compliance = self._attachments(contacts)
        k_e, alpha_e, use_e = self._k_alpha(p.k_spring, p.stiffness_spring, h)
        k_t, alpha_t, use_t = self._k_alpha(p.k_area, p.stiffness_area, h)
        edge_set = (self.edges, self.rest, self.edge_offsets) if use_e else self._no_edge_set
        tri_set = (self.tris, self.area0, self.tri_offsets) if use_t else self._no_tri_set
        residual = solve_step(
            state_in.particle_q, state_in.particle_qd, state_out.particle_q, state_out.particle_qd,
            self.model.particle_inv_mass, self.inv_mass_eff, self.x_pred, self.x_start, held_idx, held_dx,
            dt, n_sub, p.gravity, self.damp_factor(dt), self.damp_factor(h), self.walls, p.wall_y_bottom,
            p.wall_y_top, p.boundary_y_top, p.boundary_y_bottom, *edge_set, *tri_set,
            self.edges, self.rest, self.tris, self.area0,
            k_e, alpha_e, self.lam_e, self.omega_e, k_t, alpha_t, self.lam_t, self.omega_t, self.lam_m,
            self.signed, p.iterations, self.gs_mode,
            self.jacobi, self.jacobi and p.method == "xpbd" and self.jacobi_relaxation == "stiffness",
            self.relaxation_scale, self._node_sum, self.particle_scale, self._dx_acc,
            cand, surf, float(contacts.edge_side_tol), shapes, self._shape0, self._shape1, self.contact_dx,
            a_idx, a_target, a_compliance / (h * h), self.lam_a)
        return self._finish(contacts, held_idx, projection, residual)

    def _attachments(self, contacts: Contacts) -> tuple[np.ndarray, np.ndarray, float]:
        """The step's attachments (``contacts.attach_*``, core/physics/attach.py) checked and contiguous:
        (idx (K,) int64, target (K, 2) float64 [m], compliance [m/N]); sizes the multipliers ``lam_a``."""
        n = self.model.n_particles
        idx = np.ascontiguousarray(getattr(contacts, "attach_idx", self._no_index), dtype=np.int64).reshape(-1)
        target = np.ascontiguousarray(getattr(contacts, "attach_target", self._no_float), dtype=np.float64)
        target = target.reshape(-1, 2)
        compliance = float(getattr(contacts, "attach_compliance", 0.0))
        if idx.shape[0]:
            if idx.min() < 0 or idx.max() >= n:
                raise InputError(f"contacts.attach_idx must lie in [0, {n}); got [{idx.min()}, {idx.max()}]")
            if target.shape[0] != idx.shape[0] or not np.isfinite(target).all():
                raise InputError(f"contacts.attach_target has shape {target.shape} for {idx.shape[0]} attachments: "
                                 "expected (K, 2), finite [m]")
            if not (compliance > 0.0 and np.isfinite(compliance)):
                raise InputError(f"contacts.attach_compliance={compliance!r}: expected a compliance > 0 m/N")
        if self.lam_a.shape[0] != idx.shape[0]:
            self.lam_a = np.zeros((idx.shape[0], 2))
        return idx, target, compliance

    def _check_step(self, state_in: State, state_out: State, contacts: Contacts,
                    dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool]:
        """The step's arguments checked: (held_idx, held_dx, candidates, surface_edges, projection), contiguous."""
        n = self.model.n_particles
        for name, arr in (("state_in.particle_q", state_in.particle_q), ("state_in.particle_qd", state_in.particle_qd),
                          ("state_out.particle_q", state_out.particle_q),
                          ("state_out.particle_qd", state_out.particle_qd)):
            if arr.shape != (n, 2) or arr.dtype != np.float64 or not arr.flags.c_contiguous:
                raise InputError(f"{name} has shape {arr.shape}, dtype {arr.dtype}: expected ({n}, 2) float64, C-contiguous")
        if not (dt > 0.0 and math.isfinite(dt)):
            raise InputError(f"dt={dt!r}: expected a time step > 0 s")
        held_idx = np.ascontiguousarray(contacts.held_idx, dtype=np.int32)
        held_dx = np.ascontiguousarray(contacts.held_dx, dtype=np.float64).reshape(-1, 2)
        candidates = np.ascontiguousarray(contacts.candidates, dtype=np.int32)
        surface_edges = np.ascontiguousarray(contacts.surface_edges, dtype=np.int32).reshape(-1, 2)
        projection = candidates.shape[0] > 0 or surface_edges.shape[0] > 0
        # the kernels index without bounds checks: refuse indices outside the model here
        for name, idx in (("contacts.held_idx", held_idx), ("contacts.candidates", candidates),
                          ("contacts.surface_edges", surface_edges.ravel())):
            if idx.shape[0] and (idx.min() < 0 or idx.max() >= n):
                raise InputError(f"{name} must lie in [0, {n}); got [{idx.min()}, {idx.max()}]")
        if held_dx.shape[0] != held_idx.shape[0]:
            raise InputError(f"contacts.held_dx has {held_dx.shape[0]} rows for {held_idx.shape[0]} held particles")
        return held_idx, held_dx, candidates, surface_edges, projection

    def _finish(self, contacts: Contacts, held_idx: np.ndarray, projection: bool, residual: float) -> SolveInfo:
        if projection:
            moved = np.flatnonzero((self.contact_dx[:, 0] != 0.0) | (self.contact_dx[:, 1] != 0.0))
            contacts.touched = moved.astype(np.int32)
        elif held_idx.shape[0]:
            contacts.touched = held_idx.copy()
        return SolveInfo(x_pred=self.x_pred, contact_dx=self.contact_dx if projection else None,
                         residual=float(residual))

    def step_reference(self, state_in: State, state_out: State, contacts: Contacts, dt: float) -> SolveInfo:
        """Advance ``state_in`` by ``dt`` into ``state_out`` (which must not alias ``state_in``): the Python loop
        around the kernels (the material, the violated-constraint Jacobi and the parallel Gauss-Seidel use it;
        for the others it is the reference of :meth:`step`'s one compiled call).

        Parameters
        ----------
        state_in, state_out : State
            Positions [m] and velocities [m/s], (N, 2) float64 C-contiguous.
        contacts : Contacts
            The contact model's output for this step; ``contacts.touched`` is filled here.
        dt : float
            Time step [s].
        """
        if self.quasi_newton:
            return self._step_quasi_newton(state_in, state_out, contacts, dt)
        p = self.params
        model = self.model
        held_idx, held_dx, candidates, surface_edges, projection = self._check_step(state_in, state_out, contacts,
                                                                                    dt)
        n_sub = p.substeps
        h = dt / n_sub
        inv_mass = model.particle_inv_mass
        x0, v0 = state_in.particle_q, state_in.particle_qd
        x, v = state_out.particle_q, state_out.particle_qd
        if projection:
            self.contact_dx.fill(0.0)
            s0 = np.ascontiguousarray(contacts.tool_shape0, dtype=np.float64)
            s1 = np.ascontiguousarray(contacts.tool_shape1, dtype=np.float64)

        # the full-step prediction x* (the energy's reference), and the held set
        kernels.predict(x0, v0, inv_mass, dt, p.gravity, self.damp_factor(dt), self.x_pred)
        kernels.hold_displaced(self.x_pred, inv_mass, held_idx, held_dx, 1.0, self.inv_mass_eff)
        if self.walls:
            apply_walls(self.x_pred, p.wall_y_bottom, p.wall_y_top)
        w = self.inv_mass_eff

        k_e, alpha_e, use_e = self._k_alpha(p.k_spring, p.stiffness_spring, h)
        k_t, alpha_t, use_t = self._k_alpha(p.k_area, p.stiffness_area, h)
        if self.is_material:
            use_e = use_t = False
        edges, rest = (self.edges, self.rest) if use_e else (self._no_edges, self._no_float)
        tris, area0 = (self.tris, self.area0) if use_t else (self._no_tris, self._no_float)
        a_idx, a_target, a_compliance = self._attachments(contacts)
        attach = (a_idx, a_target, a_compliance / (h * h)) if a_idx.shape[0] else None

        np.copyto(v, v0)
        np.copyto(x, x0)
        for sub in range(n_sub):
            np.copyto(self.x_start, x)
            if n_sub == 1:
                np.copyto(x, self.x_pred)
            else:
                kernels.predict(self.x_start, v, inv_mass, h, p.gravity, self.damp_factor(h), x)
                kernels.place_held(x, x0, self.x_pred, inv_mass, held_idx, (sub + 1) / n_sub)
                if self.walls:
                    apply_walls(x, p.wall_y_bottom, p.wall_y_top)
            self.lam_e.fill(0.0)
            self.lam_t.fill(0.0)
            self.lam_m.fill(0.0)
            self.lam_a.fill(0.0)
            if projection:
                self._interpolate_shape(s0, s1, sub / n_sub, self._shape0)
                self._interpolate_shape(s0, s1, (sub + 1) / n_sub, self._shape1)
                cand, surf = candidates, surface_edges
            else:
                cand, surf = self._no_index, self._no_edges
            if self.is_material:
                if sub == n_sub - 1:
                    np.copyto(self.material_solve.x_pred_h, x)
                self._material_iterations(x, w, h, cand, surf, float(contacts.edge_side_tol), attach)
                if self.walls:
                    apply_walls(x, p.wall_y_bottom, p.wall_y_top)
            elif self.violated:
                # the authors' Jacobi: weights from the model's inverse masses (held particles keep theirs), only
                # particles free this step move; walls after every iteration (inside the kernel)
                violated_jacobi_iterations(x, inv_mass, w, edges, rest, k_e, p.jacobi_spring_tolerance,
                                           tris, area0, k_t, p.jacobi_area_tolerance, self.signed, p.iterations,
                                           p.wall_y_bottom, p.wall_y_top, self._dx_acc, self._dxa, self._ns,
                                           self._na, self.x_start, cand, self._shape0, self._shape1,
                                           self.contact_dx, surf, float(contacts.edge_side_tol))
                if attach is not None:  # once after the authors' sweeps (their loop has no place for it)
                    project_attachments(x, w, attach[0], attach[1], attach[2], self.lam_a)
            else:
                # with walls: one iteration per kernel call, the walls after each (as the authors' loop)
                # with attachments: one iteration per kernel call, the attachments after each (after the tool)
                calls = [1] * p.iterations if (self.walls or attach is not None) else [p.iterations]
                if self.jacobi and p.method == "xpbd" and self.jacobi_relaxation == "stiffness":
                    sweeps.jacobi_relaxation(x, w, edges, alpha_e, tris, alpha_t, self.signed, self.relaxation_scale,
                                              self._node_sum, self.omega_e, self.omega_t)
                edge_set = (edges, rest, self.edge_offsets)
                tri_set = (tris, area0, self.tri_offsets)
                tool = sweeps.tool_pack(self.x_start, cand, self._shape0, self._shape1, self.contact_dx, surf,
                                         contacts.edge_side_tol)
                for iters in calls:
                    if self.jacobi:
                        sweeps.jacobi_iterations(x, w, edge_set, tri_set, tool, k_e, alpha_e, self.lam_e,
                                                  self.omega_e, k_t, alpha_t, self.lam_t, self.omega_t,
                                                  self.signed, iters, self.particle_scale, self._dx_acc)
                    else:
                        sweeps.gauss_seidel_iterations(x, w, edge_set, tri_set, tool, k_e, alpha_e, self.lam_e,
                                                        k_t, alpha_t, self.lam_t, self.signed, iters, self.gs_mode)
                    if attach is not None:
                        project_attachments(x, w, attach[0], attach[1], attach[2], self.lam_a)
                    if self.walls:
                        apply_walls(x, p.wall_y_bottom, p.wall_y_top)
            kernels.update_velocity(x, self.x_start, h, v)
            kernels.apply_boundary_lines(x, v, inv_mass, p.boundary_y_top, p.boundary_y_bottom)

        residual = kernels.constraint_residual(x, self.edges, self.rest, self.tris, self.area0, self.signed)
        info = self._finish(contacts, held_idx, projection, residual)
        if self.is_material:
            info.solve_iterations = p.iterations
            info.solve_residual = self.material_solve.sweep_residual(
                x, self.x_start, w, h, self.contact_dx if projection else None, contacts)
            info.solve_converged = info.solve_residual <= p.solve_tolerance
        return info

    def _step_quasi_newton(self, state_in: State, state_out: State, contacts: Contacts, dt: float) -> SolveInfo:
        """One material step as the minimiser of its incremental potential (core/physics/quasi_newton.py)."""
        p = self.params
        model = self.model
        held_idx, held_dx, candidates, surface_edges, projection = self._check_step(state_in, state_out, contacts,
                                                                                    dt)
        inv_mass = model.particle_inv_mass
        x0, v0 = state_in.particle_q, state_in.particle_qd
        x, v = state_out.particle_q, state_out.particle_qd
        kernels.predict(x0, v0, inv_mass, dt, p.gravity, self.damp_factor(dt), self.x_pred)
        kernels.hold_displaced(self.x_pred, inv_mass, held_idx, held_dx, 1.0, self.inv_mass_eff)
        if self.walls:
            apply_walls(self.x_pred, p.wall_y_bottom, p.wall_y_top)
        if projection:
            np.copyto(self._shape0, np.asarray(contacts.tool_shape0, dtype=np.float64))
            np.copyto(self._shape1, np.asarray(contacts.tool_shape1, dtype=np.float64))
            cand, surf = candidates, surface_edges
        else:
            cand, surf = self._no_index, self._no_edges
        iterations, solve_residual = self.material_solve.minimise(
            x0, v0, x, self.x_pred, self.inv_mass_eff, dt, self.damp_factor(dt), cand, surf, self._shape0,
            self._shape1, float(contacts.edge_side_tol), self.contact_dx, contacts)
        kernels.update_velocity(x, x0, dt, v)
        kernels.apply_boundary_lines(x, v, inv_mass, p.boundary_y_top, p.boundary_y_bottom)
        residual = kernels.constraint_residual(x, self.edges, self.rest, self.tris, self.area0, self.signed)
        info = self._finish(contacts, held_idx, projection, residual)
        info.solve_iterations = iterations
        info.solve_residual = solve_residual
        info.solve_converged = info.solve_residual <= p.solve_tolerance
        return info
