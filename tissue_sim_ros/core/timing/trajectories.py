"""Tool trajectories as data: the presets (the paper's experiments, the authors' run) and trajectory files.

``--trajectory PRESET|FILE`` (``tissue-sim experiment a|b``, ``tissue-sim replay``,
``tissue-sim demo``) and the tool driver's ``trajectory`` parameter resolve
through :func:`resolve_trajectory`: a name of :data:`PRESETS`, or a file:

* CSV with a header ``time,x,y,yaw`` (time [s], the tool centre's x, y [m], yaw
  [rad]; or ``yaw_deg`` [deg]), one timed pose per row, linearly interpolated
  (:class:`~tissue_sim_ros.core.contact.tool.WaypointTrajectory`);
* YAML, either ``waypoints:`` (a list of ``{time, x, y, yaw}`` mappings or
  ``[time, x, y, yaw]`` rows; ``yaw_deg`` allowed; optional ``hold`` [s]), or a
  straight motion: ``start: {x, y, yaw}`` (or ``yaw_deg``; or ``[x, y, yaw]``),
  ``direction_deg`` (direction of motion, 0 = +x, -90 = straight down; the
  tool's yaw stays the start's), ``speed`` [m per step] (or ``speed_mps``
  [m/s]) and ``steps``.

:func:`write_trajectory_csv` writes any trajectory's per-step poses as such a
CSV (full precision), so a run's trajectory goes back in unchanged.

The paper's experiments on the default scene (config/tissue.png):

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
* ``authors``: the run of the authors' code whose energies they saved (their
  frames show it): their 0.8 m x 5 mm box, horizontal (yaw 0, long side
  first), centred at (0.15, 0.5008) m, moving straight down 1 mm per step for
  276 steps (their "translation perpendicular to the orientation").
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import yaml

from ..contact.tool import StraightInsertion, ToolShape, Trajectory, WaypointTrajectory
from ..errors import InputError, input_file

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
#: ``authors`` (config/scenes/authors.yaml) is the paper's 1 m scene with the authors' code as parameters.
#: The retraction scene (config/scenes/retract.yaml; its own experiment is ``tissue-sim experiment retract``): a and
#: b poke the flap (top at y = 16 mm, x = 10-70 mm) with the grasper's closed tip, as the liver scene's.
RETRACT = SceneExperiments((0.030, 0.024), -60.0, 4e-5, 250, (0, 100, 180, 250),
                           (0.040, 0.014), 0.010, 4e-5, (-45.0, -80.0), None)
SCENE_EXPERIMENTS: dict[str, SceneExperiments] = {"paper": PAPER, "liver_probe": LIVER_PROBE, "authors": PAPER,
                                                  "retract": RETRACT}


#: The retraction (config/scenes/retract.yaml): phases of :func:`retract_trajectory` as
#: (name, duration [s]): the open grasper comes down onto the flap, closes, lifts and pulls back, holds, opens.
RETRACT_PHASES = (("approach", 0.4), ("close", 0.1), ("lift", 1.0), ("pull back", 1.0), ("hold", 0.5), ("open", 0.1),
                  ("after", 0.6))
RETRACT_JAW_OPEN = 0.8
"""The jaw open [rad] (the dVRK's grasper opens to about 1 rad)."""


def retract_trajectory(x: float, surface_y: float, *, above: float = 0.01, gap: float = 0.0002, lift: float = 0.02,
                       pull: float = 0.02, jaw_open: float = RETRACT_JAW_OPEN, jaw_closed: float = 0.0,
                       phases: Sequence[tuple[str, float]] = RETRACT_PHASES) -> WaypointTrajectory:
    """Grasp and retract at ``x`` [m]: the open grasper (yaw 0, jaws down) starts ``above`` [m] over the surface
    at ``surface_y`` [m], comes down to ``gap`` [m] over it, closes, lifts by ``lift`` [m], pulls back by ``pull``
    [m] (toward -x), holds, opens and stays. Waypoints with a jaw angle [rad] (``steps_with_jaw``)."""
    for name, value in (("x", x), ("surface_y", surface_y), ("above", above), ("gap", gap), ("lift", lift),
                        ("pull", pull), ("jaw_open", jaw_open), ("jaw_closed", jaw_closed)):
        if not math.isfinite(value):
            raise InputError(f"retract {name}={value!r}: expected a finite number")
    t = np.concatenate([[0.0], np.cumsum([d for _, d in phases])])
    y0, y1, y2 = surface_y + above, surface_y + gap, surface_y + gap + lift
    xs = [x, x, x, x, x - pull, x - pull, x - pull, x - pull]
    ys = [y0, y1, y1, y2, y2, y2, y2, y2]
    jaws = [jaw_open, jaw_open, jaw_closed, jaw_closed, jaw_closed, jaw_closed, jaw_open, jaw_open]
    return WaypointTrajectory(t, np.stack([xs, ys, np.zeros(8)], axis=1), jaws=np.array(jaws))


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


AUTHORS_START = (0.15, 0.5008)
AUTHORS_YAW = 0.0
AUTHORS_DIRECTION_DEG = -90.0
AUTHORS_SPEED = 0.001
AUTHORS_STEPS = 276


def straight_motion(start: tuple[float, float, float], direction_deg: float, speed: float, steps: int,
                    dt: float) -> WaypointTrajectory:
    """The tool centre from ``start`` (x, y [m], yaw [rad]) along ``direction_deg`` at ``speed`` m per step.

    The yaw stays the start's (the tool may move sideways, as the authors' box
    moving down); after ``steps`` steps of ``dt`` it stops.
    """
    x, y, yaw = (float(v) for v in start)
    for name, v in (("start x", x), ("start y", y), ("start yaw", yaw), ("direction_deg", direction_deg),
                    ("speed", speed)):
        if not math.isfinite(v):
            raise InputError(f"trajectory {name}={v!r}: expected a finite number")
    if not speed > 0:
        raise InputError(f"trajectory speed={speed!r}: expected a distance > 0 m per step")
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
        raise InputError(f"trajectory steps={steps!r}: expected an integer >= 1")
    if not (math.isfinite(dt) and dt > 0):
        raise InputError(f"dt={dt!r}: expected a time step > 0 s")
    a = math.radians(direction_deg)
    # an axis direction is exact (cos(-90 deg) is 6e-17 in floating point, which would move x)
    c, s = (0.0 if abs(v) < 1e-15 else v for v in (math.cos(a), math.sin(a)))
    travel = speed * int(steps)
    end = (x + travel * c, y + travel * s, yaw)
    return WaypointTrajectory(np.array([0.0, int(steps) * dt]), np.array([(x, y, yaw), end]))


def authors_run(tool: ToolShape, dt: float) -> WaypointTrajectory:
    """The authors' saved run (see the module text); ``tool`` is theirs by default (0.8 x 0.005 box)."""
    del tool  # the motion is of the tool's centre, whatever its shape
    return straight_motion((*AUTHORS_START, AUTHORS_YAW), AUTHORS_DIRECTION_DEG, AUTHORS_SPEED, AUTHORS_STEPS, dt)


PRESETS = ("experiment_a", "experiment_b_shallow", "experiment_b_steep", "authors", "retract")


def preset(name: str, tool: ToolShape, dt: float, scene: str = "paper") -> Trajectory:
    """A named trajectory: one of :data:`PRESETS`; the experiments' on the shipped ``scene``
    (:data:`SCENE_EXPERIMENTS`); ``authors`` is the authors' run on the paper's scene."""
    sc = scene_experiments(scene)
    if name == "experiment_a":
        return experiment_a(tool, dt, scene=sc)
    if name == "experiment_b_shallow":
        return experiment_b(tool, dt, sc.b_angles_deg[0], scene=sc)
    if name == "experiment_b_steep":
        return experiment_b(tool, dt, sc.b_angles_deg[1], scene=sc)
    if name == "authors":
        return authors_run(tool, dt)
    if name == "retract":
        # the retraction scene's flap: its top surface at y = 16 mm (config/scenes/retract.png), taken at x = 40 mm
        return retract_trajectory(0.040, 0.016)
    raise InputError(f"trajectory preset {name!r}: expected one of {', '.join(PRESETS)} or a .csv/.yaml file")


TRAJECTORY_SUFFIXES = (".csv", ".yaml", ".yml")


def resolve_trajectory(spec: str, tool: ToolShape, dt: float, scene: str = "paper") -> Trajectory:
    """``spec`` as a preset name (:data:`PRESETS`, on the shipped ``scene``) or a trajectory file (.csv, .yaml, .yml).

    A trajectory shorter than one step of ``dt`` (a CSV of one row) is an InputError: every command that
    runs one (experiment, replay, demo, the tool driver) would otherwise run 0 steps and succeed.
    """
    if not isinstance(spec, str) or not spec:
        raise InputError(f"trajectory {spec!r}: expected a preset ({', '.join(PRESETS)}) or a .csv/.yaml file")
    if spec in PRESETS:
        traj = preset(spec, tool, dt, scene)
    else:
        path = Path(spec)
        if path.suffix.lower() not in TRAJECTORY_SUFFIXES:
            raise InputError(f"trajectory {spec!r}: expected a preset ({', '.join(PRESETS)}) or a .csv/.yaml file")
        traj = load_trajectory(path, dt)
    if traj.n_steps(dt) < 1:
        raise InputError(f"trajectory {spec!r} lasts {traj.duration} s: shorter than one step of dt={dt} s")
    return traj


def load_trajectory(path: str | Path, dt: float) -> Trajectory:
    """A trajectory file (module text): CSV of timed poses, or YAML waypoints or a straight motion."""
    path = input_file(path, "trajectory file")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"trajectory file {str(path)!r} cannot be read as text: {exc}") from None
    if path.suffix.lower() == ".csv":
        return _from_csv(text, str(path))
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise InputError(f"trajectory file {str(path)!r} is not valid YAML: {exc}".splitlines()[0]) from None
    return _from_mapping(data, str(path), dt)


