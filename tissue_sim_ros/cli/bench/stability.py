"""``tissue-sim bench stability``: the command line of bench/stability.py (and of bench/material_stability.py with
``--material``, bench/grasp_stability.py with ``--grasp``)."""
from __future__ import annotations

import argparse
from pathlib import Path

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
    if args.material:
        from ...bench.material_stability import run_material  # noqa: PLC0415  (one sweep's imports only)

        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        return run_material(out, args.quick)
    if args.grasp:
        from ...bench.grasp_stability import run_grasp_sweep  # noqa: PLC0415

        return run_grasp_sweep(args.out, args.quick)
    return stability.run(args.out, quick=args.quick, **backend_kwargs(args))
