"""tissue-sim record / play across processes, interruption of a recording, and replay = node in lock-step.

Isolated graph (own ROS_DOMAIN_ID, localhost discovery) from test/ros_env.py;
every wait has a timeout, every process is ended by the start_process fixture.
"""
from __future__ import annotations

import os
import signal
import struct

import numpy as np
import pytest

pytest.importorskip("rclpy")



from tissue_sim_ros.core.sim.scene import build_simulation  # noqa: E402
from tissue_sim_ros.ros import messages as m  # noqa: E402
from tissue_sim_ros.ros.bags import Bag, read_tool_track, recover_bag  # noqa: E402
from tissue_sim_ros.ros.replay import replay  # noqa: E402

from bag_fixtures import small_params, tool_bag, write_bag, write_params  # noqa: E402


def _payloads(path, topic: str) -> list[bytes]:
    with Bag(path) as bag:
        return [bytes(raw) for _, _, _, raw in bag.messages([topic])]


def _text(proc) -> str:
    """Everything a process printed (also after it ended: RosProcess.output() needs an open log)."""
    return proc.log_path.read_text(errors="replace")


def _status_seconds(proc) -> float:
    """Seconds since start in the recorder's last status line (0 before the first)."""
    times = [float(line.split()[0]) for line in _text(proc).splitlines()
             if line.strip().endswith("messages") and line.strip().split()[1] == "s"]
    return times[-1] if times else 0.0


def _recorded_messages(proc) -> int:
    """Messages the recorder reported in its last status line (0 before the first)."""
    counts = [int(line.split()[2]) for line in _text(proc).splitlines()
              if line.strip().endswith("messages") and line.strip().split()[1] == "s"]
    return counts[-1] if counts else 0


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_play_into_record_keeps_bytes_and_timing(tmp_path, storage, ros_client, start_process):
    src, times, _ = tool_bag(tmp_path / "in", n=40, rate_hz=37.0, twist=True)
    out = tmp_path / "rec"
    rec = start_process(["tissue-sim", "record", "-o", str(out), "--storage", storage,
                         "--topics", "/tool/pose", "/tool/twist", "--flush-period", "0.2"], name="record")
    ros_client.spin_until(lambda: "recording to" in _text(rec), 30, rec, "the recorder to start")
    play = start_process(["tissue-sim", "play", str(src), "--rate", "2", "--wait", "30"], name="play")
    assert play.wait(timeout=60) == 0, _text(play)
    ros_client.spin_until(lambda: _recorded_messages(rec) >= 80, 20, rec, "the recorder to get all 80 messages")
    assert rec.stop(signal.SIGINT, timeout=20) == 0, _text(rec)
    assert "closed" in _text(rec) and "on SIGINT" in _text(rec)
    for topic in ("/tool/pose", "/tool/twist"):
        assert _payloads(out, topic) == _payloads(src, topic), topic  # the bytes, unchanged
    with Bag(out) as bag:
        assert bag.topics == {"/tool/pose": "geometry_msgs/msg/PoseStamped",
                              "/tool/twist": "geometry_msgs/msg/TwistStamped"}
        recv = np.array([t for _, _, t, _ in bag.messages(["/tool/pose"])])
    # at --rate 2, play never sends before the schedule: the receive span is at least half the bag's span
    span = (times[-1] - times[0]) / 2
    assert recv[-1] - recv[0] >= 0.95 * span


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_interrupted_recording_closes_the_bag(tmp_path, sig, ros_client, start_process):
    src, _, _ = tool_bag(tmp_path / "in", n=30, rate_hz=50.0)
    out = tmp_path / "rec"
    rec = start_process(["tissue-sim", "record", "-o", str(out), "--topics", "/tool/pose"], name="record")
    ros_client.spin_until(lambda: "recording to" in _text(rec), 30, rec, "the recorder to start")
    play = start_process(["tissue-sim", "play", str(src), "--loop", "--wait", "30"], name="play")
    ros_client.spin_until(lambda: _recorded_messages(rec) >= 20, 30, rec, "messages in the recording")
    assert rec.stop(sig, timeout=20) == 0, _text(rec)  # while messages still flow
    play.stop(signal.SIGINT)
    text = _text(rec)
    assert f"on {signal.Signals(sig).name}" in text
    n_closed = int(text.split("closed", 1)[1].split(":", 1)[1].split()[0])
    assert (out / "metadata.yaml").is_file()
    with Bag(out) as bag:
        assert bag.message_count == n_closed >= 20
        track = read_tool_track(bag, time_source="bag")
    assert track.n == n_closed


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_killed_recorder_loses_at_most_the_last_flush(tmp_path, storage, ros_client, start_process):
    """SIGKILL: no close at all; recover_bag (tissue-sim record --recover) salvages every flushed message."""
    src, _, _ = tool_bag(tmp_path / "in", n=30, rate_hz=50.0)
    out = tmp_path / "rec"
    rec = start_process(["tissue-sim", "record", "-o", str(out), "--storage", storage, "--topics", "/tool/pose",
                         "--flush-period", "0.1"], name="record")
    ros_client.spin_until(lambda: "recording to" in _text(rec), 30, rec, "the recorder to start")
    play = start_process(["tissue-sim", "play", str(src), "--loop", "--wait", "30"], name="play")
    ros_client.spin_until(lambda: _recorded_messages(rec) >= 40, 30, rec, "messages in the recording")
    reported = _recorded_messages(rec)
    rec.stop(signal.SIGKILL)
    play.stop(signal.SIGINT)
    assert not (out / "metadata.yaml").exists()
    recover_bag(out, tmp_path / "salvaged")
    with Bag(tmp_path / "salvaged") as bag:
        # everything but the last flush period (0.1 s, at 50 Hz ~5 messages) before the status line
        assert bag.message_count >= max(1, reported - 10)
        raws = [raw for _, _, _, raw in bag.messages()]
    assert set(raws) <= set(_payloads(src, "/tool/pose"))


