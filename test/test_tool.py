"""The tool: shapes and trajectories as data (straight insertion, waypoints)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tissue_sim_ros.core.contact.tool import (
    StraightInsertion,
    ToolPose,
    ToolShape,
    ToolTwist,
    WaypointTrajectory,
    tool_shape_array,
    twist_from_poses,
    wrap_angle,
)
from tissue_sim_ros.core.errors import InputError

BOX = ToolShape()


def test_shape_validation_and_packing():
    with pytest.raises(InputError, match="tool_shape"):
        ToolShape("needle")
    with pytest.raises(InputError, match="box tool"):
        ToolShape("box", width=0.0)
    with pytest.raises(InputError, match="capsule"):
        ToolShape("capsule", radius=0.0)
    s = tool_shape_array(BOX, ToolPose(1.0, 2.0, math.pi / 2), 0.001)
    np.testing.assert_allclose(s, [1.0, 2.0, 0.0, 1.0, 0.4, 0.0025, 0.001], atol=1e-15)
    assert ToolShape("capsule", length=0.0, radius=0.01).rounded_box() == (0.0, 0.0, 0.01)


def test_insertion_reaches_the_target_at_the_expected_step():
    """The authors' speed: 0.001 m per step; a 0.3 m insertion takes exactly 300 steps."""
    dt = 0.01
    traj = StraightInsertion.from_tool(BOX, start=(0.0, 0.5), target=(0.3, 0.5), speed=0.001, dt=dt)
    assert traj.speed_mps == pytest.approx(0.1)
    assert traj.n_steps(dt) == 300
    steps = list(traj.steps(dt))
    assert len(steps) == 300
    # the pose is the tool's centre: length/2 behind the tip
    last, _ = steps[-1]
    assert (last.x + 0.4, last.y) == pytest.approx((0.3, 0.5), abs=1e-12)
    assert traj.tip_at(traj.travel_time) == pytest.approx((0.3, 0.5), abs=1e-12)
    # the tip is not yet at the target one step earlier, and stops there afterwards
    assert steps[-2][0].x + 0.4 == pytest.approx(0.299, abs=1e-12)
    assert traj.pose_at(10.0) == traj.pose_at(traj.travel_time)
    for k, (pose, twist) in enumerate(steps, start=1):
        assert pose.x + 0.4 == pytest.approx(0.001 * k, abs=1e-12)
        assert (twist.vx, twist.vy, twist.wz) == pytest.approx((0.1, 0.0, 0.0), abs=1e-9)


def test_insertion_at_an_angle_and_partial_last_step():
    dt = 0.01
    angle = math.radians(-30)
    traj = StraightInsertion.from_angle(BOX, target=(0.5, 0.5), angle=angle, distance=0.2505, speed=0.05)  # m/s
    assert traj.angle == pytest.approx(angle)
    # 0.2505 m at 0.0005 m per step: 501 steps, the last one a full one; speed in m/s needs no dt
    assert traj.n_steps(dt) == 501
    steps = list(traj.steps(dt))
    pose, _ = steps[-1]
    assert pose.yaw == pytest.approx(angle)
    tip = (pose.x + 0.4 * math.cos(angle), pose.y + 0.4 * math.sin(angle))
    assert tip == pytest.approx((0.5, 0.5), abs=1e-12)
    # a distance that is not a multiple of the step: the last step is partial and ends on the target
    traj = StraightInsertion.from_tool(ToolShape("sphere", radius=0.01), (0.0, 0.0), (0.0, 0.01025), 0.001, dt=dt)
    steps = list(traj.steps(dt))
    assert len(steps) == 11
    assert steps[-1][0].y == pytest.approx(0.01025)
    assert steps[-1][1].vy == pytest.approx(0.00025 / dt)
    with pytest.raises(InputError, match="speed"):
        StraightInsertion((0, 0), (1, 0), speed=0.0)
    with pytest.raises(InputError, match="distinct"):
        StraightInsertion((0, 0), (0, 0), speed=1.0)
    with pytest.raises(InputError, match="start"):
        StraightInsertion((0, float("nan")), (0, 1), speed=1.0)


def test_insertion_twist_matches_finite_differences():
    traj = StraightInsertion((0.1, 0.2), (0.4, 0.6), speed=0.2, tip_offset=0.4, hold=0.5)
    h = 1e-6
    for t in np.linspace(0.05, traj.travel_time - 0.05, 7):
        a, b = traj.pose_at(t - h), traj.pose_at(t + h)
        tw = traj.twist_at(t)
        assert (tw.vx, tw.vy) == pytest.approx(((b.x - a.x) / (2 * h), (b.y - a.y) / (2 * h)), rel=1e-6)
    assert traj.twist_at(traj.travel_time + 0.1).vx == 0.0
    assert traj.duration == pytest.approx(traj.travel_time + 0.5)


def test_waypoint_interpolation_and_shortest_arc_yaw():
    traj = WaypointTrajectory([0.0, 1.0, 3.0], [ToolPose(0.0, 0.0, 3.0), ToolPose(1.0, 2.0, -3.0),
                                                ToolPose(1.0, 0.0, -3.0)], hold=0.5)
    mid = traj.pose_at(0.5)
    assert (mid.x, mid.y) == pytest.approx((0.5, 1.0))
    # 3.0 -> -3.0 rad goes the short way through pi (a change of 2 pi - 6), not through 0
    assert mid.yaw == pytest.approx(wrap_angle(3.0 + 0.5 * (2 * math.pi - 6.0)))
    assert traj.pose_at(2.0).y == pytest.approx(1.0)
    assert traj.pose_at(-1.0) == ToolPose(0.0, 0.0, 3.0)
    assert traj.pose_at(10.0).x == 1.0
    assert traj.duration == pytest.approx(3.5)
    assert traj.twist_at(2.0).vy == pytest.approx(-1.0)
    assert traj.twist_at(0.5).wz == pytest.approx(2 * math.pi - 6.0)
    assert traj.twist_at(3.2).vx == 0.0
    # poses as an array work too
    arr = WaypointTrajectory(np.array([1.0, 2.0]), np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]))
    assert arr.start_time == 1.0 and arr.pose_at(1.5).x == pytest.approx(0.5)


