"""The orders a Gauss-Seidel sweep runs its constraints in: mesh order in a wavefront schedule, colours, parts.

Serial Gauss-Seidel gives the result of sweeping the constraints in mesh order, as the paper does, executed in a
wavefront schedule that changes no bit of it (:func:`wavefront_order`). The parallel path cuts the mesh into one
part per thread (:func:`partition_particles`, :func:`partition_constraints`), or sorts the constraints by greedy
colour (:func:`colour_constraints`): still Gauss-Seidel, in another order, and independent of thread timing.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from .. import kernels, sweeps

PARALLEL_MODES = ("partition", "colour")
JACOBI_RELAXATIONS = ("stiffness", "uniform")

#: Smallest mesh for which ``parallel=True`` is worth trying: below it the
#: fork-join per sweep costs more than the sweep (``tissue-sim bench solver``,
#: row ``xpbd_gs_parallel``: 0.7-1.0x serial at 500 particles). The parallel path
#: is NOT the default at any size: measured on the 2-core VM it is 0.71-1.30x
#: the serial path with the machine otherwise idle, and 5-30x slower at load 5
#: (a thread waits at every sweep's barrier for a descheduled partner), while
#: the serial path is steady at 5-8 ns per projection. It pays only on a machine
#: whose cores are free for this process, from several thousand particles:
#: run ``tissue-sim bench solver`` there and compare ``xpbd_gs_parallel`` with
#: ``xpbd_gs`` before passing ``parallel=True``. To use both cores for many
#: rollouts, run scenes side by side instead (one serial solver per core).
PARALLEL_MIN_PARTICLES = 4000

ORDERS = ("mesh", "colour", "stored")
#: Constraints per wavefront block: a block's particles stay in the L1 cache
#: (see kernels.wavefront_levels; chosen with ``tissue-sim bench solver``).
WAVEFRONT_BLOCK = 4096


def colour_constraints(indices: np.ndarray, n_particles: int) -> tuple[np.ndarray, np.ndarray]:
    """Greedy colouring of the constraints ``indices`` ((M, K) int32, the particles of each, of ``n_particles``;
    :func:`~tissue_sim_ros.core.physics.kernels.greedy_colour`), as a stable permutation sorted by colour.

    Returns
    -------
    order : (M,) int64
        Constraint indices sorted by colour (mesh order within a colour).
    offsets : (n_colours + 1,) int64
        Colour c is ``order[offsets[c]:offsets[c + 1]]``.
    """
    m = indices.shape[0]
    colour = np.zeros(m, dtype=np.int64)
    n_colours = kernels.greedy_colour(np.ascontiguousarray(indices, dtype=np.int32), n_particles, colour) if m else 0
    order = np.argsort(colour, kind="stable")
    offsets = np.zeros(n_colours + 1, dtype=np.int64)
    offsets[1:] = np.cumsum(np.bincount(colour, minlength=n_colours))
    return order, offsets


def partition_particles(q0: np.ndarray, n_parts: int, edges: np.ndarray | None = None) -> np.ndarray:
    """One part per thread, shape (N,), int64: contiguous index ranges when the numbering is local, else slabs.

    Index ranges keep each part's particles in their own cache lines (a slab
    cut across a row-major numbering shares a cache line of positions between
    the two threads in every row, and that line's ping-pong cost ~40% of the
    speed-up at 8k particles). They are used when their separator (``edges``
    across parts) is at most twice the slabs' - true for meshes numbered row by
    row, as mesh_rectangle and the image mesher do. Slabs: equal particle
    counts across the longest side of the rest bounding box.
    """
    n = q0.shape[0]
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    axis = int(np.argmax(np.ptp(q0, axis=0)))
    rank = np.empty(n, dtype=np.int64)
    rank[np.argsort(q0[:, axis], kind="stable")] = np.arange(n)
    slabs = rank * n_parts // n
    if edges is None or edges.shape[0] == 0:
        return slabs
    ranges = np.arange(n, dtype=np.int64) * n_parts // n

    def cut(part: np.ndarray) -> int:
        return int(np.count_nonzero(part[edges[:, 0]] != part[edges[:, 1]]))

    return ranges if cut(ranges) <= 2 * cut(slabs) else slabs


def partition_constraints(indices: np.ndarray, particle_part: np.ndarray, n_parts: int) -> tuple[np.ndarray, np.ndarray]:
    """Group constraints by part (all particles in one part) with a separator group last.

    Within a group the constraints keep their mesh-order result and are
    wavefront-scheduled (sorted by :func:`~tissue_sim_ros.core.physics.kernels.wavefront_levels`).

    Returns
    -------
    order : (M,) int64
        Constraint indices grouped: part 0, ..., part n_parts - 1, separator.
    offsets : (n_parts + 2,) int64
        Group g is ``order[offsets[g]:offsets[g + 1]]``.
    """
    m = indices.shape[0]
    if m == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(n_parts + 2, dtype=np.int64)
    parts = particle_part[indices]
    group = np.where((parts == parts[:, :1]).all(axis=1), parts[:, 0], n_parts)
    order = np.empty(m, dtype=np.int64)
    start = 0
    for g in range(n_parts + 1):  # mesh order within each group, then its wavefront schedule
        members = np.flatnonzero(group == g)
        order[start:start + members.size] = members[wavefront_order(indices[members], particle_part.shape[0])]
        start += members.size
    offsets = np.zeros(n_parts + 2, dtype=np.int64)
    offsets[1:] = np.cumsum(np.bincount(group, minlength=n_parts + 1))
    return order, offsets


def wavefront_order(indices: np.ndarray, n_particles: int, block: int | None = None) -> np.ndarray:
    """A permutation of the constraints that sweeps to the same result as mesh order, bit for bit.

    Stable sort by block, then by :func:`~tissue_sim_ros.core.physics.kernels.wavefront_levels`
    within the block: the constraints at each particle keep their mesh order,
    while neighbours in the new order share no particle and overlap in the
    CPU's pipeline. ``block`` defaults to :data:`WAVEFRONT_BLOCK`.
    """
    m = indices.shape[0]
    block = WAVEFRONT_BLOCK if block is None else block
    level = np.zeros(m, dtype=np.int64)
    if m:
        kernels.wavefront_levels(np.ascontiguousarray(indices, dtype=np.int32), n_particles, block, level)
    return np.lexsort((level, np.arange(m) // block))


@dataclass(frozen=True)
class SolveOrder:
    """A model's constraints in the order a solver sweeps them (:func:`solve_order`)."""

    name: str
    """``mesh``, ``colour``, ``stored`` (serial) or ``partition``, ``colour`` (parallel)."""
    gs_mode: int
    """How Gauss-Seidel runs them: ``sweeps.GS_SERIAL``, ``GS_COLOURED`` or ``GS_PARTITIONED``."""
    edges: np.ndarray
    """(E, 2) int32, in solve order."""
    rest: np.ndarray
    """(E,) rest lengths [m], in solve order."""
    edge_offsets: np.ndarray
    """Groups of edges (colours, parts and the separator; [0, E] serially), int64."""
    tris: np.ndarray
    """(T, 3) int32, in solve order."""
    area0: np.ndarray
    """(T,) signed rest areas [m^2], in solve order."""
    tri_offsets: np.ndarray
    """Groups of triangles, int64."""
    tri_perm: np.ndarray | None
    """The triangles' permutation from mesh order (per-triangle data follows it), None: mesh order."""


