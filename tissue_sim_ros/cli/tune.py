"""``tissue-sim tune``: the command line of tune/settings.py (and tune/material.py for a neo_hookean scene)."""
from __future__ import annotations

import argparse

from ..core.config import resolve_config
from ..tune import settings as tune
from .options import add_backend_arguments, backend_kwargs, positive_floats

HELP = "pick the cheapest mesh spacing/method/iterations meeting an error tolerance"
DESCRIPTION = tune.__doc__  # what tune measures and chooses, written once beside it


def _listed(values: tuple[float, ...]) -> str:
    return ",".join(map(str, values))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--tolerance", type=float, required=True,
                        help="largest accepted error (relative to the tissue's displacement), e.g. 0.1")
    parser.add_argument("--budget-ms", type=float, required=True, help="largest accepted solve time per step [ms]")
    parser.add_argument("--out", default="",
                        help="write the chosen parameters to this YAML file (nothing is written, exit 1, when no "
                             "setting meets the tolerance within the budget)")
    parser.add_argument("--params", default="", help="scene parameter file (default: config/tissue_sim.yaml)")
    parser.add_argument("--spacings", default=_listed(tune.SPACINGS),
                        help="candidate mesh spacings [m], comma-separated (the reference is twice as fine as the "
                             "finest; below 0.025 the exact reference run gets slow: the finer mesh is a softer "
                             "material that folds under the tool, where each exact step takes Newton minutes)")
    parser.add_argument("--steps", type=int, default=30, help="trajectory length in steps")
    parser.add_argument("--csv", default="", help="also write every measured setting to this CSV")
    parser.add_argument("--quick", action="store_true", help="two coarse spacings, few counts (smoke test)")
    parser.add_argument("--material-spacings", default=_listed(tune.MATERIAL_SPACINGS),
                        help="material neo_hookean: candidate spacings [m] (the reference mesh is 2 sqrt(2) x finer than the finest)")
    parser.add_argument("--grade-spacings", default=_listed(tune.GRADE_SPACINGS),
                        help="material neo_hookean: candidate spacings near the instrument [m] for graded meshes "
                             "(each with every coarser spacing; uniform meshes are always candidates; the "
                             "reference is graded 2 sqrt(2) x finer than the finest); empty = uniform only")
    parser.add_argument("--png", default="", help="material neo_hookean: write the error-time chart to this PNG")
    parser.add_argument("--verify", action="store_true",
                        help="material neo_hookean: measure the --params file as it is against the reference of "
                             "--material-spacings/--grade-spacings (exit 1 when an error exceeds --tolerance)")
    parser.add_argument("--depth", type=float, default=0.003,
                        help="material neo_hookean: how far the instrument presses into the tissue [m]")
    add_backend_arguments(parser, jobs_default=1,
                          jobs_help="worker processes for independent runs (default 1: in this process; the errors "
                                    "are the same with more, the times are measured beside the other workers)")


def parse_spacings(text: str) -> list[float]:
    """Comma-separated spacings [m] -> distinct values, coarse to fine; InputError on a bad or non-positive one.

    The message names --spacings for each of the three lists, as it always has.
    """
    values = positive_floats(text, "--spacings", numbers="numbers in metres", positive="spacings > 0 m")
    return sorted(set(values), reverse=True)


def run(args: argparse.Namespace) -> int:
    config = resolve_config(params_file=args.params or None)
    # parse only the lists this run reads (--quick reads none; a neo_hookean scene the material ones), so an
    # option that does not apply is ignored, as it always was, rather than refused
    material = config.sim.material == "neo_hookean"
    spacings = tune.SPACINGS if args.quick or material else parse_spacings(args.spacings)
    material_spacings, grade_spacings = tune.MATERIAL_SPACINGS, tune.GRADE_SPACINGS
    if material and not args.quick:
        material_spacings = parse_spacings(args.material_spacings)
        grade_spacings = parse_spacings(args.grade_spacings) if args.grade_spacings else []
    return tune.run(config, tolerance=args.tolerance, budget_ms=args.budget_ms, spacings=spacings, steps=args.steps,
                    out=args.out or None, csv_path=args.csv or None, quick=args.quick,
                    material_spacings=material_spacings, grade_spacings=grade_spacings, png_path=args.png or None,
                    verify_only=args.verify, depth=args.depth, params_file=args.params, **backend_kwargs(args))
