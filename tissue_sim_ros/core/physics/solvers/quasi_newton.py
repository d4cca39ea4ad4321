"""The material's step as the minimisation it is (``method: quasi_newton``): :class:`QuasiNewtonSolver`, and the
workspaces and factors every material step's solve or report uses (:class:`MaterialSolve`).

The kernels (the incremental potential, the L-BFGS loop with its active set, the step in one call) are in
:mod:`~tissue_sim_ros.core.physics.quasi_newton`, whose docstring gives the method.
"""
from __future__ import annotations

import math

import numpy as np

from ..kernels import constraint_residual
from ..model import Model, State
from ..prefactor import Prefactor, active_key
from ..quasi_newton import FLOOR_REL, quasi_newton_step, substep_residual
from .base import SolveInfo, SolverBase
from .ordering import solve_order

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
        self.vectors = tuple(np.zeros(2 * n) for _ in range(5))  # g, g_new, d, x_old, z
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
        self.ws = (self.hist_s, self.hist_y, self.hist_rho, self.alpha, self.kind, self.normal, self.released_once,
                   self.turns, self.scratch, self.vectors, self.b, self.out)
        """The minimisation's workspace bundle (``quasi_newton_solve``'s ``ws``)."""
        self.elim = (self.wcol, self.wkey, self.cur_slot, self.cur_i, self.cur_n, self.cur_c, self.smat, self.sinv,
                     self.used, self.t)
        """The active set's elimination (``active_set.build_constraints``' ``elim``)."""
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
        self.mat = (model.particle_mass, model.particle_inv_mass, tris, elastic, self.in_factor)
        """The material's bundle (``quasi_newton_solve``'s ``mat``)."""
        p = self.params
        self.lines = (float(p.boundary_y_top), float(p.boundary_y_bottom), float(p.wall_y_bottom),
                      float(p.wall_y_top))
        """(y_top, y_bottom, wall_bottom, wall_top) [m]: the lines and walls that bound the active set."""
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

    def sweep_residual(self, x: np.ndarray, x_start: np.ndarray, w: np.ndarray, h: float,
                       contact_dx: np.ndarray | None, contacts) -> float:
        """The sweeps' last substep (of length h, from ``x_start``, prediction :attr:`x_pred_h`) as
        :func:`substep_residual` measures it."""
        pre = self.prefactor(h)
        if contact_dx is None:
            self.scratch.fill(0.0)
            contact_dx = self.scratch
        g, z, e = self.vectors[:3]
        return float(substep_residual(x, x_start, self.x_pred_h, w, self.mat, h * h, contact_dx, self.lines,
                                      attachments(contacts), pre.arrays, (self.kind, g, z, e), self.floor_rms))


class QuasiNewtonSolver(SolverBase):
    """Steps the material as the minimiser of each step's incremental potential (L-BFGS, prefactored rest
    Hessian, the contacts an active set), one compiled call per step
    (:func:`~tissue_sim_ros.core.physics.quasi_newton.quasi_newton_step`); ``iterations`` caps it and
    ``solve_tolerance`` ends it. No options: the triangles are summed in the wavefront order of the mesh."""

    def __init__(self, model: Model) -> None:
        super().__init__(model)
        p = self.params
        so = solve_order(model, "mesh", False, False)
        self.edges, self.rest, self.tris, self.area0 = so.edges, so.rest, so.tris, so.area0
        elastic = np.ascontiguousarray(model.tri_elastic, dtype=np.float64)
        self.elastic = np.ascontiguousarray(elastic[so.tri_perm]) if so.tri_perm is not None else elastic
        self.material_solve = MaterialSolve(model, self.tris, self.elastic)
        self.guess = self.material_solve.guess
        self.solve_options = (float(p.solve_tolerance), int(p.iterations), float(self.material_solve.floor_rms))
        """The compiled step's ``solve``: (tolerance, iterations at most, the motion floor [m])."""
        self._residual_set = (self.edges, self.rest, self.tris, self.area0)

    @property
    def n_projections_per_step(self) -> int:
        """Element evaluations in one iteration (a step takes ``solve_iterations`` of them)."""
        return self.tris.shape[0] * self.params.iterations

    def step(self, state_in: State, state_out: State, contacts, dt: float) -> SolveInfo:
        """One material step as the minimiser of its incremental potential (module docstring)."""
        step = self.check_step(state_in, state_out, contacts, dt)
        if step.projection:
            np.copyto(self._shape0, np.asarray(contacts.tool_shape0, dtype=np.float64))
            np.copyto(self._shape1, np.asarray(contacts.tool_shape1, dtype=np.float64))
        ms = self.material_solve
        damp = self.damp_factor(dt)
        x = state_out.particle_q
        quasi_newton_step(
            (state_in.particle_q, state_in.particle_qd, x, state_out.particle_qd),
            (self.model.particle_inv_mass, self.inv_mass_eff, self.x_pred, self.guess, step.held_idx, step.held_dx),
            (dt, 1, self.params.gravity, damp, damp), self.bounds, ms.mat, ms.step_factor(dt).arrays,
            (state_in.particle_q, step.candidates, self._shape0, self._shape1, self.contact_dx, step.surface_edges,
             float(contacts.edge_side_tol)),
            attachments(contacts), ms.ws, ms.elim, self.solve_options)
        residual = constraint_residual(x, *self._residual_set, self.signed)
        info = self.finish(contacts, step, residual)
        info.solve_iterations = int(ms.out[0])
        info.solve_residual = float(ms.out[1])
        info.solve_converged = info.solve_residual <= self.params.solve_tolerance
        return info
