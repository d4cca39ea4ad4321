"""Baseline policies for the tissue tasks: the planners as experts, and a random policy.

* Retract-v0 and Shape-v0: the model-predictive grasp controller (:class:`~tissue_sim_ros.core.plan.control.TissueController`),
  driven as ``experiments/control.py`` drives it offline: its own model of the scene (twice the world's mesh
  spacing, :func:`~tissue_sim_ros.core.plan.control.default_model`, with the episode's material) synced each replan
  to every particle of the world, the goal pairs of the episode; its commanded pose becomes the action's velocity.
* Probe-v0: the insertion planner (:func:`~tissue_sim_ros.core.plan.insertion.plan_insertion`, the paper's way of
  choosing an insertion by its energy): from the episode's first state it rolls straight insertions toward the
  target out at three angles and keeps the cheapest; the tool then moves through the gap to that insertion's
  entry, turning to its angle, and inserts along it.
* :class:`RandomPolicy`: uniform actions from a seeded generator.

The experts are privileged (they read the world's particles, not the observation): they are demonstrators for
offline RL and imitation, and the bar a learned policy is measured against. ``expert_action(env)`` keeps one
expert per environment and starts it afresh at each episode; :func:`evaluate` runs a policy over seeded episodes.
"""
from __future__ import annotations

import math
import weakref
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from ..core.errors import InputError
from ..core.plan.control import ControlSettings, TissueController, default_model
from ..core.plan.insertion import InsertionRequest, plan_insertion
from ..core.sim.batch import BatchScene


def velocity_action(env: Any, tip: Sequence[float], yaw: float | None = None, jaw: float | None = None) -> np.ndarray:
    """The action that moves the tool's tip toward ``tip`` [m] (and its yaw toward ``yaw``, its jaw to ``jaw``)
    in one step, as far as the speed limits allow."""
    e = env.unwrapped
    a = np.zeros(e.action_space.shape, dtype=np.float32)
    a[:2] = np.clip((np.asarray(tip, dtype=np.float64) - e.tip) / (e.max_speed * e.dt), -1.0, 1.0)
    k = 2
    if e.max_yaw_rate > 0:
        a[k] = 0.0 if yaw is None else float(np.clip((yaw - e.yaw) / (e.max_yaw_rate * e.dt), -1.0, 1.0))
        k += 1
    if e.jaw_open > 0:
        a[k] = float(np.clip(2.0 * (e.jaw if jaw is None else jaw) / e.jaw_open - 1.0, -1.0, 1.0))
    return a


class GraspExpert:
    """The grasp controller as the expert of Retract-v0 and Shape-v0 (module docstring)."""

    def __init__(self, env: Any, settings: ControlSettings | None = None) -> None:
        self.env = env.unwrapped
        e = self.env
        self.settings = settings or ControlSettings(tolerance=0.75 * e.tolerance)
        self.model = default_model(e.config)
        # the model's mesh depends on the spacing alone: meshed once, each episode's material set over it
        self.mesh = e.config.replace(**self.model).scene.build_mesh()
        self.episode = -1
        self.ctrl: TissueController | None = None

    def start(self) -> None:
        e = self.env
        cfg = e.config.replace(**self.model, **e.episode_material)
        self.ctrl = TissueController(cfg, self.settings, mesh=self.mesh)
        starts, goals = e.goal_pairs()
        self.ctrl.set_goal(list(zip(starts, goals)), e.sim.state.particle_q, e.sim.tool_pose)
        self.episode = e.episode

    def __call__(self, obs: Any = None) -> np.ndarray:
        e = self.env
        if self.episode != e.episode:
            self.start()
        cmd = self.ctrl.command(e.sim.state.particle_q, e.sim.tool_pose, e.jaw, t=e.sim.time)
        return velocity_action(e, (cmd.pose.x, cmd.pose.y), jaw=cmd.jaw)


