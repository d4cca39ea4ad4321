"""Offline replay: step the simulation on a bag's tool trajectory (the library behind ``tissue-sim replay``).

:func:`replay` steps :class:`~tissue_sim_ros.core.sim.simulation.Simulation` along a
:class:`~tissue_sim_ros.ros.bags.ToolTrack` (see :func:`schedule` for the two
modes); :class:`ReplayBagSink` writes each step's outputs into a bag with the
node's own :class:`~tissue_sim_ros.ros.messages.StepEncoder`; :func:`write_outputs`
writes the CSV, plot, frames and video. The command line is in
:mod:`tissue_sim_ros.cli.replay`, the job (files, summary) in :mod:`tissue_sim_ros.experiments.replay`. Three modes (:func:`schedule`): ``per-message``, ``fixed-rate``, and ``applied``: a bag the node recorded
itself, stepped with the pose and twist the node used at each step (``tool/applied_pose``,
``tool/applied_twist``), so a timer-mode run is reproduced bit for bit. Instead of a bag, :func:`track_from_trajectory` turns a trajectory given as
data (:mod:`tissue_sim_ros.core.timing.trajectories`) into the samples, one step each.
No ROS graph and no rclpy: this runs anywhere
the core runs.
"""
from __future__ import annotations

import math
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core.contact.tool import ToolPose, ToolTwist, Trajectory
from ..core.errors import InputError
from ..core.series import rollout_terms
from ..core.sim.rollout import Rollout, rollout
from ..core.sim.simulation import Simulation, StepReport
from ..core.timing.stamps import ns_from_seconds, stamp_from_ns
from . import messages as msgs
from .bags import BagWriter, ToolTrack

MODES = ("per-message", "fixed-rate", "applied")

#: Output topics of the replay bag: the tool pose used and the node's step outputs but the markers
#: (msg_docs/topics.md), encoded by the node's own :class:`~.messages.StepEncoder`.
OUTPUT_TOPICS: dict[str, str] = {
    "/tool/pose": "geometry_msgs/msg/PoseStamped",
    **{f"/{topic}": msgtype for topic, msgtype in msgs.STEP_TOPICS.items() if topic != "tissue/markers"},
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


def track_from_trajectory(traj: Trajectory, dt: float, name: str = "trajectory") -> ToolTrack:
    """A ToolTrack of a trajectory's steps: sample k (k = 1..K) is the pose at the end of step k and the
    pose change over it / dt, at t = start + k dt, so per-message replay steps exactly as an offline rollout."""
    cmds = list(traj.steps(dt))
    if not cmds:
        raise InputError(f"trajectory {name!r} lasts {traj.duration} s: shorter than one step of dt={dt} s")
    t0 = int(round(traj.start_time * 1e9))
    t_ns = t0 + np.round(np.arange(1, len(cmds) + 1) * dt * 1e9).astype(np.int64)
    pose = np.array([p.as_array() for p, _ in cmds])
    twist = np.array([(tw.vx, tw.vy, tw.wz) for _, tw in cmds], dtype=np.float64)
    return ToolTrack(t_ns=t_ns, pose=pose, twist=twist, topic=f"trajectory {name}", msgtype="trajectory",
                     twist_topic=f"trajectory {name}", twist_t_ns=t_ns.copy(), n_messages=len(cmds))


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
    dt_ns = ns_from_seconds(dt)
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
        self._log_ns = -1
        self.encoder = msgs.StepEncoder(sim.model, sim.tool)
        grasp = {f"/{t}": m for t, m in msgs.GRASP_TOPICS.items()} if self.encoder.grasper else {}
        for name, msgtype in {**OUTPUT_TOPICS, **grasp}.items():
            writer.add_topic(name, msgtype)

    def __call__(self, report: StepReport, t_ns: int, pose: ToolPose | None) -> None:
        stamp = stamp_from_ns(t_ns)
        self._n += 1
        out = self.encoder.encode(stamp, self.frame_id, report, self.sim.state.particle_q,
                                  points=self._n % self.points_every == 0)
        # written at the step's stamp, kept increasing: stamps that jump back (a node that began following a
        # played /clock) must not reorder the steps for a reader, which sorts by these times
        log_ns = self._log_ns = max(t_ns, self._log_ns + 1)
        items = [] if pose is None else [
            ("/tool/pose", msgs.encode_pose_stamped(stamp, self.frame_id, pose.x, pose.y, pose.yaw), log_ns)]
        items += [(f"/{topic}", data, log_ns) for topic, data in out.messages.items()]
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


def replay_steps(sim: Simulation, t_ns: np.ndarray, items: list[tuple], *,
                 sink: Any = None, snapshot_every: int = 0, progress: bool = True,
                 track_duration: float | None = None, before_step: Any = None) -> ReplayResult:
    """Step ``sim`` once per (pose or None, twist or None[, jaw]) of ``items``, at times ``t_ns``; see :func:`replay`.

    ``before_step(item)``, when given, runs just before each step (the applied replay's relocations)."""
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
        def stepped():
            for item in items:
                if before_step is not None:
                    before_step(item)
                yield item

        result = rollout(sim, stepped(), snapshot_steps=[sim.step_count + s for s in snaps], on_step=on_step)
    finally:
        bar.close()
    wall = time.perf_counter() - start
    cpu = time.process_time() - cpu_start
    if track_duration is None:
        track_duration = float(t_ns[-1] - t_ns[0]) * 1e-9 if n else 0.0
    return ReplayResult(rollout=result, t_ns=t_ns, wall_time=wall, step_time=step_time, loop_times=loop_times,
                        cpu_time=cpu, sim_time=n * sim.params.dt, track_duration=track_duration)


def write_outputs(out: Path, sim: Simulation, result: ReplayResult, *, video: bool = False, title: str = "") -> None:
    """energy.csv, energy.png, frames/*.png (from the snapshots) and optionally replay.mp4 in ``out``."""
    from .. import render  # noqa: PLC0415

    ro = result.rollout
    ro.write_csv(out / "energy.csv")
    if ro.steps.size:
        render.plot_energy(out / "energy.png", ro.steps, rollout_terms(ro), body_names=sim.model.body_names,
                           contact=ro.in_contact, title=title, ylabel=render.energy_label(sim.params))
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
