"""The replay job of ``tissue-sim replay``: run the simulation offline on a bag's tool trajectory (or a trajectory
as data). The command line is :mod:`tissue_sim_ros.cli.replay`; the stepping and the replay bag's encoding are
:mod:`tissue_sim_ros.ros.replay`'s.

Reads the tool trajectory from a bag (:func:`~tissue_sim_ros.ros.bags.read_tool_track`),
steps :class:`~tissue_sim_ros.core.sim.simulation.Simulation` as fast as the
machine allows, and writes into ``--out``:

* ``replay_bag/``: a rosbag2 bag (MCAP) with what the node would publish
  (energy total and terms, points, wrench, the tool pose used), stamped with
  the input's times, so it lines up with the input bag in Foxglove/PlotJuggler;
* ``energy.csv``: the energy series (full float64 precision);
* ``replay.json``: what was replayed (tool topic, frame, samples, skips,
  every parameter, mesh) and how fast, the same keys in every mode, strict
  JSON (a non-finite number is null);
* ``energy.png``: the energy plot; ``frames/frame_NNNNN.png`` every k steps;
* ``replay.mp4`` (or ``.gif``) with ``--video`` (needs the ``video`` extra).

Three modes, chosen with ``--mode``:

``per-message`` (default)
    one step of dt per tool message, with that message's pose: exactly what
    the node does in lock-step, so the two give the same energy series;
``fixed-rate``
    steps at the simulation rate 1/dt over the bag's time span, the pose
    linearly interpolated (yaw the short way round) at each step's time;
``applied``
    a bag the node recorded itself (``record_path``): one step per message on
    ``tool/applied_twist`` with the pose of ``tool/applied_pose`` of the same
    stamp (no tool where there is none) and that very twist, i.e. exactly
    what the node stepped with, so a timer-mode run is reproduced bit for bit.

Instead of a bag, ``--trajectory PRESET|FILE`` replays a trajectory given as
data (:mod:`tissue_sim_ros.core.timing.trajectories`: a preset such as ``authors``, or
a CSV of time,x,y,yaw or a YAML file): its per-step poses and twists are the
samples, one step each, at t = k dt.

Messages with repeated or out-of-order times, non-finite poses or invalid
quaternions are skipped, counted and reported (``--strict``: an error).
No ROS graph and no rclpy: this runs anywhere the core runs.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.config import Config, params_from_json, params_json, resolve_config, strict_json
from ..core.contact.tool import ToolPose
from ..core.errors import InputError, output_dir
from ..core.sim.simulation import Simulation
from ..core.timing.stamps import ns_from_seconds
from ..core.timing.trajectories import resolve_trajectory
from ..ros.bags import SKIP_REASONS, BadSampleError, Bag, BagWriter, ToolTrack, read_tool_track
from ..ros.replay import ReplayBagSink, ReplayResult, replay, replay_steps, track_from_trajectory, write_outputs


@dataclass
class ReplayJob:
    """What to replay and how (``tissue-sim replay``'s options, as plain values).

    ``config`` is the Config of ``params_file`` and ``overrides`` over the shipped file; with neither given, the
    bag's own recorded parameters are used when it holds them (:data:`PARAMS_SOURCES`).
    """

    out: str
    config: Config
    bag: str | None = None
    trajectory: str | None = None
    params_file: str | None = None
    overrides: list[str] = field(default_factory=list)
    tool_topic: str | None = None
    frame: str | None = None
    twist_topic: str | None = None
    mode: str = "per-message"
    time_source: str = "header"
    strict: bool = False
    frame_every: int = 0
    video: bool = False
    storage: str = "mcap"
    points_every: int = 1
    bag_output: bool = True
    progress: bool = True

    @property
    def chosen(self) -> bool:
        """The parameters were given (``params_file`` or ``overrides``)."""
        return bool(self.params_file or self.overrides)


def _check_video_support() -> None:
    try:
        import imageio.v2  # noqa: F401, PLC0415
    except ImportError:
        raise InputError("--video needs imageio and imageio-ffmpeg: pip install 'tissue_sim_ros[video]' "
                         "(or leave out --video; the PNG frames are written either way)") from None


def run_replay(job: ReplayJob) -> int:
    """The replay of ``job``; its outputs written into ``job.out``. Returns the exit status (0)."""
    if job.video:
        _check_video_support()
    if job.points_every < 1:
        raise InputError(f"--points-every {job.points_every}: expected K >= 1")
    if job.frame_every < -1:
        raise InputError(f"--frame-every {job.frame_every}: expected K >= 1, 0 (automatic) or -1 (none)")
    out = output_dir(job.out, "--out")
    bag_out = out / "replay_bag"
    if bag_out.exists():
        raise InputError(f"{str(bag_out)!r} exists already: choose another --out (nothing is overwritten)")
    if job.mode == "applied":
        if job.bag is None:
            raise InputError("--mode applied replays the node's own recording: expected a bag")
        return _run_applied(job, out, bag_out)
    if (job.bag is None) == (job.trajectory is None):
        raise InputError("replay needs a bag or --trajectory PRESET|FILE: expected exactly one of them")
    cfg, params_source = _replay_config(job)
    line = PARAMS_SOURCES[params_source]
    if params_source == "shipped defaults" and job.bag is None:  # a trajectory file holds no physics to miss
        line = "parameters: the shipped defaults (config/tissue_sim.yaml)"
    print(line)
    track = _track(job, cfg)
    sim = Simulation.from_config(cfg)
    # Load the compiled kernels (numba cache, python-fcl) on a throwaway copy of the scene, so the
    # replay's speed is the stepping speed; the replayed simulation itself starts untouched.
    t_warm = time.perf_counter()
    warm = Simulation.from_config(cfg, mesh=sim.model.mesh)
    warm.step(ToolPose(*map(float, track.pose[0])))
    print(f"warm-up (kernel load) {time.perf_counter() - t_warm:.2f} s, not counted in the replay speed")
    n_steps = track.n if job.mode == "per-message" else int(
        (track.t_ns[-1] - track.t_ns[0]) // ns_from_seconds(sim.params.dt))
    out.mkdir(parents=True, exist_ok=True)
    writer = BagWriter(bag_out, job.storage) if job.bag_output else None
    if writer is not None:
        # what made this bag, so it can be reproduced from the bag alone
        _custom_data(writer, job, track.topic + (f" frame {track.child_frame}" if track.child_frame else ""),
                     track.twist_topic, cfg)
    try:
        sink = ReplayBagSink(writer, sim, points_every=job.points_every) if writer is not None else None
        result = replay(sim, track, job.mode, sink=sink, snapshot_every=_frame_every(job.frame_every, n_steps),
                        progress=job.progress)
    finally:
        if writer is not None:
            writer.close()
    print(result.speed_line())
    source = Path(job.bag).name if job.bag else f"trajectory {Path(job.trajectory).name}"
    write_outputs(out, sim, result, video=job.video, title=f"replay of {source} ({job.mode})")
    _write_summary(out / "replay.json", job, _track_info(track), cfg, sim, result, params_source)
    _say_written(out, result, writer is not None, job.video)
    return 0


def _frame_every(frame_every: int, n_steps: int) -> int:
    """A frame every this many steps: as given; 0 about 40 frames in all; -1 none (0)."""
    if frame_every > 0:
        return frame_every
    return 0 if frame_every < 0 else max(1, -(-n_steps // 40))


def _track(job: ReplayJob, cfg: Config) -> ToolTrack:
    """The tool samples to step with: the trajectory's, or the bag's (skips reported; ``strict``: an error)."""
    if job.trajectory is not None:
        dt = cfg.sim.dt
        track = track_from_trajectory(resolve_trajectory(job.trajectory, cfg.tool, dt), dt, job.trajectory)
        print(f"trajectory {job.trajectory}: {track.n} steps of {dt} s")
        return track
    on_bad = "error" if job.strict else "skip"
    try:
        track = read_tool_track(job.bag, topic=job.tool_topic, frame=job.frame, twist_topic=job.twist_topic,
                                time_source=job.time_source, on_bad_time=on_bad, on_bad_pose=on_bad)
    except BadSampleError as exc:
        raise InputError(f"{exc} (--strict; without it such samples are skipped and counted)") from None
    print(track.summary())
    if sum(track.skipped.values()):
        print(f"note: {sum(track.skipped.values())} of {track.n_messages} tool samples skipped "
              f"({', '.join(f'{k}: {v}' for k, v in track.skipped.items() if v)}); --strict makes this an error")
    return track


def _custom_data(writer: BagWriter, job: ReplayJob, tool_topic: str, twist_topic: str | None, cfg: Config) -> None:
    """What made the replay bag, written into it (the parameters as the node writes them into its recordings)."""
    writer.set_custom_data("tissue_sim.source_bag", str(job.bag) if job.bag else "")
    if job.trajectory:
        writer.set_custom_data("tissue_sim.trajectory", str(job.trajectory))
    writer.set_custom_data("tissue_sim.mode", job.mode)
    writer.set_custom_data("tissue_sim.tool_topic", tool_topic)
    if twist_topic:
        writer.set_custom_data("tissue_sim.twist_topic", twist_topic)
    writer.set_custom_data("tissue_sim.params", params_json(cfg))


def _say_written(out: Path, result: ReplayResult, bag: bool, video: bool) -> None:
    print(f"wrote {out}/energy.csv, energy.png, replay.json, frames/ ({len(result.rollout.snapshots)} PNG)"
          + (", replay_bag/" if bag else "") + (", replay.mp4" if video else ""))


#: Where a replay's parameters came from: replay.json's ``params_source`` -> the line printed
PARAMS_SOURCES = {
    "command line": "parameters: --params/--set over the shipped config/tissue_sim.yaml",
    "bag": "parameters: the recording's own (the node's, from the bag's metadata)",
    "shipped defaults": "parameters: the shipped defaults (config/tissue_sim.yaml): the bag holds no simulator "
                        "parameters, so these may not be the physics it ran with; give --params FILE to choose",
}


def _recorded_params(bag_path: str | Path) -> str | None:
    """The simulator's parameters a bag holds (custom data ``tissue_sim.params``), or None."""
    with Bag(bag_path) as bag:
        return bag.custom_data.get("tissue_sim.params")


def _replay_config(job: ReplayJob) -> tuple[Config, str]:
    """The Config a replay steps with, and where it came from (a key of :data:`PARAMS_SOURCES`, printed as its
    line and written as ``params_source`` in replay.json).

    ``--params``/``--set`` win; else the parameters the bag recorded (the node's own ``record_path``
    recordings, and ``tissue-sim record`` of a running node, hold them); else the shipped defaults,
    which is said, since they may not be the physics the recording ran with.
    """
    if job.chosen:
        return job.config, "command line"
    recorded = _recorded_params(job.bag) if job.bag is not None else None
    if recorded is None:
        return job.config, "shipped defaults"
    return resolve_config(overrides=params_from_json(recorded), source=f"the parameters recorded in {job.bag}"), "bag"


def _run_applied(job: ReplayJob, out: Path, bag_out: Path) -> int:
    """``--mode applied``: the node's own recording, stepped with exactly what the node stepped with."""
    from ..ros.tool_applied import POSE_TYPE, read_applied_steps, relocations  # noqa: PLC0415

    steps = read_applied_steps(job.bag)
    print(f"{steps.n} steps from {steps.twist_topic} ({sum(p is not None for p in steps.poses)} with a tool), "
          f"{(steps.t_ns[-1] - steps.t_ns[0]) * 1e-9:.3f} s")
    if not job.chosen and _recorded_params(job.bag) is None:
        raise InputError(f"bag {str(job.bag)!r} does not hold the node's parameters (custom_data "
                         "tissue_sim.params): give the node's parameters with --params")
    cfg, params_source = _replay_config(job)
    print(PARAMS_SOURCES[params_source])
    sim = Simulation.from_config(cfg)
    warm = Simulation.from_config(cfg, mesh=sim.model.mesh)
    warm.step(next((p for p in steps.poses if p is not None), None))
    out.mkdir(parents=True, exist_ok=True)
    writer = BagWriter(bag_out, job.storage) if job.bag_output else None
    try:
        if writer is not None:  # what made this bag, as in the other modes
            _custom_data(writer, job, steps.pose_topic, steps.twist_topic, cfg)
        sink = ReplayBagSink(writer, sim, points_every=job.points_every) if writer is not None else None
        result = replay_steps(sim, steps.t_ns, steps.items(), sink=sink,
                              snapshot_every=_frame_every(job.frame_every, steps.n), progress=job.progress,
                              before_step=relocations(sim, cfg.node.max_tool_jump))
    finally:
        if writer is not None:
            writer.close()
    print(result.speed_line())
    write_outputs(out, sim, result, video=job.video, title=f"replay of {Path(job.bag).name} (applied)")
    info = {"tool_topic": steps.pose_topic, "tool_type": POSE_TYPE, "child_frame": None,
            "twist_topic": steps.twist_topic, "time_source": "header",
            "samples": steps.n, "samples_read": steps.n, "skipped": dict.fromkeys(SKIP_REASONS, 0),
            "steps_with_tool": sum(p is not None for p in steps.poses),
            "track_duration_s": float(steps.t_ns[-1] - steps.t_ns[0]) * 1e-9}
    _write_summary(out / "replay.json", job, info, cfg, sim, result, params_source)
    _say_written(out, result, writer is not None, job.video)
    return 0


def _track_info(track: ToolTrack) -> dict:
    """replay.json's account of the tool samples read (the same keys in every mode)."""
    return {"tool_topic": track.topic, "tool_type": track.msgtype, "child_frame": track.child_frame,
            "twist_topic": track.twist_topic, "time_source": track.time_source,
            "samples": track.n, "samples_read": track.n_messages, "skipped": track.skipped,
            "track_duration_s": track.duration}


def _write_summary(path: Path, job: ReplayJob, info: dict, cfg: Config, sim: Simulation,
                   result: ReplayResult, params_source: str) -> None:
    """What was replayed, how, and how fast, as strict JSON (for scripts and reports): the same keys in every
    mode; a non-finite number (an unset parameter such as pin_y_top, a diverged energy) is null."""
    ro = result.rollout
    summary: dict[str, Any] = {
        "bag": str(job.bag) if job.bag else None, "trajectory": job.trajectory, "mode": job.mode,
        "params_file": job.params_file, "set": list(job.overrides),
        "params_source": params_source, "params": cfg.flat(),
        **info,
        "bodies": list(sim.model.body_names), "particles": sim.model.n_particles, "triangles": sim.model.n_triangles, "dt": sim.params.dt,
        "steps": result.n_steps, "simulated_s": result.sim_time, "wall_s": result.wall_time,
        "steps_per_s": result.steps_per_second, "real_time_factor": result.real_time_factor,
        "real_time_factor_median_step": result.median_real_time_factor,
        "real_time_factor_cpu": result.cpu_real_time_factor, "cpu_s": result.cpu_time,
        "median_step_ms": 1e3 * float(np.median(result.loop_times)) if result.loop_times.size else None,
        "energy_final": float(ro.scene_total[-1]) if ro.steps.size else None,
        "steps_in_contact": int(ro.in_contact.any(axis=1).sum()), "diverged_steps": int(ro.diverged.sum()),
    }
    path.write_text(json.dumps(strict_json(summary), indent=2, allow_nan=False) + "\n")
