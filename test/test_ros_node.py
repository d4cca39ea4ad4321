"""tissue_sim_node in real processes over real DDS, driven from a test client.

A small scene (a 0.4 m x 0.2 m strip, 66 particles, pinned along its top row)
keeps every step far below dt; a box tool pushes the strip's lower edge up.
One timer-mode node serves the tests of this module in turn (each starts from
a reset); a lock-step node in another namespace runs beside it.
"""
from __future__ import annotations

import math
import os
import signal
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped  # noqa: E402
from rcl_interfaces.msg import Parameter as ParameterMsg  # noqa: E402
from rcl_interfaces.msg import ParameterType, ParameterValue  # noqa: E402
from rcl_interfaces.srv import GetParameters, SetParameters  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from rclpy.serialization import deserialize_message  # noqa: E402
from rclpy.time import Time  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402
from std_srvs.srv import SetBool, Trigger  # noqa: E402
from test_realtime import may_use_fifo  # noqa: E402  (one probe for both test files)
from visualization_msgs.msg import MarkerArray  # noqa: E402

from tissue_sim_ros.core.mesh import mesh_rectangle  # noqa: E402
from tissue_sim_ros.ros import messages as M  # noqa: E402
from tissue_sim_ros.ros import qos  # noqa: E402

from ros_env import RosClient, RosProcess  # noqa: E402

DT = 0.01
TIMEOUT = 20.0  # discovery + start-up of a node process, generous for a loaded 2-core machine
BEST_EFFORT = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT)

SCENE = {
    "boundary_y_top": 0.19,  # the top row (y = 0.2) is pinned
    "boundary_y_bottom": -1.0,  # nothing pinned below
    # a 0.1 m x 0.02 m box pushed up into the lower edge; the projection contact
    # deforms locally (the paper's eq. 3 moves particles by up to alpha per step
    # whatever the tool's speed, which tears a mesh this coarse)
    "tool_shape": "box",
    "tool_length": 0.1,
    "tool_width": 0.02,
    "contact_model": "projection",
    "diagnostics_rate": 10.0,
    "max_tool_jump": 0.05,
    "max_stamp_age": 0.5,
    # the play test publishes /clock on the shared graph: only its own node follows it
    "follow_clock": False,
}


def write_params(path: Path, values: dict[str, Any], section: str = "/**") -> Path:
    lines = [f"{section}:", "  ros__parameters:"]
    for k, v in values.items():
        lines.append(f"    {k}: {v!r}" if not isinstance(v, str) else f"    {k}: \"{v}\"")
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def scene_files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    root = tmp_path_factory.mktemp("scene")
    mesh = mesh_rectangle(0.4, 0.2, 0.04)
    mesh.save(root / "strip.npz")
    params = write_params(root / "params.yaml", {**SCENE, "mesh_file": str(root / "strip.npz")})
    return {"root": root, "mesh": mesh, "params": params}


class Node:
    """The module's timer-mode node process and the client's handles on its interface."""

    def __init__(self, proc: RosProcess, client: RosClient, ns: str = "") -> None:
        self.proc, self.client, self.ns = proc, client, ns
        n = client.node
        self.points = client.raw_subscription(PointCloud2, f"{ns}/tissue/points", BEST_EFFORT)
        self.markers = client.raw_subscription(MarkerArray, f"{ns}/tissue/markers", BEST_EFFORT)
        self.energy = client.raw_subscription(Float64, f"{ns}/tissue/energy", qos.energy())
        self.wrench = client.raw_subscription(WrenchStamped, f"{ns}/tool/wrench", BEST_EFFORT)
        self.rest = client.raw_subscription(MarkerArray, f"{ns}/tissue/rest_mesh", qos.latched())
        self.diagnostics: list[DiagnosticArray] = []
        self.pose_pub = n.create_publisher(PoseStamped, f"{ns}/tool/pose", qos.tool_output())
        self.twist_pub = n.create_publisher(TwistStamped, f"{ns}/tool/twist", qos.tool_output())
        self.reset_srv = n.create_client(Trigger, f"{ns}/tissue_sim_node/reset")
        self.pause_srv = n.create_client(SetBool, f"{ns}/tissue_sim_node/pause")
        self.param_srv = n.create_client(SetParameters, f"{ns}/tissue_sim_node/set_parameters")
        self.get_param_srv = n.create_client(GetParameters, f"{ns}/tissue_sim_node/get_parameters")

    def wait_ready(self) -> None:
        c = self.client
        c.wait_for_subscriber(self.pose_pub, TIMEOUT, self.proc)
        c.spin_until(lambda: self.points.messages and self.energy.messages, TIMEOUT, self.proc, "first outputs")

    def pose(self, x: float, y: float, yaw: float = 0.0, frame: str = "world", stamp: Any = None) -> PoseStamped:
        msg = PoseStamped()
        msg.header.frame_id = frame
        msg.header.stamp = self.client.node.get_clock().now().to_msg() if stamp is None else stamp
        msg.pose.position.x, msg.pose.position.y = float(x), float(y)
        msg.pose.orientation.z, msg.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
        return msg

    def drive(self, path: np.ndarray) -> None:
        """Publish the (K, 2) tool positions at 1/DT, spinning in between."""
        for x, y in path:
            self.pose_pub.publish(self.pose(x, y))
            self.client.spin_for(DT)

    def reset(self) -> None:
        response = self.client.call(self.reset_srv, Trigger.Request(), TIMEOUT, self.proc)
        assert response.success, response.message

    def pause(self, on: bool) -> SetBool.Response:
        return self.client.call(self.pause_srv, SetBool.Request(data=on), TIMEOUT, self.proc)

    def set_param(self, name: str, value: Any) -> Any:
        if isinstance(value, bool):
            pv = ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=value)
        elif isinstance(value, int):
            pv = ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=value)
        elif isinstance(value, float):
            pv = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value)
        else:
            pv = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value)
        request = SetParameters.Request(parameters=[ParameterMsg(name=name, value=pv)])
        return self.client.call(self.param_srv, request, TIMEOUT, self.proc).results[0]

    def get_param(self, name: str) -> ParameterValue:
        request = GetParameters.Request(names=[name])
        return self.client.call(self.get_param_srv, request, TIMEOUT, self.proc).values[0]

    def latest_points(self) -> np.ndarray:
        _, frame, cloud = M.decode_point_cloud(self.points.messages[-1])
        assert frame == "world"
        return np.stack([cloud["x"], cloud["y"]], axis=1).astype(np.float64)

    def energies(self) -> np.ndarray:
        return np.array([M.decode_float64(m) for m in self.energy.messages])

    def diag(self) -> dict[str, str]:
        """Key-values of the newest diagnostics status of this node."""
        self.client.spin_until(lambda: self.diagnostics, TIMEOUT, self.proc, "diagnostics")
        status = self.diagnostics[-1].status[0]
        return {kv.key: kv.value for kv in status.values}

    def fresh_diag(self) -> dict[str, str]:
        self.diagnostics.clear()
        return self.diag()


@pytest.fixture(scope="module")
def node(ros_client: RosClient, ros_env: dict[str, str], scene_files: dict[str, Any],
         tmp_path_factory: pytest.TempPathFactory) -> Any:
    """One timer-mode node for the module (stopped at the end; test_sigterm checks its exit code)."""
    from ros_env import console_script  # noqa: PLC0415

    log = tmp_path_factory.mktemp("node") / "node.log"
    proc = RosProcess([console_script("tissue_sim_node"), "--ros-args", "--params-file", str(scene_files["params"])],
                      ros_env, log)
    handle = Node(proc, ros_client)
    ros_client.node.create_subscription(
        DiagnosticArray, "/diagnostics",
        lambda msg: handle.diagnostics.append(msg) if msg.status and msg.status[0].name.startswith("/tissue_sim_node") else None,
        qos.diagnostics())
    handle.wait_ready()
    yield handle
    proc.stop(signal.SIGTERM, timeout=10)


def _start(node: Node) -> None:
    """Each test starts from a running node at rest with empty buffers."""
    node.pause(False)
    node.reset()
    for sub in (node.points, node.markers, node.energy, node.wrench):
        sub.clear()


