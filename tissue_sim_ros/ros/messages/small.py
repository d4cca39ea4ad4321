"""The small messages (std_msgs Float64, UInt32, Float64MultiArray; geometry_msgs PoseStamped, TwistStamped,
WrenchStamped; sensor_msgs JointState) as CDR bytes and back, through ``rosbags``' Jazzy typestore: a few
microseconds each, so no hand-written layout (docs/benchmarks/ros.md)."""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..typestore import msg_class, typestore
from .cdr import CdrReader, Stamp

FLOAT64 = "std_msgs/msg/Float64"
UINT32 = "std_msgs/msg/UInt32"
FLOAT64_MULTIARRAY = "std_msgs/msg/Float64MultiArray"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"
JOINT_STATE = "sensor_msgs/msg/JointState"


def encode(msg: Any, msgtype: str) -> bytes:
    """A typestore message object as CDR bytes (little endian, with the encapsulation header)."""
    return bytes(typestore().serialize_cdr(msg, msgtype))


def decode(data: bytes | memoryview, msgtype: str) -> Any:
    """CDR bytes as a typestore message object."""
    return typestore().deserialize_cdr(bytes(data), msgtype)


def header(stamp: Stamp, frame_id: str) -> Any:
    """std_msgs/Header of a (sec, nanosec) stamp."""
    return msg_class("std_msgs/msg/Header")(stamp=msg_class("builtin_interfaces/msg/Time")(
        sec=int(stamp[0]), nanosec=int(stamp[1])), frame_id=frame_id)


def _stamp(h: Any) -> Stamp:
    return int(h.stamp.sec), int(h.stamp.nanosec)


def _vector3(x: float, y: float, z: float, kind: str = "geometry_msgs/msg/Vector3") -> Any:
    return msg_class(kind)(x=float(x), y=float(y), z=float(z))


# --------------------------------------------------------------------------- std_msgs


def encode_float64(value: float) -> bytes:
    """std_msgs/Float64."""
    return encode(msg_class(FLOAT64)(data=float(value)), FLOAT64)


def decode_float64(data: bytes) -> float:
    return float(decode(data, FLOAT64).data)


def encode_uint32(value: int) -> bytes:
    """std_msgs/UInt32."""
    return encode(msg_class(UINT32)(data=int(value)), UINT32)


def decode_uint32(data: bytes) -> int:
    return int(decode(data, UINT32).data)


def encode_float64_multiarray(data: np.ndarray, labels: list[str], sizes: list[int] | None = None) -> bytes:
    """std_msgs/Float64MultiArray of a row-major array with labelled dimensions.

    Parameters
    ----------
    data : ndarray
        The values, any shape, float64; written row-major (C order).
    labels : list of str
        One label per dimension of ``data`` (``layout.dim[i].label``).
    sizes : list of int, optional
        Dimension sizes; default ``data.shape``.
    """
    arr = np.ascontiguousarray(data, dtype="<f8")
    sizes = list(arr.shape) if sizes is None else sizes
    if len(labels) != len(sizes):
        raise ValueError(f"{len(labels)} labels for {len(sizes)} dimensions")
    dim = msg_class("std_msgs/msg/MultiArrayDimension")
    # stride: the elements one step of the previous dimension spans
    dims = [dim(label=label, size=int(size), stride=int(np.prod(sizes[i:])))
            for i, (label, size) in enumerate(zip(labels, sizes))]
    layout = msg_class("std_msgs/msg/MultiArrayLayout")(dim=dims, data_offset=0)
    return encode(msg_class(FLOAT64_MULTIARRAY)(layout=layout, data=arr.ravel()), FLOAT64_MULTIARRAY)


def decode_float64_multiarray(data: bytes) -> tuple[np.ndarray, list[str]]:
    """(values reshaped to the layout's sizes, labels) of a std_msgs/Float64MultiArray."""
    msg = decode(data, FLOAT64_MULTIARRAY)
    labels = [d.label for d in msg.layout.dim]
    sizes = [int(d.size) for d in msg.layout.dim]
    values = np.asarray(msg.data, dtype=np.float64)
    return (values.reshape(sizes) if sizes and int(np.prod(sizes)) == values.size else values), labels


# --------------------------------------------------------------------------- geometry_msgs


def pose_stamped(stamp: Stamp, frame_id: str, position: tuple[float, float, float],
                 quaternion: tuple[float, float, float, float]) -> bytes:
    """geometry_msgs/PoseStamped: a position [m] and an orientation quaternion (x, y, z, w)."""
    q = msg_class("geometry_msgs/msg/Quaternion")(x=float(quaternion[0]), y=float(quaternion[1]),
                                                 z=float(quaternion[2]), w=float(quaternion[3]))
    pose = msg_class("geometry_msgs/msg/Pose")(position=_vector3(*position, kind="geometry_msgs/msg/Point"),
                                               orientation=q)
    return encode(msg_class(POSE_STAMPED)(header=header(stamp, frame_id), pose=pose), POSE_STAMPED)


