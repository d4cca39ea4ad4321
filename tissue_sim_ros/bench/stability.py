"""``tissue-sim bench stability``: where each method and contact model fails.

A strip of tissue pinned along its bottom line is pushed down from above by a
box tool (experiment a's motion, on a small mesh) for a fixed number of steps.
The sweep covers the time step (1e-4 to 0.05 s), the stiffness (the paper's
to 1000x), the tool speed (0.001 to 0.2 m per step) and the mesh quality (a
regular mesh and one with sliver triangles), for every method and contact
model, and records the first failure of each run as found by
:mod:`~tissue_sim_ros.bench.failures`: non-finite values, energy growing
without bound, triangles staying inverted, the tool tunnelling through
tissue, or the constraint residual not falling with iterations.

Stiffness scale s multiplies the XPBD stiffnesses (``stiffness_spring``,
``stiffness_area``) and the paper's PBD coefficients (``k_spring``,
``k_area``), the latter capped at 1, their largest meaningful value.

Besides the methods as shipped, two variants kept to show documented
failures run in the sweep: XPBD Jacobi with one uniform relaxation factor of
1 (no relaxation) and PBD Jacobi summing instead of averaging corrections.

Writes ``stability.csv`` (one row per run), ``stability_<method>.png`` (a map
per method: dt x stiffness panels, tool speed x mesh quality cells, colour =
first failure) and prints a table of failure counts and the safe region.
"""
from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..core.config import BY_NAME, Config, method_options, resolve_config
from ..core.contact.tool import ToolPose, ToolShape
from ..core.errors import InputError
from ..core.health import Failure, FailureMonitor
from ..core.mesh import TissueMesh, mesh_from_arrays, mesh_rectangle
from ..core.physics.solvers import Solver
from ..core.sim.simulation import Simulation, StepDetail
from .accuracy import format_table, push_poses, write_csv
from .failures import FAILURE_KINDS, iteration_residuals, residual_falls

#: method name -> (its method by core/config.py's alias rule, further parameter changes, Solver options)
METHODS: dict[str, tuple[str, dict[str, Any], dict[str, Any]]] = {
    "pbd": ("pbd", {}, {}),
    "pbd_jacobi": ("pbd_jacobi", {}, {}),
    "xpbd": ("xpbd", {}, {}),
    "xpbd_jacobi": ("xpbd_jacobi", {}, {}),
    "xpbd_substep": ("xpbd_substep", {}, {}),
    "xpbd_jacobi_unrelaxed": ("xpbd_jacobi", {"relaxation": 1.0}, {"jacobi_relaxation": "uniform"}),
    "pbd_jacobi_summed": ("pbd_jacobi", {}, {"jacobi_average": False}),
}
CONTACT_MODELS = ("paper", "projection")
MESH_QUALITIES = ("regular", "slivers")
OUTCOMES = ("stable",) + FAILURE_KINDS


@dataclass(frozen=True)
class RunConfig:
    """One run of the sweep."""

    method: str
    contact_model: str
    dt: float
    stiffness_scale: float
    tool_speed: float
    """Tool speed [m per step]."""
    mesh_quality: str
    area_mode: str = "signed"
    iterations: int = 30
    n_steps: int = 40


def sliver_mesh(width: float, height: float, spacing: float, amount: float = 0.4, seed: int = 0) -> TissueMesh:
    """A strip whose interior vertices are moved at random by up to ``amount * spacing``.

    Moves that would invert a triangle are halved until none does, so the
    mesh is valid but full of slivers (with the defaults: minimum angle 4.8 deg on the sweep's strip,
    against 45 deg for the regular mesh).
    """
    base = mesh_rectangle(width, height, spacing)
    v = base.vertices.copy()
    tris = base.triangles
    rng = np.random.default_rng(seed)
    interior = np.flatnonzero(~base.boundary)
    for i in interior:
        move = rng.uniform(-1.0, 1.0, 2) * amount * spacing
        mine = tris[(tris == i).any(axis=1)]
        for _ in range(20):
            trial = v.copy()
            trial[i] += move
            a, b, c = trial[mine[:, 0]], trial[mine[:, 1]], trial[mine[:, 2]]
            area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
            if np.all(area2 > 1e-3 * spacing * spacing):
                v[i] = trial[i]
                break
            move *= 0.5
    return mesh_from_arrays(v, tris)


