"""Every parameter of ``tissue_sim_node`` in one table: name, type, unit, description, read-only.

The table is the single source for declaring the parameters (with a
``ParameterDescriptor`` each), for checking their values, and for
``msg_docs/parameters.md`` (``python -m tissue_sim_ros.ros.parameters`` prints
the markdown table). Names are the flat names of
:class:`~tissue_sim_ros.core.model.SimParams`, :class:`~tissue_sim_ros.core.scene.SceneConfig`,
the ``tool_*`` shape, and the node's own options; ``test/test_ros_messages.py``
checks that no field is missing.

Model-defining parameters (the mesh, dt, mass, boundary lines, tool shape,
lock-step) are read-only: changing them means a new scene, so restart the node.
The rest are tunable while running; a set is checked first and rejected with
the reason when the value is bad.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any, Callable, Mapping

from ..core.errors import InputError
from ..core.model import (
    AREA_MODES,
    CONTACT_MODELS,
    CONTACT_SURFACES,
    MATERIALS,
    METHOD_ALIASES,
    METHODS,
    SCHEMES,
    SimParams,
    apply_material_defaults,
)
from ..core.scene import SceneConfig, default_params, tool_from_mapping
from ..core.tool import TOOL_SHAPES, ToolShape

Check = Callable[[Any], "str | None"]
"""A check returns None when the value is fine, or what was expected."""


def _positive(v: Any) -> str | None:
    return None if v > 0 else "a value > 0"


def _non_negative(v: Any) -> str | None:
    return None if v >= 0 else "a value >= 0"


def _one_of(options: tuple[str, ...]) -> Check:
    return lambda v: None if v in options else f"one of {', '.join(options)}"


_FRAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_/]*$")


def _frame(v: Any) -> str | None:
    return None if _FRAME_RE.match(v) and not v.startswith("/") else "a frame name like 'world' (letters, digits, _, /; no leading /)"


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of the node."""

    name: str
    kind: type
    """float, int, str or bool (ints are accepted for floats)."""
    default: Any
    """Default when the node runs without a parameter file (``config/tissue_sim.yaml`` overrides the physics ones)."""
    unit: str
    description: str
    read_only: bool
    group: str
    """scene, physics, solver, contact, tool or node."""
    check: Check | None = None
    """Extra check of a node-only parameter (SimParams/SceneConfig/ToolShape check their own)."""


_SIM = SimParams()
_SCENE = SceneConfig()
_TOOL = ToolShape()

