"""The node's tool inputs: ``tool/pose``, ``tool/twist``, ``tool/jaw`` and the tool's /tf frame, checked and taken
into the plane.

A message is checked (finite values, a known frame, its stamp's order and age,
no jump farther than ``max_tool_jump``), taken into the plane's frame
(:class:`~tissue_sim_ros.ros.tf_input.FrameInput`) and kept as the newest
tool; a bad one is dropped and counted (``dropped_*`` on /diagnostics) with a
throttled warning. In lock-step every accepted pose is one step, paired with
the twist of its own stamp among those that arrived before it, and with the jaw angle (``tool/jaw``,
sensor_msgs/JointState ``position[0]`` [rad]) stamped last at or before it among those that arrived before it
(unstamped jaws: the newest received); timer mode steps with the newest jaw.

A relocated robot (``relocate_poses``): poses farther than ``max_tool_jump`` from the tool are rejected, but
when the tool grasps nothing and ``relocate_poses`` of them in a row each lie within ``max_tool_jump`` of the
one before, the stream is taken up: the tool is put at the newest one without a step (the simulation's
``place_tool``: no sweep, so it drags nothing across and never passes through the tissue), unless the tool
there would overlap the tissue (``Simulation.tool_overlaps_tissue``), in which case the poses go on being
rejected. A throttled warning says so and ``relocations`` on /diagnostics counts it; ``~/reset`` is unchanged.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable

from geometry_msgs.msg import PoseStamped, TwistStamped
from rclpy.exceptions import InvalidHandle
from rclpy.time import Time
from sensor_msgs.msg import JointState

from ...core.contact.tool import ToolPose, ToolTwist, yaw_from_quaternion
from ...core.errors import InputError
from ...core.timing.frames import FrameLookupError
from ...core.timing.stamps import stamp_from_ns, stamp_to_seconds
from .. import qos
from ..tool_applied import planar_quaternion

TAKE_MAX = 10
"""Queued tool messages a tick takes at most per topic (the subscriptions keep 10 in timer mode)."""

#: Twists kept for lock-step's pairing by stamp: the lock-step input queue's depth (``qos.tool_input``).
TWIST_HISTORY = 1000


@dataclass
class StepTool:
    """What a step takes from the inputs: the pose (None: no tool yet), the twist (None: derived from the poses),
    the quaternion the pose's yaw came from, the jaw angle (None: the simulation keeps its own) and the pose's
    stamp (the tool marker's)."""

    pose: ToolPose | None
    twist: ToolTwist | None
    quaternion: tuple[float, float, float, float]
    jaw: float | None
    pose_stamp: tuple[int, int]


@dataclass
class ToolInput:
    """The newest accepted tool pose and twist."""

    pose: ToolPose | None = None
    pose_stamp: tuple[int, int] = (0, 0)
    quaternion: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    """The orientation the pose's yaw was computed from (published on tool/applied_pose)."""
    twist: ToolTwist | None = None
    twist_stamp: tuple[int, int] = (0, 0)
    twist_received: float = -math.inf
    """Node-clock time the twist arrived [s]."""
    jaw: float | None = None
    """The newest accepted jaw angle [rad] (None: none yet; the grasper counts as open)."""
    at_start: bool = False
    """The pose is the start pose (``tool_start_*``): no tool pose taken yet."""
    jaw_stamp: tuple[int, int] = (0, 0)
    recent_jaws: list = field(default_factory=list)
    """The newest accepted jaws as (stamp, angle), oldest first (at most ``TWIST_HISTORY``): lock-step gives a
    pose the jaw of its time, however the two topics' messages interleave on arrival."""

    def jaw_at(self, stamp: tuple[int, int]) -> float | None:
        """The jaw angle for a lock-step pose stamped ``stamp``: the last accepted jaw stamped at or before it;
        the newest one when the pose or a jaw is unstamped; None (the simulation keeps its jaw) when every
        jaw is stamped later."""
        if stamp == (0, 0) or any(s == (0, 0) for s, _ in self.recent_jaws):
            return self.jaw
        for s, value in reversed(self.recent_jaws):
            if s <= stamp:
                return value
        return None

    def keep_jaw(self, stamp: tuple[int, int], value: float) -> None:
        self.recent_jaws.append((stamp, value))
        if len(self.recent_jaws) > TWIST_HISTORY:
            del self.recent_jaws[0]
    recent_twists: dict = field(default_factory=dict)
    """The newest accepted twists by stamp (at most ``TWIST_HISTORY``, oldest forgotten first): lock-step pairs a
    pose with the twist of its own stamp among those that arrived before it, as ``tissue-sim replay`` does,
    however many came in between (a burst queues up to 1000 poses and twists, and the pose's callback takes the
    waiting twists first)."""

    def twist_at(self, stamp: tuple[int, int]) -> ToolTwist | None:
        """The accepted twist stamped ``stamp``, or None."""
        return self.recent_twists.get(stamp)

    def keep_twist(self, stamp: tuple[int, int], twist: ToolTwist) -> None:
        self.recent_twists[stamp] = twist
        while len(self.recent_twists) > TWIST_HISTORY:
            del self.recent_twists[next(iter(self.recent_twists))]


def stamp_now(clock: Any) -> tuple[int, int]:
    """The clock's time as a (sec, nanosec) stamp."""
    return stamp_from_ns(clock.now().nanoseconds)


class ToolInputs:
    """The subscriptions' callbacks and the newest accepted tool (:attr:`tool`).

    Parameters
    ----------
    config : CurrentConfig
        The node's settings (``config.node``), read at each message.
    sim : Simulation
        Its tool (a pose's jump is measured from it) and, for a relocation, ``place_tool``.
    clock : rclpy Clock
        The node's clock (stamps' ages, a twist's arrival).
    stats, warnings
        Relocations are counted, dropped messages counted and warned about.
    frames : FrameInput
        Messages in other frames are taken into the plane's.
    phase_lock : PhaseLock or None
        Timer mode: each accepted pose's arrival (lock-step: None).
    step : callable
        Lock-step: ``step(stamp, twist)`` steps with the pose just accepted.
    subscribe : callable
        Makes a subscription (the node's ``create_subscription``): ``tool/pose``, ``tool/twist``, ``tool/jaw``.
    record : callable, optional
        ``record(topic, message)`` of every message as received (the node's bag).
    start : ToolPose, optional
        The tool's start pose (``tool_start_*``): the tool is put there now and after each :meth:`reset`, and the
        first tool pose is taken where it lies (:meth:`take_up`).
    """

    def __init__(self, config: Any, sim: Any, clock: Any, stats: Any, warnings: Any, frames: Any,
                 phase_lock: Any, step: Callable[[tuple[int, int], ToolTwist | None], None],
                 subscribe: Callable[..., Any], record: Callable[[str, Any], None] | None = None,
                 start: ToolPose | None = None) -> None:
        self.config, self.sim, self.clock, self.stats, self.warnings = config, sim, clock, stats, warnings
        self.frames, self.phase_lock, self._step, self._record = frames, phase_lock, step, record
        self.start = start
        if start is not None and sim.tool_overlaps_tissue(start):
            raise InputError(f"parameters tool_start_x={start.x!r}, tool_start_y={start.y!r}, tool_start_yaw="
                             f"{start.yaw!r}: the tool there overlaps the tissue; expected a start pose clear of it")
        self.reset()
        depth = qos.tool_input(config.node.lock_step)
        # the pose with its message info: its reception time is the pose's arrival for the phase lock
        self.sub_pose = subscribe(PoseStamped, "tool/pose", lambda msg, info: self.on_pose(msg, info), depth)
        self.sub_twist = subscribe(TwistStamped, "tool/twist", self.on_twist, depth)
        self.sub_jaw = subscribe(JointState, "tool/jaw", self.on_jaw, depth)

    @property
    def subscriptions(self) -> tuple[Any, Any, Any]:
        return self.sub_pose, self.sub_twist, self.sub_jaw

    def reset(self) -> None:
        """Forget the tool (``~/reset``): the next pose is accepted however far and whenever stamped; with a start
        pose the tool is put back there (the simulation's ``place_tool``: no step)."""
        self.tool = ToolInput()
        self._run: list[tuple[float, float]] = []
        """The rejected poses in a row, each within max_tool_jump of the one before (a relocated robot)."""
        if self.start is not None:
            self.tool.pose, self.tool.at_start = self.start, True
            self.tool.quaternion = planar_quaternion(self.start.yaw)
            self.sim.place_tool(self.start)

    def forget_stamps(self) -> None:
        """The node's clock switched: the last input stamps mean nothing on the new one."""
        self.tool.pose_stamp = self.tool.twist_stamp = self.tool.jaw_stamp = (0, 0)
        self.tool.twist_received = -math.inf
        self.tool.recent_twists.clear()
        self.tool.recent_jaws.clear()

    # ------------------------------------------------------------------ checks

    def check_header(self, topic: str, stamp: tuple[int, int], frame: str, last: tuple[int, int]) -> bool:
        """Frame, order and age of an input message; False (and counted) when it must be dropped."""
        settings, drop = self.config.node, self.warnings.drop
        if frame != settings.frame_id and not self.frames.knows(frame):
            drop("frame", f"{topic} in frame '{frame}': no transform from it to '{settings.frame_id}' is known "
                          f"(frames known: {', '.join(sorted(self.frames.buffer.frames)) or 'none'})")
            return False
        if stamp == (0, 0):
            return True  # unstamped: no order or age to check
        max_age, max_future = settings.max_stamp_age, settings.max_stamp_future
        now = self.clock.now()
        # a sim-time clock that has not received /clock yet reads 0: nothing to measure an age against
        if not settings.lock_step and (max_age > 0 or max_future > 0) and now.nanoseconds > 0:
            age = (now - Time(seconds=stamp[0], nanoseconds=stamp[1],
                              clock_type=self.clock.clock_type)).nanoseconds * 1e-9
            if max_age > 0 and age > max_age:
                drop("stale", f"{topic} is {age:.3f} s old (max_stamp_age {max_age} s)")
                return False
            # a stamp from the future would make every later message look out of order until
            # the clock catches up: the tool would freeze, so it is the message that goes
            if max_future > 0 and -age > max_future:
                drop("future", f"{topic} is stamped {-age:.3f} s in the future (max_stamp_future {max_future} s)")
                return False
        if last != (0, 0) and stamp <= last:
            drop("out_of_order", f"{topic} stamped {stamp_to_seconds(stamp):.6f} s, not after the "
                                 f"previous {stamp_to_seconds(last):.6f} s")
            return False
        return True

    def check_jump(self, x: float, y: float) -> bool:
        """False (and counted) when a pose lies farther than max_tool_jump from the tool's last accepted pose.

        The tool then holds its pose; it follows again once a pose within
        max_tool_jump of it arrives, or after ~/reset (when any pose is accepted).
        """
        last = self.tool.pose if self.tool.pose is not None else self.sim.tool_pose
        if last is None:
            return True
        dist = math.hypot(x - last.x, y - last.y)
        max_jump = self.config.node.max_tool_jump
        if dist <= max_jump:
            self._run = []
            return True
        if self._run and math.hypot(x - self._run[-1][0], y - self._run[-1][1]) <= max_jump:
            self._run.append((x, y))
        else:
            self._run = [(x, y)]
        if self.relocation_due():
            return False  # not dropped: take_pose takes the stream up (relocate), or drops it if it cannot
        self.warnings.drop(
            "tool_jump", f"tool/pose ({x:.4g}, {y:.4g}) is {dist:.3f} m from the tool at ({last.x:.4g}, "
                         f"{last.y:.4g}) (max_tool_jump {max_jump} m): the tool holds its pose until a pose "
                         "within max_tool_jump of it arrives, or ~/reset")
        return False

    def near(self, x: float, y: float) -> bool:
        """Whether (x, y) lies within max_tool_jump of the tool's pose."""
        pose = self.tool.pose
        return pose is not None and math.hypot(x - pose.x, y - pose.y) <= self.config.node.max_tool_jump

    def take_up(self, pose: ToolPose) -> bool:
        """The first tool pose after the start pose, farther than max_tool_jump from it: the tool is put there
        without a step (as a relocation is), unless it would overlap the tissue there (dropped, counted)."""
        if self.sim.tool_overlaps_tissue(pose):
            self.warnings.drop("tool_jump", f"tool/pose ({pose.x:.4g}, {pose.y:.4g}): the tool there would overlap "
                                            "the tissue; it stays at its start pose")
            return False
        self.sim.place_tool(pose)
        return True

    def relocation_due(self) -> bool:
        """A consistent stream of rejected poses (``relocate_poses`` in a row) while nothing is grasped."""
        need = self.config.node.relocate_poses
        return need > 0 and len(self._run) >= need and self.sim.grasp.n_held == 0

    def relocate(self, pose: ToolPose) -> bool:
        """Take up a relocated stream at ``pose`` (module docstring); False when the tool would land in the tissue."""
        last = self.tool.pose if self.tool.pose is not None else self.sim.tool_pose
        self._run = []
        if self.sim.tool_overlaps_tissue(pose):
            self.warnings.drop("tool_jump", f"tool/pose ({pose.x:.4g}, {pose.y:.4g}): a stream of poses beyond "
                                            "max_tool_jump was not taken up: the tool there would overlap the tissue")
            return False
        self.sim.place_tool(pose)
        self.stats.relocations += 1
        self.warnings.warn("relocate", f"tool relocated from ({last.x:.4g}, {last.y:.4g}) to ({pose.x:.4g}, "
                                       f"{pose.y:.4g}): {self.config.node.relocate_poses} consistent poses beyond "
                                       f"max_tool_jump, nothing grasped ({self.stats.relocations} relocations)"
                           if last is not None else "tool relocated")
        return True

    # ------------------------------------------------------------------ callbacks

    def _keep(self, sub: Any, msg: Any) -> None:
        if self._record is not None:
            self._record(sub.topic_name, msg)  # as received, before any check

    def on_pose(self, msg: PoseStamped, info: dict[str, Any] | None = None) -> None:
        """A tool/pose message; ``info`` (rclpy's message info) gives its reception time to the phase lock."""
        if self.config.node.lock_step:
            # the pose steps now: first every twist that arrived before it (the executor may run this callback
            # before the twist's, though the twist came first), and recorded before it in that order; the jaw too
            self.take_waiting(self.sub_twist)
            self.take_waiting(self.sub_jaw)
        self._keep(self.sub_pose, msg)
        p, o = msg.pose.position, msg.pose.orientation
        yaw = yaw_from_quaternion(o.x, o.y, o.z, o.w)
        if not all(math.isfinite(v) for v in (p.x, p.y, p.z)) or yaw is None:
            self.warnings.drop("nonfinite", "tool/pose with a NaN/inf value or a zero quaternion")
            return
        stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        received = info.get("received_timestamp") if info else None
        self.take_pose("tool/pose", stamp, msg.header.frame_id, (p.x, p.y, p.z), (o.x, o.y, o.z, o.w),
                       arrival_ns=received or None)

    def on_tool_transform(self, parent: str, stamp: tuple[int, int], translation: tuple[float, float, float],
                          rotation: tuple[float, float, float, float]) -> None:
        """A /tf transform of ``tool_frame``: the tool's pose in ``parent``."""
        self.take_pose(f"/tf {parent} -> {self.config.node.tool_frame}", stamp, parent, translation, rotation)

    def take_pose(self, topic: str, stamp: tuple[int, int], frame: str, position: tuple[float, float, float],
                  quaternion: tuple[float, float, float, float], arrival_ns: int | None = None) -> None:
        """Check a finite tool pose, take it into the plane, and use it (lock-step: step with it).

        ``arrival_ns``: when it was received (system clock) for the phase lock; None = now.
        """
        settings = self.config.node
        if not self.check_header(topic, stamp, frame, self.tool.pose_stamp):
            return
        x, y = position[0], position[1]
        if frame != settings.frame_id:
            try:
                x, y, quaternion = self.frames.pose_to_plane(frame, stamp, position, quaternion)
            except FrameLookupError as exc:
                self.warnings.drop("frame", f"{topic} in frame '{frame}': {exc}")
                return
        yaw = yaw_from_quaternion(*quaternion)
        if yaw is None:
            self.warnings.drop("nonfinite", f"{topic}: its orientation is not a rotation in '{settings.frame_id}'")
            return
        if self.tool.at_start and not self.near(x, y):
            if not self.take_up(ToolPose(x, y, yaw)):
                return
        elif not self.check_jump(x, y):
            if not (self.relocation_due() and self.relocate(ToolPose(x, y, yaw))):
                return
        self.tool.at_start = False
        self.tool.pose = ToolPose(x, y, yaw)
        self.tool.pose_stamp = stamp
        self.tool.quaternion = quaternion
        if self.phase_lock is not None:
            self.phase_lock.arrival(arrival_ns if arrival_ns is not None else time.time_ns())
        if settings.lock_step and not settings.paused:
            twist = self.tool.twist_at(stamp) if (settings.twist_source == "auto" and stamp != (0, 0)) else None
            self._step(stamp if stamp != (0, 0) else stamp_now(self.clock), twist)

    def on_jaw(self, msg: JointState) -> None:
        """A tool/jaw message: ``position[0]`` is the jaw angle [rad] (the dVRK's ``jaw/measured_js``).

        Dropped and counted: no position (``jaw_empty``), a non-finite one (``nonfinite``), a frame_id that is
        neither empty, the plane's nor a known frame (``frame``), a stamp out of order or too old or new.
        """
        self._keep(self.sub_jaw, msg)
        if len(msg.position) == 0:
            self.warnings.drop("jaw_empty", "tool/jaw with an empty position: expected position[0], the jaw angle "
                                            "in rad")
            return
        value = float(msg.position[0])
        if not math.isfinite(value):
            self.warnings.drop("nonfinite", f"tool/jaw with position[0]={value!r}: expected a finite angle in rad")
            return
        stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        frame = msg.header.frame_id
        if not self.check_header("tool/jaw", stamp, frame or self.config.node.frame_id, self.tool.jaw_stamp):
            return
        self.tool.jaw = value
        self.tool.jaw_stamp = stamp
        self.tool.keep_jaw(stamp, value)

    def on_twist(self, msg: TwistStamped) -> None:
        self._keep(self.sub_twist, msg)
        v, w = msg.twist.linear, msg.twist.angular
        if not all(math.isfinite(x) for x in (v.x, v.y, v.z, w.x, w.y, w.z)):
            self.warnings.drop("nonfinite", "tool/twist with a NaN/inf value")
            return
        stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        if not self.check_header("tool/twist", stamp, msg.header.frame_id, self.tool.twist_stamp):
            return
        vx, vy, wz = v.x, v.y, w.z
        if msg.header.frame_id != self.config.node.frame_id:
            try:
                vx, vy, wz = self.frames.twist_to_plane(msg.header.frame_id, stamp, (v.x, v.y, v.z), (w.x, w.y, w.z))
            except FrameLookupError as exc:
                self.warnings.drop("frame", f"tool/twist in frame '{msg.header.frame_id}': {exc}")
                return
        self.tool.twist = ToolTwist(vx, vy, wz)
        self.tool.twist_stamp = stamp
        self.tool.twist_received = self.clock.now().nanoseconds * 1e-9
        self.tool.keep_twist(stamp, self.tool.twist)

    # ------------------------------------------------------------------ for the step

    def tool_for_step(self, from_timer: bool, stamp: tuple[int, int]) -> StepTool:
        """The tool a step uses: timer mode the newest pose, jaw and (within ``twist_timeout``) twist; lock-step
        the pose just taken and the jaw of its time (the twist is paired by stamp in :meth:`take_pose`)."""
        tool, settings = self.tool, self.config.node
        twist = None
        if from_timer and tool.pose is not None and settings.twist_source == "auto" and tool.twist is not None:
            age = self.clock.now().nanoseconds * 1e-9 - tool.twist_received
            if age <= settings.twist_timeout:
                twist = tool.twist
        jaw = tool.jaw if from_timer else tool.jaw_at(stamp)
        return StepTool(tool.pose, twist, tool.quaternion, jaw, tool.pose_stamp)

    def take_queued(self) -> None:
        """Take the tool messages already received before stepping (the executor runs a ready timer first)."""
        for sub in (self.sub_twist, self.sub_jaw, self.sub_pose):
            self.take_waiting(sub)

    def take_waiting(self, sub: Any) -> None:
        """Run ``sub``'s callback on the messages it has received and the executor has not handed out yet."""
        for _ in range(TAKE_MAX):
            try:
                with sub.handle:
                    taken = sub.handle.take_message(sub.msg_type, sub.raw)
            except InvalidHandle:
                return
            if taken is None:
                return
            if sub is self.sub_pose:
                self.on_pose(*taken)
            elif sub is self.sub_jaw:
                self.on_jaw(taken[0])
            else:
                self.on_twist(taken[0])