def min_angle_deg(mesh: TissueMesh) -> float:
    """Smallest interior angle of any triangle [deg]."""
    v = mesh.vertices
    t = mesh.triangles
    best = 180.0
    for k in range(3):
        a, b, c = v[t[:, k]], v[t[:, (k + 1) % 3]], v[t[:, (k + 2) % 3]]
        u, w = b - a, c - a
        cos = np.einsum("ij,ij->i", u, w) / (np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1))
        best = min(best, float(np.degrees(np.arccos(np.clip(cos, -1, 1))).min()))
    return best


STRIP = dict(width=1.0, height=0.3, spacing=0.05)


def make_mesh(quality: str) -> TissueMesh:
    """The sweep's strip, regular or with slivers."""
    if quality == "regular":
        return mesh_rectangle(STRIP["width"], STRIP["height"], STRIP["spacing"])
    if quality == "slivers":
        return sliver_mesh(STRIP["width"], STRIP["height"], STRIP["spacing"])
    raise InputError(f"mesh quality {quality!r}: expected one of {', '.join(MESH_QUALITIES)}")


#: The sweep's tool: a 0.4 m x 5 mm box.
TOOL = {"tool_shape": "box", "tool_length": 0.4, "tool_width": 0.005}


def run_config(cfg: RunConfig) -> tuple[Config, dict[str, Any]]:
    """The configuration and Solver options of a run: the shipped parameters with every value the sweep sets.

    The strip is pinned along its bottom line (no top line), the tool is :data:`TOOL`, and the stiffness
    scale multiplies the parameter table's (Table I's and the calibrated XPBD) stiffnesses.
    """
    if cfg.method not in METHODS:
        raise InputError(f"method {cfg.method!r}: expected one of {', '.join(METHODS)}")
    method, changes, solver_options = METHODS[cfg.method]
    s = cfg.stiffness_scale

    def table(name: str) -> float:
        return float(BY_NAME[name].default)

    values: dict[str, Any] = dict(
        dt=cfg.dt, contact_model=cfg.contact_model, area_mode=cfg.area_mode, iterations=cfg.iterations,
        substeps=1, boundary_y_bottom=0.5 * STRIP["spacing"], boundary_y_top=math.nan,
        k_spring=min(1.0, table("k_spring") * s), k_area=min(1.0, table("k_area") * s),
        stiffness_spring=table("stiffness_spring") * s, stiffness_area=table("stiffness_area") * s, **TOOL,
    )
    values.update(method_options(method))  # xpbd_substep: 30 substeps of 1 iteration
    values.update(changes)
    return resolve_config(values, source=f"bench stability run {cfg.method}"), solver_options


def tool_poses(mesh: TissueMesh, tool: ToolShape, speed: float, n_steps: int, travel: float = 0.1) -> list[ToolPose]:
    """The tool pushing down from 0.02 m above the strip at ``speed`` m per step, stopping after ``travel`` m

    (0.1 m: 0.08 m into the 0.3 m strip, a third of its height, then held).
    """
    moving = max(1, min(n_steps, int(math.ceil(travel / speed - 1e-9))))
    poses, _ = push_poses(mesh, tool, moving, speed)
    # the last move stops at the travel (a 0.2 m/step tool makes one 0.1 m jump)
    y_end = poses[0].y - min(travel, speed * moving)
    poses[-1] = ToolPose(poses[-1].x, max(poses[-1].y, y_end), poses[-1].yaw)
    return poses + [poses[-1]] * (n_steps - moving)


