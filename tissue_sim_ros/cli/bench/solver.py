"""``tissue-sim bench solver``: the command line of bench/solver.py."""
from __future__ import annotations

import argparse

from ...bench import solver

HELP = "ms per step, ns per projection and ratio to NumPy, per method and mesh size"
DESCRIPTION = solver.__doc__


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="bench_out/solver", help="output directory (CSV, PNG)")
    parser.add_argument("--sizes", type=int, nargs="+", default=None,
                        help=f"approximate particle counts (default {' '.join(map(str, solver.SIZES))})")
    parser.add_argument("--steps", type=int, default=None, help="steps timed per method and size (default 20; quick 3)")
    parser.add_argument("--iterations", type=int, default=30, help="solver iterations per step (default 30)")
    parser.add_argument("--quick", action="store_true",
                        help=f"small sizes only ({' '.join(map(str, solver.QUICK_SIZES))}), few steps")


def run(args: argparse.Namespace) -> int:
    return solver.run(args.out, sizes=args.sizes, steps=args.steps, iterations=args.iterations, quick=args.quick)
