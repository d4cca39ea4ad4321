"""Tissue meshes: the TissueMesh type, structured test meshes, image -> mesh, quality, mesh files.

Vertices are in metres in the world frame (x right, y up). Triangles are
counter-clockwise; edges are unique and sorted (i < j); every vertex belongs to
one body (a connected tissue region).

* :func:`mesh_from_image` (the paper's "Mesh Generation"): tissue image -> TissueMesh;
* :func:`mesh_quality`: angles, area error, per-body counts (``tissue-sim mesh`` prints them);
* :func:`load_mesh`: .npz, Triangle .node/.ele/.poly, Gmsh .msh 2.2/4.1;
  :func:`load_meshes` / :func:`combine_meshes`: several files as one scene, each body named after its file;
  :func:`write_triangle`, :func:`write_gmsh` for exchange and round trips.
"""
from __future__ import annotations

import re
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError, input_file

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


def mesh_name(path: str | Path) -> str:
    """A body name from a mesh file name: the name without its suffix and Triangle's refinement number.

    ``Bottom.1.node`` -> ``Bottom``, ``upper.npz`` -> ``upper``, ``liver.msh`` -> ``liver``.
    """
    name = Path(path).name
    for suffix in MESH_SUFFIXES:
        if name.lower().endswith(suffix):
            name = name[: -len(suffix)]
            break
    return re.sub(r"\.\d+$", "", name) or Path(path).name


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


def load_meshes(paths: "str | Path | list[str | Path] | tuple[str | Path, ...]") -> TissueMesh:
    """Load one or several mesh files as one scene (:func:`combine_meshes`), each body named after its file.

    A file holding one body names it after the file (:func:`mesh_name`); a file
    holding several names them ``stem[0]``, ``stem[1]``, ... in its own body order
    (descending centroid y); an .npz written with body names keeps them. A
    missing or unreadable file is an InputError naming it.
    """
    if isinstance(paths, (str, Path)):
        paths = [paths]
    paths = list(paths)
    if not paths:
        raise InputError("mesh_file: expected at least one mesh file")
    meshes, names = [], []
    for p in paths:
        m = load_mesh(p)
        meshes.append(m)
        if m.body_names:
            names.append(list(m.body_names))
        else:
            stem = mesh_name(p)
            names.append([stem] if m.n_bodies == 1 else [f"{stem}[{b}]" for b in range(m.n_bodies)])
    return combine_meshes(meshes, names)


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


MESH_SUFFIXES = (".npz", ".node", ".ele", ".poly", ".msh")
"""File suffixes :func:`load_mesh` reads."""


def load_mesh(path: str | Path) -> TissueMesh:
    """Load a mesh file into a TissueMesh.

    * ``.npz``: written by :meth:`TissueMesh.save` (kept exactly, bodies included);
    * Triangle ``.node`` + ``.ele`` (given either, or a ``.poly`` whose ``.node``/``.ele``
      or ``.1.node``/``.1.ele`` lie beside it); 0- or 1-based numbering, attributes and
      boundary markers allowed, 6-node triangles use their corners;
    * Gmsh ``.msh`` ASCII format 2.2 or 4.1, 2D: nodes and 3-node triangles (element
      type 2); other elements are ignored, unused nodes dropped.

    For Triangle and Gmsh files triangles are oriented counter-clockwise, the
    boundary comes from the topology, and bodies (connected components) are numbered
    by descending centroid y like image meshes.
    """
    path = input_file(path, "mesh file")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        expected = "expected an .npz written by TissueMesh.save (vertices, triangles, edges, boundary, body)"
        if not zipfile.is_zipfile(path):  # np.load would try it as a pickle and talk about allow_pickle
            raise InputError(f"mesh file {str(path)!r} is not a valid .npz mesh (not an .npz archive): {expected}")
        try:
            with np.load(path, allow_pickle=False) as data:
                missing = [k for k in ("vertices", "triangles", "edges", "boundary", "body") if k not in data.files]
                if missing:
                    raise InputError(f"mesh file {str(path)!r} is not a valid .npz mesh (no {', '.join(missing)}): "
                                     f"{expected}")
                names = tuple(str(n) for n in data["body_names"]) if "body_names" in data.files else ()
                return TissueMesh(vertices=data["vertices"].astype(np.float64),
                                  triangles=data["triangles"].astype(np.int32),
                                  edges=data["edges"].astype(np.int32), boundary=data["boundary"].astype(bool),
                                  body=data["body"].astype(np.int32), body_names=names)
        except (KeyError, ValueError, TypeError, OSError, EOFError, zipfile.BadZipFile) as exc:
            if isinstance(exc, InputError):
                raise
            why = " ".join(str(exc).split(". ")[0].split())  # the first sentence, on one line
            raise InputError(f"mesh file {str(path)!r} is not a valid .npz mesh ({why}): {expected}") from None
    if suffix in (".node", ".ele", ".poly"):
        vertices, triangles = _read_triangle(path)
    elif suffix == ".msh":
        vertices, triangles = _read_gmsh(path)
    else:
        raise InputError(f"mesh file {str(path)!r}: expected a .npz, Triangle .node/.ele/.poly or Gmsh .msh file")
    return _mesh_from_file_arrays(vertices, triangles, str(path))


def _mesh_from_file_arrays(vertices: np.ndarray, triangles: np.ndarray, name: str) -> TissueMesh:
    """Mesh from loaded arrays: unused vertices dropped, bodies ordered by descending centroid y."""
    if not len(triangles):
        raise InputError(f"mesh file {name!r} has no triangles: expected a 2D triangle mesh")
    if triangles.min() < 0 or triangles.max() >= len(vertices):
        raise InputError(f"mesh file {name!r}: triangle corners must be node numbers of the file; "
                         f"got indices in [{triangles.min()}, {triangles.max()}] for {len(vertices)} nodes")
    used = np.zeros(len(vertices), dtype=bool)
    used[triangles.ravel()] = True
    if not used.all():
        remap = np.cumsum(used) - 1
        vertices, triangles = vertices[used], remap[triangles]
    try:
        mesh = mesh_from_arrays(vertices, triangles)
    except InputError as exc:
        raise InputError(f"mesh file {name!r}: {exc}") from None
    return _order_bodies(mesh)


def _order_bodies(mesh: TissueMesh) -> TissueMesh:
    """The same mesh with bodies renumbered by descending centroid y, then ascending x."""
    nb = mesh.n_bodies
    cen = np.array([mesh.vertices[mesh.body == b].mean(axis=0) for b in range(nb)])
    order = sorted(range(nb), key=lambda b: (-round(cen[b, 1], 12), round(cen[b, 0], 12)))
    new_id = np.empty(nb, dtype=np.int32)
    new_id[order] = np.arange(nb, dtype=np.int32)
    return TissueMesh(vertices=mesh.vertices, triangles=mesh.triangles, edges=mesh.edges,
                      boundary=mesh.boundary, body=new_id[mesh.body])


def _data_lines(path: Path) -> list[list[str]]:
    """Non-empty lines of a Triangle file split into fields, '#' comments removed."""
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise InputError(f"mesh file {str(path)!r} is not text: expected a Triangle ASCII file") from None
    return [ln.split("#", 1)[0].split() for ln in text.splitlines() if ln.split("#", 1)[0].strip()]


