"""Strain of the deformed mesh: per edge, and per vertex for points, markers and pictures.

The one definition the node's ``tissue/points`` and markers, ``tissue-sim
replay`` and the pictures share (msg_docs/topics.md): the strain of a vertex
is the mean over its edges of the signed engineering strain
``|x_a - x_b| / l0 - 1`` (positive stretched, negative compressed); an edge of
zero rest length counts as strain 0.
"""
from __future__ import annotations

import numpy as np

from .model import Model


def edge_strain(model: Model, x: np.ndarray) -> np.ndarray:
    """Engineering strain |x_a - x_b| / l0 - 1 of each edge, shape (E,), float64 (0 for zero rest length)."""
    e = model.edge_indices
    d = x[e[:, 1]] - x[e[:, 0]]
    length = np.sqrt((d * d).sum(axis=1))
    l0 = model.edge_rest_length
    out = np.zeros_like(length)
    np.divide(length, l0, out=out, where=l0 > 0)
    out[l0 > 0] -= 1.0
    return out


class VertexStrain:
    """Per-vertex strain of a mesh, with the mesh's constant parts computed once.

    Called every published step by the node and replay: the incidence counts
    and inverse rest lengths are kept, and ``np.take`` gathers the edge ends
    (recomputing them and fancy-indexing (N, 2) arrays every step cost ~4x as much).

    Parameters
    ----------
    edge_indices : ndarray
        Edges, shape (E, 2), int.
    edge_rest_length : ndarray
        Rest length of each edge [m], shape (E,), float64.
    n_particles : int
        Number of vertices N.
    """

    def __init__(self, edge_indices: np.ndarray, edge_rest_length: np.ndarray, n_particles: int) -> None:
        e = np.asarray(edge_indices).astype(np.intp).reshape(-1, 2)
        l0 = np.asarray(edge_rest_length, dtype=np.float64)
        self._a = np.ascontiguousarray(e[:, 0])
        self._b = np.ascontiguousarray(e[:, 1])
        self._ends = np.concatenate([self._a, self._b])
        count = np.bincount(self._ends, minlength=n_particles).astype(np.float64)
        self._inv_count = 1.0 / np.maximum(count, 1.0)
        self._n = int(n_particles)
        self._inv_l0 = np.where(l0 > 0, 1.0 / np.where(l0 > 0, l0, 1.0), 0.0)
        self._one = (l0 > 0).astype(np.float64)  # zero rest length: strain 0, as in edge_strain

    @classmethod
    def of(cls, model: Model) -> "VertexStrain":
        """The operator for ``model``'s edges."""
        return cls(model.edge_indices, model.edge_rest_length, model.n_particles)

    def edges(self, x: np.ndarray) -> np.ndarray:
        """Signed strain of each edge for positions ``x`` (N, 2) [m]; shape (E,), float64."""
        d = np.take(x, self._b, axis=0)
        d -= np.take(x, self._a, axis=0)
        s = np.hypot(d[:, 0], d[:, 1])
        s *= self._inv_l0
        s -= self._one
        return s

    def __call__(self, x: np.ndarray, absolute: bool = False) -> np.ndarray:
        """Mean strain of the edges at each vertex for positions ``x`` (N, 2) [m]; shape (N,), float64.

        Signed (the published field); ``absolute=True`` averages |strain| instead
        (how much a vertex's edges deform either way, as the pictures shade it).
        """
        s = self.edges(x)
        if absolute:
            np.abs(s, out=s)
        return np.bincount(self._ends, weights=np.concatenate([s, s]), minlength=self._n) * self._inv_count


def vertex_strain(model: Model, x: np.ndarray, absolute: bool = False) -> np.ndarray:
    """Mean signed strain of the edges at each vertex, shape (N,), float64 (see :class:`VertexStrain`)."""
    return VertexStrain.of(model)(x, absolute=absolute)


__all__ = ["edge_strain", "VertexStrain", "vertex_strain"]