def solve_order(model, order: str, parallel: bool, jacobi: bool) -> SolveOrder:
    """The model's constraints ordered for a sweep.

    ``order``: ``mesh`` (serial Gauss-Seidel: mesh order in a wavefront schedule, :func:`wavefront_order`; Jacobi:
    as stored), ``colour`` (sorted by greedy colour; run on all threads when ``parallel``), ``stored`` (the
    array order), ``partition`` (one part per thread, then the separator: ``parallel`` only).
    """
    n = model.n_particles
    edges = np.ascontiguousarray(model.edge_indices, dtype=np.int32)
    rest = np.ascontiguousarray(model.edge_rest_length, dtype=np.float64)
    tris = np.ascontiguousarray(model.tri_indices, dtype=np.int32)
    area0 = np.ascontiguousarray(model.tri_rest_area, dtype=np.float64)
    edge_offsets = np.array([0, edges.shape[0]], dtype=np.int64)
    tri_offsets = np.array([0, tris.shape[0]], dtype=np.int64)
    perm_e = perm_t = None
    gs_mode = sweeps.GS_SERIAL
    if order == "partition":
        n_parts = numba.get_num_threads()
        part = partition_particles(model.particle_q0, n_parts, model.edge_indices)
        perm_e, edge_offsets = partition_constraints(edges, part, n_parts)
        perm_t, tri_offsets = partition_constraints(tris, part, n_parts)
        gs_mode = sweeps.GS_PARTITIONED
    elif order == "colour":
        perm_e, edge_offsets = colour_constraints(edges, n)
        perm_t, tri_offsets = colour_constraints(tris, n)
        gs_mode = sweeps.GS_COLOURED if parallel else sweeps.GS_SERIAL
    elif order == "mesh" and not jacobi:
        perm_e, perm_t = wavefront_order(edges, n), wavefront_order(tris, n)
    if perm_e is not None:
        edges, rest = np.ascontiguousarray(edges[perm_e]), np.ascontiguousarray(rest[perm_e])
        tris, area0 = np.ascontiguousarray(tris[perm_t]), np.ascontiguousarray(area0[perm_t])
    return SolveOrder(order, gs_mode, edges, rest, edge_offsets, tris, area0, tri_offsets, perm_t)
