"""The tissue as a material: a plane-stress neo-Hookean membrane, one element per triangle, solved by XPBD.

Continuum (per unit rest volume, deformation gradient F = D_s D_m^-1 of each
triangle, D = [x_1 - x_0, x_2 - x_0] in current (s) and rest (m) positions)::

    Psi(F) = mu/2 (|F|^2 - 2 det F) + lambda'/2 (det F - 1)^2          [Pa = J/m^3]

the stable neo-Hookean energy of Smith, de Goes, Kim (2018) without its log
term, written in 2D with constraints that vanish at rest (Macklin and Mueller
2021 use C_D = |F|, which does not, and collapsed a 2 mm mesh at dt 2 ms in
the issue's prototype):

    C_D = sqrt(|F|^2 - 2 det F) = |g(F)|,   g(F) = (F_00 - F_11, F_01 + F_10)
    C_H = det F - 1

Indeed |F|^2 - 2 det F = (F_00 - F_11)^2 + (F_01 + F_10)^2 >= 0, zero exactly for
a rotation times a scale (a conformal map), so at rest and under any rigid
motion. Element energy: V0 Psi with V0 = |A0| thickness [m^3], so the strain
energy is in joules.

Shifted lambda (derivation, checked numerically by ``test/test_material.py``'s
patch test). Small strain: F = I + H, eps = sym H. Then

    |F|^2 - 2 det F = |H|^2 - 2 det H = (H_00 - H_11)^2 + (H_01 + H_10)^2
                    = (eps_00 - eps_11)^2 + 4 eps_01^2 = 2 |dev eps|^2
    det F - 1 = tr eps + O(H^2)

so Psi = mu |dev eps|^2 + lambda'/2 (tr eps)^2 + O(H^3). Linear elasticity in 2D,
with |eps|^2 = |dev eps|^2 + (tr eps)^2 / 2, is
Psi_lin = mu |eps|^2 + lambda/2 (tr eps)^2 = mu |dev eps|^2 + (lambda + mu)/2 (tr eps)^2.
They agree when lambda' = lambda + mu: the form's small-strain Lame parameter
is lambda' - mu (stress P = mu (F - cof F) + lambda' (det F - 1) cof F
~ 2 mu eps + (lambda' - mu) tr eps I). Plane stress needs the in-plane lambda
lambda_ps = E nu / (1 - nu^2), so lambda' = lambda_ps + mu, mu = E / (2 (1 + nu)).

The deviatoric constraint's sqrt has no gradient at rest (C_D = 0 there, the
case of every element at the start). We solve its square instead: the energy
mu/2 C_D^2 = mu/2 (g_0^2 + g_1^2) with g linear in the positions, i.e. two
linear constraints g_0, g_1 of compliance 1/(mu V0) -- the same energy, hence
the same minimiser, with constant gradients and no singularity:

    grad_a g_0 = (c_a0, -c_a1),  grad_a g_1 = (c_a1, c_a0)

where c_a is row a-1 of D_m^-1 for a = 1, 2 and c_0 = -(c_1 + c_2). Per vertex the
two gradients are orthogonal and of equal length |c_a|, so J W J^T is
S I with S = sum_a w_a |c_a|^2: the 2x2 XPBD system is diagonal, and both
components are projected at once exactly. C_H has gradient (cof F) c_a at vertex
a; it is projected after, from the updated positions. An inverted element
(det F < 0) has C_H < -1 and is pushed back towards det F = 1.

Rest data, packed per element (``Model.tri_elastic``, (T, 6) float64)::

    [Dm^-1_00, Dm^-1_01, Dm^-1_10, Dm^-1_11, 1/(mu V0), 1/(lambda' V0)]

A triangle of zero rest area has no D_m^-1: its row is zero and it is skipped.
XPBD's alpha~ = (row's compliance) / h^2 with h the substep.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .kernels import add_corners, tri_edges
from .sweeps import tool_contact

#: Rest areas [m^2] at or below this (relative to the mean) make a degenerate element (skipped).
EPS_AREA_REL = 1e-12
#: Denominators sum w |grad|^2 at or below this are skipped (no particle can move).
EPS_DEN = 1e-300

ELASTIC_COLUMNS = 6


def lame_plane_stress(young_modulus: float, poisson_ratio: float) -> tuple[float, float]:
    """(mu, lambda_ps) [Pa]: plane-stress Lame parameters, mu = E/(2(1+nu)), lambda_ps = E nu/(1-nu^2)."""
    e, nu = float(young_modulus), float(poisson_ratio)
    return e / (2.0 * (1.0 + nu)), e * nu / (1.0 - nu * nu)


def shifted_lambda(young_modulus: float, poisson_ratio: float) -> float:
    """lambda' = lambda_ps + mu [Pa]: the hydrostatic stiffness of the form whose small-strain lambda is lambda_ps."""
    mu, lam = lame_plane_stress(young_modulus, poisson_ratio)
    return lam + mu


