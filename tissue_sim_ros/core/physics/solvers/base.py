"""The solver protocol: one class per method, made once per Model, stepping ``(state_in, state_out, contacts, dt)``.

A solver holds its workspaces (multipliers, scratch arrays, orders, factors) and the options it was made with; its
:meth:`~SolverBase.step` advances ``state_in`` by ``dt`` into ``state_out`` with the step's
:class:`~tissue_sim_ros.core.contact.collision.Contacts` (the tool: the paper contact's held particles or the
projection's candidates and shapes; the grasp's attachments) and returns a :class:`SolveInfo`. Nothing a step
reads was fixed at construction and looked up again: the solver's options, the model's constants and the bundles
its compiled step takes are made in the constructor. The registry (:mod:`~tissue_sim_ros.core.physics.solvers`)
picks the class from the configuration.

What every solver shares lives here: the step's argument checks (the kernels index without bounds checks), the
grasp's attachments, the damping factor, the tool's shape per substep and the contact set it reports.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ...contact.collision import Contacts
from ...errors import InputError
from ..model import Model, State


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
    tool_q: np.ndarray | None = None
    """Barrier contact: where the tool ended, (x, y, yaw, jaw) (4,); None: no tool, or it is where commanded."""
    tool_path: tuple[np.ndarray, np.ndarray] | None = None
    """Barrier contact: the particles (P + 1, N, 2) and the tool's dofs (P + 1, 4) at the step's start and at the
    end of each part the command was approached in (the run-time checks follow the step along it)."""
    tool_force: np.ndarray | None = None
    """Barrier contact: the tissue's force and torque on the tool (F_x, F_y [N], torque about the pose [N m], on
    the jaw [N m]) (4,); None: the Simulation computes the reaction from ``contact_dx``."""
    tool_lag: tuple[float, float] | None = None
    """Barrier contact: how far the tool stopped short of its command (distance [m], angle [rad])."""
    contact_energy: np.ndarray | None = None
    """Barrier contact: dt^2 kappa sum b per body [kg m^2] (the ``contact`` energy term)."""
    contact_gap: np.ndarray | None = None
    """Barrier contact: the smallest gap between the tool and each body [m] (inf: none within reach)."""
    in_contact: np.ndarray | None = None
    """Barrier contact: per body, True when the tool touches it (a pair closer than dhat)."""
    contact_force: np.ndarray | None = None
    """Barrier contact: the net force every contact (the tool, other bodies, itself) puts on each body [N] (B, 2)."""
    refactored: bool = False
    """Barrier contact: the step refreshed its Hessian's factor."""


@dataclass
class StepInput:
    """One step's contacts, checked and contiguous (:meth:`SolverBase.check_step`)."""

    held_idx: np.ndarray
    """The paper contact's held particles, (K,) int32."""
    held_dx: np.ndarray
    """Their displacements [m], (K, 2)."""
    candidates: np.ndarray
    """The projection's candidate particles, (C,) int32."""
    surface_edges: np.ndarray
    """The projection's candidate boundary edges, (K, 2) int32."""
    projection: bool
    """True when either candidate set is non-empty (the projection contact runs)."""


def interpolate_shape(s0: np.ndarray, s1: np.ndarray, f: float, out: np.ndarray) -> None:
    """Tool shape at fraction f of the step: centre linear, angle via the normalised (cos, sin)."""
    out[:] = s0 + f * (s1 - s0)
    norm = math.hypot(out[2], out[3])
    if norm > 1e-12:
        out[2] /= norm
        out[3] /= norm
    else:  # half a turn within one step: take the end orientation
        out[2], out[3] = s1[2], s1[3]


def substep_shapes(contacts: Contacts, n_sub: int, out: np.ndarray) -> np.ndarray:
    """The tool packed at fraction s / n_sub of the step, s = 0 .. n_sub, into ``out`` (resized when its row count
    differs): (n_sub + 1, 7)."""
    if out.shape[0] != n_sub + 1:
        out = np.zeros((n_sub + 1, 7))
    s0 = np.ascontiguousarray(contacts.tool_shape0, dtype=np.float64)
    s1 = np.ascontiguousarray(contacts.tool_shape1, dtype=np.float64)
    for sub in range(n_sub + 1):
        interpolate_shape(s0, s1, sub / n_sub, out[sub])
    return out


