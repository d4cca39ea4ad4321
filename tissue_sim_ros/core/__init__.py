"""The simulator as a plain library (numpy, numba, python-fcl, OpenCV): it never imports rclpy.

The entry points a user needs are importable from here::

    from tissue_sim_ros.core import build_simulation, rollout, rollout_batch

- :func:`resolve_config` and :class:`Config`: the one front door (``config.py``): the shipped
  YAML, a parameter file and overrides, checked once;
- :class:`Simulation` and :func:`build_simulation`: one scene, ``step(pose, twist) -> StepReport``;
- :func:`rollout` and :func:`rollout_batch`: a tool path, or many, rolled out from a state.

The packages, from the bottom up (each imports only those before it):
``mesh`` (the mesh type, meshing an image, files, quality), ``contact`` (the tool, collision,
run-time tool checks), ``timing`` (stamps, frames, phase lock, trajectories), ``physics``
(model, material, kernels, solvers, energy), then ``config`` (the front door), ``sim``
(Simulation, snapshots, rollouts, batches, backends), and ``plan`` and ``fit`` on top.
``errors`` and ``resources`` (the shipped config files) serve all of them.

These names are loaded on first use, so ``import tissue_sim_ros.core.errors`` stays light.
"""
from __future__ import annotations

import importlib
from typing import Any

#: the entry points re-exported here: name -> the module that defines it
ENTRY_POINTS = {
    "resolve_config": "tissue_sim_ros.core.config",
    "Config": "tissue_sim_ros.core.config",
    "Simulation": "tissue_sim_ros.core.sim.simulation",
    "build_simulation": "tissue_sim_ros.core.sim.scene",
    "rollout": "tissue_sim_ros.core.sim.rollout",
    "rollout_batch": "tissue_sim_ros.core.sim.batch",
}

__all__ = sorted(ENTRY_POINTS)


def __getattr__(name: str) -> Any:
    module = ENTRY_POINTS.get(name)
    if module is None:
        raise AttributeError(f"module 'tissue_sim_ros.core' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
