"""Each numba kernel against its NumPy reference in ``naive.py``, on random and degenerate input.

Degenerate cases built into every fixture: a zero-length edge (two particles
at one point), a collinear triangle, pinned particles (inverse mass 0), and a
single-triangle mesh. Comparisons are to 1e-12 relative: the kernels and
references do the same arithmetic in a different order.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from tissue_sim_ros.core.physics import kernels, sweeps
from tissue_sim_ros.core.physics.solvers import colour_constraints

import naive

RTOL = 1e-12


def random_scene(seed: int, n: int = 24, n_edges: int = 40, n_tris: int = 20) -> dict:
    """Random particles and constraints with the degenerate cases appended."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-0.1, 0.1, (n, 2))
    x[1] = x[0]                      # zero-length edge 0-1
    x[4] = 0.5 * (x[2] + x[3])       # collinear triangle 2-3-4
    inv_mass = rng.uniform(0.5e4, 2e4, n)
    inv_mass[[5, 6, 7]] = 0.0        # pinned; edge 5-6 has w = 0
    edges = rng.integers(0, n, (n_edges, 2))
    edges = edges[edges[:, 0] != edges[:, 1]]
    edges = np.vstack([[[0, 1], [5, 6], [2, 4]], edges]).astype(np.int32)
    tris = np.array([rng.choice(n, 3, replace=False) for _ in range(n_tris)])
    tris = np.vstack([[[2, 3, 4], [5, 6, 7], [0, 1, 8]], tris]).astype(np.int32)
    rest = rng.uniform(0.01, 0.05, len(edges))
    area0 = rng.uniform(-2e-3, 2e-3, len(tris))
    return dict(x=x, inv_mass=inv_mass, edges=edges, rest=rest, tris=tris, area0=area0, rng=rng)


def single_triangle() -> dict:
    x = np.array([[0.0, 0.0], [0.1, 0.0], [0.0, 0.1]])
    inv_mass = np.array([1e4, 1e4, 1e4])
    return dict(x=x + np.array([[0.01, -0.003], [0.0, 0.02], [-0.004, 0.0]]), inv_mass=inv_mass,
                edges=np.array([[0, 1], [1, 2], [0, 2]], np.int32), rest=np.array([0.1, 0.1 * math.sqrt(2), 0.1]),
                tris=np.array([[0, 1, 2]], np.int32), area0=np.array([0.005]), rng=np.random.default_rng(0))


SCENES = [pytest.param(lambda s=s: random_scene(s), id=f"random{s}") for s in (0, 1, 2)] + \
    [pytest.param(single_triangle, id="single_triangle")]
PARAMS = [(1.0, 0.0), (0.15, 0.0), (1.0, 1.0), (1.0, 1e-2)]  # (k, alpha): PBD, PBD soft, XPBD compliant, XPBD stiff


def close(a, b) -> None:
    np.testing.assert_allclose(a, b, rtol=RTOL, atol=1e-15)


@pytest.mark.parametrize("scene", SCENES)
def test_predict_and_hold(scene) -> None:
    s = scene()
    v = s["rng"].normal(0, 0.3, s["x"].shape)
    out = np.zeros_like(s["x"])
    kernels.predict(s["x"], v, s["inv_mass"], 0.01, -9.8, 0.9, out)
    close(out, naive.predict(s["x"], v, s["inv_mass"], 0.01, -9.8, 0.9))
    held = np.array([0, 2], np.int32) if len(s["x"]) < 6 else np.array([0, 5, 9], np.int32)  # 5 is pinned
    held_dx = s["rng"].normal(0, 0.01, (len(held), 2))
    w = np.zeros_like(s["inv_mass"])
    ref_x, ref_w = naive.hold_displaced(out, s["inv_mass"], held, held_dx, 0.5)
    kernels.hold_displaced(out, s["inv_mass"], held, held_dx, 0.5, w)
    close(out, ref_x)
    close(w, ref_w)


@pytest.mark.parametrize("scene", SCENES)
@pytest.mark.parametrize("k,alpha", PARAMS)
def test_solve_edges(scene, k: float, alpha: float) -> None:
    s = scene()
    lam0 = s["rng"].normal(0, 1e-3, len(s["edges"])) if alpha else np.zeros(len(s["edges"]))
    x, lam = s["x"].copy(), lam0.copy()
    sweeps.solve_edges(x, s["inv_mass"], s["edges"], s["rest"], k, alpha, lam)
    ref_x, ref_lam = naive.solve_edges(s["x"], s["inv_mass"], s["edges"], s["rest"], k, alpha, lam0)
    close(x, ref_x)
    close(lam, ref_lam)
    assert np.isfinite(x).all()


