"""Recording the node's topics to a rosbag2 bag (MCAP, or sqlite3 on request): the library behind ``tissue-sim record``.

Subscribes with ``raw=True`` and writes the serialized bytes as they arrive
(no decoding, no re-encoding), with the type names read from the live graph
and the Jazzy message definitions, so the bag opens in ``ros2 bag``, Foxglove
and PlotJuggler. Topics: the node's tool input and outputs (:data:`DEFAULT_TOPICS`,
resolved in ``--namespace``) plus anything else under ``tissue/`` and
``tool/`` there; ``topics`` names them explicitly, ``all_topics`` takes every
topic in the graph. The tool inputs are subscribed at once (their types are
known), the rest as their publishers show up (a node started after the
recorder is picked up then).

SIGINT (Ctrl-C) and SIGTERM end the recording and close the bag properly;
``duration`` stops that many wall-clock seconds after the first message was
received (the time to discover publishers is not counted; it waits up to
``wait`` seconds for that first message, then ends with an empty bag). The bag is flushed to disk every
second, so even a killed recorder leaves what it wrote; ``recover=BROKEN``
turns that into a closed bag (sqlite3 also reads as it is).

The simulator node behind the recording (the one publishing ``tissue/energy``)
is asked for its parameters through its parameter services; they go into the
bag as ``tissue_sim.params`` (as the node's own ``record_path`` recordings hold
them), so ``tissue-sim replay`` steps the run with the node's physics.

Each subscription's QoS follows its publishers (as ``ros2 bag record`` does):
reliable when every publisher is reliable, else best effort; transient local
when every publisher is (a latched rest mesh is then recorded too).
"""
from __future__ import annotations

import math
import signal
import threading
import time
from pathlib import Path
from typing import Any

from ..core.errors import InputError
from .bags import Bag, BagWriter, recover_bag, typestore

#: The node's topics (relative to its namespace): tool input, then outputs (msg_docs/).
DEFAULT_TOPICS = (
    "tool/pose", "tool/twist",
    "tissue/markers", "tissue/points", "tissue/rest_mesh",
    "tissue/energy", "tissue/energy/inertial", "tissue/energy/spring", "tissue/energy/area", "tissue/energy/strain",
    "tissue/energy/potential", "tissue/energy/contact", "tissue/energy/bodies", "tissue/contact",
    "tool/wrench",
)
_PREFIXES = ("tissue/", "tool/")
#: The node's inputs, whose types are known before any publisher shows up: subscribed at once (reliable, which
#: a reliable driver matches at discovery), so the first poses of a driver that starts right away are recorded.
KNOWN_INPUTS = {"tool/pose": "geometry_msgs/msg/PoseStamped", "tool/twist": "geometry_msgs/msg/TwistStamped"}
_IGNORED = ("/rosout", "/parameter_events")


def _name_problem(exc: Exception) -> str:
    """The one-line reason of an rclpy name validation error (its message spans three lines)."""
    first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return first.split(": ", 1)[-1].rstrip(":")


def check_namespace(namespace: str) -> str:
    """``namespace`` as an absolute ROS namespace (``left`` -> ``/left``); InputError naming it when invalid."""
    from rclpy.exceptions import InvalidNamespaceException  # noqa: PLC0415
    from rclpy.validate_namespace import validate_namespace  # noqa: PLC0415

    ns = "/" + namespace.strip("/")
    try:
        validate_namespace(ns)
    except InvalidNamespaceException as exc:
        raise InputError(f"--namespace {namespace!r}: {_name_problem(exc)}: expected a ROS namespace such as "
                         "/left") from None
    return ns


def check_topic_name(name: str, option: str, given: str | None = None) -> str:
    """``name`` when it is a valid absolute topic name; InputError naming ``option`` and the name (``given``:
    the name as the user wrote it, before resolving)."""
    from rclpy.exceptions import InvalidTopicNameException  # noqa: PLC0415
    from rclpy.validate_full_topic_name import validate_full_topic_name  # noqa: PLC0415

    try:
        validate_full_topic_name(name)
    except InvalidTopicNameException as exc:
        raise InputError(f"{option} {given if given is not None else name!r}: {_name_problem(exc)}: expected a "
                         "ROS topic name such as /tool/pose") from None
    return name


