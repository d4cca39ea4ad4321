"""The material's default step (``method: ipc``): the minimiser of the incremental potential with contact barriers,
intersection- and inversion-free by construction (Incremental Potential Contact, Li et al. 2020, in 2D).

:class:`IPCSolver` owns the step's bundles (``core/physics/ipc_energy.py``, ``ipc_hessian.py``, ``ipc.py``):
the boundary (vertices, edges and the triangle each edge bounds), the Hessian's pattern and its LDL^T factor
(kept across steps and refreshed when a step needs more than a few iterations: its state is carried in
snapshots, so a rollout from one is the live run's), the pair buffers, the L-BFGS history. Each step is one
compiled call (:func:`~tissue_sim_ros.core.physics.ipc_step.ipc_step`) and the contact's report another.

Parameters (``core/physics/params.py``): ``contact_dhat`` (0: 1 % of the 10th percentile of the boundary
edges' lengths), ``contact_stiffness`` kappa at the start (0: E x thickness; raised tenfold and the step solved again when it
ends with a pair closer than ``KAPPA_RAISE_GAP`` dhat, kept for the steps that follow), ``tool_stiffness`` (0: 1e5 kappa; the tool's
turn and jaw are held by it times the tool's reach squared), ``contact_bodies``, ``solve_tolerance`` and
``iterations``; ``friction`` (tool and tissue), ``friction_tissue`` and ``friction_velocity`` (the lagged friction of
``core/physics/ipc_friction.py``).
"""
from __future__ import annotations

import math

import numpy as np

from ...contact.collider import TOOL_DOFS, ToolGeometry
from ...contact.collision import Contacts, boundary_edges_ccw
from ...errors import InputError
from ..ipc_friction import friction_workspace
from ..ipc_hessian import element_slots, hessian_pattern, slot_tables
from ..ipc_step import contact_report, ipc_step
from ..kernels import constraint_residual
from ..ldlt import LDLTPattern, make_workspace
from ..model import Model, State
from .base import SolveInfo, SolverBase
from .ordering import solve_order
from .quasi_newton import FLOOR_REL, MaterialSolve

#: L-BFGS pairs kept.
HISTORY = 5
#: A factor is refreshed when a step takes more iterations than this (and within a step after as many).
REFRESH_AFTER = 4
#: The element's inversion barrier acts below this area ratio J.
J_HAT = 0.2
#: dhat: this fraction of the short boundary edges' length, when not given.
DHAT_FRACTION = 0.01
#: The barrier's stiffness kappa: this multiple of E x thickness, when not given.
KAPPA_FACTOR = 1.0
#: The barrier is stiffened (kappa times KAPPA_GROWTH, the step solved again from its start) when a step ends with
#: a pair closer than this fraction of dhat: its barrier then holds a load far above the one kappa was sized for,
#: and the solve, pressed into the barrier's stiff end, creeps (IPC's adaptive stiffness, Li et al. 2020, sec. 4.3;
#: a 1 MPa strip pressed a third deep in one 20 ms step then held: with kappa = E x thickness the held steps
#: stopped short, the gap fell tenfold per step and the reported reaction rose to 1e8 N where the load is 24 N).
KAPPA_RAISE_GAP = 0.02
#: The factor of one raise.
KAPPA_GROWTH = 10.0
#: kappa is raised to at most this multiple of its start (per step at most log10 of it times).
KAPPA_MAX = 1e4
#: The tool's spring: this multiple of E x thickness, when not given.
TOOL_STIFFNESS_FACTOR = 1e5
#: The tool's command is approached in parts of at most this fraction of the boundary's median edge.
COMMAND_PART = 0.1
#: Parts at most.
MAX_PARTS = 64
#: Candidate tissue pairs a boundary vertex may have at most (buffer size).
PAIRS_PER_VERTEX = 32
#: A tool's outline has at most this many vertices and edges (a capsule: 32 and 32).
MAX_CORE = 64


