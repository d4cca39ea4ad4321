"""The paper's two experiments, offline (no ROS graph): run, write figures and CSV, summarise.

Experiment a (Fig. 2): the tool approaches and pushes the bottom tissue;
snapshots at steps 0, 150, 220, 270 and the energy over the steps with those
steps marked, terms beside the total, for each tissue.

Experiment b (Fig. 3): insertions from two angles toward one target (yellow
circle); the final deformation for each angle and the energy curves; which
angle costs less, and by how much.
"""
from __future__ import annotations

import itertools
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
from tqdm import tqdm

from ..core.config import Config, resolve_config
from ..core.contact.tool import ToolPose, Trajectory
from ..core.errors import InputError
from ..core.health import RunHealth
from ..core.series import rollout_terms
from ..core.sim.rollout import Rollout, rollout
from ..core.sim.scene import build_simulation
from ..core.sim.simulation import Simulation
from ..core.timing import trajectories as tr


@dataclass
class ExperimentResult:
    """What an experiment wrote and measured."""

    name: str
    files: list[Path] = field(default_factory=list)
    summary: dict[str, Any] = field(default_factory=dict)
    rollouts: dict[str, Rollout] = field(default_factory=dict)

    def summary_text(self) -> str:
        return "\n".join(f"  {k}: {v}" for k, v in self.summary.items())


#: Experiment b's tool as parameters: the command's defaults, under a parameter file's tool_* values.
B_TOOL_VALUES = {"tool_shape": tr.B_TOOL.kind, "tool_length": tr.B_TOOL.length, "tool_width": tr.B_TOOL.width}


def insertion_cost(run: Rollout, baseline: Rollout) -> float:
    """The planning cost of an insertion: the energy it adds to the scene, summed over its steps.

    Even at rest under gravity every step has some implicit Euler energy (the
    solve pulls the prediction's g dt^2 back each step), so a plain sum would
    mostly measure how long an insertion takes. ``baseline`` is the same scene
    stepped as long without the tool; the cost is sum_t (E_t - E_t^baseline).
    """
    n = min(len(run.steps), len(baseline.steps))
    if n < len(run.steps):
        raise ValueError(f"baseline has {len(baseline.steps)} steps, the run {len(run.steps)}")
    return float((run.scene_total - baseline.scene_total[:n]).sum())


def baseline_rollout(values: Mapping[str, Any] | Config, steps: int) -> Rollout:
    """The scene of ``values`` stepped ``steps`` times without a tool (the energy an insertion is measured from)."""
    sim = build_simulation(values)
    return rollout(sim, ((None, None) for _ in range(steps)))


def run_trajectory(sim: Simulation, traj: Trajectory, *, snapshot_steps: Sequence[int] = (),
                   progress: bool | str = False, max_steps: int | None = None,
                   health: RunHealth | None = None) -> tuple[Rollout, float]:
    """Roll ``sim`` out along ``traj`` (its first ``max_steps`` steps when given); rollout and wall time [s].

    ``health``: checks every step (whether the run collapsed or blew up), for the summary.
    """
    dt = sim.params.dt
    n = traj.n_steps(dt) if max_steps is None else min(traj.n_steps(dt), max_steps)
    bar = tqdm(total=n, desc=progress if isinstance(progress, str) else "steps", unit="step",
               disable=not progress, leave=False)

    def on_step(report) -> None:
        bar.update(1)
        if health is not None:
            health.observe_sim(sim, report)

    t0 = time.perf_counter()
    run = rollout(sim, itertools.islice(traj.steps(dt), n), snapshot_steps=snapshot_steps, on_step=on_step)
    wall = time.perf_counter() - t0
    bar.close()
    return run, wall


def _pose_at_step(run: Rollout, step: int) -> ToolPose | None:
    if step <= 0 or step > len(run.steps):
        return None
    x, y, yaw = run.tool_pose[step - 1]
    return ToolPose(float(x), float(y), float(yaw)) if np.isfinite(x) else None


