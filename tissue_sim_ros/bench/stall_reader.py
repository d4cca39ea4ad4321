"""A reliable reader of every topic the node publishes, for ``bench node --soak`` to stop (SIGSTOP) for a while.

A reliable writer keeps what its readers have not acknowledged, up to its history depth (keep-last; the step
never waits). Fast DDS takes each kept sample's buffer from a pool that grows to the most samples ever held at
once and keeps them: the node's points history (depth 100, 55 kB a cloud at 5k triangles) reaches 5.5 MB the
first time a reader, a recorder on a loaded machine say, falls 1 s behind. That is a bounded high-water mark, not
a leak, but a soak that only meets it half an hour in reads it as growth (seen: +5 MiB in one 5 s sample at
405, 710 and 800 s in three soaks; heaptrack put it in ``TopicPayloadPool::do_get_payload`` under
``rcl_publish_serialized_message``). So the soak's warm-up runs this reader, stops it for longer than the
deepest history lasts and lets it go: every pool is then at its ceiling before the growth is measured.

Run as ``python -m tissue_sim_ros.bench.stall_reader NODE_NAME`` in the node's ROS domain (environment): it
subscribes (reliable, raw bytes, nothing deserialized) to every topic ``NODE_NAME`` publishes, prints
``ready N`` once a message came on each of the per-step ones, then spins until killed.
"""
from __future__ import annotations

import signal
import sys
import time

#: Topics that carry one message per step (or per marker tick): the reader waits for one of each.
PER_STEP = ("tissue/points", "tissue/markers", "tool/wrench", "tool/applied_pose", "tissue/energy")


def _interrupt(_signum: int, _frame: object) -> None:
    raise KeyboardInterrupt


def message_class(type_name: str) -> type:
    """The message class of a ROS type name (``pkg/msg/Name``)."""
    import importlib  # noqa: PLC0415

    package, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


def main(argv: list[str] | None = None) -> int:
    import rclpy  # noqa: PLC0415
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: PLC0415
    from rclpy.signals import SignalHandlerOptions  # noqa: PLC0415

    args = sys.argv[1:] if argv is None else argv
    target = args[0] if args else "tissue_sim_node"
    # our own handlers: rclpy's shut the context down under a spin, which then raised RCLError (seen in a
    # soak's log); SIGTERM and SIGINT now leave the loop and the node is destroyed in order
    rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGINT, _interrupt)
    node = rclpy.create_node("bench_stall_reader")
    profile = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
    seen: set[str] = set()
    subscribed: set[str] = set()

    def callback(name: str):
        return lambda _data: seen.add(name)

    deadline = time.monotonic() + 60.0
    try:
        while time.monotonic() < deadline:
            try:
                topics = node.get_publisher_names_and_types_by_node(target, "/")
            except Exception:  # noqa: BLE001  the node not discovered yet
                topics = []
            for name, types in topics:
                if name not in subscribed and not name.startswith("/rosout") and not name.startswith("/parameter"):
                    node.create_subscription(message_class(types[0]), name, callback(name.lstrip("/")), profile,
                                             raw=True)
                    subscribed.add(name)
            if all(t in seen for t in PER_STEP):
                print(f"ready {len(subscribed)}", flush=True)
                break
            rclpy.spin_once(node, timeout_sec=0.05)
        else:
            print(f"not ready: subscribed {sorted(subscribed)}, heard {sorted(seen)}", flush=True)
            return 1
        while True:
            rclpy.spin_once(node, timeout_sec=0.1)
    except KeyboardInterrupt:  # SIGTERM or SIGINT (_interrupt)
        return 0
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    raise SystemExit(main())
