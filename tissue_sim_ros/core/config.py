"""One front door: every parameter declared once, resolved once.

Every parameter of the simulator (the YAML file, the node, every ``tissue-sim``
command and the library alike) is one row of :data:`PARAMETERS`: its flat name,
type, default, unit, description, whether it can change while a simulation runs,
and its group. The simulation's rows (each a field of SimParams, with its check) are
declared in :mod:`tissue_sim_ros.core.physics.params`, below this module, which the
physics cannot import; this table adds the scene's, the tool's and the node's. :func:`resolve_config` is the one path from values to a
simulation's configuration::

    shipped config/tissue_sim.yaml  <  parameter file(s)  <  overrides (--set, -p, library)
        -> unknown names refused (with the closest known name)
        -> values coerced to their type (an integer is accepted for a float)
        -> method aliases resolved by the one rule below
        -> a material's own solver settings (neo_hookean: quasi_newton, projection contact)
        -> every value checked (SimParams, SceneConfig, ToolShape, the node's checks)
        -> Config (frozen): .sim (SimParams, the Model's record), .scene, .tool, .node

:meth:`Simulation.from_config <tissue_sim_ros.core.sim.simulation.Simulation.from_config>`
builds a scene from a Config; ``tissue-sim config`` prints one as a parameter YAML
that the node and every command load identically.

Method aliases (one rule). ``method`` may be an alias of the orthogonal options:
``pbd_jacobi`` = pbd + jacobi, ``xpbd_jacobi`` = xpbd + jacobi, ``xpbd_substep`` =
xpbd + gauss_seidel + 30 substeps of 1 iteration (``pbd`` and ``xpbd`` set
gauss_seidel). The alias sets each of ``scheme``, ``substeps`` and ``iterations``
whose merged value still equals its shipped default (config/tissue_sim.yaml); a
value that differs from it was chosen by the user and wins. So ``method:
xpbd_substep`` gives 30 substeps of 1 iteration; with ``substeps: 10``, 10 of 1.
To ask for 30 iterations per substep, use ``method: xpbd`` with ``substeps`` and
``iterations``. The resolved configuration holds only ``pbd`` or ``xpbd``.
Code that means a method exactly, whatever the files say (a benchmark's
setting: ``xpbd_substep`` at 5 substeps), takes its options from
:func:`method_options`, the same table, and passes them as overrides.
"""
from __future__ import annotations

import difflib
import json
import math
import re
from dataclasses import dataclass, field, fields, make_dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
import yaml

from .contact.tool import TOOL_SHAPES, ToolShape
from .errors import InputError, input_file
from .mesh import OUTLINE_CORNERS
from .mesh.scene_config import SceneConfig, mesh_file_value  # noqa: F401  (the scene group's record)
from .physics.model import MATERIAL_DEFAULTS, MATERIAL_METHOD_DEFAULTS, SimParams
from .physics.params import METHOD_ALIASES, METHODS, SIM_PARAMETERS, Check, ParamSpec

#: The section of a ROS 2 parameter file that holds the node's parameters.
NODE_NAME = "tissue_sim_node"

#: Groups of the configuration, by concern.
GROUPS = ("scene", "physics", "solver", "contact", "tool", "node")


def _positive(v: Any) -> str | None:
    return None if v > 0 else "a value > 0"


def _non_negative(v: Any) -> str | None:
    return None if v >= 0 else "a value >= 0"


def _finite(v: Any) -> str | None:
    return None if math.isfinite(v) else "a finite number"


def _finite_or_nan(v: Any) -> str | None:
    return None if not math.isinf(v) else "a finite number, or NaN for none"


def _at_least_one(v: Any) -> str | None:
    return None if v >= 1 else "an integer >= 1"


def _nice(v: Any) -> str | None:
    return None if 0 <= v <= 19 else "a niceness increment from 0 to 19"


def _rt_priority(v: Any) -> str | None:
    return None if 0 <= v <= 99 else "0 (normal scheduling) or a SCHED_FIFO priority from 1 to 99"


def _one_of(options: tuple[str, ...]) -> Check:
    return lambda v: None if v in options else f"one of {', '.join(options)}"


_FRAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_/]*$")


def _frame(v: Any) -> str | None:
    return None if _FRAME_RE.match(v) and not v.startswith("/") else "a frame name like 'world' (letters, digits, _, /; no leading /)"


def _frame_or_empty(v: Any) -> str | None:
    return None if v == "" else _frame(v)


def _static_transforms(v: Any) -> str | None:
    from .timing.frames import parse_static_transforms  # noqa: PLC0415  (frames imports errors only)

    try:
        parse_static_transforms(v)
    except InputError as exc:
        return f"entries 'x y z yaw pitch roll parent child' separated by ';' ({exc})"
    return None


_SCENE = SceneConfig()
_TOOL = ToolShape()
# the simulation's rows (core/physics/params.py), the tool's shape before the grasper's rows as the table has
# always had them: the order of Config.flat(), of a bag's recorded parameters and of the checks of a set
_GRASP = next(k for k, p in enumerate(SIM_PARAMETERS) if p.name.startswith("grasp_"))
_SIM_BEFORE_TOOL, _SIM_AFTER_TOOL = SIM_PARAMETERS[:_GRASP], SIM_PARAMETERS[_GRASP:]

