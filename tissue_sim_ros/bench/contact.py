"""Contact cost: python-fcl queries per step, culled versus full per-step BVH rebuild.

python-fcl 0.7 cannot refit a BVHModel in place (no beginUpdateModel /
updateVertex / endUpdateModel in its bindings), so the tissue's BVH must be
rebuilt each step. This benchmark measures what that costs:

* ``full``: every body's whole triangle mesh rebuilt as a BVHModel each step
  (``ContactModel(cull=False)``);
* ``culled``: only the triangles that can hold the nearest point go into the
  step's BVH (the default);

on two scenes: the paper-sized default scene (config/tissue.png, two bodies,
experiment a's trajectory: the authors' 0.8 m box at 0.001 m per step) and a
1 m x 0.5 m strip of ~5,000 triangles with the same tool descending at 30
degrees. Each step, the simulation advances with the culled model; both
models' ``detect`` are timed on the same state (and their d* compared). Rows
report medians over the steps with the tool within alpha of the tissue (d*
computed), and the whole ``Simulation.step`` median for scale. Writes
``contact.csv`` and ``contact.png``.

Run: ``tissue-sim bench contact [--out DIR] [--steps N] [--quick]``.
"""
from __future__ import annotations

import csv
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..core.config import resolve_config
from ..core.contact.collision import ContactModel
from ..core.contact.tool import StraightInsertion
from ..core.errors import InputError
from ..core.mesh import mesh_rectangle
from ..core.sim.simulation import Simulation


def _scenes(kind: str, quick: bool = False) -> list[tuple[str, Simulation, StraightInsertion]]:
    from ..core.sim.scene import build_simulation  # noqa: PLC0415
    from ..core.timing.trajectories import experiment_a  # noqa: PLC0415

    sim = build_simulation({"contact_model": kind})
    scenes = [("paper scene", sim, experiment_a(sim.tool, sim.params.dt))]
    if quick:
        return scenes
    # ~5,000 triangles: 71 x 35 cells of two triangles
    strip = mesh_rectangle(1.0, 0.5, 1.0 / 71)
    # the shipped parameters and tool; the strip pinned along its bottom row, no top line
    cfg = resolve_config({"contact_model": kind, "boundary_y_bottom": 0.001, "boundary_y_top": math.nan},
                         source="bench contact strip")
    big = Simulation.from_config(cfg, mesh=strip)
    traj = StraightInsertion.from_angle(big.tool, target=(0.6, 0.42), angle=math.radians(-30), distance=0.2,
                                        speed=0.001, dt=big.params.dt)
    scenes.append((f"strip {strip.triangles.shape[0]} tris", big, traj))
    return scenes


def measure(kind: str, steps: int, progress=None, quick: bool = False) -> list[dict[str, Any]]:
    """Rows (one per scene and BVH mode) for one contact model."""
    rows = []
    for name, sim, traj in _scenes(kind, quick):
        full = ContactModel(sim.model, sim.tool, cull=False)
        culled = sim.contact
        t_full, t_cull, tris_full, tris_cull, totals, worst = [], [], [], [], [], 0.0
        prev = None
        for k, (pose, twist) in enumerate(traj.steps(sim.params.dt)):
            if k >= steps:
                break
            state = sim.state
            pose0 = prev or pose
            t0 = time.perf_counter()
            c_cull = culled.detect(state, pose0, pose, twist, sim.params.dt)
            t1 = time.perf_counter()
            c_full = full.detect(state, pose0, pose, twist, sim.params.dt)
            t2 = time.perf_counter()
            report = sim.step(pose, twist)
            prev = pose
            if progress is not None:
                progress.update(1)
            if not np.isfinite(c_cull.d_star).any():
                continue
            # where the culled model computed d*, the full BVH must agree
            ok = np.isfinite(c_cull.d_star)
            worst = max(worst, float(np.abs(c_cull.d_star[ok] - c_full.d_star[ok]).max()))
            t_cull.append(t1 - t0)
            t_full.append(t2 - t1)
            tris_cull.append(culled.last_bvh_triangles)
            tris_full.append(full.last_bvh_triangles)
            totals.append(report.timings["total"])
        if not t_cull:
            continue
        step_ms = 1e3 * float(np.median(totals))
        for mode, ts, tris in (("culled", t_cull, tris_cull), ("full", t_full, tris_full)):
            ms = 1e3 * float(np.median(ts))
            rows.append(dict(scene=name, contact_model=kind, bvh=mode, particles=sim.model.n_particles,
                             triangles=sim.model.n_triangles, steps_near=len(ts), detect_ms=ms,
                             detect_p90_ms=1e3 * float(np.percentile(ts, 90)),
                             bvh_triangles=float(np.median(tris)), step_ms=step_ms,
                             share=ms / step_ms, max_dstar_diff=worst))
    return rows


def run(out: str | Path, *, steps: int | None = None, quick: bool = False) -> int:
    """Time both BVH modes on both scenes and contact models; print, write contact.csv/png into ``out``.

    Parameters
    ----------
    out : str or Path
        Output directory (created).
    steps : int, optional
        Steps of each trajectory (default 300; ``quick`` 160).
    quick : bool
        The paper scene only (smoke test).

    Returns
    -------
    int
        0, or 1 when no step brought the tool within alpha of the tissue.
    """
    from tqdm import tqdm  # noqa: PLC0415

    steps = steps if steps is not None else (160 if quick else 300)
    if steps < 1:
        raise InputError(f"--steps={steps}: expected at least 1 step")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    with tqdm(total=(2 if quick else 4) * steps, desc="contact bench") as bar:
        for kind in ("paper", "projection"):
            rows += measure(kind, steps, bar, quick)
    if not rows:
        print(f"no step brought the tool within alpha of the tissue in {steps} steps: nothing to report")
        return 1
    header = f"{'scene':<20} {'model':<10} {'bvh':<6} {'tris':>5} {'near':>5} {'bvh tris':>8} " \
             f"{'detect ms':>9} {'p90 ms':>7} {'step ms':>8} {'share':>6} {'|dd*| max':>9}"
    print(header)
    for r in rows:
        print(f"{r['scene']:<20} {r['contact_model']:<10} {r['bvh']:<6} {r['triangles']:>5} {r['steps_near']:>5} "
              f"{r['bvh_triangles']:>8.0f} {r['detect_ms']:>9.3f} {r['detect_p90_ms']:>7.3f} {r['step_ms']:>8.3f} "
              f"{r['share']:>6.1%} {r['max_dstar_diff']:>9.1e}")
    with open(out / "contact.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, ax = plt.subplots(figsize=(9, 4))
    labels = [f"{r['scene']}\n{r['contact_model']}, {r['bvh']}" for r in rows]
    ax.bar(range(len(rows)), [r["detect_ms"] for r in rows], color=["C0" if r["bvh"] == "culled" else "C3" for r in rows])
    ax.scatter(range(len(rows)), [0.25 * r["step_ms"] for r in rows], marker="_", s=400, color="k",
               label="a quarter of the whole step")
    ax.set_xticks(range(len(rows)), labels, fontsize=7)
    ax.set_yscale("log")
    ax.set_ylabel("detect() per step [ms], median")
    ax.set_title("Contact detection: culled vs full per-step python-fcl BVH rebuild")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "contact.png", dpi=120)
    print(f"wrote {out / 'contact.csv'} and {out / 'contact.png'}")
    return 0
