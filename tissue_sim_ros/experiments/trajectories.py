"""Tool trajectories of the paper's experiments on the default scene (config/tissue.png).

The default scene is 1 m x 1 m: an upper tissue hanging from y = 0.984 m with
its wavy lower edge at y = 0.620-0.674 m, a lower tissue resting on y = 0.014 m
with its wavy upper edge at y = 0.344-0.398 m (0.396 m at x = 0.5-0.6), and a
clear channel y = 0.398-0.620 m between them where the tool enters from the left.

* ``experiment_a``: the authors' 0.8 m x 5 mm box, tip first, moves down and to
  the right at 30 degrees below horizontal at 0.001 m per step (the authors'
  speed) from the gap toward the lower tissue; it comes within alpha = 0.025 m
  of the surface near step 145-150 and reaches it near step 190, then pushes it
  for the rest of the 300 steps (the paper's snapshots are at steps 150, 220, 270).
* ``experiment_b_*``: insertions from two angles toward one target point 16 mm
  inside the lower tissue's surface (0.396 m at x = 0.55); the tool is a 0.3 m box so that the
  steeper insertion fits in the gap without touching the upper tissue.
"""
from __future__ import annotations

import math

from ..core.errors import InputError
from ..core.tool import StraightInsertion, ToolShape, Trajectory

#: Experiment a: tip start [m], direction [deg], speed [m per step], steps.
A_START = (0.25, 0.47)
A_ANGLE_DEG = -30.0
A_SPEED = 0.001
A_STEPS = 300
#: The paper's snapshot steps (Fig. 2).
A_SNAPSHOTS = (0, 150, 220, 270)

#: Experiment b: the common target of the tool tip [m], insertion distance [m], speed [m/step], angles [deg].
B_TARGET = (0.55, 0.38)
B_DISTANCE = 0.22
B_SPEED = 0.001
B_ANGLES_DEG = (-10.0, -30.0)
B_TOOL = ToolShape(kind="box", length=0.3, width=0.005)


def experiment_a(tool: ToolShape, dt: float, speed: float = A_SPEED, steps: int = A_STEPS) -> StraightInsertion:
    """Experiment a's insertion: ``steps`` steps of ``speed`` m from A_START along A_ANGLE_DEG."""
    a = math.radians(A_ANGLE_DEG)
    travel = speed * steps
    target = (A_START[0] + travel * math.cos(a), A_START[1] + travel * math.sin(a))
    return StraightInsertion.from_tool(tool, A_START, target, speed, dt=dt)


def experiment_b(tool: ToolShape, dt: float, angle_deg: float, speed: float = B_SPEED,
                 target: tuple[float, float] = B_TARGET, distance: float = B_DISTANCE) -> StraightInsertion:
    """An insertion at ``angle_deg`` (direction of the tip's motion) ending at ``target``."""
    return StraightInsertion.from_angle(tool, target, math.radians(angle_deg), distance, speed, dt=dt)


PRESETS = ("experiment_a", "experiment_b_shallow", "experiment_b_steep")


def preset(name: str, tool: ToolShape, dt: float) -> Trajectory:
    """A named trajectory (used by the tool driver node): one of :data:`PRESETS`."""
    if name == "experiment_a":
        return experiment_a(tool, dt)
    if name == "experiment_b_shallow":
        return experiment_b(tool, dt, B_ANGLES_DEG[0])
    if name == "experiment_b_steep":
        return experiment_b(tool, dt, B_ANGLES_DEG[1])
    raise InputError(f"trajectory preset {name!r}: expected one of {', '.join(PRESETS)}")
