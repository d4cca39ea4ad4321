"""The CDR encoders of tissue_sim_ros.ros.messages against rclpy's own (de)serializer, and the parameter table.

Fast CDR leaves padding bytes uninitialised, so bytes are compared through
``deserialize_message`` (our bytes -> message == the message built from Python
objects) and through our decoders (rclpy's bytes -> arrays == the arrays), and
the lengths must agree exactly (same alignment everywhere).
"""
from __future__ import annotations

import math
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")

from builtin_interfaces.msg import Time  # noqa: E402
from geometry_msgs.msg import Point, PoseStamped, TwistStamped, WrenchStamped  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from sensor_msgs.msg import PointCloud2, PointField  # noqa: E402
from std_msgs.msg import ColorRGBA, Float64, Float64MultiArray, MultiArrayDimension  # noqa: E402
from visualization_msgs.msg import Marker, MarkerArray  # noqa: E402

from tissue_sim_ros.core.config import resolve_config  # noqa: E402
from tissue_sim_ros.core.errors import InputError  # noqa: E402
from tissue_sim_ros.core.mesh import mesh_rectangle  # noqa: E402
from tissue_sim_ros.core.physics.model import SimParams  # noqa: E402
from tissue_sim_ros.core.sim.scene import SceneConfig, default_params  # noqa: E402
from tissue_sim_ros.ros import messages as M  # noqa: E402
from tissue_sim_ros.ros.parameters import BY_NAME, PARAMETERS, coerce, markdown_table  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def _same(ours: bytes, reference_msg) -> None:
    """Our bytes deserialize to the reference message, and have the length rclpy's serialization has."""
    msg_type = type(reference_msg)
    assert deserialize_message(ours, msg_type) == reference_msg
    assert len(ours) == len(serialize_message(reference_msg))


