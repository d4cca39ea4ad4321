"""The tool as one collision object per step: its core (its true outline as closed polygons) and its pose.

The barrier contact (``contact_model: barrier``) sees the tool's true outline: a box is its rectangle, a capsule
its stadium and a sphere its circle as polygons circumscribing them (``ARC_SEGMENTS`` edges per half circle, their
corners under 0.5 % of the radius outside it: no particle reaches the true shape), and the grasper its shaft (a
rectangle from the jaws' hinge up) and its two jaws (thin blades from the hinge to the tips, 0.6 of the shaft's
half width thick), opened to the jaw angle. Every edge has radius 0: with a rounded core (a segment inflated by
a radius) the gap's curvature as a tissue edge turns under it is r / gap times the barrier's force, which the
solver's Gauss-Newton Hessian leaves out; a capsule's tip pressed 1 mm per step into a 1 kPa strip then stalls in
cut steps (measured: 100-500 iterations a step, the tool 3 mm short), where the polygon takes 4-26.
The tool has four degrees of
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
    """(E, 2) int32: the outline's edges (closed loops, counter-clockwise)."""
    edge_radius: np.ndarray
    """(E,) float64 [m]: each segment's inflation."""
    vertex_radius: np.ndarray
    """(V,) float64 [m]: each vertex's inflation (the largest of its segments')."""
    reach: float
    """The largest distance of a vertex from the pose's origin at any jaw angle [m] (bounds a turn's sweep)."""
    jaw_reach: float
    """The largest jaw arm [m] (bounds a jaw's sweep)."""
    loops: tuple = ()
    """The closed polygons, each a (K,) array of vertex indices, counter-clockwise."""

    @property
    def loop_ptr(self) -> np.ndarray:
        """(L + 1,) int64: loop l's edges are ``edges[loop_ptr[l]:loop_ptr[l + 1]]`` (they are made loop by loop)."""
        return np.concatenate([[0], np.cumsum([len(loop) for loop in self.loops])]).astype(np.int64)

    @property
    def arrays(self) -> tuple:
        """(hinge, arm, sign, edges, edge_radius, vertex_radius): the kernels' bundle ``geom``."""
        return (self.hinge, self.arm, self.sign, self.edges, self.edge_radius, self.vertex_radius)


#: Segments per half circle of a rounded part (a capsule's end, a sphere's half): the polygon circumscribes the
#: true outline, its corners at most r (1 / cos(pi / 2 ARC_SEGMENTS) - 1) = 0.48 % of the radius outside it.
ARC_SEGMENTS = 16


def _arc(cx: float, cy: float, r: float, a0: float, n: int) -> list[tuple[float, float]]:
    """n corners of a polygon circumscribing the arc of radius r about (cx, cy) from angle a0 over pi (its edges
    tangent to the circle at a0, a0 + pi / n, ..., a0 + pi)."""
    step = math.pi / n
    rr = r / math.cos(0.5 * step)
    return [(cx + rr * math.cos(a0 + (k + 0.5) * step), cy + rr * math.sin(a0 + (k + 0.5) * step)) for k in range(n)]


def _loops(parts: list[list[tuple[float, float]]]) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Vertices (V, 2), edges (E, 2) and the vertex loops of closed polygons."""
    verts, edges, loops = [], [], []
    for part in parts:
        base = len(verts)
        verts += part
        m = len(part)
        edges += [(base + k, base + (k + 1) % m) for k in range(m)]
        loops.append(np.arange(base, base + m))
    return np.array(verts, dtype=np.float64), np.array(edges, dtype=np.int32), loops


def tool_geometry(shape: ToolShape) -> ToolGeometry:
    """The core of ``shape`` (module docstring): closed polygons of its true outline, radius 0."""
    sign_of: list[float] = []
    if shape.kind == "box":
        hx, hy = 0.5 * shape.length, 0.5 * shape.width
        hinge, edges, loops = _loops([[(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)]])
    elif shape.kind == "capsule":
        hx, r = 0.5 * shape.length, shape.radius
        hinge, edges, loops = _loops([_arc(hx, 0.0, r, -0.5 * math.pi, ARC_SEGMENTS)
                                      + _arc(-hx, 0.0, r, 0.5 * math.pi, ARC_SEGMENTS)])
    elif shape.kind == "sphere":
        hinge, edges, loops = _loops([_arc(0.0, 0.0, shape.radius, 0.0, ARC_SEGMENTS)
                                      + _arc(0.0, 0.0, shape.radius, math.pi, ARC_SEGMENTS)])
    else:
        w, lj = 0.5 * shape.shaft_width, shape.jaw_length
        rj = JAW_RADIUS * w
        shaft = [(-w, lj), (w, lj), (w, max(shape.length, lj + w)), (-w, max(shape.length, lj + w))]
        blade = [(-rj, 0.0), (-rj, -lj), (rj, -lj), (rj, 0.0)]  # from the hinge down to the tip, closed
        hinge, edges, loops = _loops([shaft, blade, blade])
        sign_of = [0.0] * 4 + [-1.0] * 4 + [1.0] * 4
    n = hinge.shape[0]
    arm = np.zeros((n, 2))
    sign = np.array(sign_of if sign_of else [0.0] * n, dtype=np.float64)
    if shape.kind == "grasper":
        # the blades' corners turn about the hinge (0, jaw_length) with the jaw
        arm[4:] = hinge[4:]
        hinge[4:] = (0.0, shape.jaw_length)
    radius = np.zeros(edges.shape[0])
    reach = float(np.max(np.hypot(*hinge.T) + np.hypot(*arm.T))) if n else 0.0
    return ToolGeometry(np.ascontiguousarray(hinge, dtype=np.float64), arm, sign,
                        np.ascontiguousarray(edges, dtype=np.int32), radius, np.zeros(n), reach,
                        float(np.max(np.hypot(*arm.T))) if n else 0.0, tuple(loops))


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


def core_positions(q: np.ndarray, geometry: ToolGeometry) -> np.ndarray:
    """The core's vertices (V, 2) at dofs ``q`` (NumPy; :func:`tool_vertices` is the kernel)."""
    pos = np.zeros((geometry.hinge.shape[0], 2))
    tool_vertices(np.ascontiguousarray(q, dtype=np.float64), geometry.arrays, pos,
                  np.zeros((geometry.hinge.shape[0], 2, 4)))
    return pos


