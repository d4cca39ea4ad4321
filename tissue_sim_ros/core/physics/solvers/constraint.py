"""The constraint methods: the paper's PBD and XPBD on distance and area constraints (Gauss-Seidel, Jacobi, the
authors' violated-constraint Jacobi), substepped or not.

:class:`ConstraintSolver` is made once per Model (it holds workspaces: multipliers, scratch arrays, the
constraints in their sweep order) and steps ``(state_in, state_out, contacts, dt)`` in one compiled call
(:func:`~tissue_sim_ros.core.physics.step_kernels.constraint_step`). Its sweep is a strategy it holds:
:class:`GaussSeidel`, :class:`Jacobi` or :class:`ViolatedJacobi`.

One step (the paper's Algorithm 1, with Macklin's multipliers for XPBD)::

    x* = x_t + dt damp v_t + dt^2 (0, g)            free particles; + held_dx (paper contact); walls
    for each of `substeps` substeps of h = dt / substeps:
        predict from the substep's start (h), reset multipliers
        (held particles: the fraction (s+1)/substeps of their way from x_t to x*)
        `iterations` sweeps: edges, triangles, tool (projection contact), attachments (a closed grasper), walls
                    v = (x - x_start) / h; boundary lines clamp and stop particles
    residual = RMS(C / rest size)

damp = max(0, 1 - c h) (``damping_mode: linear``) or exp(-c h) (``exponential``,
the authors' v *= exp(-8 dt)), c = ``damping``. Walls (``wall_y_bottom/top``)
put every particle that crossed them back on them (:func:`~tissue_sim_ros.core.physics.walls.apply_walls`).
PBD Jacobi averages each particle's corrections over its violated constraints
per type (``jacobi_averaging: violated``, the authors' code,
:mod:`~tissue_sim_ros.core.physics.violated_jacobi`) or over all of them (``all``).

Orders. Serial Gauss-Seidel gives the result of sweeping the constraints in
mesh order, as the paper does (executed in a wavefront schedule that changes
no bit of it, see :func:`~.ordering.wavefront_order`). The parallel path (``parallel=True``;
off by default, see :data:`~.ordering.PARALLEL_MIN_PARTICLES`) cuts the mesh into one part per
thread (:func:`~.ordering.partition_particles`): each thread sweeps its part's
constraints in mesh order, then the constraints across parts are swept. Optionally (``parallel_mode="colour"``)
constraints are sorted by greedy colour (no two constraints of one colour
share a particle) and each colour runs on all threads. Both are still
Gauss-Seidel, in another order: a result differs from the mesh-order sweep's
by what the iterations have not converged plus XPBD's small path dependence
(measured: 2e-3 of a step's displacement), not bit for bit. Neither depends
on thread timing: within a part or a colour the projections are independent.
"""
from __future__ import annotations

import numpy as np

from ...errors import InputError
from ..model import Model, State
from ..step_kernels import SWEEP_JACOBI, SWEEP_VIOLATED, constraint_step
from .base import SolveInfo, SolverBase
from .ordering import JACOBI_RELAXATIONS, ORDERS, PARALLEL_MODES, SolveOrder, solve_order

#: The constraint solver's options (the registry passes these from ``Solver(model, **options)``).
CONSTRAINT_OPTIONS = ("order", "parallel", "parallel_mode", "jacobi_relaxation", "jacobi_average")


def check_order_options(order: str | None, parallel_mode: str, jacobi_relaxation: str) -> None:
    """Refuse an order, parallel mode or relaxation that is not one of the known names."""
    if order is not None and order not in ORDERS:
        raise InputError(f"solver order={order!r}: expected one of {', '.join(ORDERS)}")
    if parallel_mode not in PARALLEL_MODES:
        raise InputError(f"parallel_mode={parallel_mode!r}: expected one of {', '.join(PARALLEL_MODES)}")
    if jacobi_relaxation not in JACOBI_RELAXATIONS:
        raise InputError(f"jacobi_relaxation={jacobi_relaxation!r}: expected one of {', '.join(JACOBI_RELAXATIONS)}")


class Sweep:
    """A sweep strategy's part of :func:`~tissue_sim_ros.core.physics.step_kernels.constraint_step`'s bundle
    ``sweep``: its mode and workspaces (multipliers, relaxations, per-particle scratch)."""

    mode: int = 0

    def __init__(self, n_particles: int, n_edges: int, n_tris: int) -> None:
        n = n_particles
        self.lam_e = np.zeros(n_edges)
        """Multiplier of each edge (solve order) of the current substep, (E,)."""
        self.lam_t = np.zeros(n_tris)
        """Multiplier of each triangle (solve order) of the current substep, (T,)."""
        self.omega_e = np.ones(n_edges)
        self.omega_t = np.ones(n_tris)
        self.mults = (self.lam_e, self.lam_t, self.omega_e, self.omega_t)
        self.jac = (False, 0.0, np.zeros(n), np.ones(n), np.zeros((n, 2)))
        """(stiffness relaxation, relaxation scale, node_sum, particle_scale, dx_acc)."""
        self.violated = (0.0, 0.0, np.zeros((0, 2)), np.zeros(0), np.zeros(0))
        """(tol_e, tol_a, dxa, ns, na): the authors' Jacobi only."""


