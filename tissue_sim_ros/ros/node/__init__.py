"""TissueSimNode: tool pose in, tissue, energy and reaction out, at a fixed rate.

Run it::

    tissue_sim_node --ros-args --params-file config/tissue_sim.yaml

Every topic, frame, unit, QoS, parameter and service is described in
``msg_docs/``. The node converts messages and calls the library
(:class:`~tissue_sim_ros.core.sim.simulation.Simulation`); all physics lives there.

Timing: a timer at 1/dt of the node's clock (``use_sim_time`` honoured) steps
the simulation with the newest valid tool pose; in lock-step mode
(``lock_step: true``) every valid tool pose is one step and the outputs carry
that pose's stamp, so replaying a bag reproduces the run exactly. rcl timers
skip ticks that were missed rather than firing them back to back, so a slow
step never piles up: the node counts the overrun and the skipped ticks and
reports them on ``/diagnostics``.
"""
from __future__ import annotations

import gc
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import InvalidHandle, ParameterNotDeclaredException
from rclpy.executors import ExternalShutdownException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy_impl
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.time import Time
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Float64, Float64MultiArray
from std_srvs.srv import SetBool, Trigger
from visualization_msgs.msg import MarkerArray

from ...core.config import (
    FOREIGN_PREFIXES,
    METHOD_ALIASES,
    Config,
    closest_name,
    load_params_file,
    params_json,
    resolve_config,
)
from ...core.contact.tool import ToolPose, ToolTwist, twist_from_poses, yaw_from_quaternion
from ...core.errors import InputError
from ...core.sim.simulation import Simulation, StepReport
from ...core.timing.frames import FrameLookupError
from ...core.timing.phase_lock import PhaseLock
from ...core.timing.stamps import Stamp, stamp_from_ns, stamp_to_seconds
from .. import messages, qos, tool_applied
from ..marker_publisher import MarkerPublisher, MarkerSnapshot
from ..parameters import BY_NAME, PARAMETERS, SIM_NAMES, descriptor, parameter_value
from ..planner_service import PlannerService
from ..raw_publish import GilFreePublisher
from ..realtime import set_step_priority, thread_scheduling
from ..tf_input import FrameInput
from .clock_follow import ClockFollower
from .recording import NodeRecorder

_TAKE_MAX = 10
"""Queued tool messages a tick takes at most per topic (the subscriptions keep 10 in timer mode)."""

_SWITCH_INTERVAL = 0.0005
"""Seconds a thread may hold the GIL before another waiting thread gets it (Python's default: 0.005)."""


@dataclass
class NodeStats:
    """Counters reported on /diagnostics (cumulative since start)."""

    steps: int = 0
    overruns: int = 0
    """Steps whose processing (step + publishing) took longer than dt of wall time."""
    missed_ticks: int = 0
    """Timer ticks skipped because the previous one ran late."""
    divergences: int = 0
    dropped: dict[str, int] = field(default_factory=lambda: {
        "nonfinite": 0, "frame": 0, "stale": 0, "future": 0, "out_of_order": 0, "tool_jump": 0,
        "unpublished_nonfinite": 0})
    window_steps: int = 0
    window_step_time_sum: float = 0.0
    window_step_time_max: float = 0.0
    window_sim_time_sum: float = 0.0
    """Wall time inside Simulation.step (contact + solve + energy) over the window [s]."""
    window_start: float = field(default_factory=time.monotonic)


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


def _stamp_of(t: Time) -> Stamp:
    return stamp_from_ns(t.nanoseconds)


class UnknownParameter(ParameterNotDeclaredException):
    """A set of a name the node does not have; rclpy's services answer with this message as the reason."""

    def __init__(self, name: str) -> None:
        near = closest_name(name)
        hint = f"; did you mean {near!r}?" if near else "; the names are listed in msg_docs/parameters.md"
        Exception.__init__(self, f"unknown parameter {name!r}{hint}")


