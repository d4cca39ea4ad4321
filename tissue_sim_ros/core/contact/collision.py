r"""Tool-tissue contact: python-fcl queries, the paper's eq. (3), and projection contact.

Contract with the solver (``solvers.py``):

* ``Contacts.held_idx`` / ``held_dx``: the paper model's displaced particles and
  their displacement; the solver adds ``held_dx`` to the predicted positions
  and holds these particles (inverse mass 0) for the step.
* ``Contacts.candidates`` with ``tool_shape0`` / ``tool_shape1``: the projection
  model; inside every solver iteration the solver calls
  :func:`project_tool` on the candidate particles, with the tool posed at the
  start and the end of the (sub)step, accumulating corrections into ``dx_accum``.

Semantics chosen here (the paper leaves them open):

* **Query positions.** Detection uses the particle positions at the start of
  the step (``state.particle_q``, the paper's x^t) against the tool at its new
  pose (the commanded pose at the end of the step). The paper adds the
  manipulator's "driving force" to the prediction from x^t ("instead of
  applying the driving force on the particles, we directly update their
  positions"), so the displacement is decided from x^t, before the solve.
* **d\* and q (paper model).** Per body, one python-fcl distance query between
  the body's triangle mesh (z = 0) and the tool gives d* (fcl's minimum
  distance, mesh to tool: it can be smaller than particle q's own distance when
  the nearest mesh point lies inside an edge) and the nearest triangle
  (``DistanceResult.b1``); q is the vertex of that triangle with the smallest
  signed distance to the tool. Bodies are never mixed: q, d* and the displaced
  particles all belong to one body, and each body is queried on its own.
* **Overlap.** When the tool overlaps a body, python-fcl 0.7's mesh-shape
  distance returns -1 with no primitive id and zero nearest points (measured;
  a signed-distance request returns ~0, also without an id). We treat that as
  d* = 0 (touching), take q = the body's particle with the smallest signed
  distance to the tool (the deepest inside it), and apply eq. (3) with d* = 0:
  the paper's displacement is then zero, so nothing is displaced or held (the
  body is in contact, and the solve moves it freely). When a particle already
  lies inside the tool (our signed distance < 0) the overlap is certain and
  the fcl query is skipped; a thin tool crossing triangles between their
  vertices is found by fcl (-1). A tool that jumps into tissue thus passes
  through it: the paper rule's documented failure for fast tools.
* **Held particles.** Eq. (3) applies when 0 < d* < alpha and the tool's
  linear speed |v| > 0; every free (not pinned) particle i of q's body with
  |x_q - x_i| <= r is displaced by (r - |x_q - x_i|)/r d* v/|v| and held for
  the step (the paper's "invisible force": the solve does not undo it). A tool
  at rest (or only rotating) displaces and holds nothing, and so does d* = 0.
* **BVH refit.** python-fcl 0.7 exposes no beginUpdateModel/updateVertex/
  endUpdateModel, so a body's BVH cannot be refitted in place: it is rebuilt
  every step. A full rebuild costs ~1.6-3 us per triangle (python-fcl converts
  each vertex through a NumPy call, then fits OBBRSS volumes), several times a
  whole step, so by default only the triangles that can hold the nearest point
  go into the step's BVH: triangles whose lower bound on the distance to the
  tool (tangent planes of the convex signed distance at their vertices, see
  :func:`~.kernels.near_triangles`) is below min(alpha, the body's nearest-vertex
  distance). The nearest triangle always passes that test, so d* and q are
  the full BVH's whenever d* < alpha (``cull=False`` rebuilds the whole body,
  for checks and benchmarks). Bodies farther than alpha get d* = inf ("not
  computed"). python-fcl reported the triangle in ``b1`` whichever object
  came first (with the tool first, ``nearest_points`` were also swapped), so
  the body is passed first and the id taken from whichever of b1/b2 is set.

The array kernels (the SDF of the tool, the swept projection of particles and boundary edges,
culling) are in :mod:`.kernels`; see there for the projection's semantics.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import fcl
import numpy as np

from .kernels import (
    EDGE_SIDE_TOL_MIN,
    body_nearest,
    compact_triangles,
    near_triangles,
    paper_displacement,
    points_sdf,
    projection_candidates,
)
from .tool import ToolPose, ToolShape, ToolTwist, tool_shape_array

if TYPE_CHECKING:  # the physics imports this package's kernels: its types are only named here
    from ..physics.model import Model, State
    from .collider import ToolCollider


@dataclass
class Contacts:
    """The contact model's output for one step."""

    held_idx: np.ndarray
    """Paper model: particles displaced and held this step, shape (K,), int32."""
    held_dx: np.ndarray
    """Paper model: displacement of each held particle [m], shape (K, 2), float64."""
    candidates: np.ndarray
    """Projection model: particles that may touch the swept tool, shape (M,), int32 (empty: no projection)."""
    tool_shape0: np.ndarray
    """Tool at the start of the step, packed by :func:`~tissue_sim_ros.core.contact.tool.tool_shape_array`, shape (7,)."""
    tool_shape1: np.ndarray
    """Tool at the end of the step, shape (7,)."""
    in_contact: np.ndarray
    """Per body: True where the tool touches, shape (B,), bool."""
    d_star: np.ndarray
    """Per body: distance tool-tissue d* [m], shape (B,), float64 (inf if not computed)."""
    touched: np.ndarray
    """Particles the contact model moved (held or projected) this step, int32; filled by the solver for projection."""
    surface_edges: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int32))
    """Projection model, ``contact_surface="edges"``: boundary edges that may touch the swept tool, shape (K, 2),
    int32, each ordered so that its body lies on the left (the CCW order of the triangle owning it); the
    free particles of these edges are also in ``candidates``. Empty: particles only."""
    edge_side_tol: float = 0.0
    """Projection model: how far [m] the tool may be past a boundary edge at the start of a (sub)step and
    still be pushed back out by it (:func:`project_edges`); deeper, the tool is taken to be through the edge."""
    attach_idx: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    """Particles held to the tool this step (a closed grasper), shape (K,), int64; set by the Simulation
    (``core/sim/grasp.py``), solved by ``core/physics/attach.py`` inside every solver iteration. Empty: none."""
    attach_target: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    """Where each held particle is held at the end of the step [m], shape (K, 2), float64."""
    attach_compliance: float = 0.0
    """Compliance of the attachment springs [m/N] (energy |x - target|^2 / (2 compliance))."""
    attach_local: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    """Where each held particle sits in the tool's frame [m], shape (K, 2): the barrier contact's solve moves the
    targets with the tool as it goes."""
    tool_collider: "ToolCollider | None" = None
    """Barrier contact: the tool of this step, built once (``core/contact/collider.py``): its core, where it starts
    and where it is commanded; the solve, the reaction and the checks all take it. None: no tool this step."""

    @property
    def attach_stiffness(self) -> float:
        """1 / ``attach_compliance`` [N/m] (0 without attachments): the form an energy-minimising solver reads."""
        return 1.0 / self.attach_compliance if self.attach_compliance > 0.0 else 0.0

    @classmethod
    def empty(cls, n_bodies: int) -> "Contacts":
        z7 = np.zeros(7)
        return cls(np.zeros(0, np.int32), np.zeros((0, 2)), np.zeros(0, np.int32), z7, z7.copy(),
                   np.zeros(n_bodies, dtype=bool), np.full(n_bodies, np.inf), np.zeros(0, np.int32))