def test_rest_mesh_is_latched(node: Node, scene_files: dict[str, Any]) -> None:
    node.client.spin_until(lambda: node.rest.messages, TIMEOUT, node.proc, "tissue/rest_mesh")
    rest = {m.ns: m for m in M.decode_marker_array(node.rest.messages[0])}
    mesh = scene_files["mesh"]
    assert rest["rest"].type == M.MARKER_LINE_LIST and rest["rest"].frame_id == "world"
    np.testing.assert_allclose(rest["rest"].points[:, :2], mesh.vertices[mesh.edges].reshape(-1, 2))
    assert len(rest["pinned"].points) == 11  # the top row


def test_tool_push_deforms_locally_and_energy_follows_contact(node: Node, scene_files: dict[str, Any]) -> None:
    _start(node)
    q0 = scene_files["mesh"].vertices
    node.client.spin_for(0.3)  # settle under gravity with the tool far away
    baseline = node.energies()[-10:].mean()
    # the box comes up from below at x = 0.2, 0.1 m/s, 3 cm into the lower edge (y = 0)
    up = np.stack([np.full(80, 0.2), np.linspace(-0.06, 0.02, 80)], axis=1)
    node.wrench.clear()
    node.drive(up)
    node.client.spin_for(0.1)
    q = node.latest_points()
    assert np.isfinite(q).all()
    moved = np.linalg.norm(q - q0, axis=1)
    near = np.hypot(q0[:, 0] - 0.2, q0[:, 1]) < 0.05
    far = np.abs(q0[:, 0] - 0.2) > 0.15
    assert moved[near].mean() > 0.015, f"particles under the tool moved only {moved[near].mean():.4f} m"
    assert moved[near].mean() > 3 * moved[far].mean()
    assert q[near][:, 1].mean() > q0[near][:, 1].mean() + 0.015  # pushed up, the way the tool moves
    in_contact = node.energies()[-20:].mean()
    assert in_contact > 2 * baseline, (in_contact, baseline)
    forces = np.array([M.decode_wrench_stamped(m)[2] for m in node.wrench.messages])
    assert np.isfinite(forces).all() and np.abs(forces[:, 1]).max() > 0  # the tissue pushes back on the tool
    markers = M.decode_marker_array(node.markers.messages[-1])
    by_ns = {m.ns: m for m in markers}
    assert {"tool", "tissue", "wireframe", "contact"} <= set(by_ns)
    assert all(np.isfinite(m.points).all() and np.isfinite(m.colors).all() for m in markers)
    assert by_ns["tool"].action == M.ACTION_ADD
    # the tool leaves: downward and away; the energy falls back toward rest
    node.drive(np.stack([np.full(15, 0.2), np.linspace(0.02, -0.2, 15)], axis=1))
    node.client.spin_for(1.5)
    after = node.energies()[-20:].mean()
    assert after < 0.5 * in_contact, (after, in_contact)
    q_after = node.latest_points()
    assert np.linalg.norm(q_after - q0, axis=1)[near].mean() < 0.5 * moved[near].mean()


def test_pause_stops_stepping_and_reset_restores_rest_mesh(node: Node, scene_files: dict[str, Any]) -> None:
    _start(node)
    node.drive(np.stack([np.full(80, 0.2), np.linspace(-0.06, 0.02, 80)], axis=1))
    assert node.pause(True).success
    node.client.spin_for(0.2)  # let in-flight messages arrive
    assert node.fresh_diag()["paused"] == "true"
    count = len(node.energy.messages)
    steps = int(node.fresh_diag()["steps"])
    node.client.spin_for(0.3)
    assert len(node.energy.messages) == count, "energy still published while paused"
    assert int(node.fresh_diag()["steps"]) == steps
    deformed = node.latest_points()
    q0 = scene_files["mesh"].vertices
    assert np.abs(deformed - q0).max() > 0.01
    assert float(node.fresh_diag()["sim_time_s"]) > 0
    node.points.clear()
    node.reset()
    node.client.spin_until(lambda: node.points.messages, TIMEOUT, node.proc, "points after reset")
    np.testing.assert_allclose(node.latest_points(), q0, atol=1e-6)  # float32 on the wire
    # as msg_docs/services.md says: the simulation restarts at step 0, t = 0; the node's counters are kept
    diag = node.fresh_diag()
    assert float(diag["sim_time_s"]) == 0.0 and int(diag["steps"]) == steps, diag
    if sys.platform.startswith("linux"):  # the marker thread yields to the step thread (marker_nice, default +10)
        assert int(diag["marker_thread_niceness"]) == min(os.getpriority(os.PRIO_PROCESS, node.proc.proc.pid) + 10, 19)
    assert diag["markers_gil_free"] == "true"
    if sys.platform.startswith("linux"):  # step_rt_priority: 0 by default
        assert diag["step_thread_scheduling"] == "SCHED_OTHER"
    assert node.diagnostics[-1].header.frame_id == "world"  # the node's frame_id, not empty
    assert node.pause(False).success
    node.client.spin_until(lambda: len(node.energy.messages) > count + 5, TIMEOUT, node.proc, "steps after unpause")


def test_parameters_are_validated_at_runtime(node: Node) -> None:
    bad = node.set_param("k_spring", 1.5)
    assert not bad.successful and "k_spring" in bad.reason and "[0, 1]" in bad.reason
    bad = node.set_param("marker_rate", -5.0)
    assert not bad.successful and "marker_rate" in bad.reason
    bad = node.set_param("iterations", "many")
    assert not bad.successful and "iterations" in bad.reason
    read_only = node.set_param("dt", 0.02)
    assert not read_only.successful and "read-only" in read_only.reason
    bad = node.set_param("young_modulus", -1.0)  # checked whatever the material (here constraints)
    assert not bad.successful and "young_modulus" in bad.reason and "> 0 Pa" in bad.reason
    bad = node.set_param("poisson_ratio", 0.5)
    assert not bad.successful and "poisson_ratio" in bad.reason
    read_only = node.set_param("density", 900.0)
    assert not read_only.successful and "read-only" in read_only.reason
    unknown = node.set_param("iteratons", 5)
    assert not unknown.successful and "unknown parameter 'iteratons'; did you mean 'iterations'?" in unknown.reason
    inverted = node.set_param("plan_angle_min", 30.0)  # above plan_angle_max (20)
    assert not inverted.successful and "plan_angle_max=20.0: expected >= plan_angle_min=30.0" in inverted.reason
    assert node.get_param("plan_angle_min").double_value == -20.0
    # an integer for a float parameter is taken and kept a double (a reader of double_value gets it)
    assert node.set_param("plan_speed_max", 1).successful
    value = node.get_param("plan_speed_max")
    assert value.type == ParameterType.PARAMETER_DOUBLE and value.double_value == 1.0
    assert node.set_param("plan_speed_max", 0.2).successful
    ok = node.set_param("iterations", 10)
    assert ok.successful, ok.reason
    ok = node.set_param("contact_radius", 0.06)
    assert ok.successful, ok.reason
    node.energy.clear()
    node.client.spin_until(lambda: len(node.energy.messages) > 5, TIMEOUT, node.proc, "steps after a rebuild")
    assert np.isfinite(node.energies()).all()
    assert node.set_param("iterations", 30).successful


def test_bad_input_is_dropped_counted_and_survived(node: Node) -> None:
    _start(node)
    before = node.fresh_diag()
    c = node.client
    now = c.node.get_clock().now()
    node.drive(np.array([[0.2, -0.1]] * 5))  # a valid tool far below the strip
    bad_poses = [
        node.pose(float("nan"), 0.0),
        node.pose(0.2, float("inf")),
        node.pose(0.2, -0.1, frame="map"),  # another frame
        node.pose(0.2, -0.1, stamp=(now - rclpy_duration(5.0)).to_msg()),  # stale
    ]
    zero_quat = node.pose(0.2, -0.1)
    zero_quat.pose.orientation.w = 0.0
    bad_poses.append(zero_quat)
    for msg in bad_poses:
        node.pose_pub.publish(msg)
        c.spin_for(DT)
    # out of order: a newer pose, then an older one
    newer = node.pose(0.2, -0.1)
    older = node.pose(0.2, -0.1, stamp=(c.node.get_clock().now() - rclpy_duration(0.1)).to_msg())
    node.pose_pub.publish(newer)
    c.spin_for(DT)
    node.pose_pub.publish(older)
    c.spin_for(DT)
    twist = TwistStamped()
    twist.header.frame_id = "world"
    twist.header.stamp = c.node.get_clock().now().to_msg()
    twist.twist.linear.x = float("nan")
    node.twist_pub.publish(twist)
    c.spin_for(DT)
    c.spin_for(0.3)
    assert node.proc.alive()
    after = node.fresh_diag()
    grew = {k: int(after[k]) - int(before[k]) for k in after if k.startswith("dropped_")}
    assert grew["dropped_nonfinite"] >= 4, grew  # 2 NaN/inf poses, the zero quaternion, the NaN twist
    assert grew["dropped_frame"] >= 1, grew
    assert grew["dropped_stale"] >= 1, grew
    assert grew["dropped_out_of_order"] >= 1, grew
    assert grew["dropped_unpublished_nonfinite"] == 0
    assert np.isfinite(node.latest_points()).all() and np.isfinite(node.energies()).all()
    out = node.proc.output()
    assert "dropped" in out and "Traceback" not in out


