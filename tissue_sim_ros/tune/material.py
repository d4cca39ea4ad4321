"""``tissue-sim tune`` for ``material: neo_hookean``: the cheapest mesh (spacing, grading) and solver setting.

The solver setting is the method's own knob (:func:`solver_settings`): the solve tolerance of the whole-step
solves (``ipc``, the default, and ``quasi_newton``: one substep, iterations a cap), substeps x iterations of
``xpbd``.

The material's answer is a physical one, so its error has two parts, both measured here on the
parameter file's own scene (e.g. ``config/scenes/liver_probe.yaml``) under a static load: gravity and
the scene's instrument pressed ``--depth`` into the top of the tissue (upright, at the middle of the
tissue's width, moved in over 40 steps, then held until every particle is slower than 1e-5 m/s; a
damping of 50 1/s on the way does not change the rest state). The instrument's pose is the same
world pose on every mesh (taken from the reference mesh's outline), so every mesh carries the same load.

Three quantities, each relative to the reference's value:

* ``field``: the rest displacement, RMS of |u - u_ref| / RMS |u_ref| over the tissue (the reference
  interpolated piecewise linearly at the mesh's particles, each weighted by its lumped mass, i.e. by the
  tissue's area it stands for: an unweighted mean over particles would let a graded mesh's many particles
  at the instrument, where the displacement is largest, outweigh the rest);
* ``force``: the tissue's reaction on the instrument (``StepReport.reaction_force``), |F - F_ref| / |F_ref|;
* ``energy``: the strain energy at rest [J] (``StepReport.energy.scene_potential``), |E - E_ref| / E_ref.

For each quantity, error = mesh error + solver error, an upper bound on the setting's error against the
continuum answer: the mesh error is the mesh solved with ``CONVERGED`` substeps x iterations against the
reference, plus the reference's own error; the solver error is the setting against ``CONVERGED`` on the same
mesh. A setting qualifies when the largest of its three errors is <= the tolerance. The reference is a
graded mesh ``REFINE`` times finer than the finest candidate (base spacing and graded spacing near the
instrument), solved with ``CONVERGED``; its own error is estimated (:func:`build_reference`) from the same
mesh with twice the substeps (solver) and from a mesh sqrt(2) coarser (mesh, first order).

Candidate meshes: every spacing, uniform and graded (``grade_spacing`` within ``GRADE_RADIUS_TOOLS`` tool
radii of the press point, growing outside; :class:`~tissue_sim_ros.core.mesh.Grading`). Why graded: under a
5 mm instrument a uniform 2.5-5 mm mesh has one to three particles in contact, placed unsymmetrically
about the instrument's axis, so the contact pushes sideways and the soft slab shears as a whole: the
displacement field's error is mostly far from the tool and falls slowly with refinement. Time: the median solver time per step during the hold. The cheapest
setting with error <= tolerance and time <= budget is written as a parameter file: the scene's file with
``spacing``, the ``grade_*`` parameters, ``substeps``, ``iterations`` and ``solve_tolerance`` replaced.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..core.config import Config
from ..core.contact.tool import ToolPose
from ..core.sim.simulation import Simulation

#: a solver setting: (substeps, iterations, solve_tolerance). xpbd (substeps of a fixed number of iterations): the
#: rest state's bias falls with the substep (1/substeps), hardly with the iterations; its tolerance only reports
SETTINGS = tuple((n, it, 1e-3) for n, it in (
    (1, 10), (2, 5), (5, 5), (10, 2), (10, 5), (10, 10), (20, 3), (20, 5), (20, 10), (30, 3), (30, 5), (30, 10),
    (40, 3), (40, 5), (50, 5)))
QUICK_SETTINGS = ((2, 5, 1e-3), (10, 5, 1e-3))
CONVERGED = (100, 10, 1e-3)
QUICK_CONVERGED = (20, 5, 1e-3)
#: the whole-step solves (ipc, quasi_newton: one substep, iterations a cap): they stop at solve_tolerance, the
#: estimated relative error of the step, so the tolerance is the setting
WHOLE_STEP = ("ipc", "quasi_newton")
WHOLE_SETTINGS = ((1, 50, 3e-2), (1, 50, 1e-2), (1, 50, 3e-3), (1, 50, 1e-3), (1, 100, 3e-4), (1, 100, 1e-4))
WHOLE_QUICK_SETTINGS = ((1, 50, 1e-2), (1, 50, 1e-3))
WHOLE_CONVERGED = (1, 300, 1e-6)
WHOLE_QUICK_CONVERGED = (1, 200, 1e-5)
REST_SPEED = 1e-5
#: radius of a graded mesh's fine disc around the press point, in tool radii
GRADE_RADIUS_TOOLS = 2.0
QUANTITIES = ("field", "force", "energy")
RAMP = 40
#: the reference mesh is this much finer than the finest candidate (two sqrt(2) refinements past it)
REFINE = 2.0 ** 1.5


def solver_settings(cfg: Config, quick: bool = False) -> tuple[tuple[tuple[int, int, float], ...],
                                                               tuple[int, int, float]]:
    """The candidate settings and the converged one for ``cfg``'s method: substeps x iterations (xpbd) or the
    solve tolerance (the whole-step solves)."""
    if cfg.sim.method in WHOLE_STEP:
        return (WHOLE_QUICK_SETTINGS, WHOLE_QUICK_CONVERGED) if quick else (WHOLE_SETTINGS, WHOLE_CONVERGED)
    return (QUICK_SETTINGS, QUICK_CONVERGED) if quick else (SETTINGS, CONVERGED)


def with_setting(cfg: Config, setting: Sequence[float]) -> Config:
    """``cfg`` with a setting's substeps, iterations and solve tolerance."""
    n, it, tol = setting
    return cfg.replace(substeps=int(n), iterations=int(it), solve_tolerance=float(tol))


