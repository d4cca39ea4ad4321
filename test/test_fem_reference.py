"""The static plane-stress FEM reference (bench/fem_reference.py) against closed forms.

The reference is what the simulator's material model is verified against, so it
is itself checked here on problems whose exact solution is a polynomial of
degree <= 2: P2 elements reproduce those to round-off, so the tolerances are
round-off (1e-9 relative), not a discretisation error. On the real problems
(no closed form) its refinement must converge: successive changes fall.
"""
from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from tissue_sim_ros.bench import fem_reference as fem
from tissue_sim_ros.core.errors import InputError

RTOL_EXACT = 1e-9  # round-off: the exact fields lie in the P2 space


def test_plane_stress_lame_parameters():
    # lambda = E nu / (1 - nu^2), mu = E / (2 (1 + nu)); E = 1000, nu = 0.25: 1000*0.25/0.9375, 400
    lam, mu = fem.plane_stress_lame(1000.0, 0.25)
    assert lam == pytest.approx(266.6666666666667, rel=1e-14)
    assert mu == pytest.approx(400.0, rel=1e-14)


def test_uniaxial_compression_is_uniform_stress():
    # bottom held vertically only, top pressed by d: sigma_yy = -E d / H uniform, sigma_xx = 0,
    # force = E W h d / H, u_y = -d (y - y0) / H, u_x = nu d (x - x0) / H (plane stress lateral bulge)
    E, nu, W, H, h, d = 20e3, 0.3, 0.05, 0.02, 2e-3, 1e-4
    x0, y0 = 0.01, -0.03
    sol = fem.flat_punch(width=W, height=H, young_modulus=E, poisson_ratio=nu, thickness=h, depth=d,
                         origin=(x0, y0), bottom="slip", rtol=1e-3, max_levels=2)
    assert sol.force == pytest.approx(E * W * h * d / H, rel=RTOL_EXACT)
    rng = np.random.default_rng(0)
    pts = np.column_stack([x0 + W * rng.random(20), y0 + H * rng.random(20)])
    pts = np.vstack([pts, [[x0, y0], [x0 + W, y0 + H]]])  # the corners: on the boundary
    u = sol.displacement(pts)
    np.testing.assert_allclose(u[:, 1], -d * (pts[:, 1] - y0) / H, rtol=0, atol=RTOL_EXACT * d)
    np.testing.assert_allclose(u[:, 0], nu * d * (pts[:, 0] - x0) / H, rtol=0, atol=RTOL_EXACT * d)


def test_hanging_bar_without_poisson_effect():
    # nu = 0, top clamped: sigma_yy = rho g (H - s), u_x = 0 and u_y(s) = -rho g (H s - s^2/2) / E with s the
    # depth below the top edge; mean sag = rho g H^2 / (3E), max sag (bottom) = rho g H^2 / (2E)
    E, W, H, rho, g = 30e3, 0.03, 0.06, 1050.0, 9.81
    sol = fem.hanging_strip(width=W, height=H, young_modulus=E, poisson_ratio=0.0, density=rho, gravity=g,
                            rtol=1.0, max_levels=2)
    assert sol.mean_sag == pytest.approx(rho * g * H ** 2 / (3 * E), rel=RTOL_EXACT)
    assert sol.max_sag == pytest.approx(rho * g * H ** 2 / (2 * E), rel=RTOL_EXACT)
    rng = np.random.default_rng(1)
    pts = np.column_stack([W * rng.random(30), H * rng.random(30)])
    s = H - pts[:, 1]
    u = sol.displacement(pts)
    scale = rho * g * H ** 2 / E
    np.testing.assert_allclose(u[:, 1], -rho * g * (H * s - s ** 2 / 2) / E, rtol=0, atol=RTOL_EXACT * scale)
    np.testing.assert_allclose(u[:, 0], 0.0, rtol=0, atol=RTOL_EXACT * scale)


@pytest.mark.parametrize("problem", ["hanging_strip", "flat_punch"])
def test_refinement_converges(problem):
    # no closed form (nu = 0.45, clamped corners): each halving of the element size changes the answer
    # less than the previous one did, and the loop stops below its tolerance
    sol = getattr(fem, problem)()
    keys = ("mean_sag", "max_sag") if problem == "hanging_strip" else ("force",)
    for q in keys:
        vals = [lv.values[q] for lv in sol.levels]
        changes = np.abs(np.diff(vals))
        assert len(changes) >= 3
        assert np.all(changes[1:] < changes[:-1]), (q, vals)
    assert sol.rel_change < fem.DEFAULT_RTOL
    assert 0 < sol.rel_error < 2 * fem.DEFAULT_RTOL


def test_clamping_and_poisson_stiffen_the_punch():
    # the clamped bottom stops the lateral bulge a nearly incompressible sheet needs: the force lies above
    # the free-bulge value E W h d / H, and with nu = 0 there is no bulge to stop (equal to it)
    base = dict(width=0.10, height=0.04, young_modulus=50e3, thickness=1e-3, depth=2e-4)
    free = 50e3 * 0.10 * 1e-3 * 2e-4 / 0.04
    assert fem.flat_punch(poisson_ratio=0.45, **base).force > 1.03 * free
    assert fem.flat_punch(poisson_ratio=0.0, rtol=1e-3, max_levels=3, **base).force == pytest.approx(free, rel=1e-9)


def test_scaling_laws():
    # linear elasticity: sag ~ rho g / E and independent of the thickness; force ~ E h d
    a = fem.hanging_strip(rtol=1.0, max_levels=2)
    b = fem.hanging_strip(rtol=1.0, max_levels=2, young_modulus=100e3, thickness=3e-3, density=1500.0)
    assert b.mean_sag == pytest.approx(a.mean_sag * 1.5 / 2.0, rel=1e-10)
    p = fem.flat_punch(rtol=1.0, max_levels=2)
    q = fem.flat_punch(rtol=1.0, max_levels=2, young_modulus=5e3, thickness=2e-3, depth=1e-4)
    assert q.force == pytest.approx(p.force * 0.1 * 2.0 * 0.5, rel=1e-10)


@pytest.mark.parametrize("kwargs", [
    dict(young_modulus=0.0), dict(young_modulus=float("nan")), dict(poisson_ratio=0.5),
    dict(poisson_ratio=-0.1), dict(thickness=0.0), dict(width=-1.0),
])
def test_bad_input_names_the_value(kwargs):
    name = next(iter(kwargs))
    with pytest.raises(InputError, match=name):
        fem.hanging_strip(**kwargs)


def test_punch_depth_and_bottom_checked():
    with pytest.raises(InputError, match="depth"):
        fem.flat_punch(depth=0.05)
    with pytest.raises(InputError, match="bottom"):
        fem.flat_punch(bottom="glued")


def test_independent_of_the_simulator():
    # the reference must not share code with what it verifies: from the package it imports only the error type
    src = Path(fem.__file__).read_text()
    imported = set()
    for node in ast.walk(ast.parse(src)):
        if isinstance(node, ast.ImportFrom) and node.level > 0:
            imported.add(node.module)
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("tissue_sim_ros"):
            imported.add(node.module)
    assert imported <= {"core.errors"}, imported