def resolve(name: str, namespace: str) -> str:
    """Absolute topic name of a relative ``name`` in ``namespace``."""
    if name.startswith("/"):
        return name
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return f"{ns}/{name}"


def message_class(msgtype: str) -> Any:
    """The rclpy message class of ``pkg/msg/Type``; InputError when its package is not installed."""
    import importlib  # noqa: PLC0415

    try:
        pkg, kind, name = msgtype.split("/")
        return getattr(importlib.import_module(f"{pkg}.{kind}"), name)
    except (ValueError, ImportError, AttributeError):
        pkg = msgtype.split("/")[0]
        raise InputError(f"message type {msgtype!r}: its Python package {pkg!r} is not installed (source a ROS 2 "
                         f"Jazzy install, or pip install ros-jazzy-{pkg.replace('_', '-')} where PyPI has it)") from None


class Recorder:
    """Subscribes (raw) to topics as they appear and writes them to a :class:`BagWriter`.

    Parameters
    ----------
    node : rclpy.node.Node
        The node to subscribe with (a helper takes the node, it does not subclass it).
    writer : BagWriter
        Where messages go; receive times from ``node``'s clock.
    wanted : set of str or None
        Absolute topic names to record; None = every topic (except /rosout, /parameter_events).
    prefixes : tuple of str
        Absolute prefixes also recorded (``/ns/tissue/``, ``/ns/tool/``).
    duration : float or None
        Record for this many wall-clock seconds from the first message received (later ones are not written).
    """

    def __init__(self, node: Any, writer: BagWriter, wanted: set[str] | None, prefixes: tuple[str, ...] = (),
                 duration: float | None = None) -> None:
        self.node = node
        self.writer = writer
        self.wanted = wanted
        self.prefixes = prefixes
        self.duration = duration
        self.first_message: float | None = None
        """time.monotonic() of the first message received: --duration counts from here."""
        self.subscriptions: dict[str, Any] = {}
        self.skipped_types: dict[str, str] = {}
        self._provisional: dict[str, str] = {}
        """Topics subscribed before any publisher was seen, with the type assumed."""
        self.lost: dict[str, int] = {}
        """Messages DDS reported lost per topic (the subscription's message-lost event), when any."""

    def _subscribe(self, cls: Any, topic: str, qos: Any) -> Any:
        """A raw subscription whose messages go to the bag and whose DDS-reported losses are counted."""
        from rclpy.event_handler import SubscriptionEventCallbacks  # noqa: PLC0415

        def on_lost(info: Any, t: str = topic) -> None:
            self.lost[t] = int(info.total_count)

        return self.node.create_subscription(cls, topic, lambda data, t=topic: self._on_message(t, data), qos,
                                             raw=True, event_callbacks=SubscriptionEventCallbacks(message_lost=on_lost))

    def wants(self, topic: str) -> bool:
        if self.wanted is None:
            return topic not in _IGNORED
        return topic in self.wanted or any(topic.startswith(p) for p in self.prefixes)

    def _qos(self, topic: str) -> Any:
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: PLC0415

        infos = self.node.get_publishers_info_by_topic(topic)
        reliable = bool(infos) and all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos)
        latched = bool(infos) and all(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos)
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                          reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)

    def presubscribe(self, topic: str, msgtype: str) -> None:
        """Subscribe to ``topic`` as ``msgtype`` now (reliable); :meth:`discover` adapts it to its publishers."""
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: PLC0415

        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
        self.writer.add_topic(topic, msgtype)
        self.subscriptions[topic] = self._subscribe(message_class(msgtype), topic, qos)
        self._provisional[topic] = msgtype

    def _settle(self, topic: str, types: list[str]) -> None:
        """A provisional subscription's publishers appeared: keep it, or re-subscribe best effort / warn on type."""
        from rclpy.qos import ReliabilityPolicy  # noqa: PLC0415

        infos = self.node.get_publishers_info_by_topic(topic)
        if not infos:
            return
        msgtype = self._provisional.pop(topic)
        if msgtype not in types:
            self.node.get_logger().warning(f"{topic} is published as {', '.join(types)}, not {msgtype}: not recorded")
            return
        if any(i.qos_profile.reliability != ReliabilityPolicy.RELIABLE for i in infos):
            # a best-effort publisher does not match a reliable subscription: follow it
            self.node.destroy_subscription(self.subscriptions[topic])
            self.subscriptions[topic] = self._subscribe(message_class(msgtype), topic, self._qos(topic))

    def discover(self) -> list[str]:
        """Subscribe to wanted topics that appeared in the graph since the last call; returns the new ones."""
        from rclpy.qos import DurabilityPolicy, ReliabilityPolicy  # noqa: PLC0415

        new = []
        for topic, types in self.node.get_topic_names_and_types():
            if topic in self._provisional:
                self._settle(topic, types)
                continue
            if topic in self.subscriptions or topic in self.skipped_types or not self.wants(topic):
                continue
            if not self.node.get_publishers_info_by_topic(topic):
                continue  # only subscribers so far (e.g. our own, or the node's inputs): wait for a publisher
            msgtype = types[0]
            if msgtype not in typestore().fielddefs:
                self.skipped_types[topic] = msgtype
                self.node.get_logger().warning(f"not recording {topic}: type {msgtype} is not in the Jazzy typestore")
                continue
            try:
                cls = message_class(msgtype)
            except InputError as exc:
                self.skipped_types[topic] = msgtype
                self.node.get_logger().warning(f"not recording {topic}: {exc}")
                continue
            qos = self._qos(topic)
            self.writer.add_topic(topic, msgtype, reliable=qos.reliability == ReliabilityPolicy.RELIABLE,
                                  transient_local=qos.durability == DurabilityPolicy.TRANSIENT_LOCAL)
            self.subscriptions[topic] = self._subscribe(cls, topic, qos)
            new.append(topic)
        return new

    def waiting_for(self) -> str:
        """One line on what a recording that has received nothing yet is waiting for."""
        import os  # noqa: PLC0415

        domain = os.environ.get("ROS_DOMAIN_ID", "0")
        live = sorted(t for t in self.subscriptions if self.node.count_publishers(t) > 0)
        if live:
            return (f"waiting for a first message: subscribed to {len(self.subscriptions)} topics, "
                    f"{len(live)} with a publisher ({', '.join(live[:4])}{', ...' if len(live) > 4 else ''})")
        wanted = ("every topic" if self.wanted is None
                  else ", ".join(sorted(self.wanted)[:3]) + (", ..." if len(self.wanted) > 3 else "")
                  + "".join(f", {p}*" for p in self.prefixes))
        return (f"waiting for publishers: none yet on {wanted} in ROS domain {domain} (a node that is still "
                "starting appears here; check its namespace and ROS_DOMAIN_ID)")

    @property
    def done(self) -> bool:
        """``duration`` seconds have passed since the first message."""
        return (self.duration is not None and self.first_message is not None
                and time.monotonic() - self.first_message >= self.duration)

    def _on_message(self, topic: str, data: bytes) -> None:
        if self.writer.closed:
            return
        if self.first_message is None:
            self.first_message = time.monotonic()
        elif self.done:
            return  # arrived after the recording's duration
        self.writer.write(topic, data, self.node.get_clock().now().nanoseconds)