def test_play_publishes_clock(tmp_path, ros_client, start_process):
    from rclpy.qos import QoSProfile
    from rosgraph_msgs.msg import Clock

    src, times, _ = tool_bag(tmp_path / "in", n=20, rate_hz=37.0)
    clock = ros_client.raw_subscription(Clock, "/clock", QoSProfile(depth=1000))
    play = start_process(["tissue-sim", "play", str(src), "--topics", "/chatter", "--clock", "--rate", "4",
                          "--wait", "2"], name="play")  # /chatter: nobody listens, /clock is matched
    ros_client.spin_until(lambda: play.returncode is not None and len(clock.messages) > 0, 60, None,
                          "play to finish")
    assert play.wait(timeout=10) == 0
    last = times[-1] + 1000  # /chatter is stamped 1 us after each tool message in the fixture
    ros_client.spin_until(lambda: any(_clock_ns(c) == last for c in clock.messages), 10, None,
                          "the /clock of the last message")
    t = np.array([_clock_ns(c) for c in clock.messages])
    assert (np.diff(t) >= 0).all() and t.max() == last and t.min() == times[0] + 1000


def _clock_ns(raw: bytes) -> int:
    sec, nsec = struct.unpack_from("<iI", raw, 4)
    return sec * 1_000_000_000 + nsec


