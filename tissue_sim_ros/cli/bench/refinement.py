"""``tissue-sim bench refinement``: the command line of bench/refinement.py."""
from __future__ import annotations

import argparse

from ...bench import refinement
from ...core.config import parse_assignments
from ..options import positive_floats

HELP = "the material model run to rest against the scikit-fem reference: errors vs mesh spacing and dt"
DESCRIPTION = refinement.__doc__


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="bench_out/refinement", help="output directory (CSV, PNG)")
    parser.add_argument("--spacings", default=",".join(map(str, refinement.SPACINGS)),
                        help="mesh spacings [m], coarse to fine")
    parser.add_argument("--dts", default=",".join(map(str, refinement.DTS)), help="time steps [s] of the dt study")
    parser.add_argument("--dt", type=float, default=0.002, help="time step of the refinement study [s] (default 0.002)")
    parser.add_argument("--damping", type=float, default=30.0, help="viscous damping on the way to rest [1/s]")
    parser.add_argument("--rest-speed", type=float, default=1e-6, help="at rest: every particle slower than this [m/s]")
    parser.add_argument("--max-steps", type=int, default=5000, help="give up on rest after this many steps")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="solver setting over the material's defaults, e.g. --set iterations=20 (repeatable)")
    parser.add_argument("--quick", action="store_true", help="two coarse spacings and two dts (smoke test)")


def run(args: argparse.Namespace) -> int:
    overrides = parse_assignments(args.set)
    spacings = positive_floats(args.spacings, "--spacings")
    dts = positive_floats(args.dts, "--dts")
    return refinement.run(args.out, spacings=spacings, dts=dts, spacing_dt=args.dt, damping=args.damping,
                          rest_speed=args.rest_speed, max_steps=args.max_steps, overrides=overrides,
                          quick=args.quick)