PARAMETERS: tuple[ParamSpec, ...] = (
    # scene: where the mesh comes from (read-only: a new mesh is a new scene)
    ParamSpec("image", str, _SCENE.image, "path", "Tissue image (PNG/JPEG/BMP) meshed at start; empty = the shipped config/tissue.png.", True, "scene"),
    ParamSpec("mesh_file", str, _SCENE.mesh_file, "path", "Mesh file (.npz from `tissue-sim mesh`); overrides image when set.", True, "scene"),
    ParamSpec("spacing", float, _SCENE.spacing, "m", "Target edge length when meshing the image.", True, "scene"),
    ParamSpec("scale", float, _SCENE.scale, "m/px", "Image scale: metres per pixel.", True, "scene"),
    ParamSpec("origin_x", float, _SCENE.origin_x, "m", "World x of the image's left edge.", True, "scene"),
    ParamSpec("origin_y", float, _SCENE.origin_y, "m", "World y of the image's bottom edge.", True, "scene"),
    ParamSpec("threshold", float, _SCENE.threshold, "grey level", "Grey threshold separating tissue from background; < 0 = automatic (Otsu).", True, "scene"),
    ParamSpec("boundary_y_top", float, _SIM.boundary_y_top, "m", "Particles at or above this y are pinned (the paper's upper line); NaN = none.", True, "scene"),
    ParamSpec("boundary_y_bottom", float, _SIM.boundary_y_bottom, "m", "Particles at or below this y are pinned (the paper's lower line); NaN = none.", True, "scene"),
    # physics (Table I)
    ParamSpec("mass", float, _SIM.mass, "kg", "Mass of each particle (Table I: 1e-4).", True, "physics"),
    ParamSpec("mass_per_area", float, _SIM.mass_per_area, "kg/m^2", "Areal density: > 0 lumps a third of each triangle's area times it on its corners (refined or graded meshes keep the same tissue); 0 = every particle has mass (the paper).", True, "physics"),
    ParamSpec("material", str, _SIM.material, "", f"Tissue model: {', '.join(MATERIALS)} (constraints = the paper's springs and areas; neo_hookean = a plane-stress membrane from young_modulus, poisson_ratio, thickness, density, with its own defaults method xpbd, substeps 10, iterations 10, contact_model projection where the shipped values stand).", True, "physics"),
    ParamSpec("young_modulus", float, _SIM.young_modulus, "Pa", "neo_hookean: Young's modulus E (> 0); ignored by constraints.", False, "physics"),
    ParamSpec("poisson_ratio", float, _SIM.poisson_ratio, "", "neo_hookean: Poisson's ratio nu in [0, 0.5); ignored by constraints.", False, "physics"),
    ParamSpec("thickness", float, _SIM.thickness, "m", "neo_hookean: membrane thickness (> 0); ignored by constraints.", True, "physics"),
    ParamSpec("density", float, _SIM.density, "kg/m^3", "neo_hookean: density (> 0); particle masses lumped from density x thickness x a third of each adjacent triangle's rest area (replaces mass, mass_per_area); ignored by constraints.", True, "physics"),
    ParamSpec("gravity", float, _SIM.gravity, "m/s^2", "Gravity along world y (Table I: -9.8).", False, "physics"),
    ParamSpec("dt", float, _SIM.dt, "s", "Time step; the node steps at 1/dt of its clock (Table I: 0.01).", True, "physics"),
    ParamSpec("damping", float, _SIM.damping, "1/s", "Velocity damping rate; 0 = off (paper).", False, "physics"),
    # solver
    ParamSpec("method", str, _SIM.method, "", f"Solver: {', '.join(METHODS)} or an alias ({', '.join(METHOD_ALIASES)}).", False, "solver"),
    ParamSpec("scheme", str, _SIM.scheme, "", f"Constraint order: {', '.join(SCHEMES)}.", False, "solver"),
    ParamSpec("iterations", int, _SIM.iterations, "", "Solver iterations per (sub)step (Table I: 30).", False, "solver"),
    ParamSpec("substeps", int, _SIM.substeps, "", "Substeps per step.", False, "solver"),
    ParamSpec("relaxation", float, _SIM.relaxation, "", "Jacobi relaxation factor in (0, 1].", False, "solver"),
    ParamSpec("k_spring", float, _SIM.k_spring, "", "PBD distance stiffness coefficient in [0, 1] (Table I: 0.15).", False, "solver"),
    ParamSpec("k_area", float, _SIM.k_area, "", "PBD area stiffness coefficient in [0, 1] (Table I: 1).", False, "solver"),
    ParamSpec("stiffness_spring", float, _SIM.stiffness_spring, "N/m", "XPBD distance stiffness (method xpbd).", False, "solver"),
    ParamSpec("stiffness_area", float, _SIM.stiffness_area, "N/m^3", "XPBD area stiffness (method xpbd).", False, "solver"),
    ParamSpec("area_mode", str, _SIM.area_mode, "", f"Area constraint: {', '.join(AREA_MODES)} (abs = the paper's |area| form).", False, "solver"),
    ParamSpec("sleep_speed", float, _SIM.sleep_speed, "m/s", "Sleeping: particles slower than this and far from any contact for 10 steps are skipped by the solver; 0 = off.", False, "solver"),
    ParamSpec("sleep_wake_radius", float, _SIM.sleep_wake_radius, "m", "Sleeping: particles within this rest distance of a contact particle stay awake.", False, "solver"),
    # contact
    ParamSpec("contact_model", str, _SIM.contact_model, "", f"Contact: {', '.join(CONTACT_MODELS)}.", False, "contact"),
    ParamSpec("contact_radius", float, _SIM.contact_radius, "m", "Paper contact: radius r of the displaced neighbourhood (Table I: 0.25).", False, "contact"),
    ParamSpec("contact_threshold", float, _SIM.contact_threshold, "m", "Paper contact: distance alpha below which contact starts (Table I: 0.025).", False, "contact"),
    ParamSpec("contact_margin", float, _SIM.contact_margin, "m", "Projection contact: the tool inflated by this margin.", False, "contact"),
    ParamSpec("contact_surface", str, _SIM.contact_surface, "", f"Projection contact keeps out of the tool: {', '.join(CONTACT_SURFACES)} (edges = particles and boundary edges; particles = particles only, a thin tool slips between them).", False, "contact"),
    # tool shape (read-only: the contact model is built around it)
    ParamSpec("tool_shape", str, _TOOL.kind, "", f"Tool shape: {', '.join(TOOL_SHAPES)}.", True, "tool"),
    ParamSpec("tool_length", float, _TOOL.length, "m", "Tool length along its axis (box, capsule).", True, "tool"),
    ParamSpec("tool_width", float, _TOOL.width, "m", "Full width of a box tool.", True, "tool"),
    ParamSpec("tool_radius", float, _TOOL.radius, "m", "Radius of a capsule or sphere tool.", True, "tool"),
    # the node's own
    ParamSpec("frame_id", str, "world", "", "The one fixed frame of every message in and out; inputs in another frame are dropped.", False, "node", _frame),
    ParamSpec("lock_step", bool, False, "", "true: one step per received tool pose (exact replay), no timer; false: a timer at 1/dt.", True, "node"),
    ParamSpec("paused", bool, False, "", "true: no steps (also set by the ~/pause service).", False, "node"),
    ParamSpec("marker_rate", float, 100.0, "Hz", "Rate of tissue/markers; capped at 1/dt (published every round(1/(dt*rate)) steps).", False, "node", _positive),
    ParamSpec("points_rate", float, 100.0, "Hz", "Rate of tissue/points; capped at 1/dt.", False, "node", _positive),
    ParamSpec("diagnostics_rate", float, 1.0, "Hz", "Rate of /diagnostics.", False, "node", _positive),
    ParamSpec("markers_wireframe", bool, True, "", "Include the wireframe LINE_LIST in tissue/markers.", False, "node"),
    ParamSpec("strain_color_max", float, 0.2, "", "Strain shown at full colour in the mesh marker (blue -max, red +max).", False, "node", _positive),
    ParamSpec("wire_width", float, 0.002, "m", "Line width of the wireframe markers.", False, "node", _positive),
    ParamSpec("max_tool_jump", float, 0.05, "m", "A tool pose farther than this from the last one used is clamped to this distance per step.", False, "node", _positive),
    ParamSpec("max_stamp_age", float, 0.5, "s", "Timer mode: tool messages stamped older than this are dropped as stale; 0 = no check.", False, "node", _non_negative),
    ParamSpec("twist_timeout", float, 0.05, "s", "A tool twist received longer ago than this is stale: velocity is derived from poses.", False, "node", _positive),
    ParamSpec("twist_source", str, "auto", "", "auto: tool/twist when fresh, else from poses; poses: always derived from poses.", False, "node", _one_of(("auto", "poses"))),
    ParamSpec("warn_period", float, 2.0, "s", "Each kind of warning about bad input is logged at most once per period.", False, "node", _positive),
    ParamSpec("record_path", str, "", "path", "Record every message in and out (the very bytes published) to this new rosbag2 bag directory; empty = no recording.", True, "node"),
    ParamSpec("record_storage", str, "mcap", "", "Storage of the recorded bag: mcap (default, as ros2 bag in Jazzy) or sqlite3.", True, "node", _one_of(("mcap", "sqlite3"))),
)