class ProbeExpert:
    """The insertion planner as the expert of Probe-v0 (module docstring)."""

    def __init__(self, env: Any, angle_offsets_deg: Sequence[float] = (-10.0, 0.0, 10.0), speed: float = 0.1,
                 entry_distance: float = 0.12) -> None:
        self.env = env.unwrapped
        self.offsets = tuple(angle_offsets_deg)
        self.speed = float(speed)
        self.entry_distance = float(entry_distance)
        self.scene = BatchScene.from_simulation(self.env.sim)
        self.episode = -1
        self.path: np.ndarray | None = None
        self.k = 0

    def start(self) -> None:
        """Plan from the episode's first state: the cheapest insertion, or a straight move when none reaches."""
        e = self.env
        target = tuple(float(v) for v in e.goal)
        base = math.radians(e.approach_deg)
        entry = (target[0] - self.entry_distance * math.cos(base), target[1] - self.entry_distance * math.sin(base))
        req = InsertionRequest(entry, target, e.tolerance, angle_offsets_deg=self.offsets, speeds=(self.speed,))
        self.scene = BatchScene.from_simulation(e.sim)  # this episode's material
        plan = plan_insertion(e.sim.snapshot(), self.scene, req)
        if plan.ok:
            best = plan.candidates[plan.best]
            poses = best.path.poses
            tips = poses[:, :2] + e.tip_offset * np.stack([np.cos(poses[:, 2]), np.sin(poses[:, 2])], axis=1)
            self.path = np.concatenate([tips, poses[:, 2:3]], axis=1)
        else:  # a target in the open (or every entry blocked): straight at it, tip first
            self.path = np.array([[target[0], target[1], math.atan2(target[1] - e.tip[1], target[0] - e.tip[0])]])
        self.k = 0
        self.episode = e.episode

    def __call__(self, obs: Any = None) -> np.ndarray:
        e = self.env
        if self.episode != e.episode:
            self.start()
        entry = self.path[0]
        if self.k == 0 and (math.hypot(*(entry[:2] - e.tip)) > 1e-6 or abs(entry[2] - e.yaw) > 1e-6):
            return velocity_action(e, entry[:2], yaw=float(entry[2]))  # through the gap to the entry, turning
        self.k = min(self.k + 1, len(self.path) - 1)
        p = self.path[self.k]
        return velocity_action(e, p[:2], yaw=float(p[2]))


class RandomPolicy:
    """Uniform random actions from a generator seeded with ``seed`` (the same actions for the same seed)."""

    def __init__(self, env: Any, seed: int | None = 0) -> None:
        self.space = env.action_space
        self.space.seed(seed)

    def __call__(self, obs: Any = None) -> np.ndarray:
        return self.space.sample()


EXPERTS: dict[str, type] = {"RetractEnv": GraspExpert, "ShapeEnv": GraspExpert, "ProbeEnv": ProbeExpert}
_experts: "weakref.WeakKeyDictionary[Any, Any]" = weakref.WeakKeyDictionary()


def make_expert(env: Any) -> Callable[[Any], np.ndarray]:
    """The expert policy of ``env``'s task: ``policy(obs) -> action`` (it reads the environment itself)."""
    kind = type(env.unwrapped).__name__
    if kind not in EXPERTS:
        raise InputError(f"environment {kind}: no expert; expected one of {', '.join(EXPERTS)}")
    return EXPERTS[kind](env)


def expert_action(env: Any) -> np.ndarray:
    """The expert's next action for ``env`` as it is now (one expert kept per environment, restarted at each
    episode: call it after ``reset`` and after each ``step``)."""
    e = env.unwrapped
    if e not in _experts:
        _experts[e] = make_expert(e)
    return _experts[e]()


@dataclass
class EpisodeResult:
    """One evaluated episode."""

    seed: int
    success: bool
    """Success at the episode's last step (``info["is_success"]``, as gymnasium-robotics reports it)."""
    ever: bool
    """Success at any step."""
    steps: int
    ret: float
    final_distance: float
    peak_force: float
    energy: float
    """The energy summed over the steps."""


def run_episode(env: Any, policy: Callable[[Any], np.ndarray], seed: int, options: dict | None = None,
                on_step: Callable[[], None] | None = None) -> EpisodeResult:
    """One episode of ``policy`` on ``env`` from ``reset(seed=seed)`` to termination or the time limit."""
    obs, info = env.reset(seed=seed, options=options)
    ret, ever, peak, energy, steps = 0.0, bool(info["is_success"]), 0.0, 0.0, 0
    done = False
    while not done:
        obs, r, term, trunc, info = env.step(policy(obs))
        ret += float(r)
        steps += 1
        ever = ever or bool(info["is_success"])
        peak = max(peak, float(info["force"]))
        energy += float(info["energy"])
        done = term or trunc
        if on_step is not None:
            on_step()
    return EpisodeResult(seed, bool(info["is_success"]), ever, steps, ret, float(info["distance"]), peak, energy)


def evaluate(env: Any, policy: Callable[[Any], np.ndarray], seeds: Sequence[int],
             progress: Callable[[int, int], None] | None = None) -> list[EpisodeResult]:
    """:func:`run_episode` for each seed; ``progress(i, n)`` after each episode."""
    out = []
    for i, s in enumerate(seeds):
        out.append(run_episode(env, policy, int(s)))
        if progress is not None:
            progress(i + 1, len(seeds))
    return out


def summarise(results: Sequence[EpisodeResult]) -> dict[str, Any]:
    """A policy's row of the baselines' table: success rate (at the last step, and at any step), median return,
    final distance, peak force and steps."""
    n = len(results)
    return {"episodes": n,
            "success": sum(r.success for r in results) / n if n else math.nan,
            "success_any_step": sum(r.ever for r in results) / n if n else math.nan,
            "median_return": float(np.median([r.ret for r in results])) if n else math.nan,
            "median_final_distance_mm": 1e3 * float(np.median([r.final_distance for r in results])) if n else math.nan,
            "median_peak_force_N": float(np.median([r.peak_force for r in results])) if n else math.nan,
            "median_steps": float(np.median([r.steps for r in results])) if n else math.nan}
