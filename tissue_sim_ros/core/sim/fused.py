"""A candidate's rollout in one compiled call, for the material's default solve (issue 31: a replan's 32 x 50 steps).

:func:`~tissue_sim_ros.core.sim.batch.rollout_candidate` steps a scratch :class:`Simulation` once per step: each
step is a dozen Python calls around the compiled solve (detection, the grasp's targets, the step's checks, the
energy terms, the reaction), about 0.3 ms of a ~150-particle step's 0.6-1 ms. A model-predictive controller rolls
32 candidates x 50 steps out per replan, so that overhead alone is ~0.5 s. Here the whole path runs in one numba
call: the same kernels, called in the same order with the same arguments, as
:meth:`Simulation.step <tissue_sim_ros.core.sim.simulation.Simulation.step>` with ``method: quasi_newton`` and
the projection contact calls them:

* contact candidates: the tool swept from the last pose to this one with the contact margin
  (:func:`~tissue_sim_ros.core.contact.kernels.swept_candidates`, and the surface edges with
  ``contact_surface: edges``), the pad |v|max dt + |g| dt^2 + the tool's travel;
* the prediction x* = x + dt damp v + dt^2 g (:func:`~tissue_sim_ros.core.physics.kernels.predict`), the
  minimiser of the step's energy (:func:`~tissue_sim_ros.core.physics.quasi_newton.quasi_newton_solve`, the held
  particles tied to T(pose) l by springs of stiffness 1/``grasp_compliance``), v = (x - x_n)/dt and the
  boundary lines;
* what the rollout measures: the scene's energy (inertial + strain + attachment terms, per body), the force on the
  tool (the contacts' -m dx / (dt h) plus the grasp's (x - target)/c), the tool's penetration (the rounded box's
  signed distance without margin), the largest displacement, contact, inverted triangles.

So a fused rollout's final state is the stepped one's bit for bit (``test/test_fused.py``; its plain twin is
the stepped rollout, ``test/naive.py:rollout_stepped``). It applies when the path does not work the jaw, the
snapshot's jaw would not close or open on the first step, the solver is the serial quasi-Newton one (no sleeping)
and the contact is the projection; otherwise, and from a step that diverges (the stepped path restores the last good
state and lets go), the caller steps the Simulation.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..contact.kernels import (
    EDGE_SIDE_TOL_MIN,
    gather_surface_edges,
    points_sdf,
    swept_candidates,
    swept_edge_candidates,
)
from ..contact.tool import ToolPose, tool_shape_array
from ..physics.kernels import (
    apply_boundary_lines,
    count_inverted,
    energy_terms_kernel,
    hold_displaced,
    predict,
    update_velocity,
)
from ..physics.material import strain_energy_kernel
from ..physics.quasi_newton import quasi_newton_solve
from ..physics.walls import apply_walls
from .simulation import Simulation
from .snapshot import SimSnapshot


@njit(cache=True, nogil=True)
def fused_quasi_newton_rollout(
        x: np.ndarray, v: np.ndarray, x_new: np.ndarray, v_new: np.ndarray, x0: np.ndarray,
        mass: np.ndarray, inv_mass: np.ndarray, inv_mass_eff: np.ndarray, x_pred: np.ndarray, body: np.ndarray,
        tris_model: np.ndarray, elastic_model: np.ndarray, tri_body: np.ndarray, tris: np.ndarray,
        elastic: np.ndarray,
        shapes_m: np.ndarray, shapes_0: np.ndarray, boundary_edges: np.ndarray, use_edges: bool,
        cand: np.ndarray, edge_cand: np.ndarray, is_cand: np.ndarray, edge_rows: np.ndarray,
        attach_idx: np.ndarray, attach_local: np.ndarray, poses: np.ndarray, attach_target: np.ndarray,
        attach_k: float, compliance: float,
        dt: float, gravity: float, damp: float, reach_pad: float, side_tol: float, reaction_den: float,
        walls: bool, wall_bottom: float, wall_top: float, y_top: float, y_bottom: float,
        tolerance: float, max_iterations: int, floor_rms: float,
        l_ptr: np.ndarray, l_idx: np.ndarray, l_val: np.ndarray, u_ptr: np.ndarray, u_idx: np.ndarray,
        u_val: np.ndarray, perm_r: np.ndarray, perm_c: np.ndarray,
        hist_s: np.ndarray, hist_y: np.ndarray, hist_rho: np.ndarray, alpha_buf: np.ndarray,
        kind: np.ndarray, normal: np.ndarray, scratch: np.ndarray, contact_dx: np.ndarray, guess: np.ndarray,
        g: np.ndarray, g_new: np.ndarray, d: np.ndarray, x_old: np.ndarray, z: np.ndarray, out3: np.ndarray,
        in_factor: np.ndarray, wcol: np.ndarray, wkey: np.ndarray, cur_slot: np.ndarray, cur_i: np.ndarray,
        cur_n: np.ndarray, smat: np.ndarray, sinv: np.ndarray, used: np.ndarray, b_unit: np.ndarray,
        t_buf: np.ndarray, released_once: np.ndarray, turns: np.ndarray, cur_c: np.ndarray,
        e_inertial: np.ndarray, e_spring: np.ndarray, e_area: np.ndarray, e_pot: np.ndarray,
        e_attach: np.ndarray, sdf: np.ndarray, grad: np.ndarray,
        energy_body: np.ndarray, force: np.ndarray, penetration: np.ndarray, displacement: np.ndarray,
        contact: np.ndarray, inverted: np.ndarray, no_edges: np.ndarray, no_index: np.ndarray) -> int:
    """Step the path (module docstring); returns the steps taken: all S, or k when step k diverged (its
    outputs are not written and ``x``, ``v`` hold the state before it).

    Steps ``S = poses.shape[0]``. ``shapes_m`` (S + 1, 7): the packed tool with the contact margin at the start
    pose and at each step's pose; ``shapes_0`` (S, 7) the same without the margin. ``x``, ``v`` (N, 2): the state,
    advanced in place; ``x_new``, ``v_new`` scratch of that shape. Per step out: ``energy_body`` (S, B, 5)
    (inertial, spring, area, strain, attachment: the terms as ``EnergyTerms`` holds them), ``force`` (S, 2) [N],
    ``penetration`` (S,) [m] (max of -sdf), ``displacement`` (S,) [m], ``contact`` (S,) bool, ``inverted``
    (S,) int. The rest are the solve's workspaces (``MaterialSolve``).
    """
    n = x.shape[0]
    n_steps = poses.shape[0]
    n_att = attach_idx.shape[0]
    dt2 = dt * dt
    empty_dx = np.zeros((0, 2))
    no_values = np.zeros(0)  # energy_terms_kernel's constraint arguments: none (the material's energy is the strain)
    no_tris = np.zeros((0, 3), np.int32)
    for k in range(n_steps):
        s0 = shapes_m[k]
        s1 = shapes_m[k + 1]
        # detection (ContactModel._detect_projection): the pad is |v|max dt + |g| dt^2 + the tool's travel
        vmax2 = 0.0
        for i in range(n):
            q = v[i, 0] * v[i, 0] + v[i, 1] * v[i, 1]
            if q > vmax2:
                vmax2 = q
        vmax = math.sqrt(vmax2) if n else 0.0
        reach = vmax * dt + reach_pad + poses[k, 3]
        n_cand = swept_candidates(x, inv_mass, s0, s1, reach, cand)
        n_edges = 0
        if use_edges:
            n_sel = swept_edge_candidates(x, inv_mass, boundary_edges, s0, s1, reach, edge_cand)
            if n_sel:
                n_cand = gather_surface_edges(boundary_edges, edge_cand, n_sel, inv_mass, cand, n_cand, is_cand,
                                              edge_rows)
                n_edges = n_sel
        projection = n_cand > 0 or n_edges > 0
        # the grasp's targets: T(pose) l (grasp.to_world)
        c = math.cos(poses[k, 2])
        s = math.sin(poses[k, 2])
        for a in range(n_att):
            attach_target[a, 0] = poses[k, 0] + c * attach_local[a, 0] - s * attach_local[a, 1]
            attach_target[a, 1] = poses[k, 1] + s * attach_local[a, 0] + c * attach_local[a, 1]
        # the solve (Solver._step_quasi_newton, MaterialSolve.minimise)
        predict(x, v, inv_mass, dt, gravity, damp, x_pred)
        hold_displaced(x_pred, inv_mass, no_index, empty_dx, 1.0, inv_mass_eff)
        if walls:
            apply_walls(x_pred, wall_bottom, wall_top)
        for i in range(n):
            x_new[i, 0] = x_pred[i, 0]
            x_new[i, 1] = x_pred[i, 1]
            guess[i, 0] = v[i, 0] * (dt * damp)
            guess[i, 1] = v[i, 1] * (dt * damp)
            guess[i, 0] += x[i, 0]
            guess[i, 1] += x[i, 1]
        quasi_newton_solve(
            x_new, x, x_pred, mass, inv_mass_eff, tris, elastic, dt2, gravity, l_ptr, l_idx, l_val, u_ptr, u_idx,
            u_val, perm_r, perm_c, hist_s, hist_y, hist_rho, alpha_buf, kind, normal,
            cand[:n_cand], edge_rows[:n_edges],
            s0, s1, side_tol, scratch, contact_dx, y_top, y_bottom, wall_bottom, wall_top,
            attach_idx, attach_target, attach_k, tolerance, max_iterations, guess, g, g_new, d, x_old, z, out3,
            inv_mass, in_factor, wcol, wkey, cur_slot, cur_i, cur_n, smat, sinv, used, b_unit, t_buf,
            released_once, turns, cur_c, floor_rms)
        update_velocity(x_new, x, dt, v_new)
        apply_boundary_lines(x_new, v_new, inv_mass, y_top, y_bottom)
        finite = True
        for i in range(n):
            if not (math.isfinite(x_new[i, 0]) and math.isfinite(x_new[i, 1]) and math.isfinite(v_new[i, 0])
                    and math.isfinite(v_new[i, 1])):
                finite = False
                break
        if not finite:
            return k
        inverted[k] = count_inverted(x_new, tris_model)
        # the energy terms (energy_terms: the inertial term, the strain energy; the attachments')
        e_inertial[:] = 0.0
        e_spring[:] = 0.0
        e_area[:] = 0.0
        e_pot[:] = 0.0
        e_attach[:] = 0.0
        energy_terms_kernel(x_new, x_pred, mass, body, no_edges, no_values, no_index, no_tris, no_values, no_index,
                            0.0, 0.0, dt, True, e_inertial, e_spring, e_area)
        strain_energy_kernel(x_new, tris_model, elastic_model, tri_body, e_pot)
        for a in range(n_att):
            i = attach_idx[a]
            ex = x_new[i, 0] - attach_target[a, 0]
            ey = x_new[i, 1] - attach_target[a, 1]
            e_attach[body[i]] += 0.5 * (ex * ex + ey * ey) / compliance
        for b in range(energy_body.shape[1]):
            energy_body[k, b, 0] = e_inertial[b]
            energy_body[k, b, 1] = e_spring[b]
            energy_body[k, b, 2] = e_area[b]
            energy_body[k, b, 3] = dt2 * e_pot[b]
            energy_body[k, b, 4] = dt2 * e_attach[b] if n_att else 0.0
        # the force on the tool (Simulation._reaction, attachment_wrench): summed in particle order
        fx = 0.0
        fy = 0.0
        touched = False
        if projection:
            for i in range(n):
                if contact_dx[i, 0] != 0.0 or contact_dx[i, 1] != 0.0:
                    touched = True
                    fx += -mass[i] * contact_dx[i, 0] / reaction_den
                    fy += -mass[i] * contact_dx[i, 1] / reaction_den
        ax = 0.0
        ay = 0.0
        for a in range(n_att):
            i = attach_idx[a]
            ax += (x_new[i, 0] - attach_target[a, 0]) / compliance
            ay += (x_new[i, 1] - attach_target[a, 1]) / compliance
        force[k, 0] = fx + ax
        force[k, 1] = fy + ay
        contact[k] = touched
        # the tool's penetration and the largest displacement (rollout_candidate's measures)
        points_sdf(x_new, shapes_0[k], sdf, grad)
        m = math.inf
        dmax = 0.0
        for i in range(n):
            if sdf[i] < m:
                m = sdf[i]
            dx = x_new[i, 0] - x0[i, 0]
            dy = x_new[i, 1] - x0[i, 1]
            q = dx * dx + dy * dy
            if q > dmax:
                dmax = q
        penetration[k] = -m
        displacement[k] = math.sqrt(dmax)
        for i in range(n):
            x[i, 0] = x_new[i, 0]
            x[i, 1] = x_new[i, 1]
            v[i, 0] = v_new[i, 0]
            v[i, 1] = v_new[i, 1]
    return n_steps


def fused_applies(sim: Simulation, snap: SimSnapshot, jaws: np.ndarray | None) -> bool:
    """Whether :func:`rollout_fused` gives the stepped rollout's numbers for this path (module docstring)."""
    p = sim.params
    solver = sim.solver
    if not (getattr(solver, "quasi_newton", False) and type(solver).__name__ == "Solver" and sim.model.is_material):
        return False
    if sim.tool is None or sim.contact is None or p.contact_model != "projection" or p.sleep_speed > 0:
        return False
    if jaws is not None and not np.isnan(jaws).all():
        return False
    grasp = snap.grasp or {}
    jaw, closed = grasp.get("jaw"), bool(grasp.get("closed", False))
    if sim.tool.kind == "grasper" and jaw is not None:
        if (closed and jaw > p.grasp_open_angle) or (not closed and jaw < p.grasp_close_angle):
            return False  # the first step would close or open the jaw
    return True