def _read_triangle(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (N, 2) and 0-based triangles (T, 3) from Triangle's .node/.ele (found from .node, .ele or .poly)."""
    stem = path.with_suffix("")
    candidates = [stem] if path.suffix.lower() != ".poly" else [stem, stem.with_name(stem.name + ".1")]
    for s in candidates:
        node = Path(str(s) + ".node")
        ele = Path(str(s) + ".ele")
        if node.is_file() and ele.is_file():
            break
    else:
        tried = ", ".join(f"{s}.node + {s}.ele" for s in candidates)
        raise InputError(f"Triangle mesh {str(path)!r}: expected {tried} (both files)")
    rows = _data_lines(node)
    try:
        n, dim, n_attr, n_mark = (int(v) for v in (rows[0] + ["0", "0", "0"])[:4])
        if dim != 2:
            raise InputError(f"Triangle node file {str(node)!r} has dimension {dim}: expected 2")
        body = rows[1:1 + n]
        if len(body) < n:
            raise InputError(f"Triangle node file {str(node)!r} lists {len(body)} nodes: its header says {n}")
        ids = np.array([int(r[0]) for r in body], dtype=np.int64)
        xy = np.array([[float(r[1]), float(r[2])] for r in body], dtype=np.float64)
        erows = _data_lines(ele)
        nt, per = int(erows[0][0]), int(erows[0][1])
        if per not in (3, 6):
            raise InputError(f"Triangle element file {str(ele)!r} has {per} nodes per triangle: expected 3 or 6")
        tri_ids = np.array([[int(v) for v in r[1:4]] for r in erows[1:1 + nt]], dtype=np.int64).reshape(-1, 3)
    except (ValueError, IndexError):
        raise InputError(f"Triangle mesh {str(node)!r}/{str(ele)!r}: expected Triangle's .node/.ele format "
                         "(a header line, then one numbered line per node / triangle)") from None
    # node numbers may start at 0 or 1 (or anywhere): map them through the node list
    return xy, _map_ids(ids, tri_ids, f"{node} / {ele}")


def _map_ids(ids: np.ndarray, tri_ids: np.ndarray, name: str) -> np.ndarray:
    """Triangles given by node numbers (T, 3) -> 0-based indices into the node list."""
    order = np.argsort(ids)
    sid = ids[order]
    if len(np.unique(sid)) != len(sid):
        raise InputError(f"mesh {name!r}: node numbers repeat: expected unique node numbers")
    pos = np.clip(np.searchsorted(sid, tri_ids), 0, len(sid) - 1)
    if not np.all(sid[pos] == tri_ids):
        bad = tri_ids[sid[pos] != tri_ids][0]
        raise InputError(f"mesh {name!r}: a triangle uses node {bad}, which is not in the node list")
    return order[pos]


def _read_gmsh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (N, 2) and 0-based triangles (T, 3) from an ASCII Gmsh .msh file, format 2.2 or 4.1."""
    name = str(path)
    try:
        lines = path.read_text().splitlines()
    except UnicodeDecodeError:
        raise InputError(f"Gmsh file {name!r} is not ASCII: expected an ASCII .msh (format 2.2 or 4.1); "
                         "save it with 'gmsh -format msh22 -save_all' or Mesh.Binary=0") from None
    sections: dict[str, list[str]] = {}
    i = 0
    while i < len(lines):
        ln = lines[i].strip()
        if ln.startswith("$") and not ln.startswith("$End"):
            tag = ln[1:]
            j = i + 1
            while j < len(lines) and lines[j].strip() != f"$End{tag}":
                j += 1
            sections[tag] = lines[i + 1:j]
            i = j
        i += 1
    if "MeshFormat" not in sections or "Nodes" not in sections or "Elements" not in sections:
        raise InputError(f"Gmsh file {name!r}: expected $MeshFormat, $Nodes and $Elements sections")
    fmt = sections["MeshFormat"][0].split()
    version, binary = fmt[0], fmt[1] if len(fmt) > 1 else "0"
    if binary != "0":
        raise InputError(f"Gmsh file {name!r} is binary: expected an ASCII .msh (format 2.2 or 4.1)")
    try:
        if version.startswith("2"):
            ids, xyz, tri_ids = _gmsh2(sections)
        elif version.startswith("4"):
            ids, xyz, tri_ids = _gmsh4(sections)
        else:
            raise InputError(f"Gmsh file {name!r} has format {version}: expected 2.2 or 4.1")
    except (ValueError, IndexError):
        raise InputError(f"Gmsh file {name!r}: malformed $Nodes/$Elements for format {version}") from None
    if len(xyz) and np.ptp(xyz[:, 2]) > 1e-9 * max(1.0, float(np.ptp(xyz[:, :2]))):
        raise InputError(f"Gmsh file {name!r} has nodes off a plane z = const: expected a 2D mesh")
    if not len(tri_ids):
        raise InputError(f"Gmsh file {name!r} has no 3-node triangles (element type 2): expected a 2D triangle mesh")
    return xyz[:, :2].copy(), _map_ids(ids, tri_ids, name)


def _gmsh2(sec: dict[str, list[str]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    nodes = sec["Nodes"]
    n = int(nodes[0])
    arr = np.array([ln.split()[:4] for ln in nodes[1:1 + n]], dtype=np.float64).reshape(-1, 4)
    elems = sec["Elements"]
    tris = []
    for ln in elems[1:1 + int(elems[0])]:
        f = ln.split()
        if int(f[1]) == 2:  # 3-node triangle: id type ntags tags... n1 n2 n3
            tris.append([int(v) for v in f[3 + int(f[2]):6 + int(f[2])]])
    return arr[:, 0].astype(np.int64), arr[:, 1:4], np.array(tris, dtype=np.int64).reshape(-1, 3)


def _gmsh4(sec: dict[str, list[str]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    nodes = sec["Nodes"]
    n_blocks = int(nodes[0].split()[0])
    ids, xyz, k = [], [], 1
    for _ in range(n_blocks):
        _, _, parametric, m = (int(v) for v in nodes[k].split()[:4])
        k += 1
        ids += [int(nodes[k + q]) for q in range(m)]
        xyz += [[float(v) for v in nodes[k + m + q].split()[:3]] for q in range(m)]
        k += 2 * m
    elems = sec["Elements"]
    n_blocks = int(elems[0].split()[0])
    tris, k = [], 1
    for _ in range(n_blocks):
        _, _, etype, m = (int(v) for v in elems[k].split()[:4])
        k += 1
        if etype == 2:
            tris += [[int(v) for v in elems[k + q].split()[1:4]] for q in range(m)]
        k += m
    return (np.array(ids, dtype=np.int64), np.array(xyz, dtype=np.float64).reshape(-1, 3),
            np.array(tris, dtype=np.int64).reshape(-1, 3))


def write_triangle(mesh: TissueMesh, stem: str | Path, first_index: int = 1) -> tuple[Path, Path]:
    """Write Triangle's ``stem.node`` (with boundary markers) and ``stem.ele``; returns both paths."""
    stem = Path(stem)
    node, ele = Path(str(stem) + ".node"), Path(str(stem) + ".ele")
    idx = np.arange(len(mesh.vertices)) + first_index
    with open(node, "w") as f:
        f.write(f"{len(mesh.vertices)} 2 0 1\n")
        for i, (x, y), b in zip(idx, mesh.vertices, mesh.boundary):
            f.write(f"{i} {float(x)!r} {float(y)!r} {int(b)}\n")
    with open(ele, "w") as f:
        f.write(f"{len(mesh.triangles)} 3 0\n")
        for k, (a, b, c) in enumerate(mesh.triangles + first_index):
            f.write(f"{k + first_index} {a} {b} {c}\n")
    return node, ele


def write_gmsh(mesh: TissueMesh, path: str | Path, version: str = "2.2") -> Path:
    """Write an ASCII Gmsh .msh (format ``"2.2"`` or ``"4.1"``) of the mesh's nodes and triangles (z = 0)."""
    path = Path(path)
    v, t = mesh.vertices, mesh.triangles + 1
    n, m = len(v), len(t)
    out = ["$MeshFormat", f"{version} 0 8", "$EndMeshFormat", "$Nodes"]
    if version == "2.2":
        out.append(str(n))
        out += [f"{i + 1} {float(x)!r} {float(y)!r} 0" for i, (x, y) in enumerate(v)]
        out += ["$EndNodes", "$Elements", str(m)]
        out += [f"{k + 1} 2 2 0 1 {a} {b} {c}" for k, (a, b, c) in enumerate(t)]
    elif version == "4.1":
        out += [f"1 {n} 1 {n}", f"2 1 0 {n}"]
        out += [str(i + 1) for i in range(n)]
        out += [f"{float(x)!r} {float(y)!r} 0" for x, y in v]
        out += ["$EndNodes", "$Elements", f"1 {m} 1 {m}", f"2 1 2 {m}"]
        out += [f"{k + 1} {a} {b} {c}" for k, (a, b, c) in enumerate(t)]
    else:
        raise InputError(f"Gmsh format {version!r}: expected '2.2' or '4.1'")
    out.append("$EndElements")
    path.write_text("\n".join(out) + "\n")
    return path


# ---------------------------------------------------------------------------
# Image -> mesh
# ---------------------------------------------------------------------------

#: Images larger than this many pixels are refused (memory and time grow with the pixel count).
MAX_PIXELS = 50_000_000
#: Tissue regions and holes with fewer pixels than this are treated as image noise (dropped / filled).
MIN_REGION_PX = 16
#: Interior lattice points closer than this many local spacings to the boundary are dropped.
_INTERIOR_CLEARANCE = 0.6
#: Graded spacing grows by this much per unit distance outside the fine disc (slow growth keeps angles good).
_GRADING_SLOPE = 0.3


@dataclass(frozen=True)
class Grading:
    """Finer spacing near a point of interest, growing smoothly to the mesh spacing away from it.

    The local target edge length at world point p is
    ``min(spacing, fine_spacing + 0.3 * max(0, |p - (x, y)| - radius))``.
    """

    x: float
    """Centre of the fine region, world x [m]."""
    y: float
    """Centre of the fine region, world y [m]."""
    radius: float
    """Radius of the disc meshed at ``fine_spacing`` [m]."""
    fine_spacing: float
    """Target edge length inside the disc [m]."""


def _as_grading(grading: Grading | tuple | None, spacing: float) -> Grading | None:
    if grading is None:
        return None
    g = grading if isinstance(grading, Grading) else Grading(*map(float, grading))
    if not all(np.isfinite([g.x, g.y, g.radius, g.fine_spacing])):
        raise InputError(f"grading {g}: expected finite x, y, radius, fine_spacing")
    if g.radius < 0 or not 0 < g.fine_spacing <= spacing:
        raise InputError(f"grading radius={g.radius}, fine_spacing={g.fine_spacing}: expected radius >= 0 "
                         f"and 0 < fine_spacing <= spacing={spacing}")
    return g


def read_image(image: str | Path | np.ndarray, max_pixels: int = MAX_PIXELS) -> np.ndarray:
    """Read an image file (PNG/JPEG/BMP/...) or check an array; returns grey (H, W) or BGR (H, W, 3) uint8.

    Raises InputError for a missing file, a file OpenCV cannot decode, a wrong
    array shape, or more than ``max_pixels`` pixels.
    """
    import cv2  # noqa: PLC0415  (OpenCV only when an image is meshed)

    if isinstance(image, np.ndarray):
        name = f"image array of shape {image.shape}"
        img = image
        if img.ndim == 3 and img.shape[2] == 4:
            img = img[:, :, :3]
        if not (img.ndim == 2 or (img.ndim == 3 and img.shape[2] in (1, 3))) or min(img.shape[:2]) < 2:
            raise InputError(f"{name}: expected a grey (H, W) or BGR (H, W, 3) image of at least 2 x 2 pixels")
        if img.ndim == 3 and img.shape[2] == 1:
            img = img[:, :, 0]
        if img.shape[0] * img.shape[1] > max_pixels:
            raise InputError(f"{name} has {img.shape[0] * img.shape[1]} pixels: the limit is {max_pixels}")
        if img.dtype != np.uint8:
            if np.issubdtype(img.dtype, np.floating) and np.nanmax(img) <= 1.0:
                img = img * 255.0
            img = np.clip(np.nan_to_num(img), 0, 255).astype(np.uint8)
        return np.ascontiguousarray(img)
    path = input_file(image, "image file")
    # check the size from the header before decoding a huge image into memory
    header_size = _image_header_size(path)
    if header_size is not None and header_size[0] * header_size[1] > max_pixels:
        raise InputError(f"image {str(path)!r} is {header_size[1]} x {header_size[0]} = "
                         f"{header_size[0] * header_size[1]} pixels: the limit is {max_pixels}")
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise InputError(f"{str(path)!r} is not an image OpenCV can read: expected a PNG, JPEG or BMP file")
    if img.shape[0] * img.shape[1] > max_pixels:
        raise InputError(f"image {str(path)!r} has {img.shape[0] * img.shape[1]} pixels: the limit is {max_pixels}")
    return img


def _image_header_size(path: Path) -> tuple[int, int] | None:
    """(height, width) from a PNG/BMP header without decoding, or None if unknown."""
    with open(path, "rb") as f:
        head = f.read(32)
    if head[:8] == b"\x89PNG\r\n\x1a\n" and len(head) >= 24:
        return int.from_bytes(head[20:24], "big"), int.from_bytes(head[16:20], "big")
    if head[:2] == b"BM" and len(head) >= 26:
        return abs(int.from_bytes(head[22:26], "little", signed=True)), int.from_bytes(head[18:22], "little", signed=True)
    return None


def tissue_mask(image: str | Path | np.ndarray, *, threshold: float | None = None,
                tissue_color: tuple[int, int, int] | None = None, color_tolerance: float = 40.0,
                min_region_px: int = MIN_REGION_PX, max_pixels: int = MAX_PIXELS,
                name: str | None = None) -> np.ndarray:
    """Which pixels are tissue, shape (H, W), bool.

    Tissue is what differs from the background, decided by (in order of precedence)

    * ``tissue_color`` (B, G, R): pixels whose every channel is within ``color_tolerance`` of it;
    * ``threshold``: grey level in [0, 255]; the side of the threshold holding most of the
      image border is background;
    * neither: Otsu's threshold on the grey image, background side again from the border.

    Regions and holes with fewer than ``min_region_px`` pixels are image noise: dropped / filled.
    ``name`` names the image in error messages (default: its path).
    """
    import cv2  # noqa: PLC0415

    img = read_image(image, max_pixels=max_pixels)
    if name is None:
        name = f"image {str(image)!r}" if not isinstance(image, np.ndarray) else "image array"
    if tissue_color is not None:
        color = np.asarray(tissue_color, dtype=np.float64).ravel()
        if color.size != 3 or not np.all((color >= 0) & (color <= 255)):
            raise InputError(f"tissue colour {tissue_color!r}: expected B,G,R in [0, 255]")
        bgr = img if img.ndim == 3 else cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        mask = np.all(np.abs(bgr.astype(np.int16) - color.astype(np.int16)) <= color_tolerance, axis=2)
    else:
        grey = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        if threshold is None:
            if int(grey.max()) == int(grey.min()):
                raise InputError(f"{name} is one flat grey level ({int(grey.min())}): expected tissue that "
                                 "differs from the background")
            t, _ = cv2.threshold(grey, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
            # Otsu always splits; on an image of noise alone the two classes overlap. Tissue on a
            # background gives classes many standard deviations apart (>= 8 on the shipped image).
            g = grey.astype(np.float64)
            lo_c, hi_c = g[g <= t], g[g > t]
            sep = abs(hi_c.mean() - lo_c.mean()) / max(np.sqrt(0.5 * (lo_c.var() + hi_c.var())), 1e-9)
            if sep < 4.0:
                raise InputError(f"{name} has no clear tissue: Otsu's threshold {t:g} splits the grey levels into "
                                 f"classes only {sep:.1f} standard deviations apart (expected >= 4); "
                                 "give a threshold or a tissue colour")
        else:
            t = float(threshold)
            if not 0 <= t <= 255:
                raise InputError(f"threshold {threshold!r}: expected a grey level in [0, 255]")
        above = grey > t
        border = np.concatenate([above[0], above[-1], above[1:-1, 0], above[1:-1, -1]])
        # the background is the class that owns most of the image border
        mask = ~above if border.mean() > 0.5 else above
    mask = _drop_small(mask, min_region_px)
    mask = ~_drop_small(~mask, min_region_px)
    if not mask.any():
        how = (f"colour {tuple(tissue_color)} +- {color_tolerance}" if tissue_color is not None
               else f"grey threshold {threshold}" if threshold is not None else "Otsu's threshold")
        raise InputError(f"{name} has no tissue ({how} leaves no region of >= {min_region_px} pixels): "
                         "expected tissue that differs from the background")
    return mask


def _drop_small(mask: np.ndarray, min_px: int) -> np.ndarray:
    """``mask`` without 8-connected regions of fewer than ``min_px`` pixels."""
    import cv2  # noqa: PLC0415

    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    keep = stats[:, cv2.CC_STAT_AREA] >= min_px
    keep[0] = False
    return keep[labels]


def mesh_from_image(image: str | Path | np.ndarray, *, spacing: float = 0.05, scale: float = 0.002,
                    origin: tuple[float, float] = (0.0, 0.0), threshold: float | None = None,
                    tissue_color: tuple[int, int, int] | None = None, color_tolerance: float = 40.0,
                    grading: Grading | tuple[float, float, float, float] | None = None,
                    max_pixels: int = MAX_PIXELS, max_particles: int | None = MAX_PARTICLES,
                    corners: str = "smooth") -> TissueMesh:
    """Triangle mesh of the tissue in an image (the paper's "Mesh Generation").

    Parameters
    ----------
    image : path or ndarray
        PNG/JPEG/BMP file, or a grey (H, W) / BGR (H, W, 3) uint8 array.
    spacing : float
        Target edge length [m].
    scale : float
        Metres per pixel [m/px].
    origin : (float, float)
        World position [m] of the image's bottom-left corner.
    threshold, tissue_color, color_tolerance
        How tissue is told from background; see :func:`tissue_mask` (default: Otsu).
    grading : Grading or (x, y, radius, fine_spacing), optional
        Finer spacing near a world point; see :class:`Grading`.
    max_pixels : int
        Larger images are refused.
    max_particles : int or None
        A mesh estimated (from the tissue's area and the spacing, see
        :func:`estimate_vertices`) to have more vertices is refused before any
        meshing is done; None: no limit.
    corners : "smooth" or "sharp"
        "sharp": where two straight runs of the outline meet at CORNER_TURN_DEG or more,
        the pixel corner is a vertex and each run between corners is resampled on its
        own, so a straight face ends at the same place at every spacing; "smooth"
        (default, the paper's meshes): the whole outline is resampled by arc length.

    Returns
    -------
    TissueMesh
        World coordinates: image column ``c`` and row ``r`` as continuous pixel
        coordinates (pixel (r, c) covers [c, c+1] x [r, r+1], rows pointing down)
        map to ``x = ox + c*scale``, ``y = oy + (H - r)*scale`` (world y up), so
        the image's bottom-left corner lands at ``origin``. Each 8-connected
        tissue region is one body; bodies are numbered by descending centroid y
        (the upper tissue is body 0), ties by ascending x. Holes stay holes,
        except holes whose rim is shorter than three spacings: too small for
        the mesh to resolve, they are filled.

    Notes
    -----
    Per body: the OpenCV contours (outer + holes, ``RETR_CCOMP``,
    ``CHAIN_APPROX_NONE``) are smoothed by one pixel, moved out from the boundary
    pixels' centres onto the pixel edges, and resampled at the target edge
    length; interior points come from a hexagonal lattice at the same spacing
    (a thinned finer lattice when graded) at least 0.6 spacings from the
    boundary; ``cv2.Subdiv2D`` triangulates; triangles whose centroid lies
    outside the body's polygon are dropped; missing boundary segments are
    recovered by removing encroaching points or splitting the segment; a few
    steps of spring smoothing (Persson-Strang) with re-triangulation move the
    interior points to equalise edges. The boundary points never move.
    """
    spacing, scale = _positive("spacing", spacing), _positive("scale", scale)
    max_particles = _max_particles(max_particles)
    ox, oy = (float(v) for v in origin)
    if not (np.isfinite(ox) and np.isfinite(oy)):
        raise InputError(f"origin {origin!r}: expected two finite numbers [m]")
    g = _as_grading(grading, spacing)
    name = f"image {str(image)!r}" if not isinstance(image, np.ndarray) else "image array"
    mask = tissue_mask(image, threshold=threshold, tissue_color=tissue_color, color_tolerance=color_tolerance,
                       max_pixels=max_pixels, name=name)
    return mesh_from_mask(mask, spacing=spacing, scale=scale, origin=(ox, oy), grading=g, name=name,
                          max_particles=max_particles, corners=corners)


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


def mesh_from_mask(mask: np.ndarray, *, spacing: float = 0.05, scale: float = 0.002,
                   origin: tuple[float, float] = (0.0, 0.0), grading: Grading | tuple | None = None,
                   name: str = "mask", max_particles: int | None = MAX_PARTICLES,
                   corners: str = "smooth") -> TissueMesh:
    """Mesh a boolean tissue mask (H, W); see :func:`mesh_from_image` for the method, world frame and limits."""
    import cv2  # noqa: PLC0415

    if corners not in OUTLINE_CORNERS:
        raise InputError(f"corners={corners!r}: expected one of {', '.join(OUTLINE_CORNERS)}")

    spacing, scale = _positive("spacing", spacing), _positive("scale", scale)
    max_particles = _max_particles(max_particles)
    g = _as_grading(grading, spacing)
    mask = np.ascontiguousarray(mask, dtype=bool)
    H = mask.shape[0]
    ox, oy = float(origin[0]), float(origin[1])
    h_px = spacing / scale
    size = _SizeField(h_px, None if g is None else
                      ((g.x - ox) / scale, H - (g.y - oy) / scale, g.radius / scale, g.fine_spacing / scale))
    # refuse a mesh too large to be meant before any work that grows with it
    check_mesh_size(_estimate_mask_vertices(mask, size), max_particles,
                    f"{name} meshed at spacing {spacing:.4g} m ({mask.sum() * scale * scale:.4g} m^2 of tissue"
                    + (f", graded to {g.fine_spacing:.4g} m" if g is not None else "") + ")")

    contours, hierarchy = cv2.findContours(mask.astype(np.uint8), cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    if not contours:
        raise InputError(f"{name} has no tissue: expected tissue that differs from the background")
    hier = hierarchy[0]
    _, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    dist = cv2.distanceTransform(np.pad(mask, 1).astype(np.uint8), cv2.DIST_L2, 5)[1:-1, 1:-1]

    bodies = []
    for i, c in enumerate(contours):
        if hier[i][3] != -1:
            continue
        holes = []
        child = hier[i][2]
        while child != -1:
            holes.append(contours[child])
            child = hier[child][0]
        r0, c0 = int(c[0, 0, 1]), int(c[0, 0, 0])
        region = labels == labels[r0, c0]
        bodies.append((c, holes, region))
    # world y of the centroid is -(row); descending y = ascending row
    info = []
    for c, holes, region in bodies:
        rows, cols = np.nonzero(region)
        info.append((rows.mean(), cols.mean()))
    order = sorted(range(len(bodies)), key=lambda k: (round(info[k][0], 6), round(info[k][1], 6)))

    all_v, all_t, all_body = [], [], []
    offset = 0
    for bid, k in enumerate(order):
        c, holes, region = bodies[k]
        rows, cols = np.nonzero(region)
        thickness = 2.0 * float(dist[region].max())
        where = (f"{name}: tissue region {bid} (centroid x={ox + (info[k][1] + 0.5) * scale:.4g} m, "
                 f"y={oy + (H - info[k][0] - 0.5) * scale:.4g} m; {cols.max() - cols.min() + 1} x "
                 f"{rows.max() - rows.min() + 1} px, {len(rows)} px, thickest {thickness * scale:.4g} m)")
        local_h = size.h_min_near(rows, cols) if g is not None else h_px
        if thickness < local_h:
            raise InputError(f"{where} is thinner than the spacing {local_h * scale:.4g} m: expected tissue at "
                             "least one spacing thick (use a smaller --spacing or a larger --scale)")
        # a hole whose rim is shorter than three local spacings cannot be resolved by the mesh: it is filled
        holes = [hc for hc in holes
                 if cv2.arcLength(hc, True) >= 3.0 * float(size(hc[:, 0, :].mean(axis=0) + 0.5)[0])]
        loops = ([_boundary_loop(c, size, outer=True, corners=corners)]
                 + [_boundary_loop(hc, size, outer=False, corners=corners) for hc in holes])
        pts, tris = _mesh_body(loops, size)
        if len(tris) < 3:
            raise InputError(f"{where} gives only {len(tris)} triangles at spacing {spacing:.4g} m: "
                             "expected at least 3 (use a smaller --spacing)")
        all_v.append(pts)
        all_t.append(tris + offset)
        all_body.append(np.full(len(pts), bid, dtype=np.int32))
        offset += len(pts)
    v_px = np.concatenate(all_v)
    world = np.stack([ox + v_px[:, 0] * scale, oy + (H - v_px[:, 1]) * scale], axis=1)
    # boundary flags come from the topology (edges used by one triangle), as for every TissueMesh
    return mesh_from_arrays(world, np.concatenate(all_t), np.concatenate(all_body))


class _SizeField:
    """Target edge length [px] over the image: uniform, or graded around a point (pixel coordinates)."""

    def __init__(self, h: float, grade: tuple[float, float, float, float] | None) -> None:
        self.h = h
        self.grade = grade
        self.h_min = h if grade is None else min(h, grade[3])

    def __call__(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, dtype=np.float64).reshape(-1, 2)
        if self.grade is None:
            return np.full(len(p), self.h)
        gx, gy, radius, fine = self.grade
        d = np.hypot(p[:, 0] - gx, p[:, 1] - gy)
        return np.minimum(self.h, fine + _GRADING_SLOPE * np.maximum(0.0, d - radius))

    def h_min_near(self, rows: np.ndarray, cols: np.ndarray) -> float:
        step = max(1, len(rows) // 20000)
        return float(self(np.stack([cols[::step] + 0.5, rows[::step] + 0.5], axis=1)).min())


def _estimate_mask_vertices(mask: np.ndarray, size: _SizeField) -> float:
    """Estimated vertex count of meshing ``mask`` with ``size``: the integral of 2 / (sqrt(3) h^2) over the tissue.

    Uniform: :func:`estimate_vertices` of the tissue's pixel area. Graded: summed
    over tissue pixels (a subsample of at most ~1M, each standing for the pixels it skips).
    """
    n_px = int(np.count_nonzero(mask))
    if size.grade is None:
        return estimate_vertices(n_px, size.h)
    step = max(1, int(np.ceil(np.sqrt(mask.size / 1e6))))
    rows, cols = np.nonzero(mask[::step, ::step])
    if len(rows) == 0:
        return 0.0
    h = size(np.stack([cols * step + 0.5, rows * step + 0.5], axis=1))
    with np.errstate(over="ignore", divide="ignore"):
        n = float(np.sum(2.0 / (np.sqrt(3.0) * h * h))) * n_px / len(rows)
    return n if np.isfinite(n) else float("inf")


#: A corner of the outline is kept as a vertex (``corners="sharp"``) where the outline turns by at least this
#: many degrees between two straight runs (of the 1 px polygon approximation) each at least CORNER_RUN_PX long.
CORNER_TURN_DEG = 60.0
CORNER_RUN_PX = 5.0
#: The outline's corners: "smooth" (every point smoothed and resampled by arc length; the paper scene's meshes)
#: or "sharp" (corners between straight runs stay vertices; each run between two corners resampled on its own).
OUTLINE_CORNERS = ("smooth", "sharp")


def _outline_corners(contour: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sharp corners of a pixel contour: their contour indices (ascending) and positions [px] on the pixel edges.

    A corner is a vertex of the contour's polygon approximation (Douglas-Peucker, 1 px) where the two
    adjacent edges are each at least CORNER_RUN_PX long and the outline turns by at least CORNER_TURN_DEG.
    Each of the two runs is the line fitted (principal axis) through its boundary pixels' centres, two pixels
    trimmed at each end (where an 8-connected contour steps diagonally round a corner), moved out onto the
    pixel edges by ``0.5 * max(|nx|, |ny|)`` as the rest of the loop; the corner is where the two lines meet:
    the corner of the pixel staircase.
    """
    import cv2  # noqa: PLC0415

    none = np.zeros(0, dtype=np.int64), np.zeros((0, 2))
    c = contour[:, 0, :]
    n_c = len(c)
    poly = cv2.approxPolyDP(contour, 1.0, True)[:, 0, :]
    n = len(poly)
    if n < 3:
        return none
    at = [np.nonzero((c[:, 0] == v[0]) & (c[:, 1] == v[1]))[0] for v in poly]
    if any(len(h) == 0 for h in at):
        return none
    vidx = np.array([int(h[0]) for h in at])
    poly = poly.astype(np.float64)
    # outward normal of an edge e = (ex, ey) is (ey, -ex) for a polygon of positive shoelace area
    area2 = float(np.sum(poly[:, 0] * np.roll(poly[:, 1], -1) - np.roll(poly[:, 0], -1) * poly[:, 1]))
    sign = 1.0 if area2 > 0 else -1.0

    def run_line(k: int) -> tuple[np.ndarray, np.ndarray]:
        """Point and unit direction of polygon edge k (vertex k to k+1), on the pixel edges."""
        e = poly[(k + 1) % n] - poly[k]
        i0, i1 = int(vidx[k]), int(vidx[(k + 1) % n])
        inner = np.arange(i0 + 2, (i1 if i1 > i0 else i1 + n_c) - 1) % n_c
        pts = c[inner].astype(np.float64) + 0.5 if len(inner) >= 2 else poly[[k, (k + 1) % n]] + 0.5
        mean = pts.mean(axis=0)
        t = np.linalg.svd(pts - mean)[2][0]
        t = t if float(t @ e) >= 0 else -t
        nrm = sign * np.array([t[1], -t[0]])
        return mean + 0.5 * max(abs(nrm[0]), abs(nrm[1])) * nrm, t

    idx, pos = [], []
    for i in range(n):
        e1, e2 = poly[i] - poly[i - 1], poly[(i + 1) % n] - poly[i]
        l1, l2 = float(np.hypot(*e1)), float(np.hypot(*e2))
        if min(l1, l2) < CORNER_RUN_PX:
            continue
        turn = np.degrees(np.arctan2(e1[0] * e2[1] - e1[1] * e2[0], float(e1 @ e2)))
        if abs(turn) < CORNER_TURN_DEG:
            continue
        (p1, t1), (p2, t2) = run_line(i - 1 if i > 0 else n - 1), run_line(i)
        det = t1[1] * t2[0] - t1[0] * t2[1]  # p1 + s t1 = p2 + u t2, solved for s by Cramer's rule
        if abs(det) < 1e-9:
            continue
        d = p2 - p1
        s_ = (d[1] * t2[0] - d[0] * t2[1]) / det
        idx.append(int(vidx[i]))
        pos.append(p1 + s_ * t1)
    if not idx:
        return none
    order = np.argsort(idx)
    return np.asarray(idx, dtype=np.int64)[order], np.asarray(pos)[order]


def _boundary_loop(contour: np.ndarray, size: _SizeField, outer: bool, corners: str = "smooth") -> np.ndarray:
    """One closed boundary loop [px], resampled at the local spacing, shape (n, 2), float64.

    The contour runs through the centres of the boundary pixels; it is smoothed
    (Gaussian, sigma 1 px) and moved outward onto the pixel edges by
    ``0.5 * max(|nx|, |ny|)`` px (the mean distance from the centre line to the
    pixel staircase), so the polygon's area matches the pixel count. Outer loops
    come out counter-clockwise in pixel coordinates (rows down), holes clockwise,
    i.e. the tissue is always on the same side.

    ``corners="sharp"``: the outline's sharp corners (:func:`_outline_corners`) are vertices at the corners
    of the pixel staircase, and each run between two corners is resampled on its own (its ends fixed), so
    a straight face keeps its ends at every spacing; elsewhere the loop is as with ``"smooth"``.
    """
    cidx, cpos = _outline_corners(contour) if corners == "sharp" else (np.zeros(0, dtype=np.int64), None)
    p = contour[:, 0, :].astype(np.float64) + 0.5  # pixel centres in continuous pixel coordinates
    if len(p) >= 5:
        k = np.array([1.0, 4.0, 6.0, 4.0, 1.0]) / 16.0  # binomial ~ Gaussian sigma 1 px
        ext = np.concatenate([p[-2:], p, p[:2]])
        p = np.stack([np.convolve(ext[:, 0], k, "valid"), np.convolve(ext[:, 1], k, "valid")], axis=1)
    area2 = np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1])
    if (area2 < 0) == outer:
        p = p[::-1]
        if len(cidx):
            cidx, cpos = (len(p) - 1 - cidx)[::-1], cpos[::-1]
    if len(p) >= 3:
        tangent = np.roll(p, -1, axis=0) - np.roll(p, 1, axis=0)
        tn = np.hypot(tangent[:, 0], tangent[:, 1])
        tn[tn == 0] = 1.0
        tangent /= tn[:, None]
        # with the tissue on the left of the direction of travel (in a y-down frame, area2 > 0 for outer),
        # away-from-tissue is (ty, -tx) rotated accordingly
        normal = np.stack([tangent[:, 1], -tangent[:, 0]], axis=1)
        probe = p.mean(axis=0)
        if outer and np.mean(np.sum((p - probe) * normal, axis=1)) < 0:
            normal = -normal
        if not outer and np.mean(np.sum((p - probe) * normal, axis=1)) > 0:
            normal = -normal
        p = p + (0.5 * np.maximum(np.abs(normal[:, 0]), np.abs(normal[:, 1])))[:, None] * normal
    if len(cidx):
        q, fixed = _resample_runs(p, cidx, cpos, size)
    else:
        q, fixed = _resample_loop(p, size), np.zeros(0, dtype=np.int64)
    if len(q) >= 3:
        # chords cut off the bulges of a curved boundary (area ~ h^2 / (12 R) per edge); move the
        # resampled points out along the normal so the polygon keeps the contour's area, by at most
        # 0.4 px so the vertices stay within a pixel of the contour
        def area(x: np.ndarray) -> float:
            return 0.5 * abs(float(np.sum(x[:, 0] * np.roll(x[:, 1], -1) - np.roll(x[:, 0], -1) * x[:, 1])))

        perimeter = float(np.sum(np.hypot(*(np.roll(q, -1, axis=0) - q).T)))
        delta = (area(p) - area(q)) / perimeter * (1.0 if outer else -1.0)
        t = np.roll(q, -1, axis=0) - np.roll(q, 1, axis=0)
        t /= np.maximum(np.hypot(t[:, 0], t[:, 1]), 1e-12)[:, None]
        n = np.stack([t[:, 1], -t[:, 0]], axis=1)
        # orient n away from the tissue: outward for outer loops, into the hole for holes
        if (np.mean(np.sum((q - q.mean(axis=0)) * n, axis=1)) < 0) == outer:
            n = -n
        shift = np.clip(delta, -0.4, 0.4) * n
        shift[fixed] = 0.0  # corners stay on the pixel staircase's corners
        q = q + shift
    return q


def _resample_runs(p: np.ndarray, cidx: np.ndarray, cpos: np.ndarray, size: _SizeField,
                   skip: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Resample a closed loop run by run between its corners; the points and the indices of the corners in them.

    Run k goes from corner k to corner k+1 (cyclically): the corner's position, the loop's points strictly
    between the two corners except ``skip`` points next to each (rounded by the 1 px smoothing), the next
    corner. Each run gets ``max(1, round(length in local spacings))`` equal steps of that length.
    """
    n, m = len(p), len(cidx)
    out, fixed = [], []
    for k in range(m):
        i0, i1 = int(cidx[k]), int(cidx[(k + 1) % m])
        inner = np.arange(i0 + 1 + skip, (i1 if i1 > i0 else i1 + n) - skip) % n
        path = np.concatenate([cpos[k][None], p[inner], cpos[(k + 1) % m][None]])
        seg = np.hypot(*np.diff(path, axis=0).T)
        mid = 0.5 * (path[:-1] + path[1:])
        s = np.concatenate([[0.0], np.cumsum(seg / size(mid))])
        steps = max(1, int(round(s[-1])))
        targets = np.arange(steps) * (s[-1] / steps)  # the run's start, not its end (the next run's start)
        fixed.append(sum(len(o) for o in out))
        out.append(np.stack([np.interp(targets, s, path[:, 0]), np.interp(targets, s, path[:, 1])], axis=1))
    return np.concatenate(out), np.asarray(fixed, dtype=np.int64)


def _resample_loop(p: np.ndarray, size: _SizeField) -> np.ndarray:
    """Resample a closed polyline so consecutive points are about the local target spacing apart."""
    closed = np.concatenate([p, p[:1]])
    seg = np.hypot(*np.diff(closed, axis=0).T)
    mid = 0.5 * (closed[:-1] + closed[1:])
    # arc length measured in local spacings: equal steps of it give edges of about size(x)
    s = np.concatenate([[0.0], np.cumsum(seg / size(mid))])
    n = max(3, int(round(s[-1])))
    targets = np.arange(n) * (s[-1] / n)
    return np.stack([np.interp(targets, s, closed[:, 0]), np.interp(targets, s, closed[:, 1])], axis=1)


def _segments(loops: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Start and end points of every boundary segment of closed loops, each (M, 2)."""
    a = np.concatenate(loops)
    b = np.concatenate([np.roll(lp, -1, axis=0) for lp in loops])
    return a, b


class _Polygon:
    """A body's boundary polygon [px] with fast point queries.

    Exact even-odd and segment-distance tests cost O(points x segments); a
    signed-distance raster of the polygon (1 px cells) answers every point
    farther than 2 px from the boundary, and only the rest get the exact test.
    """

    def __init__(self, loops: list[np.ndarray]) -> None:
        import cv2  # noqa: PLC0415

        self.a, self.b = _segments(loops)
        allp = np.concatenate(loops)
        self.lo = np.floor(allp.min(axis=0)) - 3
        shape = (np.ceil(allp.max(axis=0)) - self.lo + 4).astype(int)
        inside = np.zeros((shape[1], shape[0]), dtype=np.uint8)
        shift = 4  # 1/16 px vertex precision in fillPoly
        polys = [np.round((lp - self.lo - 0.5) * (1 << shift)).astype(np.int32) for lp in loops]
        cv2.fillPoly(inside, polys, 1, lineType=cv2.LINE_8, shift=shift)
        d_in = cv2.distanceTransform(inside, cv2.DIST_L2, 5)
        d_out = cv2.distanceTransform(1 - inside, cv2.DIST_L2, 5)
        self.sdf = np.where(inside > 0, d_in, -d_out).astype(np.float64)

    def _raster(self, p: np.ndarray) -> np.ndarray:
        ij = np.floor(p - self.lo).astype(np.int64)
        ok = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < self.sdf.shape[1]) & (ij[:, 1] < self.sdf.shape[0])
        out = np.full(len(p), -1e9)
        out[ok] = self.sdf[ij[ok, 1], ij[ok, 0]]
        return out

    def inside(self, p: np.ndarray) -> np.ndarray:
        """True for points (n, 2) inside the polygon, (n,) bool."""
        s = self._raster(p)
        out = s > 0
        near = np.abs(s) < 2.5
        if near.any():
            out[near] = _inside(p[near], self.a, self.b)
        return out

    def clear_of_boundary(self, p: np.ndarray, clearance: np.ndarray) -> np.ndarray:
        """True for points inside and at least ``clearance`` (n,) [px] from the boundary, (n,) bool."""
        s = self._raster(p)
        out = s > clearance + 2.5
        unsure = (s > -2.5) & ~out
        if unsure.any():
            q = p[unsure]
            out[unsure] = _inside(q, self.a, self.b) & (_distance(q, self.a, self.b) >= clearance[unsure])
        return out


def _inside(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Even-odd point-in-polygon of points (n, 2) for the polygon with segments a -> b; (n,) bool."""
    px, py = points[:, 0:1], points[:, 1:2]
    ax, ay, bx, by = a[:, 0], a[:, 1], b[:, 0], b[:, 1]
    cond = (ay > py) != (by > py)
    with np.errstate(divide="ignore", invalid="ignore"):
        xint = ax + (py - ay) * (bx - ax) / (by - ay)
    return (np.sum(cond & (px < xint), axis=1) % 2).astype(bool)


def _distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of points (n, 2) to the nearest segment a -> b; (n,) float64."""
    d = b - a
    dd = np.maximum(np.sum(d * d, axis=1), 1e-300)
    out = np.full(len(points), np.inf)
    for s in range(0, len(points), 2048):  # chunks bound the (n, M) temporaries
        p = points[s:s + 2048, None, :]
        t = np.clip(np.sum((p - a) * d, axis=2) / dd, 0.0, 1.0)
        q = a + t[:, :, None] * d
        out[s:s + 2048] = np.sqrt(np.min(np.sum((p - q) ** 2, axis=2), axis=1))
    return out


def _hex_lattice(lo: np.ndarray, hi: np.ndarray, h: float) -> np.ndarray:
    """Hexagonal lattice points with spacing h covering the box [lo, hi], (n, 2)."""
    dy = h * np.sqrt(3.0) / 2.0
    ys = np.arange(lo[1] + 0.5 * dy, hi[1], dy)
    rows = []
    for j, y in enumerate(ys):
        xs = np.arange(lo[0] + (0.25 + 0.5 * (j % 2)) * h, hi[0], h)
        rows.append(np.stack([xs, np.full(len(xs), y)], axis=1))
    return np.concatenate(rows) if rows else np.zeros((0, 2))


def _delaunay(points: np.ndarray) -> np.ndarray:
    """Delaunay triangles (T, 3) of points (n, 2) by cv2.Subdiv2D, as indices into points."""
    import cv2  # noqa: PLC0415

    lo = np.floor(points.min(axis=0)) - 2
    hi = np.ceil(points.max(axis=0)) + 2
    subdiv = cv2.Subdiv2D((int(lo[0]), int(lo[1]), int(hi[0] - lo[0]) + 1, int(hi[1] - lo[1]) + 1))
    p32 = np.ascontiguousarray(points, dtype=np.float32)
    subdiv.insert(p32)
    tl = subdiv.getTriangleList().reshape(-1, 3, 2).astype(np.float32)
    # map the float32 corner coordinates back to point indices through a 64-bit key per point
    keys = p32.view(np.uint64).ravel()
    order = np.argsort(keys)
    sk = keys[order]
    q = np.ascontiguousarray(tl).view(np.uint64).reshape(-1, 3)
    pos = np.clip(np.searchsorted(sk, q), 0, len(sk) - 1)
    found = sk[pos] == q
    tris = order[pos]
    return tris[np.all(found, axis=1)].astype(np.int64)


def _mesh_body(loops: list[np.ndarray], size: _SizeField) -> tuple[np.ndarray, np.ndarray]:
    """Mesh one body from its boundary loops [px]: points (N, 2), boundary first, and triangles (T, 3)."""
    poly = _Polygon(loops)
    lo, hi = np.concatenate(loops).min(axis=0), np.concatenate(loops).max(axis=0)
    if size.grade is None:
        interior = _hex_lattice(lo, hi, size.h)
    else:
        # the regular lattice where the spacing is the coarse one; where it is finer, a lattice at the
        # finest spacing thinned with probability (h_min / h)^2 (Persson-Strang, seeded: deterministic),
        # minus points crowding a coarse lattice point; the spring smoothing evens out the rest
        coarse = _hex_lattice(lo, hi, size.h)
        coarse = coarse[size(coarse) >= 0.999 * size.h]
        fine = _hex_lattice(lo, hi, size.h_min)
        h_fine = size(fine)
        keep = (h_fine < 0.999 * size.h) & (np.random.default_rng(0).random(len(fine)) < (size.h_min / h_fine) ** 2)
        fine, h_fine = fine[keep], h_fine[keep]
        if len(coarse) and len(fine):
            near = np.array([np.min(np.hypot(*(coarse - p).T)) for p in fine])
            fine = fine[near >= _INTERIOR_CLEARANCE * h_fine]
        interior = np.concatenate([coarse, fine])
    if len(interior):
        interior = interior[poly.clear_of_boundary(interior, _INTERIOR_CLEARANCE * size(interior))]
    loops, interior = _recover_boundary(loops, interior)
    poly = _Polygon(loops)
    interior = _smooth(loops, interior, poly, size, iterations=10 if size.grade is None else 30)
    loops, interior = _recover_boundary(loops, interior)
    poly = _Polygon(loops)
    bnd = np.concatenate(loops)
    pts = np.concatenate([bnd, interior])
    tris = _inner_triangles(pts, poly)
    # drop points no kept triangle uses (e.g. a boundary point cut off by a sliver)
    used = np.zeros(len(pts), dtype=bool)
    used[tris.ravel()] = True
    remap = np.cumsum(used) - 1
    return pts[used], remap[tris]


def _edge_keys(tris: np.ndarray, n: int) -> np.ndarray:
    """Unique undirected edges of triangles as int64 keys i * n + j (i < j)."""
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]).astype(np.int64)
    e.sort(axis=1)
    return np.unique(e[:, 0] * n + e[:, 1])


def _inner_triangles(pts: np.ndarray, poly: _Polygon) -> np.ndarray:
    """Delaunay triangles of pts whose centroid is inside the polygon, without slivers."""
    tris = _delaunay(pts)
    if not len(tris):
        return tris
    tris = tris[poly.inside(pts[tris].mean(axis=1))]
    p0, p1, p2 = pts[tris[:, 0]], pts[tris[:, 1]], pts[tris[:, 2]]
    area2 = np.abs((p1[:, 0] - p0[:, 0]) * (p2[:, 1] - p0[:, 1]) - (p1[:, 1] - p0[:, 1]) * (p2[:, 0] - p0[:, 0]))
    longest = np.max(np.stack([np.sum((p1 - p0) ** 2, 1), np.sum((p2 - p1) ** 2, 1), np.sum((p0 - p2) ** 2, 1)]), axis=0)
    return tris[area2 > 1e-6 * longest]  # sine of the smallest angle below ~1e-6: a sliver


def _recover_boundary(loops: list[np.ndarray], interior: np.ndarray,
                      max_rounds: int = 8) -> tuple[list[np.ndarray], np.ndarray]:
    """Make every boundary segment an edge of the Delaunay triangulation.

    A segment missing from the triangulation has a point inside its diametral
    circle: drop interior points that encroach on it, and if none do, split the
    segment at its midpoint (which stays on the polygon).
    """
    for _ in range(max_rounds):
        bnd = np.concatenate(loops)
        n_all = len(bnd) + len(interior)
        keys = _edge_keys(_delaunay(np.concatenate([bnd, interior])), n_all)
        starts = np.cumsum([0] + [len(lp) for lp in loops])
        seg_i = np.concatenate([np.arange(len(lp)) + s for lp, s in zip(loops, starts)])
        seg_j = np.concatenate([np.roll(np.arange(len(lp)), -1) + s for lp, s in zip(loops, starts)])
        missing_all = ~np.isin(np.minimum(seg_i, seg_j) * n_all + np.maximum(seg_i, seg_j), keys)
        if not missing_all.any():
            break
        new_loops, drop = [], np.zeros(len(interior), dtype=bool)
        for li, lp in enumerate(loops):
            n = len(lp)
            missing = missing_all[starts[li]:starts[li + 1]]
            if not missing.any():
                new_loops.append(lp)
                continue
            split = np.zeros(n, dtype=bool)
            for m in np.nonzero(missing)[0]:
                pa, pb = lp[m], lp[(m + 1) % n]
                c, r = 0.5 * (pa + pb), 0.5 * np.hypot(*(pb - pa))
                enc = (np.hypot(interior[:, 0] - c[0], interior[:, 1] - c[1]) < r) if len(interior) else None
                if enc is not None and enc.any():
                    drop |= enc
                else:
                    split[m] = True
            out = []
            for m in range(n):
                out.append(lp[m])
                if split[m]:
                    out.append(0.5 * (lp[m] + lp[(m + 1) % n]))
            new_loops.append(np.array(out))
        loops = new_loops
        interior = interior[~drop]
    return loops, interior


def _smooth(loops: list[np.ndarray], interior: np.ndarray, poly: _Polygon, size: _SizeField,
            iterations: int) -> np.ndarray:
    """Persson-Strang spring smoothing of the interior points with re-triangulation; the boundary stays fixed.

    Each edge pushes its ends apart when shorter than 1.2x its target length
    (scaled so the edges fill the area); a point that would leave the body or
    come closer than 0.3 local spacings to the boundary keeps its place.
    """
    if not len(interior):
        return interior
    bnd = np.concatenate(loops)
    nb = len(bnd)
    pts = np.concatenate([bnd, interior])
    h_loc = size(interior)
    for _ in range(iterations):
        tris = _inner_triangles(pts, poly)
        if not len(tris):
            break
        keys = _edge_keys(tris, len(pts))
        e0, e1 = keys // len(pts), keys % len(pts)
        vec = pts[e0] - pts[e1]
        L = np.hypot(vec[:, 0], vec[:, 1])
        hb = size(0.5 * (pts[e0] + pts[e1]))
        L0 = hb * 1.2 * np.sqrt(np.sum(L ** 2) / np.sum(hb ** 2))
        F = np.maximum(L0 - L, 0.0)
        fvec = (F / np.maximum(L, 1e-12))[:, None] * vec
        force = np.zeros_like(pts)
        np.add.at(force, e0, fvec)
        np.add.at(force, e1, -fvec)
        move = 0.2 * force[nb:]
        new = pts[nb:] + move
        ok = poly.clear_of_boundary(new, 0.3 * size(new))
        pts[nb:][ok] = new[ok]
        if np.max(np.hypot(move[:, 0], move[:, 1]) / h_loc) < 1e-3:
            break
    return pts[nb:].copy()


# ---------------------------------------------------------------------------
# Quality
# ---------------------------------------------------------------------------

def triangle_angles(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Interior angles of each triangle [deg], shape (T, 3), float64."""
    p = np.asarray(vertices, dtype=np.float64)[np.asarray(triangles, dtype=np.int64)]
    out = np.empty((len(p), 3))
    for k in range(3):
        u = p[:, (k + 1) % 3] - p[:, k]
        w = p[:, (k + 2) % 3] - p[:, k]
        cross = np.abs(u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0])
        out[:, k] = np.degrees(np.arctan2(cross, np.sum(u * w, axis=1)))
    return out


def mesh_quality(mesh: TissueMesh, tissue_pixel_area: float | None = None) -> dict:
    """Quality figures of a mesh.

    Parameters
    ----------
    mesh : TissueMesh
    tissue_pixel_area : float, optional
        Area of the tissue in the image [m^2] (tissue pixel count * scale^2), for the area error.

    Returns
    -------
    dict
        ``n_vertices``, ``n_triangles``, ``n_edges``, ``n_boundary``, ``n_bodies``,
        ``min_angle``, ``mean_angle`` (of each triangle's smallest angle) [deg],
        ``frac_min_angle_ge_20``, ``n_min_angle_lt_10``, ``area`` [m^2], ``area_error``
        (relative, NaN without ``tissue_pixel_area``), ``min_signed_area`` [m^2] (> 0: all CCW),
        and ``bodies``: a list of per-body dicts with ``body``, ``n_vertices``,
        ``n_triangles``, ``n_boundary``, ``min_angle``, ``mean_angle``, ``frac_min_angle_ge_20``, ``area``.
    """
    v, t = mesh.vertices, mesh.triangles

    def stats(tris: np.ndarray) -> dict:
        if not len(tris):
            return {"min_angle": float("nan"), "mean_angle": float("nan"), "frac_min_angle_ge_20": float("nan"),
                    "n_min_angle_lt_10": 0, "area": 0.0, "min_signed_area": float("nan")}
        mins = triangle_angles(v, tris).min(axis=1)
        p = v[tris]
        area = 0.5 * ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
                      - (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0]))
        return {"min_angle": float(mins.min()), "mean_angle": float(mins.mean()),
                "frac_min_angle_ge_20": float(np.mean(mins >= 20.0)), "n_min_angle_lt_10": int(np.sum(mins < 10.0)),
                "area": float(np.abs(area).sum()), "min_signed_area": float(area.min())}

    q = {"n_vertices": len(v), "n_triangles": len(t), "n_edges": len(mesh.edges),
         "n_boundary": int(mesh.boundary.sum()), "n_bodies": mesh.n_bodies, **stats(t)}
    q["area_error"] = (float("nan") if not tissue_pixel_area
                       else (q["area"] - tissue_pixel_area) / tissue_pixel_area)
    tb = mesh.tri_body
    q["bodies"] = []
    names = mesh.names
    for bi in range(mesh.n_bodies):
        s = stats(t[tb == bi])
        q["bodies"].append({"body": bi, "name": names[bi], "n_vertices": int(np.sum(mesh.body == bi)), "n_triangles": int(np.sum(tb == bi)),
                            "n_boundary": int(np.sum(mesh.boundary & (mesh.body == bi))), **s})
    return q
