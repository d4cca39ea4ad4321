"""``tissue-sim experiment a|b``: the paper's experiments offline, without a ROS graph."""
from __future__ import annotations

import argparse
import sys

from ..core.config import parse_assignments, resolve_config
from ..core.contact.tool import ToolShape
from ..core.errors import InputError, output_dir
from ..core.resources import scene_names, scene_params_file
from ..core.timing import trajectories as tr
from ..experiments import paper, retract
from .config import add_config_arguments, warn_implausible

HELP = "run the paper's experiment a or b offline and write its figures"
DESCRIPTION = """Run one of the paper's experiments offline, on the paper's scene (Table I parameters) or
another shipped scene (--scene liver_probe: a real-size liver slab under a 5 mm instrument).

  a  the tool approaches and pushes the bottom tissue (Fig. 2): snapshots at
     steps 0, 150, 220, 270 and the energy of each tissue with its terms.
  b  insertions from two angles toward one target (Fig. 3): the final
     deformation for each angle, the energy curves, and which angle costs less.
  retract  grasp and retract on config/scenes/retract.yaml (always that scene, under
     --params/--set): the open grasper comes down onto the flap, closes, lifts and
     pulls back 2 cm, holds and opens; snapshots of each phase, the energy with its
     attachment term, the reaction on the tool and the particles held.

--trajectory PRESET|FILE replaces the tool's path: a preset (experiment_a,
experiment_b_shallow, experiment_b_steep, authors: the paper authors' saved run)
or a trajectory file (CSV time,x,y,yaw; YAML waypoints or a straight motion);
for b it is repeatable, one run per trajectory. Bodies are labelled by their
names (a mesh file's body by its file).

Figures (PNG) and the energy series (CSV) are written to --out."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("which", choices=["a", "b", "retract"],
                        help="experiment a (approach), b (two insertion angles) or retract (grasp and retract)")
    parser.add_argument("--out", default="out", help="output directory (default: out)")
    parser.add_argument("--scene", default="paper", choices=scene_names(),
                        help="shipped scene: its parameter file (config/scenes/NAME.yaml, under --params; paper: "
                             "config/tissue_sim.yaml) and where its experiments put the tool (default: paper)")
    add_config_arguments(parser)
    parser.add_argument("--steps", type=int, default=None,
                        help=f"experiment a: steps (default: the scene's, {tr.A_STEPS} for the paper's; or all of "
                             "--trajectory)")
    parser.add_argument("--trajectory", action="append", default=None, metavar="PRESET|FILE",
                        help=f"tool trajectory: a preset ({', '.join(tr.PRESETS)}) or a file (.csv: time,x,y,yaw; "
                             ".yaml: waypoints or start, direction_deg, speed, steps). Experiment a: one (default "
                             "experiment_a); b: repeatable, replacing --angles")
    parser.add_argument("--settle", type=int, default=0, metavar="N",
                        help="experiment a: N steps under gravity alone before the run, not recorded (the authors' "
                             "saved run started after 29)")
    parser.add_argument("--angles", type=float, nargs="+", default=None,
                        help=f"experiment b: insertion angles in degrees (default: the scene's, "
                             f"{' '.join(map(str, tr.B_ANGLES_DEG))} for the paper's)")
    parser.add_argument("--contact", nargs="+", choices=["paper", "projection"], default=None,
                        help="contact model(s) to run, each writing its own figures (default: both for experiment a, "
                             "the parameter file's for b and for scenes other than the paper's); the paper's eq. (3) "
                             "lets the tool pass into the tissue "
                             "once it touches, projection keeps it out")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    if args.which == "retract":
        return _retract(args)
    scene = tr.scene_experiments(args.scene)
    files = ([scene_params_file(args.scene)] if args.scene != "paper" else []) + ([args.params] if args.params else [])
    tool = scene.b_tool
    defaults = ({"tool_shape": tool.kind, "tool_length": tool.length, "tool_width": tool.width}
                if args.which == "b" and tool is not None else None)
    cfg = warn_implausible(resolve_config(overrides=parse_assignments(args.set), params_file=files or None,
                                          defaults=defaults, source="--set"))
    output_dir(args.out, "--out")
    if args.which == "a" and args.steps is not None and args.steps < 1:
        raise InputError(f"--steps {args.steps}: expected at least 1 step")
    if args.settle < 0:
        raise InputError(f"--settle {args.settle}: expected a number of steps >= 0")
    if args.which == "a" and args.trajectory and len(args.trajectory) > 1:
        raise InputError(f"--trajectory given {len(args.trajectory)} times: experiment a runs one trajectory")
    for spec in args.trajectory or []:  # a bad name or file fails before anything runs
        tr.resolve_trajectory(spec, ToolShape(), 0.01, args.scene)
    models = args.contact or (["paper", "projection"] if args.which == "a" and args.scene == "paper" else [None])
    held = True
    for model in models:
        values = cfg.replace(contact_model=model) if model else cfg
        tag = f"_{model}" if model else ""
        if args.which == "a":
            result = paper.experiment_a(args.out, params=values, steps=args.steps, progress=not args.no_progress,
                                        prefix=f"experiment_a{tag}", scene=scene,
                                        trajectory=args.trajectory[0] if args.trajectory else "experiment_a",
                                        settle=args.settle)
        else:
            result = paper.experiment_b(args.out, params=values, angles_deg=args.angles,
                                        progress=not args.no_progress, prefix=f"experiment_b{tag}",
                                        trajectories=args.trajectory, scene=scene)
        print(f"experiment {args.which}" + (f" ({model} contact)" if model else "") + ":")
        print(result.summary_text())
        print("wrote:")
        for f in result.files:
            print(f"  {f}")
        held &= _say_if_broken(f"experiment {args.which}" + (f" ({model} contact)" if model else ""), result)
    return 0 if held else 1


def _say_if_broken(what: str, result: paper.ExperimentResult) -> bool:
    """Whether the run held; when it did not, one line on stderr saying so (the exit code is then 1)."""
    if paper.run_held(result.summary):
        return True
    why = result.summary.get("run held", "yes")
    why = "non-finite energy" if why == "yes" else why.removeprefix("no: ")
    print(f"tissue-sim: experiment failed: {what} did not hold: {why}; its figures show a broken simulation, "
          "not tissue", file=sys.stderr)
    return False


def _retract(args: argparse.Namespace) -> int:
    files = [scene_params_file("retract")] + ([args.params] if args.params else [])
    cfg = warn_implausible(resolve_config(overrides=parse_assignments(args.set), params_file=files, source="--set"))
    output_dir(args.out, "--out")
    result = retract.experiment_retract(args.out, params=cfg, progress=not args.no_progress)
    print("experiment retract:")
    print(result.summary_text())
    print("wrote:")
    for f in result.files:
        print(f"  {f}")
    return 0 if _say_if_broken("experiment retract", result) else 1
