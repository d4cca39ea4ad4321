"""Numba kernels of one simulation step around the solve, on plain arrays: the prediction, the paper contact's
held particles, the velocity update and the boundary lines, the energy terms, the residual, inverted triangles,
and the orders the sweeps run in (colouring, wavefronts).

The sweeps themselves (distance and area projections, Gauss-Seidel and Jacobi) are in
:mod:`~tissue_sim_ros.core.physics.sweeps`. Every kernel takes arrays and scalars and writes into preallocated
outputs (``@njit(cache=True)``); each has a slow NumPy twin in ``test/naive.py`` and the tests compare the two
on random and degenerate input.
"""
from __future__ import annotations

import math
import os

import numba
import numpy as np
from numba import njit

# An empty two-iteration prange call costs 2.2 us with OpenMP and 68 us with
# numba's workqueue layer (the default here: tbb is not installed), medians on
# the 2-core VM. The layer is fixed at the first parallel call, so choose it at
# import unless the user did (NUMBA_THREADING_LAYER).
if "NUMBA_THREADING_LAYER" not in os.environ and numba.config.THREADING_LAYER == "default":
    numba.config.THREADING_LAYER = "omp"

#: Squared length [m^2] below which an edge (or a triangle's gradient) counts as
#: degenerate and its projection is skipped: its direction is undefined.
EPS_LEN2 = 1e-30



# ----------------------------------------------------------------------------- triangle geometry (inlined)


@njit(cache=True, inline="always")
def tri_edges(x: np.ndarray, a: int, b: int, c: int) -> tuple[float, float, float, float]:
    """Edge vectors e1 = x_b - x_a and e2 = x_c - x_a of triangle (a, b, c) at ``x`` [m]: (e1x, e1y, e2x, e2y).

    The one place a triangle's geometry is read: the signed area (:func:`tri_cross`), the area constraint's
    gradients (:func:`area_gradients`) and the material's deformation gradient start here. Inlined, so each
    caller compiles it under its own fast-math flags.
    """
    return x[b, 0] - x[a, 0], x[b, 1] - x[a, 1], x[c, 0] - x[a, 0], x[c, 1] - x[a, 1]


@njit(cache=True, inline="always")
def tri_cross(x: np.ndarray, a: int, b: int, c: int) -> float:
    """(x_b - x_a) x (x_c - x_a): twice the signed area of triangle (a, b, c) at ``x`` [m^2] (> 0: CCW)."""
    e1x, e1y, e2x, e2y = tri_edges(x, a, b, c)
    return e1x * e2y - e1y * e2x


@njit(cache=True, inline="always")
def area_gradients(e1x: float, e1y: float, e2x: float, e2y: float,
                   sg: float) -> tuple[float, float, float, float, float, float]:
    """Gradients of sg (e1 x e2) at the corners a, b, c: (ga_x, ga_y, gb_x, gb_y, gc_x, gc_y).

    grad_b = sg (e2y, -e2x), grad_c = sg (-e1y, e1x), grad_a = -(grad_b + grad_c); sg = 1/2 gives the signed
    area's gradient, -1/2 the gradient of |area| of an inverted triangle.
    """
    gbx = sg * e2y
    gby = -sg * e2x
    gcx = -sg * e1y
    gcy = sg * e1x
    return -gbx - gcx, -gby - gcy, gbx, gby, gcx, gcy


@njit(cache=True, inline="always")
def add_corners(out: np.ndarray, a: int, b: int, c: int, wa: float, wb: float, wc: float, s: float,
                grads: tuple) -> None:
    """out_p += w_p s grad_p at the corners a, b, c of a triangle: a projection's correction (``out`` the positions,
    or a Jacobi sweep's sum); ``grads`` = (ga_x, ga_y, gb_x, gb_y, gc_x, gc_y)."""
    gax, gay, gbx, gby, gcx, gcy = grads
    out[a, 0] += wa * s * gax
    out[a, 1] += wa * s * gay
    out[b, 0] += wb * s * gbx
    out[b, 1] += wb * s * gby
    out[c, 0] += wc * s * gcx
    out[c, 1] += wc * s * gcy


