"""``tissue-sim bench material-speed``: the material's default solve, cost per step against accuracy, at three
meshes, next to the paper PBD's step on the same mesh.

The scene is the hanging strip of ``bench refinement`` with the issue's block: 10 x 4 cm, E 50 kPa, nu 0.45,
5 mm thick, 1060 kg/m^3, top edge held, gravity, stepped at dt 10 ms from the rest shape with damping 20 1/s
for ``steps`` steps (3 s). For each mesh spacing it runs

* ``paper pbd``: the paper's model on the same mesh (``material: constraints``, pbd, 30 Gauss-Seidel iterations);
  its cost only;
* ``xpbd 10x10``: the material with the former default solve (10 substeps x 10 iterations);
* ``quasi_newton``: the material with the default solve (core/physics/quasi_newton.py);

and prints, for each, the median solver time per step [ms], the ratio to the paper PBD step, the mean sag's
error against the static FEM (``bench/fem_reference.hanging_strip``; the run's last state, at rest when
``at_rest``), the median and max iterations and the largest reported ``solve_residual``. The times are measured
in one run, one after the other, one core. Writes ``material_speed.csv`` and ``material_speed.png``.
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..core.config import resolve_config
from ..core.errors import InputError
from ..core.mesh import mesh_rectangle
from ..core.sim.simulation import Simulation

WIDTH, HEIGHT = 0.10, 0.04
BLOCK = {"young_modulus": 50e3, "poisson_ratio": 0.45, "thickness": 0.005, "density": 1060.0}
GRAVITY = 9.8
SPACINGS = (0.0025, 0.00125, 0.0007)
QUICK_SPACINGS = (0.005, 0.0025)
#: at rest: no particle faster than this [m/s]
REST_SPEED = 1e-5


def _config(variant: str, dt: float, damping: float):
    base = {"dt": dt, "damping": damping, "gravity": -GRAVITY, "boundary_y_top": HEIGHT - 1e-9,
            "boundary_y_bottom": math.nan, "contact_model": "none"}
    if variant == "paper pbd":
        return resolve_config({**base, "method": "pbd", "iterations": 30}, source="--set")
    values = {**base, **BLOCK, "material": "neo_hookean"}
    if variant == "xpbd 10x10":
        values.update(method="xpbd", substeps=10, iterations=10)
    return resolve_config(values, source="--set")


def measure(variant: str, spacing: float, steps: int, dt: float = 0.01, damping: float = 20.0) -> dict[str, Any]:
    """One run of ``steps`` steps; solver time per step (median), iterations, residuals and the final state."""
    sim = Simulation.from_config(_config(variant, dt, damping), mesh=mesh_rectangle(WIDTH, HEIGHT, spacing))
    sim.step()  # compiled and factored before the clock starts
    sim.reset()
    times, its, res = [], [], []
    rest_step = -1
    for k in range(1, steps + 1):
        r = sim.step()
        times.append(r.timings["solve"])
        its.append(r.solve_iterations)
        res.append(r.solve_residual)
        if rest_step < 0 and k > 5 and float(np.abs(sim.state.particle_qd).max()) < REST_SPEED:
            rest_step = k
    m = sim.model
    u = sim.state.particle_q - m.particle_q0
    w = m.particle_mass
    mean_sag = float(-(w * u[:, 1]).sum() / w.sum())
    return {"variant": variant, "spacing_mm": 1e3 * spacing, "particles": m.n_particles,
            "solve_ms_median": 1e3 * float(np.median(times)), "iterations_median": float(np.median(its)),
            "iterations_max": int(np.max(its)), "solve_residual_max": float(np.nanmax(res)) if variant != "paper pbd"
            else math.nan, "mean_sag_m": mean_sag, "rest_time_s": rest_step * dt if rest_step > 0 else math.nan}


def plot(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.2))
    for variant, marker in (("xpbd 10x10", "s"), ("quasi_newton", "o")):
        sel = [r for r in rows if r["variant"] == variant]
        ax.scatter([r["solve_ms_median"] for r in sel], [abs(r["err_sag"]) * 100 for r in sel], marker=marker,
                   s=40, label=variant)
        for r in sel:
            ax.annotate(f"{r['particles']} p", (r["solve_ms_median"], abs(r["err_sag"]) * 100), fontsize=7,
                        xytext=(3, 3), textcoords="offset points")
    paper = [r for r in rows if r["variant"] == "paper pbd"]
    for r in paper:
        ax.axvline(r["solve_ms_median"], color="0.7", lw=0.8, ls=":")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.axhline(1.0, color="#c62828", lw=0.8, label="1% of the FEM")
    ax.set_xlabel("solver time per 10 ms step [ms] (median; dotted: paper PBD, 30 its, same meshes)")
    ax.set_ylabel("|mean sag error| vs FEM [%]")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3, which="both")
    for variant, marker in (("paper pbd", "^"), ("xpbd 10x10", "s"), ("quasi_newton", "o")):
        sel = [r for r in rows if r["variant"] == variant]
        bx.plot([r["particles"] for r in sel], [r["solve_ms_median"] for r in sel], marker=marker, label=variant)
    bx.axhline(10.0, color="0.5", lw=0.8, ls="--", label="dt = 10 ms")
    bx.set_xscale("log")
    bx.set_yscale("log")
    bx.set_xlabel("particles")
    bx.set_ylabel("solver time per step [ms] (median)")
    bx.legend(fontsize=7)
    bx.grid(alpha=0.3, which="both")
    fig.suptitle("hanging block, dt 10 ms, damping 20 1/s: cost against accuracy", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run(out: str | Path, *, spacings: Sequence[float] = SPACINGS, steps: int = 300, quick: bool = False) -> int:
    """Measure every variant at every spacing; print the table, write the CSV and the chart; 0."""
    from . import fem_reference as fem  # noqa: PLC0415
    from .accuracy import format_table  # noqa: PLC0415
    from .refinement import write_csv  # noqa: PLC0415

    if steps < 10:
        raise InputError(f"--steps {steps}: expected at least 10")
    if any(not (s > 0) for s in spacings):
        raise InputError(f"--spacings {list(spacings)}: expected mesh spacings > 0 m")
    spacings, steps = (QUICK_SPACINGS, 60) if quick else (tuple(spacings), steps)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ref = fem.hanging_strip(WIDTH, HEIGHT, BLOCK["young_modulus"], BLOCK["poisson_ratio"], BLOCK["thickness"],
                            BLOCK["density"], GRAVITY)
    rows = []
    for spacing in spacings:
        by = {}
        for variant in ("paper pbd", "xpbd 10x10", "quasi_newton"):
            print(f"  {variant} at h = {1e3 * spacing:g} mm ...", flush=True)
            row = measure(variant, spacing, steps)
            by[variant] = row
            rows.append(row)
        for row in by.values():
            row["vs_paper_pbd"] = row["solve_ms_median"] / by["paper pbd"]["solve_ms_median"]
            row["err_sag"] = row["mean_sag_m"] / ref.mean_sag - 1.0 if row["variant"] != "paper pbd" else math.nan
    load = os.getloadavg()[0]
    write_csv(out / "material_speed.csv", rows)
    plot(out / "material_speed.png", rows)
    cols = ["variant", "spacing_mm", "particles", "solve_ms_median", "vs_paper_pbd", "err_sag", "rest_time_s",
            "iterations_median", "iterations_max", "solve_residual_max"]
    print(f"hanging block, dt 10 ms, {steps} steps, FEM mean sag {ref.mean_sag:.6g} m; load {load:.2f} at the end")
    print(format_table(rows, cols))
    print(f"wrote {out / 'material_speed.csv'}, {out / 'material_speed.png'}")
    return 0
