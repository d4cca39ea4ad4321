"""``tissue-sim demo``: the command line of experiments/demo.py (node, recorder and driver through ROS)."""
from __future__ import annotations

import argparse

from ..core.resources import scene_names
from ..experiments import demo

HELP = "the main job: node + tool driver on a private ROS domain, experiment a, recorded to a bag"
DESCRIPTION = demo.__doc__  # what the demo does, written once beside it


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="out", help="output directory for the bag, figures and logs (default: out)")
    parser.add_argument("--scene", default="paper", choices=scene_names(),
                        help="shipped scene: the node's parameter file (config/scenes/NAME.yaml; paper: "
                             "config/tissue_sim.yaml) and the driver's experiment a for it (default: paper)")
    parser.add_argument("--params", help="parameter YAML for the node, over the shipped config/tissue_sim.yaml "
                                         "(default: the scene's)")
    parser.add_argument("--domain-id", type=int, default=None,
                        help="ROS_DOMAIN_ID to use (default: a free-looking one derived from the process id)")
    parser.add_argument("--timeout", type=float, default=120.0, help="give up after this many seconds (default 120)")
    parser.add_argument("--trajectory", default=None, metavar="PRESET|FILE",
                        help="the tool driver's trajectory: a preset (experiment_a, experiment_b_shallow, "
                             "experiment_b_steep, authors, retract) or a .csv/.yaml trajectory file (default "
                             "experiment_a; retract with --scene retract: grasp, lift and pull back 2 cm, open)")
    parser.add_argument("--contact-model", choices=["paper", "projection", "barrier"], default=None,
                        help="contact model of the node (default: the scene's own, projection where that is "
                             "the paper's: barrier for material: neo_hookean scenes; the paper's eq. (3) lets the "
                             "tool pass into the tissue once it touches)")


def run(args: argparse.Namespace) -> int:
    # the node reads the parameter file itself (--params-file): the demo takes the file, not a resolved Config
    trajectory = args.trajectory or ("retract" if args.scene == "retract" else "experiment_a")
    return demo.run(args.out, scene=args.scene, params_file=args.params, domain_id=args.domain_id,
                    timeout=args.timeout, trajectory=trajectory, contact_model=args.contact_model)
