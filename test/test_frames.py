"""core/timing/frames.py against an independent reference: rotation matrices built by hand (and SciPy's Rotation)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from tissue_sim_ros.core.contact.tool import yaw_from_quaternion
from tissue_sim_ros.core.errors import InputError
from tissue_sim_ros.core.timing.frames import (
    FrameLookupError,
    Transform,
    TransformBuffer,
    interpolate,
    parse_static_transforms,
    project_pose,
    project_twist,
    quat_from_rpy,
)


def _rx(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _h(r: np.ndarray, t: tuple[float, float, float]) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, t
    return m


RNG = np.random.default_rng(7)


def _random_transform() -> Transform:
    x, y, z = RNG.uniform(-1, 1, 3)
    roll, pitch, yaw = RNG.uniform(-math.pi, math.pi, 3)
    return Transform.from_xyz_rpy(x, y, z, roll, pitch, yaw)


def test_rpy_is_rz_ry_rx_as_tf2() -> None:
    """R = Rz(yaw) Ry(pitch) Rx(roll) (tf2's setRPY, URDF's rpy)."""
    for roll, pitch, yaw in RNG.uniform(-math.pi, math.pi, (20, 3)):
        m = Transform.from_xyz_rpy(0.1, -0.2, 0.3, roll, pitch, yaw).matrix()
        np.testing.assert_allclose(m, _h(_rz(yaw) @ _ry(pitch) @ _rx(roll), (0.1, -0.2, 0.3)), atol=1e-12)
        # and SciPy's extrinsic xyz = intrinsic ZYX
        q, ref = np.array(quat_from_rpy(roll, pitch, yaw)), Rotation.from_euler("xyz", [roll, pitch, yaw]).as_quat()
        np.testing.assert_allclose(q * np.sign(q[3]), ref * np.sign(ref[3]), atol=1e-12)


def test_compose_and_inverse_are_matrix_products() -> None:
    for _ in range(20):
        a, b = _random_transform(), _random_transform()
        np.testing.assert_allclose((a * b).matrix(), a.matrix() @ b.matrix(), atol=1e-12)
        np.testing.assert_allclose(a.inverse().matrix(), np.linalg.inv(a.matrix()), atol=1e-12)
        p = tuple(RNG.uniform(-1, 1, 3))
        np.testing.assert_allclose(a.apply(p), (a.matrix() @ np.array([*p, 1.0]))[:3], atol=1e-12)


def test_projection_onto_a_tilted_plane() -> None:
    """A vertical plane (rotated 90 deg about world x, lifted 0.3 m): a world pose lands at R^T (p - t) there.

    The tool's yaw in the plane is the heading of its +x axis about the plane's normal: atan2(R[1,0], R[0,0]) of
    R_plane^T R_tool.
    """
    world_plane = Transform.from_xyz_rpy(0.2, 0.0, 0.3, math.pi / 2, 0.0, 0.0)
    plane_world = world_plane.inverse()
    for _ in range(20):
        tool = _random_transform()
        x, y, height, q = project_pose(plane_world, tool.translation, tool.rotation)
        ref = np.linalg.inv(world_plane.matrix()) @ tool.matrix()
        np.testing.assert_allclose((x, y, height), ref[:3, 3], atol=1e-12)
        assert yaw_from_quaternion(*q) == pytest.approx(math.atan2(ref[1, 0], ref[0, 0]), abs=1e-12)
    # a tool lying in the plane, heading 30 deg from the plane's x: yaw 30 deg, height 0
    in_plane = world_plane * Transform.from_xyz_rpy(0.1, 0.05, 0.0, 0.0, 0.0, math.radians(30))
    x, y, height, q = project_pose(plane_world, in_plane.translation, in_plane.rotation)
    assert (x, y, height) == pytest.approx((0.1, 0.05, 0.0), abs=1e-12)
    assert yaw_from_quaternion(*q) == pytest.approx(math.radians(30), abs=1e-12)


def test_twist_is_rotated_into_the_plane() -> None:
    t = Transform.from_xyz_rpy(1.0, 2.0, 3.0, 0.0, 0.0, math.pi / 2)  # source x = plane y
    vx, vy, wz = project_twist(t, (0.1, 0.0, 0.0), (0.0, 0.0, 0.5))
    assert (vx, vy, wz) == pytest.approx((0.0, 0.1, 0.5), abs=1e-12)


def test_buffer_composes_a_chain_and_interpolates_in_time() -> None:
    """plane <- world (static) <- base (static) <- ee (moving) <- tool (static): lookup(plane, tool, t)."""
    buf = TransformBuffer(cache_time=10.0, tolerance=0.05)
    world_plane = Transform.from_xyz_rpy(0.5, 0.0, 0.1, 0.0, 0.0, 0.3)
    world_base = Transform.from_xyz_rpy(0.0, 1.0, 0.0, 0.0, 0.0, -0.2)
    ee_tool = Transform.from_xyz_rpy(0.0, 0.0, 0.12, 0.0, 0.0, 0.0)
    buf.set_static("world", "tissue", world_plane)
    buf.set_static("world", "base", world_base)
    buf.set_static("ee", "tool", ee_tool)
    e0 = Transform.from_xyz_rpy(0.3, 0.0, 0.5, 0.0, 0.4, 0.0)
    e1 = Transform.from_xyz_rpy(0.5, 0.2, 0.4, 0.2, 0.4, 0.6)
    buf.set("base", "ee", e0, 1_000_000_000)
    buf.set("base", "ee", e1, 1_100_000_000)
    # halfway in time: translation halfway, rotation the slerp halfway (SciPy as the reference)
    got = buf.lookup("tissue", "tool", 1_050_000_000)
    slerp = Slerp([0.0, 1.0], Rotation.from_quat([e0.rotation, e1.rotation]))
    mid = _h(slerp(0.5).as_matrix(), tuple((np.array(e0.translation) + e1.translation) / 2))
    ref = np.linalg.inv(world_plane.matrix()) @ world_base.matrix() @ mid @ ee_tool.matrix()
    np.testing.assert_allclose(got.matrix(), ref, atol=1e-12)
    np.testing.assert_allclose(interpolate(e0, e1, 0.5).matrix(), mid, atol=1e-12)
    # the inverse lookup, and time 0 = the newest
    np.testing.assert_allclose(buf.lookup("tool", "tissue", 1_050_000_000).matrix(), np.linalg.inv(ref), atol=1e-12)
    newest = np.linalg.inv(world_plane.matrix()) @ world_base.matrix() @ e1.matrix() @ ee_tool.matrix()
    np.testing.assert_allclose(buf.lookup("tissue", "tool", 0).matrix(), newest, atol=1e-12)
    # within the tolerance past the newest sample: the newest; beyond it: no extrapolation
    np.testing.assert_allclose(buf.lookup("tissue", "tool", 1_140_000_000).matrix(), newest, atol=1e-12)
    with pytest.raises(FrameLookupError, match="newest"):
        buf.lookup("tissue", "tool", 1_200_000_000)
    with pytest.raises(FrameLookupError, match="unknown"):
        buf.lookup("tissue", "camera", 0)
    buf.set_static("map", "odom", Transform())
    with pytest.raises(FrameLookupError, match="not connected"):
        buf.lookup("tissue", "odom", 0)
    assert buf.can_transform("base", "tool") and not buf.can_transform("odom", "tool")


def test_buffer_keeps_only_its_cache_time() -> None:
    buf = TransformBuffer(cache_time=1.0, tolerance=0.0)
    for k in range(300):
        buf.set("a", "b", Transform.from_xyz_rpy(0.01 * k, 0, 0, 0, 0, 0), k * 10_000_000)
    assert len(buf._times["b"]) <= 102
    with pytest.raises(FrameLookupError, match="oldest"):
        buf.lookup("a", "b", 0 + 1)


def test_static_transforms_parse_like_static_transform_publisher() -> None:
    (parent, child, t), = parse_static_transforms("0.1 0.2 0.3 0.5 0 0 world base_link")
    assert (parent, child) == ("world", "base_link")
    np.testing.assert_allclose(t.matrix(), _h(_rz(0.5), (0.1, 0.2, 0.3)), atol=1e-12)
    assert len(parse_static_transforms("0 0 0 0 0 0 a b; 1 0 0 0 0 0 b c;")) == 2
    assert parse_static_transforms("") == []
    for bad, what in (("0 0 0 0 0 a b", "8 words"), ("0 0 x 0 0 0 a b", "numbers"), ("0 0 0 0 0 0 a a", "same"),
                      ("0 0 nan 0 0 0 a b", "finite")):
        with pytest.raises(InputError, match=what):
            parse_static_transforms(bad)
