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

    def __post_init__(self) -> None:
        if self.strain is None:
            self.strain = np.zeros_like(self.inertial)
        if self.attach is None:
            self.attach = np.zeros_like(self.inertial)
        if self.potential is None:
            self.potential = np.zeros_like(self.inertial)

    @property
    def total(self) -> np.ndarray:
        """Total energy per body, shape (B,)."""
        return self.inertial + self.spring + self.area + self.strain + self.attach

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
        return cls(np.zeros(n_bodies), np.zeros(n_bodies), np.zeros(n_bodies), np.zeros(n_bodies),
                   np.zeros(n_bodies))


def energy_terms(model: Model, x: np.ndarray, x_pred: np.ndarray) -> EnergyTerms:
    """Implicit Euler energy terms of positions ``x`` given predictions ``x_pred``, per body.

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
    p = model.params
    out = EnergyTerms.zeros(model.n_bodies)
    if model.is_material:
        # inertial term only from the kernel (no springs, no areas), then the strain energy [J]
        energy_terms_kernel(x, x_pred, model.particle_mass, model.particle_body,
                            model.edge_indices[:0], model.edge_rest_length[:0], model.edge_body[:0],
                            model.tri_indices[:0], model.tri_rest_area[:0], model.tri_body[:0],
                            0.0, 0.0, p.dt, True, out.inertial, out.spring, out.area)
        strain_energy_kernel(x, model.tri_indices, model.tri_elastic, model.tri_body, out.potential)
        out.strain[:] = p.dt * p.dt * out.potential
        return out
    energy_terms_kernel(x, x_pred, model.particle_mass, model.particle_body,
                        model.edge_indices, model.edge_rest_length, model.edge_body,
                        model.tri_indices, model.tri_rest_area, model.tri_body,
                        p.k_spring_effective, p.k_area_effective, p.dt, p.area_mode == "signed",
                        out.inertial, out.spring, out.area)
    out.potential[:] = (out.spring + out.area) / (p.dt * p.dt)
    return out
