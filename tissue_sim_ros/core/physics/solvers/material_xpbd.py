"""The material solved by XPBD sweeps: the neo-Hookean elements (``core/physics/material.py``) projected
Gauss-Seidel or Jacobi, substepped, each step one compiled call
(:func:`~tissue_sim_ros.core.physics.step_kernels.material_xpbd_step`).

``material: neo_hookean`` with ``method: xpbd``: a fixed number of iterations, so a step stops short of its
implicit Euler minimiser when the tissue is stiff against its mass; every step reports how far
(:meth:`~tissue_sim_ros.core.physics.solvers.quasi_newton.MaterialSolve.sweep_residual`, the correction a
quasi-Newton iteration would still make to its last substep). The minimisation itself is
:class:`~tissue_sim_ros.core.physics.solvers.quasi_newton.QuasiNewtonSolver`.
"""
from __future__ import annotations

import numpy as np

from .. import sweeps
from ..model import Model, State
from ..step_kernels import material_xpbd_step
from .base import SolveInfo, SolverBase
from .constraint import check_order_options
from .ordering import solve_order
from .quasi_newton import MaterialSolve


class MaterialXPBDSolver(SolverBase):
    """Steps the material's elements by XPBD: Gauss-Seidel (serial, or by parts on all threads) or Jacobi.

    Parameters
    ----------
    model : Model
        ``material: neo_hookean``, ``method: xpbd``; ``scheme``, ``iterations``, ``substeps``, ``relaxation``.
    parallel, parallel_mode, order, jacobi_relaxation
        As :class:`~tissue_sim_ros.core.physics.solvers.constraint.ConstraintSolver` takes them (a parallel colour
        order sweeps the elements serially in colour order: they have no coloured kernel).
    """

    options = ("order", "parallel", "parallel_mode", "jacobi_relaxation")

    def __init__(self, model: Model, *, parallel: bool | None = None, parallel_mode: str = "partition",
                 order: str | None = None, jacobi_relaxation: str = "stiffness") -> None:
        check_order_options(order, parallel_mode, jacobi_relaxation)
        super().__init__(model)
        p = self.params
        n = model.n_particles
        self.jacobi = p.scheme == "jacobi"
        self.parallel = bool(parallel) and not self.jacobi
        self.parallel_mode = parallel_mode if self.parallel else None
        so = solve_order(model, parallel_mode if self.parallel else (order or "mesh"), self.parallel, self.jacobi)
        self.order = so.name
        self.edges, self.rest, self.tris, self.area0 = so.edges, so.rest, so.tris, so.area0
        # one element per triangle, in the triangles' solve order
        elastic = np.ascontiguousarray(model.tri_elastic, dtype=np.float64)
        self.elastic = np.ascontiguousarray(elastic[so.tri_perm]) if so.tri_perm is not None else elastic
        self._elements = (self.tris, self.elastic, so.tri_offsets, so.gs_mode == sweeps.GS_PARTITIONED,
                          (self.edges, self.rest, self.tris, self.area0), self.signed)
        """The compiled step's ``elements``."""
        self.lam_m = np.zeros((self.tris.shape[0], 3))
        """Multipliers (g_0, g_1, C_H) of each element (solve order) of the current substep, (T, 3)."""
        self.omega_m = np.ones((self.tris.shape[0], 2))
        self._sweep = (self.jacobi, jacobi_relaxation == "stiffness", int(p.iterations), float(p.relaxation),
                       2.0 * p.relaxation, self.lam_m, self.omega_m, np.zeros(n), np.zeros((n, 2)))
        """The compiled step's ``sweep``."""
        self.x_start = np.zeros((n, 2))
        self.material_solve = MaterialSolve(model, self.tris, self.elastic)

    @property
    def n_projections_per_step(self) -> int:
        """Element projections in one step (iterations x substeps x elements)."""
        return self.tris.shape[0] * self.params.iterations * self.params.substeps

    def step(self, state_in: State, state_out: State, contacts, dt: float) -> SolveInfo:
        """Advance ``state_in`` by ``dt`` into ``state_out`` in one compiled call, then measure the last substep's
        error against its exact step."""
        p = self.params
        step, h, state, pred, tool, attach = self.sweep_bundles(state_in, state_out, contacts, dt, self.x_start)
        ms = self.material_solve
        residual = material_xpbd_step(state, pred, self.timing(dt, h), self.bounds, self._elements, self._sweep,
                                      tool, attach, ms.x_pred_h)
        info = self.finish(contacts, step, residual)
        info.solve_iterations = p.iterations
        info.solve_residual = ms.sweep_residual(state_out.particle_q, self.x_start, self.inv_mass_eff, h,
                                                self.contact_dx if step.projection else None, contacts)
        info.solve_converged = info.solve_residual <= p.solve_tolerance
        return info
