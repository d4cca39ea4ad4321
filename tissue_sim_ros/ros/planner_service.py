"""The node's planner service ``~/plan_insertion`` (nav_msgs/srv/GetPlan), off the step thread.

``PlannerService(node)`` takes the simulation node as an argument (as tf2_ros
helpers do) and serves, for it:

* ``~/plan_insertion`` (nav_msgs/srv/GetPlan): ``start`` is where the tool's
  tip enters, ``goal`` the target for the tip, ``tolerance`` [m] (0: the
  node's ``plan_tolerance``); orientations are ignored (the approach angle is
  swept). The planner snapshots the node's current tissue
  (:meth:`~tissue_sim_ros.core.sim.simulation.Simulation.snapshot`), rolls out
  every approach angle and speed of the ``plan_*`` parameters
  (:func:`~tissue_sim_ros.core.plan.insertion.plan_insertion`) and answers with the
  cheapest path as nav_msgs/Path: the tool's pose (as ``tool/pose`` takes it:
  the tool's centre, yaw along the insertion) at the end of each step, stamped
  dt apart from the answer's time, in ``frame_id``. A request it cannot
  answer gets an empty path (header stamped and framed) and a logged reason;
* ``plan/candidates`` (visualization_msgs/MarkerArray, latched): each
  rolled-out candidate's tip path coloured by cost (green cheapest, red
  dearest, grey not feasible), the plan wider, the target as a sphere, and
  each candidate that was not rolled out as a text at its entry naming its
  angle, speed and the reason (namespace ``plan_skipped``);
* ``plan/costs`` (std_msgs/Float64MultiArray, latched): one row per
  rolled-out candidate, columns :data:`COST_FIELDS`.

The log names the skipped candidates with their reasons too.

Threading: the service and publishers belong to a second node,
``<node name>_planner`` in the same namespace and process, spun by its own
executor in its own thread, so the simulation node's executor (the step
timer, the tool subscriptions) never waits for a plan. The rollouts run in
worker processes (:class:`~tissue_sim_ros.core.sim.batch.RolloutPool`,
``plan_workers``, started at the first request, niced by ``plan_nice`` so the
step thread is scheduled first); the planner thread only waits for them.
"""
from __future__ import annotations

import math
import threading
import time
from typing import Any

import numpy as np
import rclpy
from builtin_interfaces.msg import Duration as DurationMsg
from geometry_msgs.msg import Point, PoseStamped
from nav_msgs.msg import Path
from nav_msgs.srv import GetPlan
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from std_msgs.msg import ColorRGBA, Float64MultiArray
from visualization_msgs.msg import Marker, MarkerArray

from ..core.plan.insertion import InsertionPlan, InsertionRequest, plan_insertion
from ..core.sim.batch import BatchScene, RolloutPool
from . import messages, qos

#: Columns of ``plan/costs``, one row per rolled-out candidate.
COST_FIELDS = ("angle_deg", "angle_offset_deg", "speed_mps", "cost", "peak_energy", "peak_force_n",
               "max_displacement_m", "max_penetration_m", "target_error_m", "steps", "feasible", "best")


def sweep_values(lo: float, hi: float, step: float) -> list[float]:
    """lo, lo + step, ... up to hi (inclusive, within round-off)."""
    n = int(math.floor((hi - lo) / step + 1e-9)) + 1
    return [lo + k * step for k in range(max(n, 0))]


def _stamp_plus(stamp: Any, seconds: float) -> Any:
    ns = stamp.sec * 1_000_000_000 + stamp.nanosec + int(round(seconds * 1e9))
    out = type(stamp)()
    out.sec, out.nanosec = ns // 1_000_000_000, ns % 1_000_000_000
    return out


#: Height of the texts of ``plan/candidates`` that name a skipped candidate and its reason [m].
SKIPPED_TEXT_HEIGHT = 0.01


def skipped_candidates(plan: InsertionPlan) -> list[tuple[int, Any]]:
    """The candidates of ``plan`` that were not rolled out (each has its reason), with their index in the sweep."""
    return [(i, c) for i, c in enumerate(plan.candidates) if c.result is None]


