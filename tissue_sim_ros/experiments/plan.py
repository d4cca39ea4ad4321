"""``tissue-sim plan``: rank insertion angles and speeds toward a target by implicit Euler energy.

The paper's point of tracking the energy is to choose between ways of doing a
task (its experiment b compares two insertion angles). This generalises it:
every (angle, speed) pair is a full simulated insertion from the same rest
state toward the same target, run in parallel over the machine's cores; the
cost of an insertion is the energy it adds to the scene, summed over its steps
(the energy of each step minus that of the same scene without the tool; the
peak and the final energy are reported too). Output: a ranked table, plan.csv and
plan.png (cost against angle, one curve per speed, the best marked).

``--live`` plans on a running ``tissue_sim_node`` instead, through its
``~/plan_insertion`` service, carries the plan out on its tool topics and
replans every ``--replan-every`` steps (:mod:`~tissue_sim_ros.experiments.plan_live`).
"""
from __future__ import annotations

import math
import os
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from tqdm import tqdm

from ..core.config import Config
from ..core.errors import InputError, output_dir
from ..core.timing import trajectories as tr

#: (FROM, TO, STEP) of the insertion angles [deg], the direction of the tip's motion: -5 to -40 every 5
ANGLES = (-5.0, -40.0, 5.0)
#: tip speeds [m per step]
SPEEDS = (0.001, 0.002)


def angle_grid(start: float, stop: float, step: float) -> list[float]:
    """Angles from ``start`` to ``stop`` inclusive every ``step`` (the sign of step follows the direction)."""
    if step == 0 or not all(math.isfinite(v) for v in (start, stop, step)):
        raise InputError(f"--angles {start} {stop} {step}: expected finite FROM TO and a non-zero STEP")
    n = int(math.floor(abs(stop - start) / abs(step) + 1e-9)) + 1
    sign = 1.0 if stop >= start else -1.0
    return [start + sign * abs(step) * k for k in range(n)]


def evaluate(values: Config, angle_deg: float, speed: float, target: tuple[float, float],
             distance: float) -> dict[str, Any]:
    """One insertion from rest; the numbers a planner ranks by (runs in a worker process)."""
    from ..core.sim.rollout import rollout  # noqa: PLC0415
    from ..core.sim.scene import build_simulation  # noqa: PLC0415
    from .paper import baseline_rollout, insertion_cost  # noqa: PLC0415

    sim = build_simulation(values)
    traj = tr.experiment_b(sim.tool, sim.params.dt, angle_deg, speed=speed, target=target, distance=distance)
    t0 = time.perf_counter()
    run = rollout(sim, traj.steps(sim.params.dt))
    wall = time.perf_counter() - t0
    baseline = baseline_rollout(values, len(run.steps))
    total = run.scene_total
    added = total - baseline.scene_total[: len(total)]
    force = np.linalg.norm(run.reaction_force, axis=1)
    return {
        "angle_deg": angle_deg, "speed_m_per_step": speed, "steps": int(len(run.steps)),
        "cost": insertion_cost(run, baseline), "peak_added": float(added.max()), "final_added": float(added[-1]),
        "contact_steps": int(run.in_contact.any(axis=1).sum()), "max_reaction_N": float(force.max()),
        "max_inverted": int(sim.count_inverted()), "finite": bool(np.isfinite(total).all()), "wall_s": wall,
    }


def plan(values: Config, angles: list[float], speeds: list[float], target: tuple[float, float],
         distance: float, jobs: int, progress: bool = True, backend: str = "local",
         address: str | None = None) -> list[dict[str, Any]]:
    """Roll every (angle, speed) out from the rest state as one batch; rows ranked by cost (cheapest first).

    ``jobs`` warm worker processes (local; 1: serially here) or Ray actors
    (``backend="ray"``, ``address`` of the cluster); the numbers are the same
    bit for bit (:mod:`~tissue_sim_ros.core.sim.batch`), and equal to :func:`evaluate`'s.
    """
    from ..core.sim.backends import check_backend, rollout_pool  # noqa: PLC0415
    from ..core.sim.batch import BatchScene, rollout_batch  # noqa: PLC0415
    from ..core.sim.scene import build_simulation  # noqa: PLC0415

    for s in speeds:
        if not (math.isfinite(s) and s > 0):
            raise InputError(f"--speeds {s}: expected speeds > 0 m per step")
    if not (math.isfinite(distance) and distance > 0):
        raise InputError(f"--distance {distance}: expected an insertion distance > 0 m")
    if jobs < 1:
        raise InputError(f"--jobs {jobs}: expected at least 1 worker")
    check_backend(backend)
    tasks = [(a, s) for s in speeds for a in angles]
    sim = build_simulation(values)
    from ..core.plan.insertion import locate  # noqa: PLC0415

    if locate(sim.state.particle_q, sim.model.tri_indices, target) is None:
        # as the node's planner service (~/plan_insertion) refuses it: no insertion can reach such a target
        raise InputError(f"--target {target[0]:g} {target[1]:g}: the point ({target[0]:.4f}, {target[1]:.4f}) m "
                         "is outside the tissue: expected a target inside it")
    dt = sim.params.dt
    trajs = [tr.experiment_b(sim.tool, dt, a, speed=s, target=target, distance=distance) for a, s in tasks]
    bar = tqdm(total=1, desc=f"{len(tasks)} insertions", unit="batch", disable=not progress)
    if jobs == 1 and backend == "local":
        res = rollout_batch(sim, trajs)
    else:
        with rollout_pool(BatchScene.from_simulation(sim), jobs, backend, address) as pool:
            res = rollout_batch(sim, trajs, pool=pool)
    bar.update(1)
    bar.close()
    rows = [{"angle_deg": a, "speed_m_per_step": s, "steps": c.steps, "cost": c.cost, "peak_added": c.peak_added,
             "final_added": c.final_added, "contact_steps": c.contact_steps, "max_reaction_N": c.peak_force,
             "max_inverted": c.max_inverted, "finite": c.finite, "wall_s": c.wall_s}
            for (a, s), c in zip(tasks, res.candidates)]
    return sorted(rows, key=lambda r: (not r["finite"], r["cost"]))


