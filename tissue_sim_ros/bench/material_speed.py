"""``tissue-sim bench material-speed``: the material's default solve, cost per step against accuracy, at four
meshes, next to the paper PBD's step on the same mesh.

The scene is the hanging strip of ``bench refinement`` with its block: 10 x 4 cm, E 50 kPa, nu 0.45,
5 mm thick, 1060 kg/m^3, top edge held, gravity, stepped at dt 10 ms from the rest shape with damping 20 1/s
for ``steps`` steps (3 s). For each mesh spacing it runs

* ``paper pbd``: the paper's model on the same mesh (``material: constraints``, pbd, 30 Gauss-Seidel iterations);
  its cost only;
* ``xpbd 10x10``: the material with the former default solve (10 substeps x 10 iterations);
* ``quasi_newton``: the material with the default solve (core/physics/quasi_newton.py);

and prints, for each, the median solver time per step [ms], the ratio to the paper PBD step, the mean sag's
error against the static FEM (``bench/fem_reference.hanging_strip``; the run's last state), when it came to rest
(no particle faster than 10 um/s), the median and max iterations and the largest reported ``solve_residual``.
The times are measured in one run, one after the other, one core.

Then, for the two material solves on each mesh:

* ``punch``: a 30 cm x 1 cm plate pressed 0.4 mm into the block's top, bottom edge on its line, no gravity,
  stepped to rest (at most 3 s): the reaction against the FEM's force (``fem_reference.flat_punch``);
* ``dynamics`` (quasi_newton; two meshes): each step of a run with contact against the exact implicit Euler
  step from the same start, the minimiser of the step's incremental potential by damped Newton on
  ``bench/material_reference.MembraneEnergy`` (the formula, not the kernels). Two runs: the paper contact
  (held particles displaced and fixed: the reference fixes them too) and the projection contact with a 2 cm
  box pressed 1.5 mm in and dragged 1 cm sideways (the reference holds the particles the solve ended on the
  tool, the bottom line, along their normals' dominant axis at the tool's face: an equality-constrained
  minimiser; it reports the held particles whose multiplier pulls instead of pushes, which would mean a wrong
  active set). Error per step ||x - x_ref|| / ||x_ref - x_start||, median and max over the steps that move
  more than 1 nm RMS.

Writes ``material_speed.csv``, ``material_accuracy_punch.csv``, ``material_dynamics.csv`` and
``material_speed.png``.
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
SPACINGS = (0.0025, 0.002, 0.001, 0.1 / 140)
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
            "solve_ms_median": 1e3 * float(np.median(times)), "solve_ms_mean": 1e3 * float(np.mean(times)),
            "solve_ms_max": 1e3 * float(np.max(times)), "iterations_median": float(np.median(its)),
            "iterations_max": int(np.max(its)), "solve_residual_max": float(np.nanmax(res)) if variant != "paper pbd"
            else math.nan, "mean_sag_m": mean_sag, "rest_time_s": rest_step * dt if rest_step > 0 else math.nan}


def punch(variant: str, spacing: float, depth: float = 4e-4, max_steps: int = 300) -> dict[str, Any]:
    """The plate pressed ``depth`` into the block's top, stepped to rest: reaction force [N], time to rest."""
    from ..core.contact.tool import ToolPose  # noqa: PLC0415

    values = {"dt": 0.01, "damping": 20.0, "gravity": 0.0, "boundary_y_top": math.nan, "boundary_y_bottom": 1e-9,
              "contact_model": "projection", "contact_margin": 0.0, "tool_shape": "box", "tool_length": 0.3,
              "tool_width": 0.01, **BLOCK, "material": "neo_hookean"}
    if variant == "xpbd 10x10":
        values.update(method="xpbd", substeps=10, iterations=10)
    sim = Simulation.from_config(resolve_config(values, source="--set"), mesh=mesh_rectangle(WIDTH, HEIGHT, spacing))
    pose = ToolPose(0.5 * WIDTH, HEIGHT + 0.005 - depth, 0.0)
    rest = -1
    times = []
    r = None
    for k in range(1, max_steps + 1):
        r = sim.step(pose)
        times.append(r.timings["solve"])
        if k > 5 and float(np.abs(sim.state.particle_qd).max()) < REST_SPEED:
            rest = k
            break
    return {"variant": variant, "spacing_mm": 1e3 * spacing, "particles": sim.model.n_particles,
            "force_n": float(r.reaction_force[1]), "rest_time_s": rest * 0.01 if rest > 0 else math.nan,
            "solve_ms_median": 1e3 * float(np.median(times)), "penetrating": int(r.n_penetrating)}


