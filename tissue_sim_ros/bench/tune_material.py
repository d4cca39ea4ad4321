"""``tissue-sim tune`` for ``material: neo_hookean``: the cheapest spacing, substeps and iterations within a tolerance.

The material's answer is a physical one, so its error has two parts, both measured here on the
parameter file's own scene (e.g. ``config/scenes/liver_probe.yaml``) under a static load: gravity and
the scene's instrument pressed ``--depth`` into the top of the tissue (upright, at the middle of the
tissue's width, moved in over 40 steps, then held until every particle is slower than 1e-5 m/s; a
damping of 50 1/s on the way does not change the rest state):

* mesh error of a spacing h: the rest displacement on h, solved to convergence (``--converged``
  substeps x iterations), against the same on a mesh of half the finest candidate's spacing,
  interpolated (piecewise linear) at h's particles: RMS difference / RMS displacement;
* solver error of a setting on h: its rest displacement against the converged one on h, the same
  norm (a solve stopped short of equilibrium leaves a bias at rest that grows as the mesh is refined).

error = mesh error + solver error (an upper bound on the error against the fine converged answer,
up to the normalisation). Time: the median solver time per step during the hold. The cheapest
setting with error <= tolerance and time <= budget is written as a parameter file: the scene's file
with ``spacing``, ``substeps`` and ``iterations`` replaced.
"""
from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..core.config import Config
from ..core.simulation import Simulation
from ..core.tool import ToolPose

SETTINGS = ((1, 10), (2, 5), (5, 2), (5, 5), (10, 2), (10, 5), (10, 10), (20, 10))
QUICK_SETTINGS = ((2, 5), (10, 10))
CONVERGED = (30, 30)
REST_SPEED = 1e-5


def press_to_rest(cfg: Config, depth: float, max_steps: int = 3000) -> dict[str, Any]:
    """Rest displacement under gravity and the instrument pressed ``depth`` into the top; solver ms per step."""
    cfg = cfg.replace(damping=50.0, sleep_speed=0.0)
    sim = Simulation.from_config(cfg)
    q0 = sim.model.particle_q0
    x_mid = 0.5 * (q0[:, 0].min() + q0[:, 0].max())
    near = np.abs(q0[:, 0] - x_mid) < 2.0 * cfg.scene.spacing
    top = float(q0[near, 1].max())
    half = 0.5 * sim.tool.length if sim.tool.kind in ("box", "capsule") else 0.0
    reach = sim.tool.radius if sim.tool.kind != "box" else 0.5 * sim.tool.width
    start = top + reach + 0.002  # the tool's lowest point 2 mm above the surface
    end = top + reach - depth
    ramp = 40
    solve_ms = []
    steps = 0
    for k in range(1, max_steps + 1):
        s = min(1.0, k / ramp)
        pose = ToolPose(x_mid, start + s * (end - start) + half, -0.5 * math.pi)
        r = sim.step(pose)
        steps = k
        if k > ramp:
            solve_ms.append(1e3 * r.timings.get("solve", r.timings.get("total", math.nan)))
            if float(np.abs(sim.state.particle_qd).max()) < REST_SPEED:
                break
    return {"q0": q0.copy(), "u": sim.state.particle_q - q0, "steps": steps, "particles": sim.model.n_particles,
            "solve_ms": float(np.median(solve_ms)) if solve_ms else math.nan,
            "at_rest": steps < max_steps}


def rms(a: np.ndarray) -> float:
    return float(np.sqrt((a * a).sum(axis=1).mean()))


def interpolate(fine: dict[str, Any], points: np.ndarray) -> np.ndarray:
    """The fine run's displacement at ``points`` (piecewise linear; nearest outside its hull)."""
    from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator  # noqa: PLC0415

    lin = LinearNDInterpolator(fine["q0"], fine["u"])(points)
    bad = ~np.all(np.isfinite(lin), axis=1)
    if bad.any():
        lin[bad] = NearestNDInterpolator(fine["q0"], fine["u"])(points[bad])
    return lin