def test_play_and_record_bad_input(tmp_path, ros_env, capsys):
    from tissue_sim_ros.cli import main as cli

    src, _, _ = tool_bag(tmp_path / "in", n=5)
    assert cli(["play", str(src), "--topics", "/nope"]) == 2
    assert cli(["play", str(src), "--rate", "0"]) == 2
    assert cli(["play", str(tmp_path / "missing")]) == 2
    assert cli(["play", str(src), "--remap", "bad"]) == 2
    (tmp_path / "exists").mkdir()
    assert cli(["record", "-o", str(tmp_path / "exists")]) == 2
    assert cli(["record", "-o", str(tmp_path / "x"), "--duration", "-1"]) == 2
    capsys.readouterr()

    def refused(argv, message):
        assert cli(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err and "Traceback" not in err, (argv, err)

    # play: a negative --wait (was accepted); a remap of a topic that is not played (was silently ignored)
    refused(["play", str(src), "--wait", "-1"], "--wait -1.0: expected seconds >= 0")
    refused(["play", str(src), "--remap", "/nope:=/x"],
            "--remap /nope:=/x: '/nope' is not in the bag: expected one of the played topics /tool/pose "
            "(the bag's tool topics: /tool/pose")
    refused(["play", str(src), "--remap", "/chatter:=/x"], "'/chatter' is not played")
    refused(["play", str(src), "--remap", "/tool/pose:=bad name"], "--remap target 'bad name': topic name must not")
    # record: invalid names (were an rclpy traceback leaving the bag directory, and exit 0 with no topics)
    refused(["record", "-o", str(tmp_path / "r_ns"), "--namespace", "bad name", "--duration", "1"],
            "--namespace 'bad name': namespace must not contain characters other than alphanumerics")
    refused(["record", "-o", str(tmp_path / "r_top"), "--topics", "bad topic!", "--duration", "1"],
            "--topics 'bad topic!': topic name must not contain characters other than alphanumerics")
    assert not (tmp_path / "r_ns").exists() and not (tmp_path / "r_top").exists()


def _bag_with_applied_outputs(path, n=5):
    """A node's recording: tool input and the node's own tool/applied_* outputs (also a namespaced node's)."""
    src, _, _ = tool_bag(path.parent / (path.name + "_src"), n=n, twist=True, extras=False)
    with Bag(src) as bag:
        msgs = [(topic, ty, t, bytes(raw)) for topic, ty, t, raw in bag.messages()]
    msgs += [(f"{ns}/tool/applied_{kind}", f"geometry_msgs/msg/{ty}", t + 1, raw)
             for ns in ("", "/left") for topic, _, t, raw in list(msgs)
             for kind, ty in (("pose", "PoseStamped"), ("twist", "TwistStamped"))
             if topic == f"/tool/{kind}"]
    return write_bag(path, msgs)


def test_play_leaves_the_nodes_own_outputs_out_unless_named(tmp_path):
    from tissue_sim_ros.ros.play import choose_topics

    path = _bag_with_applied_outputs(tmp_path / "node_bag")
    with Bag(path) as bag:
        assert set(bag.topics) >= {"/tool/applied_pose", "/left/tool/applied_twist"}
        assert choose_topics(bag, None) == ["/tool/pose", "/tool/twist"]  # was every pose/twist-typed topic
        assert choose_topics(bag, ["/tool/applied_pose"]) == ["/tool/applied_pose"]  # named: played


def test_play_parses_no_ros_arguments_from_its_command_line(tmp_path, ros_client, start_process):
    """rclpy.init(args=None) made rcl parse tissue-sim's own '--remap FROM:=TO' and warn 'This syntax is
    deprecated'; the node's outputs were played beside the tool topics."""
    path = _bag_with_applied_outputs(tmp_path / "node_bag")
    play = start_process(["tissue-sim", "play", str(path), "--remap", "/tool/pose:=/ee_pose", "--wait", "0",
                          "--min-subscribers", "0", "--no-clock"], name="play")
    assert play.wait(timeout=60) == 0, _text(play)
    text = _text(play)
    assert "playing 10 messages on /ee_pose, /tool/twist at 1.0x" in text, text
    assert "deprecated" not in text and "Found remap rule" not in text, text


def test_every_rclpy_init_is_given_its_arguments():
    """A tissue-sim command's rclpy.init must not read sys.argv (tissue-sim's options): args is always explicit."""
    import re
    from pathlib import Path

    root = Path(__file__).parents[1] / "tissue_sim_ros"
    calls = [(p.name, m.group(0)) for p in root.rglob("*.py") for m in re.finditer(r"rclpy\.init\([^)]*\)",
                                                                                     p.read_text())]
    assert calls
    assert [c for c in calls if "args=" not in c[1] or "args=None" in c[1]] == []


def test_record_duration_counts_from_the_first_message(tmp_path, ros_client, start_process):
    """--duration 1 against a publisher that shows up only after the recorder has run for more than 1 s: the
    recording holds its messages (it stopped at 1 s with 0 messages), and spans no more than the duration."""
    src, _, _ = tool_bag(tmp_path / "in", n=60, rate_hz=40.0, extras=False)
    out = tmp_path / "rec"
    rec = start_process(["tissue-sim", "record", "-o", str(out), "--topics", "/tool/pose", "--duration", "1",
                         "--flush-period", "0.2"], name="record")
    # the recorder's own status line: it has been up for more than the duration, with nothing received
    ros_client.spin_until(lambda: _status_seconds(rec) >= 1.0, 30, rec, "the recorder to run for 1 s")
    play = start_process(["tissue-sim", "play", str(src), "--wait", "30", "--no-clock"], name="play")
    assert rec.wait(timeout=60) == 0, _text(rec)
    assert "first message after" in _text(rec)
    play.stop(signal.SIGINT)
    with Bag(out) as bag:
        recv = np.array([t for _, _, t, _ in bag.messages(["/tool/pose"])])
    assert recv.size > 0
    assert set(_payloads(out, "/tool/pose")) <= set(_payloads(src, "/tool/pose"))
    assert (recv[-1] - recv[0]) * 1e-9 <= 1.0 + 0.1  # nothing after the duration (receive clock ~ wall clock)


def test_record_duration_with_nothing_to_record_ends_after_wait(tmp_path, start_process):
    """--duration counts from the first message; with none (no node on that topic) --wait ends it, empty."""
    out = tmp_path / "empty"
    rec = start_process(["tissue-sim", "record", "-o", str(out), "--topics", "/nobody/publishes/this", "--duration",
                         "1", "--wait", "1", "--quiet"], name="record_empty")
    assert rec.wait(timeout=60) == 0, _text(rec)
    assert "no message in 1 s" in _text(rec) and "0 messages" in _text(rec)
    assert (out / "metadata.yaml").exists()  # a closed, empty bag


def test_a_recorder_with_nothing_yet_says_what_it_waits_for(tmp_path, start_process):
    """Seconds of "0 messages" while a node starts read as a hang: the recorder says what it is waiting for."""
    out = tmp_path / "waiting"
    rec = start_process(["tissue-sim", "record", "-o", str(out), "--topics", "/nobody/publishes/this", "--duration",
                         "1", "--wait", "4"], name="record_waiting")
    assert rec.wait(timeout=60) == 0, _text(rec)
    assert "waiting for publishers: none yet on /nobody/publishes/this in ROS domain" in _text(rec), _text(rec)


def test_offline_replay_equals_node_in_lock_step(tmp_path, ros_client, start_process):
    """The node stepping once per played pose publishes what the offline replay writes, to the bit.

    The energy series, and every step's tissue/points (positions, signed strain, bodies) and tool/wrench
    as the same bytes: the node and replay encode a step with the one StepEncoder.
    """
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64

    from tissue_sim_ros.ros.bags import BagWriter
    from tissue_sim_ros.ros.replay import ReplayBagSink

    src, _, _ = tool_bag(tmp_path / "in", n=40, rate_hz=37.0)
    params = write_params(tmp_path)
    sim = build_simulation(small_params(tmp_path))
    with BagWriter(tmp_path / "offline_bag", "mcap") as writer:
        offline = replay(sim, read_tool_track(src), sink=ReplayBagSink(writer, sim), progress=False)
    assert offline.rollout.in_contact.any()

    energy = ros_client.raw_subscription(Float64, "/tissue/energy", QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE))
    node = start_process(["tissue_sim_node", "--ros-args", "--params-file", str(params), "-p", "lock_step:=true"],
                         name="node")
    ros_client.wait_for_publisher("/tissue/energy", timeout=120, process=node)
    ros_client.spin_until(lambda: energy.sub.get_publisher_count() > 0, 30, node, "matching /tissue/energy")
    # the recorder with its default topics: the node's outputs and the tool input
    out = tmp_path / "rec"
    rec = start_process(["tissue-sim", "record", "-o", str(out)], name="record")
    ros_client.spin_until(lambda: "+ /tissue/energy/bodies" in _text(rec) and "+ /tissue/points" in _text(rec),
                          30, rec, "the recorder to subscribe to the node's topics")
    # the recorder subscribes to tool/pose once play publishes it: wait for both subscribers
    play = start_process(["tissue-sim", "play", str(src), "--wait", "30", "--min-subscribers", "2"], name="play")
    ros_client.spin_until(lambda: len(energy.messages) >= 40, 180, node, "40 energy messages from the node")
    assert play.wait(timeout=30) == 0, _text(play)
    ros_client.spin_for(0.3)  # nothing more may come: one step per pose
    live = np.array([m.decode_float64(raw) for raw in energy.messages])
    assert live.shape == (40,), f"{len(live)} energy messages for 40 poses"
    np.testing.assert_array_equal(live, offline.rollout.scene_total)

    ros_client.spin_until(lambda: _recorded_messages(rec) >= 40 * 8, 30, rec, "the recorder to catch up")
    assert rec.stop(signal.SIGINT, timeout=20) == 0, _text(rec)
    with Bag(out) as bag:
        types = bag.topics
        counts = bag.message_counts
        recorded = [m.decode_float64(raw) for _, _, _, raw in bag.messages(["/tissue/energy"])]
        offered = {c.topic: c.ext.offered_qos_profiles for c in bag.connections}
    # the publishers' QoS is kept for ros2 bag play: the rest mesh stays latched
    assert offered["/tissue/rest_mesh"][0].durability.name == "TRANSIENT_LOCAL"
    assert offered["/tissue/energy"][0].reliability.name == "RELIABLE"
    assert types["/tissue/markers"] == "visualization_msgs/msg/MarkerArray"
    assert types["/tissue/points"] == "sensor_msgs/msg/PointCloud2"
    assert types["/tissue/rest_mesh"] == "visualization_msgs/msg/MarkerArray"  # latched: recorded though sent before
    assert types["/tool/wrench"] == "geometry_msgs/msg/WrenchStamped"
    assert types["/tool/pose"] == "geometry_msgs/msg/PoseStamped"
    for term in ("inertial", "spring", "area", "strain", "potential", "bodies"):
        assert counts[f"/tissue/energy/{term}"] == 40
    assert counts["/tool/pose"] == 40 and counts["/tissue/rest_mesh"] == 1
    np.testing.assert_array_equal(recorded, offline.rollout.scene_total)
    with Bag(out) as bag:
        live_out = {t: [raw for _, _, _, raw in bag.messages([t])] for t in ("/tissue/points", "/tool/wrench")}
    with Bag(tmp_path / "offline_bag") as bag:
        replayed = {t: [raw for _, _, _, raw in bag.messages([t])] for t in ("/tissue/points", "/tool/wrench")}
    # compared decoded: the middleware may pad the serialized bytes it hands the recorder
    for topic, decode in (("/tissue/points", m.decode_point_cloud), ("/tool/wrench", m.decode_wrench_stamped)):
        assert len(live_out[topic]) == len(replayed[topic]) == 40, topic
        for k, (a, b) in enumerate(zip(live_out[topic], replayed[topic])):
            (stamp_a, frame_a, *data_a), (stamp_b, frame_b, *data_b) = decode(a), decode(b)
            assert (stamp_a, frame_a) == (stamp_b, frame_b), f"{topic} step {k}"
            for x, y in zip(data_a, data_b):
                np.testing.assert_array_equal(x, y, err_msg=f"{topic} step {k}: node and replay differ")
    strain = m.decode_point_cloud(live_out["/tissue/points"][-1])[2]["strain"]
    assert (strain < 0).any() and (strain > 0).any(), "signed strain: the tool compresses and stretches the strip"


