"""Numba kernels that find the pairs the barrier contact must watch: boundary vertices against boundary edges of the
tissue, and the tissue's boundary against the tool's core, over a sweep (positions from x to x + dx, the tool from
q to q + dq) inflated by the activation distance.

Tissue pairs come from a uniform grid: each boundary edge is entered in the cells its swept, inflated bounding
box covers, each boundary vertex looks in the cells of its own; a pair is kept when the two boxes overlap and the
vertex shares no triangle with either end of the edge (the mesh's own neighbours: their distance is the mesh's
shape, not a contact). The tool has a few vertices and edges: its
pairs are tested against every boundary vertex and edge directly.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

#: Grid cells at most per boundary edge: the cell is at least half an edge's swept box, so a box spans 3 x 3.
MAX_CELLS_PER_EDGE = 9


@njit(cache=True, inline="always")
def _box(ax: float, ay: float, bx: float, by: float, cx: float, cy: float, dx: float, dy: float, pad: float):
    """The bounding box of four points, inflated by ``pad``: (x0, y0, x1, y1)."""
    return (min(min(ax, bx), min(cx, dx)) - pad, min(min(ay, by), min(cy, dy)) - pad,
            max(max(ax, bx), max(cx, dx)) + pad, max(max(ay, by), max(cy, dy)) + pad)


@njit(cache=True, nogil=True)
def tissue_pairs(x: np.ndarray, dx: np.ndarray, vertices: np.ndarray, edges: np.ndarray, near: tuple,
                 pad: float, cell: float, out: np.ndarray, ws: tuple) -> int:
    """Candidate (boundary vertex, boundary edge) pairs of the sweep x -> x + dx within ``pad`` [m]: rows
    (vertex, edge index) into ``out`` (P, 2) int32; returns their count, or -1 when ``out`` is too small.

    ``vertices`` (Nb,) int32 the boundary vertices, ``edges`` (Ne, 2) int32 the boundary edges, ``near`` = (pointers
    (Ne + 1,), vertices) int64: the vertices sharing a triangle with each edge's ends, never paired with it; ``cell`` [m] the grid's cell size (grown as needed). ``ws`` =
    (edge boxes (Ne, 4), cell counts, cell starts, cell entries (Ne * MAX_CELLS_PER_EDGE,) int32, stamp (Ne,)
    int64) scratch.
    """
    boxes, counts, starts, entries, stamp = ws
    near_ptr, near_idx = near
    ne = edges.shape[0]
    if ne == 0 or vertices.shape[0] == 0:
        return 0
    gx0 = math.inf
    gy0 = math.inf
    gx1 = -math.inf
    gy1 = -math.inf
    for e in range(ne):
        a = edges[e, 0]
        b = edges[e, 1]
        x0, y0, x1, y1 = _box(x[a, 0], x[a, 1], x[b, 0], x[b, 1], x[a, 0] + dx[a, 0], x[a, 1] + dx[a, 1],
                              x[b, 0] + dx[b, 0], x[b, 1] + dx[b, 1], pad)
        boxes[e, 0] = x0
        boxes[e, 1] = y0
        boxes[e, 2] = x1
        boxes[e, 3] = y1
        gx0 = min(gx0, x0)
        gy0 = min(gy0, y0)
        gx1 = max(gx1, x1)
        gy1 = max(gy1, y1)
        # a cell at least half of every edge's swept box: a box spans at most 3 x 3 cells
        cell = max(cell, 0.5 * (x1 - x0), 0.5 * (y1 - y0))
    nx = int((gx1 - gx0) / cell) + 1
    ny = int((gy1 - gy0) / cell) + 1
    n_cells = counts.shape[0] - 1
    while nx * ny > n_cells:
        cell *= 1.5
        nx = int((gx1 - gx0) / cell) + 1
        ny = int((gy1 - gy0) / cell) + 1
    for c in range(nx * ny + 1):
        counts[c] = 0
    for e in range(ne):
        for ix in range(int((boxes[e, 0] - gx0) / cell), int((boxes[e, 2] - gx0) / cell) + 1):
            for iy in range(int((boxes[e, 1] - gy0) / cell), int((boxes[e, 3] - gy0) / cell) + 1):
                counts[ix * ny + iy + 1] += 1
    starts[0] = 0
    for c in range(nx * ny):
        starts[c + 1] = starts[c] + counts[c + 1]
        counts[c + 1] = 0
    for e in range(ne):
        stamp[e] = -1
        for ix in range(int((boxes[e, 0] - gx0) / cell), int((boxes[e, 2] - gx0) / cell) + 1):
            for iy in range(int((boxes[e, 1] - gy0) / cell), int((boxes[e, 3] - gy0) / cell) + 1):
                c = ix * ny + iy
                entries[starts[c] + counts[c + 1]] = e
                counts[c + 1] += 1
    n = 0
    for k in range(vertices.shape[0]):
        p = vertices[k]
        px0 = min(x[p, 0], x[p, 0] + dx[p, 0])
        px1 = max(x[p, 0], x[p, 0] + dx[p, 0])
        py0 = min(x[p, 1], x[p, 1] + dx[p, 1])
        py1 = max(x[p, 1], x[p, 1] + dx[p, 1])
        if px1 < gx0 or px0 > gx1 or py1 < gy0 or py0 > gy1:
            continue
        for ix in range(max(0, int((px0 - gx0) / cell)), min(nx - 1, int((px1 - gx0) / cell)) + 1):
            for iy in range(max(0, int((py0 - gy0) / cell)), min(ny - 1, int((py1 - gy0) / cell)) + 1):
                c = ix * ny + iy
                for j in range(starts[c], starts[c + 1]):
                    e = entries[j]
                    if stamp[e] == p:
                        continue
                    stamp[e] = p
                    mesh_near = False
                    for m in range(near_ptr[e], near_ptr[e + 1]):
                        if near_idx[m] == p:
                            mesh_near = True
                            break
                    if mesh_near:
                        continue
                    if px1 < boxes[e, 0] or px0 > boxes[e, 2] or py1 < boxes[e, 1] or py0 > boxes[e, 3]:
                        continue
                    if n == out.shape[0]:
                        return -1
                    out[n, 0] = p
                    out[n, 1] = e
                    n += 1
    return n


def tissue_pair_workspace(n_edges: int) -> tuple:
    """Scratch of :func:`tissue_pairs` for ``n_edges`` boundary edges."""
    n_cells = max(16, 4 * n_edges)
    return (np.zeros((n_edges, 4)), np.zeros(n_cells + 1, dtype=np.int64), np.zeros(n_cells + 1, dtype=np.int64),
            np.zeros(max(1, n_edges * MAX_CELLS_PER_EDGE), dtype=np.int32), np.zeros(n_edges, dtype=np.int64))


@njit(cache=True, nogil=True)
def tool_pairs(x: np.ndarray, dx: np.ndarray, vertices: np.ndarray, edges: np.ndarray, tool_pos: np.ndarray,
               tool_end: np.ndarray, tool_edges: np.ndarray, sweep_pad: float, pad: float, out_vt: np.ndarray,
               out_tv: np.ndarray) -> tuple[int, int]:
    """Candidate pairs of the tissue's boundary against the tool's core over the sweep: (boundary vertex, tool
    edge) rows into ``out_vt`` (P, 2) and (tool vertex, boundary edge) rows into ``out_tv`` (Q, 2); returns
    their counts (-1 for one whose ``out`` is too small).

    ``tool_pos``, ``tool_end`` (V, 2): the core's vertices at the sweep's start and end; ``sweep_pad`` [m] how far
    a point of the core may stray from the straight line between them (a turn's bulge); ``pad`` the activation
    distance plus the core's radius.
    """
    nvt = 0
    for te in range(tool_edges.shape[0]):
        a = tool_edges[te, 0]
        b = tool_edges[te, 1]
        x0, y0, x1, y1 = _box(tool_pos[a, 0], tool_pos[a, 1], tool_pos[b, 0], tool_pos[b, 1], tool_end[a, 0],
                              tool_end[a, 1], tool_end[b, 0], tool_end[b, 1], pad + sweep_pad)
        for k in range(vertices.shape[0]):
            p = vertices[k]
            if (max(x[p, 0], x[p, 0] + dx[p, 0]) < x0 or min(x[p, 0], x[p, 0] + dx[p, 0]) > x1
                    or max(x[p, 1], x[p, 1] + dx[p, 1]) < y0 or min(x[p, 1], x[p, 1] + dx[p, 1]) > y1):
                continue
            if nvt == out_vt.shape[0]:
                return -1, 0
            out_vt[nvt, 0] = p
            out_vt[nvt, 1] = te
            nvt += 1
    ntv = 0
    for tv in range(tool_pos.shape[0]):
        x0 = min(tool_pos[tv, 0], tool_end[tv, 0]) - pad - sweep_pad
        x1 = max(tool_pos[tv, 0], tool_end[tv, 0]) + pad + sweep_pad
        y0 = min(tool_pos[tv, 1], tool_end[tv, 1]) - pad - sweep_pad
        y1 = max(tool_pos[tv, 1], tool_end[tv, 1]) + pad + sweep_pad
        for e in range(edges.shape[0]):
            a = edges[e, 0]
            b = edges[e, 1]
            ex0, ey0, ex1, ey1 = _box(x[a, 0], x[a, 1], x[b, 0], x[b, 1], x[a, 0] + dx[a, 0], x[a, 1] + dx[a, 1],
                                      x[b, 0] + dx[b, 0], x[b, 1] + dx[b, 1], 0.0)
            if ex1 < x0 or ex0 > x1 or ey1 < y0 or ey0 > y1:
                continue
            if ntv == out_tv.shape[0]:
                return nvt, -1
            out_tv[ntv, 0] = tv
            out_tv[ntv, 1] = e
            ntv += 1
    return nvt, ntv
