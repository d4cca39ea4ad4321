"""An outside client of the node, written from msg_docs (topics.md, the retract scene's YAML) with rclpy's own
message types: grasp the retract scene's flap, lift it 2 cm, let go; with the node's names and with a dVRK arm's
names by remapping. Also: bad jaw messages are dropped and counted, and a relocated robot is taken up."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import PoseStamped, WrenchStamped  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import JointState, PointCloud2  # noqa: E402
from std_msgs.msg import Float64, UInt32  # noqa: E402

SCENE = Path(__file__).resolve().parent.parent / "config" / "scenes" / "retract.yaml"
TIMEOUT = 30.0
DT = 0.01  # the scene's dt
# from the scene's YAML: the flap spans x = 10..70 mm, its top at y = 16 mm; the grasper's pose is its jaw tips
X, TOP = 0.040, 0.016
RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)


class Client:
    """What a user writes: publishers of the tool's pose and jaw, readers of points, wrench, energy, grasped."""

    def __init__(self, ros_client: Any, proc: Any, pose_topic: str = "tool/pose", jaw_topic: str = "tool/jaw") -> None:
        self.ros, self.proc = ros_client, proc
        n = ros_client.node
        self.points: list[PointCloud2] = []
        self.wrench: list[WrenchStamped] = []
        self.energy: list[float] = []
        self.grasped: list[int] = []
        self.diagnostics: list[dict[str, str]] = []
        self.subs = [
            n.create_subscription(PointCloud2, "tissue/points", self.points.append, RELIABLE),
            n.create_subscription(WrenchStamped, "tool/wrench", self.wrench.append, RELIABLE),
            n.create_subscription(Float64, "tissue/energy", lambda m: self.energy.append(m.data), RELIABLE),
            n.create_subscription(UInt32, "tool/grasped", lambda m: self.grasped.append(m.data), RELIABLE),
            n.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, RELIABLE),
        ]
        self.pose_pub = n.create_publisher(PoseStamped, pose_topic, RELIABLE)
        self.jaw_pub = n.create_publisher(JointState, jaw_topic, RELIABLE)
        self.k = 0
        self.t0 = n.get_clock().now()
        ros_client.wait_for_subscriber(self.pose_pub, TIMEOUT, proc)
        ros_client.wait_for_subscriber(self.jaw_pub, TIMEOUT, proc)
        for topic in ("tissue/energy", "tool/grasped", "tissue/points", "tool/wrench"):
            ros_client.wait_for_publisher(topic, TIMEOUT, proc)
        ros_client.spin_until(lambda: all(s.get_publisher_count() for s in self.subs[:4]), TIMEOUT, proc,
                              "our readers matched")

    def close(self) -> None:
        for s in self.subs:
            self.ros.node.destroy_subscription(s)
        self.ros.node.destroy_publisher(self.pose_pub)
        self.ros.node.destroy_publisher(self.jaw_pub)

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.endswith("tissue_sim_node: simulation"):
                self.diagnostics.append({kv.key: kv.value for kv in status.values})

    def stamp(self, later: float = 0.0) -> Any:
        """The stamp of the k-th pose (+ ``later`` s): lock-step runs on these stamps, not on the clock."""
        from rclpy.duration import Duration  # noqa: PLC0415

        return (self.t0 + Duration(nanoseconds=int(round((self.k * DT + later) * 1e9)))).to_msg()

    def jaw(self, angle: float, frame: str = "", position: list[float] | None = None) -> None:
        """The jaw, between the last pose sent and the next (lock-step: the next pose takes it, by its stamp)."""
        msg = JointState()
        msg.header.stamp = self.stamp(0.5 * DT)
        msg.header.frame_id = frame
        msg.name = ["jaw"]
        msg.position = [angle] if position is None else position
        self.jaw_pub.publish(msg)
        self.ros.spin_for(0.02)  # the reader takes it before the next pose (lock-step: the newest jaw before it)

    def pose(self, x: float, y: float, wait: bool = True) -> None:
        """One lock-step step: the pose (yaw 0: shaft up), then wait for its energy."""
        self.k += 1
        msg = PoseStamped()
        msg.header.stamp = self.stamp()
        msg.header.frame_id = "world"
        msg.pose.position.x, msg.pose.position.y = float(x), float(y)
        msg.pose.orientation.w = 1.0
        n = len(self.grasped)
        self.pose_pub.publish(msg)
        if wait:
            self.ros.spin_until(lambda: len(self.grasped) > n and len(self.energy) > n, TIMEOUT, self.proc,
                                f"step {self.k}")

    def xy(self) -> np.ndarray:
        """The newest tissue/points as (N, 2): fields x, y (float32) as PointField says."""
        self.ros.spin_until(lambda: self.points, TIMEOUT, self.proc, "tissue/points")
        msg = self.points[-1]
        fields = {f.name: f.offset for f in msg.fields}
        raw = np.frombuffer(bytes(msg.data), dtype=np.uint8).reshape(-1, msg.point_step)
        return np.stack([raw[:, fields[c]:fields[c] + 4].copy().view("<f4").ravel() for c in ("x", "y")],
                        axis=1).astype(np.float64)


