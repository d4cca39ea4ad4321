"""``tissue-sim bench stability``: the command line of bench/stability.py (and bench/material_stability.py)."""
from __future__ import annotations

import argparse

from ...bench import stability
from ..options import add_backend_arguments, backend_kwargs

HELP = "where each method fails over dt, stiffness, tool speed and mesh quality"
DESCRIPTION = stability.__doc__


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="bench_out/stability", help="output directory (CSV, PNG)")
    parser.add_argument("--quick", action="store_true", help="a few runs (smoke test)")
    parser.add_argument("--material", action="store_true",
                        help="instead: the neo_hookean material over dt, E 1 kPa-1 MPa, tool speed and mesh quality "
                             "on a real-size strip (bench/material_stability.py)")
    parser.add_argument("--grasp", action="store_true",
                        help="instead: a grasp on the retract scene, lifted fast and pulled far, over material, "
                             "substeps and the grasp's compliance (bench/grasp_stability.py)")
    add_backend_arguments(parser, jobs_default=1, jobs_help="worker processes (default 1: in this process)")


def run(args: argparse.Namespace) -> int:
    return stability.run(args.out, quick=args.quick, material=args.material, grasp=args.grasp,
                         **backend_kwargs(args))