PARAMETERS: tuple[ParamSpec, ...] = (
    # scene: where the mesh comes from (read-only: a new mesh is a new scene)
    ParamSpec("image", str, _SCENE.image, "path", "Tissue image (PNG/JPEG/BMP) meshed at start; empty = the shipped config/tissue.png.", True, "scene"),
    ParamSpec("mesh_file", str, _SCENE.mesh_file, "path", "Mesh file (.npz from `tissue-sim mesh`, Triangle .node/.ele, Gmsh .msh), or a list of them made one scene (each body named after its file); overrides image when set.", True, "scene"),
    ParamSpec("spacing", float, _SCENE.spacing, "m", "Target edge length when meshing the image.", True, "scene"),
    ParamSpec("scale", float, _SCENE.scale, "m/px", "Image scale: metres per pixel.", True, "scene"),
    ParamSpec("origin_x", float, _SCENE.origin_x, "m", "World x of the image's left edge.", True, "scene"),
    ParamSpec("origin_y", float, _SCENE.origin_y, "m", "World y of the image's bottom edge.", True, "scene"),
    ParamSpec("threshold", float, _SCENE.threshold, "grey level", "Grey threshold separating tissue from background; < 0 = automatic (Otsu).", True, "scene"),
    ParamSpec("max_particles", int, _SCENE.max_particles, "", "Largest mesh an image may be meshed into: a spacing whose estimated vertex count (2 A / (sqrt(3) spacing^2) over the tissue area A) exceeds it is refused before meshing.", True, "scene"),
    ParamSpec("grade_spacing", float, _SCENE.grade_spacing, "m", "Graded mesh: target edge length within grade_radius of (grade_x, grade_y), growing by 0.3 m per m outside it up to spacing (mesh finer where the tool works); 0 = uniform at spacing.", True, "scene"),
    ParamSpec("grade_x", float, _SCENE.grade_x, "m", "Graded mesh: world x of the fine region's centre.", True, "scene"),
    ParamSpec("grade_y", float, _SCENE.grade_y, "m", "Graded mesh: world y of the fine region's centre.", True, "scene"),
    ParamSpec("grade_radius", float, _SCENE.grade_radius, "m", "Graded mesh: radius of the disc meshed at grade_spacing.", True, "scene"),
    ParamSpec("outline_corners", str, _SCENE.outline_corners, "", f"Meshing an image: {' or '.join(OUTLINE_CORNERS)}; smooth = the outline smoothed and resampled by arc length (the paper's meshes), sharp = corners where two straight runs of the outline meet at 60 degrees or more stay vertices on the pixel corners, so a straight face ends at the same place at every spacing (a slab on a support).", True, "scene"),
    *_SIM_BEFORE_TOOL,
    # tool shape (read-only: the contact model is built around it)
    ParamSpec("tool_shape", str, _TOOL.kind, "", f"Tool shape: {', '.join(TOOL_SHAPES)}.", True, "tool"),
    ParamSpec("tool_length", float, _TOOL.length, "m", "Tool length along its axis (box, capsule).", True, "tool"),
    ParamSpec("tool_width", float, _TOOL.width, "m", "Full width of a box tool.", True, "tool"),
    ParamSpec("tool_radius", float, _TOOL.radius, "m", "Radius of a capsule or sphere tool.", True, "tool"),
    ParamSpec("jaw_length", float, _TOOL.jaw_length, "m", "Grasper: length of each jaw (tool_length is the whole grasper, jaw tips to shaft end).", True, "tool"),
    ParamSpec("shaft_width", float, _TOOL.shaft_width, "m", "Grasper: full width of the shaft; contact sees the grasper as a capsule of this diameter from the jaw tips up.", True, "tool"),
    *_SIM_AFTER_TOOL,
    # the node's own
    ParamSpec("frame_id", str, "world", "", "The simulation plane's frame (tissue in its z = 0 plane): every message out is in it. A tool input in another frame is taken through the known transforms (world_frame and plane_*, static_transforms, /tf, /tf_static) and projected onto the plane; with no transform it is dropped.", False, "node", _frame),
    ParamSpec("world_frame", str, "", "", "Frame in which plane_x .. plane_yaw place the plane (frame_id); the node broadcasts world_frame -> frame_id on /tf_static where tf2_msgs is installed. Empty = the plane is not placed.", True, "node", _frame_or_empty),
    ParamSpec("plane_x", float, 0.0, "m", "Plane origin in world_frame: x.", True, "node", _finite),
    ParamSpec("plane_y", float, 0.0, "m", "Plane origin in world_frame: y.", True, "node", _finite),
    ParamSpec("plane_z", float, 0.0, "m", "Plane origin in world_frame: z.", True, "node", _finite),
    ParamSpec("plane_roll", float, 0.0, "rad", "Plane orientation in world_frame: roll about x (R = Rz(yaw) Ry(pitch) Rx(roll), as tf2).", True, "node", _finite),
    ParamSpec("plane_pitch", float, 0.0, "rad", "Plane orientation in world_frame: pitch about y.", True, "node", _finite),
    ParamSpec("plane_yaw", float, 0.0, "rad", "Plane orientation in world_frame: yaw about z.", True, "node", _finite),
    ParamSpec("static_transforms", str, "", "", "Static transforms as static_transform_publisher takes them: 'x y z yaw pitch roll parent child' [m, rad], several separated by ';'. Empty = none.", True, "node", _static_transforms),
    ParamSpec("tool_frame", str, "", "", "TF frame of the tool: every /tf transform with this child_frame_id is a tool pose (in its parent frame, taken to the plane like tool/pose). Needs tf2_msgs. Empty = off.", True, "node", _frame_or_empty),
    ParamSpec("tf_tolerance", float, 0.05, "s", "A tool input stamped up to this long after the newest transform of its chain uses that transform; later ones are dropped (no extrapolation).", False, "node", _non_negative),
    ParamSpec("lock_step", bool, False, "", "true: one step per received tool pose (exact replay), no timer; false: a timer at 1/dt.", True, "node"),
    ParamSpec("phase_lock", bool, True, "", "Timer mode: move the step timer's ticks to just after the tool poses' arrivals (from the median of recent arrivals, a margin for their jitter, at most 2 ms per shift), so a pose waits for its step a fraction of a period, not up to a whole one; a stream at another rate or too irregular is left alone. Off with use_sim_time.", False, "node"),
    ParamSpec("paused", bool, False, "", "true: no steps (also set by the ~/pause service).", False, "node"),
    ParamSpec("follow_clock", bool, True, "", "Timer mode without use_sim_time: while a /clock publisher exists (tissue-sim play publishes the bag's time), use it (use_sim_time on); back to the system clock 1 s after it goes.", True, "node"),
    ParamSpec("marker_rate", float, 30.0, "Hz", "Rate of tissue/markers, a display rate (RViz redraws at ~30 Hz); capped at 1/dt (every round(1/(dt*rate)) steps). Encoded and published off the step thread, newest state only.", False, "node", _positive),
    ParamSpec("marker_nice", int, 10, "", "Niceness added to the marker thread alone (Linux schedules threads; 0 = as the step thread, up to 19). With the cores shared, the scheduler then runs the step thread first and the markers, a display, take what is left; raising it needs no privileges.", True, "node", _nice),
    ParamSpec("step_rt_priority", int, 0, "", "SCHED_FIFO priority of the node's step thread (the executor that steps, takes the poses and serves ~/reset, ~/pause, ...) on Linux; 0 = normal scheduling. A real-time thread runs before every normal one, so a busy machine does not delay the step (the marker, planner and DDS threads stay normal; threads and processes it starts do not inherit it). Needs CAP_SYS_NICE or an rtprio limit (/etc/security/limits.conf, as for ros2_control); refused, the node logs one line and runs as before. /diagnostics: step_thread_scheduling.", True, "node", _rt_priority),
    ParamSpec("points_rate", float, 100.0, "Hz", "Rate of tissue/points; capped at 1/dt (default: every step).", False, "node", _positive),
    ParamSpec("diagnostics_rate", float, 1.0, "Hz", "Rate of /diagnostics.", False, "node", _positive),
    ParamSpec("markers_wireframe", bool, True, "", "Include the wireframe LINE_LIST in tissue/markers.", False, "node"),
    ParamSpec("strain_color_max", float, 0.2, "", "Strain shown at full colour in the mesh marker (blue -max, red +max).", False, "node", _positive),
    ParamSpec("wire_width", float, 0.002, "m", "Line width of the wireframe markers.", False, "node", _positive),
    ParamSpec("tool_start_x", float, math.nan, "m", "The tool's start pose in the plane: x (NaN, the default, with tool_start_y: no tool before the first tool/pose). With a start pose the tool is there from the first step (and after ~/reset), tool/applied_pose is published from the start, and the first tool pose is taken where it lies, however far (unless the tool there would overlap the tissue).", True, "node", _finite_or_nan),
    ParamSpec("tool_start_y", float, math.nan, "m", "The tool's start pose in the plane: y (NaN with tool_start_x: none).", True, "node", _finite_or_nan),
    ParamSpec("tool_start_yaw", float, 0.0, "rad", "The tool's start pose in the plane: the yaw about z.", True, "node", _finite),
    ParamSpec("max_tool_jump", float, 0.05, "m", "A tool pose farther than this from the last one accepted is rejected (dropped and counted): the tool holds its pose until a pose within this distance arrives, or ~/reset (after which any pose is accepted).", False, "node", _positive),
    ParamSpec("relocate_poses", int, 5, "", "A relocated robot: when the tool grasps nothing and this many rejected poses in a row are each within max_tool_jump of the one before, the tool is taken there (through the contact checks: swept in steps no longer than max_tool_jump, stopped before it would pass through the tissue), with a warning and a count on /diagnostics; 0 = never (only ~/reset).", False, "node", _non_negative),
    ParamSpec("max_stamp_age", float, 0.5, "s", "Timer mode: tool messages stamped older than this are dropped as stale; 0 = no check.", False, "node", _non_negative),
    ParamSpec("max_stamp_future", float, 0.5, "s", "Timer mode: tool messages stamped further than this ahead of the node's clock are dropped (one would make every later message out of order until the clock caught up); 0 = no check.", False, "node", _non_negative),
    ParamSpec("twist_timeout", float, 0.05, "s", "A tool twist received longer ago than this is stale: velocity is derived from poses.", False, "node", _positive),
    ParamSpec("twist_source", str, "auto", "", "auto: tool/twist when fresh, else from poses; poses: always derived from poses.", False, "node", _one_of(("auto", "poses"))),
    ParamSpec("warn_period", float, 2.0, "s", "Each kind of warning about bad input is logged at most once per period.", False, "node", _positive),
    ParamSpec("record_path", str, "", "path", "Record every message in and out (the very bytes published) to this new rosbag2 bag directory; empty = no recording.", True, "node"),
    ParamSpec("record_storage", str, "mcap", "", "Storage of the recorded bag: mcap (default, as ros2 bag in Jazzy) or sqlite3.", True, "node", _one_of(("mcap", "sqlite3"))),
    # the node's planner service ~/plan_insertion (ros/planner_service.py, msg_docs/services.md)
    ParamSpec("plan_angle_min", float, -20.0, "deg", "Planner: smallest approach angle, as an offset from the start->goal direction.", False, "node", _finite),
    ParamSpec("plan_angle_max", float, 20.0, "deg", "Planner: largest approach angle offset (>= plan_angle_min).", False, "node", _finite),
    ParamSpec("plan_angle_step", float, 10.0, "deg", "Planner: spacing of the approach angles from plan_angle_min.", False, "node", _positive),
    ParamSpec("plan_speed_min", float, 0.1, "m/s", "Planner: slowest tip speed.", False, "node", _positive),
    ParamSpec("plan_speed_max", float, 0.2, "m/s", "Planner: fastest tip speed (>= plan_speed_min).", False, "node", _positive),
    ParamSpec("plan_speed_count", int, 2, "", "Planner: tip speeds, evenly spaced from plan_speed_min to plan_speed_max.", False, "node", _at_least_one),
    ParamSpec("plan_tolerance", float, 0.01, "m", "Planner: tolerance used when a request's tolerance is 0.", False, "node", _positive),
    ParamSpec("plan_track_target", bool, False, "", "Planner: the tolerance applies to the tissue's target point, which the insertion pushes (true), or the tip reaching the commanded goal suffices (false).", False, "node"),
    ParamSpec("plan_max_steps", int, 500, "", "Planner: candidates longer than this many steps are not rolled out.", False, "node", _at_least_one),
    ParamSpec("plan_workers", int, 2, "", "Planner: worker processes for the rollouts (started at the first request); 0 = in the node's planner thread (slows the step thread).", True, "node", _non_negative),
    ParamSpec("plan_nice", int, 10, "", "Planner: niceness added to the worker processes, so the step thread is scheduled first.", True, "node", _nice),
)