@pytest.mark.parametrize("scene", SCENES)
@pytest.mark.parametrize("k,alpha", PARAMS)
@pytest.mark.parametrize("signed", [True, False])
def test_solve_areas(scene, k: float, alpha: float, signed: bool) -> None:
    s = scene()
    lam0 = s["rng"].normal(0, 1e-3, len(s["tris"])) if alpha else np.zeros(len(s["tris"]))
    x, lam = s["x"].copy(), lam0.copy()
    sweeps.solve_areas(x, s["inv_mass"], s["tris"], s["area0"], k, alpha, lam, signed)
    ref_x, ref_lam = naive.solve_areas(s["x"], s["inv_mass"], s["tris"], s["area0"], k, alpha, lam0, signed)
    close(x, ref_x)
    close(lam, ref_lam)
    assert np.isfinite(x).all()


def test_degenerate_projections_move_nothing() -> None:
    """A zero-length edge and a zero-area (abs mode) triangle have no gradient: skipped, no NaN."""
    x = np.zeros((3, 2))
    w = np.ones(3)
    lam = np.zeros(3)
    sweeps.solve_edges(x, w, np.array([[0, 1], [1, 2], [0, 2]], np.int32), np.full(3, 0.1), 1.0, 0.0, lam)
    assert (x == 0).all() and (lam == 0).all()
    x = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])  # collinear, area 0
    sweeps.solve_areas(x, w, np.array([[0, 1, 2]], np.int32), np.array([0.5]), 1.0, 0.0, lam, False)
    assert (x[:, 1] == 0).all()
    # the signed form has a gradient on a collinear triangle and pushes it open
    sweeps.solve_areas(x, w, np.array([[0, 1, 2]], np.int32), np.array([0.5]), 1.0, 0.0, lam, True)
    assert np.isfinite(x).all() and abs(naive.area_value(x, 0, 1, 2) - 0.5) < 1e-12


@pytest.mark.parametrize("seed", [0, 1])
def test_coloured_parallel_equals_serial_in_colour_order(seed: int) -> None:
    s = random_scene(seed, n=60, n_edges=150, n_tris=60)
    order_e, off_e = colour_constraints(s["edges"], len(s["x"]))
    order_t, off_t = colour_constraints(s["tris"], len(s["x"]))
    e, r = np.ascontiguousarray(s["edges"][order_e]), np.ascontiguousarray(s["rest"][order_e])
    t, a0 = np.ascontiguousarray(s["tris"][order_t]), np.ascontiguousarray(s["area0"][order_t])
    x_par, lam_par = s["x"].copy(), np.zeros(len(e))
    sweeps.solve_edges_coloured(x_par, s["inv_mass"], e, r, 1.0, 1e-2, lam_par, off_e)
    ref_x, ref_lam = naive.solve_edges(s["x"], s["inv_mass"], e, r, 1.0, 1e-2, np.zeros(len(e)))
    close(x_par, ref_x)
    close(lam_par, ref_lam)
    lam_t = np.zeros(len(t))
    sweeps.solve_areas_coloured(x_par, s["inv_mass"], t, a0, 1.0, 1e-2, lam_t, True, off_t)
    ref_x, ref_lam = naive.solve_areas(ref_x, s["inv_mass"], t, a0, 1.0, 1e-2, np.zeros(len(t)), True)
    close(x_par, ref_x)
    close(lam_t, ref_lam)


@pytest.mark.parametrize("scene", SCENES)
@pytest.mark.parametrize("signed", [True, False])
def test_jacobi_passes_and_apply(scene, signed: bool) -> None:
    s = scene()
    omega_e = s["rng"].uniform(0.2, 1.0, len(s["edges"]))
    omega_t = s["rng"].uniform(0.2, 1.0, len(s["tris"]))
    lam_e, lam_t = np.zeros(len(s["edges"])), np.zeros(len(s["tris"]))
    acc = np.zeros_like(s["x"])
    sweeps.jacobi_edges(s["x"], s["inv_mass"], s["edges"], s["rest"], 1.0, 1e-2, lam_e, omega_e, acc)
    sweeps.jacobi_areas(s["x"], s["inv_mass"], s["tris"], s["area0"], 1.0, 1e-2, lam_t, signed, omega_t, acc)
    dx_e, ref_lam_e = naive.jacobi_edges(s["x"], s["inv_mass"], s["edges"], s["rest"], 1.0, 1e-2,
                                         np.zeros(len(s["edges"])), omega_e)
    dx_t, ref_lam_t = naive.jacobi_areas(s["x"], s["inv_mass"], s["tris"], s["area0"], 1.0, 1e-2,
                                         np.zeros(len(s["tris"])), signed, omega_t)
    close(acc, dx_e + dx_t)
    close(lam_e, ref_lam_e)
    close(lam_t, ref_lam_t)
    scale = s["rng"].uniform(0.1, 1.0, len(s["x"]))
    x = s["x"].copy()
    sweeps.jacobi_apply(x, acc, scale)
    close(x, s["x"] + scale[:, None] * (dx_e + dx_t))
    assert (acc == 0).all()


