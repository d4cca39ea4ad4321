"""The ``tissue-sim`` command.

Each subcommand lives in its own module, which defines::

    HELP = "one line shown in tissue-sim --help"
    DESCRIPTION = "a paragraph shown in tissue-sim SUBCOMMAND --help"   # optional
    def add_arguments(parser: argparse.ArgumentParser) -> None: ...
    def run(args: argparse.Namespace) -> int: ...

Modules are imported only when their subcommand runs, so ``--help`` is fast and
ROS is imported only by the commands that need it. Bad input
(:class:`~tissue_sim_ros.core.errors.InputError`) prints one line and exits 2.

Every output path a command takes (the options of :data:`OUTPUT_OPTIONS`, or the module's own ``OUTPUTS``
tuple of option strings) is checked for writing here, before the command's ``run`` does any work: an unwritable
``--out`` is one line and exit code 2, not a traceback after minutes of meshing.

This package is the only place argparse lives: a command's ``run`` turns its
arguments into a :class:`~tissue_sim_ros.core.config.Config` and plain keyword
arguments and calls the library (core, ros, experiments, bench), which takes
no command line. A DESCRIPTION may be the library module's docstring: it is
shown as plain text (:func:`plain_text`), its Sphinx markup is for the docs.
"""
from __future__ import annotations

import argparse
import importlib
import re
import sys
from typing import Sequence

from ..core.errors import InputError, writable_path

#: subcommand -> (module, one-line help). Nested groups ("bench", "envs") hold their own table (and GROUPS their text).
COMMANDS: dict[str, tuple[str, str] | dict[str, tuple[str, str]]] = {
    "config": ("tissue_sim_ros.cli.config", "print the resolved configuration (shipped YAML + --params + --set) as a parameter YAML"),
    "mesh": ("tissue_sim_ros.cli.mesh", "mesh a tissue image (or load a mesh file), report quality, write .npz and a picture"),
    "experiment": ("tissue_sim_ros.cli.experiment", "run the paper's experiment a or b offline and write its figures"),
    "plan": ("tissue_sim_ros.cli.plan", "rank insertion angles/speeds toward a target by implicit Euler energy"),
    "demo": ("tissue_sim_ros.cli.demo", "the main job: node + tool driver on a private ROS domain, experiment a, recorded to a bag"),
    "record": ("tissue_sim_ros.cli.record", "record the node's topics to a rosbag2 bag (MCAP or sqlite3)"),
    "replay": ("tissue_sim_ros.cli.replay", "run the simulation offline on a bag's tool trajectory; write a bag, CSV, plots, frames"),
    "play": ("tissue_sim_ros.cli.play", "publish a bag's tool topics into a live ROS graph with the recorded timing"),
    "fit": ("tissue_sim_ros.cli.fit", "identify the tissue's material from a recording (tracked points + tool poses)"),
    "control": ("tissue_sim_ros.cli.control", "drive a point of the tissue to a target with the model-predictive grasp controller, offline"),
    "tune": ("tissue_sim_ros.cli.tune", "pick the cheapest mesh spacing/method/iterations meeting an error tolerance"),
    "bench": {
        "solver": ("tissue_sim_ros.cli.bench.solver", "ms per step, ns per projection and ratio to NumPy, per method and mesh size"),
        "contact": ("tissue_sim_ros.cli.bench.contact", "contact detection cost per step; force smoothness of the material's default (ipc) vs the former under a held and a dragged tool"),
        "node": ("tissue_sim_ros.cli.bench.node", "sustained rate, overruns and pose-to-mesh latency of the ROS node"),
        "accuracy": ("tissue_sim_ros.cli.bench.accuracy", "error against an exact Newton solve versus time per step, Pareto front"),
        "stability": ("tissue_sim_ros.cli.bench.stability", "where each method fails over dt, stiffness, tool speed and mesh quality"),
        "spacing": ("tissue_sim_ros.cli.bench.spacing", "effective spring and area moduli, mass per area and sag against mesh spacing"),
        "refinement": ("tissue_sim_ros.cli.bench.refinement", "the material run to rest vs the scikit-fem reference: errors vs mesh spacing and dt"),
        "material-speed": ("tissue_sim_ros.cli.bench.material_speed", "the material's default solve: cost per step vs accuracy at three meshes, beside the paper PBD step"),
        "material": ("tissue_sim_ros.cli.bench.material", "the material's solve vs its exact Newton minimiser: step and response errors (median, max) vs time, Pareto"),
        "plan": ("tissue_sim_ros.cli.bench.plan", "batch rollouts per second (serial, 1 and 2 workers); the planner service's latency and node rate"),
        "fit": ("tissue_sim_ros.cli.bench.fit", "fit known parameters back from simulated recordings on another mesh: error, coverage, time"),
        "peers": ("tissue_sim_ros.cli.bench.peers", "time per step against Taichi, MuJoCo flex and the NumPy baseline (optional extras)"),
        "envs": ("tissue_sim_ros.cli.bench.envs", "learning environments: steps per second, single and vectorised, beside the plain Simulation.step"),
        "ros": ("tissue_sim_ros.cli.bench.ros", "the ROS layer's fast paths: CDR by hand vs the typestore vs rclpy; ctypes vs rclpy publish of 1 MB markers"),
    },
    "envs": {
        "collect": ("tissue_sim_ros.cli.envs.collect", "record a task's expert episodes as a Minari dataset (offline RL)"),
        "evaluate": ("tissue_sim_ros.cli.envs.evaluate", "success rates of the expert and random policies over seeded episodes"),
    },
}