def test_play_remaps_a_robot_topic_onto_the_tool_topic(tmp_path, ros_client, start_process):
    src, _, _ = tool_bag(tmp_path / "in", n=20, rate_hz=60.0, topic="/robot/ee_pose")
    out = tmp_path / "rec"
    rec = start_process(["tissue-sim", "record", "-o", str(out), "--topics", "tool/pose"], name="record")
    ros_client.spin_until(lambda: "recording to" in _text(rec), 30, rec, "the recorder to start")
    play = start_process(["tissue-sim", "play", str(src), "--remap", "/robot/ee_pose:=/tool/pose", "--wait", "30"],
                         name="play")
    assert play.wait(timeout=60) == 0, _text(play)
    ros_client.spin_until(lambda: _recorded_messages(rec) >= 20, 20, rec, "20 remapped messages")
    assert rec.stop(signal.SIGTERM, timeout=20) == 0, _text(rec)
    assert _payloads(out, "/tool/pose") == _payloads(src, "/robot/ee_pose")


def test_play_skips_tool_topics_whose_package_is_missing(tmp_path, capsys, ros_env):
    """tf2_msgs has no PyPI wheel: a default play skips /tf with a note; asking for it is an error."""
    import importlib.util

    from tissue_sim_ros.cli import main as cli

    if importlib.util.find_spec("tf2_msgs") is not None:
        pytest.skip("tf2_msgs is installed here")
    src, _, _ = tool_bag(tmp_path / "in", "tf2_msgs/msg/TFMessage", topic="/tf", n=5)
    assert cli(["play", str(src), "--topics", "/tf"]) == 2
    assert "'tf2_msgs' is not installed" in capsys.readouterr().err
    assert cli(["play", str(src), "--wait", "0"]) == 2
    captured = capsys.readouterr()
    assert "skipping /tf" in captured.out and "none of its tool topics" in captured.err


