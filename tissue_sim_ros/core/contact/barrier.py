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

CCD caps every line search so that no pair's gap falls below ``CCD_KEEP`` of what it was. Where the pair's points
move on straight lines (the tissue along a search direction, the tool sliding without turning) that time is
found to round-off (:func:`toi_point_segment`: a quadratic for the ends, a bracketed root for the segment's line).
Where the tool turns or its jaw moves, additive
CCD (Li, Kaufman, Jiang 2021, "Codimensional IPC", algorithm 1): advance in steps of 0.9 g / l_p (l_p bounds how
fast the pair's points close on each other) until the gap falls below ``CCD_KEEP g0``; conservative, and slow
only where a long edge turns about the contact (l_p large, g small), which a sliding tool does not meet.
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
def ccd_pair(p0: np.ndarray, a0: np.ndarray, b0: np.ndarray, dp: np.ndarray, da: np.ndarray, db: np.ndarray,
             xi: float, t_max: float) -> float:
    """The largest step in [0, t_max] over which a point moving p0 + t dp keeps CCD_KEEP of its gap |p - c| - xi
    to a segment (a0 + t da, b0 + t db) (:func:`toi_point_segment`); 0 when they touch already."""
    d, _, _, _ = point_segment(p0[0], p0[1], a0[0], a0[1], b0[0], b0[1])
    gap0 = d - xi
    if gap0 <= 0.0:
        return 0.0
    return toi_point_segment(p0[0], p0[1], dp[0], dp[1], a0[0], a0[1], da[0], da[1], b0[0], b0[1], db[0], db[1],
                             xi + CCD_KEEP * gap0, t_max)


@njit(cache=True, inline="always")
def _circle_toi(wx: float, wy: float, vx: float, vy: float, r: float) -> float:
    """First t >= 0 with |w + t v| = r for a point w outside the circle of radius r about the origin (inf:
    never): the smaller root of a quadratic, in its stable form."""
    a = vx * vx + vy * vy
    b = 2.0 * (wx * vx + wy * vy)
    c = wx * wx + wy * wy - r * r
    if a <= 0.0 or b >= 0.0 or c <= 0.0:
        return math.inf if c > 0.0 else 0.0
    disc = b * b - 4.0 * a * c
    if disc < 0.0:
        return math.inf
    return 2.0 * c / (-b + math.sqrt(disc))


@njit(cache=True, inline="always")
def _line_gap(wx: float, wy: float, dwx: float, dwy: float, ex: float, ey: float, dex: float, dey: float, t: float,
              side: float, r: float) -> float:
    """side (e x w) / |e| - r at time t: the point's distance to the segment's line past r, on its starting side."""
    qx, qy = wx + t * dwx, wy + t * dwy
    fx, fy = ex + t * dex, ey + t * dey
    ll = math.sqrt(fx * fx + fy * fy)
    return side * (fx * qy - fy * qx) / ll - r if ll > 0.0 else math.inf


@njit(cache=True, nogil=True)
def toi_point_segment(px: float, py: float, dpx: float, dpy: float, ax: float, ay: float, dax: float, day: float,
                      bx: float, by: float, dbx: float, dby: float, r: float, t_max: float) -> float:
    """First time in [0, t_max] at which a point moving linearly (p + t dp) comes within r of a segment whose ends
    move linearly (a + t da, b + t db); t_max when it does not. The earliest of: the point reaching either end's
    circle of radius r (the smaller root of a quadratic, exact) and its distance to the segment's line falling to
    r where its projection is on the segment (the first root of (e x w) / |e| = r, bracketed: before the line's
    crossing, e x w a quadratic in t, or at the quadratic's turn, then bisected to round-off). The point must
    start farther than r."""
    wx, wy = px - ax, py - ay
    dwx, dwy = dpx - dax, dpy - day
    ex, ey = bx - ax, by - ay
    dex, dey = dbx - dax, dby - day
    t_end = min(t_max, _circle_toi(wx, wy, dwx, dwy, r),
                _circle_toi(px - bx, py - by, dpx - dbx, dpy - dby, r))
    c0 = ex * wy - ey * wx
    if c0 == 0.0 or t_end <= 0.0:
        return max(t_end, 0.0)
    side = 1.0 if c0 > 0.0 else -1.0
    c1 = side * (ex * dwy + dex * wy - ey * dwx - dey * wx)
    c2 = side * (dex * dwy - dey * dwx)
    # the first time in (0, t_end] with the line's gap <= 0: at the turn of side (e x w) (its least), or t_end
    hit = math.inf
    if c2 > 0.0 and c1 < 0.0 and -c1 / (2.0 * c2) < t_end:
        t_turn = -c1 / (2.0 * c2)
        if _line_gap(wx, wy, dwx, dwy, ex, ey, dex, dey, t_turn, side, r) <= 0.0:
            hit = t_turn
    if hit == math.inf and _line_gap(wx, wy, dwx, dwy, ex, ey, dex, dey, t_end, side, r) <= 0.0:
        hit = t_end
    if hit == math.inf:
        return t_end
    lo, hi = 0.0, hit
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if _line_gap(wx, wy, dwx, dwy, ex, ey, dex, dey, mid, side, r) > 0.0:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-12 * hit:
            break
    # on the segment there? (past an end, that end's circle is what it meets)
    qx, qy = wx + lo * dwx, wy + lo * dwy
    fx, fy = ex + lo * dex, ey + lo * dey
    ll = fx * fx + fy * fy
    sp = (qx * fx + qy * fy) / ll if ll > 0.0 else -1.0
    return lo if 0.0 <= sp <= 1.0 else t_end
