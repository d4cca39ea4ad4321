"""Simulation parameters, the frozen Model, and the State.

A builder (:meth:`Model.from_mesh`) turns a :class:`~tissue_sim_ros.core.mesh.TissueMesh`
and :class:`SimParams` into a Model of plain arrays; ``model.state()`` makes a
:class:`State`. Names say entity then quantity (``particle_q``,
``edge_rest_length``), as in warp.sim.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..errors import InputError
from ..mesh import TissueMesh

METHODS = ("pbd", "xpbd", "quasi_newton")
SCHEMES = ("gauss_seidel", "jacobi")
AREA_MODES = ("signed", "abs")
CONTACT_MODELS = ("paper", "projection", "none")
CONTACT_SURFACES = ("edges", "particles")
DAMPING_MODES = ("linear", "exponential")
JACOBI_AVERAGINGS = ("violated", "all")
#: ``constraints``: the paper's springs and areas (per-constraint stiffnesses); ``neo_hookean``: a
#: plane-stress membrane with Young's modulus, Poisson's ratio, thickness and density (core/physics/material.py).
MATERIALS = ("constraints", "neo_hookean")
#: How a simulation starts (and resets): ``none`` at the rest shape, ``static`` at the static equilibrium under
#: gravity and the pins (core/physics/statics.py; neo_hookean only).
SETTLE_MODES = ("none", "static")
#: Parameters only ``material: neo_hookean`` reads (ignored with ``constraints``).
MATERIAL_PARAMETERS = ("young_modulus", "poisson_ratio", "thickness", "density")
#: What a material sets when the caller does not: the shipped YAML's values are the paper's (constraints)
#: and do not apply to it. Substeps: one 2 ms step of 100 Gauss-Seidel iterations stops short of
#: equilibrium on a 2 mm mesh, while 10 substeps of 10 iterations reach a static FEM (issue 16); contact:
#: the projection model (the paper's eq. 3 stays selectable with ``contact_model: paper``).
MATERIAL_DEFAULTS: dict[str, dict[str, Any]] = {
    "constraints": {},
    # the step as the minimisation it is (core/physics/quasi_newton.py): converged to solve_tolerance at any mesh
    # in 3-6 iterations; ``iterations`` is its cap
    "neo_hookean": {"method": "quasi_newton", "contact_model": "projection"},
}
#: The material's solver settings per method (applied after the method is known): xpbd keeps the former
#: default of 10 substeps x 10 Gauss-Seidel iterations (converged at dt 2 ms; it stops short at dt 10 ms).
MATERIAL_METHOD_DEFAULTS: dict[str, dict[str, dict[str, Any]]] = {
    "neo_hookean": {"quasi_newton": {"substeps": 1, "iterations": 50},
                    "xpbd": {"substeps": 10, "iterations": 10}},
}

@dataclass(frozen=True)
class SimParams:
    """Every number and switch that defines a simulation, with the paper's defaults.

    ``k_spring`` and ``k_area`` are the paper's PBD per-iteration coefficients
    (Table I), used by ``method="pbd"``. ``stiffness_spring`` [N/m] and
    ``stiffness_area`` [N/m^3 for C in m^2] are physical stiffnesses used by
    ``method="xpbd"`` (compliance = 1/stiffness), calibrated to the same static
    sag as the paper's PBD at 30 iterations (docs/calibration.md); Table I's
    coefficients read as physical stiffnesses let the tissue collapse under its
    own weight (125 mm mean sag of the 0.5 m strip). The energy uses the K of
    the method in use (:attr:`k_spring_effective`).
    """

    # physics (Table I)
    mass: float = 1e-4
    """Mass of each particle [kg]."""
    mass_per_area: float = 0.0
    """Areal density [kg/m^2]; > 0: each particle gets a third of its triangles' rest area times it (lumped
    mass), so refining or grading a mesh keeps the tissue's mass where it is; 0 (paper): every particle has ``mass``."""
    gravity: float = -9.8
    """Gravity along world y [m/s^2]."""
    dt: float = 0.01
    """Time step [s]."""
    damping: float = 0.0
    """Velocity damping rate c [1/s], applied to v before each prediction (see ``damping_mode``); 0 = off (paper)."""
    damping_mode: str = "linear"
    """How ``damping`` scales the velocity each (sub)step h: ``linear`` v *= max(0, 1 - c h) (first order);
    ``exponential`` v *= exp(-c h), the exact decay of dv/dt = -c v (the authors' code: c = 8 1/s)."""
    # solver
    method: str = "pbd"
    """``pbd`` (paper, stiffness scales each projection) or ``xpbd`` (compliance, Lagrange multipliers)."""
    scheme: str = "gauss_seidel"
    """``gauss_seidel`` (sequential) or ``jacobi`` (parallel, averaged/relaxed)."""
    iterations: int = 30
    """Solver iterations per (sub)step."""
    substeps: int = 1
    """Substeps per step (Macklin 2019: many substeps of one iteration)."""
    solve_tolerance: float = 1e-3
    """Material: the step's estimated relative error (the last correction over the step's motion) at which a
    solve counts as converged (method quasi_newton stops there; every method with the material reports it, and the node warns
    beyond it; core/physics/quasi_newton.py)."""
    relaxation: float = 0.9
    """XPBD Jacobi relaxation in (0, 1]: the fraction of the largest step with guaranteed convergence.

    Each constraint c steps omega_c = 2 relaxation / r_c, with r_c a Gershgorin
    bound of the (scaled) XPBD system at the substep's start (stiff constraints
    get small omega, soft ones ~1); stable at every stiffness tried (13..1e6
    N/m). A uniform omega of 1 or 0.5 diverged within 6 and 11 steps on the
    1 m x 0.5 m strip at the default stiffnesses. PBD Jacobi averages by constraint
    count instead (``jacobi_averaging``) and ignores this value.
    """
    jacobi_averaging: str = "violated"
    """PBD Jacobi: ``violated`` (the authors' forward()): each particle's spring corrections are averaged over
    its violated springs and its area corrections over its violated triangles, the two averages added
    (core/physics/violated_jacobi.py); ``all``: the summed corrections divided by all constraints at the particle."""
    jacobi_spring_tolerance: float = 1e-4
    """PBD Jacobi ``violated``: a spring counts (and is corrected) when |C| = ||x_i - x_j| - d0| >= this [m]
    (the authors' 1e-4 m)."""
    jacobi_area_tolerance: float = 1e-11
    """PBD Jacobi ``violated``: a triangle counts (and is corrected) when |C| > this [m^2] (the authors' 1e-11)."""
    k_spring: float = 0.15
    """PBD distance-constraint stiffness coefficient in [0, 1] (Table I)."""
    k_area: float = 1.0
    """PBD area-constraint stiffness coefficient in [0, 1] (Table I)."""
    stiffness_spring: float = 13.0
    """XPBD distance-constraint stiffness [N/m].

    Calibrated (docs/calibration.md): with ``stiffness_area`` = 1e3 x this, the
    1 m x 0.5 m strip (spacing 0.05 m, m = 1e-4 kg, pinned top and bottom)
    sags 0.284 mm (mean, after 3 s) under XPBD at 30 iterations, the paper's
    PBD sag at 30 iterations (0.279 mm); XPBD's sag then stays within 3% from
    30 to 1000 iterations, where PBD's changes 8x from 30 to 100.
    """
    stiffness_area: float = 1.3e4
    """XPBD area-constraint stiffness [N/m^3] (C in m^2); calibrated with ``stiffness_spring``."""
    area_mode: str = "signed"
    """``signed`` area constraint (resists inversion) or the paper's ``abs`` |area| form."""
    sleep_speed: float = 0.0
    """Sleeping: particles slower than this [m/s] and farther than ``sleep_wake_radius`` from any contact for
    10 steps are skipped by the solver (``core/physics/sleeping.py``); 0 = off (every particle is solved every step)."""
    sleep_wake_radius: float = 0.15
    """Sleeping: particles within this rest distance [m] of a contact particle stay awake."""
    # boundary (the paper's horizontal lines; NaN = no line)
    boundary_y_top: float = math.nan
    """Particles at or above this world y are held (velocity zero) [m]; NaN = no upper line."""
    boundary_y_bottom: float = math.nan
    """Particles at or below this world y are held (velocity zero) [m]; NaN = no lower line."""
    # pins and walls apart (the authors' code: a pinned band near each line, walls that clamp every particle)
    pin_y_bottom: float = math.nan
    """Particles whose rest y is at or below this are pinned (inverse mass 0) [m]; NaN = none."""
    pin_y_top: float = math.nan
    """Particles whose rest y is at or above this are pinned [m]; NaN = none."""
    wall_y_bottom: float = math.nan
    """Every particle (pinned ones too) with y below this is put on it, after the prediction and after every
    solver iteration [m] (velocity from the clamped position); NaN = no wall."""
    wall_y_top: float = math.nan
    """Every particle with y above this is put on it, as ``wall_y_bottom`` [m]; NaN = no wall."""
    # contact (the paper's eq. 3 and the projection model)
    contact_model: str = "paper"
    """``paper`` (eq. 3), ``projection`` (non-penetration in the solver loop, swept), or ``none``."""
    contact_radius: float = 0.25
    """Paper contact: radius r of the displaced neighbourhood [m]."""
    contact_threshold: float = 0.025
    """Paper contact: distance alpha below which contact starts [m]."""
    contact_margin: float = 0.002
    """Projection contact: the tool's shape inflated by this margin [m]."""
    contact_surface: str = "edges"
    """Projection contact: what is kept out of the tool. ``edges`` (default): particles and boundary edges,
    so a tool thinner than the mesh spacing indents the surface instead of slipping between particles;
    ``particles``: particles only (such a tool pierces the tissue between them)."""
    # grasping (issue 30): a grasper's jaw closes on what lies at its tip (core/sim/grasp.py, core/physics/attach.py)
    grasp_close_angle: float = 0.2
    """Grasper: the jaw closes (grasps) when its angle falls below this [rad]."""
    grasp_open_angle: float = 0.4
    """Grasper: the jaw opens (releases) when its angle rises above this [rad] (> grasp_close_angle: hysteresis)."""
    grasp_radius: float = 0.004
    """Grasper: particles within this distance of the tip when the jaw closes are grasped [m]."""
    grasp_compliance: float = 1e-4
    """Grasper: compliance of the springs holding grasped particles to the jaws [m/N] (stiffness 1 / it)."""
    # material (issue 16): constraints (the paper) or a plane-stress neo-Hookean membrane
    material: str = "constraints"
    """``constraints`` (the paper's springs and areas; the default, so the paper reproduces) or
    ``neo_hookean`` (plane-stress membrane in SI units, core/physics/material.py; XPBD, so ``method`` must be xpbd)."""
    young_modulus: float = 10e3
    """Neo-Hookean: Young's modulus E [Pa] (ignored by ``constraints``). Soft tissue: 1-100 kPa."""
    poisson_ratio: float = 0.45
    """Neo-Hookean: Poisson's ratio nu in [0, 0.5) [-] (ignored by ``constraints``)."""
    thickness: float = 0.005
    """Neo-Hookean: membrane thickness [m] (ignored by ``constraints``)."""
    density: float = 1000.0
    """Neo-Hookean: density [kg/m^3]; each particle's mass is a third of its triangles' rest area times
    density x thickness (lumped), replacing ``mass`` and ``mass_per_area`` (ignored by ``constraints``)."""
    settle: str = "none"
    """How the simulation starts and resets: ``none`` at the rest shape, ``static`` at the static equilibrium
    under gravity and the pins, at rest (Newton on the potential energy, core/physics/statics.py; neo_hookean only)."""

    def __post_init__(self) -> None:
        self.validate()

    @property
    def k_spring_effective(self) -> float:
        """The spring K of the method in use (PBD coefficient or XPBD stiffness)."""
        return self.k_spring if self.method == "pbd" else self.stiffness_spring

    @property
    def k_area_effective(self) -> float:
        """The area K of the method in use (PBD coefficient or XPBD stiffness)."""
        return self.k_area if self.method == "pbd" else self.stiffness_area

    def validate(self) -> None:
        """Raise :class:`InputError` naming the first invalid parameter."""

        def bad(name: str, expected: str) -> InputError:
            return InputError(f"parameter {name}={getattr(self, name)!r}: expected {expected}")

        for name in ("mass", "mass_per_area", "gravity", "dt", "damping", "relaxation", "k_spring", "k_area",
                     "stiffness_spring", "stiffness_area", "contact_radius", "contact_threshold",
                     "contact_margin", "sleep_speed", "sleep_wake_radius", "jacobi_spring_tolerance",
                     "jacobi_area_tolerance", "young_modulus", "poisson_ratio",
                     "thickness", "density", "grasp_close_angle", "grasp_open_angle", "grasp_radius",
                     "grasp_compliance"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise bad(name, "a finite number")
        for name in ("iterations", "substeps"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise bad(name, "an integer")
        if self.dt <= 0:
            raise bad("dt", "a time step > 0 s")
        if self.mass <= 0:
            raise bad("mass", "a particle mass > 0 kg")
        if self.mass_per_area < 0:
            raise bad("mass_per_area", "an areal density >= 0 kg/m^2 (0: the per-particle mass)")
        if self.iterations < 1:
            raise bad("iterations", "at least 1 solver iteration")
        if self.substeps < 1:
            raise bad("substeps", "at least 1 substep")
        if self.damping < 0:
            raise bad("damping", "a damping rate >= 0 1/s")
        if not 0.0 < self.relaxation <= 1.0:
            raise bad("relaxation", "a Jacobi relaxation factor in (0, 1]")
        if self.method not in METHODS:
            raise bad("method", f"one of {', '.join(METHODS)}")
        if self.scheme not in SCHEMES:
            raise bad("scheme", f"one of {', '.join(SCHEMES)}")
        if self.area_mode not in AREA_MODES:
            raise bad("area_mode", f"one of {', '.join(AREA_MODES)}")
        if self.contact_model not in CONTACT_MODELS:
            raise bad("contact_model", f"one of {', '.join(CONTACT_MODELS)}")
        if self.damping_mode not in DAMPING_MODES:
            raise bad("damping_mode", f"one of {', '.join(DAMPING_MODES)}")
        if self.jacobi_averaging not in JACOBI_AVERAGINGS:
            raise bad("jacobi_averaging", f"one of {', '.join(JACOBI_AVERAGINGS)}")
        for name in ("jacobi_spring_tolerance", "jacobi_area_tolerance"):
            if getattr(self, name) < 0:
                raise bad(name, "a tolerance >= 0")
        if self.contact_surface not in CONTACT_SURFACES:
            raise bad("contact_surface", f"one of {', '.join(CONTACT_SURFACES)}")
        if self.material not in MATERIALS:
            raise bad("material", f"one of {', '.join(MATERIALS)}")
        if self.young_modulus <= 0:
            raise bad("young_modulus", "a Young's modulus > 0 Pa")
        if not 0.0 <= self.poisson_ratio < 0.5:
            raise bad("poisson_ratio", "a Poisson's ratio in [0, 0.5)")
        if self.thickness <= 0:
            raise bad("thickness", "a thickness > 0 m")
        if self.density <= 0:
            raise bad("density", "a density > 0 kg/m^3")
        if self.settle not in SETTLE_MODES:
            raise bad("settle", f"one of {', '.join(SETTLE_MODES)}")
        if self.settle == "static" and self.material != "neo_hookean":
            raise bad("settle", "none with material constraints (static settle needs material neo_hookean)")
        if self.material == "neo_hookean" and self.method == "pbd":
            raise bad("method", "xpbd or quasi_newton with material neo_hookean (the material is solved with compliance)")
        if self.method == "quasi_newton" and self.material != "neo_hookean":
            raise bad("method", "pbd or xpbd with material constraints (quasi_newton minimises the material's energy)")
        if self.method == "quasi_newton" and self.substeps != 1:
            raise bad("substeps", "1 with method quasi_newton (it solves the whole step)")
        if not 0.0 < self.solve_tolerance < 1.0:
            raise bad("solve_tolerance", "a relative residual in (0, 1)")
        for name in ("k_spring", "k_area"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise bad(name, "a PBD stiffness coefficient in [0, 1]")
        for name in ("stiffness_spring", "stiffness_area"):
            if getattr(self, name) < 0:
                raise bad(name, "a stiffness >= 0")
        for name in ("sleep_speed", "sleep_wake_radius"):
            if getattr(self, name) < 0:
                raise bad(name, "a value >= 0 (sleep_speed 0 turns sleeping off)")
        if self.contact_radius <= 0:
            raise bad("contact_radius", "a radius > 0 m")
        if self.contact_threshold < 0:
            raise bad("contact_threshold", "a distance >= 0 m")
        if self.contact_margin < 0:
            raise bad("contact_margin", "a margin >= 0 m")
        if self.grasp_open_angle <= self.grasp_close_angle:
            raise bad("grasp_open_angle", f"an angle > grasp_close_angle={self.grasp_close_angle!r} rad (hysteresis)")
        if self.grasp_radius <= 0:
            raise bad("grasp_radius", "a radius > 0 m")
        if self.grasp_compliance <= 0:
            raise bad("grasp_compliance", "a compliance > 0 m/N")
        for name in ("boundary_y_top", "boundary_y_bottom", "pin_y_top", "pin_y_bottom", "wall_y_top",
                     "wall_y_bottom"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or math.isinf(value):
                raise bad(name, "a finite y in metres, or NaN for no line")
        for top, bottom in (("boundary_y_top", "boundary_y_bottom"), ("pin_y_top", "pin_y_bottom"),
                            ("wall_y_top", "wall_y_bottom")):
            t, b = getattr(self, top), getattr(self, bottom)
            if math.isfinite(t) and math.isfinite(b) and t <= b:
                raise bad(top, f"a line above {bottom}={b}")

    def with_(self, **changes: Any) -> "SimParams":
        """A copy with some fields changed (validated)."""
        return replace(self, **changes)


@dataclass
class State:
    """Positions and velocities of every particle, float64, SI units."""

    particle_q: np.ndarray
    """Particle positions [m], shape (N, 2), float64."""
    particle_qd: np.ndarray
    """Particle velocities [m/s], shape (N, 2), float64."""

    def copy(self) -> "State":
        return State(self.particle_q.copy(), self.particle_qd.copy())


@dataclass(frozen=True, eq=False)
class Model:
    """Frozen topology and rest configuration of all tissue bodies in one scene.

    Built once by :meth:`from_mesh`; arrays are made read-only so that no
    solver changes them by accident.
    """

    params: SimParams
    particle_q0: np.ndarray
    """Rest positions [m], shape (N, 2), float64."""
    particle_mass: np.ndarray
    """Particle masses [kg], shape (N,), float64."""
    particle_inv_mass: np.ndarray
    """Inverse masses [1/kg], shape (N,), float64; 0 for pinned particles."""
    particle_body: np.ndarray
    """Body index of each particle, shape (N,), int32."""
    particle_pinned: np.ndarray
    """True where the particle is pinned (explicit set or on/past a boundary line at rest), shape (N,), bool."""
    edge_indices: np.ndarray
    """Particle indices of each distance constraint, shape (E, 2), int32."""
    edge_rest_length: np.ndarray
    """Rest length d0 of each edge [m], shape (E,), float64."""
    tri_indices: np.ndarray
    """Particle indices of each triangle, counter-clockwise, shape (T, 3), int32."""
    tri_rest_area: np.ndarray
    """Signed rest area A0 of each triangle [m^2] (positive for CCW), shape (T,), float64."""
    tri_body: np.ndarray
    """Body index of each triangle, shape (T,), int32."""
    edge_body: np.ndarray
    """Body index of each edge, shape (E,), int32."""
    n_bodies: int
    """Number of separate tissue bodies."""
    mesh: TissueMesh | None = field(default=None, repr=False)
    """The mesh the model was built from (for rendering and collision)."""
    tri_elastic: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)), repr=False)
    """``material: neo_hookean``: packed rest data of each triangle's element, shape (T, 6), float64
    (:func:`~tissue_sim_ros.core.physics.material.elastic_table`: D_m^-1 and the compliances 1/(mu V0), 1/(lambda' V0)
    [1/J]); shape (0, 6) for ``constraints``."""

    @property
    def is_material(self) -> bool:
        """True for ``material: neo_hookean`` (elements instead of springs and areas)."""
        return self.params.material == "neo_hookean"

    @property
    def n_particles(self) -> int:
        return int(self.particle_q0.shape[0])

    @property
    def body_names(self) -> tuple[str, ...]:
        """Name of each body (from the mesh: its file or its region), B strings."""
        if self.mesh is not None and self.mesh.n_bodies == self.n_bodies:
            return self.mesh.names
        return tuple(f"body {b}" for b in range(self.n_bodies))

    @property
    def n_edges(self) -> int:
        return int(self.edge_indices.shape[0])

    @property
    def n_triangles(self) -> int:
        return int(self.tri_indices.shape[0])

    def state(self) -> State:
        """A new State at rest in the rest configuration."""
        return State(self.particle_q0.copy(), np.zeros_like(self.particle_q0))

    @classmethod
    def from_mesh(cls, mesh: TissueMesh, params: SimParams | None = None,
                  pinned: np.ndarray | None = None) -> "Model":
        """Build a Model from a mesh.

        Parameters
        ----------
        mesh : TissueMesh
            Vertices [m], CCW triangles, unique edges, body of each vertex.
        params : SimParams, optional
            Defaults to Table I.
        pinned : array of int or bool, optional
            Extra particles to pin (indices, or a boolean mask of length N).
            Particles on or past a boundary line or a pin line at rest are pinned as well.
        """
        params = params or SimParams()
        q0 = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
        n = q0.shape[0]
        pin = np.zeros(n, dtype=bool)
        if pinned is not None:
            pinned = np.asarray(pinned)
            if pinned.dtype == bool:
                if pinned.shape != (n,):
                    raise InputError(f"pinned mask has shape {pinned.shape}: expected ({n},)")
                pin |= pinned
            else:
                if pinned.size and (pinned.min() < 0 or pinned.max() >= n):
                    raise InputError(f"pinned indices must lie in [0, {n}); got min {pinned.min()}, max {pinned.max()}")
                pin[pinned.astype(np.int64)] = True
        if math.isfinite(params.boundary_y_top):
            pin |= q0[:, 1] >= params.boundary_y_top
        if math.isfinite(params.boundary_y_bottom):
            pin |= q0[:, 1] <= params.boundary_y_bottom
        if math.isfinite(params.pin_y_top):
            pin |= q0[:, 1] >= params.pin_y_top
        if math.isfinite(params.pin_y_bottom):
            pin |= q0[:, 1] <= params.pin_y_bottom
        edges = np.ascontiguousarray(mesh.edges, dtype=np.int32)
        tris = np.ascontiguousarray(mesh.triangles, dtype=np.int32)
        d = q0[edges[:, 1]] - q0[edges[:, 0]]
        rest_len = np.sqrt((d * d).sum(axis=1))
        a, b, c = q0[tris[:, 0]], q0[tris[:, 1]], q0[tris[:, 2]]
        rest_area = 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
        mass = np.full(n, params.mass, dtype=np.float64)
        if params.mass_per_area > 0 and len(tris):
            # lumped mass: a third of each triangle's area to each of its corners
            lumped = np.bincount(tris.ravel(), weights=np.repeat(np.abs(rest_area) / 3.0, 3), minlength=n)
            mass = np.where(lumped > 0, params.mass_per_area * lumped, params.mass)  # a lone vertex keeps `mass`
        elastic = np.zeros((0, 6))
        if params.material == "neo_hookean":
            from .material import elastic_table, lumped_mass  # noqa: PLC0415  (material -> collision -> model)

            # mass lumped from density x thickness x area (replaces mass and mass_per_area); a vertex of no
            # triangle (it feels no elasticity either) keeps `mass`
            lumped = lumped_mass(q0, tris, params.density, params.thickness)
            mass = np.where(lumped > 0, lumped, params.mass)
            elastic = elastic_table(q0, tris, params.young_modulus, params.poisson_ratio, params.thickness)
        inv_mass = np.where(pin, 0.0, 1.0 / mass)
        body = np.ascontiguousarray(mesh.body, dtype=np.int32)
        arrays = dict(
            particle_q0=q0, particle_mass=mass, particle_inv_mass=inv_mass, particle_body=body,
            particle_pinned=pin, edge_indices=edges, edge_rest_length=rest_len, tri_indices=tris,
            tri_rest_area=rest_area, tri_body=np.ascontiguousarray(body[tris[:, 0]]) if len(tris) else np.zeros(0, np.int32),
            edge_body=np.ascontiguousarray(body[edges[:, 0]]) if len(edges) else np.zeros(0, np.int32),
            tri_elastic=np.ascontiguousarray(elastic),
        )
        for arr in arrays.values():
            arr.setflags(write=False)
        return cls(params=params, n_bodies=int(body.max()) + 1 if n else 0, mesh=mesh, **arrays)

    def with_params(self, params: SimParams) -> "Model":
        """The same mesh and pinned set with other parameters (pins from boundary lines recomputed)."""
        explicit = self.particle_pinned.copy()
        return Model.from_mesh(self.mesh, params, pinned=explicit)
