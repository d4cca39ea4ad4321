"""The soak's stall reader (`tissue_sim_ros.bench.stall_reader`): it subscribes reliably to every topic a node
publishes, says when it heard each per-step one, survives a SIGSTOP and ends cleanly on SIGTERM."""
from __future__ import annotations

import signal
import sys

from tissue_sim_ros.bench.stall_reader import PER_STEP, message_class

from ros_env import RosClient  # noqa: F401  (fixtures: ros_client, start_process)


def test_message_class_resolves_ros_type_names() -> None:
    from sensor_msgs.msg import PointCloud2  # noqa: PLC0415

    assert message_class("sensor_msgs/msg/PointCloud2") is PointCloud2


def test_the_reader_matches_every_per_step_topic_and_ends_cleanly_after_a_stop(ros_client, start_process) -> None:
    from diagnostic_msgs.msg import DiagnosticArray  # noqa: PLC0415
    from geometry_msgs.msg import PoseStamped, WrenchStamped  # noqa: PLC0415
    from sensor_msgs.msg import PointCloud2  # noqa: PLC0415
    from std_msgs.msg import Float64  # noqa: PLC0415
    from visualization_msgs.msg import MarkerArray  # noqa: PLC0415

    from tissue_sim_ros.ros import qos  # noqa: PLC0415

    node = ros_client.node
    types = {"tissue/points": PointCloud2, "tissue/markers": MarkerArray, "tool/wrench": WrenchStamped,
             "tool/applied_pose": PoseStamped, "tissue/energy": Float64}
    assert set(types) == set(PER_STEP)
    pubs = {name: node.create_publisher(kind, name, qos.state_stream()) for name, kind in types.items()}
    pubs["/diagnostics"] = node.create_publisher(DiagnosticArray, "/diagnostics", qos.diagnostics())
    timer = node.create_timer(0.01, lambda: [p.publish(types.get(n, DiagnosticArray)()) for n, p in pubs.items()])
    try:
        reader = start_process([sys.executable, "-m", "tissue_sim_ros.bench.stall_reader", node.get_name()],
                               name="stall_reader")
        ros_client.spin_until(lambda: "ready" in reader.output(), 60, reader, "the reader to hear every topic")
        # every topic of the node matched by the reader, reliable (a best-effort reader would not hold the writer)
        assert all(p.get_subscription_count() >= 1 for p in pubs.values())
        assert f"ready {len(pubs)}" in reader.output(), reader.output()
        reader.proc.send_signal(signal.SIGSTOP)
        ros_client.spin_for(0.3)
        reader.proc.send_signal(signal.SIGCONT)
        ros_client.spin_for(0.3)
        assert reader.stop(signal.SIGTERM, timeout=10) == 0, reader.output()
        assert "Traceback" not in reader.output()  # rclpy's own handler once ended it in an RCLError
    finally:
        node.destroy_timer(timer)
        for p in pubs.values():
            node.destroy_publisher(p)
