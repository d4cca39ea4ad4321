"""Static settle (``settle: static``, core/physics/statics.py): the element Hessian kernel against its NumPy twin, the
settled strip against the scikit-fem reference and against a long dynamic run to rest, and the parameter."""
from __future__ import annotations

import numpy as np
import pytest
from test_material import random_elements

from tissue_sim_ros.bench import fem_reference as fem
from tissue_sim_ros.bench import refinement as rf
from tissue_sim_ros.cli import main
from tissue_sim_ros.core.config import resolve_config
from tissue_sim_ros.core.errors import InputError
from tissue_sim_ros.core.mesh import mesh_rectangle
from tissue_sim_ros.core.physics import material
from tissue_sim_ros.core.sim.simulation import Simulation

import naive

E, NU, THICK = 50e3, 0.45, 0.002


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_element_hessians_match_naive_and_the_forces(seed: int) -> None:
    scene = random_elements(seed)  # triangle 0 has zero rest area, 1 is inverted, 3 collapsed to a point
    q0, x, tris = scene["q0"], scene["x"], scene["tris"]
    elastic = material.elastic_table(q0, tris, E, NU, THICK)
    out = np.empty((len(tris), 6, 6))
    material.element_hessians(x, tris, elastic, out)
    assert not out[0].any(), "a zero-area rest triangle has no element"
    for t in range(1, len(tris)):
        want = naive.element_hessian(x, q0, tris[t], E, NU, THICK)
        np.testing.assert_allclose(out[t], want, rtol=1e-10, atol=1e-10 * np.abs(want).max())
        assert np.allclose(out[t], out[t].T, rtol=0, atol=1e-12 * np.abs(want).max())
    # and it is the derivative of the kernel's forces (central differences, O(eps^2) error)
    eps = 1e-7
    for t in (1, 3):
        one = tris[t:t + 1]
        fd = np.empty((6, 6))
        for k in range(6):
            dx = np.zeros_like(x)
            dx[one[0, k // 2], k % 2] = eps
            fp, fm = np.zeros_like(x), np.zeros_like(x)
            material.elastic_forces(x + dx, one, elastic[t:t + 1], fp)
            material.elastic_forces(x - dx, one, elastic[t:t + 1], fm)
            fd[:, k] = -(fp - fm)[one[0]].ravel() / (2 * eps)
        np.testing.assert_allclose(out[t], fd, rtol=1e-5, atol=1e-6 * np.abs(out[t]).max())


def strip(spacing: float, **overrides) -> Simulation:
    return Simulation.from_config(rf._config("hanging_strip", 0.002, overrides, 30.0),
                                  mesh=mesh_rectangle(rf.WIDTH, rf.HEIGHT, spacing))


def test_settle_converges_to_the_fem_under_refinement() -> None:
    # The static problem the FEM solves (linear plane stress, P2): grad Pi = 0 with the same load. The membrane's
    # P1 elements are stiffer than P2 (error O(h^2) in the sag), so the error falls with the spacing: measured
    # -2.5 / -0.75 / -0.16% at 10 / 5 / 2.5 mm; the finest within 0.5% (the 2% at the finest mesh).
    ref = fem.hanging_strip()
    errors = []
    for h in (0.01, 0.005, 0.0025):
        sim = strip(h)
        info = sim.settle()
        assert info.converged and info.relative_residual <= 1e-10
        errors.append(rf.strip_errors(sim, ref)["err_mean_sag"])
    assert abs(errors[0]) > abs(errors[1]) > abs(errors[2])
    assert abs(errors[2]) < 0.005


def test_settle_is_the_rest_of_a_long_dynamic_run() -> None:
    # the same discrete energy: a dynamic run damped to rest (every particle slower than 1e-7 m/s) ends where
    # the static solve does, up to the XPBD iterations' residual (measured 1e-3 of the sag)
    dynamic = strip(0.01)
    run = rf.run_to_rest(dynamic, None, 1e-7, 20000)
    assert run.at_rest
    static = strip(0.01)
    static.settle()
    sag = np.abs(static.state.particle_q - static.model.particle_q0).max()
    assert np.abs(dynamic.state.particle_q - static.state.particle_q).max() < 5e-3 * sag


def test_settled_state_is_at_rest_and_reset_returns_to_it() -> None:
    sim = strip(0.005, settle="static")
    assert sim.settle_info is not None and sim.settle_info.converged
    x_settled = sim.state.particle_q.copy()
    assert not sim.state.particle_qd.any()
    sag = np.abs(x_settled - sim.model.particle_q0).max()
    assert sag > 1e-4  # it did sag
    # the residual: every free particle's weight balanced by the elastic forces
    f = material.internal_forces(sim.model, x_settled)
    f[:, 1] += sim.model.particle_mass * sim.params.gravity
    free = sim.model.particle_inv_mass > 0
    assert np.abs(f[free]).max() <= 1e-9 * (sim.model.particle_mass * abs(sim.params.gravity)).max()
    # a step from it stays there (the solver's own residual moves it a tiny fraction of the sag)
    sim.step()
    assert np.abs(sim.state.particle_q - x_settled).max() < 1e-2 * sag
    sim.reset()
    assert sim.step_count == 0 and np.array_equal(sim.state.particle_q, x_settled)
    assert not sim.state.particle_qd.any()
    # settle none (the default): the rest shape
    plain = strip(0.005)
    assert plain.settle_info is None and np.array_equal(plain.state.particle_q, plain.model.particle_q0)


def test_settle_parameter_through_the_front_door() -> None:
    cfg = rf._config("hanging_strip", 0.002, {"settle": "static"}, 30.0)
    assert cfg.sim.settle == "static"
    with pytest.raises(InputError, match=r"parameter settle='dynamic': expected one of none, static"):
        rf._config("hanging_strip", 0.002, {"settle": "dynamic"}, 30.0)
    with pytest.raises(InputError, match=r"settle='static'.*material neo_hookean"):
        resolve_config({"settle": "static"}, source="--set")
    sim = strip(0.01)
    with pytest.raises(InputError, match="settle is read-only"):
        sim.retune(cfg)
    plain = Simulation.from_config(resolve_config({}, source="--set"), mesh=mesh_rectangle(0.1, 0.04, 0.01))
    with pytest.raises(InputError, match="expected material neo_hookean"):
        plain.settle()


def test_cli_refuses_a_bad_settle(capsys) -> None:
    assert main(["config", "--set", "settle=maybe"]) == 2
    err = capsys.readouterr().err
    assert "settle='maybe'" in err and "Traceback" not in err
