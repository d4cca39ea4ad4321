"""bench peers: runs with or without the optional peers; where Taichi is installed it equals our solver."""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from tissue_sim_ros.bench import peers
from tissue_sim_ros.cli import main


def test_bench_peers_quick(tmp_path: Path) -> None:
    assert main(["bench", "peers", "--quick", "--out", str(tmp_path)]) == 0
    with open(tmp_path / "peers.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 1
    for key in ("ours_ms", "ours_parallel_ms", "numpy_jacobi_ms", "numpy_jacobi_over_ours"):
        assert math.isfinite(float(rows[0][key])) and float(rows[0][key]) > 0
    assert (tmp_path / "peers.png").stat().st_size > 0


def test_taichi_version_is_the_same_algorithm() -> None:
    pytest.importorskip("taichi")
    _, model = peers.strip(0.1)
    _, ours = peers.time_ours(model, 1, False)
    _, theirs = peers.time_taichi(model, 1)
    # the same projections in the same order: equal to round-off
    assert np.abs(ours - theirs).max() <= 1e-12


def test_mujoco_flex_keeps_the_pinned_row() -> None:
    mujoco = pytest.importorskip("mujoco")
    _, model = peers.strip(0.1)
    m = mujoco.MjModel.from_xml_string(peers.mujoco_xml(model))
    d = mujoco.MjData(m)
    assert m.nv == 2 * int((~model.particle_pinned).sum())  # dof="2d": x and y of each free vertex
    for _ in range(10):
        mujoco.mj_step(m, d)
    xy = d.flexvert_xpos[:, :2]
    assert np.abs(xy[model.particle_pinned] - model.particle_q0[model.particle_pinned]).max() < 1e-6
    assert xy[~model.particle_pinned, 1].min() < model.particle_q0[~model.particle_pinned, 1].min() + 1e-9


def test_bench_peers_bad_steps_exits_2(tmp_path: Path) -> None:
    assert main(["bench", "peers", "--quick", "--steps", "0", "--out", str(tmp_path)]) == 2


# ----------------------------------------------------------------------------- bench peers --fem


def test_fem_peers_ours_only_dynamic_and_static_agree() -> None:
    from tissue_sim_ros.bench import peers_fem

    rows = peers_fem.compare((0.02,), (300.0,), with_mujoco=False, with_newton=False)
    by = {r["peer"]: r for r in rows}
    assert set(by) == {"ours", "ours_static"}
    assert by["ours"]["at_rest"] and by["ours_static"]["at_rest"]
    # the same discrete energy: run to rest, the dynamic strip ends where the static solve puts it (the rest
    # criterion leaves ~0.03% of the sag), and both are the coarse mesh's error against the FEM (-7.8% at 20 mm)
    assert abs(by["ours"]["err_mean_sag"] - by["ours_static"]["err_mean_sag"]) < peers_fem.ACCURACY_TOL
    assert 0.02 < abs(by["ours_static"]["err_mean_sag"]) < 0.2
    assert by["ours_static"]["wall_over_static"] == 1.0 and by["ours"]["wall_to_rest_s"] > 0


def test_rest_check_needs_a_quiet_window_and_catches_divergence() -> None:
    from tissue_sim_ros.bench.peers_fem import REST_FRACTION, RestCheck

    x0 = np.zeros((3, 2))
    check = RestCheck(x0, 1e-3, scale=1e-3)
    assert check.every == 5
    moving = [x0 + 1e-3 * k for k in range(100)]
    assert not any(check(k, lambda k=k: moving[k]) for k in range(21, 60))
    still = x0 + 0.5e-3
    assert not check(25, lambda: still)  # the first quiet window moved from the last position
    assert check(30, lambda: still + 0.5 * REST_FRACTION * 1e-3 * check.window)
    assert not check.diverged
    check(35, lambda: np.full((3, 2), np.nan))
    assert check.diverged


def test_newton_semi_implicit_reads_the_shifted_lambda() -> None:
    # Newton's semi-implicit triangle is the stable neo-Hookean with tri_ka = lambda + mu (per area: x thickness):
    # run to rest it must sit on our static solve of the same discrete problem (P1 elements, same masses)
    pytest.importorskip("newton")
    pytest.importorskip("warp")
    from tissue_sim_ros.bench import peers_fem

    rows = peers_fem.compare((0.02,), (300.0,), si_dts=(5e-4,), vbd_dts=(1e-3,), with_mujoco=False)
    by = {r["peer"]: r for r in rows}
    for peer in ("newton_si", "newton_vbd"):
        assert by[peer]["at_rest"], peer
        assert abs(by[peer]["err_mean_sag"] - by["ours_static"]["err_mean_sag"]) < 2 * peers_fem.ACCURACY_TOL, peer


def test_mujoco_membrane_runs_to_rest_on_the_fem_problem() -> None:
    pytest.importorskip("mujoco")
    from tissue_sim_ros.bench import peers_fem

    rows = peers_fem.compare((0.02,), (300.0,), mujoco_dts=(5e-4,), with_newton=False)
    m = next(r for r in rows if r["peer"] == "mujoco")
    assert m["at_rest"] and m["dt"] == 5e-4
    assert abs(m["err_mean_sag"]) < 0.2  # MuJoCo's own membrane discretisation: -8.6% at 20 mm
