"""``tissue-sim bench solver``: the speed of every method on meshes of 500 to 20k particles.

For each mesh (a 1 m x 0.5 m strip, ``mesh_rectangle``, pinned along its top
and bottom rows, sagging under gravity) and each method it times single solver
steps (``Solver.step``: prediction, constraint solve, velocity, boundary,
residual; 30 iterations unless ``--iterations``; stepped by a ``Simulation``,
timed by its report's ``timings["solve"]``) and reports the median:

* ms per step and steps per second;
* ns per constraint projection (step time / (constraints x iterations x substeps)); for the
  neo-Hookean material (``material_*`` rows) a projection is one element's (its three rows: the
  deviatoric pair and the hydrostatic one), and ``xpbd_distance`` / ``xpbd_area`` time each
  constraint kernel alone, so the three kernels stand side by side;
* the real-time factor at dt = 0.01 s (simulated time per wall time);
* ``x_numpy``: how many times faster per projection than the vectorised NumPy
  Jacobi baseline (:mod:`~tissue_sim_ros.bench.numpy_baseline`) measured in the
  same run on the same mesh.

It also runs the paper-sized scene (the shipped default image, 320 particles,
two bodies, boundary lines, the authors' 0.8 m box tool) along experiment a's
trajectory and, over the steps with the tool in contact, reports the contact
model's cost (``timings['contact']``) against the whole ``Simulation.step``.

Timings are medians over ``--steps`` steps after two warm-up steps (the first
call compiles or loads the numba cache). Other processes on the machine slow
every method down, the multi-threaded ones most (a thread waiting at a
barrier for a descheduled partner): the 1-minute load average when each row
was measured is written to the CSV (``load_1min``) and the range is printed,
so numbers from a busy machine can be recognised. Writes ``solver.csv`` and
``solver.png``.
"""
from __future__ import annotations

import csv
import functools
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numba
import numpy as np

from ..core.config import Config, method_options, resolve_config
from ..core.errors import InputError
from ..core.mesh import TissueMesh, mesh_rectangle
from ..core.physics.model import Model
from ..core.physics.solvers import Solver
from ..core.sim.simulation import Simulation
from .numpy_baseline import NumpyJacobiSolver

SIZES = (500, 2000, 8000, 20000)
QUICK_SIZES = (150, 500)
DT = 0.01


#: The material rows' tissue: a stiff membrane (1 MPa) so the 1 m strip sags little under gravity;
#: one substep, so that its iterations equal the constraint rows' (so the two compare cost per constraint row).
MATERIAL = dict(method_options("xpbd"), material="neo_hookean", young_modulus=1e6, poisson_ratio=0.45,
                thickness=0.005, density=1000.0)


@dataclass(frozen=True)
class Method:
    """One row kind of the table: parameters and solver options."""

    name: str
    label: str
    params: dict[str, Any]
    solver: dict[str, Any] = field(default_factory=dict)
    numpy: bool = False


