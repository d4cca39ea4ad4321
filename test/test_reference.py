"""The exact Newton reference for one step (bench/reference.py).

It is the yardstick of the accuracy benchmark, so it is checked against
things known independently of it: finite differences of its own energy, a
spring with a closed-form minimiser, free fall, and fixed particles.
"""
from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest

from tissue_sim_ros.bench.reference import ImplicitEulerEnergy, predict, reference_step, relative_error
from tissue_sim_ros.core.contact.collision import Contacts
from tissue_sim_ros.core.mesh import TissueMesh, mesh_rectangle
from tissue_sim_ros.core.physics.model import Model, SimParams, State


def _strip_model(area_mode: str = "signed", spacing: float = 0.05, **kw) -> Model:
    params = SimParams(method="xpbd", area_mode=area_mode, boundary_y_top=0.19, boundary_y_bottom=0.01, **kw)
    return Model.from_mesh(mesh_rectangle(0.4, 0.2, spacing), params)


@pytest.mark.parametrize("area_mode", ["signed", "abs"])
def test_gradient_and_hessian_match_finite_differences(area_mode: str) -> None:
    model = _strip_model(area_mode, spacing=0.1)
    rng = np.random.default_rng(1)
    x = model.particle_q0 + rng.normal(0.0, 0.01, model.particle_q0.shape)
    energy = ImplicitEulerEnergy(model, model.particle_q0 + 0.003, 0.01)
    g = energy.gradient(x).ravel()
    h = energy.hessian(x).toarray()
    eps = 1e-6
    g_fd = np.zeros_like(g)
    h_fd = np.zeros_like(h)
    for i in range(g.size):
        xp, xm = x.copy(), x.copy()
        xp.ravel()[i] += eps
        xm.ravel()[i] -= eps
        g_fd[i] = (energy.value(xp) - energy.value(xm)) / (2 * eps)
        h_fd[:, i] = (energy.gradient(xp).ravel() - energy.gradient(xm).ravel()) / (2 * eps)
    # central differences: error O(eps^2) relative to the curvature scale
    assert np.abs(g - g_fd).max() <= 1e-6 * np.abs(g).max()
    assert np.abs(h - h_fd).max() <= 1e-6 * np.abs(h).max()
    np.testing.assert_allclose(h, h.T, atol=1e-12 * np.abs(h).max())


def test_projected_hessian_is_positive_definite_where_exact_is_not() -> None:
    model = _strip_model(spacing=0.1, stiffness_spring=1e4)
    # compress the strip to 60%: springs in compression make the exact Hessian indefinite
    x = model.particle_q0 * np.array([0.6, 1.0])
    energy = ImplicitEulerEnergy(model, x, 0.01)
    assert np.linalg.eigvalsh(energy.hessian(x).toarray()).min() < 0.0
    # projection keeps at least the mass matrix: eigenvalues >= m
    assert np.linalg.eigvalsh(energy.hessian(x, project=True).toarray()).min() >= model.params.mass * (1 - 1e-9)