def run_one(cfg: RunConfig, mesh: TissueMesh | None = None, flip: Sequence[int] = ()) -> dict[str, Any]:
    """Run one configuration; return a CSV row with its first failure (``outcome``) and when.

    ``flip`` lists triangles whose first vertex is mirrored through the opposite
    edge at the start (an inverted start, for the area-mode check).
    """
    mesh = mesh if mesh is not None else make_mesh(cfg.mesh_quality)
    config, solver_options = run_config(cfg)
    sim = Simulation.from_config(config, mesh=mesh,
                                 solver=functools.partial(Solver, **solver_options) if solver_options else None)
    model, tool = sim.model, sim.tool
    state = sim.state
    for t in flip:
        i, j, k = model.tri_indices[t]
        if model.particle_inv_mass[i] > 0:
            mid = 0.5 * (state.particle_q[j] + state.particle_q[k])
            state.particle_q[i] = mid + 0.5 * (mid - state.particle_q[i])
    sim.set_state(state)
    poses = tool_poses(mesh, tool, cfg.tool_speed, cfg.n_steps)
    monitor = FailureMonitor(model, tool)
    # the residual check on the state where the tool first pushes (the hardest solve of the run)
    residuals: list[float] = []
    pose_prev = poses[0]
    sim.place_tool(pose_prev)
    for k in range(1, len(poses)):
        pose = poses[k]
        x_prev = sim.state.particle_q.copy()
        with np.errstate(all="ignore"):
            report = sim.step(pose, detail=not residuals)  # the step's start state and contacts, until checked
        speed = math.hypot(pose.x - pose_prev.x, pose.y - pose_prev.y) / cfg.dt
        if report.n_contact_particles and not report.diverged:
            # what drives the tissue is the contact rule: the paper's eq. (3) moves particles by up to alpha
            # per step whatever the tool's speed, so the energy bound uses the speed it imposed
            moved = sim.state.particle_q[report.contact_particles] - x_prev[report.contact_particles]
            speed = max(speed, float(np.sqrt((moved * moved).sum(axis=1)).max()) / cfg.dt)
        touching = cfg.contact_model != "none"  # without contact the tool is a ghost: nothing to tunnel
        failure = monitor.observe(k, x_prev, sim.state.particle_q, sim.state.particle_qd, k * cfg.dt,
                                  diverged=report.diverged, pose0=pose_prev if touching else None,
                                  pose1=pose if touching else None, tool_speed=speed if touching else 0.0)
        if not residuals and report.n_contact_particles > 0 and failure is None:
            residuals = _residual_check(sim, report.detail)
            # a residual held up by the contact (held particles make the constraints infeasible) stays flat;
            # a failing solver makes it rise with iterations
            if residuals and not residual_falls(residuals, min_drop=1.1):
                monitor.first = monitor.first or Failure(
                    "no_convergence", k, "residual at " + ", ".join(f"{r:.2g}" for r in residuals))
        pose_prev = pose
        if monitor.first is not None:
            break
    first = monitor.first
    return {
        "method": cfg.method, "contact_model": cfg.contact_model, "dt": cfg.dt, "stiffness_scale": cfg.stiffness_scale,
        "tool_speed": cfg.tool_speed, "mesh_quality": cfg.mesh_quality, "area_mode": cfg.area_mode,
        "outcome": first.kind if first else "stable", "failure_step": first.step if first else 0,
        "detail": first.detail if first else "", "max_kinetic_ratio": monitor.max_kinetic_ratio,
        "max_inverted": monitor.max_inverted, "n_tunnelled": monitor.n_tunnelled,
        "max_penetration": monitor.max_penetration,
        "residual_1": residuals[0] if residuals else math.nan,
        "residual_last": residuals[-1] if residuals else math.nan,
    }