class GaussSeidel(Sweep):
    """Gauss-Seidel in the solver's order: serial (wavefront-scheduled mesh order, colours, stored), or on all
    threads by parts or colours (``order.gs_mode``)."""

    def __init__(self, n_particles: int, order: SolveOrder) -> None:
        super().__init__(n_particles, order.edges.shape[0], order.tris.shape[0])
        self.mode = order.gs_mode


class Jacobi(Sweep):
    """Jacobi: every constraint sees the sweep's start. XPBD relaxes each constraint by omega_c = 2 relaxation /
    r_c from a Gershgorin bound (``stiffness``) or by ``relaxation`` alone (``uniform``); PBD divides each
    particle's summed correction by its constraint count (``average``, the authors' code) or sums them."""

    mode = SWEEP_JACOBI

    def __init__(self, model: Model, relaxation: str, average: bool) -> None:
        p = model.params
        n = model.n_particles
        super().__init__(n, model.n_edges, model.n_triangles)
        scale = np.ones(n)
        if p.method == "pbd" and average:
            count = np.bincount(model.edge_indices.ravel(), minlength=n) + np.bincount(model.tri_indices.ravel(),
                                                                                      minlength=n)
            scale = 1.0 / np.maximum(count, 1).astype(np.float64)
        if p.method == "xpbd" and relaxation == "uniform":
            self.omega_e[:] = p.relaxation
            self.omega_t[:] = p.relaxation
        # omega_c = 2 relaxation / r_c: steps below 2 / r_c converge for the linearised system
        # (sweeps.jacobi_relaxation), so relaxation in (0, 1) is a fraction of the largest guaranteed step
        self.jac = (p.method == "xpbd" and relaxation == "stiffness", 2.0 * p.relaxation, np.zeros(n), scale,
                    np.zeros((n, 2)))


class ViolatedJacobi(Sweep):
    """The authors' PBD Jacobi: each particle's spring and area corrections averaged over its violated constraints
    of that type, then added (:mod:`~tissue_sim_ros.core.physics.violated_jacobi`); the walls after every
    iteration."""

    mode = SWEEP_VIOLATED

    def __init__(self, model: Model) -> None:
        p = model.params
        n = model.n_particles
        super().__init__(n, model.n_edges, model.n_triangles)
        self.violated = (float(p.jacobi_spring_tolerance), float(p.jacobi_area_tolerance), np.zeros((n, 2)),
                         np.zeros(n), np.zeros(n))


