"""``tissue-sim plan --live``: plan on the running node, carry the plan out, replan every N steps.

A closed loop around a running ``tissue_sim_node`` (timer mode):

1. call its ``~/plan_insertion`` (nav_msgs/srv/GetPlan) from ``--entry`` to
   ``--target``; the node plans from its tissue as it is now;
2. publish the answered path on the node's ``tool/pose`` and ``tool/twist``,
   one pose per dt (stamped when sent; the twist is the pose change over dt);
3. every ``--replan-every`` steps, hold the tool where it is and ask again,
   from the tip's current position: the node plans from the tissue as the
   insertion has left it; an answered plan replaces the rest of the current
   one (a replan that chooses another approach angle starts with the tool's
   move to its new entry, which the node limits to ``max_tool_jump`` per
   step); an empty answer (e.g. the tip is inside the tissue, as the paper's
   contact rule lets it be) keeps the current plan;
4. stop when the path has been played (the tip at the target).

The tool holds while the planner thinks, so the tissue the plan was made
from is the tissue the plan starts on (up to the steps the node takes with
the tool at rest). Writes ``live.csv`` (every pose sent: time, x, y, yaw,
which plan) and ``live_plans.csv`` (every request: step, latency, poses
answered), and prints a summary.
"""
from __future__ import annotations

import argparse
import csv
import math
import time
from pathlib import Path

from ..core.errors import InputError


def add_live_arguments(parser: argparse.ArgumentParser) -> None:
    from . import trajectories as tr  # noqa: PLC0415

    a = math.radians(-30.0)
    entry = [tr.B_TARGET[0] - 0.2 * math.cos(a), tr.B_TARGET[1] - 0.2 * math.sin(a)]
    g = parser.add_argument_group("live planning (--live)")
    g.add_argument("--live", action="store_true",
                   help="plan on a running tissue_sim_node through ~/plan_insertion and carry the plan out")
    g.add_argument("--entry", type=float, nargs=2, default=entry, metavar=("X", "Y"),
                   help="--live: where the tip enters [m] (default: 0.2 m from the target at -30 deg)")
    g.add_argument("--replan-every", type=int, default=25, metavar="N",
                   help="--live: replan every N steps (0: never; default 25)")
    g.add_argument("--node", default="/tissue_sim_node", help="--live: the simulation node's name (default %(default)s)")
    g.add_argument("--frame", default="world", help="--live: frame of the request and the poses (default world)")
    g.add_argument("--timeout", type=float, default=60.0, help="--live: seconds to wait for the service and each plan")


def _wait(executor, predicate, timeout: float, what: str):
    end = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > end:
            raise InputError(f"timed out after {timeout} s waiting for {what}")
        executor.spin_once(timeout_sec=0.01)
    return predicate()