def _marker_msg(spec: M.MarkerSpec) -> Marker:
    m = Marker()
    m.header.stamp = Time(sec=spec.stamp[0], nanosec=spec.stamp[1])
    m.header.frame_id = spec.frame_id
    m.ns, m.id, m.type, m.action = spec.ns, spec.id, spec.type, spec.action
    m.pose.position.x, m.pose.position.y, m.pose.position.z = spec.position
    o = m.pose.orientation
    o.x, o.y, o.z, o.w = spec.orientation
    m.scale.x, m.scale.y, m.scale.z = spec.scale
    r, g, b, a = (float(c) for c in np.asarray(spec.color, dtype=np.float32))  # the wire type is float32
    m.color = ColorRGBA(r=r, g=g, b=b, a=a)
    pts = M.points3(spec.points)
    m.points = [Point(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in pts]
    if spec.colors is not None:
        m.colors = [ColorRGBA(r=float(c[0]), g=float(c[1]), b=float(c[2]), a=float(c[3]))
                    for c in np.asarray(spec.colors, dtype=np.float32)]
    m.text = spec.text
    return m


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(7)


def _specs(rng: np.random.Generator) -> list[M.MarkerSpec]:
    return [
        M.MarkerSpec("tissue", 0, M.MARKER_TRIANGLE_LIST, (12, 345), "world", points=rng.normal(size=(9, 3)),
                     colors=rng.random((9, 4)).astype(np.float32)),
        # odd-length strings and 2D points shift every later alignment
        M.MarkerSpec("w", 7, M.MARKER_LINE_LIST, (1, 2), "odd_frame", points=rng.normal(size=(4, 2)),
                     scale=(0.002, 0.0, 0.0), color=(0.1, 0.2, 0.3, 0.4), position=(0.0, 0.0, 0.001), text="ab"),
        M.MarkerSpec("empty", -3, M.MARKER_SPHERE_LIST, (0, 0), "", action=M.ACTION_DELETE),
        M.MarkerSpec("tool", 0, M.MARKER_CUBE, (5, 999_999_999), "world", orientation=(0.0, 0.0, 0.6, 0.8),
                     scale=(0.8, 0.005, 0.01), text="Gewebe \u00fc"),
    ]


def test_marker_and_marker_array_match_rclpy(rng: np.random.Generator) -> None:
    specs = _specs(rng)
    for spec in specs:
        _same(M.encode_marker(spec), _marker_msg(spec))
    reference = MarkerArray(markers=[_marker_msg(s) for s in specs])
    ours = M.encode_marker_array(specs)
    _same(ours, reference)
    # and our decoder reads rclpy's bytes
    decoded = M.decode_marker_array(serialize_message(reference))
    for spec, d in zip(specs, decoded):
        assert (d.ns, d.id, d.type, d.action, d.frame_id, d.stamp, d.text) == \
               (spec.ns, spec.id, spec.type, spec.action, spec.frame_id, spec.stamp, spec.text)
        np.testing.assert_array_equal(d.points, M.points3(spec.points))
        if spec.colors is not None:
            np.testing.assert_array_equal(d.colors, spec.colors)
        np.testing.assert_array_equal(d.orientation, spec.orientation)
    assert M.decode_marker_array(M.encode_marker_array([])) == []


def test_point_cloud_matches_rclpy(rng: np.random.Generator) -> None:
    pts = np.zeros(11, dtype=M.POINT_DTYPE)
    for name in ("x", "y", "z", "strain"):
        pts[name] = rng.normal(size=11)
    pts["body"] = rng.integers(0, 3, size=11)
    ours = M.encode_point_cloud((3, 4), "world", pts)
    ref = PointCloud2(height=1, width=11, is_bigendian=False, point_step=20, row_step=220, is_dense=True,
                      fields=[PointField(name=n, offset=o, datatype=d, count=1)
                              for n, o, d in (("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("strain", 12, 7), ("body", 16, 6))],
                      data=pts.tobytes())
    ref.header.stamp = Time(sec=3, nanosec=4)
    ref.header.frame_id = "world"
    _same(ours, ref)
    stamp, frame, back = M.decode_point_cloud(serialize_message(ref))
    assert (stamp, frame) == ((3, 4), "world")
    np.testing.assert_array_equal(back, pts)
    # an empty cloud and a cloud with a float64 field survive as well
    empty = np.zeros(0, dtype=M.POINT_DTYPE)
    assert M.decode_point_cloud(M.encode_point_cloud((0, 0), "w", empty))[2].shape == (0,)
    wide = np.zeros(3, dtype=[("x", "<f8"), ("i", "<i2")])
    wide["x"] = [1.5, -2.0, 3.25]
    msg = deserialize_message(M.encode_point_cloud((0, 1), "w", wide), PointCloud2)
    assert [(f.name, f.offset, f.datatype) for f in msg.fields] == [("x", 0, 8), ("i", 8, 3)]
    np.testing.assert_array_equal(M.decode_point_cloud(serialize_message(msg))[2]["x"], wide["x"])


def test_small_messages_match_rclpy() -> None:
    _same(M.encode_float64(-1.25e-9), Float64(data=-1.25e-9))
    assert M.decode_float64(serialize_message(Float64(data=math.pi))) == math.pi

    data = np.arange(8.0).reshape(2, 4)
    ref = Float64MultiArray(data=data.ravel().tolist())
    ref.layout.dim = [MultiArrayDimension(label="body", size=2, stride=8),
                      MultiArrayDimension(label="term:inertial,spring,area,total", size=4, stride=4)]
    _same(M.encode_float64_multiarray(data, ["body", "term:inertial,spring,area,total"]), ref)
    back, labels = M.decode_float64_multiarray(serialize_message(ref))
    np.testing.assert_array_equal(back, data)
    assert labels == ["body", "term:inertial,spring,area,total"]

    ref = WrenchStamped()
    ref.header.frame_id = "world"
    ref.header.stamp = Time(sec=9, nanosec=10)
    ref.wrench.force.x, ref.wrench.force.y, ref.wrench.torque.z = 1.0, -2.0, 0.5
    ours = M.encode_wrench_stamped((9, 10), "world", (1.0, -2.0, 0.0), (0.0, 0.0, 0.5))
    _same(ours, ref)
    stamp, frame, force, torque = M.decode_wrench_stamped(ours)
    assert stamp == (9, 10) and frame == "world" and force.tolist() == [1.0, -2.0, 0.0] and torque[2] == 0.5

    pose = PoseStamped()
    pose.header.frame_id = "world"
    pose.pose.position.x, pose.pose.position.y = 0.25, 0.5
    pose.pose.orientation.z, pose.pose.orientation.w = math.sin(0.3), math.cos(0.3)
    _same(M.encode_pose_stamped((0, 0), "world", 0.25, 0.5, 0.6), pose)
    twist = TwistStamped()
    twist.header.frame_id = "world"
    twist.twist.linear.x, twist.twist.linear.y, twist.twist.angular.z = 0.1, -0.2, 0.3
    _same(M.encode_twist_stamped((0, 0), "world", 0.1, -0.2, 0.3), twist)
    assert M.decode_pose_stamped(serialize_message(pose))[2].tolist() == [0.25, 0.5, 0.0]
    assert M.decode_twist_stamped(serialize_message(twist))[3].tolist() == [0.0, 0.0, 0.3]

    from sensor_msgs.msg import JointState  # noqa: PLC0415
    from std_msgs.msg import UInt32  # noqa: PLC0415

    _same(M.encode_uint32(7), UInt32(data=7))
    for positions in ([], [0.25]):
        jaw = JointState(name=["jaw"], position=positions)
        jaw.header.stamp = Time(sec=3, nanosec=4)
        # Fast CDR pads the empty velocity and effort to 8 bytes each, which its reader does not need: the same
        # message, a few bytes shorter
        assert deserialize_message(M.encode_joint_state((3, 4), "", ["jaw"], positions), JointState) == jaw
        assert M.decode_joint_state(serialize_message(jaw))[3].tolist() == positions  # Fast CDR's padding too


def test_reader_rejects_non_cdr_bytes() -> None:
    """The hand-written reader takes little-endian CDR only; the small messages (the typestore) take both."""
    import struct  # noqa: PLC0415

    with pytest.raises(ValueError, match="not CDR"):
        M.decode_marker_array(b"\x00\x00\x00\x00" + bytes(8))
    assert M.decode_float64(b"\x00\x00\x00\x00" + struct.pack(">d", 2.5)) == 2.5


def test_scene_encoder_rest_and_stretch() -> None:
    mesh = mesh_rectangle(0.4, 0.2, 0.05)
    from tissue_sim_ros.core.physics.model import Model  # noqa: PLC0415

    model = Model.from_mesh(mesh, SimParams())
    enc = M.SceneEncoder(model.tri_indices, model.edge_indices, model.edge_rest_length, model.particle_body,
                         tool_rounded_box=(0.4, 0.0025, 0.0))
    q = model.particle_q0.copy()
    strain = enc.vertex_strain(q)
    np.testing.assert_allclose(strain, 0.0, atol=1e-12)
    markers = M.decode_marker_array(enc.markers((1, 0), "world", q, strain, tool_pose=(0.1, 0.1, 0.5),
                                                tool_stamp=(0, 7), contact_particles=np.array([0, 3])))
    by_ns = {m.ns: m for m in markers}
    assert markers[0].ns == "tool" and markers[0].stamp == (0, 7)  # the tool marker carries the pose's stamp
    assert set(by_ns) == {"tool", "tissue", "wireframe", "contact"}
    tissue = by_ns["tissue"]
    assert tissue.type == M.MARKER_TRIANGLE_LIST and tissue.points.shape == (3 * model.n_triangles, 3)
    np.testing.assert_array_equal(tissue.points[:, :2], q[model.tri_indices].reshape(-1, 2))
    np.testing.assert_allclose(tissue.colors, 1.0, atol=1e-2)  # white at rest
    assert by_ns["wireframe"].points.shape == (2 * model.n_edges, 3)
    np.testing.assert_array_equal(by_ns["contact"].points[:, :2], q[[0, 3]])
    tool = by_ns["tool"].points[:, :2]
    # the box tool's triangles cover its 0.8 x 0.005 rectangle around (0.1, 0.1)
    local = (tool - [0.1, 0.1]) @ np.array([[math.cos(0.5), -math.sin(0.5)], [math.sin(0.5), math.cos(0.5)]])
    np.testing.assert_allclose(np.abs(local).max(axis=0), [0.4, 0.0025], atol=1e-12)

    # stretch along x: strain > 0 everywhere an x edge exists, red colours, point cloud carries it
    q2 = q * [1.1, 1.0]
    strain2 = enc.vertex_strain(q2)
    assert (strain2 > 0).all()
    _, _, cloud = M.decode_point_cloud(enc.point_cloud((1, 0), "world", q2, strain2))
    np.testing.assert_allclose(cloud["x"], q2[:, 0], rtol=1e-6)
    np.testing.assert_allclose(cloud["strain"], strain2, rtol=1e-6)
    colors = M.decode_marker_array(enc.markers((1, 0), "world", q2, strain2))[1].colors
    assert (colors[:, 0] >= colors[:, 2]).all()  # red channel dominates under tension
    no_tool = M.decode_marker_array(enc.markers((1, 0), "world", q2, strain2))
    assert no_tool[0].action == M.ACTION_DELETE and no_tool[-1].action == M.ACTION_DELETE

    rest = M.decode_marker_array(enc.rest_markers((0, 0), "world", q, model.particle_pinned | (q[:, 1] == 0)))
    assert [m.ns for m in rest] == ["rest", "pinned"]


def test_tool_outline_shapes() -> None:
    from tissue_sim_ros.core.contact.tool import rounded_box_outline as tool_outline  # noqa: PLC0415  (the markers')

    box = tool_outline(0.4, 0.0025, 0.0)
    assert box.shape == (4, 2)
    capsule = tool_outline(0.4, 0.0, 0.01, segments=8)
    assert capsule.shape == (36, 2)
    assert np.abs(capsule[:, 0]).max() == pytest.approx(0.41)
    disc = tool_outline(0.0, 0.0, 0.02)
    np.testing.assert_allclose(np.hypot(disc[:, 0], disc[:, 1]), 0.02)
    # counter-clockwise: positive shoelace area
    for poly in (box, capsule):
        x, y = poly[:, 0], poly[:, 1]
        assert 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) > 0


def test_parameter_table_covers_every_flat_name() -> None:
    names = set(BY_NAME)
    assert len(names) == len(PARAMETERS)
    assert {f.name for f in fields(SimParams)} <= names
    assert {f.name for f in fields(SceneConfig)} <= names
    assert {"tool_shape", "tool_length", "tool_width", "tool_radius"} <= names
    assert set(default_params()) <= names, "config/tissue_sim.yaml has a parameter the node does not declare"
    doc = (ROOT / "msg_docs" / "parameters.md").read_text()
    assert markdown_table() in doc, "msg_docs/parameters.md is stale: regenerate with python -m tissue_sim_ros.ros.parameters"
    for name in names:
        assert f"`{name}`" in doc, f"msg_docs/parameters.md does not describe {name}"
    # the shipped defaults pass validation
    resolve_config()


@pytest.mark.parametrize("name, value, expected", [
    ("iterations", 2.5, "iterations=2.5: expected an integer"),
    ("iterations", True, "expected an integer"),
    ("marker_rate", 0.0, "marker_rate=0.0: expected a value > 0"),
    ("marker_rate", math.inf, "expected a finite number"),
    ("frame_id", "/world", "frame_id='/world'"),
    ("frame_id", 3, "expected a string"),
    ("twist_source", "imu", "one of auto, poses"),
    ("lock_step", "yes", "expected a boolean"),
])
def test_coerce_names_the_parameter(name: str, value: object, expected: str) -> None:
    with pytest.raises(InputError, match=expected.replace("(", r"\(").replace(")", r"\)")):
        coerce(BY_NAME[name], value)


def test_validate_checks_physics_through_simparams() -> None:
    assert coerce(BY_NAME["dt"], 1) == 1.0 and isinstance(coerce(BY_NAME["dt"], 1), float)
    with pytest.raises(InputError, match="k_spring"):
        resolve_config({"k_spring": 1.5})
    with pytest.raises(InputError, match="tool_shape"):
        resolve_config({"tool_shape": "scalpel"})
    with pytest.raises(InputError, match="spacing"):
        resolve_config({"spacing": -0.1})


def test_vertex_strain_matches_a_plain_loop() -> None:
    """Strain of a particle = mean over its edges of |x_a - x_b| / l0 - 1, on a randomly perturbed mesh."""
    from tissue_sim_ros.core.physics.model import Model  # noqa: PLC0415

    model = Model.from_mesh(mesh_rectangle(0.3, 0.2, 0.05), SimParams())
    enc = M.SceneEncoder(model.tri_indices, model.edge_indices, model.edge_rest_length, model.particle_body)
    q = model.particle_q0 + np.random.default_rng(3).normal(scale=0.01, size=model.particle_q0.shape)
    sums = np.zeros(model.n_particles)
    counts = np.zeros(model.n_particles)
    for (a, b), l0 in zip(model.edge_indices, model.edge_rest_length):
        e = math.dist(q[a], q[b]) / l0 - 1.0
        sums[a] += e
        sums[b] += e
        counts[a] += 1
        counts[b] += 1
    np.testing.assert_allclose(enc.vertex_strain(q), sums / counts, rtol=1e-12, atol=1e-15)


def test_scene_encoder_markers_from_two_threads_match_one_thread() -> None:
    # the marker worker and the step thread (a state published after a reset) share one SceneEncoder:
    # each MarkerArray must be that of its own positions, whatever the other thread does meanwhile
    import threading  # noqa: PLC0415

    from tissue_sim_ros.core.physics.model import Model  # noqa: PLC0415

    model = Model.from_mesh(mesh_rectangle(0.4, 0.2, 0.01), SimParams())
    enc = M.SceneEncoder(model.tri_indices, model.edge_indices, model.edge_rest_length, model.particle_body)
    rng = np.random.default_rng(3)
    states = [model.particle_q0 + rng.normal(0.0, 1e-3, model.particle_q0.shape) for _ in range(2)]
    expected = [enc.markers((1, 0), "world", q, enc.vertex_strain(q)) for q in states]
    bad: list[int] = []

    def encode(k: int) -> None:
        q = states[k]
        strain = enc.vertex_strain(q)
        for _ in range(200):
            if enc.markers((1, 0), "world", q, strain) != expected[k]:
                bad.append(k)

    threads = [threading.Thread(target=encode, args=(k,)) for k in (0, 1)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not bad, f"{len(bad)} of 400 MarkerArrays held the other thread's points"


def test_tissue_contact_is_the_steps_own_contact_per_body() -> None:
    """tissue/contact, published every step: per body in_contact, d* (inf beyond reach, never NaN) and the
    particles the contact moved, read back through rclpy's deserializer."""
    from tissue_sim_ros.core.contact.tool import ToolPose
    from tissue_sim_ros.core.sim.scene import build_simulation

    sim = build_simulation({"contact_model": "projection", "spacing": 0.1})
    enc = M.StepEncoder(sim.model, sim.tool)
    seen_contact = seen_far = False
    for k in range(40):  # the tool comes down through the gap onto the lower tissue
        report = sim.step(ToolPose(0.3, 0.55 - 0.006 * k, 0.0))
        msg = deserialize_message(enc.encode((1, k), "world", report, sim.state.particle_q).messages["tissue/contact"],
                                  Float64MultiArray)
        assert [d.label for d in msg.layout.dim] == [enc.body_label, "field:in_contact,distance,moved"]
        table = np.array(msg.data).reshape(sim.model.n_bodies, 3)
        assert not np.isnan(table).any()
        np.testing.assert_array_equal(table[:, 0], report.in_contact.astype(float))
        np.testing.assert_array_equal(table[:, 1], report.d_star)
        moved = np.bincount(sim.model.particle_body[report.contact_particles], minlength=sim.model.n_bodies)
        np.testing.assert_array_equal(table[:, 2], moved)
        seen_contact |= bool(report.in_contact.any())
        seen_far |= bool(np.isinf(table[:, 1]).any())
    assert seen_contact and seen_far
