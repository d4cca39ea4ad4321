"""A candidate's rollout in one compiled call, for the material's default solve (a replan's candidates x steps).

:func:`~tissue_sim_ros.core.sim.batch.rollout_candidate` steps a scratch :class:`Simulation` once per step: each
step is a dozen Python calls around the compiled solve (detection, the grasp's targets, the step's checks, the
energy terms, the reaction). A model-predictive controller rolls dozens of candidates of dozens of steps out per
replan, so that overhead alone adds up. Here the whole path runs in one numba call that calls, step by step, the
kernels :meth:`Simulation.step <tissue_sim_ros.core.sim.simulation.Simulation.step>` calls with ``method:
quasi_newton`` and the projection contact:

* detection: :func:`~tissue_sim_ros.core.contact.kernels.projection_candidates` (the tool swept from the last pose
  to this one with the contact margin);
* the grasp's targets T(pose) l (``grasp.to_world``);
* the solve: :func:`~tissue_sim_ros.core.physics.quasi_newton.quasi_newton_step`;
* the finite check, the energy terms and inverted triangles:
  :func:`~tissue_sim_ros.core.physics.step_kernels.finish_step`;
* the force on the tool: :func:`~tissue_sim_ros.core.physics.reaction.push_reaction` and
  :func:`~tissue_sim_ros.core.physics.reaction.attach_reaction`;
* what the rollout measures besides: the tool's penetration (the rounded box's signed distance without margin)
  and the largest displacement (:func:`penetration_and_displacement`, which the stepped rollout uses too).

So a fused rollout's final state is the stepped one's bit for bit (``test/test_fused.py``; its plain twin is
the stepped rollout, ``test/naive.py:rollout_stepped``). It applies when the path does not work the jaw, the
snapshot's jaw would not close or open on the first step, the solver is the quasi-Newton one (no sleeping)
and the contact is the projection; otherwise, and from a step that diverges (the stepped path restores the last good
state and lets go), the caller steps the Simulation.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..contact.collision import tool_travel
from ..contact.kernels import EDGE_SIDE_TOL_MIN, points_sdf, projection_candidates
from ..contact.tool import ToolPose, tool_shape_array
from ..physics.energy import energy_model
from ..physics.quasi_newton import quasi_newton_step
from ..physics.reaction import attach_reaction, push_reaction, touched_particles
from ..physics.solvers import QuasiNewtonSolver
from ..physics.step_kernels import finish_step
from .simulation import Simulation
from .snapshot import SimSnapshot


@njit(cache=True, nogil=True)
def penetration_and_displacement(x: np.ndarray, x_ref: np.ndarray, shape: np.ndarray, sdf: np.ndarray,
                                 grad: np.ndarray) -> tuple[float, float]:
    """(the deepest a particle lies inside the tool ``shape`` (no margin), -min sdf [m]; the largest distance of a
    particle from ``x_ref`` [m]): what a rollout measures after each step. ``sdf`` (N,), ``grad`` (N, 2)
    scratch."""
    points_sdf(x, shape, sdf, grad)
    m = math.inf
    dmax = 0.0
    for i in range(x.shape[0]):
        if sdf[i] < m:
            m = sdf[i]
        dx = x[i, 0] - x_ref[i, 0]
        dy = x[i, 1] - x_ref[i, 1]
        q = dx * dx + dy * dy
        if q > dmax:
            dmax = q
    return -m, math.sqrt(dmax)


@njit(cache=True, nogil=True)
def _grasp_targets(pose: np.ndarray, local: np.ndarray, target: np.ndarray) -> None:
    """The held particles' targets T(pose) l: ``local`` (K, 2) in the tool frame, ``pose`` (x, y, yaw)."""
    c = math.cos(pose[2])
    s = math.sin(pose[2])
    for a in range(local.shape[0]):
        target[a, 0] = pose[0] + c * local[a, 0] - s * local[a, 1]
        target[a, 1] = pose[1] + s * local[a, 0] + c * local[a, 1]


@njit(cache=True, nogil=True)
def _measure(k: int, x: np.ndarray, contact_dx: np.ndarray, projection: bool, scene: tuple, grasp: tuple,
             scratch: tuple, path: tuple, out: tuple) -> None:
    """Step k's force on the tool (the contacts' -m dx / (dt h) and the grasp's (x - target) / c), contact, the
    tool's penetration and the largest displacement into ``out``."""
    mass, x_ref, reaction_den = scene[0], scene[1], scene[2]
    attach_idx, _local, attach_target, _k, compliance = grasp
    touched, torque_each, sdf, grad = scratch[1], scratch[2], scratch[3], scratch[4]
    _energy_body, force, penetration, displacement, contact, _inverted = out
    fx = 0.0
    fy = 0.0
    n_touched = 0
    if projection:
        n_touched = touched_particles(contact_dx, touched)
        fx, fy = push_reaction(touched[:n_touched], contact_dx, True, mass, reaction_den, x, (0.0, 0.0), torque_each)
    if attach_idx.shape[0]:
        ax, ay = attach_reaction(attach_idx, x, attach_target, compliance, (0.0, 0.0), torque_each)
        fx += ax
        fy += ay
    force[k, 0] = fx
    force[k, 1] = fy
    contact[k] = n_touched > 0
    penetration[k], displacement[k] = penetration_and_displacement(x, x_ref, path[1][k], sdf, grad)


