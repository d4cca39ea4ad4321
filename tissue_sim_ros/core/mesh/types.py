"""The mesh type: :class:`TissueMesh` (vertices in metres, counter-clockwise triangles, unique sorted
edges, boundary and body tags), building one from arrays or several meshes, structured
rectangles for tests and benchmarks, and the size guard (``max_particles``)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import InputError

#: Meshes estimated to have more vertices than this are refused before meshing (the ``max_particles``
#: parameter): meshing takes ~1 min per 100k vertices and a step ~10 ms per 20k particles, so a spacing
#: typed one digit off (1e-4 m for 1e-2 m) would otherwise run for hours or exhaust memory.
MAX_PARTICLES = 300_000


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
    body_names: tuple[str, ...] = ()
    """Name of each body (its file, or its region of the image), B strings; empty: :attr:`names` derives them."""

    def __post_init__(self) -> None:
        names = tuple(str(n) for n in self.body_names)
        object.__setattr__(self, "body_names", names)
        if names and len(names) != self.n_bodies:
            raise InputError(f"mesh has {self.n_bodies} bodies but {len(names)} body names: expected one name per body")

    @property
    def n_bodies(self) -> int:
        return int(self.body.max()) + 1 if len(self.body) else 0

    @property
    def names(self) -> tuple[str, ...]:
        """Name of each body: :attr:`body_names`, or names from the bodies' positions (:func:`region_names`)."""
        return self.body_names if self.body_names else region_names(self.vertices, self.body)

    @property
    def tri_body(self) -> np.ndarray:
        """Body index of each triangle, shape (T,), int32."""
        return self.body[self.triangles[:, 0]]

    def save(self, path: str | Path) -> None:
        """Write the mesh as a compressed .npz."""
        np.savez_compressed(path, vertices=self.vertices, triangles=self.triangles,
                            edges=self.edges, boundary=self.boundary, body=self.body,
                            body_names=np.array(self.names, dtype=str))

    def with_names(self, names: "tuple[str, ...] | list[str]") -> "TissueMesh":
        """The same mesh with other body names (one per body)."""
        return TissueMesh(vertices=self.vertices, triangles=self.triangles, edges=self.edges,
                          boundary=self.boundary, body=self.body, body_names=tuple(names))


def region_names(vertices: np.ndarray, body: np.ndarray) -> tuple[str, ...]:
    """Names of bodies from where they lie (for meshes without file names, e.g. an image's regions).

    One body: ``tissue``; two: ``upper tissue`` / ``lower tissue`` by centroid y
    (whichever index each has); more: ``region k`` with k counted from the top
    (descending centroid y, then ascending x).
    """
    nb = int(body.max()) + 1 if len(body) else 0
    if nb == 0:
        return ()
    if nb == 1:
        return ("tissue",)
    cen = np.array([vertices[body == b].mean(axis=0) if np.any(body == b) else (0.0, 0.0) for b in range(nb)])
    order = sorted(range(nb), key=lambda b: (-round(float(cen[b, 1]), 12), round(float(cen[b, 0]), 12)))
    names = [""] * nb
    if nb == 2:
        names[order[0]], names[order[1]] = "upper tissue", "lower tissue"
    else:
        for rank, b in enumerate(order):
            names[b] = f"region {rank}"
    return tuple(names)


