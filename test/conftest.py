"""Test-wide fixtures: the ROS graph helpers of ``ros_env`` (isolated domain, processes, a client)."""
pytest_plugins = ("ros_env",)
