"""Batch rollouts: K candidate tool paths from one snapshot, serially or on a pool of warm worker processes.

A planner asks the running simulation which of K motions costs least from the
tissue as it is now. :func:`rollout_batch` restores a
:class:`~tissue_sim_ros.core.sim.snapshot.SimSnapshot` into a scratch simulation
of the same scene for each candidate and for one tool-free baseline, and
returns per candidate:

* ``cost``: the energy the candidate adds over the baseline, summed over its
  steps, sum_t (E_t - E_t^baseline) (the cost of ``tissue-sim plan``; the
  baseline is the same snapshot stepped as long without the tool);
* ``peak_energy`` (max_t E_t) and ``peak_added`` (max_t E_t - E_t^baseline);
* ``peak_force``: the largest reaction on the tool, max_t |F_t| [N];
* ``max_penetration``: the deepest a tissue particle lies inside the tool's
  shape at the end of a step [m] (what the contact model left unresolved:
  ~0 with projection contact, up to the tool's half width when the paper's
  rule lets the tool through);
* ``max_displacement``: the largest distance of a particle from its position
  in the snapshot [m] (the indentation);
* the scene energy per step, contact steps, inverted triangles, divergences,
  and the final State when asked.

The serial path, the pool's workers (:mod:`.pool`) and the Ray actors (:mod:`.backends`) share one
:func:`rollout_candidate`, :func:`finish` and :class:`BaselineTrack`, so the executions cannot drift apart; a
candidate's compiled steps are in :mod:`.fused`.

Two executions, same numbers bit for bit (``test/test_batch.py`` compares
with ``np.array_equal``):

* serial (``pool=None``): one scratch simulation in this process, restored
  before each candidate;
* :class:`~.pool.RolloutPool`: persistent worker processes (:mod:`.pool`).

Both build their simulation with :meth:`BatchScene.build`: the scene's model
and tool with the serial Gauss-Seidel solver (one core per candidate; the
parallel path's sweep order would differ from a serial run's).

Steps before the tool reaches the tissue are not solved again. A step whose
contact detection finds nothing (no body in contact, nothing held, no
projection candidate or surface edge) hands the solver no contact: the same
floating-point operations as the tool-free step from the same state. So its
state, energy and counts are the baseline's, bit for bit. A
:class:`BaselineTrack` keeps the baseline's states of one snapshot, and each
candidate runs its detection against them until the first step that finds
something, restores the track's state there and solves from it
(``test/test_batch.py`` compares every number with rollouts that solve every
step). A new insertion starts outside the tissue, so its approach costs a
detection per step, not a solve.
"""
from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Iterable, Sequence

import numpy as np

from ..contact.kernels import points_sdf
from ..contact.tool import (
    StraightInsertion,
    ToolPose,
    ToolShape,
    ToolTwist,
    Trajectory,
    tool_shape_array,
    twist_from_poses,
    wrap_angle,
)
from ..errors import InputError
from ..physics.model import Model, State
from ..physics.solvers import Solver
from .fused import FusedWorkspace, fused_applies, penetration_and_displacement, rollout_fused, warm_fused
from .simulation import Simulation
from .snapshot import SimSnapshot, scene_key

if TYPE_CHECKING:
    from .pool import RolloutPool

TRACK_BYTES = 256 * 2**20
"""Baseline states a :class:`BaselineTrack` keeps at most [bytes]: ~1,500 steps of a 5k-triangle scene, ~25,000 of
the paper scene; a candidate still beyond reach after them is solved from there on."""

# --------------------------------------------------------------------------- inputs