def start_node(start_process: Any, name: str, *extra: str) -> Any:
    return start_process(["tissue_sim_node", "--ros-args", "--params-file", str(SCENE), "-p", "lock_step:=true",
                          *extra], name=name)


def grasp_lift_release(c: Client) -> None:
    """Open grasper down onto the flap, close, lift 2 cm, open: the checks of issue 30's outside client."""
    c.jaw(0.8)
    for k in range(21):  # from 1 cm above down to 0.2 mm above the surface, 0.5 mm per step
        c.pose(X, TOP + 0.010 - 0.0005 * k + 0.0002 * (k == 20))
    assert c.grasped[-1] == 0  # open: nothing held
    xy = c.xy()
    i = int(np.argmin(np.hypot(xy[:, 0] - X, xy[:, 1] - TOP)))  # the particle under the tip
    y_before = xy[i, 1]
    c.jaw(0.0)
    for _ in range(3):
        c.pose(X, TOP + 0.0002)
    assert c.grasped[-1] > 0
    e_before = c.energy[-1]
    for k in range(1, 51):  # lift 2 cm at 0.4 mm per step
        c.pose(X, TOP + 0.0002 + 0.0004 * k)
    rise = c.xy()[i, 1] - y_before
    assert abs(rise - 0.02) < 0.002, rise
    f = c.wrench[-1].wrench.force
    assert f.y < 0 and abs(f.x) < abs(f.y)  # the flap pulls the tool back down, toward the tissue
    assert math.isfinite(c.energy[-1]) and c.energy[-1] > e_before
    c.jaw(0.8)
    for _ in range(60):
        c.pose(X, TOP + 0.0202)
    assert c.grasped[-1] == 0
    assert abs(c.xy()[i, 1] - y_before) < 0.001  # the flap fell back


def test_outside_client_grasps_lifts_and_releases_the_flap(ros_client: Any, start_process: Any) -> None:
    proc = start_node(start_process, "retract_node")
    c = Client(ros_client, proc)
    try:
        grasp_lift_release(c)
    finally:
        c.close()
    assert "Traceback" not in proc.output()


def test_dvrk_names_by_remapping(ros_client: Any, start_process: Any) -> None:
    proc = start_node(start_process, "retract_dvrk", "-r", "tool/pose:=/PSM1/measured_cp",
                      "-r", "tool/twist:=/PSM1/measured_cv", "-r", "tool/jaw:=/PSM1/jaw/measured_js")
    c = Client(ros_client, proc, pose_topic="/PSM1/measured_cp", jaw_topic="/PSM1/jaw/measured_js")
    try:
        grasp_lift_release(c)
    finally:
        c.close()


