"""A scene from flat parameters in one line: :func:`build_simulation`.

The same flat parameter names configure the YAML file (``ros__parameters`` of
``config/tissue_sim.yaml``), the ROS node, every ``tissue-sim`` command and the
library; all of them resolve through :func:`~tissue_sim_ros.core.config.resolve_config`
(:mod:`tissue_sim_ros.core.config`), and this module keeps the library's
one-line entry point.
"""
from __future__ import annotations

from typing import Any, Mapping

from ..config import Config, SceneConfig, default_params, load_params_file, resolve_config
from ..contact.tool import ToolShape
from ..mesh import TissueMesh
from .simulation import Simulation

__all__ = ["SceneConfig", "build_simulation", "default_params", "load_params_file", "tool_from_mapping"]


def tool_from_mapping(values: Mapping[str, Any]) -> ToolShape:
    """ToolShape from ``tool_shape``, ``tool_length``, ``tool_width``, ``tool_radius`` (others default)."""
    kwargs: dict[str, Any] = {}
    if "tool_shape" in values:
        kwargs["kind"] = values["tool_shape"]
    for k in ("length", "width", "radius"):
        if f"tool_{k}" in values:
            kwargs[k] = float(values[f"tool_{k}"])
    return ToolShape(**kwargs)


def build_simulation(values: Mapping[str, Any] | Config | None = None, mesh: TissueMesh | None = None) -> Simulation:
    """A Simulation from flat parameters over the shipped YAML (or a resolved Config), optionally on a given mesh.

    ``build_simulation({"method": "xpbd_substep"})`` is
    ``Simulation.from_config(resolve_config({"method": "xpbd_substep"}))``: an
    unknown name is an InputError naming the closest known one, as in the node.
    """
    cfg = values if isinstance(values, Config) else resolve_config(dict(values or {}), source="build_simulation")
    return Simulation.from_config(cfg, mesh=mesh)