def _tool_centres(node: Node, last: int = 1000) -> np.ndarray:
    """x, y of the tool marker's centre in the newest markers received."""
    tools = [m for m in (M.decode_marker_array(b)[0] for b in node.markers.messages[-last:]) if m.action == M.ACTION_ADD]
    return np.array([t.points[0, :2] for t in tools])  # the fan centre: the outline's mean


def test_future_stamp_is_dropped_and_the_tool_keeps_following(node: Node) -> None:
    """One pose stamped 5 s ahead is dropped (counted); the good poses after it still move the tool."""
    _start(node)
    before = node.fresh_diag()
    c = node.client
    node.drive(np.array([[0.2, -0.1]] * 5))
    node.pose_pub.publish(node.pose(0.25, -0.1, stamp=(c.node.get_clock().now() + rclpy_duration(5.0)).to_msg()))
    c.spin_for(DT)
    node.markers.clear()
    node.drive(np.stack([np.linspace(0.2, 0.3, 20), np.full(20, -0.1)], axis=1))
    c.spin_for(0.1)
    after = node.fresh_diag()
    assert int(after["dropped_future"]) - int(before["dropped_future"]) == 1
    assert int(after["dropped_out_of_order"]) == int(before["dropped_out_of_order"])
    centres = _tool_centres(node)
    assert abs(centres[-1, 0] - 0.3) < 1e-6, centres[-5:]


def test_tool_jump_is_rejected_held_and_recovered(node: Node) -> None:
    """A pose 0.5 m away is rejected and the tool holds; a near pose is followed; after ~/reset any pose is."""
    _start(node)
    before = node.fresh_diag()
    c = node.client
    node.drive(np.array([[0.2, -0.1]] * 5))
    node.markers.clear()
    # a teleport: every one of these is rejected (one fewer than relocate_poses, 5, which would take the stream up)
    node.drive(np.array([[0.7, -0.1]] * 4))
    c.spin_for(0.1)
    held = _tool_centres(node)
    np.testing.assert_allclose(held[:, 0], 0.2, atol=1e-6)  # never followed, not even partly
    node.markers.clear()
    node.drive(np.array([[0.23, -0.1]] * 3))  # within max_tool_jump of the held pose: followed
    c.spin_for(0.1)
    assert abs(_tool_centres(node)[-1, 0] - 0.23) < 1e-6
    after = node.fresh_diag()
    assert int(after["dropped_tool_jump"]) - int(before["dropped_tool_jump"]) == 4
    node.reset()  # a re-homed robot: after a reset the first pose is taken wherever it is
    node.markers.clear()
    node.drive(np.array([[0.7, -0.1]] * 3))
    c.spin_for(0.1)
    assert abs(_tool_centres(node)[-1, 0] - 0.7) < 1e-6
    assert "max_tool_jump" in node.proc.output()


def test_phase_lock_moves_the_ticks_to_a_stream_arriving_just_after_them(node: Node) -> None:
    """Poses at 100 Hz arriving just after the node's ticks wait most of a period; the lock moves the ticks.

    Asserted on what the node measured and decided (/diagnostics): the median
    wait from a pose's reception to the next scheduled tick (times the node
    reads from DDS and rcl, not from its callbacks, so a loaded machine's late
    callbacks do not enter it) with the lock off, then, with it on, a shift and
    the locked state with the wait it measured then. The stream is put just
    after the ticks by the node's own measurement of its phase.
    """
    _start(node)
    c = node.client
    assert node.set_param("phase_lock", False).successful
    period_ms = DT * 1e3
    sent = {"n": 0}

    def publish() -> None:
        node.pose_pub.publish(node.pose(0.2, -0.1))  # the tool stays clear of the strip
        sent["n"] += 1

    def wait_after_new_poses(n: int) -> dict[str, str]:
        """Diagnostics measured over poses all sent after this call (the lock keeps the newest 128)."""
        target = sent["n"] + n
        c.spin_until(lambda: sent["n"] >= target, TIMEOUT, node.proc, f"{n} more poses")
        return node.fresh_diag()

    timer = c.node.create_timer(DT, publish)
    try:
        wait_after_new_poses(140)
        d = c.spin_until(lambda: (lambda d: d if int(d["phase_samples"]) >= 100 else None)(node.fresh_diag()),
                         TIMEOUT, node.proc, "the node to measure the poses' wait")
        assert d["phase_lock"] == "measuring" and math.isfinite(float(d["pose_wait_median_ms"])), d
        # the poses arrive w before a tick: delay the stream by w + 1 ms (one stretched interval of the
        # client's timer, exact in rcl's schedule) so that they arrive 1 ms after the ticks; again if the
        # client's own delays (a loaded machine) moved them meanwhile
        before = d
        for _ in range(3):
            delay = (float(before["pose_wait_median_ms"]) + 1.0) % period_ms
            start = sent["n"]
            timer.timer_period_ns = int((period_ms + delay) * 1e6)  # taken by the next call...
            c.spin_until(lambda: sent["n"] > start, TIMEOUT, node.proc, "the stretched interval")
            timer.timer_period_ns = int(period_ms * 1e6)  # ...and only by it
            before = wait_after_new_poses(140)
            if float(before["pose_wait_median_ms"]) > 0.5 * period_ms:
                break
        wait_before = float(before["pose_wait_median_ms"])
        assert wait_before > 0.5 * period_ms, f"the stream did not land after the ticks: {before}"
        shifts = int(before["phase_shifts"])
        assert node.set_param("phase_lock", True).successful
        # what the lock measured when it found no better phase, after moving the ticks
        after = c.spin_until(lambda: (lambda d: d if d["phase_lock"] == "locked" and int(d["phase_shifts"]) > shifts
                                      else None)(node.fresh_diag()), TIMEOUT, node.proc, "the lock to move the ticks")
    finally:
        c.node.destroy_timer(timer)
    # locked: the ticks just after most arrivals (~1 ms on an idle machine; ~2.5 ms with a 1.5 ms jitter)
    assert float(after["pose_wait_median_ms"]) < wait_before - 3.0, (before, after)


def rclpy_duration(seconds: float) -> Any:
    from rclpy.duration import Duration  # noqa: PLC0415

    return Duration(seconds=seconds)


def test_divergence_is_restored_counted_and_never_published(node: Node) -> None:
    _start(node)
    before = int(node.fresh_diag()["divergences"])
    assert node.set_param("gravity", -1e300).successful  # every solve now overflows
    node.client.spin_until(lambda: int(node.fresh_diag()["divergences"]) > before + 5, TIMEOUT, node.proc,
                           "divergences")
    node.client.spin_for(0.1)
    node.energy.clear()
    node.points.clear()
    node.client.spin_for(0.3)
    assert not node.energy.messages, "energy published for diverged steps"
    assert node.points.messages and np.isfinite(node.latest_points()).all()
    assert node.set_param("gravity", -9.8).successful
    node.client.spin_until(lambda: len(node.energy.messages) > 5, TIMEOUT, node.proc, "steps after recovery")
    assert np.isfinite(node.energies()).all() and node.proc.alive()
    assert "diverged" in node.proc.output()


def _lock_step_node(start_process: Any, ros_client: RosClient, scene_files: dict[str, Any], ns: str, name: str,
                    *extra: str, output: str = "tissue/energy") -> tuple[Any, "Node"]:
    """A lock-step node in namespace ``ns`` (``extra``: more ``-p`` arguments), matched: its tool/pose reader and
    our reader of ``output`` (given a moment to match, as a reliable writer's discovery is not instant)."""
    proc = start_process(["tissue_sim_node", "--ros-args", "-r", f"__ns:={ns}", "--params-file",
                          str(scene_files["params"]), "-p", "lock_step:=true", *extra], name=name)
    node = Node(proc, ros_client, ns=ns)
    ros_client.wait_for_subscriber(node.pose_pub, TIMEOUT, proc)
    ros_client.wait_for_publisher(f"{ns}/{output}", TIMEOUT, proc)
    ros_client.spin_for(0.3)  # let our reader match too
    return proc, node


