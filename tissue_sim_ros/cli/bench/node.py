"""``tissue-sim bench node``: the command line of bench/node.py."""
from __future__ import annotations

import argparse

from ...bench import node
from ...core.config import parse_assignments

HELP = "sustained rate, overruns and pose-to-mesh latency of the ROS node"
DESCRIPTION = node.__doc__


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="bench_out/node", help="output directory (CSV, PNG, node logs)")
    parser.add_argument("--seconds", type=float, default=10.0,
                        help="length of one measurement [s]; a run takes many: per scene and mode, timer mode one "
                             "per --phases phase and --phase-lock setting (16 by default), lock_step one. The run "
                             "prints how many and about how long before it starts, and each as it begins")
    parser.add_argument("--warmup", type=float, default=2.0, help="time driven before measuring [s]")
    parser.add_argument("--scene", action="append", choices=sorted(node.SCENES),
                        help="scene to run (repeatable; default all)")
    parser.add_argument("--mode", action="append", choices=node.MODES,
                        help="timer (1/dt timer, newest pose) or lock_step (one step per pose); repeatable; default both")
    parser.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID of the private graph (default 1 + pid %% 100)")
    parser.add_argument("--marker-rate", type=float, default=None,
                        help="the node's marker_rate [Hz] (default: the node's default, a display rate)")
    parser.add_argument("--phases", type=int, default=8,
                        help="timer mode: publisher phases measured in turn, (k + 1/2)/N of a period after the node's "
                             "ticks (0: one run at whatever phase the timers start with)")
    parser.add_argument("--settle", type=float, default=2.0,
                        help="time after placing the publisher at a phase before measuring it [s]")
    parser.add_argument("--phase-lock", choices=("both", "on", "off"), default="both",
                        help="timer mode: the node's phase_lock on, off, or both: at each phase off then on, from "
                             "the same starting phase, in one node process (the soak: on unless off)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="a node parameter for every run (repeatable; checked as the node checks it), e.g. "
                             "step_rt_priority=50 or marker_nice=0 to compare settings side by side; the benchmark's "
                             "own (points_rate, markers_wireframe, diagnostics_rate, max_tool_jump, lock_step, "
                             "phase_lock, and marker_rate with --marker-rate) win")
    parser.add_argument("--soak", type=float, default=None, metavar="SECONDS",
                        help="one long timer-mode run instead (scene 5k unless --scene): RSS growth and overruns")


def run(args: argparse.Namespace) -> int:
    # --set names node parameters (checked by the library as the node checks them), not a Config of this process
    return node.run(args.out, seconds=args.seconds, warmup=args.warmup, scenes=args.scene, modes=args.mode,
                    domain_id=args.domain_id, marker_rate=args.marker_rate, phases=args.phases, settle=args.settle,
                    phase_lock=args.phase_lock, node_params=parse_assignments(args.set), soak=args.soak)
