"""An outside client of ``tissue_controller`` beside ``tissue_sim_node``, written from msg_docs (controller.md,
topics.md) with rclpy's own message types: move a point of the retract scene's flap 1 cm right and 2 cm up
through ``~/move_tissue`` and watch it arrive on tissue/points; the refusals answer at once with an empty path.

One simulator (timer mode, 100 Hz) and one controller serve the module's tests in turn, both started as
msg_docs/controller.md shows (the scene's parameter file, the controller's defaults) and nothing else publishing
a tool pose: the scene's start pose (``tool_start_*``) gives the controller its first measured pose. The
controller's model is its own 5 mm mesh of the scene (the world's is 2.5 mm).
"""
from __future__ import annotations

import math
import signal
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import PoseStamped  # noqa: E402
from nav_msgs.srv import GetPlan  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402
from visualization_msgs.msg import MarkerArray  # noqa: E402

from ros_env import RosClient, RosProcess, console_script  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
SCENE = ROOT / "config" / "scenes" / "retract.yaml"
TIMEOUT = 30.0  # discovery and start-up of a process on a loaded 2-core machine
REACH_WALL_S = 20.0  # the bound: the point at its goal within 20 s of wall time
X = 0.040  # the flap spans x = 10..70 mm (the scene's YAML); its top surface is at y = 16 mm
HOME = (0.030, 0.031)  # the scene's start pose (tool_start_x, tool_start_y): 15 mm above the flap, open
RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
SERVICE = "/tissue_controller/move_tissue"


def xy_of(msg: PointCloud2) -> np.ndarray:
    """A PointCloud2's fields x, y (float32, as PointField says) as (N, 2) float64."""
    fields = {f.name: f.offset for f in msg.fields}
    raw = np.frombuffer(bytes(msg.data), dtype=np.uint8).reshape(-1, msg.point_step)
    return np.stack([raw[:, fields[c]:fields[c] + 4].copy().view("<f4").ravel() for c in ("x", "y")],
                    axis=1).astype(np.float64)


class World:
    """The simulator, the controller and what the client reads from them."""

    def __init__(self, ros: RosClient, sim: RosProcess, ctrl: RosProcess) -> None:
        self.ros, self.sim, self.ctrl = ros, sim, ctrl
        n = ros.node
        self.points: list[tuple[float, np.ndarray]] = []
        """(arrival, xy) of every tissue/points message."""
        self.nonfinite_clouds = 0
        self.applied: list[PoseStamped] = []
        self.sim_diag: list[tuple[float, dict[str, str]]] = []
        self.ctrl_diag: list[dict[str, str]] = []
        self.markers: list[MarkerArray] = []
        self.subs = [
            n.create_subscription(PointCloud2, "tissue/points", self._on_points, RELIABLE),
            n.create_subscription(PoseStamped, "tool/applied_pose", self.applied.append, RELIABLE),
            n.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, RELIABLE),
            n.create_subscription(MarkerArray, "control/markers", self.markers.append, LATCHED),
        ]
        self.client = n.create_client(GetPlan, SERVICE)

    def _on_points(self, msg: PointCloud2) -> None:
        xy = xy_of(msg)
        if not np.isfinite(xy).all():
            self.nonfinite_clouds += 1
        self.points.append((time.monotonic(), xy))

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            if status.name.endswith("tissue_sim_node: simulation"):
                self.sim_diag.append((time.monotonic(), values))
            elif status.name.endswith("tissue_controller: controller"):
                self.ctrl_diag.append(values)

    def close(self) -> None:
        for s in self.subs:
            self.ros.node.destroy_subscription(s)
        self.ros.node.destroy_client(self.client)

    # ------------------------------------------------------------------ reading

    def spin_until(self, predicate: Any, timeout: float, what: str) -> Any:
        for proc in (self.sim, self.ctrl):
            if not proc.alive():
                pytest.fail(f"{proc.cmd[0]} exited with {proc.returncode}:\n{proc.output()[-3000:]}")
        return self.ros.spin_until(predicate, timeout, self.ctrl, what)

    def xy(self) -> np.ndarray:
        self.spin_until(lambda: self.points, TIMEOUT, "tissue/points")
        return self.points[-1][1]

    def fresh_ctrl_diag(self, what: str = "the controller's /diagnostics") -> dict[str, str]:
        self.ctrl_diag.clear()
        return self.spin_until(lambda: self.ctrl_diag and self.ctrl_diag[-1], TIMEOUT, what)

    def fresh_sim_diag(self) -> tuple[float, dict[str, str]]:
        self.sim_diag.clear()
        return self.spin_until(lambda: self.sim_diag and self.sim_diag[-1], TIMEOUT, "the simulator's /diagnostics")

    # ------------------------------------------------------------------ acting

    def measured_tool(self) -> None:
        """The simulator publishes its start pose as the applied pose, and the controller has received it."""
        self.spin_until(lambda: self.applied, TIMEOUT, "tool/applied_pose from the scene's start pose")
        self.spin_until(lambda: self.ctrl_diag and int(self.ctrl_diag[-1]["poses_received"]) > 0, TIMEOUT,
                        "the controller to receive a measured tool pose")

    def flap_top(self) -> tuple[int, np.ndarray]:
        """The highest particle within 1.5 mm of x = X: its index and position."""
        xy = self.xy()
        near = np.flatnonzero(np.abs(xy[:, 0] - X) < 0.0015)
        i = int(near[np.argmax(xy[near, 1])])
        return i, xy[i].copy()

    def move(self, start: tuple[float, float], goal: tuple[float, float]) -> tuple[Any, float]:
        """Call ~/move_tissue; the response and its wall time [s]."""
        req = GetPlan.Request()
        for ps, (x, y) in ((req.start, start), (req.goal, goal)):
            ps.header.frame_id = "world"
            ps.header.stamp = self.ros.node.get_clock().now().to_msg()
            ps.pose.position.x, ps.pose.position.y = float(x), float(y)
            ps.pose.orientation.w = 1.0
        self.spin_until(lambda: self.client.service_is_ready(), TIMEOUT, f"service {SERVICE}")
        t0 = time.monotonic()
        resp = self.ros.call(self.client, req, TIMEOUT, self.ctrl)
        return resp, time.monotonic() - t0


