"""``tissue-sim bench accuracy``: the command line of bench/accuracy.py."""
from __future__ import annotations

import argparse

from ...bench import accuracy
from ...core.config import parse_assignments

HELP = "error against an exact Newton solve versus time per step, Pareto front"
DESCRIPTION = accuracy.__doc__


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="bench_out/accuracy", help="output directory (CSV, PNG)")
    parser.add_argument("--quick", action="store_true", help="a few settings on a coarse mesh (smoke test)")
    parser.add_argument("--tolerance", type=float, action="append",
                        help="error tolerance to pick the cheapest setting for (repeatable; default 0.3, 0.1, 0.01, 1e-3)")
    parser.add_argument("--steps", type=int, default=None, help="trajectory length in steps (default 30; quick 4)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="override a parameter of config/tissue_sim.yaml for every scene (repeatable), e.g. "
                             "--set mass_per_area=0.0506 so that refined and graded meshes are the same tissue")
    parser.add_argument("--parallel", action="store_true",
                        help="Gauss-Seidel on all threads (Solver(parallel=True)); default: one thread, as the "
                             "solver's own default, so times compare across methods and do not collapse when "
                             "other work shares the cores")


def run(args: argparse.Namespace) -> int:
    # --set here overrides every scene's parameters (refined and graded meshes alike), not one Config
    return accuracy.run(args.out, quick=args.quick, tolerances=args.tolerance, steps=args.steps,
                        overrides=parse_assignments(args.set), parallel=args.parallel)
