"""A scene from flat parameters: mesh source + SimParams + tool -> Simulation.

The same flat parameter names are used by the YAML file (``ros__parameters``
of ``config/tissue_sim.yaml``), the ROS node and the offline CLI, so one file
configures all of them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Mapping

import yaml

from .errors import InputError
from .mesh import TissueMesh, load_mesh
from .model import MATERIAL_DEFAULTS, METHOD_ALIASES, Model, SimParams
from .simulation import Simulation
from .tool import ToolShape


@dataclass(frozen=True)
class SceneConfig:
    """Where the mesh comes from and how image pixels map to metres."""

    image: str = ""
    """Tissue image (PNG/JPEG/BMP); empty = the shipped default image."""
    mesh_file: str = ""
    """A mesh file (.npz, Triangle .node, Gmsh .msh); overrides ``image`` when set."""
    spacing: float = 0.05
    """Target edge length of the mesh [m]."""
    scale: float = 0.002
    """Image scale [m per pixel]."""
    origin_x: float = 0.0
    """World x of the image's left edge [m]."""
    origin_y: float = 0.0
    """World y of the image's bottom edge [m]."""
    threshold: float = -1.0
    """Grey threshold separating tissue from background; < 0 = automatic (Otsu)."""

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> "SceneConfig":
        names = {f.name for f in fields(cls)}
        kwargs = {k: v for k, v in values.items() if k in names}
        for k in ("spacing", "scale", "origin_x", "origin_y", "threshold"):
            if k in kwargs and isinstance(kwargs[k], int) and not isinstance(kwargs[k], bool):
                kwargs[k] = float(kwargs[k])
        cfg = cls(**kwargs)
        for k in ("spacing", "scale"):
            v = getattr(cfg, k)
            if not isinstance(v, float) or not math.isfinite(v) or v <= 0:
                raise InputError(f"parameter {k}={v!r}: expected a number > 0")
        return cfg

    def build_mesh(self) -> TissueMesh:
        """Load the mesh file, or mesh the image (the default image when none is given).

        A relative path that is not a file from the working directory is looked up among the shipped
        config files (``scenes/liver_probe.png``), so a shipped scene's parameter file works from anywhere.
        """
        from ..resources import DEFAULT_IMAGE, config_path, find_data_file  # noqa: PLC0415

        if self.mesh_file:
            return load_mesh(find_data_file(self.mesh_file))
        from .mesh import mesh_from_image  # noqa: PLC0415

        image = str(find_data_file(self.image)) if self.image else str(config_path(DEFAULT_IMAGE))
        return mesh_from_image(image, spacing=self.spacing, scale=self.scale,
                               origin=(self.origin_x, self.origin_y),
                               threshold=None if self.threshold < 0 else self.threshold)


def tool_from_mapping(values: Mapping[str, Any]) -> ToolShape:
    """ToolShape from ``tool_shape``, ``tool_length``, ``tool_width``, ``tool_radius``."""
    kwargs: dict[str, Any] = {}
    if "tool_shape" in values:
        kwargs["kind"] = values["tool_shape"]
    for k in ("length", "width", "radius"):
        if f"tool_{k}" in values:
            kwargs[k] = float(values[f"tool_{k}"])
    return ToolShape(**kwargs)


def load_params_file(path: str | Path, node_name: str = "tissue_sim_node") -> dict[str, Any]:
    """Flat parameters from a ROS 2 parameter YAML (``node: ros__parameters: ...``) or a flat YAML.

    Accepts the node's own section, a ``/**`` wildcard section, or a flat mapping.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"parameter file {str(path)!r} does not exist")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise InputError(f"parameter file {str(path)!r} is not valid YAML: {exc}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise InputError(f"parameter file {str(path)!r}: expected a mapping at the top level")
    out: dict[str, Any] = {}
    found_section = False
    for key in ("/**", node_name, "/" + node_name):
        section = data.get(key)
        if isinstance(section, dict) and isinstance(section.get("ros__parameters"), dict):
            out.update(section["ros__parameters"])
            found_section = True
    if not found_section:
        out.update(data)
    return out


def default_params() -> dict[str, Any]:
    """The shipped ``config/tissue_sim.yaml`` as flat parameters."""
    from ..resources import DEFAULT_PARAMS_FILE, config_path  # noqa: PLC0415

    return load_params_file(config_path(DEFAULT_PARAMS_FILE))


def build_simulation(values: Mapping[str, Any] | None = None, mesh: TissueMesh | None = None) -> Simulation:
    """A Simulation from flat parameters (defaults: the shipped YAML), optionally on a given mesh."""
    values = dict(values or {})
    merged = default_params()
    alias = METHOD_ALIASES.get(values.get("method")) if isinstance(values.get("method"), str) else None
    if alias:
        # a method alias (xpbd_jacobi, xpbd_substep) sets its own scheme/iterations/substeps: the shipped
        # file's values must not override them, only values the caller gave explicitly
        for key in alias:
            merged.pop(key, None)
    material = values.get("material", merged.get("material"))
    for key in MATERIAL_DEFAULTS.get(material, {}) if isinstance(material, str) else ():
        # likewise a material's own solver settings (neo_hookean: xpbd, substeps, projection contact)
        if key not in values:
            merged.pop(key, None)
    merged.update(values)
    params = SimParams.from_mapping(merged)
    mesh = mesh if mesh is not None else SceneConfig.from_mapping(merged).build_mesh()
    return Simulation(Model.from_mesh(mesh, params), tool=tool_from_mapping(merged))