def test_recorder_follows_a_best_effort_tool_publisher(tmp_path, ros_client, start_process):
    """The recorder subscribes to tool/pose at once (reliable); a best-effort publisher makes it re-subscribe."""
    from geometry_msgs.msg import PoseStamped
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    out = tmp_path / "rec"
    rec = start_process(["tissue-sim", "record", "-o", str(out)], name="record")
    ros_client.spin_until(lambda: "+ /tool/pose" in _text(rec), 30, rec, "the recorder to subscribe to /tool/pose")
    pub = ros_client.node.create_publisher(PoseStamped, "/tool/pose", QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=50, reliability=ReliabilityPolicy.BEST_EFFORT))
    try:
        ros_client.wait_for_subscriber(pub, timeout=30, process=rec)  # matches only once it went best effort
        sent = [m.encode_pose_stamped((1, i), "world", 0.01 * i, 0.0, 0.0) for i in range(20)]
        for raw in sent:
            pub.publish(raw)
        ros_client.spin_until(lambda: _recorded_messages(rec) >= 20, 20, rec, "20 best-effort poses recorded")
    finally:
        ros_client.node.destroy_publisher(pub)
    assert rec.stop(signal.SIGINT, timeout=20) == 0, _text(rec)
    assert _payloads(out, "/tool/pose") == sent


