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