def describe(candidate: Any) -> str:
    """A candidate as the log and ``plan/candidates`` name it: its angle (and offset) and speed."""
    return (f"{math.degrees(candidate.angle):+.1f} deg (offset {candidate.angle_offset_deg:+g}) at "
            f"{candidate.speed:g} m/s")


def _rolled(plan: InsertionPlan) -> list[tuple[int, Any]]:
    return [(i, c) for i, c in enumerate(plan.candidates)
            if c.result is not None and math.isfinite(c.cost) and math.isfinite(c.target_error)]


def cost_colour(cost: float, lo: float, hi: float) -> tuple[float, float, float]:
    """Green (cheapest, ``lo``) to red (dearest, ``hi``), on a log scale when both are positive."""
    if hi > lo > 0 and cost > 0:
        t = (math.log(cost) - math.log(lo)) / (math.log(hi) - math.log(lo))
    elif hi > lo:
        t = (cost - lo) / (hi - lo)
    else:
        t = 0.0
    t = min(max(t, 0.0), 1.0)
    return (t, 1.0 - 0.8 * t, 0.15)


class PlannerService:
    """``~/plan_insertion`` and its RViz topics for a :class:`~tissue_sim_ros.ros.node.TissueSimNode`.

    Parameters
    ----------
    node : TissueSimNode
        The simulation node: its ``sim`` is snapshotted, its ``plan_*``
        parameters read at each request, its ``frame_id`` checked.
    """

    def __init__(self, node: Any) -> None:
        self.node = node
        self.helper = Node(f"{node.get_name()}_planner", namespace=node.get_namespace(), context=node.context,
                           start_parameter_services=False)
        self.service_name = f"{node.get_fully_qualified_name()}/plan_insertion"
        self.pub_candidates = self.helper.create_publisher(MarkerArray, "plan/candidates", qos.latched())
        self.pub_costs = self.helper.create_publisher(Float64MultiArray, "plan/costs", qos.latched())
        self.service = self.helper.create_service(GetPlan, self.service_name, self._on_plan)
        self.pool: RolloutPool | None = None
        self._pool_model = None
        self.last_plan: InsertionPlan | None = None
        self.last_latency = math.nan
        """Request-to-answer wall time of the last request [s]."""
        self.requests = 0
        self.answered = 0
        self._executor = SingleThreadedExecutor(context=node.context)
        self._executor.add_node(self.helper)
        self._thread = threading.Thread(target=self._spin, name="planner", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        try:
            self._executor.spin()
        except (ExternalShutdownException, rclpy.executors.ShutdownException):
            pass
        except Exception:  # noqa: BLE001  the context shut down under the executor (SIGTERM)
            if rclpy.ok(context=self.node.context):
                raise

    def _param(self, name: str) -> Any:
        """A ``plan_*`` setting of the node, typed, as it is now (a request reads them when it comes)."""
        return getattr(self.node.config.node, name)

    # ------------------------------------------------------------------ the request

    def _request(self, req: GetPlan.Request) -> tuple[InsertionRequest | None, str]:
        """The core request from the message and the plan_* parameters, or a reason it cannot be planned."""
        frame = self.node.frame_id
        for name, pose in (("start", req.start), ("goal", req.goal)):
            if pose.header.frame_id != frame:
                return None, f"{name} is in frame '{pose.header.frame_id}': expected '{frame}'"
        lo, hi, step = (float(self._param(n)) for n in ("plan_angle_min", "plan_angle_max", "plan_angle_step"))
        vlo, vhi, count = float(self._param("plan_speed_min")), float(self._param("plan_speed_max")), \
            int(self._param("plan_speed_count"))
        if hi < lo:
            return None, f"plan_angle_max={hi} < plan_angle_min={lo}: expected max >= min"
        if vhi < vlo:
            return None, f"plan_speed_max={vhi} < plan_speed_min={vlo}: expected max >= min"
        speeds = [vlo] if count == 1 else list(np.linspace(vlo, vhi, count))
        if not (math.isfinite(req.tolerance) and req.tolerance >= 0.0):
            return None, f"tolerance {req.tolerance:g}: expected a finite value >= 0 m (0: the parameter plan_tolerance)"
        tolerance = float(req.tolerance) if req.tolerance > 0 else float(self._param("plan_tolerance"))
        s, g = req.start.pose.position, req.goal.pose.position
        return InsertionRequest(entry=(float(s.x), float(s.y)), target=(float(g.x), float(g.y)), tolerance=tolerance,
                                angle_offsets_deg=sweep_values(lo, hi, step), speeds=[float(v) for v in speeds],
                                max_steps=int(self._param("plan_max_steps")),
                                track_target=bool(self._param("plan_track_target"))), ""

    def _pool_for(self, scene: BatchScene) -> RolloutPool | None:
        """The worker pool for this scene (started, or sent the new scene); None for plan_workers 0."""
        workers = int(self._param("plan_workers"))
        if workers == 0:
            return None
        if self.pool is None or not self.pool.alive:
            self.node.get_logger().info(f"planner: starting {workers} rollout workers")
            self.pool = RolloutPool(scene, workers, nice=int(self._param("plan_nice")))
        elif self._pool_model is not scene.model:
            self.pool.set_scene(scene)
        self._pool_model = scene.model
        return self.pool

    def _on_plan(self, request: GetPlan.Request, response: GetPlan.Response) -> GetPlan.Response:
        t0 = time.perf_counter()
        self.requests += 1
        log = self.node.get_logger()
        response.plan = Path()
        response.plan.header.frame_id = self.node.frame_id
        try:
            req, reason = self._request(request)
            plan = None
            if req is not None:
                sim = self.node.sim
                if sim.tool is None:
                    reason = "the scene has no tool: expected tool_shape to be set"
                else:
                    scene = BatchScene(sim.model, sim.tool)
                    snap = sim.snapshot()  # under the simulation's lock: between two steps
                    plan = plan_insertion(snap, scene, req, pool=self._pool_for(scene))
                    self.last_plan = plan
                    reason = plan.reason
            # stamped at the answer: a client that publishes the poses at their stamps starts now, not in the past
            now = self.node.get_clock().now().to_msg()
            response.plan.header.stamp = now
            skipped = [] if plan is None else skipped_candidates(plan)
            if skipped:
                log.info(f"plan_insertion: {len(skipped)} of {len(plan.candidates)} candidates not rolled out:\n"
                         + "\n".join(f"  {describe(c)}: {c.reason}" for _, c in skipped))
            if plan is not None and plan.candidates:
                # a sweep was made: its candidates, rolled out or skipped, replace the latched ones
                self._publish_candidates(plan, now)
            if plan is not None and plan.batch is not None:
                self._publish_costs(plan)  # only what was rolled out replaces the latched costs
            if plan is not None and plan.ok:
                self._fill_path(response.plan, plan, now, sim.params.dt)
                best = plan.candidates[plan.best]
                n = sum(c.result is not None for c in plan.candidates)
                log.info(f"plan_insertion: {n} of {len(plan.candidates)} candidates rolled out in "
                         f"{time.perf_counter() - t0:.2f} s; cheapest "
                         f"{math.degrees(best.angle):+.1f} deg at {best.speed:g} m/s, cost {best.cost:.4g}, "
                         f"{len(response.plan.poses)} poses; the target moved {best.target_error * 1e3:.1f} mm")
                self.answered += 1
            else:
                log.warning(f"plan_insertion: no plan: {reason}")
        except Exception as exc:  # noqa: BLE001  a bad request or a planner bug must not end the node
            log.error(f"plan_insertion: no plan: the planner failed: {type(exc).__name__}: {exc}")
            response.plan.poses = []
            response.plan.header.stamp = self.node.get_clock().now().to_msg()
        self.last_latency = time.perf_counter() - t0
        return response

    # ------------------------------------------------------------------ messages

    def _fill_path(self, path: Path, plan: InsertionPlan, stamp: Any, dt: float) -> None:
        best = plan.candidates[plan.best]
        frame = self.node.frame_id
        for k, (x, y, yaw) in enumerate(best.path.poses):
            ps = PoseStamped()
            ps.header.frame_id = frame
            ps.header.stamp = _stamp_plus(stamp, (k + 1) * dt)
            ps.pose.position.x, ps.pose.position.y = float(x), float(y)
            ps.pose.orientation.z, ps.pose.orientation.w = math.sin(yaw / 2.0), math.cos(yaw / 2.0)
            path.poses.append(ps)

    def _publish_candidates(self, plan: InsertionPlan, stamp: Any) -> None:
        rolled = _rolled(plan)
        frame = self.node.frame_id
        markers = MarkerArray()
        clear = Marker()
        clear.header.frame_id, clear.header.stamp = frame, stamp
        clear.action = Marker.DELETEALL
        markers.markers.append(clear)
        costs = [c.cost for _, c in rolled if c.feasible]
        lo, hi = (min(costs), max(costs)) if costs else (0.0, 0.0)
        for i, c in rolled:
            m = Marker()
            m.header.frame_id, m.header.stamp = frame, stamp
            m.ns, m.id, m.type, m.action = "plan_candidates", i, Marker.LINE_STRIP, Marker.ADD
            m.pose.orientation.w = 1.0
            m.scale.x = 0.006 if i == plan.best else 0.002
            r, g, b = cost_colour(c.cost, lo, hi) if c.feasible else (0.5, 0.5, 0.5)
            m.color = ColorRGBA(r=r, g=g, b=b, a=1.0 if c.feasible else 0.5)
            m.points = [Point(x=c.entry[0], y=c.entry[1], z=0.0),
                        Point(x=plan.request.target[0], y=plan.request.target[1], z=0.0)]
            m.lifetime = DurationMsg()
            markers.markers.append(m)
        target = Marker()
        target.header.frame_id, target.header.stamp = frame, stamp
        target.ns, target.id, target.type, target.action = "plan_target", 0, Marker.SPHERE, Marker.ADD
        target.pose.position.x, target.pose.position.y = plan.request.target
        target.pose.orientation.w = 1.0
        target.scale.x = target.scale.y = target.scale.z = 0.02
        target.color = ColorRGBA(r=1.0, g=0.84, b=0.0, a=1.0)
        markers.markers.append(target)
        for i, c in skipped_candidates(plan):
            m = Marker()
            m.header.frame_id, m.header.stamp = frame, stamp
            m.ns, m.id, m.type, m.action = "plan_skipped", i, Marker.TEXT_VIEW_FACING, Marker.ADD
            m.pose.position.x, m.pose.position.y = float(c.entry[0]), float(c.entry[1])
            m.pose.orientation.w = 1.0
            m.scale.z = SKIPPED_TEXT_HEIGHT
            m.color = ColorRGBA(r=0.6, g=0.6, b=0.6, a=1.0)
            m.text = f"{describe(c)}: {c.reason}"
            m.lifetime = DurationMsg()
            markers.markers.append(m)
        self.pub_candidates.publish(markers)

    def _publish_costs(self, plan: InsertionPlan) -> None:
        rolled = _rolled(plan)
        rows = np.array([[math.degrees(c.angle), c.angle_offset_deg, c.speed, c.cost, c.result.peak_energy,
                          c.result.peak_force, c.result.max_displacement, c.result.max_penetration, c.target_error,
                          c.result.steps, float(c.feasible), float(i == plan.best)] for i, c in rolled],
                        dtype=np.float64).reshape(len(rolled), len(COST_FIELDS))
        if np.isfinite(rows).all():
            self.pub_costs.publish(messages.encode_float64_multiarray(rows, ["candidate", "field:" + ",".join(COST_FIELDS)]))

    def close(self) -> None:
        """Stop the executor thread, the helper node and the worker processes."""
        self._executor.shutdown(timeout_sec=1.0)
        self._thread.join(timeout=2.0)
        if self.pool is not None:
            self.pool.close()
            self.pool = None
        try:
            self.helper.destroy_node()
        except Exception:  # noqa: BLE001  the context may already be shut down (SIGTERM)
            pass
