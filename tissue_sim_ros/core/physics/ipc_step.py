"""One barrier step in one compiled call (:func:`ipc_step`), and what the step reports of its contacts
(:func:`contact_report`): the tissue's reaction on the tool, each body's barrier energy, the particles the tool
touches.

The step: the prediction x* (``step_kernels.predict_step``), the free coordinates (a pinned particle none, a
particle at or past a boundary line in the rest shape its x only: it slides along the line), the motion continued
as the start (capped so nothing crosses on the way), the candidate pairs there, the factor refreshed when the last
step needed more than ``refresh`` iterations (or there is none, or dt changed), the minimisation
(:func:`~.ipc.ipc_solve`), then v = (x - x_n) / dt and the boundary lines (as every method: a particle at or past
one is put on it and stopped).

Bundles: :mod:`.ipc` and :mod:`.ipc_energy`'s, the step kernels' ``state``, ``pred``, ``timing``, ``bounds``
(``core/physics/step_kernels.py``; ``pred``'s x_start slot holds the guess), ``tool_q`` = (q at the step's start
(4,), q (4,) out, where to start the tool (4,), the command (4,), the parts it is approached in, the path out:
the particles (P + 1, N, 2) and the tool (P + 1, 4) at the start and each part's end), ``factor_state`` (3,) = (a factor is held, the last step's iterations, the dt it was made for).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..contact.barrier import barrier, point_segment
from ..contact.collider import tool_vertices
from .ipc import ipc_solve, refactor, step_bound, sweep, sweep_fitting
from .ipc_energy import contact_part, grasp_targets
from .ipc_friction import friction_lag, friction_part
from .kernels import apply_boundary_lines, update_velocity
from .step_kernels import predict_step


@njit(cache=True, nogil=True)
def _start(state: tuple, pred: tuple, timing: tuple, model: tuple, contact: tuple, tool: tuple, step: tuple,
           pairs: tuple, scratch: tuple, ws: tuple, opts: tuple, q: np.ndarray, q_guess: np.ndarray) -> None:
    """(x, q) = the motion continued from x_n (x_n + dt damp v_n on the free coordinates) with the tool moved as
    commanded (``q_guess``: where it was plus the command's change: a tool held still stays where the tissue left
    it), as far toward that as it goes without a pair crossing; the candidate pairs there in ``pairs``."""
    x0, v0, x, _v = state
    dt, damp = timing[0], timing[3]
    free = step[1]
    dvec = ws[6]
    n = x.shape[0]
    for i in range(n):
        x[i, 0] = x0[i, 0]
        x[i, 1] = x0[i, 1]
        dvec[2 * i] = v0[i, 0] * (dt * damp) * free[2 * i]
        dvec[2 * i + 1] = v0[i, 1] * (dt * damp) * free[2 * i + 1]
    for j in range(4):
        dvec[2 * n + j] = (q_guess[j] - q[j]) if tool[2] else 0.0
    a = 0.0
    if sweep_fitting(x, q, dvec, model, contact, tool, pairs, scratch, ws, opts) > 0.0:
        a = step_bound(x, q, dvec, model, contact, tool, step, pairs, ws, opts)
    for i in range(n):
        x[i, 0] += a * dvec[2 * i]
        x[i, 1] += a * dvec[2 * i + 1]
    for j in range(4):
        q[j] += a * dvec[2 * n + j]
    for k in range(dvec.shape[0]):
        dvec[k] = 0.0
    sweep(x, q, dvec, model, contact, tool, pairs, scratch, ws, opts)


@njit(cache=True, nogil=True)
def ipc_step(state: tuple, pred: tuple, timing: tuple, bounds: tuple, model: tuple, contact: tuple, tool: tuple,
             step: tuple, pairs: tuple, scratch: tuple, lin: tuple, ws: tuple, opts: tuple, tool_q: tuple,
             factor_state: np.ndarray) -> None:
    """One step of ``method: ipc`` (module docstring); the solve's numbers in ``ws``'s out; ``tool_q``'s last two,
    the path, (P + 1, N, 2) and (P + 1, 4): the particles and the tool at the start and at the end of each of the
    P parts the command is approached in (the run-time checks follow the step along it)."""
    x0, _v0, x, v = state
    inv_mass, w = pred[0], pred[1]
    dt = timing[0]
    free = step[1]
    roller = model[7]
    out = ws[11]
    predict_step(state, pred, timing, bounds)
    for i in range(x.shape[0]):
        f = 1.0 if w[i] != 0.0 else 0.0
        free[2 * i] = f
        free[2 * i + 1] = 0.0 if roller[i] else f
    q_start, q, q_guess, q_final, n_sub, xs, qs = tool_q
    for j in range(4):
        q[j] = q_start[j]
    friction = step[5]
    friction[4][0] = 0
    if friction[5][0] > 0.0 or friction[5][1] > 0.0:
        # the friction's lag: the pairs in contact at the step's start (a sweep that does not move)
        dvec = ws[6]
        for k in range(dvec.shape[0]):
            dvec[k] = 0.0
        sweep(x0, q, dvec, model, contact, tool, pairs, scratch, ws, opts)
        friction_lag(x0, q, model, contact, tool, pairs, scratch, friction)
    _start(state, pred, timing, model, contact, tool, step, pairs, scratch, ws, opts, q, q_guess)
    out[2] = 0.0
    if factor_state[0] == 0.0 or factor_state[1] > opts[3] or factor_state[2] != dt:
        refactor(x, q, model, contact, tool, step, pairs, scratch, lin)
        factor_state[0] = 1.0
        factor_state[2] = dt
        out[2] = 1.0
    # the command approached in n_sub equal parts, each solved from the last (the same minimiser at the end):
    # a tool that moves far in one step never runs ahead of the tissue it pushes by more than a part
    q_cmd = step[2]
    its = 0.0
    xs[0, :, :] = x0
    qs[0, :] = q_start
    for k in range(1, n_sub + 1):
        for j in range(4):
            q_cmd[j] = q_final[j] if k == n_sub else q_start[j] + (k / n_sub) * (q_final[j] - q_start[j])
        ipc_solve(x, q, x0, q_start, model, contact, tool, step, pairs, scratch, lin, ws, opts)
        its += out[0]
        xs[k, :, :] = x
        qs[k, :] = q
    out[0] = its
    factor_state[1] = out[0] / n_sub
    update_velocity(x, x0, dt, v)
    apply_boundary_lines(x, v, inv_mass, bounds[3], bounds[4])


@njit(cache=True, nogil=True)
def contact_report(x: np.ndarray, q: np.ndarray, model: tuple, contact: tuple, tool: tuple, step: tuple,
                   pairs: tuple, scratch: tuple, body: np.ndarray, out_body: np.ndarray, touched: np.ndarray,
                   force: np.ndarray) -> None:
    """What the step's contacts did at its end (x, q): the tissue's force and torque on the tool about its pose
    (-dE_contact/dq / dt^2, the barriers' and the friction's: (F_x, F_y, tau, jaw torque) into ``force`` (4,));
    per body, the barrier energy dt^2 kappa sum b (``out_body[:, 0]``), the smallest gap to the tool
    (``out_body[:, 1]``, inf: none within dhat), 1.0 when the tool touches it (``out_body[:, 2]``) and the net
    force every contact (the tool, other bodies, itself; barriers and friction) puts on it [N]
    (``out_body[:, 3:5]``), the smallest gap of a pair within or between bodies (``out_body[:, 5]``, inf: none
    within dhat; the pair's point's body); ``touched`` (N,) 1 at the particles in a pair with the
    tool closer than dhat. The grasp's targets at q into ``scratch``."""
    edges = model[5]
    dhat_t, dhat_tool, kappa, _lines = contact
    dt2 = step[3]
    tt, vt, tv, counts = pairs
    n = x.shape[0]
    for b in range(out_body.shape[0]):
        out_body[b, 0] = 0.0
        out_body[b, 1] = math.inf
        out_body[b, 2] = 0.0
        out_body[b, 3] = 0.0
        out_body[b, 4] = 0.0
        out_body[b, 5] = math.inf
    for i in range(n):
        touched[i] = 0
    g = np.zeros(2 * n + 4)
    if tool[2]:
        tool_vertices(q, tool[0], scratch[0], scratch[1])
    contact_part(x, model, contact, tool, pairs, scratch, dt2, g[:2 * n], g[2 * n:])
    friction_part(x, step[5], scratch, dt2, g)
    for j in range(4):
        force[j] = -g[2 * n + j] / dt2
    for i in range(n):
        out_body[body[i], 3] -= g[2 * i] / dt2
        out_body[body[i], 4] -= g[2 * i + 1] / dt2
    pos = scratch[0]
    geom = tool[0]
    for k in range(counts[0]):
        p, a, b = tt[k, 0], edges[tt[k, 1], 0], edges[tt[k, 1], 1]
        d = point_segment(x[p, 0], x[p, 1], x[a, 0], x[a, 1], x[b, 0], x[b, 1])[0]
        out_body[body[p], 0] += dt2 * kappa * barrier(d, dhat_t)[0]
        if d < dhat_t:
            out_body[body[p], 5] = min(out_body[body[p], 5], d)
    for kind in (1, 2):
        for k in range(counts[kind]):
            if kind == 1:
                p, te = vt[k, 0], vt[k, 1]
                ta, tb = geom[3][te, 0], geom[3][te, 1]
                gap = point_segment(x[p, 0], x[p, 1], pos[ta, 0], pos[ta, 1], pos[tb, 0], pos[tb, 1])[0] - geom[4][te]
                a = b = p
            else:
                wv, e = tv[k, 0], tv[k, 1]
                a, b = edges[e, 0], edges[e, 1]
                gap = point_segment(pos[wv, 0], pos[wv, 1], x[a, 0], x[a, 1], x[b, 0], x[b, 1])[0] - geom[5][wv]
            bd = body[a]
            out_body[bd, 1] = min(out_body[bd, 1], gap)
            if gap < dhat_tool:
                out_body[bd, 0] += dt2 * kappa * barrier(gap, dhat_tool)[0]
                out_body[bd, 2] = 1.0
                touched[a] = 1
                touched[b] = 1
    idx, local, _k = step[4]
    if idx.shape[0]:
        grasp_targets(q, local, scratch[2])