@dataclass(frozen=True)
class ToolPath:
    """One candidate: the tool pose at the end of each step, optionally its twist, and where it starts.

    Parameters
    ----------
    poses : (S, 3) float64
        Tool pose (x [m], y [m], yaw [rad]) at the end of steps 1..S.
    twists : (S, 3) float64, optional
        Tool velocity (vx, vy [m/s], wz [rad/s]) of each step; None: derived
        from consecutive poses by the simulation.
    start : ToolPose, optional
        Where the tool is placed before step 1 (no sweep from the snapshot's
        tool pose): a new insertion. None: the path continues from the
        snapshot's tool pose (replanning a motion in progress).
    jaws : (S,) float64, optional
        The grasper's jaw angle of each step [rad] (NaN: keep the last); None: the jaw as the snapshot left it.
    """

    poses: np.ndarray
    twists: np.ndarray | None = None
    start: ToolPose | None = None
    jaws: np.ndarray | None = None

    def __post_init__(self) -> None:
        poses = np.ascontiguousarray(self.poses, dtype=np.float64)
        if poses.ndim != 2 or poses.shape[1] != 3 or poses.shape[0] < 1:
            raise InputError(f"tool path poses have shape {poses.shape}: expected (S, 3) [x, y, yaw] with S >= 1")
        if not np.isfinite(poses).all():
            raise InputError("tool path poses must be finite")
        object.__setattr__(self, "poses", poses)
        if self.twists is not None:
            twists = np.ascontiguousarray(self.twists, dtype=np.float64)
            if twists.shape != poses.shape or not np.isfinite(twists).all():
                raise InputError(f"tool path twists have shape {twists.shape}: expected finite {poses.shape}")
            object.__setattr__(self, "twists", twists)
        if self.jaws is not None:
            jaws = np.ascontiguousarray(self.jaws, dtype=np.float64).reshape(-1)
            if jaws.shape != (poses.shape[0],) or np.isinf(jaws).any():
                raise InputError(f"tool path jaws have shape {jaws.shape}: expected ({poses.shape[0]},) angles [rad] "
                                 "(NaN: keep the last)")
            object.__setattr__(self, "jaws", jaws)

    @property
    def n_steps(self) -> int:
        return int(self.poses.shape[0])

    @classmethod
    def _straight(cls, traj: StraightInsertion, dt: float, start: bool) -> "ToolPath":
        n = traj.n_steps(dt)
        if n == 0:
            raise InputError(f"trajectory of {traj.duration} s has no step of dt={dt} s")
        end = traj.start_time + traj.duration
        # Trajectory.steps: t_k = min(start + k dt, end); StraightInsertion.pose_at / tip_at per t
        t = np.minimum(traj.start_time + np.arange(0, n + 1, dtype=np.float64) * dt, end)
        t[0] = traj.start_time
        s = np.minimum(np.maximum(t, 0.0) * traj.speed_mps, traj.length) / traj.length
        yaw = traj.angle
        c, sn = math.cos(yaw), math.sin(yaw)
        x = (traj.start[0] + s * (traj.target[0] - traj.start[0])) - traj.tip_offset * c
        y = (traj.start[1] + s * (traj.target[1] - traj.start[1])) - traj.tip_offset * sn
        poses = np.empty((n, 3))
        poses[:, 0], poses[:, 1], poses[:, 2] = x[1:], y[1:], yaw
        twists = np.zeros((n, 3))
        twists[:, 0] = (x[1:] - x[:-1]) / dt
        twists[:, 1] = (y[1:] - y[:-1]) / dt
        twists[:, 2] = wrap_angle(0.0) / dt
        return cls(poses, twists, ToolPose(float(x[0]), float(y[0]), yaw) if start else None)

    @classmethod
    def from_trajectory(cls, traj: Trajectory, dt: float, *, start: bool = True) -> "ToolPath":
        """The per-step poses and twists of ``traj`` (:meth:`Trajectory.steps`); placed at its start pose if ``start``.

        A :class:`~tissue_sim_ros.core.contact.tool.StraightInsertion` is sampled with NumPy in the same floating-point
        operations as its ``pose_at`` (the same bits, ``test/test_batch.py``), 10x faster than the loop.
        """
        if isinstance(traj, StraightInsertion):
            return cls._straight(traj, dt, start)
        rows = list(traj.steps_with_jaw(dt))
        if not rows:
            raise InputError(f"trajectory of {traj.duration} s has no step of dt={dt} s")
        poses = np.array([(p.x, p.y, p.yaw) for p, _, _ in rows], dtype=np.float64)
        twists = np.array([(t.vx, t.vy, t.wz) for _, t, _ in rows], dtype=np.float64)
        jaws = (np.array([np.nan if j is None else j for _, _, j in rows], dtype=np.float64)
                if any(j is not None for _, _, j in rows) else None)
        return cls(poses, twists, traj.pose_at(traj.start_time) if start else None, jaws)


