"""``TissueSim/Retract-v0``: grasp the retraction flap and bring one of its points to a goal.

The scene is ``config/scenes/retract.yaml``: a 6 cm x 1.2 cm flap of soft tissue (neo-Hookean, E 5 kPa) pinned
along its base, and a laparoscopic grasper. The tracked point is the flap's top surface at ``point_x`` (default
40 mm, where the controller's experiment takes it); each episode draws its goal from ``goal_region``, offsets
(dx, dy) [m] from the point's rest position: by default dx in [-10, 10] mm and dy in [5, 20] mm (lifted, pushed
sideways). The grasper's tip starts 1 cm left of and 15 mm above the point, open.

* action (3,): tip velocity v_x, v_y at +-1 = +-``max_speed`` (0.05 m/s, the controller's approach speed), and the
  jaw: -1 closed (0 rad) to +1 open (0.8 rad); the jaw grasps what lies within ``grasp_radius`` of the tip when it
  closes below ``grasp_close_angle`` and lets go above ``grasp_open_angle`` (the scene's 0.2 and 0.4 rad);
* achieved goal: the tracked point (2,) [m]; desired goal: its goal (2,) [m];
* reward: dense, minus the distance in cm; sparse, 0 within ``tolerance`` (2 mm) else -1;
* success (``info["is_success"]``): within ``tolerance`` of the goal.
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from ..core.errors import InputError
from ..core.plan.observe import RETRACT_X, embed, flap_surface
from ..core.timing.trajectories import RETRACT_JAW_OPEN
from .base import TissueEnv, as_points, embedding_matrix, range_of

#: (dx, dy) ranges [m] of the goal from the tracked point's rest position
RETRACT_GOALS = ((-0.01, 0.01), (0.005, 0.02))


def check_offsets(region: Any, default: tuple, name: str = "goal_region") -> tuple[tuple[float, float], ...]:
    """A region of (dx, dy) offsets as ((dx_low, dx_high), (dy_low, dy_high)); InputError otherwise."""
    if region is None:
        return default
    try:
        pair = list(region)
    except TypeError:
        pair = []
    if len(pair) != 2:
        raise InputError(f"{name}={region!r}: expected ((dx_low, dx_high), (dy_low, dy_high)) in m")
    return tuple(range_of(f"{name}[{i}]", r) for i, r in enumerate(pair))


class RetractEnv(TissueEnv):
    """Grasp the flap and bring its point to the goal (module docstring)."""

    scene = "retract"
    max_speed = 0.05
    jaw_open = RETRACT_JAW_OPEN
    default_tolerance = 0.002

    def __init__(self, render_mode: str | None = None, *, point_x: float = RETRACT_X, **kwargs: Any) -> None:
        self.point_x = float(point_x)
        super().__init__(render_mode, **kwargs)
        top = flap_surface(self.q0, self.point_x)
        self.start_point = np.array([self.point_x, top])
        """The tracked point's rest position [m]."""
        self.goal_matrix = embedding_matrix(*embed(self.start_point[None], self.q0, self.tris), self.q0.shape[0])

    def check_goal_region(self, region: Any) -> Any:
        return check_offsets(region, RETRACT_GOALS)

    def draw_goal(self, rng: np.random.Generator, options: Mapping[str, Any]) -> np.ndarray:
        if "goal" in options:
            return as_points(options["goal"])[0]
        (dx0, dx1), (dy0, dy1) = options.get("goal_region", self.goal_region)
        return self.start_point + np.array([rng.uniform(dx0, dx1), rng.uniform(dy0, dy1)])

    def start_pose(self) -> tuple[np.ndarray, float, float]:
        return self.start_point + np.array([-0.01, 0.015]), 0.0, self.jaw_open


    def goal_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """The (start, goal) points [m] of the episode, (P, 2) each: what a controller is asked to do."""
        return self.start_point[None], self.goal[None]
