"""tissue_sim_ros: 2D soft-tissue simulation under a surgical tool, with a ROS 2 Jazzy node.

The simulator is :mod:`tissue_sim_ros.core` (no ROS); the node and message
conversion are :mod:`tissue_sim_ros.ros`; pictures are :mod:`tissue_sim_ros.render`;
the ``tissue-sim`` command is :mod:`tissue_sim_ros.cli`, which runs the
:mod:`tissue_sim_ros.experiments` and :mod:`tissue_sim_ros.bench`.
"""
from . import _moved

__version__ = "0.1.0"

_moved.install()
