"""One scene's state as the node's output messages (:class:`SceneEncoder`): the points with their strain, the
markers (mesh coloured by strain, wireframe, contact, grasp, the tool) and the rest mesh, into buffers made once."""
from __future__ import annotations

import math
import threading

import numpy as np

from ...core.contact.tool import rounded_box_outline as tool_outline  # the outline the pictures draw too
from ...core.physics.strain import VertexStrain, strain_mesh_arrays
from .cdr import Stamp
from .markers import (
    ACTION_DELETE,
    MARKER_LINE_LIST,
    MARKER_SPHERE_LIST,
    MARKER_TRIANGLE_LIST,
    MarkerSpec,
    encode_marker_array,
)
from .points import POINT_DTYPE, encode_point_cloud


def strain_colormap(n: int = 256) -> np.ndarray:
    """Diverging RGBA lookup table: blue (compressed) - white (rest) - red (stretched), shape (n, 4), float32."""
    s = np.linspace(-1.0, 1.0, n)
    lut = np.ones((n, 4), dtype=np.float32)
    neg, pos = s < 0, s > 0
    # fade the other two channels toward the pole colour; white at rest strain
    lut[neg, 0] = 1.0 + s[neg] * 0.85
    lut[neg, 1] = 1.0 + s[neg] * 0.7
    lut[pos, 1] = 1.0 - s[pos] * 0.8
    lut[pos, 2] = 1.0 - s[pos] * 0.85
    return lut


