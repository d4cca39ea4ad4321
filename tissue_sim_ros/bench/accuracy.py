"""``tissue-sim bench accuracy``: error against the exact Newton solve versus time per step.

Every method (the paper's PBD Gauss-Seidel and Jacobi, XPBD Gauss-Seidel and
Jacobi, substepped XPBD, and Newton itself stopped after a few iterations) runs
the standard tool trajectory (experiment a's insertion from the side, over the
30 steps where the tool meets the lower tissue) at several iteration / substep
counts, time steps and mesh resolutions. For each setting it measures

* the median wall time of one solver step (contact detection excluded: it is
  the same for every method);
* the per-step error: from the method's own state at every step, the method
  and the exact reference (:mod:`~tissue_sim_ros.bench.reference`) each take
  one step with the same contacts; error = ||x_method - x_ref|| / ||x_ref - x_start||;
* the accumulated error: the method's run against the reference's own run,
  ||x_method(k) - x_ref(k)|| / ||x_ref(k) - x(0)||, at the end of the trajectory.

The reference minimises the implicit Euler energy with the physical XPBD
stiffnesses; the paper's PBD minimises nothing of the kind (its stiffness
depends on the iteration count), so its error does not fall to zero as
iterations grow. Physical accuracy against refinement compares the reference
solutions at 1x, 2x, 4x mesh resolution (and a graded mesh) with the finest.

Writes ``accuracy.csv``, ``accuracy_refinement.csv``, ``accuracy.png`` and
prints the Pareto front (the settings no other setting beats on both time and
error) and the cheapest setting for each error tolerance.
"""
from __future__ import annotations

import csv
import functools
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..core.config import Config, method_options, resolve_config
from ..core.contact.tool import ToolPose, ToolShape
from ..core.errors import InputError
from ..core.mesh import TissueMesh, mesh_rectangle
from ..core.physics.model import SimParams
from ..core.sim.simulation import Simulation
from .reference import ReferenceSolver, relative_error

#: Method names of the chart, in drawing order.
METHOD_NAMES = ("pbd", "pbd_jacobi", "xpbd", "xpbd_jacobi", "xpbd_substep", "newton")
METHOD_LABELS = {
    "pbd": "paper PBD, Gauss-Seidel",
    "pbd_jacobi": "paper PBD, Jacobi",
    "xpbd": "XPBD, Gauss-Seidel",
    "xpbd_jacobi": "XPBD, Jacobi",
    "xpbd_substep": "XPBD, substeps of 1 iteration",
    "newton": "Newton (reference), capped iterations",
}


# ----------------------------------------------------------------------------- scenes and settings


@dataclass
class Scene:
    """A mesh, a resolved configuration (parameters and tool) and the tool's trajectory: what every method is run on."""

    name: str
    mesh: TissueMesh
    config: Config
    """The scene's configuration (physics, boundary lines, contact model, tool); each setting changes only the
    method's fields (:meth:`Setting.config`)."""
    poses: list[ToolPose]
    """Tool pose at the end of each step; ``poses[0]`` is also the pose before the first step."""
    spacing: float
    """Target edge length of the mesh [m] (of the coarse region for a graded mesh)."""
    graded: bool = False
    focus: tuple[float, float] = (0.0, 0.0)
    """Where the tool works [m] (the centre of the error measured 'near the tool')."""

    @property
    def params(self) -> SimParams:
        """The base parameters (``config.sim``)."""
        return self.config.sim

    @property
    def tool(self) -> ToolShape:
        """The tool (``config.tool``)."""
        return self.config.tool

    @property
    def n_particles(self) -> int:
        return int(self.mesh.vertices.shape[0])


@dataclass(frozen=True)
class Setting:
    """One point of the chart: a method and its iteration (or substep) count, on a scene."""

    method: str
    """One of :data:`METHOD_NAMES`."""
    count: int
    """Iterations per step (substeps for ``xpbd_substep``; Newton iterations for ``newton``)."""

    def values(self) -> dict[str, Any]:
        """The method's fields as explicit overrides (``core/config.py``'s one alias rule, :func:`method_options`):
        the count is iterations, or substeps of 1 iteration for ``xpbd_substep``. Newton's model is XPBD
        Gauss-Seidel's (its physical stiffnesses), the count then Newton's iterations."""
        return method_options("xpbd" if self.method == "newton" else self.method, self.count)

    def config(self, base: Config) -> Config:
        """The base configuration with this method and count."""
        return base.replace(**self.values())

    @property
    def label(self) -> str:
        unit = {"xpbd_substep": "substeps", "newton": "Newton it."}.get(self.method, "it.")
        return f"{self.method} {self.count} {unit}"


