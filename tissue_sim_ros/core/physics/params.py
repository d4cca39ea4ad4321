"""The simulation's parameters: one row each, and how a set of them is checked.

Every simulation parameter (each becomes a field of
:class:`~tissue_sim_ros.core.physics.model.SimParams`) is one :class:`ParamSpec` row of
:data:`SIM_PARAMETERS`: name, type, default, unit, description, read-only, group and what its
value must be. Adding one is adding a row: ``SimParams`` gets the field, ``validate`` the check,
and :data:`tissue_sim_ros.core.config.PARAMETERS` (which adds the scene, tool and node rows)
the YAML name and its line in ``msg_docs/parameters.md``. A check across rows is a
:class:`Rule` of :data:`CHECK_ORDER`.

The rows live here, below ``config`` (the physics cannot import it), so that the record the
Model holds is generated from the same table the front door resolves.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Iterator

import numpy as np

from ..errors import InputError

METHODS = ("pbd", "xpbd", "quasi_newton", "ipc")
SCHEMES = ("gauss_seidel", "jacobi")
AREA_MODES = ("signed", "abs")
CONTACT_MODELS = ("paper", "projection", "barrier", "none")
CONTACT_SURFACES = ("edges", "particles")
DAMPING_MODES = ("linear", "exponential")
JACOBI_AVERAGINGS = ("violated", "all")
#: ``constraints``: the paper's springs and areas (per-constraint stiffnesses); ``neo_hookean``: a
#: plane-stress membrane with Young's modulus, Poisson's ratio, thickness and density (core/physics/material.py).
MATERIALS = ("constraints", "neo_hookean")
#: How a simulation starts (and resets): ``none`` at the rest shape, ``static`` at the static equilibrium under
#: gravity and the pins (core/physics/statics.py; neo_hookean only).
SETTLE_MODES = ("none", "static")

#: Method names of the design card, mapped onto the orthogonal options (the one alias rule:
#: :func:`tissue_sim_ros.core.config.resolve_method_alias`); ``method``'s row lists them.
METHOD_ALIASES: dict[str, dict[str, Any]] = {
    "pbd": {"method": "pbd", "scheme": "gauss_seidel"},
    "pbd_jacobi": {"method": "pbd", "scheme": "jacobi"},
    "xpbd": {"method": "xpbd", "scheme": "gauss_seidel"},
    "xpbd_jacobi": {"method": "xpbd", "scheme": "jacobi"},
    "xpbd_substep": {"method": "xpbd", "scheme": "gauss_seidel", "substeps": 30, "iterations": 1},
}

Check = Callable[[Any], "str | None"]
"""A check returns None when the value is fine, or what was expected."""


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: its declaration, the one place its name, type, unit, range and doc live."""

    name: str
    kind: type
    """float, int, str or bool (ints are accepted for floats)."""
    default: Any
    """Default when no parameter file sets it (``config/tissue_sim.yaml`` overrides the physics ones)."""
    unit: str
    description: str
    read_only: bool
    """True: the value defines the scene (a new mesh, dt, masses...): change it by building a new simulation
    (restart the node). False: tunable while running (:meth:`Simulation.retune`, ``ros2 param set``)."""
    group: str
    """scene, physics, solver, contact, tool or node."""
    check: Check | None = None
    """What a value must be. The record holding the value runs it: ``SimParams.validate`` for the simulation's
    rows (a :class:`ValueCheck`), :func:`~tissue_sim_ros.core.config.coerce` for the node's own, which have
    no record to check them. None: the record checks it itself (the scene's, the tool's) or any value will do."""


