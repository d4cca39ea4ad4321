"""``tissue-sim plan``: the command line of experiments/plan.py (offline) and experiments/plan_live.py (--live)."""
from __future__ import annotations

import argparse
import os

from ..core.timing import trajectories as tr
from ..experiments import plan, plan_live
from .config import add_config_arguments, config_from_args
from .options import add_backend_arguments, backend_kwargs

HELP = "rank insertion angles/speeds toward a target by implicit Euler energy"
DESCRIPTION = plan.__doc__  # what the planner does, written once beside it


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--target", type=float, nargs=2, default=list(tr.B_TARGET), metavar=("X", "Y"),
                        help="target of the tool tip [m], a point inside the tissue (default: experiment b's, %(default)s)")
    parser.add_argument("--angles", type=float, nargs=3, default=list(plan.ANGLES), metavar=("FROM", "TO", "STEP"),
                        help="insertion angles [deg], direction of the tip's motion (default: -5 to -40 every 5)")
    parser.add_argument("--speeds", type=float, nargs="+", default=list(plan.SPEEDS),
                        help="tip speeds [m per step] (default: 0.001 0.002)")
    parser.add_argument("--distance", type=float, default=tr.B_DISTANCE, help="insertion distance [m]")
    add_backend_arguments(parser, jobs_default=os.cpu_count() or 1,
                          jobs_help="warm worker processes (default: all cores; 1: serially in this process)")
    add_config_arguments(parser)
    parser.add_argument("--out", default="out/plan", help="output directory (default: out/plan)")
    _add_live_arguments(parser)
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def _add_live_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("live planning (--live)")
    g.add_argument("--live", action="store_true",
                   help="plan on a running tissue_sim_node through ~/plan_insertion and carry the plan out")
    g.add_argument("--entry", type=float, nargs=2, default=list(plan_live.default_entry()), metavar=("X", "Y"),
                   help="--live: where the tip enters [m] (default: 0.2 m from the target at -30 deg)")
    g.add_argument("--replan-every", type=int, default=25, metavar="N",
                   help="--live: replan every N steps (0: never; default 25)")
    g.add_argument("--node", default="/tissue_sim_node", help="--live: the simulation node's name (default %(default)s)")
    g.add_argument("--frame", default="world", help="--live: frame of the request and the poses (default world)")
    g.add_argument("--timeout", type=float, default=60.0, help="--live: seconds to wait for the service and each plan")


def run(args: argparse.Namespace) -> int:
    if args.live:  # the node plans from its own configuration: --params/--set are not read
        return plan_live.run_live(args.out, target=args.target, entry=args.entry, replan_every=args.replan_every,
                                  node_name=args.node, frame=args.frame, timeout=args.timeout)
    from ..experiments.paper import B_TOOL_VALUES  # noqa: PLC0415

    config = config_from_args(args, defaults=B_TOOL_VALUES)
    return plan.run(config, args.out, target=args.target, angles=args.angles, speeds=args.speeds,
                    distance=args.distance, progress=not args.no_progress, **backend_kwargs(args))
