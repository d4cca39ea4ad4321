"""``tissue-sim bench ros``: the command line of bench/ros_paths.py."""
from __future__ import annotations

import argparse

from ...bench import ros_paths
from ...core.errors import InputError

HELP = "the ROS layer's fast paths: CDR by hand vs the typestore vs rclpy; ctypes vs rclpy publish of 1 MB markers"
DESCRIPTION = ros_paths.__doc__


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="bench_out/ros", help="output directory (CSV)")
    parser.add_argument("--triangles", type=int, default=5000, help="triangles of the marker scene (default 5000)")
    parser.add_argument("--arrays", type=int, default=150, help="MarkerArrays per publisher and round (default 150)")
    parser.add_argument("--rounds", type=int, default=2, help="rounds of each publisher, in turn (default 2)")
    parser.add_argument("--no-publish", action="store_true", help="the CDR table only (no ROS graph)")


def run(args: argparse.Namespace) -> int:
    for name in ("triangles", "arrays", "rounds"):
        if getattr(args, name) < 1:
            raise InputError(f"--{name} {getattr(args, name)}: expected at least 1")
    return ros_paths.run(args.out, triangles=args.triangles, arrays=args.arrays, rounds=args.rounds,
                         publish=not args.no_publish)
