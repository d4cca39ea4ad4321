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


def test_ros_layer_imports_no_experiments():
    # the tool driver and replay read trajectories from the core (core/trajectories.py), never the experiments
    ros = CORE.parent / "ros"
    pattern = re.compile(r"^\s*(import|from)\s+(tissue_sim_ros\.experiments|\.\.experiments)\b", re.MULTILINE)
    offenders = [p.name for p in ros.glob("*.py") if pattern.search(p.read_text())]
    assert not offenders, f"ros modules importing the experiments: {offenders}"
