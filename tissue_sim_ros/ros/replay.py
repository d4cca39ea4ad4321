"""``tissue-sim replay``: run the simulation offline on a bag's tool trajectory.

Reads the tool trajectory from a bag (:func:`~tissue_sim_ros.ros.bags.read_tool_track`),
steps :class:`~tissue_sim_ros.core.simulation.Simulation` as fast as the
machine allows, and writes into ``--out``:

* ``replay_bag/``: a rosbag2 bag (MCAP) with what the node would publish
  (energy total and terms, points, wrench, the tool pose used), stamped with
  the input's times, so it lines up with the input bag in Foxglove/PlotJuggler;
* ``energy.csv``: the energy series (full float64 precision);
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

Messages with repeated or out-of-order times, non-finite poses or invalid
quaternions are skipped, counted and reported (``--strict``: an error).
No ROS graph and no rclpy: this runs anywhere the core runs.
"""
from __future__ import annotations

import argparse
import math
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..cli_config import add_config_arguments, config_from_args
from ..core.errors import InputError
from ..core.rollout import Rollout, rollout
from ..core.simulation import Simulation, StepReport
from ..core.tool import ToolPose, ToolTwist
from . import messages as msgs
from .bags import BagWriter, ToolTrack, read_tool_track

HELP = "run the simulation offline on a bag's tool trajectory; write a bag, CSV, plots, frames"
DESCRIPTION = __doc__.split("\n\n", 1)[1] if __doc__ else HELP

MODES = ("per-message", "fixed-rate", "applied")
TERMS = ("inertial", "spring", "area", "total")

#: Output topics of the replay bag: the node's names and types (msg_docs/topics.md).
OUTPUT_TOPICS: dict[str, str] = {
    "/tool/pose": "geometry_msgs/msg/PoseStamped",
    "/tissue/energy": "std_msgs/msg/Float64",
    "/tissue/energy/inertial": "std_msgs/msg/Float64",
    "/tissue/energy/spring": "std_msgs/msg/Float64",
    "/tissue/energy/area": "std_msgs/msg/Float64",
    "/tissue/energy/bodies": "std_msgs/msg/Float64MultiArray",
    "/tissue/points": "sensor_msgs/msg/PointCloud2",
    "/tool/wrench": "geometry_msgs/msg/WrenchStamped",
}


@dataclass
class ReplayResult:
    """What a replay did and how fast."""

    rollout: Rollout
    """The energy series and snapshots."""
    t_ns: np.ndarray
    """Input-timeline time of each step [ns], shape (S,), int64."""
    wall_time: float
    """Wall time of the stepping loop, including writing the output bag [s]."""
    step_time: float
    """Wall time inside Simulation.step only [s]."""
    loop_times: np.ndarray
    """Wall time of each iteration (step + writing) [s], shape (S,): its median resists a busy machine."""
    cpu_time: float
    """CPU time of this process over the loop [s]: unlike wall time, not inflated by other processes."""
    sim_time: float
    """Simulated time: steps * dt [s]."""
    track_duration: float
    """Span of the input trajectory [s]."""

    @property
    def n_steps(self) -> int:
        return int(self.rollout.steps.shape[0])

    @property
    def steps_per_second(self) -> float:
        return self.n_steps / self.wall_time if self.wall_time > 0 else math.inf

    @property
    def real_time_factor(self) -> float:
        """Simulated seconds per wall-clock second (10 = ten times faster than real time)."""
        return self.sim_time / self.wall_time if self.wall_time > 0 else math.inf

    @property
    def cpu_real_time_factor(self) -> float:
        """Simulated seconds per CPU second of the replay loop."""
        return self.sim_time / self.cpu_time if self.cpu_time > 0 else math.inf

    @property
    def median_real_time_factor(self) -> float:
        """dt / median iteration time: the speed without the pauses another process causes."""
        med = float(np.median(self.loop_times)) if self.loop_times.size else 0.0
        return (self.sim_time / max(1, self.n_steps)) / med if med > 0 else math.inf

    def speed_line(self) -> str:
        med = 1e3 * float(np.median(self.loop_times)) if self.loop_times.size else float("nan")
        return (f"replay speed: {self.n_steps} steps in {self.wall_time:.3f} s wall = {self.steps_per_second:.1f} steps/s, "
                f"real-time factor {self.real_time_factor:.1f}x overall, {self.median_real_time_factor:.1f}x at the "
                f"median step ({med:.3f} ms per step incl. writing), {self.cpu_real_time_factor:.1f}x per CPU second "
                f"({self.sim_time:.3f} s simulated; "
                f"Simulation.step {1e3 * self.step_time / max(1, self.n_steps):.3f} ms/step mean, "
                f"{1e3 * (self.wall_time - self.step_time) / max(1, self.n_steps):.3f} ms/step writing mean)")


