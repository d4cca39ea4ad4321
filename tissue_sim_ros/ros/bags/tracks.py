"""Tool trajectories from bags: :func:`read_tool_track` extracts the tool's planar trajectory from any message that
carries a pose (:data:`POSE_TYPES`), with an optional twist topic (:data:`TWIST_TYPES`).

Timestamp policy of :func:`read_tool_track` (documented, never silent):
    the time of a sample is its ``header.stamp`` when the type has a header and
    the stamp is non-zero, else the bag's receive time (``time_source="bag"``
    forces the receive time). A sample whose time equals the previous kept
    sample's (``repeated``) or precedes it (``out_of_order``) is skipped and
    counted; a sample with a non-finite position or an invalid quaternion is
    skipped and counted (``non_finite``, ``bad_quaternion``).
    ``on_bad_time="error"`` (times) and ``on_bad_pose="error"`` (positions,
    quaternions) raise :class:`BadSampleError` instead. The counts travel with
    the track (:attr:`ToolTrack.skipped`) and ``tissue-sim replay`` prints them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...core.contact.tool import interpolate_poses, yaw_from_quaternion
from ...core.errors import InputError
from ...core.timing.stamps import stamp_to_ns
from .read import Bag

POSE_TYPES = (
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/Pose",
    "geometry_msgs/msg/TransformStamped",
    "tf2_msgs/msg/TFMessage",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    "nav_msgs/msg/Odometry",
)
"""Message types a tool pose is read from (TFMessage needs a child frame)."""

TWIST_TYPES = ("geometry_msgs/msg/TwistStamped", "geometry_msgs/msg/Twist")
"""Message types a tool velocity is read from."""

JAW_TYPE = "sensor_msgs/msg/JointState"
#: A grasper's jaw in a bag: a JointState topic named the node's ``tool/jaw`` or a dVRK arm's ``jaw/measured_js``.
JAW_SUFFIXES = ("tool/jaw", "jaw/measured_js")


def is_jaw_topic(topic: str, msgtype: str) -> bool:
    """Whether ``topic`` carries a grasper's jaw angle (a JointState named like :data:`JAW_SUFFIXES`)."""
    t = topic.rstrip("/")
    return msgtype == JAW_TYPE and any(t == s or t.endswith("/" + s) for s in JAW_SUFFIXES)

TF_TYPE = "tf2_msgs/msg/TFMessage"

SKIP_REASONS = ("repeated", "out_of_order", "non_finite", "bad_quaternion")
"""Why :func:`read_tool_track` skips a sample (the keys of :attr:`ToolTrack.skipped`)."""

NODE_TOOL_OUTPUTS = ("tool/applied_pose", "tool/applied_twist", "tool/applied_jaw")
"""The node's own tool outputs (relative names): the pose and twist it stepped with (msg_docs/topics.md).
They carry a pose and a twist, but they are what the node did, not a tool's input: neither ``read_tool_track``
without a topic nor ``tissue-sim play`` without ``--topics`` takes them (``replay --mode applied`` does)."""


def is_node_tool_output(topic: str) -> bool:
    """Whether ``topic`` is one of :data:`NODE_TOOL_OUTPUTS` in any namespace (``/left/tool/applied_pose``)."""
    t = topic.rstrip("/")
    return any(t == name or t.endswith("/" + name) for name in NODE_TOOL_OUTPUTS)


class BadSampleError(InputError):
    """A tool sample :func:`read_tool_track` was told to refuse (``on_bad_time``/``on_bad_pose`` "error")."""



# --------------------------------------------------------------------------- tool trajectories


