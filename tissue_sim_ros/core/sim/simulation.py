"""Simulation: one scene stepped with a tool, returning a StepReport per step.

The data flow of one step::

    tool pose/twist --detect--> Contacts --Solver.step--> State --> energy, reaction, report

The Simulation owns the Model, the current State, the Solver (workspaces) and
the contact model; it never imports ROS.

Every caller steps through it, benchmarks included. What a benchmark needs
beyond the report::

    sim.place_tool(pose0)                      # the tool where the next step starts, no step taken
    report = sim.step(pose1, detail=True)      # report.detail: StepDetail (start State, Contacts, SolveInfo)
    state, info = sim.solve(report.detail, iterations=64)      # the same step again, other parameters
    state, info = sim.solve(report.detail, solver=exact)       # ... or another solver (an exact reference)
    sim.use_solver(factory)                    # step with another solver from now on (kept by retune)
"""
from __future__ import annotations

import copy
import math
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from ..config import BY_NAME, Config
from ..contact.collider import ToolCollider, clear_start, core_positions, pose_dofs, tool_geometry
from ..contact.collision import ContactModel, Contacts
from ..contact.tool import ToolPose, ToolShape, ToolTwist, tool_shape_array, twist_from_poses
from ..contact.tool_checks import INSIDE_TOL, outline_checks, tool_checks
from ..errors import InputError
from ..physics.energy import NO_ATTACH, EnergyTerms, energy_model
from ..physics.kernels import count_inverted
from ..physics.model import Model, State
from ..physics.reaction import attach_reaction, push_reaction, touched_particles
from ..physics.solvers import SolveInfo, default_solver
from ..physics.step_kernels import finish_step
from .grasp import Grasp
from .snapshot import SimSnapshot, carry_state, restore_carry, scene_key

if TYPE_CHECKING:
    from ..mesh import TissueMesh

#: The jaw angle a grasper is open at until a jaw is given [rad] (barrier contact: its jaws are solid).
OPEN_JAW = 0.8

SolverFactory = Callable[[Model], Any]
"""Makes the solver of a Model (a :class:`~tissue_sim_ros.core.physics.solvers.Solver` or one with its step())."""


@dataclass
class StepDetail:
    """One step's solve as the solver saw it: kept on the report by ``Simulation.step(..., detail=True)``.

    Everything is a copy (or, for ``contacts``, the step's own object, which no later step touches), so it
    stays valid after the next steps; :meth:`Simulation.solve` solves the same step again from it.
    """

    state_in: State
    """Positions [m] and velocities [m/s] at the start of the step (a copy), (N, 2) each."""
    contacts: Contacts
    """The step's contacts as the solver got them (``touched`` filled by the solver; with projection contact
    ``in_contact`` is set after the solve)."""
    info: Any
    """The solver's :class:`~tissue_sim_ros.core.physics.solvers.SolveInfo` of the step (its arrays copied:
    ``x_pred``, ``contact_dx``), or what another solver's ``step`` returned."""
    tool_pose0: ToolPose | None
    """Tool pose at the start of the step (None: no tool)."""
    tool_pose1: ToolPose | None
    """Tool pose at the end of the step (None: no tool)."""
    dt: float
    """Time step [s]."""


def _detached(info: Any) -> Any:
    """A shallow copy of a solver's info with its arrays copied (they are the solver's workspaces)."""
    if isinstance(info, SolveInfo):
        return SolveInfo(x_pred=info.x_pred.copy(), contact_dx=None if info.contact_dx is None else
                         info.contact_dx.copy(), residual=info.residual, solve_iterations=info.solve_iterations,
                         solve_residual=info.solve_residual, solve_converged=info.solve_converged)
    out = copy.copy(info)
    for name, value in vars(out).items() if hasattr(out, "__dict__") else ():
        if isinstance(value, np.ndarray):
            setattr(out, name, value.copy())
    return out


