"""The tissue's mesh: the :class:`TissueMesh` type, meshing an image, mesh files and mesh quality.

``types`` (the mesh type, meshes from arrays, structured rectangles, the size guard and the pixel warning),
``geometry`` (triangles' signed areas, points' distances to segments, vectorised),
``image`` (reading a tissue image and its mask), ``triangulate`` (image -> mesh: outlines,
lattice, constrained Delaunay, smoothing), ``files`` (.npz, Triangle, Gmsh) and
``quality`` (angles, area error, per-body counts). Their public names are importable
from here. Imports only :mod:`tissue_sim_ros.core.errors`: the rest of the core builds on it.
"""
from .files import MESH_SUFFIXES, load_mesh, load_meshes, mesh_name, write_gmsh, write_triangle
from .geometry import segment_distances, signed_areas
from .image import MAX_PIXELS, MIN_REGION_PX, read_image, tissue_mask
from .quality import mesh_quality, triangle_angles
from .triangulate import CORNER_RUN_PX, CORNER_TURN_DEG, OUTLINE_CORNERS, Grading, mesh_from_image, mesh_from_mask
from .types import (
    MAX_PARTICLES,
    Progress,
    TissueMesh,
    boundary_vertices,
    check_mesh_size,
    combine_meshes,
    connected_bodies,
    edges_from_triangles,
    estimate_vertices,
    mesh_from_arrays,
    mesh_rectangle,
    region_names,
    spacing_warning,
)

__all__ = [
    "CORNER_RUN_PX", "CORNER_TURN_DEG", "Grading", "MAX_PARTICLES", "MAX_PIXELS", "MESH_SUFFIXES", "MIN_REGION_PX",
    "OUTLINE_CORNERS", "Progress", "TissueMesh", "boundary_vertices", "check_mesh_size", "combine_meshes", "connected_bodies",
    "edges_from_triangles", "estimate_vertices", "load_mesh", "load_meshes", "mesh_from_arrays", "mesh_from_image",
    "mesh_from_mask", "mesh_name", "mesh_quality", "mesh_rectangle", "read_image", "region_names", "segment_distances",
    "signed_areas", "spacing_warning", "tissue_mask", "triangle_angles", "write_gmsh", "write_triangle",
]
