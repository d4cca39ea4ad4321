"""The implicit Euler energy: per body, scene total, the method's K, rigid-motion invariance."""
from __future__ import annotations

import numpy as np
import pytest

from tissue_sim_ros.core.errors import InputError
from tissue_sim_ros.core.mesh import mesh_from_arrays, mesh_rectangle
from tissue_sim_ros.core.physics.energy import energy_terms
from tissue_sim_ros.core.physics.model import Model, SimParams
from tissue_sim_ros.core.sim.simulation import Simulation

import naive


def two_body_model(params: SimParams) -> Model:
    """Two separate strips side by side: bodies 0 and 1."""
    a = mesh_rectangle(0.2, 0.1, 0.05)
    b = mesh_rectangle(0.2, 0.1, 0.05, origin=(0.5, 0.0))
    v = np.vstack([a.vertices, b.vertices])
    t = np.vstack([a.triangles, b.triangles + len(a.vertices)])
    mesh = mesh_from_arrays(v, t)
    assert mesh.n_bodies == 2
    return Model.from_mesh(mesh, params, pinned=v[:, 1] <= 1e-9)


def deformed(model: Model, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    x = model.particle_q0 + rng.normal(0, 0.004, model.particle_q0.shape)
    return x, x + rng.normal(0, 0.002, x.shape)


@pytest.mark.parametrize("method", ["pbd", "xpbd"])
@pytest.mark.parametrize("area_mode", ["signed", "abs"])
def test_per_body_terms_match_reference_and_sum_to_scene_total(method: str, area_mode: str) -> None:
    params = SimParams(method=method, area_mode=area_mode)
    model = two_body_model(params)
    x, x_pred = deformed(model)
    e = energy_terms(model, x, x_pred)
    # the K of the method: the paper's coefficients for pbd, the physical stiffness for xpbd
    k_s, k_a = (0.15, 1.0) if method == "pbd" else (params.stiffness_spring, params.stiffness_area)
    ref = naive.energy_terms(x, x_pred, model.particle_mass, model.particle_body, model.edge_indices,
                             model.edge_rest_length, model.edge_body, model.tri_indices, model.tri_rest_area,
                             model.tri_body, k_s, k_a, params.dt, area_mode == "signed", 2)
    for got, want in zip((e.inertial, e.spring, e.area), ref):
        np.testing.assert_allclose(got, want, rtol=1e-12)
    assert e.inertial.shape == (2,) and (e.total > 0).all()
    assert e.scene_total == pytest.approx(sum(float(t.sum()) for t in ref), rel=1e-12)
    assert e.scene_total == pytest.approx(float(e.total.sum()), rel=1e-15)


@pytest.mark.parametrize("angle", [0.3, np.pi / 2, 2.5])
def test_energy_is_invariant_under_rigid_motion(angle: float) -> None:
    """Rotating and translating x and x* together changes no term (the spring term uses |x_a - x_b|, not rest vectors)."""
    model = two_body_model(SimParams(method="xpbd"))
    x, x_pred = deformed(model, seed=3)
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    shift = np.array([0.3, -1.2])
    e0 = energy_terms(model, x, x_pred)
    e1 = energy_terms(model, x @ rot.T + shift, x_pred @ rot.T + shift)
    for a, b in ((e0.inertial, e1.inertial), (e0.spring, e1.spring), (e0.area, e1.area)):
        np.testing.assert_allclose(b, a, rtol=1e-9)
    assert e0.spring.sum() > 0


def test_rest_shape_rotated_has_zero_potential_energy() -> None:
    """A rigidly rotated rest shape: spring and area terms are 0 (to round-off), whatever the angle."""
    model = two_body_model(SimParams(method="xpbd"))
    rot = np.array([[0.0, -1.0], [1.0, 0.0]])
    x = model.particle_q0 @ rot.T
    e = energy_terms(model, x, x)
    assert (e.inertial == 0).all()
    assert e.spring.max() < 1e-30 and e.area.max() < 1e-30


def test_simulation_report_energy_is_zero_for_free_fall() -> None:
    """No constraint active: x = x*, so every term is 0 in every step."""
    params = SimParams(k_spring=0.0, k_area=0.0)
    model = two_body_model(params)
    sim = Simulation(Model.from_mesh(model.mesh, params))
    report = sim.step()
    assert report.energy.scene_total == 0.0


def test_energy_terms_rejects_wrong_shapes() -> None:
    model = two_body_model(SimParams())
    with pytest.raises(InputError, match="x_pred"):
        energy_terms(model, model.particle_q0, np.zeros((3, 2)))