#: The node's display stream and a topic it publishes every step (names relative to the namespace)
DISPLAY_TOPIC, STEP_TOPIC = "tissue/markers", "tissue/energy"
#: Topics the node publishes once per step: a recording with fewer of one than of another lost messages
PER_STEP_TOPICS = ("tissue/energy", "tissue/energy/bodies", "tissue/contact", "tool/wrench", "tool/applied_twist")


def completeness(counts: dict[str, int], namespace: str = "", lost: dict[str, int] | None = None) -> list[str]:
    """Lines on what a recording of the node holds fewer of than it stepped, and why; empty when nothing is short.

    The node's markers are a display stream (newest state only, at most ``marker_rate``: msg_docs/topics.md),
    so fewer markers than steps is by design, but must not look like a complete record of the run; a
    per-step topic with fewer messages than another lost some on the way.
    """
    lines = []
    steps = counts.get(resolve(STEP_TOPIC, namespace))
    markers = counts.get(resolve(DISPLAY_TOPIC, namespace))
    if steps and markers is not None and markers < steps:
        lines.append(f"note: {resolve(DISPLAY_TOPIC, namespace)} holds {markers} arrays for {steps} steps: the node "
                     "publishes markers as a display stream (newest state only, at most marker_rate), skipping steps "
                     "while its marker thread is busy; every step is in the per-step topics (energy, contact, wrench, "
                     "points at points_rate)")
    per_step = {t: counts[resolve(t, namespace)] for t in PER_STEP_TOPICS if resolve(t, namespace) in counts}
    if per_step and min(per_step.values()) < max(per_step.values()):
        most = max(per_step.values())
        short = ", ".join(f"{resolve(t, namespace)} {n}" for t, n in per_step.items() if n < most)
        lines.append(f"WARNING: per-step topics differ ({short}, against {most}): messages were lost on the way "
                     "(a loaded machine, or the recorder started after the node)")
    for topic, n in sorted((lost or {}).items()):
        if n:
            lines.append(f"WARNING: {topic}: DDS reported {n} messages lost in transport")
    return lines