def elastic_table(q0: np.ndarray, tris: np.ndarray, young_modulus: float, poisson_ratio: float,
                  thickness: float) -> np.ndarray:
    """Packed rest data of each element, shape (T, 6) float64 (module docstring); zero rows for degenerate ones."""
    tris = np.asarray(tris, dtype=np.int64)
    out = np.zeros((tris.shape[0], ELASTIC_COLUMNS))
    if tris.shape[0] == 0:
        return out
    q0 = np.asarray(q0, dtype=np.float64)
    e1 = q0[tris[:, 1]] - q0[tris[:, 0]]
    e2 = q0[tris[:, 2]] - q0[tris[:, 0]]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]  # 2 A0
    scale = np.mean(np.abs(det)) if det.size else 0.0
    ok = np.abs(det) > EPS_AREA_REL * max(scale, 1e-300)
    d = np.where(ok, det, 1.0)
    # Dm = [[e1x, e2x], [e1y, e2y]];  Dm^-1 = 1/det [[e2y, -e2x], [-e1y, e1x]]
    out[:, 0] = e2[:, 1] / d
    out[:, 1] = -e2[:, 0] / d
    out[:, 2] = -e1[:, 1] / d
    out[:, 3] = e1[:, 0] / d
    mu, lam = lame_plane_stress(young_modulus, poisson_ratio)
    volume = 0.5 * np.abs(d) * float(thickness)
    out[:, 4] = 1.0 / (mu * volume)
    out[:, 5] = 1.0 / ((lam + mu) * volume)
    out[~ok] = 0.0
    return out


def lumped_mass(q0: np.ndarray, tris: np.ndarray, density: float, thickness: float) -> np.ndarray:
    """Particle masses [kg], (N,): a third of each adjacent triangle's rest area x density x thickness."""
    q0 = np.asarray(q0, dtype=np.float64)
    n = q0.shape[0]
    tris = np.asarray(tris, dtype=np.int64)
    if tris.shape[0] == 0:
        return np.zeros(n)
    e1 = q0[tris[:, 1]] - q0[tris[:, 0]]
    e2 = q0[tris[:, 2]] - q0[tris[:, 0]]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    return float(density) * float(thickness) * np.bincount(tris.ravel(), weights=np.repeat(area / 3.0, 3),
                                                            minlength=n)


# ----------------------------------------------------------------------------- Gauss-Seidel