# ----------------------------------------------------------------------------- prediction


@njit(cache=True, nogil=True)
def predict(x: np.ndarray, v: np.ndarray, inv_mass: np.ndarray, dt: float, gravity: float,
            damp: float, x_pred: np.ndarray) -> None:
    """Explicit prediction x* = x + dt damp v + dt^2 (0, g) for free particles.

    Parameters
    ----------
    x, v : (N, 2) float64
        Positions [m] and velocities [m/s] at the start of the (sub)step.
    inv_mass : (N,) float64
        Inverse masses [1/kg]; particles with 0 keep their position.
    dt : float
        (Sub)step [s].
    gravity : float
        Gravity along y [m/s^2].
    damp : float
        Velocity scale max(0, 1 - damping dt) (1 = no damping).
    x_pred : (N, 2) float64
        Output: predicted positions [m].
    """
    dv = dt * gravity
    for i in range(x.shape[0]):
        if inv_mass[i] > 0.0:
            x_pred[i, 0] = x[i, 0] + dt * damp * v[i, 0]
            x_pred[i, 1] = x[i, 1] + dt * (damp * v[i, 1] + dv)
        else:
            x_pred[i, 0] = x[i, 0]
            x_pred[i, 1] = x[i, 1]


@njit(cache=True, nogil=True)
def hold_displaced(x_pred: np.ndarray, inv_mass: np.ndarray, held_idx: np.ndarray, held_dx: np.ndarray,
                   scale: float, inv_mass_eff: np.ndarray) -> None:
    """The paper's contact: move held particles by ``scale * held_dx`` and hold them.

    ``inv_mass_eff`` (N,) is set to ``inv_mass`` with the held particles zeroed
    (they are not moved by the constraint solve this step). Pinned particles
    (``inv_mass == 0``) are never displaced.
    """
    for i in range(inv_mass.shape[0]):
        inv_mass_eff[i] = inv_mass[i]
    for k in range(held_idx.shape[0]):
        i = held_idx[k]
        if inv_mass[i] > 0.0:
            x_pred[i, 0] += scale * held_dx[k, 0]
            x_pred[i, 1] += scale * held_dx[k, 1]
        inv_mass_eff[i] = 0.0


@njit(cache=True, nogil=True)
def place_held(x: np.ndarray, x_step_start: np.ndarray, x_target: np.ndarray, inv_mass: np.ndarray,
               held_idx: np.ndarray, f: float) -> None:
    """Substeps of the paper's contact: held particles at fraction f of the way to their full-step target.

    x_i = x_step_start_i + f (x_target_i - x_step_start_i) for held free particles,
    so after the last substep (f = 1) they sit exactly where one full step puts
    them (x_t + dt v + dt^2 g + held_dx), and the substeps' velocity updates do
    not compound the displacement.
    """
    for k in range(held_idx.shape[0]):
        i = held_idx[k]
        if inv_mass[i] > 0.0:
            x[i, 0] = x_step_start[i, 0] + f * (x_target[i, 0] - x_step_start[i, 0])
            x[i, 1] = x_step_start[i, 1] + f * (x_target[i, 1] - x_step_start[i, 1])


# ----------------------------------------------------------------------------- velocity and boundary


@njit(cache=True, nogil=True)
def update_velocity(x: np.ndarray, x_start: np.ndarray, dt: float, v: np.ndarray) -> None:
    """v = (x - x_start) / dt [m/s] for every particle."""
    inv_dt = 1.0 / dt
    for i in range(x.shape[0]):
        v[i, 0] = (x[i, 0] - x_start[i, 0]) * inv_dt
        v[i, 1] = (x[i, 1] - x_start[i, 1]) * inv_dt


