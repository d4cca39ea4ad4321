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

from .core.errors import InputError

DEFAULT_PARAMS_FILE = "tissue_sim.yaml"
DEFAULT_IMAGE = "tissue.png"


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
    dirs.append(Path(__file__).resolve().parent.parent / "config")
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