@njit(cache=True, inline="always")
def _deformation_gradient(x: np.ndarray, a: int, b: int, c: int, cbx: float, cby: float, ccx: float,
                          ccy: float):
    """F = D_s D_m^-1 = (x_b - x_a) c_b^T + (x_c - x_a) c_c^T of element (a, b, c) at ``x``, shared by every
    element kernel (inlined, as ``sweeps._area_constraint``: the same operations in the same order as the
    block it replaced, so the same bits).

    (cbx, cby), (ccx, ccy) are c_b, c_c: rows of D_m^-1 (``elastic[t, 0:2]``, ``elastic[t, 2:4]``).
    Returns (F00, F01, F10, F11).
    """
    e1x, e1y, e2x, e2y = tri_edges(x, a, b, c)
    return e1x * cbx + e2x * ccx, e1x * cby + e2x * ccy, e1y * cbx + e2y * ccx, e1y * cby + e2y * ccy


@njit(cache=True, inline="always")
def _element_rest(elastic: np.ndarray, t: int) -> tuple[float, float, float, float, float, float]:
    """Element t's rest data as the kernels read it: c_b, c_c (rows of D_m^-1) and c_a = -(c_b + c_c):
    (cbx, cby, ccx, ccy, cax, cay)."""
    cbx = elastic[t, 0]
    cby = elastic[t, 1]
    ccx = elastic[t, 2]
    ccy = elastic[t, 3]
    return cbx, cby, ccx, ccy, -cbx - ccx, -cby - ccy


@njit(cache=True, inline="always")
def neo_hookean_element(x: np.ndarray, tris: np.ndarray, elastic: np.ndarray, t: int, scale: float):
    """Element ``t``'s strain energy V0 Psi(F) [J] and ``scale`` times its gradient, shared by the strain energy,
    the elastic forces and the minimisation's potential (inlined into each).

    E_t = 1/2 (|g|^2 / alpha_D + C_H^2 / alpha_H) with g = (F00 - F11, F01 + F10), C_H = det F - 1 and the packed
    compliances alpha = ``elastic[t, 4:6]`` (module docstring); dE_t/dx_p = (dE/dg_0) grad g_0 + (dE/dg_1) grad g_1
    + (dE/dC_H) cof(F) c_p. Returns (a, b, c, E_t, then scale dE_t/dx at a, b, c as six components); the caller
    skips a degenerate element (a compliance <= 0) before calling.
    """
    a = tris[t, 0]
    b = tris[t, 1]
    c = tris[t, 2]
    ad = elastic[t, 4]
    ah = elastic[t, 5]
    cbx, cby, ccx, ccy, cax, cay = _element_rest(elastic, t)
    f00, f01, f10, f11 = _deformation_gradient(x, a, b, c, cbx, cby, ccx, ccy)
    g0 = f00 - f11
    g1 = f01 + f10
    ch = f00 * f11 - f01 * f10 - 1.0
    energy = 0.5 * ((g0 * g0 + g1 * g1) / ad + ch * ch / ah)
    kd = scale * g0 / ad  # dE/dg_0
    kd1 = scale * g1 / ad
    kh = scale * ch / ah
    return (a, b, c, energy,
            kd * cax + kd1 * cay + kh * (f11 * cax - f10 * cay), kd1 * cax - kd * cay + kh * (-f01 * cax + f00 * cay),
            kd * cbx + kd1 * cby + kh * (f11 * cbx - f10 * cby), kd1 * cbx - kd * cby + kh * (-f01 * cbx + f00 * cby),
            kd * ccx + kd1 * ccy + kh * (f11 * ccx - f10 * ccy), kd1 * ccx - kd * ccy + kh * (-f01 * ccx + f00 * ccy))


