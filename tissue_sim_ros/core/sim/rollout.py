"""Run a Simulation along a tool trajectory and keep the series a planner or a figure needs.

A rollout is what a planner's inner loop, an experiment, a bag replay and a
benchmark all do: step the simulation once per tool pose and record energy
terms, contact and (optionally) positions at chosen steps.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Iterable, Sequence

import numpy as np

from .simulation import Simulation, StepReport


@dataclass
class Rollout:
    """Series of one run, one row per step (row 0 is the first step taken)."""

    steps: np.ndarray
    """Step index of each row (1-based), shape (S,), int64."""
    time: np.ndarray
    """Simulated time at the end of each step [s], shape (S,)."""
    inertial: np.ndarray
    """Inertial energy term per body, shape (S, B)."""
    spring: np.ndarray
    """dt^2-scaled spring energy per body, shape (S, B)."""
    area: np.ndarray
    """dt^2-scaled area energy per body, shape (S, B)."""
    in_contact: np.ndarray
    """Contact flag per body, shape (S, B), bool."""
    d_star: np.ndarray
    """Tool-tissue distance per body [m], shape (S, B)."""
    reaction_force: np.ndarray
    """Reaction on the tool [N], shape (S, 2)."""
    tool_pose: np.ndarray
    """Tool pose (x, y, yaw) per step, shape (S, 3) (NaN where no tool)."""
    step_time: np.ndarray
    """Wall time of each step [s], shape (S,)."""
    diverged: np.ndarray
    """Steps whose solve diverged (state restored), shape (S,), bool."""
    snapshots: dict[int, np.ndarray] = field(default_factory=dict)
    """Particle positions at chosen steps (0 = the initial state), step -> (N, 2)."""
    strain: np.ndarray | None = None
    """dt^2-scaled strain energy per body, shape (S, B) (``material: neo_hookean``; None for constraints)."""
    attach: np.ndarray | None = None
    """dt^2-scaled attachment energy of a grasper's held particles per body, shape (S, B) (None: no grasper)."""
    n_grasped: np.ndarray | None = None
    """Particles the grasper held in each step, shape (S,), int64 (None: no grasper)."""
    jaw: np.ndarray | None = None
    """The jaw angle given with each step [rad], shape (S,) (NaN: none given; None: no grasper)."""

    @property
    def total(self) -> np.ndarray:
        """Total energy per body, shape (S, B)."""
        total = self.inertial + self.spring + self.area
        total = total if self.strain is None else total + self.strain
        return total if self.attach is None else total + self.attach

    @property
    def scene_total(self) -> np.ndarray:
        """Total energy of the scene per step, shape (S,)."""
        return self.total.sum(axis=1)

    def energy_table(self) -> tuple[list[str], np.ndarray]:
        """Column names and a (S, C) array: step, time, total, then per body total/inertial/spring/area(/strain)."""
        names = ["step", "time", "energy_total"]
        cols = [self.steps.astype(float), self.time, self.scene_total]
        for b in range(self.inertial.shape[1]):
            terms = [("total", self.total), ("inertial", self.inertial), ("spring", self.spring), ("area", self.area)]
            extra = [(n, a) for n, a in (("strain", self.strain), ("attach", self.attach)) if a is not None]
            for term, arr in terms + extra:
                names.append(f"body{b}_{term}")
                cols.append(arr[:, b])
        names += ["contact_any", "reaction_fx", "reaction_fy"]
        cols += [self.in_contact.any(axis=1).astype(float), self.reaction_force[:, 0], self.reaction_force[:, 1]]
        if self.n_grasped is not None:
            names += ["jaw", "grasped"]
            cols += [self.jaw, self.n_grasped.astype(float)]
        return names, np.column_stack(cols)

    def write_csv(self, path) -> None:
        """Write :meth:`energy_table` as CSV (full float64 precision)."""
        names, table = self.energy_table()
        np.savetxt(path, table, delimiter=",", header=",".join(names), comments="", fmt="%.17g")


def rollout(sim: Simulation, poses: Iterable[tuple], *,
            snapshot_steps: Sequence[int] = (), on_step: Callable[[StepReport], None] | None = None) -> Rollout:
    """Step ``sim`` once per (pose, twist) and record the series.

    Parameters
    ----------
    sim : Simulation
        Stepped from its current state.
    poses : iterable of (ToolPose or None, ToolTwist or None[, jaw])
        The tool at the end of each step; a None twist is derived from poses. A third item is the grasper's
        jaw angle [rad] (None: the last one; :meth:`Trajectory.steps_with_jaw` yields these).
    snapshot_steps : sequence of int
        Steps whose positions to keep (0 = the state before the first step).
    on_step : callable, optional
        Called with each StepReport (progress bars, live plots, recorders).
    """
    want = set(int(s) for s in snapshot_steps)
    snaps: dict[int, np.ndarray] = {}
    if 0 in want:
        snaps[0] = sim.state.particle_q.copy()
    rows: list[StepReport] = []
    poses_out: list[tuple[float, float, float]] = []
    jaws: list[float] = []
    for item in poses:
        pose, twist = item[0], item[1]
        jaw = item[2] if len(item) > 2 else None
        report = sim.step(pose, twist, jaw=jaw)
        jaws.append(np.nan if jaw is None else float(jaw))
        rows.append(report)
        poses_out.append((pose.x, pose.y, pose.yaw) if pose is not None else (np.nan, np.nan, np.nan))
        if report.step in want:
            snaps[report.step] = sim.state.particle_q.copy()
        if on_step is not None:
            on_step(report)
    nb = sim.model.n_bodies
    grasper = sim.tool is not None and sim.tool.kind == "grasper"
    if not rows:
        z = np.zeros((0, nb))
        return Rollout(np.zeros(0, np.int64), np.zeros(0), z, z.copy(), z.copy(), np.zeros((0, nb), bool),
                       z.copy(), np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, bool), snaps)
    return Rollout(
        steps=np.array([r.step for r in rows], dtype=np.int64),
        time=np.array([r.time for r in rows]),
        inertial=np.array([r.energy.inertial for r in rows]).reshape(len(rows), nb),
        spring=np.array([r.energy.spring for r in rows]).reshape(len(rows), nb),
        area=np.array([r.energy.area for r in rows]).reshape(len(rows), nb),
        in_contact=np.array([r.in_contact for r in rows], dtype=bool).reshape(len(rows), nb),
        d_star=np.array([r.d_star for r in rows]).reshape(len(rows), nb),
        reaction_force=np.array([r.reaction_force for r in rows]).reshape(len(rows), 2),
        tool_pose=np.array(poses_out, dtype=np.float64),
        step_time=np.array([r.timings.get("total", np.nan) for r in rows]),
        diverged=np.array([r.diverged for r in rows], dtype=bool),
        snapshots=snaps,
        strain=np.array([r.energy.strain for r in rows]).reshape(len(rows), nb) if sim.model.is_material else None,
        attach=np.array([r.energy.attach for r in rows]).reshape(len(rows), nb) if grasper else None,
        n_grasped=np.array([r.grasped.size for r in rows], dtype=np.int64) if grasper else None,
        jaw=np.array(jaws) if grasper else None,
    )