def _residual_check(sim: Simulation, detail: StepDetail) -> list[float]:
    """Residuals of the step ``detail`` (its start state and contacts) solved again at 1, 4, 16, 64 iterations
    (substeps for the substep method) with the run's solver."""
    return iteration_residuals(sim, detail, (1, 4, 16, 64), "substeps" if sim.params.substeps > 1 else "iterations")


# ----------------------------------------------------------------------------- the sweep


@dataclass
class Sweep:
    dts: list[float]
    stiffness_scales: list[float]
    tool_speeds: list[float]
    mesh_qualities: list[str]
    methods: list[str]
    contact_models: list[str]
    n_steps: int


def make_sweep(quick: bool) -> Sweep:
    if quick:
        return Sweep(dts=[0.01], stiffness_scales=[1.0, 1000.0], tool_speeds=[0.001, 0.2],
                     mesh_qualities=["regular"], methods=["pbd", "xpbd", "xpbd_jacobi_unrelaxed"],
                     contact_models=["paper", "projection"], n_steps=8)
    return Sweep(dts=[1e-4, 1e-3, 0.01, 0.05], stiffness_scales=[1.0, 10.0, 100.0, 1000.0],
                 tool_speeds=[0.001, 0.01, 0.05, 0.2], mesh_qualities=list(MESH_QUALITIES), methods=list(METHODS),
                 contact_models=list(CONTACT_MODELS), n_steps=30)


OUTCOME_COLOURS = {"stable": "#d9f0d3", "nonfinite": "#000000", "energy_growth": "#d73027",
                   "inverted": "#fc8d59", "tunnelling": "#4575b4", "no_convergence": "#984ea3"}


def plot_method_map(path: Path, rows: Sequence[dict[str, Any]], method: str, sweep: Sweep) -> None:
    """One PNG per method: a panel per contact model x dt, cells = stiffness (rows) x (speed, mesh) (columns)."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    from matplotlib.colors import ListedColormap  # noqa: PLC0415
    from matplotlib.patches import Patch  # noqa: PLC0415

    cmap = ListedColormap([OUTCOME_COLOURS[o] for o in OUTCOMES])
    nr, nc = len(sweep.contact_models), len(sweep.dts)
    fig, axes = plt.subplots(nr, nc, figsize=(3.2 * nc + 1, 2.6 * nr + 1.2), squeeze=False)
    cols = list(itertools.product(sweep.tool_speeds, sweep.mesh_qualities))
    index = {(r["contact_model"], r["dt"], r["stiffness_scale"], r["tool_speed"], r["mesh_quality"]): r
             for r in rows if r["method"] == method and r["area_mode"] == "signed"}
    for a, cm in enumerate(sweep.contact_models):
        for b, dt in enumerate(sweep.dts):
            ax = axes[a][b]
            grid = np.full((len(sweep.stiffness_scales), len(cols)), np.nan)
            for i, s in enumerate(sweep.stiffness_scales):
                for j, (v, q) in enumerate(cols):
                    r = index.get((cm, dt, s, v, q))
                    if r is not None:
                        grid[i, j] = OUTCOMES.index(r["outcome"])
            ax.imshow(np.ma.masked_invalid(grid), cmap=cmap, vmin=-0.5, vmax=len(OUTCOMES) - 0.5, aspect="auto",
                      origin="lower")
            ax.set_xticks(range(len(cols)))
            ax.set_xticklabels([f"{v:g}\n{'sl' if q == 'slivers' else 'reg'}" for v, q in cols], fontsize=6)
            ax.set_yticks(range(len(sweep.stiffness_scales)))
            ax.set_yticklabels([f"{s:g}x" for s in sweep.stiffness_scales], fontsize=7)
            ax.set_title(f"{cm} contact, dt {dt:g} s", fontsize=8)
            if b == 0:
                ax.set_ylabel("stiffness", fontsize=8)
            if a == nr - 1:
                ax.set_xlabel("tool speed [m/step], mesh", fontsize=7)
    fig.legend(handles=[Patch(color=OUTCOME_COLOURS[o], label=o) for o in OUTCOMES], loc="lower center",
               ncol=3, fontsize=7, frameon=False)
    fig.suptitle(f"First failure per run: {method}", fontsize=10)
    fig.tight_layout(rect=(0, 0.09, 1, 0.95))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def inversion_rows(n_steps: int) -> list[dict[str, Any]]:
    """Start with inverted triangles, no tool: the paper's |area| keeps them, the signed area undoes them."""
    mesh = make_mesh("regular")
    rows = []
    flip = list(range(40, 60, 4))
    for method in ("pbd", "xpbd"):
        for area_mode in ("signed", "abs"):
            cfg = RunConfig(method, "none", 0.01, 1.0, 0.001, "regular", area_mode=area_mode, n_steps=n_steps)
            rows.append(run_one(cfg, mesh, flip=flip))
    return rows


