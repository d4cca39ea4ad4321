"""The stability boundary (bench/stability.py): the safe region stays safe, documented failures are caught.

The region called safe in docs/benchmarks/stability.md is pinned here on the sweep's
strip (regular mesh, 30 steps of the tool pushing down); each documented
failure is reproduced and must be reported by the failure checks.
"""
from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest

from tissue_sim_ros.bench import stability
from tissue_sim_ros.bench.stability import RunConfig, run_one
from tissue_sim_ros.cli import main

SOLVER_FAILURES = {"nonfinite", "energy_growth", "inverted", "no_convergence"}


# --- the safe region (docs/benchmarks/stability.md) --------------------------------------------------
# Corners and middle of the swept box on the regular mesh: dt 1e-4..0.05 s, stiffness 1x..1000x,
# tool speed 0.001..0.2 m per step.

CORNERS = [(dt, s, v) for dt in (1e-4, 0.05) for s in (1.0, 1000.0) for v in (0.001, 0.2)] + [(0.01, 10.0, 0.01)]


@pytest.mark.parametrize("dt,stiffness,speed", CORNERS)
def test_default_method_never_fails_as_a_solver(dt: float, stiffness: float, speed: float) -> None:
    # the shipped default: the paper's PBD, Gauss-Seidel, 30 iterations, signed area, paper contact.
    # The solver never fails here; the paper's contact rule lets the tool pass through tissue
    # (eq. 3 moves nothing once d* = 0), the contact model's documented limitation.
    row = run_one(RunConfig("pbd", "paper", dt, stiffness, speed, "regular", n_steps=30))
    assert row["outcome"] not in SOLVER_FAILURES, row


@pytest.mark.parametrize("dt,stiffness,speed", CORNERS)
def test_default_method_with_projection_contact_is_stable(dt: float, stiffness: float, speed: float) -> None:
    # PBD Gauss-Seidel with projection contact: no failure of any kind, tunnelling included
    row = run_one(RunConfig("pbd", "projection", dt, stiffness, speed, "regular", n_steps=30))
    assert row["outcome"] == "stable", row


@pytest.mark.parametrize("dt,stiffness,speed", [(dt, s, v) for dt in (1e-3, 0.05) for s in (1.0, 1000.0)
                                                for v in (0.001, 0.01)] + [(0.01, 1.0, 0.2), (0.05, 1000.0, 0.2)])
def test_xpbd_with_projection_contact_is_stable(dt: float, stiffness: float, speed: float) -> None:
    # XPBD Gauss-Seidel with projection: safe for dt >= 1e-3 s at up to 0.01 m per step, and at any
    # swept speed for dt >= 0.01 s
    row = run_one(RunConfig("xpbd", "projection", dt, stiffness, speed, "regular", n_steps=30))
    assert row["outcome"] == "stable", row


def test_boundary_of_the_xpbd_safe_region_is_where_the_docs_say() -> None:
    # just outside: a tiny dt with a fast tool (0.05 m per step at dt 1e-4 s is 500 m/s) inverts triangles
    row = run_one(RunConfig("xpbd", "projection", 1e-4, 1.0, 0.05, "regular", n_steps=30))
    assert row["outcome"] == "inverted", row


# --- documented failures are detected ----------------------------------------------------------------

def test_jacobi_without_relaxation_blows_up_at_high_stiffness() -> None:
    unrelaxed = run_one(RunConfig("xpbd_jacobi_unrelaxed", "projection", 0.01, 100.0, 0.001, "regular", n_steps=10))
    assert unrelaxed["outcome"] in {"energy_growth", "nonfinite"}, unrelaxed
    assert unrelaxed["failure_step"] <= 3
    # the shipped Jacobi (stiffness-aware relaxation) on the same run does not blow up
    relaxed = run_one(RunConfig("xpbd_jacobi", "projection", 0.01, 100.0, 0.001, "regular", n_steps=10))
    assert relaxed["outcome"] not in {"energy_growth", "nonfinite"}, relaxed


def test_pbd_jacobi_summing_corrections_blows_up() -> None:
    row = run_one(RunConfig("pbd_jacobi_summed", "paper", 0.01, 1.0, 0.001, "regular", n_steps=10))
    assert row["outcome"] in {"energy_growth", "nonfinite"}, row


@pytest.mark.parametrize("method", ["pbd", "xpbd"])
def test_signed_area_undoes_an_inversion(method: str) -> None:
    rows = {r["area_mode"]: r for r in stability.inversion_rows(20) if r["method"] == method}
    assert rows["signed"]["outcome"] == "stable", rows["signed"]


def test_abs_area_keeps_a_triangle_inverted() -> None:
    rows = {r["area_mode"]: r for r in stability.inversion_rows(20) if r["method"] == "pbd"}
    assert rows["abs"]["outcome"] == "inverted", rows["abs"]
    assert rows["abs"]["max_inverted"] >= 1


def test_paper_contact_tunnels_at_high_tool_speed() -> None:
    fast = run_one(RunConfig("pbd", "paper", 0.01, 1.0, 0.2, "regular", n_steps=5))
    assert fast["outcome"] == "tunnelling" and fast["failure_step"] == 1, fast
    assert fast["n_tunnelled"] > 0


def test_sliver_mesh_has_slivers_and_is_valid() -> None:
    mesh = stability.make_mesh("slivers")
    assert stability.min_angle_deg(mesh) < 5.0
    assert stability.min_angle_deg(stability.make_mesh("regular")) == pytest.approx(45.0)
    a, b, c = (mesh.vertices[mesh.triangles[:, k]] for k in range(3))
    area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    assert (area2 > 0).all()


def test_bench_stability_quick(tmp_path: Path) -> None:
    assert main(["bench", "stability", "--quick", "--out", str(tmp_path)]) == 0
    with open(tmp_path / "stability.csv") as f:
        rows = list(csv.DictReader(f))
    assert rows and all(r["outcome"] in stability.OUTCOMES for r in rows)
    assert all(math.isfinite(float(r["max_kinetic_ratio"])) for r in rows if r["outcome"] != "nonfinite")
    for method in stability.make_sweep(quick=True).methods:
        assert (tmp_path / f"stability_{method}.png").stat().st_size > 0
