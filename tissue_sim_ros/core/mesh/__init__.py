"""The tissue's mesh: the :class:`TissueMesh` type, meshing an image, mesh files and mesh quality.

A tissue image becomes a triangle mesh in metres (outline, boundary resampling,
constrained Delaunay, smoothing); a mesh is also read from and written to
``.npz``, Triangle (``.node``/``.ele``/``.poly``) and Gmsh (``.msh``) files.
Imports only :mod:`tissue_sim_ros.core.errors`: everything else in the core
builds on this package.
"""
from .triangulate import *  # noqa: F401,F403
from .triangulate import MAX_PARTICLES, OUTLINE_CORNERS, TissueMesh  # noqa: F401
