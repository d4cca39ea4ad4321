"""``tissue-sim control``: the command line of experiments/control.py (the controller against a simulated world)."""
from __future__ import annotations

import argparse
import math
from pathlib import Path

from ..core.config import parse_assignments, resolve_config
from ..core.errors import InputError, output_dir
from ..core.plan.control import ControlSettings, default_model
from ..core.resources import scene_params_file
from ..core.sim.backends import check_backend, check_jobs
from ..experiments import control
from .config import warn_implausible
from .options import add_backend_arguments, positive_floats

#: --timing's grids of pull motions; each replan also rolls out holding still, so it weighs one candidate more
TIMING_COUNTS = (4, 8, 16, 32, 64)
TIMING_CANDIDATES = tuple(n + 1 for n in TIMING_COUNTS)

HELP = "drive a point of the tissue to a target with the model-predictive grasp controller, offline"
DESCRIPTION = control.__doc__


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="out/control", help="output directory (default: out/control)")
    parser.add_argument("--params", default=None, metavar="FILE",
                        help="parameter file over config/scenes/retract.yaml (the controller's model)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="a parameter of the controller's model (repeatable)")
    parser.add_argument("--world-e", type=float, default=1.3, metavar="FACTOR",
                        help="the world's Young's modulus over the model's (default 1.3: 30%% off)")
    parser.add_argument("--noise", type=float, default=0.0005,
                        help="standard deviation of the noise on the observed points [m] (default 0.0005)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the noise (default 0)")
    parser.add_argument("--lift", type=float, default=0.02, help="goal: this far above the start [m] (default 0.02)")
    parser.add_argument("--side", type=float, default=0.01, help="goal: this far right of the start [m] (default 0.01)")
    parser.add_argument("--max-time", type=float, default=10.0, help="simulated seconds at most (default 10)")
    parser.add_argument("--tolerance", type=float, default=0.002, help="goal tolerance [m] (default 0.002)")
    parser.add_argument("--replan-every", type=int, default=10, metavar="N", help="steps per plan (default 10)")
    parser.add_argument("--horizon", type=int, default=30, metavar="S", help="steps per candidate (default 30)")
    parser.add_argument("--speeds", default="0.02,0.04", metavar="V,...",
                        help="pull speeds [m/s] of the candidates (default 0.02,0.04)")
    parser.add_argument("--model-spacing", type=float, default=None, metavar="M",
                        help="mesh spacing of the controller's model [m] (default: twice the world's, 5 mm: 39 "
                             "particles where the world has 150); 0: the world's own mesh")
    parser.add_argument("--bag", default=None, metavar="DIR",
                        help="also write the world's run as a rosbag2 bag (MCAP) at DIR: the node's outputs, "
                             "/tool/pose and /tool/jaw as commanded")
    add_backend_arguments(parser, jobs_default=1,
                          jobs_help="worker processes for the candidates' rollouts (default 1: serially in this "
                                    "process)")
    parser.add_argument("--timing", action="store_true",
                        help=f"also time one replan against the number of candidates ({TIMING_CANDIDATES[0]} to "
                             f"{TIMING_CANDIDATES[-1]}: grids of {TIMING_COUNTS[0]} to {TIMING_COUNTS[-1]} pull motions "
                             "and holding still, 50 steps each; the world's mesh and the model's, serially and on "
                             "max(2, --jobs) workers) and chart it")
    parser.add_argument("--sweep", action="store_true",
                        help="also run the world E factors 0.5 0.7 1 1.3 1.5 at noise 0, 0.5, 1 mm and chart success "
                             "and final error with the replan times (implies --timing)")


def run(args: argparse.Namespace) -> int:
    files = [scene_params_file("retract")] + ([args.params] if args.params else [])
    cfg = warn_implausible(resolve_config(overrides=parse_assignments(args.set), params_file=files, source="--set"))
    check_jobs(args.jobs)
    check_backend(args.backend)
    if args.model_spacing is None:
        args.model_spacing = default_model(cfg)["spacing"]
    if not (math.isfinite(args.model_spacing) and args.model_spacing >= 0):
        raise InputError(f"--model-spacing {args.model_spacing}: expected a spacing >= 0 m (0: the world's mesh)")
    model = {"spacing": args.model_spacing} if args.model_spacing > 0 else {}
    settings = ControlSettings(tolerance=args.tolerance, replan_every=args.replan_every, horizon=args.horizon,
                               pull_speeds=tuple(positive_floats(args.speeds, "--speeds")))
    output_dir(args.out, "--out")
    pool = None
    try:
        if args.jobs > 1 or args.backend == "ray":
            from ..core.sim.backends import rollout_pool  # noqa: PLC0415
            from ..core.sim.batch import BatchScene  # noqa: PLC0415
            from ..core.sim.simulation import Simulation  # noqa: PLC0415

            scene = BatchScene.from_simulation(Simulation.from_config(cfg.replace(**model)))
            pool = rollout_pool(scene, args.jobs, backend=args.backend, address=args.address)
        res = control.run_control(cfg, world_young_factor=args.world_e, noise=args.noise, seed=args.seed,
                                  lift=args.lift, side=args.side, max_time=args.max_time, settings=settings,
                                  pool=pool, out=args.out, model=model, bag=args.bag)
        print("control:")
        for k, v in res.summary.items():
            print(f"  {k}: {v}")
        if args.timing or args.sweep:
            print("replan time against candidates (sync + candidates x 50 steps + choice; median of 5):")
            timing = control.timing_table(cfg, spacings=(0.0, args.model_spacing) if args.model_spacing else (0.0,),
                                          workers=(0, max(2, args.jobs)), counts=TIMING_COUNTS, backend=args.backend,
                                          address=args.address)
            for row in timing:
                print("  " + ", ".join(f"{k} {v:.1f}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()))
            res.files.append(control.write_rows(f"{args.out}/control_timing.csv", timing))
            if not args.sweep:
                from ..render.control import plot_control_sweep  # noqa: PLC0415

                res.files.append(plot_control_sweep(f"{args.out}/control_timing.png", [], timing,
                                                    tolerance=args.tolerance,
                                                    title="One replan against the number of candidates"))
        if args.sweep:
            sweep = control.sweep_control(cfg, seed=args.seed, settings=settings, pool=pool, max_time=args.max_time,
                                          model=model, progress=lambda i, n: print(f"  sweep: run {i} of {n}",
                                                                                   flush=True))
            print("sweep (world E factor, noise): reached, final error")
            for row in sweep:
                print(f"  E x{row['world_e_factor']:g}, noise {row['noise_mm']:g} mm: reached {row['reached']} at "
                      f"{row['reached_at_s']} s, final error {row['final_error_mm']} mm")
            res.files.append(control.write_rows(f"{args.out}/control_sweep.csv", sweep))
            from ..render.control import plot_control_sweep  # noqa: PLC0415

            res.files.append(plot_control_sweep(f"{args.out}/control_sweep.png", sweep, timing,
                                                tolerance=args.tolerance,
                                                title="The controller against a world it does not know exactly"))
    finally:
        if pool is not None:
            pool.close()
    if args.bag is not None:
        res.files.append(Path(args.bag))
    print("wrote:")
    for f in res.files:
        print(f"  {f}")
    return 0 if res.summary["reached"] else 1
