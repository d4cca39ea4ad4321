"""``tissue_controller``'s messages: its observations read from raw bytes, its commands and markers written, and
its ``/diagnostics`` (every key: msg_docs/controller.md)."""
from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from ..core.contact.tool import ToolPose, yaw_from_quaternion
from ..core.timing.stamps import stamp_from_ns, stamp_to_ns
from . import messages
from .controller_worker import Observation, Pursuit
from .tool_applied import decode_applied_jaw

#: Keys of the dropped-message counts on /diagnostics.
DROP_KINDS = ("points_empty", "points_nonfinite", "points_shape", "points_frame", "points_malformed",
              "pose_nonfinite", "pose_frame", "pose_malformed", "jaw_nonfinite", "jaw_malformed")


# --------------------------------------------------------------------------- in


def read_points(data: bytes) -> tuple[Observation | None, str, str]:
    """An observation from PointCloud2 bytes, or (None, drop kind, why)."""
    try:
        stamp, frame, cloud = messages.decode_point_cloud(data)
    except Exception as exc:  # noqa: BLE001  any malformed bytes
        return None, "points_malformed", f"could not be read: {exc}"
    names = cloud.dtype.names or ()
    if "x" not in names or "y" not in names:
        return None, "points_shape", f"has the fields {list(names)}: expected x and y"
    if cloud.shape[0] == 0:
        return None, "points_empty", "has no points"
    xy = np.stack([cloud["x"].astype(np.float64), cloud["y"].astype(np.float64)], axis=1)
    if xy.ndim != 2 or xy.shape[1] != 2:
        return None, "points_shape", f"fields x, y of shape {xy.shape}: expected one value each per point"
    if not np.isfinite(xy).all(axis=1).any():
        return None, "points_nonfinite", "every point is NaN/inf"
    return Observation(stamp_to_ns(stamp), frame, xy), "", ""


def read_pose(data: bytes) -> tuple[tuple[ToolPose, int, str] | None, str, str]:
    """(pose, stamp [ns], frame) from PoseStamped bytes, or (None, drop kind, why)."""
    try:
        stamp, frame, position, quat = messages.decode_pose_stamped(data)
    except Exception as exc:  # noqa: BLE001
        return None, "pose_malformed", f"could not be read: {exc}"
    yaw = yaw_from_quaternion(*(float(q) for q in quat))
    if not np.isfinite(position[:2]).all() or yaw is None:
        return None, "pose_nonfinite", "with a NaN/inf value or a zero quaternion"
    return (ToolPose(float(position[0]), float(position[1]), float(yaw)), stamp_to_ns(stamp), frame), "", ""


def read_jaw(data: bytes) -> tuple[float | None, str, str]:
    """The jaw angle from JointState bytes (None and no kind: none given yet), or (None, drop kind, why)."""
    try:
        _, jaw = decode_applied_jaw(data)
    except Exception as exc:  # noqa: BLE001
        return None, "jaw_malformed", f"could not be read: {exc}"
    if jaw is not None and not math.isfinite(jaw):
        return None, "jaw_nonfinite", f"with position[0]={jaw!r}"
    return jaw, "", ""


# --------------------------------------------------------------------------- out


