"""Insertion planning from a snapshot: sweep approach angles and speeds, keep the cheapest that reaches the target.

The question a planner beside the robot asks the running simulator: from the
tissue as it is now, which straight insertion from near ``entry`` to
``target`` costs least? :func:`plan_insertion` answers it without ROS (the
node's ``~/plan_insertion`` service converts messages and calls it):

* the target must lie inside the tissue (in the snapshot's deformed mesh) and
  the entry point outside it; the insertion distance is |target - entry|;
* candidates: every approach angle ``atan2(target - entry) + offset`` for the
  offsets given, at every speed; each one's tip starts at ``target - distance
  (cos a, sin a)`` and moves straight to the target (the tool along its motion,
  tip first), placed at its start without a sweep;
* a candidate whose tool at its start overlaps the tissue (a particle inside
  the tool, or the tool crossing a triangle, as a thin tool lying across the
  tissue does between its particles: :func:`tool_overlaps`), or that needs
  more than ``max_steps`` steps, is not rolled out (its reason is kept);
* the target is also a point of the tissue, which moves as the tool pushes
  the tissue: it is followed as the barycentric point of the snapshot's
  triangle that holds it, and every candidate reports ``target_error``, the
  distance from its tip at the last step (at the commanded target) to where
  that point went. With ``track_target`` the tolerance applies to it: a
  candidate reaches the target only if the tissue's point ends within
  ``tolerance`` of the tip. (A tool that pushes rather than cuts moves an
  inner target ahead of it: with projection contact by about the target's
  depth, with the paper's rule by up to its radius r, so on the default scene
  tracked plans need a tolerance of that size.) Without it the tip reaches the
  commanded target by construction and a candidate is feasible when it was
  rolled out and stayed finite;
* of the feasible candidates, the cheapest by :mod:`~tissue_sim_ros.core.sim.batch`'s
  cost (energy added over the tool-free baseline) is the plan.

A request that cannot be answered returns an :class:`InsertionPlan` with no
best candidate and a ``reason`` naming the value and what was expected.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from ..contact.collision import ContactModel
from ..contact.tool import StraightInsertion, ToolPose
from ..sim.batch import BatchResult, BatchScene, CandidateResult, RolloutPool, ToolPath, rollout_batch
from ..sim.snapshot import SimSnapshot


@dataclass(frozen=True)
class InsertionRequest:
    """What to plan: the tip's entry point and target [m], the tolerance [m], the sweep."""

    entry: tuple[float, float]
    target: tuple[float, float]
    tolerance: float
    angle_offsets_deg: Sequence[float] = (-20.0, -10.0, 0.0, 10.0, 20.0)
    speeds: Sequence[float] = (0.1, 0.2)
    """Tip speeds [m/s]."""
    max_steps: int = 500
    track_target: bool = False
    """Apply the tolerance to the tissue's target point, moved by the insertion (see the module docstring)."""


@dataclass
class PlanCandidate:
    """One approach: its angle, speed, entry and path, and what its rollout did (None: not rolled out)."""

    angle: float
    """Direction of the tip's motion [rad] (the tool's yaw)."""
    angle_offset_deg: float
    speed: float
    """Tip speed [m/s]."""
    entry: tuple[float, float]
    path: ToolPath | None
    result: CandidateResult | None = None
    target_error: float = math.inf
    """Distance [m] from the tip at the last step to where the target point of the tissue went."""
    feasible: bool = False
    reason: str = ""
    """Why the candidate was not rolled out or does not reach the target (empty: it does)."""

    @property
    def cost(self) -> float:
        return math.nan if self.result is None else self.result.cost


@dataclass
class InsertionPlan:
    """The candidates, the cheapest feasible one (``best``, or None with a ``reason``) and the batch."""

    request: InsertionRequest
    candidates: list[PlanCandidate] = field(default_factory=list)
    best: int | None = None
    reason: str = ""
    batch: BatchResult | None = None
    target_triangle: int = -1

    @property
    def ok(self) -> bool:
        return self.best is not None


def locate(x: np.ndarray, tris: np.ndarray, point: tuple[float, float]) -> tuple[int, np.ndarray] | None:
    """The triangle of positions ``x`` (N, 2) holding ``point`` and its barycentric coordinates, or None outside.

    Barycentric coordinates l_i = signed area of the sub-triangle opposite vertex i / signed area; inside when
    every l_i >= 0 (a point on an edge counts as inside; the lowest triangle index wins).
    """
    if tris.shape[0] == 0:
        return None
    a, b, c = x[tris[:, 0]], x[tris[:, 1]], x[tris[:, 2]]
    px, py = point

    def cross(u: np.ndarray, v: np.ndarray, wx: float, wy: float) -> np.ndarray:
        return (v[:, 0] - u[:, 0]) * (wy - u[:, 1]) - (v[:, 1] - u[:, 1]) * (wx - u[:, 0])

    area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        l0 = cross(b, c, px, py) / area2
        l1 = cross(c, a, px, py) / area2
    l2 = 1.0 - l0 - l1
    inside = np.flatnonzero((area2 != 0) & (l0 >= 0) & (l1 >= 0) & (l2 >= 0))
    if inside.size == 0:
        return None
    t = int(inside[0])
    return t, np.array([l0[t], l1[t], l2[t]])


def tool_overlaps(contact: ContactModel, x: np.ndarray, pose: ToolPose) -> bool:
    """True when the tool at ``pose`` overlaps the tissue at positions ``x`` (N, 2) [m].

    The contact model's own query (:meth:`~tissue_sim_ros.core.contact.collision.ContactModel.distances` with reach 0):
    a particle inside the tool's shape, or python-fcl finding the tool's shape through a triangle (a tool 5 mm
    wide lying across the tissue can cross triangles without holding any of their particles).
    """
    return any(d.overlap or d.d_star <= 0.0 for d in contact.distances(x, pose, 0.0))


