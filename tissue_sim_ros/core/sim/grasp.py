"""The grasper's jaw: what it holds, when it closes and opens (issue 30).

The jaw angle [rad] comes with a step (``Simulation.step(pose, twist, jaw=...)``; None keeps the last one). The
jaw has two states with a hysteresis: it *closes* when the angle falls below ``grasp_close_angle`` and *opens*
when it rises above ``grasp_open_angle`` (> close). At the step in which it closes, with the tool at the pose
where that step starts, every free particle (inverse mass > 0) within ``grasp_radius`` of the tip (the grasper's
pose) is grasped and its coordinates in the tool's frame are stored; a jaw that closes on nothing holds nothing,
and stays empty until it opens and closes again (a closed jaw pushed into tissue does not grasp). While closed,
each step's attachment targets are the tool's pose at the end of the step composed with those coordinates, held by
the zero-length springs of ``core/physics/attach.py``. Opening, a step without a tool, :meth:`Grasp.reset` (the
simulation's reset) and a diverged step release everything. Only a ``grasper`` tool grasps.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..contact.tool import ToolPose
from ..errors import InputError


def check_jaw(jaw: Any) -> float:
    """A jaw angle as a float [rad]; InputError naming the value when it is not a finite number."""
    try:
        value = float(jaw)
    except (TypeError, ValueError):
        raise InputError(f"jaw={jaw!r}: expected a jaw angle in rad (a finite number)") from None
    if not math.isfinite(value):
        raise InputError(f"jaw={jaw!r}: expected a finite jaw angle in rad")
    return value


def to_tool_frame(x: np.ndarray, pose: ToolPose) -> np.ndarray:
    """World points (K, 2) [m] in the frame of the tool at ``pose`` (origin the pose, x along yaw)."""
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    d = x - np.array([pose.x, pose.y])
    return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1)


def to_world(local: np.ndarray, pose: ToolPose) -> np.ndarray:
    """Tool-frame points (K, 2) [m] in the world, the tool at ``pose``."""
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    return np.stack([pose.x + c * local[:, 0] - s * local[:, 1], pose.y + s * local[:, 0] + c * local[:, 1]], axis=1)


class Grasp:
    """The jaw's state and the particles it holds (see the module docstring)."""

    def __init__(self) -> None:
        self.jaw: float | None = None
        """The last jaw angle given [rad] (None: never given; the jaw counts as open)."""
        self.closed = False
        """True between a close and the next open (hysteresis)."""
        self.idx = np.zeros(0, dtype=np.int64)
        """Held particles, (K,) int64."""
        self.local = np.zeros((0, 2))
        """Their coordinates in the tool frame at the moment of closing [m], (K, 2)."""

    @property
    def n_held(self) -> int:
        return int(self.idx.shape[0])

    def release(self) -> None:
        self.idx = np.zeros(0, dtype=np.int64)
        self.local = np.zeros((0, 2))

    def reset(self) -> None:
        """Open and empty, no jaw angle known."""
        self.jaw = None
        self.closed = False
        self.release()

    def update(self, jaw: float | None, grasper: bool, pose: ToolPose | None, x: np.ndarray, inv_mass: np.ndarray,
               close_angle: float, open_angle: float, radius: float) -> None:
        """Take this step's jaw angle (None: the last one) with the tool at ``pose`` (where the step starts; None:
        no tool this step, which releases) and the particles at ``x`` (N, 2) [m]."""
        if jaw is not None:
            self.jaw = check_jaw(jaw)
        if not grasper or pose is None:
            self.release()
            return
        if self.jaw is None:
            return
        if self.closed and self.jaw > open_angle:
            self.closed = False
            self.release()
        elif not self.closed and self.jaw < close_angle:
            self.closed = True
            d = x - np.array([pose.x, pose.y])
            near = np.flatnonzero(((d * d).sum(axis=1) <= radius * radius) & (inv_mass > 0))
            self.idx = near.astype(np.int64)
            self.local = to_tool_frame(x[near], pose)

    def targets(self, pose: ToolPose) -> np.ndarray:
        """Where the held particles are held with the tool at ``pose`` [m], (K, 2) float64."""
        return np.ascontiguousarray(to_world(self.local, pose))

    def carry_state(self) -> dict[str, Any]:
        return {"jaw": self.jaw, "closed": self.closed, "idx": self.idx.copy(), "local": self.local.copy()}

    def restore_carry(self, state: dict[str, Any]) -> None:
        if not state:
            self.reset()
            return
        self.jaw = state["jaw"]
        self.closed = bool(state["closed"])
        self.idx = np.asarray(state["idx"], dtype=np.int64).copy()
        self.local = np.asarray(state["local"], dtype=np.float64).reshape(-1, 2).copy()