@dataclass(frozen=True)
class ValueCheck:
    """What a simulation parameter's value must be, in the two parts ``SimParams.validate`` runs apart: every
    value's type first, then every value's range (so a range is only compared on a number).

    ``typed``: ``"number"`` (a finite int or float, not a bool), ``"integer"`` (an int or NumPy integer, not a
    bool) or None (no type check of its own: ``ok`` takes any value, as a line's NaN or a tolerance's range).
    ``ok(value)`` False refuses the value, expecting ``expected``.
    """

    typed: str | None
    ok: Callable[[Any], bool] | None = None
    expected: str = ""

    def type_expected(self, value: Any) -> str | None:
        """What was expected of the value's type, or None."""
        if self.typed == "number":
            ok = not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)
            return None if ok else "a finite number"
        if self.typed == "integer":
            return None if not isinstance(value, bool) and isinstance(value, (int, np.integer)) else "an integer"
        return None

    def range_expected(self, value: Any) -> str | None:
        """What was expected of the value (of the right type), or None."""
        return None if self.ok is None or self.ok(value) else self.expected

    def __call__(self, value: Any) -> str | None:
        return self.type_expected(value) or self.range_expected(value)


def number(ok: Callable[[Any], bool] | None = None, expected: str = "") -> ValueCheck:
    """A finite number, within ``ok`` when given."""
    return ValueCheck("number", ok, expected)


def positive(expected: str) -> ValueCheck:
    """A finite number > 0."""
    return number(lambda v: v > 0, expected)


def non_negative(expected: str) -> ValueCheck:
    """A finite number >= 0."""
    return number(lambda v: v >= 0, expected)


def integer(ok: Callable[[Any], bool], expected: str) -> ValueCheck:
    """An integer within ``ok``."""
    return ValueCheck("integer", ok, expected)


def one_of(options: tuple[str, ...]) -> ValueCheck:
    """One of ``options``."""
    return ValueCheck(None, lambda v: v in options, f"one of {', '.join(options)}")


#: A horizontal line: a y in metres, or NaN for none.
LINE = ValueCheck(None, lambda v: not isinstance(v, bool) and isinstance(v, (int, float)) and not math.isinf(v),
                  "a finite y in metres, or NaN for no line")


@dataclass(frozen=True)
class Rule:
    """A check across rows: a record for which ``broken(record)`` holds is refused naming ``name``, expecting
    ``expected``, in which ``{field}`` is replaced by the record's value (``str.format``)."""

    name: str
    broken: Callable[[Any], bool]
    expected: str


#: The (top, bottom) lines whose top must be above the bottom when both are set.
LINE_PAIRS = (("boundary_y_top", "boundary_y_bottom"), ("pin_y_top", "pin_y_bottom"), ("wall_y_top", "wall_y_bottom"))