def test_bad_jaw_messages_are_dropped_counted_and_a_relocated_robot_is_taken_up(ros_client: Any,
                                                                                  start_process: Any) -> None:
    proc = start_node(start_process, "retract_bad", "-p", "diagnostics_rate:=20.0")
    c = Client(ros_client, proc)
    try:
        c.jaw(0.8)
        c.pose(X, TOP + 0.01)
        c.jaw(float("nan"))
        c.jaw(0.0, position=[])
        c.jaw(0.0, frame="nowhere")
        for k in range(1, 5):
            c.pose(X, TOP + 0.01 - 0.0025 * k + 0.0002 * (k == 4))
        c.pose(X, TOP + 0.0002)
        assert c.grasped[-1] == 0  # none of them closed the jaw
        c.diagnostics.clear()
        d = c.ros.spin_until(lambda: c.diagnostics and c.diagnostics[-1], TIMEOUT, proc, "diagnostics")
        assert int(d["dropped_nonfinite"]) == 1 and int(d["dropped_jaw_empty"]) == 1 and int(d["dropped_frame"]) == 1
        assert d["jaw_closed"] == "false" and d["grasped_particles"] == "0"
        # a re-homed robot: 4 cm away (max_tool_jump is 5 mm), a consistent stream; taken up at its 5th pose
        for k in range(5):  # rejected poses take no step (lock-step); the 5th is taken up and steps
            c.pose(X + 0.02, TOP + 0.03 + 0.001 * k, wait=k == 4)
        c.ros.spin_until(lambda: c.diagnostics and c.diagnostics[-1].get("relocations") == "1", TIMEOUT, proc,
                         "a relocation on /diagnostics")
        d = c.diagnostics[-1]
        assert int(d["dropped_tool_jump"]) == 4
        assert "tool relocated" in proc.output()
        assert int(d["tool_tunnelled_particles"]) == 0 and d["tool_buried_in_tissue"] == "false"
        # the tool follows from there (the step after the relocation moved it along the new stream)
        c.pose(X + 0.02, TOP + 0.035)
        assert c.grasped[-1] == 0
        # holding tissue, a far stream is never taken up: the flap would be torn across the scene
        for k in range(1, 9):  # down onto the flap, 4.35 mm per step
            c.pose(X + 0.02, TOP + 0.035 - 0.0043 * k - 0.0001 * (k == 8))
        c.jaw(0.0)
        c.pose(X + 0.02, TOP + 0.0002)
        assert c.grasped[-1] > 0
        for k in range(6):
            c.pose(X - 0.02, TOP + 0.03 + 0.001 * k, wait=False)
        c.pose(X + 0.02, TOP + 0.001)  # within max_tool_jump of the tool: a step, which also flushes the far ones
        c.diagnostics.clear()
        d = c.ros.spin_until(lambda: c.diagnostics and c.diagnostics[-1], TIMEOUT, proc, "diagnostics")
        assert d["relocations"] == "1" and int(d["dropped_tool_jump"]) == 4 + 6
        assert c.grasped[-1] > 0
    finally:
        c.close()


def test_a_recorded_grasp_replays_bit_for_bit(ros_client: Any, start_process: Any, tmp_path: Path) -> None:
    """record_path records tool/jaw in and tool/applied_jaw out; ``replay --mode applied`` steps with that jaw and
    equals the live run (energy, wrench, points), grasp and release included."""
    import signal  # noqa: PLC0415

    from test_ros_node import _assert_replay_is_the_live_run  # noqa: PLC0415

    from tissue_sim_ros.ros.bags import Bag  # noqa: PLC0415

    bag = tmp_path / "grasp_bag"
    proc = start_node(start_process, "retract_rec", "-p", f"record_path:={bag}")
    c = Client(ros_client, proc)
    try:
        grasp_lift_release(c)
    finally:
        c.close()
    assert proc.stop(signal.SIGINT) == 0, proc.output()[-2000:]
    with Bag(bag) as b:
        counts = b.message_counts
    assert counts["/tool/applied_jaw"] == counts["/tool/applied_twist"] and counts["/tool/jaw"] >= 3
    _assert_replay_is_the_live_run(bag, "", tmp_path / "replay")
    with Bag(tmp_path / "replay" / "replay_bag") as b:
        from tissue_sim_ros.ros import messages as M  # noqa: PLC0415

        held = [M.decode_uint32(raw) for _, _, _, raw in b.messages(["/tool/grasped"])]
    assert max(held) > 0 and held[-1] == 0
    # tissue-sim play drives a fresh node through the same grasp (tool/pose, tool/twist and tool/jaw by default)
    fresh = start_node(start_process, "retract_played")
    c = Client(ros_client, fresh)
    try:
        play = start_process(["tissue-sim", "play", str(bag), "--wait", "30"], name="play")
        # read the node's outputs while play runs (they keep the last 100 for a reader that does not)
        c.ros.spin_until(lambda: not play.alive(), 120, None, "play to finish")
        assert play.wait(10) == 0, play.output()[-2000:]
        assert "/tool/jaw" in play.output()
        c.ros.spin_until(lambda: len(c.grasped) >= len(held), TIMEOUT, fresh, "every played step")
        assert c.grasped == held  # the same grasp, step for step
    finally:
        c.close()