#: A recording's simulator: the node that publishes this topic (relative to the namespace) is asked for its
#: parameters, which go into the bag (custom data ``tissue_sim.params``) as the node's own recordings hold them.
SIMULATOR_TOPIC = "tissue/energy"


class ParameterFetch:
    """Asks the simulator node behind a recording for its parameters, without blocking the recording.

    Once :meth:`poll` sees exactly one node publishing the simulator's topic, it calls that node's
    ``list_parameters`` and ``get_parameters`` services; when both answered, :attr:`params` holds the
    values of every simulator parameter (``core/config.py``'s table), resolved through the front door,
    so ``tissue-sim replay`` steps the recorded run with the node's own physics, not the shipped defaults.
    """

    def __init__(self, node: Any, topics: list[str]) -> None:
        self.node = node
        self.topics = topics
        self.target: str | None = None
        """The node asked (``/namespace/name``), once chosen."""
        self.params: dict[str, Any] | None = None
        self.problem: str | None = None
        self._list = self._get = None
        self._future = None
        self._names: list[str] = []

    def poll(self) -> str | None:
        """Advance; returns a line to print when something happened (the node found, parameters in, a problem)."""
        if self.params is not None or self.problem is not None:
            return None
        if self.target is None:
            infos = [i for t in self.topics for i in self.node.get_publishers_info_by_topic(t)]
            if not infos or any(i.node_name.startswith("_NODE_NAME_UNKNOWN") for i in infos):
                return None  # the graph names a publisher's node a moment after the publisher itself
            nodes = sorted({f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in infos})
            if len(nodes) > 1:
                self.problem = (f"several nodes publish {', '.join(self.topics)} ({', '.join(nodes)}): their parameters "
                                "are not recorded; replay this bag with --params")
                return self.problem
            from rcl_interfaces.srv import GetParameters, ListParameters  # noqa: PLC0415

            self.target = nodes[0]
            self._list = self.node.create_client(ListParameters, f"{self.target}/list_parameters")
            self._get = self.node.create_client(GetParameters, f"{self.target}/get_parameters")
            return None
        if self._future is None:
            if not self._list.service_is_ready():
                return None
            from rcl_interfaces.srv import ListParameters  # noqa: PLC0415

            self._future = ("list", self._list.call_async(ListParameters.Request()))
            return None
        kind, future = self._future
        if not future.done():
            return None
        if future.exception() is not None:
            self.problem = f"{self.target} did not give its parameters ({future.exception()}): replay with --params"
            return self.problem
        if kind == "list":
            from rcl_interfaces.srv import GetParameters  # noqa: PLC0415

            from ..core.config import BY_NAME  # noqa: PLC0415

            self._names = [n for n in future.result().result.names if n in BY_NAME]
            self._future = ("get", self._get.call_async(GetParameters.Request(names=self._names)))
            return None
        from rclpy.parameter import parameter_value_to_python  # noqa: PLC0415

        values = {n: parameter_value_to_python(v) for n, v in zip(self._names, future.result().values)}
        try:
            from ..core.config import resolve_config  # noqa: PLC0415

            self.params = resolve_config(overrides=values, source=f"the parameters of {self.target}").flat()
        except InputError as exc:
            self.problem = f"the parameters of {self.target} do not resolve ({exc}): replay with --params"
            return self.problem
        return f"  parameters of {self.target} recorded ({len(self.params)}): replay steps with them"