def test_tool_only_on_tf_played_into_the_node_equals_the_offline_replay(tmp_path, ros_client, start_process):
    """A robot's bag with the tool only on /tf (tool_tip among other links): played into a lock-step node with
    tool_frame, it gives the energy series of `replay --tool-topic /tf --frame tool_tip`, to the bit."""
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64

    from tissue_sim_ros.ros import tf_input

    if not tf_input.TF_AVAILABLE:
        pytest.skip("tf2_msgs is not importable here (scripts/build_tf2_msgs.sh generates it)")
    src, _, _ = tool_bag(tmp_path / "in", msgtype="tf2_msgs/msg/TFMessage", topic="/tf", n=40, rate_hz=37.0)
    # the tool's poses are in base_link, the TF parent: the plane's frame here, as offline
    params = write_params(tmp_path, frame_id="base_link", tool_frame="tool_tip", lock_step=True)
    offline = replay(build_simulation(small_params(tmp_path)), read_tool_track(src, topic="/tf", frame="tool_tip"),
                     progress=False)
    assert offline.rollout.in_contact.any()
    energy = ros_client.raw_subscription(Float64, "/tissue/energy", QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE))
    node = start_process(["tissue_sim_node", "--ros-args", "--params-file", str(params)],
                         name="node")
    ros_client.wait_for_publisher("/tissue/energy", timeout=120, process=node)
    ros_client.spin_until(lambda: energy.sub.get_publisher_count() > 0, 30, node, "matching /tissue/energy")
    play = start_process(["tissue-sim", "play", str(src), "--topics", "/tf", "--no-clock", "--wait", "30"],
                         name="play")
    ros_client.spin_until(lambda: len(energy.messages) >= 40, 180, node, "40 energy messages from the node")
    assert play.wait(timeout=30) == 0, _text(play)
    ros_client.spin_for(0.3)
    live = np.array([m.decode_float64(raw) for raw in energy.messages])
    assert live.shape == (40,), f"{len(live)} energy messages for 40 tool transforms"
    np.testing.assert_array_equal(live, offline.rollout.scene_total)