@njit(cache=True, nogil=True)
def solve_elements_range(x: np.ndarray, inv_mass: np.ndarray, tris: np.ndarray, elastic: np.ndarray,
                         inv_h2: float, lam: np.ndarray, start: int, stop: int) -> None:
    """Gauss-Seidel over elements ``start:stop`` in array order: deviatoric pair, then hydrostatic; ``x`` (N, 2)
    [m] updated in place, ``inv_mass`` (N,) [1/kg] (0 = held/pinned), ``tris`` (T, 3) int32 the elements' corners.

    Parameters
    ----------
    elastic : (T, 6) float64
        Packed rest data (module docstring): Dm^-1 and the rows' compliances per unit energy [1/J].
    inv_h2 : float
        1 / h^2 of the substep [1/s^2].
    lam : (T, 3) float64
        Multipliers (g_0, g_1, C_H), accumulated in place.
    start, stop : int
        The range of elements to sweep.
    """
    for t in range(start, stop):
        a = tris[t, 0]
        b = tris[t, 1]
        c = tris[t, 2]
        wa = inv_mass[a]
        wb = inv_mass[b]
        wc = inv_mass[c]
        if wa + wb + wc == 0.0:
            continue
        # c_b, c_c: rows of Dm^-1; c_a = -(c_b + c_c)
        cbx, cby, ccx, ccy, cax, cay = _element_rest(elastic, t)
        s_dev = wa * (cax * cax + cay * cay) + wb * (cbx * cbx + cby * cby) + wc * (ccx * ccx + ccy * ccy)
        if s_dev <= EPS_DEN:
            continue
        # F = D_s D_m^-1 = (x_b - x_a) c_b^T + (x_c - x_a) c_c^T
        f00, f01, f10, f11 = _deformation_gradient(x, a, b, c, cbx, cby, ccx, ccy)
        # deviatoric: g_0 = F00 - F11, g_1 = F01 + F10, grad_p g_0 = (c_px, -c_py), grad_p g_1 = (c_py, c_px)
        alpha = elastic[t, 4] * inv_h2
        den = s_dev + alpha
        d0 = (-(f00 - f11) - alpha * lam[t, 0]) / den
        d1 = (-(f01 + f10) - alpha * lam[t, 1]) / den
        lam[t, 0] += d0
        lam[t, 1] += d1
        x[a, 0] += wa * (d0 * cax + d1 * cay)
        x[a, 1] += wa * (d1 * cax - d0 * cay)
        x[b, 0] += wb * (d0 * cbx + d1 * cby)
        x[b, 1] += wb * (d1 * cbx - d0 * cby)
        x[c, 0] += wc * (d0 * ccx + d1 * ccy)
        x[c, 1] += wc * (d1 * ccx - d0 * ccy)
        # hydrostatic: C_H = det F - 1, grad_p = cof(F) c_p = (F11 c_px - F10 c_py, -F01 c_px + F00 c_py)
        f00, f01, f10, f11 = _deformation_gradient(x, a, b, c, cbx, cby, ccx, ccy)
        gax = f11 * cax - f10 * cay
        gay = -f01 * cax + f00 * cay
        gbx = f11 * cbx - f10 * cby
        gby = -f01 * cbx + f00 * cby
        gcx = f11 * ccx - f10 * ccy
        gcy = -f01 * ccx + f00 * ccy
        alpha = elastic[t, 5] * inv_h2
        den = wa * (gax * gax + gay * gay) + wb * (gbx * gbx + gby * gby) + wc * (gcx * gcx + gcy * gcy)
        if den <= EPS_DEN:
            continue
        den += alpha
        s = (-(f00 * f11 - f01 * f10 - 1.0) - alpha * lam[t, 2]) / den
        lam[t, 2] += s
        add_corners(x, a, b, c, wa, wb, wc, s, (gax, gay, gbx, gby, gcx, gcy))


@njit(cache=True, nogil=True)
def solve_elements(x: np.ndarray, inv_mass: np.ndarray, tris: np.ndarray, elastic: np.ndarray,
                   inv_h2: float, lam: np.ndarray) -> None:
    """One Gauss-Seidel sweep over all elements in array order (:func:`solve_elements_range`)."""
    solve_elements_range(x, inv_mass, tris, elastic, inv_h2, lam, 0, tris.shape[0])


