"""Vertex strain (core/physics/strain.py), the one definition points, markers, replay and pictures share."""
from __future__ import annotations

import math

import numpy as np

from tissue_sim_ros.core.mesh import mesh_rectangle
from tissue_sim_ros.core.physics.model import Model, SimParams
from tissue_sim_ros.core.physics.strain import VertexStrain, edge_strain, vertex_strain


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


def test_compiled_strain_kernels_match_their_numpy_twins_bit_for_bit() -> None:
    """vertex_strain_kernel and strain_mesh_arrays (nogil, for the node's two threads) against test/naive.py."""
    from tissue_sim_ros.core.physics.strain import strain_mesh_arrays, vertex_strain_kernel
    from tissue_sim_ros.ros.messages import strain_colormap

    import naive

    model = Model.from_mesh(mesh_rectangle(0.3, 0.2, 0.03), SimParams())
    op = VertexStrain.of(model)
    rng = np.random.default_rng(11)
    q = model.particle_q0 + rng.normal(scale=3e-3, size=model.particle_q0.shape)
    for absolute in (False, True):
        got, want = np.empty(model.n_particles), np.empty(model.n_particles)
        vertex_strain_kernel(q, op._a, op._b, op._inv_l0, op._one, op._inv_count, absolute, got)
        naive.vertex_strain_kernel(q, op._a, op._b, op._inv_l0, op._one, op._inv_count, absolute, want)
        np.testing.assert_array_equal(got, want)
    strain = op(q)
    strain[:3] = [-5.0, 5.0, 0.0]  # past both ends of the table, and rest
    lut = np.ascontiguousarray(strain_colormap()).view(np.complex128).ravel()
    tri_flat = np.ascontiguousarray(model.tri_indices.ravel().astype(np.int64))
    edge_flat = np.ascontiguousarray(model.edge_indices.ravel().astype(np.int64))
    outs = []
    for f in (strain_mesh_arrays, naive.strain_mesh_arrays):
        tri, rgba = np.full((len(tri_flat), 3), np.nan), np.zeros(len(tri_flat), dtype=np.complex128)
        wire = np.full((len(edge_flat), 3), np.nan)
        f(q, tri_flat, edge_flat, strain, 0.2, lut, tri, rgba, wire, True)
        outs.append((tri, rgba, wire))
    for got, want in zip(*outs):
        np.testing.assert_array_equal(got, want)
    rgba = outs[0][1].view(np.float32).reshape(-1, 4)
    first = {v: k for k, v in reversed(list(enumerate(tri_flat)))}
    np.testing.assert_array_equal(rgba[first[0]], strain_colormap()[0])  # -5: the compressed pole
    np.testing.assert_array_equal(rgba[first[1]], strain_colormap()[-1])  # +5: the stretched pole
    assert np.all(outs[0][0][:, 2] == 0.0) and np.all(outs[0][2][:, 2] == 0.0)
