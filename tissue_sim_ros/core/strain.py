"""Strain of the deformed mesh, for colouring pictures and markers."""
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


def vertex_strain(model: Model, x: np.ndarray) -> np.ndarray:
    """Mean absolute strain of the edges at each vertex, shape (N,), float64."""
    s = np.abs(edge_strain(model, x))
    e = model.edge_indices
    n = model.n_particles
    total = np.bincount(e[:, 0], weights=s, minlength=n) + np.bincount(e[:, 1], weights=s, minlength=n)
    count = np.bincount(e[:, 0], minlength=n) + np.bincount(e[:, 1], minlength=n)
    return total / np.maximum(count, 1)