def _segments_apart(p0: np.ndarray, p1: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance between segment p0 -> p1 and each segment a -> b (M, 2): (M,) (0 where they cross)."""
    from ..mesh.geometry import segment_distances  # noqa: PLC0415

    d = np.minimum(segment_distances(np.stack([p0, p1]), a, b).min(axis=0),
                   np.minimum(segment_distances(a, p0[None], p1[None])[:, 0],
                              segment_distances(b, p0[None], p1[None])[:, 0]))

    def side(u, v, w):
        return np.sign((v[..., 0] - u[..., 0]) * (w[..., 1] - u[..., 1]) - (v[..., 1] - u[..., 1]) * (w[..., 0] - u[..., 0]))

    cross = (side(p0, p1, a) * side(p0, p1, b) < 0) & (side(a, b, p0) * side(a, b, p1) < 0)
    return np.where(cross, 0.0, d)


def points_in_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """(P,) bool: each point strictly inside the closed polygon (K, 2) (even-odd rule: a ray along +x crosses its
    edges an odd number of times)."""
    inside = np.zeros(points.shape[0], dtype=bool)
    px, py = points[:, 0], points[:, 1]
    for k in range(polygon.shape[0]):
        (ax, ay), (bx, by) = polygon[k], polygon[(k + 1) % polygon.shape[0]]
        straddles = (ay > py) != (by > py)
        with np.errstate(divide="ignore", invalid="ignore"):
            cross_x = ax + (py - ay) * (bx - ax) / (by - ay)
        inside ^= straddles & (px < cross_x)
    return inside


def tool_clearance(q: np.ndarray, geometry: ToolGeometry, x: np.ndarray, edges: np.ndarray,
                   tris: np.ndarray) -> float:
    """How far the tool's outline at ``q`` is from the tissue's boundary [m] (``edges`` (K, 2) its boundary
    edges, x (N, 2) the positions); -1 when the tool lies inside a triangle, or (a box) the tissue inside it."""
    pos = core_positions(q, geometry)
    gap = math.inf
    a, b = x[edges[:, 0]], x[edges[:, 1]]
    for (i, j), r in zip(geometry.edges, geometry.edge_radius):
        gap = min(gap, float(_segments_apart(pos[i], pos[j], a, b).min()) - float(r))
    # a core point inside a triangle of the tissue (the whole core inside the body: no edge near it)
    t = np.asarray(tris)
    pa, pb, pc = x[t[:, 0]], x[t[:, 1]], x[t[:, 2]]
    for p in pos:
        s1 = (pb[:, 0] - pa[:, 0]) * (p[1] - pa[:, 1]) - (pb[:, 1] - pa[:, 1]) * (p[0] - pa[:, 0])
        s2 = (pc[:, 0] - pb[:, 0]) * (p[1] - pb[:, 1]) - (pc[:, 1] - pb[:, 1]) * (p[0] - pb[:, 0])
        s3 = (pa[:, 0] - pc[:, 0]) * (p[1] - pc[:, 1]) - (pa[:, 1] - pc[:, 1]) * (p[0] - pc[:, 0])
        if np.any((s1 >= 0) & (s2 >= 0) & (s3 >= 0)):
            return -1.0
    if geometry.loops:
        # a closed polygon holding a tissue vertex (a small body wholly inside the tool)
        inner = x[np.unique(edges)]
        for loop in geometry.loops:
            if points_in_polygon(inner, pos[loop]).any():
                return -1.0
    return gap


def clear_start(q: np.ndarray, geometry: ToolGeometry, x: np.ndarray, edges: np.ndarray, tris: np.ndarray,
                clearance: float) -> np.ndarray:
    """``q`` when the tool there is free of the tissue; otherwise ``q`` moved the least distance (along one of
    eight directions, in steps of 25 % from ``clearance``) that leaves ``clearance`` between them: where a tool
    that appears inside the tissue (a first pose, a placed one) starts, to move in from outside as commanded."""
    q = np.array(q, dtype=np.float64)
    if edges.shape[0] == 0 or tool_clearance(q, geometry, x, edges, tris) > 0.0:
        return q
    size = float(np.hypot(*np.ptp(x, axis=0))) + 2.0 * geometry.reach + clearance
    best = None
    for k in range(8):
        angle = 0.25 * math.pi * k
        direction = np.array([math.cos(angle), math.sin(angle)])
        s = clearance
        while s <= 2.0 * size:
            moved = q.copy()
            moved[:2] += s * direction
            if tool_clearance(moved, geometry, x, edges, tris) >= clearance:
                if best is None or s < best[0]:
                    best = (s, moved)
                break
            s *= 1.25
    return best[1] if best is not None else q