@njit(cache=True, nogil=True)
def fused_quasi_newton_rollout(state: tuple, step: tuple, scene: tuple, solver: tuple, detect: tuple, grasp: tuple,
                               path: tuple, scratch: tuple, out: tuple) -> int:
    """Step the path (module docstring); returns the steps taken: all S, or k when step k diverged (its outputs
    are not written and ``x``, ``v`` hold the state before it).

    ``state`` = (x, v, x_new, v_new) (N, 2): the state, advanced in place, and scratch. ``step`` = (the pred,
    timing and bounds bundles of ``step_kernels.predict_step``, with empty held sets); ``scene`` = (mass (N,),
    x_ref (N, 2) the positions displacements are measured from, dt h [s^2], side_tol [m], the energy's terms
    (``energy.energy_model``), dt [s]); ``solver`` = (mat, factor, ws, elim, solve) of ``quasi_newton_step``;
    ``detect`` = (|g| dt^2 [m], boundary edges (K, 2), use them, the detection's workspace); ``grasp`` =
    (attach_idx (K,), their tool-frame places (K, 2), targets (K, 2) scratch, stiffness [N/m], compliance
    [m/N]); ``path`` = (shapes_m (S + 1, 7) the packed tool with the contact margin at the start pose and at each
    step's, shapes_0 (S, 7) the same without the margin, poses (S, 4) = (x, y, yaw, the tool's travel));
    ``scratch`` = (contact_dx (N, 2), touched (N,) int64, torques (N,), sdf (N,), grad (N, 2), the energy
    terms' six (B,) arrays). Per step out: ``energy_body`` (S, B, 5) (inertial, spring, area, strain,
    attachment: the terms as ``EnergyTerms`` holds them), ``force`` (S, 2) [N], ``penetration`` (S,) [m] (max
    of -sdf), ``displacement`` (S,) [m], ``contact`` (S,) bool, ``inverted`` (S,) int.
    """
    x, v, x_new, v_new = state
    pred, timing, bounds = step
    dt = timing[0]
    mat, factor, ws, elim, solve = solver
    free_fall, boundary_edges, use_edges, det_ws = detect
    attach_idx, local, attach_target, attach_k, compliance = grasp
    shapes_m, _shapes_0, poses = path
    contact_dx, e = scratch[0], scratch[5]
    energy_body, inverted = out[0], out[5]
    cand, edge_rows = det_ws[0], det_ws[3]
    terms, side_tol = scene[4], scene[3]
    for k in range(poses.shape[0]):
        s0 = shapes_m[k]
        s1 = shapes_m[k + 1]
        n_cand, n_edges = projection_candidates(x, v, pred[0], s0, s1, (dt, free_fall, poses[k, 3]),
                                                (boundary_edges, use_edges), det_ws)
        _grasp_targets(poses[k], local, attach_target)
        quasi_newton_step((x, v, x_new, v_new), pred, timing, bounds, mat, factor,
                          (x, cand[:n_cand], s0, s1, contact_dx, edge_rows[:n_edges], side_tol),
                          (attach_idx, attach_target, attach_k), ws, elim, solve)
        finite, n_inverted = finish_step(x_new, v_new, pred[2], terms, dt, (attach_idx, attach_target, compliance), e)
        if not finite:
            return k
        inverted[k] = n_inverted
        for b in range(energy_body.shape[1]):
            energy_body[k, b, 0] = e[0][b]
            energy_body[k, b, 1] = e[1][b]
            energy_body[k, b, 2] = e[2][b]
            energy_body[k, b, 3] = e[3][b]
            energy_body[k, b, 4] = e[5][b]
        _measure(k, x_new, contact_dx, n_cand > 0 or n_edges > 0, scene, grasp, scratch, path, out)
        for i in range(x.shape[0]):
            x[i, 0] = x_new[i, 0]
            x[i, 1] = x_new[i, 1]
            v[i, 0] = v_new[i, 0]
            v[i, 1] = v_new[i, 1]
    return poses.shape[0]