BY_NAME: dict[str, ParamSpec] = {p.name: p for p in PARAMETERS}

#: Names read by :func:`tissue_sim_ros.core.scene.build_simulation` (everything but the node's own).
SIM_NAMES: tuple[str, ...] = tuple(p.name for p in PARAMETERS if p.group != "node")


def coerce(spec: ParamSpec, value: Any) -> Any:
    """The value as the parameter's type, or InputError naming the parameter and what was expected."""
    kind = spec.kind
    ok = (isinstance(value, bool) if kind is bool else
          isinstance(value, int) and not isinstance(value, bool) if kind is int else
          isinstance(value, (int, float)) and not isinstance(value, bool) if kind is float else
          isinstance(value, str))
    if not ok:
        raise InputError(f"parameter {spec.name}={value!r}: expected {'a number' if kind is float else 'an integer' if kind is int else 'a boolean' if kind is bool else 'a string'}")
    value = float(value) if kind is float else value
    if spec.check is not None:
        if kind is float and not math.isfinite(value):
            raise InputError(f"parameter {spec.name}={value!r}: expected a finite number")
        expected = spec.check(value)
        if expected is not None:
            raise InputError(f"parameter {spec.name}={value!r}: expected {expected}")
    return value


def validate(values: Mapping[str, Any]) -> dict[str, Any]:
    """Coerce and check a full flat parameter set; InputError names the first bad parameter.

    The physics, solver and contact values are checked by building
    :class:`SimParams`; the scene values by :class:`SceneConfig`; the tool by
    :class:`ToolShape`.
    """
    out = {name: coerce(BY_NAME[name], value) for name, value in values.items() if name in BY_NAME}
    SimParams.from_mapping(apply_material_defaults(out, default_params()))
    SceneConfig.from_mapping(out)
    tool_from_mapping(out)
    return out


def markdown_table() -> str:
    """The parameter reference as a markdown table (for msg_docs/parameters.md)."""
    from ..core.scene import default_params  # noqa: PLC0415

    shipped = default_params()
    lines = ["| name | type | default | unit | read-only | description |", "|---|---|---|---|---|---|"]
    for group in ("scene", "physics", "solver", "contact", "tool", "node"):
        for p in (p for p in PARAMETERS if p.group == group):
            default = shipped.get(p.name, p.default)
            shown = f"`{default!r}`" if not isinstance(default, str) else f"`\"{default}\"`"
            lines.append(f"| `{p.name}` | {p.kind.__name__} | {shown} | {p.unit} | {'yes' if p.read_only else 'no'} | {p.description} |")
    return "\n".join(lines)


if __name__ == "__main__":
    print(markdown_table())