def push_poses(mesh: TissueMesh, tool: ToolShape, n_steps: int, speed: float, approach: float = 0.02,
               tip_fraction: float = 0.6) -> tuple[list[ToolPose], tuple[float, float]]:
    """Experiment a's motion: the tool lies horizontally in from the left and pushes the bottom tissue down.

    The tool (yaw 0) reaches from the left edge to ``tip_fraction`` of the
    tissue's width; it starts ``approach`` above the bottom body's top surface
    under it and moves down by ``speed`` [m per step] each step.

    Returns
    -------
    poses : list of ToolPose, length n_steps + 1 (the pose before step 1, then one per step)
    focus : (float, float), the tool tip's position at the end [m]
    """
    v = mesh.vertices
    centroid_y = [v[mesh.body == b, 1].mean() for b in range(mesh.n_bodies)]
    bottom = int(np.argmin(centroid_y))
    x_min, x_max = float(v[:, 0].min()), float(v[:, 0].max())
    tip_x = x_min + tip_fraction * (x_max - x_min)
    half = 0.5 * tool.length if tool.kind != "sphere" else 0.0
    under = (mesh.body == bottom) & (v[:, 0] <= tip_x) & (v[:, 0] >= tip_x - 2 * half)
    top = float(v[under, 1].max()) if under.any() else float(v[mesh.body == bottom, 1].max())
    hy = tool.rounded_box()[1] + tool.rounded_box()[2]
    y0 = top + approach + hy
    poses = [ToolPose(tip_x - half, y0 - k * speed, 0.0) for k in range(n_steps + 1)]
    return poses, (tip_x, poses[-1].y)


#: Experiment a's steps where the tool meets the lower tissue (it comes within alpha near step 150 of the
#: tissue as it sags; from the tissue at rest, contact starts at once).
EXPERIMENT_A_FIRST_STEP = 175


def experiment_a_poses(tool: ToolShape, dt: float, n_steps: int, first_step: int = EXPERIMENT_A_FIRST_STEP,
                       dt_ref: float = 0.01) -> tuple[list[ToolPose], tuple[float, float]]:
    """Experiment a's tool poses (:func:`~tissue_sim_ros.core.timing.trajectories.experiment_a`) over a window.

    The trajectory is defined at ``dt_ref`` (0.001 m per step); at another dt the same motion in time
    is used (speed per step and step indices scaled by dt / dt_ref). Returns n_steps + 1 poses (the pose
    before the window's first step, then one per step) and the tool tip at the end [m].
    """
    from ..core.timing.trajectories import A_SPEED, A_STEPS, experiment_a  # noqa: PLC0415

    scale = dt / dt_ref
    traj = experiment_a(tool, dt, speed=A_SPEED * scale, steps=int(round(A_STEPS / scale)))
    poses = [traj.pose_at(traj.start_time)] + [pose for pose, _ in traj.steps(dt)]
    k0 = int(round(first_step / scale))
    window = poses[k0:k0 + n_steps + 1]
    if len(window) < n_steps + 1:
        raise InputError(f"experiment a has {len(poses) - 1} steps at dt={dt}: the window {k0}..{k0 + n_steps} "
                         "does not fit")
    end = window[-1]
    half = 0.5 * tool.length if tool.kind != "sphere" else 0.0
    tip = (end.x + half * math.cos(end.yaw), end.y + half * math.sin(end.yaw))
    return window, tip


def default_scene(spacing: float = 0.05, dt: float = 0.01, n_steps: int = 40, speed: float = 0.002,
                  grading: tuple[float, float, float, float] | None = None,
                  overrides: dict[str, Any] | None = None,
                  like: "Scene | None" = None) -> Scene:
    """The shipped tissue image and parameters (config/tissue_sim.yaml) with a stretch of experiment a.

    The tool follows experiment a's insertion over ``n_steps`` steps from step 175 (dt 0.01 s; the same
    motion in time at other dt), where it meets the lower tissue, starting from the tissue at rest.
    ``speed`` is unused (kept for :func:`push_poses`-style callers).
    ``grading`` = (x, y, radius, fine_spacing) meshes finer near a point (H1's graded mesh).
    ``like``: take the tool trajectory from this scene (so that meshes of other resolutions
    see exactly the same tool motion; ``n_steps`` is then ignored).
    """
    resolved = resolve_config({**(overrides or {}), "spacing": spacing, "dt": dt}, source="the accuracy scene")
    cfg = resolved.scene
    if grading is None:
        mesh = cfg.build_mesh()
    else:
        from ..core.mesh import mesh_from_image  # noqa: PLC0415
        from ..core.resources import DEFAULT_IMAGE, config_path  # noqa: PLC0415

        mesh = mesh_from_image(cfg.image or str(config_path(DEFAULT_IMAGE)), spacing=spacing, scale=cfg.scale,
                               origin=(cfg.origin_x, cfg.origin_y),
                               threshold=None if cfg.threshold < 0 else cfg.threshold, grading=grading)
    if like is not None:
        poses, focus = list(like.poses), like.focus
    else:
        poses, focus = experiment_a_poses(resolved.tool, resolved.sim.dt, n_steps)
    return Scene("tissue image", mesh, resolved, poses, spacing, graded=grading is not None, focus=focus)


