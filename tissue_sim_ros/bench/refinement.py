"""``tissue-sim bench refinement``: the material model, run to rest, against the static FEM reference.

Two problems with a closed-form-free, independently computed answer
(:mod:`~tissue_sim_ros.bench.fem_reference`: linear plane-stress P2 FEM,
scikit-fem, converged by its own refinement to ~3e-4):

* **hanging strip**: 10 cm wide, 4 cm tall, top edge pinned, gravity; E 50 kPa,
  nu 0.45, 1 mm thick, 1000 kg/m^3 (nominal strain rho g H / E = 0.8 %).
  Measured: the mean sag (the lumped-mass mean of -u_y, i.e. the area mean),
  the largest sag, and the displacement field's RMS error over the particles
  (the FEM evaluated at each particle's rest position), relative to the FEM.
* **flat punch**: the same strip, bottom edge pinned, no gravity, pressed
  0.2 mm down (0.5 %) by a rigid frictionless plate: a box tool wider than
  the strip, ``contact_model: projection`` with no margin. Measured: the
  plate's force (``StepReport.reaction_force``, the reaction from the
  contact corrections) against the FEM's.

The simulator runs each mesh spacing (``mesh_rectangle``, right triangles)
from rest until no particle moves faster than ``--rest-speed`` (a viscous
``damping`` only shortens the way there: the rest state does not depend on
it). Its P1 elements converge at O(spacing^2) to the linear answer plus the
neo-Hookean model's O(strain) nonlinearity, so the errors fall with each
refinement toward a floor of about the strain x the answer.

Convergence in dt, on the middle spacing: (1) the rest state at each dt
against the FEM (the static answer of a converged solve does not depend on
dt: what changes is how far the fixed iterations per substep get); (2) the
dynamics: the strip released from rest, its mean displacement at t = 8 ms
against the run at the smallest dt (implicit Euler: first order).

Writes ``refinement.csv`` (one row per run), ``refinement.png`` (error
against spacing and against dt, log-log) and prints the table. Solver
settings (``--set substeps=..., iterations=..., scheme=...``) go through the
front door like every command's.
"""
from __future__ import annotations

import csv
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from ..core.config import resolve_config
from ..core.contact.tool import ToolPose
from ..core.errors import InputError
from ..core.mesh import mesh_rectangle
from ..core.sim.simulation import Simulation
from . import fem_reference as fem

WIDTH, HEIGHT = 0.10, 0.04
MATERIAL = {"material": "neo_hookean", "young_modulus": 50e3, "poisson_ratio": 0.45, "thickness": 1e-3,
            "density": 1000.0}
GRAVITY = 9.8
DEPTH = 2e-4
#: the plate: a box much wider than the strip, 1 cm thick, its lower face DEPTH below the strip's top
PLATE = {"tool_shape": "box", "tool_length": 3 * WIDTH, "tool_width": 0.01}
SPACINGS = (0.01, 0.005, 0.0025, 0.00125)
DTS = (0.004, 0.002, 0.001, 0.0005)
DYNAMIC_T_END = 0.008


@dataclass
class RestRun:
    """A simulation run until rest."""

    sim: Simulation
    report: Any
    steps: int
    wall: float
    """Wall time from the first step to rest [s]."""
    at_rest: bool


def _config(problem: str, dt: float, overrides: dict[str, Any], damping: float):
    values = dict(MATERIAL, dt=dt, damping=damping)
    if problem == "hanging_strip":
        values.update(gravity=-GRAVITY, boundary_y_top=HEIGHT - 1e-9, boundary_y_bottom=math.nan,
                      contact_model="none")
    else:
        values.update(gravity=0.0, boundary_y_top=math.nan, boundary_y_bottom=1e-9, contact_model="projection",
                      contact_margin=0.0, **PLATE)
    values.update(overrides)
    return resolve_config(values, source="--set")


def run_to_rest(sim: Simulation, pose: ToolPose | None, rest_speed: float, max_steps: int) -> RestRun:
    """Step until no particle moves faster than ``rest_speed`` [m/s] (at least 20 steps)."""
    t0 = time.perf_counter()
    report = None
    for k in range(1, max_steps + 1):
        report = sim.step(pose)
        if k > 20 and float(np.abs(sim.state.particle_qd).max()) < rest_speed:
            return RestRun(sim, report, k, time.perf_counter() - t0, True)
    return RestRun(sim, report, max_steps, time.perf_counter() - t0, False)


def strip_errors(sim: Simulation, ref: fem.FemSolution) -> dict[str, float]:
    """Relative errors of the hanging strip's mean sag, max sag and displacement field against the FEM."""
    m = sim.model
    u = sim.state.particle_q - m.particle_q0
    w = m.particle_mass
    mean_sag = float(-(w * u[:, 1]).sum() / w.sum())  # lumped masses: the area mean of -u_y
    max_sag = float(-u[:, 1].min())
    u_ref = ref.displacement(m.particle_q0)
    field = float(np.sqrt(((u - u_ref) ** 2).sum(axis=1).mean() / (u_ref ** 2).sum(axis=1).mean()))
    return {"mean_sag": mean_sag, "max_sag": max_sag,
            "err_mean_sag": mean_sag / ref.mean_sag - 1.0, "err_max_sag": max_sag / ref.max_sag - 1.0,
            "err_field": field}


