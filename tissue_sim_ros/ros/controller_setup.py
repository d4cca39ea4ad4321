"""What ``tissue_controller`` (:mod:`~tissue_sim_ros.ros.controller_node`) is built from: its parameters (the
tables, their descriptors with their ranges, and their markdown for ``msg_docs/parameters.md``), its model's
configuration, and the start-up warm-up of the controller's kernels.

Three tables: the node's own (:data:`NODE_PARAMETERS`), one row per
:class:`~tissue_sim_ros.core.plan.control.ControlSettings` field (:data:`SETTINGS_PARAMETERS`; a field without a row
still becomes a parameter, :func:`settings_rows`), and the simulation parameters the model shares with
``tissue_sim_node`` (:data:`MODEL_PARAMETERS`, described by the one table of :mod:`tissue_sim_ros.core.config`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException

from ..core.config import BY_NAME, Config, ParamSpec, coerce, load_params_file, resolve_config
from ..core.contact.tool import ToolPose
from ..core.errors import InputError
from ..core.plan.control import MODEL_COARSENING, ControlSettings, TissueController, default_model
from ..core.resources import scene_params_file
from .parameters import parameter_value, take_overrides

#: The node's own parameters, name -> (default, description).
NODE_PARAMETERS: dict[str, tuple[Any, str]] = {
    "scene": ("retract", "Shipped scene whose parameter file (config/scenes/NAME.yaml; paper: config/tissue_sim.yaml) is the controller's model of the tissue; it must have tool_shape grasper and material neo_hookean."),
    "params_file": ("", "A parameter file (as tissue_sim_node takes) applied over the scene's for the model; empty = none."),
    "points_topic": ("tissue/points", "The tissue's observed points (sensor_msgs/PointCloud2 with float fields x, y, in the tissue plane's frame; the first cloud's frame is the plane's)."),
    "pose_topic": ("tool/applied_pose", "The measured tool pose (geometry_msgs/PoseStamped in the plane's frame; x, y and the yaw about z)."),
    "jaw_topic": ("tool/applied_jaw", "The measured jaw (sensor_msgs/JointState, position[0] [rad]; none yet: open)."),
    "max_time": (20.0, "Give up a goal after pursuing it this long (node clock) [s]."),
    "hold_time": (0.5, "The goal is reached once the controller has held with its goal error within goal_tolerance this long (points' stamps) [s]."),
    "jobs": (1, "Rollout worker processes for the candidates (a RolloutPool, started at start and closed at shutdown); 1 = serially in the node."),
    "nice": (10, "Niceness added to the controller's worker thread (one numba thread) and to the rollout workers (Linux), so that a simulator sharing the cores is scheduled first; 0 = as the rest of the node."),
    "warm_up": (True, "At start, before ~/move_tissue is offered, drive a throwaway copy of the controller through a grasp and one pull replan on its own model, so the numba kernels are compiled (or loaded) before the first goal."),
    "diagnostics_rate": (1.0, "Rate of /diagnostics [Hz]."),
    "warn_period": (2.0, "Each kind of warning about bad input is logged at most once per period [s]."),
}

#: The node's parameters with a range (inclusive; rclpy checks it at declaration): name -> (lowest, highest).
NODE_RANGES: dict[str, tuple[float, float]] = {
    "max_time": (1e-3, 1e6), "hold_time": (0.0, 1e6), "jobs": (1, 256), "nice": (0, 19),
    "diagnostics_rate": (1e-3, 1e3), "warn_period": (0.0, 1e6),
}

#: One parameter per ControlSettings field: node name -> (field, description); default = the dataclass default.
SETTINGS_PARAMETERS: dict[str, tuple[str, str]] = {
    "goal_tolerance": ("tolerance", "The goal is met when the goal point of the synced model is within this distance of its goal [m]."),
    "replan_every": ("replan_every", "Steps committed from each plan: the controller replans every this many steps (at most horizon)."),
    "horizon": ("horizon", "Steps each pull candidate is rolled out."),
    "gains": ("gains", "Pull candidates: gains g on the goal's displacement still to go d (each candidate moves the tool toward its pose + g R(theta) d)."),
    "angles_deg": ("angles_deg", "Pull candidates: the rotations theta of that displacement [deg]."),
    "pull_speeds": ("pull_speeds", "Pull candidates: tool speeds [m/s] (each gain x angle at each speed, and holding still); the first also pulls the grasp sites' trial rollouts."),
    "approach_speed": ("approach_speed", "Tool speed of the approach to the grasp site [m/s]."),
    "approach_hover": ("approach_hover", "The grasper comes down onto the site from this high above it [m]."),
    "approach_clearance": ("approach_clearance", "Its tip stops this far above the site before closing [m]."),
    "grasp_search": ("grasp_search", "Grasp sites: free particles within this distance of the start point [m]."),
    "max_sites": ("max_sites", "At most this many grasp sites are tried (rolled out) per goal."),
    "max_reach": ("max_reach", "A goal farther than this from its start is refused [m]."),
    "start_tolerance": ("start_tolerance", "A start must lie within this distance of an observed tissue point, else it is refused [m]."),
    "sync_stiffness": ("sync_stiffness", "Stiffness k tying each observed particle to its observation in the sync [N/m]; 0 = 10 x young_modulus x thickness."),
    "force_weight": ("force_weight", "Score weight of a candidate's peak reaction force [m/N]."),
    "penetration_weight": ("penetration_weight", "Score weight of its deepest penetration [m/m]."),
    "bias_gain": ("bias_gain", "Offset-free prediction: the weight of each sync's (observed - modelled) goal point in the bias added to the model's goal points (0: trust the model; 1: the last observation alone)."),
    "energy_weight": ("energy_weight", "Score weight of the peak energy it adds over the tool-free baseline [m per unit of energy]."),
    "open_jaw": ("open_jaw", "Jaw angle commanded open [rad]."),
    "closed_jaw": ("closed_jaw", "Jaw angle commanded closed [rad]."),
}

#: The simulation parameters the model shares with tissue_sim_node (the one table's names, types and units);
#: default: the scene's (and params_file's) value, so a user gives the controller a model unlike the world
#: (spacing: a coarser mesh plans faster; the controller ties it to the world's points embedded in its triangles).
MODEL_PARAMETERS = ("spacing", "dt", "young_modulus", "poisson_ratio", "density", "thickness", "damping", "gravity",
                    "grasp_radius", "grasp_compliance")


def settings_rows() -> dict[str, tuple[str, str]]:
    """:data:`SETTINGS_PARAMETERS`, and a row named after any ControlSettings field it does not name yet (so a new
    field is a parameter at once; its description then points at the dataclass)."""
    rows = dict(SETTINGS_PARAMETERS)
    named = {attr for attr, _ in rows.values()}
    for f in fields(ControlSettings):
        if f.name not in named:
            rows[f.name] = (f.name, f"ControlSettings.{f.name} (tissue_sim_ros/core/plan/control.py).")
    return rows


def settings_defaults() -> dict[str, Any]:
    """Each settings parameter's default: the ControlSettings dataclass default (a list for a sequence)."""
    d = ControlSettings()
    out = {}
    for name, (attr, _) in settings_rows().items():
        v = getattr(d, attr)
        out[name] = [float(x) for x in v] if isinstance(v, (tuple, list)) else v
    return out