def strip_scene(spacing: float = 0.05, dt: float = 0.01, n_steps: int = 20, speed: float = 0.002,
                width: float = 1.0, height: float = 0.3, overrides: dict[str, Any] | None = None) -> Scene:
    """A structured strip pinned along its bottom, pushed down from above by a box tool (small, for tests).

    The shipped parameters with the strip's own: its bottom line, no top line, the paper's contact and a
    box tool of 0.4 x its width.
    """
    mesh = mesh_rectangle(width, height, spacing)
    values: dict[str, Any] = {"dt": dt, "boundary_y_bottom": 0.5 * spacing, "boundary_y_top": math.nan,
                              "contact_model": "paper", "tool_shape": "box", "tool_length": 0.4 * width,
                              "tool_width": 0.005}
    values.update(overrides or {})
    cfg = resolve_config(values, source="the strip scene")
    # a single body: push its top surface (push_poses picks the bottom body, which here is the only one)
    poses, focus = push_poses(mesh, cfg.tool, n_steps, speed)
    return Scene("strip", mesh, cfg, poses, spacing, focus=focus)


# ----------------------------------------------------------------------------- stepping


def simulation(scene: Scene, setting: Setting, solver_options: dict[str, Any] | None = None) -> Simulation:
    """The scene with one setting: a Simulation (serial :class:`~tissue_sim_ros.core.physics.solvers.Solver`,
    or for ``newton`` the exact reference capped at ``count`` Newton iterations), the tool at the trajectory's
    start. ``solver_options`` go to the Solver (e.g. ``{"parallel": False}``)."""
    from ..core.physics.solvers import Solver  # noqa: PLC0415

    if setting.method == "newton":
        solver = functools.partial(ReferenceSolver, max_iterations=setting.count)
    else:
        solver = functools.partial(Solver, **(solver_options or {}))
    sim = Simulation.from_config(setting.config(scene.config), mesh=scene.mesh, solver=solver)
    sim.report_tool_checks = False  # measured here: the solve alone
    sim.place_tool(scene.poses[0])
    return sim


def reference_run(scene: Scene, progress: Callable[[], None] | None = None) -> tuple[list[np.ndarray], float]:
    """The exact reference's own run along the scene's trajectory.

    Returns
    -------
    positions : list of (N, 2) arrays, [x(0), x(1), ..., x(n)]
    ms_per_step : float, median wall time of one exact Newton step [ms]
    """
    sim = simulation(scene, Setting("newton", 200))
    out = [sim.state.particle_q.copy()]
    times = []
    for pose in scene.poses[1:]:
        times.append(sim.step(pose).timings["solve"])
        out.append(sim.state.particle_q.copy())
        if progress:
            progress()
    return out, 1e3 * float(np.median(times)) if times else math.nan