@njit(cache=True, parallel=True)
def solve_elements_partitioned(x: np.ndarray, inv_mass: np.ndarray, tris: np.ndarray, elastic: np.ndarray,
                               inv_h2: float, lam: np.ndarray, offsets: np.ndarray) -> None:
    """One sweep, domain-decomposed (as :func:`~tissue_sim_ros.core.physics.sweeps.solve_partitioned`): parts, then separator."""
    n_parts = offsets.shape[0] - 2
    for part in prange(n_parts):
        solve_elements_range(x, inv_mass, tris, elastic, inv_h2, lam, offsets[part], offsets[part + 1])
    solve_elements_range(x, inv_mass, tris, elastic, inv_h2, lam, offsets[n_parts], offsets[n_parts + 1])


@njit(cache=True, nogil=True)
def material_gauss_seidel(x: np.ndarray, inv_mass: np.ndarray, tris: np.ndarray, elastic: np.ndarray,
                          inv_h2: float, lam: np.ndarray, offsets: np.ndarray, partitioned: bool,
                          iterations: int, tool: tuple) -> None:
    """``iterations`` sweeps: every element, then the tool (``sweeps.tool_contact``, ``tool`` its bundle), as
    ``sweeps.gauss_seidel_iterations``."""
    for _ in range(iterations):
        if partitioned:
            solve_elements_partitioned(x, inv_mass, tris, elastic, inv_h2, lam, offsets)
        else:
            solve_elements(x, inv_mass, tris, elastic, inv_h2, lam)
        tool_contact(x, inv_mass, tool)


# ----------------------------------------------------------------------------- Jacobi


@njit(cache=True, nogil=True)
def jacobi_elements(x: np.ndarray, inv_mass: np.ndarray, tris: np.ndarray, elastic: np.ndarray,
                    inv_h2: float, lam: np.ndarray, omega: np.ndarray, dx_acc: np.ndarray) -> None:
    """Jacobi pass over elements: all three rows from the same ``x``, corrections summed into ``dx_acc``.

    ``omega`` (T, 2): relaxation of the deviatoric pair and of the hydrostatic row; each
    multiplier increment is scaled by it before it moves ``lam`` and the particles.
    """
    for t in range(tris.shape[0]):
        a = tris[t, 0]
        b = tris[t, 1]
        c = tris[t, 2]
        wa = inv_mass[a]
        wb = inv_mass[b]
        wc = inv_mass[c]
        if wa + wb + wc == 0.0:
            continue
        cbx, cby, ccx, ccy, cax, cay = _element_rest(elastic, t)
        s_dev = wa * (cax * cax + cay * cay) + wb * (cbx * cbx + cby * cby) + wc * (ccx * ccx + ccy * ccy)
        if s_dev <= EPS_DEN:
            continue
        f00, f01, f10, f11 = _deformation_gradient(x, a, b, c, cbx, cby, ccx, ccy)
        alpha = elastic[t, 4] * inv_h2
        den = s_dev + alpha
        om = omega[t, 0]
        d0 = om * (-(f00 - f11) - alpha * lam[t, 0]) / den
        d1 = om * (-(f01 + f10) - alpha * lam[t, 1]) / den
        lam[t, 0] += d0
        lam[t, 1] += d1
        dx_acc[a, 0] += wa * (d0 * cax + d1 * cay)
        dx_acc[a, 1] += wa * (d1 * cax - d0 * cay)
        dx_acc[b, 0] += wb * (d0 * cbx + d1 * cby)
        dx_acc[b, 1] += wb * (d1 * cbx - d0 * cby)
        dx_acc[c, 0] += wc * (d0 * ccx + d1 * ccy)
        dx_acc[c, 1] += wc * (d1 * ccx - d0 * ccy)
        gax = f11 * cax - f10 * cay
        gay = -f01 * cax + f00 * cay
        gbx = f11 * cbx - f10 * cby
        gby = -f01 * cbx + f00 * cby
        gcx = f11 * ccx - f10 * ccy
        gcy = -f01 * ccx + f00 * ccy
        alpha = elastic[t, 5] * inv_h2
        den = wa * (gax * gax + gay * gay) + wb * (gbx * gbx + gby * gby) + wc * (gcx * gcx + gcy * gcy)
        if den <= EPS_DEN:
            continue
        den += alpha
        s = omega[t, 1] * (-(f00 * f11 - f01 * f10 - 1.0) - alpha * lam[t, 2]) / den
        lam[t, 2] += s
        add_corners(dx_acc, a, b, c, wa, wb, wc, s, (gax, gay, gbx, gby, gcx, gcy))


