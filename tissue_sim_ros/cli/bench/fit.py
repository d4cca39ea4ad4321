"""``tissue-sim bench fit``: the command line of bench/fit.py."""
from __future__ import annotations

import argparse
import os

from ...bench import fit
from ...core.errors import InputError
from ..options import add_backend_arguments, backend_kwargs

HELP = "fit known parameters back from simulated recordings on another mesh: error, coverage, time"
DESCRIPTION = fit.__doc__


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="out/bench_fit", help="output directory (default: out/bench_fit)")
    points = ",".join(map(str, fit.POINTS))
    parser.add_argument("--points", default=points, help=f"tracked point counts, one recording each (default {points})")
    parser.add_argument("--seeds", type=int, default=2, help="recordings per point count, each its own noise and points")
    add_backend_arguments(parser, jobs_default=min(2, os.cpu_count() or 1), jobs_help="worker processes per fit")
    parser.add_argument("--record-spacing", type=float, default=None, help="mesh spacing of the recordings [m]")
    parser.add_argument("--fit-spacing", type=float, default=None, help="mesh spacing of the fits [m]")
    parser.add_argument("--quick", action="store_true", help="one short recording at coarse spacings (smoke test)")


def run(args: argparse.Namespace) -> int:
    try:
        points = [int(v) for v in args.points.split(",") if v.strip()]
    except ValueError:
        raise InputError(f"--points {args.points!r}: expected comma-separated integers") from None
    return fit.run(args.out, points=points, seeds=args.seeds, record_spacing=args.record_spacing,
                   fit_spacing=args.fit_spacing, quick=args.quick, **backend_kwargs(args))