def measure_setting(scene: Scene, setting: Setting, ref_positions: Sequence[np.ndarray] | None,
                    per_step_every: int = 1, progress: Callable[[], None] | None = None,
                    max_newton: int = 60, solver_options: dict[str, Any] | None = None) -> dict[str, Any]:
    """Run one setting along the scene's trajectory and measure its time and errors.

    Parameters
    ----------
    scene : Scene
    setting : Setting
    ref_positions : list of (N, 2) arrays, optional
        The reference's own run (:func:`reference_run`) for the accumulated error.
    per_step_every : int
        Measure the per-step error at every this many steps (each costs a Newton solve); 0: never.
    solver_options : dict, optional
        Passed to the Solver (e.g. ``{"parallel": False}``).
    max_newton : int
        Newton iterations allowed per per-step reference; a step whose reference has not converged
        (relative gradient > 1e-6: far-off states of the paper's PBD on fine meshes) is left out.

    Returns
    -------
    dict: one CSV row (scene, spacing, particles, dt, method, count, ms_per_step, err_step_median,
    err_step_max, err_accum_final, err_accum_max, diverged).
    """
    sim = simulation(scene, setting, solver_options)
    dt = sim.params.dt
    exact_solver = functools.partial(ReferenceSolver, max_iterations=max_newton)
    x0 = sim.state.particle_q.copy()
    times: list[float] = []
    ref_solves = ref_converged = 0
    err_step: list[float] = []
    err_accum: list[float] = []
    diverged = False
    for k in range(1, len(scene.poses)):
        per_step = per_step_every > 0 and (k % per_step_every == 0 or k == 1)
        with np.errstate(all="ignore"):
            report = sim.step(scene.poses[k], detail=per_step)
        times.append(report.timings["solve"])
        if report.diverged:
            diverged = True
            err_step.append(math.inf)
            err_accum.append(math.inf)
            if progress:
                progress()
            break
        x = sim.state.particle_q
        if per_step:
            # the exact solve of the same step: the method's start state and contacts (report.detail)
            _, info = sim.solve(report.detail, solver=exact_solver)
            exact = info.result
            ref_solves += 1
            if exact.relative_grad <= 1e-6:  # a per-step error needs a converged reference
                ref_converged += 1
                err_step.append(relative_error(x, exact.particle_q, report.detail.state_in.particle_q))
        if ref_positions is not None:
            err_accum.append(relative_error(x, ref_positions[k], x0))
        if progress:
            progress()
    p = sim.params
    return {
        "scene": scene.name + (" graded" if scene.graded else ""), "spacing": scene.spacing,
        "particles": scene.n_particles, "dt": dt, "method": setting.method, "count": setting.count,
        "iterations": p.iterations if setting.method != "newton" else 0,
        "substeps": p.substeps if setting.method != "newton" else 0,
        "ms_per_step": 1e3 * float(np.median(times)) if times else math.nan,
        "err_step_median": float(np.median(err_step)) if err_step else math.nan,
        "err_step_max": float(np.max(err_step)) if err_step else math.nan,
        "err_accum_final": err_accum[-1] if err_accum else math.nan,
        "err_accum_max": float(np.max(err_accum)) if err_accum else math.nan,
        "diverged": diverged, "ref_solves": ref_solves, "ref_converged": ref_converged,
    }


# ----------------------------------------------------------------------------- sleeping


SLEEP_SETTINGS = ({"wake_radius": 0.15, "sleep_speed": 1e-3, "quiet_steps": 10},
                  {"wake_radius": 0.15, "sleep_speed": 1e-2, "quiet_steps": 5})


def measure_sleeping(scene: Scene, setting: Setting, sleep_settings: Sequence[dict[str, Any]] = SLEEP_SETTINGS,
                     progress: Callable[[], None] | None = None) -> list[dict[str, Any]]:
    """The cost of sleeping far, quiet particles: time saved and error against the same method awake.

    Runs ``setting`` on the scene awake and with each sleeping setting
    (:class:`~tissue_sim_ros.core.physics.sleeping.SleepingSolver`), one solver thread.
    Error = ||x_sleeping - x_awake|| / ||x_awake - x(0)|| at the end of the run;
    times are medians over the whole run and over its second half (once regions have gone to sleep).
    """
    from ..core.physics.solvers.sleeping import SleepingSolver  # noqa: PLC0415

    runs = []
    for cfg in (None, *sleep_settings):
        sim = simulation(scene, setting, {"parallel": False})
        if cfg is not None:
            sim.use_solver(functools.partial(SleepingSolver, **cfg))
        times, awake = [], []
        for pose in scene.poses[1:]:
            with np.errstate(all="ignore"):
                times.append(sim.step(pose).timings["solve"])
            awake.append(sim.solver.awake_constraint_fraction if cfg is not None else 1.0)
            if progress:
                progress()
        runs.append((cfg, sim.state.particle_q.copy(), times, awake))
    x0 = np.asarray(scene.mesh.vertices)
    x_awake = runs[0][1]
    rows = []
    for cfg, x, times, awake in runs:
        half = len(times) // 2
        rows.append({
            "particles": scene.n_particles, "method": setting.method, "count": setting.count,
            "sleep_speed": cfg["sleep_speed"] if cfg else 0.0, "quiet_steps": cfg["quiet_steps"] if cfg else 0,
            "wake_radius": cfg["wake_radius"] if cfg else 0.0, "steps": len(times),
            "ms_per_step": 1e3 * float(np.median(times)), "ms_per_step_2nd_half": 1e3 * float(np.median(times[half:])),
            "awake_constraints_mean": float(np.mean(awake)), "awake_constraints_end": float(awake[-1]),
            "err_vs_awake": relative_error(x, x_awake, x0),
        })
    return rows


