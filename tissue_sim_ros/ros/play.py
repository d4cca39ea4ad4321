"""Publishing a bag's tool topics into a live ROS graph with the recorded timing: the library behind ``tissue-sim play``.

The bytes stored in the bag are published as they are (rclpy's
``Publisher.publish`` accepts serialized messages), so nothing is decoded or
re-encoded and header stamps stay as recorded. By default the tool topics are
played: every topic of a pose or twist type (PoseStamped, Pose,
TransformStamped, TFMessage, TwistStamped, Twist...) except the node's own
outputs ``tool/applied_pose`` and ``tool/applied_twist`` (in any namespace: what
a node stepped with, which a node running now publishes itself); ``--topics``
chooses others, those included. ``--remap FROM:=TO`` publishes a played topic
under another name (a robot's ``/ee_pose`` as the node's ``/tool/pose``); a
FROM that is not played is refused.

Timing: message i goes out at start + (t_i - t_0) / rate of the bag's receive
times; ``--rate 2`` plays twice as fast. ``--loop`` repeats. By default play
publishes ``/clock`` (rosgraph_msgs/Clock) at ``--clock-rate`` Hz with the bag
time (continuing across loops; ``--no-clock``: none), so the recorded stamps
are current on that clock: ``tissue_sim_node`` follows it by itself
(parameter ``follow_clock``), other nodes with ``use_sim_time:=true``. Before
starting, play waits up to ``--wait`` seconds for every played topic to have
``--min-subscribers`` subscribers, and every subscription the graph already
shows on it matched, then up to 2 s more for a ``/clock``
subscriber (a node that follows /clock subscribes within about 0.5 s), so the
first messages are not lost.

QoS: each topic is published with the QoS its publishers offered when it was
recorded (rosbag2 keeps it in the bag's metadata, as ``ros2 bag play`` uses
it): a latched ``/tf_static`` is played latched (TRANSIENT_LOCAL), so a node that
subscribes to it latched receives it; a VOLATILE publisher would never match.
"""
from __future__ import annotations

import math
import signal
import threading
import time
from pathlib import Path
from typing import Any

from ..core.errors import InputError
from ..core.timing.stamps import ns_from_seconds, stamp_from_ns
from .bags import POSE_TYPES, TWIST_TYPES, Bag, is_jaw_topic, is_node_tool_output
from .record import check_topic_name, message_class


def load_messages(bag: Bag, topics: list[str]) -> list[tuple[str, int, bytes]]:
    """All (topic, t_ns, raw) of ``topics`` in receive-time order (held in memory: tool topics are small)."""
    return [(topic, t, bytes(raw)) for topic, _, t, raw in bag.messages(topics)]


def tool_topics(bag: Bag) -> list[str]:
    """The bag's tool topics, played by default: pose/twist types and a grasper's jaw (``tool/jaw``, a dVRK's
    ``jaw/measured_js``), but the node's own outputs (tool/applied_*)."""
    return [t for t, ty in sorted(bag.topics.items())
            if (ty in POSE_TYPES + TWIST_TYPES or is_jaw_topic(t, ty)) and not is_node_tool_output(t)]


def choose_topics(bag: Bag, requested: list[str] | None) -> list[str]:
    """The topics to play: the requested ones (checked), else :func:`tool_topics`."""
    topics = bag.topics
    if requested:
        missing = [t for t in requested if t not in topics]
        if missing:
            raise InputError(f"bag {str(bag.path)!r} has no topic {', '.join(missing)}; it has: {bag.describe_topics()}")
        return list(requested)
    chosen = tool_topics(bag)
    if not chosen:
        outputs = [t for t in sorted(topics) if is_node_tool_output(t)]
        raise InputError(f"bag {str(bag.path)!r} has no tool topic (pose or twist types"
                         + (f"; the node's own outputs {', '.join(outputs)} are played only when named" if outputs
                            else "") + f"); it has: {bag.describe_topics()}; choose topics with --topics")
    return chosen


#: Seconds play stays after its last message, for best-effort readers, which acknowledge nothing.
LINGER_S = 0.5

#: Topics that are latched by convention: played TRANSIENT_LOCAL even from a bag that recorded no QoS for them.
LATCHED_BY_NAME = ("/tf_static",)


def play_qos(bag: Bag, topic: str, n_messages: int) -> tuple[bool, bool, int]:
    """(reliable, transient_local, depth) to publish ``topic`` with: as its publishers offered it when recorded.

    A subscriber that asks for TRANSIENT_LOCAL (the node's ``/tf_static``, RViz's latched markers) never
    matches a VOLATILE publisher, so a latched topic must be played latched: then a late subscriber still
    gets it. ``/tf_static`` is latched even without recorded QoS (a bag from another recorder). A latched
    topic keeps every one of its messages (``depth`` = their count, one per broadcaster in a robot's bag);
    the others keep 1000, enough for a bag played at speed.
    """
    recorded = bag.offered_qos(topic)
    latched_name = topic in LATCHED_BY_NAME
    if recorded is None:
        reliable, latched = True, latched_name
    else:
        reliable, latched = recorded[0], recorded[1] or latched_name
    depth = min(1000, max(1, n_messages)) if latched else 1000
    return reliable, latched, depth


