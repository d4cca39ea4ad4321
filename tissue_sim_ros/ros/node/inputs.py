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
from typing import Any

from geometry_msgs.msg import PoseStamped, TwistStamped
from rclpy.exceptions import InvalidHandle
from rclpy.time import Time
from sensor_msgs.msg import JointState

from ...core.contact.tool import ToolPose, ToolTwist, yaw_from_quaternion
from ...core.timing.frames import FrameLookupError
from ...core.timing.stamps import stamp_from_ns, stamp_to_seconds

TAKE_MAX = 10
"""Queued tool messages a tick takes at most per topic (the subscriptions keep 10 in timer mode)."""

#: Twists kept for lock-step's pairing by stamp: the lock-step input queue's depth (``qos.tool_input``).
TWIST_HISTORY = 1000


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


def stamp_now(node: Any) -> tuple[int, int]:
    """The node clock's time as a (sec, nanosec) stamp."""
    return stamp_from_ns(node.get_clock().now().nanoseconds)


class ToolInputs:
    """The subscriptions' callbacks and the newest accepted tool (:attr:`tool`).

    Parameters
    ----------
    node : TissueSimNode
        Its typed settings (``config.node``), clock, frames (``frames``),
        subscriptions (``sub_pose``, ``sub_twist``), recorder, warnings, the
        stepping loop's phase lock and, in lock-step, its step.
    """

    def __init__(self, node: Any) -> None:
        self.node = node
        self.tool = ToolInput()
        self._run: list[tuple[float, float]] = []
        """The rejected poses in a row, each within max_tool_jump of the one before (a relocated robot)."""

    def reset(self) -> None:
        """Forget the tool (``~/reset``): the next pose is accepted however far and whenever stamped."""
        self.tool = ToolInput()
        self._run = []

    def forget_stamps(self) -> None:
        """The node's clock switched: the last input stamps mean nothing on the new one."""
        self.tool.pose_stamp = self.tool.twist_stamp = self.tool.jaw_stamp = (0, 0)
        self.tool.twist_received = -math.inf
        self.tool.recent_twists.clear()
        self.tool.recent_jaws.clear()

    # ------------------------------------------------------------------ checks

    def check_header(self, topic: str, stamp: tuple[int, int], frame: str, last: tuple[int, int]) -> bool:
        """Frame, order and age of an input message; False (and counted) when it must be dropped."""
        node, settings, drop = self.node, self.node.config.node, self.node.warnings.drop
        if frame != settings.frame_id and not node.frames.knows(frame):
            drop("frame", f"{topic} in frame '{frame}': no transform from it to '{settings.frame_id}' is known "
                          f"(frames known: {', '.join(sorted(node.frames.buffer.frames)) or 'none'})")
            return False
        if stamp == (0, 0):
            return True  # unstamped: no order or age to check
        max_age, max_future = settings.max_stamp_age, settings.max_stamp_future
        now = node.get_clock().now()
        # a sim-time clock that has not received /clock yet reads 0: nothing to measure an age against
        if not settings.lock_step and (max_age > 0 or max_future > 0) and now.nanoseconds > 0:
            age = (now - Time(seconds=stamp[0], nanoseconds=stamp[1],
                              clock_type=node.get_clock().clock_type)).nanoseconds * 1e-9
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
        last = self.tool.pose if self.tool.pose is not None else self.node.sim.tool_pose
        if last is None:
            return True
        dist = math.hypot(x - last.x, y - last.y)
        max_jump = self.node.config.node.max_tool_jump
        if dist <= max_jump:
            self._run = []
            return True
        if self._run and math.hypot(x - self._run[-1][0], y - self._run[-1][1]) <= max_jump:
            self._run.append((x, y))
        else:
            self._run = [(x, y)]
        if self.relocation_due():
            return False  # not dropped: take_pose takes the stream up (relocate), or drops it if it cannot
        self.node.warnings.drop(
            "tool_jump", f"tool/pose ({x:.4g}, {y:.4g}) is {dist:.3f} m from the tool at ({last.x:.4g}, "
                         f"{last.y:.4g}) (max_tool_jump {max_jump} m): the tool holds its pose until a pose "
                         "within max_tool_jump of it arrives, or ~/reset")
        return False

    def relocation_due(self) -> bool:
        """A consistent stream of rejected poses (``relocate_poses`` in a row) while nothing is grasped."""
        need = self.node.config.node.relocate_poses
        return need > 0 and len(self._run) >= need and self.node.sim.grasp.n_held == 0

    def relocate(self, pose: ToolPose) -> bool:
        """Take up a relocated stream at ``pose`` (module docstring); False when the tool would land in the tissue."""
        node = self.node
        last = self.tool.pose if self.tool.pose is not None else node.sim.tool_pose
        self._run = []
        if node.sim.tool_overlaps_tissue(pose):
            node.warnings.drop("tool_jump", f"tool/pose ({pose.x:.4g}, {pose.y:.4g}): a stream of poses beyond "
                                            "max_tool_jump was not taken up: the tool there would overlap the tissue")
            return False
        node.sim.place_tool(pose)
        node.stats.relocations += 1
        node.warnings.warn("relocate", f"tool relocated from ({last.x:.4g}, {last.y:.4g}) to ({pose.x:.4g}, "
                                       f"{pose.y:.4g}): {node.config.node.relocate_poses} consistent poses beyond "
                                       f"max_tool_jump, nothing grasped ({node.stats.relocations} relocations)"
                           if last is not None else "tool relocated")
        return True

    # ------------------------------------------------------------------ callbacks

    def on_pose(self, msg: PoseStamped, info: dict[str, Any] | None = None) -> None:
        """A tool/pose message; ``info`` (rclpy's message info) gives its reception time to the phase lock."""
        node = self.node
        if node.config.node.lock_step:
            # the pose steps now: first every twist that arrived before it (the executor may run this callback
            # before the twist's, though the twist came first), and recorded before it in that order; the jaw too
            self.take_waiting(node.sub_twist)
            self.take_waiting(node.sub_jaw)
        if node.recorder is not None:
            node.recorder.write(node.sub_pose.topic_name, msg)  # as received, before any check
        p, o = msg.pose.position, msg.pose.orientation
        yaw = yaw_from_quaternion(o.x, o.y, o.z, o.w)
        if not all(math.isfinite(v) for v in (p.x, p.y, p.z)) or yaw is None:
            node.warnings.drop("nonfinite", "tool/pose with a NaN/inf value or a zero quaternion")
            return
        stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        received = info.get("received_timestamp") if info else None
        self.take_pose("tool/pose", stamp, msg.header.frame_id, (p.x, p.y, p.z), (o.x, o.y, o.z, o.w),
                       arrival_ns=received or None)

    def on_tool_transform(self, parent: str, stamp: tuple[int, int], translation: tuple[float, float, float],
                          rotation: tuple[float, float, float, float]) -> None:
        """A /tf transform of ``tool_frame``: the tool's pose in ``parent``."""
        self.take_pose(f"/tf {parent} -> {self.node.config.node.tool_frame}", stamp, parent, translation, rotation)

    def take_pose(self, topic: str, stamp: tuple[int, int], frame: str, position: tuple[float, float, float],
                  quaternion: tuple[float, float, float, float], arrival_ns: int | None = None) -> None:
        """Check a finite tool pose, take it into the plane, and use it (lock-step: step with it).

        ``arrival_ns``: when it was received (system clock) for the phase lock; None = now.
        """
        node, settings = self.node, self.node.config.node
        if not self.check_header(topic, stamp, frame, self.tool.pose_stamp):
            return
        x, y = position[0], position[1]
        if frame != settings.frame_id:
            try:
                x, y, quaternion = node.frames.pose_to_plane(frame, stamp, position, quaternion)
            except FrameLookupError as exc:
                node.warnings.drop("frame", f"{topic} in frame '{frame}': {exc}")
                return
        yaw = yaw_from_quaternion(*quaternion)
        if yaw is None:
            node.warnings.drop("nonfinite", f"{topic}: its orientation is not a rotation in '{settings.frame_id}'")
            return
        if not self.check_jump(x, y):
            if not (self.relocation_due() and self.relocate(ToolPose(x, y, yaw))):
                return
        self.tool.pose = ToolPose(x, y, yaw)
        self.tool.pose_stamp = stamp
        self.tool.quaternion = quaternion
        phase_lock = node.stepping.phase_lock
        if phase_lock is not None:
            phase_lock.arrival(arrival_ns if arrival_ns is not None else time.time_ns())
        if settings.lock_step and not node.paused:
            twist = self.tool.twist_at(stamp) if (settings.twist_source == "auto" and stamp != (0, 0)) else None
            node.stepping.step(stamp if stamp != (0, 0) else stamp_now(node), twist)

    def on_jaw(self, msg: JointState) -> None:
        """A tool/jaw message: ``position[0]`` is the jaw angle [rad] (the dVRK's ``jaw/measured_js``).

        Dropped and counted: no position (``jaw_empty``), a non-finite one (``nonfinite``), a frame_id that is
        neither empty, the plane's nor a known frame (``frame``), a stamp out of order or too old or new.
        """
        node = self.node
        if node.recorder is not None:
            node.recorder.write(node.sub_jaw.topic_name, msg)
        if len(msg.position) == 0:
            node.warnings.drop("jaw_empty", "tool/jaw with an empty position: expected position[0], the jaw angle "
                                            "in rad")
            return
        value = float(msg.position[0])
        if not math.isfinite(value):
            node.warnings.drop("nonfinite", f"tool/jaw with position[0]={value!r}: expected a finite angle in rad")
            return
        stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        frame = msg.header.frame_id
        if not self.check_header("tool/jaw", stamp, frame or self.node.config.node.frame_id, self.tool.jaw_stamp):
            return
        self.tool.jaw = value
        self.tool.jaw_stamp = stamp
        self.tool.keep_jaw(stamp, value)

    def on_twist(self, msg: TwistStamped) -> None:
        node = self.node
        if node.recorder is not None:
            node.recorder.write(node.sub_twist.topic_name, msg)
        v, w = msg.twist.linear, msg.twist.angular
        if not all(math.isfinite(x) for x in (v.x, v.y, v.z, w.x, w.y, w.z)):
            node.warnings.drop("nonfinite", "tool/twist with a NaN/inf value")
            return
        stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        if not self.check_header("tool/twist", stamp, msg.header.frame_id, self.tool.twist_stamp):
            return
        vx, vy, wz = v.x, v.y, w.z
        if msg.header.frame_id != node.config.node.frame_id:
            try:
                vx, vy, wz = node.frames.twist_to_plane(msg.header.frame_id, stamp, (v.x, v.y, v.z), (w.x, w.y, w.z))
            except FrameLookupError as exc:
                node.warnings.drop("frame", f"tool/twist in frame '{msg.header.frame_id}': {exc}")
                return
        self.tool.twist = ToolTwist(vx, vy, wz)
        self.tool.twist_stamp = stamp
        self.tool.twist_received = node.get_clock().now().nanoseconds * 1e-9
        self.tool.keep_twist(stamp, self.tool.twist)

    # ------------------------------------------------------------------ for the step

    def tool_for_step(self) -> tuple[ToolPose | None, ToolTwist | None]:
        """Timer mode: the pose to use this step and the twist (None: derive from poses)."""
        pose = self.tool.pose
        if pose is None:
            return None, None
        settings = self.node.config.node
        twist = None
        if settings.twist_source == "auto" and self.tool.twist is not None:
            age = self.node.get_clock().now().nanoseconds * 1e-9 - self.tool.twist_received
            if age <= settings.twist_timeout:
                twist = self.tool.twist
        return pose, twist

    def take_queued(self) -> None:
        """Take the tool messages already received before stepping (the executor runs a ready timer first)."""
        for sub in (self.node.sub_twist, self.node.sub_jaw, self.node.sub_pose):
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
            if sub is self.node.sub_pose:
                self.on_pose(*taken)
            elif sub is self.node.sub_jaw:
                self.on_jaw(taken[0])
            else:
                self.on_twist(taken[0])