def _recover(recover: str | Path, output: Path, storage: str) -> dict[str, int]:
    counts = recover_bag(recover, output, storage)
    with Bag(output) as bag:
        kept = sorted(bag.custom_data)
    print(f"recovered {sum(counts.values())} messages from {recover} into {output}: "
          + (", ".join(f"{t} {n}" for t, n in sorted(counts.items())) or "no topics")
          + (f"; custom_data kept: {', '.join(kept)}" if kept else ""))
    return counts


def _start(node: Any, writer: BagWriter, namespace: str, topics: list[str] | None, all_topics: bool,
           duration: float | None) -> tuple[Recorder, ParameterFetch]:
    """The recorder of the chosen topics (subscribed to the known inputs at once) and the simulator's
    parameters' fetch."""
    if all_topics:
        wanted, prefixes = None, ()
    elif topics:
        wanted, prefixes = {resolve(t, namespace) for t in topics}, ()
    else:
        wanted = {resolve(t, namespace) for t in DEFAULT_TOPICS}
        prefixes = tuple(resolve(p, namespace) for p in _PREFIXES)
    recorder = Recorder(node, writer, wanted, prefixes, duration=duration)
    simulator = resolve(SIMULATOR_TOPIC, namespace)
    fetch = ParameterFetch(node, [simulator] if wanted is None or recorder.wants(simulator) else [])
    for name, msgtype in KNOWN_INPUTS.items():
        topic = resolve(name, namespace)
        if wanted is not None and topic in wanted:
            recorder.presubscribe(topic, msgtype)
            print(f"  + {topic} ({msgtype})", flush=True)
    return recorder, fetch


def _run(executor: Any, recorder: Recorder, fetch: ParameterFetch, writer: BagWriter, stop: threading.Event,
         duration: float | None, wait: float, quiet: bool) -> None:
    """Spin until stopped, the duration is over, or nothing came within ``wait`` s; say how it goes."""
    start = time.monotonic()
    next_discovery, next_status, next_waiting = 0.0, start + 1.0, start + 2.0
    announced = duration is None
    while not stop.is_set():
        now = time.monotonic()
        if recorder.done:
            break
        if duration is not None and recorder.first_message is None and now - start >= wait:
            print(f"  no message in {wait:g} s: nothing to record (is the node running, in this namespace and "
                  "ROS domain?)", flush=True)
            break
        if not announced and recorder.first_message is not None:
            announced = True
            print(f"  first message after {recorder.first_message - start:.1f} s: recording {duration:g} s "
                  "from it", flush=True)
        if now >= next_discovery:
            for topic in recorder.discover():
                print(f"  + {topic} ({writer.topics[topic]})", flush=True)
            next_discovery = now + 0.2
        executor.spin_once(timeout_sec=0.05)
        said = fetch.poll()
        if said:
            print(said, flush=True)
            if fetch.params is not None:
                from ..core.config import params_json_flat  # noqa: PLC0415

                # durable: in the storage file at once, so a killed recorder's bag keeps them (record --recover)
                writer.set_custom_data("tissue_sim.params", params_json_flat(fetch.params), durable=True)
        if not quiet and now >= next_status:
            next_status = now + 1.0
            total = sum(writer.counts.values())
            print(f"  {now - start:6.1f} s  {total} messages", flush=True)
            if total == 0 and now >= next_waiting:
                # a status of 0 messages for many seconds reads as a hang: say what it waits for
                next_waiting = now + 5.0
                print("  " + recorder.waiting_for(), flush=True)