# the method fields by core/config.py's one alias rule (method_options: xpbd_substep = 30 substeps x 1 iteration);
# a row without iterations gets --iterations
PBD, PBD_JACOBI, XPBD, XPBD_JACOBI = (method_options(m) for m in ("pbd", "pbd_jacobi", "xpbd", "xpbd_jacobi"))
METHODS = (
    Method("pbd_gs", "paper PBD, Gauss-Seidel, serial", PBD, dict(parallel=False)),
    Method("pbd_jacobi", "paper PBD, Jacobi (averaged)", PBD_JACOBI),
    Method("xpbd_gs", "XPBD Gauss-Seidel, serial (mesh order, wavefront schedule)", XPBD, dict(parallel=False)),
    Method("xpbd_gs_stored", "XPBD Gauss-Seidel, serial, plain mesh-order loop", XPBD,
           dict(parallel=False, order="stored")),
    Method("xpbd_gs_colour", "XPBD Gauss-Seidel, colour order, 1 thread", XPBD, dict(parallel=False, order="colour")),
    Method("xpbd_gs_parallel", "XPBD Gauss-Seidel, partitioned, all threads", XPBD, dict(parallel=True)),
    Method("xpbd_gs_par_colour", "XPBD Gauss-Seidel, coloured, all threads", XPBD,
           dict(parallel=True, parallel_mode="colour")),
    Method("xpbd_gs_auto", "XPBD Gauss-Seidel, default choice", XPBD),
    Method("xpbd_jacobi", "XPBD Jacobi (stiffness-aware relaxation)", XPBD_JACOBI),
    Method("xpbd_substep", "XPBD, 30 substeps x 1 iteration", method_options("xpbd_substep")),
    Method("numpy_jacobi", "NumPy XPBD Jacobi (baseline)", XPBD_JACOBI, numpy=True),
    # each kernel on its own (the other constraint type off), and the material's elements
    Method("xpbd_distance", "XPBD GS serial, distance constraints only", dict(XPBD, stiffness_area=0.0),
           dict(parallel=False)),
    Method("xpbd_area", "XPBD GS serial, area constraints only", dict(XPBD, stiffness_spring=0.0),
           dict(parallel=False)),
    Method("material_gs", "neo-Hookean elements, GS serial (one projection = 3 rows of an element)",
           dict(MATERIAL, substeps=1), dict(parallel=False)),
    Method("material_gs_parallel", "neo-Hookean elements, GS partitioned, all threads", dict(MATERIAL, substeps=1),
           dict(parallel=True)),
    Method("material_jacobi", "neo-Hookean elements, Jacobi", dict(MATERIAL, substeps=1, scheme="jacobi")),
)

COLUMNS = ("scene", "particles", "constraints", "method", "iterations", "substeps", "threads", "steps_timed",
           "ms_per_step", "steps_per_s", "ns_per_projection", "realtime_factor", "x_numpy",
           "contact_ms", "total_ms", "contact_share", "load_1min")


def strip_for(n_target: int) -> TissueMesh:
    """A 1 m x 0.5 m strip whose particle count is close to ``n_target``: (nx + 1)(nx / 2 + 1) ~ n."""
    nx = max(2, int(round((-3 + math.sqrt(9 + 8 * (n_target - 1))) / 2)))  # (nx+1)(nx/2+1) = n
    nx += nx % 2
    return mesh_rectangle(1.0, 0.5, 1.0 / nx)


def strip_config(mesh: TissueMesh, values: dict[str, Any]) -> Config:
    """The strip's configuration: the shipped parameters with ``values`` (a row's, iterations included), one
    substep unless given, dt :data:`DT`, and the strip's top and bottom rows pinned (pin lines at its rest
    extremes, no boundary lines)."""
    y = mesh.vertices[:, 1]
    return resolve_config({"substeps": 1, **values, "dt": DT, "pin_y_bottom": float(y.min()) + 1e-9,
                           "pin_y_top": float(y.max()) - 1e-9, "boundary_y_bottom": math.nan,
                           "boundary_y_top": math.nan}, source="bench solver strip")


def strip_model(mesh: TissueMesh, values: dict[str, Any]) -> Model:
    """The strip's Model (:func:`strip_config`)."""
    return Model.from_mesh(mesh, strip_config(mesh, values).sim)


def time_solver(model: Model, method: Method, steps: int) -> tuple[float, int, int]:
    """Median seconds of one solver step, projections per step and threads used, stepping the strip from rest
    (a Simulation without a tool; each step's ``timings["solve"]``)."""
    sim = Simulation(model, solver=NumpyJacobiSolver if method.numpy else functools.partial(Solver, **method.solver))
    for _ in range(2):  # compile / load the cache, touch the workspaces
        sim.step()
    times = np.empty(steps)
    diverged = False
    for k in range(steps):
        report = sim.step()
        times[k] = report.timings["solve"]
        diverged |= report.diverged
    if diverged:
        raise RuntimeError(f"{method.name} diverged on {model.n_particles} particles")
    return float(np.median(times)), sim.solver.n_projections_per_step, _threads(sim.solver)


