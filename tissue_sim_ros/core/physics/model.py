"""Simulation parameters, the frozen Model, and the State.

A builder (:meth:`Model.from_mesh`) turns a :class:`~tissue_sim_ros.core.mesh.TissueMesh`
and :class:`SimParams` into a Model of plain arrays; ``model.state()`` makes a
:class:`State`. Names say entity then quantity (``particle_q``,
``edge_rest_length``), as in warp.sim.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, make_dataclass, replace
from typing import Any

import numpy as np

from ..errors import InputError
from ..mesh import TissueMesh, signed_areas
from .params import SIM_PARAMETERS
from .params import validate as validate_params

#: Parameters only ``material: neo_hookean`` reads (ignored with ``constraints``).
MATERIAL_PARAMETERS = ("young_modulus", "poisson_ratio", "thickness", "density")
#: What a material sets when the caller does not: the shipped YAML's values are the paper's (constraints)
#: and do not apply to it. Substeps: one 2 ms step of 100 Gauss-Seidel iterations stops short of
#: equilibrium on a 2 mm mesh, while 10 substeps of 10 iterations reach a static FEM (issue 16); contact:
#: the projection model (the paper's eq. 3 stays selectable with ``contact_model: paper``).
MATERIAL_DEFAULTS: dict[str, dict[str, Any]] = {
    "constraints": {},
    # the step as the minimisation it is, contact in the potential (core/physics/ipc.py)
    "neo_hookean": {"method": "ipc"},
}
#: The material's solver settings per method (applied after the method is known): ipc and quasi_newton solve the
#: whole step (``iterations`` is their cap), ipc with its barrier contact and quasi_newton with the projection;
#: xpbd keeps 10 substeps x 10 Gauss-Seidel iterations (converged at dt 2 ms; it stops short at dt 10 ms).
MATERIAL_METHOD_DEFAULTS: dict[str, dict[str, dict[str, Any]]] = {
    "neo_hookean": {"ipc": {"substeps": 1, "iterations": 50, "contact_model": "barrier"},
                    "quasi_newton": {"substeps": 1, "iterations": 50, "contact_model": "projection"},
                    "xpbd": {"substeps": 10, "iterations": 10, "contact_model": "projection"}},
}


class SimParamsMethods:
    """Every number and switch that defines a simulation, with the paper's defaults.

    ``k_spring`` and ``k_area`` are the paper's PBD per-iteration coefficients
    (Table I), used by ``method="pbd"``. ``stiffness_spring`` [N/m] and
    ``stiffness_area`` [N/m^3 for C in m^2] are physical stiffnesses used by
    ``method="xpbd"`` (compliance = 1/stiffness), calibrated to the same static
    sag as the paper's PBD at 30 iterations (docs/calibration.md); Table I's
    coefficients read as physical stiffnesses let the tissue collapse under its
    own weight (125 mm mean sag of the 0.5 m strip). The energy uses the K of
    the method in use (:attr:`k_spring_effective`).

    The fields, their defaults, units, descriptions and checks are the rows of
    :data:`~tissue_sim_ros.core.physics.params.SIM_PARAMETERS`; :class:`SimParams` is the frozen dataclass
    made from them on this base. Build it by keyword (``SimParams(dt=0.02)``).
    """

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
        """Raise :class:`InputError` naming the first invalid parameter (the rows' checks and rules)."""
        validate_params(self)

    def with_(self, **changes: Any) -> "SimParams":
        """A copy with some fields changed (validated)."""
        return replace(self, **changes)


SimParams = make_dataclass(
    "SimParams", [(p.name, p.kind, field(default=p.default)) for p in SIM_PARAMETERS],
    bases=(SimParamsMethods,), frozen=True, kw_only=True)
SimParams.__module__, SimParams.__qualname__ = __name__, "SimParams"  # picklable (worker processes, Ray)
SimParams.__doc__ = SimParamsMethods.__doc__


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
        rest_area = signed_areas(q0, tris)
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