SIM_PARAMETERS: tuple[ParamSpec, ...] = (
    # the paper's horizontal lines, and pins and walls apart (the authors' code: a pinned band near each line,
    # walls that clamp every particle)
    ParamSpec("boundary_y_top", float, math.nan, "m", "Particles at or above this y are pinned (the paper's upper line); NaN = none.", True, "scene", LINE),
    ParamSpec("boundary_y_bottom", float, math.nan, "m", "Particles at or below this y are pinned (the paper's lower line); NaN = none.", True, "scene", LINE),
    ParamSpec("pin_y_top", float, math.nan, "m", "Particles whose rest y is at or above this are pinned (no wall); NaN = none.", True, "scene", LINE),
    ParamSpec("pin_y_bottom", float, math.nan, "m", "Particles whose rest y is at or below this are pinned (no wall); NaN = none.", True, "scene", LINE),
    ParamSpec("wall_y_top", float, math.nan, "m", "Wall: every particle (pinned too) above this y is put on it after the prediction and after every solver iteration (the authors' 0.9768); NaN = none.", True, "scene", LINE),
    ParamSpec("wall_y_bottom", float, math.nan, "m", "Wall: every particle below this y is put on it, as wall_y_top (the authors' 0.0232); NaN = none.", True, "scene", LINE),
    # physics (Table I)
    ParamSpec("mass", float, 1e-4, "kg", "Mass of each particle (Table I: 1e-4).", True, "physics",
              positive("a particle mass > 0 kg")),
    ParamSpec("mass_per_area", float, 0.0, "kg/m^2", "Areal density: > 0 lumps a third of each triangle's area times it on its corners (refined or graded meshes keep the same tissue); 0 = every particle has mass (the paper).", True, "physics",
              non_negative("an areal density >= 0 kg/m^2 (0: the per-particle mass)")),
    ParamSpec("material", str, "constraints", "", f"Tissue model: {', '.join(MATERIALS)} (constraints = the paper's springs and areas; neo_hookean = a plane-stress membrane from young_modulus, poisson_ratio, thickness, density, which brings method ipc (iterations 50 at most, substeps 1) with contact_model barrier unless they are given (quasi_newton and xpbd bring projection; a projection or paper contact given without a method brings quasi_newton)).", True, "physics",
              one_of(MATERIALS)),
    ParamSpec("young_modulus", float, 10e3, "Pa", "neo_hookean: Young's modulus E (> 0); ignored by constraints.", False, "physics",
              positive("a Young's modulus > 0 Pa")),
    ParamSpec("poisson_ratio", float, 0.45, "", "neo_hookean: Poisson's ratio nu in [0, 0.5); ignored by constraints.", False, "physics",
              number(lambda v: 0.0 <= v < 0.5, "a Poisson's ratio in [0, 0.5)")),
    ParamSpec("thickness", float, 0.005, "m", "neo_hookean: membrane thickness (> 0); ignored by constraints.", True, "physics",
              positive("a thickness > 0 m")),
    ParamSpec("density", float, 1000.0, "kg/m^3", "neo_hookean: density (> 0); each particle's mass is density x thickness x a third of its triangles' rest area (replaces mass and mass_per_area); ignored by constraints.", True, "physics",
              positive("a density > 0 kg/m^3")),
    ParamSpec("settle", str, "none", "", f"How the simulation starts and every reset puts it: {' or '.join(SETTLE_MODES)}; none = the rest shape, static = the static equilibrium under gravity and the pins, at rest (Newton's method on strain energy + gravity; material neo_hookean only).", True, "scene",
              one_of(SETTLE_MODES)),
    ParamSpec("gravity", float, -9.8, "m/s^2", "Gravity along world y (Table I: -9.8).", False, "physics", number()),
    ParamSpec("dt", float, 0.01, "s", "Time step; the node steps at 1/dt of its clock (Table I: 0.01).", True, "physics",
              positive("a time step > 0 s")),
    ParamSpec("damping", float, 0.0, "1/s", "Velocity damping rate c, applied before each prediction (damping_mode); 0 = off (paper; the authors' code: 8).", False, "physics",
              non_negative("a damping rate >= 0 1/s")),
    ParamSpec("damping_mode", str, "linear", "", f"Damping per (sub)step h: linear v *= max(0, 1 - c h), or exponential v *= exp(-c h) (the authors'); one of {', '.join(DAMPING_MODES)}.", False, "physics",
              one_of(DAMPING_MODES)),
    # solver
    ParamSpec("method", str, "pbd", "", f"Solver: {', '.join(METHODS)} or an alias ({', '.join(METHOD_ALIASES)}).", False, "solver",
              one_of(METHODS)),
    ParamSpec("scheme", str, "gauss_seidel", "", f"Constraint order: {', '.join(SCHEMES)}.", False, "solver", one_of(SCHEMES)),
    ParamSpec("iterations", int, 30, "", "Solver iterations per (sub)step (Table I: 30).", False, "solver",
              integer(lambda v: v >= 1, "at least 1 solver iteration")),
    ParamSpec("substeps", int, 1, "", "Substeps per step.", False, "solver", integer(lambda v: v >= 1, "at least 1 substep")),
    ParamSpec("solve_tolerance", float, 1e-3, "", "Material: estimated relative error of a step (its last correction over its motion) at which its solve counts as converged (ipc and quasi_newton stop there; the node warns beyond it).", False, "solver",
              ValueCheck(None, lambda v: 0.0 < v < 1.0, "a relative residual in (0, 1)")),
    # a per-constraint omega = 2 relaxation / r_c (r_c: a Gershgorin bound): one omega for all diverged
    # (docs/calibration.md)
    ParamSpec("relaxation", float, 0.9, "", "Jacobi relaxation factor in (0, 1].", False, "solver",
              number(lambda v: 0.0 < v <= 1.0, "a Jacobi relaxation factor in (0, 1]")),
    ParamSpec("jacobi_averaging", str, "violated", "", f"PBD Jacobi: violated (the authors': spring and area corrections each averaged over the particle's violated constraints of that type, then added) or all (divided by all its constraints); one of {', '.join(JACOBI_AVERAGINGS)}.", False, "solver",
              one_of(JACOBI_AVERAGINGS)),
    ParamSpec("jacobi_spring_tolerance", float, 1e-4, "m", "PBD Jacobi violated: a spring counts when ||x_i - x_j| - d0| >= this (the authors' 1e-4).", False, "solver",
              non_negative("a tolerance >= 0")),
    ParamSpec("jacobi_area_tolerance", float, 1e-11, "m^2", "PBD Jacobi violated: a triangle counts when its area error exceeds this (the authors' 1e-11).", False, "solver",
              non_negative("a tolerance >= 0")),
    ParamSpec("k_spring", float, 0.15, "", "PBD distance stiffness coefficient in [0, 1] (Table I: 0.15).", False, "solver",
              number(lambda v: 0.0 <= v <= 1.0, "a PBD stiffness coefficient in [0, 1]")),
    ParamSpec("k_area", float, 1.0, "", "PBD area stiffness coefficient in [0, 1] (Table I: 1).", False, "solver",
              number(lambda v: 0.0 <= v <= 1.0, "a PBD stiffness coefficient in [0, 1]")),
    # XPBD's stiffnesses: calibrated to the paper's PBD sag at 30 iterations (docs/calibration.md)
    ParamSpec("stiffness_spring", float, 13.0, "N/m", "XPBD distance stiffness (method xpbd).", False, "solver",
              non_negative("a stiffness >= 0")),
    ParamSpec("stiffness_area", float, 1.3e4, "N/m^3", "XPBD area stiffness (method xpbd).", False, "solver",
              non_negative("a stiffness >= 0")),
    ParamSpec("area_mode", str, "signed", "", f"Area constraint: {', '.join(AREA_MODES)} (abs = the paper's |area| form).", False, "solver",
              one_of(AREA_MODES)),
    ParamSpec("sleep_speed", float, 0.0, "m/s", "Sleeping: particles slower than this and far from any contact for 10 steps are skipped by the solver; 0 = off.", False, "solver",
              non_negative("a value >= 0 (sleep_speed 0 turns sleeping off)")),
    ParamSpec("sleep_wake_radius", float, 0.15, "m", "Sleeping: particles within this rest distance of a contact particle stay awake.", False, "solver",
              non_negative("a value >= 0 (sleep_speed 0 turns sleeping off)")),
    # contact
    ParamSpec("contact_model", str, "paper", "", f"Contact: {', '.join(CONTACT_MODELS)}.", False, "contact", one_of(CONTACT_MODELS)),
    ParamSpec("contact_radius", float, 0.25, "m", "Paper contact: radius r of the displaced neighbourhood (Table I: 0.25).", False, "contact",
              positive("a radius > 0 m")),
    ParamSpec("contact_threshold", float, 0.025, "m", "Paper contact: distance alpha below which contact starts (Table I: 0.025).", False, "contact",
              non_negative("a distance >= 0 m")),
    ParamSpec("contact_margin", float, 0.002, "m", "Projection contact: the tool inflated by this margin.", False, "contact",
              non_negative("a margin >= 0 m")),
    ParamSpec("contact_surface", str, "edges", "", f"Projection contact keeps out of the tool: {', '.join(CONTACT_SURFACES)} (edges = particles and boundary edges; particles = particles only, a thin tool slips between them).", False, "contact",
              one_of(CONTACT_SURFACES)),
    ParamSpec("contact_dhat", float, 0.0, "m", "Barrier contact (method ipc): the activation distance dhat; a boundary vertex and an edge (of the tissue or the tool's core) closer than this repel, and never touch; 0 = 1 % of the mesh's short boundary edges (their 10th percentile): the gap a pressed contact keeps is a fraction of it (a 0.4 mm punch at h = 2 mm is 3 % off the FEM, 1 % at dhat 0.3 %; a smaller dhat is more accurate and takes more iterations where the tool moves fast into the tissue).", False, "contact",
              non_negative("a distance >= 0 m (0: from the mesh)")),
    ParamSpec("contact_stiffness", float, 0.0, "N/m", "Barrier contact: the barrier's stiffness kappa at the start; 0 = young_modulus x thickness (the membrane's own stiffness scale). A step that ends with a pair closer than 2% of contact_dhat is solved again with kappa x10 (at most 1e4 x the start; kept for the following steps, carried in snapshots, back to the start on reset).", False, "contact",
              non_negative("a stiffness >= 0 N/m (0: from the material)")),
    ParamSpec("tool_stiffness", float, 0.0, "N/m", "Barrier contact: the spring that moves the tool to its commanded pose (the tool stops short of a command the tissue cannot make room for, by force / tool_stiffness); 0 = 1e5 x young_modulus x thickness (a position-controlled robot: the tool stops short by micrometres under newtons).", False, "contact",
              non_negative("a stiffness >= 0 N/m (0: from the barrier's)")),
    ParamSpec("contact_bodies", bool, True, "", "Barrier contact: bodies repel each other and themselves (a fold, a flap on its base); false = the tool only.", False, "contact"),
    ParamSpec("friction", float, 0.0, "", "Barrier contact: Coulomb friction coefficient between the tool and the tissue (lagged, smoothed: IPC's friction); 0 = frictionless.", False, "contact",
              non_negative("a friction coefficient >= 0")),
    ParamSpec("friction_tissue", float, 0.0, "", "Barrier contact: Coulomb friction coefficient between bodies and within one; 0 = frictionless.", False, "contact",
              non_negative("a friction coefficient >= 0")),
    ParamSpec("friction_velocity", float, 1e-3, "m/s", "Barrier contact: the slip speed below which friction sticks (the smoothing of Coulomb's law, IPC's epsilon_v).", False, "contact",
              positive("a speed > 0 m/s")),
    # grasping (tunable)
    ParamSpec("grasp_close_angle", float, 0.2, "rad", "Grasper: a jaw angle (tool/jaw) below this closes the jaw: the free particles within grasp_radius of the tip are held to it.", False, "contact", number()),
    ParamSpec("grasp_open_angle", float, 0.4, "rad", "Grasper: a jaw angle above this opens the jaw and releases what it held (> grasp_close_angle: hysteresis).", False, "contact", number()),
    ParamSpec("grasp_radius", float, 0.004, "m", "Grasper: reach of the closing jaw from its tip (the pose); should exceed contact_margin, which keeps the tissue that far from the tool.", False, "contact",
              positive("a radius > 0 m")),
    ParamSpec("grasp_compliance", float, 1e-4, "m/N", "Grasper: compliance of the zero-length springs holding each grasped particle to its place in the jaws (energy |x - target|^2 / (2 compliance)).", False, "contact",
              positive("a compliance > 0 m/N")),
)