def warm_fused(sim: Simulation) -> None:
    """Load (or compile) the fused kernel now, with two steps of the tool at the tissue's centre, then
    :meth:`Simulation.reset`: a pool worker's or a Ray actor's first candidate does not wait for it."""
    q0 = sim.model.particle_q0
    snap = sim.snapshot()
    if len(q0) == 0 or not fused_applies(sim, snap, None):
        return
    cx, cy = (q0.min(axis=0) + q0.max(axis=0)) / 2.0
    poses = np.array([[cx, cy, 0.0], [cx + 1e-3, cy, 0.0]])
    rollout_fused(sim, snap, poses, ToolPose(float(cx), float(cy), 0.0), FusedWorkspace(sim))
    sim.reset()


class FusedWorkspace:
    """The per-scene arrays :func:`rollout_fused` reuses (one per scratch Simulation)."""

    def __init__(self, sim: Simulation) -> None:
        model = sim.model
        n = model.n_particles
        nb = model.n_bodies
        self.n, self.nb = n, nb
        self.x = np.zeros((n, 2))
        self.v = np.zeros((n, 2))
        self.x_new = np.zeros((n, 2))
        self.v_new = np.zeros((n, 2))
        self.x_pred = np.zeros((n, 2))
        self.inv_mass_eff = np.zeros(n)
        self.cand = np.empty(n, dtype=np.int32)
        edges = sim.contact.boundary_edges
        self.edge_cand = np.empty(edges.shape[0], dtype=np.int32)
        self.edge_rows = np.empty((edges.shape[0], 2), dtype=np.int32)
        self.is_cand = np.zeros(n, dtype=bool)
        self.contact_dx = np.zeros((n, 2))
        self.e = [np.zeros(nb) for _ in range(5)]
        self.sdf = np.empty(n)
        self.grad = np.empty((n, 2))
        self.no_edges = np.zeros((0, 2), dtype=np.int32)
        self.no_index = np.zeros(0, dtype=np.int32)


