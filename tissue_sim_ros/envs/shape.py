"""``TissueSim/Shape-v0``: grasp the retraction flap and bring three of its points to a target shape.

The paper's second half, "generate the operation from the current and the target deformation", as a task: the
goal is a deformation, three points of the flap's top surface 8 mm apart, where a grasp and pull would put them.
Each episode draws the grasp's x from ``goal_region[0]`` (default 30 to 50 mm) and its pull (dx, dy) from
``goal_region[1:]`` (default dx in [-10, 10] mm, dy in [5, 20] mm, as Retract-v0's goals), then makes the target by
doing it on the episode's own scene (the grasper closed on the surface there, pulled at 3 cm/s, held 0.2 s) and
keeping where the three points went: so every target is a shape the tissue can take, and the same seed gives the
same target. The scene then starts afresh at rest, the grasper open 15 mm above the middle point, 1 cm left of it.

* action (3,): as Retract-v0 (tip velocity at +-0.05 m/s, jaw);
* achieved goal: the three points (6,) [m] (x0, y0, x1, y1, x2, y2); desired goal: their targets (6,);
* reward: dense, minus the largest point's distance in cm; sparse, 0 when every point is within ``tolerance``
  (3 mm) of its target, else -1;
* success: every point within ``tolerance``.
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from ..core.contact.tool import ToolPose
from ..core.errors import InputError
from ..core.plan.observe import embed, flap_surface
from ..core.timing.trajectories import RETRACT_JAW_OPEN
from .base import TissueEnv, as_points, embedding_matrix, range_of
from .retract import RETRACT_GOALS

#: where the grasp that makes the target takes the flap: x range [m]
SHAPE_SITES = (0.03, 0.05)
#: the three points' x offsets from the grasp [m]
SHAPE_OFFSETS = (-0.008, 0.0, 0.008)
PULL_SPEED = 0.03
HOLD_STEPS = 20


class ShapeEnv(TissueEnv):
    """Bring three points of the flap to a target shape (module docstring)."""

    scene = "retract"
    max_speed = 0.05
    jaw_open = RETRACT_JAW_OPEN
    default_tolerance = 0.003
    goal_size = 2 * len(SHAPE_OFFSETS)

    def __init__(self, render_mode: str | None = None, **kwargs: Any) -> None:
        super().__init__(render_mode, **kwargs)
        self.starts = np.zeros((len(SHAPE_OFFSETS), 2))

    def check_goal_region(self, region: Any) -> Any:
        if region is None:
            return (SHAPE_SITES, *RETRACT_GOALS)
        try:
            parts = list(region)
        except TypeError:
            parts = []
        if len(parts) != 3:
            raise InputError(f"goal_region={region!r}: expected ((x_low, x_high), (dx_low, dx_high), "
                             "(dy_low, dy_high)) in m")
        return tuple(range_of(f"goal_region[{i}]", r) for i, r in enumerate(parts))

    def draw_goal(self, rng: np.random.Generator, options: Mapping[str, Any]) -> np.ndarray:
        (x0, x1), (dx0, dx1), (dy0, dy1) = options.get("goal_region", self.goal_region)
        site = float(rng.uniform(x0, x1))
        pull = np.array([rng.uniform(dx0, dx1), rng.uniform(dy0, dy1)])
        self.starts = np.array([(site + o, flap_surface(self.q0, site + o)) for o in SHAPE_OFFSETS])
        self.goal_matrix = embedding_matrix(*embed(self.starts, self.q0, self.tris), self.q0.shape[0])
        if "goal" in options:
            return as_points(options["goal"]).reshape(-1)
        return self._pulled(site, pull)

    def _pulled(self, site: float, pull: np.ndarray) -> np.ndarray:
        """Where the points go when the flap is grasped at ``site`` and pulled by ``pull``; the scene is put back."""
        sim = self.sim
        snap = sim.snapshot()
        top = flap_surface(sim.state.particle_q, site)
        pose = ToolPose(site, top + 0.0005, 0.0)
        sim.place_tool(pose)
        sim.step(pose, jaw=self.jaw_open)
        sim.step(pose, jaw=0.0)
        n = max(1, int(np.ceil(float(np.hypot(*pull)) / (PULL_SPEED * self.dt))))
        for k in range(1, n + HOLD_STEPS + 1):
            f = min(k, n) / n
            sim.step(ToolPose(pose.x + f * pull[0], pose.y + f * pull[1], 0.0))
        target = self.achieved()
        sim.restore(snap)
        return target

    def start_pose(self) -> tuple[np.ndarray, float, float]:
        return self.starts[1] + np.array([-0.01, 0.015]), 0.0, self.jaw_open

    def goal_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """The (start, goal) points [m] of the episode, (3, 2) each."""
        return self.starts, self.goal.reshape(-1, 2)
