"""The package installs three ways and finds its config files in each.

* a wheel (what `pip install .` installs) carries the config data and console scripts;
* colcon (from PyPI, no ROS install) builds it as an ament_python package;
* a source checkout finds config/ beside the package.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _copy_source(dst: Path) -> Path:
    """Copy the package sources (not the venv, outputs or build dirs) so builds never touch the checkout."""
    shutil.copytree(ROOT, dst, ignore=shutil.ignore_patterns(".venv", ".git", "out", "build", "install", "log",
                                                             "*.egg-info", "__pycache__", ".pytest_cache"))
    return dst


def test_source_checkout_finds_config():
    from tissue_sim_ros.core.resources import DEFAULT_PARAMS_FILE, config_path

    path = config_path(DEFAULT_PARAMS_FILE)
    assert path.is_file()
    # the shipped params parse into valid SimParams
    from tissue_sim_ros.core.config import resolve_config

    params = resolve_config(params_file=path).sim
    assert params.dt == 0.01 and params.iterations == 30 and params.k_spring == 0.15


def test_wheel_carries_config_and_entry_points(tmp_path):
    # build the wheel exactly as `pip install .` would, without touching the network
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                    "-w", str(tmp_path), str(_copy_source(tmp_path / "src"))], check=True, cwd=tmp_path)
    wheel = next(tmp_path.glob("tissue_sim_ros-*.whl"))
    with zipfile.ZipFile(wheel) as zf:
        names = zf.namelist()
        entry_points = zf.read(next(n for n in names if n.endswith("entry_points.txt"))).decode()
    assert "tissue_sim_ros/config/tissue_sim.yaml" in names
    assert "tissue_sim_ros/config/tissue.png" in names
    assert "tissue_sim_ros/config/scenes/authors.yaml" in names
    assert "tissue_sim_ros/config/scenes/liver_probe.yaml" in names  # the real-size scene and its image
    assert "tissue_sim_ros/config/scenes/liver_probe.png" in names
    assert any(n.endswith("share/tissue_sim_ros/package.xml") for n in names)
    for script in ("tissue-sim", "tissue_sim_node", "tool_driver", "tissue_controller"):
        assert script in entry_points
    # the installed copy finds its data with no source tree around it
    site = tmp_path / "site"
    with zipfile.ZipFile(wheel) as zf:
        zf.extractall(site)
    env = {**os.environ, "PYTHONPATH": str(site)}
    out = subprocess.run([sys.executable, "-c", "import tissue_sim_ros.core.resources as r; print(r.config_path('tissue.png'))"],
                         cwd=tmp_path, env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip().startswith(str(site))


@pytest.mark.skipif(shutil.which("colcon") is None and not (Path(sys.prefix) / "bin" / "colcon").exists(),
                    reason="colcon not installed (pip install colcon-common-extensions colcon-ros)")
def test_colcon_build_installs_ament_layout(tmp_path):
    colcon = shutil.which("colcon") or str(Path(sys.prefix) / "bin" / "colcon")
    ws = tmp_path / "ws"
    (ws / "src").mkdir(parents=True)
    _copy_source(ws / "src" / "tissue_sim_ros")
    result = subprocess.run([colcon, "build", "--event-handlers", "console_cohesion-"], cwd=ws,
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    prefix = ws / "install" / "tissue_sim_ros"
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / "tissue_sim_ros").is_file()
    assert (prefix / "share" / "tissue_sim_ros" / "config" / "tissue_sim.yaml").is_file()
    assert (prefix / "share" / "tissue_sim_ros" / "config" / "tissue.png").is_file()
    assert (prefix / "share" / "tissue_sim_ros" / "config" / "scenes" / "liver_probe.yaml").is_file()
    assert (prefix / "share" / "tissue_sim_ros" / "config" / "scenes" / "liver_probe.png").is_file()
    assert (prefix / "lib" / "tissue_sim_ros" / "tissue_sim_node").is_file()  # where `ros2 run` looks
    # the colcon-installed package finds its config through the ament share directory as well
    site = next(prefix.glob("lib/python3*/site-packages"))
    env = {**os.environ, "PYTHONPATH": str(site), "AMENT_PREFIX_PATH": str(prefix)}
    out = subprocess.run([sys.executable, "-c", "import tissue_sim_ros.core.resources as r; print(r.config_path('tissue_sim.yaml'))"],
                         cwd=tmp_path, env=env, capture_output=True, text=True, check=True)
    assert str(prefix) in out.stdout


def test_cli_help_lists_every_command():
    out = subprocess.run([sys.executable, "-m", "tissue_sim_ros.cli", "--help"], capture_output=True, text=True, check=True)
    for cmd in ("mesh", "experiment", "plan", "demo", "record", "replay", "play", "tune", "bench"):
        assert cmd in out.stdout