def _number(value: Any, what: str, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(f"trajectory file {name!r}: {what}={value!r}: expected a finite number")
    return float(value)


def _yaw(row: Mapping[str, Any], what: str, name: str) -> float:
    if "yaw_deg" in row:
        return math.radians(_number(row["yaw_deg"], f"{what} yaw_deg", name))
    return _number(row.get("yaw", 0.0), f"{what} yaw", name)


def _from_csv(text: str, name: str) -> WaypointTrajectory:
    rows = [r for r in csv.reader(line for line in text.splitlines() if line.strip() and not line.startswith("#"))]
    if not rows:
        raise InputError(f"trajectory file {name!r} is empty: expected a header time,x,y,yaw and one row per pose")
    head = [h.strip().lower() for h in rows[0]]
    yaw_col = "yaw" if "yaw" in head else "yaw_deg" if "yaw_deg" in head else None
    missing = [c for c in ("time", "x", "y") if c not in head]
    if missing or yaw_col is None:
        raise InputError(f"trajectory file {name!r}: header {','.join(head)!r}: expected columns time,x,y,yaw "
                         "(yaw [rad]; or yaw_deg [deg])")
    cols = [head.index(c) for c in ("time", "x", "y", yaw_col)] + ([head.index("jaw")] if "jaw" in head else [])
    times, poses, jaws = [], [], []
    for k, r in enumerate(rows[1:], start=2):
        try:
            values = [float(r[c]) for c in cols]
        except (ValueError, IndexError):
            raise InputError(f"trajectory file {name!r} line {k}: {','.join(r)!r}: expected {len(cols)} numbers "
                             f"{','.join(head[c] for c in cols)}") from None
        t, x, y, yaw = values[:4]
        times.append(t)
        poses.append((x, y, math.radians(yaw) if yaw_col == "yaw_deg" else yaw))
        jaws += values[4:]
    if not times:
        raise InputError(f"trajectory file {name!r} has a header but no poses: expected one row per pose")
    try:
        return WaypointTrajectory(np.array(times), np.array(poses), jaws=np.array(jaws) if "jaw" in head else None)
    except InputError as exc:
        raise InputError(f"trajectory file {name!r}: {exc}") from None


def _from_mapping(data: Any, name: str, dt: float) -> Trajectory:
    if not isinstance(data, dict):
        raise InputError(f"trajectory file {name!r}: expected a mapping with 'waypoints', or 'start', "
                         "'direction_deg', 'speed' and 'steps'")
    if "waypoints" in data:
        rows = data["waypoints"]
        if not isinstance(rows, list) or not rows:
            raise InputError(f"trajectory file {name!r}: waypoints: expected a list of {{time, x, y, yaw}}")
        times, poses, jaws = [], [], []
        for k, r in enumerate(rows):
            if isinstance(r, (list, tuple)) and len(r) in (3, 4, 5):
                r = dict(zip(("time", "x", "y", "yaw", "jaw"), r))
            if not isinstance(r, dict):
                raise InputError(f"trajectory file {name!r}: waypoints[{k}]={r!r}: expected {{time, x, y, yaw}}")
            if ("jaw" in r) != ("jaw" in (rows[0] if isinstance(rows[0], dict) else
                                          dict(zip(("time", "x", "y", "yaw", "jaw"), rows[0])))):
                raise InputError(f"trajectory file {name!r}: waypoints[{k}]: a jaw in some waypoints only: "
                                 "expected a jaw angle [rad] in every waypoint or in none")
            if "jaw" in r:
                jaws.append(_number(r["jaw"], f"waypoints[{k}].jaw", name))
            times.append(_number(r.get("time"), f"waypoints[{k}].time", name))
            poses.append((_number(r.get("x"), f"waypoints[{k}].x", name),
                          _number(r.get("y"), f"waypoints[{k}].y", name), _yaw(r, f"waypoints[{k}]", name)))
        try:
            return WaypointTrajectory(np.array(times), np.array(poses),
                                      hold=_number(data.get("hold", 0.0), "hold", name),
                                      jaws=np.array(jaws) if jaws else None)
        except InputError as exc:
            raise InputError(f"trajectory file {name!r}: {exc}") from None
    missing = [k for k in ("start", "direction_deg", "steps") if k not in data]
    if "speed" not in data and "speed_mps" not in data:
        missing.append("speed")
    if missing:
        raise InputError(f"trajectory file {name!r}: missing {', '.join(missing)}: expected 'waypoints', or "
                         "'start', 'direction_deg', 'speed' (m per step) and 'steps'")
    start = data["start"]
    if isinstance(start, (list, tuple)) and len(start) in (2, 3):
        start = dict(zip(("x", "y", "yaw"), start))
    if not isinstance(start, dict):
        raise InputError(f"trajectory file {name!r}: start={start!r}: expected {{x, y, yaw}} or [x, y, yaw]")
    pose = (_number(start.get("x"), "start.x", name), _number(start.get("y"), "start.y", name),
            _yaw(start, "start", name))
    if not (math.isfinite(dt) and dt > 0):
        raise InputError(f"dt={dt!r}: expected a time step > 0 s")
    speed = (_number(data["speed"], "speed", name) if "speed" in data
             else _number(data["speed_mps"], "speed_mps", name) * dt)
    steps = data["steps"]
    if isinstance(steps, bool) or not isinstance(steps, int):
        raise InputError(f"trajectory file {name!r}: steps={steps!r}: expected an integer >= 1")
    try:
        return straight_motion(pose, _number(data["direction_deg"], "direction_deg", name), speed, steps, dt)
    except InputError as exc:
        raise InputError(f"trajectory file {name!r}: {exc}") from None


def trajectory_poses(traj: Trajectory, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Times [s] (K + 1,) and poses (K + 1, 3) [m, m, rad]: the start and the end of each of its K steps."""
    start = traj.pose_at(traj.start_time)
    times = [traj.start_time]
    poses = [start.as_array()]
    for k, (pose, _) in enumerate(traj.steps(dt), start=1):
        times.append(min(traj.start_time + k * dt, traj.start_time + traj.duration))
        poses.append(pose.as_array())
    return np.array(times), np.array(poses)


def write_trajectory_csv(path: str | Path, traj: Trajectory, dt: float) -> Path:
    """Write ``traj`` sampled at its steps of ``dt`` as a trajectory CSV (time,x,y,yaw; full precision), with a jaw
    column [rad] when the trajectory drives the jaw."""
    path = Path(path)
    times, poses = trajectory_poses(traj, dt)
    jaws = [traj.jaw_at(float(t)) for t in times]
    with_jaw = any(j is not None for j in jaws)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["time", "x", "y", "yaw"] + (["jaw"] if with_jaw else []))
        for t, (x, y, yaw), jaw in zip(times, poses, jaws):
            w.writerow([repr(float(t)), repr(float(x)), repr(float(y)), repr(float(yaw))]
                       + ([repr(float(jaw))] if with_jaw else []))
    return path
