"""``tissue-sim fit``: identify the tissue's material from a recording (tracked points + tool poses).

Reads a bag with the tracked tissue points (``sensor_msgs/PointCloud2``, the
same points in every cloud, NaN where a point was not seen, at the camera's own
stamps) and the tool's poses (any type ``tissue-sim replay`` reads), binds
each point to the mesh of the scene (``--params``) by barycentric coordinates
at the first frame (or by ``--correspondence``), and fits the parameters named
by ``--fit`` so that the simulated points, brought to the observation stamps by
interpolation in time, match the observed ones in least squares. The
simulation starts at the first frame from the mesh's rest (stress-free) shape.

Several tissues (bodies of the mesh) get their own material values with
``NAME@BODY`` (``--fit young_modulus@0,young_modulus@1``); those are reported
in fit.json and fitted.yaml's comments (the node takes one value per scene).

The last ``--holdout`` fraction of the recording is not fitted: its RMS error
tells how well the fitted tissue predicts. Error bars are Gauss-Newton ones
from the Jacobian, widened by the residuals' autocorrelation time and by how
far the estimate moves on a mesh of half the spacing (one rollout); a parameter
the recording cannot determine (the tool never touches, Poisson's ratio moves
no observed point, only a combination of two is determined) is reported as
such, held at its start value, and the others refitted.

Writes into --out (all at once, at the end; nothing on an error):

  fitted.yaml      the scene's parameters with the fitted values, a ``tissue_sim_node: ros__parameters:``
                   file that the node (--params-file) and every command (--params) load
  fit.json         values, error bars, identifiability, RMS errors, the optimiser's run
  tracks.csv       observed and simulated position of every point at every frame
  tracks.png       observed against simulated points over time
  errors.png       RMS error per point, fitted and held-out part, and where the points are
  cost.png         the cost along each parameter through the optimum (1D slices)

``--demo`` makes its own recording first (the simulator with known
parameters on a finer mesh, 0.5 mm noise; experiments/fit_scene.py), writes it
as a bag into --out/recording/ and fits it.
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from ..core.errors import InputError
from ..core.fit.tracking import (
    split_body_name,
)
from ..experiments.fit import (
    DEFAULT_FIT,
    POINTS_TOPIC,
    TOOL_TOPIC,
    commit_outputs,
    discard_staging,
    load_scene_values,
    make_demo_recording,
    missing_parents,
    prepare,
    read_correspondence,
    run_fit,
    staging_dir,
    summary_lines,
    write_outputs,
)
from .config import add_config_arguments
from .options import add_backend_arguments

HELP = "identify the tissue's material (Young's modulus, Poisson's ratio, damping...) from a recorded bag"
DESCRIPTION = __doc__.split("\n\n", 1)[1] if __doc__ else HELP



def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", nargs="?", help="the recording: a rosbag2 directory or a .mcap/.db3 file")
    parser.add_argument("--points-topic", default=None, help=f"PointCloud2 topic of the tracked points (--demo: {POINTS_TOPIC})")
    parser.add_argument("--tool-topic", default=None, help="topic of the tool pose (default: the one pose topic in the bag)")
    parser.add_argument("--frame", default=None, help="TF child frame that is the tool (TFMessage tool topics)")
    add_config_arguments(parser)  # --params FILE (the scene: mesh, tool, material, solver; --demo: its own), --set
    parser.add_argument("--fit", default=DEFAULT_FIT,
                        help=f"comma-separated parameters to fit (default {DEFAULT_FIT}); e.g. "
                             "young_modulus,poisson_ratio,damping; per body (several tissues): "
                             "young_modulus@0,young_modulus@1; start values come from the parameters")
    parser.add_argument("--bounds", action="append", default=[], metavar="NAME=LO:HI",
                        help="bounds of a fitted parameter (default: start/100..start*100; poisson_ratio 0..0.49)")
    parser.add_argument("--holdout", type=float, default=0.2,
                        help="fraction of the recording (by frames, at its end) held out of the fit (default 0.2)")
    parser.add_argument("--correspondence", default=None,
                        help="CSV binding each tracked point (rows in cloud order) to the mesh: a column 'vertex', "
                             "or columns 'triangle,w0,w1,w2' (default: barycentric at the first frame)")
    parser.add_argument("--bind-tolerance", type=float, default=None,
                        help="a point up to this far outside the mesh at the first frame is bound to the nearest "
                             "triangle [m] (default: half the mesh spacing)")
    parser.add_argument("--optimizer", choices=["least_squares", "cma"], default="least_squares",
                        help="scipy least_squares (trust region, default) or CMA-ES (needs the fit extra) for a rough cost")
    parser.add_argument("--max-evals", type=int, default=60, help="most cost evaluations of the optimiser (default 60)")
    parser.add_argument("--diff-step", type=float, default=0.1,
                        help="finite-difference step in the scaled parameters (default 0.1: 10%% of a log-scaled "
                             "one, 0.04 of Poisson's ratio; contact makes rollouts rough at the micrometre level)")
    parser.add_argument("--no-mesh-check", action="store_true",
                        help="skip the rollout on half the mesh spacing whose shift of the estimate joins its error bar")
    add_backend_arguments(parser, jobs_default=min(2, os.cpu_count() or 1),
                          jobs_help="worker processes for the rollouts (default: 2 or the cores; 1: in this process)")
    parser.add_argument("--out", required=True, help="output directory (must not exist or be empty)")
    parser.add_argument("--demo", action="store_true",
                        help="make a recording with known parameters (experiments/fit_scene.py) and fit it")
    parser.add_argument("--seed", type=int, default=0, help="--demo: noise and point seed; CMA-ES seed")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


# --------------------------------------------------------------------------- the pipeline


def parse_fit_names(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise InputError(f"--fit {text!r}: expected comma-separated parameter names")
    if len(set(names)) != len(names):
        raise InputError(f"--fit {text!r}: a parameter is named twice")
    for n in names:
        split_body_name(n)  # NAME@BODY: a per-body material value (checked here, the body later)
    return names


def parse_bounds(items: list[str]) -> dict[str, tuple[float, float]]:
    out = {}
    for item in items:
        try:
            name, rng = item.split("=", 1)
            lo, hi = (float(v) for v in rng.split(":"))
        except ValueError:
            raise InputError(f"--bounds {item!r}: expected NAME=LO:HI") from None
        out[name.strip()] = (lo, hi)
    return out


def run(args: argparse.Namespace) -> int:
    from ..ros.recording import read_recording  # noqa: PLC0415

    out = Path(args.out)
    created = missing_parents(out)
    staging = staging_dir(out)
    try:
        truth = None
        bag, params = args.bag, args.params
        points_topic, tool_topic = args.points_topic, args.tool_topic
        if args.demo:
            if bag is not None:
                raise InputError("--demo makes its own recording: give no BAG")
            print("demo: simulating a recording with known parameters (finer mesh, 0.5 mm noise) ...")
            bag_path, params_path, truth = make_demo_recording(staging / "recording", seed=args.seed)
            bag, params = str(bag_path), str(params_path) if params is None else params
            points_topic = points_topic or POINTS_TOPIC
            tool_topic = tool_topic or TOOL_TOPIC
        if bag is None:
            raise InputError("expected a BAG (or --demo)")
        if points_topic is None:
            raise InputError("expected --points-topic (the PointCloud2 topic of the tracked points)")
        names = parse_fit_names(args.fit)
        if args.max_evals < 2:
            raise InputError(f"--max-evals {args.max_evals}: expected at least 2")
        from ..core.sim.backends import check_backend, check_jobs  # noqa: PLC0415

        jobs, backend, address = check_jobs(args.jobs), check_backend(args.backend), args.address
        recording = read_recording(bag, points_topic, tool_topic, frame=args.frame)
        recording.source = recording.source.replace(str(staging), str(out))  # --demo: where it will be
        values = load_scene_values(params, args.set)
        setup = prepare(recording, values, names, holdout=args.holdout, bounds=parse_bounds(args.bounds),
                        correspondence=read_correspondence(args.correspondence) if args.correspondence else None,
                        bind_tolerance=args.bind_tolerance)
        print(f"recording: {recording.n_points} points x {recording.n_frames} frames over {recording.duration:.2f} s "
              f"({recording.source}); fitting {', '.join(names)} on {setup.schedule.n_steps} steps, "
              f"{setup.mesh.vertices.shape[0]} particles, {jobs} {'Ray worker(s)' if backend == 'ray' else 'worker(s)'}")
        t0 = time.perf_counter()
        result = run_fit(setup, jobs=jobs, backend=backend, address=address, optimizer=args.optimizer, max_evals=args.max_evals,
                         diff_step=args.diff_step, seed=args.seed, progress=not args.no_progress,
                         mesh_check=not args.no_mesh_check)
        files = write_outputs(staging, setup, result, truth=truth, final=out,
                              extra={"jobs": args.jobs, "total_wall_s": time.perf_counter() - t0})
        commit_outputs(staging, out)
    except BaseException:
        discard_staging(staging, created)
        raise
    for line in summary_lines(setup, result, truth):
        print(line)
    print(f"wrote {out}/: {', '.join(files)}" + (", recording/" if args.demo else ""))
    return 0
