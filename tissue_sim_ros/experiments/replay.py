"""``tissue-sim replay``: run the simulation offline on a bag's tool trajectory (or a trajectory as data).

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

import argparse
import time
from pathlib import Path

import numpy as np

from ..core.config import Config, params_json, strict_json
from ..core.contact.tool import ToolPose
from ..core.errors import InputError, output_dir
from ..core.sim.simulation import Simulation
from ..core.timing.stamps import ns_from_seconds
from ..core.timing.trajectories import resolve_trajectory
from ..ros.bags import SKIP_REASONS, BadSampleError, BagWriter, ToolTrack, read_tool_track
from ..ros.replay import (
    MODES,
    ReplayBagSink,
    ReplayResult,
    replay,
    replay_steps,
    track_from_trajectory,
    write_outputs,
)
from .config import add_config_arguments, config_from_args

HELP = "run the simulation offline on a bag's tool trajectory; write a bag, CSV, plots, frames"
DESCRIPTION = __doc__.split("\n\n", 1)[1] if __doc__ else HELP


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", nargs="?", default=None, help="input bag: a rosbag2 directory, or a .mcap/.db3 file")
    parser.add_argument("--trajectory", default=None, metavar="PRESET|FILE",
                        help="replay a trajectory instead of a bag: a preset (experiment_a, experiment_b_shallow, "
                             "experiment_b_steep, authors) or a .csv (time,x,y,yaw) / .yaml trajectory file")
    parser.add_argument("--out", required=True, help="output directory (created; must not hold a replay already)")
    parser.add_argument("--tool-topic", default=None,
                        help="topic of the tool pose (PoseStamped, Pose, TransformStamped, TFMessage, "
                             "PoseWithCovarianceStamped, Odometry); default: the one pose topic in the bag "
                             "other than the node's own output tool/applied_pose")
    parser.add_argument("--frame", default=None, help="TF child frame of the tool (for tf2_msgs/TFMessage topics)")
    parser.add_argument("--twist-topic", default=None,
                        help="TwistStamped/Twist topic of the tool velocity (default: derived from poses)")
    add_config_arguments(parser)
    parser.add_argument("--mode", choices=MODES, default="per-message",
                        help="one step per tool message (default, = node lock-step), steps at 1/dt with "
                             "the pose interpolated, or applied: the node's own recording (tool/applied_*) "
                             "stepped exactly as the node did (bit for bit)")
    parser.add_argument("--time-source", choices=("header", "bag"), default="header",
                        help="sample times from header stamps (default) or bag receive times")
    parser.add_argument("--strict", action="store_true",
                        help="a tool sample that would be skipped (repeated or out-of-order time, non-finite "
                             "position, invalid quaternion) is an error (exit 2) instead of a counted skip")
    parser.add_argument("--frame-every", type=int, default=0,
                        help="write a PNG frame every K steps (default: about 40 frames in all; -1: none)")
    parser.add_argument("--video", action="store_true", help="also write replay.mp4 (needs the video extra)")
    parser.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap", help="storage of the output bag")
    parser.add_argument("--points-every", type=int, default=1,
                        help="write tissue/points every K steps (default 1, as the node at its default points_rate)")
    parser.add_argument("--no-bag", action="store_true", help="do not write the output bag (fastest)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def _check_video_support() -> None:
    try:
        import imageio.v2  # noqa: F401, PLC0415
    except ImportError:
        raise InputError("--video needs imageio and imageio-ffmpeg: pip install 'tissue_sim_ros[video]' "
                         "(or leave out --video; the PNG frames are written either way)") from None


def run(args: argparse.Namespace) -> int:
    if args.video:
        _check_video_support()
    if args.points_every < 1:
        raise InputError(f"--points-every {args.points_every}: expected K >= 1")
    if args.frame_every < -1:
        raise InputError(f"--frame-every {args.frame_every}: expected K >= 1, 0 (automatic) or -1 (none)")
    out = output_dir(args.out, "--out")
    bag_out = out / "replay_bag"
    if bag_out.exists():
        raise InputError(f"{str(bag_out)!r} exists already: choose another --out (nothing is overwritten)")

    if args.mode == "applied":
        if args.bag is None:
            raise InputError("--mode applied replays the node's own recording: expected a bag")
        return _run_applied(args, out, bag_out)
    if (args.bag is None) == (args.trajectory is None):
        raise InputError("replay needs a bag or --trajectory PRESET|FILE: expected exactly one of them")
    cfg, params_source = _replay_config(args)
    line = PARAMS_SOURCES[params_source]
    if params_source == "shipped defaults" and args.bag is None:  # a trajectory file holds no physics to miss
        line = "parameters: the shipped defaults (config/tissue_sim.yaml)"
    print(line)
    if args.trajectory is not None:
        dt = cfg.sim.dt
        track = track_from_trajectory(resolve_trajectory(args.trajectory, cfg.tool, dt), dt, args.trajectory)
        print(f"trajectory {args.trajectory}: {track.n} steps of {dt} s")
    else:
        on_bad = "error" if args.strict else "skip"
        try:
            track = read_tool_track(args.bag, topic=args.tool_topic, frame=args.frame, twist_topic=args.twist_topic,
                                    time_source=args.time_source, on_bad_time=on_bad, on_bad_pose=on_bad)
        except BadSampleError as exc:
            raise InputError(f"{exc} (--strict; without it such samples are skipped and counted)") from None
        print(track.summary())
        if sum(track.skipped.values()):
            print(f"note: {sum(track.skipped.values())} of {track.n_messages} tool samples skipped "
                  f"({', '.join(f'{k}: {v}' for k, v in track.skipped.items() if v)}); --strict makes this an error")
    sim = Simulation.from_config(cfg)
    # Load the compiled kernels (numba cache, python-fcl) on a throwaway copy of the scene, so the
    # replay's speed is the stepping speed; the replayed simulation itself starts untouched.
    t_warm = time.perf_counter()
    warm = Simulation.from_config(cfg, mesh=sim.model.mesh)
    warm.step(ToolPose(*map(float, track.pose[0])))
    print(f"warm-up (kernel load) {time.perf_counter() - t_warm:.2f} s, not counted in the replay speed")
    n_steps = track.n if args.mode == "per-message" else int(
        (track.t_ns[-1] - track.t_ns[0]) // ns_from_seconds(sim.params.dt))
    if args.frame_every > 0:
        frame_every = args.frame_every
    else:  # -1: none; 0: about 40 frames
        frame_every = 0 if args.frame_every < 0 else max(1, -(-n_steps // 40))

    out.mkdir(parents=True, exist_ok=True)
    writer = None if args.no_bag else BagWriter(bag_out, args.storage)
    if writer is not None:
        # what made this bag, so it can be reproduced from the bag alone
        writer.set_custom_data("tissue_sim.source_bag", str(args.bag) if args.bag else "")
        if args.trajectory:
            writer.set_custom_data("tissue_sim.trajectory", str(args.trajectory))
        writer.set_custom_data("tissue_sim.mode", args.mode)
        writer.set_custom_data("tissue_sim.tool_topic", track.topic + (f" frame {track.child_frame}"
                                                                        if track.child_frame else ""))
        if track.twist_topic:
            writer.set_custom_data("tissue_sim.twist_topic", track.twist_topic)
        # as the node writes it into its own recordings (replay --mode applied reads it back the same way)
        writer.set_custom_data("tissue_sim.params", params_json(cfg))
    try:
        sink = ReplayBagSink(writer, sim, points_every=args.points_every) if writer is not None else None
        result = replay(sim, track, args.mode, sink=sink, snapshot_every=frame_every, progress=not args.no_progress)
    except BaseException:
        if writer is not None:
            writer.close()
        raise
    if writer is not None:
        writer.close()
    print(result.speed_line())
    source = Path(args.bag).name if args.bag else f"trajectory {Path(args.trajectory).name}"
    write_outputs(out, sim, result, video=args.video, title=f"replay of {source} ({args.mode})")
    _write_summary(out / "replay.json", args, _track_info(track), cfg, sim, result, params_source)
    print(f"wrote {out}/energy.csv, energy.png, replay.json, frames/ ({len(result.rollout.snapshots)} PNG)"
          + (", replay_bag/" if writer is not None else "") + (", replay.mp4" if args.video else ""))
    return 0


#: Where a replay's parameters came from: replay.json's ``params_source`` -> the line printed
PARAMS_SOURCES = {
    "command line": "parameters: --params/--set over the shipped config/tissue_sim.yaml",
    "bag": "parameters: the recording's own (the node's, from the bag's metadata)",
    "shipped defaults": "parameters: the shipped defaults (config/tissue_sim.yaml): the bag holds no simulator "
                        "parameters, so these may not be the physics it ran with; give --params FILE to choose",
}


def _recorded_params(bag_path: str | Path) -> str | None:
    """The simulator's parameters a bag holds (custom data ``tissue_sim.params``), or None."""
    from ..ros.bags import Bag  # noqa: PLC0415

    with Bag(bag_path) as bag:
        return bag.custom_data.get("tissue_sim.params")