# ----------------------------------------------------------------------------- physical accuracy


def displacement_error(scene: Scene, positions: np.ndarray, fine: Scene, fine_positions: np.ndarray,
                       near_radius: float | None = None) -> float:
    """Displacement of ``scene``'s particles against the finest scene's displacement field at the same points.

    The fine mesh's displacement is interpolated linearly (on its rest
    triangles) at the coarse particles' rest positions; the error is
    ||u_coarse - u_fine|| / ||u_fine|| over the particles (within
    ``near_radius`` of the scene's focus when given) that lie inside the fine mesh.
    """
    import matplotlib.tri as mtri  # noqa: PLC0415

    fm = fine.mesh
    tri = mtri.Triangulation(fm.vertices[:, 0], fm.vertices[:, 1], fm.triangles)
    u_fine = fine_positions - fm.vertices
    rest = scene.mesh.vertices
    ux = mtri.LinearTriInterpolator(tri, u_fine[:, 0])(rest[:, 0], rest[:, 1])
    uy = mtri.LinearTriInterpolator(tri, u_fine[:, 1])(rest[:, 0], rest[:, 1])
    inside = ~(np.ma.getmaskarray(ux) | np.ma.getmaskarray(uy))
    if near_radius is not None:
        inside &= np.hypot(rest[:, 0] - scene.focus[0], rest[:, 1] - scene.focus[1]) <= near_radius
    u_ref = np.stack([np.asarray(ux.filled(0.0)), np.asarray(uy.filled(0.0))], axis=1)[inside]
    u = (positions - rest)[inside]
    den = float(np.linalg.norm(u_ref))
    return float(np.linalg.norm(u - u_ref)) / den if den > 0 else math.nan


# ----------------------------------------------------------------------------- Pareto front and choice


def pareto_front(rows: Sequence[dict[str, Any]], error_key: str = "err_step_median") -> list[int]:
    """Indices of rows on the front: no other row is both faster and more accurate; sorted by time."""
    ok = [i for i, r in enumerate(rows) if math.isfinite(r["ms_per_step"]) and math.isfinite(r[error_key])]
    ok.sort(key=lambda i: (rows[i]["ms_per_step"], rows[i][error_key]))
    front: list[int] = []
    best = math.inf
    for i in ok:
        if rows[i][error_key] < best:
            front.append(i)
            best = rows[i][error_key]
    return front


def cheapest(rows: Sequence[dict[str, Any]], tolerance: float, error_key: str = "err_step_median",
             exclude: Sequence[str] = ("newton",)) -> dict[str, Any] | None:
    """The fastest row whose error is at most ``tolerance`` (None if none is)."""
    ok = [r for r in rows if r["method"] not in exclude and math.isfinite(r[error_key])
          and r[error_key] <= tolerance and math.isfinite(r["ms_per_step"])]
    return min(ok, key=lambda r: r["ms_per_step"]) if ok else None


# ----------------------------------------------------------------------------- output