def rollout_fused(sim: Simulation, snap: SimSnapshot, poses: np.ndarray, start: ToolPose,
                  ws: FusedWorkspace, x_ref: np.ndarray | None = None) -> dict:
    """Roll the poses (S, 3) out from ``snap`` in one compiled call (module docstring). ``start``: the tool's
    pose before the first step (the path's start or the snapshot's); ``x_ref``: the positions displacements are
    measured from (default the snapshot's). Returns the per-step arrays and the final state, ``steps`` < S when
    a step diverged (the caller steps from there)."""
    model = sim.model
    p = sim.params
    solver = sim.solver
    ms = solver.material_solve
    tool = sim.tool
    dt = float(p.dt)
    n_steps = poses.shape[0]
    margin = float(p.contact_margin)
    shapes_m = np.empty((n_steps + 1, 7))
    shapes_0 = np.empty((n_steps, 7))
    ext = np.empty((n_steps, 4))
    ext[:, :3] = poses[:, :3]
    prev = start
    shapes_m[0] = tool_shape_array(tool, prev, margin)
    rr = tool.rounded_box()[2]
    for k in range(n_steps):
        pose = ToolPose(float(poses[k, 0]), float(poses[k, 1]), float(poses[k, 2]))
        s1 = tool_shape_array(tool, pose, margin)
        shapes_m[k + 1] = s1
        shapes_0[k] = s1
        shapes_0[k, 6] = rr
        s0 = shapes_m[k]
        radius = math.hypot(s1[4], s1[5]) + s1[6]
        dyaw = abs(math.atan2(math.sin(pose.yaw - prev.yaw), math.cos(pose.yaw - prev.yaw)))
        ext[k, 3] = math.hypot(s1[0] - s0[0], s1[1] - s0[1]) + dyaw * radius
        prev = pose
    grasp = snap.grasp or {}
    if tool.kind == "grasper" and len(grasp.get("idx", ())):
        idx = np.ascontiguousarray(grasp["idx"], dtype=np.int64)
        local = np.ascontiguousarray(grasp["local"], dtype=np.float64).reshape(-1, 2)
        compliance = float(p.grasp_compliance)
    else:
        idx, local, compliance = np.zeros(0, dtype=np.int64), np.zeros((0, 2)), 0.0
    attach_k = 1.0 / compliance if compliance > 0.0 else 0.0
    pre = ms.step_factor(dt)
    x, v = ws.x, ws.v
    np.copyto(x, snap.particle_q)
    np.copyto(v, snap.particle_qd)
    energy_body = np.zeros((n_steps, ws.nb, 5))
    force = np.zeros((n_steps, 2))
    penetration = np.zeros(n_steps)
    displacement = np.zeros(n_steps)
    contact = np.zeros(n_steps, dtype=np.bool_)
    inverted = np.zeros(n_steps, dtype=np.int64)
    g, g_new, d, x_old, z = ms.vectors
    use_edges = p.contact_surface == "edges" and sim.contact.boundary_edges.shape[0] > 0
    side_tol = max(margin, EDGE_SIDE_TOL_MIN) if use_edges else 0.0
    taken = fused_quasi_newton_rollout(
        x, v, ws.x_new, ws.v_new, np.ascontiguousarray(snap.particle_q if x_ref is None else x_ref),
        model.particle_mass,
        model.particle_inv_mass, ws.inv_mass_eff, ws.x_pred, model.particle_body, model.tri_indices,
        model.tri_elastic, model.tri_body, solver.tris, solver.elastic, shapes_m, shapes_0,
        sim.contact.boundary_edges, use_edges, ws.cand, ws.edge_cand, ws.is_cand, ws.edge_rows, idx, local, ext,
        np.zeros((idx.shape[0], 2)), attach_k, compliance if compliance > 0.0 else 1.0, dt, float(p.gravity),
        float(solver.damp_factor(dt)), abs(p.gravity) * dt * dt, side_tol, dt * (dt / p.substeps),
        bool(solver.walls), float(p.wall_y_bottom), float(p.wall_y_top), float(p.boundary_y_top),
        float(p.boundary_y_bottom), float(p.solve_tolerance), int(p.iterations), float(ms.floor_rms),
        pre.l_ptr, pre.l_idx, pre.l_val, pre.u_ptr, pre.u_idx, pre.u_val, pre.perm_r, pre.perm_c, ms.hist_s,
        ms.hist_y, ms.hist_rho, ms.alpha, ms.kind, ms.normal, ms.scratch, ws.contact_dx, ms.guess, g, g_new, d,
        x_old, z, ms.out, ms.in_factor, ms.wcol, ms.wkey, ms.cur_slot, ms.cur_i, ms.cur_n, ms.smat, ms.sinv,
        ms.used, ms.b, ms.t, ms.released_once, ms.turns, ms.cur_c, *ws.e, ws.sdf, ws.grad, energy_body, force,
        penetration, displacement, contact, inverted, ws.no_edges, ws.no_index)
    return {"steps": int(taken), "x": x, "v": v, "energy_body": energy_body, "force": force,
            "penetration": penetration, "displacement": displacement, "contact": contact, "inverted": inverted}


__all__ = ["FusedWorkspace", "fused_applies", "fused_quasi_newton_rollout", "rollout_fused", "warm_fused"]