@njit(cache=True, nogil=True)
def apply_boundary_lines(x: np.ndarray, v: np.ndarray, inv_mass: np.ndarray, y_top: float,
                         y_bottom: float) -> int:
    """The paper's horizontal lines: a free particle at or past a line is put on it with velocity zero.

    A NaN line is absent. Pinned particles (``inv_mass == 0``) are left
    where they are (they may rest beyond a line). Returns how many were held.
    """
    has_top = not math.isnan(y_top)
    has_bottom = not math.isnan(y_bottom)
    held = 0
    for i in range(x.shape[0]):
        if inv_mass[i] == 0.0:
            continue
        if has_top and x[i, 1] >= y_top:
            x[i, 1] = y_top
        elif has_bottom and x[i, 1] <= y_bottom:
            x[i, 1] = y_bottom
        else:
            continue
        v[i, 0] = 0.0
        v[i, 1] = 0.0
        held += 1
    return held


# ----------------------------------------------------------------------------- energy and residual


@njit(cache=True, nogil=True)
def energy_terms_kernel(x: np.ndarray, x_pred: np.ndarray, mass: np.ndarray, particle_body: np.ndarray,
                        edge_set: tuple, tri_set: tuple, coeffs: tuple, out: tuple) -> None:
    """Implicit Euler energy terms of the constraints per body.

    inertial_b = 1/2 sum_i m_i |x_i - x*_i|^2;
    spring_b = dt^2 sum_e 1/2 K_s (|x_a - x_b| - l0)^2 (current lengths only, so
    a rigid rotation leaves it unchanged); area_b = dt^2 sum_t 1/2 K_a C_t^2.
    ``edge_set`` = (edges (E, 2), rest lengths (E,) [m], edge_body (E,)), ``tri_set`` = (triangles (T, 3),
    signed rest areas (T,) [m^2], tri_body (T,)) (empty: none), ``coeffs`` = (K_s, K_a, dt [s], signed),
    ``out`` = (inertial, spring, area), (B,) float64 each, overwritten.
    """
    edges, rest, edge_body = edge_set
    tris, area0, tri_body = tri_set
    k_spring, k_area, dt, signed = coeffs
    inertial, spring, area = out
    for b in range(inertial.shape[0]):
        inertial[b] = 0.0
        spring[b] = 0.0
        area[b] = 0.0
    for i in range(x.shape[0]):
        dx = x[i, 0] - x_pred[i, 0]
        dy = x[i, 1] - x_pred[i, 1]
        inertial[particle_body[i]] += 0.5 * mass[i] * (dx * dx + dy * dy)
    hs = 0.5 * k_spring * dt * dt
    for e in range(edges.shape[0]):
        i = edges[e, 0]
        j = edges[e, 1]
        dx = x[i, 0] - x[j, 0]
        dy = x[i, 1] - x[j, 1]
        C = math.sqrt(dx * dx + dy * dy) - rest[e]
        spring[edge_body[e]] += hs * C * C
    ha = 0.5 * k_area * dt * dt
    for t in range(tris.shape[0]):
        a = tris[t, 0]
        b = tris[t, 1]
        c = tris[t, 2]
        A = 0.5 * tri_cross(x, a, b, c)
        C = A - area0[t] if signed else abs(A) - abs(area0[t])
        area[tri_body[t]] += ha * C * C


@njit(cache=True, nogil=True)
def constraint_residual(x: np.ndarray, edges: np.ndarray, rest: np.ndarray, tris: np.ndarray,
                        area0: np.ndarray, signed: bool) -> float:
    """RMS over all constraints of C / l0 (edges) and C / |A0| (triangles); 0 without constraints.

    Constraints with a zero rest size contribute C itself.
    """
    total = 0.0
    for e in range(edges.shape[0]):
        i = edges[e, 0]
        j = edges[e, 1]
        dx = x[i, 0] - x[j, 0]
        dy = x[i, 1] - x[j, 1]
        C = math.sqrt(dx * dx + dy * dy) - rest[e]
        if rest[e] > 0.0:
            C /= rest[e]
        total += C * C
    for t in range(tris.shape[0]):
        a = tris[t, 0]
        b = tris[t, 1]
        c = tris[t, 2]
        A = 0.5 * tri_cross(x, a, b, c)
        C = A - area0[t] if signed else abs(A) - abs(area0[t])
        if area0[t] != 0.0:
            C /= abs(area0[t])
        total += C * C
    n = edges.shape[0] + tris.shape[0]
    if n == 0:
        return 0.0
    return math.sqrt(total / n)


