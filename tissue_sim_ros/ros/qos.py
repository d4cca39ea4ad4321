"""The QoS profiles of the node's topics, chosen once here and passed in.

* Tool input (``tool/pose``, ``tool/twist``): BEST_EFFORT subscriptions, so
  both reliable and best-effort publishers match (a best-effort reader accepts
  either; a reliable reader would refuse a best-effort writer). Keep-last: the
  timer uses the newest pose; in lock-step every pose is a step, so the queue
  is deep enough for a bag replayed at speed.
* Per-step output (``tissue/markers``, ``tissue/points``, ``tool/wrench``):
  RELIABLE keep-last (100; markers 2), VOLATILE. Reliable writers match both reliable readers
  (RViz's default) and best-effort readers (plotters, sensor-data QoS);
  keep-last means a slow reader only ever gets the newest states, the
  simulation never waits for it.
* Energy (``tissue/energy*``): RELIABLE, deeper history, so a plot gets every
  step.
* Rest mesh (``tissue/rest_mesh``): RELIABLE, TRANSIENT_LOCAL, depth 1 - latched
  like ``/tf_static``: a late subscriber still gets the one message.
* Diagnostics: the ROS default (reliable, depth 10), as diagnostic_aggregator expects.
* The controller's readers (``tissue_controller``: points, measured tool pose and jaw): best effort,
  keep last 10, like the tool input: they match any writer and the controller uses the newest.
"""
from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy


def tool_input(lock_step: bool = False) -> QoSProfile:
    """Subscriptions to tool/pose and tool/twist: best effort, keep last 10 (1000 in lock-step)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000 if lock_step else 10,
                      reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)


def state_stream(depth: int = 100) -> QoSProfile:
    """Points, wrench, applied tool (keep last 100, as energy) and markers (keep last 2): reliable, volatile.

    A reliable writer resends only what its history still holds, so a short history loses
    point clouds to a recorder on a busy machine. A second of points (55 kB each at 5k triangles: 5.5 MB at most, which
    Fast DDS allocates once a reader first falls that far behind and then keeps: msg_docs/topics.md)
    never blocks the step (keep-last); markers (1 MB) keep 2.
    """
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)


#: History depth of tissue/markers (about 1 MB each at 5k triangles): a slow reader gets the newest states.
MARKER_DEPTH = 2


def energy() -> QoSProfile:
    """Energy totals and terms: reliable, keep last 100, volatile."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                      reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)


def latched() -> QoSProfile:
    """Published once (rest mesh): reliable, transient local, keep last 1."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                      reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def diagnostics() -> QoSProfile:
    """/diagnostics: reliable, keep last 10, volatile."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                      reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)


def tool_output() -> QoSProfile:
    """The tool driver's tool/pose and tool/twist publishers: reliable (matches any reader), keep last 100, so
    a recorder on a busy machine gets every pose (a history of 10 lost some)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                      reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)


def observation_input() -> QoSProfile:
    """The controller's readers of points, measured tool pose and jaw: best effort (matches reliable and
    best-effort writers, e.g. a tracker's sensor-data QoS), keep last 10: it uses the newest of each."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                      reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)