BY_NAME: dict[str, ParamSpec] = {p.name: p for p in PARAMETERS}

#: Where each parameter goes: "sim" (SimParams), "scene" (SceneConfig), "tool" (ToolShape) or "node".
_SIM_FIELDS = {f.name for f in fields(SimParams)}
_SCENE_FIELDS = {f.name for f in fields(SceneConfig)}
TOOL_FIELDS = {"tool_shape": "kind", "tool_length": "length", "tool_width": "width", "tool_radius": "radius",
               "jaw_length": "jaw_length", "shaft_width": "shaft_width"}


def _home(spec: ParamSpec) -> str:
    if spec.name in _SIM_FIELDS:
        return "sim"
    if spec.name in _SCENE_FIELDS:
        return "scene"
    if spec.name in TOOL_FIELDS:
        return "tool"
    if spec.group == "node":
        return "node"
    raise RuntimeError(f"parameter {spec.name!r} has no home: add it to SimParams (a row of "
                       "core/physics/params.py), SceneConfig or the node group")


HOME: dict[str, str] = {p.name: _home(p) for p in PARAMETERS}

#: Names the simulation reads (everything but the node's own).
SIM_NAMES: tuple[str, ...] = tuple(p.name for p in PARAMETERS if HOME[p.name] != "node")

