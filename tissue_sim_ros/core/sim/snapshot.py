"""Snapshots of a Simulation: everything a step reads that an earlier step wrote, as plain data.

A planner asks "from the tissue as it is now, which motion costs least?". It
takes a :class:`SimSnapshot` of the running simulation (``sim.snapshot()``),
restores it into scratch simulations of the same scene (``sim.restore(snap)``)
and rolls candidates out from there; stepping a restored simulation gives the
bit-identical continuation of the original (``test/test_batch.py``).

What carries over between steps, and so is in a snapshot:

* the State (positions, velocities) and the last good State (restored when a
  solve diverges);
* time, step count and the tool pose of the last step (the next step's twist
  is derived from it and projection contact sweeps the tool from it);
* solver state that outlives a step: none for :class:`~tissue_sim_ros.core.physics.solvers.Solver`
  (its multipliers are reset every substep, its other workspaces are written
  before they are read); the sleeping set and quiet counters of
  :class:`~tissue_sim_ros.core.physics.sleeping.SleepingSolver`. A solver exposes such
  state through ``carry_state() -> dict`` and ``restore_carry(dict)``;
* contact-model state that outlives a step: none (:class:`~tissue_sim_ros.core.contact.collision.ContactModel`
  rebuilds its BVHs and poses its tool every step); the same two hooks apply.

A snapshot is a plain dataclass of NumPy arrays and numbers: picklable, so
it goes to worker processes and Ray tasks as is.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..contact.tool import ToolPose
from ..physics.model import Model


def scene_key(model: Model) -> str:
    """Fingerprint of a scene's topology and rest shape (not its parameters): a snapshot fits scenes with this key."""
    h = hashlib.blake2b(digest_size=16)
    for arr in (model.particle_q0, model.tri_indices, model.edge_indices, model.particle_inv_mass == 0.0):
        a = np.ascontiguousarray(arr)
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


@dataclass
class SimSnapshot:
    """The state of a Simulation between two steps (see the module docstring for what is in it)."""

    scene: str
    """:func:`scene_key` of the model it was taken from."""
    particle_q: np.ndarray
    """Particle positions [m], shape (N, 2), float64."""
    particle_qd: np.ndarray
    """Particle velocities [m/s], shape (N, 2), float64."""
    last_good_q: np.ndarray
    """Positions of the last step that did not diverge [m], shape (N, 2)."""
    last_good_qd: np.ndarray
    """Velocities of the last step that did not diverge [m/s], shape (N, 2)."""
    step_count: int
    """Steps taken."""
    time: float
    """Simulated time [s]."""
    tool_pose: ToolPose | None
    """Tool pose of the last step with a tool (None: no tool yet)."""
    solver: dict[str, Any] = field(default_factory=dict)
    """The solver's ``carry_state()`` (empty when nothing carries over)."""
    contact: dict[str, Any] = field(default_factory=dict)
    """The contact model's ``carry_state()`` (empty when nothing carries over)."""
    grasp: dict[str, Any] = field(default_factory=dict)
    """The grasper jaw's ``carry_state()`` (:class:`~.grasp.Grasp`: jaw angle, closed, held particles); empty: open."""
    tool_jaw: float | None = None
    """Barrier contact: the jaw angle the tool was left at [rad] (None: not yet)."""
    tool_command: ToolPose | None = None
    """Barrier contact: the last commanded pose (``tool_pose`` is where the tool got to)."""
    jaw_command: float | None = None
    """Barrier contact: the last commanded jaw angle [rad]."""

    @property
    def n_particles(self) -> int:
        return int(self.particle_q.shape[0])


def carry_state(obj: Any) -> dict[str, Any]:
    """``obj.carry_state()`` copied, or {} for an object with nothing to carry."""
    fn = getattr(obj, "carry_state", None)
    return {} if fn is None else fn()


def restore_carry(obj: Any, state: dict[str, Any]) -> None:
    """Give ``obj`` its carried state back (a no-op for objects without any)."""
    fn = getattr(obj, "restore_carry", None)
    if fn is not None:
        fn(state)