def edge_neighbours(tris: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each boundary edge (K, 2), the vertices that share a triangle with either of its ends (the ends and
    their rings), as (pointers (K + 1,), vertices) int64: a pair of the edge with one of them is the mesh's own
    shape (a corner folding about a pin, an edge squeezed along a line), which the element's inversion barrier
    keeps; self-contact is between parts of the surface farther apart than that."""
    ring: dict[int, set[int]] = {}
    for t in np.asarray(tris, dtype=np.int64):
        for v in t:
            ring.setdefault(int(v), set()).update(int(u) for u in t)
    ptr = [0]
    idx: list[int] = []
    for a, b in np.asarray(edges, dtype=np.int64):
        near = sorted(ring.get(int(a), {int(a)}) | ring.get(int(b), {int(b)}))
        idx += near
        ptr.append(len(idx))
    return np.array(ptr, dtype=np.int64), np.array(idx, dtype=np.int64)


def default_dhat(q0: np.ndarray, edges: np.ndarray) -> float:
    """A tenth of the 10th percentile of the boundary edges' rest lengths [m] (1 mm without edges)."""
    if edges.shape[0] == 0:
        return 1e-3
    lengths = np.hypot(*(q0[edges[:, 1]] - q0[edges[:, 0]]).T)
    return DHAT_FRACTION * float(np.percentile(lengths, 10))


class IPCSolver(SolverBase):
    """Steps the material as the minimiser of its incremental potential with contact barriers (module docstring).
    The tool comes with each step (``contacts.tool_collider``); without one, the bodies and the lines are the
    only contacts."""

    def __init__(self, model: Model) -> None:
        super().__init__(model)
        p = self.params
        n = model.n_particles
        q0 = np.asarray(model.particle_q0, dtype=np.float64)
        so = solve_order(model, "mesh", False, False)
        self.edges, self.rest, self.tris, self.area0 = so.edges, so.rest, so.tris, so.area0
        elastic = np.ascontiguousarray(model.tri_elastic, dtype=np.float64)
        self.elastic = np.ascontiguousarray(elastic[so.tri_perm]) if so.tri_perm is not None else elastic
        self.material_solve = MaterialSolve(model, self.tris, self.elastic)
        edges = np.ascontiguousarray(boundary_edges_ccw(model.tri_indices), dtype=np.int32)
        self.boundary_edges = edges
        bverts = np.unique(edges).astype(np.int32) if edges.shape[0] else np.zeros(0, np.int32)
        roller = np.zeros(n, dtype=np.bool_)
        roller[self.material_solve.rest_lines[0]] = True
        self.dhat = float(p.contact_dhat) if p.contact_dhat > 0 else default_dhat(q0, edges)
        self.kappa = (float(p.contact_stiffness) if p.contact_stiffness > 0
                      else KAPPA_FACTOR * float(p.young_modulus * p.thickness))
        self.tool_stiffness = (float(p.tool_stiffness) if p.tool_stiffness > 0
                               else TOOL_STIFFNESS_FACTOR * float(p.young_modulus * p.thickness))
        self._model = (np.ascontiguousarray(model.particle_mass, dtype=np.float64), self.tris, self.elastic, J_HAT,
                       bverts, edges, edge_neighbours(model.tri_indices, edges), roller, bool(p.contact_bodies))
        self.kappa0 = self.kappa
        """kappa at the start; :attr:`kappa` is raised from it where a step ends too deep inside dhat."""
        self._contact = (self.dhat, self.dhat, self.kappa, (float(p.boundary_y_top), float(p.boundary_y_bottom),
                                                           float(p.wall_y_bottom), float(p.wall_y_top)))
        size = float(np.hypot(*np.ptp(q0, axis=0))) if n else 0.0
        cell = float(np.median(np.hypot(*(q0[edges[:, 1]] - q0[edges[:, 0]]).T))) if edges.shape[0] else 1.0
        self._opts = (float(p.solve_tolerance), int(p.iterations), max(FLOOR_REL * size, 1e-12), REFRESH_AFTER,
                      max(cell, 2.0 * self.dhat))
        self.residual_set = (self.edges, self.rest, self.tris, self.area0)
        self._no_tool = tool_geometry_none()
        self._make_workspaces(n, bverts.shape[0], edges.shape[0])

    def _make_workspaces(self, n: int, n_bverts: int, n_bedges: int) -> None:
        from ...contact.broadphase import tissue_pair_workspace  # noqa: PLC0415

        rows, cols, adjacency = hessian_pattern(n, self.model.tri_indices)
        self.pattern = LDLTPattern(2 * n + TOOL_DOFS, rows, cols)
        adj_slot, tool_slot = slot_tables(n, self.pattern.slot, adjacency)
        n_dof = 2 * n + TOOL_DOFS
        self._lin = (self.pattern.arrays, np.zeros(self.pattern.nnz_a), np.zeros(self.pattern.l_size),
                     np.zeros(n_dof), make_workspace(self.pattern), np.zeros(2 * n_dof), adjacency[0], adjacency[1],
                     adj_slot, tool_slot, np.zeros((self.tris.shape[0], 21), dtype=np.int64))
        element_slots(self.tris, self._lin, self._lin[10])
        self._pairs = (np.zeros((PAIRS_PER_VERTEX * n_bverts + 64, 2), np.int32),
                       np.zeros((MAX_CORE * max(n_bverts, 1), 2), np.int32),
                       np.zeros((MAX_CORE * max(n_bedges, 1), 2), np.int32), np.zeros(3, np.int64))
        self._ws = (np.zeros((HISTORY, n_dof)), np.zeros((HISTORY, n_dof)), np.zeros(HISTORY), np.zeros(HISTORY),
                    np.zeros(n_dof), np.zeros(n_dof), np.zeros(n_dof), np.zeros(n_dof), np.zeros((n, 2)),
                    np.zeros((MAX_CORE, 2)), tissue_pair_workspace(n_bedges), np.zeros(6), np.zeros(n_dof))
        n_pairs = sum(b.shape[0] for b in self._pairs[:3])
        self._friction = friction_workspace(n, n_pairs)
        p = self.params
        self._friction[5][:2] = (float(p.friction), float(p.friction_tissue))
        self._scratch = (np.zeros((MAX_CORE, 2)), np.zeros((MAX_CORE, 2, TOOL_DOFS)), np.zeros((0, 2)))
        self._free = np.zeros(2 * n)
        self.factor_state = np.zeros(3)
        """(a factor is held, the last step's iterations, the dt it was made for): carried in snapshots."""
        self._q = np.zeros(TOOL_DOFS)
        self._body = np.ascontiguousarray(self.model.particle_body, dtype=np.int64)
        self._report = np.zeros((self.model.n_bodies, 6))
        self._touched = np.zeros(n, dtype=np.int64)
        self._force = np.zeros(TOOL_DOFS)
        self._q_cmd = np.zeros(TOOL_DOFS)

    @property
    def n_projections_per_step(self) -> int:
        """Element evaluations in one iteration (a step takes ``solve_iterations`` of them)."""
        return self.tris.shape[0] * self.params.iterations

    def carry_state(self) -> dict:
        """The lagged factor and its state, and the barrier's stiffness (for :meth:`Simulation.snapshot`), copied."""
        return {"factor_state": self.factor_state.copy(), "l": self._lin[2].copy(), "d": self._lin[3].copy(),
                "kappa": self.kappa}

    def restore_carry(self, state: dict) -> None:
        """Back to a :meth:`carry_state`: the next step is the one that followed it, bit for bit."""
        if not state:
            self.factor_state[:] = 0.0
            self._set_kappa(self.kappa0)
            return
        self._set_kappa(float(state.get("kappa", self.kappa0)))
        np.copyto(self.factor_state, state["factor_state"])
        np.copyto(self._lin[2], state["l"])
        np.copyto(self._lin[3], state["d"])

    def reset_carry(self) -> None:
        """As built (for :meth:`Simulation.reset`): no factor held, kappa at its start."""
        self.restore_carry({})

    def _set_kappa(self, kappa: float) -> None:
        """The barrier's stiffness from now on (the contact bundle rebuilt)."""
        self.kappa = float(kappa)
        c = self._contact
        self._contact = (c[0], c[1], self.kappa, c[3])

    def _tool_bundles(self, collider) -> tuple[tuple, tuple, np.ndarray, np.ndarray, np.ndarray]:
        """(the tool's bundle, the solve's options, the start q, the command q, where the solve starts it) of this
        step's collider."""
        geom = collider.geometry if collider is not None else self._no_tool
        reach, jaw_reach = max(geom.reach, 1e-3), max(geom.jaw_reach, 1e-3)
        k = self.tool_stiffness
        servo = np.array([k, k, k * reach * reach, k * jaw_reach * jaw_reach])
        opts = self._opts + (float(reach), float(jaw_reach))
        if collider is None:
            return (geom.arrays, servo, False), opts, np.zeros(TOOL_DOFS), np.zeros(TOOL_DOFS), np.zeros(TOOL_DOFS)
        return ((geom.arrays, servo, True), opts, np.ascontiguousarray(collider.q0, dtype=np.float64),
                np.ascontiguousarray(collider.q1, dtype=np.float64),
                np.ascontiguousarray(collider.q_guess, dtype=np.float64))

    def _step_bundle(self, contacts: Contacts, q_cmd: np.ndarray, dt: float) -> tuple:
        """The step's bundle (x*, free, the command, dt^2, the grasp), its scratch of targets sized."""
        idx = np.ascontiguousarray(getattr(contacts, "attach_idx", np.zeros(0, np.int64)), dtype=np.int64)
        local = np.ascontiguousarray(getattr(contacts, "attach_local", np.zeros((0, 2))), dtype=np.float64)
        local = local.reshape(-1, 2)
        k_att = float(getattr(contacts, "attach_stiffness", 0.0))
        if local.shape[0] != idx.shape[0]:
            idx, local, k_att = idx[:0], np.zeros((0, 2)), 0.0
        if self._scratch[2].shape[0] != idx.shape[0]:
            self._scratch = (self._scratch[0], self._scratch[1], np.zeros((idx.shape[0], 2)))
        self._friction[5][2] = float(self.params.friction_velocity) * dt
        return (self.x_pred, self._free, q_cmd, dt * dt, (idx, local, k_att), self._friction)

    @staticmethod
    def _parts(q0: np.ndarray, q1: np.ndarray, opts: tuple) -> int:
        """In how many parts the step approaches the tool's command: one per ``COMMAND_PART`` of the boundary's
        median edge (``opts[4]``) its farthest point moves (1 for a tool moving less)."""
        d = q1 - q0
        move = math.hypot(d[0], d[1]) + abs(d[2]) * opts[5] + 0.5 * abs(d[3]) * opts[6]
        return max(1, min(MAX_PARTS, int(math.ceil(move / (COMMAND_PART * opts[4]) - 1e-9))))

    def step(self, state_in: State, state_out: State, contacts: Contacts, dt: float) -> SolveInfo:
        """One step as the minimiser of its incremental potential with contact barriers (module docstring)."""
        step = self.check_step(state_in, state_out, contacts, dt)
        collider = getattr(contacts, "tool_collider", None)
        tool, opts, q_start, q_cmd, q_guess = self._tool_bundles(collider)
        n_sub = self._parts(q_start, q_cmd, opts) if collider is not None else 1
        if n_sub > 1:
            q_guess = q_start + (q_guess - q_start) / n_sub
        np.copyto(self._q_cmd, q_cmd)
        sb = self._step_bundle(contacts, self._q_cmd, dt)
        damp = self.damp_factor(dt)
        x = state_out.particle_q
        its = 0.0
        path = (np.empty((n_sub + 1, x.shape[0], 2)), np.empty((n_sub + 1, TOOL_DOFS)))
        while True:
            ipc_step((state_in.particle_q, state_in.particle_qd, x, state_out.particle_qd),
                     (self.model.particle_inv_mass, self.inv_mass_eff, self.x_pred, self.material_solve.guess,
                      step.held_idx, step.held_dx), (dt, 1, self.params.gravity, damp, damp), self.bounds,
                     self._model, self._contact, tool, sb, self._pairs, self._scratch, self._lin, self._ws, opts,
                     (q_start, self._q, q_guess, q_cmd, n_sub, *path), self.factor_state)
            contact_report(x, self._q, self._model, self._contact, tool, sb, self._pairs, self._scratch,
                           self._body, self._report, self._touched, self._force)
            its += self._ws[11][0]
            gap = float(self._report[:, [1, 5]].min()) if self._report.shape[0] else math.inf
            if not (gap < KAPPA_RAISE_GAP * self.dhat and self.kappa * KAPPA_GROWTH <= KAPPA_MAX * self.kappa0):
                break
            # too deep inside dhat: a stiffer barrier, the step again from its start with a fresh factor
            self._set_kappa(self.kappa * KAPPA_GROWTH)
            self.factor_state[0] = 0.0
        out = self._ws[11]
        out[0] = its
        if int(out[4]):
            raise InputError("barrier contact: more candidate pairs than the buffers hold (is contact_dhat "
                             f"{self.dhat:g} m far larger than the mesh's edges?)")
        contacts.touched = np.flatnonzero(self._touched).astype(np.int32)
        if sb[4][0].shape[0]:
            contacts.attach_target = self._scratch[2].copy()
        info = SolveInfo(x_pred=self.x_pred, contact_dx=None,
                         residual=float(constraint_residual(x, *self.residual_set, self.signed)),
                         solve_iterations=int(out[0]), solve_residual=float(out[1]),
                         solve_converged=bool(out[1] <= self.params.solve_tolerance),
                         contact_energy=self._report[:, 0].copy(), contact_gap=self._report[:, 1].copy(),
                         in_contact=self._report[:, 2] > 0.0, refactored=bool(out[2]),
                         contact_force=self._report[:, 3:5].copy())
        if collider is not None:
            info.tool_q = self._q.copy()
            info.tool_path = path
            info.tool_force = self._force.copy()
            lag = self._q - q_cmd
            info.tool_lag = (float(math.hypot(lag[0], lag[1])), float(abs(lag[2])))
        return info


def tool_geometry_none() -> ToolGeometry:
    """A tool with no core (no tool in the scene)."""
    return ToolGeometry(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros((0, 2), np.int32), np.zeros(0),
                        np.zeros(0), 0.0, 0.0)