@pytest.mark.parametrize("scene", SCENES)
@pytest.mark.parametrize("signed", [True, False])
@pytest.mark.parametrize("alpha", [0.0, 1e-2, 10.0])
def test_jacobi_relaxation(scene, signed: bool, alpha: float) -> None:
    s = scene()
    om_e, om_t = np.zeros(len(s["edges"])), np.zeros(len(s["tris"]))
    sweeps.jacobi_relaxation(s["x"], s["inv_mass"], s["edges"], alpha, s["tris"], 10 * alpha, signed, 1.8,
                              np.zeros(len(s["x"])), om_e, om_t)
    ref_e, ref_t = naive.jacobi_relaxation(s["x"], s["inv_mass"], s["edges"], alpha, s["tris"], 10 * alpha, signed, 1.8)
    close(om_e, ref_e)
    close(om_t, ref_t)
    assert (om_e <= 1.8 + 1e-12).all() and (om_t <= 1.8 + 1e-12).all()


def test_jacobi_relaxation_bounds_the_spectrum() -> None:
    """The Gershgorin omega keeps the linearised Jacobi iteration contractive: rho(I - Omega D^-1 A) < 1.

    A = J W J^T + diag(alpha) assembled densely from the reference gradients on a
    small random scene with stiff constraints (alpha ~ 0), where a uniform omega
    of 1 is not contractive.
    """
    s = random_scene(3, n=12, n_edges=20, n_tris=8)
    w = np.where(s["inv_mass"] > 0, 1e4, 0.0)
    x = s["x"]
    x[1] += 0.01  # no zero-length edge here: every row of J is a real gradient
    x[4] += 0.01
    alpha_e, alpha_t = 1e-3, 1e-1
    rows, alphas = [], []
    for i, j in s["edges"]:
        g = np.zeros_like(x)
        d = (x[i] - x[j]) / np.linalg.norm(x[i] - x[j])
        g[i], g[j] = d, -d
        rows.append(g.ravel())
        alphas.append(alpha_e)
    for a, b, c in s["tris"]:
        g = np.zeros_like(x)
        rot = np.array([[0.0, 1.0], [-1.0, 0.0]])
        g[b], g[c] = 0.5 * rot @ (x[c] - x[a]), -0.5 * rot @ (x[b] - x[a])
        g[a] = -(g[b] + g[c])
        rows.append(g.ravel())
        alphas.append(alpha_t)
    J = np.array(rows)
    A = J @ np.diag(np.repeat(w, 2)) @ J.T + np.diag(alphas)
    D = np.diag(A)
    om_e, om_t = np.zeros(len(s["edges"])), np.zeros(len(s["tris"]))
    sweeps.jacobi_relaxation(x, w, s["edges"], alpha_e, s["tris"], alpha_t, True, 1.8, np.zeros(len(x)), om_e, om_t)
    omega = np.concatenate([om_e, om_t])
    rho = max(abs(np.linalg.eigvals(np.eye(len(D)) - (omega / D)[:, None] * A)))
    rho_uniform = max(abs(np.linalg.eigvals(np.eye(len(D)) - (1.0 / D)[:, None] * A)))
    assert rho < 1.0
    assert rho_uniform > 1.0


def test_velocity_and_boundary_lines() -> None:
    rng = np.random.default_rng(4)
    x_start = rng.uniform(0, 1, (50, 2))
    x = x_start + rng.normal(0, 0.1, (50, 2))
    v = np.zeros_like(x)
    kernels.update_velocity(x, x_start, 0.01, v)
    close(v, naive.update_velocity(x, x_start, 0.01))
    inv_mass = np.where(rng.uniform(size=50) < 0.2, 0.0, 1e4)
    for top, bottom in ((0.9, 0.1), (math.nan, 0.2), (0.8, math.nan), (math.nan, math.nan)):
        xk, vk = x.copy(), v.copy()
        n_held = kernels.apply_boundary_lines(xk, vk, inv_mass, top, bottom)
        ref_x, ref_v, ref_n = naive.apply_boundary_lines(x, v, inv_mass, top, bottom)
        close(xk, ref_x)
        close(vk, ref_v)
        assert n_held == ref_n