def schedule(track: ToolTrack, dt: float, mode: str) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Times [ns], poses (S, 3) and twists (S, 3) or None of each step of a replay.

    ``per-message``: the track's own samples, with a twist only where one
    carries the pose's own stamp and was received no later than the pose (NaN
    rows: derived from poses), as the node does in lock-step. ``fixed-rate``: t0 + k dt for k = 1 .. floor(span / dt),
    poses interpolated, twists sample-and-hold.
    """
    if mode == "per-message":
        if track.twist is None:
            return track.t_ns.copy(), track.pose.copy(), None
        # as the node in lock-step: only a twist with the pose's own stamp that had arrived when the pose did
        # (the node steps on the pose; a twist after it is too late); else velocity from poses
        twist = track.twist.copy()
        if track.twist_t_ns is not None:
            twist[track.twist_t_ns != track.t_ns] = np.nan
        if track.twist_received_ns is not None and track.received_ns is not None:
            twist[track.twist_received_ns > track.received_ns] = np.nan
        return track.t_ns.copy(), track.pose.copy(), twist
    if mode != "fixed-rate":
        raise InputError(f"--mode {mode!r}: expected one of {', '.join(MODES)}")
    dt_ns = int(round(dt * 1e9))
    n = int((track.t_ns[-1] - track.t_ns[0]) // dt_ns)
    if n < 1:
        raise InputError(f"tool track {track.topic} spans {track.duration:.4f} s, shorter than one step dt={dt} s: "
                         "nothing to replay at the fixed rate (use --mode per-message)")
    t = track.t_ns[0] + dt_ns * np.arange(1, n + 1, dtype=np.int64)
    twist = None
    if track.twist is not None:
        idx = np.searchsorted(track.t_ns, t, side="right") - 1
        twist = track.twist[idx]
    return t, track.interpolate(t), twist


def _stamp(t_ns: int) -> tuple[int, int]:
    return int(t_ns // 1_000_000_000), int(t_ns % 1_000_000_000)


class VertexStrain:
    """:func:`~tissue_sim_ros.core.strain.vertex_strain` with the mesh's constant parts computed once.

    The mean absolute edge strain at each vertex. Recomputing the incidence
    counts and fancy-indexing (N, 2) arrays every step made it the largest cost
    of writing a step's points (~85 us at the paper scene's size); with the
    counts kept and ``np.take`` it is ~20 us. Equal to the core function up to
    summation order (checked in test_replay.py).
    """

    def __init__(self, model) -> None:
        e = model.edge_indices.astype(np.intp)
        n = model.n_particles
        self._e0, self._e1 = e[:, 0].copy(), e[:, 1].copy()
        self._ends = np.concatenate([self._e0, self._e1])
        count = np.bincount(self._ends, minlength=n).astype(np.float64)
        self._inv_count = 1.0 / np.maximum(count, 1.0)
        self._n = n
        l0 = model.edge_rest_length
        self._inv_l0 = np.where(l0 > 0, 1.0 / np.where(l0 > 0, l0, 1.0), 0.0)
        self._one = (l0 > 0).astype(np.float64)  # zero rest length: strain 0, as in the core function

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """Mean |strain| of the edges at each vertex for positions ``x`` (N, 2) [m]; shape (N,), float64."""
        d = np.take(x, self._e1, axis=0) - np.take(x, self._e0, axis=0)
        strain = np.abs(np.hypot(d[:, 0], d[:, 1]) * self._inv_l0 - self._one)
        return np.bincount(self._ends, weights=np.concatenate([strain, strain]), minlength=self._n) * self._inv_count


class ReplayBagSink:
    """Writes the node's outputs of each step into a bag (CDR from :mod:`.messages`, no rclpy)."""

    def __init__(self, writer: BagWriter, sim: Simulation, frame_id: str = "world", points_every: int = 1) -> None:
        if points_every < 1:
            raise InputError(f"--points-every {points_every}: expected K >= 1")
        self.writer = writer
        self.sim = sim
        self.frame_id = frame_id
        self.points_every = points_every
        self._n = 0
        for name, msgtype in OUTPUT_TOPICS.items():
            writer.add_topic(name, msgtype)
        model = sim.model
        self._points = np.zeros(model.n_particles, dtype=msgs.POINT_DTYPE)
        self._points["body"] = model.particle_body
        self._strain = VertexStrain(model)

    def __call__(self, report: StepReport, t_ns: int, pose: ToolPose | None) -> None:
        stamp, e = _stamp(t_ns), report.energy
        # the node's layout: (B, 4) rows of inertial, spring, area, total
        table = np.column_stack([e.inertial, e.spring, e.area, e.total])
        f = report.reaction_force
        items = [] if pose is None else [
            ("/tool/pose", msgs.encode_pose_stamped(stamp, self.frame_id, pose.x, pose.y, pose.yaw), t_ns)]
        items += [
            ("/tissue/energy", msgs.encode_float64(e.scene_total), t_ns),
            ("/tissue/energy/inertial", msgs.encode_float64(float(e.inertial.sum())), t_ns),
            ("/tissue/energy/spring", msgs.encode_float64(float(e.spring.sum())), t_ns),
            ("/tissue/energy/area", msgs.encode_float64(float(e.area.sum())), t_ns),
            ("/tissue/energy/bodies", msgs.encode_float64_multiarray(table, ["body", "term:" + ",".join(TERMS)]), t_ns),
            ("/tool/wrench", msgs.encode_wrench_stamped(stamp, self.frame_id, (float(f[0]), float(f[1]), 0.0),
                                                        (0.0, 0.0, float(report.reaction_torque))), t_ns),
        ]
        self._n += 1
        if self._n % self.points_every == 0:
            x = self.sim.state.particle_q
            self._points["x"] = x[:, 0]
            self._points["y"] = x[:, 1]
            self._points["strain"] = self._strain(x)
            items.append(("/tissue/points", msgs.encode_point_cloud(stamp, self.frame_id, self._points), t_ns))
        self.writer.write_many(items)


