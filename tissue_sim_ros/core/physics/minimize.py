"""Damped Newton minimisation of a smooth energy over free coordinates, with a backtracking line search.

One minimiser for the exact one-step references of the benchmarks
(:mod:`~tissue_sim_ros.bench.reference`, :mod:`~tissue_sim_ros.bench.material_reference`) and the static
settle of the core (:mod:`~tissue_sim_ros.core.physics.statics`). Plain NumPy/SciPy: it imports no kernel.

An energy is any object with ``value(x) -> float``, ``gradient(x) -> (N, 2)``, ``hessian(x, project)
-> sparse (2N, 2N)`` (dofs x0, y0, x1, y1, ...; ``project=True`` returns a positive semi-definite
approximation) and ``mass`` (N,) (the fallback step -g / m when no Hessian gives a descent direction).

The exact Hessian is tried first (quadratic convergence); when it gives no descent direction, or its
step had to be cut below 1/4 by the line search, the next iterations use the projected Hessian, which
gives robust steps far from the minimiser, until a full projected step is taken with a small gradient.
A backtracking (Armijo) line search makes every step decrease the energy; near the minimiser, where
the energy changes below its round-off, a step that reduces the gradient norm is accepted instead.
"""
from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse.linalg as spla


def newton_minimize(energy: Any, x0: np.ndarray, fixed: np.ndarray, g_scale: float | None = None,
                    rtol: float = 1e-10, max_iterations: int = 200,
                    reuse_factor: bool = False) -> tuple[np.ndarray, dict]:
    """Minimise ``energy`` over the particles not ``fixed``, starting from ``x0`` (fixed ones stay there).

    Parameters
    ----------
    energy : object
        ``value``, ``gradient``, ``hessian(x, project)`` and ``mass`` (module docstring).
    x0 : ndarray, shape (N, 2)
        Starting point [m] (copied).
    fixed : ndarray, shape (N,), bool
        Particles that do not move.
    g_scale : float, optional
        The gradient norm ``rtol`` is relative to; default the free gradient norm at ``x0``.
    rtol : float
        Stop when the free gradient norm is at most ``rtol * g_scale``.
    max_iterations : int
        Newton iterations at most.
    reuse_factor : bool
        Keep the last exact Hessian's factor (a sparse LU with a symmetric ordering) and take the next
        directions from it (the chord method: a back-substitution instead of a factorisation) while each
        such step cuts the gradient norm at least 4x; otherwise factor again. For problems whose Hessian
        changes little between iterations (small strains: the static settle).

    Returns
    -------
    x : ndarray, shape (N, 2), float64
        The minimiser.
    info : dict
        ``grad_norm``, ``grad_norm0`` (= g_scale), ``iterations``, ``projected``, ``converged``, ``energy``.
    """
    free_dofs = np.repeat(~np.asarray(fixed, dtype=bool), 2)
    x = np.array(x0, dtype=np.float64)
    e = energy.value(x)
    g = energy.gradient(x).ravel()[free_dofs]
    gnorm = float(np.linalg.norm(g))
    g0 = gnorm if g_scale is None else float(g_scale)
    target = rtol * g0
    iterations = projected = 0
    exact_first = True
    lu = None  # the last exact Hessian's factor (reuse_factor)
    while gnorm > target and iterations < max_iterations and free_dofs.any():
        iterations += 1
        step = None
        used_exact = chord = False
        if lu is not None:
            p = lu.solve(-g)
            if np.all(np.isfinite(p)) and g @ p < -1e-14 * gnorm * np.linalg.norm(p):
                step, used_exact, chord = p, True, True
        for project in ((False, True) if exact_first else (True,)) if step is None else ():
            h = energy.hessian(x, project=project)[free_dofs][:, free_dofs].tocsc()
            try:
                if reuse_factor:
                    factor = spla.splu(h, permc_spec="MMD_AT_PLUS_A")
                    p = factor.solve(-g)
                else:
                    p = spla.spsolve(h, -g)
            except RuntimeError:  # singular factor
                continue
            if np.all(np.isfinite(p)) and g @ p < -1e-14 * gnorm * np.linalg.norm(p):
                step = p
                projected += int(project)
                used_exact = not project
                if reuse_factor and used_exact:
                    lu = factor
                break
        if step is None:  # the projected Hessian (M + PSD) is positive definite: should not happen
            step = -g / np.repeat(np.asarray(energy.mass), 2)[free_dofs]
        accepted, x_try, e_try, t = _backtrack(energy, x, e, g, gnorm, step, free_dofs)
        if not accepted:
            if not exact_first:
                exact_first = True  # at round-off with the projected Hessian: let the exact one finish
                continue
            break  # no further progress possible in float64
        x, e = x_try, e_try
        g = energy.gradient(x).ravel()[free_dofs]
        gnorm_before, gnorm = gnorm, float(np.linalg.norm(g))
        if lu is not None and (t < 1.0 or gnorm > 0.25 * gnorm_before):
            lu = None  # the kept factor no longer gives fast progress: factor the Hessian here next time
        if chord:
            continue
        if used_exact and t < 0.25:
            exact_first = False
        elif not used_exact and t == 1.0 and gnorm <= 1e-3 * max(g0, 1e-300):
            exact_first = True
    return x, {"grad_norm": gnorm, "grad_norm0": g0, "iterations": iterations, "projected": projected,
               "converged": bool(gnorm <= target), "energy": e}


def _backtrack(energy: Any, x: np.ndarray, e: float, g: np.ndarray, gnorm: float, step: np.ndarray,
               free_dofs: np.ndarray) -> tuple[bool, np.ndarray, float, float]:
    """Armijo backtracking along ``step`` from x (energy e, free gradient g): (accepted, x there, its energy, the
    step's fraction). A step that changes the energy only by round-off is accepted when it lowers the gradient."""
    slope = float(g @ step)
    t = 1.0
    x_try, e_try = x, e
    for _ in range(60):
        x_try = x.copy()
        x_try.ravel()[free_dofs] += t * step
        e_try = energy.value(x_try)
        if e_try <= e + 1e-4 * t * slope:
            return True, x_try, e_try, t
        if abs(e_try - e) <= 1e-13 * max(abs(e), 1e-300):
            g_try = energy.gradient(x_try).ravel()[free_dofs]
            if float(np.linalg.norm(g_try)) < gnorm:
                return True, x_try, e_try, t
        t *= 0.5
    return False, x_try, e_try, t
