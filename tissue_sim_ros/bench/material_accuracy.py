"""``tissue-sim bench material``: the material model's solve against its exact minimiser, versus time per step.

For each solver setting (substeps x iterations, Gauss-Seidel or Jacobi) the
material model (``material: neo_hookean``) runs a scene; at every step, from
the method's own state, an exact step is taken too: ``substeps`` implicit
Euler substeps of h = dt / substeps, each the exact minimiser (damped Newton,
:func:`~tissue_sim_ros.bench.reference.minimize_step`) of

    E(x) = 1/2 sum m |x - x*_h|^2 + h^2 sum V0 Psi(F)          (Psi: bench/material_reference.py)

with x*_h = x + h v' + h^2 g, v' = v max(0, 1 - damping h), the same
discretisation the substepped solver approximates, so what is measured is the
solver's error alone. Two normalisations, both reported as the median AND the
maximum over the steps (a median hides per-step plateaus):

* ``err_step``     = ||x_method - x_ref|| / ||x_ref - x_start||  (the whole step's motion);
* ``err_response`` = ||x_method - x_ref|| / ||x_ref - x*||  (the solve's own work: x* is the step's
  prediction, so a solve that returned x* unchanged scores 1, however small its step error looks).

Scenes (tool-free: the reference models no inequality contact):

* ``strip``: the hanging strip of ``bench refinement`` (10 x 4 cm, E 50 kPa, 5 mm spacing) released
  from its rest shape under gravity, steps 1-N;
* ``liver``: ``config/scenes/liver_probe.yaml`` (E 4 kPa, 2.5 mm) settling under gravity.

Timing: the median of the solver's own wall time per step (``StepReport.timings["solve"]``). The
Pareto front (no other setting is both faster and more accurate on ``err_response`` max) is printed and
drawn. Writes ``material_accuracy.csv`` and ``material_accuracy.png``.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from ..core.config import Config, resolve_config
from ..core.errors import InputError
from ..core.mesh import mesh_rectangle
from ..core.physics.model import State
from ..core.sim.simulation import Simulation
from .material_reference import MembraneEnergy
from .reference import minimize_step

#: (scheme, substeps, iterations) of the sweep
SETTINGS = (("gauss_seidel", 1, 10), ("gauss_seidel", 1, 50), ("gauss_seidel", 2, 5), ("gauss_seidel", 5, 2),
            ("gauss_seidel", 5, 5), ("gauss_seidel", 10, 1), ("gauss_seidel", 10, 2), ("gauss_seidel", 10, 5),
            ("gauss_seidel", 10, 10), ("gauss_seidel", 20, 10), ("jacobi", 10, 10), ("jacobi", 10, 30),
            ("quasi_newton", 1, 50))
QUICK_SETTINGS = (("gauss_seidel", 1, 5), ("gauss_seidel", 5, 5), ("jacobi", 5, 10), ("quasi_newton", 1, 50))


def scene_config(scene: str, overrides: dict[str, Any]) -> tuple[Config, Any]:
    """Config and mesh (None: the scene's own) of a benchmark scene."""
    if scene == "strip":
        values = {"material": "neo_hookean", "young_modulus": 50e3, "poisson_ratio": 0.45, "thickness": 1e-3,
                  "density": 1000.0, "dt": 0.002, "boundary_y_top": 0.04 - 1e-9, "boundary_y_bottom": math.nan,
                  "contact_model": "none", "damping": 0.0, **overrides}
        return resolve_config(values, source="--set"), mesh_rectangle(0.10, 0.04, 0.005)
    if scene == "liver":
        from ..core.resources import scene_params_file  # noqa: PLC0415

        values = {"contact_model": "none", **overrides}
        return resolve_config(values, params_file=scene_params_file("liver_probe"), source="--set"), None
    raise InputError(f"--scene {scene!r}: expected strip or liver")


def exact_step(sim: Simulation, start: State, rtol: float = 1e-9, worst: list[float] | None = None) -> np.ndarray:
    """``substeps`` exact implicit Euler substeps of the model from ``start``; positions after the step.

    ``worst[0]`` is raised to the largest final relative gradient norm of the Newton solves.
    """
    worst = worst if worst is not None else [0.0]
    model = sim.model
    p = model.params
    n = max(1, int(p.substeps))
    h = p.dt / n
    fixed = np.asarray(model.particle_inv_mass) == 0.0
    x = start.particle_q.copy()
    v = start.particle_qd.copy()
    for _ in range(n):
        v_damped = v * max(0.0, 1.0 - p.damping * h)
        pred = x + h * v_damped
        pred[:, 1] += h * h * p.gravity
        pred[fixed] = x[fixed]
        x_new, info = minimize_step(MembraneEnergy(model, pred, h), fixed, rtol=rtol)
        # converged, or stopped by the line search at float64 round-off of the energy (the exact step's own
        # error then far below the errors this benchmark reports)
        worst[0] = max(worst[0], info["grad_norm"] / max(info["grad_norm0"], 1e-300))
        if not info["converged"] and info["grad_norm"] > 1e-5 * info["grad_norm0"]:
            raise RuntimeError(f"the exact step did not converge (gradient {info['grad_norm']:.3g} of "
                               f"{info['grad_norm0']:.3g})")
        v = (x_new - x) / h
        x = x_new
    return x


def measure(cfg: Config, mesh: Any, scheme: str, substeps: int, iterations: int, n_steps: int) -> dict[str, Any]:
    """Run one setting ``n_steps`` steps; the per-step errors against the exact step from the same state."""
    if scheme == "quasi_newton":  # the material's default: the step minimised, iterations its cap
        cfg = cfg.replace(method="quasi_newton", substeps=1, iterations=iterations)
    else:
        cfg = cfg.replace(method="xpbd", scheme=scheme, substeps=substeps, iterations=iterations)
    sim = Simulation.from_config(cfg, mesh=mesh)
    e_step, e_resp, solve_ms = [], [], []
    worst = [0.0]
    for _ in range(n_steps):
        start = sim.state.copy()
        report = sim.step()
        x_ref = exact_step(sim, start, worst=worst)
        x = sim.state.particle_q
        diff = float(np.linalg.norm(x - x_ref))
        e_step.append(diff / max(float(np.linalg.norm(x_ref - start.particle_q)), 1e-300))
        e_resp.append(diff / max(float(np.linalg.norm(x_ref - report.x_pred)), 1e-300))
        solve_ms.append(1e3 * report.timings.get("solve", report.timings.get("total", math.nan)))
    return {"scheme": scheme, "substeps": substeps, "iterations": iterations, "dt": cfg.sim.dt,
            "particles": sim.model.n_particles, "steps": n_steps,
            "err_step_median": float(np.median(e_step)), "err_step_max": float(np.max(e_step)),
            "err_response_median": float(np.median(e_resp)), "err_response_max": float(np.max(e_resp)),
            "solve_ms_median": float(np.median(solve_ms)), "reference_rel_grad_max": worst[0]}


def pareto(rows: Sequence[dict[str, Any]], key: str = "err_response_max") -> list[int]:
    """Indices of the rows no other row beats on both ``solve_ms_median`` and ``key``."""
    out = []
    for i, r in enumerate(rows):
        if not any((o["solve_ms_median"] <= r["solve_ms_median"] and o[key] <= r[key])
                   and (o["solve_ms_median"] < r["solve_ms_median"] or o[key] < r[key]) for o in rows):
            out.append(i)
    return sorted(out, key=lambda i: rows[i]["solve_ms_median"])


def plot(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    fig, axes = plt.subplots(1, len(scenes), figsize=(5.6 * len(scenes), 4.4), squeeze=False)
    for ax, scene in zip(axes[0], scenes):
        rs = [r for r in rows if r["scene"] == scene]
        for scheme, marker in (("gauss_seidel", "o"), ("jacobi", "s"), ("quasi_newton", "*")):
            sel = [r for r in rs if r["scheme"] == scheme]
            if not sel:
                continue
            t = [r["solve_ms_median"] for r in sel]
            ax.scatter(t, [r["err_response_max"] for r in sel], marker=marker, label=f"{scheme}: response, max")
            ax.scatter(t, [r["err_step_median"] for r in sel], marker=marker, facecolors="none", edgecolors="0.4",
                       label=f"{scheme}: step, median")
            for r in sel:
                ax.annotate(f"{r['substeps']}x{r['iterations']}", (r["solve_ms_median"], r["err_response_max"]),
                            fontsize=6, xytext=(3, 2), textcoords="offset points")
        front = [rs[i] for i in pareto(rs)]
        ax.plot([r["solve_ms_median"] for r in front], [r["err_response_max"] for r in front], color="#c62828",
                lw=1.0, label="Pareto front (response, max)")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("solver time per step [ms] (median)")
        ax.set_ylabel("error against the exact step")
        ax.set_title(f"material model, {scene} (substeps x iterations)", fontsize=10)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run(out: str | Path, *, scenes: Sequence[str] = ("strip", "liver"), steps: int = 20,
        overrides: Mapping[str, Any] | None = None, quick: bool = False) -> int:
    """Every setting against the exact step on each scene; print the tables and fronts, write the CSV and chart; 0.

    Parameters
    ----------
    out : str or Path
        Output directory (created).
    scenes : sequence of str
        ``"strip"`` and/or ``"liver"`` (``quick``: the strip only).
    steps : int
        Steps per setting (``quick``: 3).
    overrides : mapping, optional
        Parameters over the scene's (flat names, as ``--set``).
    quick : bool
        Three settings, three steps, the strip only.
    """
    from .accuracy import format_table  # noqa: PLC0415
    from .refinement import write_csv  # noqa: PLC0415

    if steps < 1:
        raise InputError(f"--steps {steps}: expected at least 1")
    overrides = dict(overrides or {})
    scenes = list(scenes)
    settings, steps = (QUICK_SETTINGS, 3) if quick else (SETTINGS, steps)
    if quick:
        scenes = ["strip"]
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for scene in scenes:
        cfg, mesh = scene_config(scene, overrides)
        if mesh is None:
            mesh = cfg.scene.build_mesh()
        for scheme, n, it in settings:
            rows.append({"scene": scene, **measure(cfg, mesh, scheme, n, it, steps)})
    write_csv(out / "material_accuracy.csv", rows)
    plot(out / "material_accuracy.png", rows)
    cols = ["scheme", "substeps", "iterations", "err_step_median", "err_step_max", "err_response_median",
            "err_response_max", "solve_ms_median"]
    for scene in scenes:
        rs = [r for r in rows if r["scene"] == scene]
        print(f"{scene} ({rs[0]['particles']} particles, dt {rs[0]['dt']:g} s, {steps} steps):")
        print(format_table(rs, cols))
        print("Pareto front (solve time vs response error, max): "
              + ", ".join(f"{rs[i]['scheme']} {rs[i]['substeps']}x{rs[i]['iterations']}" for i in pareto(rs)))
        print()
    print(f"wrote {out / 'material_accuracy.csv'}, {out / 'material_accuracy.png'}")
    return 0