@pytest.mark.parametrize("recorded_qos", [True, False], ids=["latched-in-metadata", "no-qos-recorded"])
def test_play_delivers_a_bags_tf_static_to_the_node(tmp_path, start_process, recorded_qos):
    """A robot bag whose tool frame reaches the node only through /tf_static (world -> robot_base, poses in
    robot_base): played into a fresh lock-step node, every pose becomes a step, none dropped as dropped_frame.

    The node subscribes to /tf_static TRANSIENT_LOCAL; a VOLATILE publisher never matches it (DDS: "offering
    incompatible QoS ... DURABILITY"), so play must publish it latched, as its publishers offered it.
    """
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
    from std_msgs.msg import Float64

    from tissue_sim_ros.ros import play as player
    from tissue_sim_ros.ros import tf_input

    from bag_fixtures import T, header, irregular_times, pose, trajectory, transform_stamped

    if not tf_input.TF_AVAILABLE:
        pytest.skip("tf2_msgs is not importable here (scripts/build_tf2_msgs.sh generates it)")
    n = 30
    times = irregular_times(n, 40.0)
    poses = trajectory(times)
    base = (0.05, -0.02, 0.0)  # world -> robot_base: a pure translation in the plane
    # as a robot's bag starts: /tf_static first, the arm's poses half a second later
    t_static = int(times[0]) - 500_000_000
    static = T["tf2_msgs/msg/TFMessage"](transforms=[transform_stamped(t_static, "world", "robot_base", *base)])
    msgs = [("/tf_static", "tf2_msgs/msg/TFMessage", t_static, static)]
    for t, (x, y, yaw) in zip(times, poses):
        msgs.append(("/tool/pose", "geometry_msgs/msg/PoseStamped", int(t),
                     T["geometry_msgs/msg/PoseStamped"](header=header(int(t), "robot_base"),
                                                        pose=pose(float(x - base[0]), float(y - base[1]), float(yaw)))))
    zero = QosTime(0, 0)
    latched = Qos(history=QosHistory.KEEP_LAST, depth=1, reliability=QosReliability.RELIABLE,
                  durability=QosDurability.TRANSIENT_LOCAL, deadline=zero, lifespan=zero,
                  liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=zero,
                  avoid_ros_namespace_conventions=False)
    src = write_bag(tmp_path / "robot_bag", msgs, qos={"/tf_static": latched} if recorded_qos else None)
    with Bag(src) as bag:
        assert bag.offered_qos("/tf_static") == ((True, True, 1) if recorded_qos else None)
        assert player.play_qos(bag, "/tf_static", 1) == (True, True, 1)
        assert player.play_qos(bag, "/tool/pose", n) == (True, False, 1000)

    import yaml

    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": small_params(tmp_path, frame_id="world",
                                                                               lock_step=True)}}))
    # on a ROS domain of its own, so that nothing else in the session's graph (a participant an earlier test
    # killed lingers there until its lease ends) counts as one of play's subscribers
    from tissue_sim_ros.ros.domain import domain_in_use

    from ros_env import RosClient

    domain = next(d for d in range(1, 101) if str(d) != os.environ.get("ROS_DOMAIN_ID") and not domain_in_use(d))
    client = RosClient(domain, name="tf_static_client")
    try:
        energy = client.raw_subscription(Float64, "/tissue/energy", QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE))
        from diagnostic_msgs.msg import DiagnosticArray

        diags: list = []
        client.node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
        own = {"ROS_DOMAIN_ID": str(domain)}
        node = start_process(["tissue_sim_node", "--ros-args", "--params-file", str(params)], name="node",
                             env_changes=own)
        client.wait_for_publisher("/tissue/energy", timeout=120, process=node)
        client.spin_until(lambda: energy.sub.get_publisher_count() > 0, 30, node, "matching /tissue/energy")
        play = start_process(["tissue-sim", "play", str(src), "--no-clock", "--wait", "30"], name="play",
                             env_changes=own)
        assert play.wait(timeout=60) == 0, _text(play)
        client.spin_until(lambda: len(energy.messages) >= n, 60, node,
                          f"{n} energy messages (every pose in robot_base taken through /tf_static); play said:\n"
                          f"{_text(play)}")

        def counters() -> dict[str, str] | None:  # the node's diagnostics once they count every step
            last = {kv.key: kv.value for d in diags[-1:] for kv in d.status[0].values} if diags else {}
            return last if int(last.get("steps", 0)) >= n else None

        last = client.spin_until(counters, 30, node, f"/diagnostics counting {n} steps")
        assert {k: v for k, v in last.items() if k.startswith("dropped_") and v != "0"} == {}
        assert len(energy.messages) == n
    finally:
        client.close()


