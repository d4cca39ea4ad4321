"""Bags made by tests with ``rosbags`` alone: tool poses of every supported type, odd rates, extra topics.

Kept apart from the tests so test_bags, test_replay and test_record_play build
the same bags.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

TS = get_typestore(Stores.ROS2_JAZZY)
T = TS.types


def stamp(t_ns: int) -> Any:
    return T["builtin_interfaces/msg/Time"](sec=int(t_ns // 1_000_000_000), nanosec=int(t_ns % 1_000_000_000))


def header(t_ns: int, frame: str = "world") -> Any:
    return T["std_msgs/msg/Header"](stamp=stamp(t_ns), frame_id=frame)


def quat(yaw: float) -> Any:
    return T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(0.5 * yaw), w=math.cos(0.5 * yaw))


def pose(x: float, y: float, yaw: float) -> Any:
    return T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0), orientation=quat(yaw))


def transform_stamped(t_ns: int, parent: str, child: str, x: float, y: float, yaw: float) -> Any:
    tr = T["geometry_msgs/msg/Transform"](translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=0.0),
                                          rotation=quat(yaw))
    return T["geometry_msgs/msg/TransformStamped"](header=header(t_ns, parent), child_frame_id=child, transform=tr)


def tool_msg(msgtype: str, t_ns: int, x: float, y: float, yaw: float, child: str = "tool_tip") -> Any:
    """A message of ``msgtype`` carrying the tool at (x, y, yaw) at time t_ns (TF: with a distractor frame)."""
    if msgtype == "geometry_msgs/msg/PoseStamped":
        return T[msgtype](header=header(t_ns), pose=pose(x, y, yaw))
    if msgtype == "geometry_msgs/msg/Pose":
        return pose(x, y, yaw)
    if msgtype == "geometry_msgs/msg/TransformStamped":
        return transform_stamped(t_ns, "world", child, x, y, yaw)
    if msgtype == "geometry_msgs/msg/PoseWithCovarianceStamped":
        pwc = T["geometry_msgs/msg/PoseWithCovariance"](pose=pose(x, y, yaw), covariance=np.zeros(36))
        return T[msgtype](header=header(t_ns), pose=pwc)
    if msgtype == "nav_msgs/msg/Odometry":
        v3 = T["geometry_msgs/msg/Vector3"]
        twc = T["geometry_msgs/msg/TwistWithCovariance"](
            twist=T["geometry_msgs/msg/Twist"](linear=v3(x=0.0, y=0.0, z=0.0), angular=v3(x=0.0, y=0.0, z=0.0)),
            covariance=np.zeros(36))
        pwc = T["geometry_msgs/msg/PoseWithCovariance"](pose=pose(x, y, yaw), covariance=np.zeros(36))
        return T[msgtype](header=header(t_ns, "odom"), child_frame_id=child, pose=pwc, twist=twc)
    if msgtype == "tf2_msgs/msg/TFMessage":
        # a real robot's /tf: other links in the same message, the tool among them
        return T[msgtype](transforms=[transform_stamped(t_ns, "world", "base_link", 0.1, 0.2, 0.3),
                                      transform_stamped(t_ns, "base_link", child, x, y, yaw)])
    raise ValueError(msgtype)


def twist_msg(t_ns: int, vx: float, vy: float, wz: float) -> Any:
    v3 = T["geometry_msgs/msg/Vector3"]
    tw = T["geometry_msgs/msg/Twist"](linear=v3(x=vx, y=vy, z=0.0), angular=v3(x=0.0, y=0.0, z=wz))
    return T["geometry_msgs/msg/TwistStamped"](header=header(t_ns), twist=tw)


def trajectory(times_ns: np.ndarray) -> np.ndarray:
    """A tool sweeping right and down with a slow turn: (x, y, yaw) per time, shape (M, 3)."""
    t = (times_ns - times_ns[0]) * 1e-9
    return np.column_stack([-0.3 + 0.4 * t, 0.2 - 0.05 * t, 0.2 * np.sin(t)])


def irregular_times(n: int, rate_hz: float = 37.0, t0_ns: int = 1_700_000_000_123_456_789, jitter: float = 0.3,
                    seed: int = 7) -> np.ndarray:
    """``n`` strictly increasing times near ``rate_hz`` with +-``jitter`` relative spacing noise [ns], int64."""
    rng = np.random.default_rng(seed)
    dt = 1e9 / rate_hz * (1.0 + jitter * rng.uniform(-1.0, 1.0, n))
    dt[0] = 0.0
    return t0_ns + np.cumsum(dt).astype(np.int64)


def write_bag(path: Path, messages: Sequence[tuple[str, str, int, Any]], storage: str = "mcap",
              qos: dict[str, Any] | None = None) -> Path:
    """Write (topic, msgtype, t_ns, message object or raw bytes) in the given order; returns ``path``.

    ``qos``: topic -> a rosbags ``Qos`` stored as its offered QoS (as rosbag2 records it); others store none.
    """
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as w:
        conns: dict[str, Any] = {}
        for topic, msgtype, _, _ in messages:
            if topic not in conns:
                offered = (qos[topic],) if qos and topic in qos else ()
                conns[topic] = w.add_connection(topic, msgtype, typestore=TS, offered_qos_profiles=offered)
        for topic, msgtype, t_ns, msg in messages:
            data = msg if isinstance(msg, (bytes, bytearray)) else TS.serialize_cdr(msg, msgtype)
            w.write(conns[topic], int(t_ns), data)
    return path


def tool_bag(path: Path, msgtype: str = "geometry_msgs/msg/PoseStamped", n: int = 60, rate_hz: float = 37.0,
             topic: str = "/tool/pose", storage: str = "mcap", extras: bool = True, twist: bool = False,
             child: str = "tool_tip") -> tuple[Path, np.ndarray, np.ndarray]:
    """A bag of ``n`` tool messages at an irregular ``rate_hz`` plus unrelated topics.

    Returns (path, times [ns] (n,), poses (n, 3)). Header stamps equal receive times.
    """
    times = irregular_times(n, rate_hz)
    poses = trajectory(times)
    msgs: list[tuple[str, str, int, Any]] = []
    for t, (x, y, yaw) in zip(times, poses):
        msgs.append((topic, msgtype, int(t), tool_msg(msgtype, int(t), float(x), float(y), float(yaw), child)))
        if twist:
            msgs.append(("/tool/twist", "geometry_msgs/msg/TwistStamped", int(t), twist_msg(int(t), 0.4, -0.05, 0.1)))
        if extras:
            msgs.append(("/chatter", "std_msgs/msg/String", int(t) + 1000, T["std_msgs/msg/String"](data="hi")))
            msgs.append(("/joint_temp", "std_msgs/msg/Float64", int(t) + 2000, T["std_msgs/msg/Float64"](data=41.5)))
    return write_bag(path, msgs, storage), times, poses


def small_params(tmp_path: Path, **overrides: Any) -> dict[str, Any]:
    """Flat parameters of a small, fast scene: a 0.6 m x 0.3 m strip at 0.05 m spacing, saved as .npz."""
    from tissue_sim_ros.core.mesh import mesh_rectangle

    mesh_file = tmp_path / "strip.npz"
    if not mesh_file.exists():
        mesh_rectangle(0.6, 0.3, 0.05, origin=(-0.3, 0.0)).save(mesh_file)
    params: dict[str, Any] = {"mesh_file": str(mesh_file), "boundary_y_top": 0.29, "boundary_y_bottom": 0.01,
                              "iterations": 10, "contact_radius": 0.1, "tool_length": 0.3}
    params.update(overrides)
    return params


def write_params(tmp_path: Path, **overrides: Any) -> Path:
    """:func:`small_params` as a ROS 2 parameter YAML; returns its path."""
    import yaml

    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump({"tissue_sim_node": {"ros__parameters": small_params(tmp_path, **overrides)}}))
    return path