def _threads(solver: Any) -> int:
    return numba.get_num_threads() if getattr(solver, "parallel", False) else 1


def paper_scene_rows(methods: list[Method], iterations: int, steps: int, progress) -> list[dict[str, Any]]:
    """Experiment a on the default scene: solve and contact cost over the steps in contact."""
    from ..core.timing.trajectories import experiment_a  # noqa: PLC0415

    rows = []
    for method in methods:
        flat = {"substeps": 1, "iterations": iterations, **method.params}
        cfg = resolve_config(flat, source=f"bench solver method {method.name}")
        sim = Simulation.from_config(cfg, solver=NumpyJacobiSolver if method.numpy
                                     else functools.partial(Solver, **method.solver))
        traj = experiment_a(sim.tool, sim.params.dt)
        solve, contact, total = [], [], []
        for pose, twist in traj.steps(sim.params.dt):
            report = sim.step(pose, twist)
            if report.n_contact_particles > 0:
                solve.append(report.timings["solve"])
                contact.append(report.timings["contact"])
                total.append(report.timings["total"])
                if len(solve) >= steps:
                    break
        progress.update(1)
        n_proj = (sim.model.n_edges + sim.model.n_triangles) * sim.params.iterations * sim.params.substeps
        if not solve:
            rows.append(dict(scene="paper", particles=sim.model.n_particles, method=method.name,
                             contact_ms="n/a (no contact along experiment a)"))
            continue
        med = float(np.median(solve))
        rows.append(dict(
            scene=f"paper ({sim.params.contact_model} contact)", particles=sim.model.n_particles,
            load_1min=os.getloadavg()[0],
            constraints=sim.model.n_edges + sim.model.n_triangles, method=method.name,
            iterations=sim.params.iterations, substeps=sim.params.substeps, threads=_threads(sim.solver),
            steps_timed=len(solve), ms_per_step=1e3 * med, steps_per_s=1.0 / med, ns_per_projection=1e9 * med / n_proj,
            realtime_factor=DT / float(np.median(total)), contact_ms=1e3 * float(np.median(contact)),
            total_ms=1e3 * float(np.median(total)),
            contact_share=float(np.median(np.asarray(contact) / np.asarray(total)))))
    return rows


