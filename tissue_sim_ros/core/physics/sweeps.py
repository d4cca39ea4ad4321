"""Numba kernels of the constraint sweeps: distance and area projections, Gauss-Seidel (serial, partitioned,
coloured) and Jacobi, with the tool's contact after every sweep.

Vocabulary (Mueller, Macklin): ``C`` constraint value, ``w`` inverse mass,
``alpha`` = compliance / dt_sub^2 (0 for the paper's PBD), ``k`` the PBD
coefficient scaling each projection (1 for XPBD), ``lam`` the constraint's
Lagrange multiplier accumulated over the iterations of one (sub)step.
One projection, PBD and XPBD alike::

    s = k (-C - alpha lam) / (sum_i w_i |grad_i C|^2 + alpha);  lam += s;  x_i += w_i s grad_i C

With ``alpha = 0`` this is the paper's projection scaled by k; with ``k = 1`` it
is XPBD's (Macklin, Mueller, Chentanez 2016, eq. 18).

Every kernel takes arrays and scalars and writes into preallocated outputs
(``@njit(cache=True)``); the solvers (:mod:`~tissue_sim_ros.core.physics.solvers`) own the workspaces and
:mod:`~tissue_sim_ros.core.physics.step_kernels` compiles them into one call per step. Each kernel has a
slow NumPy twin in ``test/naive.py`` and the tests compare the two on random and degenerate input.

The hot loops are written flat on purpose: a small helper with array arguments called per constraint keeps
reference-count calls in the loop, so the helpers shared by the loops (``_edge_geometry``,
``_area_constraint``) are inlined into each. Particle and constraint indices are read as unsigned
(``uint32``): a signed index makes numba wrap negative values around on every access (a compare and a
select per load and store). The model's indices are checked non-negative where they enter (``TissueMesh``,
the solvers' step checks).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange, uint32

from ..contact.kernels import project_edges, project_tool
from .kernels import EPS_LEN2, add_corners, area_gradients, tri_edges

#: Fast-math flags of the distance-projection kernels: only fused multiply-add
#: contraction (6% fewer cycles per projection at 8k particles). No flag that
#: assumes finite values: the NaN guards must keep working. The serial signed
#: area sweeps use it too (17% less time per projection); the paper's |area|
#: form goes without: contracting the cross product makes an exactly collinear
#: triangle's area a round-off-signed nonzero, which |area| turns into a
#: projection in an arbitrary direction (the signed form's C = area - A0 and
#: its gradients do not depend on that sign).
FMA = {"contract"}

#: Gauss-Seidel execution modes of :func:`gauss_seidel_iterations`.
GS_SERIAL = 0
GS_COLOURED = 1
GS_PARTITIONED = 2



@njit(cache=True, inline="always")
def tool_contact(x: np.ndarray, inv_mass: np.ndarray, tool: tuple) -> None:
    """The projection contact after a sweep: the candidate particles, then the surface edges, kept out of the tool
    swept over the (sub)step (:func:`~tissue_sim_ros.core.contact.kernels.project_tool`,
    :func:`~tissue_sim_ros.core.contact.kernels.project_edges`), their corrections summed into the bundle's
    ``dx_accum``. ``tool`` = (x_start (N, 2), candidates (C,) int32, shape0 (7,), shape1 (7,), dx_accum (N, 2),
    surface_edges (K, 2) int32, edge_side_tol [m]) (:func:`tool_pack`); empty candidates and edges: nothing.
    Every sweep of every solver ends with it, so the tool has the last word in an iteration."""
    x_start, candidates, shape0, shape1, dx_accum, surface_edges, edge_side_tol = tool
    if candidates.shape[0] > 0:
        project_tool(x, x_start, inv_mass, candidates, shape0, shape1, dx_accum)
    if surface_edges.shape[0] > 0:
        project_edges(x, x_start, inv_mass, surface_edges, shape0, shape1, edge_side_tol, dx_accum)

# ----------------------------------------------------------------------------- Gauss-Seidel projections


@njit(cache=True, inline="always")
def _edge_geometry(x: np.ndarray, inv_mass: np.ndarray, edges: np.ndarray, e: int):
    """Distance constraint ``e``'s particles and geometry, shared by the distance sweeps (inlined).

    Returns (i, j, w_i, w_j, w_i + w_j, dx, dy, |x_i - x_j|) with (dx, dy) = x_i - x_j; the length is 0.0
    when the projection is to be skipped: both particles held (w = 0) or the edge degenerate (its direction
    undefined, |x_i - x_j|^2 <= EPS_LEN2).
    """
    i = uint32(edges[e, 0])
    j = uint32(edges[e, 1])
    wi = inv_mass[i]
    wj = inv_mass[j]
    w = wi + wj
    if w == 0.0:
        return i, j, wi, wj, w, 0.0, 0.0, 0.0
    dx = x[i, 0] - x[j, 0]
    dy = x[i, 1] - x[j, 1]
    len2 = dx * dx + dy * dy
    if len2 <= EPS_LEN2:
        return i, j, wi, wj, w, dx, dy, 0.0
    return i, j, wi, wj, w, dx, dy, math.sqrt(len2)


@njit(cache=True, inline="always")
def _edge_sweep(x: np.ndarray, inv_mass: np.ndarray, edges: np.ndarray, rest: np.ndarray, k: float, alpha: float,
                lam: np.ndarray, start: int, stop: int, multipliers: bool) -> None:
    """The body of the serial distance sweeps (inlined into each, under its fast-math flags).

    ``multipliers`` False: the paper's PBD (``alpha`` 0), ``lam`` neither read nor written (with alpha = 0 the
    multiplier never enters a projection: ``- alpha lam`` and ``+ alpha`` add exact zeros, so the positions are
    the same bit for bit).
    """
    for e in range(uint32(start), uint32(stop)):
        i, j, wi, wj, w, dx, dy, length = _edge_geometry(x, inv_mass, edges, e)
        if length == 0.0:
            continue
        # one division: s / length, with s the multiplier increment
        if multipliers:
            f = k * (rest[e] - length - alpha * lam[e]) / ((w + alpha) * length)
            lam[e] += f * length
        else:
            f = k * (rest[e] - length) / (w * length)
        x[i, 0] += wi * f * dx
        x[i, 1] += wi * f * dy
        x[j, 0] -= wj * f * dx
        x[j, 1] -= wj * f * dy


@njit(cache=True, fastmath=FMA, nogil=True)
def solve_edges_range(x: np.ndarray, inv_mass: np.ndarray, edges: np.ndarray, rest: np.ndarray,
                      k: float, alpha: float, lam: np.ndarray, start: int, stop: int) -> None:
    """Gauss-Seidel over distance constraints ``start:stop``, C = |x_i - x_j| - d0, in array order.

    Parameters
    ----------
    x : (N, 2) float64
        Positions [m], updated in place.
    inv_mass : (N,) float64
        Inverse masses [1/kg] (0 = held/pinned).
    edges : (E, 2) int32
        Particle indices.
    rest : (E,) float64
        Rest lengths d0 [m].
    k : float
        PBD coefficient in [0, 1] (1 for XPBD).
    alpha : float
        Compliance over dt_sub^2 [1/kg] (0 for PBD).
    lam : (E,) float64
        Multipliers, accumulated in place.
    start, stop : int
        The range of constraints to sweep.
    """
    _edge_sweep(x, inv_mass, edges, rest, k, alpha, lam, start, stop, True)


@njit(cache=True, fastmath=FMA, nogil=True)
def solve_edges_pbd_range(x: np.ndarray, inv_mass: np.ndarray, edges: np.ndarray, rest: np.ndarray,
                          k: float, start: int, stop: int) -> None:
    """:func:`solve_edges_range` with ``alpha = 0`` (the paper's PBD) and no multipliers: the same positions bit
    for bit, without the multipliers' load and store per constraint."""
    # the sweep's lam is never touched here, but typing needs a writable float64 array (a view of x, no allocation)
    _edge_sweep(x, inv_mass, edges, rest, k, 0.0, x[:, 0], start, stop, False)


@njit(cache=True, inline="always")
def _area_constraint(x: np.ndarray, a: int, b: int, c: int, a0: float, signed: bool):
    """The area constraint of triangle (a, b, c) and its gradients, shared by the area sweeps (inlined).

    Signed: C = 1/2 (x_b - x_a) x (x_c - x_a) - A0; abs (the paper's): C = |area| - |A0|. Gradients:
    grad_b = sg (e2y, -e2x), grad_c = sg (-e1y, e1x), grad_a = -(grad_b + grad_c), sg = 1/2 (abs: its sign).
    Returns C, the three gradients' components and their squared norms.
    """
    e1x, e1y, e2x, e2y = tri_edges(x, a, b, c)
    area = 0.5 * (e1x * e2y - e1y * e2x)
    if signed:
        sg = 0.5
        C = area - a0
    else:
        sg = 0.5 if area > 0.0 else (-0.5 if area < 0.0 else 0.0)
        C = abs(area) - abs(a0)
    gax, gay, gbx, gby, gcx, gcy = area_gradients(e1x, e1y, e2x, e2y, sg)
    return C, gax, gay, gbx, gby, gcx, gcy, gax * gax + gay * gay, gbx * gbx + gby * gby, gcx * gcx + gcy * gcy


@njit(cache=True, inline="always")
def _area_sweep(x: np.ndarray, inv_mass: np.ndarray, tris: np.ndarray, area0: np.ndarray, k: float, alpha: float,
                lam: np.ndarray, signed: bool, start: int, stop: int, multipliers: bool) -> None:
    """The body of every serial area sweep (inlined, so each caller's fast-math flags apply to it).

    ``multipliers`` False: the paper's PBD (``alpha`` 0), ``lam`` neither read nor written; with alpha = 0 the
    multiplier never enters a projection, so the positions are the same bit for bit.
    """
    for t in range(uint32(start), uint32(stop)):
        a = uint32(tris[t, 0])
        b = uint32(tris[t, 1])
        c = uint32(tris[t, 2])
        wa = inv_mass[a]
        wb = inv_mass[b]
        wc = inv_mass[c]
        if wa + wb + wc == 0.0:
            continue
        C, gax, gay, gbx, gby, gcx, gcy, ga2, gb2, gc2 = _area_constraint(x, a, b, c, area0[t], signed)
        if ga2 + gb2 + gc2 <= EPS_LEN2:
            continue
        den = wa * ga2 + wb * gb2 + wc * gc2 + alpha
        if den <= 0.0:
            continue
        if multipliers:
            s = k * (-C - alpha * lam[t]) / den
            lam[t] += s
        else:
            s = k * -C / den
        add_corners(x, a, b, c, wa, wb, wc, s, (gax, gay, gbx, gby, gcx, gcy))


@njit(cache=True, fastmath=FMA, nogil=True)
def _areas_signed(x: np.ndarray, inv_mass: np.ndarray, tris: np.ndarray, area0: np.ndarray, k: float,
                  alpha: float, lam: np.ndarray, start: int, stop: int, multipliers: bool) -> None:
    """Signed area sweep with FMA contraction: a collinear triangle's round-off-signed area is harmless here
    (C = area - A0 and the gradients do not depend on the area's sign)."""
    if multipliers:
        _area_sweep(x, inv_mass, tris, area0, k, alpha, lam, True, start, stop, True)
    else:
        _area_sweep(x, inv_mass, tris, area0, k, 0.0, lam, True, start, stop, False)


@njit(cache=True, nogil=True)
def _areas_abs(x: np.ndarray, inv_mass: np.ndarray, tris: np.ndarray, area0: np.ndarray, k: float,
               alpha: float, lam: np.ndarray, start: int, stop: int, multipliers: bool) -> None:
    """The paper's |area| sweep, without contraction (:data:`FMA`)."""
    if multipliers:
        _area_sweep(x, inv_mass, tris, area0, k, alpha, lam, False, start, stop, True)
    else:
        _area_sweep(x, inv_mass, tris, area0, k, 0.0, lam, False, start, stop, False)


@njit(cache=True, nogil=True)
def solve_areas_pbd_range(x: np.ndarray, inv_mass: np.ndarray, tris: np.ndarray, area0: np.ndarray,
                          k: float, signed: bool, start: int, stop: int) -> None:
    """:func:`solve_areas_range` with ``alpha = 0`` and no multipliers (see :func:`solve_edges_pbd_range`)."""
    # no multipliers: the sweep's ``lam`` is never touched, but typing needs a writable float64 array there (the
    # dead ``lam[t] += s`` is typed too): a view of x, no allocation
    unused = x[:, 0]
    if signed:
        _areas_signed(x, inv_mass, tris, area0, k, 0.0, unused, start, stop, False)
    else:
        _areas_abs(x, inv_mass, tris, area0, k, 0.0, unused, start, stop, False)


@njit(cache=True, nogil=True)
def solve_edges(x: np.ndarray, inv_mass: np.ndarray, edges: np.ndarray, rest: np.ndarray,
                k: float, alpha: float, lam: np.ndarray) -> None:
    """One Gauss-Seidel sweep over all distance constraints in array order (:func:`solve_edges_range`)."""
    solve_edges_range(x, inv_mass, edges, rest, k, alpha, lam, 0, edges.shape[0])


@njit(cache=True, nogil=True)
def solve_areas_range(x: np.ndarray, inv_mass: np.ndarray, tris: np.ndarray, area0: np.ndarray,
                      k: float, alpha: float, lam: np.ndarray, signed: bool, start: int, stop: int) -> None:
    """Gauss-Seidel over area constraints ``start:stop``, in array order.

    Signed: C = 1/2 (x_b - x_a) x (x_c - x_a) - A0 (an inverted triangle is
    pushed back). Abs (the paper): C = |1/2 (x_b - x_a) x (x_c - x_a)| - |A0|,
    which an inverted triangle also satisfies; a triangle of zero area has no
    gradient there and is skipped.

    Parameters
    ----------
    x : (N, 2) float64
        Positions [m], updated in place.
    inv_mass : (N,) float64
        Inverse masses [1/kg].
    tris : (T, 3) int32
        Particle indices (CCW at rest).
    area0 : (T,) float64
        Signed rest areas A0 [m^2].
    k, alpha : float
        PBD coefficient and compliance / dt_sub^2 [1/(kg m^2)].
    lam : (T,) float64
        Multipliers, accumulated in place.
    signed : bool
        Signed (True) or the paper's absolute (False) area.
    start, stop : int
        The range of constraints to sweep.

    The signed form runs with fused multiply-add contraction (:func:`_areas_signed`, 17% less time per
    projection on the paper scene: 10.4 -> 8.6 ns); the absolute form without (:func:`_areas_abs`, see
    :data:`FMA`).
    """
    if signed:
        _areas_signed(x, inv_mass, tris, area0, k, alpha, lam, start, stop, True)
    else:
        _areas_abs(x, inv_mass, tris, area0, k, alpha, lam, start, stop, True)


@njit(cache=True, nogil=True)
def solve_areas(x: np.ndarray, inv_mass: np.ndarray, tris: np.ndarray, area0: np.ndarray,
                k: float, alpha: float, lam: np.ndarray, signed: bool) -> None:
    """One Gauss-Seidel sweep over all area constraints in array order (:func:`solve_areas_range`)."""
    solve_areas_range(x, inv_mass, tris, area0, k, alpha, lam, signed, 0, tris.shape[0])


@njit(cache=True, parallel=True)
def solve_partitioned(x: np.ndarray, inv_mass: np.ndarray,
                      edges: np.ndarray, rest: np.ndarray, k_e: float, alpha_e: float, lam_e: np.ndarray,
                      edge_offsets: np.ndarray,
                      tris: np.ndarray, area0: np.ndarray, k_t: float, alpha_t: float, lam_t: np.ndarray,
                      tri_offsets: np.ndarray, signed: bool) -> None:
    """One Gauss-Seidel sweep, domain-decomposed: each part on its own thread, then the separator.

    Constraints are grouped by part (``*_offsets``, n_parts + 2 entries): the
    constraints of part p touch only particles of part p, so parts run
    concurrently; the last group (the separator: constraints across parts)
    runs afterwards on one thread. The result equals a serial sweep over
    part 0, part 1, ..., separator, whatever the threads: one fork-join per
    sweep instead of one per colour.
    """
    n_parts = edge_offsets.shape[0] - 2
    for part in prange(n_parts):
        solve_edges_range(x, inv_mass, edges, rest, k_e, alpha_e, lam_e, edge_offsets[part], edge_offsets[part + 1])
        solve_areas_range(x, inv_mass, tris, area0, k_t, alpha_t, lam_t, signed, tri_offsets[part],
                          tri_offsets[part + 1])
    solve_edges_range(x, inv_mass, edges, rest, k_e, alpha_e, lam_e, edge_offsets[n_parts], edge_offsets[n_parts + 1])
    solve_areas_range(x, inv_mass, tris, area0, k_t, alpha_t, lam_t, signed, tri_offsets[n_parts],
                      tri_offsets[n_parts + 1])


#: Pieces each colour is cut into for the threads (numba's thread count read inside a kernel would make it
#: uncacheable); any number gives the same bits.
COLOUR_PARTS = 32


@njit(cache=True, inline="always")
def _chunk(start: int, stop: int, part: int, parts: int) -> tuple[int, int]:
    """Part ``part`` of ``parts`` nearly equal consecutive pieces of ``start:stop``."""
    n = stop - start
    return start + n * part // parts, start + n * (part + 1) // parts


@njit(cache=True, parallel=True)
def solve_edges_coloured(x: np.ndarray, inv_mass: np.ndarray, edges: np.ndarray, rest: np.ndarray,
                         k: float, alpha: float, lam: np.ndarray, offsets: np.ndarray) -> None:
    """:func:`solve_edges` on edges sorted by colour, each colour's edges in parallel.

    No two edges of one colour share a particle, so within a colour the
    projections are independent (still Gauss-Seidel between colours): each
    thread sweeps a consecutive piece of the colour with the serial kernel
    (:func:`solve_edges_range`), and the result is a serial sweep's in colour
    order bit for bit, whatever the threads.
    ``offsets`` (n_colours + 1,) int64 delimits the colours in ``edges``.
    """
    for col in range(offsets.shape[0] - 1):
        start = offsets[col]
        stop = offsets[col + 1]
        parts = max(1, min(COLOUR_PARTS, stop - start))
        for part in prange(parts):
            lo, hi = _chunk(start, stop, part, parts)
            solve_edges_range(x, inv_mass, edges, rest, k, alpha, lam, lo, hi)


@njit(cache=True, parallel=True)
def solve_areas_coloured(x: np.ndarray, inv_mass: np.ndarray, tris: np.ndarray, area0: np.ndarray,
                         k: float, alpha: float, lam: np.ndarray, signed: bool, offsets: np.ndarray) -> None:
    """:func:`solve_areas` on triangles sorted by colour, each colour in parallel (see :func:`solve_edges_coloured`:
    each thread sweeps a piece of the colour with :func:`solve_areas_range`)."""
    for col in range(offsets.shape[0] - 1):
        start = offsets[col]
        stop = offsets[col + 1]
        parts = max(1, min(COLOUR_PARTS, stop - start))
        for part in prange(parts):
            lo, hi = _chunk(start, stop, part, parts)
            solve_areas_range(x, inv_mass, tris, area0, k, alpha, lam, signed, lo, hi)


@njit(cache=True, nogil=True)
def gauss_seidel_iterations(x: np.ndarray, inv_mass: np.ndarray, edge_set: tuple, tri_set: tuple, tool: tuple,
                            coeffs: tuple, mults: tuple, signed: bool, iterations: int, mode: int,
                            skip_multipliers: bool = False) -> None:
    """``iterations`` Gauss-Seidel sweeps: all edges, then all triangles, then the tool (:func:`tool_contact`).

    Pass empty ``edges``/``tris`` to switch a constraint type off. ``mode``:
    :data:`GS_SERIAL` sweeps in array order (offsets ignored);
    :data:`GS_COLOURED` needs constraints sorted by colour (``*_offsets``
    delimit colours) and runs each colour on all threads;
    :data:`GS_PARTITIONED` needs constraints grouped by part
    (:func:`solve_partitioned`). The tool runs after the constraints of every
    iteration, so the last word is the tool's and no particle ends inside it.

    Bundles: ``edge_set`` = (edges (E, 2) int32, rest lengths (E,) [m], offsets (G + 1,) int64), ``tri_set`` =
    (triangles (T, 3) int32, signed rest areas (T,) [m^2], offsets), ``tool`` as :func:`tool_contact` takes it
    (:func:`tool_pack`), ``coeffs`` = (k_e, alpha_e, k_t, alpha_t) (PBD coefficients and compliances / h^2),
    ``mults`` = (lam_e (E,), lam_t (T,), omega_e, omega_t) (the omegas unused here). ``skip_multipliers``: the
    paper's PBD (alpha 0 for both types) sweeps serially without multipliers (they never enter its projections:
    the same positions bit for bit); lam_e, lam_t stay as they were.
    """
    edges, rest, edge_offsets = edge_set
    tris, area0, tri_offsets = tri_set
    k_e, alpha_e, k_t, alpha_t = coeffs
    lam_e, lam_t, _omega_e, _omega_t = mults
    pbd = skip_multipliers and alpha_e == 0.0 and alpha_t == 0.0
    for _ in range(iterations):
        if mode == GS_COLOURED:
            solve_edges_coloured(x, inv_mass, edges, rest, k_e, alpha_e, lam_e, edge_offsets)
            solve_areas_coloured(x, inv_mass, tris, area0, k_t, alpha_t, lam_t, signed, tri_offsets)
        elif mode == GS_PARTITIONED:
            solve_partitioned(x, inv_mass, edges, rest, k_e, alpha_e, lam_e, edge_offsets,
                              tris, area0, k_t, alpha_t, lam_t, tri_offsets, signed)
        elif pbd:  # no multipliers: the same positions (solve_edges_pbd_range)
            solve_edges_pbd_range(x, inv_mass, edges, rest, k_e, 0, edges.shape[0])
            solve_areas_pbd_range(x, inv_mass, tris, area0, k_t, signed, 0, tris.shape[0])
        else:
            solve_edges(x, inv_mass, edges, rest, k_e, alpha_e, lam_e)
            solve_areas(x, inv_mass, tris, area0, k_t, alpha_t, lam_t, signed)
        tool_contact(x, inv_mass, tool)


# ----------------------------------------------------------------------------- Jacobi


@njit(cache=True, fastmath=FMA, nogil=True)
def jacobi_edges(x: np.ndarray, inv_mass: np.ndarray, edges: np.ndarray, rest: np.ndarray,
                 k: float, alpha: float, lam: np.ndarray, omega: np.ndarray, dx_acc: np.ndarray) -> None:
    """Jacobi pass over distance constraints: corrections from the same ``x`` summed into ``dx_acc``.

    Each multiplier increment is scaled by ``omega[e]`` (relaxation) before it
    is added to ``lam`` and turned into corrections, so multipliers and
    positions stay consistent. ``x`` is not changed.
    """
    for e in range(uint32(edges.shape[0])):
        i, j, wi, wj, w, dx, dy, length = _edge_geometry(x, inv_mass, edges, e)
        if length == 0.0:
            continue
        f = omega[e] * k * (rest[e] - length - alpha * lam[e]) / ((w + alpha) * length)
        lam[e] += f * length
        dx_acc[i, 0] += wi * f * dx
        dx_acc[i, 1] += wi * f * dy
        dx_acc[j, 0] -= wj * f * dx
        dx_acc[j, 1] -= wj * f * dy


@njit(cache=True, nogil=True)
def jacobi_areas(x: np.ndarray, inv_mass: np.ndarray, tris: np.ndarray, area0: np.ndarray,
                 k: float, alpha: float, lam: np.ndarray, signed: bool, omega: np.ndarray,
                 dx_acc: np.ndarray) -> None:
    """Jacobi pass over area constraints (see :func:`jacobi_edges` and :func:`solve_areas`)."""
    for t in range(uint32(tris.shape[0])):
        a = uint32(tris[t, 0])
        b = uint32(tris[t, 1])
        c = uint32(tris[t, 2])
        wa = inv_mass[a]
        wb = inv_mass[b]
        wc = inv_mass[c]
        if wa + wb + wc == 0.0:
            continue
        C, gax, gay, gbx, gby, gcx, gcy, ga2, gb2, gc2 = _area_constraint(x, a, b, c, area0[t], signed)
        if ga2 + gb2 + gc2 <= EPS_LEN2:
            continue
        den = wa * ga2 + wb * gb2 + wc * gc2 + alpha
        if den <= 0.0:
            continue
        s = omega[t] * k * (-C - alpha * lam[t]) / den
        lam[t] += s
        add_corners(dx_acc, a, b, c, wa, wb, wc, s, (gax, gay, gbx, gby, gcx, gcy))


@njit(cache=True, nogil=True)
def jacobi_apply(x: np.ndarray, dx_acc: np.ndarray, particle_scale: np.ndarray) -> None:
    """x += particle_scale * dx_acc per particle, then clear ``dx_acc`` for the next pass."""
    for i in range(x.shape[0]):
        s = particle_scale[i]
        x[i, 0] += s * dx_acc[i, 0]
        x[i, 1] += s * dx_acc[i, 1]
        dx_acc[i, 0] = 0.0
        dx_acc[i, 1] = 0.0


@njit(cache=True, inline="always")
def _edge_gradient_length(x: np.ndarray, edges: np.ndarray, e: int) -> tuple[int, int, float]:
    """(i, j, |grad C_e| at either end): 1, or 0 for a degenerate edge (its direction undefined)."""
    i = edges[e, 0]
    j = edges[e, 1]
    dx = x[i, 0] - x[j, 0]
    dy = x[i, 1] - x[j, 1]
    return i, j, 1.0 if dx * dx + dy * dy > EPS_LEN2 else 0.0


@njit(cache=True, inline="always")
def _area_gradient_lengths(x: np.ndarray, tris: np.ndarray, t: int, signed: bool):
    """(a, b, c, |grad_a C_t|, |grad_b C_t|, |grad_c C_t|): half the opposite edges' lengths (|grad_a| = |x_c -
    x_b| / 2), zero for the paper's |area| of a triangle of zero area (no gradient there)."""
    a = tris[t, 0]
    b = tris[t, 1]
    c = tris[t, 2]
    e1x, e1y, e2x, e2y = tri_edges(x, a, b, c)
    gb = 0.5 * math.sqrt(e2x * e2x + e2y * e2y)
    gc = 0.5 * math.sqrt(e1x * e1x + e1y * e1y)
    ga = 0.5 * math.sqrt((e2x - e1x) ** 2 + (e2y - e1y) ** 2)
    if not signed and e1x * e2y - e1y * e2x == 0.0:
        return a, b, c, 0.0, 0.0, 0.0
    return a, b, c, ga, gb, gc


@njit(cache=True, nogil=True)
def jacobi_relaxation(x: np.ndarray, inv_mass: np.ndarray, edges: np.ndarray, alpha_e: float,
                      tris: np.ndarray, alpha_t: float, signed: bool, scale: float,
                      node_sum: np.ndarray, omega_e: np.ndarray, omega_t: np.ndarray) -> None:
    """Stiffness-aware Jacobi relaxation: one omega per constraint with guaranteed linear convergence.

    The Jacobi iteration on the XPBD system A dlam = r, A = J W J^T + diag(alpha),
    converges for any SPD A when each row's step is 1 / (its Gershgorin row
    sum) of the symmetrically scaled matrix D^-1/2 A D^-1/2 (then 2 D' - A is
    diagonally dominant, hence SPD). With D_c = sum_p w_p |g_cp|^2 + alpha_c and
    the bound |A_cd| <= sum_{p shared} w_p |g_cp| |g_dp|::

        r_c = alpha_c / D_c + D_c^-1/2 sum_{p in c} w_p |g_cp| G_p,   G_p = sum_{d at p} |g_dp| / D_d^1/2
        omega_c = scale / r_c   (r_c >= 1; any scale < 2 converges: 2 D'/scale - A stays SPD)

    Soft constraints (alpha dominates) get omega ~ 1; stiff ones about one
    over the number of constraints they share particles with, which is what
    keeps stiff XPBD Jacobi from diverging (a uniform omega of 1 or 0.5
    diverged once 2 k dt^2 / m > ~200). Gradients are taken at ``x``.

    ``node_sum`` (N,) is scratch; ``omega_e`` (E,), ``omega_t`` (T,) are outputs.
    """
    for i in range(node_sum.shape[0]):
        node_sum[i] = 0.0
    # pass 1: sqrt(D_c) into omega, G_p into node_sum
    for e in range(edges.shape[0]):
        i, j, g = _edge_gradient_length(x, edges, e)
        d = (inv_mass[i] + inv_mass[j]) * g + alpha_e
        if d <= 0.0:
            omega_e[e] = 0.0
            continue
        sd = math.sqrt(d)
        omega_e[e] = sd
        node_sum[i] += g / sd
        node_sum[j] += g / sd
    for t in range(tris.shape[0]):
        a, b, c, ga, gb, gc = _area_gradient_lengths(x, tris, t, signed)
        d = inv_mass[a] * ga * ga + inv_mass[b] * gb * gb + inv_mass[c] * gc * gc + alpha_t
        if d <= 0.0:
            omega_t[t] = 0.0
            continue
        sd = math.sqrt(d)
        omega_t[t] = sd
        node_sum[a] += ga / sd
        node_sum[b] += gb / sd
        node_sum[c] += gc / sd
    # pass 2: omega_c = scale / r_c
    for e in range(edges.shape[0]):
        sd = omega_e[e]
        if sd == 0.0:
            continue
        i, j, g = _edge_gradient_length(x, edges, e)
        r = alpha_e / (sd * sd) + g * (inv_mass[i] * node_sum[i] + inv_mass[j] * node_sum[j]) / sd
        omega_e[e] = scale / r if r > 0.0 else scale
    for t in range(tris.shape[0]):
        sd = omega_t[t]
        if sd == 0.0:
            continue
        a, b, c, ga, gb, gc = _area_gradient_lengths(x, tris, t, signed)
        r = alpha_t / (sd * sd) + (inv_mass[a] * ga * node_sum[a] + inv_mass[b] * gb * node_sum[b]
                                   + inv_mass[c] * gc * node_sum[c]) / sd
        omega_t[t] = scale / r if r > 0.0 else scale


@njit(cache=True, nogil=True)
def jacobi_iterations(x: np.ndarray, inv_mass: np.ndarray, edge_set: tuple, tri_set: tuple, tool: tuple,
                      coeffs: tuple, mults: tuple, signed: bool, iterations: int, particle_scale: np.ndarray,
                      dx_acc: np.ndarray) -> None:
    """``iterations`` Jacobi sweeps: every constraint sees the positions of the sweep's start.

    Corrections are summed per particle and applied as
    ``x += particle_scale * sum`` (``1 / constraint count`` for the paper
    authors' averaging, 1 with per-constraint relaxation ``omega_*``); then
    the tool, as in :func:`gauss_seidel_iterations`, whose bundles these are (offsets unused; ``mults`` =
    (lam_e, lam_t, omega_e, omega_t) with the relaxations used). ``dx_acc`` (N, 2) must be zero on entry and is
    zero on exit.
    """
    edges, rest, _edge_offsets = edge_set
    tris, area0, _tri_offsets = tri_set
    k_e, alpha_e, k_t, alpha_t = coeffs
    lam_e, lam_t, omega_e, omega_t = mults
    for _ in range(iterations):
        jacobi_edges(x, inv_mass, edges, rest, k_e, alpha_e, lam_e, omega_e, dx_acc)
        jacobi_areas(x, inv_mass, tris, area0, k_t, alpha_t, lam_t, signed, omega_t, dx_acc)
        jacobi_apply(x, dx_acc, particle_scale)
        tool_contact(x, inv_mass, tool)


def tool_pack(x_start: np.ndarray, candidates: np.ndarray, shape0: np.ndarray, shape1: np.ndarray,
              dx_accum: np.ndarray, surface_edges: np.ndarray, edge_side_tol: float) -> tuple:
    """The projection contact's arrays of a (sub)step, packed for the iteration kernels (order as documented there)."""
    return (x_start, candidates, shape0, shape1, dx_accum, surface_edges, float(edge_side_tol))