@dataclass
class ToolTrack:
    """A planar tool trajectory read from a bag."""

    t_ns: np.ndarray
    """Sample times [ns], strictly increasing, shape (M,), int64."""
    pose: np.ndarray
    """Tool pose per sample: x [m], y [m], yaw [rad], shape (M, 3), float64."""
    twist: np.ndarray | None
    """Tool velocity per sample: vx, vy [m/s], wz [rad/s], shape (M, 3), float64; NaN rows where no
    twist had been received yet (the simulation then derives it from poses); None without a twist topic."""
    topic: str
    """Topic the poses came from."""
    msgtype: str
    """Its message type."""
    child_frame: str | None = None
    """For TF messages: the child frame that is the tool."""
    frame_ids: tuple[str, ...] = ()
    """Parent/header frames seen on the pose samples."""
    twist_topic: str | None = None
    twist_t_ns: np.ndarray | None = None
    """Time of the twist each row holds [ns], shape (M,), int64, -1 where none; equal to ``t_ns`` where the
    twist carries the pose's own stamp (the only twists the node uses in lock-step)."""
    n_messages: int = 0
    """Pose-topic messages read (kept + skipped, TF messages without the frame not counted)."""
    skipped: dict[str, int] = field(default_factory=dict)
    """Samples skipped per reason: repeated, out_of_order, non_finite, bad_quaternion."""
    time_source: str = "header"
    """``header`` (stamps, receive time where a stamp is 0 or absent) or ``bag`` (receive times)."""
    received_ns: np.ndarray | None = None
    """Bag receive time of each pose sample [ns], shape (M,), int64."""
    twist_received_ns: np.ndarray | None = None
    """Bag receive time of the twist each row holds [ns], shape (M,), int64, -1 where none: a twist with the
    pose's stamp received after the pose is one the node in lock-step had not got when it stepped."""

    @property
    def n(self) -> int:
        return int(self.t_ns.shape[0])

    @property
    def duration(self) -> float:
        """Time from first to last sample [s]."""
        return float(self.t_ns[-1] - self.t_ns[0]) * 1e-9 if self.n else 0.0

    def interpolate(self, t_ns: np.ndarray) -> np.ndarray:
        """Pose at times ``t_ns`` [ns] (clamped to the track's span): linear in x, y and unwrapped yaw.

        Returns shape (K, 3), float64.
        """
        return interpolate_poses(self.t_ns, self.pose, np.asarray(t_ns, dtype=np.int64))

    def summary(self) -> str:
        """One line: topic, frame, samples, duration, rate, skips."""
        rate = (self.n - 1) / self.duration if self.duration > 0 else float("nan")
        frame = f" child frame {self.child_frame!r}" if self.child_frame else ""
        skips = ", ".join(f"{k} {v}" for k, v in sorted(self.skipped.items()) if v) or "none"
        tw = f", twist from {self.twist_topic}" if self.twist_topic else ""
        return (f"tool track: {self.topic} ({self.msgtype}){frame}, {self.n} samples over {self.duration:.3f} s "
                f"(~{rate:.1f} Hz, {self.time_source} time){tw}; skipped: {skips}")


def _stamp_ns(header: Any) -> int:
    return stamp_to_ns((header.stamp.sec, header.stamp.nanosec))


def _yaw(q: Any) -> float | None:
    """Heading about +z of a quaternion message; None when it is not a rotation (the node's formula)."""
    return yaw_from_quaternion(float(q.x), float(q.y), float(q.z), float(q.w))


# each extractor: msg -> list of (stamp_ns or 0, x, y, quaternion, frame_id, child_frame)
def _samples(msg: Any, msgtype: str, child: str | None) -> list[tuple[int, float, float, Any, str]]:
    if msgtype == "geometry_msgs/msg/PoseStamped":
        p = msg.pose
        return [(_stamp_ns(msg.header), p.position.x, p.position.y, p.orientation, msg.header.frame_id)]
    if msgtype == "geometry_msgs/msg/Pose":
        return [(0, msg.position.x, msg.position.y, msg.orientation, "")]
    if msgtype in ("geometry_msgs/msg/PoseWithCovarianceStamped", "nav_msgs/msg/Odometry"):
        p = msg.pose.pose
        return [(_stamp_ns(msg.header), p.position.x, p.position.y, p.orientation, msg.header.frame_id)]
    if msgtype == "geometry_msgs/msg/TransformStamped":
        tr = msg.transform
        return [(_stamp_ns(msg.header), tr.translation.x, tr.translation.y, tr.rotation, msg.header.frame_id)]
    if msgtype == TF_TYPE:
        out = []
        for ts in msg.transforms:
            if ts.child_frame_id.lstrip("/") == child:
                tr = ts.transform
                out.append((_stamp_ns(ts.header), tr.translation.x, tr.translation.y, tr.rotation, ts.header.frame_id))
        return out
    raise AssertionError(msgtype)