def summarise(run: Rollout, wall: float, dt: float, body_names: Sequence[str] | None = None,
              health: RunHealth | None = None) -> dict[str, Any]:
    """Steps, real-time factor, peak energy per body (by name), contact steps, first contact; with ``health``,
    whether the run held (``"run held"``: ``yes`` or what broke, and when)."""
    contact_any = run.in_contact.any(axis=1)
    first = int(run.steps[np.argmax(contact_any)]) if contact_any.any() else None
    total = run.total
    nb = run.inertial.shape[1] if run.inertial.ndim == 2 else 0
    names = list(body_names) if body_names is not None else [f"body {b}" for b in range(nb)]
    return {
        "steps": int(len(run.steps)),
        "wall time [s]": round(wall, 3),
        "real-time factor": round(len(run.steps) * dt / wall, 1) if wall > 0 else float("inf"),
        "median step [ms]": round(float(np.median(run.step_time)) * 1e3, 3) if len(run.step_time) else None,
        "bodies": list(names),
        "peak energy per body": {n: float(f"{v:.4g}") for n, v in zip(names, total.max(axis=0))} if len(total) else {},
        "peak energy step per body": ({n: int(run.steps[i]) for n, i in zip(names, total.argmax(axis=0))}
                                      if len(total) else {}),
        "contact steps": int(contact_any.sum()),
        "first contact step": first,
        "diverged steps": int(run.diverged.sum()),
        "energy finite": bool(np.isfinite(total).all()),
        **({"run held": health.verdict()} if health is not None else {}),
    }


def run_held(summary: Mapping[str, Any]) -> bool:
    """Whether a run's summary says it held: finite energy and no failure found by its :class:`RunHealth`."""
    return bool(summary.get("energy finite", True)) and str(summary.get("run held", "yes")) == "yes"


def experiment_a(out: str | Path, *, params: Mapping[str, Any] | Config | None = None, steps: int | None = None,
                 snapshot_steps: Sequence[int] | None = None, progress: bool = True,
                 prefix: str = "experiment_a", trajectory: str = "experiment_a",
                 settle: int = 0, scene: tr.SceneExperiments = tr.PAPER) -> ExperimentResult:
    """Run experiment a and write ``{prefix}_snapshots.png``, ``{prefix}_energy.png``, ``{prefix}_energy.csv``.

    ``scene`` places the tool of experiment a (:data:`~tissue_sim_ros.core.timing.trajectories.SCENE_EXPERIMENTS`);
    ``params`` must describe the same scene (e.g. its parameter file); ``snapshot_steps`` default to the scene's.
    ``trajectory``: ``experiment_a`` (the scene's insertion), another preset or a trajectory file
    (:func:`~tissue_sim_ros.core.timing.trajectories.resolve_trajectory`);
    ``steps``: experiment a's insertion of that many steps (default: the scene's), or the first ``steps`` of
    another trajectory (default: all of it). ``{prefix}_trajectory.csv`` records the poses run.
    ``settle``: steps under gravity alone (no tool) before the run, not recorded: the run starts from the
    settled state (velocities kept) at step 0, as the authors' recording started after their tissue had
    hung for a while (29 steps: docs/paper.md, "Reproducing the authors' run").
    """
    snapshot_steps = scene.a_snapshots if snapshot_steps is None else snapshot_steps
    from ..render import energy_label, plot_energy, save_snapshots  # noqa: PLC0415  (matplotlib only when drawing)

    out = Path(out)
    if isinstance(settle, bool) or not isinstance(settle, int) or settle < 0:
        raise InputError(f"--settle {settle!r}: expected a number of steps >= 0")
    sim = build_simulation(params)
    if settle:
        for _ in range(settle):
            sim.step()
        settled = sim.state.copy()
        sim.reset()
        sim.set_state(settled)
    if trajectory == "experiment_a":
        traj = tr.experiment_a(sim.tool, sim.params.dt, steps=steps, scene=scene)
    else:
        traj = tr.resolve_trajectory(trajectory, sim.tool, sim.params.dt)
    n = traj.n_steps(sim.params.dt) if steps is None else min(steps, traj.n_steps(sim.params.dt))
    snaps = [s for s in snapshot_steps if s <= n]
    out.mkdir(parents=True, exist_ok=True)  # only once the scene and trajectory are known good: bad input creates nothing
    health = RunHealth(sim.model, sim.params.dt)
    run, wall = run_trajectory(sim, traj, snapshot_steps=snaps, progress="experiment a" if progress else False,
                               max_steps=n, health=health)
    res = ExperimentResult("a", rollouts={"a": run})
    res.summary = summarise(run, wall, sim.params.dt, sim.model.body_names, health)
    res.summary["contact model"] = sim.params.contact_model
    res.summary["method"] = f"{sim.params.method} ({sim.params.scheme}, {sim.params.iterations} iterations)"
    res.summary["particles"] = sim.model.n_particles
    res.summary["trajectory"] = trajectory
    if settle:
        res.summary["settled under gravity first [steps]"] = settle
    shots = [(s, run.snapshots[s], _pose_at_step(run, s)) for s in snaps if s in run.snapshots]
    what = ("the tool approaches the bottom tissue" if trajectory == "experiment_a"
            else f"trajectory {Path(trajectory).name}")
    res.files.append(save_snapshots(out / f"{prefix}_snapshots.png", sim.model, shots, tool=sim.tool,
                                    title=f"Experiment a: {what} ({sim.params.contact_model} contact)"))
    res.files.append(plot_energy(out / f"{prefix}_energy.png", run.steps, rollout_terms(run),
                                 body_names=sim.model.body_names, markers=[s for s in snaps if s > 0],
                                 contact=run.in_contact, title="Experiment a: implicit Euler energy",
                                 ylabel=energy_label(sim.params)))
    csv = out / f"{prefix}_energy.csv"
    run.write_csv(csv)
    res.files.append(csv)
    res.files.append(tr.write_trajectory_csv(out / f"{prefix}_trajectory.csv", _Truncated(traj, n, sim.params.dt),
                                             sim.params.dt))
    return res