def run(out: str | Path, *, sizes: Sequence[int] | None = None, steps: int | None = None, iterations: int = 30,
        quick: bool = False) -> int:
    """Time every method on every strip size and the paper scene; print, write solver.csv/png into ``out``.

    Parameters
    ----------
    out : str or Path
        Output directory (created).
    sizes : sequence of int, optional
        Approximate particle counts (default :data:`SIZES`; ``quick``: :data:`QUICK_SIZES`).
    steps : int, optional
        Steps timed per method and size (default 20; ``quick`` 3).
    iterations : int
        Solver iterations per step.
    quick : bool
        Small sizes, few steps (smoke test).

    Returns
    -------
    int
        0.
    """
    from tqdm import tqdm  # noqa: PLC0415

    timed_steps = steps
    sizes = sizes or (QUICK_SIZES if quick else SIZES)
    steps = timed_steps if timed_steps is not None else (3 if quick else 20)
    if steps < 1:
        raise InputError(f"--steps={steps}: expected at least 1 step")
    if iterations < 1:
        raise InputError(f"--iterations={iterations}: expected at least 1 iteration")
    for s in sizes:
        if s < 4:
            raise InputError(f"--sizes {s}: expected particle counts >= 4")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)

    rows: list[dict[str, Any]] = []
    paper_methods = [m for m in METHODS if m.name in ("pbd_gs", "xpbd_gs", "xpbd_jacobi", "numpy_jacobi")]
    progress = tqdm(total=len(sizes) * len(METHODS) + len(paper_methods) + 1, desc="bench solver", unit="run")
    for size in sizes:
        mesh = strip_for(size)
        size_rows = []
        for method in METHODS:
            params = dict(method.params)
            params.setdefault("iterations", iterations)
            model = strip_model(mesh, params)
            # the NumPy baseline is much slower: fewer steps keep the run short, the median stays robust
            n_steps = max(3, steps // 4) if method.numpy else steps
            progress.set_postfix_str(f"{model.n_particles} particles, {method.name}")
            med, n_proj, threads = time_solver(model, method, n_steps)
            progress.update(1)
            size_rows.append(dict(scene="strip", particles=model.n_particles, load_1min=os.getloadavg()[0],
                                  constraints=n_proj // (model.params.iterations * model.params.substeps), method=method.name,
                                  iterations=model.params.iterations, substeps=model.params.substeps, threads=threads,
                                  steps_timed=n_steps, ms_per_step=1e3 * med, steps_per_s=1.0 / med,
                                  ns_per_projection=1e9 * med / n_proj, realtime_factor=DT / med))
        base = next(r for r in size_rows if r["method"] == "numpy_jacobi")["ns_per_projection"]
        for r in size_rows:
            r["x_numpy"] = base / r["ns_per_projection"]
        rows += size_rows

    paper = paper_scene_rows(paper_methods + [Method("xpbd_gs_projection", "XPBD GS, projection contact",
                                                     dict(method="xpbd", contact_model="projection"))],
                             iterations, steps if not quick else 5, progress)
    numpy_paper = next((r for r in paper if r["method"] == "numpy_jacobi" and "ns_per_projection" in r), None)
    for r in paper:
        if numpy_paper is not None and "ns_per_projection" in r:
            r["x_numpy"] = numpy_paper["ns_per_projection"] / r["ns_per_projection"]
    rows += paper
    progress.close()

    write_csv(out / "solver.csv", rows)
    print_table(rows)
    print_summary(rows)
    plot(out / "solver.png", rows)
    print(f"wrote {out / 'solver.csv'} and {out / 'solver.png'}")
    return 0


def write_csv(path: Path, rows: list[dict[str, Any]], columns: tuple[str, ...] = COLUMNS) -> None:
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns)
        writer.writeheader()
        for r in rows:
            writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})


def _fmt(v: Any, spec: str) -> str:
    return format(v, spec) if isinstance(v, (int, float)) else (str(v) if v is not None else "")


def print_table(rows: list[dict[str, Any]]) -> None:
    header = (f"{'scene':<24} {'N':>6} {'method':<20} {'thr':>3} {'ms/step':>9} {'steps/s':>9} {'ns/proj':>8} "
              f"{'RTF':>7} {'x NumPy':>8} {'contact ms':>10} {'share':>6}")
    print(header)
    print("-" * len(header))
    for r in rows:
        print(f"{r['scene']:<24} {r['particles']:>6} {r['method']:<20} {_fmt(r.get('threads'), '>3')} "
              f"{_fmt(r.get('ms_per_step'), '>9.3f')} {_fmt(r.get('steps_per_s'), '>9.1f')} "
              f"{_fmt(r.get('ns_per_projection'), '>8.2f')} {_fmt(r.get('realtime_factor'), '>7.2f')} "
              f"{_fmt(r.get('x_numpy'), '>8.1f')} {_fmt(r.get('contact_ms'), '>10.3f')} "
              f"{_fmt(r.get('contact_share'), '>6.1%')}")


