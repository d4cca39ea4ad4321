"""Tool trajectories of the experiments on each shipped scene (the paper's default first, config/tissue.png).

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
from dataclasses import dataclass

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


@dataclass(frozen=True)
class SceneExperiments:
    """Where a scene's experiments a and b put the tool (speeds in m per step, as the paper's)."""

    a_start: tuple[float, float]
    """Experiment a: the tool tip's start [m]."""
    a_angle_deg: float
    """Experiment a: direction of the tip's motion [deg]."""
    a_speed: float
    """Experiment a: tip speed [m per step]."""
    a_steps: int
    """Experiment a: steps."""
    a_snapshots: tuple[int, ...]
    """Experiment a: the steps drawn."""
    b_target: tuple[float, float]
    """Experiment b: the common target of the tool tip [m]."""
    b_distance: float
    """Experiment b: insertion distance [m]."""
    b_speed: float
    """Experiment b: tip speed [m per step]."""
    b_angles_deg: tuple[float, float]
    """Experiment b: the shallow and the steep insertion angle [deg]."""
    b_tool: ToolShape | None
    """Experiment b: the tool (None: the scene's own)."""


PAPER = SceneExperiments(A_START, A_ANGLE_DEG, A_SPEED, A_STEPS, A_SNAPSHOTS,
                         B_TARGET, B_DISTANCE, B_SPEED, B_ANGLES_DEG, B_TOOL)

#: The real-size scene (config/scenes/liver_probe.yaml, dt 10 ms): the 5 mm instrument comes down at 40 degrees
#: at 4 mm/s (4e-5 m per step) onto the slab's dome (surface at y = 33.4-33.8 mm around x = 28-34 mm), touches
#: it near step 150 and presses its tip about 4 mm in by step 400; experiment b reaches a point 3 mm under the
#: surface at x = 40 mm from 20 and 50 degrees below horizontal.
LIVER_PROBE = SceneExperiments((0.022, 0.040), -40.0, 4e-5, 400, (0, 150, 280, 400),
                               (0.040, 0.031), 0.012, 4e-5, (-20.0, -50.0), None)

#: Experiments per shipped scene (``tissue-sim experiment a --scene NAME``; the tool driver's ``scene``).
SCENE_EXPERIMENTS: dict[str, SceneExperiments] = {"paper": PAPER, "liver_probe": LIVER_PROBE}


def scene_experiments(name: str) -> SceneExperiments:
    """The experiments of a shipped scene by name; InputError naming the known ones."""
    try:
        return SCENE_EXPERIMENTS[name]
    except KeyError:
        raise InputError(f"scene {name!r}: expected one of {', '.join(SCENE_EXPERIMENTS)}") from None


def experiment_a(tool: ToolShape, dt: float, speed: float | None = None, steps: int | None = None,
                 scene: SceneExperiments = PAPER) -> StraightInsertion:
    """Experiment a's insertion: ``steps`` steps of ``speed`` m from the scene's start along its angle."""
    speed = scene.a_speed if speed is None else speed
    steps = scene.a_steps if steps is None else steps
    a = math.radians(scene.a_angle_deg)
    travel = speed * steps
    target = (scene.a_start[0] + travel * math.cos(a), scene.a_start[1] + travel * math.sin(a))
    return StraightInsertion.from_tool(tool, scene.a_start, target, speed, dt=dt)


def experiment_b(tool: ToolShape, dt: float, angle_deg: float, speed: float | None = None,
                 target: tuple[float, float] | None = None, distance: float | None = None,
                 scene: SceneExperiments = PAPER) -> StraightInsertion:
    """An insertion at ``angle_deg`` (direction of the tip's motion) ending at ``target``."""
    speed = scene.b_speed if speed is None else speed
    target = scene.b_target if target is None else target
    distance = scene.b_distance if distance is None else distance
    return StraightInsertion.from_angle(tool, target, math.radians(angle_deg), distance, speed, dt=dt)


PRESETS = ("experiment_a", "experiment_b_shallow", "experiment_b_steep")


def preset(name: str, tool: ToolShape, dt: float, scene: str = "paper") -> Trajectory:
    """A named trajectory of a scene (used by the tool driver node): one of :data:`PRESETS`."""
    sc = scene_experiments(scene)
    if name == "experiment_a":
        return experiment_a(tool, dt, scene=sc)
    if name == "experiment_b_shallow":
        return experiment_b(tool, dt, sc.b_angles_deg[0], scene=sc)
    if name == "experiment_b_steep":
        return experiment_b(tool, dt, sc.b_angles_deg[1], scene=sc)
    raise InputError(f"trajectory preset {name!r}: expected one of {', '.join(PRESETS)}")
