"""Vertex strain (core/strain.py), the one definition points, markers, replay and pictures share."""
from __future__ import annotations

import math

import numpy as np

from tissue_sim_ros.core.mesh import mesh_rectangle
from tissue_sim_ros.core.model import Model, SimParams
from tissue_sim_ros.core.strain import VertexStrain, edge_strain, vertex_strain


def _loop(edges, l0, q, n, absolute=False):
    """Strain of a vertex = mean over its edges of |x_a - x_b| / l0 - 1 (0 for l0 = 0), by a plain loop."""
    sums, counts = np.zeros(n), np.zeros(n)
    for (a, b), rest in zip(edges, l0):
        e = math.dist(q[a], q[b]) / rest - 1.0 if rest > 0 else 0.0
        e = abs(e) if absolute else e
        sums[a] += e
        sums[b] += e
        counts[a] += 1
        counts[b] += 1
    return sums / np.maximum(counts, 1)


def test_vertex_strain_matches_a_plain_loop_signed_and_absolute() -> None:
    model = Model.from_mesh(mesh_rectangle(0.3, 0.2, 0.05), SimParams())
    rng = np.random.default_rng(3)
    for scale in (0.0, 1e-3, 1e-2):
        q = model.particle_q0 + rng.normal(scale=scale, size=model.particle_q0.shape)
        for absolute in (False, True):
            expected = _loop(model.edge_indices, model.edge_rest_length, q, model.n_particles, absolute)
            np.testing.assert_allclose(vertex_strain(model, q, absolute=absolute), expected, rtol=1e-12, atol=1e-15)
    # compression is negative: shrink everything by 10 % and every vertex reads -0.1
    q = 0.9 * model.particle_q0
    np.testing.assert_allclose(vertex_strain(model, q), -0.1, rtol=1e-12)
    np.testing.assert_allclose(vertex_strain(model, q, absolute=True), 0.1, rtol=1e-12)
    np.testing.assert_allclose(VertexStrain.of(model).edges(q), edge_strain(model, q), rtol=1e-12, atol=1e-15)


def test_degenerate_edges() -> None:
    """A zero-rest-length edge counts as strain 0; an isolated vertex reads 0."""
    edges = np.array([[0, 1], [1, 2]])
    l0 = np.array([1.0, 0.0])
    q = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 0.5], [9.0, 9.0]])
    op = VertexStrain(edges, l0, 4)
    np.testing.assert_allclose(op(q), _loop(edges, l0, q, 4))
    np.testing.assert_array_equal(op(q), [1.0, 0.5, 0.0, 0.0])