def _constrained_minimiser(energy, x_init: np.ndarray, fixed: np.ndarray, held: np.ndarray, normal: np.ndarray,
                           rtol: float = 1e-10, max_iterations: int = 100) -> np.ndarray:
    """Damped Newton on ``energy`` (value, gradient, hessian) with ``fixed`` (N,) particles at ``x_init`` and
    ``held`` particles free only along the tangent of their ``normal`` (x = x_init + Z u, Newton on u)."""
    import scipy.sparse as sp  # noqa: PLC0415
    import scipy.sparse.linalg as sla  # noqa: PLC0415

    n = x_init.shape[0]
    rows, cols, vals = [], [], []
    col = 0
    tangent = {int(i): (-float(nv[1]), float(nv[0])) for i, nv in zip(held, normal)}
    for i in range(n):
        if fixed[i]:
            continue
        if i in tangent:
            tx, ty = tangent[i]
            rows += [2 * i, 2 * i + 1]
            cols += [col, col]
            vals += [tx, ty]
            col += 1
        else:
            rows += [2 * i, 2 * i + 1]
            cols += [col, col + 1]
            vals += [1.0, 1.0]
            col += 2
    z = sp.csr_matrix((vals, (rows, cols)), shape=(2 * n, col))
    x = x_init.copy()
    g0 = float(np.linalg.norm(z.T @ energy.gradient(x).ravel()))
    for _ in range(max_iterations):
        g = z.T @ energy.gradient(x).ravel()
        if float(np.linalg.norm(g)) <= rtol * max(g0, 1e-300):
            break
        for project in (False, True):
            h = (z.T @ energy.hessian(x, project=project) @ z).tocsc()
            d = sla.spsolve(h, -g)
            if float(g @ d) < 0.0:
                break
        f = energy.value(x)
        step = 1.0
        while step > 1e-8:
            trial = x + (z @ (step * d)).reshape(-1, 2)
            if energy.value(trial) <= f + 1e-4 * step * float(g @ d):
                break
            step *= 0.5
        x = trial
    return x