@njit(cache=True, nogil=True)
def jacobi_relaxation_elements(x: np.ndarray, inv_mass: np.ndarray, tris: np.ndarray, elastic: np.ndarray,
                               inv_h2: float, scale: float, node_sum: np.ndarray, omega: np.ndarray) -> None:
    """Per-row relaxation omega = scale / r with r a Gershgorin bound (as ``sweeps.jacobi_relaxation``).

    Rows: the deviatoric pair (both rows have the same D and gradient lengths |c_p|)
    and the hydrostatic row (gradient lengths |cof(F) c_p| at ``x``). With
    D_r = sum_p w_p |g_rp|^2 + alpha_r and G_p = sum_{rows r at p} |g_rp| / D_r^1/2
    (the deviatoric pair counted twice)::

        r = alpha_r / D_r + D_r^-1/2 sum_p w_p |g_rp| G_p,   omega_r = scale / r

    Any scale < 2 converges for the linearised system. ``node_sum`` (N,) is scratch,
    ``omega`` (T, 2) the output.
    """
    for i in range(node_sum.shape[0]):
        node_sum[i] = 0.0
    for t in range(tris.shape[0]):
        a = tris[t, 0]
        b = tris[t, 1]
        c = tris[t, 2]
        cbx, cby, ccx, ccy, cax, cay = _element_rest(elastic, t)
        la = math.sqrt(cax * cax + cay * cay)
        lb = math.sqrt(cbx * cbx + cby * cby)
        lc = math.sqrt(ccx * ccx + ccy * ccy)
        d = inv_mass[a] * la * la + inv_mass[b] * lb * lb + inv_mass[c] * lc * lc
        if d <= EPS_DEN:
            omega[t, 0] = 0.0
            omega[t, 1] = 0.0
            continue
        d += elastic[t, 4] * inv_h2
        sd = math.sqrt(d)
        omega[t, 0] = sd
        node_sum[a] += 2.0 * la / sd
        node_sum[b] += 2.0 * lb / sd
        node_sum[c] += 2.0 * lc / sd
        f00, f01, f10, f11 = _deformation_gradient(x, a, b, c, cbx, cby, ccx, ccy)
        ha = math.hypot(f11 * cax - f10 * cay, -f01 * cax + f00 * cay)
        hb = math.hypot(f11 * cbx - f10 * cby, -f01 * cbx + f00 * cby)
        hc = math.hypot(f11 * ccx - f10 * ccy, -f01 * ccx + f00 * ccy)
        d = inv_mass[a] * ha * ha + inv_mass[b] * hb * hb + inv_mass[c] * hc * hc
        if d <= EPS_DEN:
            omega[t, 1] = 0.0
            continue
        d += elastic[t, 5] * inv_h2
        sd = math.sqrt(d)
        omega[t, 1] = sd
        node_sum[a] += ha / sd
        node_sum[b] += hb / sd
        node_sum[c] += hc / sd
    for t in range(tris.shape[0]):
        a = tris[t, 0]
        b = tris[t, 1]
        c = tris[t, 2]
        cbx, cby, ccx, ccy, cax, cay = _element_rest(elastic, t)
        sd = omega[t, 0]
        if sd > 0.0:
            la = math.sqrt(cax * cax + cay * cay)
            lb = math.sqrt(cbx * cbx + cby * cby)
            lc = math.sqrt(ccx * ccx + ccy * ccy)
            r = elastic[t, 4] * inv_h2 / (sd * sd) + (inv_mass[a] * la * node_sum[a] + inv_mass[b] * lb * node_sum[b]
                                                      + inv_mass[c] * lc * node_sum[c]) / sd
            omega[t, 0] = scale / r if r > 0.0 else scale
        sd = omega[t, 1]
        if sd > 0.0:
            f00, f01, f10, f11 = _deformation_gradient(x, a, b, c, cbx, cby, ccx, ccy)
            ha = math.hypot(f11 * cax - f10 * cay, -f01 * cax + f00 * cay)
            hb = math.hypot(f11 * cbx - f10 * cby, -f01 * cbx + f00 * cby)
            hc = math.hypot(f11 * ccx - f10 * ccy, -f01 * ccx + f00 * ccy)
            r = elastic[t, 5] * inv_h2 / (sd * sd) + (inv_mass[a] * ha * node_sum[a] + inv_mass[b] * hb * node_sum[b]
                                                      + inv_mass[c] * hc * node_sum[c]) / sd
            omega[t, 1] = scale / r if r > 0.0 else scale