@dataclass
class StepReport:
    """What one step did: energy, solver residual, contact, reaction and timings."""

    step: int
    """Index of the step just taken (1 for the first step)."""
    time: float
    """Simulated time at the end of the step [s]."""
    energy: EnergyTerms
    """Implicit Euler energy terms per body and in total [kg m^2 for xpbd; PBD-coefficient units for pbd]."""
    residual: float
    """Solver residual after the solve: RMS constraint violation (edges [m], areas [m^2] scaled by rest size)."""
    in_contact: np.ndarray
    """Per body: True where the tool touches (paper: d* < alpha; projection: any particle pushed), shape (B,)."""
    d_star: np.ndarray
    """Per body: tool-tissue distance d* [m] (inf when no tool), shape (B,)."""
    n_contact_particles: int
    """Particles moved by the contact model this step."""
    contact_particles: np.ndarray
    """Indices of the particles moved by the contact model this step, int32."""
    reaction_force: np.ndarray
    """Tissue's reaction on the tool [N], shape (2,): - sum m dx / (dt h) over projection contact corrections
    (h = dt / substeps: the mean over the substeps), - sum m dx / dt^2 over the paper contact's held displacements."""
    reaction_torque: float
    """Torque of the reaction about the tool centre [N m] (about +z)."""
    n_inverted: int
    """Triangles whose signed area is <= 0 after the step."""
    diverged: bool
    """True if the solve produced NaN/inf and the previous state was restored."""
    timings: dict[str, float] = field(default_factory=dict)
    """Wall time of each phase [s]: contact, solve, energy, total."""
    x_pred: np.ndarray | None = None
    """The step's prediction x* [m], shape (N, 2) (the paper contact's held displacements included): with the
    published positions x it gives the energy, E = 1/2 sum m |x - x*|^2 + dt^2 E_p(x)."""
    held_idx: np.ndarray | None = None
    """Paper contact: the particles displaced and held this step, int32 (empty for projection)."""
    held_dx: np.ndarray | None = None
    """Paper contact: their displacements [m], shape (K, 2) (x* = free prediction + held_dx there)."""
    n_penetrating: int = 0
    """Particles inside the tool's shape (no margin) after the step."""
    penetration_depth: float = 0.0
    """Depth of the deepest of them inside the tool [m] (0 when none)."""
    deepest_particle: int = -1
    """Index of that particle (-1 when none)."""
    n_tunnelled: int = 0
    """Particles whose path relative to the tool ran through it within the step (``core/contact/tool_checks.py``)."""
    tool_buried: bool = False
    """True when a point of the tool's axis lies inside a triangle of the deformed tissue (the tool is buried in it)."""
    grasped: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    """Particles the grasper's jaw held during this step (``core/sim/grasp.py``), int64 (empty: none)."""
    attach_force: np.ndarray = field(default_factory=lambda: np.zeros(2))
    """The held particles' pull on the tool [N], (2,): sum (x - target) / grasp_compliance (included in
    ``reaction_force``)."""
    solve_iterations: int = 0
    """Material: iterations the step's solve took (quasi_newton; xpbd its fixed count); 0 for the constraint model."""
    solve_residual: float = math.nan
    """Material: the step's estimated relative error against its exact (implicit Euler) step: the correction a
    quasi-Newton iteration would still make, over the step's motion (``core/physics/quasi_newton.py``; xpbd: of its
    last substep); NaN for the constraint model."""
    solve_converged: bool = True
    """Material: ``solve_residual <= solve_tolerance``. False: the step stopped short of its own minimiser (a
    softer tissue than the material, or a stiffer one); the node warns and counts it."""
    detail: StepDetail | None = None
    """The step's start State, Contacts and solver info when asked (``Simulation.step(..., detail=True)``), else None."""
    tool_applied: ToolPose | None = None
    """Where the tool is at the end of the step: the commanded pose, or with barrier contact where the tissue let
    it go (``tool_lag`` short of the command); the next step starts there. None: no tool this step."""
    tool_lag: float = 0.0
    """Barrier contact: how far the tool stopped short of its commanded position [m] (0: it got there)."""
    tool_lag_angle: float = 0.0
    """Barrier contact: how far its yaw stopped short of the command [rad]."""
    contact_force: np.ndarray | None = None
    """Barrier contact: the net force every contact (the tool, the other bodies, the body itself; barriers and
    friction) puts on each body [N], shape (B, 2); None for the other contact models."""