def combine_meshes(meshes: "list[TissueMesh] | tuple[TissueMesh, ...]",
                   names: "list[list[str]] | None" = None) -> TissueMesh:
    """Several meshes as one scene: vertices and triangles concatenated in order, bodies renumbered.

    Mesh k's vertices follow those of meshes 0..k-1 (so its vertex i becomes
    ``i + sum of the earlier vertex counts``), its bodies follow theirs, and
    every vertex, triangle, edge and boundary flag is kept. ``names[k]`` names
    mesh k's bodies (default: each mesh's own :attr:`TissueMesh.names`); a name
    used twice gets `` (2)``, `` (3)``... so every body's name is its own.
    """
    if not meshes:
        raise InputError("no meshes to combine: expected at least one mesh file")
    verts, tris, edges, bnd, body, all_names = [], [], [], [], [], []
    n_off = 0
    b_off = 0
    for k, m in enumerate(meshes):
        verts.append(m.vertices)
        tris.append(m.triangles.astype(np.int64) + n_off)
        edges.append(m.edges.astype(np.int64) + n_off)
        bnd.append(m.boundary)
        body.append(m.body.astype(np.int64) + b_off)
        mine = list(names[k]) if names is not None else list(m.names)
        if len(mine) != m.n_bodies:
            raise InputError(f"mesh {k} has {m.n_bodies} bodies but {len(mine)} names: expected one name per body")
        all_names += mine
        n_off += len(m.vertices)
        b_off += m.n_bodies
    seen: dict[str, int] = {}
    unique = []
    for n in all_names:
        seen[n] = seen.get(n, 0) + 1
        unique.append(n if seen[n] == 1 else f"{n} ({seen[n]})")
    return TissueMesh(vertices=np.ascontiguousarray(np.concatenate(verts), dtype=np.float64),
                      triangles=np.ascontiguousarray(np.concatenate(tris), dtype=np.int32),
                      edges=np.ascontiguousarray(np.concatenate(edges), dtype=np.int32),
                      boundary=np.concatenate(bnd).astype(bool),
                      body=np.ascontiguousarray(np.concatenate(body), dtype=np.int32), body_names=tuple(unique))


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
                   origin: tuple[float, float] = (0.0, 0.0), max_particles: int | None = MAX_PARTICLES) -> TissueMesh:
    """A structured strip [x0, x0+width] x [y0, y0+height] of right triangles with alternating diagonals.

    Used by tests and benchmarks: its area, vertex count and rows are known exactly.
    More than ``max_particles`` vertices are refused before anything is built (None: no limit).
    """
    if not (np.isfinite([width, height, spacing]).all() and spacing > 0 and width > 0 and height > 0):
        raise InputError(f"mesh_rectangle needs finite width, height, spacing > 0; got {width}, {height}, {spacing}")
    with np.errstate(over="ignore"):
        nx_f, ny_f = (max(1.0, float(np.rint(np.float64(side) / spacing))) for side in (width, height))
    check_mesh_size((nx_f + 1.0) * (ny_f + 1.0), _max_particles(max_particles),
                    f"a {width:g} m x {height:g} m strip at spacing {spacing:.4g} m")
    nx, ny = int(nx_f), int(ny_f)
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


def estimate_vertices(area: float, spacing: float) -> float:
    """Vertices of a mesh of ``area`` [m^2] at edge length ``spacing`` [m]: 2 A / (sqrt(3) h^2).

    A hexagonal lattice of spacing h has one vertex per sqrt(3) h^2 / 2 of area
    (two equilateral triangles of area sqrt(3) h^2 / 4 per vertex); the boundary
    adds about perimeter / h more, small for any mesh worth refusing. Returns
    inf rather than overflowing for absurd spacings.
    """
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        n = 2.0 * float(area) / (np.sqrt(3.0) * float(spacing) ** 2)
    return float(n) if np.isfinite(n) else float("inf")


def check_mesh_size(n_estimate: float, max_particles: int | None, what: str) -> None:
    """InputError when a mesh's estimated vertex count exceeds ``max_particles`` (None: no limit)."""
    if max_particles is None:
        return
    if not n_estimate <= max_particles:
        about = f"about {n_estimate:.3g}" if np.isfinite(n_estimate) else "over 1e308"
        raise InputError(f"{what} would have {about} particles, over the limit max_particles={max_particles}: "
                         "expected a larger spacing (or a larger max_particles if you mean it)")


def _max_particles(value: int | None) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise InputError(f"max_particles={value!r}: expected a whole number >= 1 (or None: no limit)")
    return int(value)


def _positive(name: str, value: float) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name}={value!r}: expected a number > 0") from None
    if not np.isfinite(v) or v <= 0:
        raise InputError(f"{name}={value!r}: expected a number > 0")
    return v


#: Reports meshing progress: (fraction done in [0, 1], what it is doing). Meshing an image takes minutes at fine
#: spacings, with nothing to show for it otherwise.
Progress = Callable[[float, str], None]


def spacing_warning(spacing: float, scale: float, spacing_name: str = "--spacing",
                    scale_name: str = "--scale") -> str | None:
    """A line saying that ``spacing`` [m] is below the image's pixel ``scale`` [m/px], or None when it is not.

    The outline comes from the pixels, so a finer mesh only adds vertices (and minutes of meshing) inside
    detail the image does not have.
    """
    if spacing < scale:
        return (f"{spacing_name} {spacing:g} m is {spacing / scale:.2g} of the image's pixel ({scale_name} {scale:g} "
                f"m/px): the image holds no detail finer than a pixel, so the mesh only grows (expected a spacing "
                f"of at least {scale:g} m)")
    return None
