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
which plan), ``live_plans.csv`` (every request: step, latency, poses
answered) and ``live_plan.png``: the first plan as RViz shows it, drawn from
what the node published (the particles of ``tissue/points``, the candidate
lines of ``plan/candidates`` in their cost colours, ``plan/costs``), and
prints a summary.
"""
from __future__ import annotations

import csv
import math
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from ..core.errors import InputError


def default_entry() -> tuple[float, float]:
    """Where the tip enters by default [m]: 0.2 m from experiment b's target, approaching it at -30 deg."""
    from ..core.timing import trajectories as tr  # noqa: PLC0415

    a = math.radians(-30.0)
    return (tr.B_TARGET[0] - 0.2 * math.cos(a), tr.B_TARGET[1] - 0.2 * math.sin(a))


def _wait(executor, predicate, timeout: float, what: str):
    end = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > end:
            raise InputError(f"timed out after {timeout} s waiting for {what}")
        executor.spin_once(timeout_sec=0.01)
    return predicate()


def run_live(out: str | Path, *, target: Sequence[float], entry: Sequence[float] | None = None,
             replan_every: int = 25, node_name: str = "/tissue_sim_node", frame: str = "world",
             timeout: float = 60.0) -> int:
    """Plan on the running node, carry the plan out, replan; write the CSVs and the figure into ``out``.

    Parameters
    ----------
    out : str or Path
        Output directory (created).
    target : (x, y)
        The tip's target [m].
    entry : (x, y), optional
        Where the tip enters [m] (default :func:`default_entry`).
    replan_every : int
        Replan every this many steps (0: never).
    node_name : str
        The simulation node's name; its namespace is the tool topics'.
    frame : str
        Frame of the request and the poses.
    timeout : float
        Seconds to wait for the service, the subscribers and each plan.

    Returns
    -------
    int
        0, or 1 when the node answers the first request with no plan.
    """
    import rclpy  # noqa: PLC0415
    from geometry_msgs.msg import PoseStamped, TwistStamped  # noqa: PLC0415
    from nav_msgs.srv import GetPlan  # noqa: PLC0415
    from rclpy.executors import SingleThreadedExecutor  # noqa: PLC0415
    from std_msgs.msg import Float64MultiArray  # noqa: PLC0415
    from visualization_msgs.msg import MarkerArray  # noqa: PLC0415

    from ..ros import qos  # noqa: PLC0415

    if replan_every < 0:
        raise InputError(f"--replan-every={replan_every}: expected N >= 0 steps (0: never)")
    if not (math.isfinite(timeout) and timeout > 0):
        raise InputError(f"--timeout={timeout}: expected seconds > 0")
    entry = default_entry() if entry is None else entry
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rclpy.init(args=[])  # rcl must not parse tissue-sim's own command line
    node = rclpy.create_node("plan_live")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    ns = node_name.rsplit("/", 1)[0]
    pub_pose = node.create_publisher(PoseStamped, f"{ns}/tool/pose", qos.tool_output())
    pub_twist = node.create_publisher(TwistStamped, f"{ns}/tool/twist", qos.tool_output())
    client = node.create_client(GetPlan, f"{node_name}/plan_insertion")
    seen: dict[str, object] = {}
    node.create_subscription(MarkerArray, f"{ns}/plan/candidates", lambda m: seen.setdefault("candidates", m),
                             qos.latched())
    node.create_subscription(Float64MultiArray, f"{ns}/plan/costs", lambda m: seen.setdefault("costs", m),
                             qos.latched(), raw=True)
    node.create_subscription(MarkerArray, f"{ns}/tissue/markers", lambda m: seen.__setitem__("tissue", m),
                             qos.state_stream())
    target = (float(target[0]), float(target[1]))
    sent: list[tuple[float, float, float, float, int]] = []
    requests: list[dict] = []

    def pose_msg(x: float, y: float, yaw: float = 0.0) -> PoseStamped:
        ps = PoseStamped()
        ps.header.frame_id = frame
        ps.header.stamp = node.get_clock().now().to_msg()
        ps.pose.position.x, ps.pose.position.y = float(x), float(y)
        ps.pose.orientation.z, ps.pose.orientation.w = math.sin(yaw / 2.0), math.cos(yaw / 2.0)
        return ps

    stamp_dt = {"dt": 0.01}

    def ask(start: tuple[float, float], step: int) -> list[tuple[float, float, float]]:
        t0 = time.perf_counter()
        future = client.call_async(GetPlan.Request(start=pose_msg(*start), goal=pose_msg(*target)))
        _wait(executor, future.done, timeout, "a plan")
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
        _wait(executor, client.service_is_ready, timeout, f"the service {node_name}/plan_insertion")
        _wait(executor, lambda: pub_pose.get_subscription_count() > 0, timeout, f"{ns}/tool/pose's subscriber")
        _wait(executor, lambda: "tissue" in seen, timeout, f"{ns}/tissue/markers")
        tissue_at_request = seen["tissue"]
        path = ask(tuple(entry), 0)
        if not path:
            print(f"no plan from {tuple(entry)} to {target}: the node's log says why")
            return 1
        _wait(executor, lambda: "candidates" in seen and "costs" in seen, timeout, "the plan's candidates")
        figure = draw_plan(out / "live_plan.png", tissue_at_request, seen["candidates"], seen["costs"],
                           tuple(entry), target)
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
            if replan_every and step % replan_every == 0 and k < len(path):
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
          f"from the target; wrote {out / 'live.csv'}, {out / 'live_plans.csv'} and {figure}")
    return 0


