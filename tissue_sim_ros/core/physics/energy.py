"""Implicit Euler energy of a step and its terms (per body and in total).

E = 1/2 sum_i m_i |x_i - x*_i|^2 + dt^2 (E_spring + E_area), with
E_spring = sum_e 1/2 k_s (|x_a - x_b| - l0)^2 and E_area = sum_t 1/2 k_a C_t^2,
where x* are the predicted positions (before the constraint solve) and x the
solved ones. K is the method's own (:attr:`SimParams.k_spring_effective`):
the paper's per-iteration coefficients for ``pbd`` (as the paper defines its
energy; the terms are then in "coefficient" units, comparable between steps of
one run but not a physical energy), the physical stiffness [N/m, N/m^3] for
``xpbd`` (then E is the implicit Euler objective XPBD minimises, in
kg m^2 = J s^2). See docs/calibration.md. C_t uses the model's area mode. The spring term uses current edge
lengths only, never rest edge vectors, so a rigid rotation leaves it unchanged.

``material: neo_hookean``: E = 1/2 sum_i m_i |x_i - x*_i|^2 + dt^2 E_strain, with E_strain the membrane's
strain energy sum_t V0_t Psi(F_t) in joules (:mod:`~tissue_sim_ros.core.physics.material`); the spring and area
terms are zero. Either way :attr:`EnergyTerms.potential` is the unscaled potential energy
(E_spring + E_area + E_strain; joules for xpbd and the material).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ..errors import InputError
from .kernels import energy_terms_kernel
from .material import strain_energy_kernel
from .model import Model


@dataclass
class EnergyTerms:
    """Energy terms of one step, per body, shape (B,) each, float64."""

    inertial: np.ndarray
    """1/2 sum m |x - x*|^2 per body."""
    spring: np.ndarray
    """dt^2 * E_spring per body (already scaled by dt^2, so terms add up to total)."""
    area: np.ndarray
    """dt^2 * E_area per body."""
    strain: np.ndarray | None = None
    """dt^2 * E_strain per body (``material: neo_hookean``; zeros otherwise; None counts as zeros)."""
    potential: np.ndarray | None = None
    """Potential energy per body, not scaled: E_spring + E_area + E_strain [J for xpbd and the material]."""
    attach: np.ndarray | None = None
    """dt^2 * E_attach per body: the grasper's springs, sum |x - target|^2 / (2 grasp_compliance) over the held
    particles (``core/physics/attach.py``; zeros when nothing is held; None counts as zeros). In the total, not in
    ``potential`` (the tissue's own)."""
    contact: np.ndarray | None = None
    """dt^2 * kappa sum b per body: the barrier contact's energy (``contact_model: barrier``; zeros otherwise; None
    counts as zeros). In the total, not in ``potential``."""

    def __post_init__(self) -> None:
        if self.strain is None:
            self.strain = np.zeros_like(self.inertial)
        if self.attach is None:
            self.attach = np.zeros_like(self.inertial)
        if self.contact is None:
            self.contact = np.zeros_like(self.inertial)
        if self.potential is None:
            self.potential = np.zeros_like(self.inertial)

    @property
    def total(self) -> np.ndarray:
        """Total energy per body, shape (B,)."""
        return self.inertial + self.spring + self.area + self.strain + self.attach + self.contact

    @property
    def scene_potential(self) -> float:
        """Potential energy of the whole scene (not scaled by dt^2) [J for xpbd and the material]."""
        return float(self.potential.sum())

    @property
    def scene_total(self) -> float:
        """Total energy of the whole scene."""
        return float(self.total.sum())

    @classmethod
    def zeros(cls, n_bodies: int) -> "EnergyTerms":
        return cls(*(np.zeros(n_bodies) for _ in range(7)))

    @property
    def arrays(self) -> tuple:
        """(inertial, spring, area, strain, potential, attach): the bundle :func:`step_energy` writes."""
        return (self.inertial, self.spring, self.area, self.strain, self.potential, self.attach)


def energy_model(model: Model) -> tuple:
    """The model's part of :func:`step_energy`'s bundle ``terms``: (mass, particle_body, edge_set, tri_set, K_s, K_a,
    signed, material, triangles, elastic, tri_body) (the material's constraint sets empty, K 0: its energy is the
    strain)."""
    p = model.params
    edge_set = (model.edge_indices, model.edge_rest_length, model.edge_body)
    tri_set = (model.tri_indices, model.tri_rest_area, model.tri_body)
    if model.is_material:
        edge_set = tuple(a[:0] for a in edge_set)
        tri_set = tuple(a[:0] for a in tri_set)
        k_spring = k_area = 0.0
        signed = True
    else:
        k_spring, k_area, signed = p.k_spring_effective, p.k_area_effective, p.area_mode == "signed"
    return (model.particle_mass, model.particle_body, edge_set, tri_set, float(k_spring), float(k_area), bool(signed),
            bool(model.is_material), model.tri_indices, model.tri_elastic, model.tri_body)


NO_ATTACH = (np.zeros(0, np.int64), np.zeros((0, 2)), 1.0)
"""An empty attachment bundle of :func:`step_energy` (no grasp)."""


@njit(cache=True, nogil=True)
def step_energy(x: np.ndarray, x_pred: np.ndarray, terms: tuple, dt: float, attach: tuple, out: tuple) -> None:
    """Every energy term of a step per body (module docstring) into ``out`` = (inertial, spring, area, strain,
    potential, attach), (B,) float64 each, overwritten.

    ``terms``: :func:`energy_model`. ``attach`` = (attach_idx (K,) int64, attach_target (K, 2) [m], compliance
    [m/N]): the grasp's springs, dt^2 sum |x - target|^2 / (2 c) per body (``core/physics/attach.py``); K = 0:
    none. The constraints' terms come from :func:`~tissue_sim_ros.core.physics.kernels.energy_terms_kernel` and
    potential = (spring + area) / dt^2; the material's inertial term from it (no constraints), its potential from
    :func:`~tissue_sim_ros.core.physics.material.strain_energy_kernel` and strain = dt^2 potential.
    """
    inertial, spring, area, strain, potential, e_attach = out
    mass, body, edge_set, tri_set, k_spring, k_area, signed, material, tris, elastic, tri_body = terms
    for b in range(inertial.shape[0]):
        strain[b] = 0.0
        potential[b] = 0.0
        e_attach[b] = 0.0
    energy_terms_kernel(x, x_pred, mass, body, edge_set, tri_set, (k_spring, k_area, dt, signed),
                        (inertial, spring, area))
    if material:
        strain_energy_kernel(x, tris, elastic, tri_body, potential)
        for b in range(inertial.shape[0]):
            strain[b] = dt * dt * potential[b]
    else:
        for b in range(inertial.shape[0]):
            potential[b] = (spring[b] + area[b]) / (dt * dt)
    attach_idx, target, compliance = attach
    if attach_idx.shape[0]:
        for a in range(attach_idx.shape[0]):
            i = attach_idx[a]
            ex = x[i, 0] - target[a, 0]
            ey = x[i, 1] - target[a, 1]
            e_attach[body[i]] += 0.5 * (ex * ex + ey * ey) / compliance
        for b in range(inertial.shape[0]):
            e_attach[b] = dt * dt * e_attach[b]


def energy_terms(model: Model, x: np.ndarray, x_pred: np.ndarray) -> EnergyTerms:
    """Implicit Euler energy terms of positions ``x`` given predictions ``x_pred``, per body (no attachments).

    Parameters
    ----------
    model : Model
        Topology, masses, rest sizes; ``model.params`` gives dt, K and the area mode.
    x : (N, 2) float64
        Solved positions x(t+1) [m].
    x_pred : (N, 2) float64
        Predicted positions x* [m] (before the constraint solve).
    """
    n = model.n_particles
    x = np.ascontiguousarray(x, dtype=np.float64)
    x_pred = np.ascontiguousarray(x_pred, dtype=np.float64)
    for name, arr in (("x", x), ("x_pred", x_pred)):
        if arr.shape != (n, 2):
            raise InputError(f"energy_terms: {name} has shape {arr.shape}: expected ({n}, 2)")
    out = EnergyTerms.zeros(model.n_bodies)
    step_energy(x, x_pred, energy_model(model), float(model.params.dt), NO_ATTACH, out.arrays)
    return out
