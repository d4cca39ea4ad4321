"""Implicit Euler energy of a step and its terms (per body and in total).

E = 1/2 sum_i m_i |x_i - x*_i|^2 + dt^2 (E_spring + E_area), with
E_spring = sum_e 1/2 k_s (|x_a - x_b| - l0)^2 and E_area = sum_t 1/2 k_a C_t^2,
where x* are the predicted positions (before the constraint solve) and x the
solved ones. K is the method's own (the paper's coefficients for ``pbd``, the
physical stiffness for ``xpbd``); C_t uses the model's area mode.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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

    @property
    def total(self) -> np.ndarray:
        """Total energy per body, shape (B,)."""
        return self.inertial + self.spring + self.area

    @property
    def scene_total(self) -> float:
        """Total energy of the whole scene."""
        return float(self.total.sum())

    @classmethod
    def zeros(cls, n_bodies: int) -> "EnergyTerms":
        return cls(np.zeros(n_bodies), np.zeros(n_bodies), np.zeros(n_bodies))


def energy_terms(model: Model, x: np.ndarray, x_pred: np.ndarray) -> EnergyTerms:
    """Implicit Euler energy terms of positions ``x`` given predictions ``x_pred``, per body."""
    raise NotImplementedError("energy_terms: implemented with the numba kernels (issue 3)")
