"""Bags written by version 0.1's bag writer (``test/data/bags_0_1``) still read, recover and replay.

The fixtures were written once by the code before ``ros/bags`` became a package on the ``mcap`` library
(commit 6b8baf7): a node's recording of the retract scene's grasp (``tool/applied_*`` and the node's
parameters as durable custom data) as MCAP and as sqlite3, the same recording killed halfway (an MCAP cut
after a flush, no ``metadata.yaml``), and a robot's recording of ``tool/pose`` and ``tool/twist`` (MCAP).
Replaying them now must give what the library gives when stepped directly with what the bags hold.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from tissue_sim_ros.cli import main as cli
from tissue_sim_ros.core.config import params_from_json, resolve_config
from tissue_sim_ros.core.contact.tool import ToolPose
from tissue_sim_ros.core.resources import scene_params_file
from tissue_sim_ros.core.sim.simulation import Simulation
from tissue_sim_ros.ros.bags import Bag
from tissue_sim_ros.ros.tool_applied import read_applied_steps

from bag_fixtures import TS

OLD = Path(__file__).resolve().parent / "data" / "bags_0_1"
STEPS = 75


def _replay(bag: Path, out: Path, *args: str) -> list[str]:
    assert cli(["replay", str(bag), "--out", str(out), "--no-progress", "--frame-every", "-1", *args]) == 0
    return (out / "energy.csv").read_text().splitlines()


def _bag_messages(path: Path) -> list[tuple[str, int, bytes]]:
    with Bag(path) as bag:
        return [(topic, t, bytes(raw)) for topic, _, t, raw in bag.messages()]


@pytest.mark.parametrize("name", ["node_mcap", "node_sqlite3"])
def test_an_old_recording_holds_its_parameters_and_steps(name):
    with Bag(OLD / name) as bag:
        params = params_from_json(bag.custom_data["tissue_sim.params"])
        assert bag.message_counts == {"/tool/applied_pose": STEPS, "/tool/applied_jaw": STEPS,
                                      "/tool/applied_twist": STEPS}
    assert params["tool_shape"] == "grasper" and params["image"] == "scenes/retract.png"
    steps = read_applied_steps(OLD / name)
    assert steps.n == STEPS and all(p is not None for p in steps.poses) and steps.jaws is not None
    assert np.all(np.diff(steps.t_ns) == 10_000_000)


def test_an_old_recording_replays_as_the_library_steps_it(tmp_path):
    """``replay --mode applied`` of the MCAP and the sqlite3 recording: the same bytes out, and the energy the
    library gives stepped directly with the recorded steps."""
    lines = _replay(OLD / "node_mcap", tmp_path / "a", "--mode", "applied")
    assert _replay(OLD / "node_sqlite3", tmp_path / "b", "--mode", "applied") == lines
    assert _bag_messages(tmp_path / "a" / "replay_bag") == _bag_messages(tmp_path / "b" / "replay_bag")
    with Bag(OLD / "node_mcap") as bag:
        cfg = resolve_config(overrides=params_from_json(bag.custom_data["tissue_sim.params"]))
    sim = Simulation.from_config(cfg)
    direct = [sim.step(pose, twist, jaw=jaw).energy.scene_total
              for pose, twist, jaw in read_applied_steps(OLD / "node_mcap").items()]
    replayed = [float(row.split(",")[2]) for row in lines[1:]]
    header = lines[0].split(",")
    assert header[2] == "energy_total", header
    np.testing.assert_array_equal(replayed, direct)


def test_an_old_killed_recording_recovers_and_replays_as_the_first_half(tmp_path):
    """The recording killed after its flush at step 38: record --recover keeps those 38 steps and the node's
    parameters, and their replay is the first 38 rows of the whole recording's."""
    assert not (OLD / "node_killed" / "metadata.yaml").exists()
    assert cli(["record", "--recover", str(OLD / "node_killed"), "-o", str(tmp_path / "fixed")]) == 0
    with Bag(tmp_path / "fixed") as bag:
        assert "tissue_sim.params" in bag.custom_data
        assert bag.message_counts["/tool/applied_twist"] == 38
    part = _replay(tmp_path / "fixed", tmp_path / "a", "--mode", "applied")
    whole = _replay(OLD / "node_mcap", tmp_path / "b", "--mode", "applied")
    assert len(part) == 39 and part == whole[:39]


def test_an_old_outside_recording_replays_per_message_as_the_library_steps_its_poses(tmp_path):
    lines = _replay(OLD / "outside", tmp_path / "o", "--params", str(scene_params_file("retract")))
    from rosbags.rosbag2 import Reader  # noqa: PLC0415  (the poses read by rosbags alone, as a reference)

    with Reader(OLD / "outside") as reader:
        conns = [c for c in reader.connections if c.topic == "/tool/pose"]
        poses = [TS.deserialize_cdr(raw, c.msgtype).pose for c, _, raw in reader.messages(connections=conns)]
    sim = Simulation.from_config(resolve_config(params_file=[scene_params_file("retract")]))
    direct = [sim.step(ToolPose(p.position.x, p.position.y,
                                2.0 * math.atan2(p.orientation.z, p.orientation.w))).energy.scene_total
              for p in poses]
    assert len(direct) == 60
    np.testing.assert_allclose([float(row.split(",")[2]) for row in lines[1:]], direct, rtol=0, atol=0)
