"""Drive the tissue to a target: a model-predictive controller for a grasper, on its own model.

The controller sees what a tracker gives: tissue points (positions, with the model's particle ids, or bound to the
model at the first observation), the tool's measured pose and jaw. It keeps its own model of the tissue (a
:class:`~tissue_sim_ros.core.sim.simulation.Simulation` of the scene it is given, whose mesh and material may differ
from the world's: by default a coarser mesh, so a replan fits in its 100 ms) in step with them, and each control
step returns the next tool command (pose, twist, jaw):

* **binding**: as many points as the model has particles are its particles; other points (another mesh, a
  tracker's markers) are embedded at the first observation in the model's triangle under each, barycentric
  weights w (:func:`~tissue_sim_ros.core.plan.observe.embed`; points farther than half the model's median edge from it are not used).
* **sync** (every replan): the model's positions are the least-energy state that matches the observations, the
  minimiser of

      Pi(x) + k/2 sum_obs |sum_j w_j x_(t_j) - o|^2 + 1/(2 c) sum_held |x_h - T(pose) l_h|^2

  (Pi: the material's strain energy plus gravity's potential, :class:`~tissue_sim_ros.core.physics.statics.PotentialEnergy`;
  k = ``sync_stiffness`` [N/m] ties each observed point to its observation, so noise is smoothed by the
  tissue's stiffness and unobserved particles take their least-energy place; the held particles hang from the
  jaw with the grasp's compliance c), by Newton's method (:func:`~tissue_sim_ros.core.physics.minimize.newton_minimize`,
  pins fixed). Velocities are the difference of two synced states over the time between them. The jaw's hold is
  the controller's own record: the particles within ``grasp_radius`` of the tip when it closed the jaw (or the ids
  the caller passes).
* **the goal point** is the start point embedded in the model's triangle under it (not the particle nearest it),
  and its prediction is offset-free: the model's point plus a bias b, the observed point nearest the start minus
  the model's, filtered over the syncs (b <- (1 - a) b + a (o - m), a = ``bias_gain``). A model that is not the
  world (coarser, another E) is then wrong about where the point goes by what it was wrong about where it is,
  which the bias removes (docs/control.md: a coarse model of the flap reaches its goal with it, not without).
* **approach**: the grasp site is chosen once, from the free particles within ``grasp_search`` of the goal's
  start point that the open grasper can reach from above without touching the tissue: each is rolled out on the
  model (tool placed at the site, jaw closed, a straight pull by the goal's displacement at ``pull_speeds[0]``)
  and the one whose rollout leaves the goal point nearest its goal is taken. The tool then moves above the site
  at ``approach_speed`` (from wherever it is: first straight up to the hover height when it is below it),
  comes down to ``approach_clearance`` above it and closes the jaw.
* **pull** (model-predictive): every ``replan_every`` steps the candidates are straight tool motions of
  ``horizon`` steps toward the tool pose plus g R(theta) d (d: the goal's displacement still to go in the synced
  model; g in ``gains``, theta in ``angles_deg``, at each of ``pull_speeds``; and holding still), rolled out in a
  batch from the synced state (:func:`~tissue_sim_ros.core.sim.batch.rollout_batch`: serially, or on a
  :class:`~tissue_sim_ros.core.sim.batch.RolloutPool` or :class:`~tissue_sim_ros.core.sim.backends.RayRolloutPool`;
  each candidate's steps in one compiled call, :mod:`~tissue_sim_ros.core.sim.fused`), each scored

      score = goal error at the horizon [m] + force_weight * peak |F| + penetration_weight * max penetration
              + energy_weight * max(0, peak energy added)

  and the first ``replan_every`` poses of the best are committed. The goal error of several (start, goal) pairs is
  the largest of them.
* **holding**: when the synced goal error is within ``tolerance`` the tool holds still (the jaw stays closed) and
  keeps replanning, so a drift is pulled back.

Bad input (a start not on the tissue, a goal beyond ``max_reach``, NaN, observations of the wrong shape) raises
:class:`~tissue_sim_ros.core.errors.InputError` naming the value and what was expected. Same inputs, same commands:
nothing here is random, and the pool's rollouts equal the serial ones bit for bit.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from ..config import Config
from ..contact.tool import ToolPose, ToolTwist, twist_from_poses
from ..errors import InputError
from ..physics.minimize import newton_minimize
from ..physics.model import State
from ..physics.statics import PotentialEnergy
from ..sim.batch import BatchScene, RolloutPool, ToolPath, rollout_batch
from ..sim.grasp import to_tool_frame, to_world
from ..sim.simulation import Simulation
from ..sim.snapshot import SimSnapshot
from .observe import SyncEnergy, embed, particle_points

PHASES = ("approach", "close", "pull", "holding")
MODEL_COARSENING = 2.0
"""The controller's model is its scene on a mesh this many times coarser than the world's by default
(:func:`default_model`): the retraction flap's 2.5 mm world is modelled at 5 mm, where a replan's candidates fit
within the steps it commits (docs/control.md)."""
MODEL_SOLVE = {"method": "quasi_newton", "contact_model": "projection"}
"""How the controller's model steps when its scene asks for the barrier step (``method: ipc``, the material's
default): the whole-step quasi-Newton solve with projection contact, whose rollouts run fused, one compiled call
per candidate (``core/sim/fused.py``). The model is an approximation the bias corrects (module docstring); the
world keeps its own step. On the retract scene's ipc the 39-particle model's pull replan (19 candidates x 30
steps) took 380 ms mean, stepped; the scene's earlier quasi_newton model 79 ms for 17 x 50."""
RECORDS_KEPT = 200
"""Replan records a controller keeps by default (:attr:`TissueController.records`, the newest last)."""
APPROACH_REACHED = 3e-4
"""The approach ends when the tool is this close to its pose above the grasp site [m]."""


