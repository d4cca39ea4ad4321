"""The tool as one collision object per step: its core (points and segments inflated by a radius) and its pose.

The barrier contact (``contact_model: barrier``) sees the tool's true outline as cores: a box is its rectangle's
four edges (radius 0), a capsule its axis segment inflated by its radius, a sphere a point, and the grasper its
shaft (a segment of the shaft's half width from the jaws' hinge up) and its two jaws (segments from the hinge to
the jaw tips, a third of the shaft's half width thick), opened to the jaw angle. The tool has four degrees of
freedom q = (x, y, yaw, jaw) in the pose frame of :class:`~tissue_sim_ros.core.contact.tool.ToolPose` (the jaw
only moves a grasper's tips): a vertex of the core sits at

    w(q) = (x, y) + R(yaw) (hinge + R(s jaw / 2) arm)

with s = -1, 0, +1 (the left tip, a rigid vertex, the right tip). :class:`ToolCollider` holds that geometry, the
step's start pose (where the tool is, free of the tissue) and its commanded end pose; :func:`tool_vertices` gives
the world positions and their Jacobian to q. The solver moves q from the start toward the command, held to it by
a stiff spring, so a command the tissue cannot make room for leaves the tool short of it instead of inside.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .tool import ToolPose, ToolShape

#: A grasper jaw's thickness (radius of its core segment) relative to the shaft's half width.
JAW_RADIUS = 0.3
#: Tool degrees of freedom: x [m], y [m], yaw [rad], jaw [rad].
TOOL_DOFS = 4


@dataclass(frozen=True)
class ToolGeometry:
    """A tool's core in its pose frame, as arrays (:func:`tool_geometry`)."""

    hinge: np.ndarray
    """(V, 2) float64 [m]: each core vertex's rigid part."""
    arm: np.ndarray
    """(V, 2) float64 [m]: the part that turns with the jaw (zero for a rigid vertex)."""
    sign: np.ndarray
    """(V,) float64: -1, 0, +1: how the vertex's arm turns with half the jaw angle."""
    edges: np.ndarray
    """(E, 2) int32: the core segments (a == b: a point core)."""
    edge_radius: np.ndarray
    """(E,) float64 [m]: each segment's inflation."""
    vertex_radius: np.ndarray
    """(V,) float64 [m]: each vertex's inflation (the largest of its segments')."""
    reach: float
    """The largest distance of a vertex from the pose's origin at any jaw angle [m] (bounds a turn's sweep)."""
    jaw_reach: float
    """The largest jaw arm [m] (bounds a jaw's sweep)."""

    @property
    def arrays(self) -> tuple:
        """(hinge, arm, sign, edges, edge_radius, vertex_radius): the kernels' bundle ``geom``."""
        return (self.hinge, self.arm, self.sign, self.edges, self.edge_radius, self.vertex_radius)


def tool_geometry(shape: ToolShape) -> ToolGeometry:
    """The core of ``shape`` (module docstring)."""
    if shape.kind == "box":
        hx, hy = 0.5 * shape.length, 0.5 * shape.width
        hinge = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
        edges = np.array([[0, 1], [1, 2], [2, 3], [3, 0]])
        radius = np.zeros(4)
    elif shape.kind == "capsule":
        hinge = np.array([[-0.5 * shape.length, 0.0], [0.5 * shape.length, 0.0]])
        edges = np.array([[0, 1]])
        radius = np.array([shape.radius])
    elif shape.kind == "sphere":
        hinge = np.zeros((1, 2))
        edges = np.array([[0, 0]])
        radius = np.array([shape.radius])
    else:
        w, lj = 0.5 * shape.shaft_width, shape.jaw_length
        top = max(shape.length - w, lj)
        hinge = np.array([[0.0, lj], [0.0, top], [0.0, lj], [0.0, lj]])
        edges = np.array([[0, 1], [0, 2], [0, 3]])
        radius = np.array([w, JAW_RADIUS * w, JAW_RADIUS * w])
    n = hinge.shape[0]
    arm = np.zeros((n, 2))
    sign = np.zeros(n)
    if shape.kind == "grasper":
        arm[2:] = (0.0, -shape.jaw_length)
        sign[2], sign[3] = -1.0, 1.0
    vertex_radius = np.zeros(n)
    for (a, b), r in zip(edges, radius):
        vertex_radius[a] = max(vertex_radius[a], r)
        vertex_radius[b] = max(vertex_radius[b], r)
    reach = float(np.max(np.hypot(*hinge.T) + np.hypot(*arm.T))) if n else 0.0
    return ToolGeometry(np.ascontiguousarray(hinge, dtype=np.float64), arm, sign,
                        np.ascontiguousarray(edges, dtype=np.int32), np.ascontiguousarray(radius, dtype=np.float64),
                        vertex_radius, reach, float(np.max(np.hypot(*arm.T))) if n else 0.0)