def replay(sim: Simulation, track: ToolTrack, mode: str = "per-message", *, sink: Any = None,
           snapshot_every: int = 0, progress: bool = True) -> ReplayResult:
    """Step ``sim`` along ``track`` and collect the series.

    Parameters
    ----------
    sim : Simulation
        Stepped from its current state (call ``sim.reset()`` for a fresh run).
    track : ToolTrack
        The tool trajectory.
    mode : {"per-message", "fixed-rate"}
    sink : callable(report, t_ns, pose), optional
        Called after each step (e.g. :class:`ReplayBagSink`).
    snapshot_every : int
        Keep particle positions every k steps (and the first and last) for frames; 0 = none.
    progress : bool
        Show a tqdm progress bar on stderr.
    """
    t_ns, poses, twists = schedule(track, sim.params.dt, mode)
    items: list[tuple[ToolPose | None, ToolTwist | None]] = []
    for i in range(int(t_ns.shape[0])):
        tw = None
        if twists is not None and np.isfinite(twists[i]).all():
            tw = ToolTwist(float(twists[i, 0]), float(twists[i, 1]), float(twists[i, 2]))
        items.append((ToolPose(float(poses[i, 0]), float(poses[i, 1]), float(poses[i, 2])), tw))
    return replay_steps(sim, t_ns, items, sink=sink, snapshot_every=snapshot_every, progress=progress,
                        track_duration=track.duration)