def run_live(args: argparse.Namespace) -> int:
    import rclpy  # noqa: PLC0415
    from geometry_msgs.msg import PoseStamped, TwistStamped  # noqa: PLC0415
    from nav_msgs.srv import GetPlan  # noqa: PLC0415
    from rclpy.executors import SingleThreadedExecutor  # noqa: PLC0415

    from ..ros import qos  # noqa: PLC0415

    if args.replan_every < 0:
        raise InputError(f"--replan-every={args.replan_every}: expected N >= 0 steps (0: never)")
    if not (math.isfinite(args.timeout) and args.timeout > 0):
        raise InputError(f"--timeout={args.timeout}: expected seconds > 0")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rclpy.init()
    node = rclpy.create_node("plan_live")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    ns = args.node.rsplit("/", 1)[0]
    pub_pose = node.create_publisher(PoseStamped, f"{ns}/tool/pose", qos.tool_output())
    pub_twist = node.create_publisher(TwistStamped, f"{ns}/tool/twist", qos.tool_output())
    client = node.create_client(GetPlan, f"{args.node}/plan_insertion")
    target = (float(args.target[0]), float(args.target[1]))
    sent: list[tuple[float, float, float, float, int]] = []
    requests: list[dict] = []

    def pose_msg(x: float, y: float, yaw: float = 0.0) -> PoseStamped:
        ps = PoseStamped()
        ps.header.frame_id = args.frame
        ps.header.stamp = node.get_clock().now().to_msg()
        ps.pose.position.x, ps.pose.position.y = float(x), float(y)
        ps.pose.orientation.z, ps.pose.orientation.w = math.sin(yaw / 2.0), math.cos(yaw / 2.0)
        return ps

    stamp_dt = {"dt": 0.01}

    def ask(start: tuple[float, float], step: int) -> list[tuple[float, float, float]]:
        t0 = time.perf_counter()
        future = client.call_async(GetPlan.Request(start=pose_msg(*start), goal=pose_msg(*target)))
        _wait(executor, future.done, args.timeout, "a plan")
        plan = future.result().plan
        poses = [(p.pose.position.x, p.pose.position.y, 2.0 * math.atan2(p.pose.orientation.z, p.pose.orientation.w))
                 for p in plan.poses]
        if len(plan.poses) >= 2:  # the planner stamps its poses dt apart: the node's step
            a, b = plan.poses[0].header.stamp, plan.poses[1].header.stamp
            stamp_dt["dt"] = (b.sec - a.sec) + (b.nanosec - a.nanosec) * 1e-9
        requests.append({"step": step, "start_x": start[0], "start_y": start[1],
                         "latency_s": time.perf_counter() - t0, "poses": len(poses)})
        return poses

    try:
        _wait(executor, client.service_is_ready, args.timeout, f"the service {args.node}/plan_insertion")
        _wait(executor, lambda: pub_pose.get_subscription_count() > 0, args.timeout, f"{ns}/tool/pose's subscriber")
        path = ask(tuple(args.entry), 0)
        if not path:
            print(f"no plan from {tuple(args.entry)} to {target}: the node's log says why")
            return 1
        dt = stamp_dt["dt"]
        # the tip is at the target at the path's end: its offset from the tool's centre follows
        tip_offset = math.hypot(target[0] - path[-1][0], target[1] - path[-1][1])
        plan_no, k, step = 0, 0, 0
        prev = None
        next_t = time.monotonic()
        while k < len(path):
            x, y, yaw = path[k]
            msg = pose_msg(x, y, yaw)
            pub_pose.publish(msg)
            tw = TwistStamped()
            tw.header = msg.header
            if prev is not None:
                tw.twist.linear.x, tw.twist.linear.y = (x - prev[0]) / dt, (y - prev[1]) / dt
                tw.twist.angular.z = math.atan2(math.sin(yaw - prev[2]), math.cos(yaw - prev[2])) / dt
            pub_twist.publish(tw)
            sent.append((time.time(), x, y, yaw, plan_no))
            prev = (x, y, yaw)
            k += 1
            step += 1
            next_t += dt
            while time.monotonic() < next_t:
                executor.spin_once(timeout_sec=max(0.0, min(0.005, next_t - time.monotonic())))
            if args.replan_every and step % args.replan_every == 0 and k < len(path):
                tip = (x + tip_offset * math.cos(yaw), y + tip_offset * math.sin(yaw))
                new = ask(tip, step)  # the tool holds its last pose meanwhile
                next_t = time.monotonic()
                if new:
                    path, k, plan_no = new, 0, plan_no + 1
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    with open(out / "live.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["wall_time_s", "x", "y", "yaw", "plan"])
        w.writerows(sent)
    with open(out / "live_plans.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(requests[0]))
        w.writeheader()
        w.writerows(requests)
    answered = sum(r["poses"] > 0 for r in requests)
    x, y, yaw = sent[-1][1:4]
    tip = (x + tip_offset * math.cos(yaw), y + tip_offset * math.sin(yaw))
    lat = sorted(r["latency_s"] for r in requests)
    print(f"{len(sent)} poses sent in {len(requests)} plans ({answered} answered, {len(requests) - answered} "
          f"kept the current plan); plan latency median {lat[len(lat) // 2]:.3f} s, max {lat[-1]:.3f} s")
    print(f"tip at ({tip[0]:.4f}, {tip[1]:.4f}) m, {1e3 * math.hypot(tip[0] - target[0], tip[1] - target[1]):.2f} mm "
          f"from the target; wrote {out / 'live.csv'} and {out / 'live_plans.csv'}")
    return 0