NodeConfig = make_dataclass(
    "NodeConfig", [(p.name, p.kind, field(default=p.default)) for p in PARAMETERS if HOME[p.name] == "node"],
    frozen=True)
NodeConfig.__module__, NodeConfig.__qualname__ = __name__, "NodeConfig"  # picklable (worker processes)
NodeConfig.__doc__ = "The node's own options (the ``node`` group of :data:`PARAMETERS`); the offline commands ignore them."

#: Prefixes of names a ROS parameter file may hold that rclpy handles (not ours, not unknown).
FOREIGN_PREFIXES = ("qos_overrides.", "use_sim_time", "start_type_description_service")


# --------------------------------------------------------------------------- files and assignments


def load_params_file(path: str | Path, node_name: str = NODE_NAME) -> dict[str, Any]:
    """Flat parameters from a ROS 2 parameter YAML (``node: ros__parameters: ...``) or a flat YAML.

    Accepts the node's own section, a ``/**`` wildcard section, or a flat mapping.
    A file that cannot be read or parsed is an InputError of one line.
    """
    path = input_file(path, "parameter file")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or type(exc).__name__
        raise InputError(f"parameter file {str(path)!r} is not valid YAML{where}: {problem}") from None
    except UnicodeDecodeError:
        raise InputError(f"parameter file {str(path)!r} is not text (a binary file?): expected a parameter "
                         "YAML such as config/tissue_sim.yaml") from None
    except OSError as exc:
        raise InputError(f"parameter file {str(path)!r} cannot be read: {exc}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise InputError(f"parameter file {str(path)!r}: expected a mapping at the top level")
    out: dict[str, Any] = {}
    found_section = False
    for key in ("/**", node_name, "/" + node_name):
        section = data.get(key)
        if isinstance(section, dict) and isinstance(section.get("ros__parameters"), dict):
            out.update(section["ros__parameters"])
            found_section = True
    if not found_section:
        out.update(data)
    return out


def strict_json(value: Any) -> Any:
    """``value`` with every non-finite float (NaN, inf) replaced by None, so ``json.dumps`` writes strict JSON
    (``null``) instead of the ``NaN`` literals that strict parsers refuse."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: strict_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [strict_json(v) for v in value]
    if isinstance(value, np.generic):
        return strict_json(value.item())
    return value


def params_json(cfg: "Config") -> str:
    """Every resolved parameter as strict JSON (what a bag's ``tissue_sim.params`` holds): a non-finite number
    (an unset bound such as ``pin_y_top``) is written as null, which every JSON parser reads."""
    return params_json_flat(cfg.flat())


def params_json_flat(flat: Mapping[str, Any]) -> str:
    """:func:`params_json` of flat resolved parameters (``Config.flat()``)."""
    return json.dumps(strict_json(dict(flat)), default=str, allow_nan=False)


def params_from_json(text: str) -> dict[str, Any]:
    """The parameters of :func:`params_json` (also of bags written before it, with bare NaN): null as NaN for
    a number parameter. Not JSON, or not an object: InputError."""
    try:
        values = json.loads(text)
    except ValueError as exc:
        raise InputError(f"the recorded parameters are not JSON ({exc})") from None
    if not isinstance(values, dict):
        raise InputError(f"the recorded parameters are a JSON {type(values).__name__}: expected an object")
    return {k: (math.nan if v is None and k in BY_NAME and BY_NAME[k].kind is float else v) for k, v in values.items()}


def default_params() -> dict[str, Any]:
    """The shipped ``config/tissue_sim.yaml`` as flat parameters."""
    from .resources import DEFAULT_PARAMS_FILE, config_path  # noqa: PLC0415

    return load_params_file(config_path(DEFAULT_PARAMS_FILE))


def parse_assignments(items: Iterable[str]) -> dict[str, Any]:
    """``NAME=VALUE`` strings (``--set``) -> dict, values parsed as YAML scalars (numbers, booleans, strings)."""
    out: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise InputError(f"--set {item!r}: expected NAME=VALUE")
        name, value = item.split("=", 1)
        try:
            out[name.strip()] = yaml.safe_load(value) if value.strip() else ""
        except yaml.YAMLError:
            raise InputError(f"--set {item!r}: {value!r} is not a number, boolean or string") from None
    return out


# --------------------------------------------------------------------------- resolution


def closest_name(name: str) -> str | None:
    """The known parameter name closest to ``name`` (a typo's likely intent), or None."""
    match = difflib.get_close_matches(name, BY_NAME, n=1, cutoff=0.6)
    return match[0] if match else None


def _check_known(values: Mapping[str, Any], source: str) -> None:
    for name in values:
        if name in BY_NAME or str(name).startswith(FOREIGN_PREFIXES):
            continue
        near = closest_name(str(name))
        hint = f"; did you mean {near!r}?" if near else "; the names are listed in msg_docs/parameters.md"
        raise InputError(f"unknown parameter {name!r} in {source}{hint}")


def _type_name(kind: type) -> str:
    return {float: "a number", int: "an integer", bool: "a boolean", str: "a string"}[kind]


def coerce(spec: ParamSpec, value: Any) -> Any:
    """The value as the parameter's type (an int for a float is accepted) and, for the node's own parameters, its
    range check; or InputError. The other values' records check their ranges (:meth:`SimParams.validate` every
    type before any range, so it names the same parameter whichever path the values took)."""
    kind = spec.kind
    if spec.name == "mesh_file" and isinstance(value, (list, tuple)):
        return mesh_file_value(value)  # several mesh files: one scene
    ok = (isinstance(value, bool) if kind is bool else
          isinstance(value, int) and not isinstance(value, bool) if kind is int else
          isinstance(value, (int, float)) and not isinstance(value, bool) if kind is float else
          isinstance(value, str))
    if not ok:
        raise InputError(f"parameter {spec.name}={value!r}: expected {_type_name(kind)}")
    value = float(value) if kind is float else value
    if spec.check is not None and HOME[spec.name] == "node":
        if kind is float and not math.isfinite(value) and not (math.isnan(value) and spec.check is _finite_or_nan):
            raise InputError(f"parameter {spec.name}={value!r}: expected a finite number")
        expected = spec.check(value)
        if expected is not None:
            raise InputError(f"parameter {spec.name}={value!r}: expected {expected}")
    return value


def _reference_default(name: str, shipped: Mapping[str, Any]) -> Any:
    return shipped.get(name, BY_NAME[name].default)


def resolve_method_alias(values: dict[str, Any], shipped: Mapping[str, Any]) -> None:
    """Apply the one alias rule (module docstring) to a merged flat mapping, in place."""
    method = values.get("method")
    alias = METHOD_ALIASES.get(method) if isinstance(method, str) else None
    if alias is None:
        if isinstance(method, str) and method not in METHODS:
            raise InputError(f"parameter method={method!r}: expected one of {', '.join(METHOD_ALIASES)}")
        return
    for key, value in alias.items():
        if key == "method" or values.get(key) == _reference_default(key, shipped):
            values[key] = value


def method_options(method: str, count: int | None = None) -> dict[str, Any]:
    """The orthogonal options a method name stands for, by the one alias rule's table (:data:`METHOD_ALIASES`).

    For callers that mean a method exactly, whatever a parameter file or the shipped file holds (a
    benchmark's setting): pass the result as explicit overrides to :func:`resolve_config` or
    :meth:`Config.replace`. ``method`` is always resolved to ``pbd`` or ``xpbd``, so the alias rule (which sets
    only what still holds its shipped value) has nothing left to decide.

    Parameters
    ----------
    method : str
        ``pbd``, ``pbd_jacobi``, ``xpbd``, ``xpbd_jacobi`` or ``xpbd_substep``.
    count : int, optional
        How often the method's unit repeats in a step: iterations of one substep, or for an alias made of
        substeps (``xpbd_substep``: substeps of 1 iteration) the substeps. None: the alias's own values
        (``xpbd_substep``: 30 substeps of 1 iteration; the others set no count).

    Examples
    --------
    >>> method_options("xpbd_substep", 5)
    {'method': 'xpbd', 'scheme': 'gauss_seidel', 'substeps': 5, 'iterations': 1}
    >>> method_options("pbd_jacobi", 10)
    {'method': 'pbd', 'scheme': 'jacobi', 'iterations': 10, 'substeps': 1}
    """
    if method not in METHOD_ALIASES:
        raise InputError(f"method {method!r}: expected one of {', '.join(METHOD_ALIASES)}")
    values = dict(METHOD_ALIASES[method])
    if count is not None:
        if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 1:
            raise InputError(f"method {method} count={count!r}: expected an integer >= 1")
        if "substeps" in values:
            values["substeps"] = int(count)
        else:
            values.update(iterations=int(count), substeps=1)
    return values


#: Solver keys that only the sweeping methods read: given without a method, the material is swept (xpbd).
SWEEP_KEYS = frozenset({"substeps", "scheme", "relaxation"})


def resolve_material_defaults(values: dict[str, Any], shipped: Mapping[str, Any], chosen: Iterable[str]) -> None:
    """A material's own solver settings (:data:`~tissue_sim_ros.core.physics.model.MATERIAL_DEFAULTS`), in place.

    The shipped file is the paper's scene (``method: pbd``, one step of 30 iterations, the paper's
    contact); ``material: neo_hookean`` sets ``method: ipc`` and its barrier contact, then the method's own
    substeps and iterations (ipc and quasi_newton: 1 step, at most 50 iterations; xpbd: 10 substeps of 10;
    substeps, scheme or relaxation given without a method choose xpbd, the method they belong to; a
    projection or paper contact given without a method chooses quasi_newton, the whole-step solve that
    has it), each for what was not ``chosen`` (given by a file, the overrides or a command's defaults)
    and still holds its shipped value (so an alias's own substeps stay).
    """
    material = values.get("material")
    chosen = set(chosen)
    if not isinstance(material, str):
        return
    for key, value in MATERIAL_DEFAULTS.get(material, {}).items():
        if key not in chosen and _same(values.get(key), _reference_default(key, shipped)):
            if key == "method" and chosen & SWEEP_KEYS and material == "neo_hookean":
                value = "xpbd"  # substeps or a sweep order asked for: the sweeps they belong to
            elif (key == "method" and material == "neo_hookean" and "contact_model" in chosen
                  and values.get("contact_model") in ("projection", "paper")):
                value = "quasi_newton"  # a constraint contact asked for: the whole-step solve that has it
            values[key] = value
    method = values.get("method")
    for key, value in MATERIAL_METHOD_DEFAULTS.get(material, {}).get(method, {}).items() \
            if isinstance(method, str) else ():
        if key not in chosen and _same(values.get(key), _reference_default(key, shipped)):
            values[key] = value


@dataclass(frozen=True)
class Config:
    """A resolved, validated configuration, grouped by concern.

    Build with :func:`resolve_config`; change with :meth:`replace` (re-resolved
    and re-validated). ``flat()`` is the external interface (the flat names).
    """

    sim: SimParams
    """Physics, solver and contact: the Model's parameter record."""
    scene: SceneConfig
    """Where the mesh comes from."""
    tool: ToolShape
    """The tool's shape."""
    node: Any
    """The node's own options (:data:`NodeConfig`)."""

    def flat(self) -> dict[str, Any]:
        """Every parameter by its flat name, in table order."""
        out: dict[str, Any] = {}
        for spec in PARAMETERS:
            home = HOME[spec.name]
            if home == "tool":
                out[spec.name] = getattr(self.tool, TOOL_FIELDS[spec.name])
            else:
                out[spec.name] = getattr(getattr(self, home), spec.name)
        return out

    def group(self, name: str) -> Mapping[str, Any]:
        """The values of one group (``scene``, ``physics``, ``solver``, ``contact``, ``tool``, ``node``), read-only."""
        if name not in GROUPS:
            raise InputError(f"configuration group {name!r}: expected one of {', '.join(GROUPS)}")
        flat = self.flat()
        return MappingProxyType({p.name: flat[p.name] for p in PARAMETERS if p.group == name})

    @property
    def physics(self) -> Mapping[str, Any]:
        return self.group("physics")

    @property
    def solver(self) -> Mapping[str, Any]:
        return self.group("solver")

    @property
    def contact(self) -> Mapping[str, Any]:
        return self.group("contact")

    def replace(self, **changes: Any) -> "Config":
        """A new Config with some flat values changed (unknown names, aliases and values as in resolve_config)."""
        return resolve_config(overrides=changes, base=self.flat())

    def changed(self, other: "Config") -> list[str]:
        """Names whose values differ between this and ``other`` (NaN equals NaN)."""
        a, b = self.flat(), other.flat()
        return [n for n in a if not _same(a[n], b[n])]

    def to_yaml(self, node_name: str = NODE_NAME, names: Iterable[str] | None = None) -> str:
        """The configuration as a ROS 2 parameter file that the node and every command load identically.

        Parameters
        ----------
        node_name : str
            The file's section: the node's name, or ``"/**"`` for every node.
        names : iterable of str, optional
            Write only these parameters (their resolved values): a partial file, as a scene's own file is,
            over which the shipped ``config/tissue_sim.yaml`` fills the rest when it is loaded (and a
            material's solver settings apply to what it leaves out). Default: every parameter.
        """
        flat = self.flat()
        only = None if names is None else set(names)
        if only is not None and only - set(flat):
            raise InputError(f"to_yaml: unknown parameter(s) {', '.join(sorted(only - set(flat)))}")
        what = "every parameter" if only is None else f"{len(only)} parameters (the others: the shipped file)"
        lines = [f"# resolved by tissue-sim config: {what} of {node_name} (msg_docs/parameters.md)",
                 f"{node_name}:", "  ros__parameters:"]
        for group in GROUPS:
            specs = [p for p in PARAMETERS if p.group == group and (only is None or p.name in only)]
            if not specs:
                continue
            lines.append(f"    # {group}")
            for spec in specs:
                value = _yaml_scalar(flat[spec.name])
                unit = f"  # [{spec.unit}]" if spec.unit and spec.unit not in ("path",) else ""
                lines.append(f"    {spec.name}: {value}{unit}")
        return "\n".join(lines) + "\n"


def _yaml_scalar(value: Any) -> str:
    """One value as YAML that reads back to the same value and type (floats keep their dot, NaN is .nan)."""
    value = list(value) if isinstance(value, tuple) else value
    return yaml.safe_dump([value], default_flow_style=True, width=1 << 16).strip()[1:-1]


def _same(a: Any, b: Any) -> bool:
    return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))


def resolve_config(overrides: Mapping[str, Any] | None = None,
                   params_file: str | Path | Sequence[str | Path] | None = None, *,
                   defaults: Mapping[str, Any] | None = None, source: str = "the overrides",
                   base: Mapping[str, Any] | None = None) -> Config:
    """Merge, resolve and validate: the one path from parameter values to a :class:`Config`.

    Parameters
    ----------
    overrides : mapping, optional
        Flat values that win over everything else (``--set``, the node's ``-p``, a library call).
    params_file : path or list of paths, optional
        ROS 2 parameter YAML file(s), applied in order over the shipped ``config/tissue_sim.yaml``.
    defaults : mapping, optional
        A command's own defaults, over the shipped file and under the parameter file
        (experiment b's shorter tool).
    source : str
        How to name the overrides in an error message (e.g. ``"--set"``, ``"the node's parameters"``).
    base : mapping, optional
        Start from these flat values instead of the shipped file (used by :meth:`Config.replace`).

    Raises
    ------
    InputError
        An unknown name (with the closest known one), a value of the wrong type, or a value out of range.
    """
    shipped = default_params()
    _check_known(shipped, "the shipped config/tissue_sim.yaml")
    values: dict[str, Any] = {p.name: p.default for p in PARAMETERS}
    values.update(shipped if base is None else base)
    chosen: set[str] = set()
    if defaults:
        _check_known(defaults, "the command's defaults")
        values.update(defaults)
        chosen.update(defaults)
    files = [] if params_file is None else [params_file] if isinstance(params_file, (str, Path)) else list(params_file)
    for path in files:
        data = load_params_file(path)
        _check_known(data, f"parameter file {str(path)!r}")
        values.update(data)
        chosen.update(data)
    if overrides:
        _check_known(overrides, source)
        values.update(overrides)
        chosen.update(overrides)
    values = {k: v for k, v in values.items() if k in BY_NAME}
    resolve_method_alias(values, shipped)
    if base is None or values.get("material") != base.get("material"):
        # the material was chosen here (not carried over by Config.replace): its solver settings apply
        resolve_material_defaults(values, shipped, chosen)
    values = {name: coerce(BY_NAME[name], value) for name, value in values.items()}
    return _build(values)


#: Pairs (low, high) whose high must not be below its low (the planner's sweep).
ORDERED_PAIRS = (("plan_angle_min", "plan_angle_max"), ("plan_speed_min", "plan_speed_max"))


def _build(values: Mapping[str, Any]) -> Config:
    for lo, hi in ORDERED_PAIRS:
        if lo in values and hi in values and values[hi] < values[lo]:
            raise InputError(f"parameter {hi}={values[hi]!r}: expected >= {lo}={values[lo]!r} (to move the range past "
                             "its other end, set both at once: a parameter file, or ~/set_parameters_atomically)")
    start = [values.get(name, math.nan) for name in ("tool_start_x", "tool_start_y")]
    if math.isnan(start[0]) != math.isnan(start[1]):
        raise InputError(f"parameters tool_start_x={start[0]!r}, tool_start_y={start[1]!r}: expected both (a start "
                         "pose) or neither (NaN: no tool before the first tool/pose)")
    by_home: dict[str, dict[str, Any]] = {"sim": {}, "scene": {}, "tool": {}, "node": {}}
    for name, value in values.items():
        home = HOME[name]
        by_home[home][TOOL_FIELDS.get(name, name)] = value
    return Config(sim=SimParams(**by_home["sim"]), scene=SceneConfig(**by_home["scene"]),
                  tool=ToolShape(**by_home["tool"]), node=NodeConfig(**by_home["node"]))


#: Values that pass the parameter checks but no tissue step can mean: name -> (low, high, what it is). A value
#: outside gets a warning naming it (not a refusal: a study may want an extreme on purpose). The material's rows
#: apply only to ``material: neo_hookean``, which reads them.
PLAUSIBLE_RANGES: dict[str, tuple[float, float, str]] = {
    "dt": (1e-5, 0.1, "a soft-tissue step (Table I: 0.01 s)"),
    "gravity": (-100.0, 100.0, "gravity along y (Earth: -9.8 m/s^2)"),
    "young_modulus": (1.0, 1e9, "a tissue's Young's modulus (soft tissue: about 0.1-100 kPa)"),
    "density": (100.0, 1e4, "a tissue's density (about 1000 kg/m^3)"),
    "thickness": (1e-5, 0.5, "a tissue membrane's thickness"),
}
_MATERIAL_ONLY = ("young_modulus", "density", "thickness")


def implausible_values(cfg: Config) -> list[str]:
    """One line per value of ``cfg`` far outside what it can mean for tissue (:data:`PLAUSIBLE_RANGES`); empty
    when none is. For a command to print as warnings. (A spacing below the image's pixel is ``tissue-sim
    mesh``'s warning, said once the mesh's size is accepted: a scene refused for its size gets one line.)"""
    flat = cfg.flat()
    lines = []
    for name, (low, high, what) in PLAUSIBLE_RANGES.items():
        if name in _MATERIAL_ONLY and flat.get("material") != "neo_hookean":
            continue
        value = flat[name]
        if not low <= value <= high:
            unit = BY_NAME[name].unit
            lines.append(f"{name}={value!r} {unit} is far outside {what}: expected {low:g} to {high:g} {unit}; "
                         "the run may collapse or blow up")
    return lines


def markdown_table() -> str:
    """The parameter reference as a markdown table (for msg_docs/parameters.md)."""
    shipped = default_params()
    lines = ["| name | type | default | unit | read-only | description |", "|---|---|---|---|---|---|"]
    for group in GROUPS:
        for p in (p for p in PARAMETERS if p.group == group):
            default = shipped.get(p.name, p.default)
            shown = f"`{default!r}`" if not isinstance(default, str) else f"`\"{default}\"`"
            lines.append(f"| `{p.name}` | {p.kind.__name__} | {shown} | {p.unit} | {'yes' if p.read_only else 'no'} | {p.description} |")
    return "\n".join(lines)


if __name__ == "__main__":
    print(markdown_table())