def setting_label(setting: Sequence[float], method: str) -> str:
    """``10 x 5`` (substeps x iterations) or ``tolerance 0.001`` (a whole-step solve)."""
    n, it, tol = setting
    return f"tolerance {float(tol):g}" if method in WHOLE_STEP else f"{int(n)} x {int(it)}"


def tighter(setting: Sequence[float], method: str) -> tuple[int, int, float]:
    """The setting a converged one is checked against: twice the substeps (xpbd) or a tenth of the tolerance."""
    n, it, tol = setting
    return (int(n), int(it), float(tol) / 10) if method in WHOLE_STEP else (2 * int(n), int(it), float(tol))


def _reach(cfg: Config) -> float:
    """The tool's half thickness across its axis [m] (box: width/2; capsule, sphere: radius)."""
    _, hy, r = cfg.tool.rounded_box()
    return hy + r


def _half_length(cfg: Config) -> float:
    """From the tool's centre to the end of its straight part along the axis [m] (0 for a sphere)."""
    return cfg.tool.rounded_box()[0]


def _listing(values: dict[str, float], fmt: str = ".2g") -> str:
    """``name value, ...`` for a quantity -> error mapping."""
    return ", ".join(f"{q} {v:{fmt}}" for q, v in values.items())


@dataclass(frozen=True)
class Press:
    """The load: the instrument's tip pressed to ``tip_y`` at ``x`` (world, the same on every mesh)."""

    x: float
    top: float
    """The tissue's rest top at x (reference mesh) [m]."""
    depth: float

    def pose(self, cfg: Config, s: float) -> ToolPose:
        """The instrument's pose at ramp fraction ``s`` (0: 2 mm above the top, 1: ``depth`` below it)."""
        half, reach = _half_length(cfg), _reach(cfg)
        start, end = self.top + reach + 0.002, self.top + reach - self.depth
        return ToolPose(self.x, start + s * (end - start) + half, -0.5 * math.pi)


