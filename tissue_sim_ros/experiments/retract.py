"""Grasp and retract, offline: the grasper comes down onto the flap of ``config/scenes/retract.yaml``,
closes, lifts and pulls back 2 cm, holds, opens; snapshots of each phase, the energy with its terms, the reaction
on the tool and the held count, as figures and a CSV.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Mapping

import numpy as np
from tqdm import tqdm

from ..core.config import Config
from ..core.contact.tool import ToolPose
from ..core.errors import InputError
from ..core.plan.observe import RETRACT_X, flap_surface  # also imported from here by experiments.control
from ..core.sim.rollout import rollout
from ..core.sim.scene import build_simulation
from ..core.timing import trajectories as tr
from .paper import ExperimentResult


def grasp_and_lift(sim: Any, lift_steps: int, x: float = RETRACT_X, rise: float = 0.0005) -> ToolPose:
    """Grasp the flap of ``sim`` (a Simulation of the retraction scene at rest) at ``x`` and lift it: the jaw
    open 0.8 rad with its tip ``rise`` above the top surface, closed, then ``lift_steps`` steps each ``rise``
    higher. Returns the tool's last pose (the rollouts' and the controller's timing's held flap)."""
    top = flap_surface(sim.state.particle_q, x)
    pose = ToolPose(x, top + rise, 0.0)
    sim.step(pose, jaw=0.8)
    sim.step(pose, jaw=0.0)
    for k in range(1, lift_steps + 1):
        pose = ToolPose(x, top + rise + rise * k, 0.0)
        sim.step(pose)
    return pose


def experiment_retract(out: str | Path, *, params: Mapping[str, Any] | Config | None = None, x: float = RETRACT_X,
                       lift: float = 0.02, pull: float = 0.02, progress: bool = True,
                       prefix: str = "retract") -> ExperimentResult:
    """Run the retraction and write ``{prefix}_snapshots.png``, ``{prefix}_energy.png`` (energy, force, held),
    ``{prefix}_energy.csv`` and ``{prefix}_trajectory.csv`` (with the jaw) into ``out``.

    ``params``: the retraction scene (``config/scenes/retract.yaml``); its tool must be a grasper.
    """
    sim = build_simulation(params)
    if sim.tool is None or sim.tool.kind != "grasper":
        raise InputError(f"tool_shape={getattr(sim.tool, 'kind', None)!r}: the retraction needs tool_shape grasper "
                         "(config/scenes/retract.yaml)")
    dt = sim.params.dt
    surface = flap_surface(sim.state.particle_q, x)
    traj = tr.retract_trajectory(x, surface, lift=lift, pull=pull)
    n = traj.n_steps(dt)
    bounds = (x - pull - 0.03, x + 0.03, 0.0, surface + lift + 0.03)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ends = np.cumsum([d for _, d in tr.RETRACT_PHASES])
    shot_steps = [0] + [int(round(t / dt)) for t in ends]
    labels = {0: "start"} | {int(round(t / dt)): name for (name, _), t in zip(tr.RETRACT_PHASES, ends)}
    shots = []
    if 0 in shot_steps:
        shots.append(("start", sim.state.particle_q.copy(), traj.pose_at(0.0), traj.jaw_at(0.0), np.zeros(0, int)))
    bar = tqdm(total=n, desc="retract", unit="step", disable=not progress, leave=False)

    def on_step(report) -> None:
        bar.update(1)
        if report.step in shot_steps[1:]:
            t = report.step * dt
            shots.append((f"{labels[report.step]} (step {report.step})", sim.state.particle_q.copy(),
                          traj.pose_at(t), traj.jaw_at(t), report.grasped.copy()))

    t0 = time.perf_counter()
    run = rollout(sim, traj.steps_with_jaw(dt), on_step=on_step)
    wall = time.perf_counter() - t0
    bar.close()
    from ..render import plot_grasp, save_grasp_snapshots  # noqa: PLC0415  (matplotlib only when drawing)

    res = ExperimentResult("retract", rollouts={"retract": run})
    res.files.append(save_grasp_snapshots(out / f"{prefix}_snapshots.png", sim.model, shots, tool=sim.tool,
                                          bounds=bounds, title="Grasp and retract (strain; held particles cyan)"))
    terms = {"inertial": run.inertial.sum(axis=1), "strain": run.strain.sum(axis=1) if run.strain is not None else
             (run.spring + run.area).sum(axis=1), "attach": run.attach.sum(axis=1)}
    phase_marks = [(float(t), name) for (name, _), t in zip(tr.RETRACT_PHASES, np.concatenate([[0.0], ends[:-1]]))]
    res.files.append(plot_grasp(out / f"{prefix}_energy.png", run.time, terms, run.reaction_force, run.n_grasped,
                                run.jaw, phases=phase_marks, title="Grasp and retract: energy, force, grasp"))
    csv = out / f"{prefix}_energy.csv"
    run.write_csv(csv)
    res.files.append(csv)
    res.files.append(tr.write_trajectory_csv(out / f"{prefix}_trajectory.csv", traj, dt))
    lift_end = int(round(ends[2] / dt)) - 1
    held = run.n_grasped
    res.summary = {
        "steps": int(len(run.steps)),
        "wall time [s]": round(wall, 3),
        "real-time factor": round(len(run.steps) * dt / wall, 1) if wall > 0 else float("inf"),
        "particles": sim.model.n_particles,
        "surface at x [m]": round(surface, 6),
        "particles held": int(held.max()) if len(held) else 0,
        "force after the lift [N]": [round(float(v), 4) for v in run.reaction_force[lift_end]],
        "peak energy": float(f"{run.scene_total.max():.4g}"),
        "held at the end": int(held[-1]) if len(held) else 0,
        "diverged steps": int(run.diverged.sum()),
        "energy finite": bool(np.isfinite(run.total).all()),
    }
    return res


def tool_pose_at(traj: tr.WaypointTrajectory, t: float) -> ToolPose:
    """The grasper's pose at ``t`` [s] (for callers drawing a phase)."""
    return traj.pose_at(t)
