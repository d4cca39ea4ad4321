"""``tissue-sim config``, and the ``--params``/``--set`` options every command shares.

Every command that builds a simulation takes its configuration the same way,
through :func:`~tissue_sim_ros.core.config.resolve_config`::

    tissue-sim COMMAND [--params FILE] [--set NAME=VALUE ...]

``tissue-sim config`` prints the resolved configuration as a ROS 2 parameter
YAML: the node (``--ros-args --params-file``) and every command (``--params``)
load it identically.
"""
from __future__ import annotations

import argparse
import sys
from typing import Any, Mapping

from ..core.config import Config, implausible_values, parse_assignments, resolve_config
from ..core.errors import make_parent, output_file

HELP = "print the resolved configuration (shipped YAML + --params + --set) as a parameter YAML"
DESCRIPTION = """Resolve the configuration once, as every command and the node do, and print it.

The shipped config/tissue_sim.yaml, then --params FILE, then each --set NAME=VALUE:
unknown names are refused (with the closest known one), method aliases are resolved
(xpbd_substep -> method xpbd, 30 substeps of 1 iteration), every value is checked.
The output is a ROS 2 parameter file: `tissue_sim_node --ros-args --params-file OUT`
and `tissue-sim COMMAND --params OUT` load exactly this configuration."""


def add_config_arguments(parser: argparse.ArgumentParser) -> None:
    """The shared configuration options: ``--params FILE`` and repeatable ``--set NAME=VALUE``."""
    parser.add_argument("--params", metavar="FILE",
                        help="parameter YAML over the shipped config/tissue_sim.yaml (a ROS 2 parameter file or flat)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="override one parameter, e.g. --set method=xpbd_substep (repeatable; "
                             "names as in msg_docs/parameters.md)")


def config_from_args(args: argparse.Namespace, defaults: Mapping[str, Any] | None = None, **extra: Any) -> Config:
    """The Config of a command's ``--params`` and ``--set``.

    ``defaults`` are the command's own (under the parameter file); ``extra`` values win over everything.
    """
    overrides = parse_assignments(getattr(args, "set", None) or [])
    overrides.update(extra)
    return warn_implausible(resolve_config(overrides=overrides, params_file=getattr(args, "params", None),
                                           defaults=defaults, source="--set"))


def warn_implausible(cfg: Config) -> Config:
    """``cfg``, after a warning on stderr for each value no tissue step can mean (a 10 s dt): such a run goes ahead,
    but its numbers are no tissue's (:func:`~tissue_sim_ros.core.config.implausible_values`)."""
    for line in implausible_values(cfg):
        print(f"tissue-sim: warning: {line}", file=sys.stderr)
    return cfg


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_config_arguments(parser)
    parser.add_argument("--out", metavar="FILE",
                        help="write the YAML here instead of printing it (its directory is created)")


def run(args: argparse.Namespace) -> int:
    out = output_file(args.out, "--out") if args.out else None
    text = config_from_args(args).to_yaml()
    if out is not None:
        make_parent(out, "--out")  # as every command's --out FILE: its directory is created
        out.write_text(text)
        print(f"wrote {args.out}")
    else:
        print(text, end="")
    return 0
