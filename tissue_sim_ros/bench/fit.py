"""``tissue-sim bench fit``: does ``tissue-sim fit`` give known parameters back, with honest error bars, fast?

Recordings made by the simulator with known parameters (experiments/fit_scene.py:
a 100 mm x 40 mm neo-Hookean block released under its weight and pressed by a
16 mm ball, 300 steps of 10 ms) on a finer mesh (2.5 mm) than the fit uses
(4 mm), 10, 20 and 30 tracked points with 0.5 mm Gaussian noise at 30 Hz, tool
poses at 125 Hz, written as real bags (PointCloud2 + PoseStamped) and read back
by the fit's own reader. For each, Young's modulus and Poisson's ratio are
fitted from a start of 2 kPa and 0.45 (truth 5 kPa and 0.30), the last 20% of
the recording held out, and the table gives the errors, whether the 95%
intervals hold the truth, the RMS tracking errors and the wall time of the fit
(--jobs worker processes).

The targets: Young's modulus within 5%, Poisson's ratio within 0.05,
error bars that cover the truth, a two-parameter fit of a 300-step recording
in at most 60 s on 2 cores. Writes fit.csv and fit.png to --out.
"""
from __future__ import annotations

import csv
import math
import os
import tempfile
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..core.errors import InputError

#: tracked point counts, one recording each
POINTS = (10, 20, 30)


def measure(n_points: int, seed: int, *, record_spacing: float, fit_spacing: float, jobs: int, work: Path,
            duration: float | None = None, backend: str = "local", address: str | None = None) -> dict[str, Any]:
    """One recording (written as a bag and read back) and its fit; the row of the table."""
    from ..experiments import fit as fitcli  # noqa: PLC0415
    from ..experiments import fit_scene as fs  # noqa: PLC0415
    from ..ros.recording import read_recording, write_recording  # noqa: PLC0415

    image = fs.write_scene_image(work / "scene.png")
    syn = fs.synthesize(fs.scene_params(image, spacing=record_spacing, **fs.TRUTH), n_points=n_points, noise=5e-4,
                        seed=seed, duration=duration)
    bag = work / f"rec_{n_points}_{seed}"
    write_recording(bag, syn.t_ns, syn.points, syn.tool_t_ns, syn.tool_pose)
    rec = read_recording(bag, "/tracker/points", "/tool/pose")
    setup = fitcli.prepare(rec, fs.scene_params(image, spacing=fit_spacing), ["young_modulus", "poisson_ratio"],
                           holdout=0.2)
    t0 = time.perf_counter()
    res = fitcli.run_fit(setup, jobs=jobs, slices=0, backend=backend, address=address)
    wall = time.perf_counter() - t0
    e, nu = res.estimate("young_modulus"), res.estimate("poisson_ratio")
    te, tnu = fs.TRUTH["young_modulus"], fs.TRUTH["poisson_ratio"]

    def covered(est, truth):
        return bool(est.value is not None and est.low95 <= truth <= est.high95)

    return {
        "points": n_points, "seed": seed, "steps": setup.schedule.n_steps, "fit_particles": int(setup.mesh.vertices.shape[0]),
        "E": e.value, "E_sigma": e.sigma, "E_low95": e.low95, "E_high95": e.high95, "E_err_pct": 100 * (e.value / te - 1) if e.value else float("nan"),
        "E_covered": covered(e, te), "E_mesh_shift": e.mesh_shift,
        "nu": nu.value, "nu_sigma": nu.sigma, "nu_low95": nu.low95, "nu_high95": nu.high95, "nu_err": (nu.value - tnu) if nu.value is not None else float("nan"),
        "nu_covered": covered(nu, tnu), "nu_mesh_shift": nu.mesh_shift,
        "rms_fit_mm": res.rms_fit_mm, "rms_holdout_mm": res.rms_holdout_mm, "tau": res.tau,
        "evaluations": res.n_iterations, "rollouts": res.n_rollouts, "fit_wall_s": wall, "jobs": jobs,
        "E_reason": e.reason, "nu_reason": nu.reason,
    }


