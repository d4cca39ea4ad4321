"""The vectorised NumPy Jacobi solver: the baseline the numba kernels are measured against.

The same step as :class:`~tissue_sim_ros.core.physics.solvers.Solver` with
``scheme="jacobi"`` (prediction, paper contact's held particles, Jacobi sweeps,
velocity update, boundary lines), written the way one would in plain NumPy:
every sweep gathers all constraints' particles, computes all corrections at
once and scatters them with ``np.bincount``. PBD averages each particle's
summed correction by its constraint count (``jacobi_averaging: all``; the
authors' averaging over violated constraints, walls and exponential damping
are not written here and are refused); XPBD relaxes each constraint by the
same stiffness-aware omega as the numba solver. It agrees with the numba
Jacobi solver to round-off (``test/test_bench_solver.py``), so the ratio of
their times is a like-for-like speed-up. Projection contact is not supported.
"""
from __future__ import annotations

import math

import numpy as np

from ..core.contact.collision import Contacts
from ..core.errors import InputError
from ..core.physics.model import Model, State
from ..core.physics.solvers import SolveInfo

EPS_LEN2 = 1e-30  # as the kernels: squared length below which a gradient is undefined


class NumpyJacobiSolver:
    """Vectorised NumPy XPBD/PBD Jacobi; ``step`` mirrors :meth:`Solver.step <tissue_sim_ros.core.physics.solvers.Solver.step>`.

    Parameters
    ----------
    model : Model
        Topology and parameters (``method`` pbd or xpbd, ``iterations``, ``substeps``, ``relaxation``).
    """

    def __init__(self, model: Model) -> None:
        self.model = model
        self.params = p = model.params
        if p.method == "pbd" and p.jacobi_averaging != "all":
            raise InputError("the NumPy Jacobi baseline averages PBD over all constraints: expected "
                             f"jacobi_averaging all, got {p.jacobi_averaging!r}")
        if p.damping_mode != "linear" or not (math.isnan(p.wall_y_bottom) and math.isnan(p.wall_y_top)):
            raise InputError("the NumPy Jacobi baseline has linear damping and no walls: expected damping_mode "
                             "linear and wall_y_bottom/top NaN")
        n = model.n_particles
        self.e = np.asarray(model.edge_indices, dtype=np.int64)
        self.t = np.asarray(model.tri_indices, dtype=np.int64)
        count = np.bincount(self.e.ravel(), minlength=n) + np.bincount(self.t.ravel(), minlength=n)
        self.particle_scale = (1.0 / np.maximum(count, 1)) if p.method == "pbd" else np.ones(n)
        self.x_pred = np.zeros((n, 2))
        """Full-step prediction x* [m], (N, 2)."""

    @property
    def n_projections_per_step(self) -> int:
        p = self.params
        active_e = (p.k_spring if p.method == "pbd" else p.stiffness_spring) > 0
        active_t = (p.k_area if p.method == "pbd" else p.stiffness_area) > 0
        return (len(self.e) * active_e + len(self.t) * active_t) * p.iterations * p.substeps

    def _edge_terms(self, x: np.ndarray, w: np.ndarray):
        i, j = self.e[:, 0], self.e[:, 1]
        d = x[i] - x[j]
        len2 = (d * d).sum(axis=1)
        ok = (len2 > EPS_LEN2) & (w[i] + w[j] > 0)
        length = np.sqrt(np.where(ok, len2, 1.0))
        return i, j, d, length, ok

    def _tri_terms(self, x: np.ndarray, w: np.ndarray):
        a, b, c = self.t[:, 0], self.t[:, 1], self.t[:, 2]
        e1, e2 = x[b] - x[a], x[c] - x[a]
        area = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
        if self.params.area_mode == "signed":
            sg = np.full_like(area, 0.5)
            C = area - self.model.tri_rest_area
        else:
            sg = 0.5 * np.sign(area)
            C = np.abs(area) - np.abs(self.model.tri_rest_area)
        gb = sg[:, None] * np.stack([e2[:, 1], -e2[:, 0]], axis=1)
        gc = sg[:, None] * np.stack([-e1[:, 1], e1[:, 0]], axis=1)
        ga = -(gb + gc)
        return a, b, c, ga, gb, gc, C

    def _omega(self, x: np.ndarray, w: np.ndarray, alpha_e: float, alpha_t: float, scale: float):
        """The stiffness-aware (Gershgorin) omega of sweeps.jacobi_relaxation, vectorised."""
        n = len(x)
        i, j, _, _, okl = self._edge_terms(x, np.ones_like(w))
        g_e = okl.astype(float)
        sd_e = np.sqrt((w[i] + w[j]) * g_e + alpha_e)
        a, b, c, ga, gb, gc, _ = self._tri_terms(x, w)
        na, nb, nc = (np.sqrt((g * g).sum(axis=1)) for g in (ga, gb, gc))
        sd_t = np.sqrt(w[a] * na ** 2 + w[b] * nb ** 2 + w[c] * nc ** 2 + alpha_t)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv_e = np.where(sd_e > 0, 1.0 / sd_e, 0.0)
            inv_t = np.where(sd_t > 0, 1.0 / sd_t, 0.0)
            G = (np.bincount(i, g_e * inv_e, minlength=n) + np.bincount(j, g_e * inv_e, minlength=n)
                 + np.bincount(a, na * inv_t, minlength=n) + np.bincount(b, nb * inv_t, minlength=n)
                 + np.bincount(c, nc * inv_t, minlength=n))
            r_e = alpha_e * inv_e ** 2 + g_e * (w[i] * G[i] + w[j] * G[j]) * inv_e
            r_t = alpha_t * inv_t ** 2 + (w[a] * na * G[a] + w[b] * nb * G[b] + w[c] * nc * G[c]) * inv_t
            om_e = np.where(r_e > 0, scale / r_e, scale)
            om_t = np.where(r_t > 0, scale / r_t, scale)
        return np.where(sd_e > 0, om_e, 0.0), np.where(sd_t > 0, om_t, 0.0)

    def step(self, state_in: State, state_out: State, contacts: Contacts | None, dt: float) -> SolveInfo:
        """Advance ``state_in`` by ``dt`` into ``state_out`` (so it can stand in for a Simulation's solver)."""
        p = self.params
        m = self.model
        n = m.n_particles
        if contacts is not None and len(contacts.candidates):
            raise InputError("NumpyJacobiSolver: projection contact is not supported (paper contact only)")
        inv_mass = m.particle_inv_mass
        free = inv_mass > 0
        held = np.asarray(contacts.held_idx, dtype=np.int64) if contacts is not None else np.zeros(0, np.int64)
        held_dx = np.asarray(contacts.held_dx).reshape(-1, 2) if contacts is not None else np.zeros((0, 2))
        g = np.array([0.0, p.gravity])

        x0, v0 = state_in.particle_q, state_in.particle_qd
        x_full = np.where(free[:, None], x0 + dt * max(0.0, 1 - p.damping * dt) * v0 + dt * dt * g, x0)
        x_full[held[free[held]]] += held_dx[free[held]]
        w = inv_mass.copy()
        w[held] = 0.0
        self.x_pred[:] = x_full

        n_sub = p.substeps
        h = dt / n_sub
        pbd = p.method == "pbd"
        k_e, k_t = (p.k_spring, p.k_area) if pbd else (1.0, 1.0)
        alpha_e = 0.0 if pbd or p.stiffness_spring <= 0 else 1.0 / (p.stiffness_spring * h * h)
        alpha_t = 0.0 if pbd or p.stiffness_area <= 0 else 1.0 / (p.stiffness_area * h * h)
        use_e = (p.k_spring if pbd else p.stiffness_spring) > 0
        use_t = (p.k_area if pbd else p.stiffness_area) > 0
        x, v = x0.copy(), v0.copy()
        rest = m.edge_rest_length
        for sub in range(n_sub):
            x_start = x.copy()
            if n_sub == 1:
                x = x_full.copy()
            else:
                x = np.where(free[:, None], x_start + h * max(0.0, 1 - p.damping * h) * v + h * h * g, x_start)
                f = (sub + 1) / n_sub
                x[held[free[held]]] = (x0 + f * (x_full - x0))[held[free[held]]]
            lam_e = np.zeros(len(self.e))
            lam_t = np.zeros(len(self.t))
            if pbd:
                om_e, om_t = np.ones(len(self.e)), np.ones(len(self.t))
            else:
                om_e, om_t = self._omega(x, w, alpha_e, alpha_t, 2.0 * p.relaxation)
            # per-step constants of the sweeps: masses at each constraint's particles, one scatter index
            i, j = self.e[:, 0], self.e[:, 1]
            a, b, c = self.t[:, 0], self.t[:, 1], self.t[:, 2]
            wi, wj, wa, wb, wc = w[i], w[j], w[a], w[b], w[c]
            parts_e = [i, j] if use_e else []
            parts_t = [a, b, c] if use_t else []
            scatter_idx = np.concatenate(parts_e + parts_t) if parts_e or parts_t else np.zeros(0, np.int64)
            signed = p.area_mode == "signed"
            for _ in range(p.iterations):
                vals = []
                if use_e:
                    d = x[i] - x[j]
                    len2 = np.einsum("ij,ij->i", d, d)
                    ok = (len2 > EPS_LEN2) & (wi + wj > 0)
                    length = np.sqrt(np.where(ok, len2, 1.0))
                    f = om_e * k_e * (rest - length - alpha_e * lam_e) / np.where(ok, (wi + wj + alpha_e) * length, 1.0)
                    f[~ok] = 0.0
                    lam_e += f * length
                    corr = f[:, None] * d
                    vals += [wi[:, None] * corr, -wj[:, None] * corr]
                if use_t:
                    xa = x[a]
                    e1, e2 = x[b] - xa, x[c] - xa
                    area = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
                    if signed:
                        sg = 0.5
                        C = area - self.model.tri_rest_area
                    else:
                        sg = 0.5 * np.sign(area)[:, None]
                        C = np.abs(area) - np.abs(self.model.tri_rest_area)
                    gb = sg * np.column_stack([e2[:, 1], -e2[:, 0]])
                    gc = sg * np.column_stack([-e1[:, 1], e1[:, 0]])
                    ga = -(gb + gc)
                    na, nb, nc = (np.einsum("ij,ij->i", g, g) for g in (ga, gb, gc))
                    den = wa * na + wb * nb + wc * nc + alpha_t
                    ok = (wa + wb + wc > 0) & (na + nb + nc > EPS_LEN2) & (den > 0)
                    st = om_t * k_t * (-C - alpha_t * lam_t) / np.where(ok, den, 1.0)
                    st[~ok] = 0.0
                    lam_t += st
                    vals += [(wa * st)[:, None] * ga, (wb * st)[:, None] * gb, (wc * st)[:, None] * gc]
                if vals:
                    allv = np.concatenate(vals)
                    dx = np.column_stack([np.bincount(scatter_idx, allv[:, 0], minlength=n),
                                          np.bincount(scatter_idx, allv[:, 1], minlength=n)])
                    x = x + self.particle_scale[:, None] * dx
            v = (x - x_start) / h
            for line, past in ((p.boundary_y_top, lambda y, L: y >= L), (p.boundary_y_bottom, lambda y, L: y <= L)):
                if math.isnan(line):
                    continue
                hit = free & past(x[:, 1], line)
                x[hit, 1] = line
                v[hit] = 0.0
        state_out.particle_q[:] = x
        state_out.particle_qd[:] = v
        if contacts is not None and len(held):
            contacts.touched = np.asarray(held, dtype=np.int32).copy()
        return SolveInfo(x_pred=self.x_pred, contact_dx=None, residual=self._residual(x))

    def _residual(self, x: np.ndarray) -> float:
        """RMS of C / l0 over edges and C / |A0| over triangles."""
        m = self.model
        i, j, _, length, _ = self._edge_terms(x, np.ones(len(x)))
        c_e = (length - m.edge_rest_length) / m.edge_rest_length
        *_, C = self._tri_terms(x, np.ones(len(x)))
        c_t = C / np.abs(m.tri_rest_area)
        allc = np.concatenate([c_e, c_t])
        return float(np.sqrt(np.mean(allc ** 2))) if allc.size else 0.0
