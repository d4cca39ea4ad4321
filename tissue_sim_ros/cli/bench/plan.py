"""``tissue-sim bench plan``: the command line of bench/plan.py."""
from __future__ import annotations

import argparse

from ...bench import plan
from ..config import config_from_args

HELP = "batch rollouts per second (serial, 1 and 2 workers) and the planner service's latency and node rate"
DESCRIPTION = plan.__doc__


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="bench_out/plan", help="output directory (CSV, PNG)")
    parser.add_argument("--candidates", type=int, default=64, help="candidates per batch (default 64)")
    parser.add_argument("--steps", type=int, default=100, help="steps per candidate (default 100)")
    parser.add_argument("--repeats", type=int, default=5, help="batches per backend; the median is reported")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="pool sizes (default 1 2)")
    parser.add_argument("--seconds", type=float, default=10.0, help="node part: seconds idle and planning each")
    parser.add_argument("--no-node", action="store_true", help="skip the node part")
    parser.add_argument("--node-workers", type=int, default=2, help="node part: the node's plan_workers (default 2)")
    parser.add_argument("--node-only", action="store_true", help="skip the library part")
    # --params/--set as every command's (cli/config.py), with this benchmark's shorter help
    parser.add_argument("--params", metavar="FILE", help="parameter YAML over the shipped config/tissue_sim.yaml")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="override one parameter")


def run(args: argparse.Namespace) -> int:
    config = config_from_args(args, defaults=plan.SCENE_DEFAULTS)
    return plan.run(config, args.out, candidates=args.candidates, steps=args.steps, repeats=args.repeats,
                    workers=args.workers, seconds=args.seconds, library_part=not args.node_only,
                    node_part=not args.no_node, node_workers=args.node_workers)