class ConstraintSolver(SolverBase):
    """Steps a Model of distance and area constraints: prediction, sweeps, velocity update, boundary lines.

    Parameters
    ----------
    model : Model
        Topology and parameters (``model.params``: method pbd or xpbd, scheme, iterations, substeps, ...).
    parallel : bool, optional
        Gauss-Seidel on all numba threads. Default (None or False): serial, at
        every mesh size; True is an explicit choice for a machine with free
        cores and a mesh of at least :data:`~.ordering.PARALLEL_MIN_PARTICLES` particles,
        where ``tissue-sim bench solver`` shows it pays (Jacobi is always serial).
    parallel_mode : {"partition", "colour"}
        How Gauss-Seidel runs in parallel. ``partition`` (default): the mesh
        is cut into one part per thread (:func:`~.ordering.partition_particles`); each
        thread sweeps its part's constraints (mesh order, wavefront-scheduled),
        then the few constraints across parts are swept on one thread: one fork-join per
        sweep, and the result does not depend on the thread count's timing.
        ``colour``: constraints sorted by greedy colour, each colour on all
        threads (one fork-join per colour).
    order : {"mesh", "colour", "stored"}, optional
        Serial Gauss-Seidel order. ``mesh`` (default): the result of sweeping
        in mesh order, bit for bit, executed in a wavefront schedule
        (:func:`~.ordering.wavefront_order`) so consecutive projections share no particle
        and overlap in the CPU's pipeline instead of waiting on each other's
        stores. ``colour``: sorted by colour (the
        parallel path's order, on one thread). ``stored``: literally the array
        order (same result as ``mesh``, slower; kept for the benchmark). The
        parallel path uses the order of its ``parallel_mode``.
    jacobi_relaxation : {"stiffness", "uniform"}
        XPBD Jacobi relaxation: per-constraint omega_c = 2 relaxation / r_c from
        a Gershgorin bound r_c (default; stable at any stiffness, see
        :func:`~tissue_sim_ros.core.physics.sweeps.jacobi_relaxation`), or the same
        omega = ``params.relaxation`` for every constraint (diverges for stiff
        constraints; kept to show that).
    jacobi_average : bool
        PBD Jacobi: divide each particle's summed correction by its constraint
        count (the paper authors' code; default), averaged over the violated ones (``jacobi_averaging:
        violated``) or all of them (``all``). False sums them, which blows up for stiff constraints (kept for
        the stability tests).
    """

    options = CONSTRAINT_OPTIONS

    def __init__(self, model: Model, *, parallel: bool | None = None, parallel_mode: str = "partition",
                 order: str | None = None, jacobi_relaxation: str = "stiffness", jacobi_average: bool = True) -> None:
        check_order_options(order, parallel_mode, jacobi_relaxation)
        super().__init__(model)
        p = self.params
        jacobi = p.scheme == "jacobi"
        # serial unless asked: the two-thread path loses to it on a shared machine (PARALLEL_MIN_PARTICLES)
        self.parallel = bool(parallel) and not jacobi
        self.parallel_mode = parallel_mode if self.parallel else None
        so = solve_order(model, parallel_mode if self.parallel else (order or "mesh"), self.parallel, jacobi)
        self.order = so.name
        self.edges, self.rest, self.edge_offsets = so.edges, so.rest, so.edge_offsets
        self.tris, self.area0, self.tri_offsets = so.tris, so.area0, so.tri_offsets
        if jacobi and p.method == "pbd" and jacobi_average and p.jacobi_averaging == "violated":
            self.sweep: Sweep = ViolatedJacobi(model)
        elif jacobi:
            self.sweep = Jacobi(model, jacobi_relaxation, jacobi_average)
        else:
            self.sweep = GaussSeidel(model.n_particles, so)
        self.pbd = p.method == "pbd"
        self.use_e = (p.k_spring > 0.0) if self.pbd else (p.stiffness_spring > 0.0)
        self.use_t = (p.k_area > 0.0) if self.pbd else (p.stiffness_area > 0.0)
        no_float = np.zeros(0)
        edge_set = (self.edges, self.rest, self.edge_offsets) if self.use_e else (self._no_edges, no_float,
                                                                                   self.edge_offsets)
        tri_set = ((self.tris, self.area0, self.tri_offsets) if self.use_t
                   else (np.zeros((0, 3), dtype=np.int32), no_float, self.tri_offsets))
        self._sets = (edge_set, tri_set, (self.edges, self.rest, self.tris, self.area0), self.signed)
        """The compiled step's ``sets``: the active constraints in solve order, all of them (the residual), signed."""
        self.x_start = np.zeros((model.n_particles, 2))
        """Positions at the start of the current substep [m], (N, 2)."""

    @property
    def n_projections_per_step(self) -> int:
        """Constraint projections in one step (iterations x substeps x active constraints)."""
        p = self.params
        n_c = (self.edges.shape[0] if self.use_e else 0) + (self.tris.shape[0] if self.use_t else 0)
        return n_c * p.iterations * p.substeps

    def coefficients(self, h: float) -> tuple[float, float, float, float]:
        """(k_e, alpha_e, k_t, alpha_t) for a substep h: PBD's coefficients with alpha 0, or XPBD's k = 1 and
        alpha = 1 / (stiffness h^2) (an inactive type: k 1, alpha 0, its constraints not swept)."""
        p = self.params
        if self.pbd:
            return float(p.k_spring), 0.0, float(p.k_area), 0.0
        alpha_e = 1.0 / (p.stiffness_spring * h * h) if self.use_e else 0.0
        alpha_t = 1.0 / (p.stiffness_area * h * h) if self.use_t else 0.0
        return 1.0, alpha_e, 1.0, alpha_t

    def step(self, state_in: State, state_out: State, contacts, dt: float) -> SolveInfo:
        """Advance ``state_in`` by ``dt`` into ``state_out`` in one compiled call (module docstring)."""
        step, h, state, pred, tool, attach = self.sweep_bundles(state_in, state_out, contacts, dt, self.x_start)
        sw = self.sweep
        residual = constraint_step(state, pred, self.timing(dt, h), self.bounds, self._sets,
                                   (sw.mode, self.params.iterations, self.coefficients(h), sw.mults, sw.jac,
                                    sw.violated), tool, attach)
        return self.finish(contacts, step, residual)
