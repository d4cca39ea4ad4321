"""An exact reference for one step: Newton's method on the implicit Euler energy.

For one time step the discretised model's answer is the minimiser of

    E(x) = 1/2 sum_i m_i |x_i - x*_i|^2
           + dt^2 ( sum_edges 1/2 k_s C_s(x)^2 + sum_triangles 1/2 k_a C_a(x)^2 )

with ``C_s = |x_b - x_a| - l0`` and ``C_a = A(x) - A0`` (signed area; the paper's
``|A(x)| - |A0|`` when ``area_mode == "abs"``), ``k_s``/``k_a`` the *physical*
stiffnesses of XPBD (``stiffness_spring``, ``stiffness_area``) and ``x*`` the
predicted positions. Pinned particles and particles held by the paper's
contact rule stay at their predicted positions.

This module is written in plain NumPy/SciPy, independent of the numba kernels
(it must not import ``core.kernels``), so it doubles as a check on them. It is
used only by benchmarks and tests: it is slow (a sparse factorisation per
Newton iteration) and exact to a tight gradient norm. :class:`ReferenceSolver`
makes it a Simulation's solver, so that it receives each step (start state,
contacts) from the Simulation's path, as the methods it is compared with do.

Newton details: the exact sparse Hessian ``M + dt^2 sum_c k_c (grad C grad C^T
+ C hess C)`` is tried first; where it is indefinite (compressed springs,
the area's saddle-shaped Hessian) and the Newton direction is not a descent
direction, each element's Hessian is projected onto the positive
semi-definite cone (eigenvalues clamped at 0) instead. A backtracking
(Armijo) line search makes every step decrease the energy.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp

from ..core.physics.minimize import newton_minimize

if TYPE_CHECKING:  # types only: at run time this module needs nothing but NumPy and SciPy
    from ..core.contact.collision import Contacts
    from ..core.physics.model import Model, State

#: The constant Hessian of the 2D cross product u x v = ux vy - uy vx with respect to (u, v):
#: d2/dux dvy = 1, d2/duy dvx = -1.
_CROSS_BLOCK = np.array([[0.0, 1.0], [-1.0, 0.0]])


def _area_hessian() -> np.ndarray:
    """Hessian of the signed triangle area A = 1/2 (a x b + b x c + c x a) in (ax, ay, bx, by, cx, cy), (6, 6)."""
    h = np.zeros((6, 6))
    for i, j in ((0, 1), (1, 2), (2, 0)):
        h[2 * i:2 * i + 2, 2 * j:2 * j + 2] += 0.5 * _CROSS_BLOCK
        h[2 * j:2 * j + 2, 2 * i:2 * i + 2] += 0.5 * _CROSS_BLOCK.T
    return h


_AREA_HESSIAN = _area_hessian()


@dataclass
class ReferenceResult:
    """The exact minimiser of one step and how well it was converged."""

    particle_q: np.ndarray
    """Positions after the step [m], shape (N, 2), float64."""
    particle_qd: np.ndarray
    """Velocities after the step, (x - x_n) / dt, zeroed past the boundary lines [m/s], shape (N, 2)."""
    x_pred: np.ndarray
    """Predicted positions x* the energy was measured against [m], shape (N, 2)."""
    fixed: np.ndarray
    """Particles held at x* (pinned or held by the paper contact), shape (N,), bool."""
    energy: float
    """Implicit Euler energy at the minimiser [J]."""
    grad_norm: float
    """Euclidean norm of the energy gradient over free coordinates at the end [N s^2 = kg m]."""
    grad_norm0: float
    """The same at the starting point (x*), the scale of ``grad_norm``."""
    newton_iterations: int
    """Newton iterations taken."""
    projected_iterations: int
    """Iterations in which the exact Hessian gave no descent direction and the projected one was used."""
    converged: bool
    """True if ``grad_norm <= rtol * grad_norm0`` (or the gradient is 0)."""

    @property
    def relative_grad(self) -> float:
        """Final gradient norm relative to the starting one."""
        return self.grad_norm / self.grad_norm0 if self.grad_norm0 > 0 else 0.0


class ImplicitEulerEnergy:
    """The implicit Euler energy of one step on a Model, with its gradient and sparse Hessian.

    Parameters
    ----------
    model : Model
        Topology, rest lengths/areas, masses and area mode.
    x_pred : ndarray, shape (N, 2), float64
        Predicted positions x* [m].
    dt : float
        Time step [s].
    stiffness_spring, stiffness_area : float, optional
        Physical stiffnesses [N/m], [N/m^3]; default the model's XPBD ones.
    """

    def __init__(self, model: Model, x_pred: np.ndarray, dt: float,
                 stiffness_spring: float | None = None, stiffness_area: float | None = None) -> None:
        p = model.params
        self.model = model
        self.x_pred = np.asarray(x_pred, dtype=np.float64)
        self.dt = float(dt)
        self.k_s = float(p.stiffness_spring if stiffness_spring is None else stiffness_spring)
        self.k_a = float(p.stiffness_area if stiffness_area is None else stiffness_area)
        self.mass = np.asarray(model.particle_mass, dtype=np.float64)
        self.edges = np.asarray(model.edge_indices, dtype=np.int64)
        self.rest_length = np.asarray(model.edge_rest_length, dtype=np.float64)
        self.tris = np.asarray(model.tri_indices, dtype=np.int64)
        self.abs_area = p.area_mode == "abs"
        rest_area = np.asarray(model.tri_rest_area, dtype=np.float64)
        self.rest_area = np.abs(rest_area) if self.abs_area else rest_area
        n = model.n_particles
        # sparsity pattern of the Hessian, built once: 2x2 blocks (i, j) per edge, 6x6 per triangle
        e_dofs = np.stack([2 * self.edges[:, 0], 2 * self.edges[:, 0] + 1,
                           2 * self.edges[:, 1], 2 * self.edges[:, 1] + 1], axis=1)  # (E, 4)
        t_dofs = np.stack([2 * self.tris[:, k] + d for k in range(3) for d in range(2)], axis=1)  # (T, 6)
        self._e_rows = np.repeat(e_dofs, 4, axis=1).ravel()
        self._e_cols = np.tile(e_dofs, (1, 4)).ravel()
        self._t_rows = np.repeat(t_dofs, 6, axis=1).ravel()
        self._t_cols = np.tile(t_dofs, (1, 6)).ravel()
        self._m_diag = np.repeat(self.mass, 2)
        self.n_dofs = 2 * n

    # --- constraint values and gradients ------------------------------------------------------
    def _edges(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Edge lengths (E,), unit directions a->b (E, 2) and C_s (E,)."""
        d = x[self.edges[:, 1]] - x[self.edges[:, 0]]
        length = np.sqrt((d * d).sum(axis=1))
        safe = np.where(length > 0.0, length, 1.0)
        n = d / safe[:, None]
        n[length == 0.0] = (1.0, 0.0)  # any direction: the gradient of |d| is undefined at 0
        return length, n, length - self.rest_length

    def _areas(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Signed areas (T,), gradient of C_a w.r.t. (a, b, c) as (T, 6), and C_a (T,)."""
        a, b, c = x[self.tris[:, 0]], x[self.tris[:, 1]], x[self.tris[:, 2]]
        area = 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
        grad = 0.5 * np.stack([b[:, 1] - c[:, 1], c[:, 0] - b[:, 0],
                               c[:, 1] - a[:, 1], a[:, 0] - c[:, 0],
                               a[:, 1] - b[:, 1], b[:, 0] - a[:, 0]], axis=1)
        if self.abs_area:
            sign = np.where(area < 0.0, -1.0, 1.0)
            return area, grad * sign[:, None], np.abs(area) - self.rest_area
        return area, grad, area - self.rest_area

    # --- energy, gradient, Hessian ------------------------------------------------------------
    def value(self, x: np.ndarray) -> float:
        """E(x) [J] for positions x, shape (N, 2)."""
        _, _, cs = self._edges(x)
        _, _, ca = self._areas(x)
        r = x - self.x_pred
        inertial = 0.5 * float(np.sum(self.mass[:, None] * r * r))
        return inertial + self.dt ** 2 * (0.5 * self.k_s * float(cs @ cs) + 0.5 * self.k_a * float(ca @ ca))

    def terms(self, x: np.ndarray) -> tuple[float, float, float]:
        """(inertial, dt^2 E_spring, dt^2 E_area) [J]."""
        _, _, cs = self._edges(x)
        _, _, ca = self._areas(x)
        r = x - self.x_pred
        return (0.5 * float(np.sum(self.mass[:, None] * r * r)),
                self.dt ** 2 * 0.5 * self.k_s * float(cs @ cs), self.dt ** 2 * 0.5 * self.k_a * float(ca @ ca))

    def gradient(self, x: np.ndarray) -> np.ndarray:
        """dE/dx, shape (N, 2) [N s^2]."""
        g = self.mass[:, None] * (x - self.x_pred)
        _, n, cs = self._edges(x)
        fe = (self.dt ** 2 * self.k_s * cs)[:, None] * n  # gradient on b; -fe on a
        np.add.at(g, self.edges[:, 1], fe)
        np.add.at(g, self.edges[:, 0], -fe)
        _, ga, ca = self._areas(x)
        ft = (self.dt ** 2 * self.k_a * ca)[:, None] * ga
        for k in range(3):
            np.add.at(g, self.tris[:, k], ft[:, 2 * k:2 * k + 2])
        return g

    def hessian(self, x: np.ndarray, project: bool = False) -> sp.csr_matrix:
        """Sparse Hessian d2E/dx2, shape (2N, 2N), dofs ordered (x0, y0, x1, y1, ...).

        ``project=True`` clamps each element Hessian's negative eigenvalues to 0
        (for springs: the transverse term C/|d| at 0), so the result is positive definite.
        """
        length, n, cs = self._edges(x)
        safe = np.where(length > 0.0, length, 1.0)
        nn = n[:, :, None] * n[:, None, :]  # (E, 2, 2)
        transverse = cs / safe  # eigenvalue of the spring's Hessian across the edge, per unit k
        if project:
            transverse = np.maximum(transverse, 0.0)
        block = nn + transverse[:, None, None] * (np.eye(2)[None] - nn)  # (E, 2, 2)
        block *= self.dt ** 2 * self.k_s
        he = np.empty((len(block), 4, 4))
        he[:, :2, :2] = block
        he[:, 2:, 2:] = block
        he[:, :2, 2:] = -block
        he[:, 2:, :2] = -block
        _, ga, ca = self._areas(x)
        hess_a = _AREA_HESSIAN[None] if not self.abs_area else None
        if self.abs_area:
            area, _, _ = self._areas(x)
            hess_a = np.where(area < 0.0, -1.0, 1.0)[:, None, None] * _AREA_HESSIAN[None]
        ht = ga[:, :, None] * ga[:, None, :] + ca[:, None, None] * hess_a  # (T, 6, 6)
        if project and len(ht):
            w, v = np.linalg.eigh(ht)
            ht = np.einsum("tij,tj,tkj->tik", v, np.maximum(w, 0.0), v)
        ht = ht * (self.dt ** 2 * self.k_a)
        rows = np.concatenate([np.arange(self.n_dofs), self._e_rows, self._t_rows])
        cols = np.concatenate([np.arange(self.n_dofs), self._e_cols, self._t_cols])
        vals = np.concatenate([self._m_diag, he.ravel(), ht.ravel()])
        return sp.csr_matrix((vals, (rows, cols)), shape=(self.n_dofs, self.n_dofs))


def predict(model: Model, state: State, contacts: Contacts | None, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Predicted positions x* and the fixed set, as Algorithm 1 of the paper.

    x* = x + dt v' + dt^2 g with v' = v max(0, 1 - damping dt); pinned particles
    stay; the paper contact's held particles move by ``held_dx`` and are fixed.

    Returns
    -------
    x_pred : ndarray, shape (N, 2), float64
    fixed : ndarray, shape (N,), bool
    """
    p = model.params
    x = state.particle_q
    v = state.particle_qd * max(0.0, 1.0 - p.damping * dt)
    fixed = np.asarray(model.particle_inv_mass) == 0.0
    x_pred = x + dt * v
    x_pred[:, 1] += dt * dt * p.gravity
    x_pred[fixed] = x[fixed]
    if contacts is not None and contacts.held_idx.size:
        idx = contacts.held_idx.astype(np.int64)
        movable = ~fixed[idx]  # pinned particles are never displaced
        x_pred[idx[movable]] += np.asarray(contacts.held_dx).reshape(-1, 2)[movable]
        fixed = fixed.copy()
        fixed[idx] = True
    return x_pred, fixed


def minimize_step(energy: ImplicitEulerEnergy, fixed: np.ndarray, x0: np.ndarray | None = None,
                  rtol: float = 1e-10, max_iterations: int = 200) -> tuple[np.ndarray, dict]:
    """Minimise ``energy`` over the free particles by damped Newton (:func:`~tissue_sim_ros.core.physics.minimize.newton_minimize`,
    shared with the core's static settle); fixed particles stay at x*.

    Parameters
    ----------
    energy : ImplicitEulerEnergy
    fixed : ndarray, shape (N,), bool
        Particles held at their predicted position.
    x0 : ndarray, shape (N, 2), optional
        Starting point (free particles); default x*.
    rtol : float
        Stop when the free gradient norm falls to ``rtol`` times its value at x*.
    max_iterations : int
        Newton iterations at most.

    Returns
    -------
    x : ndarray, shape (N, 2), float64
        The minimiser.
    info : dict
        ``grad_norm``, ``grad_norm0``, ``iterations``, ``projected``, ``converged``, ``energy``.
    """
    x_pred = energy.x_pred
    fixed = np.asarray(fixed, dtype=bool)
    free_dofs = np.repeat(~fixed, 2)
    x = x_pred.copy() if x0 is None else np.array(x0, dtype=np.float64)
    x[fixed] = x_pred[fixed]
    g0 = float(np.linalg.norm(energy.gradient(x_pred).ravel()[free_dofs]))
    return newton_minimize(energy, x, fixed, g_scale=g0, rtol=rtol, max_iterations=max_iterations)


def reference_step(model: Model, state_in: State, contacts: Contacts | None = None, dt: float | None = None,
                   x_pred: np.ndarray | None = None, x0: np.ndarray | None = None, rtol: float = 1e-10,
                   max_iterations: int = 200, stiffness_spring: float | None = None,
                   stiffness_area: float | None = None) -> ReferenceResult:
    """One exact implicit Euler step of ``model`` from ``state_in``.

    Parameters
    ----------
    model : Model
    state_in : State
        Positions and velocities at the start of the step.
    contacts : Contacts, optional
        The paper contact's held particles (``held_idx``, ``held_dx``) are displaced and fixed.
        Projection contact is not modelled (it is an inequality; benchmarks use the paper model).
    dt : float, optional
        Time step [s]; default ``model.params.dt``.
    x_pred : ndarray, shape (N, 2), optional
        Use these predicted positions (e.g. a solver's ``SolveInfo.x_pred``) instead of predicting here;
        particles with inverse mass 0 or held by ``contacts`` stay fixed at them.
    x0 : ndarray, shape (N, 2), optional
        Newton's starting point; default x*.
    rtol : float
        Relative gradient-norm tolerance.
    stiffness_spring, stiffness_area : float, optional
        Override the model's physical stiffnesses.
    """
    dt = float(model.params.dt if dt is None else dt)
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt={dt!r}: expected a time step > 0 s")
    pred, fixed = predict(model, state_in, contacts, dt)
    if x_pred is not None:
        pred = np.array(x_pred, dtype=np.float64)
        if pred.shape != state_in.particle_q.shape:
            raise ValueError(f"x_pred has shape {pred.shape}: expected {state_in.particle_q.shape}")
    energy = ImplicitEulerEnergy(model, pred, dt, stiffness_spring, stiffness_area)
    x, info = minimize_step(energy, fixed, x0=x0, rtol=rtol, max_iterations=max_iterations)
    v = (x - state_in.particle_q) / dt
    p = model.params
    # the paper's boundary lines, after the solve: a movable particle at or past a line is put on it
    # and stopped (a projection outside the energy, as every method does it)
    movable = np.asarray(model.particle_inv_mass) > 0.0
    if math.isfinite(p.boundary_y_top):
        past = movable & (x[:, 1] >= p.boundary_y_top)
        x[past, 1] = p.boundary_y_top
        v[past] = 0.0
    if math.isfinite(p.boundary_y_bottom):
        past = movable & (x[:, 1] <= p.boundary_y_bottom)
        x[past, 1] = p.boundary_y_bottom
        v[past] = 0.0
    return ReferenceResult(particle_q=x, particle_qd=v, x_pred=pred, fixed=fixed, energy=info["energy"],
                           grad_norm=info["grad_norm"], grad_norm0=info["grad_norm0"],
                           newton_iterations=info["iterations"], projected_iterations=info["projected"],
                           converged=info["converged"])


def constraint_residual(model: Model, x: np.ndarray) -> float:
    """RMS over all constraints of C / l0 (edges) and C / |A0| (triangles) at ``x``, as the solvers report it
    (``core/physics/kernels.constraint_residual``, written again here in NumPy); 0 without constraints."""
    signed = model.params.area_mode == "signed"
    e, t = np.asarray(model.edge_indices), np.asarray(model.tri_indices)
    rest, area0 = np.asarray(model.edge_rest_length), np.asarray(model.tri_rest_area)
    d = x[e[:, 0]] - x[e[:, 1]]
    c_e = np.sqrt((d * d).sum(axis=1)) - rest
    c_e = np.where(rest > 0.0, c_e / np.where(rest > 0.0, rest, 1.0), c_e)
    a, b, c = x[t[:, 0]], x[t[:, 1]], x[t[:, 2]]
    area = 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
    c_t = area - area0 if signed else np.abs(area) - np.abs(area0)
    c_t = np.where(area0 != 0.0, c_t / np.where(area0 != 0.0, np.abs(area0), 1.0), c_t)
    n = c_e.size + c_t.size
    return math.sqrt(float((c_e @ c_e + c_t @ c_t) / n)) if n else 0.0


@dataclass
class ReferenceInfo:
    """What :class:`ReferenceSolver` hands the Simulation: the fields of a solver's ``SolveInfo``, and the result."""

    x_pred: np.ndarray
    """Predicted positions x* [m], shape (N, 2) (the paper contact's held displacements included)."""
    contact_dx: None
    """None: projection contact is not modelled (no contact corrections)."""
    residual: float
    """RMS constraint violation at the minimiser (:func:`constraint_residual`)."""
    result: ReferenceResult
    """The exact step: minimiser, energy, convergence."""


class ReferenceSolver:
    """The exact reference as a Simulation's solver: every step is :func:`reference_step`.

    So the reference gets its step (start state, contacts) from the Simulation's own path, as every method
    does: ``Simulation.from_config(cfg, mesh=mesh, solver=ReferenceSolver)`` runs the exact run, and
    ``sim.solve(report.detail, solver=ReferenceSolver)`` solves one step of another method's run exactly
    (``functools.partial(ReferenceSolver, max_iterations=...)`` to cap Newton).

    Parameters
    ----------
    model : Model
    rtol : float
        Relative gradient-norm tolerance of Newton.
    max_iterations : int
        Newton iterations at most per step.
    """

    def __init__(self, model: Model, rtol: float = 1e-10, max_iterations: int = 200) -> None:
        self.model = model
        self.rtol = float(rtol)
        self.max_iterations = int(max_iterations)

    def step(self, state_in: State, state_out: State, contacts: Contacts, dt: float) -> ReferenceInfo:
        """One exact step from ``state_in`` into ``state_out`` (the solver's protocol; ``contacts.touched`` set to
        the held particles)."""
        ref = reference_step(self.model, state_in, contacts, dt, rtol=self.rtol, max_iterations=self.max_iterations)
        np.copyto(state_out.particle_q, ref.particle_q)
        np.copyto(state_out.particle_qd, ref.particle_qd)
        if contacts is not None and contacts.held_idx.size:
            contacts.touched = np.asarray(contacts.held_idx, dtype=np.int32).copy()
        return ReferenceInfo(ref.x_pred, None, constraint_residual(self.model, ref.particle_q), ref)


def relative_error(x: np.ndarray, x_ref: np.ndarray, x_start: np.ndarray) -> float:
    """Position error of ``x`` against ``x_ref``, relative to the reference step's displacement.

    ``||x - x_ref|| / ||x_ref - x_start||`` over all particles (Frobenius norms), where
    ``x_start`` are the positions at the start of the step; inf if the reference did not move.
    """
    den = float(np.linalg.norm(x_ref - x_start))
    num = float(np.linalg.norm(x - x_ref))
    if den == 0.0:
        return 0.0 if num == 0.0 else math.inf
    return num / den
