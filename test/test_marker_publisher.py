"""The marker worker: newest state only, never blocking the submitter, and at a lower priority."""
from __future__ import annotations

import os
import sys
import threading
from typing import Any

import pytest

from tissue_sim_ros.ros.marker_publisher import MarkerPublisher


class _Snap:
    """Stands in for a MarkerSnapshot: encode() returns its label, optionally waiting for a gate."""

    def __init__(self, label: bytes, gate: threading.Event | None = None) -> None:
        self.label, self.gate = label, gate

    def encode(self) -> bytes:
        if self.gate is not None:
            assert self.gate.wait(5.0)
        return self.label


def test_newest_state_replaces_the_waiting_one() -> None:
    out: list[bytes] = []
    gate = threading.Event()
    w = MarkerPublisher(out.append)
    try:
        w.submit(_Snap(b"first", gate))  # the worker takes it and waits at the gate
        assert not w.flush(0.2)
        for k in range(5):  # these queue behind it: only the newest survives
            w.submit(_Snap(b"s%d" % k))
        gate.set()
        assert w.flush(5.0)
    finally:
        w.close()
    assert out == [b"first", b"s4"]
    assert (w.submitted, w.published, w.skipped, w.errors) == (6, 2, 4, 0)


def test_a_failing_encode_is_counted_and_the_worker_goes_on() -> None:
    out: list[bytes] = []
    errors: list[BaseException] = []

    class _Bad:
        def encode(self) -> bytes:
            raise ValueError("bad snapshot")

    w = MarkerPublisher(out.append, on_error=errors.append)
    try:
        w.submit(_Bad())
        assert w.flush(5.0)
        w.submit(_Snap(b"good"))
        assert w.flush(5.0)
    finally:
        w.close()
    assert out == [b"good"] and w.errors == 1 and "bad snapshot" in str(errors[0])


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread niceness is Linux's")
@pytest.mark.parametrize("nice", [0, 7])
def test_the_worker_thread_alone_runs_at_the_added_niceness(nice: int) -> None:
    own = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    errors: list[BaseException] = []
    w = MarkerPublisher(lambda _data: None, on_error=errors.append, nice=nice)
    try:
        w.submit(_Snap(b"x"))
        assert w.flush(5.0)
    finally:
        w.close()
    assert not errors
    assert w.niceness == min(own + nice, 19)
    # the caller's thread (the node's step thread) keeps its own
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == own


# ----------------------------------------------------------------------------- GIL-free publishing (raw_publish.py)

def test_the_gil_free_publisher_was_checked_against_the_installed_rclpy() -> None:
    """The ctypes call assumes rclpy's publisher handle and rcl's serialized-message layout of the releases it
    names: a new rclpy fails here (check the layout, then add its version to RCLPY_CHECKED)."""
    pytest.importorskip("rclpy")
    from importlib.metadata import version  # noqa: PLC0415

    from tissue_sim_ros.ros.raw_publish import RCLPY_CHECKED, rclpy_checked  # noqa: PLC0415

    assert rclpy_checked(), f"rclpy {version('rclpy')} is not one of {RCLPY_CHECKED}"


def test_gil_free_publisher_delivers_the_same_bytes(ros_client: Any) -> None:
    """The ctypes path hands rcl the caller's bytes: a subscriber receives them unchanged, large and small."""
    pytest.importorskip("rclpy")
    from rclpy.serialization import serialize_message  # noqa: PLC0415
    from visualization_msgs.msg import Marker, MarkerArray  # noqa: PLC0415

    from tissue_sim_ros.ros import qos  # noqa: PLC0415
    from tissue_sim_ros.ros.raw_publish import GilFreePublisher  # noqa: PLC0415

    profile = qos.state_stream(qos.MARKER_DEPTH)
    pub = GilFreePublisher(ros_client.node.create_publisher(MarkerArray, "gil_free_markers", profile))
    assert pub.gil_free, "librcl not found in this process: the node would publish markers holding the GIL"
    assert pub.topic_name == "/gil_free_markers"  # the rest is the rclpy publisher's
    sub = ros_client.raw_subscription(MarkerArray, "gil_free_markers", profile)
    ros_client.wait_for_subscriber(pub, 10.0)

    big = MarkerArray(markers=[Marker(id=k, ns="big") for k in range(4000)])  # ~ 0.5 MB
    sent = [serialize_message(MarkerArray(markers=[Marker(id=7, ns="tissue")])), serialize_message(big)]
    for data in sent:
        pub.publish(data)
    ros_client.spin_until(lambda: len(sub.messages) >= 2, 10.0, what="the two arrays")
    assert [bytes(m) for m in sub.messages[:2]] == sent
    # a message object goes through rclpy's publish unchanged
    pub.publish(MarkerArray(markers=[Marker(id=3)]))
    ros_client.spin_until(lambda: len(sub.messages) >= 3, 10.0, what="the message object")
    assert bytes(sub.messages[2]) == serialize_message(MarkerArray(markers=[Marker(id=3)]))