class TissueSimNode(Node):
    """The simulation as a ROS 2 node.

    Parameters
    ----------
    node_name : str
        Default ``tissue_sim_node`` (the section name in ``config/tissue_sim.yaml``).
    **kwargs
        Passed to :class:`rclpy.node.Node` (namespace, context, parameter_overrides, ...).

    Raises
    ------
    InputError
        A parameter has a bad value or the scene cannot be built; the message names it.
    """

    def __init__(self, node_name: str = "tissue_sim_node", **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        try:
            self._build()
        except BaseException:
            # a bad parameter, or SIGINT/SIGTERM while starting: end the threads already started (marker,
            # planner) and close the bag, or the interpreter's exit aborts on them ("terminate called ...")
            self.destroy_node()
            raise

    def _build(self) -> None:
        self.config: Config = self._declare_parameters()
        self._values = self.config.flat()
        self.sim: Simulation = Simulation.from_config(self.config)
        self._warm_up()
        self.stats = NodeStats()
        self.tool = ToolInput()
        self.last_report: StepReport | None = None
        self._last_warn: dict[str, float] = {}
        self._last_tick: int | None = None
        """Scheduled time of the step timer's next call after the last tick [ns of the node clock]."""
        self._steps_since_points = 0
        self._steps_since_markers = 0
        self._encoder = self._make_encoder()

        # 1 MB at 5k triangles: published without holding the GIL, so the step thread runs meanwhile (raw_publish.py)
        self.pub_markers = GilFreePublisher(
            self.create_publisher(MarkerArray, "tissue/markers", qos.state_stream(qos.MARKER_DEPTH)))
        self.pub_points = self.create_publisher(PointCloud2, "tissue/points", qos.state_stream())
        self.pub_rest = self.create_publisher(MarkerArray, "tissue/rest_mesh", qos.latched())
        self.pub_wrench = self.create_publisher(WrenchStamped, "tool/wrench", qos.state_stream())
        self.pub_energy = self.create_publisher(Float64, "tissue/energy", qos.energy())
        self.pub_energy_terms = {term: self.create_publisher(Float64, f"tissue/energy/{term}", qos.energy())
                                 for term in messages.ENERGY_TERMS[:3]}
        self.pub_energy_bodies = self.create_publisher(Float64MultiArray, "tissue/energy/bodies", qos.energy())
        # material: dt^2 E_strain (a term of the total) and the potential energy itself in J (msg_docs/topics.md)
        self.pub_energy_terms.update({term: self.create_publisher(Float64, f"tissue/energy/{term}", qos.energy())
                                      for term in ("strain", "potential")})
        self.pub_diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", qos.diagnostics())
        self.pub_applied_pose = self.create_publisher(PoseStamped, "tool/applied_pose", qos.state_stream())
        self.pub_applied_twist = self.create_publisher(TwistStamped, "tool/applied_twist", qos.state_stream())
        lock_step = self._values["lock_step"]
        self.frames = FrameInput(self, self._values, on_tool_transform=self._on_tool_transform, on_bad=self._drop)
        # with the message info: its reception time is the pose's arrival for the phase lock
        self.sub_pose = self.create_subscription(PoseStamped, "tool/pose", lambda msg, info: self._on_pose(msg, info),
                                                 qos.tool_input(lock_step))
        self.sub_twist = self.create_subscription(TwistStamped, "tool/twist", self._on_twist, qos.tool_input(lock_step))
        self.recorder: NodeRecorder | None = None
        if self._values["record_path"]:
            self._start_recording(self._values["record_path"], self._values["record_storage"])
        # markers are encoded and published on their own thread: the step thread never waits for 1 MB of DDS
        self.marker_worker = MarkerPublisher(
            lambda data: self.pub_markers.publish(data),
            on_error=self._marker_error,
            nice=self._values["marker_nice"])
        self.create_service(Trigger, "~/reset", self._on_reset)
        self.create_service(SetBool, "~/pause", self._on_pause)
        self.planner = PlannerService(self)  # ~/plan_insertion, on its own thread
        self.step_timer = None if lock_step else self.create_timer(self.sim.params.dt, self._on_tick)
        self._marker_due: MarkerSnapshot | None = None
        self._marker_sent = -math.inf
        self.marker_timer = (self.create_timer(1.0 / self._values["marker_rate"], self._flush_markers)
                             if lock_step else None)
        self._period_ns = None if self.step_timer is None else self.step_timer.timer_period_ns
        self.phase_lock = None if self._period_ns is None else PhaseLock(self._period_ns)
        self._stretched = False
        """The timer's period is stretched by the phase lock for one interval (restored at the next tick)."""
        self.clock_follower = (ClockFollower(self, self._on_clock_switch)
                               if not lock_step and self._values["follow_clock"]
                               and not self.get_parameter("use_sim_time").value else None)
        self.diagnostics_timer = self.create_timer(1.0 / self._values["diagnostics_rate"], self._publish_diagnostics)
        self.heap_trimmer = HeapTrimmer()
        self.memory_trace = MemoryTrace.from_env(self.get_logger())
        self.add_pre_set_parameters_callback(self._pre_set)
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self._publish_rest_mesh()
        m = self.sim.model
        self.get_logger().info(
            f"{m.n_particles} particles, {m.n_triangles} triangles, {m.n_bodies} bodies; method "
            f"{self.sim.params.method}/{self.sim.params.scheme}, {self.sim.params.iterations} iterations, contact "
            f"{self.sim.params.contact_model}; {'lock-step' if lock_step else f'{1.0 / self.sim.params.dt:g} Hz'} "
            f"in frame '{self._values['frame_id']}'; {self.frames.status}")

    def _warm_up(self) -> None:
        """Take a few throwaway steps (tool in the tissue) and reset, so JIT loading is not the first step's overrun."""
        q0 = self.sim.model.particle_q0
        if len(q0) == 0:
            return
        cx, cy = (q0.min(axis=0) + q0.max(axis=0)) / 2.0
        self.sim.step(None)
        if self.sim.tool is not None:
            self.sim.step(ToolPose(float(cx), float(cy), 0.0))
            self.sim.step(ToolPose(float(cx) + 1e-3, float(cy), 0.0))
        self.sim.reset()

    # ------------------------------------------------------------------ parameters

    def _declare_parameters(self) -> Config:
        """Resolve the parameters given to the node (file and -p) through the front door; declare them resolved.

        An unknown name, a type mismatch or a bad value raises InputError naming it.
        Each parameter is declared with its resolved value (a method alias such as
        ``xpbd_substep`` reads back as ``method: xpbd`` with its substeps and
        iterations), so ``ros2 param get`` shows what the simulation runs.
        """
        overrides = getattr(self, "_parameter_overrides", {})  # rclpy keeps the file's and -p values here
        given = {name: parameter_value(p.value) for name, p in overrides.items()
                 if not name.startswith(FOREIGN_PREFIXES)}
        cfg = resolve_config(overrides=given, source=f"the parameters of {self.get_name()}")
        flat = cfg.flat()
        for spec in PARAMETERS:
            self.declare_parameter(spec.name, flat[spec.name], descriptor(spec), ignore_override=True)
        return cfg

    def _pre_set(self, params: list[Parameter]) -> list[Parameter]:
        """Pre-set, before rclpy's own checks: an unknown name is refused naming the closest known one (rclpy's
        reason names neither); an integer for a float parameter becomes a float (the parameter stays a double
        for every reader); a method alias is expanded (:meth:`_expand_alias`)."""
        for p in params:
            if not self.has_parameter(p.name):
                raise UnknownParameter(p.name)
        params = [Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
                  if p.type_ == Parameter.Type.INTEGER and p.name in BY_NAME and BY_NAME[p.name].kind is float else p
                  for p in params]
        return self._expand_alias(params)

    def _expand_alias(self, params: list[Parameter]) -> list[Parameter]:
        """Pre-set: a method alias set at run time becomes the orthogonal values it resolves to."""
        method = next((p for p in params if p.name == "method"), None)
        if method is None or method.value not in METHOD_ALIASES:
            return params
        try:
            cfg = self.config.replace(**{p.name: parameter_value(p.value) for p in params if p.name in BY_NAME})
        except InputError:
            return params  # the set callback rejects it with the reason
        resolved = cfg.flat()
        names = {p.name for p in params}
        out = [p for p in params if p.name != "method"] + [Parameter("method", value=resolved["method"])]
        for key in METHOD_ALIASES[method.value]:
            if key != "method" and key not in names and resolved[key] != self._values[key]:
                out.append(Parameter(key, value=resolved[key]))
        return out

    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        """Check a set of tunable parameters as a whole; apply it only if all are fine."""
        changes: dict[str, Any] = {}
        for p in params:
            spec = BY_NAME.get(p.name)
            if spec is None:
                continue  # use_sim_time and friends: rclpy handles them
            if spec.read_only:
                return SetParametersResult(successful=False, reason=f"parameter {p.name} is read-only: restart the node to change it")
            changes[p.name] = parameter_value(p.value)
        if not changes:
            return SetParametersResult(successful=True)
        try:
            cfg = self.config.replace(**changes)
            changed = self.config.changed(cfg)
            if "frame_id" in changed:
                self.frames.check_plane(cfg.flat()["frame_id"])
            if any(name in SIM_NAMES for name in changed):
                self.sim.retune(cfg)
        except InputError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        old, new = self._values, cfg.flat()
        self.config, self._values = cfg, new
        if new["tf_tolerance"] != old["tf_tolerance"]:
            self.frames.buffer.tolerance_ns = int(new["tf_tolerance"] * 1e9)
        if any(new[k] != old[k] for k in ("strain_color_max", "wire_width", "markers_wireframe")):
            self._encoder = self._make_encoder()
        if new["frame_id"] != old["frame_id"]:
            self.frames.set_plane(self, new["frame_id"])  # poses in the old frame are no longer the plane's
            self._publish_rest_mesh()
        if self.marker_timer is not None and new["marker_rate"] != old["marker_rate"]:
            self.destroy_timer(self.marker_timer)
            self.marker_timer = self.create_timer(1.0 / new["marker_rate"], self._flush_markers)
        if new["diagnostics_rate"] != old["diagnostics_rate"]:
            self.destroy_timer(self.diagnostics_timer)
            self.diagnostics_timer = self.create_timer(1.0 / new["diagnostics_rate"], self._publish_diagnostics)
        if new["paused"] != old["paused"]:
            self.get_logger().info("paused" if new["paused"] else "running")
        return SetParametersResult(successful=True)

    def _make_encoder(self) -> messages.StepEncoder:
        return messages.StepEncoder(
            self.sim.model, self.sim.tool, strain_color_max=self._values["strain_color_max"],
            wire_width=self._values["wire_width"], wireframe=self._values["markers_wireframe"])

    def _output_publishers(self) -> dict[str, Any]:
        """The publisher of each step output (messages.STEP_TOPICS); looked up per call, as recording wraps them."""
        return {"tissue/energy": self.pub_energy,
                **{f"tissue/energy/{k}": p for k, p in self.pub_energy_terms.items()},
                "tissue/energy/bodies": self.pub_energy_bodies, "tool/wrench": self.pub_wrench,
                "tissue/points": self.pub_points, "tissue/markers": self.pub_markers}

    def _publish(self, out: messages.StepMessages) -> None:
        for reason in out.withheld:
            self._drop("unpublished_nonfinite", reason)
        pubs = self._output_publishers()
        for topic, data in out.messages.items():
            pubs[topic].publish(data)

    @property
    def frame_id(self) -> str:
        return self._values["frame_id"]

    @property
    def paused(self) -> bool:
        return bool(self._values["paused"])

    # ------------------------------------------------------------------ input

    def _warn(self, kind: str, message: str) -> None:
        """Log a warning at most once per ``warn_period`` for each kind."""
        now = time.monotonic()
        if now - self._last_warn.get(kind, -math.inf) >= self._values["warn_period"]:
            self._last_warn[kind] = now
            self.get_logger().warning(message)

    def _drop(self, kind: str, message: str) -> None:
        self.stats.dropped[kind] += 1
        self._warn(kind, f"dropped: {message} ({self.stats.dropped[kind]} dropped so far)")

    def _check_header(self, topic: str, stamp: tuple[int, int], frame: str, last: tuple[int, int]) -> bool:
        """Frame, order and age of an input message; False (and counted) when it must be dropped."""
        if frame != self.frame_id and not self.frames.knows(frame):
            self._drop("frame", f"{topic} in frame '{frame}': no transform from it to '{self.frame_id}' is known "
                                f"(frames known: {', '.join(sorted(self.frames.buffer.frames)) or 'none'})")
            return False
        if stamp == (0, 0):
            return True  # unstamped: no order or age to check
        max_age, max_future = self._values["max_stamp_age"], self._values["max_stamp_future"]
        now = self.get_clock().now()
        # a sim-time clock that has not received /clock yet reads 0: nothing to measure an age against
        if not self._values["lock_step"] and (max_age > 0 or max_future > 0) and now.nanoseconds > 0:
            age = (now - Time(seconds=stamp[0], nanoseconds=stamp[1],
                              clock_type=self.get_clock().clock_type)).nanoseconds * 1e-9
            if max_age > 0 and age > max_age:
                self._drop("stale", f"{topic} is {age:.3f} s old (max_stamp_age {max_age} s)")
                return False
            # a stamp from the future would make every later message look out of order until
            # the clock catches up: the tool would freeze, so it is the message that goes
            if max_future > 0 and -age > max_future:
                self._drop("future", f"{topic} is stamped {-age:.3f} s in the future (max_stamp_future "
                                     f"{max_future} s)")
                return False
        if last != (0, 0) and stamp <= last:
            self._drop("out_of_order", f"{topic} stamped {stamp_to_seconds(stamp):.6f} s, not after the "
                                       f"previous {stamp_to_seconds(last):.6f} s")
            return False
        return True

    def _on_pose(self, msg: PoseStamped, info: dict[str, Any] | None = None) -> None:
        """A tool/pose message; ``info`` (rclpy's message info) gives its reception time to the phase lock."""
        if self._values["lock_step"]:
            # the pose steps now: first every twist that arrived before it (the executor may run this callback
            # before the twist's, though the twist came first), and recorded before it in that order
            self._take_waiting(self.sub_twist)
        if self.recorder is not None:
            self.recorder.write(self.sub_pose.topic_name, msg)  # as received, before any check
        p, o = msg.pose.position, msg.pose.orientation
        yaw = yaw_from_quaternion(o.x, o.y, o.z, o.w)
        if not all(math.isfinite(v) for v in (p.x, p.y, p.z)) or yaw is None:
            self._drop("nonfinite", "tool/pose with a NaN/inf value or a zero quaternion")
            return
        stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        received = info.get("received_timestamp") if info else None
        self._take_pose("tool/pose", stamp, msg.header.frame_id, (p.x, p.y, p.z), (o.x, o.y, o.z, o.w),
                        arrival_ns=received or None)

    def _on_tool_transform(self, parent: str, stamp: tuple[int, int], translation: tuple[float, float, float],
                           rotation: tuple[float, float, float, float]) -> None:
        """A /tf transform of ``tool_frame``: the tool's pose in ``parent``."""
        self._take_pose(f"/tf {parent} -> {self._values['tool_frame']}", stamp, parent, translation, rotation)

    def _take_pose(self, topic: str, stamp: tuple[int, int], frame: str, position: tuple[float, float, float],
                   quaternion: tuple[float, float, float, float], arrival_ns: int | None = None) -> None:
        """Check a finite tool pose, take it into the plane, and use it (lock-step: step with it).

        ``arrival_ns``: when it was received (system clock) for the phase lock; None = now.
        """
        if not self._check_header(topic, stamp, frame, self.tool.pose_stamp):
            return
        x, y = position[0], position[1]
        if frame != self.frame_id:
            try:
                x, y, quaternion = self.frames.pose_to_plane(frame, stamp, position, quaternion)
            except FrameLookupError as exc:
                self._drop("frame", f"{topic} in frame '{frame}': {exc}")
                return
        yaw = yaw_from_quaternion(*quaternion)
        if yaw is None:
            self._drop("nonfinite", f"{topic}: its orientation is not a rotation in '{self.frame_id}'")
            return
        if not self._check_jump(x, y):
            return
        self.tool.pose = ToolPose(x, y, yaw)
        self.tool.pose_stamp = stamp
        self.tool.quaternion = quaternion
        if self.phase_lock is not None:
            self.phase_lock.arrival(arrival_ns if arrival_ns is not None else time.time_ns())
        if self._values["lock_step"] and not self.paused:
            twist = self.tool.twist_at(stamp) if (self._values["twist_source"] == "auto"
                                                  and stamp != (0, 0)) else None
            self._step(stamp if stamp != (0, 0) else _stamp_of(self.get_clock().now()), twist)

    def _on_twist(self, msg: TwistStamped) -> None:
        if self.recorder is not None:
            self.recorder.write(self.sub_twist.topic_name, msg)
        v, w = msg.twist.linear, msg.twist.angular
        if not all(math.isfinite(x) for x in (v.x, v.y, v.z, w.x, w.y, w.z)):
            self._drop("nonfinite", "tool/twist with a NaN/inf value")
            return
        stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        if not self._check_header("tool/twist", stamp, msg.header.frame_id, self.tool.twist_stamp):
            return
        vx, vy, wz = v.x, v.y, w.z
        if msg.header.frame_id != self.frame_id:
            try:
                vx, vy, wz = self.frames.twist_to_plane(msg.header.frame_id, stamp, (v.x, v.y, v.z), (w.x, w.y, w.z))
            except FrameLookupError as exc:
                self._drop("frame", f"tool/twist in frame '{msg.header.frame_id}': {exc}")
                return
        self.tool.twist = ToolTwist(vx, vy, wz)
        self.tool.twist_stamp = stamp
        self.tool.twist_received = self.get_clock().now().nanoseconds * 1e-9
        self.tool.keep_twist(stamp, self.tool.twist)

    def _on_clock_switch(self, following: bool) -> None:
        """The node's clock changed between /clock and the system clock: forget the input stamps."""
        self.tool.pose_stamp = self.tool.twist_stamp = (0, 0)
        self.tool.twist_received = -math.inf
        self.tool.recent_twists.clear()
        self._last_tick = None
        if self.phase_lock is not None:
            self.phase_lock.reset()
        self.get_logger().info(
            "a /clock is published: following it (use_sim_time on) while it lasts (follow_clock: false keeps the "
            "system clock)" if following else "no /clock publisher any more: back to the system clock")

    def _check_jump(self, x: float, y: float) -> bool:
        """False (and counted) when a pose lies farther than max_tool_jump from the tool's last accepted pose.

        The tool then holds its pose; it follows again once a pose within
        max_tool_jump of it arrives, or after ~/reset (when any pose is accepted).
        """
        last = self.tool.pose if self.tool.pose is not None else self.sim.tool_pose
        if last is None:
            return True
        dist = math.hypot(x - last.x, y - last.y)
        max_jump = self._values["max_tool_jump"]
        if dist <= max_jump:
            return True
        self._drop("tool_jump", f"tool/pose ({x:.4g}, {y:.4g}) is {dist:.3f} m from the tool at ({last.x:.4g}, "
                                f"{last.y:.4g}) (max_tool_jump {max_jump} m): the tool holds its pose until a pose "
                                "within max_tool_jump of it arrives, or ~/reset")
        return False

    def _tool_for_step(self) -> tuple[ToolPose | None, ToolTwist | None]:
        """The pose to use this step and the twist (None: derive from poses)."""
        pose = self.tool.pose
        if pose is None:
            return None, None
        twist = None
        if self._values["twist_source"] == "auto" and self.tool.twist is not None:
            age = self.get_clock().now().nanoseconds * 1e-9 - self.tool.twist_received
            if age <= self._values["twist_timeout"]:
                twist = self.tool.twist
        return pose, twist

    # ------------------------------------------------------------------ stepping

    def _on_tick(self) -> None:
        now = self.get_clock().now()
        # rcl keeps the timer on its schedule and, when a tick is late by more than a
        # period, skips the ticks missed; the next scheduled call tells how many it skipped
        next_call = now.nanoseconds + self.step_timer.time_until_next_call()
        if self._last_tick is not None:
            missed = int(round((next_call - self._last_tick) / self.step_timer.timer_period_ns)) - 1
            if missed > 0:
                self.stats.missed_ticks += missed
        self._last_tick = next_call
        self._steer_phase(next_call)
        if self.paused:
            return
        self._take_queued_input()
        self._step(_stamp_of(now), None, from_timer=True)

    def _steer_phase(self, next_call: int) -> None:
        """Phase lock: move the timer's ticks to just after the poses' arrivals (core/timing/phase_lock.py).

        A shift s stretches one interval: the period is set to dt + s now, rcl
        computes the call after the next one from it, and the next tick puts dt
        back. Only on the system clock (arrivals are received times on it).
        """
        period = self.step_timer.timer_period_ns
        if self._stretched:
            self.step_timer.timer_period_ns = self._period_ns
            self._stretched = False
        if self.get_clock().ros_time_is_active:
            return
        # this tick's scheduled time; with the parameter off the lock only measures (the wait on /diagnostics)
        shift = self.phase_lock.tick(next_call - period, steer=self._values["phase_lock"])
        if shift:
            self.step_timer.timer_period_ns = self._period_ns + shift
            self._stretched = True
            st = self.phase_lock.status
            self.get_logger().debug(
                f"phase lock: ticks moved by {shift * 1e-6:+.2f} ms (median wait {_ms(st.wait_median_ns):.2f} ms, "
                f"jitter {_ms(st.jitter_ns):.2f} ms, concentration {st.concentration:.2f}, gain {_ms(st.gain_ns):.2f} ms, "
                f"{st.shifts} shifts)")

    def _take_queued_input(self) -> None:
        """Take the tool messages already received before stepping (the executor runs a ready timer first)."""
        for sub in (self.sub_twist, self.sub_pose):
            self._take_waiting(sub)

    def _take_waiting(self, sub: Any) -> None:
        """Run ``sub``'s callback on the messages it has received and the executor has not handed out yet."""
        for _ in range(_TAKE_MAX):
            try:
                with sub.handle:
                    taken = sub.handle.take_message(sub.msg_type, sub.raw)
            except InvalidHandle:
                return
            if taken is None:
                return
            if sub is self.sub_pose:
                self._on_pose(*taken)
            else:
                self._on_twist(taken[0])

    def _step(self, stamp: tuple[int, int], twist: ToolTwist | None, from_timer: bool = False) -> None:
        """One simulation step and its messages; ``stamp`` stamps every output."""
        t0 = time.perf_counter()
        if from_timer:
            pose, twist = self._tool_for_step()
        else:
            pose = self.tool.pose
        if pose is None:
            twist = ToolTwist()
        elif twist is None:
            # derived here, by the Simulation's own formula, so the twist used can be published and replayed
            twist = twist_from_poses(self.sim.tool_pose, pose, self.sim.params.dt)
        quaternion = self.tool.quaternion
        report = self.sim.step(pose, twist)
        self.last_report = report
        self.stats.steps += 1
        if report.diverged:
            self.stats.divergences += 1
            self._warn("diverged", f"step {report.step}: the solver diverged; restored the last good state "
                                   f"({self.stats.divergences} divergences so far)")
        self._publish_step(stamp, report)
        # what this step used, for an exact offline replay (tool_applied.py); last, so that a step whose
        # applied tool is out (and recorded) has all its outputs out too, even when a signal ends the node
        if pose is not None:
            self.pub_applied_pose.publish(tool_applied.encode_applied_pose(stamp, self.frame_id, pose.x, pose.y,
                                                                           quaternion))
        self.pub_applied_twist.publish(tool_applied.encode_applied_twist(stamp, self.frame_id, twist))
        elapsed = time.perf_counter() - t0
        s = self.stats
        s.window_steps += 1
        s.window_step_time_sum += elapsed
        s.window_step_time_max = max(s.window_step_time_max, elapsed)
        s.window_sim_time_sum += report.timings.get("total", 0.0)
        if elapsed > self.sim.params.dt:
            s.overruns += 1
            self._warn("overrun", f"step {report.step} took {elapsed * 1e3:.1f} ms > dt {self.sim.params.dt * 1e3:.1f} ms "
                                  f"({s.overruns} overruns in {s.steps} steps)")

    def _every(self, rate: float) -> int:
        """Publish every this many steps for a rate [Hz] (at least every step)."""
        return max(1, int(round(1.0 / (self.sim.params.dt * rate))))

    def _start_recording(self, path: str, storage: str) -> None:
        """Wrap every publisher so what it publishes is also written to the bag; record the tool inputs."""
        if os.path.exists(path):
            raise InputError(f"parameter record_path={path!r}: that path exists; expected a new bag directory")
        self.recorder = NodeRecorder(self, path, storage)
        # what `tissue-sim replay --mode applied` needs to rebuild this very Simulation from the bag alone
        self.recorder.writer.set_custom_data("tissue_sim.params", params_json(self.config))
        for name in ("pub_markers", "pub_points", "pub_rest", "pub_wrench", "pub_energy", "pub_energy_bodies",
                     "pub_diagnostics", "pub_applied_pose", "pub_applied_twist"):
            setattr(self, name, self.recorder.wrap(getattr(self, name)))
        self.pub_energy_terms = {k: self.recorder.wrap(p) for k, p in self.pub_energy_terms.items()}
        for sub in (self.sub_pose, self.sub_twist, *self.frames.subs):
            self.recorder.add(sub.topic_name, sub.msg_type, sub.qos_profile)
        self.frames.record = self.recorder.write
        self.get_logger().info(f"recording every message in and out to {path} ({storage})")

    def _marker_error(self, exc: Exception) -> None:
        """The marker thread could not publish: a warning, unless the node is shutting down (SIGINT/SIGTERM: rcl
        then refuses the last array, which loses nothing a reader could still receive)."""
        if rclpy.ok(context=self.context):
            self._warn("markers", f"tissue/markers not published: {exc}")

    def destroy_node(self) -> None:
        """Stop the marker and planner threads, close the bag, destroy the node (also of one half built)."""
        for name in ("marker_worker", "planner", "recorder"):  # the markers before the bag: their last go in
            part = getattr(self, name, None)
            if part is not None:
                part.close()
        super().destroy_node()

    def _publish_step(self, stamp: tuple[int, int], report: StepReport) -> None:
        self._steps_since_points += 1
        self._steps_since_markers += 1
        publish_points = self._steps_since_points >= self._every(self._values["points_rate"])
        publish_markers = self._steps_since_markers >= self._every(self._values["marker_rate"])
        if publish_points:
            self._steps_since_points = 0
        if publish_markers:
            self._steps_since_markers = 0
        q = self.sim.state.particle_q
        self._publish(self._encoder.encode(stamp, self.frame_id, report, q, points=publish_points, markers=False))
        if not np.isfinite(q).all():
            return
        if self.step_timer is None:
            # lock-step: poses come at any rate and may stop; markers at marker_rate by the clock, and the newest
            # state is kept due until the flush timer hands it over (the last pose's state is always shown)
            self._marker_due = self._marker_snapshot(stamp, report, q)
            self._flush_markers()
        elif publish_markers:
            # encoded and published on the marker worker's thread, newest state only: never blocks the step
            self.marker_worker.submit(self._marker_snapshot(stamp, report, q))

    def _marker_snapshot(self, stamp: tuple[int, int], report: StepReport, q: np.ndarray) -> MarkerSnapshot:
        pose = self.sim.tool_pose
        contact = report.contact_particles
        return MarkerSnapshot(
            self._encoder.scene, stamp, self.frame_id, q.copy(),
            tool_pose=None if pose is None else (pose.x, pose.y, pose.yaw),
            tool_stamp=self.tool.pose_stamp if pose is not None else None,
            contact_particles=None if contact is None else np.array(contact))

    def _flush_markers(self) -> None:
        """Lock-step: hand the newest unshown state to the marker worker if 1/marker_rate has passed since the last."""
        if self._marker_due is None:
            return
        now = time.monotonic()
        if now - self._marker_sent >= 1.0 / self._values["marker_rate"]:
            self.marker_worker.submit(self._marker_due)
            self._marker_due, self._marker_sent = None, now

    def _publish_rest_mesh(self) -> None:
        self.pub_rest.publish(self._encoder.rest_markers(_stamp_of(self.get_clock().now()), self.frame_id,
                                                         self.sim.model))

    def _publish_state_now(self) -> None:
        """Points and markers of the current state, outside the step cadence (after a reset)."""
        self._publish(self._encoder.state(_stamp_of(self.get_clock().now()), self.frame_id, self.sim.state.particle_q))

    # ------------------------------------------------------------------ services

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        self.sim.reset()
        self.tool = ToolInput()
        self._last_tick = None
        self._publish_state_now()
        response.success = True
        response.message = f"reset to the rest mesh ({self.sim.model.n_particles} particles), t = 0"
        self.get_logger().info(response.message)
        return response

    def _on_pause(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        result = self.set_parameters([Parameter("paused", Parameter.Type.BOOL, bool(request.data))])[0]
        response.success = result.successful
        response.message = ("paused" if request.data else "running") if result.successful else result.reason
        return response

    # ------------------------------------------------------------------ diagnostics

    def _phase_lock_values(self) -> dict[str, Any]:
        """The phase lock's state and measurements for /diagnostics (msg_docs/topics.md)."""
        lock = self.phase_lock
        if lock is None:
            return {"phase_lock": "off"}
        st = lock.status
        return {"phase_lock": "off" if self.get_clock().ros_time_is_active else st.state, "phase_shifts": st.shifts,
                "phase_shift_total_ms": _ms(st.shift_total_ns), "phase_shift_last_ms": _ms(st.last_shift_ns),
                "pose_wait_median_ms": _ms(st.wait_median_ns), "pose_jitter_ms": _ms(st.jitter_ns),
                "pose_phase_concentration": st.concentration, "phase_samples": st.samples}

    def _publish_diagnostics(self) -> None:
        s, w = self.stats, self.marker_worker
        now = time.monotonic()
        self.heap_trimmer.maybe_trim(now)
        if self.memory_trace is not None:
            self.memory_trace.maybe_report(now)
        window = max(now - s.window_start, 1e-9)
        r = self.last_report
        level = DiagnosticStatus.OK
        message = "paused" if self.paused else "running"
        if s.window_steps and s.window_step_time_max > self.sim.params.dt:
            level, message = DiagnosticStatus.WARN, f"{message}; a step overran dt in the last {window:.1f} s"
        if r is not None and r.diverged:
            level, message = DiagnosticStatus.ERROR, f"{message}; the last step diverged (state restored)"
        values = {
            "steps": s.steps,
            "step_rate_hz": s.window_steps / window,
            "step_time_mean_ms": 1e3 * s.window_step_time_sum / max(s.window_steps, 1),
            "step_time_max_ms": 1e3 * s.window_step_time_max,
            "sim_step_ms_mean": 1e3 * s.window_sim_time_sum / max(s.window_steps, 1),
            "overruns": s.overruns,
            "missed_ticks": s.missed_ticks,
            "divergences": s.divergences,
            "markers_published": w.published,
            "markers_skipped": w.skipped,
            "marker_encode_ms_mean": 1e3 * w.encode_seconds / max(w.published + w.errors, 1),
            "marker_thread_niceness": "unknown" if w.niceness is None else w.niceness,
            "step_thread_scheduling": thread_scheduling(),  # this timer runs on the step thread
            "markers_gil_free": self.pub_markers.gil_free,
            "heap_trims": self.heap_trimmer.trims,
            "heap_trim_ms_max": 1e3 * self.heap_trimmer.seconds_max,
            **self._phase_lock_values(),
            **{f"dropped_{k}": v for k, v in s.dropped.items()},
            "paused": self.paused,
            "lock_step": self._values["lock_step"],
            "method": self.sim.params.method,
            "scheme": self.sim.params.scheme,
            "iterations": self.sim.params.iterations,
            "substeps": self.sim.params.substeps,
            "contact_model": self.sim.params.contact_model,
            "bodies": ",".join(str(n).replace(",", " ") for n in self.sim.model.body_names),
            "sim_time_s": self.sim.time,
        }
        if r is not None:
            values.update({
                "in_contact": ",".join(str(bool(c)).lower() for c in r.in_contact),
                "d_star_m": ",".join(f"{d:.6g}" for d in r.d_star),
                "contact_particles": r.n_contact_particles,
                "residual": r.residual,
                "inverted_triangles": r.n_inverted,
                "energy_total": r.energy.scene_total,
                "energy_potential_j": r.energy.scene_potential,
                "material": self.sim.params.material,
                "tool_penetrating_particles": r.n_penetrating,
                "tool_penetration_depth_m": r.penetration_depth,
                "tool_tunnelled_particles": r.n_tunnelled,
                "tool_buried_in_tissue": r.tool_buried,
            })
            if r.tool_buried and level == DiagnosticStatus.OK:
                level, message = DiagnosticStatus.WARN, f"{message}; the tool is buried in the tissue"
        status = DiagnosticStatus(level=level, name=f"{self.get_fully_qualified_name()}: simulation",
                                  message=message, hardware_id="tissue_sim",
                                  values=[KeyValue(key=k, value=f"{v:.6g}" if isinstance(v, float) else str(v).lower()
                                                   if isinstance(v, bool) else str(v)) for k, v in values.items()])
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        array.header.frame_id = self.frame_id  # the frame of everything this node publishes (msg_docs/topics.md)
        self.pub_diagnostics.publish(array)
        s.window_steps, s.window_step_time_sum, s.window_step_time_max, s.window_start = 0, 0.0, 0.0, now
        s.window_sim_time_sum = 0.0


def _ms(ns: float) -> float:
    return ns * 1e-6


def _params_files(argv: list[str]) -> list[str]:
    """The ``--params-file`` paths inside the ``--ros-args`` sections of a command line."""
    files, in_ros, it = [], False, iter(argv)
    for arg in it:
        if arg == "--ros-args":
            in_ros = True
        elif arg == "--":
            in_ros = False
        elif in_ros and arg == "--params-file":
            files.append(next(it, ""))
    return files


def _glibc_function(name: str):
    """glibc's function ``name`` through ctypes, or None where there is no glibc (or no such function)."""
    import ctypes  # noqa: PLC0415
    import ctypes.util  # noqa: PLC0415

    lib = ctypes.util.find_library("c")
    if sys.platform != "linux" or lib is None:
        return None
    try:
        return getattr(ctypes.CDLL(lib), name)
    except (OSError, AttributeError):
        return None


def _fix_mmap_threshold() -> None:
    """glibc: serve every allocation above 128 KiB by mmap, returned to the system when freed.

    A MarkerArray is ~1 MB of bytes made and dropped 30 times a second on the
    marker thread. glibc raises its mmap threshold after such frees, so later
    ones come from the heap and its arenas, which then keep growing (the soak
    showed +1 MiB steps under load). A fixed threshold keeps them out of the
    heap. No-op where there is no glibc.
    """
    mallopt = _glibc_function("mallopt")
    if mallopt is not None:
        mallopt(_M_MMAP_THRESHOLD, 128 * 1024)


_M_MMAP_THRESHOLD = -3
"""glibc's mallopt() parameter number (malloc.h)."""


class HeapTrimmer:
    """Give the heap's free pages back to the system every ``period`` seconds (glibc ``malloc_trim(0)``).

    Small allocations made and freed on two threads (step and markers) leave free
    pages inside glibc's arenas that it keeps; over an hour they show as resident
    memory that only grows under load. ``malloc_trim`` returns them (measured: a
    fraction of a millisecond on the node). Called from the diagnostics timer,
    never from the step. No-op where there is no glibc.
    """

    def __init__(self, period: float = 10.0) -> None:
        self.period = period
        self.trims = 0
        self.seconds_max = 0.0
        self._next = time.monotonic() + period
        self._trim = _glibc_function("malloc_trim")

    def maybe_trim(self, now: float) -> None:
        if self._trim is None or now < self._next:
            return
        self._next = now + self.period
        t0 = time.perf_counter()
        self._trim(0)
        self.seconds_max = max(self.seconds_max, time.perf_counter() - t0)
        self.trims += 1


class MemoryTrace:
    """Debugging a memory creep: Python allocations that grew since a baseline, logged every ``period`` s.

    On when the environment variable ``TISSUE_SIM_TRACEMALLOC`` gives the period
    [s] (e.g. ``TISSUE_SIM_TRACEMALLOC=60 tissue-sim bench node --soak 600``: the
    bench's node inherits it and logs to its log file). The baseline is taken one
    period after start (after warm-up); each report lists the ``top`` source lines
    whose live allocations grew most since, with the traced total. tracemalloc
    slows every allocation: not for timing runs.
    """

    ENV = "TISSUE_SIM_TRACEMALLOC"

    def __init__(self, logger: Any, period: float, top: int = 10) -> None:
        import tracemalloc  # noqa: PLC0415

        self._tm = tracemalloc
        self.logger, self.period, self.top = logger, period, top
        tracemalloc.start(12)
        self._baseline = None
        self._next = time.monotonic() + period

    @classmethod
    def from_env(cls, logger: Any) -> "MemoryTrace | None":
        value = os.environ.get(cls.ENV, "")
        if not value:
            return None
        try:
            period = float(value)
        except ValueError:
            period = math.nan
        if not (math.isfinite(period) and period > 0):
            logger.warning(f"{cls.ENV}={value!r}: expected a period > 0 s; not tracing")
            return None
        return cls(logger, period)

    def maybe_report(self, now: float) -> None:
        if now < self._next:
            return
        self._next = now + self.period
        snapshot = self._tm.take_snapshot().filter_traces((self._tm.Filter(False, self._tm.__file__),))
        if self._baseline is None:
            self._baseline = snapshot
            self.logger.info(f"tracemalloc baseline: {self._tm.get_traced_memory()[0] / 2**20:.2f} MiB traced")
            return
        stats = snapshot.compare_to(self._baseline, "traceback")
        lines = [f"tracemalloc: {self._tm.get_traced_memory()[0] / 2**20:.2f} MiB traced; grown since the baseline:"]
        for stat in stats[:self.top]:
            # innermost frame first (a Traceback runs from the oldest frame to the most recent)
            frames = " <- ".join(f"{Path(f.filename).name}:{f.lineno}" for f in reversed(stat.traceback[-6:]))
            lines.append(f"  {stat.size_diff / 1024:+.1f} KiB ({stat.count_diff:+d} blocks) {frames}")
        self.logger.info("\n".join(lines))


def main(args: list[str] | None = None) -> int:
    """Console script ``tissue_sim_node``: exit 0 on SIGINT/SIGTERM, 2 on a bad parameter (named)."""
    try:
        # read every --params-file ourselves first: a malformed one is one line naming it and where,
        # before rcl logs its own parse error
        for path in _params_files(sys.argv if args is None else args):
            load_params_file(path)
    except InputError as exc:
        print(f"tissue_sim_node: error: {exc}", file=sys.stderr)
        return 2
    try:
        rclpy.init(args=args)
    except Exception as exc:  # noqa: BLE001  rcl's parse errors (a missing or malformed --params-file)
        print(f"tissue_sim_node: error: {exc}", file=sys.stderr)
        return 2
    node = None
    code = 0
    try:
        node = TissueSimNode()
        # everything built so far lives as long as the node: keep the collector from rescanning it each step
        gc.collect()
        gc.freeze()
        # the marker worker holds the GIL while it encodes; a short switch interval hands it back to a
        # waking step within 0.5 ms instead of Python's default 5 ms
        sys.setswitchinterval(_SWITCH_INTERVAL)
        _fix_mmap_threshold()
        # this thread spins the executor: steps, poses and services run on it
        refused = set_step_priority(node.get_parameter("step_rt_priority").value)
        if refused is not None:
            node.get_logger().warning(refused)
        rclpy.spin(node)
    except InputError as exc:
        print(f"tissue_sim_node: error: {exc}", file=sys.stderr)
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except _rclpy_impl.RCLError:
        # SIGTERM/SIGINT shut the context down while a callback was publishing: a clean shutdown
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            node.destroy_node()
        try:
            rclpy.try_shutdown()
        except _rclpy_impl.RCLError:
            pass  # the signal handler shut the context down meanwhile ("rcl_shutdown already called")
    return code


if __name__ == "__main__":
    sys.exit(main())