def check_remaps(bag: Bag, topics: list[str], remaps: dict[str, str]) -> None:
    """Every remap's FROM is a played topic and its TO a valid topic name; else one line naming it."""
    for src, dst in remaps.items():
        if src not in topics:
            where = "is not in the bag" if src not in bag.topics else "is not played"
            raise InputError(f"--remap {src}:={dst}: {src!r} {where}: expected one of the played topics "
                             f"{', '.join(topics)} (the bag's tool topics: {', '.join(tool_topics(bag)) or 'none'}; "
                             "--topics plays others)")
        check_topic_name(dst if dst.startswith(("/", "~")) else "/" + dst, "--remap target", given=dst)


def _prepare(bag_path: str | Path, topics: list[str] | None,
             remaps: dict[str, str]) -> tuple[list[str], dict[str, Any], list[tuple[str, int, bytes]], dict]:
    """The topics to play, their message classes, their messages in order and the QoS each is played with."""
    with Bag(bag_path) as bag:
        requested = topics
        topics = choose_topics(bag, requested)
        check_remaps(bag, topics, remaps)
        classes = {}
        for t in topics:
            try:
                classes[t] = message_class(bag.topics[t])
            except InputError as exc:
                if requested:  # asked for by name: an error
                    raise
                print(f"play: skipping {t}: {exc}", flush=True)
        topics = [t for t in topics if t in classes]
        if not topics:
            raise InputError(f"bag {str(bag_path)!r}: none of its tool topics can be published here "
                             "(their message packages are missing; see above)")
        messages = load_messages(bag, topics)
        counts = bag.message_counts
        qos_of = {t: play_qos(bag, t, counts.get(t, 0)) for t in topics}
    if not messages:
        raise InputError(f"bag {str(bag_path)!r}: topics {', '.join(topics)} hold no messages")
    return topics, classes, messages, qos_of


class _Player:
    """A node publishing the played topics (and /clock), stopped by ``stop``."""

    def __init__(self, node: Any, topics: list[str], classes: dict[str, Any], qos_of: dict, remaps: dict[str, str],
                 clock: bool, stop: threading.Event) -> None:
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: PLC0415

        def qos(topic: str) -> QoSProfile:
            reliable, latched, depth = qos_of[topic]
            return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                              reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                              durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)

        self.node, self.remaps, self.stop = node, remaps, stop
        self.pubs = {t: node.create_publisher(classes[t], remaps.get(t, t), qos(t)) for t in topics}
        self.clock_pub = None
        if clock:
            from rosgraph_msgs.msg import Clock  # noqa: PLC0415

            self.clock_pub = node.create_publisher(Clock, "/clock", QoSProfile(depth=10))
        self.watched = dict(self.pubs) if self.clock_pub is None else {**self.pubs, "/clock": self.clock_pub}

    def _matched(self, pub: Any, need: int) -> bool:
        # --min-subscribers matched, and every subscription the graph already shows on the topic: one
        # subscriber elsewhere (a monitor, a viewer) must not start the play before the node's own is
        # matched, whose first messages, and a latched /tf_static once play has ended, it would miss
        known = self.node.count_subscribers(pub.topic_name) if need > 0 else 0
        return pub.get_subscription_count() >= max(need, known)

    def wait_for_subscribers(self, need: int, wait: float) -> None:
        """Up to ``wait`` s for ``need`` subscribers on every played topic (and a /clock follower); says what is
        missing when it plays anyway."""
        stop, pubs, clock_pub = self.stop, self.pubs, self.clock_pub
        deadline = time.monotonic() + max(0.0, wait)
        while not stop.is_set() and time.monotonic() < deadline:
            if all(self._matched(p, need) for p in pubs.values()):
                break
            stop.wait(0.02)  # polling the graph; a signal ends the wait at once
        if clock_pub is not None and need > 0:
            # a node that follows /clock subscribes once it has seen this publisher; nodes that do not never do
            clock_deadline = min(deadline, time.monotonic() + 2.0) if wait > 0 else time.monotonic()
            while not stop.is_set() and time.monotonic() < clock_deadline and clock_pub.get_subscription_count() < 1:
                stop.wait(0.02)
        waiting = [self.remaps.get(t, t) for t, p in pubs.items() if p.get_subscription_count() < need]
        if waiting and wait > 0:
            print(f"play: fewer than {need} subscribers on {', '.join(waiting)} after {wait} s; playing anyway",
                  flush=True)
        unmatched = [f"{p.topic_name} ({p.get_subscription_count()} of {self.node.count_subscribers(p.topic_name)})"
                     for t, p in pubs.items() if self.remaps.get(t, t) not in waiting and not self._matched(p, need)]
        if unmatched and wait > 0:
            print(f"play: not every subscription in the graph matched after {wait} s on {', '.join(unmatched)} (one "
                  "with incompatible QoS never does); playing anyway", flush=True)
        if clock_pub is not None and clock_pub.get_subscription_count() == 0:
            print("play: nobody subscribes to /clock (yet): nodes with use_sim_time or follow_clock follow the "
                  "bag's time once they do", flush=True)

    def run(self, messages: list[tuple[str, int, bytes]], rate: float, loop: bool, clock_rate: float) -> int:
        """Publish the messages at their recorded times (scaled by ``rate``), /clock between; the count sent."""
        stop, clock_pub, sent = self.stop, self.clock_pub, 0
        t0 = messages[0][1]
        span = messages[-1][1] - t0
        period_ns = int(1e9 / clock_rate)
        loop_offset = 0  # bag-time offset of the current loop, so /clock keeps increasing
        while not stop.is_set():
            start = time.monotonic()
            next_clock = t0
            for topic, t_ns, raw in messages:
                # /clock ticks up to this message's time, each at its own wall time
                while clock_pub is not None and next_clock <= t_ns and not stop.is_set():
                    _sleep_until(start + (next_clock - t0) * 1e-9 / rate, stop)
                    _publish_clock(clock_pub, next_clock + loop_offset)
                    next_clock += period_ns
                _sleep_until(start + (t_ns - t0) * 1e-9 / rate, stop)
                if stop.is_set():
                    break
                if clock_pub is not None:
                    _publish_clock(clock_pub, t_ns + loop_offset)
                self.pubs[topic].publish(raw)
                sent += 1
            if not loop:
                break
            loop_offset += span + period_ns
        return sent

    def drain(self) -> None:
        """Let the middleware hand the last messages (and /clock) over before the node goes: reliable readers
        acknowledge them; best-effort ones (the node's tool input) never do, and the publisher's sending
        thread may still hold the last sample when wait_for_all_acked returns, so play lingers a moment more
        (without it a lock-step node lost the bag's last pose)."""
        from rclpy.duration import Duration  # noqa: PLC0415

        end = time.monotonic() + 1.0
        for p in self.watched.values():
            left = end - time.monotonic()
            if left > 0 and p.get_subscription_count() > 0 and not self.stop.is_set():
                p.wait_for_all_acked(Duration(nanoseconds=ns_from_seconds(left)))
        if any(p.get_subscription_count() > 0 for p in self.watched.values()):
            self.stop.wait(LINGER_S)


