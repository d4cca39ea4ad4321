"""The quasi-Newton step's active set: which particles the tool, a line or a wall holds, and along what.

Each particle has a kind: FREE; TOOL (pushed out of the tool by ``contact.kernels.project_tool``: held along
the push, its normal); EDGE (moved by the edge contact ``project_edges``: held along that push); LINE (on a
boundary line or wall: held along +-y); FIXED (zero inverse mass: pinned, held by the paper contact, asleep);
CORNER (pushed along a second direction while held along a first, or whose normal kept turning: held in both
directions, where it is, for the rest of the step). A held particle slides along its surface (frictionless):
:func:`project_vector` takes the normal parts out of the gradient and the direction.

The preconditioner knows the set exactly: :func:`build_constraints` makes the rows C of the held particles
and keeps each row's column A0^-1 c under its key (particle, normal), and :func:`apply_preconditioner` applies
the inverse of A0 on the null space of C (a Schur complement on the kept columns), so a held particle does not
spoil the quasi-Newton direction of its neighbours.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..contact.kernels import _rounded_box_sdf
from .prefactor import apply_inverse
from .sweeps import tool_contact

#: Constraint kinds per particle in the solve.
FREE, TOOL, FIXED, LINE, EDGE, CORNER = 0, 1, 2, 3, 4, 5
#: A held particle pushed along a direction this far (cosine) from its normal is held in both directions.
CORNER_COS = 0.9
#: A held particle's normal that turns (cosine below this) changes the active set.
NORMAL_SAME = 1.0 - 1e-9
#: Turns of one particle's normal within a step after which it is held in both directions.
MAX_TURNS = 3
#: A particle this close to the tool's surface [m] at a step's start is held along it from the first iteration.
TOUCH_EPS = 1e-9
#: Pushes of the contacts at or below this [m] are round-off and hold nothing.
PUSH_EPS = 1e-12
#: The elimination's workspace, in the order of its bundle (:func:`build_constraints`).
ELIMINATION_FIELDS = ("wcol", "wkey", "cur_slot", "cur_i", "cur_n", "cur_c", "smat", "sinv", "used", "t")


@njit(cache=True, nogil=True)
def project_vector(v: np.ndarray, kind: np.ndarray, normal: np.ndarray) -> None:
    """Remove from ``v`` (2N,) what the active set forbids: all of a FIXED or CORNER particle, the normal part at
    TOOL, LINE and EDGE particles."""
    for i in range(kind.shape[0]):
        k = kind[i]
        if k == FIXED or k == CORNER:
            v[2 * i] = 0.0
            v[2 * i + 1] = 0.0
        elif k == TOOL or k == LINE or k == EDGE:
            s = v[2 * i] * normal[i, 0] + v[2 * i + 1] * normal[i, 1]
            v[2 * i] -= s * normal[i, 0]
            v[2 * i + 1] -= s * normal[i, 1]


@njit(cache=True, nogil=True)
def _join(i: int, k: int, kind: np.ndarray, normal: np.ndarray, scratch: np.ndarray, turns: np.ndarray) -> int:
    """Particle i was pushed by ``scratch[i]``: held along that direction as kind ``k``; 1 if the active set
    changed (it was not held, or its normal turned).

    A held particle whose push turns from its normal by more than acos(CORNER_COS), or turns at all for the
    MAX_TURNS-th time in the step (an edge's normal rocking between two tool faces), is held in both directions
    where it is (CORNER) for the rest of the step: so the set settles and the solve converges."""
    dx = scratch[i, 0]
    dy = scratch[i, 1]
    scratch[i, 0] = 0.0
    scratch[i, 1] = 0.0
    d = math.sqrt(dx * dx + dy * dy)
    if d <= PUSH_EPS or kind[i] == FIXED or kind[i] == CORNER:
        return 0  # (a push of round-off size, an edge already on the tool's face, has no direction to hold)
    nx = dx / d
    ny = dy / d
    joined = 1 if (kind[i] == FREE or kind[i] == LINE) else 0
    if kind[i] == TOOL or kind[i] == EDGE:
        c = nx * normal[i, 0] + ny * normal[i, 1]
        if c < NORMAL_SAME:
            turns[i] += 1
            if c < CORNER_COS or turns[i] >= MAX_TURNS:
                kind[i] = CORNER
                return 1
            joined = 1
    normal[i, 0] = nx
    normal[i, 1] = ny
    kind[i] = k  # the last push decides: an edge push moves a particle off the tool's surface
    return joined


@njit(cache=True, nogil=True)
def touching(x: np.ndarray, kind: np.ndarray, normal: np.ndarray, candidates: np.ndarray, shape1: np.ndarray,
             eps: float) -> None:
    """The active set's start: a free candidate within ``eps`` [m] of the tool's surface (``shape1``; a particle
    the last step left on it) is held along the surface's normal there from the first iteration."""
    for k in range(candidates.shape[0]):
        i = candidates[k]
        if kind[i] != FREE:
            continue
        d, gx, gy = _rounded_box_sdf(x[i, 0], x[i, 1], shape1)
        if abs(d) <= eps:
            kind[i] = TOOL
            normal[i, 0] = gx
            normal[i, 1] = gy


@njit(cache=True, nogil=True)
def enforce_bounds(x: np.ndarray, w: np.ndarray, kind: np.ndarray, normal: np.ndarray, tool: tuple, lines: tuple,
                   scratch: np.ndarray, turns: np.ndarray) -> int:
    """Put back every free particle past the tool, a line or a wall, and hold it along the push (its normal).

    The tool: ``tool`` = (x_start, candidates, shape0, shape1, dx_accum, surface_edges, side_tol), the bundle of
    ``sweeps.tool_contact`` (its ``dx_accum`` unused here: the pushes go to ``scratch``), swept from ``x_start``
    and ``shape0`` to ``x`` and ``shape1``; the push's direction is the normal (kind TOOL, EDGE). Lines and walls:
    ``lines`` = (y_top, y_bottom, wall_bottom, wall_top) [m] (NaN: none), y clamped, normal +-y (LINE).
    Returns how many particles joined the active set (a particle already held is moved back but not counted).
    """
    x_start, candidates, shape0, shape1, _dx_accum, surface_edges, side_tol = tool
    y_top, y_bottom, wall_bottom, wall_top = lines
    n = x.shape[0]
    moved = 0
    if candidates.shape[0] > 0:
        for k in range(candidates.shape[0]):
            i = candidates[k]
            scratch[i, 0] = 0.0
            scratch[i, 1] = 0.0
        tool_contact(x, w, (x_start, candidates, shape0, shape1, scratch, surface_edges[:0], side_tol))
        for k in range(candidates.shape[0]):
            i = candidates[k]
            moved += _join(i, TOOL, kind, normal, scratch, turns)
    if surface_edges.shape[0] > 0:
        for k in range(surface_edges.shape[0]):
            for j in range(2):
                i = surface_edges[k, j]
                scratch[i, 0] = 0.0
                scratch[i, 1] = 0.0
        tool_contact(x, w, (x_start, candidates[:0], shape0, shape1, scratch, surface_edges, side_tol))
        for k in range(surface_edges.shape[0]):
            for j in range(2):
                moved += _join(surface_edges[k, j], EDGE, kind, normal, scratch, turns)
    has_top = not math.isnan(y_top)
    has_bottom = not math.isnan(y_bottom)
    has_wb = not math.isnan(wall_bottom)
    has_wt = not math.isnan(wall_top)
    if has_top or has_bottom or has_wb or has_wt:
        for i in range(n):
            if w[i] == 0.0:
                continue
            y = x[i, 1]
            if has_top and y > y_top:
                x[i, 1] = y_top
                ny = -1.0
            elif has_wt and y > wall_top:
                x[i, 1] = wall_top
                ny = -1.0
            elif has_bottom and y < y_bottom:
                x[i, 1] = y_bottom
                ny = 1.0
            elif has_wb and y < wall_bottom:
                x[i, 1] = wall_bottom
                ny = 1.0
            else:
                continue
            if kind[i] == FREE:
                kind[i] = LINE
                normal[i, 0] = 0.0
                normal[i, 1] = ny
                moved += 1
    return moved


@njit(cache=True, nogil=True)
def build_constraints(kind: np.ndarray, normal: np.ndarray, inv_mass: np.ndarray, in_factor: np.ndarray,
                      factor: tuple, elim: tuple, b: np.ndarray, z: np.ndarray, attach_idx: np.ndarray,
                      attach_c: float) -> int:
    """The active set's rows C for the preconditioner's exact elimination (:func:`apply_preconditioner`).

    Rows, in particle order: n_i at a TOOL or LINE particle the factor does not already hold
    (``in_factor``), and the unit x and y rows at a FIXED particle that is not pinned (``inv_mass > 0``: held
    by the paper contact, asleep); pinned ones are identity rows of A0. Then the unit x and y rows of each
    particle held to the tool by an attachment (``attach_idx``): a spring, not a constraint, of compliance
    ``attach_c`` = 1 / (dt^2 k) in these units, which enters S's diagonal (``cur_c``), so the preconditioner is
    the inverse of A0 + C^T diag(1/c) C for them (Woodbury) and a stiff grasp does not slow the solve. Each row's
    column W = A0^-1 c is kept in ``wcol`` under its key (particle, n_x, n_y) in ``wkey`` and reused while the
    factor is the same (its value is a function of the key alone, so reuse changes no bit). S = C W and its
    inverse go to ``smat``, ``sinv``. Returns the number of rows k, or -1 when they would exceed the workspace (no
    elimination then).

    ``factor``: A0's factor (:attr:`~tissue_sim_ros.core.physics.prefactor.Prefactor.arrays`); ``elim`` = (wcol
    (cap, 2N), wkey (cap, 3), cur_slot (cap,), cur_i (cap,), cur_n (cap, 2), cur_c (cap,), smat (cap, cap), sinv
    (cap, cap), used (cap,), t (cap,)) the elimination's workspace (:data:`ELIMINATION_FIELDS`); ``b``, ``z``
    (2N,) scratch.
    """
    wcol, wkey, cur_slot, cur_i, cur_n, cur_c, smat, sinv, used, _t = elim
    n = kind.shape[0]
    cap = wcol.shape[0]
    k = 0
    for i in range(n):
        k_rows = 0
        if (kind[i] == TOOL or kind[i] == LINE or kind[i] == EDGE) and not in_factor[i]:
            k_rows = 1
        elif (kind[i] == FIXED and inv_mass[i] > 0.0) or kind[i] == CORNER:
            k_rows = 2
        for r in range(k_rows):
            if k == cap:
                return -1
            cur_i[k] = i
            if k_rows == 1:
                cur_n[k, 0] = normal[i, 0]
                cur_n[k, 1] = normal[i, 1]
            else:
                cur_n[k, 0] = 1.0 if r == 0 else 0.0
                cur_n[k, 1] = 0.0 if r == 0 else 1.0
            cur_c[k] = 0.0
            k += 1
    if attach_c > 0.0:
        for j in range(attach_idx.shape[0]):
            for r in range(2):
                if k == cap:
                    return -1
                cur_i[k] = attach_idx[j]
                cur_n[k, 0] = 1.0 if r == 0 else 0.0
                cur_n[k, 1] = 0.0 if r == 0 else 1.0
                cur_c[k] = attach_c
                k += 1
    for s in range(cap):
        used[s] = False
    for a in range(k):
        cur_slot[a] = -1
        for s in range(cap):
            if (not used[s] and wkey[s, 0] == cur_i[a] and wkey[s, 1] == cur_n[a, 0]
                    and wkey[s, 2] == cur_n[a, 1]):
                cur_slot[a] = s
                used[s] = True
                break
    free = 0
    for a in range(k):
        if cur_slot[a] >= 0:
            continue
        while used[free]:
            free += 1
        i = cur_i[a]
        b[2 * i] = cur_n[a, 0]
        b[2 * i + 1] = cur_n[a, 1]
        apply_inverse(factor, b, z, wcol[free])
        b[2 * i] = 0.0
        b[2 * i + 1] = 0.0
        wkey[free, 0] = i
        wkey[free, 1] = cur_n[a, 0]
        wkey[free, 2] = cur_n[a, 1]
        cur_slot[a] = free
        used[free] = True
    if k == 0:
        return 0
    for a in range(k):
        ia = cur_i[a]
        for c in range(k):
            col = wcol[cur_slot[c]]
            smat[a, c] = cur_n[a, 0] * col[2 * ia] + cur_n[a, 1] * col[2 * ia + 1]
        smat[a, a] += cur_c[a]
    sinv[:k, :k] = np.linalg.inv(smat[:k, :k])
    return k


@njit(cache=True, nogil=True)
def apply_preconditioner(factor: tuple, elim: tuple, q: np.ndarray, z: np.ndarray, out: np.ndarray, k: int) -> None:
    """out = (A0^-1 - W S^-1 W^T) q with W = A0^-1 C^T, S = C W: the inverse of A0 on the active set's null
    space (the Newton step of the quadratic model min 1/2 d^T A0 d - q^T d subject to C d = 0), from the
    rows :func:`build_constraints` made (k <= 0: A0^-1 q); ``factor``, ``elim`` as there, ``z`` (2N,) scratch."""
    wcol, _wkey, cur_slot, cur_i, cur_n, _cur_c, _smat, sinv, _used, t = elim
    apply_inverse(factor, q, z, out)
    if k <= 0:
        return
    for a in range(k):
        i = cur_i[a]
        t[a] = cur_n[a, 0] * out[2 * i] + cur_n[a, 1] * out[2 * i + 1]
    for a in range(k):
        u = 0.0
        for c in range(k):
            u += sinv[a, c] * t[c]
        col = wcol[cur_slot[a]]
        for j in range(out.shape[0]):
            out[j] -= u * col[j]