def tool_candidates(bag: Bag) -> list[tuple[str, str, str | None]]:
    """Every (topic, type, child frame) in the bag that can carry the tool pose.

    TF topics contribute one candidate per child frame they carry (found by
    reading them).
    """
    out: list[tuple[str, str, str | None]] = []
    tf_topics = []
    for topic, msgtype in sorted(bag.topics.items()):
        if msgtype == TF_TYPE:
            tf_topics.append(topic)
        elif msgtype in POSE_TYPES:
            out.append((topic, msgtype, None))
    for topic in tf_topics:
        frames: set[str] = set()
        for _, msgtype, _, raw in bag.messages([topic]):
            frames.update(ts.child_frame_id.lstrip("/") for ts in bag.decode(raw, msgtype).transforms)
        out += [(topic, TF_TYPE, f) for f in sorted(frames)]
    return out


def _format_candidates(cands: list[tuple[str, str, str | None]]) -> str:
    return "; ".join(f"--tool-topic {t}" + (f" --frame {f}" if f else "") + f" ({ty})" for t, ty, f in cands)


def _choose(bag: Bag, topic: str | None, frame: str | None) -> tuple[str, str, str | None]:
    """Resolve the tool topic (and TF child frame) from the options, or explain what is there."""
    topics = bag.topics
    frame = frame.lstrip("/") if frame else frame
    if topic is not None:
        if topic not in topics:
            alt = "/" + topic if not topic.startswith("/") else topic.lstrip("/")
            if alt in topics:
                topic = alt
            else:
                raise InputError(f"bag {str(bag.path)!r} has no topic {topic!r}; it has: {bag.describe_topics()}")
        msgtype = topics[topic]
        if msgtype not in POSE_TYPES:
            raise InputError(f"topic {topic!r} in bag {str(bag.path)!r} has type {msgtype}, which carries no tool pose; "
                             f"supported: {', '.join(POSE_TYPES)}")
        if msgtype != TF_TYPE:
            return topic, msgtype, None
        if frame is not None:
            return topic, msgtype, frame  # checked while reading (a scan of a large /tf only if it is absent)
        cands = [c for c in tool_candidates(bag) if c[0] == topic]
    else:
        found = tool_candidates(bag)
        # the node's own outputs (tool/applied_*) are what it did with a tool, not a tool: never chosen unasked
        cands = [c for c in found if not is_node_tool_output(c[0])]
        outputs = [c for c in found if is_node_tool_output(c[0])]
        if not cands and outputs and frame is None:
            raise InputError(f"bag {str(bag.path)!r}: its only tool pose is the node's own output "
                             f"{', '.join(c[0] for c in outputs)} (the tool it applied): expected a tool input; "
                             f"replay a node's recording with --mode applied, or name it with --tool-topic "
                             f"{outputs[0][0]}")
    if frame is not None:
        matching = [c for c in cands if c[2] == frame]
        if not matching:
            tf = [c for c in cands if c[1] == TF_TYPE]
            raise InputError(f"bag {str(bag.path)!r}: no TF child frame {frame!r}"
                             + (f" on {topic}" if topic else "")
                             + f"; TF child frames there: {', '.join(sorted({c[2] for c in tf if c[2]})) or 'none'}")
        cands = matching
    if not cands:
        raise InputError(f"bag {str(bag.path)!r} has no topic carrying a tool pose (supported types: "
                         f"{', '.join(POSE_TYPES)}); it has: {bag.describe_topics()}")
    if len(cands) > 1:
        raise InputError(f"bag {str(bag.path)!r}: {len(cands)} possible tool poses, choose one with --tool-topic "
                         f"and --frame: {_format_candidates(cands)}")
    return cands[0]