@njit(cache=True, nogil=True)
def material_jacobi(x: np.ndarray, inv_mass: np.ndarray, tris: np.ndarray, elastic: np.ndarray,
                    inv_h2: float, lam: np.ndarray, omega: np.ndarray, iterations: int, dx_acc: np.ndarray,
                    tool: tuple) -> None:
    """``iterations`` Jacobi sweeps (every element sees the sweep's start), then the tool each sweep
    (``sweeps.tool_contact``, ``tool`` its bundle).

    ``dx_acc`` (N, 2) must be zero on entry and is zero on exit.
    """
    n = x.shape[0]
    for _ in range(iterations):
        jacobi_elements(x, inv_mass, tris, elastic, inv_h2, lam, omega, dx_acc)
        for i in range(n):
            x[i, 0] += dx_acc[i, 0]
            x[i, 1] += dx_acc[i, 1]
            dx_acc[i, 0] = 0.0
            dx_acc[i, 1] = 0.0
        tool_contact(x, inv_mass, tool)


# ----------------------------------------------------------------------------- energy and forces


@njit(cache=True, nogil=True)
def strain_energy_kernel(x: np.ndarray, tris: np.ndarray, elastic: np.ndarray, tri_body: np.ndarray,
                         out: np.ndarray) -> None:
    """Strain energy per body [J], added into ``out`` (B,): sum_t V0 Psi(F_t) = 1/2 (|g|^2 / k_D + C_H^2 / k_H).

    With k_D = 1/(mu V0) and k_H = 1/(lambda' V0) the packed compliances (``elastic[:, 4:6]``).
    """
    for t in range(tris.shape[0]):
        if elastic[t, 4] <= 0.0 or elastic[t, 5] <= 0.0:
            continue
        energy = neo_hookean_element(x, tris, elastic, t, 1.0)[3]
        out[tri_body[t]] += energy


@njit(cache=True, nogil=True)
def elastic_forces(x: np.ndarray, tris: np.ndarray, elastic: np.ndarray, out: np.ndarray) -> None:
    """Internal elastic force on each particle [N], -dE_strain/dx, added into ``out`` (N, 2)."""
    for t in range(tris.shape[0]):
        if elastic[t, 4] <= 0.0 or elastic[t, 5] <= 0.0:
            continue
        a, b, c, _, gax, gay, gbx, gby, gcx, gcy = neo_hookean_element(x, tris, elastic, t, 1.0)
        out[a, 0] -= gax
        out[a, 1] -= gay
        out[b, 0] -= gbx
        out[b, 1] -= gby
        out[c, 0] -= gcx
        out[c, 1] -= gcy