class SceneEncoder:
    """Encodes one scene's state into the node's output messages, reusing preallocated buffers.

    Parameters
    ----------
    tri_indices : ndarray
        Triangles, shape (T, 3), int32 (the Model's ``tri_indices``).
    edge_indices : ndarray
        Edges, shape (E, 2), int32.
    edge_rest_length : ndarray
        Rest length of each edge [m], shape (E,), float64.
    particle_body : ndarray
        Body of each particle, shape (N,), int.
    tool_rounded_box : tuple of float, optional
        (hx, hy, radius) of the tool [m]; None: no tool marker.
    tool_outline_local : ndarray, optional
        The tool's convex outline in its pose frame, (K, 2) [m] (:meth:`ToolShape.outline`); overrides
        ``tool_rounded_box`` (the grasper, whose pose is its tip).
    grasper : bool
        Show the particles a grasper holds (a ``grasped`` sphere list, cyan) in every MarkerArray.
    strain_color_max : float
        Strain shown at full colour (blue at -max, red at +max).
    wire_width : float
        Line width of the wireframe [m].
    wireframe : bool
        Include the LINE_LIST wireframe in the MarkerArray.
    """

    def __init__(self, tri_indices: np.ndarray, edge_indices: np.ndarray, edge_rest_length: np.ndarray,
                 particle_body: np.ndarray, tool_rounded_box: tuple[float, float, float] | None = None,
                 strain_color_max: float = 0.2, wire_width: float = 0.002, wireframe: bool = True,
                 tool_outline_local: np.ndarray | None = None, grasper: bool = False) -> None:
        self.tri = np.ascontiguousarray(tri_indices, dtype=np.int64)
        self.grasper = grasper
        self.edges = np.ascontiguousarray(edge_indices, dtype=np.int64)
        self.strain = VertexStrain(edge_indices, edge_rest_length, particle_body.shape[0])
        n = particle_body.shape[0]
        self.strain_color_max = strain_color_max
        self.wire_width = wire_width
        self.wireframe = wireframe
        self.lut = strain_colormap()
        self._lut16 = np.ascontiguousarray(self.lut).view(np.complex128).ravel()
        # flat index arrays and preallocated buffers: np.take into them is faster than fancy indexing
        self.tri_flat = np.ascontiguousarray(self.tri.ravel())
        self.edge_flat = np.ascontiguousarray(self.edges.ravel())
        self.tri_points = np.zeros((3 * len(self.tri), 3), dtype="<f8")
        self.wire_points = np.zeros((2 * len(self.edges), 3), dtype="<f8")
        # one RGBA (4 float32 = 16 bytes) viewed as one complex128, so colours gather as single elements
        self._tri_rgba = np.empty(3 * len(self.tri), dtype=np.complex128)
        # markers() gathers into the buffers above; the marker worker and the step thread (a state published
        # after a reset) may both encode: one at a time, or each sees the other's half-written points
        self._markers_lock = threading.Lock()
        self.cloud = np.zeros(n, dtype=POINT_DTYPE)
        self.cloud["body"] = particle_body
        spacing = float(np.median(edge_rest_length)) if len(edge_rest_length) else 0.01
        self.contact_diameter = 0.4 * spacing
        self.tool_outline = tool_outline(*tool_rounded_box) if tool_rounded_box is not None else None
        if tool_outline_local is not None:
            self.tool_outline = np.asarray(tool_outline_local, dtype=np.float64)

    def vertex_strain(self, q: np.ndarray) -> np.ndarray:
        """Signed strain per particle (:class:`~tissue_sim_ros.core.physics.strain.VertexStrain`), shape (N,), float64."""
        return self.strain(q)

    def point_cloud(self, stamp: Stamp, frame_id: str, q: np.ndarray, strain: np.ndarray) -> bytes:
        """``tissue/points``: x, y, z=0 [m], strain [-], body; float32 (body uint32)."""
        self.cloud["x"] = q[:, 0]
        self.cloud["y"] = q[:, 1]
        self.cloud["strain"] = strain
        return encode_point_cloud(stamp, frame_id, self.cloud)

    def _tool_marker(self, stamp: Stamp, frame_id: str, pose: tuple[float, float, float] | None) -> MarkerSpec:
        if pose is None or self.tool_outline is None:
            return MarkerSpec("tool", 0, MARKER_TRIANGLE_LIST, stamp, frame_id, action=ACTION_DELETE)
        x, y, yaw = pose
        c, s = math.cos(yaw), math.sin(yaw)
        o = self.tool_outline
        world = np.stack([x + c * o[:, 0] - s * o[:, 1], y + s * o[:, 0] + c * o[:, 1]], axis=1)
        k = len(world)
        tris = np.zeros((3 * k, 3), dtype="<f8")
        tris[0::3, :2] = world.mean(axis=0)  # fan from the centre: the outline is convex
        tris[1::3, :2] = world
        tris[2::3, :2] = np.roll(world, -1, axis=0)
        return MarkerSpec("tool", 0, MARKER_TRIANGLE_LIST, stamp, frame_id, position=(0.0, 0.0, 0.002),
                          color=(0.25, 0.25, 0.3, 1.0), points=tris)

    def markers(self, stamp: Stamp, frame_id: str, q: np.ndarray, strain: np.ndarray,
                tool_pose: tuple[float, float, float] | None = None, tool_stamp: Stamp | None = None,
                contact_particles: np.ndarray | None = None, grasped_particles: np.ndarray | None = None) -> bytes:
        """``tissue/markers``: tool (first; stamped with the tool pose's stamp), mesh, wireframe, contact region
        (and, for a grasper, the grasped particles).

        Parameters
        ----------
        q : ndarray
            Particle positions [m], shape (N, 2), float64, finite.
        strain : ndarray
            Per-particle strain, shape (N,) (from :meth:`vertex_strain`).
        tool_pose : (x, y, yaw), optional
            The tool pose used by the step; None: the tool marker is deleted.
        tool_stamp : (sec, nanosec), optional
            Stamp of the tool pose message used by the step (default ``stamp``).
        contact_particles : ndarray of int, optional
            Particles the contact model moved this step.
        grasped_particles : ndarray of int, optional
            Particles the grasper holds (shown in cyan when the encoder is made for a grasper).
        """
        with self._markers_lock:
            return self._markers(stamp, frame_id, q, strain, tool_pose, tool_stamp, contact_particles,
                                 grasped_particles)

    def _markers(self, stamp: Stamp, frame_id: str, q: np.ndarray, strain: np.ndarray,
                 tool_pose: tuple[float, float, float] | None, tool_stamp: Stamp | None,
                 contact_particles: np.ndarray | None, grasped_particles: np.ndarray | None = None) -> bytes:
        tri = self.tri_points
        # one compiled, GIL-free gather (core/physics/strain.py): the step thread runs while the marker thread fills these
        strain_mesh_arrays(np.ascontiguousarray(q, dtype=np.float64), self.tri_flat, self.edge_flat,
                           np.ascontiguousarray(strain, dtype=np.float64), float(self.strain_color_max), self._lut16,
                           tri, self._tri_rgba, self.wire_points, bool(self.wireframe))
        colors = self._tri_rgba.view(np.float32).reshape(-1, 4)
        specs = [self._tool_marker(stamp if tool_stamp is None else tool_stamp, frame_id, tool_pose),
                 MarkerSpec("tissue", 0, MARKER_TRIANGLE_LIST, stamp, frame_id, points=tri, colors=colors)]
        if self.wireframe:
            wire = self.wire_points
            specs.append(MarkerSpec("wireframe", 0, MARKER_LINE_LIST, stamp, frame_id, position=(0.0, 0.0, 0.001),
                                    scale=(self.wire_width, 0.0, 0.0), color=(0.1, 0.1, 0.1, 0.6), points=wire))
        if contact_particles is not None and len(contact_particles):
            d = self.contact_diameter
            specs.append(MarkerSpec("contact", 0, MARKER_SPHERE_LIST, stamp, frame_id, position=(0.0, 0.0, 0.003),
                                    scale=(d, d, d), color=(1.0, 0.85, 0.0, 0.9), points=q[contact_particles]))
        else:
            specs.append(MarkerSpec("contact", 0, MARKER_SPHERE_LIST, stamp, frame_id, action=ACTION_DELETE))
        if self.grasper:
            if grasped_particles is not None and len(grasped_particles):
                d = 1.3 * self.contact_diameter
                specs.append(MarkerSpec("grasped", 0, MARKER_SPHERE_LIST, stamp, frame_id, position=(0.0, 0.0, 0.004),
                                        scale=(d, d, d), color=(0.0, 0.8, 0.9, 1.0),
                                        points=q[np.asarray(grasped_particles, dtype=np.int64)]))
            else:
                specs.append(MarkerSpec("grasped", 0, MARKER_SPHERE_LIST, stamp, frame_id, action=ACTION_DELETE))
        return encode_marker_array(specs)

    def rest_markers(self, stamp: Stamp, frame_id: str, q0: np.ndarray, pinned: np.ndarray) -> bytes:
        """``tissue/rest_mesh``: the rest wireframe and the pinned particles, published once (latched)."""
        wire = np.zeros((2 * len(self.edges), 3), dtype="<f8")
        wire[:, :2] = q0[self.edges].reshape(-1, 2)
        d = self.contact_diameter
        specs = [MarkerSpec("rest", 0, MARKER_LINE_LIST, stamp, frame_id, position=(0.0, 0.0, -0.001),
                            scale=(self.wire_width, 0.0, 0.0), color=(0.5, 0.5, 0.5, 0.5), points=wire)]
        if np.any(pinned):
            specs.append(MarkerSpec("pinned", 0, MARKER_SPHERE_LIST, stamp, frame_id, position=(0.0, 0.0, -0.001),
                                    scale=(d, d, d), color=(0.2, 0.2, 0.2, 0.8), points=q0[pinned]))
        return encode_marker_array(specs)


def body_label(names) -> str:
    """``layout.dim[0].label`` of ``tissue/energy/bodies``: ``body:`` and the body names, comma-separated.

    A comma inside a name becomes a space, so the label splits back into one name per body.
    """
    return "body:" + ",".join(str(n).replace(",", " ") for n in names)