class CommandOutput:
    """The controller's publishers: tool/twist, tool/jaw and tool/pose (in that order: the simulator steps with the
    pose), and control/markers. A publish while the node shuts down is dropped (``ok`` False)."""

    def __init__(self, pose: Any, twist: Any, jaw: Any, markers: Any, now_ns: Callable[[], int],
                 ok: Callable[[], bool]) -> None:
        self._pose, self._twist, self._jaw, self._markers = pose, twist, jaw, markers
        self._now_ns, self._ok = now_ns, ok

    def _publish(self, publisher: Any, data: bytes) -> None:
        try:
            publisher.publish(data)
        except Exception:  # noqa: BLE001  the context shut down under the worker (SIGTERM)
            if self._ok():
                raise

    def command(self, obs: Observation, dt_ns: int, pose: ToolPose, jaw: float, vx: float, vy: float,
                wz: float) -> None:
        """The command for the step after ``obs``: stamped with its stamp + dt, in its frame."""
        base = obs.stamp_ns if obs.stamp_ns > 0 else self._now_ns()
        stamp = stamp_from_ns(base + dt_ns)
        self._publish(self._twist, messages.encode_twist_stamped(stamp, obs.frame, vx, vy, wz))
        self._publish(self._jaw, messages.encode_joint_state(stamp, "", ["jaw"], [jaw]))
        self._publish(self._pose, messages.encode_pose_stamped(stamp, obs.frame, pose.x, pose.y, pose.yaw))

    def markers(self, obs: Observation, plan: np.ndarray | None, record: Any, start: np.ndarray | None,
                goal: np.ndarray | None) -> None:
        """control/markers: the last replan's candidates (grey), the chosen one (green), start and goal, the plan."""
        M = messages
        stamp, frame = stamp_from_ns(max(obs.stamp_ns, 0)), obs.frame
        out = [M.MarkerSpec("", 0, M.MARKER_ARROW, stamp, frame, action=M.ACTION_DELETEALL)]
        if record is not None and record.paths:
            for i, p in enumerate(record.paths):
                if len(p) >= 2 and np.isfinite(p).all():
                    out.append(M.MarkerSpec("control_candidates", i, M.MARKER_LINE_STRIP, stamp, frame,
                                            scale=(0.0005, 0.0, 0.0), color=(0.6, 0.6, 0.6, 0.6), points=p))
            if 0 <= record.best < len(record.paths) and np.isfinite(record.paths[record.best]).all():
                out.append(M.MarkerSpec("control_chosen", 0, M.MARKER_LINE_STRIP, stamp, frame,
                                        scale=(0.0015, 0.0, 0.0), color=(0.1, 0.9, 0.2, 1.0),
                                        points=record.paths[record.best]))
        if plan is not None:
            out.append(M.MarkerSpec("control_plan", 0, M.MARKER_LINE_STRIP, stamp, frame, scale=(0.001, 0.0, 0.0),
                                    color=(1.0, 0.55, 0.0, 1.0), points=plan[:, :2]))
        for ns, p, color in (("control_start", start, (0.2, 0.4, 1.0, 1.0)),
                             ("control_goal", goal, (1.0, 0.84, 0.0, 1.0))):
            if p is not None:
                out.append(M.MarkerSpec(ns, 0, M.MARKER_SPHERE, stamp, frame, position=(float(p[0]), float(p[1]), 0.0),
                                        scale=(0.003, 0.003, 0.003), color=color))
        self._publish(self._markers, M.encode_marker_array(out))


def _num(x: float | None) -> str:
    return "nan" if x is None or not math.isfinite(x) else f"{x:.6g}"


def diagnostics(name: str, p: Pursuit, drops: dict[str, int], settings: Any, jobs: int,
                niceness: int | None) -> DiagnosticStatus:
    """The controller's status from a copy of its pursuit (msg_docs/controller.md)."""
    level = DiagnosticStatus.OK if p.state in ("idle", "pursuing", "reached") else DiagnosticStatus.WARN
    values = {
        "state": p.state, "reason": p.reason, "last_refusal": p.last_refusal, "phase": p.phase,
        "goal_error_m": _num(p.goal_error), "observed_goal_error_m": _num(p.observed_error),
        "goal_particle": str(p.goal_particle),
        "start_m": "none" if p.start is None else f"{p.start[0]:.6g}, {p.start[1]:.6g}",
        "goal_m": "none" if p.goal is None else f"{p.goal[0]:.6g}, {p.goal[1]:.6g}",
        "grasp_site": "none" if p.grasp_site is None else str(p.grasp_site),
        "elapsed_s": _num(p.elapsed),
        "last_replan_ms": _num(p.last_replan_ms), "max_replan_ms": _num(p.max_replan_ms),
        "last_sync_ms": _num(p.last_sync_ms),
        "command_latency_ms_mean": _num(p.latency[0] / p.latency[1] if p.latency[1] else math.nan),
        "command_latency_ms_max": _num(p.latency[2] if p.latency[1] else math.nan),
        "candidates": str(settings.n_candidates), "horizon": str(settings.horizon), "jobs": str(jobs),
        "worker_niceness": "unknown" if niceness is None else str(niceness),
        **{k: str(n) for k, n in p.counts.items()},
        **{f"dropped_{k}": str(n) for k, n in drops.items()},
    }
    return DiagnosticStatus(level=level, name=name, hardware_id="tissue_controller",
                            message=p.state + (f": {p.reason}" if p.reason else ""),
                            values=[KeyValue(key=k, value=str(x)) for k, x in values.items()])


def diagnostic_array(status: DiagnosticStatus, stamp: Any, frame: str) -> DiagnosticArray:
    msg = DiagnosticArray()
    msg.header.stamp = stamp
    msg.header.frame_id = frame
    msg.status = [status]
    return msg
