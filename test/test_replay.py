"""tissue-sim replay: offline runs on bags' tool trajectories (small strip mesh, short bags).

The reference for "replay does what it says" is a Simulation stepped directly
with the poses the test put into the bag.
"""
from __future__ import annotations

import math
import sys

import numpy as np
import pytest

from tissue_sim_ros.cli import main as cli
from tissue_sim_ros.core.contact.tool import ToolPose, ToolTwist
from tissue_sim_ros.core.sim.scene import build_simulation
from tissue_sim_ros.ros import messages as m
from tissue_sim_ros.ros.bags import Bag, read_tool_track
from tissue_sim_ros.ros.replay import OUTPUT_TOPICS, replay, schedule

from bag_fixtures import small_params, tool_bag, tool_msg, write_bag, write_params


def _direct_energy(params, poses, twists=None) -> np.ndarray:
    """Scene energy per step of a Simulation stepped with ``poses`` directly (no bag in between)."""
    sim = build_simulation(params)
    out = []
    for i, (x, y, yaw) in enumerate(poses):
        tw = None if twists is None or not np.isfinite(twists[i]).all() else ToolTwist(*map(float, twists[i]))
        out.append(sim.step(ToolPose(float(x), float(y), float(yaw)), tw).energy.scene_total)
    return np.array(out)


def test_per_message_replay_equals_direct_stepping(tmp_path):
    path, times, poses = tool_bag(tmp_path / "in", n=45, rate_hz=37.0)
    params = small_params(tmp_path)
    result = replay(build_simulation(params), read_tool_track(path), progress=False)
    assert result.n_steps == 45
    np.testing.assert_array_equal(result.t_ns, times)
    np.testing.assert_array_equal(result.rollout.scene_total, _direct_energy(params, poses))
    assert result.rollout.in_contact.any(), "the trajectory should reach the tissue, or the test checks little"
    np.testing.assert_array_equal(result.rollout.tool_pose, read_tool_track(path).pose)


