"""rosbag2 bags: BagWriter round trips, tool tracks from every pose type, and every bad input.

No ROS graph: bags are written with BagWriter or directly with rosbags
(test/bag_fixtures.py) and read back.
"""
from __future__ import annotations

import math
import shutil
import sqlite3
import struct

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from tissue_sim_ros.core.errors import InputError
from tissue_sim_ros.ros import messages as m
from tissue_sim_ros.ros.bags import (
    POSE_TYPES,
    STORAGES,
    BadSampleError,
    Bag,
    BagWriter,
    is_node_tool_output,
    read_tool_track,
    recover_mcap,
    tool_candidates,
    typestore,
)

from bag_fixtures import TS, T, tool_bag, tool_msg, twist_msg, write_bag

POSE_MSG_TYPES = ["geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/Pose",
                  "geometry_msgs/msg/TransformStamped", "tf2_msgs/msg/TFMessage",
                  "geometry_msgs/msg/PoseWithCovarianceStamped", "nav_msgs/msg/Odometry"]


def _payloads(n: int = 25) -> list[tuple[str, str, int, bytes]]:
    """Messages as the node produces them: small ones and a large point cloud, at irregular times."""
    rng = np.random.default_rng(3)
    out = []
    t = 1_700_000_000_000_000_000
    for i in range(n):
        t += int(rng.integers(1, 50_000_000))
        pts = np.zeros(3000, dtype=m.POINT_DTYPE)
        pts["x"] = rng.normal(size=3000)
        pts["y"] = rng.normal(size=3000)
        pts["body"] = i % 2
        stamp = (t // 1_000_000_000, t % 1_000_000_000)
        out.append(("/tissue/energy", "std_msgs/msg/Float64", t, m.encode_float64(float(rng.normal()))))
        out.append(("/tissue/points", "sensor_msgs/msg/PointCloud2", t + 1, m.encode_point_cloud(stamp, "world", pts)))
        out.append(("/tool/pose", "geometry_msgs/msg/PoseStamped", t + 2,
                    m.encode_pose_stamped(stamp, "world", 0.1 * i, -0.2, 0.01 * i)))
        out.append(("/tool/wrench", "geometry_msgs/msg/WrenchStamped", t + 2,  # same time as another topic
                    m.encode_wrench_stamped(stamp, "world", (1.0, 2.0, 0.0), (0.0, 0.0, 0.5))))
    return out


@pytest.mark.parametrize("storage", STORAGES)
def test_round_trip_every_payload_and_timestamp(tmp_path, storage):
    msgs = _payloads()
    path = tmp_path / "bag"
    with BagWriter(path, storage) as w:
        for topic, msgtype, _, _ in msgs:
            w.add_topic(topic, msgtype)  # repeated adds of the same type are no-ops
        for topic, _, t, data in msgs:
            w.write(topic, data, t)
        assert w.counts["/tissue/points"] == 25
    assert (path / "metadata.yaml").is_file()
    with Reader(path) as r:
        got = [(c.topic, c.msgtype, t, bytes(d)) for c, t, d in r.messages()]
        for c in r.connections:  # the Jazzy definitions and hashes, so ros2 bag / Foxglove decode them
            assert c.digest == TS.hash_rihs01(c.msgtype)
            assert c.msgdef.data == TS.generate_msgdef(c.msgtype, ros_version=2)[0]
    key = lambda x: (x[2], x[0])  # noqa: E731  (readers order by time; ties between topics by topic here)
    assert sorted(got, key=key) == sorted(msgs, key=key)
    # and the payloads decode back to what was encoded
    pc = [d for topic, _, _, d in got if topic == "/tissue/points"][0]
    decoded = TS.deserialize_cdr(pc, "sensor_msgs/msg/PointCloud2")
    assert decoded.width == 3000 and decoded.point_step == m.POINT_DTYPE.itemsize


def test_mcap_opens_in_the_reference_mcap_reader(tmp_path):
    """The independent ``mcap`` library (Foxglove's) reads our MCAP with its summary and ros2msg schemas."""
    mcap_reader = pytest.importorskip("mcap.reader")
    msgs = _payloads(5)
    with BagWriter(tmp_path / "bag") as w:
        for topic, msgtype, t, data in msgs:
            w.add_topic(topic, msgtype)
            w.write(topic, data, t)
    with open(tmp_path / "bag" / "bag.mcap", "rb") as f:
        reader = mcap_reader.make_reader(f)
        summary = reader.get_summary()
        assert summary.statistics.message_count == len(msgs)
        schemas = {s.name: s.encoding for s in summary.schemas.values()}
        assert schemas["sensor_msgs/msg/PointCloud2"] == "ros2msg"
        got = [(ch.topic, msg.log_time, msg.data) for _, ch, msg in reader.iter_messages(log_time_order=True)]
    assert sorted(got) == sorted((tp, t, d) for tp, _, t, d in msgs)


@pytest.mark.parametrize("storage", STORAGES)
def test_offered_qos_is_stored(tmp_path, storage):
    from rosbags.interfaces import QosDurability, QosReliability

    with BagWriter(tmp_path / "bag", storage) as w:
        w.add_topic("/tissue/rest_mesh", "visualization_msgs/msg/MarkerArray", reliable=True, transient_local=True,
                    depth=1)
        w.add_topic("/tool/pose", "geometry_msgs/msg/PoseStamped", reliable=False)
        w.add_topic("/e", "std_msgs/msg/Float64")
        w.write("/e", m.encode_float64(1.0), 1)
    with Bag(tmp_path / "bag") as b:
        qos = {c.topic: c.ext.offered_qos_profiles for c in b.connections}
    assert qos["/tissue/rest_mesh"][0].durability == QosDurability.TRANSIENT_LOCAL
    assert qos["/tissue/rest_mesh"][0].reliability == QosReliability.RELIABLE and qos["/tissue/rest_mesh"][0].depth == 1
    assert qos["/tool/pose"][0].reliability == QosReliability.BEST_EFFORT
    assert qos["/e"] == []


def test_sqlite3_bag_has_rosbag2_schema(tmp_path):
    with BagWriter(tmp_path / "bag", "sqlite3") as w:
        w.add_topic("/tissue/energy", "std_msgs/msg/Float64")
        w.write("/tissue/energy", m.encode_float64(1.5), 10)
    con = sqlite3.connect(tmp_path / "bag" / "bag.db3")
    assert con.execute("select name, type, serialization_format from topics").fetchall() == [
        ("/tissue/energy", "std_msgs/msg/Float64", "cdr")]
    assert con.execute("select timestamp, data from messages").fetchall() == [(10, m.encode_float64(1.5))]
    con.close()


def test_writer_accepts_numpy_and_memoryview_without_copy_semantics_change(tmp_path):
    data = np.frombuffer(m.encode_float64(2.0), dtype=np.uint8)
    with BagWriter(tmp_path / "bag") as w:
        w.add_topic("/e", "std_msgs/msg/Float64")
        w.write("/e", data, 5)
        w.write("/e", memoryview(m.encode_float64(3.0)), 6)
        w.write_message("/e", T["std_msgs/msg/Float64"](data=4.0), 7)
    with Bag(tmp_path / "bag") as b:
        vals = [b.decode(raw, ty).data for _, ty, _, raw in b.messages()]
    assert vals == [2.0, 3.0, 4.0]


def test_writer_bad_input(tmp_path):
    (tmp_path / "exists").mkdir()
    with pytest.raises(InputError, match="exists already"):
        BagWriter(tmp_path / "exists")
    with pytest.raises(InputError, match="storage 'rosbag1'"):
        BagWriter(tmp_path / "a", "rosbag1")
    with pytest.raises(InputError, match="does not exist"):
        BagWriter(tmp_path / "no" / "such" / "dir")
    w = BagWriter(tmp_path / "b")
    with pytest.raises(InputError, match="not in the ROS 2 Jazzy typestore"):
        w.add_topic("/x", "my_msgs/msg/Nope")
    w.add_topic("/x", "std_msgs/msg/Float64")
    with pytest.raises(InputError, match="was added as std_msgs/msg/Float64"):
        w.add_topic("/x", "std_msgs/msg/String")
    with pytest.raises(InputError, match="'/y' was not added"):
        w.write("/y", b"\x00\x01\x00\x00", 1)
    with pytest.raises(InputError, match="expected >= 0"):
        w.write("/x", m.encode_float64(1.0), -5)
    w.close()
    w.close()  # idempotent
    with pytest.raises(InputError, match="is closed"):
        w.write("/x", m.encode_float64(1.0), 1)


@pytest.mark.parametrize("storage", STORAGES)
def test_flushed_data_survives_a_writer_that_never_closes(tmp_path, storage):
    """A crash after flush(): sqlite3 reads straight from the .db3; both recover into a closed bag."""
    path = tmp_path / "bag"
    w = BagWriter(path, storage, flush_period=3600.0)
    w.add_topic("/e", "std_msgs/msg/Float64")
    for i in range(10):
        w.write("/e", m.encode_float64(float(i)), 100 + i)
    w.flush()
    # simulate the crash: copy the files as they are on disk now, before any close
    crashed = tmp_path / "crashed"
    shutil.copytree(path, crashed)
    w.close()
    assert not (crashed / "metadata.yaml").exists()
    if storage == "mcap":
        with pytest.raises(InputError, match=f"tissue-sim record --recover {crashed}"):
            Bag(crashed)
    else:
        with Bag(crashed) as b:  # sqlite3 reads as it is
            assert b.message_count == 10
    # the CLI turns it into a closed bag (metadata.yaml and all)
    from tissue_sim_ros.cli import main as cli

    assert cli(["record", "--recover", str(crashed), "-o", str(tmp_path / "fixed")]) == 0
    assert (tmp_path / "fixed" / "metadata.yaml").is_file()
    with Bag(tmp_path / "fixed") as b:
        vals = [(t, b.decode(raw, ty).data) for _, ty, t, raw in b.messages()]
        assert b.topics == {"/e": "std_msgs/msg/Float64"}
    assert vals == [(100 + i, float(i)) for i in range(10)]


@pytest.mark.parametrize("storage", STORAGES)
def test_durable_custom_data_survives_a_writer_that_never_closes(tmp_path, storage):
    """custom_data set durably is in the storage file at once (MCAP: a Metadata record; sqlite3: a table): a
    recording killed before its close keeps it, and record --recover carries it into metadata.yaml; plain
    custom_data is written at close only."""
    from tissue_sim_ros.ros.bags import durable_custom_data  # noqa: PLC0415

    path = tmp_path / "bag"
    w = BagWriter(path, storage, flush_period=3600.0)
    w.add_topic("/e", "std_msgs/msg/Float64")
    w.set_custom_data("tissue_sim.params", '{"dt": 0.01, "pin_y_top": null}', durable=True)
    w.set_custom_data("at_close", "only")
    for i in range(10):
        w.write("/e", m.encode_float64(float(i)), 100 + i)
    w.flush()
    crashed = tmp_path / "crashed"
    shutil.copytree(path, crashed)  # the files as a SIGKILL leaves them
    w.close()
    stored = next(crashed.glob("*.mcap" if storage == "mcap" else "*.db3"))
    assert durable_custom_data(stored) == {"tissue_sim.params": '{"dt": 0.01, "pin_y_top": null}'}
    from tissue_sim_ros.cli import main as cli  # noqa: PLC0415

    assert cli(["record", "--recover", str(crashed), "-o", str(tmp_path / "fixed")]) == 0
    with Bag(tmp_path / "fixed") as b:
        assert b.custom_data == {"tissue_sim.params": '{"dt": 0.01, "pin_y_top": null}'}
        assert b.message_count == 10
    assert "tissue_sim.params" in (tmp_path / "fixed" / "metadata.yaml").read_text()
    # the closed bag: both, in metadata.yaml; its storage file still reads (the extra record or table is ignored)
    with Bag(path) as b:
        assert b.custom_data == {"tissue_sim.params": '{"dt": 0.01, "pin_y_top": null}', "at_close": "only"}
        assert [b.decode(raw, ty).data for _, ty, _, raw in b.messages()] == [float(i) for i in range(10)]


def test_recover_mcap_keeps_complete_chunks_of_a_cut_file(tmp_path):
    path = tmp_path / "bag"
    with BagWriter(path, flush_period=0.0) as w:  # one chunk per message
        w.add_topic("/e", "std_msgs/msg/Float64")
        for i in range(40):
            w.write("/e", m.encode_float64(float(i)), 1000 + i)
    blob = (path / "bag.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(blob[: len(blob) // 2])
    with pytest.raises(InputError, match="cut.mcap"):
        Bag(cut)
    recover_mcap(cut, tmp_path / "fixed.mcap")
    with Bag(tmp_path / "fixed.mcap") as b:
        vals = [b.decode(raw, ty).data for _, ty, _, raw in b.messages()]
    assert 5 < len(vals) < 40
    assert vals == [float(i) for i in range(len(vals))]


# --------------------------------------------------------------------------- tool tracks


@pytest.mark.parametrize("storage", STORAGES)
@pytest.mark.parametrize("msgtype", POSE_MSG_TYPES)
def test_tool_track_from_every_pose_type(tmp_path, msgtype, storage):
    path, times, poses = tool_bag(tmp_path / "bag", msgtype, n=50, rate_hz=37.0, storage=storage)
    frame = "tool_tip" if msgtype == "tf2_msgs/msg/TFMessage" else None
    track = read_tool_track(path, topic="/tool/pose", frame=frame)
    assert track.msgtype == msgtype and track.n == 50
    np.testing.assert_array_equal(track.t_ns, times)  # header stamps (receive times for Pose) = bag times
    np.testing.assert_allclose(track.pose, poses, rtol=0, atol=1e-12)
    assert sum(track.skipped.values()) == 0
    assert abs((track.n - 1) / track.duration - 37.0) < 2.0  # irregular spacing around 37 Hz


def test_tool_topic_auto_detected_and_extra_topics_ignored(tmp_path):
    path, times, _ = tool_bag(tmp_path / "bag", "geometry_msgs/msg/PoseStamped", n=20)
    track = read_tool_track(path)
    assert track.topic == "/tool/pose" and track.n == 20
    # a relative name finds the absolute topic
    assert read_tool_track(path, topic="tool/pose").n == 20


def test_tf_frames_listed_when_ambiguous(tmp_path):
    path, _, poses = tool_bag(tmp_path / "bag", "tf2_msgs/msg/TFMessage", topic="/tf", n=20)
    with pytest.raises(InputError) as err:
        read_tool_track(path)
    assert "--tool-topic /tf --frame base_link" in str(err.value)
    assert "--tool-topic /tf --frame tool_tip" in str(err.value)
    assert read_tool_track(path, frame="/tool_tip").child_frame == "tool_tip"
    with pytest.raises(InputError, match="no TF child frame 'gripper'.*base_link, tool_tip"):
        read_tool_track(path, topic="/tf", frame="gripper")
    assert {c[2] for c in tool_candidates(Bag(path))} == {"base_link", "tool_tip"}


def test_two_pose_topics_are_ambiguous(tmp_path):
    msgs = []
    for i in range(5):
        t = 1_000_000_000 + i * 10_000_000
        msgs.append(("/a/pose", "geometry_msgs/msg/PoseStamped", t, tool_msg("geometry_msgs/msg/PoseStamped", t, i, 0, 0)))
        msgs.append(("/b/pose", "geometry_msgs/msg/Pose", t, tool_msg("geometry_msgs/msg/Pose", t, i, 0, 0)))
    path = write_bag(tmp_path / "bag", msgs)
    with pytest.raises(InputError, match=r"2 possible tool poses.*--tool-topic /a/pose.*--tool-topic /b/pose"):
        read_tool_track(path)
    assert read_tool_track(path, topic="/b/pose").n == 5


def _node_bag(path, pose_topics, n=5, applied=("/tool/applied_pose",)):
    """A bag like the node's recordings: tool input(s), plus the node's own tool/applied_* outputs."""
    msgs = []
    for i in range(n):
        t = 1_000_000_000 + i * 10_000_000
        for topic in pose_topics:
            msgs.append((topic, "geometry_msgs/msg/PoseStamped", t, tool_msg("geometry_msgs/msg/PoseStamped", t, i, 0, 0)))
        for topic in applied:
            msgs.append((topic, "geometry_msgs/msg/PoseStamped", t + 1,
                         tool_msg("geometry_msgs/msg/PoseStamped", t, 10 + i, 0, 0)))
            msgs.append((topic.replace("applied_pose", "applied_twist"), "geometry_msgs/msg/TwistStamped", t + 1,
                         twist_msg(t, 0.0, 0.0, 0.0)))
    return write_bag(path, msgs)


def test_the_nodes_applied_outputs_are_not_chosen_unasked(tmp_path):
    """Every bag the project makes holds tool/pose and the node's tool/applied_pose: the input is the tool."""
    path = _node_bag(tmp_path / "bag", ["/tool/pose"], applied=("/tool/applied_pose", "/left/tool/applied_pose"))
    track = read_tool_track(path)  # was "3 possible tool poses"
    assert track.topic == "/tool/pose" and track.n == 5 and track.pose[0, 0] == 0
    assert read_tool_track(path, topic="/tool/applied_pose").pose[0, 0] == 10  # named: read as asked
    # two genuine pose topics still ask, and list only them
    two = _node_bag(tmp_path / "two", ["/a/pose", "/b/pose"])
    with pytest.raises(InputError, match=r"2 possible tool poses.*--tool-topic /a/pose.*--tool-topic /b/pose") as err:
        read_tool_track(two)
    assert "--tool-topic /tool/applied_pose" not in str(err.value)
    # only the node's output: say how to read it
    only = _node_bag(tmp_path / "only", [])
    with pytest.raises(InputError, match=r"only tool pose is the node's own output /tool/applied_pose.*--mode applied"
                                         r".*--tool-topic /tool/applied_pose"):
        read_tool_track(only)
    assert is_node_tool_output("/ns/tool/applied_twist") and is_node_tool_output("tool/applied_pose")
    assert not is_node_tool_output("/tool/pose") and not is_node_tool_output("/tool/not_applied_pose")


def test_missing_topic_lists_topics_and_types(tmp_path):
    path, _, _ = tool_bag(tmp_path / "bag", n=5)
    with pytest.raises(InputError) as err:
        read_tool_track(path, topic="/robot/ee_pose")
    text = str(err.value)
    assert "no topic '/robot/ee_pose'" in text and str(path) in text
    assert "/tool/pose (geometry_msgs/msg/PoseStamped, 5 msgs)" in text
    assert "/chatter (std_msgs/msg/String, 5 msgs)" in text


def test_unsupported_type(tmp_path):
    path, _, _ = tool_bag(tmp_path / "bag", n=5)
    with pytest.raises(InputError, match="'/chatter'.*std_msgs/msg/String, which carries no tool pose"):
        read_tool_track(path, topic="/chatter")
    only_extras = write_bag(tmp_path / "x", [("/chatter", "std_msgs/msg/String", 5, T["std_msgs/msg/String"](data="a"))])
    with pytest.raises(InputError, match="no topic carrying a tool pose.*/chatter"):
        read_tool_track(only_extras)


def test_out_of_order_and_repeated_times_are_counted_skips_or_errors(tmp_path):
    ty = "geometry_msgs/msg/PoseStamped"
    stamps = [100, 200, 200, 150, 300, 300, 400]  # header stamps [ms]; the bag receive times increase
    msgs = [("/tool/pose", ty, (i + 1) * 1_000_000, tool_msg(ty, s * 1_000_000, 0.01 * i, 0.0, 0.0))
            for i, s in enumerate(stamps)]
    path = write_bag(tmp_path / "bag", msgs)
    track = read_tool_track(path)
    assert track.skipped == {"repeated": 2, "out_of_order": 1, "non_finite": 0, "bad_quaternion": 0}
    np.testing.assert_array_equal(track.t_ns, np.array([100, 200, 300, 400]) * 1_000_000)
    np.testing.assert_allclose(track.pose[:, 0], [0.0, 0.01, 0.04, 0.06])
    assert "repeated 2" in track.summary() and "out_of_order 1" in track.summary()
    with pytest.raises(BadSampleError, match="sample 3 has time 200000000 ns, equal to.*: expected increasing sample times$"):
        read_tool_track(path, on_bad_time="error")
    # receive times are in order: no skips
    assert read_tool_track(path, time_source="bag").n == len(stamps)


def test_non_finite_and_invalid_quaternion_are_counted(tmp_path):
    ty = "geometry_msgs/msg/PoseStamped"
    good = [tool_msg(ty, (i + 1) * 1_000_000, 0.1 * i, 0.0, 0.0) for i in range(4)]
    bad_pos = tool_msg(ty, 10_000_000, float("nan"), 0.0, 0.0)
    bad_q = tool_msg(ty, 11_000_000, 0.0, 0.0, 0.0)
    bad_q.pose.orientation.w = 0.0
    msgs = [("/tool/pose", ty, i + 1, msg) for i, msg in enumerate(good + [bad_pos, bad_q])]
    path = write_bag(tmp_path / "bag", msgs)
    track = read_tool_track(path)
    assert track.n == 4 and track.skipped["non_finite"] == 1 and track.skipped["bad_quaternion"] == 1
    with pytest.raises(BadSampleError, match=r"sample 5 has a non-finite position \(nan, 0.0\) \(non_finite\)"):
        read_tool_track(path, on_bad_pose="error")
    with pytest.raises(BadSampleError, match=r"sample 5 has an invalid quaternion \(0.0, 0.0, 0.0, 0.0\)"):
        read_tool_track(write_bag(tmp_path / "bag2", [m for m in msgs if m[3] is not bad_pos]), on_bad_pose="error")
    assert read_tool_track(path, on_bad_time="error").n == 4  # times are fine: only poses are refused by on_bad_pose


def test_twist_topic_sample_and_hold(tmp_path):
    ty = "geometry_msgs/msg/PoseStamped"
    msgs = []
    for i in range(6):
        t = (i + 1) * 10_000_000
        msgs.append(("/tool/pose", ty, t, tool_msg(ty, t, 0.01 * i, 0.0, 0.0)))
        if i in (1, 4):
            msgs.append(("/tool/twist", "geometry_msgs/msg/TwistStamped", t, twist_msg(t, float(i), 0.0, 0.5)))
    path = write_bag(tmp_path / "bag", msgs)
    track = read_tool_track(path, twist_topic="/tool/twist")
    assert np.isnan(track.twist[0]).all()
    np.testing.assert_array_equal(track.twist[1:, 0], [1, 1, 1, 4, 4])
    with pytest.raises(InputError, match="expected one of geometry_msgs/msg/TwistStamped"):
        read_tool_track(path, twist_topic="/tool/pose")
    with pytest.raises(InputError, match="no twist topic '/nope'"):
        read_tool_track(path, twist_topic="/nope")


def test_interpolate_linear_and_yaw_across_pi():
    from tissue_sim_ros.ros.bags import ToolTrack

    track = ToolTrack(t_ns=np.array([0, 10, 20]), pose=np.array([[0.0, 0.0, 3.0], [1.0, 2.0, -3.0], [2.0, 2.0, -3.0]]),
                      twist=None, topic="/t", msgtype="geometry_msgs/msg/Pose")
    out = track.interpolate(np.array([5, 10, 25]))
    np.testing.assert_allclose(out[:, :2], [[0.5, 1.0], [1.0, 2.0], [2.0, 2.0]])
    # halfway between 3.0 and -3.0 the short way round is pi, not 0
    assert abs(abs(out[0, 2]) - (3.0 + (2 * math.pi - 6.0) / 2)) < 1e-12


# --------------------------------------------------------------------------- bad bags


def test_not_a_bag(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        Bag(tmp_path / "nope")
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    with pytest.raises(InputError, match="notes.txt.*is not a rosbag2 bag"):
        Bag(text)
    (tmp_path / "emptydir").mkdir()
    with pytest.raises(InputError, match="emptydir.*no metadata.yaml"):
        Bag(tmp_path / "emptydir")
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"this is not an mcap file at all" * 10)
    with pytest.raises(InputError, match="garbage.mcap.*cannot be read"):
        Bag(garbage)
    garbage_db = tmp_path / "garbage.db3"
    garbage_db.write_bytes(b"SQLite format 2\x00" + b"\x17" * 500)
    with pytest.raises(InputError, match="garbage.db3"):
        read_tool_track(garbage_db)
    bad_meta = tmp_path / "badmeta"
    bad_meta.mkdir()
    (bad_meta / "metadata.yaml").write_text(": : not yaml [")
    with pytest.raises(InputError, match="badmeta"):
        Bag(bad_meta)


def test_empty_files_and_empty_bags(tmp_path):
    (tmp_path / "zero.mcap").write_bytes(b"")
    with pytest.raises(InputError, match="zero.mcap.*is empty"):
        Bag(tmp_path / "zero.mcap")
    for storage in STORAGES:
        path = tmp_path / f"empty_{storage}"
        with BagWriter(path, storage) as w:
            w.add_topic("/tool/pose", "geometry_msgs/msg/PoseStamped")
        with pytest.raises(InputError, match=f"empty_{storage}.*holds no messages.*tool/pose"):
            read_tool_track(path)


@pytest.mark.parametrize("storage", STORAGES)
def test_truncated_file_is_an_input_error_naming_the_path(tmp_path, storage):
    path, _, _ = tool_bag(tmp_path / "bag", n=400, storage=storage)
    f = next(path.glob("*.mcap" if storage == "mcap" else "*.db3"))
    for frac in (0.9, 0.5, 0.1):
        cut = tmp_path / f"cut{int(frac * 100)}{f.suffix}"
        cut.write_bytes(f.read_bytes()[: int(f.stat().st_size * frac)])
        with pytest.raises(InputError, match=str(cut.name)):
            read_tool_track(cut)


def test_corrupt_payload_is_an_input_error(tmp_path):
    ty = "geometry_msgs/msg/PoseStamped"
    msgs = [("/tool/pose", ty, 1, tool_msg(ty, 1, 0.0, 0.0, 0.0)), ("/tool/pose", ty, 2, b"\x00\x01\x00\x00\x07")]
    path = write_bag(tmp_path / "bag", msgs)
    with pytest.raises(InputError, match="bag.*PoseStamped message cannot be decoded"):
        read_tool_track(path)


def test_typestore_is_jazzy():
    assert "tf2_msgs/msg/TFMessage" in typestore().fielddefs
    assert set(POSE_MSG_TYPES) == set(POSE_TYPES)


def test_signals_are_held_during_a_write_and_delivered_after():
    """A SIGINT that arrives while a record is written is raised only once the record is complete."""
    import os
    import signal

    from tissue_sim_ros.ros.bags.write import signals_held

    seen = []
    old = signal.signal(signal.SIGINT, lambda *_: seen.append("int"))
    try:
        with signals_held():
            os.kill(os.getpid(), signal.SIGINT)
            inside = list(seen)
        assert inside == [] and seen == ["int"]
    finally:
        signal.signal(signal.SIGINT, old)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_every_thread_can_write_a_bag(tmp_path, storage):
    """The node writes its bag from the step thread and the marker thread: with sqlite3 the marker thread's
    writes failed ("SQLite objects created in a thread can only be used in that same thread"), so a node's
    sqlite3 recording held no tissue/markers. Each of several threads' messages is in the bag, read back."""
    import threading

    from tissue_sim_ros.ros.bags import Bag, BagWriter

    path = tmp_path / "threads"
    writer = BagWriter(path, storage)
    writer.add_topic("/a", "std_msgs/msg/Float64")
    errors: list[BaseException] = []

    def write(k: int) -> None:
        try:
            for i in range(20):
                writer.write("/a", struct.pack("<4xd", float(100 * k + i)), 1_000_000 * (100 * k + i + 1))
        except BaseException as exc:  # noqa: BLE001  reported below
            errors.append(exc)

    threads = [threading.Thread(target=write, args=(k,)) for k in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    writer.close()
    assert not errors, errors
    with Bag(path) as bag:
        values = sorted(struct.unpack_from("<d", bytes(raw), 4)[0] for _, _, _, raw in bag.messages(["/a"]))
    assert values == sorted(float(100 * k + i) for k in range(3) for i in range(20))


# --------------------------------------------------------------------------- the libraries, as relied on


def test_installed_bag_libraries_are_within_the_pinned_ranges():
    """setup.py pins rosbags and mcap to the ranges whose behaviour the tests below check."""
    import ast
    from importlib.metadata import version
    from pathlib import Path

    from packaging.requirements import Requirement

    tree = ast.parse((Path(__file__).resolve().parent.parent / "setup.py").read_text())
    call = next(n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "setup")
    requires = ast.literal_eval(next(k.value for k in call.keywords if k.arg == "install_requires"))
    pins = {r.name: r.specifier for r in map(Requirement, requires) if r.name in ("rosbags", "mcap")}
    assert set(pins) == {"rosbags", "mcap"} and all(str(s).count(",") == 1 for s in pins.values()), pins
    for name, spec in pins.items():
        assert spec.contains(version(name)), f"{name} {version(name)} is outside setup.py's {spec}"


@pytest.mark.parametrize("storage", STORAGES)
def test_rosbags_writer_writes_through_the_storage_its_plugins_map_name(tmp_path, storage):
    """rosbags' Writer makes its storage from ``STORAGE_PLUGINS`` and calls the storage protocol (add_msgtype
    once per type, add_connection, write, close with the metadata); the bag's storage file is ours."""
    from tissue_sim_ros.ros.bags.storage import LIBRARY

    with BagWriter(tmp_path / "bag", storage) as w:
        w.add_topic("/a", "std_msgs/msg/Float64", reliable=True)
        w.add_topic("/b", "std_msgs/msg/Float64")
        w.write("/a", m.encode_float64(1.0), 5)
        w.write("/b", m.encode_float64(2.0), 6)
    if storage == "mcap":
        from mcap.reader import make_reader

        with open(tmp_path / "bag" / "bag.mcap", "rb") as f:
            reader = make_reader(f)
            assert reader.get_header().library.startswith(LIBRARY)
            assert [md.name for md in reader.iter_metadata()] == ["rosbag2"]
            assert len(reader.get_summary().schemas) == 1 and len(reader.get_summary().channels) == 2
    else:
        con = sqlite3.connect(tmp_path / "bag" / "bag.db3")
        assert con.execute("select count(*) from message_definitions").fetchone() == (1,)
        assert "storage_identifier: sqlite3" in con.execute("select metadata from metadata").fetchone()[0]
        con.close()
    with Reader(tmp_path / "bag") as r:
        assert r.message_count == 2 and [c.topic for c in r.connections] == ["/a", "/b"]


@pytest.mark.parametrize("storage", STORAGES)
def test_a_bare_storage_file_keeps_the_bags_custom_data(tmp_path, storage):
    with BagWriter(tmp_path / "bag", storage) as w:
        w.set_custom_data("plain", "at close")
        w.set_custom_data("durable", "at once", durable=True)
        w.add_topic("/a", "std_msgs/msg/Float64")
        w.write("/a", m.encode_float64(1.0), 5)
    (tmp_path / "bag" / "metadata.yaml").unlink()
    with Bag(next(p for p in (tmp_path / "bag").iterdir())) as bag:
        assert bag.custom_data == {"plain": "at close", "durable": "at once"}


def test_mcap_library_flushes_a_readable_prefix_and_reads_up_to_a_cut(tmp_path):
    """What the writer relies on in ``mcap``: ``Writer.flush`` puts complete chunks on disk while the file stays
    open, ``add_metadata`` then ``flush`` puts its record there too, and the stream reader yields the records
    before a cut."""
    from mcap.records import Message, Metadata
    from mcap.stream_reader import StreamReader
    from mcap.writer import CompressionType, Writer

    path = tmp_path / "x.mcap"
    with path.open("wb") as f:
        w = Writer(f, compression=CompressionType.NONE)
        w.start(profile="ros2", library="test")
        channel = w.register_channel("/e", "cdr", w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data"))
        for i in range(5):
            w.add_message(channel, 10 + i, m.encode_float64(float(i)), 10 + i)
        w.flush()
        w.add_metadata("tissue_sim", {"k": "v"})
        w.flush()
        w.add_message(channel, 20, m.encode_float64(9.0), 20)  # pending in a chunk, never flushed
        size = path.stat().st_size
        cut = path.read_bytes()[: size - 3]  # the metadata record cut short
        full = path.read_bytes()
    records = []
    for data in (full, cut):
        stream = StreamReader(__import__("io").BytesIO(data)).records
        got = []
        with pytest.raises(Exception):  # noqa: B017  the end of a file whose writer did not finish it
            for r in stream:
                got.append(r)
        records.append(got)
    assert [r.log_time for r in records[0] if isinstance(r, Message)] == [10, 11, 12, 13, 14]
    assert [r.metadata for r in records[0] if isinstance(r, Metadata)] == [{"k": "v"}]
    assert [r.log_time for r in records[1] if isinstance(r, Message)] == [10, 11, 12, 13, 14]
    assert not [r for r in records[1] if isinstance(r, Metadata)]