def press_point(cfg: Config, depth: float) -> Press:
    """The press at the middle of the tissue's width, from ``cfg``'s mesh (the reference's, finest outline)."""
    q0 = cfg.scene.build_mesh().vertices
    x_mid = 0.5 * (q0[:, 0].min() + q0[:, 0].max())
    near = np.abs(q0[:, 0] - x_mid) < 2.0 * cfg.scene.spacing
    return Press(float(x_mid), float(q0[near, 1].max()), depth)


def mesh_config(cfg: Config, press: Press, spacing: float, grade_spacing: float) -> Config:
    """``cfg`` meshed at ``spacing``, graded to ``grade_spacing`` around the press point (0: uniform)."""
    if grade_spacing <= 0 or grade_spacing >= spacing:
        return cfg.replace(spacing=spacing, grade_spacing=0.0, grade_x=0.0, grade_y=0.0, grade_radius=0.0)
    return cfg.replace(spacing=spacing, grade_spacing=grade_spacing, grade_x=press.x, grade_y=press.top,
                       grade_radius=GRADE_RADIUS_TOOLS * _reach(cfg))


def press_to_rest(cfg: Config, press: Press, max_steps: int = 3000) -> dict[str, Any]:
    """Rest state under gravity and the press: displacement, reaction force, strain energy, solver ms per step."""
    cfg = cfg.replace(damping=50.0, sleep_speed=0.0)
    sim = Simulation.from_config(cfg)
    q0 = sim.model.particle_q0
    solve_ms = []
    steps = 0
    report = None
    for k in range(1, max_steps + 1):
        report = sim.step(press.pose(cfg, min(1.0, k / RAMP)))
        steps = k
        if k > RAMP:
            solve_ms.append(1e3 * report.timings.get("solve", report.timings.get("total", math.nan)))
            if float(np.abs(sim.state.particle_qd).max()) < REST_SPEED:
                break
    return {"q0": q0.copy(), "u": sim.state.particle_q - q0, "mass": sim.model.particle_mass.copy(),
            "steps": steps, "particles": sim.model.n_particles,
            "force": np.array(report.reaction_force, dtype=float), "energy": float(report.energy.scene_potential),
            "solve_ms": float(np.median(solve_ms)) if solve_ms else math.nan,
            "at_rest": steps < max_steps}


def rest_runs(runs: Sequence[tuple[Config, Press]], jobs: int = 1, backend: str = "local",
              address: str | None = None) -> list[dict[str, Any]]:
    """:func:`press_to_rest` of each ``(cfg, press)``, independent calls: in this process (``jobs`` 1, local), on
    worker processes or on Ray (:func:`~tissue_sim_ros.core.sim.backends.map_calls`); the same numbers."""
    from ..core.sim.backends import map_calls  # noqa: PLC0415

    return map_calls(press_to_rest, list(runs), backend=backend, workers=jobs, address=address)


def rms(a: np.ndarray, weight: np.ndarray | None = None) -> float:
    """RMS length of the rows of ``a``, weighted by ``weight`` (e.g. the lumped masses: the tissue's L2 mean)."""
    sq = (a * a).sum(axis=1)
    return float(np.sqrt(sq.mean() if weight is None else (weight * sq).sum() / weight.sum()))


def interpolate(fine: dict[str, Any], points: np.ndarray) -> np.ndarray:
    """The fine run's displacement at ``points`` (piecewise linear; nearest outside its hull)."""
    from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator  # noqa: PLC0415

    lin = LinearNDInterpolator(fine["q0"], fine["u"])(points)
    bad = ~np.all(np.isfinite(lin), axis=1)
    if bad.any():
        lin[bad] = NearestNDInterpolator(fine["q0"], fine["u"])(points[bad])
    return lin