# The order of the checks decides which parameter is named when several are invalid. It is the order the
# checks had when SimParams.validate spelled each out; a row left out of these lists is checked after the
# ones in them, in table order.

#: The rows whose type ``validate`` checks first, in this order.
TYPE_ORDER = (
    "mass", "mass_per_area", "gravity", "dt", "damping", "relaxation", "k_spring", "k_area", "stiffness_spring",
    "stiffness_area", "contact_radius", "contact_threshold", "contact_margin", "sleep_speed", "sleep_wake_radius",
    "jacobi_spring_tolerance", "jacobi_area_tolerance", "young_modulus", "poisson_ratio", "thickness", "density",
    "grasp_close_angle", "grasp_open_angle", "grasp_radius", "grasp_compliance", "iterations", "substeps",
)

#: Then the rows' ranges (by name) and the rules across rows, in this order.
CHECK_ORDER: tuple[str | Rule, ...] = (
    "dt", "mass", "mass_per_area", "iterations", "substeps", "damping", "relaxation", "method", "scheme",
    "area_mode", "contact_model", "damping_mode", "jacobi_averaging", "jacobi_spring_tolerance",
    "jacobi_area_tolerance", "contact_surface", "material", "young_modulus", "poisson_ratio", "thickness", "density",
    "settle",
    Rule("settle", lambda p: p.settle == "static" and p.material != "neo_hookean",
         "none with material constraints (static settle needs material neo_hookean)"),
    Rule("method", lambda p: p.material == "neo_hookean" and p.method == "pbd",
         "xpbd, quasi_newton or ipc with material neo_hookean (the material is solved with compliance)"),
    Rule("method", lambda p: p.method == "quasi_newton" and p.material != "neo_hookean",
         "pbd or xpbd with material constraints (quasi_newton minimises the material's energy)"),
    Rule("method", lambda p: p.method == "ipc" and p.material != "neo_hookean",
         "pbd or xpbd with material constraints (ipc minimises the material's energy)"),
    Rule("substeps", lambda p: p.method == "quasi_newton" and p.substeps != 1,
         "1 with method quasi_newton (it solves the whole step)"),
    Rule("substeps", lambda p: p.method == "ipc" and p.substeps != 1, "1 with method ipc (it solves the whole step)"),
    Rule("contact_model", lambda p: p.method == "ipc" and p.contact_model not in ("barrier", "none"),
         "barrier or none with method ipc (its contact is in the potential it minimises)"),
    Rule("contact_model", lambda p: p.contact_model == "barrier" and p.method != "ipc",
         "paper, projection or none with method {method} (barrier contact is method ipc's)"),
    "solve_tolerance", "k_spring", "k_area", "stiffness_spring", "stiffness_area", "sleep_speed",
    Rule("sleep_speed", lambda p: p.method == "ipc" and p.sleep_speed > 0,
         "0 with method ipc (its contact sees the whole surface: a sleeping region's border would be a new one)"),
    "sleep_wake_radius",
    "contact_radius", "contact_threshold", "contact_margin",
    Rule("grasp_open_angle", lambda p: p.grasp_open_angle <= p.grasp_close_angle,
         "an angle > grasp_close_angle={grasp_close_angle!r} rad (hysteresis)"),
    "grasp_radius", "grasp_compliance",
    *(name for pair in LINE_PAIRS for name in pair),
    *(Rule(top, lambda p, t=top, b=bottom: (math.isfinite(getattr(p, t)) and math.isfinite(getattr(p, b))
                                            and getattr(p, t) <= getattr(p, b)),
           f"a line above {bottom}={{{bottom}}}") for top, bottom in LINE_PAIRS),
)