def test_the_recorders_summary_says_what_a_recording_holds_fewer_of():
    """The demo's bag held 263 marker arrays for 300 steps and nothing said so: markers are a display stream
    (the node skipped them while its marker thread was busy), which the summary now says; a per-step topic
    short of another means messages were lost, which it warns about."""
    from tissue_sim_ros.ros.record import completeness

    full = {"/tissue/energy": 300, "/tissue/energy/bodies": 300, "/tool/wrench": 300, "/tool/applied_twist": 300,
            "/tissue/points": 300}
    assert completeness({**full, "/tissue/markers": 300}) == []
    lines = completeness({**full, "/tissue/markers": 263})
    assert len(lines) == 1 and lines[0].startswith("note: /tissue/markers holds 263 arrays for 300 steps: the node "
                                                   "publishes markers as a display stream")
    lines = completeness({**full, "/tool/wrench": 290, "/tissue/markers": 300})
    assert lines == ["WARNING: per-step topics differ (/tool/wrench 290, against 300): messages were lost on the way "
                     "(a loaded machine, or the recorder started after the node)"]
    ns = {f"/left{t}": n for t, n in {**full, "/tissue/markers": 10}.items()}
    assert completeness(ns, "left")[0].startswith("note: /left/tissue/markers holds 10 arrays for 300 steps")
    assert completeness(full, lost={"/tissue/points": 3}) == [
        "WARNING: /tissue/points: DDS reported 3 messages lost in transport"]
