"""``tissue-sim bench spacing``: the command line of bench/spacing.py."""
from __future__ import annotations

import argparse

from ...bench import spacing

HELP = "effective spring and area moduli, mass per area and sag against mesh spacing"
DESCRIPTION = spacing.__doc__


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="bench_out/spacing", help="output directory (CSV, PNG)")
    parser.add_argument("--spacings", type=float, nargs="+", default=list(spacing.SPACINGS),
                        help=f"mesh spacings [m] (default {' '.join(map(str, spacing.SPACINGS))})")
    parser.add_argument("--width", type=float, default=0.4, help="strip width [m] (default 0.4)")
    parser.add_argument("--height", type=float, default=0.2, help="strip height [m] (default 0.2)")
    parser.add_argument("--mass-per-area", type=float, default=0.0506,
                        help="areal density of the areal-mass runs [kg/m^2] (default 0.0506, the default scene's)")
    parser.add_argument("--quick", action="store_true", help="two coarse spacings (smoke test)")


def run(args: argparse.Namespace) -> int:
    return spacing.run(args.out, spacings=args.spacings, width=args.width, height=args.height,
                       mass_per_area=args.mass_per_area, quick=args.quick)