def read_tool_track(path: str | Path | Bag, topic: str | None = None, frame: str | None = None,
                    twist_topic: str | None = None, time_source: str = "header",
                    on_bad_time: str = "skip", on_bad_pose: str = "skip") -> ToolTrack:
    """Extract the tool's planar trajectory from a bag.

    Parameters
    ----------
    path : bag path, or an open :class:`~.read.Bag`
    topic : str, optional
        The pose topic; when None, the one topic (or TF child frame) that can
        carry a pose, else an InputError listing the candidates. The node's own
        outputs (:data:`NODE_TOOL_OUTPUTS`) are never candidates: name them to read them.
    frame : str, optional
        TF child frame that is the tool (for ``tf2_msgs/msg/TFMessage`` topics).
    twist_topic : str, optional
        A TwistStamped/Twist topic; each pose sample gets the latest twist at or
        before its time.
    time_source : {"header", "bag"}
        Sample time: header stamps (receive time where absent or 0) or receive times.
    on_bad_time : {"skip", "error"}
        Repeated or out-of-order sample times: skip and count, or raise :class:`BadSampleError`.
    on_bad_pose : {"skip", "error"}
        Non-finite positions and invalid quaternions: skip and count, or raise :class:`BadSampleError`.

    Returns
    -------
    ToolTrack
        Poses projected onto the tissue plane: x, y and the heading about +z.
    """
    for name, value, allowed in (("time_source", time_source, ("header", "bag")),
                                 ("on_bad_time", on_bad_time, ("skip", "error")),
                                 ("on_bad_pose", on_bad_pose, ("skip", "error"))):
        if value not in allowed:
            raise InputError(f"{name}={value!r}: expected {allowed[0]!r} or {allowed[1]!r}")
    own = not isinstance(path, Bag)
    bag = Bag(path) if own else path
    try:
        if bag.message_count == 0:
            raise InputError(f"bag {str(bag.path)!r} holds no messages (topics: {bag.describe_topics()})")
        topic, msgtype, child = _choose(bag, topic, frame)
        if twist_topic is not None:
            _check_twist_topic(bag, twist_topic)
        samples = _PoseSamples(bag, topic, time_source, on_bad_time, on_bad_pose)
        samples.read(msgtype, child)
        t_arr = np.asarray(samples.times, dtype=np.int64)
        twist, twist_t, twist_rx = (_read_twist(bag, twist_topic, t_arr, time_source) if twist_topic
                                    else (None, None, None))
        return ToolTrack(t_ns=t_arr, pose=np.asarray(samples.poses, dtype=np.float64), twist=twist,
                         twist_t_ns=twist_t, received_ns=np.asarray(samples.received, dtype=np.int64),
                         twist_received_ns=twist_rx, topic=topic, msgtype=msgtype, child_frame=child,
                         frame_ids=tuple(sorted(samples.frames)), twist_topic=twist_topic,
                         n_messages=samples.n_messages, skipped=samples.skipped, time_source=time_source)
    finally:
        if own:
            bag.close()


def _check_twist_topic(bag: Bag, twist_topic: str) -> None:
    if twist_topic not in bag.topics:
        raise InputError(f"bag {str(bag.path)!r} has no twist topic {twist_topic!r}; it has: {bag.describe_topics()}")
    if bag.topics[twist_topic] not in TWIST_TYPES:
        raise InputError(f"twist topic {twist_topic!r} has type {bag.topics[twist_topic]}: expected one of "
                         f"{', '.join(TWIST_TYPES)}")