def test_lock_step_node_beside_it_steps_once_per_pose_and_replays_exactly(
        ros_client: RosClient, start_process: Any, scene_files: dict[str, Any], node: Node) -> None:
    """A second node in namespace /left, lock-step: N poses -> N steps stamped like the poses; a replay is exact."""
    proc, left = _lock_step_node(start_process, ros_client, scene_files, "/left", "lockstep")
    ros_client.spin_until(lambda: left.rest.messages, TIMEOUT, proc, "/left/tissue/rest_mesh")
    path = np.stack([np.full(61, 0.2), np.linspace(-0.06, 0.02, 61)], axis=1)  # 61: not a multiple of 3
    t0 = ros_client.node.get_clock().now()

    def replay() -> tuple[np.ndarray, list[tuple[int, int]]]:
        for sub in (left.points, left.energy, left.wrench):
            sub.clear()
        for k, (x, y) in enumerate(path):
            left.pose_pub.publish(left.pose(x, y, stamp=(t0 + rclpy_duration(k * DT)).to_msg()))
            # one pose per step: wait for its energy before sending the next (as tool_driver does)
            ros_client.spin_until(lambda k=k: len(left.energy.messages) > k, TIMEOUT, proc, f"step {k}")
        ros_client.spin_until(lambda: len(left.wrench.messages) >= len(path) and len(left.points.messages) >= len(path),
                              TIMEOUT, proc, "all outputs")
        return left.latest_points(), [M.decode_wrench_stamped(m)[0] for m in left.wrench.messages]

    first, stamps = replay()
    assert len(left.energy.messages) == len(path)
    expected = [(t0 + rclpy_duration(k * DT)).seconds_nanoseconds() for k in range(len(path))]
    assert stamps == [tuple(s) for s in expected]
    # the poses stopped: the last one's state still reaches tissue/markers (lock-step: by the clock, not per step)
    last = tuple(expected[-1])
    ros_client.spin_until(lambda: any(M.decode_marker_array(m)[1].stamp == last for m in left.markers.messages),
                          TIMEOUT, proc, "the last pose's state on tissue/markers")
    assert np.abs(first - scene_files["mesh"].vertices).max() > 0.01
    left.reset()
    ros_client.spin_for(0.1)
    second, _ = replay()
    np.testing.assert_array_equal(first, second)
    # the timer node in the root namespace kept its own state meanwhile
    assert node.proc.alive()
    assert proc.stop(signal.SIGINT) == 0, proc.output()[-2000:]
    assert "Traceback" not in proc.output()