def play(bag_path: str | Path, *, topics: list[str] | None = None, remaps: dict[str, str] | None = None,
         rate: float = 1.0, loop: bool = False, clock: bool = True, clock_rate: float = 100.0, wait: float = 5.0,
         min_subscribers: int = 1) -> int:
    """Publish a bag's tool topics (or ``topics``) with the recorded timing; returns the messages published.

    ``remaps`` publishes a bag topic under another name; ``rate`` scales the
    speed; ``loop`` repeats; ``clock`` publishes ``/clock`` at ``clock_rate`` Hz;
    waits up to ``wait`` s for ``min_subscribers`` on every played topic first.
    SIGINT/SIGTERM stop it cleanly.
    """
    if not rate > 0:
        raise InputError(f"rate {rate}: expected a speed factor > 0")
    if min_subscribers < 0:
        raise InputError(f"min_subscribers {min_subscribers}: expected a count >= 0")
    if not clock_rate > 0:
        raise InputError(f"clock_rate {clock_rate}: expected > 0 Hz")
    if not (math.isfinite(wait) and wait >= 0):
        raise InputError(f"--wait {wait}: expected seconds >= 0")
    remaps = dict(remaps or {})
    topics, classes, messages, qos_of = _prepare(bag_path, topics, remaps)

    import rclpy  # noqa: PLC0415
    from rclpy.signals import SignalHandlerOptions  # noqa: PLC0415

    stop = threading.Event()

    def on_signal(_signum: int, _frame: Any) -> None:
        stop.set()

    old_handlers = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    # args=[]: rcl must not parse this process's command line (a --remap FROM:=TO there is tissue-sim's own
    # option, which rcl took for a deprecated remap rule and warned about)
    rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
    node = None
    sent = 0
    try:
        node = rclpy.create_node("tissue_sim_player", namespace="/")
        player = _Player(node, topics, classes, qos_of, remaps, clock, stop)
        player.wait_for_subscribers(min_subscribers, wait)
        print(f"playing {len(messages)} messages on {', '.join(remaps.get(t, t) for t in topics)} at {rate}x"
              + (" with /clock" if player.clock_pub else "") + (", looping" if loop else ""), flush=True)
        sent = player.run(messages, rate, loop, clock_rate)
        player.drain()
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        for s, h in old_handlers.items():
            signal.signal(s, h)
    print(f"play: published {sent} messages", flush=True)
    return sent


def _sleep_until(when: float, stop: threading.Event) -> None:
    delay = when - time.monotonic()
    if delay > 0:
        stop.wait(delay)


def _publish_clock(pub: Any, t_ns: int) -> None:
    from builtin_interfaces.msg import Time  # noqa: PLC0415
    from rosgraph_msgs.msg import Clock  # noqa: PLC0415

    sec, nanosec = stamp_from_ns(t_ns)
    pub.publish(Clock(clock=Time(sec=sec, nanosec=nanosec)))