def boundary_edges_ccw(tri_indices: np.ndarray) -> np.ndarray:
    """Boundary edges (used by exactly one triangle), each ordered as in its CCW triangle: body on the left.

    tri_indices : (T, 3) int, counter-clockwise. Returns (K, 2) int32, sorted by
    (first, second) particle. The inward normal of a -> b is (-(y_b - y_a), x_b - x_a) / |b - a|.
    """
    tris = np.asarray(tri_indices, dtype=np.int64).reshape(-1, 3)
    directed = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    if directed.shape[0] == 0:
        return np.zeros((0, 2), dtype=np.int32)
    key = np.sort(directed, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    once = directed[counts[inverse.ravel()] == 1]
    once = once[np.lexsort((once[:, 1], once[:, 0]))]
    return np.ascontiguousarray(once, dtype=np.int32)


# --------------------------------------------------------------------------- python-fcl


def _fcl_tool(shape: ToolShape) -> tuple[fcl.CollisionGeometry, np.ndarray]:
    """The tool as an fcl shape and the rotation taking its axis onto the tool frame's +x.

    The tissue lies in z = 0, so any z extent gives the same in-plane distances;
    the box is given a z extent equal to its width (thin, but not so flat that
    GJK loses accuracy). fcl's capsule lies along its z axis: a quarter turn
    about y lays it along +x. A zero-length capsule is a sphere.
    """
    if shape.kind == "box":
        return fcl.Box(shape.length, shape.width, shape.width), np.eye(3)
    lay = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # R_y(+90 deg): z -> +x
    if shape.kind == "grasper":
        # its envelope (ToolShape.rounded_box), placed at ToolShape.contact_pose by _place_tool
        hx, _, r = shape.rounded_box()
        return (fcl.Capsule(r, 2.0 * hx), lay) if hx > 0 else (fcl.Sphere(r), np.eye(3))
    if shape.kind == "capsule" and shape.length > 0:
        return fcl.Capsule(shape.radius, shape.length), lay
    return fcl.Sphere(shape.radius), np.eye(3)


def _yaw_matrix(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass
class BodyDistance:
    """One body's distance query result."""

    d_star: float
    """Distance mesh-tool [m]: 0 when they overlap, inf when farther than the query's reach."""
    q: int
    """Particle q (global index), -1 when not computed."""
    overlap: bool
    """True when python-fcl reported the tool overlapping the body (distance -1)."""
    n_tris: int
    """Triangles in the BVH built for this query (0: no query was needed)."""


class ContactModel:
    """Finds tool-tissue contact each step (python-fcl) and builds :class:`Contacts`.

    Parameters
    ----------
    model : Model
        The scene; ``model.params.contact_model`` selects ``paper`` or ``projection``.
    tool : ToolShape
        The tool's geometry.
    cull : bool
        Put only the triangles that can hold the nearest point into each step's
        BVH (default). False rebuilds every body's full BVH each step.
    """

    def __init__(self, model: Model, tool: ToolShape, cull: bool = True) -> None:
        self.model = model
        self.tool = tool
        self.cull = cull
        p = model.params
        self.kind = p.contact_model
        tris = np.ascontiguousarray(model.tri_indices, dtype=np.int32)
        self.body_particles = [np.flatnonzero(model.particle_body == b).astype(np.int32) for b in range(model.n_bodies)]
        self.body_tris = [np.ascontiguousarray(tris[model.tri_body == b]) for b in range(model.n_bodies)]
        n, t = model.n_particles, model.n_triangles
        # scratch for the kernels (the model is fixed, so are the sizes)
        self._sdf = np.empty(n)
        self._grad = np.empty((n, 2))
        self._sel = np.empty(max(t, 1), dtype=np.int32)
        self._vmap = np.full(n, -1, dtype=np.int32)
        self._verts = np.empty((n, 3))
        self._ids = np.empty(n, dtype=np.int32)
        self._ctris = np.empty((max(t, 1), 3), dtype=np.int32)
        self._cand = np.empty(n, dtype=np.int32)
        # boundary edges for the projection's surface contact (contact_surface="edges")
        self.boundary_edges = boundary_edges_ccw(model.tri_indices)
        """Every body's boundary edges, ordered with the body on the left, (K, 2) int32."""
        self._edge_cand = np.empty(self.boundary_edges.shape[0], dtype=np.int32)
        self._edge_rows = np.empty((self.boundary_edges.shape[0], 2), dtype=np.int32)
        self._is_cand = np.zeros(n, dtype=bool)
        self._projection_ws = (self._cand, self._edge_cand, self._is_cand, self._edge_rows)
        self._body_min = np.empty(model.n_bodies)
        self._body_arg = np.empty(model.n_bodies, dtype=np.int32)
        self._pose = ToolPose(0.0, 0.0, 0.0)
        self._placed = False
        self._held_idx = np.empty(n, dtype=np.int32)
        self._held_dx = np.empty((n, 2))
        geom, self._axis_rot = _fcl_tool(tool)
        self._tool_obj = fcl.CollisionObject(geom, fcl.Transform())
        self._request = fcl.DistanceRequest(enable_nearest_points=True)
        self.last_bvh_triangles = 0
        """Triangles put into BVHs by the last :meth:`detect` (for benchmarks)."""

    # -- queries ------------------------------------------------------------------------------

    def _place_tool(self, pose: ToolPose) -> None:
        cx, cy, yaw = self.tool.contact_pose(pose)
        rot = _yaw_matrix(yaw) @ self._axis_rot
        self._tool_obj.setTransform(fcl.Transform(rot, np.array([cx, cy, 0.0])))

    def prepare(self, x: np.ndarray, pose: ToolPose) -> None:
        """Every particle's signed distance (and gradient) to the tool at ``pose``, for :meth:`body_distance`.

        The fcl tool object is posed lazily, by the first query that needs it.
        """
        points_sdf(x, tool_shape_array(self.tool, pose, 0.0), self._sdf, self._grad)
        body_nearest(self._sdf, self.model.particle_body, self._body_min, self._body_arg)
        self._pose = pose
        self._placed = False

    def distances(self, x: np.ndarray, pose: ToolPose, reach: float) -> list["BodyDistance"]:
        """d* and q of every body for positions ``x`` (N, 2) [m] and the tool at ``pose``."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        self.prepare(x, pose)
        return [self.body_distance(b, x, reach) for b in range(self.model.n_bodies)]

    def body_distance(self, b: int, x: np.ndarray, reach: float) -> BodyDistance:
        """d* and q of body ``b`` at positions ``x``; :meth:`prepare` must have been called with the same ``x``.

        d* is exact when <= ``reach``; farther bodies report d* = inf (not computed).
        """
        sdf = self._sdf
        tris = self.body_tris[b]
        if tris.shape[0] == 0:
            return BodyDistance(math.inf, -1, False, 0)
        upper = float(self._body_min[b])  # d* <= the nearest vertex's distance
        deepest = int(self._body_arg[b])
        if upper < 0.0:
            # a particle lies inside the tool: they overlap, which is all fcl would say (distance -1)
            return BodyDistance(0.0, deepest, True, 0)
        if self.cull:
            n_sel = near_triangles(x, tris, sdf, self._grad, min(reach, upper), self._sel)
            if n_sel == 0:
                return BodyDistance(math.inf, -1, False, 0)
        else:
            n_sel = tris.shape[0]
            self._sel[:n_sel] = np.arange(n_sel, dtype=np.int32)
        nv = compact_triangles(x, tris, self._sel, n_sel, self._vmap, self._verts, self._ids, self._ctris)
        bvh = fcl.BVHModel()
        bvh.beginModel(n_sel, nv)
        bvh.addSubModel(self._verts[:nv], self._ctris[:n_sel])
        bvh.endModel()
        obj = fcl.CollisionObject(bvh, fcl.Transform())
        if not self._placed:
            self._place_tool(self._pose)
            self._placed = True
        result = fcl.DistanceResult()
        # the body first: python-fcl then reports the triangle in b1 and its nearest point first
        dist = fcl.distance(obj, self._tool_obj, self._request, result)
        prim = result.b1 if result.b1 >= 0 else result.b2
        if dist < 0.0 or prim < 0 or prim >= n_sel:
            # overlap (python-fcl returns -1 without a primitive): q = the deepest particle
            return BodyDistance(0.0, deepest, True, n_sel)
        verts = self._ids[self._ctris[prim]]
        q = int(verts[np.argmin(sdf[verts])])
        if dist > reach and self.cull:
            return BodyDistance(math.inf, -1, False, n_sel)
        return BodyDistance(float(dist), q, False, n_sel)

    def detect(self, state: State, pose0: ToolPose, pose1: ToolPose, twist: ToolTwist, dt: float) -> Contacts:
        """Contacts of one step: the tool moves from ``pose0`` to ``pose1`` with ``twist`` over ``dt``.

        ``state`` holds the positions at the start of the step (the query positions).
        """
        model, p = self.model, self.model.params
        nb = model.n_bodies
        contacts = Contacts.empty(nb)
        x = np.ascontiguousarray(state.particle_q, dtype=np.float64)
        self.prepare(x, pose1)
        self.last_bvh_triangles = 0
        if self.kind == "projection":
            self._detect_projection(state, pose0, pose1, dt, contacts)
        # d* is reported up to alpha for both models (beyond: inf)
        reach = max(p.contact_threshold, p.contact_margin)
        n_held = 0
        speed = math.hypot(twist.vx, twist.vy)
        for b in range(nb):
            res = self.body_distance(b, x, reach)
            self.last_bvh_triangles += res.n_tris
            contacts.d_star[b] = res.d_star
            if self.kind in ("projection", "barrier"):
                # known only after the solve: the Simulation marks the bodies the tool pushed
                continue
            if not res.d_star < p.contact_threshold:
                continue
            contacts.in_contact[b] = True
            if speed == 0.0 or res.d_star <= 0.0:
                # eq. (3) needs the tool's direction of motion (a tool at rest moves nothing), and with
                # d* = 0 it displaces nothing: nothing is held then either (freezing a disc of radius r
                # in place while the tool passes through inverted up to 125 triangles in experiment a)
                continue
            n_held += paper_displacement(x, self.body_particles[b], model.particle_inv_mass, res.q, res.d_star,
                                         twist.vx / speed, twist.vy / speed, p.contact_radius,
                                         self._held_idx[n_held:], self._held_dx[n_held:])
        if n_held:
            contacts.held_idx = self._held_idx[:n_held].copy()
            contacts.held_dx = self._held_dx[:n_held].copy()
            contacts.touched = contacts.held_idx.copy()
        return contacts

    def _detect_projection(self, state: State, pose0: ToolPose, pose1: ToolPose, dt: float,
                           contacts: Contacts) -> None:
        """Candidates for the in-solver projection: particles (and boundary edges) near the tool swept over the
        step (:func:`~.kernels.projection_candidates`)."""
        p = self.model.params
        shape0 = tool_shape_array(self.tool, pose0, p.contact_margin)
        shape1 = tool_shape_array(self.tool, pose1, p.contact_margin)
        use_edges = p.contact_surface == "edges" and self.boundary_edges.shape[0] > 0
        n, k = projection_candidates(np.ascontiguousarray(state.particle_q), state.particle_qd,
                                     self.model.particle_inv_mass, shape0, shape1,
                                     (float(dt), abs(p.gravity) * dt * dt, tool_travel(shape0, shape1, pose0, pose1)),
                                     (self.boundary_edges, use_edges), self._projection_ws)
        if use_edges:
            if k:
                contacts.surface_edges = self._edge_rows[:k].copy()
            contacts.edge_side_tol = max(p.contact_margin, EDGE_SIDE_TOL_MIN)
        contacts.candidates = self._cand[:n].copy()
        contacts.tool_shape0 = shape0
        contacts.tool_shape1 = shape1


def tool_travel(shape0: np.ndarray, shape1: np.ndarray, pose0: ToolPose, pose1: ToolPose) -> float:
    """How far a point of the tool moves in a step [m], at most: its rounded box's centre's travel (the grasper's
    envelope turns about its tip) plus the turn times the box's radius."""
    radius = math.hypot(shape1[4], shape1[5]) + shape1[6]
    dyaw = abs(math.atan2(math.sin(pose1.yaw - pose0.yaw), math.cos(pose1.yaw - pose0.yaw)))
    return math.hypot(shape1[0] - shape0[0], shape1[1] - shape0[1]) + dyaw * radius