def run(out: str | Path, *, quick: bool = False, jobs: int = 1, backend: str = "local",
        address: str | None = None) -> int:
    """Run the sweep; print the failure counts, write stability.csv and a map per method into ``out``; 0.

    The material's and the grasp's sweeps are their own (:func:`~tissue_sim_ros.bench.material_stability.run_material`,
    :func:`~tissue_sim_ros.bench.grasp_stability.run_grasp_sweep`), which use this module's meshes.

    Parameters
    ----------
    out : str or Path
        Output directory (created).
    quick : bool
        A few runs (smoke test).
    jobs, backend, address
        Where the runs go: worker processes or Ray (:func:`~tissue_sim_ros.core.sim.backends.map_calls`);
        the same rows either way.
    """
    from tqdm import tqdm  # noqa: PLC0415

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    sweep = make_sweep(quick)
    meshes = {q: make_mesh(q) for q in sweep.mesh_qualities}
    configs = [RunConfig(m, c, dt, s, v, q, n_steps=sweep.n_steps)
               for m in sweep.methods for c in sweep.contact_models for dt in sweep.dts
               for s in sweep.stiffness_scales for v in sweep.tool_speeds for q in sweep.mesh_qualities]
    from ..core.sim.backends import check_backend, check_jobs, map_calls  # noqa: PLC0415

    jobs, backend = check_jobs(jobs), check_backend(backend)
    with tqdm(total=len(configs), desc="stability", unit="run", dynamic_ncols=True) as bar:
        rows = map_calls(run_one, [(cfg, meshes[cfg.mesh_quality]) for cfg in configs], backend=backend,
                         workers=jobs, address=address, progress=lambda: bar.update(1))
    rows += inversion_rows(10 if quick else 30)
    write_csv(out / "stability.csv", rows)
    for method in sweep.methods:
        plot_method_map(out / f"stability_{method}.png", rows, method, sweep)

    table = []
    for m in sweep.methods:
        for c in sweep.contact_models:
            sel = [r for r in rows if r["method"] == m and r["contact_model"] == c and r["area_mode"] == "signed"]
            row = {"method": m, "contact": c, "runs": len(sel)}
            for o in OUTCOMES:
                row[o] = sum(r["outcome"] == o for r in sel)
            table.append(row)
    print("\nfirst failure per run (counts over dt x stiffness x tool speed x mesh quality):")
    print(format_table(table, ["method", "contact", "runs", *OUTCOMES]))
    print("\nstarting with inverted triangles (no tool):")
    print(format_table(rows[-4:], ["method", "area_mode", "outcome", "failure_step", "max_inverted"]))
    print(f"\nmesh: regular min angle {min_angle_deg(meshes.get('regular', make_mesh('regular'))):.1f} deg; "
          f"slivers min angle {min_angle_deg(make_mesh('slivers')):.1f} deg")
    print(f"\nwrote {out / 'stability.csv'} and {len(sweep.methods)} maps stability_<method>.png")
    return 0
