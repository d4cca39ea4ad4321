"""The controller's model tied to what a tracker sees (:mod:`.control` uses them).

* :func:`embed`: observed points as barycentric weights in the model's triangles (the fit's weights,
  :func:`~tissue_sim_ros.core.fit.tracking.barycentric`), so a model on another mesh is tied at the material
  points the tracker sees; :func:`particle_points`: the model's own particles in the same form.
* :class:`SyncEnergy`: the sync's energy, the material's potential plus a spring from each embedded point to its
  observation and the jaw's hold, minimised by Newton's method.
* :func:`flap_surface`: where the retraction flap's top surface is at an x (the controller's experiment and the
  learning environments place their goals on it).
"""
from __future__ import annotations

import numpy as np

from ..fit.tracking import barycentric
from ..physics.statics import PotentialEnergy


class SyncEnergy:
    """Pi(x) plus the observation springs and the jaw's hold (the sync of :mod:`.control`), for
    ``newton_minimize``.

    Observation m ties the model's point sum_j w_mj x_(t_mj) (its particle, w = (1, 0, 0), or a point embedded in a
    triangle) to ``obs[m]``: k/2 |B x - o|^2 with B the (M, N) interpolation matrix, Hessian k B^T B."""

    def __init__(self, potential: PotentialEnergy, tris: np.ndarray, w: np.ndarray, obs: np.ndarray, k: float,
                 held: np.ndarray, targets: np.ndarray, k_hold: float) -> None:
        import scipy.sparse as sp  # noqa: PLC0415  (SciPy, as statics)

        self.pot = potential
        self.mass = potential.mass
        self.tris, self.w, self.obs, self.k = tris, w, obs, k
        self.held, self.targets, self.k_hold = held, targets, k_hold
        n = potential.n_dofs // 2
        m = obs.shape[0]
        b = sp.coo_matrix((w.ravel(), (np.repeat(np.arange(m), 3), tris.ravel())), shape=(m, n)).tocsr()
        hold = np.zeros(n)
        np.add.at(hold, held, k_hold)
        self._h = (sp.kron(k * (b.T @ b), sp.identity(2)) + sp.diags(np.repeat(hold, 2))).tocsr()

    def _residual(self, x: np.ndarray) -> np.ndarray:
        return (self.w[:, :, None] * x[self.tris]).sum(axis=1) - self.obs

    def value(self, x: np.ndarray) -> float:
        d = self._residual(x)
        h = x[self.held] - self.targets
        return self.pot.value(x) + 0.5 * self.k * float((d * d).sum()) + 0.5 * self.k_hold * float((h * h).sum())

    def gradient(self, x: np.ndarray) -> np.ndarray:
        g = self.pot.gradient(x)
        d = self.k * self._residual(x)
        for j in range(3):
            np.add.at(g, self.tris[:, j], self.w[:, j, None] * d)
        np.add.at(g, self.held, self.k_hold * (x[self.held] - self.targets))
        return g

    def hessian(self, x: np.ndarray, project: bool = False):
        return self.pot.hessian(x, project) + self._h


def embed(points: np.ndarray, x: np.ndarray, tris: np.ndarray, chunk: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Each point (P, 2) as barycentric weights in a triangle of the mesh at positions ``x``: (tris (P, 3),
    weights (P, 3)). The triangle that contains the point (the largest smallest weight, as the fit's
    :func:`~tissue_sim_ros.core.fit.tracking.bind_points` chooses); a point outside every triangle (just off the
    surface) takes the one whose smallest weight is largest, its weights clipped to >= 0 and renormalised (the
    caller drops the points that lie far off the model, where the fit raises)."""
    tris = np.asarray(tris, dtype=np.int64)
    pts = np.asarray(points, dtype=np.float64)
    a, b, c = x[tris[:, 0]], x[tris[:, 1]], x[tris[:, 2]]
    t = np.zeros(pts.shape[0], dtype=np.int64)
    wt = np.zeros((pts.shape[0], 3))
    for start in range(0, pts.shape[0], chunk):  # (chunk, T, 3) at a time
        w = barycentric(pts[start:start + chunk], a, b, c)
        best = w.min(axis=2).argmax(axis=1)
        t[start:start + chunk] = best
        wt[start:start + chunk] = np.clip(w[np.arange(best.shape[0]), best], 0.0, None)
    total = wt.sum(axis=1, keepdims=True)
    return tris[t], np.where(total > 0, wt / np.where(total > 0, total, 1.0), np.array([1.0, 0.0, 0.0]))


def particle_points(idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Particles ``idx`` as embedded points: tris (i, i, i), weights (1, 0, 0)."""
    tris = np.repeat(np.asarray(idx, dtype=np.int64)[:, None], 3, axis=1)
    w = np.zeros((len(idx), 3))
    w[:, 0] = 1.0
    return tris, w


#: Where the grasper takes the retraction flap (config/scenes/retract.yaml): x [m] (the flap spans 10-70 mm).
RETRACT_X = 0.040


def flap_surface(q: np.ndarray, x: float) -> float:
    """Height [m] of the tissue's top surface at ``x``: the highest particle within a spacing of it."""
    near = np.abs(q[:, 0] - x)
    band = near <= max(float(np.sort(near)[min(3, len(near) - 1)]), 1e-9) + 1e-12
    return float(q[band, 1].max())