def errors(run: dict[str, Any], ref: dict[str, Any], same_mesh: bool = False) -> dict[str, float]:
    """``run``'s relative error against ``ref`` per quantity (``same_mesh``: no interpolation)."""
    u_ref = ref["u"] if same_mesh else interpolate(ref, run["q0"])
    w = run["mass"]  # lumped from the tissue's area: a graded mesh's crowd of particles at the tool counts once
    return {"field": rms(run["u"] - u_ref, w) / rms(u_ref, w),
            "force": float(np.linalg.norm(run["force"] - ref["force"]) / np.linalg.norm(ref["force"])),
            "energy": abs(run["energy"] - ref["energy"]) / abs(ref["energy"])}


def reference_meshes(spacings: Sequence[float], grades: Sequence[float]) -> tuple[float, float]:
    """The reference mesh: ``REFINE`` x finer than the finest spacing and the finest graded spacing (or spacing)."""
    fine = [g for g in grades if g > 0] or [min(spacings)]
    return min(spacings) / REFINE, min(fine) / REFINE


def build_reference(cfg: Config, spacing: float, grade_spacing: float, depth: float,
                    converged: tuple[int, int, float] | None = None, progress: Any = print,
                    **backend: Any) -> dict[str, Any]:
    """The press solved with ``converged`` on a mesh of ``spacing`` graded to ``grade_spacing`` (the press point
    from this mesh's outline), and the reference's own errors.

    Solver: against the same mesh with twice the substeps (xpbd) or a tenth of the tolerance (:func:`tighter`). Mesh: from the change against the same family of
    mesh sqrt(2) coarser (spacing and graded spacing both), taken as first order (the strain energy's changes
    fall about that fast; the force's do not fall steadily, contact particles come and go): error ~ change /
    (sqrt(2) - 1) = 2.4 x the change.
    """
    method = cfg.sim.method
    converged = converged or solver_settings(cfg)[1]
    press = press_point(cfg.replace(spacing=spacing, grade_spacing=0.0), depth)
    ref_cfg = mesh_config(cfg, press, spacing, grade_spacing)
    ref, check, coarser = rest_runs([
        (with_setting(ref_cfg, converged), press),
        (with_setting(ref_cfg, tighter(converged, method)), press),
        (with_setting(mesh_config(cfg, press, spacing * math.sqrt(2), grade_spacing * math.sqrt(2)), converged),
         press)], **backend)
    solver = errors(ref, check, same_mesh=True)
    change = errors(coarser, ref)
    mesh = {q: v / (math.sqrt(2) - 1) for q, v in change.items()}
    reference = {"spacing": spacing, "grade_spacing": grade_spacing, "particles": ref["particles"], "press": press,
                 "solver_error": solver, "change": change, "mesh_error": mesh,
                 "error": {q: solver[q] + mesh[q] for q in QUANTITIES},
                 "at_rest": ref["at_rest"] and check["at_rest"] and coarser["at_rest"],
                 "converged": converged, "run": ref}
    progress(f"reference: {ref['particles']} particles (spacing {spacing * 1e3:.4g} mm, {grade_spacing * 1e3:.4g} mm "
             f"near the tool), {setting_label(converged, method)}: force {ref['force'][1]:.5g} N, strain energy "
             f"{ref['energy']:.5g} J, RMS displacement {rms(ref['u'], ref['mass']):.4g} m; its own error, solver (vs "
             f"{setting_label(tighter(converged, method), method)}): "
             + _listing(solver)
             + f"; mesh (2.4 x the change from {coarser['particles']} particles): "
             + _listing(mesh))
    return reference


