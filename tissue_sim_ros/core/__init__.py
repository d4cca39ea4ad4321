"""The simulator as a plain library (numpy, numba, python-fcl, OpenCV): never imports rclpy."""