def model_config(scene: str, params_file: str) -> tuple[list[Any], Config]:
    """The parameter files of the model (the scene's, then ``params_file``) and their resolved configuration."""
    try:
        files: list[Any] = [scene_params_file(scene)]
    except InputError as exc:
        raise InputError(f"parameter scene={scene!r}: {str(exc).split(': ', 1)[-1]}") from None
    if params_file:
        load_params_file(params_file)  # a bad file: one line naming it
        files.append(params_file)
    return files, resolve_config(params_file=files)


def typed_value(name: str, value: Any, default: Any) -> Any:
    """A parameter's value as its default's type (ints for floats, int lists for float lists), or InputError."""
    value = parameter_value(value)
    if isinstance(default, list):
        if not isinstance(value, list) or not value or \
                not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
            raise InputError(f"parameter {name}={value!r}: expected a non-empty list of numbers")
        value = [float(v) for v in value]
        if not all(math.isfinite(v) for v in value):
            raise InputError(f"parameter {name}={value!r}: expected finite numbers")
        return value
    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if type(value) is not type(default):
        kind = {bool: "a boolean", int: "an integer", float: "a number", str: "a string"}[type(default)]
        raise InputError(f"parameter {name}={value!r}: expected {kind}")
    if isinstance(value, float) and not math.isfinite(value):
        raise InputError(f"parameter {name}={value!r}: expected a finite number")
    return value


def model_default_text(name: str) -> str:
    """Where a model parameter's default comes from (the mesh: coarser than the scene's, core/plan/control.py)."""
    if name == "spacing":
        return f"{MODEL_COARSENING:g} x the scene's (and params_file's) spacing: a coarser mesh plans faster"
    return "the scene's (and params_file's) value"


def sim_description(spec: ParamSpec) -> str:
    unit = f" [{spec.unit}]" if spec.unit else ""
    return f"The controller's model: {spec.description}{unit} Default: {model_default_text(spec.name)}."


_TYPES = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
          float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING}


def descriptor(name: str, default: Any, description: str) -> ParameterDescriptor:
    """Read-only, typed as its default (a list: of floats), with its range from :data:`NODE_RANGES`."""
    kind = ParameterType.PARAMETER_DOUBLE_ARRAY if isinstance(default, list) else _TYPES[type(default)]
    d = ParameterDescriptor(name=name, type=kind, description=description, read_only=True)
    if name in NODE_RANGES:
        lo, hi = NODE_RANGES[name]
        if isinstance(default, int):
            d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
        else:
            d.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)]
    return d


