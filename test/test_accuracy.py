"""The accuracy benchmark (bench/accuracy.py): its measures, its front, and a --quick smoke run."""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from tissue_sim_ros.bench import accuracy
from tissue_sim_ros.cli import main


def test_newton_capped_error_falls_to_zero_and_xpbd_error_falls_with_iterations() -> None:
    scene = accuracy.strip_scene(spacing=0.1, n_steps=4, speed=0.004)
    ref, _ = accuracy.reference_run(scene)
    rows = {(m, c): accuracy.measure_setting(scene, accuracy.Setting(m, c), ref)
            for m, c in [("newton", 200), ("xpbd", 2), ("xpbd", 200)]}
    # the converged Newton run is the reference itself
    assert rows["newton", 200]["err_step_median"] <= 1e-9
    assert rows["newton", 200]["err_accum_final"] <= 1e-9
    # XPBD approaches the implicit Euler minimiser as iterations grow
    assert rows["xpbd", 200]["err_step_median"] < 0.5 * rows["xpbd", 2]["err_step_median"]
    assert all(math.isfinite(r["ms_per_step"]) and r["ms_per_step"] > 0 for r in rows.values())


def test_pareto_front_and_cheapest() -> None:
    rows = [{"method": "a", "ms_per_step": 1.0, "err_step_median": 0.5},
            {"method": "b", "ms_per_step": 2.0, "err_step_median": 0.6},   # dominated by a
            {"method": "c", "ms_per_step": 3.0, "err_step_median": 0.1},
            {"method": "d", "ms_per_step": 4.0, "err_step_median": math.nan},
            {"method": "newton", "ms_per_step": 9.0, "err_step_median": 0.0}]
    assert accuracy.pareto_front(rows) == [0, 2, 4]
    assert accuracy.cheapest(rows, 0.55)["method"] == "a"
    assert accuracy.cheapest(rows, 0.2)["method"] == "c"
    assert accuracy.cheapest(rows, 0.01) is None  # Newton is the reference, not a candidate


def test_displacement_error_of_a_nested_mesh_is_zero_for_a_linear_field() -> None:
    coarse = accuracy.strip_scene(spacing=0.1, n_steps=1)
    fine = accuracy.strip_scene(spacing=0.05, n_steps=1)
    # a linear displacement field is interpolated exactly by the fine mesh's linear triangles
    field = lambda v: np.stack([0.01 * v[:, 1], -0.02 * v[:, 0]], axis=1)  # noqa: E731
    err = accuracy.displacement_error(coarse, coarse.mesh.vertices + field(coarse.mesh.vertices),
                                      fine, fine.mesh.vertices + field(fine.mesh.vertices))
    assert err <= 1e-12
    err_off = accuracy.displacement_error(coarse, coarse.mesh.vertices + 2 * field(coarse.mesh.vertices),
                                          fine, fine.mesh.vertices + field(fine.mesh.vertices))
    assert math.isclose(err_off, 1.0, rel_tol=1e-9)


def test_bench_accuracy_quick(tmp_path: Path, capsys) -> None:
    assert main(["bench", "accuracy", "--quick", "--out", str(tmp_path)]) == 0
    for name in ("accuracy.csv", "accuracy_refinement.csv", "accuracy_sleeping.csv", "accuracy.png",
                 "accuracy_accumulated.png"):
        assert (tmp_path / name).stat().st_size > 0
    with open(tmp_path / "accuracy.csv") as f:
        rows = list(csv.DictReader(f))
    assert {r["method"] for r in rows} >= {"pbd", "pbd_jacobi", "xpbd", "xpbd_jacobi", "xpbd_substep", "newton"}
    for r in rows:
        assert math.isfinite(float(r["ms_per_step"])) and math.isfinite(float(r["err_accum_final"]))
        # the per-step error is measured wherever its reference was solved (PBD on finer meshes: accumulated only)
        assert math.isfinite(float(r["err_step_median"])) == (int(r["ref_converged"]) > 0)
    assert all(int(r["ref_converged"]) > 0 for r in rows if float(r["particles"]) == min(float(q["particles"]) for q in rows))
    with open(tmp_path / "accuracy_sleeping.csv") as f:
        sleep_rows = list(csv.DictReader(f))
    assert len(sleep_rows) == 3 and float(sleep_rows[0]["err_vs_awake"]) == 0.0
    assert all(math.isfinite(float(r["err_vs_awake"])) and float(r["ms_per_step"]) > 0 for r in sleep_rows)
    assert "Pareto front" in capsys.readouterr().out


def test_bench_accuracy_bad_tolerance_exits_2(tmp_path: Path) -> None:
    assert main(["bench", "accuracy", "--quick", "--out", str(tmp_path), "--tolerance", "-1"]) == 2
