"""``tissue-sim bench ros``: the command line of bench/ros_paths.py."""
from __future__ import annotations

import argparse

from ...bench import ros_paths

HELP = "the ROS layer's fast paths: CDR by hand vs the typestore vs rclpy; ctypes vs rclpy publish of 1 MB markers"
DESCRIPTION = ros_paths.__doc__

#: The counts it takes: option, default, what it counts.
COUNTS = (("--triangles", 5000, "triangles of the marker scene"),
          ("--arrays", 150, "MarkerArrays per publisher and round"),
          ("--rounds", 2, "rounds of each publisher, in turn"))


def _count(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value}: expected at least 1")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="bench_out/ros", help="output directory (CSV)")
    for flag, default, what in COUNTS:
        parser.add_argument(flag, type=_count, default=default, help=f"{what} (default {default})")
    parser.add_argument("--no-publish", action="store_true", help="the CDR table only (no ROS graph)")


def run(args: argparse.Namespace) -> int:
    return ros_paths.run(args.out, triangles=args.triangles, arrays=args.arrays, rounds=args.rounds,
                         publish=not args.no_publish)
