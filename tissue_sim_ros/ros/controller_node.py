"""``tissue_controller``: the model-predictive grasp controller (issue 31) as a node of its own, beside the simulator.

Like a robot's controller beside the simulator (or beside the real robot), it sees only what a tracker and the
robot give: the tissue's points (``points_topic``, sensor_msgs/PointCloud2 in the tissue plane's frame), the
measured tool pose (``pose_topic``, PoseStamped) and jaw (``jaw_topic``, JointState ``position[0]``), and keeps
its own model of the tissue (:class:`~tissue_sim_ros.core.plan.control.TissueController` on the scene
``scene``, optionally another ``params_file`` and its own ``young_modulus``...: a model that need not be the
world). ``~/move_tissue`` (nav_msgs/srv/GetPlan) takes a goal: ``start`` the tissue point to move, ``goal``
where it should go; it answers at once with the plan (the tool's waypoints) or an empty path and a logged
reason. While it pursues a goal, each new points message is one control step: the command
(:meth:`~tissue_sim_ros.core.plan.control.TissueController.command`) from those points, the newest pose and
jaw, published on ``tool/twist``, ``tool/jaw`` and ``tool/pose`` stamped with the points' stamp + dt (the
step it is meant for). The goal is reached when the controller holds with its goal error within
``goal_tolerance`` for ``hold_time``; then it keeps publishing that pose. It gives up after ``max_time``, or
on a command that is not finite (never published), with the reason on /diagnostics and in the log.

Threading: the executor (two threads: subscriptions and the diagnostics timer in one callback group, the
service in another) only stores the newest observation and answers; a worker thread owns the controller and
makes every call into it (the requests' ``set_goal`` and ``planned_path``, each step's ``command``) in the
order they come, so nothing planning does blocks a subscription, and a run is as deterministic as the
observations it was given. A replan longer than dt makes the worker skip to the newest points (counted as
``skipped_points``); the simulator meanwhile holds the last pose. ``msg_docs/controller.md`` describes the
interface; the parameter tables and the start-up warm-up are in :mod:`~tissue_sim_ros.ros.controller_setup`.
"""
from __future__ import annotations

import math
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import rclpy
from builtin_interfaces.msg import Time as TimeMsg
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, TwistStamped
from nav_msgs.msg import Path
from nav_msgs.srv import GetPlan
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import JointState, PointCloud2
from visualization_msgs.msg import MarkerArray

from ..core.config import BY_NAME, coerce, resolve_config
from ..core.contact.tool import ToolPose, yaw_from_quaternion
from ..core.errors import InputError
from ..core.plan.control import ControlSettings, TissueController, default_model
from ..core.timing.stamps import ns_from_seconds, stamp_from_ns, stamp_to_ns
from . import messages, qos
from .controller_setup import (
    MODEL_PARAMETERS,
    NODE_PARAMETERS,
    model_config,
    settings_defaults,
    settings_rows,
    sim_descriptor,
    typed_value,
    warm_up,
)
from .realtime import SWITCH_INTERVAL, nice_this_thread
from .throttle import ThrottledWarnings
from .tool_applied import decode_applied_jaw, planar_quaternion
from .usage import init_rclpy, msg_docs_dir, parameter_list, usage_head, wants_help

NODE_NAME = "tissue_controller"


#: Keys of the dropped-message counts on /diagnostics.
DROP_KINDS = ("points_empty", "points_nonfinite", "points_shape", "points_frame", "points_malformed",
              "pose_nonfinite", "pose_frame", "pose_malformed", "jaw_nonfinite", "jaw_malformed")
STATES = ("idle", "pursuing", "reached", "gave up", "refused")
#: Records of replans kept (each holds its candidates' paths).
KEEP_RECORDS = 20



@dataclass
class Observation:
    """The newest points: stamp [ns], frame, positions (N, 2) [m]."""

    stamp_ns: int
    frame: str
    xy: np.ndarray


@dataclass
class MoveRequest:
    """A ``~/move_tissue`` request handed to the worker, and its answer."""

    start: tuple[float, float]
    goal: tuple[float, float]
    obs: Observation
    pose: ToolPose
    jaw: float
    done: threading.Event
    path: np.ndarray | None = None
    reason: str = ""