@pytest.fixture(scope="module")
def world(ros_client: RosClient, ros_env: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Any:
    """The simulator on the retract scene (timer mode) and the controller, for the module; both ended after it."""
    logs = tmp_path_factory.mktemp("controller_node")
    sim = RosProcess([console_script("tissue_sim_node"), "--ros-args", "--params-file", str(SCENE)], ros_env,
                     logs / "sim.log")
    ctrl = RosProcess([console_script("tissue_controller")], ros_env, logs / "controller.log")
    w = World(ros_client, sim, ctrl)
    try:
        w.spin_until(lambda: w.client.service_is_ready(), 60.0, f"service {SERVICE}")
        w.spin_until(lambda: w.points and w.sim_diag and w.ctrl_diag, TIMEOUT, "points and both diagnostics")
        yield w
    finally:
        w.close()
        ctrl.stop(signal.SIGTERM, timeout=10)
        sim.stop(signal.SIGTERM, timeout=10)


def test_the_two_nodes_work_as_started(world: World) -> None:
    """Nobody but the controller publishes tool/pose, and the simulator's applied pose is its start pose."""
    world.measured_tool()
    writers = [i.node_name for i in world.ros.node.get_publishers_info_by_topic("/tool/pose")]
    assert writers == ["tissue_controller"], writers
    p = world.applied[-1].pose.position
    assert (p.x, p.y) == pytest.approx(HOME, abs=1e-12)


def test_refusals_answer_at_once_with_an_empty_path(world: World) -> None:
    world.measured_tool()
    _, top = world.flap_top()
    cases = [
        ((top[0], top[1] + 0.03), (top[0] + 0.01, top[1] + 0.05), "on the tissue"),  # 3 cm above
        ((top[0], top[1]), (top[0] + 0.01, math.nan), "finite"),  # a NaN goal
        ((top[0], top[1]), (top[0] + 0.1, top[1]), "max_reach"),  # 10 cm away
    ]
    for start, goal, words in cases:
        resp, took = world.move(start, goal)
        assert not resp.plan.poses, (start, goal)
        assert took < 2.0, f"the refusal of {start} -> {goal} took {took:.2f} s"
        d = world.fresh_ctrl_diag()
        assert words in d["last_refusal"], d["last_refusal"]
        # a refusal leaves a pursuit alone; with none, the state says refused
        assert d["state"] == "refused" or int(d["accepted"]) > 0, d


def test_the_flap_point_reaches_its_goal(world: World) -> None:
    world.measured_tool()
    i, start = world.flap_top()
    goal = start + np.array([0.01, 0.02])
    t_diag0, d0 = world.fresh_sim_diag()
    n_points = len(world.points)
    nonfinite0 = world.nonfinite_clouds
    resp, took = world.move(tuple(start), tuple(goal))
    t_request = time.monotonic() - took
    plan = np.array([(p.pose.position.x, p.pose.position.y) for p in resp.plan.poses])
    assert len(plan) >= 2 and np.isfinite(plan).all(), plan
    assert resp.plan.header.frame_id == "world"
    assert np.hypot(*(plan[0] - HOME)) < 1e-3  # it starts at the measured tool

    def error() -> float:
        return float(np.hypot(*(world.points[-1][1][i] - goal))) if len(world.points) > n_points else math.inf

    world.spin_until(lambda: error() <= 0.002, REACH_WALL_S - took, "the point within 2 mm of its goal")
    reached_wall = world.points[-1][0] - t_request
    t_diag1, d1 = world.fresh_sim_diag()
    assert world.nonfinite_clouds == nonfinite0 == 0
    # the simulator kept its rate while the controller planned beside it
    steps = int(d1["steps"]) - int(d0["steps"])
    missed = int(d1["missed_ticks"]) - int(d0["missed_ticks"])
    over = int(d1["overruns"]) - int(d0["overruns"])
    rate = steps / (t_diag1 - t_diag0)
    missed_pct = 100.0 * (missed + over) / max(steps + missed, 1)
    # the controller holds once its own goal error stays within goal_tolerance (0.5 s), and says so
    d = world.spin_until(lambda: world.ctrl_diag and world.ctrl_diag[-1]["state"] != "pursuing"
                         and world.ctrl_diag[-1], TIMEOUT, "the controller to finish")
    print(f"\nreached within 2 mm {reached_wall:.2f} s of wall time after the request (answered in {took:.3f} s); "
          f"simulator {rate:.1f} Hz, {steps} steps, {missed} skipped ticks, {over} overruns ({missed_pct:.2f}%); "
          f"controller: {d['state']} after {d['elapsed_s']} s, {d['replans']} replans, last {d['last_replan_ms']} ms, "
          f"max {d['max_replan_ms']} ms, {d['skipped_points']} points skipped, observed error "
          f"{float(d['observed_goal_error_m']) * 1e3:.2f} mm, command latency mean {d['command_latency_ms_mean']} ms, max {d['command_latency_ms_max']} ms")
    assert d["state"] == "reached", d
    assert float(d["observed_goal_error_m"]) <= 0.0025 and float(d["goal_error_m"]) <= 0.002, d
    assert int(d["unpublished_nonfinite"]) == 0 and int(d["accepted"]) >= 1
    # (alone on the 2 cores: 0-1 late steps in 200; a bound that a controller taking the simulator's core breaks,
    # 39% un-niced, and that other load on a shared machine does not)
    assert rate >= 90.0 and missed_pct < 10.0, (rate, steps, missed, over)
    doc = (ROOT / "msg_docs" / "controller.md").read_text()
    assert not [k for k in d if f"`{k}`" not in doc], "keys on /diagnostics that msg_docs/controller.md omits"
    # its markers: the candidates of the last replan, the chosen one, the start and the goal
    world.spin_until(lambda: world.markers, TIMEOUT, "control/markers")
    ns = {m.ns for m in world.markers[-1].markers}
    assert {"control_candidates", "control_chosen", "control_start", "control_goal"} <= ns, ns
    # it keeps holding: the point stays at its goal
    world.ros.spin_until(lambda: len(world.points) > n_points + 50, TIMEOUT, world.sim, "50 more steps")
    assert error() <= 0.0025


def test_sigterm_ends_the_controller_cleanly(world: World) -> None:
    assert world.ctrl.stop(signal.SIGTERM, timeout=10) == 0, world.ctrl.output()[-3000:]
    out = world.ctrl.output()
    assert "Traceback" not in out, out[-3000:]
    assert "ready: ~/move_tissue" in out


def test_help_and_a_bad_parameter(ros_env: dict[str, str], tmp_path: Path) -> None:
    """--help prints the usage without starting a node; a bad parameter is one line naming it, exit 2."""
    import subprocess  # noqa: PLC0415

    run = subprocess.run([console_script("tissue_controller"), "--help"], env=ros_env, capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 0 and "~/move_tissue" in run.stdout and "controller.md" in run.stdout, run.stdout
    run = subprocess.run([console_script("tissue_controller"), "--ros-args", "-p", "horizon:=5"], env=ros_env,
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2, run.stderr
    assert run.stderr.strip().splitlines() == ["tissue_controller: error: replan_every=10: expected at most "
                                               "horizon=5 steps"], run.stderr
    # the node's own ranges are its parameters' descriptors' (rclpy refuses the value at declaration)
    for given, line in (("jobs:=0", "jobs=0: expected 1 to 256"), ("max_time:=0", "max_time=0.0: expected 0.001 to 1e+06"),
                        ("nice:=hi", "nice='hi': expected an integer")):
        run = subprocess.run([console_script("tissue_controller"), "--ros-args", "-p", given], env=ros_env,
                             capture_output=True, text=True, timeout=60)
        assert run.returncode == 2 and run.stderr.strip().splitlines() == [f"tissue_controller: error: parameter {line}"], \
            run.stderr


def test_the_parameter_table_is_current() -> None:
    """msg_docs/parameters.md holds the node's table as it is: every ControlSettings field (a new field without
    its row in SETTINGS_PARAMETERS shows as a bare row there, and fails here until the doc is regenerated)."""
    from tissue_sim_ros.ros.controller_setup import markdown_table  # noqa: PLC0415

    assert markdown_table() in (ROOT / "msg_docs" / "parameters.md").read_text(), \
        ("msg_docs/parameters.md is stale: give a new ControlSettings field its row in SETTINGS_PARAMETERS "
         "(tissue_sim_ros/ros/controller_setup.py), then paste markdown_table() into the tissue_controller section")
