"""``TissueSim/Probe-v0``: the paper's experiment b as a task: bring the tool tip to a target at the lower tissue
through the gap, paying the tissue's implicit Euler energy and the reaction force.

The scene is the paper's (the shipped ``config/tissue_sim.yaml``: two tissues 1 m wide, PBD, the clear gap
y = 0.40-0.62 m between them), with experiment b's 0.3 m x 5 mm box (``core/timing/trajectories.py``, ``B_TOOL``)
and projection contact (the paper's contact rule lets a moving tool pass through the tissue, which a learner
would exploit); ``params`` changes any of it. The tip starts in the gap at (0.30, 0.50) m, pointing +x. Each
episode draws the target from ``goal_region`` = ((x_low, x_high), (depth_low, depth_high)) [m]: x in
[0.45, 0.65] m and a depth of 5 to 25 mm under the lower tissue's rest surface at that x (experiment b's target is
16 mm under it at x = 0.55 m). A target in the open gap is a negative depth.

* action (3,): the tip's velocity v_x, v_y at +-1 = +-``max_speed`` (0.2 m/s: experiment b moves at 0.1 m/s) and
  the yaw rate at +-1 = +-1 rad/s;
* achieved goal: the tip (2,) [m]; desired goal: the target (2,) [m];
* reward: minus the distance in units of 10 cm (dense) or -1 outside ``tolerance`` (5 mm; sparse), minus
  ``energy_weight`` x the energy the step adds over the same scene without a tool (the paper's cost, as
  ``experiments/paper.py``'s ``insertion_cost`` measures it; ``info["energy_added"]``), minus ``force_weight`` x
  the reaction force [N];
* success: the tip within ``tolerance`` of the target.
"""
from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from ..core.errors import InputError
from ..core.plan.observe import flap_surface
from ..core.sim.batch import rollout_baseline
from ..core.timing.trajectories import B_TOOL
from .base import MATERIAL, TissueEnv, as_points
from .retract import check_offsets

#: ((x_low, x_high), (depth_low, depth_high)) [m] of the target
PROBE_GOALS = ((0.45, 0.65), (0.005, 0.025))
PROBE_START = (0.30, 0.50)


class ProbeEnv(TissueEnv):
    """Bring the tip to the target at the least energy (module docstring)."""

    scene = ""
    scene_defaults = {"tool_shape": B_TOOL.kind, "tool_length": B_TOOL.length, "tool_width": B_TOOL.width,
                      "contact_model": "projection"}
    max_speed = 0.2
    max_yaw_rate = 1.0
    default_tolerance = 0.005
    n_points_default = 24
    approach_deg = -20.0
    """The direction an expert's insertions are centred on [deg] (experiment b's are at -10 and -30)."""

    def __init__(self, render_mode: str | None = None, *, energy_weight: float = 1e7, force_weight: float = 1.0,
                 **kwargs: Any) -> None:
        for name, v in (("energy_weight", energy_weight), ("force_weight", force_weight)):
            if not (math.isfinite(v) and v >= 0):
                raise InputError(f"{name}={v!r}: expected a finite weight >= 0")
        self.energy_weight, self.force_weight = float(energy_weight), float(force_weight)
        super().__init__(render_mode, **kwargs)
        self.lower = int(np.argmin([self.q0[np.asarray(self.sim.model.particle_body) == b][:, 1].mean()
                                    for b in range(self.sim.model.n_bodies)]))
        """The body the targets are in: the lowest."""
        self._baselines: dict[tuple, np.ndarray] = {}
        self.baseline = np.zeros(1)

    def make_workspace(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        return np.array([lo[0], lo[1], hi[0], hi[1]])

    def check_goal_region(self, region: Any) -> Any:
        return check_offsets(region, PROBE_GOALS)

    def surface(self, x: float) -> float:
        """The lower tissue's rest surface at ``x`` [m]."""
        q = self.q0[np.asarray(self.sim.model.particle_body) == self.lower]
        return flap_surface(q, x)

    def draw_goal(self, rng: np.random.Generator, options: Mapping[str, Any]) -> np.ndarray:
        if "goal" in options:
            return as_points(options["goal"])[0]
        (x0, x1), (d0, d1) = options.get("goal_region", self.goal_region)
        x = float(rng.uniform(x0, x1))
        return np.array([x, self.surface(x) - float(rng.uniform(d0, d1))])

    def start_pose(self) -> tuple[np.ndarray, float, float]:
        return np.array(PROBE_START), 0.0, 0.0

    def achieved(self) -> np.ndarray:
        return self.tip.copy()

    def _start_episode(self, material: Mapping[str, float | None]) -> None:
        """The scene as the base class starts it, and the tool-free energy of the episode's steps from there (once
        per material), which each step's energy is measured against."""
        super()._start_episode(material)
        key = tuple(material[k] for k in MATERIAL)
        if key not in self._baselines:
            snap = self.sim.snapshot()
            limit = self.spec.max_episode_steps if self.spec is not None and self.spec.max_episode_steps else 300
            self._baselines[key] = rollout_baseline(self.sim, snap, int(limit))
            self.sim.restore(snap)
        self.baseline = self._baselines[key]

    def _info(self, r, achieved_goal: np.ndarray, desired_goal: np.ndarray) -> dict[str, Any]:
        info = super()._info(r, achieved_goal, desired_goal)
        base = self.baseline[min(self.steps, len(self.baseline)) - 1] if r is not None else 0.0
        info["energy_added"] = max(0.0, info["energy"] - float(base)) if r is not None else 0.0
        return info

    def compute_reward(self, achieved_goal: Any, desired_goal: Any, info: Any) -> Any:
        """The distance term (dense: minus the distance in units of 10 cm; sparse: -1 outside ``tolerance``) minus
        the energy and force penalties of ``info`` (a dict of numbers or of arrays, or a sequence of dicts, as a
        vector env or a replay buffer hands it). Vectorised over leading batch dimensions."""
        d = self.distance(achieved_goal, desired_goal)
        r = -(d > self.tolerance).astype(np.float64) if self.reward_type == "sparse" else -d / 0.1
        r = r - self.energy_weight * _field(info, "energy_added", d) - self.force_weight * _field(info, "force", d)
        return float(r) if np.ndim(r) == 0 else r.astype(np.float32)


def _field(info: Any, name: str, like: np.ndarray) -> np.ndarray:
    """``info[name]`` as an array shaped as ``like``: from a dict, a dict of arrays, or a sequence of dicts (0 when
    absent, as for a relabelled goal whose info had none)."""
    if isinstance(info, Mapping):
        v = np.asarray(info.get(name, 0.0), dtype=np.float64)
    elif info is None:
        v = np.zeros(())
    else:
        v = np.array([i.get(name, 0.0) for i in np.ravel(info)], dtype=np.float64).reshape(np.shape(info))
    return np.broadcast_to(v, np.shape(like)) if np.ndim(like) else v.reshape(())