@pytest.mark.parametrize("scene", SCENES)
@pytest.mark.parametrize("signed", [True, False])
def test_energy_and_residual(scene, signed: bool) -> None:
    s = scene()
    n = len(s["x"])
    x_pred = s["x"] + s["rng"].normal(0, 0.01, s["x"].shape)
    mass = s["rng"].uniform(1e-4, 2e-4, n)
    body = (np.arange(n) % 2).astype(np.int32)
    edge_body = body[s["edges"][:, 0]]
    tri_body = body[s["tris"][:, 0]]
    out = [np.zeros(2) for _ in range(3)]
    kernels.energy_terms_kernel(s["x"], x_pred, mass, body, (s["edges"], s["rest"], edge_body),
                                (s["tris"], s["area0"], tri_body), (100.0, 1e5, 0.01, signed), tuple(out))
    ref = naive.energy_terms(s["x"], x_pred, mass, body, s["edges"], s["rest"], edge_body, s["tris"], s["area0"],
                             tri_body, 100.0, 1e5, 0.01, signed, 2)
    for got, want in zip(out, ref):
        close(got, want)
    res = kernels.constraint_residual(s["x"], s["edges"], s["rest"], s["tris"], s["area0"], signed)
    assert res == pytest.approx(naive.constraint_residual(s["x"], s["edges"], s["rest"], s["tris"], s["area0"], signed),
                                rel=RTOL)


@pytest.mark.parametrize("scene", SCENES)
def test_count_inverted(scene) -> None:
    s = scene()
    assert kernels.count_inverted(s["x"], s["tris"]) == naive.count_inverted(s["x"], s["tris"])
    flipped = s["tris"][:, [0, 2, 1]].copy()
    assert kernels.count_inverted(s["x"], flipped) == naive.count_inverted(s["x"], flipped)


def test_residual_without_constraints_is_zero() -> None:
    x = np.zeros((3, 2))
    assert kernels.constraint_residual(x, np.zeros((0, 2), np.int32), np.zeros(0), np.zeros((0, 3), np.int32),
                                       np.zeros(0), True) == 0.0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_greedy_colour(seed: int) -> None:
    s = random_scene(seed, n=40, n_edges=120, n_tris=50)
    for idx in (s["edges"], s["tris"]):
        colour = np.zeros(len(idx), np.int64)
        n_col = kernels.greedy_colour(idx, len(s["x"]), colour)
        ref, ref_n = naive.greedy_colour(idx, len(s["x"]))
        np.testing.assert_array_equal(colour, ref)
        assert n_col == ref_n
        for c in range(n_col):  # the property the parallel sweep relies on
            members = idx[colour == c].ravel()
            assert len(members) == len(np.unique(members))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_wavefront_levels_and_schedule_reproduce_mesh_order_exactly(seed: int) -> None:
    from tissue_sim_ros.core.physics.solvers import wavefront_order

    s = random_scene(seed, n=40, n_edges=120, n_tris=50)
    for idx in (s["edges"], s["tris"]):
        for block in (1, 16, 1000):
            level = np.zeros(len(idx), np.int64)
            n_lv = kernels.wavefront_levels(idx, len(s["x"]), block, level)
            ref, ref_n = naive.wavefront_levels(idx, len(s["x"]), block)
            np.testing.assert_array_equal(level, ref)
            assert n_lv == ref_n
    # a sweep in the wavefront schedule equals the mesh-order sweep bit for bit
    block = 32 if seed else 10_000
    pe, pt = wavefront_order(s["edges"], len(s["x"]), block), wavefront_order(s["tris"], len(s["x"]), block)
    assert not (pe == np.arange(len(pe))).all()
    x_mesh, x_wave = s["x"].copy(), s["x"].copy()
    lam_mesh, lam_wave = np.zeros(len(pe)), np.zeros(len(pe))
    sweeps.solve_edges(x_mesh, s["inv_mass"], s["edges"], s["rest"], 1.0, 1e-2, lam_mesh)
    sweeps.solve_edges(x_wave, s["inv_mass"], np.ascontiguousarray(s["edges"][pe]), s["rest"][pe], 1.0, 1e-2, lam_wave)
    np.testing.assert_array_equal(x_wave, x_mesh)
    np.testing.assert_array_equal(lam_wave, lam_mesh[pe])
    sweeps.solve_areas(x_mesh, s["inv_mass"], s["tris"], s["area0"], 1.0, 0.0, np.zeros(len(pt)), True)
    sweeps.solve_areas(x_wave, s["inv_mass"], np.ascontiguousarray(s["tris"][pt]), s["area0"][pt], 1.0, 0.0,
                        np.zeros(len(pt)), True)
    np.testing.assert_array_equal(x_wave, x_mesh)


