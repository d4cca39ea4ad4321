"""The quasi-Newton step's prefactored matrix: A0 = M + dt^2 K0, factored once, applied by two triangular solves.

K0 is the exact Hessian of the material's strain energy at the rest shape (``material.element_hessians`` at
q0): the deviatoric part of the energy is quadratic in x, so K0 holds it exactly at every shape, and only the
hydrostatic term departs from it (by the strain and the rotation), which the quasi-Newton updates take up
(:mod:`~tissue_sim_ros.core.physics.quasi_newton`). SuperLU (SciPy) factors it once per (model, dt) with a
symmetric minimum-degree ordering and no pivoting (A0 is symmetric positive definite); :func:`apply_inverse`
is the compiled solve.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla
from numba import njit

from .material import element_hessians

#: Stiffness along a held particle's normal in the preconditioner, relative to its row's diagonal.
HELD_STIFFNESS = 1e4
#: Normals are compared to 1/NORMAL_QUANTUM when deciding whether the active set changed.
NORMAL_QUANTUM = 20.0


def active_key(held: np.ndarray | None, normal: np.ndarray | None) -> bytes:
    """A signature of an active set: the held particles and their normals to 1/NORMAL_QUANTUM."""
    if held is None or len(held) == 0:
        return b""
    q = np.round(np.asarray(normal, dtype=np.float64).reshape(-1, 2) * NORMAL_QUANTUM).astype(np.int64)
    return np.asarray(held, dtype=np.int64).tobytes() + q.tobytes()


class Prefactor:
    """A0 = M + dt^2 K0 (rest Hessian) over the model's free coordinates, factored (SuperLU: Pr A0 Pc = L U).

    Parameters
    ----------
    q0 : (N, 2) rest positions [m]; tris (T, 3); elastic (T, 6) packed rest data; mass (N,) [kg];
    inv_mass : (N,) (0 = pinned: an identity row); dt : the step [s].
    """

    def __init__(self, q0: np.ndarray, tris: np.ndarray, elastic: np.ndarray, mass: np.ndarray,
                 inv_mass: np.ndarray, dt: float, held: np.ndarray | None = None,
                 held_normal: np.ndarray | None = None) -> None:
        n = q0.shape[0]
        self.dt = float(dt)
        t = tris.shape[0]
        he = np.zeros((t, 6, 6))
        if t:
            element_hessians(np.ascontiguousarray(q0, dtype=np.float64), np.ascontiguousarray(tris, dtype=np.int32),
                             np.ascontiguousarray(elastic, dtype=np.float64), he)
        dofs = np.stack([2 * tris[:, k].astype(np.int64) + d for k in range(3) for d in range(2)], axis=1)
        rows = np.repeat(dofs, 6, axis=1).ravel()
        cols = np.tile(dofs, (1, 6)).ravel()
        pinned = np.repeat(np.asarray(inv_mass) == 0.0, 2)
        keep = ~(pinned[rows] | pinned[cols])
        diag = np.where(pinned, 1.0, np.repeat(mass, 2))
        a = sp.csc_matrix((np.concatenate([diag, (dt * dt) * he.ravel()[keep]]),
                           (np.concatenate([np.arange(2 * n), rows[keep]]),
                            np.concatenate([np.arange(2 * n), cols[keep]]))), shape=(2 * n, 2 * n))
        if held is not None and held.size:
            # particles the contacts hold along a normal n: A0 + kappa n n^T there, so the preconditioner is
            # (nearly) the constrained system's (kappa: HELD_STIFFNESS times the particle's row)
            idx = np.asarray(held, dtype=np.int64)
            nn = np.asarray(held_normal, dtype=np.float64).reshape(-1, 2)
            kappa = HELD_STIFFNESS * np.asarray(a.diagonal()).reshape(-1, 2)[idx].max(axis=1)
            r = np.stack([2 * idx, 2 * idx, 2 * idx + 1, 2 * idx + 1], axis=1).ravel()
            c = np.stack([2 * idx, 2 * idx + 1, 2 * idx, 2 * idx + 1], axis=1).ravel()
            v = (kappa[:, None] * np.stack([nn[:, 0] * nn[:, 0], nn[:, 0] * nn[:, 1], nn[:, 1] * nn[:, 0],
                                            nn[:, 1] * nn[:, 1]], axis=1)).ravel()
            a = (a + sp.csc_matrix((v, (r, c)), shape=a.shape)).tocsc()
        self.held_key = active_key(held, held_normal)
        lu = sla.splu(a, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        lo, up = lu.L.tocsc(), lu.U.tocsc()
        lo.sort_indices()
        up.sort_indices()
        self.l_ptr, self.l_idx, self.l_val = (lo.indptr.astype(np.int64), lo.indices.astype(np.int64),
                                              lo.data.astype(np.float64))
        self.u_ptr, self.u_idx, self.u_val = (up.indptr.astype(np.int64), up.indices.astype(np.int64),
                                              up.data.astype(np.float64))
        self.perm_r = lu.perm_r.astype(np.int64)
        self.perm_c = lu.perm_c.astype(np.int64)
        self.arrays = (self.l_ptr, self.l_idx, self.l_val, self.u_ptr, self.u_idx, self.u_val, self.perm_r,
                       self.perm_c)
        """The factor as the compiled solve takes it (:func:`apply_inverse`'s ``factor``)."""
        self.nnz = int(lo.nnz + up.nnz)
        self.matrix = a
        self.scratch = np.zeros(2 * n)

    def solve(self, b: np.ndarray) -> np.ndarray:
        """A0^-1 b for a (2N,) vector (the compiled loop's own triangular solves, from Python; for tests)."""
        out = np.zeros_like(b, dtype=np.float64)
        apply_inverse(self.arrays, np.ascontiguousarray(b, dtype=np.float64), self.scratch, out)
        return out


@njit(cache=True, nogil=True)
def apply_inverse(factor: tuple, b: np.ndarray, z: np.ndarray, out: np.ndarray) -> None:
    """out = A0^-1 b with Pr A0 Pc = L U (SuperLU's convention): z = Pr b, L y = z, U w = y, out = Pc w.

    ``factor`` = (l_ptr, l_idx, l_val, u_ptr, u_idx, u_val, perm_r, perm_c) (:attr:`Prefactor.arrays`): L, U in
    CSC with sorted row indices; L's diagonal is each column's first entry, U's its last. ``z`` (2N,) is scratch.
    """
    l_ptr, l_idx, l_val, u_ptr, u_idx, u_val, perm_r, perm_c = factor
    n = b.shape[0]
    for j in range(n):
        z[perm_r[j]] = b[j]
    for j in range(n):  # forward: L y = z (column-oriented)
        start = l_ptr[j]
        yj = z[j] / l_val[start]
        z[j] = yj
        for k in range(start + 1, l_ptr[j + 1]):
            z[l_idx[k]] -= l_val[k] * yj
    for j in range(n - 1, -1, -1):  # backward: U w = y
        stop = u_ptr[j + 1] - 1
        wj = z[j] / u_val[stop]
        z[j] = wj
        for k in range(u_ptr[j], stop):
            z[u_idx[k]] -= u_val[k] * wj
    for j in range(n):
        out[j] = z[perm_c[j]]
