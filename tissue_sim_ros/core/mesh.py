"""Tissue meshes: the TissueMesh type, structured test meshes, and image -> mesh.

Vertices are in metres in the world frame (x right, y up). Triangles are
counter-clockwise; edges are unique and sorted (i < j); every vertex belongs to
one body (a connected tissue region).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import InputError


@dataclass(frozen=True, eq=False)
class TissueMesh:
    """A 2D triangle mesh of one or more tissue bodies."""

    vertices: np.ndarray
    """Vertex positions [m], shape (N, 2), float64."""
    triangles: np.ndarray
    """Vertex indices, counter-clockwise, shape (T, 3), int32."""
    edges: np.ndarray
    """Unique edges (i < j), shape (E, 2), int32."""
    boundary: np.ndarray
    """True for vertices on a tissue boundary (outer contour or hole), shape (N,), bool."""
    body: np.ndarray
    """Body index of each vertex, shape (N,), int32, bodies numbered 0..B-1."""

    @property
    def n_bodies(self) -> int:
        return int(self.body.max()) + 1 if len(self.body) else 0

    @property
    def tri_body(self) -> np.ndarray:
        """Body index of each triangle, shape (T,), int32."""
        return self.body[self.triangles[:, 0]]

    def save(self, path: str | Path) -> None:
        """Write the mesh as a compressed .npz."""
        np.savez_compressed(path, vertices=self.vertices, triangles=self.triangles,
                            edges=self.edges, boundary=self.boundary, body=self.body)


def edges_from_triangles(triangles: np.ndarray) -> np.ndarray:
    """Unique sorted edges (i < j) of a triangle list, shape (E, 2), int32."""
    tris = np.asarray(triangles, dtype=np.int64)
    if tris.size == 0:
        return np.zeros((0, 2), dtype=np.int32)
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    e.sort(axis=1)
    return np.unique(e, axis=0).astype(np.int32)


def boundary_vertices(triangles: np.ndarray, n_vertices: int) -> np.ndarray:
    """Vertices on an edge used by exactly one triangle, shape (N,), bool."""
    tris = np.asarray(triangles, dtype=np.int64)
    mask = np.zeros(n_vertices, dtype=bool)
    if tris.size == 0:
        return mask
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    e.sort(axis=1)
    uniq, counts = np.unique(e, axis=0, return_counts=True)
    mask[uniq[counts == 1].ravel()] = True
    return mask


def connected_bodies(triangles: np.ndarray, n_vertices: int) -> np.ndarray:
    """Body index per vertex from triangle connectivity (union-find), shape (N,), int32."""
    parent = np.arange(n_vertices)

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a, b, c in np.asarray(triangles, dtype=np.int64):
        ra, rb, rc = find(a), find(b), find(c)
        parent[rb] = ra
        parent[find(rc)] = ra
    roots = np.array([find(i) for i in range(n_vertices)], dtype=np.int64)
    _, body = np.unique(roots, return_inverse=True)
    return body.astype(np.int32)


def mesh_from_arrays(vertices: np.ndarray, triangles: np.ndarray, body: np.ndarray | None = None) -> TissueMesh:
    """Build a TissueMesh from vertices and triangles, orienting triangles CCW.

    Raises InputError for out-of-range indices or zero-area triangles.
    """
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    t = np.ascontiguousarray(triangles, dtype=np.int32).reshape(-1, 3)
    if v.ndim != 2 or v.shape[1] != 2:
        raise InputError(f"vertices have shape {v.shape}: expected (N, 2)")
    if t.size and (t.min() < 0 or t.max() >= len(v)):
        raise InputError(f"triangle indices must lie in [0, {len(v)}); got [{t.min()}, {t.max()}]")
    if t.size:
        a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
        area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
        if np.any(area2 == 0):
            raise InputError(f"{int(np.sum(area2 == 0))} zero-area triangles: expected none")
        flip = area2 < 0
        t = t.copy()
        t[flip, 1], t[flip, 2] = t[flip, 2].copy(), t[flip, 1].copy()
    body = connected_bodies(t, len(v)) if body is None else np.ascontiguousarray(body, dtype=np.int32)
    return TissueMesh(vertices=v, triangles=t, edges=edges_from_triangles(t),
                      boundary=boundary_vertices(t, len(v)), body=body)


def mesh_rectangle(width: float = 1.0, height: float = 0.5, spacing: float = 0.05,
                   origin: tuple[float, float] = (0.0, 0.0)) -> TissueMesh:
    """A structured strip [x0, x0+width] x [y0, y0+height] of right triangles with alternating diagonals.

    Used by tests and benchmarks: its area, vertex count and rows are known exactly.
    """
    if spacing <= 0 or width <= 0 or height <= 0:
        raise InputError(f"mesh_rectangle needs width, height, spacing > 0; got {width}, {height}, {spacing}")
    nx = max(1, int(round(width / spacing)))
    ny = max(1, int(round(height / spacing)))
    xs = origin[0] + np.linspace(0.0, width, nx + 1)
    ys = origin[1] + np.linspace(0.0, height, ny + 1)
    gx, gy = np.meshgrid(xs, ys)
    vertices = np.stack([gx.ravel(), gy.ravel()], axis=1)
    tris = []
    for j in range(ny):
        for i in range(nx):
            v00 = j * (nx + 1) + i
            v10, v01, v11 = v00 + 1, v00 + nx + 1, v00 + nx + 2
            if (i + j) % 2 == 0:
                tris += [(v00, v10, v11), (v00, v11, v01)]
            else:
                tris += [(v00, v10, v01), (v10, v11, v01)]
    return mesh_from_arrays(vertices, np.array(tris, dtype=np.int32))


def load_mesh(path: str | Path) -> TissueMesh:
    """Load a mesh saved by :meth:`TissueMesh.save` (.npz).

    Triangle .node/.ele and Gmsh .msh loaders are added alongside.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"mesh file {str(path)!r} does not exist")
    if path.suffix == ".npz":
        with np.load(path) as data:
            return TissueMesh(vertices=data["vertices"].astype(np.float64), triangles=data["triangles"].astype(np.int32),
                              edges=data["edges"].astype(np.int32), boundary=data["boundary"].astype(bool),
                              body=data["body"].astype(np.int32))
    raise InputError(f"mesh file {str(path)!r}: expected a .npz, Triangle .node/.ele or Gmsh .msh file")
