"""An exact implicit Euler step of the neo-Hookean membrane: its energy, gradient and Hessian in NumPy.

The material model (``material: neo_hookean``) minimises, per step, approximately

    E(x) = 1/2 sum_i m_i |x_i - x*_i|^2 + dt^2 sum_t V0_t Psi(F_t)                      [J]

    Psi(F) = mu/2 (|F|^2 - 2 det F) + lambda'/2 (det F - 1)^2                            [Pa]

with F = D_s D_m^-1 per triangle (D = [x_1 - x_0, x_2 - x_0] in current and rest
positions), V0 = |A0| thickness, the plane-stress Lame parameters lambda =
E nu / (1 - nu^2), mu = E / (2 (1 + nu)) and the shifted lambda' = lambda + mu
(the form's small-strain Lame parameter is lambda' - mu). This module writes
that energy again, from the formula and not from ``core/physics/material.py`` (it
imports nothing from the kernels), so :func:`~tissue_sim_ros.bench.reference.minimize_step`
(damped Newton) can give the exact minimiser the XPBD solve approaches.

Derivatives, with vec F = (F00, F01, F10, F11), J = det F, cof F = dJ/dF =
(F11, -F10, -F01, F00):

    dPsi/dF   = mu (F - cof F) + lambda' (J - 1) cof F
    d2Psi/dF2 = mu (I - K) + lambda' cof F cof F^T + lambda' (J - 1) K

where K = d2J/dF2 is constant (K[0,3] = K[3,0] = 1, K[1,2] = K[2,1] = -1).
dF_ij / dx_(a,i') = delta_ii' c_a[j] with c_1, c_2 the rows of D_m^-1 and
c_0 = -(c_1 + c_2), so the element gradient is V0 B^T vec(dPsi/dF) and the
element Hessian V0 B^T H B (B: 4 x 6). ``project=True`` clamps H's negative
eigenvalues (per element, in F space) so Newton always has a descent
direction.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp

if TYPE_CHECKING:  # types only
    from ..core.physics.model import Model

_K = np.zeros((4, 4))
_K[0, 3] = _K[3, 0] = 1.0
_K[1, 2] = _K[2, 1] = -1.0


def lame(young_modulus: float, poisson_ratio: float) -> tuple[float, float, float]:
    """(lambda_ps, mu, lambda') [Pa]: plane-stress lambda, shear modulus, the form's shifted lambda."""
    E, nu = float(young_modulus), float(poisson_ratio)
    lam = E * nu / (1.0 - nu * nu)
    mu = E / (2.0 * (1.0 + nu))
    return lam, mu, lam + mu


class MembraneEnergy:
    """The implicit Euler energy of one step of the neo-Hookean membrane (the interface ``minimize_step`` uses).

    Parameters
    ----------
    model : Model
        Rest positions, triangles, masses and the material parameters (``young_modulus``,
        ``poisson_ratio``, ``thickness``).
    x_pred : ndarray, shape (N, 2)
        Predicted positions x* [m].
    dt : float
        Time step [s].
    """

    def __init__(self, model: "Model", x_pred: np.ndarray, dt: float) -> None:
        p = model.params
        self.x_pred = np.asarray(x_pred, dtype=np.float64)
        self.dt = float(dt)
        self.mass = np.asarray(model.particle_mass, dtype=np.float64)
        _, self.mu, self.lam_shift = lame(p.young_modulus, p.poisson_ratio)
        tris = np.asarray(model.tri_indices, dtype=np.int64)
        q0 = np.asarray(model.particle_q0, dtype=np.float64)
        dm = np.stack([q0[tris[:, 1]] - q0[tris[:, 0]], q0[tris[:, 2]] - q0[tris[:, 0]]], axis=2)  # (T, 2, 2)
        det = dm[:, 0, 0] * dm[:, 1, 1] - dm[:, 0, 1] * dm[:, 1, 0]
        ok = np.abs(det) > 1e-300  # a zero-area triangle has no D_m^-1: it carries no energy
        self.tris = tris[ok]
        dm, det = dm[ok], det[ok]
        inv = np.empty_like(dm)
        inv[:, 0, 0], inv[:, 1, 1] = dm[:, 1, 1] / det, dm[:, 0, 0] / det
        inv[:, 0, 1], inv[:, 1, 0] = -dm[:, 0, 1] / det, -dm[:, 1, 0] / det
        self.dm_inv = inv
        self.volume = 0.5 * np.abs(det) * float(p.thickness)
        # B (T, 4, 6): vec F = B x_local, x_local = (x0x, x0y, x1x, x1y, x2x, x2y)
        c = np.stack([-(inv[:, 0] + inv[:, 1]), inv[:, 0], inv[:, 1]], axis=1)  # (T, 3, 2): c_a[j]
        b = np.zeros((len(self.tris), 4, 6))
        for i in range(2):
            for j in range(2):
                for a in range(3):
                    b[:, 2 * i + j, 2 * a + i] = c[:, a, j]
        self.B = b
        t_dofs = np.stack([2 * self.tris[:, k] + d for k in range(3) for d in range(2)], axis=1)
        self._rows = np.repeat(t_dofs, 6, axis=1).ravel()
        self._cols = np.tile(t_dofs, (1, 6)).ravel()
        self._t_dofs = t_dofs
        self.n_dofs = 2 * len(self.mass)

    def _F(self, x: np.ndarray) -> np.ndarray:
        """vec F per triangle, (T, 4)."""
        xl = x[self.tris].reshape(len(self.tris), 6)
        return np.einsum("tij,tj->ti", self.B, xl)

    def strain_energy_density(self, x: np.ndarray) -> np.ndarray:
        """Psi per triangle [Pa], (T,)."""
        f = self._F(x)
        det = f[:, 0] * f[:, 3] - f[:, 1] * f[:, 2]
        return 0.5 * self.mu * ((f * f).sum(axis=1) - 2.0 * det) + 0.5 * self.lam_shift * (det - 1.0) ** 2

    def strain_energy(self, x: np.ndarray) -> float:
        """Strain energy sum V0 Psi [J]."""
        return float(self.volume @ self.strain_energy_density(x))

    def value(self, x: np.ndarray) -> float:
        r = x - self.x_pred
        return 0.5 * float(np.sum(self.mass[:, None] * r * r)) + self.dt ** 2 * self.strain_energy(x)

    def gradient(self, x: np.ndarray) -> np.ndarray:
        f = self._F(x)
        det = f[:, 0] * f[:, 3] - f[:, 1] * f[:, 2]
        cof = np.stack([f[:, 3], -f[:, 2], -f[:, 1], f[:, 0]], axis=1)
        pk = self.mu * (f - cof) + (self.lam_shift * (det - 1.0))[:, None] * cof  # (T, 4)
        ge = np.einsum("tij,ti->tj", self.B, pk) * (self.dt ** 2 * self.volume)[:, None]  # (T, 6)
        g = (self.mass[:, None] * (x - self.x_pred)).ravel()
        np.add.at(g, self._t_dofs.ravel(), ge.ravel())
        return g.reshape(-1, 2)

    def hessian(self, x: np.ndarray, project: bool = False) -> sp.csr_matrix:
        f = self._F(x)
        det = f[:, 0] * f[:, 3] - f[:, 1] * f[:, 2]
        cof = np.stack([f[:, 3], -f[:, 2], -f[:, 1], f[:, 0]], axis=1)
        h = (self.mu * (np.eye(4) - _K))[None] + self.lam_shift * cof[:, :, None] * cof[:, None, :] \
            + (self.lam_shift * (det - 1.0))[:, None, None] * _K[None]
        if project and len(h):
            w, v = np.linalg.eigh(h)
            h = np.einsum("tij,tj,tkj->tik", v, np.maximum(w, 0.0), v)
        he = np.einsum("tai,tab,tbj->tij", self.B, h, self.B) * (self.dt ** 2 * self.volume)[:, None, None]
        rows = np.concatenate([np.arange(self.n_dofs), self._rows])
        cols = np.concatenate([np.arange(self.n_dofs), self._cols])
        vals = np.concatenate([np.repeat(self.mass, 2), he.ravel()])
        return sp.csr_matrix((vals, (rows, cols)), shape=(self.n_dofs, self.n_dofs))
