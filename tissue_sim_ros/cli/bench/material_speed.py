"""``tissue-sim bench material-speed``: the command line of bench/material_speed.py."""
from __future__ import annotations

import argparse

from ...bench import material_speed

HELP = "the material's default solve: cost per step against accuracy at three meshes, beside the paper PBD step"
DESCRIPTION = material_speed.__doc__


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="bench_out/material_speed", help="output directory (CSV, PNG)")
    parser.add_argument("--spacings", default=",".join(f"{s:.6g}" for s in material_speed.SPACINGS),
                        help="comma-separated mesh spacings [m]")
    parser.add_argument("--steps", type=int, default=300, help="steps per run (default 300: 3 s)")
    parser.add_argument("--quick", action="store_true", help="two coarse meshes, 60 steps")


def run(args: argparse.Namespace) -> int:
    from ...core.errors import InputError  # noqa: PLC0415

    try:
        spacings = [float(s) for s in args.spacings.split(",") if s.strip()]
    except ValueError:
        raise InputError(f"--spacings {args.spacings!r}: expected comma-separated numbers (metres)") from None
    return material_speed.run(args.out, spacings=spacings, steps=args.steps, quick=args.quick)
