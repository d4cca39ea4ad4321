"""The tool the node applied at each step: ``tool/applied_pose`` and ``tool/applied_twist``, and reading them back.

Every step the node publishes (and, with ``record_path``, records) the tool it
stepped with, stamped with the step's stamp (the stamp of that step's
tissue/points and tool/wrench):

* ``tool/applied_twist`` (TwistStamped) on every step: the velocity the contact
  model used, whether it came from ``tool/twist`` or was derived from poses
  (zero when there is no tool);
* ``tool/applied_pose`` (PoseStamped) on every step that had a tool: its
  position and the orientation quaternion the yaw was computed from, so that
  an offline replay computes the very same yaw from it.

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
from .messages import CdrReader, CdrWriter, Stamp

POSE_TOPIC = "/tool/applied_pose"
TWIST_TYPE = "geometry_msgs/msg/TwistStamped"
TWIST_TOPIC = "/tool/applied_twist"
POSE_TYPE = "geometry_msgs/msg/PoseStamped"

PLANAR = (0.0, 0.0, 0.0, 1.0)


def planar_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation about +z by ``yaw`` [rad]."""
    return 0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw)


def encode_applied_pose(stamp: Stamp, frame_id: str, x: float, y: float,
                        quaternion: tuple[float, float, float, float]) -> bytes:
    """geometry_msgs/PoseStamped: the tool's position in the plane (z = 0) and the quaternion its yaw came from."""
    w = CdrWriter()
    w.header(stamp, frame_id)
    w.f64s(x, y, 0.0, *quaternion)
    return w.getvalue()


def encode_applied_twist(stamp: Stamp, frame_id: str, twist: ToolTwist) -> bytes:
    """geometry_msgs/TwistStamped: linear (vx, vy, 0) [m/s], angular (0, 0, wz) [rad/s]."""
    w = CdrWriter()
    w.header(stamp, frame_id)
    w.f64s(twist.vx, twist.vy, 0.0, 0.0, 0.0, twist.wz)
    return w.getvalue()


def decode_applied_pose(data: bytes) -> tuple[Stamp, ToolPose]:
    r = CdrReader(data)
    stamp, _ = r.header()
    x, y, _z, qx, qy, qz, qw = r.f64s(7)
    yaw = yaw_from_quaternion(qx, qy, qz, qw)
    if yaw is None:
        raise InputError(f"{POSE_TOPIC} stamped {stamp}: not a rotation ({qx}, {qy}, {qz}, {qw})")
    return stamp, ToolPose(x, y, yaw)


def decode_applied_twist(data: bytes) -> tuple[Stamp, ToolTwist]:
    r = CdrReader(data)
    stamp, _ = r.header()
    vx, vy, _vz, _wx, _wy, wz = r.f64s(6)
    return stamp, ToolTwist(vx, vy, wz)


@dataclass
class AppliedSteps:
    """The node's steps as recorded: one entry per step, in order."""

    t_ns: np.ndarray
    """Step stamp [ns], shape (S,), int64."""
    poses: list[ToolPose | None]
    twists: list[ToolTwist]
    twist_topic: str = TWIST_TOPIC
    pose_topic: str = POSE_TOPIC

    @property
    def n(self) -> int:
        return int(self.t_ns.shape[0])

    def items(self) -> list[tuple[ToolPose | None, ToolTwist]]:
        return list(zip(self.poses, self.twists))


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
        # in the order written: each step writes its pose (when it had a tool), then its twist. The stamps
        # need not increase (a node that starts following /clock jumps to the bag's time), so a twist takes
        # the pose written just before it when that pose has its stamp
        poses: list[ToolPose | None] = []
        steps: list[tuple[Stamp, ToolTwist]] = []
        pending: tuple[Stamp, ToolPose] | None = None
        topics = [twist_topic] + ([pose_topic] if pose_topic in bag.topics else [])
        for topic, _, _, raw in bag.messages(topics):
            data = bytes(raw)
            if topic == pose_topic:
                pending = decode_applied_pose(data)
            else:
                stamp, twist = decode_applied_twist(data)
                poses.append(pending[1] if pending is not None and pending[0] == stamp else None)
                steps.append((stamp, twist))
                pending = None
    finally:
        bag.close()
    if not steps:
        raise InputError(f"bag {str(path)!r}: {twist_topic} holds no messages")
    t_ns = np.array([s * 1_000_000_000 + ns for (s, ns), _ in steps], dtype=np.int64)
    return AppliedSteps(t_ns=t_ns, poses=poses, twists=[tw for _, tw in steps], twist_topic=twist_topic,
                        pose_topic=pose_topic)