def replay_steps(sim: Simulation, t_ns: np.ndarray, items: list[tuple[ToolPose | None, ToolTwist | None]], *,
                 sink: Any = None, snapshot_every: int = 0, progress: bool = True,
                 track_duration: float | None = None) -> ReplayResult:
    """Step ``sim`` once per (pose or None, twist or None) of ``items``, at times ``t_ns``; see :func:`replay`."""
    n = len(items)
    snaps: list[int] = []
    if snapshot_every > 0:
        snaps = sorted(set(range(0, n + 1, snapshot_every)) | {n})
    step_time = 0.0

    from tqdm import tqdm  # noqa: PLC0415

    bar = tqdm(total=n, unit="step", desc="replay", disable=not progress, mininterval=0.25, leave=False)
    counter = [0]

    loop_times = np.zeros(n)
    last = [0.0]

    def on_step(report: StepReport) -> None:
        nonlocal step_time
        i = counter[0]
        counter[0] += 1
        step_time += report.timings.get("total", 0.0)
        now = time.perf_counter()
        loop_times[i] = now - last[0]
        last[0] = now
        if sink is not None:
            sink(report, int(t_ns[i]), items[i][0])
        bar.update(1)

    start = time.perf_counter()
    cpu_start = time.process_time()
    last[0] = start
    try:
        result = rollout(sim, items, snapshot_steps=[sim.step_count + s for s in snaps], on_step=on_step)
    finally:
        bar.close()
    wall = time.perf_counter() - start
    cpu = time.process_time() - cpu_start
    if track_duration is None:
        track_duration = float(t_ns[-1] - t_ns[0]) * 1e-9 if n else 0.0
    return ReplayResult(rollout=result, t_ns=t_ns, wall_time=wall, step_time=step_time, loop_times=loop_times,
                        cpu_time=cpu, sim_time=n * sim.params.dt, track_duration=track_duration)