def as_tool_path(candidate: ToolPath | Trajectory | np.ndarray, dt: float) -> ToolPath:
    """A ToolPath from a ToolPath, a Trajectory (placed at its start) or an (S, 3) pose array (continuing)."""
    if isinstance(candidate, ToolPath):
        return candidate
    if isinstance(candidate, Trajectory):
        return ToolPath.from_trajectory(candidate, dt)
    return ToolPath(np.asarray(candidate, dtype=np.float64))


@dataclass(frozen=True)
class BatchScene:
    """What a worker needs to build the scene: the Model and the tool (sent once per worker)."""

    model: Model
    tool: ToolShape

    @classmethod
    def from_simulation(cls, sim: Simulation) -> "BatchScene":
        if sim.tool is None:
            raise InputError("batch rollouts need a simulation with a tool (tool_shape ...)")
        return cls(sim.model, sim.tool)

    @property
    def key(self) -> str:
        """:func:`~tissue_sim_ros.core.sim.snapshot.scene_key` of the model."""
        return scene_key(self.model)

    def build(self) -> Simulation:
        """A scratch Simulation of this scene with the serial solver (see the module docstring)."""
        sim = Simulation(self.model, self.tool)
        if getattr(sim.solver, "parallel", False):
            sim.use_solver(functools.partial(Solver, parallel=False))
        sim.report_tool_checks = False  # the rollout measures its own penetration (CandidateResult)
        return sim

    def build_warm(self) -> Simulation:
        """:meth:`build`, its kernels loaded (or compiled) now, the fused rollout's too: a worker's scene."""
        sim = self.build()
        sim.warm_up()
        warm_fused(sim)
        return sim


# --------------------------------------------------------------------------- results


@dataclass
class CandidateResult:
    """What one candidate did (see the module docstring for each number)."""

    index: int
    steps: int
    cost: float
    peak_energy: float
    peak_added: float
    final_added: float
    peak_force: float
    max_penetration: float
    max_displacement: float
    contact_steps: int
    max_inverted: int
    diverged_steps: int
    finite: bool
    energy: np.ndarray
    """Scene energy of each step, shape (S,)."""
    final_state: State | None = None
    wall_s: float = 0.0
    """Wall time of the rollout in its process [s] (not part of the comparison with a serial run)."""
    baseline_steps: int = 0
    """Leading steps taken from the tool-free baseline, not solved: the tool was still beyond reach
    (:class:`BaselineTrack`)."""

    def metrics(self) -> dict[str, Any]:
        """The scalar numbers (a CSV row)."""
        return {k: getattr(self, k) for k in ("index", "steps", "cost", "peak_energy", "peak_added", "final_added",
                                              "peak_force", "max_penetration", "max_displacement", "contact_steps",
                                              "max_inverted", "diverged_steps", "finite")}


