"""The tool the node applied at each step: ``tool/applied_pose`` and ``tool/applied_twist``, and reading them back.

Every step the node publishes (and, with ``record_path``, records) the tool it
stepped with, stamped with the step's stamp (the stamp of that step's
tissue/points and tool/wrench):

* ``tool/applied_twist`` (TwistStamped) on every step: the velocity the contact
  model used, whether it came from ``tool/twist`` or was derived from poses
  (zero when there is no tool);
* ``tool/applied_pose`` (PoseStamped) on every step that had a tool: its
  position and the orientation quaternion the yaw was computed from, so that
  an offline replay computes the very same yaw from it;
* ``tool/applied_jaw`` (JointState; a grasper only) on every step: ``position[0]`` the jaw angle the step
  used [rad] (empty before any ``tool/jaw``).

A relocation (the node put the tool at a pose of a stream beyond ``max_tool_jump``, without a step) shows in
the applied poses as a step farther than ``max_tool_jump`` from the one before; the replay puts the tool there
first, as the node did (:func:`applied_items`).

:func:`read_applied_steps` turns a bag of those two topics back into one
(pose or None, twist) per step; ``tissue-sim replay --mode applied`` steps
the library with exactly those values, which reproduces a timer-mode run bit
for bit (the node passes the same values to the same
:meth:`Simulation.step <tissue_sim_ros.core.sim.simulation.Simulation.step>`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.contact.tool import ToolPose, ToolTwist, yaw_from_quaternion
from ..core.errors import InputError
from .messages import (
    Stamp,
    decode_joint_state,
    decode_pose_stamped,
    decode_twist_stamped,
    encode_joint_state,
    pose_stamped,
    twist_stamped,
)

POSE_TOPIC = "/tool/applied_pose"
TWIST_TYPE = "geometry_msgs/msg/TwistStamped"
TWIST_TOPIC = "/tool/applied_twist"
POSE_TYPE = "geometry_msgs/msg/PoseStamped"
JAW_TOPIC = "/tool/applied_jaw"
JAW_TYPE = "sensor_msgs/msg/JointState"

PLANAR = (0.0, 0.0, 0.0, 1.0)


def planar_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation about +z by ``yaw`` [rad]."""
    return 0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw)


def encode_applied_pose(stamp: Stamp, frame_id: str, x: float, y: float,
                        quaternion: tuple[float, float, float, float]) -> bytes:
    """geometry_msgs/PoseStamped: the tool's position in the plane (z = 0) and the quaternion its yaw came from."""
    return pose_stamped(stamp, frame_id, (x, y, 0.0), quaternion)


def encode_applied_twist(stamp: Stamp, frame_id: str, twist: ToolTwist) -> bytes:
    """geometry_msgs/TwistStamped: linear (vx, vy, 0) [m/s], angular (0, 0, wz) [rad/s]."""
    return twist_stamped(stamp, frame_id, (twist.vx, twist.vy, 0.0), (0.0, 0.0, twist.wz))


def encode_applied_jaw(stamp: Stamp, frame_id: str, jaw: float | None) -> bytes:
    """sensor_msgs/JointState: one joint ``jaw``, ``position[0]`` the jaw angle [rad]; no position: none given."""
    return encode_joint_state(stamp, frame_id, ["jaw"], [] if jaw is None else [jaw])


def decode_applied_jaw(data: bytes) -> tuple[Stamp, float | None]:
    stamp, _, _, positions = decode_joint_state(data)
    return stamp, (float(positions[0]) if positions.size else None)


def decode_applied_pose(data: bytes) -> tuple[Stamp, ToolPose]:
    stamp, _, (x, y, _z), (qx, qy, qz, qw) = decode_pose_stamped(data)
    yaw = yaw_from_quaternion(qx, qy, qz, qw)
    if yaw is None:
        raise InputError(f"{POSE_TOPIC} stamped {stamp}: not a rotation ({qx}, {qy}, {qz}, {qw})")
    return stamp, ToolPose(float(x), float(y), yaw)


def decode_applied_twist(data: bytes) -> tuple[Stamp, ToolTwist]:
    stamp, _, (vx, vy, _vz), (_wx, _wy, wz) = decode_twist_stamped(data)
    return stamp, ToolTwist(float(vx), float(vy), float(wz))


@dataclass
class AppliedSteps:
    """The node's steps as recorded: one entry per step, in order."""

    t_ns: np.ndarray
    """Step stamp [ns], shape (S,), int64."""
    poses: list[ToolPose | None]
    twists: list[ToolTwist]
    twist_topic: str = TWIST_TOPIC
    pose_topic: str = POSE_TOPIC
    jaws: list[float | None] | None = None
    """The jaw angle of each step [rad] (a grasper's recording; None: no ``tool/applied_jaw`` in the bag)."""

    @property
    def n(self) -> int:
        return int(self.t_ns.shape[0])

    def items(self) -> list[tuple]:
        """(pose, twist) per step, or (pose, twist, jaw) with the jaw recorded."""
        if self.jaws is None:
            return list(zip(self.poses, self.twists))
        return list(zip(self.poses, self.twists, self.jaws))