def print_summary(rows: list[dict[str, Any]]) -> None:
    """The numbers the targets are about, from this run."""
    strip = [r for r in rows if r["scene"] == "strip"]
    by = {(r["particles"], r["method"]): r for r in strip}
    sizes = sorted({r["particles"] for r in strip})
    loads = [r["load_1min"] for r in rows if isinstance(r.get("load_1min"), float)] or [math.nan]
    try:
        layer = numba.threading_layer()
    except ValueError:  # no parallel region has run
        layer = "unused"
    print(f"\nsummary (medians of this run; 1-min load average {min(loads):.1f}-{max(loads):.1f} "
          f"on {os.cpu_count()} CPUs, {numba.get_num_threads()} numba threads, layer {layer}):")
    for n in sizes:
        serial, par = by.get((n, "xpbd_gs")), by.get((n, "xpbd_gs_parallel"))
        par_c = by.get((n, "xpbd_gs_par_colour"))
        stored, auto = by.get((n, "xpbd_gs_stored")), by.get((n, "xpbd_gs_auto"))
        if serial and par and stored and auto and par_c:
            print(f"  {n:>6} particles: XPBD GS serial {serial['ns_per_projection']:.2f} ns/projection "
                  f"(plain mesh-order loop {stored['ns_per_projection']:.2f}); all threads: parts "
                  f"x{serial['ms_per_step'] / par['ms_per_step']:.2f}, colours x{serial['ms_per_step'] / par_c['ms_per_step']:.2f} "
                  f"vs serial; default uses {auto['threads']} thread(s); serial x{serial['x_numpy']:.1f} NumPy")
        dist, area, mat = by.get((n, "xpbd_distance")), by.get((n, "xpbd_area")), by.get((n, "material_gs"))
        if serial and dist and area and mat:
            print(f"  {n:>6} particles: ns per projection: distance {dist['ns_per_projection']:.2f}, area "
                  f"{area['ns_per_projection']:.2f}, material element {mat['ns_per_projection']:.2f}; a material step "
                  f"costs x{mat['ms_per_step'] / serial['ms_per_step']:.2f} the constraints' (serial GS, "
                  f"{mat['iterations']} iterations each)")
    for r in rows:
        if r["scene"].startswith("paper") and "ms_per_step" in r:
            print(f"  paper scene {r['method']:<20} solve {r['ms_per_step']:.3f} ms, step {r['total_ms']:.3f} ms "
                  f"(contact {r['contact_ms']:.3f} ms = {r['contact_share']:.0%}), {r['realtime_factor']:.0f}x real time")


def plot(path: Path, rows: list[dict[str, Any]]) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    strip = [r for r in rows if r["scene"] == "strip"]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(13, 5))
    colours = plt.get_cmap("tab20").colors
    markers = "osD^v<>ph*X"
    for k, m in enumerate(METHODS):
        rs = sorted((r for r in strip if r["method"] == m.name), key=lambda r: r["particles"])
        if not rs:
            continue
        n = [r["particles"] for r in rs]
        colour = colours[(2 * k) % 20 + (2 * k) // 20]  # dark shades first, then light ones
        style = dict(ls="--" if m.numpy else "-", marker=markers[k % len(markers)], color=colour, label=m.label)
        ax1.plot(n, [r["ns_per_projection"] for r in rs], **style)
        ax2.plot(n, [r["ms_per_step"] for r in rs], **style)
    ax2.axhline(1e3 * DT, color="k", lw=0.8, ls=":", label="real time (dt = 10 ms)")
    for ax in (ax1, ax2):
        ax.set_xscale("log")
        ax.set_xlabel("particles")
        ax.grid(True, which="both", alpha=0.3)
    ax1.set_yscale("log")
    ax1.set_ylabel("ns per constraint projection (median)")
    ax2.set_yscale("log")
    ax2.set_ylabel("ms per step (median)")
    ax1.set_title("cost per projection")
    loads = [r["load_1min"] for r in strip if isinstance(r.get("load_1min"), float)] or [math.nan]
    ax2.set_title(f"cost per step ({numba.get_num_threads()} threads; load average {min(loads):.1f}-{max(loads):.1f})")
    ax2.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
