"""visualization_msgs/Marker and MarkerArray written from NumPy arrays (:class:`MarkerSpec`) and read back
(:func:`decode_marker_array`), by hand: a 5,000-triangle array is 15,000 points, and a message object per
point is what makes the message types' own encoders slow (docs/benchmarks/ros.md)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .cdr import CdrReader, CdrWriter, Stamp

# visualization_msgs/Marker type and action constants (from Marker.msg)
MARKER_ARROW = 0
MARKER_CUBE = 1
MARKER_SPHERE = 2
MARKER_CYLINDER = 3
MARKER_LINE_STRIP = 4
MARKER_LINE_LIST = 5
MARKER_CUBE_LIST = 6
MARKER_SPHERE_LIST = 7
MARKER_POINTS = 8
MARKER_TEXT_VIEW_FACING = 9
MARKER_MESH_RESOURCE = 10
MARKER_TRIANGLE_LIST = 11
ACTION_ADD = 0
ACTION_DELETE = 2
ACTION_DELETEALL = 3



@dataclass
class MarkerSpec:
    """One visualization_msgs/Marker to encode; points and colors are NumPy arrays."""

    ns: str
    id: int
    type: int
    stamp: Stamp
    frame_id: str
    action: int = ACTION_ADD
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    orientation: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    """Quaternion x, y, z, w (identity by default; RViz rejects an all-zero quaternion)."""
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    color: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    points: np.ndarray | None = None
    """Points [m], shape (K, 3), float64 (or (K, 2): z = 0 is added)."""
    colors: np.ndarray | None = None
    """Per-point RGBA in [0, 1], shape (K, 4), float32; empty or K long."""
    text: str = ""


def points3(points: np.ndarray | None) -> np.ndarray:
    if points is None:
        return np.zeros((0, 3), dtype="<f8")
    p = np.asarray(points, dtype="<f8")
    if p.ndim == 2 and p.shape[1] == 2:
        out = np.zeros((p.shape[0], 3), dtype="<f8")
        out[:, :2] = p
        return out
    return p.reshape(-1, 3)


def _write_marker(w: CdrWriter, m: MarkerSpec) -> None:
    w.header(m.stamp, m.frame_id)
    w.string(m.ns)
    w.i32(m.id)
    w.i32(m.type)
    w.i32(m.action)
    w.f64s(*m.position, *m.orientation, *m.scale)  # pose (Point, Quaternion), then scale (Vector3)
    w.f32s(*m.color)
    w.i32(0)  # lifetime.sec: 0 = forever
    w.u32(0)  # lifetime.nanosec
    w.bool(False)  # frame_locked
    pts = points3(m.points)
    w.sequence(pts, pts.shape[0], 8)
    cols = np.zeros((0, 4), dtype="<f4") if m.colors is None else np.asarray(m.colors, dtype="<f4").reshape(-1, 4)
    w.sequence(cols, cols.shape[0], 4)
    w.string("")  # texture_resource
    w.header((0, 0), "")  # texture (sensor_msgs/CompressedImage): header,
    w.string("")  # format,
    w.u32(0)  # data[]
    w.u32(0)  # uv_coordinates[]
    w.string(m.text)
    w.string("")  # mesh_resource
    w.string("")  # mesh_file.filename
    w.u32(0)  # mesh_file.data[]
    w.bool(False)  # mesh_use_embedded_materials


def encode_marker(m: MarkerSpec) -> bytes:
    """visualization_msgs/Marker."""
    w = CdrWriter()
    _write_marker(w, m)
    return w.getvalue()


def encode_marker_array(markers: list[MarkerSpec]) -> bytes:
    """visualization_msgs/MarkerArray."""
    w = CdrWriter()
    w.u32(len(markers))
    for m in markers:
        _write_marker(w, m)
    return w.getvalue()


@dataclass
class DecodedMarker:
    """A Marker read back from CDR bytes (the fields tests and benches look at)."""

    stamp: Stamp
    frame_id: str
    ns: str
    id: int
    type: int
    action: int
    position: np.ndarray
    orientation: np.ndarray
    scale: np.ndarray
    color: np.ndarray
    points: np.ndarray
    """Shape (K, 3), float64."""
    colors: np.ndarray
    """Shape (K, 4), float32."""
    text: str = ""
    extra: dict = field(default_factory=dict)


def read_marker(r: CdrReader) -> DecodedMarker:
    stamp, frame = r.header()
    ns = r.string()
    mid, mtype, action = r.i32(), r.i32(), r.i32()
    pose = np.array(r.f64s(10))
    color = np.array(r.f32s(4), dtype=np.float32)
    lifetime = (r.i32(), r.u32())
    frame_locked = r.bool()
    points = r.sequence("<f8", 8, 3)
    colors = r.sequence("<f4", 4, 4)
    texture_resource = r.string()
    r.header()
    r.string()
    r.sequence("u1", 1)
    r.sequence("<f4", 4, 2)
    text = r.string()
    mesh_resource = r.string()
    r.string()
    r.sequence("u1", 1)
    r.bool()
    return DecodedMarker(stamp, frame, ns, mid, mtype, action, pose[:3], pose[3:7], pose[7:10], color,
                         points, colors, text,
                         extra={"lifetime": lifetime, "frame_locked": frame_locked,
                                "texture_resource": texture_resource, "mesh_resource": mesh_resource})


def decode_marker_array(data: bytes) -> list[DecodedMarker]:
    r = CdrReader(data)
    return [read_marker(r) for _ in range(r.u32())]