def write_csv(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    """Rows (dicts with the same keys) as CSV."""
    if not rows:
        return
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
        w.writeheader()
        w.writerows(rows)


def plot_chart(path: Path, rows: Sequence[dict[str, Any]], title: str, error_key: str = "err_step_median") -> None:
    """Log error against log time per step, one curve per method and resolution, Pareto front marked."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, ax = plt.subplots(figsize=(9, 6.5))
    colours = dict(zip(METHOD_NAMES, ("tab:red", "tab:orange", "tab:blue", "tab:green", "tab:purple", "black")))
    markers = ["o", "s", "^", "D", "v"]
    groups: dict[tuple[str, str, float, float], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r["method"], r["scene"], r["particles"], r["dt"]), []).append(r)
    resolutions = sorted({(r["scene"], r["particles"]) for r in rows}, key=lambda s: s[1])
    dts = sorted({r["dt"] for r in rows}, reverse=True)
    for (method, scene, particles, dt), g in sorted(groups.items(), key=lambda kv: (METHOD_NAMES.index(kv[0][0]), kv[0][2])):
        g = [r for r in g if math.isfinite(r[error_key]) and r[error_key] > 0]
        if not g:
            continue
        g.sort(key=lambda r: r["count"])
        res_i = resolutions.index((scene, particles))
        style = "-" if dt == dts[0] else "--"
        ax.plot([r["ms_per_step"] for r in g], [r[error_key] for r in g], style,
                marker=markers[res_i % len(markers)], color=colours.get(method, "grey"), alpha=0.85, ms=4,
                label=f"{METHOD_LABELS.get(method, method)}, {scene} {particles} p., dt {dt:g}")
        for r in (g[0], g[-1]):
            ax.annotate(str(r["count"]), (r["ms_per_step"], r[error_key]), fontsize=6, xytext=(2, 2),
                        textcoords="offset points")
    # the front within the base scene (coarsest mesh, first dt): errors at other dts or meshes are
    # against other exact problems, and a smaller dt needs more steps per simulated second
    base = [r for r in rows if r["particles"] == min(q["particles"] for q in rows) and r["dt"] == dts[0]
            and "graded" not in r["scene"]]
    front = [base[i] for i in pareto_front(base, error_key)]
    if front:
        ax.step([r["ms_per_step"] for r in front], [r[error_key] for r in front], where="post", color="k",
                lw=2.5, alpha=0.35, label=f"Pareto front ({front[0]['particles']} p., dt {dts[0]:g})")
        ax.scatter([r["ms_per_step"] for r in front], [r[error_key] for r in front], s=70, facecolors="none",
                   edgecolors="k", zorder=5)
    newton = sorted({(r["particles"], r["newton_ms"]) for r in rows
                     if r["dt"] == dts[0] and math.isfinite(r.get("newton_ms", math.nan))})
    for i, (particles, ms) in enumerate(newton):
        ax.axvline(ms, color="k", ls=":", lw=1)
        ax.annotate(f"exact Newton\n{particles} p.", (ms, 0.02 + 0.08 * (i % 3)), xycoords=("data", "axes fraction"),
                    fontsize=6, rotation=90, ha="right")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("median wall time per step [ms] (solve only)")
    ax.set_ylabel({"err_step_median": "per-step error vs exact Newton (median, relative to step)",
                   "err_accum_final": "accumulated error vs exact run (relative to displacement)"}.get(error_key, error_key))
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=6, loc="best", ncol=1)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def format_table(rows: Sequence[dict[str, Any]], columns: Sequence[str]) -> str:
    """A plain-text table of some columns."""
    def fmt(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.3g}"
        return str(v)

    cells = [[fmt(r[c]) for c in columns] for r in rows]
    widths = [max(len(c), *(len(row[i]) for row in cells)) if cells else len(c) for i, c in enumerate(columns)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(columns, widths))]
    lines += ["  ".join(v.ljust(w) for v, w in zip(row, widths)) for row in cells]
    return "\n".join(lines)


# ----------------------------------------------------------------------------- the command


@dataclass
class Plan:
    """What one run of the benchmark measures."""

    counts: list[int]
    counts_fine: list[int]
    newton_counts: list[int]
    spacings: list[float]
    dts: list[float]
    n_steps: int
    per_step_every: int
    per_step_every_fine: int
    n_steps_fine: int
    """Steps run on the finer meshes: the first steps of the same motion. Per-constraint stiffnesses make
    a finer mesh a softer material; on the 4x mesh the exact run folds (inverted triangles) after a few steps,
    where each exact step takes Newton minutes."""
    graded: bool
    sleep_spacing: float = 0.025
    sleep_steps: int = 80
    methods: list[str] = field(default_factory=lambda: list(METHOD_NAMES))
    methods_fine: list[str] = field(default_factory=lambda: ["pbd", "xpbd", "xpbd_jacobi", "xpbd_substep"])
    """Methods run at the finer resolutions (fewer, to keep the run to minutes)."""


def make_plan(quick: bool) -> Plan:
    if quick:
        return Plan(counts=[1, 10], counts_fine=[10], newton_counts=[1], spacings=[0.1, 0.05], dts=[0.01],
                    n_steps=4, per_step_every=2, per_step_every_fine=2, n_steps_fine=2, graded=False,
                    sleep_spacing=0.05, sleep_steps=8)
    return Plan(counts=[1, 2, 5, 10, 20, 50, 100, 200], counts_fine=[5, 20, 50, 200], newton_counts=[1, 2, 3, 5],
                spacings=[0.05, 0.025, 0.0125], dts=[0.01, 0.005], n_steps=30, per_step_every=3,
                per_step_every_fine=3, n_steps_fine=7, graded=True)



#: error tolerances to pick the cheapest setting for
TOLERANCES = (0.3, 0.1, 0.01, 1e-3)


def run(out: str | Path, *, quick: bool = False, tolerances: Sequence[float] | None = None,
        steps: int | None = None, overrides: Mapping[str, Any] | None = None, parallel: bool = False) -> int:
    """Measure every setting against the exact reference; print the Pareto front, write the CSVs and charts; 0.

    Parameters
    ----------
    out : str or Path
        Output directory (created).
    quick : bool
        A few settings on a coarse mesh (smoke test).
    tolerances : sequence of float, optional
        Error tolerances to pick the cheapest setting for (default :data:`TOLERANCES`).
    steps : int, optional
        Trajectory length in steps (default 30; ``quick`` 4).
    overrides : mapping, optional
        Parameters over config/tissue_sim.yaml for every scene (flat names, as ``--set``).
    parallel : bool
        Gauss-Seidel on all threads (``Solver(parallel=True)``); default one thread, the solver's own default.
    """
    from tqdm import tqdm  # noqa: PLC0415

    plan = make_plan(quick)
    if steps is not None:
        if steps < 1:
            raise InputError(f"--steps={steps}: expected at least 1 step")
        plan.n_steps = steps
    tolerances = list(tolerances or TOLERANCES)
    for tol in tolerances:
        if not (math.isfinite(tol) and tol > 0):
            raise InputError(f"--tolerance={tol}: expected an error > 0")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    overrides = dict(overrides or {})

    # the scenes: every resolution at the first dt; the other dts at the base resolution; graded at base spacing
    base_speed = 0.002  # unused by experiment a's scenes (their speed is the experiment's)
    scenes: list[tuple[Scene, list[Setting], int]] = []
    fine_scene: dict[int, bool] = {}
    finest: Scene | None = None
    refinement: list[Scene] = []
    for si, spacing in enumerate(plan.spacings):
        dts = plan.dts if si == 0 else plan.dts[:1]
        for dt in dts:
            n_steps = int(round(plan.n_steps * plan.dts[0] / dt))
            like = refinement[0] if refinement and dt == plan.dts[0] else None
            scene = default_scene(spacing, dt, n_steps, base_speed * dt / plan.dts[0], overrides=overrides, like=like)
            if si > 0:  # finer meshes: the first steps of the same motion (see Plan.n_steps_fine)
                scene.poses = scene.poses[:plan.n_steps_fine + 1]
            counts = plan.counts if si == 0 else plan.counts_fine
            methods = [m for m in plan.methods if m != "newton"] if si == 0 else plan.methods_fine
            settings = [Setting(m, c) for m in methods for c in counts]
            if si == 0 and dt == plan.dts[0]:
                settings += [Setting("newton", c) for c in plan.newton_counts]
            scenes.append((scene, settings, plan.per_step_every if si == 0 else plan.per_step_every_fine))
            fine_scene[id(scene)] = si > 0
            if dt == plan.dts[0]:
                refinement.append(scene)
    finest = refinement[-1]
    if plan.graded:
        focus = refinement[0].focus
        graded = default_scene(plan.spacings[0], plan.dts[0], plan.n_steps, base_speed,
                               grading=(focus[0], focus[1], 0.15, plan.spacings[-1]), overrides=overrides,
                               like=refinement[0])
        graded.poses = graded.poses[:plan.n_steps_fine + 1]
        refinement.insert(-1, graded)
        scenes.append((graded, [Setting(m, c) for m in ("xpbd", "xpbd_substep") for c in plan.counts_fine],
                       plan.per_step_every_fine))

    total = sum(len(s.poses) - 1 for s in refinement) + sum(len(s.poses) - 1 for s, _, _ in scenes
                                                         if s not in refinement)
    total += sum((len(s.poses) - 1) * len(st) for s, st, _ in scenes)
    rows: list[dict[str, Any]] = []
    ref_runs: dict[int, list[np.ndarray]] = {}
    newton_ms: dict[int, float] = {}
    with tqdm(total=total, desc="accuracy", unit="step", dynamic_ncols=True) as bar:
        for scene in refinement + [s for s, _, _ in scenes if s not in refinement]:
            bar.set_postfix_str(f"reference {scene.name} {scene.n_particles} p. dt {scene.params.dt:g}")
            ref_runs[id(scene)], newton_ms[id(scene)] = reference_run(scene, bar.update)
        for scene, settings, every in scenes:
            for setting in settings:
                bar.set_postfix_str(f"{setting.label}, {scene.n_particles} p., dt {scene.params.dt:g}")
                # the paper's PBD drifts far from the physical state on fine meshes, where one exact
                # step from its state takes Newton minutes: there only its accumulated error is measured
                skip = fine_scene.get(id(scene), True) and setting.method.startswith("pbd")
                row = measure_setting(scene, setting, ref_runs[id(scene)], 0 if skip else every, bar.update,
                                      solver_options={"parallel": bool(parallel)})
                # the exact solve's time on the same scene: the accuracy end of the front
                row["newton_ms"] = newton_ms[id(scene)]
                rows.append(row)

    # physical accuracy: each resolution's exact run against the finest, at the last step all of them ran
    ref_rows = []
    k_common = min(len(s.poses) for s in refinement) - 1
    finest_positions = ref_runs[id(finest)][k_common]
    for scene in refinement:
        positions = ref_runs[id(scene)][k_common]
        ref_rows.append({
            "scene": scene.name + (" graded" if scene.graded else ""), "spacing": scene.spacing,
            "particles": scene.n_particles,
            "step": k_common, "newton_ms": newton_ms[id(scene)],
            "err_vs_finest_all": displacement_error(scene, positions, finest, finest_positions)
            if scene is not finest else 0.0,
            "err_vs_finest_near_tool": displacement_error(scene, positions, finest, finest_positions,
                                                          near_radius=0.15) if scene is not finest else 0.0,
        })

    # sleeping: experiment a on the 2x mesh, long enough for far regions to settle
    sleep_scene = default_scene(plan.sleep_spacing, plan.dts[0], plan.sleep_steps, 0.001, overrides=overrides)
    with tqdm(total=(len(sleep_scene.poses) - 1) * (1 + len(SLEEP_SETTINGS)), desc="sleeping", unit="step",
              dynamic_ncols=True) as bar:
        sleep_rows = measure_sleeping(sleep_scene, Setting("xpbd", 50), progress=bar.update)

    write_csv(out / "accuracy.csv", rows)
    write_csv(out / "accuracy_sleeping.csv", sleep_rows)
    write_csv(out / "accuracy_refinement.csv", ref_rows)
    base_rows = [r for r in rows if r["particles"] == refinement[0].n_particles and r["dt"] == plan.dts[0]
                 and "graded" not in r["scene"]]
    plot_chart(out / "accuracy.png", rows,
               f"Error against the exact implicit Euler step vs time: experiment a, steps 175-{175 + plan.n_steps}")
    plot_chart(out / "accuracy_accumulated.png", rows,
               "Accumulated error of the run against the exact run", error_key="err_accum_final")

    cols = ["method", "count", "particles", "dt", "ms_per_step", "err_step_median", "err_accum_final"]
    front = [base_rows[i] for i in pareto_front(base_rows)]
    print(f"\nPareto front at {refinement[0].n_particles} particles, dt {plan.dts[0]:g} "
          "(per-step error against exact Newton vs median solve time):")
    print(format_table(front, cols))
    if base_rows and "newton_ms" in base_rows[0]:
        print(f"\nexact Newton solve: {base_rows[0]['newton_ms']:.3g} ms per step at {base_rows[0]['particles']} particles")
    print(f"\ncheapest setting per error tolerance at {refinement[0].n_particles} particles, dt {plan.dts[0]:g} "
          "(per-step error; Newton excluded):")
    for tol in tolerances:
        best = cheapest(base_rows, tol)
        if best is None:
            print(f"  error <= {tol:g}: no measured setting")
        else:
            print(f"  error <= {tol:g}: {best['method']} count {best['count']} at {best['particles']} particles, "
                  f"dt {best['dt']:g}: {best['ms_per_step']:.3g} ms/step (error {best['err_step_median']:.3g})")
    print("\nphysical accuracy: exact run at each resolution against the finest (final displacement):")
    print(format_table(ref_rows, ["scene", "spacing", "particles", "step", "newton_ms", "err_vs_finest_all",
                                  "err_vs_finest_near_tool"]))
    print(f"\nsleeping far, quiet particles (XPBD 50 iterations, {sleep_scene.n_particles} particles, "
          f"{len(sleep_scene.poses) - 1} steps of experiment a from step 175; error against the same run awake):")
    print(format_table(sleep_rows, ["sleep_speed", "quiet_steps", "ms_per_step", "ms_per_step_2nd_half",
                                    "awake_constraints_mean", "awake_constraints_end", "err_vs_awake"]))
    print(f"\nwrote {out / 'accuracy.csv'}, {out / 'accuracy_refinement.csv'}, {out / 'accuracy_sleeping.csv'}, "
          f"{out / 'accuracy.png'}, {out / 'accuracy_accumulated.png'}")
    return 0
