"""Static settle: the tissue's equilibrium under gravity and its pins, by Newton's method.

``settle: static`` (a scene parameter) starts a ``material: neo_hookean`` simulation, and every reset,
from the minimiser of the total potential energy

    Pi(x) = sum_t V0_t Psi(F_t) - sum_i m_i g y_i                                  [J]

(the strain energy of :mod:`~tissue_sim_ros.core.physics.material` plus gravity's potential, g = ``gravity``
along y) over the free particles, pinned ones (inverse mass 0) at rest: at the minimiser the elastic
forces balance the weights, grad Pi = 0, the static problem a run to rest approaches. Newton's method
(:func:`~tissue_sim_ros.core.physics.minimize.newton_minimize`) with the element Hessians of
:func:`~tissue_sim_ros.core.physics.material.element_hessians` assembled sparse (SciPy); where the exact
Hessian is indefinite (strong compression) each element's is projected onto the positive semi-definite
cone. The state is at rest: velocities zero. The paper's boundary lines and walls are not in the energy:
a free particle past one after the solve is put on it (as every step does).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .material import element_hessians, internal_forces, strain_energy
from .minimize import newton_minimize
from .model import Model, State
from .params import SETTLE_MODES  # noqa: F401  (re-exported)


@dataclass
class SettleInfo:
    """How the static solve went."""

    iterations: int
    """Newton iterations."""
    grad_norm: float
    """Norm of grad Pi over the free coordinates at the end [N]."""
    weight: float
    """Norm of the free particles' weights m g, the scale of ``grad_norm`` [N]."""
    converged: bool
    """True when grad_norm <= rtol * weight."""
    energy: float
    """Pi at the minimiser [J]."""

    @property
    def relative_residual(self) -> float:
        """grad_norm / weight: the fraction of the weight left unbalanced."""
        return self.grad_norm / self.weight if self.weight > 0 else 0.0


class PotentialEnergy:
    """Pi(x) of a neo-Hookean Model (module docstring): value, gradient, sparse Hessian (``newton_minimize``'s)."""

    def __init__(self, model: Model) -> None:
        if not model.is_material:
            raise ValueError("static settle needs material neo_hookean (an energy in joules)")
        self.model = model
        self.mass = np.asarray(model.particle_mass, dtype=np.float64)
        self.gravity = float(model.params.gravity)
        tris = np.asarray(model.tri_indices, dtype=np.int64)
        dofs = np.stack([2 * tris[:, k] + d for k in range(3) for d in range(2)], axis=1)  # (T, 6)
        self.n_dofs = 2 * len(self.mass)
        rows = np.repeat(dofs, 6, axis=1).ravel()
        cols = np.tile(dofs, (1, 6)).ravel()
        # the sparsity pattern once (duplicates summed by CSR order); values are scattered through `_perm`
        pattern = sp.csr_matrix((np.arange(1, len(rows) + 1, dtype=np.float64), (rows, cols)),
                                shape=(self.n_dofs, self.n_dofs))
        pattern.sum_duplicates()
        key = rows * self.n_dofs + cols
        csr_key = np.repeat(np.arange(self.n_dofs), np.diff(pattern.indptr)) * self.n_dofs + pattern.indices
        self._slot = np.searchsorted(csr_key, key)
        self._indptr, self._indices = pattern.indptr, pattern.indices
        self._nnz = len(pattern.indices)
        self._hess = np.empty((len(tris), 6, 6))

    def value(self, x: np.ndarray) -> float:
        return float(strain_energy(self.model, x).sum() - self.gravity * float(self.mass @ x[:, 1]))

    def gradient(self, x: np.ndarray) -> np.ndarray:
        g = -internal_forces(self.model, x)
        g[:, 1] -= self.mass * self.gravity
        return g

    def hessian(self, x: np.ndarray, project: bool = False) -> sp.csr_matrix:
        h = self._hess
        element_hessians(np.ascontiguousarray(x, dtype=np.float64), self.model.tri_indices,
                         self.model.tri_elastic, h)
        if project and len(h):
            w, v = np.linalg.eigh(h)
            h = np.einsum("tij,tj,tkj->tik", v, np.maximum(w, 0.0), v)
        data = np.bincount(self._slot, weights=h.ravel(), minlength=self._nnz)
        return sp.csr_matrix((data, self._indices, self._indptr), shape=(self.n_dofs, self.n_dofs))


def settle_static(model: Model, x0: np.ndarray | None = None, rtol: float = 1e-10,
                  max_iterations: int = 100) -> tuple[State, SettleInfo]:
    """The static equilibrium of ``model`` under gravity and its pins, at rest (module docstring).

    Parameters
    ----------
    model : Model
        ``material: neo_hookean``.
    x0 : ndarray, shape (N, 2), optional
        Newton's start; default the rest shape. Pinned particles stay at their rest positions.
    rtol : float
        Stop when |grad Pi| (free coordinates) is at most ``rtol`` times the free particles' weight.

    Returns
    -------
    state : State
        Positions at the equilibrium, velocities zero.
    info : SettleInfo
    """
    energy = PotentialEnergy(model)
    fixed = np.asarray(model.particle_inv_mass) == 0.0
    q0 = np.asarray(model.particle_q0, dtype=np.float64)
    x = q0.copy() if x0 is None else np.array(x0, dtype=np.float64)
    x[fixed] = q0[fixed]
    weight = float(np.linalg.norm(energy.mass[~fixed] * energy.gravity))
    x, info = newton_minimize(energy, x, fixed, g_scale=weight, rtol=rtol, max_iterations=max_iterations,
                              reuse_factor=True)
    p = model.params
    movable = ~fixed
    for line, above in ((p.boundary_y_top, True), (p.boundary_y_bottom, False), (p.wall_y_top, True),
                        (p.wall_y_bottom, False)):
        if math.isfinite(line):
            past = movable & ((x[:, 1] > line) if above else (x[:, 1] < line))
            x[past, 1] = line
    state = model.state()
    state.particle_q[:] = x
    state.particle_qd[:] = 0.0
    return state, SettleInfo(iterations=info["iterations"], grad_norm=info["grad_norm"], weight=weight,
                             converged=info["converged"], energy=info["energy"])