def run(out: str | Path, *, points: Sequence[int] = POINTS, seeds: int = 2, record_spacing: float | None = None,
        fit_spacing: float | None = None, quick: bool = False, jobs: int | None = None, backend: str = "local",
        address: str | None = None) -> int:
    """Record, fit and compare with the truth for every point count and seed; print, write fit.csv/png; 0.

    Parameters
    ----------
    out : str or Path
        Output directory (created).
    points : sequence of int
        Tracked point counts, one recording each (``quick``: the first).
    seeds : int
        Recordings per point count, each its own noise and points (``quick``: 1).
    record_spacing, fit_spacing : float, optional
        Mesh spacings of the recordings and of the fits [m] (default: experiments/fit_scene.py's; ``quick``
        6 and 8 mm).
    quick : bool
        One short recording at coarse spacings (smoke test).
    jobs : int, optional
        Worker processes per fit (default: 2 or the cores).
    backend, address
        ``"local"`` or ``"ray"`` and the Ray cluster.
    """
    from ..core.sim.backends import check_backend, check_jobs  # noqa: PLC0415
    from ..experiments import fit_scene as fs  # noqa: PLC0415

    counts = list(points)
    jobs = check_jobs(min(2, os.cpu_count() or 1) if jobs is None else jobs)
    backend = check_backend(backend)
    if not counts or min(counts) < 1 or seeds < 1:
        raise InputError("--points and --seeds: expected at least 1")
    rec_sp = record_spacing or (0.006 if quick else fs.RECORDING_SPACING)
    fit_sp = fit_spacing or (0.008 if quick else fs.FIT_SPACING)
    duration = 1.5 if quick else None
    if quick:
        counts, seeds = counts[:1], 1
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    with open("/proc/loadavg") if os.path.exists("/proc/loadavg") else open(os.devnull) as fh:
        load_before = fh.read().strip()
    with tempfile.TemporaryDirectory() as tmp:
        for n in counts:
            for seed in range(seeds):
                row = measure(n, seed, record_spacing=rec_sp, fit_spacing=fit_sp, jobs=jobs, work=Path(tmp),
                              duration=duration, backend=backend, address=address)
                rows.append(row)
                print(f"  {n} points, seed {seed}: E {_num(row['E'], '.1f')} Pa ({_num(row['E_err_pct'], '+.2f')}%), "
                      f"nu {_num(row['nu'], '.4f')} ({_num(row['nu_err'], '+.4f')}), {row['fit_wall_s']:.1f} s"
                      + "".join(f"; {k[:-7]} not identifiable: {row[k]}" for k in ("E_reason", "nu_reason") if row[k]),
                      flush=True)
    with open("/proc/loadavg") if os.path.exists("/proc/loadavg") else open(os.devnull) as fh:
        load_after = fh.read().strip()
    print(f"recordings on a {rec_sp * 1e3:g} mm mesh, fits on {fit_sp * 1e3:g} mm; truth E {fs.TRUTH['young_modulus']:g} Pa, "
          f"nu {fs.TRUTH['poisson_ratio']:g}; start 2000 Pa, 0.45; 0.5 mm noise; {jobs} worker(s)")
    head = (f"{'points':>6} {'seed':>4} {'steps':>5} {'E [Pa]':>8} {'+-1s':>6} {'E err':>7} {'cov':>4} {'nu':>7} "
            f"{'+-1s':>6} {'nu err':>7} {'cov':>4} {'RMS fit':>8} {'RMS hold':>8} {'evals':>5} {'fit s':>6}")
    print(head)
    for r in rows:
        print(f"{r['points']:>6} {r['seed']:>4} {r['steps']:>5} {_num(r['E'], '8.1f')} {_num(r['E_sigma'], '6.1f')} "
              f"{_num(r['E_err_pct'], '6.2f')}% {'yes' if r['E_covered'] else 'NO':>4} {_num(r['nu'], '7.4f')} "
              f"{_num(r['nu_sigma'], '6.4f')} {_num(r['nu_err'], '+7.4f')} "
              f"{'yes' if r['nu_covered'] else 'NO':>4} {r['rms_fit_mm']:>8.3f} {r['rms_holdout_mm']:>8.3f} "
              f"{r['evaluations']:>5} {r['fit_wall_s']:>6.1f}")
    walls = np.array([r["fit_wall_s"] for r in rows])
    ok_e = sum(abs(r["E_err_pct"]) < 5 for r in rows)
    ok_nu = sum(abs(r["nu_err"]) < 0.05 for r in rows)
    cov = sum(r["E_covered"] and r["nu_covered"] for r in rows)
    print(f"E within 5%: {ok_e}/{len(rows)}; nu within 0.05: {ok_nu}/{len(rows)}; both 95% intervals hold the truth: "
          f"{cov}/{len(rows)}; fit wall time median {np.median(walls):.1f} s, max {walls.max():.1f} s "
          f"(load {load_before} before, {load_after} after)")
    with open(out / "fit.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    _plot(out / "fit.png", rows, fs.TRUTH)
    print(f"wrote {out}/fit.csv, fit.png")
    return 0


def _num(v: float | None, fmt: str) -> str:
    """A number, or '-' right-aligned for one the fit did not return (not identifiable)."""
    width = int(fmt.lstrip("+").split(".")[0] or 0)
    # an error of an estimate the fit did not return is NaN: no number to print either
    return format(v, fmt) if v is not None and not (isinstance(v, float) and math.isnan(v)) else "-".rjust(width)


def _plot(path: Path, rows: list[dict], truth: dict) -> None:
    from ..render import _save, plt  # noqa: PLC0415

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    x = np.arange(len(rows))
    labels = [f"{r['points']} pts\nseed {r['seed']}" for r in rows]
    for ax, key, name, t in ((axes[0], "E", "Young's modulus [Pa]", truth["young_modulus"]),
                             (axes[1], "nu", "Poisson's ratio", truth["poisson_ratio"])):
        ok = [i for i, r in enumerate(rows) if r[key] is not None]
        ax.errorbar(x[ok], [rows[i][key] for i in ok], yerr=[[rows[i][key] - rows[i][f"{key}_low95"] for i in ok],
                                                              [rows[i][f"{key}_high95"] - rows[i][key] for i in ok]],
                    fmt="o", capsize=4, label="fitted, 95% interval")
        ax.axhline(t, color="k", ls="--", lw=1, label="truth")
        band = (0.05 * t) if key == "E" else 0.05
        ax.axhspan(t - band, t + band, color="0.9", zorder=-1, label="target (5% / 0.05)")
        ax.set_xticks(x, labels, fontsize=7)
        ax.set_ylabel(name)
        ax.legend(fontsize=7)
    ax = axes[2]
    ax.bar(x, [r["fit_wall_s"] for r in rows], color="C2")
    ax.axhline(60, color="C3", ls="--", lw=1, label="60 s target")
    ax.set_xticks(x, labels, fontsize=7)
    ax.set_ylabel(f"fit wall time [s], {rows[0]['jobs']} worker(s)")
    ax.legend(fontsize=7)
    fig.suptitle("tissue-sim fit on simulated recordings (finer mesh than the fit's, 0.5 mm noise)", fontsize=10)
    _save(fig, path, 110)