def tune_material(cfg: Config, tolerance: float, budget_ms: float, spacings: Sequence[float],
                  grades: Sequence[float], depth: float, settings: Sequence[tuple[int, int, float]] | None = None,
                  converged: tuple[int, int, float] | None = None,
                  progress: Any = print,
                  **backend: Any) -> tuple[dict[str, Any] | None, list[dict[str, Any]], dict[str, Any]]:
    """Measure every mesh x setting; the cheapest row meeting tolerance and budget (None if none), rows, reference.

    A mesh whose mesh error alone exceeds the tolerance gets one row (its converged setting): no setting
    on it can qualify. ``backend``: ``jobs``, ``backend``, ``address`` of :func:`rest_runs` (the runs of each
    stage, reference, converged per mesh, settings, are independent calls; the same numbers).
    """
    settings = settings or solver_settings(cfg)[0]
    converged = converged or solver_settings(cfg)[1]
    t0 = time.perf_counter()
    reference = build_reference(cfg, *reference_meshes(spacings, grades), depth, converged, progress, **backend)
    press, ref = reference["press"], reference["run"]
    ref_h, ref_g = reference["spacing"], reference["grade_spacing"]
    meshes = [(h, g, mesh_config(cfg, press, h, g)) for h in sorted(spacings, reverse=True)
              for g in sorted({0.0, *(g for g in grades if 0 < g < h)}, reverse=True)]
    convs = rest_runs([(with_setting(m, converged), press) for _, _, m in meshes], **backend)
    plans = []
    for (h, g, mesh_cfg), conv in zip(meshes, convs):
        mesh_err = errors(conv, ref)
        worst_mesh = max(mesh_err[q] + reference["error"][q] for q in QUANTITIES)
        progress(f"mesh {h * 1e3:g} mm" + (f", {g * 1e3:g} mm near the tool" if g else "")
                 + f" ({conv['particles']} particles): against the reference "
                 + _listing(mesh_err, ".3g"))
        plans.append((h, g, mesh_cfg, conv, mesh_err, [] if worst_mesh > tolerance else list(settings)))
    todo = [(with_setting(mesh_cfg, s), press) for _, _, mesh_cfg, _, _, sets in plans for s in sets]
    done = iter(rest_runs(todo, **backend))
    rows: list[dict[str, Any]] = []
    for h, g, _, conv, mesh_err, sets in plans:
        runs = [(s, next(done)) for s in sets] or [(converged, conv)]
        for (n, it, tol), run in runs:
            solver_err = errors(run, conv, same_mesh=True)
            row: dict[str, Any] = {"spacing": h, "grade_spacing": g, "particles": run["particles"],
                                   "substeps": n, "iterations": it, "solve_tolerance": tol,
                                   "ms_per_step": run["solve_ms"]}
            for q in QUANTITIES:
                row[f"mesh_{q}"] = mesh_err[q] + reference["error"][q]
                row[f"solver_{q}"] = solver_err[q]
                row[f"err_{q}"] = row[f"mesh_{q}"] + solver_err[q]
            row["error"] = max(row[f"err_{q}"] for q in QUANTITIES)
            row["at_rest"] = run["at_rest"] and conv["at_rest"]
            rows.append(row)
    ok = [r for r in rows if r["error"] <= tolerance and r["ms_per_step"] <= budget_ms and r["at_rest"]]
    best = min(ok, key=lambda r: r["ms_per_step"]) if ok else None
    for r in rows:
        r["ref_spacing"], r["ref_grade_spacing"] = ref_h, ref_g
        r["wall_s_total"] = time.perf_counter() - t0
    return best, rows, reference


def chosen_config(cfg: Config, press: Press, row: dict[str, Any]) -> Config:
    """The scene's configuration with the row's mesh and solver setting."""
    return with_setting(mesh_config(cfg, press, float(row["spacing"]), float(row["grade_spacing"])),
                        (row["substeps"], row["iterations"], row["solve_tolerance"]))


def verify(chosen: Config, reference: dict[str, Any]) -> dict[str, Any]:
    """Run a configuration (e.g. a written parameter file, resolved) under the press; its errors against a
    reference run directly (not the mesh + solver sum), and its solver time per step."""
    run = press_to_rest(chosen, reference["press"])
    out: dict[str, Any] = {"particles": run["particles"], "ms_per_step": run["solve_ms"], "at_rest": run["at_rest"]}
    out.update({f"err_{q}": v for q, v in errors(run, reference["run"]).items()})
    out["error"] = max(out[f"err_{q}"] for q in QUANTITIES)
    return out


