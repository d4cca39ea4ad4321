"""Recordings for fits: tracked tissue points (sensor_msgs/PointCloud2) and tool poses, read from and written to bags.

A tracker publishes one PointCloud2 per camera frame: the same P tracked
points in every cloud, in the same order (field ``x``, ``y``; ``z`` and any
other fields ignored), NaN for a point it lost in that frame, stamped with the
frame's capture time, in the simulation's fixed frame. The tool's poses come
from the same bag through :func:`~tissue_sim_ros.ros.bags.read_tool_track`
(PoseStamped, TransformStamped, TF, Odometry, ...).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.fit.tracking import Recording
from . import messages as msgs
from .bags import Bag, BagWriter, read_tool_track

POINT_CLOUD_TYPE = "sensor_msgs/msg/PointCloud2"
#: The tracked points' layout this module writes: x, y, z as float32.
TRACKED_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4")])


def read_point_track(bag: Bag, topic: str) -> tuple[np.ndarray, np.ndarray, set[str]]:
    """Stamps [ns] (F,), points [m] (F, P, 2) and frame ids of a PointCloud2 topic, in the bag's order.

    Raises :class:`InputError` for a missing topic, another type, clouds without x/y fields or of changing
    width. The stamps are returned as recorded (their order is checked by :meth:`Recording.validate`).
    """
    topics = bag.topics
    if topic not in topics:
        alt = "/" + topic if not topic.startswith("/") else topic.lstrip("/")
        if alt not in topics:
            raise InputError(f"bag {str(bag.path)!r} has no points topic {topic!r}; it has: {bag.describe_topics()}")
        topic = alt
    if topics[topic] != POINT_CLOUD_TYPE:
        raise InputError(f"points topic {topic!r} has type {topics[topic]}: expected {POINT_CLOUD_TYPE}")
    stamps: list[int] = []
    frames: list[np.ndarray] = []
    frame_ids: set[str] = set()
    width = None
    for i, (_, _, t_bag, raw) in enumerate(bag.messages([topic])):
        try:
            (sec, nsec), frame_id, cloud = msgs.decode_point_cloud(raw)
        except (ValueError, IndexError, KeyError) as exc:
            raise InputError(f"points topic {topic}: cloud {i} cannot be read ({exc})") from None
        names = cloud.dtype.names or ()
        if "x" not in names or "y" not in names:
            raise InputError(f"points topic {topic}: cloud {i} has fields {list(names)}: expected x and y")
        if width is None:
            width = cloud.shape[0]
        elif cloud.shape[0] != width:
            raise InputError(f"points topic {topic}: cloud {i} has {cloud.shape[0]} points, the first had {width}: "
                             "expected the same tracked points in every cloud (NaN for a point not seen)")
        stamp = int(sec) * 1_000_000_000 + int(nsec)
        stamps.append(stamp if stamp > 0 else int(t_bag))
        frames.append(np.stack([cloud["x"].astype(np.float64), cloud["y"].astype(np.float64)], axis=1))
        frame_ids.add(frame_id)
    if not frames:
        raise InputError(f"points topic {topic} in bag {str(bag.path)!r} holds no clouds")
    return np.asarray(stamps, dtype=np.int64), np.stack(frames), frame_ids


def read_recording(path: str | Path, points_topic: str, tool_topic: str | None = None, *,
                   frame: str | None = None) -> Recording:
    """The tracked points and the tool trajectory of a bag, as a :class:`~tissue_sim_ros.core.fit.tracking.Recording`.

    The tool's poses with repeated or out-of-order stamps are an error, as are points and tool in
    different frames (no transform is applied).
    """
    with Bag(path) as bag:
        t_ns, points, point_frames = read_point_track(bag, points_topic)
        track = read_tool_track(bag, tool_topic, frame=frame, on_bad_time="error")
    tool_frames = {f for f in track.frame_ids if f}
    pf = {f for f in point_frames if f}
    if pf and tool_frames and pf != tool_frames:
        raise InputError(f"points are in frame {', '.join(sorted(pf))} but the tool in {', '.join(sorted(tool_frames))}: "
                         "expected both in the simulation's fixed frame")
    if len(pf) > 1:
        raise InputError(f"points topic {points_topic}: clouds in several frames ({', '.join(sorted(pf))}): "
                         "expected one fixed frame")
    return Recording(t_ns=t_ns, points=points, tool_t_ns=track.t_ns, tool_pose=track.pose,
                     source=f"{path} ({points_topic}, {track.topic})")


def write_recording(path: str | Path, t_ns: np.ndarray, points: np.ndarray, tool_t_ns: np.ndarray,
                    tool_pose: np.ndarray, *, points_topic: str = "/tracker/points", tool_topic: str = "/tool/pose",
                    frame_id: str = "world", storage: str = "mcap") -> Path:
    """Write tracked points (PointCloud2 of x, y, z float32; NaN kept) and tool poses (PoseStamped) as a bag.

    Each message is stamped and received at its own time; the two streams interleave in time order.
    """
    t_ns = np.asarray(t_ns, dtype=np.int64)
    tool_t_ns = np.asarray(tool_t_ns, dtype=np.int64)
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 3 or points.shape[0] != t_ns.shape[0] or points.shape[2] != 2:
        raise InputError(f"points have shape {points.shape}: expected ({t_ns.shape[0]}, P, 2)")
    items: list[tuple[int, int, str, bytes]] = []
    for i, t in enumerate(t_ns.tolist()):
        cloud = np.zeros(points.shape[1], TRACKED_DTYPE)
        cloud["x"], cloud["y"] = points[i, :, 0], points[i, :, 1]
        stamp = (t // 1_000_000_000, t % 1_000_000_000)
        dense = bool(np.isfinite(points[i]).all())
        items.append((t, 1, points_topic, msgs.encode_point_cloud(stamp, frame_id, cloud, dense=dense)))
    for i, t in enumerate(tool_t_ns.tolist()):
        stamp = (t // 1_000_000_000, t % 1_000_000_000)
        items.append((t, 0, tool_topic, msgs.encode_pose_stamped(stamp, frame_id, *map(float, tool_pose[i]))))
    items.sort(key=lambda it: (it[0], it[1]))
    with BagWriter(path, storage) as w:
        w.add_topic(tool_topic, "geometry_msgs/msg/PoseStamped")
        w.add_topic(points_topic, POINT_CLOUD_TYPE)
        for t, _, topic, data in items:
            w.write(topic, data, t)
    return Path(path)