def relocations(sim, max_tool_jump: float):
    """A ``before_step`` for :func:`~tissue_sim_ros.ros.replay.replay_steps`: puts the tool at a step's pose first
    (``place_tool``) when it lies farther than ``max_tool_jump`` [m] from the simulation's tool: the node took a
    relocated stream up there without a step (``ros/node/inputs.py``), so the step that follows starts from it."""

    def before_step(item: tuple) -> None:
        pose, last = item[0], sim.tool_pose
        if pose is not None and last is not None and math.hypot(pose.x - last.x, pose.y - last.y) > max_tool_jump:
            sim.place_tool(pose)

    return before_step


def read_applied_steps(path: str | Path, namespace: str | None = None) -> AppliedSteps:
    """The (pose or None, twist) of each step from a bag with the node's ``tool/applied_*`` topics.

    ``namespace``: the node's namespace (``/left`` for ``/left/tool/applied_twist``); None: the one
    ``.../tool/applied_twist`` topic in the bag.
    """
    from .bags import Bag  # noqa: PLC0415  (rosbags: only when reading)

    bag = Bag(path)
    try:
        if namespace is None:
            found = sorted(t for t in bag.topics if t.endswith(TWIST_TOPIC))
            if len(found) > 1:
                raise InputError(f"bag {str(path)!r} holds several nodes' applied tools ({', '.join(found)}): "
                                 "name the node's namespace")
            namespace = found[0][:-len(TWIST_TOPIC)] if found else ""
        pose_topic, twist_topic = namespace.rstrip("/") + POSE_TOPIC, namespace.rstrip("/") + TWIST_TOPIC
        if twist_topic not in bag.topics:
            raise InputError(f"bag {str(path)!r} has no {twist_topic}: it is not a recording of the node's applied "
                             f"tool (record with the node's record_path); it has: {bag.describe_topics()}")
        # the node writes each step's pose (when it had a tool), then its twist, but a recorder in another process
        # receives the topics on separate subscriptions: a pose can arrive after its twist, or two poses before
        # their twists (on a busy machine). So the steps are the twists in order, and a pose or jaw belongs to the
        # twist with its stamp. Stamps need not increase (a node that starts following /clock jumps to the bag's
        # time), so when a stamp recurs, the step whose twist arrived nearest in time takes it
        jaw_topic = namespace.rstrip("/") + JAW_TOPIC
        steps: list[tuple[Stamp, ToolTwist]] = []
        received: list[int] = []
        extras: dict[str, dict[Stamp, list[tuple[int, object]]]] = {pose_topic: {}, jaw_topic: {}}
        topics = [twist_topic] + [t for t in (pose_topic, jaw_topic) if t in bag.topics]
        has_jaw = jaw_topic in bag.topics
        for topic, _, t_ns, raw in bag.messages(topics):
            data = bytes(raw)
            if topic == twist_topic:
                steps.append(decode_applied_twist(data))
                received.append(t_ns)
            else:
                stamp, value = (decode_applied_pose if topic == pose_topic else decode_applied_jaw)(data)
                extras[topic].setdefault(stamp, []).append((t_ns, value))
    finally:
        bag.close()
    if not steps:
        raise InputError(f"bag {str(path)!r}: {twist_topic} holds no messages")
    poses = _by_stamp(steps, received, extras[pose_topic])
    jaws = _by_stamp(steps, received, extras[jaw_topic]) if has_jaw else None
    t_ns = np.array([s * 1_000_000_000 + ns for (s, ns), _ in steps], dtype=np.int64)
    return AppliedSteps(t_ns=t_ns, poses=poses, twists=[tw for _, tw in steps], twist_topic=twist_topic,
                        pose_topic=pose_topic, jaws=jaws)


def _by_stamp(steps: list[tuple[Stamp, ToolTwist]], received: list[int],
              values: dict[Stamp, list[tuple[int, object]]]) -> list:
    """Each step's value of ``values`` (stamp -> [(receive time, value)], in arrival order), or None.

    A stamp's values go to the steps of that stamp in order when there are as many as steps; otherwise (a stamp
    that recurs, with a step that had no tool) each value goes to the free step whose twist arrived nearest it."""
    out: list = [None] * len(steps)
    by_stamp: dict[Stamp, list[int]] = {}
    for i, (stamp, _) in enumerate(steps):
        by_stamp.setdefault(stamp, []).append(i)
    for stamp, found in values.items():
        idx = by_stamp.get(stamp, [])
        if len(found) == len(idx):
            for i, (_, value) in zip(idx, found):
                out[i] = value
            continue
        free = list(idx)
        for t_ns, value in found:
            if not free:
                break
            i = min(free, key=lambda k: abs(received[k] - t_ns))
            out[i] = value
            free.remove(i)
    return out
