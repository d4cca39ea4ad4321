"""When and where the tool's inputs are: ROS stamps as integer (sec, nsec) pairs (``stamps``),
a transform tree by time (``frames``), the phase lock that steps on a robot's clock
(``phase_lock``) and the tool's trajectories, their presets and files (``trajectories``).
Pure Python and NumPy; it may import :mod:`..contact` for the tool's types.
"""