@dataclass
class BatchResult:
    """Every candidate's result, in candidate order, and the baseline."""

    candidates: list[CandidateResult]
    baseline_energy: np.ndarray
    """Scene energy of each step of the tool-free baseline, shape (max S,)."""
    wall_s: float = 0.0
    workers: int = 0
    """Worker processes used (0: serial, in this process)."""
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def costs(self) -> np.ndarray:
        return np.array([c.cost for c in self.candidates])

    def best(self) -> int | None:
        """Index of the cheapest candidate with finite numbers, or None."""
        ok = [c for c in self.candidates if c.finite]
        return None if not ok else min(ok, key=lambda c: c.cost).index


# --------------------------------------------------------------------------- one rollout (worker and serial alike)


class BaselineTrack:
    """The tool-free steps from one snapshot, each state kept: the steps of a candidate before its tool reaches the tissue.

    ``states[k]`` is the snapshot after k tool-free steps (``states[0]`` the snapshot itself), kept while they
    fit in ``max_bytes``; ``energy``, ``n_inverted``, ``diverged`` and ``displacement`` (the largest distance
    of a particle from the snapshot) are kept for every step. :meth:`extend` steps ``sim`` further on demand
    (it restores the track's newest state first, so ``sim`` may be used for candidates in between).
    """

    def __init__(self, sim: Simulation, snap: SimSnapshot, max_bytes: int = TRACK_BYTES) -> None:
        self.sim = sim
        self.snap = snap
        self.states: list[SimSnapshot] = [snap]
        self.energy: list[float] = []
        self.n_inverted: list[int] = []
        self.diverged: list[bool] = []
        self.displacement: list[float] = []
        self.longest_edge: list[float] = [longest_edge(snap.particle_q, sim.model.tri_indices)]
        """Per kept state: the longest triangle edge [m] (:func:`_beyond_reach`'s bound)."""
        per_state = 4 * snap.particle_q.nbytes  # positions, velocities and the last good pair
        self.max_states = max(1, int(max_bytes) // max(per_state, 1))
        self._newest = snap
        """The state after the last step taken (kept when ``states`` is full)."""

    @property
    def steps(self) -> int:
        """Tool-free steps taken so far."""
        return len(self.energy)

    def extend(self, steps: int) -> None:
        """Take tool-free steps until ``steps`` are known."""
        if self.steps >= steps:
            return
        sim = self.sim
        sim.restore(self._newest)
        x0 = self.snap.particle_q
        while self.steps < steps:
            r = sim.step(None)
            self.energy.append(r.energy.scene_total)
            self.n_inverted.append(r.n_inverted)
            self.diverged.append(bool(r.diverged))
            self.displacement.append(max_displacement(sim.state.particle_q, x0))
            if len(self.states) < self.max_states:
                self.states.append(sim.snapshot())
                self.longest_edge.append(longest_edge(sim.state.particle_q, sim.model.tri_indices))
        self._newest = self.states[-1] if len(self.states) > self.steps else sim.snapshot()


def longest_edge(x: np.ndarray, tris: np.ndarray) -> float:
    """The longest edge of the triangles ``tris`` at positions ``x`` [m] (0 without triangles)."""
    if tris.shape[0] == 0:
        return 0.0
    longest = 0.0
    for a, b in ((0, 1), (1, 2), (2, 0)):
        d = x[tris[:, a]] - x[tris[:, b]]
        longest = max(longest, float((d * d).sum(axis=1).max()))
    return math.sqrt(longest)


def max_displacement(x: np.ndarray, x0: np.ndarray) -> float:
    """max_i |x_i - x0_i| [m] (0 for no particles): as a rollout measures its indentation."""
    if x.shape[0] == 0:
        return 0.0
    d = x - x0
    return math.sqrt(float((d * d).sum(axis=1).max()))


def rollout_baseline(sim: Simulation, snap: SimSnapshot, steps: int, track: BaselineTrack | None = None) -> np.ndarray:
    """The scene energy of ``steps`` tool-free steps from ``snap``, shape (steps,) (kept in ``track`` when given;
    without one, a track that keeps no states steps them)."""
    if track is None:
        track = BaselineTrack(sim, snap, max_bytes=0)
    track.extend(steps)
    return np.array(track.energy[:steps], dtype=np.float64)


#: Margin [m] of the paper contact's bound in :func:`_beyond_reach` over python-fcl's distance tolerance.
BOUND_TOL = 1e-6


def _beyond_reach(sim: Simulation, state: SimSnapshot, longest: float, pose0: ToolPose, pose: ToolPose,
                  twist: ToolTwist, sdf: np.ndarray, grad: np.ndarray) -> bool:
    """True when the step from ``state`` with the tool moving to ``pose`` hands the solver no contact.

    The step's own detection (:meth:`~tissue_sim_ros.core.contact.collision.ContactModel.detect`, with the pose it
    would use for the start of the step) finds no body in contact, nothing held, no projection candidate and
    no surface edge: the solver then runs exactly the tool-free step (``Solver.step``: no projection, no held
    particles; the reaction is zero).

    The paper's contact is decided first by a bound, without python-fcl: the tool's signed distance f is
    1-Lipschitz and every point of a triangle lies within its longest edge L of one of its vertices, so every
    body's distance d* >= min_i f(x_i) - L. When that exceeds the detection's reach, max(alpha, margin), no
    body is within reach and detection would report none in contact (its python-fcl distance beyond reach
    is reported as inf); otherwise the detection itself decides.
    """
    p = sim.params
    if p.contact_model == "none":
        return True
    if p.contact_model == "paper":
        points_sdf(state.particle_q, tool_shape_array(sim.tool, pose, 0.0), sdf, grad)
        if float(sdf.min()) - longest > max(p.contact_threshold, p.contact_margin) + BOUND_TOL:
            return True
    c = sim.contact.detect(State(state.particle_q, state.particle_qd), pose0, pose, twist, p.dt)
    return not (c.held_idx.size or c.candidates.size or np.size(c.surface_edges) or c.in_contact.any())


def rollout_candidate(sim: Simulation, snap: SimSnapshot, path: ToolPath, index: int = 0,
                      final_state: bool = False, track: BaselineTrack | None = None,
                      fused: bool = True) -> CandidateResult:
    """Roll ``path`` out from ``snap`` in ``sim``; ``cost`` and the added energies are filled by :func:`finish`.

    With ``track`` (the baseline of ``snap``) the leading steps with the tool beyond reach are the track's
    (see the module docstring): the same numbers as solving them.
    """
    t0 = time.perf_counter()
    n = path.n_steps
    energy = np.empty(n)
    x0 = snap.particle_q
    n_part = x0.shape[0]
    sdf = np.empty(n_part)
    grad = np.empty((n_part, 2))
    peak_force = max_pen = max_disp = 0.0
    contact = inverted = diverged = 0
    poses, twists = path.poses, path.twists
    dt = sim.params.dt
    prev = path.start if path.start is not None else snap.tool_pose
    jaws = path.jaws
    k = 0
    # a path that works the jaw, or a snapshot whose jaw holds particles, is never the tool-free baseline's
    holding = bool(snap.grasp) and len(snap.grasp.get("idx", ())) > 0
    if track is not None and n_part and sim.contact is not None and jaws is None and not holding:
        while k < n:
            track.extend(k + 1)
            if len(track.states) < k + 2:
                break  # the track's memory is full: solve from here
            pose = ToolPose(float(poses[k, 0]), float(poses[k, 1]), float(poses[k, 2]))
            twist = (twist_from_poses(prev, pose, dt) if twists is None
                     else ToolTwist(float(twists[k, 0]), float(twists[k, 1]), float(twists[k, 2])))
            if not _beyond_reach(sim, track.states[k], track.longest_edge[k], prev or pose, pose, twist, sdf, grad):
                break
            # the step is the baseline's: its numbers as the loop below measures them
            energy[k] = track.energy[k]
            points_sdf(track.states[k + 1].particle_q, tool_shape_array(sim.tool, pose, 0.0), sdf, grad)
            max_pen = max(max_pen, -float(sdf.min()))
            max_disp = max(max_disp, track.displacement[k])
            inverted = max(inverted, track.n_inverted[k])
            diverged += track.diverged[k]
            prev = pose
            k += 1
    skipped = k
    from_snap = track.states[k] if skipped else snap
    sim.restore(from_snap)
    sim.place_tool(prev)
    start = skipped
    if fused and n_part and k < n and fused_applies(sim, from_snap, None if jaws is None else jaws[k:]):
        # the rest of the path in one compiled call (core/sim/fused.py): the same numbers as the loop below
        ws = getattr(sim, "_fused_workspace", None)
        if ws is None:
            ws = FusedWorkspace(sim)
            sim._fused_workspace = ws
        out = rollout_fused(sim, from_snap, poses[k:], prev or ToolPose(*map(float, poses[k, :3])), ws, x0)
        taken = out["steps"]
        e = out["energy_body"]
        energy[k:k + taken] = (e[:, :, 0] + e[:, :, 1] + e[:, :, 2] + e[:, :, 3] + e[:, :, 4])[:taken].sum(axis=1)
        for j in range(taken):
            fx, fy = float(out["force"][j, 0]), float(out["force"][j, 1])
            peak_force = max(peak_force, math.sqrt(fx * fx + fy * fy))
            max_pen = max(max_pen, float(out["penetration"][j]))
            max_disp = max(max_disp, float(out["displacement"][j]))
        contact += int(out["contact"][:taken].sum())
        if taken:
            inverted = max(inverted, int(out["inverted"][:taken].max()))
        start = k + taken
        # the Simulation where the steps left it (or before step k + taken, which diverged: it and the rest are
        # stepped below, as the Simulation does, from there)
        sim.set_state(State(out["x"], out["v"]))
        sim.step_count = from_snap.step_count + taken
        sim.time = sim.step_count * sim.params.dt
        if taken:
            sim.place_tool(ToolPose(float(poses[start - 1, 0]), float(poses[start - 1, 1]),
                                    float(poses[start - 1, 2])))
    for k in range(start, n):
        pose = ToolPose(float(poses[k, 0]), float(poses[k, 1]), float(poses[k, 2]))
        twist = None if twists is None else ToolTwist(float(twists[k, 0]), float(twists[k, 1]), float(twists[k, 2]))
        r = sim.step(pose, twist, jaw=None if jaws is None or math.isnan(jaws[k]) else float(jaws[k]))
        energy[k] = r.energy.scene_total
        fx, fy = float(r.reaction_force[0]), float(r.reaction_force[1])
        peak_force = max(peak_force, math.sqrt(fx * fx + fy * fy))  # as np.linalg.norm rounds it
        x = sim.state.particle_q
        if n_part:
            pen, disp = penetration_and_displacement(x, x0, tool_shape_array(sim.tool, pose, 0.0), sdf, grad)
            max_pen = max(max_pen, pen)
            max_disp = max(max_disp, disp)
        contact += bool(r.in_contact.any())
        inverted = max(inverted, r.n_inverted)
        diverged += bool(r.diverged)
    state = sim.state.copy() if final_state else None
    return CandidateResult(index=index, steps=n, cost=math.nan, peak_energy=float(energy.max()), peak_added=math.nan,
                           final_added=math.nan, peak_force=peak_force, max_penetration=max(0.0, max_pen),
                           max_displacement=max_disp, contact_steps=contact, max_inverted=inverted,
                           diverged_steps=diverged, finite=bool(np.isfinite(energy).all()) and diverged == 0,
                           energy=energy, final_state=state, wall_s=time.perf_counter() - t0, baseline_steps=skipped)


def finish(result: CandidateResult, baseline: np.ndarray | None) -> CandidateResult:
    """Fill the numbers measured against the baseline (in the caller's process: same arithmetic either way).
    Without one (``rollout_batch(..., baseline=False)``) they stay NaN."""
    if baseline is None:
        return result
    added = result.energy - baseline[: result.steps]
    result.cost = float(added.sum())
    result.peak_added = float(added.max())
    result.final_added = float(added[-1])
    result.finite = result.finite and bool(np.isfinite(added).all())
    return result


def _paths(candidates: Iterable[ToolPath | Trajectory | np.ndarray], dt: float) -> list[ToolPath]:
    paths = [as_tool_path(c, dt) for c in candidates]
    if not paths:
        raise InputError("no candidate tool paths: expected at least one")
    return paths


def pool_paths(scene: BatchScene, scene_key: str, snap: SimSnapshot,
               candidates: Sequence[ToolPath | Trajectory | np.ndarray]) -> list[ToolPath]:
    """A pool's batch: the snapshot checked against the pool's scene, the candidates as paths."""
    if snap.scene != scene_key:
        raise InputError(f"snapshot of scene {snap.scene[:8]}: expected one of the pool's scene {scene_key[:8]}")
    return _paths(candidates, scene.model.params.dt)


def _snapshot_of(source: Simulation | SimSnapshot) -> SimSnapshot:
    return source.snapshot() if isinstance(source, Simulation) else source


def rollout_batch(source: Simulation | SimSnapshot, candidates: Sequence[ToolPath | Trajectory | np.ndarray], *,
                  scene: BatchScene | None = None, pool: "RolloutPool | None" = None,
                  final_state: bool = False, reuse_baseline: bool = True, baseline: bool = True) -> BatchResult:
    """Roll every candidate out from ``source`` (a Simulation: its snapshot now; or a snapshot).

    Parameters
    ----------
    source : Simulation or SimSnapshot
        Where every candidate starts.
    candidates : sequence of ToolPath, Trajectory or (S, 3) pose arrays
        See :func:`as_tool_path`.
    scene : BatchScene, optional
        The scene (default: ``source``'s, which must then be a Simulation; or the pool's).
    pool : RolloutPool, optional
        Run on its workers; None: serially in this process.
    final_state : bool
        Keep each candidate's final State.
    reuse_baseline : bool
        Serial only: take the steps with the tool beyond reach from the baseline (:class:`BaselineTrack`, the same
        numbers); False solves every step (for benchmarks). Pools always reuse it.
    baseline : bool
        Roll the tool-free baseline out and fill each candidate's cost and added energies against it (True); False
        skips it (a caller that scores candidates by other numbers, the controller of core/plan/control.py): the
        result's ``baseline_energy`` is empty and those numbers NaN.
    """
    snap = _snapshot_of(source)
    if pool is not None:
        return pool.run(snap, candidates, final_state=final_state, baseline=baseline)
    if scene is None:
        if not isinstance(source, Simulation):
            raise InputError("rollout_batch from a snapshot needs scene= (a BatchScene) or pool=")
        scene = BatchScene.from_simulation(source)
    t0 = time.perf_counter()
    sim = scene.build()
    paths = _paths(candidates, scene.model.params.dt)
    track = BaselineTrack(sim, snap) if reuse_baseline else None
    energy = rollout_baseline(sim, snap, max(p.n_steps for p in paths), track) if baseline else None
    results = [finish(rollout_candidate(sim, snap, p, i, final_state, track), energy) for i, p in enumerate(paths)]
    return BatchResult(results, np.zeros(0) if energy is None else energy, time.perf_counter() - t0, 0)


def __getattr__(name: str) -> Any:
    """``RolloutPool`` where it has always been imported from: the pool (:mod:`.pool`) runs this module's
    rollout_candidate, finish and BaselineTrack on worker processes, so it imports this module, not the reverse."""
    if name == "RolloutPool":
        from .pool import RolloutPool  # noqa: PLC0415

        return RolloutPool
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