def test_hanging_spring_matches_closed_form() -> None:
    # particle 0 pinned at the origin, particle 1 hanging below it on one spring at rest length
    l0, m, k, dt, g = 0.1, 1e-4, 100.0, 0.01, -9.8
    mesh = TissueMesh(vertices=np.array([[0.0, 0.0], [0.0, -l0]]), triangles=np.zeros((0, 3), np.int32),
                      edges=np.array([[0, 1]], np.int32), boundary=np.ones(2, bool), body=np.zeros(2, np.int32))
    model = Model.from_mesh(mesh, SimParams(method="xpbd", mass=m, stiffness_spring=k), pinned=[0])
    ref = reference_step(model, model.state())
    # minimise 1/2 m (s - s*)^2 + dt^2 k/2 (s - l0)^2 over the length s:  s = (m s* + dt^2 k l0) / (m + dt^2 k)
    s_star = l0 - dt * dt * g
    s = (m * s_star + dt * dt * k * l0) / (m + dt * dt * k)
    np.testing.assert_allclose(ref.particle_q[1], [0.0, -s], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(ref.particle_q[0], [0.0, 0.0])
    np.testing.assert_allclose(ref.particle_qd[1], [0.0, (l0 - s) / dt], atol=1e-12)
    assert ref.converged


def test_free_fall_without_stiffness_is_the_prediction() -> None:
    model = Model.from_mesh(mesh_rectangle(0.2, 0.1, 0.05),
                            SimParams(method="xpbd", stiffness_spring=0.0, stiffness_area=0.0))
    state = model.state()
    state.particle_qd[:] = (0.3, -0.1)
    dt = 0.02
    ref = reference_step(model, state, dt=dt)
    # x(t+dt) = x + v dt + g dt^2 (symplectic Euler of Algorithm 1)
    expected = model.particle_q0 + dt * np.array([0.3, -0.1]) + np.array([0.0, -9.8 * dt * dt])
    np.testing.assert_allclose(ref.particle_q, expected, atol=1e-15)


def test_pinned_and_held_particles_stay_at_their_prediction() -> None:
    model = _strip_model()
    state = model.state()
    contacts = Contacts.empty(model.n_bodies)
    held = np.array([10, 11], dtype=np.int32)
    contacts.held_idx = held
    contacts.held_dx = np.array([[0.004, 0.0], [0.003, -0.001]])
    ref = reference_step(model, state, contacts)
    pinned = model.particle_pinned
    assert pinned.any()
    np.testing.assert_array_equal(ref.particle_q[pinned], model.particle_q0[pinned])
    # the collision contract: held_dx is added to the prediction (x + dt v + dt^2 g) and the particle held there
    gravity_drop = np.array([0.0, model.params.gravity * model.params.dt ** 2])
    np.testing.assert_allclose(ref.particle_q[held], model.particle_q0[held] + gravity_drop + contacts.held_dx,
                               rtol=0, atol=1e-15)
    assert ref.converged and ref.relative_grad <= 1e-10
    # the rest of the tissue followed the held particles
    free = ~ref.fixed
    assert np.abs(ref.particle_q[free, 0] - model.particle_q0[free, 0]).max() > 1e-4


def test_minimiser_is_a_stationary_point_below_the_energy_of_perturbations() -> None:
    model = _strip_model(stiffness_spring=1e4)
    state = model.state()
    state.particle_qd[:, 0] = np.where(model.particle_pinned, 0.0, 0.5)  # a hard step: large displacement
    ref = reference_step(model, state)
    assert ref.converged
    energy = ImplicitEulerEnergy(model, ref.x_pred, model.params.dt)
    rng = np.random.default_rng(2)
    for _ in range(5):
        dx = rng.normal(0.0, 1e-5, ref.particle_q.shape)
        dx[ref.fixed] = 0.0
        assert energy.value(ref.particle_q + dx) > ref.energy


def test_recovers_an_inverted_triangle_with_the_signed_area() -> None:
    model = _strip_model(spacing=0.1)
    state = model.state()
    t = model.tri_indices[0]
    free = [i for i in t if not model.particle_pinned[i]]
    assert free
    q = state.particle_q
    # push a free corner through the opposite edge: the triangle is inverted at the start
    i = free[0]
    others = [j for j in t if j != i]
    mid = 0.5 * (q[others[0]] + q[others[1]])
    q[i] = mid + 0.5 * (mid - q[i])
    ref = reference_step(model, State(q.copy(), np.zeros_like(q)))
    x = ref.particle_q
    a, b, c = x[t[0]], x[t[1]], x[t[2]]
    area = 0.5 * ((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))
    assert ref.converged
    assert area > 0.0


def test_prediction_follows_algorithm_1() -> None:
    model = _strip_model(damping=2.0)
    state = model.state()
    state.particle_qd[:] = (1.0, 0.0)
    x_pred, fixed = predict(model, state, None, 0.01)
    free = ~model.particle_pinned
    # x* = x + dt v (1 - damping dt) + dt^2 g for free particles; pinned stay
    np.testing.assert_allclose(x_pred[free], model.particle_q0[free] + [0.01 * 0.98, -9.8e-4], atol=1e-15)
    np.testing.assert_array_equal(x_pred[~free], model.particle_q0[~free])
    np.testing.assert_array_equal(fixed, model.particle_pinned)


def test_relative_error() -> None:
    x0 = np.zeros((2, 2))
    ref = np.array([[3.0, 0.0], [0.0, 4.0]])
    assert relative_error(ref, ref, x0) == 0.0
    assert math.isclose(relative_error(ref + [0.5, 0.0], ref, x0), math.sqrt(0.5) / 5.0)


def test_reference_is_independent_of_the_kernels() -> None:
    # the reference checks the numba kernels, so it must not use them
    source = Path(__file__).resolve().parents[1] / "tissue_sim_ros" / "bench" / "reference.py"
    imported = set()
    for node in ast.walk(ast.parse(source.read_text())):
        if isinstance(node, ast.Import):
            imported.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            imported.add(node.module or "")
    assert not any("kernels" in m or "solvers" in m or "numba" in m for m in imported), imported