def measure(problem: str, spacing: float, dt: float, overrides: dict[str, Any], *, damping: float,
            rest_speed: float, max_steps: int) -> dict[str, Any]:
    """One run to rest on one mesh: errors against the FEM, steps and wall time to rest."""
    cfg = _config(problem, dt, overrides, damping)
    sim = Simulation.from_config(cfg, mesh=mesh_rectangle(WIDTH, HEIGHT, spacing))
    p = sim.params
    row: dict[str, Any] = {"problem": problem, "spacing": spacing, "dt": dt, "substeps": p.substeps,
                           "iterations": p.iterations, "scheme": p.scheme, "particles": sim.model.n_particles}
    if problem == "hanging_strip":
        ref = fem.hanging_strip(WIDTH, HEIGHT, p.young_modulus, p.poisson_ratio, p.thickness, p.density, GRAVITY)
        rest = run_to_rest(sim, None, rest_speed, max_steps)
        row.update(strip_errors(sim, ref))
        row["err"] = row["err_mean_sag"]
    else:
        ref = fem.flat_punch(WIDTH, HEIGHT, p.young_modulus, p.poisson_ratio, p.thickness, DEPTH)
        pose = ToolPose(0.5 * WIDTH, HEIGHT + 0.5 * PLATE["tool_width"] - DEPTH, 0.0)
        rest = run_to_rest(sim, pose, rest_speed, max_steps)
        force = float(rest.report.reaction_force[1])
        row.update(force=force, err_force=force / ref.force - 1.0, err=force / ref.force - 1.0)
    row.update(ref_rel_error=ref.rel_error, steps_to_rest=rest.steps, at_rest=rest.at_rest,
               wall_to_rest_s=rest.wall, ms_per_step=1e3 * rest.wall / rest.steps,
               inverted=int(rest.report.n_inverted))
    return row


def dynamic_displacement(dt: float, spacing: float, overrides: dict[str, Any]) -> float:
    """Mean vertical displacement [m] of the strip released from rest under gravity, at t = 8 ms (no damping)."""
    cfg = _config("hanging_strip", dt, overrides, 0.0)
    sim = Simulation.from_config(cfg, mesh=mesh_rectangle(WIDTH, HEIGHT, spacing))
    for _ in range(int(round(DYNAMIC_T_END / dt))):
        sim.step()
    m = sim.model
    return float((m.particle_mass * (sim.state.particle_q[:, 1] - m.particle_q0[:, 1])).sum() / m.particle_mass.sum())


