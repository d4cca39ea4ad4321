"""``--help`` of the ROS executables (``tissue_sim_node``, ``tool_driver``, ``tissue_controller``), answered before
rclpy is initialised.

rclpy ignores the arguments outside ``--ros-args``, so without this a
``tissue_sim_node --help`` started a full node on the current domain. A
``-h``/``--help`` outside the ``--ros-args`` sections prints the executable's
usage and where its interface is described (``msg_docs/``), and the
executable exits 0 without touching ROS.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

HELP_FLAGS = ("-h", "--help")


def user_args(argv: list[str]) -> list[str]:
    """The arguments of a command line (without the program name) that are not ROS arguments: those outside
    ``--ros-args ... [--]`` sections."""
    out, in_ros = [], False
    for arg in argv:
        if arg == "--ros-args":
            in_ros = True
        elif arg == "--" and in_ros:
            in_ros = False
        elif not in_ros:
            out.append(arg)
    return out


def wants_help(args: list[str] | None) -> bool:
    """True when the command line (``args`` as given to ``main``, program name first; None: ``sys.argv``) asks
    for help outside its ROS arguments."""
    argv = sys.argv if args is None else args
    return any(a in HELP_FLAGS for a in user_args(list(argv[1:])))


def msg_docs_dir() -> str:
    """Where the interface description (``msg_docs/``) is on this machine: the source checkout's, or an install's
    ``share/tissue_sim_ros/msg_docs``."""
    candidates = [Path(__file__).resolve().parents[2] / "msg_docs"]
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p] + [sys.prefix]
    candidates += [Path(p) / "share" / "tissue_sim_ros" / "msg_docs" for p in prefixes]
    for d in candidates:
        if (d / "README.md").is_file():
            return str(d)
    return "msg_docs/ in the tissue_sim_ros sources (installed: <prefix>/share/tissue_sim_ros/msg_docs)"


def ros_arguments(name: str, example: str) -> str:
    """The lines of a usage that explain the ROS arguments of the executable ``name``."""
    return (f"ROS arguments (after --ros-args):\n"
            f"  -p NAME:=VALUE        set a parameter, e.g. {example}\n"
            f"  --params-file FILE    parameters from a YAML file (the section `{name}:` or `/**:`,\n"
            f"                        then `ros__parameters:`)\n"
            f"  -r __ns:=/NS          run in a namespace\n")


def usage_head(name: str, about: str, example: str) -> str:
    """The start every executable's ``--help`` shares: the usage line, ``about`` (what it does, ending in a blank
    line), the options and the ROS arguments (:func:`ros_arguments` with ``example``)."""
    return (f"usage: {name} [-h] [--ros-args [-p NAME:=VALUE ...] [--params-file FILE] [-r __ns:=/NS]]\n\n"
            + about
            + "options:\n"
              "  -h, --help            show this message and exit (no node is started)\n\n"
            + ros_arguments(name, example))


def parameter_list(names: list[str], width: int = 100) -> str:
    """Parameter names as a usage prints them: comma-separated, wrapped at ``width`` columns, indented."""
    lines, line = [], " "
    for name in names:
        if len(line) + len(name) + 2 > width:
            lines.append(line.rstrip())
            line = " "
        line += f" {name},"
    lines.append(line.rstrip(","))
    return "\n".join(lines)


def init_rclpy(name: str, args: list[str] | None) -> bool:
    """rclpy initialised with ``args``; False (after one line on stderr naming ``name``) when rcl refuses the arguments or
    a parameter file: the executable then exits 2."""
    import rclpy  # noqa: PLC0415  (--help is answered without it)

    try:
        rclpy.init(args=args)
    except Exception as exc:  # noqa: BLE001  rcl's argument/parameter-file errors
        print(f"{name}: error: {exc}", file=sys.stderr)
        return False
    return True