def draw_plan(path: Path, tissue, candidates, costs: bytes, entry: tuple[float, float],
              target: tuple[float, float]) -> Path:
    """The plan as RViz shows it, from the published messages: the tissue, candidate lines in their colours, costs."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    from matplotlib.collections import PolyCollection  # noqa: PLC0415
    from matplotlib.colors import LinearSegmentedColormap, LogNorm  # noqa: PLC0415
    from matplotlib.lines import Line2D  # noqa: PLC0415
    from matplotlib.patches import Patch  # noqa: PLC0415

    from ..ros import messages  # noqa: PLC0415

    rows, labels = messages.decode_float64_multiarray(costs)
    fields = labels[1].split(":", 1)[1].split(",")
    col = {name: rows[:, i] for i, name in enumerate(fields)}
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.8), gridspec_kw={"width_ratios": [1.25, 1]})
    tissue_colour = (0.9, 0.6, 0.6, 1.0)
    for m in tissue.markers:  # the deformed mesh (TRIANGLE_LIST, strain colours) as RViz draws it
        if m.ns == "tissue" and m.type == m.TRIANGLE_LIST and m.points:
            xy = np.array([(p.x, p.y) for p in m.points]).reshape(-1, 3, 2)
            rgba = np.array([(c.r, c.g, c.b, c.a) for c in m.colors]).reshape(-1, 3, 4).mean(axis=1) \
                if len(m.colors) == len(m.points) else (m.color.r, m.color.g, m.color.b, m.color.a)
            tissue_colour = tuple(np.atleast_2d(rgba).mean(axis=0))
            ax.add_collection(PolyCollection(xy, facecolors=rgba, edgecolors="#9e9e9e", linewidths=0.4, zorder=1))
    for m in candidates.markers:
        if m.ns != "plan_candidates":
            continue
        xs, ys = [p.x for p in m.points], [p.y for p in m.points]
        ax.plot(xs, ys, color=(m.color.r, m.color.g, m.color.b), alpha=m.color.a, lw=1000 * m.scale.x / 2,
                solid_capstyle="round", zorder=2 + (m.scale.x > 0.004))
    ax.plot(*target, marker="o", ms=9, color="#ffd600", mec="#8d6e00", zorder=5, label="goal")
    ax.plot(*entry, marker="s", ms=6, color="k", zorder=5, label="start")
    # the mesh's legend entry as it is drawn: a filled triangle in its colours with grey edges, not a line
    mesh_handle = Patch(facecolor=tissue_colour, edgecolor="#9e9e9e", lw=0.4,
                        label="tissue mesh (tissue/markers, strain colours)")
    ax.set_aspect("equal")
    ax.set_xlim(min(entry[0], target[0]) - 0.25, max(entry[0], target[0]) + 0.1)
    ax.set_ylim(min(entry[1], target[1]) - 0.15, max(entry[1], target[1]) + 0.15)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("plan/candidates: tip paths coloured by cost (wide: the plan)", fontsize=9)
    ax.legend(handles=ax.get_legend_handles_labels()[0] + [mesh_handle], fontsize=7, loc="lower left")
    feasible = col["feasible"] > 0
    green_red = LinearSegmentedColormap.from_list("cost", [(0.0, 1.0, 0.15), (1.0, 0.2, 0.15)])
    positive = col["cost"][feasible & (col["cost"] > 0)]
    norm = LogNorm(positive.min(), positive.max()) if positive.size >= 2 and positive.max() > positive.min() else None
    for v in np.unique(col["speed_mps"]):
        sel = col["speed_mps"] == v
        order = np.argsort(col["angle_deg"][sel])
        bx.plot(col["angle_deg"][sel][order], col["cost"][sel][order], "-", color="0.7", zorder=1)
        bx.scatter(col["angle_deg"][sel], col["cost"][sel], c=col["cost"][sel], cmap=green_red, norm=norm,
                   s=40, marker="o" if v == col["speed_mps"].min() else "^", zorder=2, label=f"{v:g} m/s")
    best = col["best"] > 0
    bx.scatter(col["angle_deg"][best], col["cost"][best], marker="*", s=260, color="#ffd600", edgecolor="#8d6e00",
               zorder=3)
    # the points' colour is their cost, not their speed: the legend says the speed by the marker's shape alone
    # (a scatter's own legend entry takes the colour of its first point's cost)
    handles = [Line2D([], [], ls="none", marker="o" if v == col["speed_mps"].min() else "^", color="0.45", ms=6,
                      label=f"{v:g} m/s (colour: cost)") for v in np.unique(col["speed_mps"])]
    handles.append(Line2D([], [], ls="none", marker="*", ms=13, color="#ffd600", mec="#8d6e00", label="the plan"))
    if positive.size:
        bx.set_yscale("log")
    bx.set_xlabel("approach angle [deg]")
    bx.set_ylabel("cost: energy added over the tool-free baseline")
    bx.set_title("plan/costs", fontsize=9)
    bx.legend(handles=handles, fontsize=7)
    bx.grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path