class TissueControllerNode(Node):
    """The node (module docstring). ``close()`` stops the worker and the rollout pool."""

    def __init__(self, node_name: str = NODE_NAME, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.values: dict[str, Any] = {}
        for name, (default, description) in NODE_PARAMETERS.items():
            value = self.declare_parameter(name, default, ParameterDescriptor(
                description=description, read_only=True, dynamic_typing=True)).value
            self.values[name] = typed_value(name, value, default)
        rows = settings_rows()
        for name, default in settings_defaults().items():
            value = self.declare_parameter(name, default, ParameterDescriptor(
                description=rows[name][1], read_only=True, dynamic_typing=True)).value
            self.values[name] = typed_value(name, value, default)
        v = self.values
        for name in ("max_time", "hold_time", "diagnostics_rate", "warn_period"):
            if v[name] < 0 or (v[name] == 0 and name in ("max_time", "diagnostics_rate")):
                raise InputError(f"parameter {name}={v[name]!r}: expected a value > 0"
                                 + (" (hold_time, warn_period: >= 0)" if name in ("hold_time", "warn_period") else ""))
        if not 0 <= v["nice"] <= 19:
            raise InputError(f"parameter nice={v['nice']!r}: expected 0 to 19")
        if v["jobs"] < 1:
            raise InputError(f"parameter jobs={v['jobs']!r}: expected at least 1 (1 = serially in the node)")
        files, base = model_config(v["scene"], v["params_file"])
        flat = base.flat()
        overrides = {}
        defaults = {**flat, **default_model(base)}  # the model's mesh: coarser than the scene's
        for name in MODEL_PARAMETERS:
            spec = BY_NAME[name]
            value = coerce(spec, self.declare_parameter(name, defaults[name], sim_descriptor(spec)).value)
            if value != flat[name]:
                overrides[name] = value
        self.config = resolve_config(overrides, params_file=files, source="the controller's parameters")
        self.settings = ControlSettings(**{attr: v[name] for name, (attr, _) in rows.items()})
        self.ctrl = TissueController(self.config, self.settings, records_kept=KEEP_RECORDS)
        self.dt = float(self.config.sim.dt)
        self.dt_ns = ns_from_seconds(self.dt)
        log = self.get_logger()
        if v["warm_up"]:
            # in this process (numba caches the kernels on disk, so the pool's workers load them)
            t0 = time.perf_counter()
            note = warm_up(self.config, self.settings)
            log.info(f"warm-up on the model: {time.perf_counter() - t0:.2f} s{note}")
        self.warnings = ThrottledWarnings(log, dict.fromkeys(DROP_KINDS, 0), lambda: v["warn_period"])
        # shared between the executor's callbacks and the worker, under self.cond
        self.cond = threading.Condition()
        self.obs: Observation | None = None
        self.n_points: int | None = None
        self.plane_frame: str | None = None
        self.pose: ToolPose | None = None
        self.pose_ns = -1
        self.jaw: float | None = None
        self.request: MoveRequest | None = None
        self.stopping = False
        self.obs_taken = True
        # the pursuit (written by the worker; read by diagnostics)
        self.state = "idle"
        self.reason = ""
        self.last_refusal = ""
        self.phase = "none"
        self.goal_error = math.nan
        self.observed_error = math.nan
        self.start: np.ndarray | None = None
        self.goal: np.ndarray | None = None
        self.goal_particle = -1
        self.goal_point = -1
        """The observed point nearest the start at the request (its index in the cloud)."""
        self.t_start_ns = 0
        self.elapsed = 0.0
        self.held_since_ns: int | None = None
        self.hold_cmd: tuple[ToolPose, float] | None = None
        self.counts = {"points_received": 0, "poses_received": 0, "jaws_received": 0, "requests": 0,
                       "accepted": 0, "refused": 0, "commands": 0, "skipped_points": 0, "replans": 0,
                       "unpublished_nonfinite": 0}
        self.last_replan_ms = math.nan
        self.max_replan_ms = math.nan
        self.last_sync_ms = math.nan
        self.latency = (0.0, 0, 0.0)
        """Of the commands for the current goal: (sum, count, max) of the points' stamp to publication [ms]."""
        # ROS interface
        inputs = qos.observation_input()
        for name, kind, callback in (("points_topic", PointCloud2, self._on_points),
                                     ("pose_topic", PoseStamped, self._on_pose),
                                     ("jaw_topic", JointState, self._on_jaw)):
            try:
                self.create_subscription(kind, v[name], callback, inputs, raw=True)
            except Exception as exc:  # noqa: BLE001  rclpy's invalid-name errors
                first = str(exc).splitlines()[0].rstrip(":")
                raise InputError(f"parameter {name}={v[name]!r}: expected a valid topic name ({first})") from None
        self.pub_pose = self.create_publisher(PoseStamped, "tool/pose", qos.tool_output())
        self.pub_twist = self.create_publisher(TwistStamped, "tool/twist", qos.tool_output())
        self.pub_jaw = self.create_publisher(JointState, "tool/jaw", qos.tool_output())
        self.pub_markers = self.create_publisher(MarkerArray, "control/markers", qos.latched())
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", qos.diagnostics())
        self.create_timer(1.0 / v["diagnostics_rate"], self._publish_diagnostics)
        if v["jobs"] > 1:  # last but the worker: nothing after it can fail and leave the workers running
            from ..core.sim.batch import RolloutPool  # noqa: PLC0415  (worker processes only when asked for)

            self.ctrl.pool = RolloutPool(self.ctrl.scene, workers=v["jobs"], nice=v["nice"])
        self.worker_niceness: int | None = None
        self.worker = threading.Thread(target=self._work, name="controller", daemon=True)
        self.worker.start()
        self.service = self.create_service(GetPlan, "~/move_tissue", self._on_move,
                                           callback_group=MutuallyExclusiveCallbackGroup())
        log.info(f"ready: ~/move_tissue; model {v['scene']}{' + ' + v['params_file'] if v['params_file'] else ''}"
                 f"{''.join(f', {k} {x:g}' for k, x in overrides.items() if isinstance(x, float))}; "
                 f"{self.settings.n_candidates} candidates x {self.settings.horizon} steps every "
                 f"{self.settings.replan_every} steps ({'serially' if v['jobs'] == 1 else str(v['jobs']) + ' workers'})")

    # ------------------------------------------------------------------ inputs (executor)

    def _on_points(self, data: bytes) -> None:
        try:
            stamp, frame, cloud = messages.decode_point_cloud(data)
        except Exception as exc:  # noqa: BLE001  any malformed bytes
            self.warnings.drop("points_malformed", f"{self.values['points_topic']} could not be read: {exc}")
            return
        names = cloud.dtype.names or ()
        if "x" not in names or "y" not in names:
            self.warnings.drop("points_shape", f"{self.values['points_topic']} has the fields {list(names)}: "
                                               "expected x and y")
            return
        if cloud.shape[0] == 0:
            self.warnings.drop("points_empty", f"{self.values['points_topic']} has no points")
            return
        xy = np.stack([cloud["x"].astype(np.float64), cloud["y"].astype(np.float64)], axis=1)
        if xy.ndim != 2 or xy.shape[1] != 2:
            self.warnings.drop("points_shape", f"{self.values['points_topic']}: fields x, y of shape {xy.shape}: "
                                               "expected one value each per point")
            return
        if not np.isfinite(xy).all(axis=1).any():
            self.warnings.drop("points_nonfinite", f"{self.values['points_topic']}: every point is NaN/inf")
            return
        with self.cond:
            if self.n_points is not None and xy.shape[0] != self.n_points:
                self.warnings.drop("points_shape", f"{self.values['points_topic']} has {xy.shape[0]} points: "
                                                   f"expected {self.n_points}, as the first cloud")
                return
            if self.plane_frame is not None and frame != self.plane_frame:
                self.warnings.drop("points_frame", f"{self.values['points_topic']} in frame '{frame}': expected "
                                                   f"'{self.plane_frame}', the first cloud's")
                return
            self.n_points, self.plane_frame = xy.shape[0], frame
            if not self.obs_taken and self.state == "pursuing":
                self.counts["skipped_points"] += 1
            self.obs = Observation(stamp_to_ns(stamp), frame, xy)
            self.obs_taken = False
            self.counts["points_received"] += 1
            self.cond.notify_all()

    def _on_pose(self, data: bytes) -> None:
        try:
            stamp, frame, position, quat = messages.decode_pose_stamped(data)
        except Exception as exc:  # noqa: BLE001
            self.warnings.drop("pose_malformed", f"{self.values['pose_topic']} could not be read: {exc}")
            return
        yaw = yaw_from_quaternion(*(float(q) for q in quat))
        if not np.isfinite(position[:2]).all() or yaw is None:
            self.warnings.drop("pose_nonfinite", f"{self.values['pose_topic']} with a NaN/inf value or a zero "
                                                 "quaternion")
            return
        with self.cond:
            if self.plane_frame is not None and frame != self.plane_frame:
                self.warnings.drop("pose_frame", f"{self.values['pose_topic']} in frame '{frame}': expected "
                                                 f"'{self.plane_frame}', the points' frame")
                return
            self.pose = ToolPose(float(position[0]), float(position[1]), float(yaw))
            self.pose_ns = stamp_to_ns(stamp)
            self.counts["poses_received"] += 1
            self.cond.notify_all()

    def _on_jaw(self, data: bytes) -> None:
        try:
            _, jaw = decode_applied_jaw(data)
        except Exception as exc:  # noqa: BLE001
            self.warnings.drop("jaw_malformed", f"{self.values['jaw_topic']} could not be read: {exc}")
            return
        if jaw is None:
            return  # no position: no jaw given yet (the simulator's grasper is open)
        if not math.isfinite(jaw):
            self.warnings.drop("jaw_nonfinite", f"{self.values['jaw_topic']} with position[0]={jaw!r}")
            return
        with self.cond:
            self.jaw = float(jaw)
            self.counts["jaws_received"] += 1

    # ------------------------------------------------------------------ the service (executor)

    def _on_move(self, request: GetPlan.Request, response: GetPlan.Response) -> GetPlan.Response:
        t0 = time.perf_counter()
        log = self.get_logger()
        s, g = request.start.pose.position, request.goal.pose.position
        with self.cond:
            self.counts["requests"] += 1
            obs, pose, jaw, frame = self.obs, self.pose, self.jaw, self.plane_frame
        response.plan = Path()
        response.plan.header.frame_id = frame or ""
        response.plan.header.stamp = self.get_clock().now().to_msg()
        reason = ""
        if obs is None:
            reason = f"no points received yet on {self.values['points_topic']}"
        elif pose is None:
            reason = (f"no tool pose received yet on {self.values['pose_topic']} (the simulator publishes it once "
                      "it has a tool: send it a first tool/pose)")
        elif not all(math.isfinite(c) for c in (s.x, s.y, g.x, g.y)):
            reason = (f"start ({s.x}, {s.y}), goal ({g.x}, {g.y}): expected finite points (x, y) in m")
        else:
            for name, ps in (("start", request.start), ("goal", request.goal)):
                if ps.header.frame_id not in ("", frame):
                    reason = f"{name} is in frame '{ps.header.frame_id}': expected '{frame}' (the points' frame) or ''"
                    break
        if not reason:
            req = MoveRequest((float(s.x), float(s.y)), (float(g.x), float(g.y)), obs, pose,
                              self.settings.open_jaw if jaw is None else jaw, threading.Event())
            with self.cond:
                self.request = req
                self.cond.notify_all()
            while not req.done.wait(0.1):
                if not rclpy.ok(context=self.context) or not self.worker.is_alive():
                    req.reason = "the node is shutting down"
                    break
            reason = req.reason
            if not reason and req.path is not None:
                response.plan.header.stamp = stamp_msg(obs.stamp_ns)
                for x, y, yaw in req.path:
                    ps = PoseStamped()
                    ps.header = response.plan.header
                    ps.pose.position.x, ps.pose.position.y = float(x), float(y)
                    _, _, ps.pose.orientation.z, ps.pose.orientation.w = planar_quaternion(float(yaw))
                    response.plan.poses.append(ps)
                log.info(f"move_tissue: start ({s.x:.4f}, {s.y:.4f}) -> goal ({g.x:.4f}, {g.y:.4f}) m: particle "
                         f"{self.goal_particle}, grasp site {self.ctrl.site}, {len(req.path)} waypoints, answered in "
                         f"{time.perf_counter() - t0:.3f} s; pursuing")
                return response
        with self.cond:
            self.counts["refused"] += 1
            self.last_refusal = reason
            if self.state not in ("pursuing", "reached"):  # a refusal leaves a goal pursued or held alone
                self.state, self.reason = "refused", reason
        log.warning(f"move_tissue: refused: {reason}")
        return response

    # ------------------------------------------------------------------ the worker

    def _work(self) -> None:
        self.worker_niceness = lower_priority(self.values["nice"])
        try:
            self._loop()
        except Exception as exc:  # noqa: BLE001  a controller bug must not leave the node looking alive
            if rclpy.ok(context=self.context):
                self.get_logger().error(f"the controller's worker stopped: {type(exc).__name__}: {exc}")
                with self.cond:
                    self.state, self.reason = "gave up", f"the controller failed: {type(exc).__name__}: {exc}"
                if self.request is not None:
                    self.request.reason = self.reason
                    self.request.done.set()

    def _loop(self) -> None:
        last_ns = -1
        while True:
            with self.cond:
                self.cond.wait_for(lambda: self.stopping or self.request is not None or (
                    self.state in ("pursuing", "reached") and self.obs is not None and self.obs.stamp_ns != last_ns),
                    timeout=0.1)
                if self.stopping:
                    return
                req, self.request = self.request, None
                obs = None
                if req is None and self.state in ("pursuing", "reached") and self.obs is not None \
                        and self.obs.stamp_ns != last_ns:
                    obs = self.obs
                    self.obs_taken = True
            if req is not None:
                self._serve(req)
                continue
            if self.state == "pursuing":
                self.elapsed = (self.get_clock().now().nanoseconds - self.t_start_ns) * 1e-9
                if self.elapsed > self.values["max_time"]:
                    self._give_up(f"the goal was not reached within max_time={self.values['max_time']:g} s "
                                  f"(goal error {self.goal_error * 1e3:.2f} mm, phase {self.phase})")
                    continue
            if obs is None:
                continue
            last_ns = obs.stamp_ns
            with self.cond:  # the measured pose of the points' step (published just after them), briefly waited for
                self.cond.wait_for(lambda: self.stopping or self.pose_ns >= obs.stamp_ns, timeout=0.5 * self.dt)
                pose, jaw = self.pose, self.jaw
            if self.state == "reached":
                self._publish_command(obs, *self.hold_cmd, vx=0.0, vy=0.0, wz=0.0)
            elif self.state == "pursuing":
                self._step(obs, pose, self.settings.open_jaw if jaw is None else jaw)

    def _serve(self, req: MoveRequest) -> None:
        """set_goal and planned_path on the request's observation; the answer in ``req``."""
        ctrl = self.ctrl
        t = req.obs.stamp_ns * 1e-9
        try:
            ids = ctrl.set_goal([(req.start, req.goal)], req.obs.xy, req.pose)  # (a hold is let go: a new approach)
            path = ctrl.planned_path(req.obs.xy, req.pose, req.jaw, t=t)
            if not np.isfinite(path).all():
                raise InputError("the plan is not finite")
        except InputError as exc:
            req.reason = str(exc)
            req.done.set()
            return
        except Exception as exc:  # noqa: BLE001  a controller bug: refused, named
            self.get_logger().error(f"move_tissue: the controller failed: {type(exc).__name__}: {exc}")
            req.reason = f"the controller failed: {type(exc).__name__}: {exc}"
            req.done.set()
            return
        with self.cond:
            self.goal_particle = int(ids[0]) if len(ids) else -1
            d = np.hypot(*(req.obs.xy - np.array(req.start)).T)
            self.goal_point = int(np.argmin(np.where(np.isfinite(d), d, np.inf)))
            self.start, self.goal = ctrl.starts[0].copy(), np.array(req.goal)
            self.state, self.reason = "pursuing", ""
            self.phase = ctrl.phase
            self.goal_error = ctrl.goal_error(ctrl.x)
            self.observed_error = self._observed_error(req.obs)
            self.t_start_ns = self.get_clock().now().nanoseconds
            self.elapsed = 0.0
            self.held_since_ns = None
            self.hold_cmd = None
            self.latency = (0.0, 0, 0.0)
            self.counts["accepted"] += 1
        req.path = path
        req.done.set()
        self._publish_markers(req.obs, path)

    def _step(self, obs: Observation, pose: ToolPose, jaw: float) -> None:
        ctrl, s = self.ctrl, self.settings
        t = obs.stamp_ns * 1e-9
        try:
            cmd = ctrl.command(obs.xy, pose, jaw, t=t)
        except InputError as exc:
            self._give_up(f"the controller refused the observation: {exc}")
            return
        except Exception as exc:  # noqa: BLE001
            self._give_up(f"the controller failed: {type(exc).__name__}: {exc}")
            return
        values = (cmd.pose.x, cmd.pose.y, cmd.pose.yaw, cmd.twist.vx, cmd.twist.vy, cmd.twist.wz, cmd.jaw)
        if not all(math.isfinite(x) for x in values):
            self.counts["unpublished_nonfinite"] += 1
            self._give_up(f"the controller's command is not finite (pose {cmd.pose}, twist {cmd.twist}, jaw "
                          f"{cmd.jaw}): not published")
            return
        self._publish_command(obs, cmd.pose, cmd.jaw, cmd.twist.vx, cmd.twist.vy, cmd.twist.wz)
        if cmd.replanned and ctrl.records:
            rec = ctrl.records[-1]
            self.counts["replans"] += 1
            self.last_replan_ms = rec.total_s * 1e3
            self.last_sync_ms = rec.sync_s * 1e3
            self.max_replan_ms = self.last_replan_ms if math.isnan(self.max_replan_ms) else \
                max(self.max_replan_ms, self.last_replan_ms)
            self.get_logger().debug(
                f"replan at step {rec.step} ({rec.phase}): sync {rec.sync_s * 1e3:.1f} ms, {rec.candidates} "
                f"candidates x {rec.horizon} steps {rec.rollout_s * 1e3:.1f} ms, choice {rec.choose_s * 1e3:.1f} ms; "
                f"goal error {cmd.goal_error * 1e3:.2f} mm")
            if rec.paths:
                self._publish_markers(obs, None)
        with self.cond:
            self.phase, self.goal_error = cmd.phase, cmd.goal_error
            self.observed_error = self._observed_error(obs)
            if cmd.phase == "holding" and cmd.goal_error <= s.tolerance:
                if self.held_since_ns is None:
                    self.held_since_ns = obs.stamp_ns
                if (obs.stamp_ns - self.held_since_ns) * 1e-9 >= self.values["hold_time"] - 1e-9:
                    self.state = "reached"
                    self.hold_cmd = (cmd.pose, cmd.jaw)
            else:
                self.held_since_ns = None
        if self.state == "reached":
            self.get_logger().info(
                f"goal reached: goal error {cmd.goal_error * 1e3:.2f} mm (observed {self.observed_error * 1e3:.2f} "
                f"mm) within goal_tolerance {s.tolerance * 1e3:g} mm for {self.values['hold_time']:g} s, after "
                f"{self.elapsed:.2f} s; holding the tool at ({cmd.pose.x:.4f}, {cmd.pose.y:.4f})")

    def _observed_error(self, obs: Observation) -> float:
        """The distance from the goal of the observed point that was nearest the start at the request [m]."""
        i = self.goal_point
        if self.goal is None or i < 0 or i >= obs.xy.shape[0] or not np.isfinite(obs.xy[i]).all():
            return math.nan
        return float(np.hypot(*(obs.xy[i] - self.goal)))

    def _give_up(self, reason: str) -> None:
        with self.cond:
            self.state, self.reason = "gave up", reason
        self.get_logger().error(f"gave up: {reason}")

    # ------------------------------------------------------------------ outputs

    def _publish_command(self, obs: Observation, pose: ToolPose, jaw: float, vx: float, vy: float, wz: float) -> None:
        """tool/twist, tool/jaw, then tool/pose (the simulator steps with the pose), stamped points + dt."""
        base = obs.stamp_ns if obs.stamp_ns > 0 else self.get_clock().now().nanoseconds
        stamp = stamp_from_ns(base + self.dt_ns)
        frame = obs.frame
        self.pub_twist.publish(messages.encode_twist_stamped(stamp, frame, vx, vy, wz))
        self.pub_jaw.publish(messages.encode_joint_state(stamp, "", ["jaw"], [jaw]))
        self.pub_pose.publish(messages.encode_pose_stamped(stamp, frame, pose.x, pose.y, pose.yaw))
        self.counts["commands"] += 1
        if obs.stamp_ns > 0:  # from the points' stamp to the command's publication (on the node's clock)
            lat = (self.get_clock().now().nanoseconds - obs.stamp_ns) * 1e-6
            self.latency = (self.latency[0] + lat, self.latency[1] + 1, max(self.latency[2], lat))

    def _publish_markers(self, obs: Observation, plan: np.ndarray | None) -> None:
        """control/markers: the last replan's candidates (grey), the chosen one (green), start and goal, the plan."""
        M = messages
        stamp, frame = stamp_from_ns(max(obs.stamp_ns, 0)), obs.frame
        out = [M.MarkerSpec("", 0, M.MARKER_ARROW, stamp, frame, action=M.ACTION_DELETEALL)]
        rec = self.ctrl.records[-1] if self.ctrl.records else None
        if rec is not None and rec.paths:
            for i, p in enumerate(rec.paths):
                if len(p) >= 2 and np.isfinite(p).all():
                    out.append(M.MarkerSpec("control_candidates", i, M.MARKER_LINE_STRIP, stamp, frame,
                                            scale=(0.0005, 0.0, 0.0), color=(0.6, 0.6, 0.6, 0.6), points=p))
            if 0 <= rec.best < len(rec.paths) and np.isfinite(rec.paths[rec.best]).all():
                out.append(M.MarkerSpec("control_chosen", 0, M.MARKER_LINE_STRIP, stamp, frame,
                                        scale=(0.0015, 0.0, 0.0), color=(0.1, 0.9, 0.2, 1.0),
                                        points=rec.paths[rec.best]))
        if plan is not None:
            out.append(M.MarkerSpec("control_plan", 0, M.MARKER_LINE_STRIP, stamp, frame, scale=(0.001, 0.0, 0.0),
                                    color=(1.0, 0.55, 0.0, 1.0), points=plan[:, :2]))
        for ns, p, color in (("control_start", self.start, (0.2, 0.4, 1.0, 1.0)),
                             ("control_goal", self.goal, (1.0, 0.84, 0.0, 1.0))):
            if p is not None:
                out.append(M.MarkerSpec(ns, 0, M.MARKER_SPHERE, stamp, frame, position=(float(p[0]), float(p[1]), 0.0),
                                        scale=(0.003, 0.003, 0.003), color=color))
        self.pub_markers.publish(M.encode_marker_array(out))

    def _publish_diagnostics(self) -> None:
        with self.cond:
            state, reason, c = self.state, self.reason, dict(self.counts)
            drops = dict(self.warnings.counts)
        level = DiagnosticStatus.OK if state in ("idle", "pursuing", "reached") else DiagnosticStatus.WARN
        status = DiagnosticStatus(level=level, name=f"{self.get_fully_qualified_name()}: controller",
                                  hardware_id="tissue_controller",
                                  message=state + (f": {reason}" if reason else ""))

        def num(x: float) -> str:
            return "nan" if x is None or not math.isfinite(x) else f"{x:.6g}"

        values = {
            "state": state, "reason": reason, "last_refusal": self.last_refusal, "phase": self.phase,
            "goal_error_m": num(self.goal_error), "observed_goal_error_m": num(self.observed_error),
            "goal_particle": str(self.goal_particle),
            "start_m": "none" if self.start is None else f"{self.start[0]:.6g}, {self.start[1]:.6g}",
            "goal_m": "none" if self.goal is None else f"{self.goal[0]:.6g}, {self.goal[1]:.6g}",
            "grasp_site": "none" if self.ctrl.site is None else str(self.ctrl.site),
            "elapsed_s": num(self.elapsed),
            "last_replan_ms": num(self.last_replan_ms), "max_replan_ms": num(self.max_replan_ms),
            "last_sync_ms": num(self.last_sync_ms),
            "command_latency_ms_mean": num(self.latency[0] / self.latency[1] if self.latency[1] else math.nan),
            "command_latency_ms_max": num(self.latency[2] if self.latency[1] else math.nan),
            "candidates": str(self.settings.n_candidates), "horizon": str(self.settings.horizon),
            "jobs": str(self.values["jobs"]),
            "worker_niceness": "unknown" if self.worker_niceness is None else str(self.worker_niceness),
            **{k: str(n) for k, n in c.items()},
            **{f"dropped_{k}": str(n) for k, n in drops.items()},
        }
        status.values = [KeyValue(key=k, value=str(x)) for k, x in values.items()]
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = self.plane_frame or ""
        msg.status = [status]
        try:
            self.pub_diag.publish(msg)
        except Exception:  # noqa: BLE001  the context shut down under the timer (SIGTERM)
            if rclpy.ok(context=self.context):
                raise

    def close(self) -> None:
        """Stop the worker (after its current call) and the rollout pool."""
        with self.cond:
            self.stopping = True
            self.cond.notify_all()
        self.worker.join(timeout=10.0)
        if self.ctrl.pool is not None:
            self.ctrl.pool.close()
            self.ctrl.pool = None


def lower_priority(nice: int) -> int | None:
    """This thread: ``nice`` added to its niceness (Linux names a thread by its id) and one numba thread for its
    parallel kernels (the others would run at the node's priority); its niceness, None where unknown."""
    import numba  # noqa: PLC0415  (the core's kernels are numba's already)

    numba.set_num_threads(1)
    try:
        return nice_this_thread(nice)
    except OSError:  # a sandbox may forbid it: the worker then runs at the node's priority
        return None


def stamp_msg(ns: int) -> TimeMsg:
    """builtin_interfaces/Time of a time in ns."""
    sec, nsec = stamp_from_ns(max(ns, 0))
    return TimeMsg(sec=sec, nanosec=nsec)


def usage() -> str:
    """What ``tissue_controller --help`` prints."""
    names = [*NODE_PARAMETERS, *settings_rows(), *MODEL_PARAMETERS]
    about = (
        "Drives the tissue to a target: a model-predictive grasp controller beside tissue_sim_node (or a robot).\n"
        "It reads tissue/points, tool/applied_pose and tool/applied_jaw, offers ~/move_tissue (nav_msgs/GetPlan:\n"
        "start = the tissue point to move, goal = where it should go) and publishes tool/pose, tool/twist and\n"
        "tool/jaw until the goal is met or it gives up; control/markers and /diagnostics show what it does.\n"
        "Exit 0 on SIGINT/SIGTERM, 2 on a bad parameter (named).\n\n")
    return (
        usage_head(NODE_NAME, about, "-p horizon:=20 -p gains:=[1.0]")
        + "\nparameters (all read-only):\n" + parameter_list(names) + "\n\n"
        f"Its topics, service and every parameter: {msg_docs_dir()}/controller.md\n")


def main(args: list[str] | None = None) -> int:
    """Console script ``tissue_controller``: 0 on SIGINT/SIGTERM, 2 on a bad parameter.

    ``-h``/``--help`` outside ``--ros-args`` prints :func:`usage` and returns 0 before rclpy is initialised.
    """
    if wants_help(args):
        print(usage(), end="")
        return 0
    if not init_rclpy(NODE_NAME, args):
        return 2
    node = None
    code = 0
    executor = None
    try:
        node = TissueControllerNode()
        # the worker holds the GIL while it plans; a short switch interval hands it to a waiting callback
        # within 0.5 ms instead of Python's default 5 ms (as tissue_sim_node does for its marker thread)
        sys.setswitchinterval(SWITCH_INTERVAL)
        executor = MultiThreadedExecutor(num_threads=2)
        executor.add_node(node)
        executor.spin()
    except InputError as exc:
        print(f"{NODE_NAME}: error: {exc}", file=sys.stderr)
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            node.close()
        if executor is not None:
            executor.shutdown(timeout_sec=1.0)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