class _PoseSamples:
    """The pose samples of one topic (and TF child frame), kept by the timestamp policy (module docstring)."""

    def __init__(self, bag: Bag, topic: str, time_source: str, on_bad_time: str, on_bad_pose: str) -> None:
        self.bag, self.topic, self.time_source = bag, topic, time_source
        self.on_bad_time, self.on_bad_pose = on_bad_time, on_bad_pose
        self.skipped = dict.fromkeys(SKIP_REASONS, 0)
        self.times: list[int] = []
        self.received: list[int] = []
        self.poses: list[tuple[float, float, float]] = []
        self.frames: set[str] = set()
        self.n_messages = 0

    def read(self, msgtype: str, child: str | None) -> None:
        bag = self.bag
        for _, _, t_bag, raw in bag.messages([self.topic]):
            for stamp, x, y, q, frame_id in _samples(bag.decode(raw, msgtype), msgtype, child):
                self.n_messages += 1
                self._take(t_bag if (self.time_source == "bag" or stamp == 0) else stamp, t_bag, x, y, q, frame_id)
        if not self.times and msgtype == TF_TYPE and self.n_messages == 0:
            frames_there = sorted({c[2] for c in tool_candidates(bag) if c[0] == self.topic and c[2]})
            raise InputError(f"bag {str(bag.path)!r}: no TF child frame {child!r} on {self.topic}; TF child frames "
                             f"there: {', '.join(frames_there) or 'none'}")
        if not self.times:
            raise InputError(f"bag {str(bag.path)!r}: topic {self.topic}"
                             + (f" frame {child!r}" if child else "")
                             + f" gave no usable tool pose ({self.n_messages} samples; skipped {self.skipped})")

    def _skip(self, reason: str, error: bool, message: str) -> None:
        if error:
            raise BadSampleError(f"bag {str(self.bag.path)!r}, topic {self.topic}: sample {self.n_messages} "
                                 f"{message}")
        self.skipped[reason] += 1

    def _take(self, t: int, t_bag: int, x: float, y: float, q: Any, frame_id: str) -> None:
        yaw = _yaw(q)
        bad_pose = self.on_bad_pose == "error"
        if not (math.isfinite(x) and math.isfinite(y)):
            self._skip("non_finite", bad_pose, f"has a non-finite position ({x}, {y}) (non_finite): "
                                               "expected finite coordinates")
            return
        if yaw is None:
            self._skip("bad_quaternion", bad_pose, f"has an invalid quaternion ({q.x}, {q.y}, {q.z}, {q.w}) "
                                                   "(bad_quaternion): expected a finite, non-zero quaternion")
            return
        last = self.times[-1] if self.times else -1
        if t <= last:
            reason = "repeated" if t == last else "out_of_order"
            self._skip(reason, self.on_bad_time == "error",
                       f"has time {t} ns, {'equal to' if t == last else 'before'} the previous sample's {last} "
                       f"ns ({reason}): expected increasing sample times")
            return
        self.times.append(t)
        self.received.append(int(t_bag))
        self.poses.append((float(x), float(y), yaw))
        self.frames.add(frame_id)


def _read_twist(bag: Bag, topic: str, t_pose: np.ndarray,
                time_source: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Latest twist at or before each pose time (sample and hold; NaN rows before the first twist), its time
    and its bag receive time."""
    t_tw: list[int] = []
    rx: list[int] = []
    vals: list[tuple[float, float, float]] = []
    for _, msgtype, t_bag, raw in bag.messages([topic]):
        msg = bag.decode(raw, msgtype)
        if msgtype == "geometry_msgs/msg/TwistStamped":
            stamp, tw = _stamp_ns(msg.header), msg.twist
        else:
            stamp, tw = 0, msg
        t = t_bag if (time_source == "bag" or stamp == 0) else stamp
        v = (float(tw.linear.x), float(tw.linear.y), float(tw.angular.z))
        if not all(math.isfinite(c) for c in v) or (t_tw and t < t_tw[-1]):
            continue  # a bad or late twist: the pose-derived velocity stands in
        t_tw.append(t)
        rx.append(int(t_bag))
        vals.append(v)
    out = np.full((t_pose.shape[0], 3), np.nan)
    times = np.full(t_pose.shape[0], -1, dtype=np.int64)
    received = np.full(t_pose.shape[0], -1, dtype=np.int64)
    if t_tw:
        t_arr = np.asarray(t_tw, dtype=np.int64)
        idx = np.searchsorted(t_arr, t_pose, side="right") - 1
        ok = idx >= 0
        out[ok] = np.asarray(vals)[idx[ok]]
        times[ok] = t_arr[idx[ok]]
        received[ok] = np.asarray(rx, dtype=np.int64)[idx[ok]]
    return out, times, received


