"""Where two paths must agree: one parameter file through the node and through the CLI.

The node (in-process, no graph needed) and ``tissue-sim experiment a`` read the
same parameter file; they must resolve the same configuration and take
bit-identical first 100 steps of experiment a.
"""
from __future__ import annotations

import csv
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")

import rclpy  # noqa: E402
from geometry_msgs.msg import PoseStamped  # noqa: E402
from rclpy.context import Context  # noqa: E402

from tissue_sim_ros.core.config import resolve_config  # noqa: E402
from tissue_sim_ros.core.timing.trajectories import experiment_a  # noqa: E402
from tissue_sim_ros.ros.node import TissueSimNode  # noqa: E402

STEPS = 100
PARAMS = """tissue_sim_node:
  ros__parameters:
    method: xpbd_substep
    contact_model: projection
    stiffness_spring: 40
    lock_step: true
"""


def _node(ros_env: dict[str, str], args: list[str]) -> tuple[TissueSimNode, Context]:
    context = Context()
    rclpy.init(context=context, domain_id=int(ros_env["ROS_DOMAIN_ID"]), args=["--ros-args", *args])
    return TissueSimNode(context=context), context


def _pose_msg(k: int, x: float, y: float, yaw: float) -> PoseStamped:
    msg = PoseStamped()
    msg.header.frame_id = "world"
    msg.header.stamp.sec, msg.header.stamp.nanosec = 100 + k // 100, (k % 100) * 10_000_000
    msg.pose.position.x, msg.pose.position.y = x, y
    msg.pose.orientation.z, msg.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
    return msg


def test_node_and_cli_resolve_one_configuration(ros_env: dict[str, str], tmp_path: Path) -> None:
    path = tmp_path / "params.yaml"
    path.write_text(PARAMS)
    node, context = _node(ros_env, ["--params-file", str(path)])
    try:
        cli = subprocess.run([sys.executable, "-m", "tissue_sim_ros.cli", "config", "--params", str(path)],
                             capture_output=True, text=True, check=True).stdout
        printed = tmp_path / "printed.yaml"
        printed.write_text(cli)
        assert node.config.changed(resolve_config(params_file=printed)) == []
        assert node.config.changed(resolve_config(params_file=path)) == []
        p = node.sim.params
        assert (p.method, p.substeps, p.iterations, p.stiffness_spring) == ("xpbd", 30, 1, 40.0)
        assert node.get_parameter("method").value == "xpbd" and node.get_parameter("substeps").value == 30
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_set_method_alias_on_the_command_line_matches_the_node(ros_env: dict[str, str]) -> None:
    """The issue's check: `tissue-sim config --set method=xpbd_substep` and `-p method:=xpbd_substep` agree."""
    node, context = _node(ros_env, ["-p", "method:=xpbd_substep"])
    try:
        cli = resolve_config({"method": "xpbd_substep"}, source="--set").sim
        assert (node.sim.params.substeps, node.sim.params.iterations) == (cli.substeps, cli.iterations) == (30, 1)
        # an alias set at run time resolves the same way
        node.set_parameters([rclpy.parameter.Parameter("method", value="xpbd_jacobi")])
        assert (node.sim.params.method, node.sim.params.scheme) == ("xpbd", "jacobi")
        assert node.get_parameter("method").value == "xpbd" and node.get_parameter("scheme").value == "jacobi"
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_lock_step_node_and_experiment_a_take_identical_steps(ros_env: dict[str, str], tmp_path: Path) -> None:
    path = tmp_path / "params.yaml"
    path.write_text(PARAMS)
    out = tmp_path / "cli"
    subprocess.run([sys.executable, "-m", "tissue_sim_ros.cli", "experiment", "a", "--params", str(path),
                    "--steps", str(STEPS), "--contact", "projection", "--no-progress", "--out", str(out)],
                   check=True, capture_output=True, text=True)
    with open(out / "experiment_a_projection_energy.csv") as fh:
        cli_energy = np.array([float(r["energy_total"]) for r in csv.DictReader(fh)])
    node, context = _node(ros_env, ["--params-file", str(path)])
    try:
        traj = experiment_a(node.sim.tool, node.sim.params.dt, steps=STEPS)
        energies = []
        for k, (pose, _twist) in enumerate(traj.steps(node.sim.params.dt)):
            node.inputs.on_pose(_pose_msg(k, pose.x, pose.y, pose.yaw))
            energies.append(node.last_report.energy.scene_total)
        assert node.sim.step_count == STEPS
        np.testing.assert_array_equal(np.array(energies), cli_energy)
        assert np.ptp(cli_energy) > 0 and np.all(np.isfinite(cli_energy))
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
