"""Where a scene's mesh comes from (the ``scene`` group of the configuration): an image and how its pixels map to
metres, or mesh files, meshed or loaded by :meth:`SceneConfig.build_mesh`."""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Mapping

from ..errors import InputError
from .files import load_meshes
from .triangulate import OUTLINE_CORNERS
from .types import MAX_PARTICLES, TissueMesh


def mesh_file_value(value: Any) -> str | tuple[str, ...]:
    """``mesh_file`` as given: one path (str), or several (a list or tuple of paths) as a tuple."""
    if isinstance(value, str):
        return value
    if isinstance(value, (list, tuple)) and value and all(isinstance(v, str) and v for v in value):
        return value[0] if len(value) == 1 else tuple(value)
    raise InputError(f"parameter mesh_file={value!r}: expected a mesh file path or a list of paths")


@dataclass(frozen=True)
class SceneConfig:
    """Where the mesh comes from and how image pixels map to metres (the ``scene`` group)."""

    image: str = ""
    """Tissue image (PNG/JPEG/BMP); empty = the shipped default image."""
    mesh_file: str | tuple[str, ...] = ""
    """A mesh file (.npz, Triangle .node, Gmsh .msh), or a list of them combined into one scene (each body
    named after its file, :func:`~tissue_sim_ros.core.mesh.load_meshes`); overrides ``image`` when set."""
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
    max_particles: int = MAX_PARTICLES
    """Largest mesh meshing an image may make; a larger estimate (area and spacing) is refused before meshing."""
    grade_spacing: float = 0.0
    """Graded mesh: target edge length within ``grade_radius`` of (``grade_x``, ``grade_y``) [m]; 0 = uniform."""
    grade_x: float = 0.0
    """Graded mesh: world x of the fine region's centre [m]."""
    grade_y: float = 0.0
    """Graded mesh: world y of the fine region's centre [m]."""
    grade_radius: float = 0.0
    """Graded mesh: radius of the disc meshed at ``grade_spacing`` [m] (the spacing then grows by 0.3 m/m)."""
    outline_corners: str = "smooth"
    """Meshing an image: "smooth" (the outline smoothed and resampled by arc length, the paper's meshes) or
    "sharp" (corners of the outline between straight runs stay vertices, so a straight face ends at the same
    place at every spacing)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "mesh_file", mesh_file_value(self.mesh_file))
        for k in ("spacing", "scale"):
            v = getattr(self, k)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise InputError(f"parameter {k}={v!r}: expected a number > 0")
        for k in ("grade_spacing", "grade_x", "grade_y", "grade_radius"):
            v = getattr(self, k)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise InputError(f"parameter {k}={v!r}: expected a finite number")
        if not 0.0 <= self.grade_spacing <= self.spacing:
            raise InputError(f"parameter grade_spacing={self.grade_spacing!r}: expected 0 (uniform) or a spacing "
                             f"in (0, spacing={self.spacing!r}] m")
        if self.outline_corners not in OUTLINE_CORNERS:
            raise InputError(f"parameter outline_corners={self.outline_corners!r}: expected one of "
                             f"{', '.join(OUTLINE_CORNERS)}")
        if self.grade_radius < 0:
            raise InputError(f"parameter grade_radius={self.grade_radius!r}: expected a radius >= 0 m")
        v = self.max_particles
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise InputError(f"parameter max_particles={v!r}: expected a whole number >= 1")

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> "SceneConfig":
        """The scene fields of a flat mapping (other names are not the scene's and are skipped)."""
        names = {f.name for f in fields(cls)}
        kwargs = {k: v for k, v in values.items() if k in names}
        for k in (f.name for f in fields(cls) if f.type in (float, "float")):
            if k in kwargs and isinstance(kwargs[k], int) and not isinstance(kwargs[k], bool):
                kwargs[k] = float(kwargs[k])
        return cls(**kwargs)

    def build_mesh(self) -> TissueMesh:
        """Load the mesh file, or mesh the image (the default image when none is given).

        A relative path that is not a file from the working directory is looked up among the shipped
        config files (``scenes/liver_probe.png``), so a shipped scene's parameter file works from anywhere.
        """
        from ..resources import DEFAULT_IMAGE, config_path, find_data_file  # noqa: PLC0415

        if self.mesh_file:
            files = [self.mesh_file] if isinstance(self.mesh_file, str) else list(self.mesh_file)
            return load_meshes([find_data_file(f) for f in files])

        from . import mesh_from_image  # noqa: PLC0415

        image = str(find_data_file(self.image)) if self.image else str(config_path(DEFAULT_IMAGE))
        return mesh_from_image(image, spacing=self.spacing, scale=self.scale,
                               origin=(self.origin_x, self.origin_y),
                               threshold=None if self.threshold < 0 else self.threshold,
                               grading=self.grading, max_particles=self.max_particles,
                               corners=self.outline_corners)

    @property
    def grading(self) -> tuple[float, float, float, float] | None:
        """(x, y, radius, fine_spacing) for :func:`~tissue_sim_ros.core.mesh.mesh_from_image`; None when uniform."""
        if self.grade_spacing <= 0:
            return None
        return (self.grade_x, self.grade_y, self.grade_radius, self.grade_spacing)
