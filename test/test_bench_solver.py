"""``tissue-sim bench solver`` smoke test and the NumPy baseline against the numba Jacobi solver."""
from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from tissue_sim_ros.bench.numpy_baseline import NumpyJacobiSolver
from tissue_sim_ros.core.contact.collision import Contacts
from tissue_sim_ros.core.mesh import mesh_rectangle
from tissue_sim_ros.core.physics.model import Model, SimParams, State
from tissue_sim_ros.core.physics.solvers import Solver


@pytest.mark.parametrize("params", [dict(method="pbd", scheme="jacobi", jacobi_averaging="all"),
                                    dict(method="xpbd", scheme="jacobi"),
                                    dict(method="xpbd", scheme="jacobi", area_mode="abs", substeps=3, iterations=5,
                                         damping=2.0, boundary_y_bottom=0.02, boundary_y_top=0.18)])
def test_numpy_baseline_matches_the_numba_jacobi_solver(params: dict) -> None:
    """Same algorithm, different summation order: equal to 1e-9 of the step's displacement."""
    mesh = mesh_rectangle(0.4, 0.2, 0.05)
    model = Model.from_mesh(mesh, SimParams(**params), pinned=mesh.vertices[:, 1] <= 1e-9)
    rng = np.random.default_rng(0)
    start = State(model.particle_q0 + rng.normal(0, 0.003, model.particle_q0.shape),
                  np.where(model.particle_pinned[:, None], 0.0, rng.normal(0, 0.1, model.particle_q0.shape)))
    start.particle_q[model.particle_pinned] = model.particle_q0[model.particle_pinned]
    contacts = Contacts.empty(1)
    contacts.held_idx, contacts.held_dx = np.array([30, 31], np.int32), np.full((2, 2), -0.004)
    a, b = model.state(), model.state()
    info = Solver(model).step(start, a, contacts, 0.01)
    x_pred = NumpyJacobiSolver(model).step(start, b, contacts, 0.01).x_pred
    scale = np.abs(a.particle_q - start.particle_q).max()
    np.testing.assert_allclose(x_pred, info.x_pred, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(b.particle_q, a.particle_q, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(b.particle_qd, a.particle_qd, rtol=0, atol=1e-9 * scale / 0.01)


def test_bench_solver_quick_writes_csv_and_png(tmp_path, capsys) -> None:
    """Smoke test: the command runs, writes its CSV and chart, and every number it wrote is finite."""
    from tissue_sim_ros.cli import main

    assert main(["bench", "solver", "--quick", "--steps", "2", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "solver.png").stat().st_size > 0
    with (tmp_path / "solver.csv").open() as f:
        rows = list(csv.DictReader(f))
    methods = {r["method"] for r in rows}
    assert {"pbd_gs", "xpbd_gs", "xpbd_gs_parallel", "xpbd_jacobi", "xpbd_substep", "numpy_jacobi"} <= methods
    assert any(r["scene"].startswith("paper") for r in rows)
    for r in rows:
        for key in ("ms_per_step", "ns_per_projection", "realtime_factor", "x_numpy"):
            assert math.isfinite(float(r[key])) and float(r[key]) > 0, (key, r)
    out = capsys.readouterr().out
    assert "ns/proj" in out and "summary" in out


def test_bench_solver_rejects_bad_arguments(tmp_path) -> None:
    from tissue_sim_ros.cli import main

    assert main(["bench", "solver", "--steps", "0", "--out", str(tmp_path)]) == 2
    assert main(["bench", "solver", "--sizes", "2", "--out", str(tmp_path)]) == 2
