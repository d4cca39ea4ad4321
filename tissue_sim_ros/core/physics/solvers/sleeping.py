"""Sleeping: skip particles far from any contact whose motion has died down.

A wrapper around the method's own solver (:func:`~tissue_sim_ros.core.physics.solvers.Solver`;
the kernels are untouched): a particle sleeps once it has been slower than
``sleep_speed`` and farther than ``wake_radius`` (at rest) from every
particle the contact model touches for ``quiet_steps`` consecutive steps; a
sleeping particle is held where it is (inverse mass 0, velocity 0) and every
constraint whose particles all sleep is dropped from the solve. It wakes as
soon as the contact comes near it or an edge neighbour moves faster than
``sleep_speed``. The solver works on a reduced Model (same particles, the
awake triangles and their edges, sleepers pinned), rebuilt only when the
sleeping set changes.

A scene asks for it with ``sleep_speed`` > 0 (the Simulation's default solver), or::

    sim.use_solver(functools.partial(SleepingSolver, wake_radius=0.15, sleep_speed=1e-3))

The error it costs is measured by ``tissue-sim bench accuracy`` (``accuracy_sleeping.csv``).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ...contact.collision import Contacts
from ...errors import InputError
from ...mesh import TissueMesh, edges_from_triangles
from ..model import Model, State
from . import Solver
from .base import SolveInfo


class SleepingSolver:
    """A solver that skips sleeping particles and the constraints among them: the method's own solver (the
    registry's) on a reduced Model.

    Parameters
    ----------
    model : Model
        The full model.
    wake_radius : float
        Particles within this rest distance [m] of a contact particle stay awake.
    sleep_speed : float
        Speed [m/s] below which a particle counts as quiet.
    quiet_steps : int
        Consecutive quiet, far steps before a particle sleeps.
    """

    def __init__(self, model: Model, wake_radius: float = 0.15, sleep_speed: float = 1e-3,
                 quiet_steps: int = 10) -> None:
        if not (wake_radius >= 0 and sleep_speed >= 0 and quiet_steps >= 1):
            raise InputError(f"sleeping: wake_radius={wake_radius}, sleep_speed={sleep_speed}, "
                             f"quiet_steps={quiet_steps}: expected >= 0, >= 0, >= 1")
        if model.mesh is None:
            raise InputError("sleeping needs a Model built from a mesh (Model.from_mesh)")
        self.model = model
        self.wake_radius = float(wake_radius)
        self.sleep_speed = float(sleep_speed)
        self.quiet_steps = int(quiet_steps)
        n = model.n_particles
        self._quiet = np.zeros(n, dtype=np.int64)
        self.sleeping = np.zeros(n, dtype=bool)
        """Particles asleep this step, shape (N,), bool."""
        self._solver = Solver(model)
        self._reduced = model
        self._last_contact = np.zeros(0, dtype=np.int64)
        edges = np.asarray(model.edge_indices, dtype=np.int64)
        self._edges = edges
        self.min_batch = max(1, int(0.02 * n))
        """Sleepers are added in batches of at least this many (2% of N): each change rebuilds the solver."""
        self.awake_constraint_fraction = 1.0
        """Share of the model's constraints in the last solve."""

    def _neighbour_of_fast(self, fast: np.ndarray) -> np.ndarray:
        """Particles sharing an edge with a fast particle, shape (N,), bool."""
        out = fast.copy()
        e = self._edges
        out[e[fast[e[:, 0]], 1]] = True
        out[e[fast[e[:, 1]], 0]] = True
        return out

    def _near_contact(self, contact_idx: np.ndarray) -> np.ndarray:
        n = self.model.n_particles
        near = np.zeros(n, dtype=bool)
        if contact_idx.size == 0:
            return near
        from scipy.spatial import cKDTree  # noqa: PLC0415

        q0 = np.asarray(self.model.particle_q0)
        dist, _ = cKDTree(q0[contact_idx]).query(q0, k=1, distance_upper_bound=self.wake_radius)
        near[:] = np.isfinite(dist)
        return near

    def _rebuild(self) -> None:
        model = self.model
        tris = np.asarray(model.tri_indices)
        awake_tri = ~self.sleeping[tris].all(axis=1)
        kept = np.ascontiguousarray(tris[awake_tri])
        mesh = model.mesh
        sub = TissueMesh(vertices=mesh.vertices, triangles=kept, edges=edges_from_triangles(kept),
                         boundary=mesh.boundary, body=mesh.body)
        reduced = Model.from_mesh(sub, model.params, pinned=np.asarray(model.particle_pinned) | self.sleeping)
        # the full model's masses: lumped ones (mass_per_area, material) recomputed from the awake triangles
        # alone would make the particles at the sleeping region's border lighter than they are
        mass = np.array(model.particle_mass)
        inv_mass = np.where(reduced.particle_inv_mass > 0, 1.0 / mass, 0.0)
        for arr in (mass, inv_mass):
            arr.setflags(write=False)
        self._reduced = replace(reduced, particle_mass=mass, particle_inv_mass=inv_mass)
        self._solver = Solver(self._reduced)
        total = model.n_edges + model.n_triangles
        self.awake_constraint_fraction = (self._reduced.n_edges + self._reduced.n_triangles) / total if total else 1.0

    def carry_state(self) -> dict:
        """What the next steps read of this solver (for :meth:`Simulation.snapshot`), copied."""
        return {"quiet": self._quiet.copy(), "sleeping": self.sleeping.copy(),
                "last_contact": self._last_contact.copy(), "full": self._reduced is self.model}

    def restore_carry(self, state: dict) -> None:
        """Back to a :meth:`carry_state`; the reduced solver is rebuilt only when the sleeping set differs."""
        full = bool(state["full"])
        same = full == (self._reduced is self.model) and np.array_equal(state["sleeping"], self.sleeping)
        self._quiet = np.array(state["quiet"], dtype=np.int64)
        self._last_contact = np.array(state["last_contact"], dtype=np.int64)
        self.sleeping = np.array(state["sleeping"], dtype=bool)
        if same:
            return
        if full:
            self._reduced = self.model
            self._solver = Solver(self.model)
            self.awake_constraint_fraction = 1.0
        else:
            self._rebuild()

    def step(self, state_in: State, state_out: State, contacts: Contacts, dt: float) -> SolveInfo:
        """As the method's own ``step``, with sleepers held and their constraints skipped."""
        contact_idx = np.union1d(np.asarray(contacts.held_idx, dtype=np.int64),
                                 np.asarray(contacts.candidates, dtype=np.int64))
        contact_idx = np.union1d(contact_idx, self._last_contact)
        # a grasper's held particles stay awake (core/physics/attach.py)
        contact_idx = np.union1d(contact_idx, np.asarray(getattr(contacts, "attach_idx", contact_idx[:0]),
                                                         dtype=np.int64))
        near = self._near_contact(contact_idx)
        speed = np.sqrt((state_in.particle_qd ** 2).sum(axis=1))
        moving = self._neighbour_of_fast(speed >= self.sleep_speed)
        quiet = ~(near | moving)
        self._quiet = np.where(quiet, self._quiet + 1, 0)
        ready = self._quiet >= self.quiet_steps
        # hysteresis: a sleeper wakes for the contact, or for a neighbour 10x faster than the sleep speed,
        # so the border of a sleeping region does not flicker (every change rebuilds the solver)
        shaken = self._neighbour_of_fast(speed >= 10.0 * self.sleep_speed)
        ready |= self.sleeping & ~(near | shaken)
        self._quiet[ready & self.sleeping] = np.maximum(self._quiet[ready & self.sleeping], self.quiet_steps)
        woken = self.sleeping & ~ready
        new = ready & ~self.sleeping
        if woken.any() or np.count_nonzero(new) >= self.min_batch:
            # wake at once (a sleeper must not miss the tool); put to sleep in batches (rebuilds cost)
            self.sleeping = ready
            self._rebuild()
        if self.sleeping.any():
            state_in.particle_qd[self.sleeping] = 0.0
        info = self._solver.step(state_in, state_out, contacts, dt)
        self._last_contact = np.asarray(contacts.touched, dtype=np.int64)
        return info
