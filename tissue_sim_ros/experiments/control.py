"""Drive the tissue to a target offline: the controller of :mod:`~tissue_sim_ros.core.plan.control`
against a simulation standing in for the world.

The world is the retraction scene (``config/scenes/retract.yaml``) with its Young's modulus ``world_young_factor``
times the controller's, seen through noisy points (every particle, Gaussian noise of ``noise`` m per coordinate,
a seeded generator: the same run each time). Each step the controller gets the noisy points, the world's tool pose
and jaw, and returns the command the world steps with. The run stops at ``max_time`` or ``hold_time`` after the
world's goal point first came within the tolerance while the controller holds.

Written into ``out``: ``{prefix}.png`` (the goal error over time, the tool path over the tissue, snapshots),
``{prefix}.csv`` (per step: time, tool pose, jaw, phase, true and synced goal error, held particles, reaction) and
``{prefix}_replans.csv`` (per replan: its phase, candidates, horizon, sync / rollout / choice times).
"""
from __future__ import annotations

import csv
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..core.config import Config
from ..core.contact.tool import ToolPose
from ..core.errors import InputError
from ..core.plan.control import ControlSettings, TissueController, default_model
from ..core.sim.batch import RolloutPool
from ..core.sim.grasp import to_tool_frame
from ..core.sim.simulation import Simulation
from .retract import RETRACT_X, flap_surface, grasp_and_lift


@dataclass
class ControlRun:
    """What one offline run did."""

    summary: dict[str, Any] = field(default_factory=dict)
    files: list[Path] = field(default_factory=list)
    time: np.ndarray | None = None
    error: np.ndarray | None = None
    """The world's goal point's distance from its goal per step [m] (noise-free)."""
    records: list = field(default_factory=list)


