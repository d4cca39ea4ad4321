"""``tissue-sim tune``: the cheapest mesh spacing, method, iterations and substeps meeting an error tolerance.

Model no more than the scene needs. On the scene of a parameter file (the
shipped one by default) and experiment a's steps 175-205, every candidate mesh spacing
is solved exactly (Newton, :mod:`~tissue_sim_ros.bench.reference`) and against
an exact run on a mesh twice as fine as the finest candidate; every method is
run at growing iteration (substep) counts. The error of a setting is

    error = accumulated error of the method against the exact run on its own mesh
          + error of that exact run against the finest mesh's (discretisation),

both relative to the tissue's displacement, at the end of the trajectory (the
sum bounds the error against the finest exact run, up to the normalisations).
The cheapest setting (median solve time per step) with error <= tolerance and
time <= budget is written as a parameter file in the format of
``config/tissue_sim.yaml``. Everything is measured in this run; nothing is
extrapolated.

With ``material: neo_hookean`` (e.g. ``--params config/scenes/liver_probe.yaml``) the error is the
material's physical one instead, mesh plus solver error at rest under the scene's instrument, over
uniform and graded meshes (finer near the instrument), substeps and iterations
(:mod:`~tissue_sim_ros.bench.tune_material`).

Exit status: 0 when a setting meets the tolerance within the budget (written to
--out if given); 1 when none does (nothing is written; the most accurate setting
within the budget is printed), and with --verify when the file's error exceeds
--tolerance; 2 on bad input.
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..core.config import Config, resolve_config
from ..core.errors import InputError
from .accuracy import (
    Setting,
    default_scene,
    displacement_error,
    format_table,
    measure_setting,
    reference_run,
    write_csv,
)

HELP = "pick the cheapest mesh spacing/method/iterations meeting an error tolerance"
DESCRIPTION = __doc__

COUNTS = (1, 2, 5, 10, 20, 50, 100, 200)
METHODS = ("pbd", "xpbd", "xpbd_jacobi", "xpbd_substep")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--tolerance", type=float, required=True,
                        help="largest accepted error (relative to the tissue's displacement), e.g. 0.1")
    parser.add_argument("--budget-ms", type=float, required=True, help="largest accepted solve time per step [ms]")
    parser.add_argument("--out", default="",
                        help="write the chosen parameters to this YAML file (nothing is written, exit 1, when no "
                             "setting meets the tolerance within the budget)")
    parser.add_argument("--params", default="", help="scene parameter file (default: config/tissue_sim.yaml)")
    parser.add_argument("--spacings", default="0.1,0.05",
                        help="candidate mesh spacings [m], comma-separated (the reference is twice as fine as the "
                             "finest; below 0.025 the exact reference run gets slow: the finer mesh is a softer "
                             "material that folds under the tool, where each exact step takes Newton minutes)")
    parser.add_argument("--steps", type=int, default=30, help="trajectory length in steps")
    parser.add_argument("--csv", default="", help="also write every measured setting to this CSV")
    parser.add_argument("--quick", action="store_true", help="two coarse spacings, few counts (smoke test)")
    parser.add_argument("--material-spacings", default="0.005,0.0035,0.0025",
                        help="material neo_hookean: candidate spacings [m] (the reference mesh is 2 sqrt(2) x finer than the finest)")
    parser.add_argument("--grade-spacings", default="0.00125,0.000875,0.000625,0.00044",
                        help="material neo_hookean: candidate spacings near the instrument [m] for graded meshes "
                             "(each with every coarser spacing; uniform meshes are always candidates; the "
                             "reference is graded 2 sqrt(2) x finer than the finest); empty = uniform only")
    parser.add_argument("--png", default="", help="material neo_hookean: write the error-time chart to this PNG")
    parser.add_argument("--verify", action="store_true",
                        help="material neo_hookean: measure the --params file as it is against the reference of "
                             "--material-spacings/--grade-spacings (exit 1 when an error exceeds --tolerance)")
    parser.add_argument("--depth", type=float, default=0.003,
                        help="material neo_hookean: how far the instrument presses into the tissue [m]")
    from ..core.sim.backends import add_backend_arguments  # noqa: PLC0415

    add_backend_arguments(parser, jobs_default=1,
                          jobs_help="worker processes for independent runs (default 1: in this process; the errors "
                                    "are the same with more, the times are measured beside the other workers)")


def _parse_spacings(text: str) -> list[float]:
    try:
        values = sorted({float(v) for v in text.split(",") if v.strip()}, reverse=True)
    except ValueError:
        raise InputError(f"--spacings={text!r}: expected comma-separated numbers in metres") from None
    if not values or any(not (math.isfinite(v) and v > 0) for v in values):
        raise InputError(f"--spacings={text!r}: expected spacings > 0 m")
    return values


def _chain(scene: Any, method: str, counts: tuple[int, ...], ref_run: list[np.ndarray], disc: float,
           newton_ms: float, tolerance: float, budget_ms: float,
           progress: Any = None) -> list[dict[str, Any]]:
    """One method on one mesh at growing counts until it meets the tolerance, exceeds the budget or diverges
    (more iterations then only cost more): the rows. Independent of every other chain (a unit of work)."""
    rows = []
    for count in counts:
        row = measure_setting(scene, Setting(method, count), ref_run, per_step_every=0, progress=progress)
        row["err_discretisation"] = disc
        row["error"] = row["err_accum_final"] + disc
        row["newton_ms"] = newton_ms
        rows.append(row)
        if row["ms_per_step"] > budget_ms or row["error"] <= tolerance or row["diverged"]:
            break
    return rows


def _reference(scene: Any, progress: Any = None) -> tuple[list[np.ndarray], float]:
    return reference_run(scene, progress)


def tune(values: dict[str, Any], tolerance: float, budget_ms: float, spacings: list[float], n_steps: int,
         counts: tuple[int, ...] = COUNTS, methods: tuple[str, ...] = METHODS,
         progress: Any = None, *, jobs: int = 1, backend: str = "local",
         address: str | None = None) -> tuple[dict[str, Any] | None, list[dict[str, Any]]]:
    """Measure the candidates; return the chosen row (None if none qualifies) and every row.

    Counts grow per method and spacing until the method meets the tolerance
    (more iterations then only cost more) or its time exceeds the budget.
    ``jobs`` > 1 or ``backend="ray"``: the exact reference runs, then the (spacing, method) chains, run as
    independent calls (:func:`~tissue_sim_ros.core.sim.backends.map_calls`); the errors are those of ``jobs=1``
    exactly, the times are measured with the other workers running beside (``progress`` then counts calls).
    """
    from ..core.sim.backends import map_calls  # noqa: PLC0415

    base = default_scene(spacings[0], float(values.get("dt", 0.01)), n_steps, overrides=values)
    finest = default_scene(spacings[-1] / 2, base.params.dt, n_steps, overrides=values, like=base)
    scenes = [base if spacing == spacings[0] else default_scene(spacing, base.params.dt, n_steps,
                                                                  overrides=values, like=base)
              for spacing in spacings]
    here = jobs == 1 and backend == "local"

    def calls(fn: Any, args: list[tuple]) -> list[Any]:
        if here:  # in this process, with a progress tick per step
            return [fn(*a, progress=progress) for a in args]
        return map_calls(fn, args, backend=backend, workers=jobs, address=address,
                         progress=(lambda: progress(1)) if progress else None)

    refs = calls(_reference, [(finest,)] + [(scene,) for scene in scenes])
    finest_run = refs[0][0]
    chains = []
    for scene, (ref_run, newton_ms) in zip(scenes, refs[1:]):
        disc = displacement_error(scene, ref_run[-1], finest, finest_run[-1])
        chains += [(scene, method, tuple(counts), ref_run, disc, newton_ms, tolerance, budget_ms)
                   for method in methods]
    rows = [row for chain in calls(_chain, chains) for row in chain]
    ok = [r for r in rows if r["error"] <= tolerance and r["ms_per_step"] <= budget_ms and not r["diverged"]]
    return (min(ok, key=lambda r: r["ms_per_step"]) if ok else None), rows


def params_for(cfg: Config, row: dict[str, Any]) -> Config:
    """The scene's configuration with the chosen spacing, method, scheme, iterations and substeps."""
    return cfg.replace(spacing=float(row["spacing"]), **Setting(row["method"], int(row["count"])).values())


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm  # noqa: PLC0415

    if not (math.isfinite(args.tolerance) and args.tolerance > 0):
        raise InputError(f"--tolerance={args.tolerance}: expected an error > 0")
    if not (math.isfinite(args.budget_ms) and args.budget_ms > 0):
        raise InputError(f"--budget-ms={args.budget_ms}: expected a time > 0 ms")
    if args.steps < 1:
        raise InputError(f"--steps={args.steps}: expected at least 1 step")
    from ..core.sim.backends import check_backend_arguments  # noqa: PLC0415

    jobs, backend, address = check_backend_arguments(args)
    cfg = resolve_config(params_file=args.params or None)
    if cfg.sim.material == "neo_hookean":
        # a physical material: mesh + solver error at rest under the instrument (bench/tune_material.py)
        from .tune_material import run_tune_material  # noqa: PLC0415

        if not (math.isfinite(args.depth) and args.depth > 0):
            raise InputError(f"--depth={args.depth}: expected a depth > 0 m")
        return run_tune_material(args, cfg, jobs=jobs, backend=backend, address=address)
    values = cfg.flat()
    spacings = [0.1, 0.05] if args.quick else _parse_spacings(args.spacings)
    counts = (1, 10) if args.quick else COUNTS
    n_steps = min(args.steps, 4) if args.quick else args.steps

    with tqdm(desc="tune", unit="step", dynamic_ncols=True) as bar:
        best, rows = tune(values, args.tolerance, args.budget_ms, spacings, n_steps, counts, METHODS, bar.update,
                           jobs=jobs, backend=backend, address=address)
    if args.csv:
        Path(args.csv).parent.mkdir(parents=True, exist_ok=True)
        write_csv(Path(args.csv), rows)
    cols = ["spacing", "particles", "method", "count", "ms_per_step", "err_accum_final", "err_discretisation", "error"]
    print("\nmeasured settings (error = method vs exact on its mesh + exact vs the finest mesh):")
    print(format_table(rows, cols))
    if best is None:
        within = [r for r in rows if r["ms_per_step"] <= args.budget_ms and math.isfinite(r["error"])]
        hint = min(within, key=lambda r: r["error"]) if within else None
        msg = f"\nno setting meets error <= {args.tolerance:g} within {args.budget_ms:g} ms per step"
        if hint:
            msg += (f"; the most accurate within budget: {hint['method']} count {hint['count']} at spacing "
                    f"{hint['spacing']:g} (error {hint['error']:.3g}, {hint['ms_per_step']:.3g} ms)")
        print(msg + (f"; {args.out} not written" if args.out else "") + " (exit 1)")
        return 1
    print(f"\nchosen: spacing {best['spacing']:g} m ({best['particles']} particles), {best['method']} count "
          f"{best['count']}: {best['ms_per_step']:.3g} ms per step, error {best['error']:.3g} "
          f"(method {best['err_accum_final']:.3g} + mesh {best['err_discretisation']:.3g})")
    if args.out:
        path = Path(args.out)
        path.parent.mkdir(parents=True, exist_ok=True)
        header = (f"# written by tissue-sim tune --tolerance {args.tolerance:g} --budget-ms {args.budget_ms:g}\n"
                  f"# measured: {best['ms_per_step']:.3g} ms per step, error {best['error']:.3g} on experiment a (steps 175-205)\n")
        path.write_text(header + params_for(cfg, best).to_yaml())
        print(f"wrote {path}")
    return 0