def tune_material(cfg: Config, tolerance: float, budget_ms: float, spacings: Sequence[float], depth: float,
                  settings: Sequence[tuple[int, int]] = SETTINGS,
                  converged: tuple[int, int] = CONVERGED) -> tuple[dict[str, Any] | None, list[dict[str, Any]]]:
    """Measure every spacing x setting; the cheapest row meeting the tolerance and budget (None if none), all rows."""
    n_c, it_c = converged
    fine_h = 0.5 * min(spacings)
    t0 = time.perf_counter()
    fine = press_to_rest(cfg.replace(spacing=fine_h, substeps=n_c, iterations=it_c), depth)
    rows: list[dict[str, Any]] = []
    for h in sorted(spacings, reverse=True):
        conv = press_to_rest(cfg.replace(spacing=h, substeps=n_c, iterations=it_c), depth)
        mesh_err = rms(conv["u"] - interpolate(fine, conv["q0"])) / rms(interpolate(fine, conv["q0"]))
        for n, it in settings:
            run = press_to_rest(cfg.replace(spacing=h, substeps=n, iterations=it), depth)
            solver_err = rms(run["u"] - conv["u"]) / rms(conv["u"])
            rows.append({"spacing": h, "particles": run["particles"], "substeps": n, "iterations": it,
                         "ms_per_step": run["solve_ms"], "err_mesh": mesh_err, "err_solver": solver_err,
                         "error": mesh_err + solver_err, "at_rest": run["at_rest"] and conv["at_rest"]})
    ok = [r for r in rows if r["error"] <= tolerance and r["ms_per_step"] <= budget_ms and r["at_rest"]]
    best = min(ok, key=lambda r: r["ms_per_step"]) if ok else None
    for r in rows:
        r["fine_spacing"] = fine_h
        r["wall_s_total"] = time.perf_counter() - t0
    return best, rows


def run_tune_material(args: Any, cfg: Config) -> int:
    from .accuracy import format_table, write_csv  # noqa: PLC0415
    from .tune import _parse_spacings  # noqa: PLC0415

    spacings = [0.006, 0.004] if args.quick else _parse_spacings(args.material_spacings)
    settings = QUICK_SETTINGS if args.quick else SETTINGS
    converged = (10, 20) if args.quick else CONVERGED
    best, rows = tune_material(cfg, args.tolerance, args.budget_ms, spacings, args.depth, settings, converged)
    if args.csv:
        Path(args.csv).parent.mkdir(parents=True, exist_ok=True)
        write_csv(Path(args.csv), rows)
    print(f"\nmaterial {cfg.sim.material}, E {cfg.sim.young_modulus:g} Pa: rest under gravity and the instrument "
          f"{args.depth * 1e3:g} mm in; error = mesh (vs {rows[0]['fine_spacing'] * 1e3:g} mm, converged) + solver "
          f"(vs {converged[0]}x{converged[1]} on the same mesh):")
    print(format_table(rows, ["spacing", "particles", "substeps", "iterations", "ms_per_step", "err_mesh",
                              "err_solver", "error", "at_rest"]))
    if best is None:
        print(f"\nno setting meets error <= {args.tolerance:g} within {args.budget_ms:g} ms per step")
        return 1
    print(f"\nchosen: spacing {best['spacing']:g} m ({best['particles']} particles), {best['substeps']} substeps x "
          f"{best['iterations']} iterations: {best['ms_per_step']:.3g} ms per step, error {best['error']:.3g} "
          f"(mesh {best['err_mesh']:.3g} + solver {best['err_solver']:.3g})")
    if args.out:
        chosen = cfg.replace(spacing=best["spacing"], substeps=best["substeps"], iterations=best["iterations"])
        header = (f"# written by tissue-sim tune --tolerance {args.tolerance:g} --budget-ms {args.budget_ms:g}"
                  f" (material): measured {best['ms_per_step']:.3g} ms per step, error {best['error']:.3g}\n")
        path = Path(args.out)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(header + chosen.to_yaml())
        print(f"wrote {path}")
    return 0