def pose_dofs(pose: ToolPose, jaw: float) -> np.ndarray:
    """q = (x, y, yaw, jaw) (4,) of a pose and jaw angle (the jaw clamped to [0, pi])."""
    return np.array([pose.x, pose.y, pose.yaw, min(max(float(jaw), 0.0), math.pi)], dtype=np.float64)


@dataclass
class ToolCollider:
    """The tool of one step: its core, where it starts (q0: the pose it was left at, free of the tissue) and where
    it is commanded to (q1), built once and handed to the solve, the reaction and the checks."""

    shape: ToolShape
    geometry: ToolGeometry
    q0: np.ndarray
    """(4,) the start: x, y [m], yaw, jaw [rad]."""
    q1: np.ndarray
    """(4,) the command."""
    q_guess: np.ndarray
    """(4,) where the solve starts the tool: q0 moved by the command's change since the last command (a tool held
    still starts where it was left; one moving as commanded starts at its command)."""

    @classmethod
    def make(cls, shape: ToolShape, geometry: ToolGeometry, pose0: ToolPose, pose1: ToolPose, jaw0: float,
             jaw1: float, command0: ToolPose | None = None, jaw_command0: float | None = None) -> "ToolCollider":
        """The step's tool: from ``pose0`` (where it was left) with jaw ``jaw0`` toward ``pose1`` with ``jaw1``;
        ``command0`` and ``jaw_command0`` the last step's command (None: ``pose0``, ``jaw0``)."""
        q0 = pose_dofs(pose0, jaw0)
        q1 = pose_dofs(pose1, jaw1)
        # the command's yaw on the start's branch: a turn of 350 degrees is one of -10
        q1[2] = q0[2] + math.atan2(math.sin(q1[2] - q0[2]), math.cos(q1[2] - q0[2]))
        qc = pose_dofs(command0 or pose0, jaw0 if jaw_command0 is None else jaw_command0)
        qc[2] = q0[2] + math.atan2(math.sin(qc[2] - q0[2]), math.cos(qc[2] - q0[2]))
        return cls(shape, geometry, q0, q1, q0 + (q1 - qc))

    def pose(self, q: np.ndarray) -> ToolPose:
        """The pose of dofs ``q`` (yaw wrapped to [-pi, pi))."""
        yaw = math.atan2(math.sin(q[2]), math.cos(q[2]))
        return ToolPose(float(q[0]), float(q[1]), float(yaw))


@njit(cache=True, nogil=True)
def tool_vertices(q: np.ndarray, geom: tuple, pos: np.ndarray, jac: np.ndarray) -> None:
    """World positions of the core's vertices at dofs ``q`` (4,) into ``pos`` (V, 2), and dw/dq into ``jac``
    (V, 2, 4) (module docstring's formula)."""
    hinge, arm, sign, _edges, _er, _vr = geom
    c = math.cos(q[2])
    s = math.sin(q[2])
    half = 0.5 * q[3]
    for v in range(hinge.shape[0]):
        a = sign[v] * half
        ca = math.cos(a)
        sa = math.sin(a)
        lx = hinge[v, 0] + ca * arm[v, 0] - sa * arm[v, 1]
        ly = hinge[v, 1] + sa * arm[v, 0] + ca * arm[v, 1]
        # d(local)/d(jaw) = sign / 2 R'(a) arm
        djx = 0.5 * sign[v] * (-sa * arm[v, 0] - ca * arm[v, 1])
        djy = 0.5 * sign[v] * (ca * arm[v, 0] - sa * arm[v, 1])
        pos[v, 0] = q[0] + c * lx - s * ly
        pos[v, 1] = q[1] + s * lx + c * ly
        jac[v, 0, 0] = 1.0
        jac[v, 0, 1] = 0.0
        jac[v, 1, 0] = 0.0
        jac[v, 1, 1] = 1.0
        jac[v, 0, 2] = -s * lx - c * ly
        jac[v, 1, 2] = c * lx - s * ly
        jac[v, 0, 3] = c * djx - s * djy
        jac[v, 1, 3] = s * djx + c * djy
