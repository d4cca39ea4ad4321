r"""Numba kernels of the barrier contact (Incremental Potential Contact, Li et al. 2020, in 2D): the point-segment
distance and its gradient, the barrier and its derivatives, the smoothed friction, and continuous collision
detection (CCD) that caps a line search so no pair ever crosses.

A pair is a point p against a segment (a, b) (a point core when a == b), each side possibly inflated by a
thickness xi (a capsule's radius, the tool's rounding): its gap is d = |p - c| - xi with c the segment's point
nearest p. Every pair the solver meets is one of: a tissue boundary vertex against a tissue boundary edge (between
bodies and within one), a tissue boundary vertex against an edge of the tool's core, a core vertex against a
tissue boundary edge.

The barrier (IPC, eq. 6), for 0 < d < dhat, zero beyond::

    b(d) = -(d - dhat)^2 ln(d / dhat)
    b'(d) = -2 (d - dhat) ln(d / dhat) - (d - dhat)^2 / d                       (<= 0: it pushes apart)
    b''(d) = -2 ln(d / dhat) - 4 (d - dhat) / d + (d - dhat)^2 / d^2          (> 0)

and the distance's gradient by the envelope theorem (the nearest point's parameter t held): with n = (p - c) / |p -
c|, dd/dp = n, dd/da = -(1 - t) n, dd/db = -t n. The solver's Hessian of a pair is b'' grad d grad d^T (the
Gauss-Newton part, positive semi-definite; the b' grad^2 d part is left to its quasi-Newton updates).

Friction (IPC, section 5, lagged): a pair's tangential slip u over the step, with its normal force lambda and
tangent frozen at the step's start, dissipates mu lambda f0(|u|) with the smoothed Coulomb profile
f0(y) = -y^3 / (3 eps^2) + y^2 / eps + eps / 3 for |y| < eps, |y| beyond (eps = eps_v dt: the slip below which
friction is sticking), f1 = f0' = min(1, (2 - y / eps) y / eps).

CCD: additive CCD (Li, Kaufman, Jiang 2021, "Codimensional IPC", algorithm 1): from a pair's gap g0 > 0,
advance in steps of 0.9 g / l_p (l_p bounds how fast the pair's points close on each other) until the gap falls
below ``s g0``; the time before that step is a conservative time of impact. It needs only the distance at any
time and the bound l_p, so it serves points moving on straight lines (the tissue along a search direction) and a
rigid tool turning and sliding alike.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

#: CCD keeps at least this fraction of a pair's gap (the line search never closes more than 1 - s of it at once).
CCD_KEEP = 0.1
#: Steps of an additive CCD at most before it gives up and returns the time reached (conservative).
CCD_MAX_STEPS = 200


@njit(cache=True, inline="always")
def point_segment(px: float, py: float, ax: float, ay: float, bx: float, by: float):
    """Distance from p to the segment (a, b) and its nearest point: (d, t, cx, cy), c = a + t (b - a), t in
    [0, 1] (0 for a point segment a == b)."""
    ex = bx - ax
    ey = by - ay
    ll = ex * ex + ey * ey
    t = 0.0
    if ll > 0.0:
        t = ((px - ax) * ex + (py - ay) * ey) / ll
        if t < 0.0:
            t = 0.0
        elif t > 1.0:
            t = 1.0
    cx = ax + t * ex
    cy = ay + t * ey
    dx = px - cx
    dy = py - cy
    return math.sqrt(dx * dx + dy * dy), t, cx, cy


@njit(cache=True, inline="always")
def barrier(d: float, dhat: float) -> tuple[float, float, float]:
    """(b, b', b'') of the IPC barrier at gap d (module docstring); zero at d >= dhat, +inf at d <= 0."""
    if d >= dhat:
        return 0.0, 0.0, 0.0
    if d <= 0.0:
        return math.inf, -math.inf, math.inf
    r = d - dhat
    lg = math.log(d / dhat)
    return -r * r * lg, -2.0 * r * lg - r * r / d, -2.0 * lg - 4.0 * r / d + r * r / (d * d)


@njit(cache=True, inline="always")
def friction_f0(y: float, eps: float) -> float:
    """The smoothed Coulomb profile f0 (module docstring): the dissipation of a slip y per unit mu lambda."""
    if y >= eps:
        return y
    return -y * y * y / (3.0 * eps * eps) + y * y / eps + eps / 3.0


@njit(cache=True, inline="always")
def friction_f1_over_y(y: float, eps: float) -> float:
    """f0'(y) / y: the friction force per unit slip per unit mu lambda (1 / y when sliding, (2 - y/eps) / eps
    when sticking, finite at y = 0)."""
    if y >= eps:
        return 1.0 / y
    return (2.0 - y / eps) / eps


@njit(cache=True, inline="always")
def friction_f2(y: float, eps: float) -> float:
    """f0''(y), y >= 0: 2 (1 - y/eps) / eps sticking, 0 sliding (continuous at y = eps)."""
    if y >= eps:
        return 0.0
    return 2.0 * (1.0 - y / eps) / eps


@njit(cache=True, nogil=True)
def accd_pair(p0: np.ndarray, a0: np.ndarray, b0: np.ndarray, dp: np.ndarray, da: np.ndarray, db: np.ndarray,
              xi: float, t_max: float) -> float:
    """Conservative time of impact in [0, t_max] of a point moving p0 + t dp against a segment (a0 + t da, b0 + t
    db), gap |p - c| - xi (additive CCD, module docstring); t_max when they do not come within CCD_KEEP of their
    gap. The displacements' common part is taken out first (it moves neither closer)."""
    mx = (dp[0] + da[0] + db[0]) / 3.0
    my = (dp[1] + da[1] + db[1]) / 3.0
    dpx, dpy = dp[0] - mx, dp[1] - my
    dax, day = da[0] - mx, da[1] - my
    dbx, dby = db[0] - mx, db[1] - my
    lp = math.sqrt(dpx * dpx + dpy * dpy) + max(math.sqrt(dax * dax + day * day), math.sqrt(dbx * dbx + dby * dby))
    if lp <= 0.0:
        return t_max
    d, _, _, _ = point_segment(p0[0], p0[1], a0[0], a0[1], b0[0], b0[1])
    gap0 = d - xi
    if gap0 <= 0.0:
        return 0.0
    keep = CCD_KEEP * gap0
    t = 0.0
    tl = (1.0 - CCD_KEEP) * gap0 / lp
    for _ in range(CCD_MAX_STEPS):
        tn = t + tl
        d, _, _, _ = point_segment(p0[0] + tn * dpx, p0[1] + tn * dpy, a0[0] + tn * dax, a0[1] + tn * day,
                                   b0[0] + tn * dbx, b0[1] + tn * dby)
        if t > 0.0 and d - xi < keep:  # (the first advance is safe by construction: l_p bounds the closing)
            return t
        t = tn
        if t > t_max:
            return t_max
        tl = 0.9 * (d - xi) / lp
    return t