# --------------------------------------------------------------------------- CLI


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", help="input bag: a rosbag2 directory, or a .mcap/.db3 file")
    parser.add_argument("--out", required=True, help="output directory (created; must not hold a replay already)")
    parser.add_argument("--tool-topic", default=None,
                        help="topic of the tool pose (PoseStamped, Pose, TransformStamped, TFMessage, "
                             "PoseWithCovarianceStamped, Odometry); default: the one pose topic in the bag")
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
                        help="repeated or out-of-order sample times are an error instead of counted skips")
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
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {str(out)!r} exists and is not a directory")
    bag_out = out / "replay_bag"
    if bag_out.exists():
        raise InputError(f"{str(bag_out)!r} exists already: choose another --out (nothing is overwritten)")

    if args.mode == "applied":
        return _run_applied(args, out, bag_out)
    track = read_tool_track(args.bag, topic=args.tool_topic, frame=args.frame, twist_topic=args.twist_topic,
                            time_source=args.time_source, on_bad_time="error" if args.strict else "skip")
    print(track.summary())
    if sum(track.skipped.values()):
        print(f"note: {sum(track.skipped.values())} of {track.n_messages} tool samples skipped "
              f"({', '.join(f'{k}: {v}' for k, v in track.skipped.items() if v)}); --strict makes this an error")
    cfg = config_from_args(args)
    sim = Simulation.from_config(cfg)
    # Load the compiled kernels (numba cache, python-fcl) on a throwaway copy of the scene, so the
    # replay's speed is the stepping speed; the replayed simulation itself starts untouched.
    t_warm = time.perf_counter()
    warm = Simulation.from_config(cfg, mesh=sim.model.mesh)
    warm.step(ToolPose(*map(float, track.pose[0])))
    print(f"warm-up (kernel load) {time.perf_counter() - t_warm:.2f} s, not counted in the replay speed")
    n_steps = track.n if args.mode == "per-message" else int(
        (track.t_ns[-1] - track.t_ns[0]) // int(round(sim.params.dt * 1e9)))
    if args.frame_every > 0:
        frame_every = args.frame_every
    else:  # -1: none; 0: about 40 frames
        frame_every = 0 if args.frame_every < 0 else max(1, -(-n_steps // 40))

    out.mkdir(parents=True, exist_ok=True)
    writer = None if args.no_bag else BagWriter(bag_out, args.storage)
    if writer is not None:
        import json  # noqa: PLC0415

        # what made this bag, so it can be reproduced from the bag alone
        writer.set_custom_data("tissue_sim.source_bag", str(args.bag))
        writer.set_custom_data("tissue_sim.mode", args.mode)
        writer.set_custom_data("tissue_sim.tool_topic", track.topic + (f" frame {track.child_frame}"
                                                                        if track.child_frame else ""))
        writer.set_custom_data("tissue_sim.params", json.dumps(cfg.flat(), default=str))
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
    write_outputs(out, sim, result, video=args.video, title=f"replay of {Path(args.bag).name} ({args.mode})")
    _write_summary(out / "replay.json", args, track, sim, result)
    print(f"wrote {out}/energy.csv, energy.png, replay.json, frames/ ({len(result.rollout.snapshots)} PNG)"
          + (", replay_bag/" if writer is not None else "") + (", replay.mp4" if args.video else ""))
    return 0


def _run_applied(args: argparse.Namespace, out: Path, bag_out: Path) -> int:
    """``--mode applied``: the node's own recording, stepped with exactly what the node stepped with."""
    import json  # noqa: PLC0415

    from ..core.config import resolve_config  # noqa: PLC0415
    from .bags import Bag  # noqa: PLC0415
    from .tool_applied import read_applied_steps  # noqa: PLC0415

    steps = read_applied_steps(args.bag)
    print(f"{steps.n} steps from {steps.twist_topic} ({sum(p is not None for p in steps.poses)} with a tool), "
          f"{(steps.t_ns[-1] - steps.t_ns[0]) * 1e-9:.3f} s")
    if args.params or getattr(args, "set", None):
        cfg = config_from_args(args)
    else:
        bag = Bag(args.bag)
        try:
            recorded = bag.custom_data.get("tissue_sim.params")
        finally:
            bag.close()
        if recorded is None:
            raise InputError(f"bag {str(args.bag)!r} does not hold the node's parameters (custom_data "
                             "tissue_sim.params): give the node's parameters with --params")
        cfg = resolve_config(overrides=json.loads(recorded), source=f"the parameters recorded in {args.bag}")
        print("parameters: the node's own, from the bag's metadata")
    sim = Simulation.from_config(cfg)
    warm = Simulation.from_config(cfg, mesh=sim.model.mesh)
    warm.step(next((p for p in steps.poses if p is not None), None))
    frame_every = args.frame_every if args.frame_every > 0 else (0 if args.frame_every < 0 else max(1, -(-steps.n // 40)))
    out.mkdir(parents=True, exist_ok=True)
    writer = None if args.no_bag else BagWriter(bag_out, args.storage)
    try:
        if writer is not None:
            writer.set_custom_data("tissue_sim.source_bag", str(args.bag))
            writer.set_custom_data("tissue_sim.mode", args.mode)
        sink = ReplayBagSink(writer, sim, points_every=args.points_every) if writer is not None else None
        result = replay_steps(sim, steps.t_ns, steps.items(), sink=sink, snapshot_every=frame_every,
                              progress=not args.no_progress)
    finally:
        if writer is not None:
            writer.close()
    print(result.speed_line())
    write_outputs(out, sim, result, video=args.video, title=f"replay of {Path(args.bag).name} (applied)")
    (out / "replay.json").write_text(json.dumps({
        "bag": str(args.bag), "mode": args.mode, "params": cfg.flat(),
        "steps": result.n_steps, "steps_with_tool": sum(p is not None for p in steps.poses),
        "particles": sim.model.n_particles, "triangles": sim.model.n_triangles, "dt": sim.params.dt,
        "wall_s": result.wall_time, "real_time_factor": result.real_time_factor,
        "energy_final": float(result.rollout.scene_total[-1]) if result.rollout.steps.size else None,
    }, indent=2) + "\n")
    print(f"wrote {out}/energy.csv, energy.png, replay.json, frames/ ({len(result.rollout.snapshots)} PNG)"
          + (", replay_bag/" if writer is not None else "") + (", replay.mp4" if args.video else ""))
    return 0


def _write_summary(path: Path, args: argparse.Namespace, track: ToolTrack, sim: Simulation,
                   result: ReplayResult) -> None:
    """What was replayed, how, and how fast, as JSON (for scripts and reports)."""
    import json  # noqa: PLC0415

    ro = result.rollout
    summary = {
        "bag": str(args.bag), "mode": args.mode, "params": args.params,
        "tool_topic": track.topic, "tool_type": track.msgtype, "child_frame": track.child_frame,
        "twist_topic": track.twist_topic, "time_source": track.time_source,
        "samples": track.n, "samples_read": track.n_messages, "skipped": track.skipped,
        "track_duration_s": track.duration,
        "particles": sim.model.n_particles, "triangles": sim.model.n_triangles, "dt": sim.params.dt,
        "steps": result.n_steps, "simulated_s": result.sim_time, "wall_s": result.wall_time,
        "steps_per_s": result.steps_per_second, "real_time_factor": result.real_time_factor,
        "real_time_factor_median_step": result.median_real_time_factor,
        "real_time_factor_cpu": result.cpu_real_time_factor, "cpu_s": result.cpu_time,
        "median_step_ms": 1e3 * float(np.median(result.loop_times)) if result.loop_times.size else None,
        "energy_final": float(ro.scene_total[-1]) if ro.steps.size else None,
        "steps_in_contact": int(ro.in_contact.any(axis=1).sum()), "diverged_steps": int(ro.diverged.sum()),
    }
    path.write_text(json.dumps(summary, indent=2) + "\n")


def write_outputs(out: Path, sim: Simulation, result: ReplayResult, *, video: bool = False, title: str = "") -> None:
    """energy.csv, energy.png, frames/*.png (from the snapshots) and optionally replay.mp4 in ``out``."""
    from .. import render  # noqa: PLC0415

    ro = result.rollout
    ro.write_csv(out / "energy.csv")
    if ro.steps.size:
        render.plot_energy(out / "energy.png", ro.steps, {"inertial": ro.inertial, "spring": ro.spring, "area": ro.area},
                           contact=ro.in_contact, title=title)
    frames_dir = out / "frames"
    if frames_dir.exists():
        shutil.rmtree(frames_dir)
    frames_dir.mkdir()
    first = int(ro.steps[0]) - 1 if ro.steps.size else 0
    frames = []
    for step in sorted(ro.snapshots):
        row = step - first - 1
        pose = None
        if 0 <= row < ro.tool_pose.shape[0] and np.isfinite(ro.tool_pose[row]).all():
            pose = ToolPose(*map(float, ro.tool_pose[row]))
        path = frames_dir / f"frame_{step:05d}.png"
        render.save_frame(path, sim.model, ro.snapshots[step], tool=sim.tool, pose=pose,
                          title=f"step {step}  t = {step * sim.params.dt:.2f} s", size=4.0, dpi=80)
        frames.append(path)
    if video and frames:
        render.write_video(out / "replay.mp4", frames, fps=max(1.0, min(30.0, len(frames) / 4.0)))


def main() -> int:  # pragma: no cover - `python -m tissue_sim_ros.ros.replay`
    import sys  # noqa: PLC0415

    from ..cli import main as cli_main  # noqa: PLC0415

    return cli_main(["replay", *sys.argv[1:]])


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