def _held_all(healths: Mapping[str, RunHealth]) -> str:
    """``yes`` when every run held, else each broken run's verdict by its label."""
    broken = {label: h.verdict() for label, h in healths.items() if h.failure is not None}
    return "yes" if not broken else "; ".join(f"{label}: {v}" for label, v in broken.items())


class _Truncated(Trajectory):
    """The first ``n`` steps of a trajectory (what a run with ``max_steps`` went through)."""

    def __init__(self, traj: Trajectory, n: int, dt: float) -> None:
        self._traj = traj
        self.start_time = traj.start_time
        self._duration = min(traj.duration, n * dt)

    @property
    def duration(self) -> float:
        return self._duration

    def pose_at(self, t: float) -> ToolPose:
        return self._traj.pose_at(min(t, self.start_time + self._duration))

    def twist_at(self, t: float):
        return self._traj.twist_at(t)


def experiment_b(out: str | Path, *, params: Mapping[str, Any] | Config | None = None,
                 angles_deg: Sequence[float] | None = None, target: tuple[float, float] | None = None,
                 speed: float | None = None, distance: float | None = None, progress: bool = True,
                 prefix: str = "experiment_b", trajectories: Sequence[str] | None = None,
                 scene: tr.SceneExperiments = tr.PAPER) -> ExperimentResult:
    """Run experiment b: the same target from each angle; figure of final states and energy curves.

    Unset arguments come from ``scene`` (:data:`~tissue_sim_ros.core.timing.trajectories.SCENE_EXPERIMENTS`), whose
    tool (if it names one) is the command's default tool, under a parameter file's, as the paper's 0.3 m box is.
    ``trajectories`` (presets or trajectory files) replace the angles: one run each, labelled by its name,
    compared by the same cost.
    """
    angles_deg = scene.b_angles_deg if angles_deg is None else angles_deg
    target = scene.b_target if target is None else target
    speed = scene.b_speed if speed is None else speed
    distance = scene.b_distance if distance is None else distance
    import matplotlib.pyplot as plt  # noqa: PLC0415

    from ..render import OTHER_TERM_STYLE, TERM_STYLES, draw_scene, energy_label  # noqa: PLC0415

    out = Path(out)
    tool_values = ({"tool_shape": scene.b_tool.kind, "tool_length": scene.b_tool.length,
                    "tool_width": scene.b_tool.width} if scene.b_tool is not None else {})
    values = params if isinstance(params, Config) else resolve_config(dict(params or {}), defaults=tool_values)
    res = ExperimentResult("b")
    runs: list[tuple[Any, Rollout, Simulation, float]] = []
    baseline: Rollout | None = None
    healths: dict[str, RunHealth] = {}
    if trajectories:
        labels: list[Any] = [Path(s).stem if Path(s).suffix else s for s in trajectories]
        specs: list[Any] = list(trajectories)
    else:
        labels, specs = [float(a) for a in angles_deg], [float(a) for a in angles_deg]

    def tag(label: Any) -> str:
        return f"{label:+.0f}deg" if isinstance(label, float) else str(label)

    def shown(label: Any) -> str:
        return f"{label:+.0f} deg" if isinstance(label, float) else str(label)

    for label, spec in zip(labels, specs):
        sim = build_simulation(values)
        if isinstance(spec, str):
            traj = tr.resolve_trajectory(spec, sim.tool, sim.params.dt)
        else:
            traj = tr.experiment_b(sim.tool, sim.params.dt, spec, speed=speed, target=target, distance=distance)
        health = RunHealth(sim.model, sim.params.dt)
        run, wall = run_trajectory(sim, traj, progress=f"experiment b {shown(label)}" if progress else False,
                                   health=health)
        healths[tag(label)] = health
        if baseline is None or len(baseline.steps) < len(run.steps):
            baseline = baseline_rollout(values, len(run.steps))
        runs.append((label, run, sim, wall))
        res.rollouts[tag(label)] = run
        out.mkdir(parents=True, exist_ok=True)  # after the first scene is built: bad input creates nothing
        run.write_csv(out / f"{prefix}_{tag(label)}_energy.csv")
        res.files.append(out / f"{prefix}_{tag(label)}_energy.csv")

    n = len(runs)
    fig, axes = plt.subplots(2, n, figsize=(4.6 * n, 8.2), squeeze=False)
    ymax = max(float(r.scene_total.max()) for _, r, _, _ in runs) * 1.08 or 1.0
    for j, (angle, run, sim, _) in enumerate(runs):
        pose = _pose_at_step(run, len(run.steps))
        draw_scene(axes[0, j], sim.model, sim.state.particle_q, tool=sim.tool, pose=pose,
                   target=None if trajectories else target, contact=None)
        axes[0, j].set_title(f"insertion at {shown(angle)}: final state" if not trajectories
                             else f"{shown(angle)}: final state", fontsize=10)
        ax = axes[1, j]
        ax.plot(run.steps, run.scene_total, color="#c62828", lw=2.0, label="total")
        for name, arr in rollout_terms(run).items():
            if not np.any(arr):  # the material's spring and area, a grasper-less attach: zero throughout
                continue
            colour, ls = TERM_STYLES.get(name, OTHER_TERM_STYLE)
            ax.plot(run.steps, arr.sum(axis=1), color=colour, ls=ls, lw=1.2, label=name)
        ax.set_ylim(0, ymax)
        ax.set_xlabel("step")
        ax.set_ylabel(energy_label(sim.params).replace("energy", "energy of the scene", 1), fontsize=9)
        ax.set_title(f"{shown(angle)}: cost (energy added) {insertion_cost(run, baseline):.3g}", fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper left")
    fig.suptitle(f"Experiment b: two insertion angles, same target (yellow), {runs[0][2].params.contact_model} contact",
                 fontsize=11)
    fig.tight_layout()
    fig_path = out / f"{prefix}.png"
    fig.savefig(fig_path, dpi=120)
    plt.close(fig)
    res.files.insert(0, fig_path)

    costs = {angle: insertion_cost(run, baseline) for angle, run, _, _ in runs}
    best = min(costs, key=costs.get)
    worst = max(costs, key=costs.get)
    res.summary = {
        "contact model": runs[0][2].params.contact_model,
        "bodies": list(runs[0][2].model.body_names),
        **({"trajectories": list(trajectories)} if trajectories else {"target": target, "angles [deg]": list(angles_deg)}),
        "cost (energy added, summed over steps)": {shown(a): float(f"{c:.4g}") for a, c in costs.items()},
        "peak energy added": {shown(a): float(f"{(r.scene_total - baseline.scene_total[:len(r.steps)]).max():.4g}")
                              for a, r, _, _ in runs},
        "contact steps": {shown(a): int(r.in_contact.any(axis=1).sum()) for a, r, _, _ in runs},
        "energy finite": all(bool(np.isfinite(r.total).all()) for _, r, _, _ in runs),
        "run held": _held_all({shown(a): healths[tag(a)] for a, _, _, _ in runs}),
        ("cheaper trajectory" if trajectories else "cheaper angle [deg]"): best,
        "saving vs the other": (f"{(1 - costs[best] / costs[worst]) * 100:.1f}% less energy than {shown(worst)}"
                                if costs[worst] > 0 else "no energy at either angle"),
    }
    return res
