"""tissue_sim_ros: 2D soft-tissue simulation under a surgical tool, with a ROS 2 Jazzy node.

The simulator is :mod:`tissue_sim_ros.core` (no ROS); the node and message
conversion are :mod:`tissue_sim_ros.ros`.
"""

__version__ = "0.1.0"
