"""``tissue_controller``: the model-predictive grasp controller as a node of its own, beside the simulator.

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

Laid out by job: :class:`TissueControllerNode` only wires. The executor (two threads: subscriptions and the
diagnostics timer in one callback group, the service in another) reads the messages
(:mod:`~tissue_sim_ros.ros.controller_io`) and hands them to the worker thread
(:mod:`~tissue_sim_ros.ros.controller_worker`), which owns the controller and its state; the parameters
(typed, read-only, ranged descriptors), the model and the start-up warm-up are
:mod:`~tissue_sim_ros.ros.controller_setup`'s. ``msg_docs/controller.md`` describes the interface.
"""
from __future__ import annotations

import math
import sys
import threading
import time
from typing import Any

import rclpy
from builtin_interfaces.msg import Time as TimeMsg
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, TwistStamped
from nav_msgs.msg import Path
from nav_msgs.srv import GetPlan
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import JointState, PointCloud2
from visualization_msgs.msg import MarkerArray

from ..core.errors import InputError
from ..core.plan.control import TissueController
from ..core.timing.stamps import ns_from_seconds, stamp_from_ns
from . import qos
from .controller_io import DROP_KINDS, CommandOutput, diagnostic_array, diagnostics, read_jaw, read_points, read_pose
from .controller_setup import (
    MODEL_PARAMETERS,
    NODE_PARAMETERS,
    declare_controller_parameters,
    settings_rows,
    warm_up,
)
from .controller_worker import ControllerWorker, MoveRequest
from .realtime import SWITCH_INTERVAL, nice_this_thread
from .throttle import ThrottledWarnings
from .tool_applied import planar_quaternion
from .usage import init_rclpy, msg_docs_dir, parameter_list, usage_head, wants_help

NODE_NAME = "tissue_controller"

#: Records of replans kept (each holds its candidates' paths).
KEEP_RECORDS = 20