def test_lock_step_pairs_each_pose_with_the_twist_sent_just_before_it(
        ros_client: RosClient, start_process: Any, scene_files: dict[str, Any]) -> None:
    """Twist then pose, same stamp, back to back and in a burst: every step uses its own twist (the executor may
    hand out the pose first; the node takes the waiting twists before stepping), never a later pair's."""
    applied = ros_client.raw_subscription(TwistStamped, "/pair/tool/applied_twist",
                                          QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
    proc, pair = _lock_step_node(start_process, ros_client, scene_files, "/pair", "pairing",
                                 output="tool/applied_twist")
    ros_client.wait_for_subscriber(pair.twist_pub, TIMEOUT, proc)
    t0 = ros_client.node.get_clock().now()
    n = 150  # a burst longer than the twists the pose callback takes at once: they must all stay pairable
    for k in range(n):
        stamp = (t0 + rclpy_duration(k * DT)).to_msg()
        twist = TwistStamped()
        twist.header.frame_id, twist.header.stamp = "world", stamp
        twist.twist.linear.x = 0.01 + 1e-4 * k  # not what the poses (moving in y) would give
        pair.twist_pub.publish(twist)
        pair.pose_pub.publish(pair.pose(0.2, -0.06 + 1e-3 * k, stamp=stamp))
    ros_client.spin_until(lambda: len(applied.messages) >= n, TIMEOUT, proc, "an applied twist per pose")
    vx = [deserialize_message(m, TwistStamped).twist.linear.x for m in applied.messages]
    np.testing.assert_array_equal(vx, [0.01 + 1e-4 * k for k in range(n)])
    assert proc.stop(signal.SIGINT) == 0, proc.output()[-2000:]


def test_use_sim_time_steps_with_the_clock(ros_client: RosClient, start_process: Any,
                                          scene_files: dict[str, Any]) -> None:
    """With use_sim_time the step timer follows /clock: 0.5 s of simulated clock -> about 50 steps."""
    from rosgraph_msgs.msg import Clock  # noqa: PLC0415

    proc = start_process(["tissue_sim_node", "--ros-args", "-r", "__ns:=/simtime", "-r", "/clock:=/simtime/clock",
                          "--params-file", str(scene_files["params"]), "-p", "use_sim_time:=true"], name="simtime")
    clock_pub = ros_client.node.create_publisher(Clock, "/simtime/clock", QoSProfile(depth=10))
    energy = ros_client.raw_subscription(Float64, "/simtime/tissue/energy", qos.energy())
    ros_client.wait_for_subscriber(clock_pub, TIMEOUT, proc)
    ros_client.wait_for_publisher("/simtime/tissue/energy", TIMEOUT, proc)
    ros_client.spin_for(0.5)
    assert not energy.messages, "stepped without a clock"
    t_ns = 1_000_000_000
    for _ in range(50):
        t_ns += 10_000_000
        before = len(energy.messages)
        clock_pub.publish(Clock(clock=Time(seconds=0, nanoseconds=t_ns).to_msg()))
        # the step this tick brings, 0.5 s at most (a loaded CI run stepped 36 times for 50 ticks 20 ms apart:
        # ticks that queued up behind a late timer fire it once); the wall runs slower than the clock either way
        end = time.monotonic() + 0.5
        while len(energy.messages) == before and time.monotonic() < end:
            ros_client.spin_for(0.005)
    ros_client.spin_for(0.3)
    assert 40 <= len(energy.messages) <= 51, len(energy.messages)


def test_tool_driver_plays_a_trajectory_in_lock_step(ros_client: RosClient, start_process: Any,
                                                     scene_files: dict[str, Any]) -> None:
    sim = start_process(["tissue_sim_node", "--ros-args", "-r", "__ns:=/drv", "--params-file",
                         str(scene_files["params"]), "-p", "lock_step:=true"], name="sim_for_driver")
    energy = ros_client.raw_subscription(Float64, "/drv/tissue/energy", qos.energy())
    ros_client.wait_for_publisher("/drv/tissue/energy", TIMEOUT, sim)
    # 0.05 m at 0.5 m/s = 0.1 s = 10 steps, then hold 0.05 s = 5 steps
    driver = start_process(["tool_driver", "--ros-args", "-r", "__ns:=/drv", "-p", "lock_step:=true", "-p", "preset:=straight",
                            "-p", "tool_length:=0.1", "-p", "target_x:=0.2", "-p", "target_y:=0.0",
                            "-p", "angle:=90.0", "-p", "distance:=0.05", "-p", "speed:=0.5", "-p", "hold:=0.05"],
                           name="driver")
    ros_client.spin_until(lambda: driver.returncode is not None, TIMEOUT, None, "the driver to finish")
    assert driver.returncode == 0, driver.output()
    ros_client.spin_for(0.2)
    assert len(energy.messages) == 15, driver.output()  # k = 1..15: the end of each step, 10 moving, 5 holding
    assert np.isfinite([M.decode_float64(m) for m in energy.messages]).all()


@pytest.mark.parametrize("values, name", [
    ({"dt": -0.01}, "dt"),
    ({"iteratons": 3}, "iteratons"),
    ({"tool_shape": "scalpel"}, "tool_shape"),
    ({"marker_rate": 0.0}, "marker_rate"),
])
def test_bad_parameter_file_exits_2_naming_the_parameter(start_process: Any, tmp_path: Path,
                                                         values: dict[str, Any], name: str) -> None:
    path = write_params(tmp_path / "bad.yaml", {**SCENE, **values})
    proc = start_process(["tissue_sim_node", "--ros-args", "--params-file", str(path)], name="bad")
    code = proc.wait(timeout=60)
    out = proc.output()
    assert code == 2, out
    assert name in out and "Traceback" not in out


def test_too_fine_spacing_exits_2_before_meshing(start_process: Any, tmp_path: Path) -> None:
    """spacing 1e-4 m on the shipped image (~7e7 particles) is refused from the estimate, in one line."""
    path = write_params(tmp_path / "fine.yaml", {"spacing": 0.0001})
    proc = start_process(["tissue_sim_node", "--ros-args", "--params-file", str(path)], name="fine")
    assert proc.wait(timeout=60) == 2
    lines = [line for line in proc.output().splitlines() if line.strip()]
    assert len(lines) == 1 and "over the limit max_particles=300000" in lines[0], proc.output()


def test_malformed_parameter_file_exits_2(start_process: Any, tmp_path: Path) -> None:
    path = tmp_path / "broken.yaml"
    path.write_text("/**:\n  ros__parameters:\n    dt: [0.01,\n")
    proc = start_process(["tissue_sim_node", "--ros-args", "--params-file", str(path)], name="broken")
    assert proc.wait(timeout=60) == 2
    assert "broken.yaml" in proc.output() and "Traceback" not in proc.output()
    # one line, naming the file and where (not rcl's log line and its own)
    lines = [line for line in proc.output().splitlines() if line.strip()]
    assert len(lines) == 1 and "not valid YAML at line" in lines[0], proc.output()


def test_sigterm_ends_the_node_cleanly(node: Node) -> None:
    assert node.proc.alive()
    code = node.proc.stop(signal.SIGTERM, timeout=10)
    assert code == 0, node.proc.output()[-2000:]
    assert "Traceback" not in node.proc.output()


def test_an_interrupt_while_the_node_starts_ends_it_cleanly(ros_env: dict[str, str], scene_files: dict[str, Any],
                                                             tmp_path: Path) -> None:
    """SIGINT raised once the node's construction has started its marker and planner threads (here at its last
    step, made to raise KeyboardInterrupt): exit 0, no traceback, no abort ('terminate called...' was seen in 4 of
    10 interrupts at start-up), and the bag of record_path closed."""
    import subprocess  # noqa: PLC0415

    code = ("import sys\n"
            "from tissue_sim_ros.ros import node\n"
            "def interrupted(self):\n"
            "    raise KeyboardInterrupt\n"
            "node.outputs.Outputs.publish_rest_mesh = interrupted\n"
            "code = node.main()\n"
            "import threading\n"
            "print('threads left:', sorted(t.name for t in threading.enumerate() if t is not threading.main_thread()))\n"
            "sys.exit(code)\n")
    bag = tmp_path / "startup_bag"
    run = subprocess.run([sys.executable, "-c", code, "--ros-args", "--params-file", str(scene_files["params"]),
                          "-r", "__ns:=/interrupted", "-p", f"record_path:={bag}"],
                         env=ros_env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "Traceback" not in run.stderr and "terminate called" not in run.stderr + run.stdout
    # the marker and planner threads were ended, not left to the interpreter's exit (which aborted on them)
    assert "threads left: []" in run.stdout, run.stdout
    assert (bag / "metadata.yaml").exists()  # closed, not left to --recover


#: A step's outputs (relative topics): each step publishes every one of them once (points at the default points_rate
#: = 1/dt; the tool-free steps of a node without poses publish no tool/applied_pose).
STEP_OUTPUTS = ("tissue/energy", *(f"tissue/energy/{t}" for t in ("inertial", "spring", "area", "strain", "potential",
                                                                   "bodies")),
                "tool/wrench", "tissue/points", "tool/applied_twist")


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_inside_a_step_ends_the_node_after_the_whole_step(ros_env: dict[str, str],
                                                                   scene_files: dict[str, Any], tmp_path: Path,
                                                                   sig: int) -> None:
    """A signal that lands while a step publishes (sent here right after the step's energy went into the node's
    bag) ends the node after the step's last output, never inside it: the bag holds every output of every step,
    as many energies as replayable steps. (Before: SIGINT's KeyboardInterrupt or SIGTERM's context shutdown cut
    the step after its energy, 1 interrupt in 4 when the signal came from outside.)"""
    import subprocess  # noqa: PLC0415

    from tissue_sim_ros.ros.bags import Bag  # noqa: PLC0415

    code = ("import os, sys, time\n"
            "from tissue_sim_ros.ros import bags, node\n"
            "write = bags.BagWriter.write\n"
            "def write_then_signal(self, name, data, t_ns):\n"
            "    write(self, name, data, t_ns)\n"
            "    if name.endswith('/tissue/energy') and self.counts[name] == 20:\n"
            f"        os.kill(os.getpid(), {int(sig)})\n"
            "        time.sleep(0.3)  # the signal's handlers run meanwhile, in the middle of the step\n"
            "bags.BagWriter.write = write_then_signal\n"
            "sys.exit(node.main())\n")
    bag = tmp_path / "signalled"
    run = subprocess.run([sys.executable, "-c", code, "--ros-args", "--params-file", str(scene_files["params"]),
                          "-r", "__ns:=/signalled", "-p", f"record_path:={bag}"],
                         env=ros_env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "Traceback" not in run.stderr, run.stderr
    with Bag(bag) as b:
        counts = b.message_counts
    per_output = {t: counts.get(f"/signalled/{t}", 0) for t in STEP_OUTPUTS}
    # the signalled step (the 20th) whole, and at most one more step that had begun publishing before the gate
    # closed (SIGTERM): whole too
    assert set(per_output.values()) in ({20}, {21}), per_output


@pytest.mark.parametrize("script", ["tissue_sim_node", "tool_driver"])
def test_help_prints_a_usage_and_starts_no_node(ros_env: dict[str, str], script: str) -> None:
    """``--help`` outside ``--ros-args`` prints a short usage (what it is, -p, --params-file, where msg_docs are)
    and exits 0 at once, without initialising rclpy. (Before: it started a whole node on the current domain.)"""
    import subprocess  # noqa: PLC0415

    from ros_env import console_script  # noqa: PLC0415

    run = subprocess.run([console_script(script), "--help"], env=ros_env, capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stdout + run.stderr
    out = run.stdout
    assert out.startswith(f"usage: {script} ") and "--ros-args" in out, out
    assert "-p NAME:=VALUE" in out and "--params-file FILE" in out and "msg_docs" in out, out
    # rclpy is never initialised: the same main, with rclpy.init made to fail, and -h among ROS arguments
    module = {"tissue_sim_node": "tissue_sim_ros.ros.node", "tool_driver": "tissue_sim_ros.ros.tool_driver"}[script]
    code = ("import sys, rclpy\n"
            "def init(*args, **kwargs):\n"
            "    raise SystemExit('rclpy.init was called')\n"
            "rclpy.init = init\n"
            f"from {module} import main\n"
            f"sys.exit(main([{script!r}, '--ros-args', '-p', 'lock_step:=true', '--', '-h']))\n")
    run = subprocess.run([sys.executable, "-c", code], env=ros_env, capture_output=True, text=True, timeout=60)
    assert run.returncode == 0 and run.stdout.startswith(f"usage: {script} "), run.stdout + run.stderr


def test_tool_driver_bad_preset_exits_2(start_process: Any) -> None:
    proc = start_process(["tool_driver", "--ros-args", "-p", "preset:=bogus"], name="bad_driver")
    assert proc.wait(timeout=60) == 2
    out = proc.output()
    assert "preset" in out and "experiment_a" in out and "Traceback" not in out


def test_tool_driver_unknown_scene_exits_2(start_process: Any) -> None:
    proc = start_process(["tool_driver", "--ros-args", "-p", "scene:=bogus"], name="bad_scene_driver")
    assert proc.wait(timeout=60) == 2
    out = proc.output()
    assert "bogus" in out and "liver_probe" in out and "Traceback" not in out


def test_bench_node_command_writes_its_table(ros_env: dict[str, str], tmp_path: Path) -> None:
    """Smoke test of `tissue-sim bench node` (one short lock-step run; no timing is asserted)."""
    import subprocess  # noqa: PLC0415

    from ros_env import console_script  # noqa: PLC0415

    out = tmp_path / "bench"
    proc = subprocess.run([console_script("tissue-sim"), "bench", "node", "--out", str(out), "--seconds", "1",
                           "--warmup", "0", "--scene", "paper", "--mode", "lock_step",
                           "--set", "step_rt_priority=3"],  # its own free domain: not the module's node's
                          env=ros_env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "lat_markers_ms_median" in proc.stdout
    rows = (out / "node.csv").read_text().splitlines()
    assert len(rows) == 2 and rows[1].startswith("paper,lock_step,")
    # --set reached the node, which ran its step thread real-time where this process may (root, CAP_SYS_NICE,
    # an rtprio limit), and said why not where it may not
    row = dict(zip(rows[0].split(","), rows[1].split(",")))
    may = sys.platform.startswith("linux") and may_use_fifo(3)
    assert row["step_scheduling"] == ("SCHED_FIFO 3" if may else "SCHED_OTHER"), row
    if not may and sys.platform.startswith("linux"):
        assert "step_rt_priority=3 not applied" in (out / "node_paper_lock_step.log").read_text()
    assert (out / "node.png").stat().st_size > 0 and (out / "node_latency_paper_lock_step.csv").exists()
    # bad input creates nothing: run where the default --out (bench_out/node) would land ('make test' left
    # an empty bench_out/node/ in the checkout when the --set check came after the directory was made)
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    bad = subprocess.run([console_script("tissue-sim"), "bench", "node", "--seconds", "0"], env=ros_env,
                         capture_output=True, text=True, timeout=60, cwd=cwd)
    assert bad.returncode == 2 and "--seconds" in bad.stderr and "Traceback" not in bad.stderr
    bad = subprocess.run([console_script("tissue-sim"), "bench", "node", "--set", "step_rt_priority=100"],
                         env=ros_env, capture_output=True, text=True, timeout=60, cwd=cwd)
    assert bad.returncode == 2 and "step_rt_priority=100" in bad.stderr and "Traceback" not in bad.stderr
    assert not any(cwd.iterdir()), sorted(cwd.rglob("*"))


@pytest.mark.parametrize("args, expected", [
    (["-p", "method:=xpbd_jacobi"], ("xpbd", "jacobi", 1, 30)),
    (["-p", "method:=xpbd_substep"], ("xpbd", "gauss_seidel", 30, 1)),
    (["-p", "method:=xpbd_substep", "-p", "substeps:=10"], ("xpbd", "gauss_seidel", 10, 1)),
    (["-p", "method:=xpbd", "-p", "scheme:=jacobi"], ("xpbd", "jacobi", 1, 30)),
    (["-p", "iterations:=5"], ("pbd", "gauss_seidel", 1, 5)),
])
def test_method_alias_decides_unless_set(ros_env: dict[str, str], scene_files: dict[str, Any],
                                         args: list[str], expected: tuple) -> None:
    """In-process node (no graph needed): a method alias sets scheme/substeps/iterations a user left alone."""
    import rclpy  # noqa: PLC0415
    from rclpy.context import Context  # noqa: PLC0415

    from tissue_sim_ros.ros.node import TissueSimNode  # noqa: PLC0415

    context = Context()
    rclpy.init(context=context, domain_id=int(ros_env["ROS_DOMAIN_ID"]),
               args=["--ros-args", "-p", f"mesh_file:={scene_files['root'] / 'strip.npz'}", *args])
    try:
        node = TissueSimNode(context=context)
        p = node.sim.params
        assert (p.method, p.scheme, p.substeps, p.iterations) == expected
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


def test_record_path_writes_every_message_in_and_out(ros_client: RosClient, start_process: Any,
                                                     scene_files: dict[str, Any], tmp_path: Path) -> None:
    """record_path: the node writes what it publishes and the poses it receives; SIGTERM leaves a closed bag."""
    from tissue_sim_ros.ros.bags import Bag  # noqa: PLC0415

    bag_path = tmp_path / "node_bag"
    proc, rec = _lock_step_node(start_process, ros_client, scene_files, "/rec", "recording",
                                "-p", f"record_path:={bag_path}", "-p", "marker_rate:=100.0")
    t0 = ros_client.node.get_clock().now()
    n = 12
    for k in range(n):
        rec.pose_pub.publish(rec.pose(0.2, -0.06 + 0.005 * k, stamp=(t0 + rclpy_duration(k * DT)).to_msg()))
        ros_client.spin_until(lambda k=k: len(rec.energy.messages) > k, TIMEOUT, proc, f"step {k}")
    live = [M.decode_float64(m) for m in rec.energy.messages]
    # markers go out from their own thread, newest state only: stop once the last step's are out
    last = (t0 + rclpy_duration((n - 1) * DT)).seconds_nanoseconds()
    ros_client.spin_until(lambda: rec.markers.messages and M.decode_marker_array(rec.markers.messages[-1])[1].stamp
                          == tuple(last), TIMEOUT, proc, "the last step's markers")
    assert proc.stop(signal.SIGTERM) == 0
    with Bag(bag_path) as bag:
        counts = bag.message_counts
        topics = bag.topics
        recorded = [M.decode_float64(raw) for t, _, _, raw in bag.messages(["/rec/tissue/energy"])]
    assert topics["/rec/tissue/markers"] == "visualization_msgs/msg/MarkerArray"
    assert topics["/rec/tool/pose"] == "geometry_msgs/msg/PoseStamped"
    for topic in ("/rec/tissue/energy", "/rec/tissue/points", "/rec/tool/wrench", "/rec/tissue/energy/bodies",
                  "/rec/tool/pose", "/rec/tool/applied_pose", "/rec/tool/applied_twist"):
        assert counts[topic] == n, (topic, counts)
    # a marker snapshot replaced before the worker took it is skipped by design (never the newest)
    assert 1 <= counts["/rec/tissue/markers"] <= n, counts
    assert counts["/rec/tissue/rest_mesh"] == 1
    assert recorded == live  # the same bytes the subscribers got


def test_replay_of_a_timer_mode_recording_is_bit_for_bit(ros_client: RosClient, start_process: Any,
                                                         scene_files: dict[str, Any], tmp_path: Path) -> None:
    """A live timer-mode run (poses, some twists, tool-free steps first) replayed offline from the node's own bag.

    ``tissue-sim replay --mode applied`` steps with the tool/applied_* the node recorded: the energy series, the
    wrenches and the particle positions equal the live run's to the bit.
    """
    bag_path = tmp_path / "live"
    proc = start_process(["tissue_sim_node", "--ros-args", "-r", "__ns:=/live", "--params-file",
                          str(scene_files["params"]), "-p", f"record_path:={bag_path}"], name="live")
    live = Node(proc, ros_client, ns="/live")
    live.wait_ready()
    c = ros_client
    for k, y in enumerate(np.linspace(-0.06, 0.02, 50)):
        pose = live.pose(0.2 + 0.02 * math.sin(k / 7.0), y, yaw=0.1 * math.sin(k / 5.0))
        live.pose_pub.publish(pose)
        if k % 3 == 0:  # a twist with the pose's stamp now and then: the node uses it while fresh
            twist = TwistStamped()
            twist.header = pose.header
            twist.twist.linear.y = 0.16
            live.twist_pub.publish(twist)
        c.spin_for(DT)
    c.spin_for(0.2)
    assert proc.stop(signal.SIGINT) == 0, proc.output()[-2000:]
    w_live_values = _assert_replay_is_the_live_run(bag_path, "/live", tmp_path / "replay")
    assert np.abs(w_live_values).max() > 0


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_node_killed_hard_leaves_its_parameters_for_an_applied_replay(
        ros_client: RosClient, start_process: Any, scene_files: dict[str, Any], tmp_path: Path, storage: str) -> None:
    """SIGKILL: the node's bag never closes, yet ``tissue-sim record --recover`` gives a bag that holds the node's
    parameters (written into the storage file when the recording started), with a ``-p`` override among them, and
    ``tissue-sim replay --mode applied`` reproduces the run bit for bit from it alone. (Before: the parameters were
    written at close only; the recovered bag had none and the replay refused it.)"""
    import json  # noqa: PLC0415
    import subprocess  # noqa: PLC0415

    from tissue_sim_ros.ros.bags import Bag  # noqa: PLC0415

    from ros_env import console_script  # noqa: PLC0415

    bag_path, ns = tmp_path / "killed", f"/killed_{storage}"
    proc = start_process(["tissue_sim_node", "--ros-args", "-r", f"__ns:={ns}", "--params-file",
                          str(scene_files["params"]), "-p", "k_spring:=0.3", "-p", f"record_storage:={storage}",
                          "-p", f"record_path:={bag_path}"], name=f"killed_{storage}")
    live = Node(proc, ros_client, ns=ns)
    live.wait_ready()

    def pushed() -> bool:
        return any(np.abs(np.concatenate(M.decode_wrench_stamped(raw)[2:4])).max() > 0 for raw in live.wrench.messages)

    # the node took the poses and the tool pushes the tissue, seen live: the tool input is best effort by design
    # (sensor-data QoS), so the drive is repeated, up to three times, when no push follows it (the kept steps of
    # 2 of 5 full runs held no push, with no pose dropped by the node); the replay checks what the node took
    for _ in range(3):
        live.drive(np.stack([np.full(40, 0.2), np.linspace(-0.06, 0.02, 40)], axis=1))
        end = time.monotonic() + 3.0
        while not pushed() and time.monotonic() < end:
            ros_client.spin_for(0.05)
        if pushed():
            break
    ros_client.spin_until(pushed, TIMEOUT, proc, f"a non-zero {ns}/tool/wrench after the drive")
    # ... and the bag is flushed every second: wait for one after that, so the pushed steps are on disk
    ros_client.spin_for(1.5)
    assert proc.stop(signal.SIGKILL) == -signal.SIGKILL
    assert not (bag_path / "metadata.yaml").exists()  # never closed
    fixed = tmp_path / "recovered"
    run = subprocess.run([console_script("tissue-sim"), "record", "--recover", str(bag_path), "-o", str(fixed)],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    w_live = _assert_replay_is_the_live_run(fixed, ns, tmp_path / "replay", cut=True)
    assert np.abs(w_live).max() > 0, proc.log_path.read_text(errors="replace")[-4000:]  # the tool pushed the tissue within what was kept
    assert "custom_data kept: tissue_sim.params" in run.stdout, run.stdout
    with Bag(fixed) as bag:
        params = json.loads(bag.custom_data["tissue_sim.params"])
        markers = bag.message_counts.get(f"{ns}/tissue/markers", 0)
    assert params["k_spring"] == 0.3 and params["contact_model"] == "projection"  # the -p and the file's
    # written by the marker thread: with sqlite3 those writes used to fail (the connection was the opening
    # thread's only), so the node's sqlite3 recordings held no markers
    assert markers > 0


def _assert_replay_is_the_live_run(bag_path: Path, ns: str, out: Path, cut: bool = False) -> np.ndarray:
    """``tissue-sim replay BAG --mode applied``: energy, wrench (stamps and values) and the last positions equal the
    node's own recording, step by step in the order recorded; returns the wrenches. ``cut``: a recording that
    ended with a SIGKILL (recovered), whose last flushed chunk may end inside a step."""
    import subprocess  # noqa: PLC0415

    from tissue_sim_ros.ros.bags import Bag  # noqa: PLC0415

    from ros_env import console_script  # noqa: PLC0415

    run = subprocess.run([console_script("tissue-sim"), "replay", str(bag_path), "--mode", "applied", "--out",
                          str(out), "--no-progress", "--frame-every", "-1"],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr

    def series(path: Path, ns: str, n: int | None = None) -> tuple[list[float], list[bytes], bytes]:
        with Bag(path) as bag:
            energy = [M.decode_float64(raw) for _, _, _, raw in bag.messages([f"{ns}/tissue/energy"])][:n]
            wrench = [bytes(raw) for _, _, _, raw in bag.messages([f"{ns}/tool/wrench"])][:n]
            points = [bytes(raw) for _, _, _, raw in bag.messages([f"{ns}/tissue/points"])][:n]
        return energy, wrench, points[-1]

    e_off, w_off, p_off = series(out / "replay_bag", "")
    with Bag(bag_path) as bag:
        n_live = bag.message_counts[f"{ns}/tissue/energy"]
    # a signal ends the node between two steps' outputs, never inside one: every recorded energy is a replayed step
    # (a SIGKILL's bag ends where its last flush did: a step's energy may be in it without its applied tool)
    assert len(e_off) > 50 and n_live - len(e_off) in ((0, 1) if cut else (0,)), (n_live, len(e_off))
    e_live, w_live, p_live = series(bag_path, ns, len(e_off))
    assert e_off == e_live  # float64, every step

    def wrenches(raw: list[bytes]) -> tuple[list[Any], np.ndarray]:
        decoded = [M.decode_wrench_stamped(w) for w in raw]
        return [d[0] for d in decoded], np.array([np.concatenate([d[2], d[3]]) for d in decoded])

    (stamps_off, w_off_values), (stamps_live, w_live_values) = wrenches(w_off), wrenches(w_live)
    assert stamps_off == stamps_live
    np.testing.assert_array_equal(w_off_values, w_live_values)
    _, _, cloud_live = M.decode_point_cloud(p_live)
    _, _, cloud_off = M.decode_point_cloud(p_off)
    np.testing.assert_array_equal(cloud_off[["x", "y"]], cloud_live[["x", "y"]])
    return w_live_values


def test_record_path_that_exists_is_refused(start_process: Any, scene_files: dict[str, Any], tmp_path: Path) -> None:
    proc = start_process(["tissue_sim_node", "--ros-args", "--params-file", str(scene_files["params"]),
                          "-p", f"record_path:={tmp_path}"], name="bad_record")
    assert proc.wait(timeout=60) == 2
    assert "record_path" in proc.output() and "Traceback" not in proc.output()


def test_poses_in_other_frames_are_projected_onto_the_placed_plane(ros_client: RosClient, start_process: Any,
                                                                   scene_files: dict[str, Any]) -> None:
    """The plane placed in 'map' by parameters, a static 'map -> base_link' given as static_transform_publisher
    would: a 3D pose in base_link lands where the transforms put it (reference: core.frames, itself checked
    against hand-built matrices), with its yaw about the plane's normal; a pose in an unknown frame is dropped.
    Where tf2_msgs is importable, the plane's transform is on /tf_static and the tool is also taken from /tf.
    """
    from tissue_sim_ros.core.timing.frames import Transform, project_pose  # noqa: PLC0415
    from tissue_sim_ros.ros import tf_input  # noqa: PLC0415

    plane_args = {"world_frame": "map", "plane_x": 1.0, "plane_y": -0.5, "plane_z": 0.2, "plane_roll": 0.0,
                  "plane_pitch": 0.0, "plane_yaw": math.pi / 2}
    args = ["tissue_sim_node", "--ros-args", "-r", "__ns:=/placed", "--params-file", str(scene_files["params"]),
            "-p", "lock_step:=true", "-p", "static_transforms:=0.3 0.1 0.5 0.2 0 0 map base_link"]
    for k, v in plane_args.items():
        args += ["-p", f"{k}:={v}"]
    if tf_input.TF_AVAILABLE:
        args += ["-p", "tool_frame:=tool0"]
    proc = start_process(args, name="placed")
    node = Node(proc, ros_client, ns="/placed")
    applied = ros_client.raw_subscription(PoseStamped, "/placed/tool/applied_pose", BEST_EFFORT)
    ros_client.wait_for_subscriber(node.pose_pub, TIMEOUT, proc)
    ros_client.wait_for_publisher("/placed/tool/applied_pose", TIMEOUT, proc)
    ros_client.spin_for(0.3)
    map_plane = Transform.from_xyz_rpy(1.0, -0.5, 0.2, 0.0, 0.0, math.pi / 2)
    map_base = Transform.from_xyz_rpy(0.3, 0.1, 0.5, 0.0, 0.0, 0.2)
    plane_base = map_plane.inverse() * map_base
    # a tool 0.2 m above the plane's origin side, tilted: roll 0.3, yaw 0.4 in base_link
    position = (-0.6, -0.9, -0.5)
    q = Transform.from_xyz_rpy(0, 0, 0, 0.3, 0.0, 0.4).rotation
    x, y, _, q_plane = project_pose(plane_base, position, q)
    t0 = ros_client.node.get_clock().now()
    msg = node.pose(0.0, 0.0, frame="base_link", stamp=t0.to_msg())
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = position
    (msg.pose.orientation.x, msg.pose.orientation.y, msg.pose.orientation.z, msg.pose.orientation.w) = q
    # sent again every 0.5 s, each copy 0.1 ms later (a lock-step node drops a repeated stamp), until a step takes
    # it: on a loaded machine, just after start, the node may not take the first copy
    deadline = time.monotonic() + TIMEOUT
    copies = 0
    while not applied.messages and time.monotonic() < deadline and proc.alive():
        msg.header.stamp = (t0 + rclpy_duration(1e-4 * copies)).to_msg()
        node.pose_pub.publish(msg)
        copies += 1
        ros_client.spin_for(0.5)
    ros_client.spin_until(lambda: applied.messages, 1.0, proc, "the step of the base_link pose")
    ros_client.spin_for(0.3)  # every copy in flight has arrived before the counts below
    _, frame, p, o = M.decode_pose_stamped(applied.messages[-1])
    assert frame == "world"
    np.testing.assert_allclose(p[:2], (x, y), atol=1e-12)
    from tissue_sim_ros.core.contact.tool import yaw_from_quaternion  # noqa: PLC0415

    assert yaw_from_quaternion(*o) == pytest.approx(yaw_from_quaternion(*q_plane), abs=1e-12)
    # unknown frame: dropped, counted, no step
    n = len(applied.messages)
    node.pose_pub.publish(node.pose(0.2, 0.0, frame="camera", stamp=(t0 + rclpy_duration(0.01)).to_msg()))
    ros_client.spin_for(0.3)
    assert len(applied.messages) == n
    assert "camera" in proc.output() and "no transform" in proc.output()

    def frame_change(stamp_s: float) -> None:
        """frame_id set at run time: the old plane name is just a frame the node cannot place any more, base_link
        still lands where the transforms put it (now reported in the new frame), and world_frame is refused."""
        assert node.set_param("frame_id", "tissue2").successful
        k = len(applied.messages)
        node.pose_pub.publish(node.pose(0.2, 0.0, frame="world", stamp=(t0 + rclpy_duration(stamp_s)).to_msg()))
        msg.header.stamp = (t0 + rclpy_duration(stamp_s + 0.01)).to_msg()
        node.pose_pub.publish(msg)
        ros_client.spin_until(lambda: len(applied.messages) > k, TIMEOUT, proc, "the base_link pose in tissue2")
        ros_client.spin_for(0.2)
        assert len(applied.messages) == k + 1  # the 'world' pose was dropped
        _, frame2, p3, _ = M.decode_pose_stamped(applied.messages[-1])
        assert frame2 == "tissue2"
        np.testing.assert_allclose(p3[:2], (x, y), atol=1e-12)
        refused = node.set_param("frame_id", "map")
        assert not refused.successful and "world_frame='map'" in refused.reason

    if not tf_input.TF_AVAILABLE:
        assert "tf2_msgs not installed" in proc.output()
        frame_change(0.1)
        return
    from geometry_msgs.msg import TransformStamped  # noqa: PLC0415
    from tf2_msgs.msg import TFMessage  # noqa: PLC0415

    static = ros_client.raw_subscription(TFMessage, "/tf_static", tf_input.tf_static_qos())
    ros_client.spin_until(lambda: static.messages, TIMEOUT, proc, "the plane on /tf_static")
    from rclpy.serialization import deserialize_message  # noqa: PLC0415

    plane_tf = [t for m in static.messages for t in deserialize_message(m, TFMessage).transforms
                if t.child_frame_id == "world"]
    assert plane_tf and plane_tf[0].header.frame_id == "map"
    assert plane_tf[0].transform.translation.x == 1.0 and plane_tf[0].transform.translation.z == 0.2
    # the tool only on /tf, as base_link -> tool0
    tf_pub = ros_client.node.create_publisher(TFMessage, "/tf", tf_input.tf_qos())
    ros_client.wait_for_subscriber(tf_pub, TIMEOUT, proc)
    ts = TransformStamped()
    ts.header.stamp = (t0 + rclpy_duration(0.02)).to_msg()
    ts.header.frame_id, ts.child_frame_id = "base_link", "tool0"
    ts.transform.translation.x, ts.transform.translation.y, ts.transform.translation.z = (-0.58, -0.9, -0.5)
    ts.transform.rotation.w = 1.0
    tf_pub.publish(TFMessage(transforms=[ts]))
    x2, y2, _, _ = project_pose(plane_base, (-0.58, -0.9, -0.5), (0.0, 0.0, 0.0, 1.0))
    ros_client.spin_until(lambda: len(applied.messages) > n, TIMEOUT, proc, "the step of the /tf tool")
    _, _, p2, _ = M.decode_pose_stamped(applied.messages[-1])
    np.testing.assert_allclose(p2[:2], (x2, y2), atol=1e-12)
    frame_change(0.1)
    # the broadcast names the new plane frame
    ros_client.spin_until(lambda: any(t.child_frame_id == "tissue2" for m in static.messages
                                      for t in deserialize_message(m, TFMessage).transforms),
                          TIMEOUT, proc, "tissue2 on /tf_static")


def test_play_into_a_node_started_plainly_moves_the_tool(ros_client: RosClient, start_process: Any,
                                                         scene_files: dict[str, Any], tmp_path: Path) -> None:
    """`tissue-sim play BAG` (no options) into a timer-mode node without use_sim_time: the node follows the played
    /clock, takes every recorded pose (none stale), steps on the bag's time, and returns to the system clock after."""
    import time as _time  # noqa: PLC0415

    from bag_fixtures import tool_msg, write_bag  # noqa: PLC0415

    ty = "geometry_msgs/msg/PoseStamped"
    t0 = 1_700_000_000_000_000_000  # Nov 2023: years before the node's system clock
    xs = np.linspace(0.1, 0.3, 60)
    bag = write_bag(tmp_path / "old", [("/tool/pose", ty, t0 + k * 20_000_000, tool_msg(ty, t0 + k * 20_000_000,
                                                                                        float(x), -0.1, 0.0))
                                       for k, x in enumerate(xs)])
    rec = tmp_path / "rec"
    proc = start_process(["tissue_sim_node", "--ros-args", "-r", "__ns:=/played", "--params-file",
                          str(scene_files["params"]), "-p", "follow_clock:=true", "-p", f"record_path:={rec}"],
                         name="played")
    node = Node(proc, ros_client, ns="/played")
    node.wait_ready()
    applied = ros_client.raw_subscription(PoseStamped, "/played/tool/applied_pose", BEST_EFFORT)
    ros_client.wait_for_publisher("/played/tool/applied_pose", TIMEOUT, proc)
    play = start_process(["tissue-sim", "play", str(bag), "--remap", "/tool/pose:=/played/tool/pose", "--wait", "30"],
                         name="play")
    ros_client.spin_until(lambda: play.returncode is not None, 60, None, "play to finish")
    assert play.wait(timeout=10) == 0, play.output()
    ros_client.spin_until(lambda: "back to the system clock" in proc.output(), TIMEOUT, proc,
                          "the node back on the system clock")
    out = proc.output()
    assert "following it" in out and "Traceback" not in out
    assert "dropped" not in out, out[-2000:]
    decoded = [M.decode_pose_stamped(m) for m in applied.messages]
    in_bag_time = [(s, p) for s, _, p, _ in decoded if t0 <= s[0] * 1_000_000_000 + s[1] <= t0 + 3_000_000_000]
    assert len(in_bag_time) >= 50  # stepped on the bag's clock while it played
    # the tool followed the recorded poses (the last one may come with the last /clock tick, after its step)
    assert in_bag_time[-1][1][0] in xs[-3:]
    # back on the system clock: it steps at the wall time again (the tool held where the bag left it)
    applied.clear()
    ros_client.spin_until(lambda: applied.messages, TIMEOUT, proc, "steps on the system clock")
    s, _, p, _ = M.decode_pose_stamped(applied.messages[-1])
    # tool/pose is best-effort in timer mode (msg_docs/topics.md): the bag's last message may be lost on the way,
    # so the tool holds at the last pose that arrived, at or after the last one stepped on the bag's clock
    assert abs(s[0] + s[1] * 1e-9 - _time.time()) < 5.0
    assert p[0] in xs[-3:] and p[0] >= in_bag_time[-1][1][0]
    # the node's own recording, made while its clock went from the system's to the bag's and back, replays the
    # run bit for bit (its messages are written in the order they happened, whatever the clock said)
    assert proc.stop(signal.SIGINT) == 0, proc.output()[-2000:]
    _assert_replay_is_the_live_run(rec, "/played", tmp_path / "replay")