def chart(path: Path, rows: list[dict[str, Any]], target: tuple[float, float]) -> Path:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, ax = plt.subplots(figsize=(8.4, 4.0))
    for speed in sorted({r["speed_m_per_step"] for r in rows}):
        sel = sorted((r for r in rows if r["speed_m_per_step"] == speed), key=lambda r: r["angle_deg"])
        ax.plot([r["angle_deg"] for r in sel], [r["cost"] for r in sel], "o-", label=f"{speed * 1e3:g} mm per step")
    best = rows[0]
    ax.plot([best["angle_deg"]], [best["cost"]], marker="*", ms=16, color="#ffd600", mec="#8d6e00",
            label=f"cheapest: {best['angle_deg']:+.0f} deg, {best['speed_m_per_step'] * 1e3:g} mm/step")
    ax.set_xlabel("insertion angle [deg] (direction of the tip's motion)")
    ax.set_ylabel("cost: energy added by the insertion")
    ax.set_yscale("symlog", linthresh=max(1e-15, min(abs(r["cost"]) for r in rows if r["cost"] != 0) if any(
        r["cost"] != 0 for r in rows) else 1e-15))
    ax.set_title(f"Insertions toward ({target[0]:.3f}, {target[1]:.3f}) m", fontsize=10)
    ax.grid(alpha=0.3, which="both")
    # beside the axes, never over them: inside, "best" still covered a curve whichever corner it chose
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def run(config: Config, out: str | Path, *, target: Sequence[float] = tr.B_TARGET,
        angles: Sequence[float] = ANGLES, speeds: Sequence[float] = SPEEDS, distance: float = tr.B_DISTANCE,
        jobs: int | None = None, backend: str = "local", address: str | None = None, progress: bool = True) -> int:
    """Plan, print the ranked table and write plan.csv and plan.png into ``out``; the exit status (0).

    Parameters
    ----------
    config : Config
        The scene (``tissue-sim plan`` resolves it over experiment b's tool, ``paper.B_TOOL_VALUES``).
    out : str or Path
        Output directory, created once the input is checked.
    target : (x, y)
        The tip's target [m], inside the tissue.
    angles : (from, to, step)
        Insertion angles [deg] (:func:`angle_grid`).
    speeds : sequence of float
        Tip speeds [m per step].
    distance : float
        Insertion distance [m].
    jobs : int, optional
        Warm workers (default: all cores; 1: serially in this process).
    backend, address : str
        ``"local"`` or ``"ray"`` and the Ray cluster (:func:`plan`).
    progress : bool
        Show a progress bar.

    Raises
    ------
    InputError
        Bad angles, speeds, distance, jobs, backend, a target outside the tissue, or ``out`` a file.
    """
    jobs = (os.cpu_count() or 1) if jobs is None else jobs
    angles = angle_grid(*angles)
    target = (float(target[0]), float(target[1]))
    out = output_dir(out, "--out")
    t0 = time.perf_counter()
    rows = plan(config, angles, list(speeds), target, distance, jobs, progress=progress,
                backend=backend, address=address)
    wall = time.perf_counter() - t0
    out.mkdir(parents=True, exist_ok=True)  # after the input is checked: bad input creates nothing
    cols = list(rows[0])
    with open(out / "plan.csv", "w") as fh:
        fh.write(",".join(cols) + "\n")
        for r in rows:
            fh.write(",".join(repr(r[c]) if isinstance(r[c], float) else str(r[c]) for c in cols) + "\n")
    chart(out / "plan.png", rows, target)
    print(f"{len(rows)} insertions toward {target} in {wall:.1f} s on {jobs} {'Ray actors' if backend == 'ray' else 'processes'}, ranked by cost "
          f"(energy the insertion adds, summed over its steps):")
    print(f"{'rank':>4} {'angle':>7} {'speed':>11} {'cost':>11} {'peak added':>11} {'contact':>8} {'max force':>10}")
    for i, r in enumerate(rows, 1):
        print(f"{i:>4} {r['angle_deg']:>+6.1f}° {r['speed_m_per_step'] * 1e3:>5.2f} mm/st {r['cost']:>11.4g} "
              f"{r['peak_added']:>11.4g} {r['contact_steps']:>8} {r['max_reaction_N']:>9.3g}N"
              + ("" if r["finite"] else "  (not finite)"))
    best, worst = rows[0], rows[-1]
    saving = (f"{(1 - best['cost'] / worst['cost']) * 100:.0f}% less energy than the most expensive "
              f"({worst['angle_deg']:+.1f} deg at {worst['speed_m_per_step'] * 1e3:g} mm per step)"
              if worst["cost"] > 0 else "no insertion added energy (the tool never reached the tissue?)")
    print(f"cheapest: {best['angle_deg']:+.1f} deg at {best['speed_m_per_step'] * 1e3:g} mm per step, {saving}")
    print(f"wrote {out / 'plan.csv'} and {out / 'plan.png'}")
    return 0
