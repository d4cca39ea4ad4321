"""``tissue-sim experiment a|b``: the paper's experiments offline, without a ROS graph."""
from __future__ import annotations

import argparse

from ..cli_config import add_config_arguments, config_from_args
from ..core.errors import InputError
from . import paper
from . import trajectories as tr

HELP = "run the paper's experiment a or b offline and write its figures"
DESCRIPTION = """Run one of the paper's experiments on the default scene (Table I parameters), offline.

  a  the tool approaches and pushes the bottom tissue (Fig. 2): snapshots at
     steps 0, 150, 220, 270 and the energy of each tissue with its terms.
  b  insertions from two angles toward one target (Fig. 3): the final
     deformation for each angle, the energy curves, and which angle costs less.

Figures (PNG) and the energy series (CSV) are written to --out."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("which", choices=["a", "b"], help="experiment a (approach) or b (two insertion angles)")
    parser.add_argument("--out", default="out", help="output directory (default: out)")
    add_config_arguments(parser)
    parser.add_argument("--steps", type=int, default=tr.A_STEPS, help=f"experiment a: steps (default {tr.A_STEPS})")
    parser.add_argument("--angles", type=float, nargs="+", default=list(tr.B_ANGLES_DEG),
                        help="experiment b: insertion angles in degrees (default: %(default)s)")
    parser.add_argument("--contact", nargs="+", choices=["paper", "projection"], default=None,
                        help="contact model(s) to run, each writing its own figures (default: both for experiment a, "
                             "the parameter file's for b); the paper's eq. (3) lets the tool pass into the tissue "
                             "once it touches, projection keeps it out")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    cfg = config_from_args(args, defaults=paper.B_TOOL_VALUES if args.which == "b" else None)
    if args.which == "a" and args.steps < 1:
        raise InputError(f"--steps {args.steps}: expected at least 1 step")
    models = args.contact or (["paper", "projection"] if args.which == "a" else [None])
    finite = True
    for model in models:
        values = cfg.replace(contact_model=model) if model else cfg
        tag = f"_{model}" if model else ""
        if args.which == "a":
            result = paper.experiment_a(args.out, params=values, steps=args.steps, progress=not args.no_progress,
                                        prefix=f"experiment_a{tag}")
        else:
            result = paper.experiment_b(args.out, params=values, angles_deg=args.angles,
                                        progress=not args.no_progress, prefix=f"experiment_b{tag}")
        print(f"experiment {args.which}" + (f" ({model} contact)" if model else "") + ":")
        print(result.summary_text())
        print("wrote:")
        for f in result.files:
            print(f"  {f}")
        finite &= bool(result.summary.get("energy finite", True))
    return 0 if finite else 1