def test_a_step_that_stops_short_is_reported_and_warned(ros_client: Any, start_process: Any) -> None:
    """issue 29: a material step whose solve ends beyond solve_tolerance says so on /diagnostics (WARN level,
    solve_converged false, unconverged_steps counted) and in a throttled log line; converged steps say nothing."""
    proc = start_node(start_process, "grasp_unconverged", "-p", "iterations:=1", "-p", "solve_tolerance:=1e-9")
    c = Client(ros_client, proc)
    try:
        c.jaw(0.8)
        for k in range(10):  # the open grasper comes down onto the flap: each step a real motion
            c.pose(X, TOP + 0.010 - 0.0008 * k)
        c.diagnostics.clear()
        d = c.ros.spin_until(lambda: c.diagnostics and c.diagnostics[-1], TIMEOUT, proc, "diagnostics")
        assert d["solve_converged"] == "false" and int(d["unconverged_steps"]) >= 1, d
        # one iteration per part: the barrier step approaches the tool's 0.8 mm in parts of a tenth of the
        # boundary's median edge (core/physics/solvers/ipc.py, COMMAND_PART), each capped at `iterations`
        assert 1 <= int(d["solve_iterations"]) <= 8 and float(d["solve_residual"]) > 1e-9
        c.ros.spin_until(lambda: "stopped short of its own step" in proc.output(), TIMEOUT, proc,
                         "the node's warning")
    finally:
        c.close()


def test_the_scenes_start_pose_is_applied_until_a_pose_is_taken_where_it_lies(ros_client: Any,
                                                                               start_process: Any) -> None:
    """Timer mode on the retract scene, which sets tool_start_*: tool/applied_pose is the start pose from the
    first step; a first pose 3 cm away is taken where it lies (no drop, no relocation counted); a first pose in
    the tissue is refused; ~/reset puts the tool back at the start pose."""
    from std_srvs.srv import Trigger  # noqa: PLC0415

    start = (0.030, 0.031)
    proc = start_process(["tissue_sim_node", "--ros-args", "--params-file", str(SCENE),
                          "-p", "diagnostics_rate:=5.0"], name="retract_start")
    n = ros_client.node
    applied: list[PoseStamped] = []
    diag: list[dict[str, str]] = []
    subs = [n.create_subscription(PoseStamped, "tool/applied_pose", applied.append, RELIABLE),
            n.create_subscription(DiagnosticArray, "/diagnostics", lambda m: diag.extend(
                {kv.key: kv.value for kv in s.values} for s in m.status), RELIABLE)]
    pub = n.create_publisher(PoseStamped, "tool/pose", RELIABLE)
    reset = n.create_client(Trigger, "/tissue_sim_node/reset")

    def at(x: float, y: float, what: str) -> None:
        applied.clear()
        ros_client.spin_until(lambda: applied and (applied[-1].pose.position.x, applied[-1].pose.position.y)
                              == pytest.approx((x, y), abs=1e-12), TIMEOUT, proc, what)

    def send(x: float, y: float) -> None:
        msg = PoseStamped()
        msg.header.stamp = n.get_clock().now().to_msg()
        msg.header.frame_id = "world"
        msg.pose.position.x, msg.pose.position.y = x, y
        msg.pose.orientation.w = 1.0
        pub.publish(msg)

    try:
        at(*start, "the start pose applied")
        ros_client.wait_for_subscriber(pub, TIMEOUT, proc)
        send(0.060, 0.030)  # 3 cm from the start pose (max_tool_jump 5 mm), clear of the flap
        at(0.060, 0.030, "the first pose taken where it lies")
        diag.clear()
        d = ros_client.spin_until(lambda: diag and diag[-1], TIMEOUT, proc, "/diagnostics")
        assert d["dropped_tool_jump"] == "0" and d["relocations"] == "0", d
        ros_client.call(reset, Trigger.Request(), TIMEOUT, proc)
        at(*start, "the start pose after ~/reset")
        send(0.040, 0.010)  # inside the flap (y = 4..16 mm): the tool stays at its start pose
        diag.clear()
        d = ros_client.spin_until(lambda: diag and diag[-1]["dropped_tool_jump"] == "1" and diag[-1], TIMEOUT, proc,
                                  "the pose in the tissue dropped")
        at(*start, "the start pose held")
    finally:
        for s in subs:
            n.destroy_subscription(s)
        n.destroy_publisher(pub)
        n.destroy_client(reset)