#: The checks across rows.
RULES: tuple[Rule, ...] = tuple(c for c in CHECK_ORDER if isinstance(c, Rule))


def _steps() -> Iterator[tuple[str, Callable[[Any], str | None]]]:
    """(name, record -> what was expected or None) of every check, in the order :func:`validate` runs them."""
    checks = {p.name: p.check for p in SIM_PARAMETERS if isinstance(p.check, ValueCheck)}
    typed = [n for n in checks if checks[n].typed]
    ranged = [n for n in checks if checks[n].ok is not None]
    listed = [s for s in CHECK_ORDER if not isinstance(s, Rule)]
    if set(TYPE_ORDER) - set(typed) or set(listed) - set(ranged):
        raise RuntimeError(f"TYPE_ORDER or CHECK_ORDER names a row without that check: "
                           f"{sorted(set(TYPE_ORDER) - set(typed))}, {sorted(set(listed) - set(ranged))}")
    for name in (*TYPE_ORDER, *(n for n in typed if n not in TYPE_ORDER)):
        yield name, lambda p, n=name: checks[n].type_expected(getattr(p, n))
    for step in (*CHECK_ORDER, *(n for n in ranged if n not in listed)):
        if isinstance(step, Rule):
            yield step.name, lambda p, r=step: r.expected.format_map(vars(p)) if r.broken(p) else None
        else:
            yield step, lambda p, n=step: checks[n].range_expected(getattr(p, n))


_STEPS: tuple[tuple[str, Callable[[Any], str | None]], ...] = tuple(_steps())


def validate(record: Any) -> None:
    """Raise :class:`InputError` naming the first invalid parameter of ``record`` (a SimParams)."""
    for name, expected_of in _STEPS:
        expected = expected_of(record)
        if expected is not None:
            raise InputError(f"parameter {name}={getattr(record, name)!r}: expected {expected}")
