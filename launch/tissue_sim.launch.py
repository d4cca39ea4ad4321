"""Launch the tissue simulation, optionally with the scripted tool driver and RViz.

    ros2 launch tissue_sim_ros tissue_sim.launch.py
    ros2 launch tissue_sim_ros tissue_sim.launch.py driver:=true rviz:=true
    ros2 launch tissue_sim_ros tissue_sim.launch.py namespace:=left params_file:=/path/to/scene.yaml

Needs a full ROS 2 Jazzy install (``ros2 launch`` is not on PyPI); without one,
start the console scripts directly: ``tissue_sim_node --ros-args --params-file
config/tissue_sim.yaml`` and ``tool_driver``.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription


def generate_launch_description() -> LaunchDescription:
    share = get_package_share_directory("tissue_sim_ros")
    namespace = LaunchConfiguration("namespace")
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value=os.path.join(share, "config", "tissue_sim.yaml"),
                              description="Parameter file of tissue_sim_node (section tissue_sim_node or /**)."),
        DeclareLaunchArgument("namespace", default_value="", description="Namespace of both nodes."),
        DeclareLaunchArgument("use_sim_time", default_value="false", description="Follow /clock (bag replay)."),
        DeclareLaunchArgument("driver", default_value="false", description="Also start the scripted tool_driver."),
        DeclareLaunchArgument("rviz", default_value="false", description="Also start RViz with config/tissue_sim.rviz."),
        Node(package="tissue_sim_ros", executable="tissue_sim_node", name="tissue_sim_node", namespace=namespace,
             parameters=[LaunchConfiguration("params_file"), {"use_sim_time": LaunchConfiguration("use_sim_time")}],
             output="screen", emulate_tty=True),
        Node(package="tissue_sim_ros", executable="tool_driver", name="tool_driver", namespace=namespace,
             parameters=[{"use_sim_time": LaunchConfiguration("use_sim_time")}],
             output="screen", condition=IfCondition(LaunchConfiguration("driver"))),
        Node(package="rviz2", executable="rviz2", name="rviz2",
             arguments=["-d", os.path.join(share, "config", "tissue_sim.rviz")],
             condition=IfCondition(LaunchConfiguration("rviz"))),
    ])