def default_model(cfg: Config) -> dict[str, Any]:
    """The parameters that make the world's configuration ``cfg`` the controller's default model."""
    return {"spacing": MODEL_COARSENING * float(cfg.flat()["spacing"])}


@dataclass(frozen=True)
class ControlSettings:
    """How the controller plans (module docstring). Lengths in m, speeds in m/s, weights per unit of the term."""

    tolerance: float = 0.002
    """Goal met when the (synced) goal point is this close to its goal [m]."""
    replan_every: int = 10
    """Steps committed from each plan (the replan period in steps)."""
    horizon: int = 30
    """Steps each candidate is rolled out."""
    gains: Sequence[float] = (0.8, 1.0, 1.25)
    angles_deg: Sequence[float] = (-15.0, 0.0, 15.0)
    pull_speeds: Sequence[float] = (0.02, 0.04)
    approach_speed: float = 0.05
    approach_hover: float = 0.005
    """The grasper comes down onto the site from this high above it [m]."""
    approach_clearance: float = 0.0005
    """Its tip stops this far above the site before closing [m]."""
    grasp_search: float = 0.005
    """Grasp sites: free particles within this distance of the start point [m]."""
    max_sites: int = 5
    max_reach: float = 0.05
    """Refuse goals farther than this from their start [m]."""
    start_tolerance: float = 0.003
    """A start point must lie within this distance of a tissue point [m]."""
    sync_stiffness: float = 0.0
    """k of the sync [N/m]; 0: 10 x young_modulus x thickness of the model."""
    force_weight: float = 1e-3
    """[m/N]: 1 N of peak reaction costs as much as 1 mm of goal error."""
    penetration_weight: float = 1.0
    bias_gain: float = 0.3
    """Offset-free prediction: the weight of each sync's (observed - modelled) goal point in the bias added to the
    model's goal points (0: trust the model; 1: the last observation alone)."""
    energy_weight: float = 0.0
    """[m per unit of the scene's energy] on the peak energy a candidate adds over the tool-free baseline."""
    open_jaw: float = 0.8
    closed_jaw: float = 0.0

    def __post_init__(self) -> None:
        for name in ("tolerance", "approach_speed", "grasp_search", "max_reach", "start_tolerance"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InputError(f"{name}={v}: expected a finite value > 0")
        for name in ("approach_hover", "approach_clearance", "sync_stiffness", "force_weight", "penetration_weight",
                     "energy_weight"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise InputError(f"{name}={v}: expected a finite value >= 0")
        if not (math.isfinite(self.bias_gain) and 0.0 <= self.bias_gain <= 1.0):
            raise InputError(f"bias_gain={self.bias_gain}: expected a value in [0, 1]")
        for name in ("replan_every", "horizon", "max_sites"):
            if int(getattr(self, name)) < 1:
                raise InputError(f"{name}={getattr(self, name)}: expected an integer >= 1")
        if self.replan_every > self.horizon:
            raise InputError(f"replan_every={self.replan_every}: expected at most horizon={self.horizon} steps")
        for name in ("gains", "angles_deg", "pull_speeds"):
            vals = list(getattr(self, name))
            if not vals or not all(math.isfinite(v) for v in vals):
                raise InputError(f"{name}={vals}: expected a non-empty list of finite numbers")
        if min(self.pull_speeds) <= 0 or min(self.gains) <= 0:
            raise InputError(f"pull_speeds={list(self.pull_speeds)}, gains={list(self.gains)}: expected values > 0")

    @property
    def n_candidates(self) -> int:
        """Pull candidates per replan (the grid and holding still)."""
        return len(self.gains) * len(self.angles_deg) * len(self.pull_speeds) + 1


@dataclass
class ToolCommand:
    """The next step's tool command and what the controller knows."""

    pose: ToolPose
    twist: ToolTwist
    jaw: float
    phase: str
    goal_error: float
    """The largest distance of a goal point from its goal in the synced model [m] (nan before the first sync)."""
    replanned: bool = False


@dataclass
class ReplanRecord:
    """One replan: when, in which phase, its wall times [s] and what it chose."""

    step: int
    phase: str
    sync_s: float
    rollout_s: float
    choose_s: float
    candidates: int
    horizon: int
    best: int = -1
    predicted_error: float = math.nan
    goal_error: float = math.nan
    paths: list[np.ndarray] = field(default_factory=list)
    """The candidates' tool positions (S, 2) (for drawing)."""

    @property
    def total_s(self) -> float:
        return self.sync_s + self.rollout_s + self.choose_s


def _finite_point(name: str, p: Any) -> np.ndarray:
    try:
        a = np.asarray(p, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"{name}={p!r}: expected a point (x, y) in m") from None
    if a.shape != (2,) or not np.isfinite(a).all():
        raise InputError(f"{name}={p!r}: expected a finite point (x, y) in m")
    return a


class TissueController:
    """The controller (module docstring). Call :meth:`set_goal` once, then :meth:`command` once per step.

    Parameters
    ----------
    config : Config
        The controller's model of the scene (its tool must be a grasper, its material neo-Hookean).
    settings : ControlSettings
    pool : RolloutPool, optional
        Roll candidates out on its workers (its scene must be this model's); None: serially.
    mesh : TissueMesh, optional
        The model's mesh (default: the config's).
    """

    def __init__(self, config: Config, settings: ControlSettings | None = None, pool: RolloutPool | None = None,
                 mesh: Any = None, records_kept: int = RECORDS_KEPT) -> None:
        self.settings = settings or ControlSettings()
        self.records_kept = int(records_kept)
        if config.sim.method == "ipc":
            config = config.replace(**MODEL_SOLVE)
        self.sim = Simulation.from_config(config, mesh=mesh)
        if self.sim.tool is None or self.sim.tool.kind != "grasper":
            raise InputError(f"tool_shape={getattr(self.sim.tool, 'kind', None)!r}: the controller needs tool_shape "
                             "grasper (config/scenes/retract.yaml)")
        if not self.sim.model.is_material:
            raise InputError(f"material={self.sim.params.material!r}: the controller syncs its model by the "
                             "material's energy; expected material neo_hookean")
        self.scene = BatchScene.from_simulation(self.sim)
        self.pool = pool
        p = self.sim.params
        self.dt = float(p.dt)
        self.k_sync = self.settings.sync_stiffness or 10.0 * p.young_modulus * p.thickness
        self.k_hold = 1.0 / p.grasp_compliance
        self.potential = PotentialEnergy(self.sim.model)
        self.fixed = np.asarray(self.sim.model.particle_inv_mass) == 0.0
        self.weight = float(np.linalg.norm(self.potential.mass[~self.fixed] * p.gravity)) or 1.0
        self.n = self.sim.model.n_particles
        self.x = np.array(self.sim.model.particle_q0, dtype=np.float64)
        """The synced positions [m] (N, 2)."""
        self.v = np.zeros_like(self.x)
        self._sync_time: float | None = None
        self.binding: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        """(point indices, tris, weights): the observed points bound to the model at the first observation."""
        self.n_points = 0
        tri = np.asarray(self.sim.model.tri_indices)
        q0 = np.asarray(self.sim.model.particle_q0)
        lengths = np.concatenate([np.hypot(*(q0[tri[:, a]] - q0[tri[:, b]]).T) for a, b in ((0, 1), (1, 2), (2, 0))])
        self.edge = float(np.median(lengths)) if lengths.size else 0.0
        """The model's median edge length [m] (the binding's reach)."""
        self.goal_ids = np.zeros(0, dtype=np.int64)
        self.goal_tris = np.zeros((0, 3), dtype=np.int64)
        self.goal_w = np.zeros((0, 3))
        self.goal_rows = np.zeros(0, dtype=np.int64)
        self.bias = np.zeros((0, 2))
        self._bias_set = False
        self.goals = np.zeros((0, 2))
        self.starts = np.zeros((0, 2))
        self.phase = "approach"
        self.site: int | None = None
        self.held = np.zeros(0, dtype=np.int64)
        self.held_local = np.zeros((0, 2))
        self.queue: list[tuple[ToolPose, float]] = []
        self.steps = 0
        self.records: list[ReplanRecord] = []
        self._since_replan = 0

    # ----------------------------------------------------------------------------------------------- observations
    def _observed(self, points: Any, ids: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The finite observations (M, 2), the model points they observe and their rows in ``points``: (obs,
        tris (M, 3), weights (M, 3), rows (M,))."""
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] == 0:
            raise InputError(f"observed points of shape {pts.shape}: expected (M, 2) positions in m, M >= 1")
        if ids is None:
            if self.binding is None:
                self.binding = self._bind(pts)
            rows, tris, w = self.binding
            if pts.shape[0] != self.n_points:
                raise InputError(f"{pts.shape[0]} observed points: expected {self.n_points} (as at the "
                                 "first observation) or their particle ids")
            pts = pts[rows]
        else:
            idx = np.asarray(ids, dtype=np.int64).reshape(-1)
            if idx.shape[0] != pts.shape[0] or (idx.size and (idx.min() < 0 or idx.max() >= self.n)):
                raise InputError(f"particle ids of shape {idx.shape} in [{idx.min() if idx.size else 0}, "
                                 f"{idx.max() if idx.size else 0}]: expected one id per point in [0, {self.n - 1}]")
            tris, w = particle_points(idx)
            rows = np.arange(idx.shape[0])
        ok = np.isfinite(pts).all(axis=1)  # a tracker's lost points are unobserved
        if not ok.any():
            raise InputError("every observed point is NaN/inf: expected finite positions")
        return pts[ok], tris[ok], w[ok], rows[ok]

    def _bind(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The first observation's points bound to the model: (kept point indices, tris, weights)."""
        self.n_points = pts.shape[0]
        if pts.shape[0] == self.n:  # the model's own particles (the node's tissue/points of the same mesh)
            return (np.arange(self.n),) + particle_points(np.arange(self.n, dtype=np.int64))
        # another mesh or a tracker's markers: each point embedded in the model's triangle under it (the model
        # as it stands: its rest shape, or its last sync), so a coarser model is tied at the material points
        # the tracker sees, not pulled toward them at its particles; points farther than half the model's
        # median edge from it are not used
        fin = np.flatnonzero(np.isfinite(pts).all(axis=1))
        tris, w = embed(pts[fin], self.x, np.asarray(self.sim.model.tri_indices))
        at = (w[:, :, None] * self.x[tris]).sum(axis=1)
        near = np.hypot(*(at - pts[fin]).T) <= 0.5 * self.edge
        if not near.any():
            raise InputError(f"{pts.shape[0]} observed points, none within {0.5e3 * self.edge:.2f} mm of the "
                             "model's tissue: expected points on the tissue (in the tissue plane's frame)")
        return fin[near], tris[near], w[near]

    def _static_sync(self, obs: np.ndarray, tris: np.ndarray, w: np.ndarray, tool_pose: ToolPose | None) -> np.ndarray:
        """The least-energy positions that match the observations (module docstring)."""
        x0 = self.x.copy()
        single = (w[:, 0] == 1.0)
        x0[tris[single, 0]] = obs[single]
        x0[self.fixed] = np.asarray(self.sim.model.particle_q0)[self.fixed]
        held = self.held if (self.held.size and tool_pose is not None) else np.zeros(0, dtype=np.int64)
        targets = to_world(self.held_local, tool_pose) if held.size else np.zeros((0, 2))
        energy = SyncEnergy(self.potential, tris, w, obs, self.k_sync, held, targets, self.k_hold)
        x, _ = newton_minimize(energy, x0, self.fixed, g_scale=self.weight, rtol=1e-6, max_iterations=30,
                               reuse_factor=True)
        return x if np.isfinite(x).all() else x0

    def sync(self, points: Any, tool_pose: ToolPose, t: float, ids: Any = None) -> np.ndarray:
        """Bring the model's state to the observations (module docstring); returns the synced positions (N, 2)."""
        obs, tris, w, rows = self._observed(points, ids)
        x = self._static_sync(obs, tris, w, tool_pose)
        self._update_bias(obs, rows, x)
        if self._sync_time is not None and t > self._sync_time:
            self.v = (x - self.x) / (t - self._sync_time)
        else:
            self.v = np.zeros_like(x)
        self.x, self._sync_time = x, float(t)
        return x

    def snapshot(self, tool_pose: ToolPose, jaw: float) -> SimSnapshot:
        """The synced state as a snapshot of the model, the tool at ``tool_pose``, the jaw holding what it holds."""
        state = State(self.x.copy(), self.v.copy())
        sim = self.sim
        sim.set_state(state)
        sim.place_tool(tool_pose)
        closed = bool(self.held.size) or jaw < sim.params.grasp_close_angle
        sim.grasp.restore_carry({"jaw": float(jaw), "closed": closed, "idx": self.held.copy(),
                                 "local": self.held_local.copy()})
        return sim.snapshot()

    # ----------------------------------------------------------------------------------------------- goal
    def set_goal(self, pairs: Sequence[tuple[Any, Any]], points: Any, tool_pose: ToolPose | None = None,
                 ids: Any = None) -> np.ndarray:
        """Move the tissue point nearest each ``start`` to its ``goal`` ([(start, goal), ...], m). Returns the goal
        particles' ids. InputError: a NaN, a start not on the tissue, a goal beyond ``max_reach``."""
        if len(pairs) == 0:
            raise InputError("no (start, goal) pair: expected at least one")
        s = self.settings
        obs, tris, w, rows = self._observed(points, ids)
        x_now = self._static_sync(obs, tris, w, tool_pose)  # the model as observed now (positions only)
        self.x = x_now
        starts, goals, gids, goal_rows = [], [], [], []
        for k, (p, q) in enumerate(pairs):
            p = _finite_point(f"start[{k}]", p)
            q = _finite_point(f"goal[{k}]", q)
            d = np.hypot(*(obs - p).T)
            j = int(np.argmin(d))
            if d[j] > s.start_tolerance:
                raise InputError(f"start ({p[0]:.4f}, {p[1]:.4f}) m is {d[j] * 1e3:.1f} mm from the nearest tissue "
                                 f"point: expected a point on the tissue (within {s.start_tolerance * 1e3:.1f} mm)")
            i = int(np.argmin(np.hypot(*(x_now - p).T)))
            if self.fixed[i]:
                raise InputError(f"start ({p[0]:.4f}, {p[1]:.4f}) m is a pinned particle: expected a point that "
                                 "can move")
            reach = float(np.hypot(*(q - obs[j])))
            if reach > s.max_reach:
                raise InputError(f"goal ({q[0]:.4f}, {q[1]:.4f}) m is {reach * 1e3:.1f} mm from its start: expected "
                                 f"at most max_reach={s.max_reach * 1e3:.1f} mm")
            starts.append(p)
            goals.append(q)
            gids.append(i)
            goal_rows.append(int(rows[j]))
        self.goal_ids = np.array(gids, dtype=np.int64)
        self.goals = np.array(goals)
        self.held = np.zeros(0, dtype=np.int64)  # a new goal starts with its own approach and grasp
        self.held_local = np.zeros((0, 2))
        self.starts = np.array(starts)
        # the tissue point at each start: embedded in the model's triangle under it (the model as observed now),
        # so a model coarser than the world (or than the tracker's points) moves the point itself, not the
        # particle nearest it
        self.goal_tris, self.goal_w = embed(self.starts, x_now, np.asarray(self.sim.model.tri_indices))
        self.goal_rows = np.array(goal_rows, dtype=np.int64)
        self.bias = np.zeros_like(self.goals)
        self._bias_set = False
        self._update_bias(obs, rows, x_now)
        self.phase = "approach"
        self.site = None
        self.queue = []
        self._since_replan = 0
        return self.goal_ids

    def model_goal_points(self, x: np.ndarray) -> np.ndarray:
        """The model's goal points (embedded at the starts) with its particles at ``x`` (N, 2) [m]: (P, 2)."""
        return (self.goal_w[:, :, None] * x[self.goal_tris]).sum(axis=1)

    def goal_points(self, x: np.ndarray) -> np.ndarray:
        """Where the goal points are predicted to be with the model's particles at ``x``: the model's points plus
        the bias estimate (offset-free prediction: what the model gets wrong at the goal points, observed)."""
        return self.model_goal_points(x) + self.bias

    def _update_bias(self, obs: np.ndarray, rows: np.ndarray, x: np.ndarray) -> None:
        """bias <- (1 - a) bias + a (observed goal point - model's), a = ``bias_gain`` (the first sync: a = 1);
        a goal point the tracker lost this time leaves its bias as it is."""
        a = self.settings.bias_gain
        if self.goals.shape[0] == 0 or a == 0.0:
            return
        model = self.model_goal_points(x)
        for k, r in enumerate(self.goal_rows):
            at = np.flatnonzero(rows == r)
            if at.size == 0:
                continue
            new = obs[at[0]] - model[k]
            self.bias[k] = new if not self._bias_set else (1.0 - a) * self.bias[k] + a * new
        self._bias_set = True

    def to_go(self) -> np.ndarray:
        """The goals' displacement still to go in the synced model (the mean over the goal points) [m]: (2,)."""
        return (self.goals - self.goal_points(self.x)).mean(axis=0)

    def goal_error(self, x: np.ndarray) -> float:
        """The largest distance of a goal point at positions ``x`` from its goal [m]."""
        d = self.goal_points(x) - self.goals
        return float(np.sqrt((d * d).sum(axis=1)).max())

    # ----------------------------------------------------------------------------------------------- the step
    def command(self, points: Any, tool_pose: ToolPose, jaw: float, *, t: float | None = None, ids: Any = None,
                grasped: Any = None) -> ToolCommand:
        """The next step's command from this step's observation (points, measured tool pose and jaw)."""
        if self.goal_ids.size == 0:
            raise InputError("no goal: call set_goal first")
        if not all(math.isfinite(v) for v in (tool_pose.x, tool_pose.y, tool_pose.yaw)):
            raise InputError(f"tool pose {tool_pose}: expected finite x, y, yaw")
        t = self.steps * self.dt if t is None else float(t)
        if grasped is not None:
            g = np.asarray(grasped, dtype=np.int64).reshape(-1)
            if not np.array_equal(g, self.held):
                self.held = g
                self.held_local = to_tool_frame(self.x[g], tool_pose) if g.size else np.zeros((0, 2))
        replanned = False
        if not self.queue or self._since_replan >= self.settings.replan_every:
            self._replan(points, ids, tool_pose, jaw, t)
            replanned = True
        pose, next_jaw = self.queue.pop(0)
        self._since_replan += 1
        self.steps += 1
        if self.phase == "close" and next_jaw < self.sim.params.grasp_close_angle and not self.held.size:
            # the jaw closes at the start of the next step with the tool here: what lies in reach is held
            self.hold_in_reach(tool_pose)
            self.phase = "pull"
            self.queue = []
        return ToolCommand(pose, twist_from_poses(tool_pose, pose, self.dt), next_jaw, self.phase,
                           self.goal_error(self.x), replanned)

    def hold_in_reach(self, tool_pose: ToolPose) -> np.ndarray:
        """The model's jaw closes with the tool at ``tool_pose``: the free particles within ``grasp_radius`` of the
        tip are held (:attr:`held`, in the tool's frame :attr:`held_local`); returns their ids."""
        d = self.x - np.array([tool_pose.x, tool_pose.y])
        r = self.sim.params.grasp_radius
        near = np.flatnonzero(((d * d).sum(axis=1) <= r * r) & ~self.fixed)
        self.held = near.astype(np.int64)
        self.held_local = to_tool_frame(self.x[near], tool_pose)
        return self.held

    # ----------------------------------------------------------------------------------------------- planning
    def _replan(self, points: Any, ids: Any, tool_pose: ToolPose, jaw: float, t: float) -> None:
        t0 = time.perf_counter()
        self.sync(points, tool_pose, t, ids)
        t1 = time.perf_counter()
        self._since_replan = 0
        rec = ReplanRecord(self.steps, self.phase, t1 - t0, 0.0, 0.0, 0, 0, goal_error=self.goal_error(self.x))
        if self.phase in ("approach", "close"):
            if self.site is None:
                self._choose_site(tool_pose, jaw, rec)
            self._approach(tool_pose)
        else:
            self._pull(tool_pose, jaw, rec)
        rec.choose_s = time.perf_counter() - t1 - rec.rollout_s
        self._record(rec)

    def _record(self, rec: ReplanRecord) -> None:
        """Keep ``rec``, and the newest ``records_kept`` records with it."""
        self.records.append(rec)
        del self.records[:-self.records_kept]

    def _site_pose(self, site: int) -> ToolPose:
        x, y = self.x[site]
        return ToolPose(float(x), float(y) + self.settings.approach_clearance, 0.0)

    def _choose_site(self, tool_pose: ToolPose, jaw: float, rec: ReplanRecord) -> None:
        s = self.settings
        centre = self.goal_points(self.x).mean(axis=0)
        d = np.hypot(*(self.x - centre).T)
        order = [int(i) for i in np.argsort(d, kind="stable") if d[i] <= s.grasp_search and not self.fixed[i]]
        sites = []
        self.sim.set_state(State(self.x.copy(), np.zeros_like(self.x)))
        for i in order:
            pose = self._site_pose(i)
            hover = ToolPose(pose.x, pose.y + s.approach_hover, 0.0)
            if not (self.sim.tool_overlaps_tissue(pose) or self.sim.tool_overlaps_tissue(hover)):
                sites.append(i)
            if len(sites) == s.max_sites:
                break
        if not sites:
            raise InputError(f"no grasp site within grasp_search={s.grasp_search * 1e3:.1f} mm of the start that the "
                             "grasper reaches from above: expected a start near the tissue's top surface")
        disp = self.to_go()
        speed = float(s.pull_speeds[0])
        n_pull = max(1, int(math.ceil(float(np.hypot(*disp)) / (speed * self.dt))))
        paths = []
        for i in sites:
            start = self._site_pose(i)
            frac = np.minimum(np.arange(1, n_pull + 1) / n_pull, 1.0)
            poses = np.empty((n_pull + 1, 3))
            poses[0] = (start.x, start.y, 0.0)
            poses[1:, 0] = start.x + frac * disp[0]
            poses[1:, 1] = start.y + frac * disp[1]
            poses[1:, 2] = 0.0
            jaws = np.full(n_pull + 1, np.nan)
            jaws[0] = s.closed_jaw
            paths.append(ToolPath(poses, start=start, jaws=jaws))
        snap = self.snapshot(tool_pose, s.open_jaw)
        t0 = time.perf_counter()
        batch = rollout_batch(snap, paths, scene=self.scene, pool=self.pool, final_state=True,
                              baseline=self.settings.energy_weight > 0)
        rec.rollout_s += time.perf_counter() - t0
        scores = [self.goal_error(c.final_state.particle_q) if c.finite else math.inf for c in batch.candidates]
        best = int(np.argmin(scores))
        self.site = sites[best]
        rec.candidates, rec.horizon, rec.best, rec.predicted_error = len(paths), n_pull + 1, best, float(scores[best])
        rec.paths = [p.poses[:, :2].copy() for p in paths]

    def _approach(self, tool_pose: ToolPose) -> None:
        """Straight moves above the site, down onto it, then close (the queue up to the next replan)."""
        s = self.settings
        target = self._site_pose(self.site)
        hover = ToolPose(target.x, target.y + s.approach_hover, 0.0)
        step = s.approach_speed * self.dt
        pos = np.array([tool_pose.x, tool_pose.y])
        yaw = tool_pose.yaw
        queue: list[tuple[ToolPose, float]] = []
        if float(np.hypot(tool_pose.x - target.x, tool_pose.y - target.y)) <= APPROACH_REACHED:
            # at the site (the synced site moves with the noise on the points): close the jaw where the tool is
            self.phase = "close"
            self.queue = [(ToolPose(tool_pose.x, tool_pose.y, tool_pose.yaw), s.closed_jaw)]
            return
        waypoints = [np.array([target.x, target.y])] if abs(tool_pose.x - target.x) < 1e-3 and \
            tool_pose.y <= hover.y + 1e-9 else [*self._rise(tool_pose, hover), np.array([hover.x, hover.y]),
                                                 np.array([target.x, target.y])]
        for w in waypoints:
            while len(queue) < s.replan_every:
                d = w - pos
                dist = float(np.hypot(*d))
                if dist <= 1e-9:
                    break
                pos = w.copy() if dist <= step else pos + d * (step / dist)
                yaw = 0.0
                queue.append((ToolPose(float(pos[0]), float(pos[1]), yaw), s.open_jaw))
        if not queue:
            queue.append((ToolPose(target.x, target.y, 0.0), s.open_jaw))
        self.queue = queue

    @staticmethod
    def _rise(tool_pose: ToolPose, hover: ToolPose) -> list[np.ndarray]:
        """A tool below the hover height and not over the site first rises straight up to that height: from
        wherever it starts, the open grasper then crosses to the site above the tissue, never through it."""
        if tool_pose.y < hover.y - 1e-9 and abs(tool_pose.x - hover.x) >= 1e-3:
            return [np.array([tool_pose.x, hover.y])]
        return []

    def planned_path(self, points: Any, tool_pose: ToolPose, jaw: float, *, t: float | None = None,
                     ids: Any = None) -> np.ndarray:
        """The plan as it stands, as tool poses (K, 3) [m, m, rad]: from ``tool_pose`` above the grasp site, down
        onto it, then the straight pull by the goal's displacement (the pull the site was chosen by). Syncs to the
        observation and chooses the grasp site first when it is not chosen yet (:meth:`set_goal` resets it); the
        pull phase's plan is the committed part of the best candidate, then the rest of the displacement."""
        if self.goal_ids.size == 0:
            raise InputError("no goal: call set_goal first")
        s = self.settings
        t = self.steps * self.dt if t is None else float(t)
        pts = [(tool_pose.x, tool_pose.y, tool_pose.yaw)]
        if self.phase in ("approach", "close"):
            if self.site is None:
                self.sync(points, tool_pose, t, ids)
                rec = ReplanRecord(self.steps, self.phase, 0.0, 0.0, 0.0, 0, 0, goal_error=self.goal_error(self.x))
                self._choose_site(tool_pose, jaw, rec)
                self._record(rec)
            site = self._site_pose(self.site)
            hover = ToolPose(site.x, site.y + s.approach_hover, 0.0)
            pts += [(float(w[0]), float(w[1]), 0.0) for w in self._rise(tool_pose, hover)]
            pts += [(hover.x, hover.y, 0.0), (site.x, site.y, 0.0)]
        else:
            pts += [(p.x, p.y, p.yaw) for p, _ in self.queue]
        disp = self.to_go()
        last = pts[-1]
        if self.phase in ("approach", "close"):
            pts.append((last[0] + disp[0], last[1] + disp[1], 0.0))
        elif self.phase == "pull":
            pts.append((tool_pose.x + disp[0], tool_pose.y + disp[1], tool_pose.yaw))
        return np.array(pts, dtype=np.float64)

    def pull_candidates(self, tool_pose: ToolPose) -> list[ToolPath]:
        """The pull phase's candidate tool paths from ``tool_pose`` (module docstring); the last holds still."""
        s = self.settings
        disp = self.to_go()
        p0 = np.array([tool_pose.x, tool_pose.y])
        out = []
        k = np.arange(1, s.horizon + 1, dtype=np.float64)
        for speed in s.pull_speeds:
            for gain in s.gains:
                for ang in s.angles_deg:
                    a = math.radians(ang)
                    c, sn = math.cos(a), math.sin(a)
                    d = gain * np.array([c * disp[0] - sn * disp[1], sn * disp[0] + c * disp[1]])
                    dist = float(np.hypot(*d))
                    frac = np.minimum(k * speed * self.dt / dist, 1.0) if dist > 0 else np.ones_like(k)
                    poses = np.empty((s.horizon, 3))
                    poses[:, 0] = p0[0] + frac * d[0]
                    poses[:, 1] = p0[1] + frac * d[1]
                    poses[:, 2] = tool_pose.yaw
                    out.append(ToolPath(poses))
        hold = np.empty((s.horizon, 3))
        hold[:] = (tool_pose.x, tool_pose.y, tool_pose.yaw)
        out.append(ToolPath(hold))
        return out

    def score(self, result: Any) -> float:
        """A candidate's score (module docstring); inf when its rollout was not finite."""
        s = self.settings
        if not result.finite or result.final_state is None:
            return math.inf
        score = (self.goal_error(result.final_state.particle_q) + s.force_weight * result.peak_force
                 + s.penetration_weight * result.max_penetration)
        if s.energy_weight > 0:  # the baseline is rolled out only then
            score += s.energy_weight * max(0.0, result.peak_added)
        return score

    def _pull(self, tool_pose: ToolPose, jaw: float, rec: ReplanRecord) -> None:
        s = self.settings
        if self.goal_error(self.x) <= s.tolerance:
            self.phase = "holding"
        elif self.phase == "holding" and self.goal_error(self.x) > 1.5 * s.tolerance:
            self.phase = "pull"
        paths = self.pull_candidates(tool_pose)
        snap = self.snapshot(tool_pose, jaw)
        t0 = time.perf_counter()
        batch = rollout_batch(snap, paths, scene=self.scene, pool=self.pool, final_state=True,
                              baseline=self.settings.energy_weight > 0)
        rec.rollout_s += time.perf_counter() - t0
        scores = np.array([self.score(c) for c in batch.candidates])
        best = len(paths) - 1 if self.phase == "holding" else int(np.argmin(scores))
        rec.candidates, rec.horizon, rec.best, rec.predicted_error = len(paths), s.horizon, best, float(scores[best])
        rec.paths = [p.poses[:, :2].copy() for p in paths]
        poses = paths[best].poses[: s.replan_every]
        self.queue = [(ToolPose(float(p[0]), float(p[1]), float(p[2])), s.closed_jaw) for p in poses]