@njit(cache=True, nogil=True)
def count_inverted(x: np.ndarray, tris: np.ndarray) -> int:
    """Triangles whose signed area (x_b - x_a) x (x_c - x_a) / 2 is <= 0."""
    n = 0
    for t in range(tris.shape[0]):
        a = tris[t, 0]
        b = tris[t, 1]
        c = tris[t, 2]
        if tri_cross(x, a, b, c) <= 0.0:
            n += 1
    return n


# ----------------------------------------------------------------------------- colouring


@njit(cache=True, nogil=True)
def greedy_colour(indices: np.ndarray, n_particles: int, colour: np.ndarray) -> int:
    """Greedy constraint colouring: no two constraints of one colour share a particle.

    Constraints are visited in array order and each takes the smallest colour
    not yet used at any of its particles (a 64-bit mask per particle, so at
    most 64 colours; a mesh with a vertex of degree > 63 raises).

    Parameters
    ----------
    indices : (M, K) int32
        Particles of each constraint.
    n_particles : int
        Number of particles.
    colour : (M,) int64
        Output: colour of each constraint.

    Returns
    -------
    int
        Number of colours used.
    """
    used = np.zeros(n_particles, dtype=np.uint64)
    n_colours = 0
    for m in range(indices.shape[0]):
        mask = np.uint64(0)
        for q in range(indices.shape[1]):
            mask |= used[indices[m, q]]
        c = 0
        while c < 64 and (mask >> np.uint64(c)) & np.uint64(1):
            c += 1
        if c == 64:
            raise ValueError("greedy_colour: more than 64 colours needed (a vertex of very high degree)")
        colour[m] = c
        bit = np.uint64(1) << np.uint64(c)
        for q in range(indices.shape[1]):
            used[indices[m, q]] |= bit
        if c + 1 > n_colours:
            n_colours = c + 1
    return n_colours


@njit(cache=True, nogil=True)
def wavefront_levels(indices: np.ndarray, n_particles: int, block: int, level: np.ndarray) -> int:
    """Wavefront schedule of a Gauss-Seidel sweep, per block of ``block`` consecutive constraints.

    Within a block, level(c) = 1 + the highest level of the block's earlier
    constraints that share a particle with c. Sorting constraints stably by
    (block, level) keeps, at every particle, the order of the constraints that
    touch it, so a sweep in that order gives bit for bit the result of the
    sweep in array (mesh) order. Constraints of one level share no particle,
    so consecutive projections no longer wait for each other's stores (the
    mesh-order sweep is latency-bound: ~16 ns each); blocks keep the
    particles a stretch of the sweep touches in the L1 cache.

    Parameters
    ----------
    indices : (M, K) int32
        Particles of each constraint, in sweep order.
    n_particles : int
        Number of particles.
    block : int
        Constraints per block (>= 1); M or more gives one block.
    level : (M,) int64
        Output: level of each constraint within its block (0-based).

    Returns
    -------
    int
        The largest number of levels in a block.
    """
    last = np.full(n_particles, -1, dtype=np.int64)
    stamp = np.full(n_particles, -1, dtype=np.int64)
    n_levels = 0
    for m in range(indices.shape[0]):
        b = m // block
        lv = -1
        for q in range(indices.shape[1]):
            p = indices[m, q]
            if stamp[p] == b and last[p] > lv:
                lv = last[p]
        lv += 1
        level[m] = lv
        for q in range(indices.shape[1]):
            p = indices[m, q]
            last[p] = lv
            stamp[p] = b
        if lv + 1 > n_levels:
            n_levels = lv + 1
    return n_levels