def candidates_for(scene: BatchScene, snap: SimSnapshot, req: InsertionRequest) -> list[PlanCandidate]:
    """The sweep's candidates, each with its path or the reason it is not rolled out."""
    dt = scene.model.params.dt
    tx, ty = req.target
    ex, ey = req.entry
    distance = math.hypot(tx - ex, ty - ey)
    base = math.atan2(ty - ey, tx - ex)
    x = np.ascontiguousarray(snap.particle_q)
    contact = ContactModel(scene.model, scene.tool)
    overlapping: dict[float, bool] = {}  # per angle: the entry pose does not depend on the speed
    out: list[PlanCandidate] = []
    for speed in req.speeds:
        for off in req.angle_offsets_deg:
            a = base + math.radians(off)
            entry = (tx - distance * math.cos(a), ty - distance * math.sin(a))
            traj = StraightInsertion.from_tool(scene.tool, entry, (tx, ty), float(speed))
            cand = PlanCandidate(a, float(off), float(speed), entry, None)
            out.append(cand)
            n = traj.n_steps(dt)
            if n > req.max_steps:
                cand.reason = f"{n} steps at {speed} m/s: more than plan_max_steps={req.max_steps}"
                continue
            start = traj.pose_at(0.0)
            if x.shape[0]:
                if off not in overlapping:
                    overlapping[off] = tool_overlaps(contact, x, start)
                if overlapping[off]:
                    cand.reason = (f"the tool at its entry ({entry[0]:.3f}, {entry[1]:.3f}) m, "
                                   f"{math.degrees(a):+.1f} deg, overlaps the tissue")
                    continue
            cand.path = ToolPath.from_trajectory(traj, dt)
    return out


def _check_request(snap: SimSnapshot, tris: np.ndarray, req: InsertionRequest) -> tuple[str, int, np.ndarray | None]:
    """(reason, target triangle, barycentric coordinates); reason is empty when the request can be planned."""
    values = (*req.entry, *req.target, req.tolerance)
    if not all(math.isfinite(v) for v in values):
        return "the request has a NaN/inf coordinate or tolerance: expected finite values", -1, None
    if not req.tolerance > 0:
        return f"tolerance {req.tolerance} m: expected > 0", -1, None
    if not req.speeds or not req.angle_offsets_deg:
        return "the sweep is empty: expected at least one speed and one angle", -1, None
    if any(not (math.isfinite(s) and s > 0) for s in req.speeds):
        return f"speeds {list(req.speeds)} m/s: expected speeds > 0", -1, None
    if math.hypot(req.target[0] - req.entry[0], req.target[1] - req.entry[1]) == 0.0:
        return "start and goal are the same point: expected an entry point away from the target", -1, None
    x = snap.particle_q
    hit = locate(x, tris, req.target)
    if hit is None:
        return (f"goal ({req.target[0]:.4f}, {req.target[1]:.4f}) m is outside the tissue: expected a target "
                "inside it"), -1, None
    if locate(x, tris, req.entry) is not None:
        return (f"start ({req.entry[0]:.4f}, {req.entry[1]:.4f}) m is inside the tissue: expected an entry point "
                "outside it"), -1, None
    return "", hit[0], hit[1]


def plan_insertion(snap: SimSnapshot, scene: BatchScene, req: InsertionRequest,
                   pool: RolloutPool | None = None) -> InsertionPlan:
    """Roll the sweep out from ``snap`` (on ``pool``, or serially) and pick the cheapest candidate within tolerance."""
    tris = np.asarray(scene.model.tri_indices)
    plan = InsertionPlan(req)
    reason, tri, bary = _check_request(snap, tris, req)
    if reason:
        plan.reason = reason
        return plan
    plan.target_triangle = tri
    plan.candidates = candidates_for(scene, snap, req)
    todo = [c for c in plan.candidates if c.path is not None]
    if not todo:
        plan.reason = f"no candidate can be rolled out ({plan.candidates[0].reason})" if plan.candidates else \
            "no candidate"
        return plan
    batch = rollout_batch(snap, [c.path for c in todo], scene=scene, pool=pool, final_state=True)
    plan.batch = batch
    corners = tris[tri]
    for cand, res in zip(todo, batch.candidates):
        cand.result = res
        moved = bary @ res.final_state.particle_q[corners]
        cand.target_error = float(math.hypot(req.target[0] - moved[0], req.target[1] - moved[1]))
        if not res.finite:
            cand.reason = "the rollout diverged or its energy is not finite"
        elif req.track_target and cand.target_error > req.tolerance:
            cand.reason = (f"the target moved {cand.target_error * 1e3:.1f} mm from the tip: more than the tolerance "
                           f"{req.tolerance * 1e3:.1f} mm")
        else:
            cand.feasible = True
        res.final_state = None  # not needed past here; keep the plan small
    feasible = [i for i, c in enumerate(plan.candidates) if c.feasible]
    if not feasible:
        closest = min(todo, key=lambda c: c.target_error)
        plan.reason = (f"no candidate within tolerance {req.tolerance * 1e3:.1f} mm of the target (closest: the "
                       f"target moved {closest.target_error * 1e3:.1f} mm from the tip at "
                       f"{math.degrees(closest.angle):+.1f} deg, {closest.speed} m/s)" if req.track_target else
                       f"no candidate reached the target: {todo[0].reason}")
        return plan
    plan.best = min(feasible, key=lambda i: plan.candidates[i].cost)
    return plan