#: a group's (word in the listing, metavar, description): "tissue-sim bench --help", "tissue-sim envs --help"
GROUPS = {
    "bench": ("benchmarks", "BENCHMARK", "Benchmarks; each prints a table and writes a CSV and a chart."),
    "envs": ("learning environments", "COMMAND", "The tissue tasks as Gymnasium environments (tissue_sim_ros.envs, "
                                      "docs/envs.md): datasets of expert episodes and baseline success rates."),
}


#: The options that name a file or directory a command writes. A command module may name its own in ``OUTPUTS``.
OUTPUT_OPTIONS = ("--out", "--output", "--png", "--csv", "--bag")


def _output_dests(parser: argparse.ArgumentParser, options: Sequence[str]) -> list[tuple[str, str]]:
    """(option string, dest) of each of ``parser``'s options among ``options``."""
    return [(next(o for o in action.option_strings if o in options), action.dest) for action in parser._actions
            if any(o in options for o in action.option_strings)]


def check_outputs(args: argparse.Namespace) -> None:
    """InputError when an output path of the parsed command (``args._outputs``) cannot be written; unset ones
    (None, empty: the command writes nothing there) are not checked."""
    for option, dest in getattr(args, "_outputs", ()):
        value = getattr(args, dest, None)
        if value not in (None, ""):
            writable_path(value, option)


#: ``:role:`target` `` or ``:role:`title <target>` `` (Sphinx cross-references), ``~`` to show the last part only
_ROLE = re.compile(r":(?:py:)?(\w+):`(~?)([^`<]*?)\s*(?:<([^>`]+)>)?`")


def _role_text(match: re.Match[str]) -> str:
    role, tilde, text, target = match.groups()
    if target is not None:  # an explicit title
        return text
    if role == "mod":  # the whole dotted name: in a terminal there is no link to follow to the module
        return text
    name = text.rsplit(".", 1)[-1] if tilde else text
    return name + ("()" if role in ("func", "meth") else "")


def plain_text(text: str) -> str:
    """A docstring's reStructuredText as ``--help`` shows it: cross-references, literals and bold as plain words.

    ``:mod:`~a.b``` -> ``a.b``; ``:func:`~a.f``` -> ``f()``; ``:class:`a.C``` -> ``a.C``;
    ````x```` -> ``x``; ``**x**`` -> ``x``. Line breaks are kept (the parsers format descriptions raw).
    """
    text = _ROLE.sub(_role_text, text)
    text = re.sub(r"``(.+?)``", r"\1", text, flags=re.DOTALL)
    # strong emphasis as reST reads it: not inside a word, so x**2 stays a power
    return re.sub(r"(?<![\w*])\*\*(\S(?:.*?\S)?)\*\*(?![\w*])", r"\1", text)


def _add_command(sub: argparse._SubParsersAction, name: str, module: str, help_text: str) -> None:
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name and module.startswith(exc.name):
            sub.add_parser(name, help=f"{help_text} (not available in this build)")
            return
        raise
    help_line = plain_text(getattr(mod, "HELP", help_text))
    parser = sub.add_parser(name, help=help_line, description=plain_text(getattr(mod, "DESCRIPTION", help_line)),
                            formatter_class=argparse.RawDescriptionHelpFormatter)
    mod.add_arguments(parser)
    parser.set_defaults(_run=mod.run, _outputs=_output_dests(parser, getattr(mod, "OUTPUTS", OUTPUT_OPTIONS)))


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tissue-sim",
        description="2D soft-tissue simulation under a surgical tool (PBD/XPBD, python-fcl contact, "
                    "implicit Euler energy), offline and with ROS 2 Jazzy.",
    )
    sub = parser.add_subparsers(title="commands", metavar="COMMAND")
    # import only the module the user asked for (plus help texts for the listing)
    wanted = [a for a in (argv or []) if not a.startswith("-")][:2]
    for name, entry in COMMANDS.items():
        if isinstance(entry, dict):
            word, metavar, description = GROUPS[name]
            group = sub.add_parser(name, help=f"{word}: {', '.join(entry)}", description=description)
            group_sub = group.add_subparsers(title=word, metavar=metavar)
            for sub_name, (module, help_text) in entry.items():
                if wanted[:2] == [name, sub_name]:
                    _add_command(group_sub, sub_name, module, help_text)
                else:
                    group_sub.add_parser(sub_name, help=help_text)
        elif wanted[:1] == [name]:
            _add_command(sub, name, *entry)
        else:
            sub.add_parser(name, help=entry[1])
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    run = getattr(args, "_run", None)
    if run is None:
        parser.print_help()
        return 2
    try:
        check_outputs(args)
        return int(run(args) or 0)
    except InputError as exc:
        print(f"tissue-sim: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("tissue-sim: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
