"""``tissue-sim bench envs``: the command line of bench/envs.py."""
from __future__ import annotations

import argparse

from ...bench import envs
from ..options import positive_floats

HELP = "learning environments: steps per second, single and vectorised, beside the plain Simulation.step"
DESCRIPTION = envs.__doc__


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="bench_out/envs", help="output directory (CSV, PNG)")
    parser.add_argument("--envs", nargs="+", default=None, metavar="ID", help="tasks (default: all)")
    parser.add_argument("--spacings", default="0.004", metavar="M,...",
                        help="Retract-v0 also at these mesh spacings [m] (default 0.004)")
    parser.add_argument("--vector", type=int, nargs="+", default=[1, 2, 4, 8], metavar="N",
                        help="vector env sizes (default 1 2 4 8)")
    parser.add_argument("--vector-steps", type=int, default=200, help="vector steps per repeat (default 200)")
    parser.add_argument("--repeats", type=int, default=5, help="repeats; the median is reported (default 5)")


def run(args: argparse.Namespace) -> int:
    envs.run(args.out, envs=args.envs, spacings=positive_floats(args.spacings, "--spacings"), vector=args.vector,
             vector_steps=args.vector_steps, repeats=args.repeats)
    return 0
