"""``tissue-sim bench material``: the command line of bench/material_accuracy.py."""
from __future__ import annotations

import argparse

from ...bench import material_accuracy
from ...core.config import parse_assignments

HELP = "the material's solve vs its exact (Newton) minimiser: step and response errors (median, max) vs time"
DESCRIPTION = material_accuracy.__doc__


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="bench_out/material", help="output directory (CSV, PNG)")
    parser.add_argument("--scenes", default="strip,liver", help="comma-separated: strip, liver")
    parser.add_argument("--steps", type=int, default=20, help="steps per setting (default 20)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="parameter over the scene's, e.g. --set dt=0.005 (repeatable)")
    parser.add_argument("--quick", action="store_true", help="three settings, three steps, the strip only")


def run(args: argparse.Namespace) -> int:
    scenes = [s.strip() for s in args.scenes.split(",") if s.strip()]
    return material_accuracy.run(args.out, scenes=scenes, steps=args.steps, overrides=parse_assignments(args.set),
                                 quick=args.quick)