class SolverBase:
    """One method's solver: what the Simulation steps with.

    Subclasses take the Model and their own keyword options (named in :attr:`options`, which the registry's
    :func:`~tissue_sim_ros.core.physics.solvers.Solver` passes on) and implement :meth:`step`.

    Parameters
    ----------
    model : Model
        Topology and parameters (``model.params``).
    """

    #: The keyword options the constructor takes besides the model.
    options: ClassVar[tuple[str, ...]] = ()

    def __init__(self, model: Model) -> None:
        p = model.params
        self.model = model
        self.params = p
        n = model.n_particles
        self.x_pred = np.zeros((n, 2))
        """Full-step prediction x* [m], (N, 2)."""
        self.inv_mass_eff = np.zeros(n)
        """Inverse masses of this step (held particles zeroed) [1/kg], (N,)."""
        self.contact_dx = np.zeros((n, 2))
        """Summed projection-contact corrections of the step [m], (N, 2)."""
        self.lam_a = np.zeros((0, 2))
        """Multipliers of the attachments (contacts.attach_idx, core/physics/attach.py) of the current substep, (K, 2)."""
        self.walls = not (math.isnan(p.wall_y_bottom) and math.isnan(p.wall_y_top))
        self.bounds = (self.walls, float(p.wall_y_bottom), float(p.wall_y_top), float(p.boundary_y_top),
                       float(p.boundary_y_bottom))
        """(walls, wall_y_bottom, wall_y_top, y_top, y_bottom) [m]: the compiled steps' ``bounds``."""
        self.signed = p.area_mode == "signed"
        self._damping = float(p.damping)
        self._exponential = p.damping_mode == "exponential"
        self._no_index = np.zeros(0, dtype=np.int32)
        self._no_edges = np.zeros((0, 2), dtype=np.int32)
        self._shapes = np.zeros((0, 7))
        self._shape0 = np.zeros(7)
        self._shape1 = np.zeros(7)

    def step(self, state_in: State, state_out: State, contacts: Contacts, dt: float) -> SolveInfo:
        """Advance ``state_in`` by ``dt`` into ``state_out`` (which must not alias ``state_in``).

        Parameters
        ----------
        state_in, state_out : State
            Positions [m] and velocities [m/s], (N, 2) float64 C-contiguous.
        contacts : Contacts
            The contact model's output for this step; ``contacts.touched`` is filled here.
        dt : float
            Time step [s].
        """
        raise NotImplementedError

    @property
    def n_projections_per_step(self) -> int:
        """Constraint projections (or element solves) in one step, for benchmarks."""
        return 0

    def damp_factor(self, h: float) -> float:
        """Velocity scale of one (sub)step h: max(0, 1 - c h) (linear) or exp(-c h) (exponential)."""
        c = self._damping
        return math.exp(-c * h) if self._exponential else max(0.0, 1.0 - c * h)

    def check_step(self, state_in: State, state_out: State, contacts: Contacts, dt: float) -> StepInput:
        """The step's arguments checked (InputError naming the first bad one), its contact sets contiguous."""
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
        # the kernels index without bounds checks: refuse indices outside the model here
        for name, idx in (("contacts.held_idx", held_idx), ("contacts.candidates", candidates),
                          ("contacts.surface_edges", surface_edges.ravel())):
            if idx.shape[0] and (idx.min() < 0 or idx.max() >= n):
                raise InputError(f"{name} must lie in [0, {n}); got [{idx.min()}, {idx.max()}]")
        if held_dx.shape[0] != held_idx.shape[0]:
            raise InputError(f"contacts.held_dx has {held_dx.shape[0]} rows for {held_idx.shape[0]} held particles")
        projection = candidates.shape[0] > 0 or surface_edges.shape[0] > 0
        return StepInput(held_idx, held_dx, candidates, surface_edges, projection)

    def attachments(self, contacts: Contacts) -> tuple[np.ndarray, np.ndarray, float]:
        """The step's attachments (``contacts.attach_*``, core/physics/attach.py) checked and contiguous:
        (idx (K,) int64, target (K, 2) float64 [m], compliance [m/N]); sizes the multipliers ``lam_a``."""
        n = self.model.n_particles
        idx = np.ascontiguousarray(getattr(contacts, "attach_idx", self._no_index), dtype=np.int64).reshape(-1)
        target = np.ascontiguousarray(getattr(contacts, "attach_target", np.zeros(0)), dtype=np.float64)
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

    def sweep_bundles(self, state_in: State, state_out: State, contacts: Contacts, dt: float,
                      x_start: np.ndarray) -> tuple[StepInput, float, tuple, tuple, tuple, tuple]:
        """What a substepping solver's compiled step takes besides its own bundles: (the checked step, h = dt /
        substeps, state, pred, tool, attach), the tool's shape per substep made here (:func:`substep_shapes`) and
        the contact corrections cleared when the projection runs."""
        n_sub = self.params.substeps
        h = dt / n_sub
        step = self.check_step(state_in, state_out, contacts, dt)
        if step.projection:
            self.contact_dx.fill(0.0)
            self._shapes = shapes = substep_shapes(contacts, n_sub, self._shapes)
        else:
            shapes = np.zeros((0, 7))
        a_idx, a_target, a_compliance = self.attachments(contacts)
        state = (state_in.particle_q, state_in.particle_qd, state_out.particle_q, state_out.particle_qd)
        pred = (self.model.particle_inv_mass, self.inv_mass_eff, self.x_pred, x_start, step.held_idx, step.held_dx)
        tool = (step.candidates, step.surface_edges, float(contacts.edge_side_tol), shapes, self._shape0,
                self._shape1, self.contact_dx)
        return step, h, state, pred, tool, (a_idx, a_target, a_compliance / (h * h), self.lam_a)

    def timing(self, dt: float, h: float) -> tuple:
        """(dt, substeps, gravity, the damping over dt, over h): the compiled steps' ``timing``."""
        return (dt, self.params.substeps, self.params.gravity, self.damp_factor(dt), self.damp_factor(h))

    def finish(self, contacts: Contacts, step: StepInput, residual: float) -> SolveInfo:
        """The step's :class:`SolveInfo`; ``contacts.touched``: the particles the projection moved, or the paper
        contact's held ones."""
        if step.projection:
            moved = np.flatnonzero((self.contact_dx[:, 0] != 0.0) | (self.contact_dx[:, 1] != 0.0))
            contacts.touched = moved.astype(np.int32)
        elif step.held_idx.shape[0]:
            contacts.touched = step.held_idx.copy()
        return SolveInfo(x_pred=self.x_pred, contact_dx=self.contact_dx if step.projection else None,
                         residual=float(residual))