def _replay_config(args: argparse.Namespace) -> tuple[Config, str]:
    """The Config a replay steps with, and where it came from (a key of :data:`PARAMS_SOURCES`, printed as its
    line and written as ``params_source`` in replay.json).

    ``--params``/``--set`` win; else the parameters the bag recorded (the node's own ``record_path``
    recordings, and ``tissue-sim record`` of a running node, hold them); else the shipped defaults,
    which is said, since they may not be the physics the recording ran with.
    """
    from ..core.config import params_from_json, resolve_config  # noqa: PLC0415

    if args.params or getattr(args, "set", None):
        return config_from_args(args), "command line"
    recorded = _recorded_params(args.bag) if args.bag is not None else None
    if recorded is None:
        return config_from_args(args), "shipped defaults"
    return resolve_config(overrides=params_from_json(recorded), source=f"the parameters recorded in {args.bag}"), "bag"


def _run_applied(args: argparse.Namespace, out: Path, bag_out: Path) -> int:
    """``--mode applied``: the node's own recording, stepped with exactly what the node stepped with."""
    from ..ros.tool_applied import POSE_TYPE, read_applied_steps, relocations  # noqa: PLC0415

    steps = read_applied_steps(args.bag)
    print(f"{steps.n} steps from {steps.twist_topic} ({sum(p is not None for p in steps.poses)} with a tool), "
          f"{(steps.t_ns[-1] - steps.t_ns[0]) * 1e-9:.3f} s")
    if not (args.params or getattr(args, "set", None)) and _recorded_params(args.bag) is None:
        raise InputError(f"bag {str(args.bag)!r} does not hold the node's parameters (custom_data "
                         "tissue_sim.params): give the node's parameters with --params")
    cfg, params_source = _replay_config(args)
    print(PARAMS_SOURCES[params_source])
    sim = Simulation.from_config(cfg)
    warm = Simulation.from_config(cfg, mesh=sim.model.mesh)
    warm.step(next((p for p in steps.poses if p is not None), None))
    frame_every = args.frame_every if args.frame_every > 0 else (0 if args.frame_every < 0 else max(1, -(-steps.n // 40)))
    out.mkdir(parents=True, exist_ok=True)
    writer = None if args.no_bag else BagWriter(bag_out, args.storage)
    try:
        if writer is not None:  # what made this bag, as in the other modes
            writer.set_custom_data("tissue_sim.source_bag", str(args.bag))
            writer.set_custom_data("tissue_sim.mode", args.mode)
            writer.set_custom_data("tissue_sim.tool_topic", steps.pose_topic)
            writer.set_custom_data("tissue_sim.twist_topic", steps.twist_topic)
            writer.set_custom_data("tissue_sim.params", params_json(cfg))
        sink = ReplayBagSink(writer, sim, points_every=args.points_every) if writer is not None else None
        result = replay_steps(sim, steps.t_ns, steps.items(), sink=sink, snapshot_every=frame_every,
                              progress=not args.no_progress, before_step=relocations(sim, cfg.node.max_tool_jump))
    finally:
        if writer is not None:
            writer.close()
    print(result.speed_line())
    write_outputs(out, sim, result, video=args.video, title=f"replay of {Path(args.bag).name} (applied)")
    with_tool = sum(p is not None for p in steps.poses)
    info = {"tool_topic": steps.pose_topic, "tool_type": POSE_TYPE, "child_frame": None,
            "twist_topic": steps.twist_topic, "time_source": "header",
            "samples": steps.n, "samples_read": steps.n, "skipped": dict.fromkeys(SKIP_REASONS, 0),
            "steps_with_tool": with_tool,
            "track_duration_s": float(steps.t_ns[-1] - steps.t_ns[0]) * 1e-9}
    _write_summary(out / "replay.json", args, info, cfg, sim, result, params_source)
    print(f"wrote {out}/energy.csv, energy.png, replay.json, frames/ ({len(result.rollout.snapshots)} PNG)"
          + (", replay_bag/" if writer is not None else "") + (", replay.mp4" if args.video else ""))
    return 0


def _track_info(track: ToolTrack) -> dict:
    """replay.json's account of the tool samples read (the same keys in every mode)."""
    return {"tool_topic": track.topic, "tool_type": track.msgtype, "child_frame": track.child_frame,
            "twist_topic": track.twist_topic, "time_source": track.time_source,
            "samples": track.n, "samples_read": track.n_messages, "skipped": track.skipped,
            "track_duration_s": track.duration}


def _write_summary(path: Path, args: argparse.Namespace, info: dict, cfg: Config, sim: Simulation,
                   result: ReplayResult, params_source: str) -> None:
    """What was replayed, how, and how fast, as strict JSON (for scripts and reports): the same keys in every
    mode; a non-finite number (an unset parameter such as pin_y_top, a diverged energy) is null."""
    import json  # noqa: PLC0415

    ro = result.rollout
    summary = {
        "bag": str(args.bag) if args.bag else None, "trajectory": args.trajectory, "mode": args.mode,
        "params_file": args.params, "set": list(getattr(args, "set", None) or []),
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