def test_replay_is_bit_identical_twice(tmp_path):
    path, _, _ = tool_bag(tmp_path / "in", n=40, rate_hz=37.0)
    params = small_params(tmp_path)
    track = read_tool_track(path)
    a = replay(build_simulation(params), track, progress=False).rollout
    b = replay(build_simulation(params), track, progress=False).rollout
    for name in ("inertial", "spring", "area", "reaction_force"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


def test_cli_twice_gives_identical_csv_and_bag_energy(tmp_path, capsys):
    path, _, _ = tool_bag(tmp_path / "in", n=30, rate_hz=37.0)
    params = write_params(tmp_path)
    for out in ("o1", "o2"):
        assert cli(["replay", str(path), "--params", str(params), "--out", str(tmp_path / out), "--no-progress",
                    "--frame-every", "10"]) == 0
    text = capsys.readouterr().out
    assert "real-time factor" in text and "steps/s" in text
    assert (tmp_path / "o1" / "energy.csv").read_bytes() == (tmp_path / "o2" / "energy.csv").read_bytes()
    energies = []
    for out in ("o1", "o2"):
        with Bag(tmp_path / out / "replay_bag") as bag:
            energies.append([raw for _, _, _, raw in bag.messages(["/tissue/energy"])])
    assert energies[0] == energies[1] and len(energies[0]) == 30


def test_cli_outputs(tmp_path, capsys):
    path, times, poses = tool_bag(tmp_path / "in", n=25, rate_hz=37.0)
    out = tmp_path / "out"
    assert cli(["replay", str(path), "--params", str(write_params(tmp_path)), "--out", str(out), "--no-progress",
                "--frame-every", "10"]) == 0
    assert (out / "energy.png").stat().st_size > 1000
    import json

    summary = json.loads((out / "replay.json").read_text())
    assert summary["steps"] == 25 and summary["tool_topic"] == "/tool/pose" and summary["real_time_factor"] > 0
    assert sorted(p.name for p in (out / "frames").glob("*.png")) == [
        "frame_00000.png", "frame_00010.png", "frame_00020.png", "frame_00025.png"]
    table = np.genfromtxt(out / "energy.csv", delimiter=",", names=True)
    assert table.shape == (25,)
    with Bag(out / "replay_bag") as bag:
        assert bag.topics == OUTPUT_TOPICS
        meta = bag.custom_data
        assert meta["tissue_sim.mode"] == "per-message" and meta["tissue_sim.tool_topic"] == "/tool/pose"
        assert json.loads(meta["tissue_sim.params"])["mesh_file"] == small_params(tmp_path)["mesh_file"]
        assert all(n == 25 for n in bag.message_counts.values())
        got = list(bag.messages(["/tool/pose", "/tissue/energy", "/tissue/points"]))
    # stamped with the input's times, the pose the step used, the energy of the CSV
    pose_msgs = [(t, raw) for tp, _, t, raw in got if tp == "/tool/pose"]
    assert [t for t, _ in pose_msgs] == list(times)
    stamp, _, pos, _ = m.decode_pose_stamped(pose_msgs[3][1])
    np.testing.assert_allclose(pos[:2], poses[3, :2])
    energy = [m.decode_float64(raw) for tp, _, _, raw in got if tp == "/tissue/energy"]
    np.testing.assert_array_equal(energy, table["energy_total"])
    _, _, cloud = m.decode_point_cloud([raw for tp, _, _, raw in got if tp == "/tissue/points"][-1])
    assert cloud.shape[0] == build_simulation(small_params(tmp_path)).model.n_particles
    assert np.isfinite(cloud["x"]).all()


def test_fixed_rate_mode_interpolates(tmp_path):
    path, times, _ = tool_bag(tmp_path / "in", n=30, rate_hz=37.0)
    params = small_params(tmp_path)
    track = read_tool_track(path)
    dt = build_simulation(params).params.dt
    t, poses, twists = schedule(track, dt, "fixed-rate")
    span = times[-1] - times[0]
    assert t.shape[0] == span // int(round(dt * 1e9)) and twists is None
    assert t[0] == times[0] + int(round(dt * 1e9))
    # every scheduled pose lies on the segment between its neighbouring samples
    k = np.searchsorted(times, t) - 1
    w = (t - times[k]) / (times[k + 1] - times[k])
    np.testing.assert_allclose(poses[:, 0], track.pose[k, 0] * (1 - w) + track.pose[k + 1, 0] * w, atol=1e-12)
    result = replay(build_simulation(params), track, "fixed-rate", progress=False)
    np.testing.assert_array_equal(result.rollout.scene_total, _direct_energy(params, poses))


def test_twist_topic_is_used(tmp_path):
    path, _, poses = tool_bag(tmp_path / "in", n=20, twist=True)
    params = small_params(tmp_path)
    track = read_tool_track(path, twist_topic="/tool/twist")
    result = replay(build_simulation(params), track, progress=False)
    np.testing.assert_array_equal(result.rollout.scene_total, _direct_energy(params, poses, track.twist))


def test_tf_bag_with_frame(tmp_path, capsys):
    path, _, poses = tool_bag(tmp_path / "in", "tf2_msgs/msg/TFMessage", topic="/tf", n=20)
    params = write_params(tmp_path)
    assert cli(["replay", str(path), "--params", str(params), "--out", str(tmp_path / "o"), "--no-progress",
                "--frame-every", "-1", "--no-bag"]) == 2
    assert "--frame base_link" in capsys.readouterr().err
    assert cli(["replay", str(path), "--params", str(params), "--out", str(tmp_path / "o"), "--no-progress",
                "--frame-every", "-1", "--no-bag", "--frame", "tool_tip"]) == 0
    table = np.genfromtxt(tmp_path / "o" / "energy.csv", delimiter=",", names=True)
    np.testing.assert_array_equal(table["energy_total"], _direct_energy(small_params(tmp_path), poses))


def test_skips_are_reported_and_strict_refuses(tmp_path, capsys):
    ty = "geometry_msgs/msg/PoseStamped"
    stamps = [10, 20, 20, 30, 25, 40]
    msgs = [("/tool/pose", ty, (i + 1) * 1_000_000, tool_msg(ty, s * 1_000_000, -0.3 + 0.01 * i, 0.15, 0.0))
            for i, s in enumerate(stamps)]
    path = write_bag(tmp_path / "in", msgs)
    params = write_params(tmp_path)
    args = ["replay", str(path), "--params", str(params), "--no-progress", "--frame-every", "-1", "--no-bag"]
    assert cli(args + ["--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    assert "2 of 6 tool samples skipped (repeated: 1, out_of_order: 1)" in out
    assert len(np.genfromtxt(tmp_path / "o" / "energy.csv", delimiter=",", names=True)) == 4
    assert cli(args + ["--out", str(tmp_path / "o2"), "--strict"]) == 2
    err = capsys.readouterr().err
    assert "equal to the previous sample" in err and err.count("\n") == 1
    # the CLI's words, not the Python API's (was "use on_bad_time='skip' to drop such samples")
    assert "on_bad_time" not in err and "(--strict; without it such samples are skipped and counted)" in err
    assert not (tmp_path / "o2").exists()


def test_strict_refuses_every_skip_it_is_offered_for(tmp_path, capsys):
    """The note says "--strict makes this an error": so it does for a bad quaternion (was exit 0)."""
    ty = "geometry_msgs/msg/PoseStamped"
    good = [tool_msg(ty, (i + 1) * 1_000_000, -0.3 + 0.01 * i, 0.15, 0.0) for i in range(5)]
    bad_q = tool_msg(ty, 10_000_000, -0.2, 0.15, 0.0)
    bad_q.pose.orientation.w = 0.0
    path = write_bag(tmp_path / "in", [("/tool/pose", ty, i + 1, msg) for i, msg in enumerate(good + [bad_q])])
    args = ["replay", str(path), "--params", str(write_params(tmp_path)), "--no-progress", "--frame-every", "-1",
            "--no-bag"]
    assert cli(args + ["--out", str(tmp_path / "o")]) == 0
    assert "1 of 6 tool samples skipped (bad_quaternion: 1); --strict makes this an error" in capsys.readouterr().out
    assert cli(args + ["--out", str(tmp_path / "o2"), "--strict"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "sample 6 has an invalid quaternion (0.0, 0.0, 0.0, 0.0) (bad_quaternion)" in err
    assert not (tmp_path / "o2").exists()


def test_cli_bad_input(tmp_path, capsys, monkeypatch):
    path, _, _ = tool_bag(tmp_path / "in", n=5)
    params = str(write_params(tmp_path))
    assert cli(["replay", str(path), "--params", params, "--out", str(tmp_path / "o"), "--tool-topic", "/nope"]) == 2
    err = capsys.readouterr().err
    assert "no topic '/nope'" in err and "/tool/pose (geometry_msgs/msg/PoseStamped, 5 msgs)" in err
    assert "Traceback" not in err
    assert cli(["replay", str(tmp_path / "missing"), "--out", str(tmp_path / "o")]) == 2
    assert "does not exist" in capsys.readouterr().err
    # an existing replay is never overwritten
    (tmp_path / "o3" / "replay_bag").mkdir(parents=True)
    assert cli(["replay", str(path), "--params", params, "--out", str(tmp_path / "o3")]) == 2
    assert "exists already" in capsys.readouterr().err
    # --video without imageio: a clear message before any work
    monkeypatch.setitem(sys.modules, "imageio.v2", None)
    monkeypatch.setitem(sys.modules, "imageio", None)
    assert cli(["replay", str(path), "--params", params, "--out", str(tmp_path / "o4"), "--video"]) == 2
    assert "pip install 'tissue_sim_ros[video]'" in capsys.readouterr().err
    assert not (tmp_path / "o4").exists()
    # fixed rate on a track shorter than one step
    short = write_bag(tmp_path / "short", [("/tool/pose", "geometry_msgs/msg/PoseStamped", 1,
                                            tool_msg("geometry_msgs/msg/PoseStamped", 5, 0.0, 0.0, 0.0))])
    assert cli(["replay", str(short), "--params", params, "--out", str(tmp_path / "o5"), "--mode", "fixed-rate"]) == 2
    assert "shorter than one step" in capsys.readouterr().err


def test_video_when_imageio_is_installed(tmp_path):
    pytest.importorskip("imageio.v2")
    pytest.importorskip("imageio_ffmpeg")
    path, _, _ = tool_bag(tmp_path / "in", n=12)
    assert cli(["replay", str(path), "--params", str(write_params(tmp_path)), "--out", str(tmp_path / "o"),
                "--no-progress", "--frame-every", "4", "--video", "--no-bag"]) == 0
    assert (tmp_path / "o" / "replay.mp4").stat().st_size > 0


def test_twist_with_another_stamp_is_not_used_per_message(tmp_path):
    """As the node in lock-step: a twist counts for a pose only with the pose's own stamp."""
    from bag_fixtures import twist_msg

    ty = "geometry_msgs/msg/PoseStamped"
    msgs = []
    poses = []
    for i in range(15):
        t = 1_000_000_000 + i * 20_000_000
        x, y = -0.3 + 0.012 * i, 0.15
        poses.append((x, y, 0.0))
        msgs.append(("/tool/twist", "geometry_msgs/msg/TwistStamped", t - 5_000_000, twist_msg(t - 5_000_000, 5.0, 0, 0)))
        msgs.append(("/tool/pose", ty, t, tool_msg(ty, t, x, y, 0.0)))
    path = write_bag(tmp_path / "in", msgs)
    params = small_params(tmp_path)
    track = read_tool_track(path, twist_topic="/tool/twist")
    assert (track.twist[:, 0] == 5.0).all()  # held for fixed-rate use
    result = replay(build_simulation(params), track, progress=False)
    np.testing.assert_array_equal(result.rollout.scene_total, _direct_energy(params, np.array(poses)))


def test_twist_received_after_its_pose_is_not_used_per_message(tmp_path):
    """As the node in lock-step, which steps when the pose arrives: a twist with the pose's stamp counts only if it
    was received (bag time) no later than the pose; one after it is too late. Before: used; after: derived."""
    from bag_fixtures import twist_msg

    ty = "geometry_msgs/msg/PoseStamped"
    msgs = []
    poses, twists = [], []
    for i in range(15):
        t = 1_000_000_000 + i * 20_000_000
        x, y = -0.3 + 0.012 * i, 0.15
        poses.append((x, y, 0.0))
        early = i % 2 == 0  # even samples: the twist comes first; odd: it comes 1 ms after its pose
        twists.append((0.6, 0.0, 0.0) if early else (np.nan, np.nan, np.nan))
        twist = ("/tool/twist", "geometry_msgs/msg/TwistStamped", t + (0 if early else 1_000_000),
                 twist_msg(t, 0.6, 0, 0))
        pose = ("/tool/pose", ty, t, tool_msg(ty, t, x, y, 0.0))
        msgs += [twist, pose] if early else [pose, twist]
    path = write_bag(tmp_path / "in", msgs)
    params = small_params(tmp_path)
    track = read_tool_track(path, twist_topic="/tool/twist", time_source="header")
    _, _, used = schedule(track, 0.01, "per-message")
    np.testing.assert_array_equal(np.isfinite(used[:, 0]), np.arange(15) % 2 == 0)
    result = replay(build_simulation(params), track, progress=False)
    np.testing.assert_array_equal(result.rollout.scene_total, _direct_energy(params, np.array(poses), np.array(twists)))


def test_replay_points_carry_signed_strain(tmp_path):
    """tissue/points' strain field is signed in replay as in the node (msg_docs/topics.md): compression < 0."""
    from tissue_sim_ros.core.physics.strain import vertex_strain
    from tissue_sim_ros.ros.bags import BagWriter
    from tissue_sim_ros.ros.replay import ReplayBagSink

    path, _, _ = tool_bag(tmp_path / "in", n=30, rate_hz=37.0)
    sim = build_simulation(small_params(tmp_path))
    with BagWriter(tmp_path / "out_bag", "mcap") as w:
        replay(sim, read_tool_track(path), sink=ReplayBagSink(w, sim), progress=False)
    with Bag(tmp_path / "out_bag") as bag:
        clouds = [m.decode_point_cloud(raw)[2] for _, _, _, raw in bag.messages(["/tissue/points"])]
    last = clouds[-1]
    expected = vertex_strain(sim.model, sim.state.particle_q)
    np.testing.assert_array_equal(last["strain"], expected.astype(np.float32))
    assert (last["strain"] < 0).any(), "the tool should compress some tissue, or the test checks little"


def test_sqlite3_output_and_points_every(tmp_path, capsys):
    path, _, _ = tool_bag(tmp_path / "in", n=12)
    params = str(write_params(tmp_path))
    assert cli(["replay", str(path), "--params", params, "--out", str(tmp_path / "o"), "--no-progress",
                "--frame-every", "-1", "--storage", "sqlite3", "--points-every", "5"]) == 0
    assert next((tmp_path / "o" / "replay_bag").glob("*.db3")).is_file()
    with Bag(tmp_path / "o" / "replay_bag") as bag:
        counts = bag.message_counts
    assert counts["/tissue/energy"] == 12 and counts["/tissue/points"] == 2
    assert cli(["replay", str(path), "--params", params, "--out", str(tmp_path / "o2"), "--points-every", "0"]) == 2
    assert "--points-every 0" in capsys.readouterr().err and not (tmp_path / "o2").exists()


def test_a_bag_with_the_nodes_outputs_replays_with_the_documented_command(tmp_path, capsys):
    """docs/bags.md's `tissue-sim replay run1 --out replay1`: run1 holds tool/pose and the node's own
    tool/applied_pose/twist, as every bag the project makes (was exit 2, "2 possible tool poses")."""
    path, times, poses = tool_bag(tmp_path / "in", n=12, twist=True)
    with Bag(path) as bag:
        raw = [(topic, ty, t, bytes(data)) for topic, ty, t, data in bag.messages()]
    ty_pose, ty_twist = "geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/TwistStamped"
    extra = [(f"{ns}/tool/applied_pose", ty_pose, int(t) + 5, tool_msg(ty_pose, int(t), 9.0, 9.0, 0.0))
             for ns in ("", "/left") for t in times]
    extra += [("/tool/applied_twist", ty_twist, int(t) + 5, m.encode_twist_stamped((0, 0), "world", 0.0, 0.0, 0.0))
              for t in times]
    node_bag = write_bag(tmp_path / "run1", raw + extra)
    out = tmp_path / "replay1"
    assert cli(["replay", str(node_bag), "--params", str(write_params(tmp_path)), "--out", str(out), "--no-progress",
                "--frame-every", "-1", "--no-bag"]) == 0, capsys.readouterr().err
    table = np.genfromtxt(out / "energy.csv", delimiter=",", names=True)
    np.testing.assert_array_equal(table["energy_total"], _direct_energy(small_params(tmp_path), poses))


def _strict_json(path, text=None):
    """replay.json (or ``text``) parsed as a strict parser would: NaN/Infinity literals refused."""
    import json

    def refuse(name):
        raise ValueError(f"{path}: non-standard JSON constant {name}")

    return json.loads(path.read_text() if text is None else text, parse_constant=refuse)


SUMMARY_KEYS = {"bag", "mode", "params", "params_file", "params_source", "tool_topic", "tool_type", "child_frame", "twist_topic",
                "time_source", "samples", "samples_read", "skipped", "bodies", "particles", "triangles", "dt",
                "steps", "wall_s", "real_time_factor", "energy_final"}
METADATA_KEYS = {"tissue_sim.source_bag", "tissue_sim.mode", "tissue_sim.tool_topic", "tissue_sim.params"}


def test_per_message_replay_writes_what_the_docs_list(tmp_path):
    """docs/bags.md: custom_data holds the source bag, mode, tool topic and every parameter; replay.json the
    topic, frame, samples, skips and mesh, as strict JSON (its "params" was null without --params)."""

    from tissue_sim_ros.core.config import resolve_config

    path, _, _ = tool_bag(tmp_path / "in", n=8, twist=True)
    out = tmp_path / "o"
    assert cli(["replay", str(path), "--set", f"mesh_file={small_params(tmp_path)['mesh_file']}", "--set",
                "boundary_y_top=0.29", "--set", "boundary_y_bottom=0.01", "--twist-topic", "/tool/twist",
                "--out", str(out), "--no-progress", "--frame-every", "-1"]) == 0
    summary = _strict_json(out / "replay.json")
    assert SUMMARY_KEYS <= set(summary)
    flat = resolve_config(overrides={"mesh_file": small_params(tmp_path)["mesh_file"], "boundary_y_top": 0.29,
                                     "boundary_y_bottom": 0.01}).flat()
    assert summary["params"] == {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in flat.items()}
    assert summary["params_file"] is None and math.isnan(flat["pin_y_top"])  # NaN written as null
    assert summary["twist_topic"] == "/tool/twist" and summary["samples"] == 8 and summary["particles"] > 0
    with Bag(out / "replay_bag") as bag:
        meta = bag.custom_data
    assert METADATA_KEYS <= set(meta) and meta["tissue_sim.twist_topic"] == "/tool/twist"
    recorded = _strict_json("tissue_sim.params", meta["tissue_sim.params"])  # unset bounds as null, not NaN
    assert recorded["mesh_file"] == flat["mesh_file"] and recorded["pin_y_top"] is None


def test_applied_replay_writes_what_the_docs_list(tmp_path, capsys):
    """--mode applied wrote only the mode and source bag into custom_data, and a replay.json without topic,
    frame, samples or skips, with bare NaN literals."""
    import json

    from tissue_sim_ros.core.config import resolve_config
    from tissue_sim_ros.ros import tool_applied as ta
    from tissue_sim_ros.ros.bags import BagWriter

    cfg = resolve_config(small_params(tmp_path))
    src = tmp_path / "node_bag"
    with BagWriter(src) as w:  # what the node's record_path writes: its applied tool and its parameters
        w.add_topic(ta.POSE_TOPIC, ta.POSE_TYPE)
        w.add_topic(ta.TWIST_TOPIC, ta.TWIST_TYPE)
        w.set_custom_data("tissue_sim.params", json.dumps(cfg.flat(), default=str))
        for k in range(1, 7):
            t = 1_000_000_000 + k * 10_000_000
            stamp = (t // 1_000_000_000, t % 1_000_000_000)
            if k > 2:  # no tool on the first two steps
                w.write(ta.POSE_TOPIC, ta.encode_applied_pose(stamp, "world", -0.3 + 0.01 * k, 0.15,
                                                              ta.PLANAR), t)
            w.write(ta.TWIST_TOPIC, ta.encode_applied_twist(stamp, "world", ToolTwist(1.0, 0.0, 0.0)), t)
    out = tmp_path / "o"
    assert cli(["replay", str(src), "--mode", "applied", "--out", str(out), "--no-progress",
                "--frame-every", "-1"]) == 0, capsys.readouterr().err
    summary = _strict_json(out / "replay.json")
    assert SUMMARY_KEYS <= set(summary)
    assert summary["tool_topic"] == "/tool/applied_pose" and summary["twist_topic"] == "/tool/applied_twist"
    assert summary["samples"] == summary["steps"] == 6 and summary["steps_with_tool"] == 4
    assert summary["skipped"] == {"repeated": 0, "out_of_order": 0, "non_finite": 0, "bad_quaternion": 0}
    assert summary["params"]["pin_y_top"] is None and summary["params"]["mesh_file"] == cfg.flat()["mesh_file"]
    with Bag(out / "replay_bag") as bag:
        meta = bag.custom_data
    assert METADATA_KEYS <= set(meta) and meta["tissue_sim.mode"] == "applied"
    assert meta["tissue_sim.tool_topic"] == "/tool/applied_pose"
    assert meta["tissue_sim.twist_topic"] == "/tool/applied_twist"
    assert json.loads(meta["tissue_sim.params"])["mesh_file"] == cfg.flat()["mesh_file"]


def test_applied_steps_pair_by_stamp_in_whatever_order_a_recorder_received_them(tmp_path):
    """A recorder in another process receives tool/applied_pose and tool/applied_twist on separate subscriptions:
    under load two poses came before their twists, and the replay then stepped two steps without a tool (the
    fresh-clone CI's demo replay missed the live energies from step 207). Each pose and jaw goes to the twist
    of its stamp; a stamp that recurs (a node that began following /clock) goes by arrival time."""
    from tissue_sim_ros.ros import tool_applied as ta
    from tissue_sim_ros.ros.bags import BagWriter

    def stamp(k: int) -> tuple[int, int]:
        return 1, (k % 6) * 10_000_000  # step 6 has step 0's stamp again

    # (topic, step) in the order received: step 0 without a tool; 2 and 3 with poses ahead of both twists;
    # step 4's twist before its pose; step 6 reuses step 0's stamp, with a pose and a jaw
    order = [("t", 0), ("j", 0), ("p", 1), ("j", 1), ("t", 1), ("p", 2), ("p", 3), ("t", 2), ("j", 2), ("t", 3),
             ("j", 3), ("t", 4), ("j", 4), ("p", 4), ("p", 5), ("t", 5), ("j", 5), ("p", 6), ("j", 6), ("t", 6)]
    src = tmp_path / "recorded"
    with BagWriter(src) as w:
        for topic, kind in ((ta.POSE_TOPIC, ta.POSE_TYPE), (ta.TWIST_TOPIC, ta.TWIST_TYPE), (ta.JAW_TOPIC, ta.JAW_TYPE)):
            w.add_topic(topic, kind)
        for n, (what, k) in enumerate(order):
            t = 5_000_000_000 + n * 1_000_000
            if what == "p":
                w.write(ta.POSE_TOPIC, ta.encode_applied_pose(stamp(k), "world", 0.01 * k, 0.2, ta.PLANAR), t)
            elif what == "j":
                w.write(ta.JAW_TOPIC, ta.encode_applied_jaw(stamp(k), "world", 0.1 * k), t)
            else:
                w.write(ta.TWIST_TOPIC, ta.encode_applied_twist(stamp(k), "world", ToolTwist(float(k), 0.0, 0.0)), t)
    steps = ta.read_applied_steps(src)
    assert [tw.vx for tw in steps.twists] == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    assert [None if p is None else round(p.x / 0.01) for p in steps.poses] == [None, 1, 2, 3, 4, 5, 6]
    assert steps.jaws is not None and [round(j / 0.1) for j in steps.jaws] == [0, 1, 2, 3, 4, 5, 6]


def test_plain_replay_steps_with_the_bags_own_parameters_or_says_it_falls_back(tmp_path, capsys):
    """A bag holding its simulator's parameters replays with them (no --params needed); one holding none falls
    back to the shipped defaults and says so, in one line and in replay.json (it used to be silent)."""
    import json

    from tissue_sim_ros.core.config import params_json, resolve_config
    from tissue_sim_ros.ros.bags import BagWriter

    src, _, _ = tool_bag(tmp_path / "plain", n=12)
    cfg = resolve_config(small_params(tmp_path, contact_model="projection", iterations=7))
    with_params = tmp_path / "with_params"
    with Bag(src) as bag, BagWriter(with_params) as w:
        for topic, msgtype, t, raw in bag.messages(["/tool/pose"]):
            w.add_topic(topic, msgtype)
            w.write(topic, bytes(raw), t)
        w.set_custom_data("tissue_sim.params", params_json(cfg))
    out = tmp_path / "o1"
    assert cli(["replay", str(with_params), "--out", str(out), "--no-progress", "--frame-every", "-1"]) == 0
    said = capsys.readouterr().out
    assert "parameters: the recording's own" in said
    summary = json.loads((out / "replay.json").read_text())
    assert summary["params_source"] == "bag"
    assert summary["params"]["iterations"] == 7 and summary["params"]["contact_model"] == "projection"
    assert summary["params"]["mesh_file"] == cfg.flat()["mesh_file"]

    out = tmp_path / "o2"  # a robot's bag: no simulator parameters in it
    assert cli(["replay", str(src), "--out", str(out), "--no-progress", "--frame-every", "-1", "--no-bag"]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("parameters:")]
    assert lines == ["parameters: the shipped defaults (config/tissue_sim.yaml): the bag holds no simulator "
                     "parameters, so these may not be the physics it ran with; give --params FILE to choose"]
    assert json.loads((out / "replay.json").read_text())["params_source"] == "shipped defaults"

    out = tmp_path / "o3"  # the command line wins over what the bag holds
    assert cli(["replay", str(with_params), "--params", str(write_params(tmp_path)), "--out", str(out),
                "--no-progress", "--frame-every", "-1", "--no-bag"]) == 0
    assert json.loads((out / "replay.json").read_text())["params_source"] == "command line"
    assert json.loads((out / "replay.json").read_text())["params"]["iterations"] == 10
