"""Mesh files: .npz, Triangle (.node/.ele/.poly) and Gmsh (.msh 2.2 and 4.1) read into a
:class:`~.types.TissueMesh`; several files as one scene, each body named after its file; writers
for exchange and round trips."""
from __future__ import annotations

import re
import zipfile
from pathlib import Path

import numpy as np

from ..errors import InputError, input_file
from .types import (
    TissueMesh,
    combine_meshes,
    mesh_from_arrays,
)


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
