"""The tool: shape, planar pose and velocity, and trajectories as data.

All in the simulation frame: x right, y up, yaw about +z (the tool's heading in
the tissue plane). A tool's long axis is its local +x.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import InputError

TOOL_SHAPES = ("box", "capsule", "sphere")


@dataclass(frozen=True)
class ToolShape:
    """Tool geometry in the tool frame (local +x is the long axis, the tip at +length/2).

    * ``box``: a ``length`` x ``width`` rectangle (the paper's authors used 0.8 x 0.005);
    * ``capsule``: a segment of ``length`` along +x, inflated by ``radius``;
    * ``sphere``: a disc of ``radius``.
    """

    kind: str = "box"
    length: float = 0.8
    """Length along the tool axis [m] (box, capsule)."""
    width: float = 0.005
    """Full width of a box [m]."""
    radius: float = 0.0025
    """Radius of a capsule or sphere [m]."""

    def __post_init__(self) -> None:
        if self.kind not in TOOL_SHAPES:
            raise InputError(f"tool_shape={self.kind!r}: expected one of {', '.join(TOOL_SHAPES)}")
        for name in ("length", "width", "radius"):
            value = getattr(self, name)
            if not math.isfinite(value) or value < 0:
                raise InputError(f"tool_{name}={value!r}: expected a finite size >= 0 m")
        if self.kind == "box" and (self.length <= 0 or self.width <= 0):
            raise InputError(f"box tool needs tool_length and tool_width > 0; got {self.length}, {self.width}")
        if self.kind in ("capsule", "sphere") and self.radius <= 0:
            raise InputError(f"{self.kind} tool needs tool_radius > 0; got {self.radius}")

    def rounded_box(self) -> tuple[float, float, float]:
        """The shape as a rounded box: half extents (hx, hy) and corner radius, all [m].

        Box: (length/2, width/2, 0); capsule: (length/2, 0, radius); sphere: (0, 0, radius).
        """
        if self.kind == "box":
            return 0.5 * self.length, 0.5 * self.width, 0.0
        if self.kind == "capsule":
            return 0.5 * self.length, 0.0, self.radius
        return 0.0, 0.0, self.radius


@dataclass(frozen=True)
class ToolPose:
    """Planar pose of the tool's centre: position [m] and yaw [rad]."""

    x: float
    y: float
    yaw: float = 0.0

    def as_array(self) -> np.ndarray:
        return np.array([self.x, self.y, self.yaw], dtype=np.float64)


@dataclass(frozen=True)
class ToolTwist:
    """Planar velocity of the tool's centre: linear [m/s] and angular [rad/s]."""

    vx: float = 0.0
    vy: float = 0.0
    wz: float = 0.0

    def as_array(self) -> np.ndarray:
        return np.array([self.vx, self.vy, self.wz], dtype=np.float64)


def tool_shape_array(shape: ToolShape, pose: ToolPose, margin: float = 0.0) -> np.ndarray:
    """Pack a posed shape for numba kernels: [cx, cy, cos(yaw), sin(yaw), hx, hy, radius + margin], float64 (7,)."""
    hx, hy, rr = shape.rounded_box()
    return np.array([pose.x, pose.y, math.cos(pose.yaw), math.sin(pose.yaw), hx, hy, rr + margin], dtype=np.float64)
