"""``tissue-sim record``: record the node's topics to a rosbag2 bag (MCAP, or sqlite3 on request).

Subscribes with ``raw=True`` and writes the serialized bytes as they arrive
(no decoding, no re-encoding), with the type names read from the live graph
and the Jazzy message definitions, so the bag opens in ``ros2 bag``, Foxglove
and PlotJuggler. Topics: the node's tool input and outputs (:data:`DEFAULT_TOPICS`,
resolved in ``--namespace``) plus anything else under ``tissue/`` and
``tool/`` there; ``--topics`` names them explicitly, ``--all`` takes every
topic in the graph. The tool inputs are subscribed at once (their types are
known), the rest as their publishers show up (a node started after the
recorder is picked up then).

SIGINT (Ctrl-C) and SIGTERM end the recording and close the bag properly;
``--duration`` stops that many wall-clock seconds after the first message was
received (the time to discover publishers is not counted; it waits up to
``--wait`` seconds, default 30, for that first message, then ends empty). The bag is flushed to disk every
second, so even a killed recorder leaves what it wrote; ``--recover BROKEN -o NEW``
turns that into a closed bag (sqlite3 also reads as it is).

Each subscription's QoS follows its publishers (as ``ros2 bag record`` does):
reliable when every publisher is reliable, else best effort; transient local
when every publisher is (a latched rest mesh is then recorded too).
"""
from __future__ import annotations

import argparse

from ..core.errors import InputError
from ..ros.bags import STORAGES
from ..ros.record import record

HELP = "record the node's topics to a rosbag2 bag (MCAP or sqlite3)"
DESCRIPTION = __doc__.split("\n\n", 1)[1] if __doc__ else HELP


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--output", "-o", default=None,
                        help="bag directory to create (default: tissue_sim_YYYYmmdd_HHMMSS)")
    parser.add_argument("--storage", choices=STORAGES, default="mcap",
                        help="storage plugin (default mcap, as ros2 bag in Jazzy)")
    parser.add_argument("--duration", type=float, default=None,
                        help="stop this many wall-clock seconds after the first message was received (discovery not "
                             "counted; it waits up to --wait seconds for that first message)")
    parser.add_argument("--wait", type=float, default=30.0,
                        help="with --duration: end an empty recording when no message came within this many "
                             "seconds of the start (default 30)")
    parser.add_argument("--namespace", default="",
                        help="namespace of the node whose topics to record (a ROS namespace, e.g. /left)")
    parser.add_argument("--topics", nargs="+", default=None,
                        help="topics to record (relative names resolve in --namespace); default: the node's topics")
    parser.add_argument("--all", action="store_true", help="record every topic in the graph")
    parser.add_argument("--flush-period", type=float, default=1.0, help="seconds between flushes to disk")
    parser.add_argument("--quiet", action="store_true", help="no per-second status line")
    parser.add_argument("--use-sim-time", action="store_true",
                        help="stamp messages with /clock time (as nodes with use_sim_time) instead of wall time")
    parser.add_argument("--recover", metavar="BROKEN_BAG", default=None,
                        help="instead of recording: rewrite what a killed recording left (MCAP without footer, "
                             "sqlite3 without metadata.yaml) as a closed bag at --output")


def run(args: argparse.Namespace) -> int:
    if args.duration is not None and not args.duration > 0:
        raise InputError(f"--duration {args.duration}: expected seconds > 0")
    record(args.output, args.storage, duration=args.duration, namespace=args.namespace, topics=args.topics,
           all_topics=args.all, flush_period=args.flush_period, quiet=args.quiet, use_sim_time=args.use_sim_time,
           recover=args.recover, wait=args.wait)
    return 0