class TissueControllerNode(Node):
    """The node (module docstring). ``close()`` stops the worker and the rollout pool."""

    def __init__(self, node_name: str = NODE_NAME, **kwargs: Any) -> None:
        # what was given is declared as given, read back and declared again typed (controller_setup)
        kwargs["automatically_declare_parameters_from_overrides"] = True
        super().__init__(node_name, **kwargs)
        params = declare_controller_parameters(self)
        v = self.values = params.values
        self.settings, self.config = params.settings, params.config
        ctrl = TissueController(self.config, self.settings, records_kept=KEEP_RECORDS)
        self.dt_ns = ns_from_seconds(float(self.config.sim.dt))
        if v["warm_up"]:
            # in this process (numba caches the kernels on disk, so the pool's workers load them)
            t0 = time.perf_counter()
            note = warm_up(self.config, self.settings)
            self.get_logger().info(f"warm-up on the model: {time.perf_counter() - t0:.2f} s{note}")
        self.warnings = ThrottledWarnings(self.get_logger(), dict.fromkeys(DROP_KINDS, 0), lambda: v["warn_period"])
        self._subscribe(v)
        now_ns = lambda: self.get_clock().now().nanoseconds  # noqa: E731
        output = CommandOutput(self.create_publisher(PoseStamped, "tool/pose", qos.tool_output()),
                               self.create_publisher(TwistStamped, "tool/twist", qos.tool_output()),
                               self.create_publisher(JointState, "tool/jaw", qos.tool_output()),
                               self.create_publisher(MarkerArray, "control/markers", qos.latched()),
                               now_ns, lambda: rclpy.ok(context=self.context))
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", qos.diagnostics())
        self.create_timer(1.0 / v["diagnostics_rate"], self._publish_diagnostics)
        self.worker = ControllerWorker(ctrl, self.settings, self.dt_ns, output, now_ns, self.get_logger(),
                                       v["max_time"], v["hold_time"], start=lambda: lower_priority(v["nice"]))
        if v["jobs"] > 1:  # last but the worker: nothing after it can fail and leave the workers running
            from ..core.sim.batch import RolloutPool  # noqa: PLC0415  (worker processes only when asked for)

            ctrl.pool = RolloutPool(ctrl.scene, workers=v["jobs"], nice=v["nice"])
        self.worker.start()
        self.service = self.create_service(GetPlan, "~/move_tissue", self._on_move,
                                           callback_group=MutuallyExclusiveCallbackGroup())
        self._log_ready(params.overrides)

    def _subscribe(self, v: dict[str, Any]) -> None:
        inputs = qos.observation_input()
        for name, kind, callback in (("points_topic", PointCloud2, self._on_points),
                                     ("pose_topic", PoseStamped, self._on_pose),
                                     ("jaw_topic", JointState, self._on_jaw)):
            try:
                self.create_subscription(kind, v[name], callback, inputs, raw=True)
            except Exception as exc:  # noqa: BLE001  rclpy's invalid-name errors
                first = str(exc).splitlines()[0].rstrip(":")
                raise InputError(f"parameter {name}={v[name]!r}: expected a valid topic name ({first})") from None

    def _log_ready(self, overrides: dict[str, Any]) -> None:
        v, s = self.values, self.settings
        self.get_logger().info(
            f"ready: ~/move_tissue; model {v['scene']}{' + ' + v['params_file'] if v['params_file'] else ''}"
            f"{''.join(f', {k} {x:g}' for k, x in overrides.items() if isinstance(x, float))}; "
            f"{s.n_candidates} candidates x {s.horizon} steps every {s.replan_every} steps "
            f"({'serially' if v['jobs'] == 1 else str(v['jobs']) + ' workers'})")

    # ------------------------------------------------------------------ inputs (executor)

    def _drop(self, kind: str, topic: str, why: str) -> None:
        self.warnings.drop(kind, f"{self.values[topic]} {why}")

    def _on_points(self, data: bytes) -> None:
        obs, kind, why = read_points(data)
        if obs is None:
            self._drop(kind, "points_topic", why)
            return
        kind, why = self.worker.check_points(obs.xy.shape[0], obs.frame)
        if kind:
            self._drop(kind, "points_topic", why)
            return
        self.worker.put_points(obs)

    def _on_pose(self, data: bytes) -> None:
        pose, kind, why = read_pose(data)
        if pose is None:
            self._drop(kind, "pose_topic", why)
            return
        why = self.worker.put_pose(*pose)
        if why:
            self._drop("pose_frame", "pose_topic", why)

    def _on_jaw(self, data: bytes) -> None:
        jaw, kind, why = read_jaw(data)
        if kind:
            self._drop(kind, "jaw_topic", why)
        elif jaw is not None:  # no position: no jaw given yet (the simulator's grasper is open)
            self.worker.put_jaw(float(jaw))

    # ------------------------------------------------------------------ the service (executor)

    def _refusal(self, req: GetPlan.Request, obs: Any, pose: Any, frame: str | None) -> str:
        """Why ``req`` cannot be handed to the worker ('' when it can)."""
        s, g = req.start.pose.position, req.goal.pose.position
        if obs is None:
            return f"no points received yet on {self.values['points_topic']}"
        if pose is None:
            return (f"no tool pose received yet on {self.values['pose_topic']} (the simulator publishes it from its "
                    "start pose, tool_start_*, or once it has a tool: send it a first tool/pose)")
        if not all(math.isfinite(c) for c in (s.x, s.y, g.x, g.y)):
            return f"start ({s.x}, {s.y}), goal ({g.x}, {g.y}): expected finite points (x, y) in m"
        for name, ps in (("start", req.start), ("goal", req.goal)):
            if ps.header.frame_id not in ("", frame):
                return f"{name} is in frame '{ps.header.frame_id}': expected '{frame}' (the points' frame) or ''"
        return ""

    def _on_move(self, request: GetPlan.Request, response: GetPlan.Response) -> GetPlan.Response:
        t0 = time.perf_counter()
        s, g = request.start.pose.position, request.goal.pose.position
        obs, pose, jaw, frame = self.worker.inputs()
        response.plan = Path()
        response.plan.header.frame_id = frame or ""
        response.plan.header.stamp = self.get_clock().now().to_msg()
        reason = self._refusal(request, obs, pose, frame)
        if not reason:
            req = MoveRequest((float(s.x), float(s.y)), (float(g.x), float(g.y)), obs, pose,
                              self.settings.open_jaw if jaw is None else jaw, threading.Event())
            self.worker.request(req, lambda: not rclpy.ok(context=self.context))
            reason = req.reason
            if not reason and req.path is not None:
                response.plan.header.stamp = stamp_msg(obs.stamp_ns)
                response.plan.poses = [self._waypoint(response.plan.header, x, y, yaw) for x, y, yaw in req.path]
                p = self.worker.snapshot()
                self.get_logger().info(
                    f"move_tissue: start ({s.x:.4f}, {s.y:.4f}) -> goal ({g.x:.4f}, {g.y:.4f}) m: particle "
                    f"{p.goal_particle}, grasp site {p.grasp_site}, {len(req.path)} waypoints, answered in "
                    f"{time.perf_counter() - t0:.3f} s; pursuing")
                return response
        self.worker.refuse(reason)
        self.get_logger().warning(f"move_tissue: refused: {reason}")
        return response

    @staticmethod
    def _waypoint(header: Any, x: float, y: float, yaw: float) -> PoseStamped:
        ps = PoseStamped()
        ps.header = header
        ps.pose.position.x, ps.pose.position.y = float(x), float(y)
        _, _, ps.pose.orientation.z, ps.pose.orientation.w = planar_quaternion(float(yaw))
        return ps

    # ------------------------------------------------------------------ /diagnostics

    def _publish_diagnostics(self) -> None:
        status = diagnostics(f"{self.get_fully_qualified_name()}: controller", self.worker.snapshot(),
                             dict(self.warnings.counts), self.settings, self.values["jobs"], self.worker.niceness)
        try:
            self.pub_diag.publish(diagnostic_array(status, self.get_clock().now().to_msg(),
                                                   self.worker.plane_frame or ""))
        except Exception:  # noqa: BLE001  the context shut down under the timer (SIGTERM)
            if rclpy.ok(context=self.context):
                raise

    def close(self) -> None:
        """Stop the worker (after its current call) and the rollout pool."""
        worker = getattr(self, "worker", None)
        if worker is not None:
            worker.close()


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