def run_control(cfg: Config, *, world_young_factor: float = 1.3, noise: float = 0.0005, seed: int = 0,
                start_x: float = RETRACT_X, lift: float = 0.02, side: float = 0.01, max_time: float = 10.0,
                hold_time: float = 0.5, settings: ControlSettings | None = None, pool: RolloutPool | None = None,
                out: str | Path | None = None, prefix: str = "control",
                model: Mapping[str, Any] | None = None, bag: str | Path | None = None) -> ControlRun:
    """Run the controller against the world (module docstring); write the files when ``out`` is given, and the
    world's run as a rosbag2 bag at ``bag`` (the node's outputs of each step, ``/tool/pose`` and ``/tool/jaw`` as
    the controller commanded them)."""
    for name, v in (("world_young_factor", world_young_factor), ("max_time", max_time)):
        if not (math.isfinite(v) and v > 0):
            raise InputError(f"{name}={v}: expected a finite value > 0")
    if not (math.isfinite(noise) and noise >= 0):
        raise InputError(f"noise={noise}: expected a finite standard deviation >= 0 [m]")
    ctrl = TissueController(cfg.replace(**dict(default_model(cfg) if model is None else model)), settings, pool=pool)
    world_cfg = cfg.replace(young_modulus=cfg.sim.young_modulus * world_young_factor)
    world = Simulation.from_config(world_cfg)
    dt = world.params.dt
    rng = np.random.default_rng(seed)
    x_w = world.state.particle_q
    surface = flap_surface(x_w, start_x)
    start = (start_x, surface)
    goal = (start_x + side, surface + lift)
    tool = ToolPose(start_x - 0.01, surface + 0.015, 0.0)
    world.place_tool(tool)
    jaw = ctrl.settings.open_jaw

    def observe() -> np.ndarray:
        x = world.state.particle_q
        return x + rng.normal(0.0, noise, x.shape) if noise > 0 else x.copy()

    ctrl.set_goal([(start, goal)], observe(), tool)
    # the world's goal particle: its own particle nearest the start (the controller's model may be another mesh)
    gid = int(np.argmin(np.hypot(*(x_w - np.array(start)).T)))
    q = np.array(goal)
    sink = writer = None
    if bag is not None:
        from ..core.timing.stamps import ns_from_seconds, stamp_from_ns  # noqa: PLC0415
        from ..ros import messages  # noqa: PLC0415  (CDR without rclpy)
        from ..ros.bags import BagWriter  # noqa: PLC0415
        from ..ros.replay import ReplayBagSink  # noqa: PLC0415

        if Path(bag).exists():
            raise InputError(f"--bag {bag}: exists; expected a new path")
        writer = BagWriter(bag)
        sink = ReplayBagSink(writer, world)
        writer.add_topic("/tool/jaw", "sensor_msgs/msg/JointState")
    rows: list[tuple] = []
    shots: list[tuple[str, np.ndarray, ToolPose, float]] = [("start", world.state.particle_q.copy(), tool, jaw)]
    n_max = int(round(max_time / dt))
    reached_at = math.nan
    wall0 = time.perf_counter()
    phase_seen = set()
    try:  # the bag is closed (readable) however the run ends
        for k in range(n_max):
            cmd = ctrl.command(observe(), world.tool_pose or tool, jaw, t=world.time)
            if cmd.phase not in phase_seen:
                phase_seen.add(cmd.phase)
                if cmd.phase in ("pull", "holding"):
                    shots.append((f"{cmd.phase} from t = {world.time:.2f} s", world.state.particle_q.copy(),
                                  world.tool_pose, jaw))
            r = world.step(cmd.pose, cmd.twist, jaw=cmd.jaw)
            jaw = cmd.jaw
            if sink is not None:
                t_ns = ns_from_seconds(world.time)
                sink(r, t_ns, cmd.pose)
                writer.write("/tool/jaw", messages.encode_joint_state(stamp_from_ns(t_ns), "", ["jaw"], [jaw]), t_ns)
            err = float(np.hypot(*(world.state.particle_q[gid] - q)))
            if not all(np.isfinite([cmd.pose.x, cmd.pose.y, err])):
                raise RuntimeError(f"a non-finite command or state at step {k + 1}")
            rows.append((world.time, cmd.pose.x, cmd.pose.y, cmd.pose.yaw, cmd.jaw, cmd.phase, err, cmd.goal_error,
                         len(r.grasped), float(r.reaction_force[0]), float(r.reaction_force[1]), int(cmd.replanned)))
            if math.isnan(reached_at) and cmd.phase == "holding" and err <= ctrl.settings.tolerance:
                reached_at = world.time
            if not math.isnan(reached_at) and world.time >= reached_at + hold_time - 1e-9:
                break
    finally:
        wall = time.perf_counter() - wall0
        if writer is not None:
            writer.close()
    shots.append((f"end, t = {world.time:.2f} s", world.state.particle_q.copy(), world.tool_pose, jaw))
    t = np.array([r[0] for r in rows])
    e = np.array([r[6] for r in rows])
    pulls = [rec for rec in ctrl.records if rec.phase in ("pull", "holding")]
    res = ControlRun(time=t, error=e, records=ctrl.records)
    res.summary = {
        "world E / model E": world_young_factor,
        "noise [mm]": noise * 1e3,
        "model particles / world particles": f"{ctrl.n} / {world.model.n_particles}",
        "seed": seed,
        "start [m]": [round(v, 5) for v in start],
        "goal [m]": [round(v, 5) for v in goal],
        "goal particle": gid,
        "grasp site": ctrl.site,
        "reached": bool(math.isfinite(reached_at)),
        "reached at [s]": None if math.isnan(reached_at) else round(reached_at, 3),
        "final error [mm]": round(float(e[-1]) * 1e3, 3),
        "steps": len(rows),
        "replans": len(ctrl.records),
        "pull replans": len(pulls),
        "candidates per pull replan": ctrl.settings.n_candidates,
        "horizon [steps]": ctrl.settings.horizon,
        "pull replan mean [ms]": round(1e3 * float(np.mean([r.total_s for r in pulls])), 1) if pulls else None,
        "pull replan max [ms]": round(1e3 * float(np.max([r.total_s for r in pulls])), 1) if pulls else None,
        "sync mean [ms]": round(1e3 * float(np.mean([r.sync_s for r in ctrl.records])), 2),
        "wall time [s]": round(wall, 2),
    }
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        path = out / f"{prefix}.csv"
        with path.open("w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["time", "tool_x", "tool_y", "tool_yaw", "jaw", "phase", "goal_error", "synced_goal_error",
                        "held", "force_x", "force_y", "replanned"])
            w.writerows(rows)
        res.files.append(path)
        path = out / f"{prefix}_replans.csv"
        with path.open("w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["step", "phase", "candidates", "horizon", "sync_ms", "rollout_ms", "choose_ms", "total_ms",
                        "best", "predicted_score", "synced_goal_error"])
            for rec in ctrl.records:
                w.writerow([rec.step, rec.phase, rec.candidates, rec.horizon, 1e3 * rec.sync_s, 1e3 * rec.rollout_s,
                            1e3 * rec.choose_s, 1e3 * rec.total_s, rec.best, rec.predicted_error, rec.goal_error])
        res.files.append(path)
        from ..render.control import plot_control  # noqa: PLC0415  (matplotlib only when drawing)

        tool_xy = np.array([(r[1], r[2]) for r in rows])
        res.files.append(plot_control(out / f"{prefix}.png", world.model, shots, world.tool, t, e, tool_xy,
                                      start, goal, ctrl.settings.tolerance, gid,
                                      title=f"Drive the tissue to a target: world E x{world_young_factor:g}, "
                                            f"noise {noise * 1e3:g} mm"))
    return res