def encode_pose_stamped(stamp: Stamp, frame_id: str, x: float, y: float, yaw: float) -> bytes:
    """geometry_msgs/PoseStamped of a planar pose (z = 0, rotation about +z by ``yaw`` [rad])."""
    return pose_stamped(stamp, frame_id, (x, y, 0.0), (0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw)))


def decode_pose_stamped(data: bytes) -> tuple[Stamp, str, np.ndarray, np.ndarray]:
    """(stamp, frame_id, position (3,), orientation xyzw (4,)) of a geometry_msgs/PoseStamped."""
    msg = decode(data, POSE_STAMPED)
    p, o = msg.pose.position, msg.pose.orientation
    return _stamp(msg.header), msg.header.frame_id, np.array([p.x, p.y, p.z]), np.array([o.x, o.y, o.z, o.w])


def twist_stamped(stamp: Stamp, frame_id: str, linear: tuple[float, float, float],
                  angular: tuple[float, float, float]) -> bytes:
    """geometry_msgs/TwistStamped: linear [m/s] and angular [rad/s] velocity."""
    twist = msg_class("geometry_msgs/msg/Twist")(linear=_vector3(*linear), angular=_vector3(*angular))
    return encode(msg_class(TWIST_STAMPED)(header=header(stamp, frame_id), twist=twist), TWIST_STAMPED)


def encode_twist_stamped(stamp: Stamp, frame_id: str, vx: float, vy: float, wz: float) -> bytes:
    """geometry_msgs/TwistStamped of a planar twist (linear [m/s] in the plane, angular [rad/s] about +z)."""
    return twist_stamped(stamp, frame_id, (vx, vy, 0.0), (0.0, 0.0, wz))


def decode_twist_stamped(data: bytes) -> tuple[Stamp, str, np.ndarray, np.ndarray]:
    """(stamp, frame_id, linear (3,), angular (3,)) of a geometry_msgs/TwistStamped."""
    msg = decode(data, TWIST_STAMPED)
    v, w = msg.twist.linear, msg.twist.angular
    return _stamp(msg.header), msg.header.frame_id, np.array([v.x, v.y, v.z]), np.array([w.x, w.y, w.z])


def encode_wrench_stamped(stamp: Stamp, frame_id: str, force: tuple[float, float, float],
                          torque: tuple[float, float, float]) -> bytes:
    """geometry_msgs/WrenchStamped: force [N] and torque [N m] in ``frame_id``."""
    wrench = msg_class("geometry_msgs/msg/Wrench")(force=_vector3(*force), torque=_vector3(*torque))
    return encode(msg_class(WRENCH_STAMPED)(header=header(stamp, frame_id), wrench=wrench), WRENCH_STAMPED)


def decode_wrench_stamped(data: bytes) -> tuple[Stamp, str, np.ndarray, np.ndarray]:
    """(stamp, frame_id, force (3,), torque (3,))."""
    msg = decode(data, WRENCH_STAMPED)
    f, t = msg.wrench.force, msg.wrench.torque
    return _stamp(msg.header), msg.header.frame_id, np.array([f.x, f.y, f.z]), np.array([t.x, t.y, t.z])


# --------------------------------------------------------------------------- sensor_msgs


def encode_joint_state(stamp: Stamp, frame_id: str, names: list[str], positions: list[float]) -> bytes:
    """sensor_msgs/JointState with names and positions (no velocity, no effort): ``tool/jaw`` is one joint, the
    jaw angle [rad] in ``position[0]`` (as the dVRK's ``jaw/measured_js``); ``positions`` may be empty."""
    empty = np.zeros(0, dtype=np.float64)
    msg = msg_class(JOINT_STATE)(header=header(stamp, frame_id), name=list(names),
                                 position=np.asarray(positions, dtype=np.float64), velocity=empty, effort=empty)
    return encode(msg, JOINT_STATE)


def decode_joint_state(data: bytes) -> tuple[Stamp, str, list[str], np.ndarray]:
    """(stamp, frame_id, names, positions) of a sensor_msgs/JointState.

    Read by hand up to the positions: Fast CDR (rclpy's and rclcpp's serializer) pads an empty float64 sequence
    to the next 8 bytes, which the typestore's reader does not skip, so it refuses a JointState whose velocity
    or effort is empty (every jaw a robot publishes); the fields after the positions are not needed.
    """
    r = CdrReader(data)
    stamp, frame = r.header()
    names = [r.string() for _ in range(r.u32())]
    return stamp, frame, names, r.sequence("<f8", 8)[:, 0]
