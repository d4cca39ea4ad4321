"""The core simulator imports without ROS: anyone can use it in a notebook or a planner loop."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

CORE = Path(__file__).resolve().parent.parent / "tissue_sim_ros" / "core"
ROS_MODULES = ("rclpy", "std_msgs", "geometry_msgs", "sensor_msgs", "visualization_msgs", "diagnostic_msgs",
               "std_srvs", "rosgraph_msgs", "builtin_interfaces")


def test_core_sources_import_no_ros():
    pattern = re.compile(rf"^\s*(import|from)\s+({'|'.join(ROS_MODULES)})\b", re.MULTILINE)
    offenders = [p.name for p in CORE.glob("*.py") if pattern.search(p.read_text())]
    assert not offenders, f"core modules importing ROS: {offenders}"


def test_importing_every_core_module_loads_no_ros():
    modules = sorted(p.stem for p in CORE.glob("*.py") if p.stem != "__init__")
    code = ("import sys\n" + "".join(f"import tissue_sim_ros.core.{m}\n" for m in modules)
            + f"print(sorted(m for m in sys.modules if m.split('.')[0] in {ROS_MODULES!r}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


PACKAGE = CORE.parent


def test_imports_run_down_the_layers():
    """The CLI layer calls the library, never the reverse: core, ros and bench import no CLI module.

    A CLI module is ``tissue_sim_ros/cli*.py`` or ``cli/experiment.py``; bench commands build their
    configuration from core.config rather than the experiments' command line.
    """
    cli = re.compile(r"^\s*(from|import)\s+(\.\.|tissue_sim_ros\.)(cli\w*|experiments\.cli|experiments import cli)\b",
                     re.MULTILINE)
    offenders = [str(p.relative_to(PACKAGE)) for layer in ("core", "ros", "bench") for p in (PACKAGE / layer).rglob("*.py")
                 if cli.search(p.read_text())]
    assert not offenders, f"library modules importing the command line: {offenders}"


def test_every_command_module_is_in_the_cli_layer():
    from tissue_sim_ros.cli import COMMANDS

    modules = [m for entry in COMMANDS.values() for m, _ in (entry.values() if isinstance(entry, dict) else [entry])]
    in_ros = [m for m in modules if m.startswith("tissue_sim_ros.ros.") or m.startswith("tissue_sim_ros.core.")]
    assert not in_ros, f"commands whose argparse lives in the library layers: {in_ros}"


def test_ros_layer_imports_no_experiments():
    # the tool driver and replay read trajectories from the core (core/timing/trajectories.py), never the experiments
    ros = CORE.parent / "ros"
    pattern = re.compile(r"^\s*(import|from)\s+(tissue_sim_ros\.experiments|\.\.experiments)\b", re.MULTILINE)
    offenders = [p.name for p in ros.rglob("*.py") if pattern.search(p.read_text())]
    assert not offenders, f"ros modules importing the experiments: {offenders}"
