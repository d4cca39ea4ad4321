"""Strain of the deformed mesh: per edge, and per vertex for points, markers and pictures.

The one definition the node's ``tissue/points`` and markers, ``tissue-sim
replay`` and the pictures share (msg_docs/topics.md): the strain of a vertex
is the mean over its edges of the signed engineering strain
``|x_a - x_b| / l0 - 1`` (positive stretched, negative compressed); an edge of
zero rest length counts as strain 0.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

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
        out = np.empty(self._n)
        vertex_strain_kernel(np.ascontiguousarray(x, dtype=np.float64), self._a, self._b, self._inv_l0, self._one,
                             self._inv_count, absolute, out)
        return out


@njit(cache=True, nogil=True)
def vertex_strain_kernel(x: np.ndarray, a: np.ndarray, b: np.ndarray, inv_l0: np.ndarray, one: np.ndarray,
                         inv_count: np.ndarray, absolute: bool, out: np.ndarray) -> None:
    """Per-vertex mean edge strain into ``out`` (N,): for each edge e = (a, b),

        s_e = |x_b - x_a| / l0_e - 1    (0 for l0 = 0: ``inv_l0`` = ``one`` = 0 there)

    then ``out[i] = (sum of s_e over the edges at i) / (number of edges at i)``, summed as
    ``np.bincount`` over ``concat(a, b)`` does (all a-ends in edge order, then all b-ends), so the
    result is bit for bit :meth:`VertexStrain.__call__`'s NumPy form (twin: ``test/naive.py``). Compiled
    ``nogil``: the node's step and marker threads both call it. ``absolute``: average |s_e| instead.
    """
    out[:] = 0.0
    n_edges = a.shape[0]
    s = np.empty(n_edges)
    for e in range(n_edges):
        i, j = a[e], b[e]
        v = math.hypot(x[j, 0] - x[i, 0], x[j, 1] - x[i, 1]) * inv_l0[e] - one[e]
        s[e] = abs(v) if absolute else v
    for e in range(n_edges):
        out[a[e]] += s[e]
    for e in range(n_edges):
        out[b[e]] += s[e]
    for i in range(out.shape[0]):
        out[i] *= inv_count[i]


@njit(cache=True, nogil=True)
def strain_mesh_arrays(q: np.ndarray, tri_flat: np.ndarray, edge_flat: np.ndarray, strain: np.ndarray,
                       strain_color_max: float, lut: np.ndarray, tri_points: np.ndarray, tri_rgba: np.ndarray,
                       wire_points: np.ndarray, wireframe: bool) -> None:
    """The markers' big arrays for positions ``q`` (N, 2), in preallocated outputs (the node's marker thread).

    * ``tri_points`` (3T, 3): ``(q[v], 0)`` for each corner v of ``tri_flat`` (triangles, flattened);
    * ``tri_rgba`` (3T,): the colour of each corner, ``lut[k]`` with
      ``k = int(clip((s_v / strain_color_max * 0.5 + 0.5) * (L - 1), 0, L - 1))`` (L = len(lut); each RGBA is
      one complex128, 16 bytes), so -max is the table's first colour, 0 its middle, +max its last;
    * ``wire_points`` (2E, 3): ``(q[v], 0)`` for each end of ``edge_flat``, when ``wireframe``.

    Bit for bit the NumPy gathers the encoder used before (twin: ``test/naive.py``); compiled ``nogil``, so the
    marker thread holds the GIL only to copy the bytes out. ``strain`` must be finite (the node checks ``q``).
    """
    top = lut.shape[0] - 1
    for k in range(tri_flat.shape[0]):
        v = tri_flat[k]
        tri_points[k, 0] = q[v, 0]
        tri_points[k, 1] = q[v, 1]
        tri_points[k, 2] = 0.0
        c = ((strain[v] / strain_color_max) * 0.5 + 0.5) * top
        c = min(max(c, 0.0), float(top))
        tri_rgba[k] = lut[int(c)]
    if wireframe:
        for k in range(edge_flat.shape[0]):
            v = edge_flat[k]
            wire_points[k, 0] = q[v, 0]
            wire_points[k, 1] = q[v, 1]
            wire_points[k, 2] = 0.0


def vertex_strain(model: Model, x: np.ndarray, absolute: bool = False) -> np.ndarray:
    """Mean signed strain of the edges at each vertex, shape (N,), float64 (see :class:`VertexStrain`)."""
    return VertexStrain.of(model)(x, absolute=absolute)


__all__ = ["edge_strain", "VertexStrain", "vertex_strain", "vertex_strain_kernel", "strain_mesh_arrays"]
