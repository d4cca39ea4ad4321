"""The ROS 2 layer: the only place that imports rclpy or message packages.

The node (``tissue_sim_node``: tool poses in, a stepped :class:`~tissue_sim_ros.core.sim.simulation.Simulation`,
mesh, points, energy, wrench and diagnostics out), the tool driver, the planner service, the grasp
controller's node (``tissue_controller``),
NumPy <-> CDR message conversion (``messages``), QoS profiles (``qos``), and rosbag2 bags
through the ``rosbags`` library (``bags``, ``record``, ``play``, ``replay``). It converts
messages and calls the core; it may import :mod:`tissue_sim_ros.core` and
:mod:`tissue_sim_ros.render`, never the experiments, benchmarks or CLI.
"""