def replan_timing(cfg: Config, counts: tuple[int, ...] = (4, 8, 16, 32), horizon: int = 50, repeats: int = 5,
                  pool: RolloutPool | None = None, settings: Mapping[str, Any] | None = None,
                  model: Mapping[str, Any] | None = None) -> list[dict[str, Any]]:
    """Wall time of one pull replan (sync + candidates x ``horizon`` steps + choice) against the number of
    candidate motions (and holding still: ``counts`` + 1 rollouts), on the retraction scene (the world, ``cfg``)
    with the flap grasped and lifted 1 cm, the controller's model ``cfg`` with ``model`` set over it (default:
    :func:`default_model`): the median of ``repeats`` (after one untimed replan)."""
    world = Simulation.from_config(cfg)
    x0 = world.state.particle_q.copy()
    surface = flap_surface(x0, RETRACT_X)
    grasp_and_lift(world, 20)
    model_cfg = cfg.replace(**dict(default_model(cfg) if model is None else model))
    rows = []
    for n in counts:
        # a grid of n motions (gains x angles at one speed; n a power of 2: 4 = 2 x 2, 32 = 4 x 8) and holding still
        n_ang = 2 ** math.ceil(math.log2(max(n, 1)) / 2)
        n_gain = max(1, n // n_ang)
        gains = tuple(np.linspace(0.7, 1.3, n_gain)) if n_gain > 1 else (1.0,)
        angles = tuple(np.linspace(-30.0, 30.0, n_ang)) if n_ang > 1 else (0.0,)
        s = ControlSettings(horizon=horizon, replan_every=min(10, horizon), gains=gains, angles_deg=angles,
                            pull_speeds=(0.02,), **dict(settings or {}))
        ctrl = TissueController(model_cfg, s, pool=pool)
        ctrl.set_goal([((RETRACT_X, surface), (RETRACT_X + 0.01, surface + 0.02))], x0)  # bound at rest
        x = ctrl.sync(world.state.particle_q, world.tool_pose, world.time)
        if ctrl.hold_in_reach(world.tool_pose).size == 0:  # a coarse model: its free particle nearest the tip
            d = np.hypot(*(x - np.array([world.tool_pose.x, world.tool_pose.y])).T)
            ctrl.held = np.array([int(np.argmin(np.where(ctrl.fixed, np.inf, d)))], dtype=np.int64)
            ctrl.held_local = to_tool_frame(x[ctrl.held], world.tool_pose)
        ctrl.phase = "pull"
        ctrl.site = int(ctrl.held[0])
        times = []
        for r in range(repeats + 1):
            ctrl.queue = []
            ctrl._sync_time = None
            ctrl.command(world.state.particle_q, world.tool_pose, 0.0, t=world.time)
            if r:
                times.append(ctrl.records[-1])
        rows.append({"particles": ctrl.n, "candidates": s.n_candidates, "horizon": horizon,
                     "workers": pool.n_workers if pool else 0,
                     "sync_ms": 1e3 * float(np.median([r.sync_s for r in times])),
                     "rollout_ms": 1e3 * float(np.median([r.rollout_s for r in times])),
                     "choose_ms": 1e3 * float(np.median([r.choose_s for r in times])),
                     "total_ms": 1e3 * float(np.median([r.total_s for r in times]))})
    return rows


def timing_table(cfg: Config, *, spacings: tuple[float, ...] | None = None,
                 workers: tuple[int, ...] = (0, 2), counts: tuple[int, ...] = (4, 8, 16, 32, 64), horizon: int = 50,
                 repeats: int = 5, backend: str = "local", address: str | None = None) -> list[dict[str, Any]]:
    """:func:`replan_timing` for each model spacing (0: the world's mesh; default: it and the default model's)
    and number of workers (0: serially), side by side in one run: the rows of the chart of replan time against
    candidates."""
    from ..core.sim.backends import rollout_pool  # noqa: PLC0415
    from ..core.sim.batch import BatchScene  # noqa: PLC0415

    rows = []
    if spacings is None:  # the world's mesh and the default model's
        spacings = (0.0, default_model(cfg)["spacing"])
    for spacing in spacings:
        model = {"spacing": spacing} if spacing > 0 else {}
        for n in workers:
            if n == 0:
                rows += replan_timing(cfg, counts, horizon, repeats, model=model)
                continue
            scene = BatchScene.from_simulation(Simulation.from_config(cfg.replace(**model)))
            with rollout_pool(scene, n, backend=backend, address=address) as pool:
                rows += replan_timing(cfg, counts, horizon, repeats, pool=pool, model=model)
    return rows


def sweep_control(cfg: Config, *, factors: tuple[float, ...] = (0.5, 0.7, 1.0, 1.3, 1.5),
                  noises: tuple[float, ...] = (0.0, 0.0005, 0.001), seed: int = 0,
                  settings: ControlSettings | None = None, pool: RolloutPool | None = None,
                  max_time: float = 10.0, model: Mapping[str, Any] | None = None,
                  progress: Any = None) -> list[dict[str, Any]]:
    """One run per (world E factor, noise): reached, when, and the final error (a row each). ``progress(i, n)``
    after each run."""
    rows = []
    runs = [(noise, f) for noise in noises for f in factors]
    for i, (noise, f) in enumerate(runs):
        s = run_control(cfg, world_young_factor=f, noise=noise, seed=seed, settings=settings, pool=pool,
                        max_time=max_time, model=model).summary
        rows.append({"world_e_factor": f, "noise_mm": noise * 1e3, "reached": s["reached"],
                     "reached_at_s": s["reached at [s]"], "final_error_mm": s["final error [mm]"],
                     "pull_replan_mean_ms": s["pull replan mean [ms]"]})
        if progress is not None:
            progress(i + 1, len(runs))
    return rows


def write_rows(path: str | Path, rows: list[dict[str, Any]]) -> Path:
    """Rows of dicts as a CSV (the keys of the first row as its header)."""
    path = Path(path)
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    return path