def write_csv(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    keys: list[str] = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow(r)


def plot(path: Path, spacing_rows: Sequence[dict[str, Any]], dt_rows: Sequence[dict[str, Any]],
         dyn_rows: Sequence[dict[str, Any]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.4))
    strip = [r for r in spacing_rows if r["problem"] == "hanging_strip"]
    punch = [r for r in spacing_rows if r["problem"] == "flat_punch"]
    for rows, key, label, style in ((strip, "err_mean_sag", "strip: mean sag", "o-"),
                                    (strip, "err_max_sag", "strip: max sag", "s--"),
                                    (strip, "err_field", "strip: displacement field (RMS)", "^:"),
                                    (punch, "err_force", "punch: plate force", "D-")):
        if rows:
            a1.loglog([1e3 * r["spacing"] for r in rows], [max(abs(r[key]), 1e-6) for r in rows], style, label=label)
    if strip:
        h = np.array([1e3 * r["spacing"] for r in strip])
        e0 = abs(strip[0]["err_mean_sag"])
        a1.loglog(h, e0 * (h / h[0]) ** 2, color="0.6", lw=0.8, label="slope 2")
    a1.axhline(0.02, color="#c62828", lw=0.8, ls="--", label="2 %")
    a1.set_xlabel("mesh spacing [mm]")
    a1.set_ylabel("|relative error| against the FEM")
    a1.set_title("refinement: run to rest vs scikit-fem P2", fontsize=10)
    a1.grid(alpha=0.3, which="both")
    a1.legend(fontsize=7)
    if dt_rows:
        a2.loglog([1e3 * r["dt"] for r in dt_rows], [max(abs(r["err"]), 1e-6) for r in dt_rows], "o-",
                  label=f"rest, strip mean sag vs FEM ({1e3 * dt_rows[0]['spacing']:g} mm)")
    if dyn_rows:
        a2.loglog([1e3 * r["dt"] for r in dyn_rows], [max(r["err_dynamic"], 1e-9) for r in dyn_rows], "s--",
                  label=f"dynamics: mean displacement at {1e3 * DYNAMIC_T_END:g} ms vs smallest dt")
    a2.set_xlabel("dt [ms]")
    a2.set_ylabel("|relative error|")
    a2.set_title("convergence in dt", fontsize=10)
    a2.grid(alpha=0.3, which="both")
    a2.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run(out: str | Path, *, spacings: Sequence[float] = SPACINGS, dts: Sequence[float] = DTS,
        spacing_dt: float = 0.002, damping: float = 30.0, rest_speed: float = 1e-6, max_steps: int = 5000,
        overrides: Mapping[str, Any] | None = None, quick: bool = False) -> int:
    """Both studies against the FEM reference; print the tables, write refinement.csv/png into ``out``.

    Parameters
    ----------
    out : str or Path
        Output directory (created).
    spacings : sequence of float
        Mesh spacings [m] of the refinement study (``quick``: 20 and 10 mm).
    dts : sequence of float
        Time steps [s] of the dt study (``quick``: 4 and 2 ms).
    spacing_dt : float
        Time step of the refinement study [s].
    damping : float
        Viscous damping on the way to rest [1/s].
    rest_speed : float
        At rest: every particle slower than this [m/s].
    max_steps : int
        Give up on rest after this many steps (at least 21).
    overrides : mapping, optional
        Solver settings over the material's defaults (flat names, as ``--set``).
    quick : bool
        Two coarse spacings and two dts (smoke test).

    Returns
    -------
    int
        0, or 1 when a run did not come to rest within ``max_steps``.
    """
    overrides = dict(overrides or {})
    spacings = sorted(spacings, reverse=True)
    dts = sorted(dts, reverse=True)
    if quick:
        spacings, dts = [0.02, 0.01], [0.004, 0.002]
    if max_steps < 21:
        raise InputError(f"--max-steps {max_steps}: expected at least 21")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    kw = dict(damping=damping, rest_speed=rest_speed, max_steps=max_steps)
    spacing_rows = [dict(measure(problem, h, spacing_dt, overrides, **kw), study="spacing")
                    for problem in ("hanging_strip", "flat_punch") for h in spacings]
    mid = spacings[min(1, len(spacings) - 1)]
    dt_rows = [dict(measure("hanging_strip", mid, dt, overrides, **kw), study="dt_rest") for dt in dts]
    fine = dynamic_displacement(dts[-1] / 2, mid, overrides)
    dyn_rows = []
    for dt in dts:
        d = dynamic_displacement(dt, mid, overrides)
        dyn_rows.append({"study": "dt_dynamic", "problem": "hanging_strip", "spacing": mid, "dt": dt,
                         "mean_displacement": d, "reference_dt": dts[-1] / 2, "err_dynamic": abs(d / fine - 1.0)})
    rows = spacing_rows + dt_rows + dyn_rows
    write_csv(out / "refinement.csv", rows)
    plot(out / "refinement.png", spacing_rows, dt_rows, dyn_rows)
    from .accuracy import format_table  # noqa: PLC0415

    def pct(rows: list[dict[str, Any]], keys: Sequence[str]) -> list[dict[str, Any]]:
        return [{**r, **{k: f"{100 * r[k]:+.3f}%" for k in keys if k in r}} for r in rows]

    print("hanging strip (10 x 4 cm, E 50 kPa, nu 0.45, 1 mm, 1000 kg/m^3), run to rest vs the FEM:")
    strip = [r for r in spacing_rows if r["problem"] == "hanging_strip"]
    print(format_table(pct(strip, ("err_mean_sag", "err_max_sag", "err_field")),
                       ["spacing", "particles", "err_mean_sag", "err_max_sag", "err_field", "steps_to_rest",
                        "wall_to_rest_s", "at_rest"]))
    print(f"\nflat punch ({DEPTH * 1e3:g} mm, rigid frictionless plate), plate force vs the FEM:")
    punch = [r for r in spacing_rows if r["problem"] == "flat_punch"]
    print(format_table(pct(punch, ("err_force",)),
                       ["spacing", "particles", "force", "err_force", "steps_to_rest", "wall_to_rest_s", "at_rest"]))
    print(f"\nconvergence in dt (spacing {mid * 1e3:g} mm): rest sag vs the FEM; dynamics at "
          f"{DYNAMIC_T_END * 1e3:g} ms vs dt = {dts[-1] / 2:g} s")
    merged = [{"dt": a["dt"], "substeps": a["substeps"], "iterations": a["iterations"],
               "err_rest": f"{100 * a['err']:+.3f}%", "err_dynamic": f"{100 * b['err_dynamic']:.3f}%"}
              for a, b in zip(dt_rows, dyn_rows)]
    print(format_table(merged, ["dt", "substeps", "iterations", "err_rest", "err_dynamic"]))
    print(f"FEM reference's own error: {fem.hanging_strip().rel_error:.1e} (strip), "
          f"{fem.flat_punch().rel_error:.1e} (punch)")
    print(f"wrote {out / 'refinement.csv'}, {out / 'refinement.png'}")
    return 0 if all(r.get("at_rest", True) for r in rows) else 1
