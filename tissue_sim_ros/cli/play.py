"""``tissue-sim play``: the command line of :func:`tissue_sim_ros.ros.play.play` (its docstring says what it does)."""
from __future__ import annotations

import argparse
import math

from ..core.errors import InputError
from ..ros import play as _play_module
from ..ros.play import play

HELP = "publish a bag's tool topics into a live ROS graph with the recorded timing"
DESCRIPTION = _play_module.__doc__.split("\n\n", 1)[1] if _play_module.__doc__ else HELP


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", help="a rosbag2 directory, or a .mcap/.db3 file")
    parser.add_argument("--topics", nargs="+", default=None,
                        help="bag topics to play (default: its pose- and twist-typed topics except the node's own "
                             "outputs tool/applied_pose and tool/applied_twist, which play only when named here)")
    parser.add_argument("--remap", nargs="+", default=[], metavar="FROM:=TO",
                        help="publish played topic FROM as TO (a FROM that is not played is refused)")
    parser.add_argument("--rate", type=float, default=1.0, help="playback speed factor (default 1)")
    parser.add_argument("--loop", action="store_true", help="play again from the start at the end")
    parser.add_argument("--clock", action=argparse.BooleanOptionalAction, default=True,
                        help="publish /clock with the bag time (default; the node follows it): --no-clock for none")
    parser.add_argument("--clock-rate", type=float, default=100.0, help="/clock messages per second (default 100)")
    parser.add_argument("--wait", type=float, default=5.0,
                        help="seconds (>= 0) to wait for subscribers on the played topics before starting (default 5)")
    parser.add_argument("--min-subscribers", type=int, default=1,
                        help="subscribers each played topic needs before starting, e.g. 2 for the node and a "
                             "recorder (default 1)")


def _parse_remaps(items: list[str]) -> dict[str, str]:
    out = {}
    for item in items:
        if ":=" not in item:
            raise InputError(f"--remap {item!r}: expected FROM:=TO")
        src, dst = item.split(":=", 1)
        if not src or not dst:
            raise InputError(f"--remap {item!r}: expected FROM:=TO with both names")
        out[src] = dst
    return out


def run(args: argparse.Namespace) -> int:
    if not args.rate > 0:
        raise InputError(f"--rate {args.rate}: expected a speed factor > 0")
    if args.min_subscribers < 0:
        raise InputError(f"--min-subscribers {args.min_subscribers}: expected a count >= 0")
    if not args.clock_rate > 0:
        raise InputError(f"--clock-rate {args.clock_rate}: expected > 0 Hz")
    if not (math.isfinite(args.wait) and args.wait >= 0):
        raise InputError(f"--wait {args.wait}: expected seconds >= 0")
    play(args.bag, topics=args.topics, remaps=_parse_remaps(args.remap), rate=args.rate, loop=args.loop,
         clock=args.clock, clock_rate=args.clock_rate, wait=args.wait, min_subscribers=args.min_subscribers)
    return 0
