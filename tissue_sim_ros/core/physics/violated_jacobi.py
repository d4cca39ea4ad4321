r"""PBD Jacobi as the paper authors' code averages it (their walls: :mod:`~tissue_sim_ros.core.physics.walls`).

The authors' ``forward()`` (y8han/2DPBD_Interface, ``Surgical_spring_IROS_workshop.py``,
commit a0ff238) solves the springs and areas in parallel (Jacobi), but it does not
average a particle's corrections over all of its constraints: in every
iteration it first finds the *violated* ones,

* a spring e = (i, j) is violated when |C_e| >= tol_s, C_e = |x_i - x_j| - d_e
  (their ``epsolon`` = 1e-4 m);
* a triangle t is violated when |C_t| > tol_a, C_t = |A_t| - |A0_t| (their
  ``area_epsolon`` = 1e-11 m^2; with ``area_mode: signed`` C_t = A_t - A0_t),

counts them per particle and per type (n_s(i) springs, n_a(i) triangles), and
moves each free particle by the two averages added::

    dx_i = 1/n_s(i) sum_{violated e at i} -k_s w_i / (w_i + w_j) C_e (x_i - x_j) / |x_i - x_j|
         + 1/n_a(i) sum_{violated t at i} -k_a w_i C_t / (sum_p w_p |grad_p C_t|^2) grad_i C_t

(an average with no violated constraint of its type is 0). The spring
stiffness k_s scales its correction, the area correction is the full one
(their code has no area coefficient; ``k_area`` = 1 is theirs). A violated
triangle whose area is exactly 0 is counted but not corrected, as theirs
(its |A| has no gradient). ``w`` are the inverse masses weighting each
correction; only particles with ``w_move > 0`` move (the paper contact's
held particles keep their mass in their neighbours' weights but are not
moved, as the authors' ``actuation_type == 2`` particles). After the
corrections are applied every particle, pinned ones too, is clamped into
the walls (their ``collision_check``): y < y_bottom -> y_bottom, y > y_top -> y_top.

:func:`~tissue_sim_ros.core.physics.sweeps.jacobi_iterations` with per-particle scale
1 / (all constraints at i) is the other averaging (``jacobi_averaging: all``).
Twins: ``test/naive.py`` (``authors_forward``, written from the authors' code
line by line, and ``apply_walls``).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .kernels import add_corners, area_gradients, tri_edges
from .sweeps import tool_contact
from .walls import apply_walls

#: Squared length [m^2] below which an edge (or a triangle's gradient) counts as degenerate.
EPS_LEN2 = 1e-30


@njit(cache=True, nogil=True)
def violated_jacobi_pass(x: np.ndarray, w: np.ndarray, w_move: np.ndarray, constraints: tuple,
                         scratch: tuple) -> None:
    """One authors' Jacobi iteration: corrections from the same ``x``, averaged per type over violated constraints.

    Parameters
    ----------
    x : (N, 2) float64
        Positions [m], updated in place.
    w : (N,) float64
        Inverse masses weighting the corrections [1/kg] (0 = pinned).
    w_move : (N,) float64
        A particle moves only where ``w_move > 0`` (the step's held particles are 0 here, not in ``w``).
    constraints : tuple
        (edges (E, 2) int32, rest lengths (E,) [m], k_e, tol_e [m], triangles (T, 3) int32, signed rest areas
        (T,) [m^2], k_t, tol_a [m^2], signed): the springs' and areas' coefficients and violation tolerances.
    scratch : tuple
        (dxs (N, 2), dxa (N, 2), ns (N,), na (N,)) float64: summed spring / area corrections and violated
        counts (overwritten).
    """
    edges, rest, k_e, tol_e, tris, area0, k_t, tol_a, signed = constraints
    dxs, dxa, ns, na = scratch
    n = x.shape[0]
    for i in range(n):
        dxs[i, 0] = 0.0
        dxs[i, 1] = 0.0
        dxa[i, 0] = 0.0
        dxa[i, 1] = 0.0
        ns[i] = 0.0
        na[i] = 0.0
    for e in range(edges.shape[0]):
        i = edges[e, 0]
        j = edges[e, 1]
        dx = x[i, 0] - x[j, 0]
        dy = x[i, 1] - x[j, 1]
        len2 = dx * dx + dy * dy
        length = math.sqrt(len2)
        C = length - rest[e]
        if abs(C) < tol_e:
            continue
        ns[i] += 1.0
        ns[j] += 1.0
        wi = w[i]
        wj = w[j]
        ws = wi + wj
        if ws == 0.0 or len2 <= EPS_LEN2:
            continue
        f = -k_e * C / (ws * length)
        dxs[i, 0] += wi * f * dx
        dxs[i, 1] += wi * f * dy
        dxs[j, 0] -= wj * f * dx
        dxs[j, 1] -= wj * f * dy
    for t in range(tris.shape[0]):
        a = tris[t, 0]
        b = tris[t, 1]
        c = tris[t, 2]
        e1x, e1y, e2x, e2y = tri_edges(x, a, b, c)
        area = 0.5 * (e1x * e2y - e1y * e2x)
        if signed:
            C = area - area0[t]
            sg = 0.5
        else:
            C = abs(area) - abs(area0[t])
            sg = 0.5 if area > 0.0 else -0.5
        if not abs(C) > tol_a:
            continue
        na[a] += 1.0
        na[b] += 1.0
        na[c] += 1.0
        if not signed and area == 0.0:
            continue
        gax, gay, gbx, gby, gcx, gcy = area_gradients(e1x, e1y, e2x, e2y, sg)
        den = (w[a] * (gax * gax + gay * gay) + w[b] * (gbx * gbx + gby * gby)
               + w[c] * (gcx * gcx + gcy * gcy))
        if den <= 0.0:
            continue
        s = -k_t * C / den
        add_corners(dxa, a, b, c, w[a], w[b], w[c], s, (gax, gay, gbx, gby, gcx, gcy))
    for i in range(n):
        if w_move[i] > 0.0:
            if ns[i] > 0.0:
                x[i, 0] += dxs[i, 0] / ns[i]
                x[i, 1] += dxs[i, 1] / ns[i]
            if na[i] > 0.0:
                x[i, 0] += dxa[i, 0] / na[i]
                x[i, 1] += dxa[i, 1] / na[i]


@njit(cache=True, nogil=True)
def violated_jacobi_iterations(x: np.ndarray, w: np.ndarray, w_move: np.ndarray, constraints: tuple,
                               iterations: int, walls: tuple, scratch: tuple, tool: tuple) -> None:
    """``iterations`` of :func:`violated_jacobi_pass` (its ``constraints`` and ``scratch``), each followed by the
    tool (:func:`~tissue_sim_ros.core.physics.sweeps.tool_contact`, ``tool`` its bundle, moving ``w_move``'s
    particles) and the walls (:func:`apply_walls`; ``walls`` = (y_bottom, y_top), NaN: none)."""
    for _ in range(iterations):
        violated_jacobi_pass(x, w, w_move, constraints, scratch)
        tool_contact(x, w_move, tool)
        apply_walls(x, walls[0], walls[1])
