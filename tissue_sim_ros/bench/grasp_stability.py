"""``tissue-sim bench stability --grasp``: where a grasp fails.

The retraction scene (``config/scenes/retract.yaml``: a 6 cm flap held at its base, a 5 mm grasper) grasped
at the middle of its top surface and lifted straight up by ``lift`` [m] at a tool speed of ``speed`` [m per
step], then held for 20 steps. Swept: the material (the scene's neo-Hookean membrane; XPBD springs and
areas), the substeps (1, the scene's 10), the grasp's compliance (1e-2 to 1e-8 m/N) and the lift (a fast lift
of 2 cm, a huge pull of 20 cm) at 1 to 20 mm per step. Each run records its first failure as
:mod:`~tissue_sim_ros.bench.failures` finds it (non-finite values, energy growing without bound, triangles
staying inverted, the tool tunnelling), whether the grasp let go (a diverged step releases it), the held
particle's lag behind the tool at the end, and the largest pull on the tool; nothing is published NaN in any
case (the Simulation restores a diverged step, the encoders withhold non-finite values).

Writes ``grasp_stability.csv`` (one row per run) and prints the table.
"""
from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..core.contact.tool import ToolPose
from ..core.health import FailureMonitor
from ..core.resources import scene_params_file
from ..core.sim.scene import build_simulation, load_params_file
from .accuracy import format_table, write_csv

#: material name -> parameter changes over the scene's file
MATERIALS = {
    "neo_hookean": {},
    "xpbd_constraints": {"material": "constraints", "method": "xpbd", "stiffness_spring": 50.0,
                         "stiffness_area": 1e5, "mass_per_area": 5.3},
}
X, TOP, GAP = 0.040, 0.016, 0.0002  # where the grasper takes the flap [m] (the scene's image)
COLUMNS = ["material", "substeps", "compliance", "speed", "lift", "outcome", "failure_step", "held",
           "released_step", "lag_mm", "max_force_n", "max_inverted", "diverged_steps"]


def run_grasp(material: str, substeps: int, compliance: float, speed: float, lift: float,
              hold_steps: int = 20) -> dict[str, Any]:
    """One run: grasp, lift ``lift`` [m] at ``speed`` [m per step], hold; a CSV row."""
    values = {**load_params_file(scene_params_file("retract")), **MATERIALS[material], "substeps": substeps,
              "grasp_compliance": compliance}
    sim = build_simulation(values)
    sim.step(ToolPose(X, TOP + 0.003, 0.0), jaw=1.0)
    for _ in range(3):
        sim.step(ToolPose(X, TOP + GAP, 0.0))
    report = sim.step(ToolPose(X, TOP + GAP, 0.0), jaw=0.0)
    held = report.grasped.copy()
    # the held particle nearest the tip: its lag behind the tool is what a user sees
    tip = held[np.argmin(np.hypot(*(sim.state.particle_q[held] - [X, TOP]).T))] if held.size else -1
    offset = sim.state.particle_q[tip, 1] - (TOP + GAP) if tip >= 0 else 0.0
    monitor = FailureMonitor(sim.model, sim.tool)
    n_lift = max(1, int(math.ceil(lift / speed - 1e-9)))
    pose_prev = ToolPose(X, TOP + GAP, 0.0)
    released = diverged = 0
    released_step: int | str = ""
    max_force = 0.0
    dt = sim.params.dt
    for k in range(1, n_lift + hold_steps + 1):
        pose = ToolPose(X, TOP + GAP + min(lift, speed * k), 0.0)
        x_prev = sim.state.particle_q.copy()
        with np.errstate(all="ignore"):
            report = sim.step(pose)
        diverged += report.diverged
        if held.size and not released and report.grasped.size == 0:
            released, released_step = 1, k
        if np.isfinite(report.reaction_force).all():
            max_force = max(max_force, float(np.hypot(*report.reaction_force)))
        monitor.observe(k, x_prev, sim.state.particle_q, sim.state.particle_qd, k * dt, diverged=report.diverged,
                        pose0=pose_prev, pose1=pose, tool_speed=math.hypot(pose.x - pose_prev.x,
                                                                           pose.y - pose_prev.y) / dt)
        pose_prev = pose
        if monitor.first is not None and monitor.first.kind == "nonfinite":
            break
    first = monitor.first
    lag = (pose_prev.y + offset - sim.state.particle_q[tip, 1]) if tip >= 0 else math.nan
    return {"material": material, "substeps": substeps, "compliance": compliance, "speed": speed, "lift": lift,
            "outcome": first.kind if first else "stable", "failure_step": first.step if first else 0,
            "held": int(held.size), "released_step": released_step, "lag_mm": 1e3 * float(lag),
            "max_force_n": max_force, "max_inverted": monitor.max_inverted, "diverged_steps": diverged}


def sweep(quick: bool) -> list[tuple[str, int, float, float, float]]:
    """The runs: (material, substeps, compliance, speed, lift)."""
    if quick:
        return [("neo_hookean", 10, 1e-4, 0.005, 0.02), ("neo_hookean", 10, 1e-4, 0.02, 0.2)]
    return list(itertools.product(list(MATERIALS), [1, 10], [1e-2, 1e-4, 1e-8], [0.001, 0.005, 0.02], [0.02, 0.2]))


def run_grasp_sweep(out: str | Path, quick: bool = False) -> int:
    """Run the sweep; print the table, write ``grasp_stability.csv`` into ``out``; 0."""
    from tqdm import tqdm  # noqa: PLC0415

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = [run_grasp(*args) for args in tqdm(sweep(quick), desc="grasp stability", unit="run", leave=False)]
    write_csv(out / "grasp_stability.csv", rows)
    print(format_table(rows, COLUMNS))
    counts: dict[str, int] = {}
    for r in rows:
        counts[r["outcome"]] = counts.get(r["outcome"], 0) + 1
    print("outcomes: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())) + f" of {len(rows)} runs")
    print(f"wrote {out / 'grasp_stability.csv'}")
    return 0
