"""``tissue-sim bench contact``: the command line of bench/contact.py."""
from __future__ import annotations

import argparse

from ...bench import contact

HELP = "contact detection cost per step; force smoothness of the material's default (ipc) vs the former under a held and a dragged tool"
DESCRIPTION = contact.__doc__


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="bench_out/contact", help="output directory (CSV, PNG)")
    parser.add_argument("--steps", type=int, default=None, help="steps of each trajectory (default 300; quick 160)")
    parser.add_argument("--quick", action="store_true",
                        help="the paper scene only, 160 steps; smoothness at E 50 kPa, 10 held steps, a 1 cm drag "
                             "(smoke test)")
    parser.add_argument("--only", choices=contact.PARTS, default=None,
                        help="one part only: detection (contact.csv) or smoothness (contact_smoothness.csv)")


def run(args: argparse.Namespace) -> int:
    return contact.run(args.out, steps=args.steps, quick=args.quick, only=args.only)