def dynamics(spacing: float, contact: str, steps: int = 60) -> dict[str, Any]:
    """Each quasi_newton step of a run with contact against the exact step from the same start (module doc)."""
    from ..core.contact.tool import ToolPose  # noqa: PLC0415
    from ..core.physics import quasi_newton as qn  # noqa: PLC0415
    from .material_reference import MembraneEnergy  # noqa: PLC0415

    values = {"dt": 0.01, "damping": 20.0, "gravity": -GRAVITY, "boundary_y_top": math.nan,
              "boundary_y_bottom": 1e-9, "contact_model": contact, "contact_margin": 0.0, "tool_shape": "box",
              "tool_length": 0.02, "tool_width": 0.01, **BLOCK, "material": "neo_hookean"}
    sim = Simulation.from_config(resolve_config(values, source="--set"), mesh=mesh_rectangle(WIDTH, HEIGHT, spacing))
    n = sim.model.n_particles
    floor = 1e-9 * math.sqrt(n)
    errors, its, wrong_sign, excluded, worst, times = [], [], 0, 0, [], []
    top = HEIGHT + 0.005
    for k in range(steps):
        # press 1.5 mm over the first third, drag 1 cm sideways over the second, hold
        a = min(1.0, k / (steps / 3))
        b = min(1.0, max(0.0, (k - steps / 3) / (steps / 3)))
        pose = ToolPose(0.04 + 0.01 * b, top - 1.5e-3 * a + 1e-4, 0.0)
        start = sim.state.copy()
        r = sim.step(pose)
        its.append(r.solve_iterations)
        times.append(r.timings["solve"])
        energy = MembraneEnergy(sim.model, r.x_pred, sim.params.dt)
        ms = sim.solver.material_solve
        fixed = (sim.model.particle_inv_mass == 0.0) | (ms.kind == qn.CORNER)
        if contact == "paper" and r.held_idx.size:
            fixed[r.held_idx] = True
        held = np.flatnonzero((ms.kind == qn.TOOL) | (ms.kind == qn.LINE) | (ms.kind == qn.EDGE))
        normal = ms.normal[held].copy()
        # start: x*, with the held particles where the solve put them (on the tool's surface, their lines)
        x_init = r.x_pred.copy()
        x_init[held] = sim.state.particle_q[held]
        x_init[ms.kind == qn.CORNER] = sim.state.particle_q[ms.kind == qn.CORNER]
        x_ref = _constrained_minimiser(energy, x_init, fixed, held, normal)
        g = energy.gradient(x_ref)
        push = (g[held] * normal).sum(axis=1)  # the held particle's gradient along its normal: > 0 pushes
        wrong_sign += int(np.count_nonzero(push < -1e-9 * max(float(np.abs(g).max()), 1e-300)))
        motion = float(np.linalg.norm(x_ref - start.particle_q))
        if motion <= floor:
            excluded += 1
            continue
        errors.append(float(np.linalg.norm(sim.state.particle_q - x_ref)) / motion)
        worst.append((errors[-1], k, r.solve_iterations, r.solve_residual, r.solve_converged))
    return {"contact": contact, "spacing_mm": 1e3 * spacing, "particles": n, "steps": steps,
            "steps_measured": len(errors), "err_step_median": float(np.median(errors)) if errors else math.nan,
            "err_step_max": float(np.max(errors)) if errors else math.nan,
            "iterations_median": float(np.median(its)), "iterations_max": int(np.max(its)),
            "solve_ms_median": 1e3 * float(np.median(times)), "solve_ms_max": 1e3 * float(np.max(times)),
            "wrong_sign_holds": wrong_sign, "worst_steps": sorted(worst, reverse=True)[:3],
            "unconverged_steps": sum(1 for w in worst if not w[4]),
            "err_step_max_converged": max((w[0] for w in worst if w[4]), default=math.nan)}


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
    punch_ref = fem.flat_punch(WIDTH, HEIGHT, BLOCK["young_modulus"], BLOCK["poisson_ratio"], BLOCK["thickness"],
                               depth=4e-4).force
    punch_rows = []
    for spacing in spacings:
        for variant in ("xpbd 10x10", "quasi_newton"):
            print(f"  punch, {variant} at h = {1e3 * spacing:g} mm ...", flush=True)
            row = punch(variant, spacing)
            row["err_force"] = row["force_n"] / punch_ref - 1.0
            punch_rows.append(row)
    dyn_rows = []
    for spacing in spacings[:2]:
        for contact in ("projection",):
            print(f"  dynamics, {contact} contact at h = {1e3 * spacing:g} mm (exact steps by Newton) ...", flush=True)
            dyn_rows.append(dynamics(spacing, contact, steps=30 if quick else 60))
    load = os.getloadavg()[0]
    write_csv(out / "material_speed.csv", rows)
    write_csv(out / "material_accuracy_punch.csv", punch_rows)
    write_csv(out / "material_dynamics.csv", dyn_rows)
    plot(out / "material_speed.png", rows)
    cols = ["variant", "spacing_mm", "particles", "solve_ms_median", "vs_paper_pbd", "solve_ms_mean", "solve_ms_max",
            "err_sag", "rest_time_s",
            "iterations_median", "iterations_max", "solve_residual_max"]
    print(f"hanging block, dt 10 ms, {steps} steps, FEM mean sag {ref.mean_sag:.6g} m; load {load:.2f} at the end")
    print(format_table(rows, cols))
    print(f"\npunch 0.4 mm, FEM force {punch_ref:.6g} N:")
    print(format_table(punch_rows, ["variant", "spacing_mm", "particles", "force_n", "err_force", "rest_time_s",
                                    "solve_ms_median", "penetrating"]))
    print("\ndynamics (quasi_newton): each step against the exact implicit Euler step from the same start:")
    print(format_table(dyn_rows, ["contact", "spacing_mm", "particles", "steps_measured", "err_step_median",
                                  "err_step_max", "iterations_median", "iterations_max", "solve_ms_median",
                                  "solve_ms_max", "wrong_sign_holds"]))
    print(f"wrote {out / 'material_speed.csv'}, material_accuracy_punch.csv, material_dynamics.csv, "
          f"{out / 'material_speed.png'}")
    return 0
