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
(:mod:`~tissue_sim_ros.tune.material`).

Exit status: 0 when a setting meets the tolerance within the budget (written to
--out if given); 1 when none does (nothing is written; the most accurate setting
within the budget is printed), and with --verify when the file's error exceeds
--tolerance; 2 on bad input.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..bench.accuracy import (
    Setting,
    default_scene,
    displacement_error,
    format_table,
    measure_setting,
    reference_run,
    write_csv,
)
from ..core.config import Config
from ..core.errors import InputError

COUNTS = (1, 2, 5, 10, 20, 50, 100, 200)
METHODS = ("pbd", "xpbd", "xpbd_jacobi", "xpbd_substep")
#: candidate mesh spacings [m], coarse to fine (the reference is twice as fine as the finest)
SPACINGS = (0.1, 0.05)
#: material neo_hookean: candidate uniform spacings and spacings near the instrument [m], coarse to fine
MATERIAL_SPACINGS = (0.005, 0.0035, 0.0025)
GRADE_SPACINGS = (0.00125, 0.000875, 0.000625, 0.00044)


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


def run(config: Config, *, tolerance: float, budget_ms: float, spacings: Sequence[float] = SPACINGS, steps: int = 30,
        out: str | Path | None = None, csv_path: str | Path | None = None, quick: bool = False,
        material_spacings: Sequence[float] = MATERIAL_SPACINGS, grade_spacings: Sequence[float] = GRADE_SPACINGS,
        png_path: str | Path | None = None, verify_only: bool = False, depth: float = 0.003,
        params_file: str | Path | None = None, jobs: int = 1, backend: str = "local",
        address: str | None = None) -> int:
    """Tune the scene of ``config``, print the table and the choice, write it to ``out``; the exit status.

    Parameters
    ----------
    config : Config
        The scene (its parameter file resolved). ``material: neo_hookean`` tunes the material's physical
        error instead (:func:`~tissue_sim_ros.tune.material.run_tune_material`).
    tolerance : float
        Largest accepted error, relative to the tissue's displacement.
    budget_ms : float
        Largest accepted solve time per step [ms].
    spacings : sequence of float
        Candidate mesh spacings [m], coarse to fine (``quick``: 0.1 and 0.05).
    steps : int
        Trajectory length in steps (``quick``: at most 4).
    out : str or Path, optional
        Write the chosen parameters to this YAML file (nothing is written when no setting qualifies).
    csv_path : str or Path, optional
        Also write every measured setting to this CSV.
    quick : bool
        Two coarse spacings, few counts (smoke test).
    material_spacings, grade_spacings : sequence of float
        Material neo_hookean: candidate uniform spacings and spacings near the instrument [m] (grade: empty for
        uniform meshes only).
    png_path : str or Path, optional
        Material neo_hookean: the error-time chart.
    verify_only : bool
        Material neo_hookean: measure ``config`` as it is against the reference instead.
    depth : float
        Material neo_hookean: how far the instrument presses into the tissue [m].
    params_file : str or Path, optional
        The file ``config`` was read from, named in the ``verify_only`` report.
    jobs, backend, address
        Where the independent runs go (:func:`tune`).

    Returns
    -------
    int
        0 when a setting meets the tolerance within the budget; 1 when none does (and with ``verify_only`` when the
        file's error exceeds the tolerance).

    Raises
    ------
    InputError
        A tolerance, budget, step count, depth, jobs or backend out of range.
    """
    from tqdm import tqdm  # noqa: PLC0415

    if not (math.isfinite(tolerance) and tolerance > 0):
        raise InputError(f"--tolerance={tolerance}: expected an error > 0")
    if not (math.isfinite(budget_ms) and budget_ms > 0):
        raise InputError(f"--budget-ms={budget_ms}: expected a time > 0 ms")
    if steps < 1:
        raise InputError(f"--steps={steps}: expected at least 1 step")
    from ..core.sim.backends import check_backend, check_jobs  # noqa: PLC0415

    jobs, backend = check_jobs(jobs), check_backend(backend)
    if config.sim.material == "neo_hookean":
        # a physical material: mesh + solver error at rest under the instrument (tune/material.py)
        from .material import run_tune_material  # noqa: PLC0415

        if not (math.isfinite(depth) and depth > 0):
            raise InputError(f"--depth={depth}: expected a depth > 0 m")
        return run_tune_material(config, tolerance=tolerance, budget_ms=budget_ms, quick=quick,
                                 material_spacings=material_spacings, grade_spacings=grade_spacings, verify_only=verify_only,
                                 depth=depth, out=out, csv_path=csv_path, png_path=png_path, params_file=params_file,
                                 jobs=jobs, backend=backend, address=address)
    values = config.flat()
    spacings = [0.1, 0.05] if quick else sorted(set(spacings), reverse=True)  # coarse to fine, as tune() reads them
    counts = (1, 10) if quick else COUNTS
    n_steps = min(steps, 4) if quick else steps

    with tqdm(desc="tune", unit="step", dynamic_ncols=True) as bar:
        best, rows = tune(values, tolerance, budget_ms, spacings, n_steps, counts, METHODS, bar.update,
                           jobs=jobs, backend=backend, address=address)
    if csv_path:
        Path(csv_path).parent.mkdir(parents=True, exist_ok=True)
        write_csv(Path(csv_path), rows)
    cols = ["spacing", "particles", "method", "count", "ms_per_step", "err_accum_final", "err_discretisation", "error"]
    print("\nmeasured settings (error = method vs exact on its mesh + exact vs the finest mesh):")
    print(format_table(rows, cols))
    if best is None:
        within = [r for r in rows if r["ms_per_step"] <= budget_ms and math.isfinite(r["error"])]
        hint = min(within, key=lambda r: r["error"]) if within else None
        msg = f"\nno setting meets error <= {tolerance:g} within {budget_ms:g} ms per step"
        if hint:
            msg += (f"; the most accurate within budget: {hint['method']} count {hint['count']} at spacing "
                    f"{hint['spacing']:g} (error {hint['error']:.3g}, {hint['ms_per_step']:.3g} ms)")
        print(msg + (f"; {out} not written" if out else "") + " (exit 1)")
        return 1
    print(f"\nchosen: spacing {best['spacing']:g} m ({best['particles']} particles), {best['method']} count "
          f"{best['count']}: {best['ms_per_step']:.3g} ms per step, error {best['error']:.3g} "
          f"(method {best['err_accum_final']:.3g} + mesh {best['err_discretisation']:.3g})")
    if out:
        path = Path(out)
        path.parent.mkdir(parents=True, exist_ok=True)
        header = (f"# written by tissue-sim tune --tolerance {tolerance:g} --budget-ms {budget_ms:g}\n"
                  f"# measured: {best['ms_per_step']:.3g} ms per step, error {best['error']:.3g} on experiment a (steps 175-205)\n")
        path.write_text(header + params_for(config, best).to_yaml())
        print(f"wrote {path}")
    return 0
