"""``tissue-sim bench peers``: the command line of bench/peers.py (and bench/peers_fem.py)."""
from __future__ import annotations

import argparse

from ...bench import peers

HELP = "time per step against Taichi, MuJoCo flex and the NumPy baseline on the same meshes"
DESCRIPTION = peers.__doc__


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="bench_out/peers", help="output directory (CSV, PNG)")
    parser.add_argument("--quick", action="store_true", help="the smallest mesh, few steps (smoke test)")
    parser.add_argument("--steps", type=int, default=30, help="timed steps per measurement (median)")
    parser.add_argument("--fem", action="store_true",
                        help="instead: the material model (dynamic and static settle), MuJoCo's flex membrane and Newton's "
                             "triangle FEM run to rest on the hanging strip, "
                             "errors against the scikit-fem reference and wall time to rest (bench/peers_fem.py)")


def run(args: argparse.Namespace) -> int:
    return peers.run(args.out, quick=args.quick, steps=args.steps, fem=args.fem)