@pytest.mark.parametrize("seed", [0, 1])
def test_partitioned_sweep_equals_serial_sweep_part_by_part(seed: int) -> None:
    """solve_partitioned = serial sweeps: part 0 (edges, triangles), part 1, ..., then the separator."""
    from tissue_sim_ros.core.physics.solvers import partition_constraints, partition_particles

    s = random_scene(seed, n=60, n_edges=150, n_tris=60)
    part = partition_particles(s["x"], 2)
    assert set(part) == {0, 1}
    order_e, off_e = partition_constraints(s["edges"], part, 2)
    order_t, off_t = partition_constraints(s["tris"], part, 2)
    e, r = np.ascontiguousarray(s["edges"][order_e]), np.ascontiguousarray(s["rest"][order_e])
    t, a0 = np.ascontiguousarray(s["tris"][order_t]), np.ascontiguousarray(s["area0"][order_t])
    for g in range(3):  # groups hold what they claim: one part's particles, or the separator's mixed ones
        members_e = part[e[off_e[g]:off_e[g + 1]]]
        if g < 2:
            assert (members_e == g).all()
        else:
            assert (members_e.min(axis=1) != members_e.max(axis=1)).all()
    x, lam_e, lam_t = s["x"].copy(), np.zeros(len(e)), np.zeros(len(t))
    sweeps.solve_partitioned(x, s["inv_mass"], e, r, 1.0, 1e-2, lam_e, off_e, t, a0, 1.0, 1e-2, lam_t, off_t, True)
    ref, ref_le, ref_lt = s["x"].copy(), np.zeros(len(e)), np.zeros(len(t))
    for g in range(3):
        ge, gt = slice(off_e[g], off_e[g + 1]), slice(off_t[g], off_t[g + 1])
        ref, ref_le[ge] = naive.solve_edges(ref, s["inv_mass"], e[ge], r[ge], 1.0, 1e-2, ref_le[ge])
        ref, ref_lt[gt] = naive.solve_areas(ref, s["inv_mass"], t[gt], a0[gt], 1.0, 1e-2, ref_lt[gt], True)
    close(x, ref)
    close(lam_e, ref_le)
    close(lam_t, ref_lt)


@pytest.mark.parametrize("scene", SCENES)
@pytest.mark.parametrize("signed", [True, False])
def test_pbd_sweeps_without_multipliers(scene, signed: bool) -> None:
    """alpha = 0: the multiplier-free sweeps give the positions of the NumPy twin and, bit for bit, of the
    kernels with multipliers (whatever the multipliers hold)."""
    s = scene()
    k = 0.7
    x = s["x"].copy()
    sweeps.solve_edges_pbd_range(x, s["inv_mass"], s["edges"], s["rest"], k, 0, len(s["edges"]))
    sweeps.solve_areas_pbd_range(x, s["inv_mass"], s["tris"], s["area0"], k, signed, 0, len(s["tris"]))
    ref_x, _ = naive.solve_edges(s["x"], s["inv_mass"], s["edges"], s["rest"], k, 0.0, np.zeros(len(s["edges"])))
    ref_x, _ = naive.solve_areas(ref_x, s["inv_mass"], s["tris"], s["area0"], k, 0.0, np.zeros(len(s["tris"])),
                                 signed)
    close(x, ref_x)
    y = s["x"].copy()
    sweeps.solve_edges(y, s["inv_mass"], s["edges"], s["rest"], k, 0.0, s["rng"].normal(0, 1, len(s["edges"])))
    sweeps.solve_areas(y, s["inv_mass"], s["tris"], s["area0"], k, 0.0, s["rng"].normal(0, 1, len(s["tris"])),
                        signed)
    assert np.array_equal(x, y)
    assert not np.array_equal(x, s["x"])  # the sweep moved something