def _declare(node: Any, name: str, value: Any, default: Any, description: str) -> Any:
    """Declare one parameter at ``value`` (its default's type); a value out of its range is an InputError."""
    try:
        node.declare_parameter(name, value, descriptor(name, default, description), ignore_override=True)
    except (InvalidParameterValueException, InvalidParameterTypeException):
        lo, hi = NODE_RANGES.get(name, (None, None))
        raise InputError(f"parameter {name}={value!r}: expected {lo:g} to {hi:g}" if lo is not None
                         else f"parameter {name}={value!r}: rclpy refused it") from None
    return value


@dataclass
class ControllerParameters:
    """The controller's parameters, declared: the node's own and the settings' values by name, its settings, its
    model's Config and the model parameters that differ from the scene's."""

    values: dict[str, Any]
    settings: ControlSettings
    config: Config
    overrides: dict[str, Any]


def declare_controller_parameters(node: Any) -> ControllerParameters:
    """Declare every parameter of the controller (read-only, typed, ranged) at the value it was given or its
    default; an integer given for a float (or a list of them) is taken as one. A bad value: InputError naming it.

    ``node`` was made with ``automatically_declare_parameters_from_overrides`` (:func:`~.parameters.take_overrides`).
    """
    given = take_overrides(node)
    values: dict[str, Any] = {}
    rows = settings_rows()
    tables = [(name, default, description) for name, (default, description) in NODE_PARAMETERS.items()]
    tables += [(name, default, rows[name][1]) for name, default in settings_defaults().items()]
    for name, default, description in tables:
        value = typed_value(name, given.get(name, default), default)
        values[name] = _declare(node, name, value, default, description)
    files, base = model_config(values["scene"], values["params_file"])
    flat = base.flat()
    defaults = {**flat, **default_model(base)}  # the model's mesh: coarser than the scene's
    overrides = {}
    for name in MODEL_PARAMETERS:
        spec = BY_NAME[name]
        value = coerce(spec, given.get(name, defaults[name]))
        _declare(node, name, value, float(defaults[name]), sim_description(spec))
        if value != flat[name]:
            overrides[name] = value
    config = resolve_config(overrides, params_file=files, source="the controller's parameters")
    settings = ControlSettings(**{attr: values[name] for name, (attr, _) in rows.items()})
    return ControllerParameters(values, settings, config, overrides)


def markdown_table() -> str:
    """The parameters as the markdown table of msg_docs/parameters.md (a test checks it is there)."""
    lines = ["| name | default | description |", "|---|---|---|"]

    def shown(v: Any) -> str:
        return f'`"{v}"`' if isinstance(v, str) else f"`{v!r}`".replace("True", "true").replace("False", "false")

    for name, (default, description) in NODE_PARAMETERS.items():
        lo_hi = NODE_RANGES.get(name)
        ranged = f" Range {lo_hi[0]:g} to {lo_hi[1]:g}." if lo_hi else ""
        lines.append(f"| `{name}` | {shown(default)} | {description}{ranged} |")
    defaults = settings_defaults()
    for name, (attr, description) in settings_rows().items():
        field = f" ControlSettings' field {attr}." if attr != name else ""
        lines.append(f"| `{name}` | {shown(defaults[name])} | {description}{field} |")
    for name in MODEL_PARAMETERS:
        spec = BY_NAME[name]
        unit = f" [{spec.unit}]" if spec.unit else ""
        default = "the scene's" if name != "spacing" else f"{MODEL_COARSENING:g} x the scene's"
        lines.append(f"| `{name}` | {default} | The model's {name}{unit}, as tissue_sim_node's (parameters.md above). |")
    return "\n".join(lines)


def warm_up(config: Config, settings: ControlSettings, pool: Any = None, max_commands: int = 300) -> str:
    """Drive a throwaway controller through a grasp and a pull replan on its own model at rest (the measured
    pose is the command, the points the rest shape): the kernels a pursuit uses are compiled (or loaded from
    numba's cache) now. Returns a note for the log ('' when it got to a pull replan)."""
    ctrl = TissueController(config, settings, pool=pool)
    x = ctrl.x.copy()
    free = np.flatnonzero(~ctrl.fixed)
    if free.size == 0:
        return "; skipped (no free particle)"
    top = int(free[np.argmax(x[free, 1])])
    start = x[top]
    goal = start + np.array([0.0, min(0.01, 0.5 * settings.max_reach)])
    pose = ToolPose(float(start[0]), float(start[1] + settings.approach_hover + settings.approach_clearance), 0.0)
    jaw = settings.open_jaw
    try:
        ctrl.set_goal([(start, goal)], x, pose)
        for k in range(max_commands):
            cmd = ctrl.command(x, pose, jaw, t=k * ctrl.dt)
            pose, jaw = cmd.pose, cmd.jaw
            if any(r.phase in ("pull", "holding") and r.candidates for r in ctrl.records):
                return ""
    except InputError as exc:
        return f"; stopped early: {exc}"
    return f"; no pull replan within {max_commands} steps"
