"""Recording inside the node (parameter ``record_path``): every message in and out, into a rosbag2 bag.

A recorder beside the node (``tissue-sim record``) receives what DDS delivers
and can fall behind; recording in the node writes the very bytes it publishes
(and the tool messages it takes in), so the bag holds every step. Outputs are
written from their serialized CDR bytes, never re-encoded; the tool inputs
and diagnostics, which arrive or are built as message objects, are serialized
once with rclpy.

Each message is written at the system clock's time of writing (made strictly
increasing), not the node's clock: a node that follows ``/clock`` (``tissue-sim
play``) jumps from the system's time to the bag's and back, and a bag reader
sorts by these times, so they must keep the order in which the node took its
inputs and stepped. The messages' own header stamps carry the node's clock.
"""
from __future__ import annotations

import os
import threading
import time
from typing import Any

from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy
from rclpy.serialization import serialize_message

from ...core.config import Config, params_json
from ...core.errors import InputError
from ..bags import BagWriter


def _type_name(msg_class: Any) -> str:
    """'pkg/msg/Type' of a generated message class."""
    module = msg_class.__module__.split(".")  # e.g. visualization_msgs.msg._marker_array
    return f"{module[0]}/msg/{msg_class.__name__}"


class RecordingPublisher:
    """A publisher that also writes what it publishes into the node's bag."""

    def __init__(self, publisher: Publisher, recorder: "NodeRecorder") -> None:
        self._publisher = publisher
        self._recorder = recorder
        self.topic_name = publisher.topic_name
        recorder.add(publisher.topic_name, publisher.msg_type, publisher.qos_profile)

    def publish(self, msg: Any) -> None:
        self._publisher.publish(msg)
        self._recorder.write(self.topic_name, msg)

    def __getattr__(self, name: str) -> Any:  # get_subscription_count, destroy, ...
        return getattr(self._publisher, name)


class NodeRecorder:
    """Owns the node's bag: topics with their types and QoS, written at the system time of writing, in order."""

    def __init__(self, path: str, storage: str) -> None:
        self.writer = BagWriter(path, storage, hold_signals=False)
        self.path = path
        self._lock = threading.Lock()  # the step, marker and executor threads write
        self._last_ns = 0

    def add(self, topic: str, msg_class: Any, qos: Any) -> None:
        self.writer.add_topic(topic, _type_name(msg_class),
                              reliable=qos.reliability == ReliabilityPolicy.RELIABLE,
                              transient_local=qos.durability == DurabilityPolicy.TRANSIENT_LOCAL, depth=qos.depth)

    def wrap(self, publisher: Publisher) -> RecordingPublisher:
        return RecordingPublisher(publisher, self)

    def add_subscriptions(self, subscriptions: Any) -> None:
        """Record what these subscriptions receive (their callbacks call :meth:`write`)."""
        for sub in subscriptions:
            self.add(sub.topic_name, sub.msg_type, sub.qos_profile)

    def write(self, topic: str, msg: Any) -> None:
        if self.writer.closed:
            return
        data = msg if isinstance(msg, (bytes, bytearray, memoryview)) else serialize_message(msg)
        with self._lock:
            self._last_ns = max(time.time_ns(), self._last_ns + 1)
            self.writer.write(topic, data, self._last_ns)

    def close(self) -> None:
        self.writer.close()


def start_recording(path: str, storage: str, config: Config) -> NodeRecorder:
    """A new bag at ``path`` holding the node's resolved parameters (``tissue_sim.params``): what ``tissue-sim
    replay --mode applied`` needs to rebuild this very Simulation from the bag alone, written when the recording
    starts. The node then wraps its publishers (:meth:`NodeRecorder.wrap`) and adds its subscriptions."""
    if os.path.exists(path):
        raise InputError(f"parameter record_path={path!r}: that path exists; expected a new bag directory")
    recorder = NodeRecorder(path, storage)
    # durable: in the storage file from the start, so a node killed hard (SIGKILL, a crash) leaves them too and
    # `tissue-sim record --recover` carries them into the bag it writes
    recorder.writer.set_custom_data("tissue_sim.params", params_json(config), durable=True)
    return recorder