def fused_applies(sim: Simulation, snap: SimSnapshot, jaws: np.ndarray | None) -> bool:
    """Whether :func:`rollout_fused` gives the stepped rollout's numbers for this path (module docstring)."""
    p = sim.params
    solver = sim.solver
    if type(solver) is not QuasiNewtonSolver:  # (a subclass or a wrapper steps its own way)
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
        self.state = (self.x, self.v, np.zeros((n, 2)), np.zeros((n, 2)))
        edges = sim.contact.boundary_edges
        self.detect_ws = (np.empty(n, dtype=np.int32), np.empty(edges.shape[0], dtype=np.int32),
                          np.zeros(n, dtype=bool), np.empty((edges.shape[0], 2), dtype=np.int32))
        self.scratch = (np.zeros((n, 2)), np.empty(n, dtype=np.int64), np.empty(n), np.empty(n), np.empty((n, 2)),
                        tuple(np.zeros(nb) for _ in range(6)))
        self.energy_terms = energy_model(model)


def _path_shapes(sim: Simulation, poses: np.ndarray, start: ToolPose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The path's bundle: the tool packed with the contact margin at the start and at every pose (S + 1, 7), without
    it at every pose (S, 7), and the poses with each step's travel (S, 4)."""
    tool = sim.tool
    margin = float(sim.params.contact_margin)
    n_steps = poses.shape[0]
    shapes_m = np.empty((n_steps + 1, 7))
    shapes_0 = np.empty((n_steps, 7))
    ext = np.empty((n_steps, 4))
    ext[:, :3] = poses[:, :3]
    prev = start
    shapes_m[0] = tool_shape_array(tool, prev, margin)
    rr = tool.rounded_box()[2]
    for k in range(n_steps):
        pose = ToolPose(float(poses[k, 0]), float(poses[k, 1]), float(poses[k, 2]))
        shapes_m[k + 1] = tool_shape_array(tool, pose, margin)
        shapes_0[k] = shapes_m[k + 1]
        shapes_0[k, 6] = rr
        ext[k, 3] = tool_travel(shapes_m[k], shapes_m[k + 1], prev, pose)
        prev = pose
    return shapes_m, shapes_0, ext


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
    dt = float(p.dt)
    n_steps = poses.shape[0]
    grasp = snap.grasp or {}
    if sim.tool.kind == "grasper" and len(grasp.get("idx", ())):
        idx = np.ascontiguousarray(grasp["idx"], dtype=np.int64)
        local = np.ascontiguousarray(grasp["local"], dtype=np.float64).reshape(-1, 2)
        compliance = float(p.grasp_compliance)
    else:
        idx, local, compliance = np.zeros(0, dtype=np.int64), np.zeros((0, 2)), 0.0
    np.copyto(ws.x, snap.particle_q)
    np.copyto(ws.v, snap.particle_qd)
    out = (np.zeros((n_steps, ws.nb, 5)), np.zeros((n_steps, 2)), np.zeros(n_steps), np.zeros(n_steps),
           np.zeros(n_steps, dtype=np.bool_), np.zeros(n_steps, dtype=np.int64))
    use_edges = p.contact_surface == "edges" and sim.contact.boundary_edges.shape[0] > 0
    margin = float(p.contact_margin)
    damp = float(solver.damp_factor(dt))
    step = ((model.particle_inv_mass, solver.inv_mass_eff, solver.x_pred, solver.guess, np.zeros(0, dtype=np.int32),
             np.zeros((0, 2))), (dt, 1, float(p.gravity), damp, damp), solver.bounds)
    scene = (model.particle_mass, np.ascontiguousarray(snap.particle_q if x_ref is None else x_ref),
             dt * (dt / p.substeps), max(margin, EDGE_SIDE_TOL_MIN) if use_edges else 0.0, ws.energy_terms, dt)
    taken = fused_quasi_newton_rollout(
        ws.state, step, scene,
        (ms.mat, ms.step_factor(dt).arrays, ms.ws, ms.elim, solver.solve_options),
        (abs(p.gravity) * dt * dt, sim.contact.boundary_edges, use_edges, ws.detect_ws),
        (idx, local, np.zeros((idx.shape[0], 2)), 1.0 / compliance if compliance > 0.0 else 0.0,
         compliance if compliance > 0.0 else 1.0),
        _path_shapes(sim, poses, start), ws.scratch, out)
    energy_body, force, penetration, displacement, contact, inverted = out
    return {"steps": int(taken), "x": ws.x, "v": ws.v, "energy_body": energy_body, "force": force,
            "penetration": penetration, "displacement": displacement, "contact": contact, "inverted": inverted}


__all__ = ["FusedWorkspace", "fused_applies", "fused_quasi_newton_rollout", "penetration_and_displacement",
           "rollout_fused", "warm_fused"]