def plot(path: Path, rows: Sequence[dict[str, Any]], best: dict[str, Any] | None, tolerance: float,
         title: str, method: str = "xpbd") -> None:
    """The worst of the three errors against solver time per step, one marker per mesh; the choice circled."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, ax = plt.subplots(figsize=(7.5, 4.6))
    meshes = sorted({(r["spacing"], r["grade_spacing"]) for r in rows}, reverse=True)
    markers = "osD^v<>phX*"
    for k, (h, g) in enumerate(meshes):
        sel = [r for r in rows if (r["spacing"], r["grade_spacing"]) == (h, g)]
        label = f"{h * 1e3:g} mm" + (f", {g * 1e3:g} mm at the tool" if g else " uniform") + f" ({sel[0]['particles']})"
        ax.loglog([r["ms_per_step"] for r in sel], [max(r["error"], 1e-5) for r in sel], markers[k % len(markers)],
                  ls="none", mfc="none" if not g else None, label=label)
    ax.axhline(tolerance, color="#c62828", lw=0.8, ls="--", label=f"tolerance {tolerance:g}")
    if best is not None:
        ax.loglog([best["ms_per_step"]], [best["error"]], "o", ms=16, mfc="none", mec="k",
                  label="chosen: " + setting_label((best["substeps"], best["iterations"], best["solve_tolerance"]), method))
    ax.set_xlabel("solver time per step [ms]")
    ax.set_ylabel("worst of field, force, energy error (mesh + solver)")
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=6.5, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


TABLE = ["spacing", "grade_spacing", "particles", "substeps", "iterations", "solve_tolerance", "ms_per_step", "mesh_field",
         "solver_field", "mesh_force", "solver_force", "mesh_energy", "solver_energy", "error", "at_rest"]


def run_tune_material(cfg: Config, *, tolerance: float, budget_ms: float, material_spacings: Sequence[float],
                      grade_spacings: Sequence[float] = (), quick: bool = False,
                      verify_only: bool = False, depth: float = 0.003, out: str | Path | None = None,
                      csv_path: str | Path | None = None, png_path: str | Path | None = None,
                      params_file: str | Path | None = None, **backend: Any) -> int:
    """``tissue-sim tune`` on a neo_hookean scene: the arguments of :func:`~tissue_sim_ros.tune.settings.run`.

    ``material_spacings`` and ``grade_spacings`` [m] are the candidates (``quick``: 6 mm and 3 mm; no grade
    spacing: uniform meshes only); ``backend`` holds ``jobs``, ``backend`` and ``address``. Returns the exit status.
    """
    from ..bench.accuracy import format_table, write_csv  # noqa: PLC0415
    from ..core.config import resolve_config  # noqa: PLC0415

    method = cfg.sim.method
    settings, converged = solver_settings(cfg, quick)
    if quick:
        spacings, grades = [0.006], [0.003]
    else:
        spacings = sorted(set(material_spacings), reverse=True)
        grades = sorted(set(grade_spacings), reverse=True)
    if verify_only:
        return run_verify(cfg, spacings, grades, converged, depth=depth, tolerance=tolerance,
                          params_file=params_file, **backend)
    best, rows, reference = tune_material(cfg, tolerance, budget_ms, spacings, grades, depth,
                                          settings, converged, **backend)
    if csv_path:
        Path(csv_path).parent.mkdir(parents=True, exist_ok=True)
        write_csv(Path(csv_path), rows)
    title = (f"tune, material {cfg.sim.material}, E {cfg.sim.young_modulus:g} Pa, instrument {depth * 1e3:g} mm "
             f"in;\nreference {reference['spacing'] * 1e3:.3g} mm, {reference['grade_spacing'] * 1e3:.3g} mm at the tool")
    if png_path:
        Path(png_path).parent.mkdir(parents=True, exist_ok=True)
        plot(Path(png_path), rows, best, tolerance, title, method)
    print(f"\n{title.replace(chr(10), ' ')}; error = mesh (converged {setting_label(converged, method)} vs the reference, plus the reference's "
          f"own error: " + _listing(reference["error"])
          + f") + solver (vs {setting_label(converged, method)} on the same mesh), per quantity; 'error' is the worst:")
    print(format_table(rows, TABLE))
    if best is None:
        within = [r for r in rows if r["ms_per_step"] <= budget_ms and r["at_rest"]]
        hint = min(within, key=lambda r: r["error"]) if within else None
        msg = f"\nno setting meets error <= {tolerance:g} within {budget_ms:g} ms per step"
        if hint:
            msg += (f"; the most accurate within budget: spacing {hint['spacing']:g} m, grade_spacing "
                    f"{hint['grade_spacing']:g} m, {setting_label((hint['substeps'], hint['iterations'], hint['solve_tolerance']), method)} (error field "
                    f"{hint['err_field']:.3g}, force {hint['err_force']:.3g}, energy {hint['err_energy']:.3g}, "
                    f"{hint['ms_per_step']:.3g} ms)")
        print(msg + (f"; {out} not written" if out else "") + " (exit 1)")
        return 1
    print(f"\nchosen: spacing {best['spacing']:g} m" + (f", {best['grade_spacing']:g} m near the tool"
                                                       if best["grade_spacing"] else "")
          + f" ({best['particles']} particles), {setting_label((best['substeps'], best['iterations'], best['solve_tolerance']), method)}: "
          f"{best['ms_per_step']:.3g} ms per step, error field {best['err_field']:.3g}, force {best['err_force']:.3g}, "
          f"energy {best['err_energy']:.3g}")
    if out:
        chosen = chosen_config(cfg, reference["press"], best)
        header = (f"# written by tissue-sim tune --tolerance {tolerance:g} --budget-ms {budget_ms:g}"
                  f" (material): measured {best['ms_per_step']:.3g} ms per step, error (mesh + solver) field "
                  f"{best['err_field']:.3g}, force {best['err_force']:.3g}, energy {best['err_energy']:.3g}\n")
        path = Path(out)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(header + chosen.to_yaml())
        print(f"wrote {path}")
        # the written file, run as any command would load it, against the reference directly
        check = verify(resolve_config(params_file=path), reference)
        print(f"verified {path}: {check['particles']} particles, {check['ms_per_step']:.3g} ms per step, error "
              f"against the reference field {check['err_field']:.3g}, force {check['err_force']:.3g}, energy "
              f"{check['err_energy']:.3g} (the reference's own: "
              + _listing(reference["error"]) + ")")
    return 0


def run_verify(cfg: Config, spacings: Sequence[float], grades: Sequence[float], converged: tuple[int, int, float], *,
               depth: float, tolerance: float, params_file: str | Path | None = None, **backend: Any) -> int:
    """``--verify``: the parameter file as it is, against the reference tune would build for these candidates."""
    reference = build_reference(cfg, *reference_meshes(spacings, grades), depth, converged, **backend)
    check = verify(cfg, reference)
    print(f"\n{params_file or ''}: {check['particles']} particles (spacing {cfg.scene.spacing:g} m, grade_spacing "
          f"{cfg.scene.grade_spacing:g} m), {setting_label((cfg.sim.substeps, cfg.sim.iterations, cfg.sim.solve_tolerance), cfg.sim.method)}: {check['ms_per_step']:.3g} ms "
          f"per step, error against the reference field {check['err_field']:.3g}, force {check['err_force']:.3g}, "
          f"energy {check['err_energy']:.3g}" + ("" if check["at_rest"] else " (not at rest)")
          + " (the reference's own: " + _listing(reference["error"]) + ")")
    return 0 if check["error"] <= tolerance and check["at_rest"] else 1