def record(output: str | Path | None = None, storage: str = "mcap", *, duration: float | None = None,
           namespace: str = "", topics: list[str] | None = None, all_topics: bool = False, flush_period: float = 1.0,
           quiet: bool = False, use_sim_time: bool = False, recover: str | Path | None = None,
           wait: float = 30.0) -> dict[str, int]:
    """Record until SIGINT/SIGTERM or ``duration`` [s]; returns the message count per topic.

    With ``duration``, a recording that has received nothing ``wait`` seconds after its start ends (an empty
    bag, and a line saying so) instead of waiting for a first message that may never come.

    ``output`` defaults to ``tissue_sim_YYYYmmdd_HHMMSS``; ``topics`` (relative
    names resolve in ``namespace``) or ``all_topics`` choose what to record,
    else the node's topics. ``recover``: instead of recording, rewrite what a
    killed recording left as a closed bag at ``output``.
    """
    if duration is not None and not duration > 0:
        raise InputError(f"duration {duration}: expected seconds > 0")
    if not (math.isfinite(wait) and wait > 0):
        raise InputError(f"--wait {wait}: expected seconds > 0")
    output = Path(output or time.strftime("tissue_sim_%Y%m%d_%H%M%S"))
    if recover:
        return _recover(recover, output, storage)
    # names are checked before the bag directory exists: bad input creates nothing
    check_namespace(namespace)
    for t in topics or []:
        check_topic_name(resolve(t, namespace), "--topics", t)
    writer = BagWriter(output, storage, flush_period=flush_period)

    import rclpy  # noqa: PLC0415
    from rclpy.executors import SingleThreadedExecutor  # noqa: PLC0415
    from rclpy.parameter import Parameter  # noqa: PLC0415
    from rclpy.signals import SignalHandlerOptions  # noqa: PLC0415

    stop = threading.Event()
    received: list[int] = []

    def on_signal(signum: int, _frame: Any) -> None:
        received.append(signum)
        stop.set()

    # our own handlers, so a signal ends the loop and the bag is closed here, not mid-write
    old_handlers = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    # args=[]: rcl must not parse this process's command line (tissue-sim's own options), only ROS's defaults
    rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
    node = recorder = None
    try:
        node = rclpy.create_node("tissue_sim_recorder", namespace="/", parameter_overrides=[
            Parameter("use_sim_time", Parameter.Type.BOOL, bool(use_sim_time))])
        recorder, fetch = _start(node, writer, namespace, topics, all_topics, duration)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        print(f"recording to {output} ({storage}); Ctrl-C to stop"
              + (f"; {duration:g} s from the first message" if duration is not None else ""), flush=True)
        _run(executor, recorder, fetch, writer, stop, duration, wait, quiet)
    finally:
        writer.close()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        for s, h in old_handlers.items():
            signal.signal(s, h)
    why = f" on {signal.Signals(received[0]).name}" if received else ""
    counts = writer.counts
    print(f"closed {output}{why}: {sum(counts.values())} messages; "
          + (", ".join(f"{t} {n}" for t, n in sorted(counts.items())) or "no topics found"), flush=True)
    for line in completeness(counts, namespace, recorder.lost if recorder is not None else None):
        print(line, flush=True)
    return dict(counts)
