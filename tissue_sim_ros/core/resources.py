"""Find the package's config files (YAML, scenes, default tissue image, RViz config).

Looked up, in order, so that a source checkout, ``pip install .`` (editable or
not) and a colcon/ament install all work:

1. ``$TISSUE_SIM_CONFIG_DIR`` if set;
2. the ``tissue_sim_ros.config`` package data (``config/`` mapped into the package by setup.py);
3. ``config/`` beside the package in a source checkout;
4. ``<prefix>/share/tissue_sim_ros/config`` of an ament install (``AMENT_PREFIX_PATH`` and ``sys.prefix``).
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

from .errors import InputError

DEFAULT_PARAMS_FILE = "tissue_sim.yaml"
DEFAULT_IMAGE = "tissue.png"
#: Shipped scenes: ``config/scenes/<name>.yaml`` (``tissue-sim demo --scene NAME``).
SCENES_DIR = "scenes"


def config_dirs() -> list[Path]:
    """Candidate config directories, most specific first (only those that exist)."""
    dirs: list[Path] = []
    env = os.environ.get("TISSUE_SIM_CONFIG_DIR")
    if env:
        dirs.append(Path(env))
    try:
        import tissue_sim_ros.config as cfg_pkg  # noqa: PLC0415  (package data after pip install)

        for p in getattr(cfg_pkg, "__path__", []):
            dirs.append(Path(p))
    except ImportError:
        pass
    dirs.append(Path(__file__).resolve().parents[2] / "config")  # tissue_sim_ros/core/resources.py -> the checkout
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p] + [sys.prefix]
    dirs += [Path(p) / "share" / "tissue_sim_ros" / "config" for p in prefixes]
    seen: list[Path] = []
    for d in dirs:
        if d.is_dir() and d not in seen:
            seen.append(d)
    return seen


def config_path(name: str) -> Path:
    """Path of a shipped config file by name; InputError listing where it looked if missing."""
    dirs = config_dirs()
    for d in dirs:
        if (d / name).is_file():
            return d / name
    raise InputError(f"config file {name!r} not found in {', '.join(map(str, dirs)) or 'any config directory'}")


def find_data_file(path: str | Path) -> Path:
    """A file a parameter names: as given when it exists (relative to the working directory), else a
    relative path among the config directories (``scenes/liver_probe.png``); else the path as given,
    so the caller's own "does not exist" message names what the user wrote."""
    p = Path(path)
    if p.is_file() or p.is_absolute():
        return p
    for d in config_dirs():
        if (d / p).is_file():
            return d / p
    return p


def scene_names() -> list[str]:
    """Names of the shipped scenes (``config/scenes/*.yaml``), sorted; ``paper`` is the default file."""
    names = {"paper"}
    for d in config_dirs():
        names.update(f.stem for f in (d / SCENES_DIR).glob("*.yaml"))
    return sorted(names)


def scene_params_file(name: str) -> Path:
    """The parameter file of a shipped scene: ``paper`` is config/tissue_sim.yaml, others config/scenes/NAME.yaml."""
    if name == "paper":
        return config_path(DEFAULT_PARAMS_FILE)
    if name not in scene_names():
        raise InputError(f"--scene {name!r}: expected one of {', '.join(scene_names())}")
    return config_path(f"{SCENES_DIR}/{name}.yaml")