def strain_energy(model, x: np.ndarray) -> np.ndarray:
    """Strain energy of positions ``x`` (N, 2) [m] per body [J], (B,); zeros for ``material: constraints``."""
    out = np.zeros(model.n_bodies)
    if model.tri_elastic.shape[0]:
        strain_energy_kernel(np.ascontiguousarray(x, dtype=np.float64), model.tri_indices, model.tri_elastic,
                             model.tri_body, out)
    return out


def internal_forces(model, x: np.ndarray) -> np.ndarray:
    """Elastic force on each particle [N], (N, 2): -grad of :func:`strain_energy` (zeros for constraints)."""
    out = np.zeros((model.n_particles, 2))
    if model.tri_elastic.shape[0]:
        elastic_forces(np.ascontiguousarray(x, dtype=np.float64), model.tri_indices, model.tri_elastic, out)
    return out



@njit(cache=True, nogil=True)
def element_hessians(x: np.ndarray, tris: np.ndarray, elastic: np.ndarray, out: np.ndarray) -> None:
    """Hessian of each element's strain energy V0 Psi(F) in its corners' coordinates, written to ``out`` (T, 6, 6).

    Dofs ordered (a_x, a_y, b_x, b_y, c_x, c_y). With E_t = 1/2 (|g|^2 / alpha_D + C_H^2 / alpha_H)
    (the packed compliances alpha = ``elastic[:, 4:6]``) and g linear in x::

        d2E_t = (G_0 G_0^T + G_1 G_1^T) / alpha_D + (grad C_H grad C_H^T + C_H d2(det F)) / alpha_H

    grad_a g_0 = (c_a0, -c_a1), grad_a g_1 = (c_a1, c_a0), grad_a C_H = cof F c_a, and
    d2(det F)/dx_a dx_b = [[0, s_ab], [-s_ab, 0]] with s_ab = c_a0 c_b1 - c_a1 c_b0 (c_a: row of D_m^-1,
    c_0 = -(c_1 + c_2)). Exact, so indefinite under strong compression (C_H d2 det F); degenerate rows are 0.
    """
    ca = np.empty((3, 2))
    gd0 = np.empty(6)
    gd1 = np.empty(6)
    gh = np.empty(6)
    for t in range(tris.shape[0]):
        ad = elastic[t, 4]
        ah = elastic[t, 5]
        for i in range(6):
            for j in range(6):
                out[t, i, j] = 0.0
        if ad <= 0.0 or ah <= 0.0:
            continue
        a = tris[t, 0]
        b = tris[t, 1]
        c = tris[t, 2]
        ca[1, 0] = elastic[t, 0]
        ca[1, 1] = elastic[t, 1]
        ca[2, 0] = elastic[t, 2]
        ca[2, 1] = elastic[t, 3]
        ca[0, 0] = -ca[1, 0] - ca[2, 0]
        ca[0, 1] = -ca[1, 1] - ca[2, 1]
        f00, f01, f10, f11 = _deformation_gradient(x, a, b, c, ca[1, 0], ca[1, 1], ca[2, 0], ca[2, 1])
        ch = f00 * f11 - f01 * f10 - 1.0
        for k in range(3):
            gd0[2 * k] = ca[k, 0]
            gd0[2 * k + 1] = -ca[k, 1]
            gd1[2 * k] = ca[k, 1]
            gd1[2 * k + 1] = ca[k, 0]
            gh[2 * k] = f11 * ca[k, 0] - f10 * ca[k, 1]
            gh[2 * k + 1] = -f01 * ca[k, 0] + f00 * ca[k, 1]
        for i in range(6):
            for j in range(6):
                out[t, i, j] = (gd0[i] * gd0[j] + gd1[i] * gd1[j]) / ad + gh[i] * gh[j] / ah
        for p in range(3):
            for q in range(3):
                s = ca[p, 0] * ca[q, 1] - ca[p, 1] * ca[q, 0]
                out[t, 2 * p, 2 * q + 1] += ch * s / ah
                out[t, 2 * p + 1, 2 * q] -= ch * s / ah