class Simulation:
    """One scene: Model + State + Solver + tool contact.

    Build one with :meth:`from_config` (the one way the node, the commands and
    the library do) or from a Model directly.

    Parameters
    ----------
    model : Model
        Topology, rest state and parameters (``model.params``).
    tool : ToolShape, optional
        Shape of the tool; without it the tissue only feels gravity.
    solver : callable, optional
        ``solver(model)`` makes the solver (default: :func:`default_solver`); it is
        called again with the new Model by :meth:`retune`.
    config : Config, optional
        The configuration the scene was built from (kept for :meth:`retune`).
    """

    def __init__(self, model: Model, tool: ToolShape | None = None, solver: SolverFactory | None = None,
                 config: Config | None = None) -> None:
        self.model = model
        self.params = model.params
        self.tool = tool
        self.config = config
        self._solver_factory: SolverFactory = solver or default_solver
        self.solver = self._solver_factory(model)
        self.contact = ContactModel(model, tool) if tool is not None else None
        self._bind_model()
        self.state: State = model.state()
        self._state_out: State = model.state()
        self.step_count = 0
        self.time = 0.0
        self.tool_pose: ToolPose | None = None
        self._last_good: State = self.state.copy()
        self.lock = threading.RLock()
        """Held by :meth:`step`, :meth:`snapshot` and :meth:`restore`: a planner thread snapshots a stepping scene."""
        self._scene_key: str | None = None
        self._settled: State | None = None
        self.report_tool_checks = True
        """Fill the report's penetration, tunnelling and buried-tool fields each step (``core/contact/tool_checks.py``, ~15 us
        of a paper-scene step); batch rollouts' scratch simulations turn it off (they measure what they report)."""
        self.grasp = Grasp()
        """The grasper's jaw: its angle, closed or open, the particles it holds (``core/sim/grasp.py``)."""
        self.tool_jaw: float | None = None
        """Barrier contact: the jaw angle the tool was left at [rad] (the tissue may stop a closing jaw); None
        before the first step."""
        self._tool_left_free = False
        """The barrier contact's tool was left by a step (free of the tissue by construction)."""
        self.tool_command: ToolPose | None = None
        """Barrier contact: the last commanded pose (the tool may have stopped short of it, at ``tool_pose``)."""
        self.jaw_command: float | None = None
        """Barrier contact: the last commanded jaw angle [rad]."""
        self.settle_info = None
        """:class:`~tissue_sim_ros.core.physics.statics.SettleInfo` of the last :meth:`settle` (None before)."""
        if self.params.settle == "static":
            self.settle()

    @property
    def scene_key(self) -> str:
        """Fingerprint of the model's topology and rest shape (:func:`~tissue_sim_ros.core.sim.snapshot.scene_key`)."""
        if self._scene_key is None:
            self._scene_key = scene_key(self.model)
        return self._scene_key

    def snapshot(self) -> SimSnapshot:
        """Everything the next steps read, copied: restore it here or in another Simulation of the same scene."""
        with self.lock:
            return SimSnapshot(
                scene=self.scene_key, particle_q=self.state.particle_q.copy(), particle_qd=self.state.particle_qd.copy(),
                last_good_q=self._last_good.particle_q.copy(), last_good_qd=self._last_good.particle_qd.copy(),
                step_count=self.step_count, time=self.time, tool_pose=self.tool_pose,
                solver=carry_state(self.solver), contact=carry_state(self.contact), grasp=self.grasp.carry_state(),
                tool_jaw=self.tool_jaw, tool_command=self.tool_command, jaw_command=self.jaw_command)

    def restore(self, snap: SimSnapshot) -> None:
        """Continue from ``snap`` (copied): the next step is bit for bit the one that followed the snapshot.

        Raises InputError when ``snap`` comes from another scene (other topology or rest shape).
        """
        if not isinstance(snap, SimSnapshot):
            raise InputError(f"restore({type(snap).__name__}): expected a SimSnapshot from Simulation.snapshot()")
        if snap.scene != self.scene_key:
            raise InputError(f"snapshot of scene {snap.scene[:8]} ({snap.n_particles} particles): expected one of this "
                             f"scene, {self.scene_key[:8]} ({self.model.n_particles} particles)")
        with self.lock:
            np.copyto(self.state.particle_q, snap.particle_q)
            np.copyto(self.state.particle_qd, snap.particle_qd)
            np.copyto(self._last_good.particle_q, snap.last_good_q)
            np.copyto(self._last_good.particle_qd, snap.last_good_qd)
            self.step_count = int(snap.step_count)
            self.time = float(snap.time)
            self.tool_pose = snap.tool_pose
            restore_carry(self.solver, snap.solver)
            restore_carry(self.contact, snap.contact)
            self.grasp.restore_carry(snap.grasp)
            self.tool_jaw = snap.tool_jaw
            self.tool_command = snap.tool_command
            self.jaw_command = snap.jaw_command
            self._tool_left_free = False

    @classmethod
    def from_config(cls, cfg: Config, mesh: "TissueMesh | None" = None,
                    solver: SolverFactory | None = None) -> "Simulation":
        """The scene a resolved configuration describes.

        Parameters
        ----------
        cfg : Config
            From :func:`~tissue_sim_ros.core.config.resolve_config`.
        mesh : TissueMesh, optional
            Use this mesh instead of building ``cfg.scene``'s (a benchmark's strip, a cached mesh).
        solver : callable, optional
            ``solver(model)`` makes the solver (default: what the parameters ask for).
        """
        mesh = mesh if mesh is not None else cfg.scene.build_mesh()
        return cls(Model.from_mesh(mesh, cfg.sim), tool=cfg.tool, solver=solver, config=cfg)

    def retune(self, cfg: Config) -> None:
        """Apply tunable changes (iterations, stiffness, contact model...) and keep state, time and tool pose.

        Raises InputError naming the first changed parameter that is read-only
        (the mesh, dt, masses, boundary lines, the tool shape: a new scene).
        """
        if self.config is not None:
            for name in self.config.changed(cfg):
                if BY_NAME[name].read_only:
                    raise InputError(f"parameter {name} is read-only: it defines the scene; build a new "
                                     "simulation (restart the node) to change it")
        state, last_good = self.state.copy(), self._last_good.copy()
        model = self.model.with_params(cfg.sim)
        self.model = model
        self.params = model.params
        self.config = cfg
        self.solver = self._solver_factory(model)
        self.contact = ContactModel(model, self.tool) if self.tool is not None else None
        self._bind_model()
        self.state, self._state_out, self._last_good = state, model.state(), last_good

    def _bind_model(self) -> None:
        """The step's model bundles and scratch (:func:`~tissue_sim_ros.core.physics.energy.energy_model`, the
        reaction's per-particle torques), made again when the model changes."""
        n = self.model.n_particles
        self._energy_model = energy_model(self.model)
        self._geometry = tool_geometry(self.tool) if self.tool is not None else None
        self._touched = np.empty(n, dtype=np.int64)
        self._torque_each = np.empty(n)

    def settle(self):
        """Put the tissue at its static equilibrium under gravity and the pins, at rest; returns its SettleInfo.

        Newton's method on strain energy + gravity's potential (:func:`~tissue_sim_ros.core.physics.statics.settle_static`;
        ``material: neo_hookean`` only, else InputError). Time and step count are unchanged. With ``settle:
        static`` the simulation starts here and :meth:`reset` comes back here (solved once, kept).
        """
        from ..physics.statics import settle_static  # noqa: PLC0415  (SciPy: only a scene that settles needs it)

        if not self.model.is_material:
            raise InputError(f"settle with material={self.params.material!r}: expected material neo_hookean "
                             "(static settle minimises the material's energy in joules)")
        with self.lock:
            state, info = settle_static(self.model)
            self._settled = state.copy()
            self.settle_info = info
            self.set_state(state)
            return info

    def warm_up(self) -> None:
        """A few throwaway steps with the tool in the tissue, then :meth:`reset`: the numba kernels and python-fcl
        are loaded (or compiled) now, not in the first real step (the node's first tick, a pool worker's first
        candidate)."""
        q0 = self.model.particle_q0
        if len(q0) == 0:
            return
        cx, cy = (q0.min(axis=0) + q0.max(axis=0)) / 2.0
        self.step(None)
        if self.tool is not None:
            self.step(ToolPose(float(cx), float(cy), 0.0))
            self.step(ToolPose(float(cx) + 1e-3, float(cy), 0.0))
        self.reset()

    def reset(self) -> None:
        """Back to t = 0 (tool pose forgotten), at rest in the rest shape, or at the static equilibrium with
        ``settle: static``."""
        with self.lock:
            if self.params.settle == "static" and self._settled is None:
                self.settle()
            self.state = self._settled.copy() if self.params.settle == "static" else self.model.state()
            self._state_out = self.model.state()
            self._last_good = self.state.copy()
            self.step_count = 0
            self.time = 0.0
            self.tool_pose = None
            self.grasp.reset()
            reset_carry = getattr(self.solver, "reset_carry", None)
            if reset_carry is not None:
                reset_carry()  # (the barrier step's lagged factor and its stiffness: as built)
            self.tool_jaw = None
            self.tool_command = None
            self.jaw_command = None
            self._tool_left_free = False

    def set_state(self, state: State) -> None:
        """Replace the current state (copied)."""
        self.state = state.copy()
        self._last_good = state.copy()
        self._tool_left_free = False

    def place_tool(self, pose: ToolPose | None) -> None:
        """Put the tool at ``pose`` without stepping: the next step moves it from there (its twist, by default,
        and the projection contact's sweep start at ``pose``). None: no tool yet (the next step starts where it ends).

        A new insertion starts here (batch rollouts, a benchmark's first pose); the state is unchanged.
        """
        with self.lock:
            self.tool_pose = pose
            self.tool_command = pose
            self._tool_left_free = False

    def tool_overlaps_tissue(self, pose: ToolPose) -> bool:
        """True when the tool at ``pose`` (its own shape, no margin) holds a particle or lies inside a triangle of
        the current state (``core/contact/tool_checks.py``): a pose where it cannot be put without passing
        through the tissue. False without a tool."""
        if self.tool is None:
            return False
        x = self.state.particle_q
        n_in, _, _, _, buried = self._tool_checks(x, x, pose, pose)
        return bool(n_in) or bool(buried)

    def use_solver(self, solver: SolverFactory) -> None:
        """Step with ``solver(model)`` from now on, instead of the solver made so far (and after :meth:`retune`).

        Parameters
        ----------
        solver : callable
            Makes the solver of a Model, e.g. ``functools.partial(Solver, parallel=False)`` or
            ``functools.partial(SleepingSolver, sleep_speed=1e-3)``. The old solver's carried state (a
            sleeping set) is dropped; the State is unchanged.
        """
        with self.lock:
            self._solver_factory = solver
            self.solver = solver(self.model)

    def solve(self, detail: StepDetail, solver: SolverFactory | None = None, **changes: Any) -> tuple[State, Any]:
        """Solve a kept step again: from its start state with its contacts, the simulation left unchanged.

        The step's own solve (``detail`` of a report of :meth:`step` with ``detail=True``) with other
        parameters or another solver: the residual after 1, 4, 16, 64 iterations of the same step, or the
        exact solve of the step (a benchmark's reference). With neither, the result equals the step's own
        bit for bit (for a solver that carries nothing between steps).

        Parameters
        ----------
        detail : StepDetail
            The step (its start State and Contacts are copied, not changed).
        solver : callable, optional
            ``solver(model)`` makes the solver that solves it (default: this simulation's kind, made afresh:
            nothing carried over from earlier steps, so a sleeping solver starts awake).
        **changes
            SimParams fields to change for this solve (``iterations=16``, ``substeps=4``), validated.

        Returns
        -------
        state : State
            Positions and velocities at the end of the step (not checked for NaN: a diverged solve stays so).
        info : SolveInfo
            The solver's info (arrays of the fresh solver, valid as long as they are kept).
        """
        model = self.model.with_params(self.params.with_(**changes)) if changes else self.model
        make = solver or self._solver_factory
        state_in = detail.state_in.copy()  # a sleeping solver zeroes its sleepers' velocities in place
        contacts = copy.copy(detail.contacts)  # the solver sets contacts.touched
        state_out = model.state()
        info = make(model).step(state_in, state_out, contacts, detail.dt)
        return state_out, info

    def step(self, tool_pose: ToolPose | None = None, tool_twist: ToolTwist | None = None, *,
             jaw: float | None = None, detail: bool = False) -> StepReport:
        """Advance one time step dt.

        Parameters
        ----------
        tool_pose : ToolPose, optional
            Tool pose at the end of this step (the commanded pose). None: no tool this step.
        tool_twist : ToolTwist, optional
            Tool velocity. None: derived from the previous and this pose over dt.
        jaw : float, optional
            The grasper's jaw angle [rad] (``tool_shape: grasper``): closing below ``grasp_close_angle`` grasps
            what lies within ``grasp_radius`` of the tip, opening above ``grasp_open_angle`` releases it
            (``core/sim/grasp.py``). None: the last angle given (open before any).
        detail : bool
            Keep the step's start State, Contacts and solver info on the report (``report.detail``, a
            :class:`StepDetail`: copies, for :meth:`solve` and benchmarks); the step itself is the same.
        """
        with self.lock:
            return self._step(tool_pose, tool_twist, keep=detail, jaw=jaw)

    def _contacts(self, tool_pose: ToolPose | None, tool_twist: ToolTwist | None, jaw: float | None) -> Contacts:
        """The step's contacts: the contact model's detection (the tool from where it is to ``tool_pose``), then
        the jaw, which closes (grasps at the step's start pose) or opens; held particles follow the end pose."""
        p = self.params
        if self.contact is not None and tool_pose is not None and p.contact_model != "none":
            contacts = self.contact.detect(self.state, self.tool_pose or tool_pose, tool_pose, tool_twist, p.dt)
        else:
            contacts = Contacts.empty(self.model.n_bodies)
        grasper = self.tool is not None and self.tool.kind == "grasper"
        self.grasp.update(jaw, grasper, (self.tool_pose or tool_pose) if tool_pose is not None else None,
                          self.state.particle_q, self.model.particle_inv_mass, p.grasp_close_angle,
                          p.grasp_open_angle, p.grasp_radius)
        if self.grasp.n_held and tool_pose is not None:
            contacts.attach_idx = self.grasp.idx.copy()
            contacts.attach_target = self.grasp.targets(tool_pose)
            contacts.attach_local = self.grasp.local.copy()
            contacts.attach_compliance = float(p.grasp_compliance)
        if p.contact_model == "barrier" and self.tool is not None and tool_pose is not None:
            # the tool's jaw: the command (open until one is given), from where it was left
            jaw1 = (self.grasp.jaw if self.grasp.jaw is not None else OPEN_JAW) if self.tool.kind == "grasper" else 0.0
            jaw0 = self.tool_jaw if self.tool_jaw is not None else jaw1
            contacts.tool_collider = ToolCollider.make(self.tool, self._geometry, self._free_start(tool_pose, jaw0),
                                                       tool_pose, jaw0, jaw1, self.tool_command, self.jaw_command)
        return contacts

    def _free_start(self, tool_pose: ToolPose, jaw: float) -> ToolPose:
        """Where the barrier contact's tool starts the step: where it was left, or (a first pose, a placed one, a
        restored one) that pose moved out of the tissue by the least distance if it lies in it
        (``core/contact/collider.py``'s ``clear_start``): the tool then moves in as commanded, and stops short
        where the tissue cannot make room, instead of starting inside it."""
        start = self.tool_pose or tool_pose
        if self._tool_left_free:
            return start
        edges = self.solver.boundary_edges
        q = clear_start(pose_dofs(start, jaw), self._geometry, self.state.particle_q, edges, self.model.tri_indices,
                        2.0 * self.solver.dhat)
        return ToolPose(float(q[0]), float(q[1]), start.yaw)

    def _step(self, tool_pose: ToolPose | None, tool_twist: ToolTwist | None, keep: bool = False,
              jaw: float | None = None) -> StepReport:
        """:meth:`step`: detection, the solver's one compiled call, the post-solve call, the reaction."""
        t_start = time.perf_counter()
        p = self.params
        model = self.model
        if tool_pose is not None and tool_twist is None:
            tool_twist = twist_from_poses(self.tool_pose, tool_pose, p.dt)
        contacts = self._contacts(tool_pose, tool_twist, jaw)
        state_in = self.state.copy() if keep else None  # before the solve: a sleeping solver writes into it
        t_contact = time.perf_counter()
        info = self.solver.step(self.state, self._state_out, contacts, p.dt)
        t_solve = time.perf_counter()
        if contacts.candidates.size:
            # projection contact: a body is in contact when the solve pushed one of its particles
            contacts.in_contact[:] = False
            contacts.in_contact[model.particle_body[contacts.touched]] = True
        end_pose = tool_pose
        if getattr(info, "in_contact", None) is not None:
            contacts.in_contact[:] = info.in_contact
        if getattr(info, "tool_q", None) is not None and contacts.tool_collider is not None:
            # the barrier contact's tool ends where the tissue let it: the next step starts there
            end_pose = contacts.tool_collider.pose(info.tool_q)
            self.tool_jaw = float(info.tool_q[3])
            self._tool_left_free = True
        detail = StepDetail(state_in, contacts, _detached(info), (self.tool_pose or tool_pose) if tool_pose else None,
                            tool_pose, p.dt) if keep else None
        out = self._state_out
        # one compiled call: finite?, every energy term, inverted triangles
        energy = EnergyTerms.zeros(model.n_bodies)
        attach = ((contacts.attach_idx, contacts.attach_target, contacts.attach_compliance)
                  if contacts.attach_idx.shape[0] else NO_ATTACH)
        finite, n_inverted = finish_step(out.particle_q, out.particle_qd, info.x_pred, self._energy_model, p.dt,
                                         attach, energy.arrays)
        force, torque, attach_force = np.zeros(2), 0.0, np.zeros(2)
        if not finite:
            # restore the last good state; never hand NaN to anyone
            out.particle_q[:] = self._last_good.particle_q
            out.particle_qd[:] = 0.0
            n_inverted = int(count_inverted(out.particle_q, model.tri_indices))
            energy = EnergyTerms.zeros(model.n_bodies)
            self.grasp.release()  # what diverged tore loose: the jaw holds nothing until it opens and closes again
        else:
            if tool_pose is not None:
                force, torque, attach_force = self._reaction(info, end_pose, p.dt, contacts, out.particle_q)
            if getattr(info, "contact_energy", None) is not None:
                energy.contact = info.contact_energy
        checks = (self._tool_checks(self.state.particle_q, out.particle_q, self.tool_pose or tool_pose, end_pose,
                                    getattr(info, "tool_path", None))
                  if self.report_tool_checks else (0, 0.0, -1, 0, False))
        t_energy = time.perf_counter()

        self.state, self._state_out = out, self.state
        if finite:
            self._last_good.particle_q[:] = self.state.particle_q
            self._last_good.particle_qd[:] = self.state.particle_qd
        self.step_count += 1
        self.time = self.step_count * p.dt
        if tool_pose is not None:
            self.tool_pose = end_pose
            self.tool_command = tool_pose
            if contacts.tool_collider is not None:
                self.jaw_command = float(contacts.tool_collider.q1[3])
        lag = getattr(info, "tool_lag", None) or (0.0, 0.0)
        return StepReport(
            step=self.step_count, time=self.time, energy=energy, residual=float(info.residual),
            in_contact=contacts.in_contact.copy(), d_star=contacts.d_star.copy(),
            n_contact_particles=int(contacts.touched.size), contact_particles=contacts.touched.copy(),
            reaction_force=force, reaction_torque=torque, n_inverted=int(n_inverted), diverged=not finite,
            timings={"contact": t_contact - t_start, "solve": t_solve - t_contact,
                     "energy": t_energy - t_solve, "total": time.perf_counter() - t_start},
            x_pred=info.x_pred.copy(), held_idx=np.asarray(contacts.held_idx, dtype=np.int32).copy(),
            held_dx=np.asarray(contacts.held_dx, dtype=np.float64).reshape(-1, 2).copy(),
            n_penetrating=checks[0], penetration_depth=checks[1], deepest_particle=checks[2],
            n_tunnelled=checks[3], tool_buried=checks[4],
            solve_iterations=int(getattr(info, "solve_iterations", 0)),
            solve_residual=float(getattr(info, "solve_residual", math.nan)),
            solve_converged=bool(getattr(info, "solve_converged", True)), detail=detail,
            grasped=np.asarray(contacts.attach_idx, dtype=np.int64).copy(), attach_force=attach_force,
            tool_applied=end_pose if tool_pose is not None else None, tool_lag=float(lag[0]),
            tool_lag_angle=float(lag[1]),
            contact_force=(info.contact_force if finite and getattr(info, "contact_force", None) is not None
                           else None),
        )

    def _tool_checks(self, x0: np.ndarray, x1: np.ndarray, pose0: ToolPose | None,
                     pose1: ToolPose | None, path: tuple | None = None) -> tuple[int, float, int, int, bool]:
        """Penetration, tunnelling and a buried tool after a step (``core/contact/tool_checks.py``); zeros without a
        tool. ``path``: the barrier step's (particles, tool dofs) at its start and at each part's end; tunnelling is
        then counted along it, part by part (a particle's chord over a whole step of a tool moving farther than its
        own width cut through the rounded tip it slid around)."""
        if self.tool is None or pose1 is None:
            return 0, 0.0, -1, 0, False
        if self.params.contact_model == "barrier":
            # against the tool's true outline, as the barrier sees it (the grasper's jaws, not its envelope), over
            # each part of a step approached in parts, else over the step from pose0 to pose1
            geom = self._geometry
            if path is not None and path[0].shape[0] > 2:
                xs, qs = path
            else:
                jaw = self.tool_jaw or 0.0
                xs, qs = (x0, x1), (pose_dofs(pose0 or pose1, jaw), pose_dofs(pose1, jaw))
            n_tunnel = 0
            for k in range(1, len(xs)):
                frames = [np.array([q[0], q[1], math.cos(q[2]), math.sin(q[2])]) for q in (qs[k - 1], qs[k])]
                part = outline_checks(xs[k - 1], xs[k], frames[0], frames[1], core_positions(qs[k], geom),
                                      geom.edges, geom.loop_ptr, self.model.tri_indices, INSIDE_TOL)
                n_tunnel += int(part[3])
            n_in, depth, arg, _, buried = part
            return int(n_in), float(depth), int(arg), n_tunnel, bool(buried)
        n_in, depth, arg, n_tunnel, buried = tool_checks(
            x0, x1, tool_shape_array(self.tool, pose0 or pose1), tool_shape_array(self.tool, pose1),
            self.model.tri_indices, INSIDE_TOL)
        return int(n_in), float(depth), int(arg), int(n_tunnel), bool(buried)

    def _reaction(self, info: Any, tool_pose: ToolPose, dt: float, contacts: Contacts,
                  x: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
        """The tissue's reaction on the tool: (force [N] (2,), torque about the tool's centre [N m], the grasp's
        part of the force (2,)) (``core/physics/reaction.py``).

        The barrier contact's solve gives it (``info.tool_force``: minus the barrier's gradient to the tool's
        pose). Otherwise ``info.contact_dx`` (N, 2) are the projection model's corrections summed over the step's
        n = ``substeps`` substeps of h = dt / n: a correction dx in a substep is a force m dx / h^2 acting for h,
        so the step's mean force is m sum(dx) / (n h^2) = m sum(dx) / (dt h). Without them the paper model's held
        displacements (``contacts.held_dx``, prescribed over the whole step) give m dx / dt^2. The held particles
        pull the tool (x - target) / c. The particles are at ``x`` (their positions after the step).
        """
        contact_dx = info.contact_dx
        m = self.model.particle_mass
        centre = (float(tool_pose.x), float(tool_pose.y))
        each = self._torque_each
        force, torque = np.zeros(2), 0.0
        tool_force = getattr(info, "tool_force", None)
        if tool_force is not None:
            force, torque = np.array([tool_force[0], tool_force[1]]), float(tool_force[2])
        elif contact_dx is not None:
            k = touched_particles(contact_dx, self._touched)
            fx, fy = push_reaction(self._touched[:k], contact_dx, True, m, dt * (dt / self.params.substeps), x,
                                   centre, each)
            force, torque = np.array([fx, fy]), float(np.sum(each[:k]))
        elif contacts.held_idx.size:
            k = contacts.held_idx.shape[0]
            fx, fy = push_reaction(np.ascontiguousarray(contacts.held_idx, dtype=np.int64),
                                   np.ascontiguousarray(contacts.held_dx, dtype=np.float64).reshape(-1, 2), False, m,
                                   dt * dt, x, centre, each)
            force, torque = np.array([fx, fy]), float(np.sum(each[:k]))
        attach_force = np.zeros(2)
        k = contacts.attach_idx.shape[0]
        if k:
            ax, ay = attach_reaction(np.ascontiguousarray(contacts.attach_idx, dtype=np.int64), x,
                                     np.ascontiguousarray(contacts.attach_target, dtype=np.float64),
                                     float(contacts.attach_compliance), centre, each)
            attach_force = np.array([ax, ay])
            force = force + attach_force
            torque = torque + float(np.sum(each[:k]))
        return force, torque, attach_force

    def count_inverted(self) -> int:
        """Triangles with signed area <= 0 in the current state."""
        return int(count_inverted(self.state.particle_q, self.model.tri_indices))