def test_waypoint_steps_twist_is_the_finite_difference_of_the_poses():
    dt = 0.01
    traj = WaypointTrajectory([0.0, 0.25, 0.6], [[0.0, 0.0, 0.0], [0.1, 0.05, 0.4], [0.1, 0.2, -0.3]], hold=0.1)
    steps = list(traj.steps(dt))
    assert len(steps) == 70
    prev = traj.pose_at(0.0)
    for k, (pose, twist) in enumerate(steps, start=1):
        assert pose == traj.pose_at(min(k * dt, 0.7))
        assert twist.vx == pytest.approx((pose.x - prev.x) / dt)
        assert twist.vy == pytest.approx((pose.y - prev.y) / dt)
        assert twist.wz == pytest.approx(wrap_angle(pose.yaw - prev.yaw) / dt)
        prev = pose
    # in the middle of a segment the step's twist equals the instantaneous twist
    _, tw = steps[9]
    inst = traj.twist_at(0.095)
    assert (tw.vx, tw.vy, tw.wz) == pytest.approx((inst.vx, inst.vy, inst.wz))
    assert steps[-1][1].vx == 0.0  # holding


def test_waypoint_validation():
    with pytest.raises(InputError, match="increase"):
        WaypointTrajectory([0.0, 0.0], [[0, 0, 0], [1, 0, 0]])
    with pytest.raises(InputError, match="shape"):
        WaypointTrajectory([0.0, 1.0], [[0, 0, 0]])
    with pytest.raises(InputError, match="finite"):
        WaypointTrajectory([0.0, 1.0], [[0, 0, 0], [float("inf"), 0, 0]])
    with pytest.raises(InputError, match="no waypoints"):
        WaypointTrajectory([], np.zeros((0, 3)))
    single = WaypointTrajectory([2.0], [[0.1, 0.2, 0.3]])
    assert single.duration == 0.0 and list(single.steps(0.01)) == []
    with pytest.raises(InputError, match="dt"):
        single.n_steps(0.0)


def test_yaw_from_quaternion_is_shared_and_normalises():
    """One formula for the node, bag replay and demo: yaw of q = (0, 0, sin(a/2), cos(a/2)) is a, also scaled."""
    import math

    from tissue_sim_ros.core.contact.tool import yaw_from_quaternion

    for a in (-3.0, -0.5, 0.0, 0.7, 3.1):
        q = (0.0, 0.0, math.sin(a / 2), math.cos(a / 2))
        assert yaw_from_quaternion(*q) == pytest.approx(a, abs=1e-12)
        assert yaw_from_quaternion(*(1.02 * c for c in q)) == pytest.approx(a, abs=1e-12)  # a robot's 2% off
    assert yaw_from_quaternion(0.0, 0.0, 0.0, 0.0) is None
    assert yaw_from_quaternion(float("nan"), 0.0, 0.0, 1.0) is None


def test_twist_from_poses_wraps_the_yaw():
    """The one pose-to-twist conversion: (pose - prev) / dt with the yaw change along the shortest arc."""
    dt = 0.01
    a = ToolPose(0.1, 0.2, math.radians(179.0))
    b = ToolPose(0.1 + 0.003, 0.2 - 0.001, math.radians(-179.0))
    tw = twist_from_poses(a, b, dt)
    assert tw.vx == pytest.approx(0.3) and tw.vy == pytest.approx(-0.1)
    assert tw.wz == pytest.approx(math.radians(2.0) / dt)  # +2 deg, not -358 deg
    assert twist_from_poses(b, a, dt).wz == pytest.approx(-math.radians(2.0) / dt)
    assert twist_from_poses(None, b, dt) == ToolTwist()
    # a small change is kept to the bit (no sin/cos round trip)
    c = ToolPose(0.0, 0.0, 0.3)
    assert twist_from_poses(ToolPose(0.0, 0.0, 0.1), c, dt).wz == (0.3 - 0.1) / dt
    assert wrap_angle(0.2) == 0.2 and wrap_angle(math.pi) == -math.pi and wrap_angle(-math.pi) == -math.pi


def test_the_simulation_derives_the_twist_with_the_shared_function():
    """A step without a twist uses twist_from_poses of the previous and the new pose (yaw wrapped)."""
    from tissue_sim_ros.core.mesh import mesh_rectangle
    from tissue_sim_ros.core.physics.model import Model, SimParams
    from tissue_sim_ros.core.sim.simulation import Simulation

    dt = 0.01
    sim = Simulation(Model.from_mesh(mesh_rectangle(0.1, 0.1, 0.05), SimParams(dt=dt)), tool=ToolShape())
    a, b = ToolPose(2.0, 2.0, math.radians(179.0)), ToolPose(2.001, 2.0, math.radians(-179.0))
    sim.step(a)
    seen = []
    detect = sim.contact.detect

    def spy(state, pose0, pose1, twist, dt_):
        seen.append(twist)
        return detect(state, pose0, pose1, twist, dt_)

    sim.contact.detect = spy
    sim.step(b)
    assert seen == [twist_from_poses(a, b, dt)]
