"""Simulation arrays <-> serialized ROS 2 messages (CDR bytes), straight from NumPy.

One piece (past 700 lines) on purpose: every encoder and decoder shares one CDR writer and
its alignment rule, which the tests check byte for byte against rclpy's serializer.

Building a ``visualization_msgs/Marker`` with 15,000 ``geometry_msgs/Point``
objects costs ~100 ms in Python; the same message written here from a NumPy
array into XCDR1 little-endian bytes takes about a millisecond, and rclpy's
``Publisher.publish`` accepts those bytes as they are. The byte layout is the
one rmw_fastrtps writes (and ``rclpy.serialization.serialize_message``
produces): a 4-byte encapsulation header ``00 01 00 00`` (CDR, little endian),
then the fields in declaration order, every primitive aligned to its own size
counted from the end of the header, strings as ``uint32`` length (with the
terminating NUL) + bytes + NUL, sequences as ``uint32`` count + elements.
``test/test_ros_messages.py`` checks every encoder here against
``serialize_message`` byte for byte and through ``deserialize_message``.

The decoders (:func:`decode_marker_array`, :func:`decode_point_cloud`, ...)
read the same bytes back into NumPy for tests, benchmarks and controllers that
subscribe with ``raw=True``.

This module imports no rclpy and no message package: it only writes bytes.
It is one piece (about 780 lines) because every encoder, its decoder and the
step's encoding (:class:`StepEncoder`) share one CDR writer and reader and
are checked together against rclpy.
"""
from __future__ import annotations

import math
import struct
import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.contact.tool import rounded_box_outline as tool_outline  # the outline the pictures draw too
from ..core.physics.strain import VertexStrain, strain_mesh_arrays
from ..core.timing.stamps import Stamp

#: CDR little-endian encapsulation header (representation id 0x0001, options 0).
CDR_LE_HEADER = b"\x00\x01\x00\x00"

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

# sensor_msgs/PointField datatypes
POINTFIELD_DATATYPES: dict[str, int] = {"i1": 1, "u1": 2, "i2": 3, "u2": 4, "i4": 5, "u4": 6, "f4": 7, "f8": 8}
_POINTFIELD_NUMPY = {v: k for k, v in POINTFIELD_DATATYPES.items()}

#: The fields of ``tissue/points``: position [m] (z = 0, the tissue plane), signed strain [-], body index.
POINT_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("strain", "<f4"), ("body", "<u4")])

class CdrWriter:
    """Append-only XCDR1 little-endian writer; alignment counted from the end of the header."""

    __slots__ = ("_chunks", "_pos")

    def __init__(self) -> None:
        self._chunks: list[bytes] = [CDR_LE_HEADER]
        self._pos = 0

    def _align(self, n: int) -> None:
        pad = -self._pos % n
        if pad:
            self._chunks.append(b"\x00" * pad)
            self._pos += pad

    def _put(self, fmt: str, size: int, value: float | int) -> None:
        self._align(size)
        self._chunks.append(struct.pack(fmt, value))
        self._pos += size

    def bool(self, value: bool) -> None:
        self._chunks.append(b"\x01" if value else b"\x00")
        self._pos += 1

    def u8(self, value: int) -> None:
        self._chunks.append(struct.pack("<B", value))
        self._pos += 1

    def i32(self, value: int) -> None:
        self._put("<i", 4, value)

    def u32(self, value: int) -> None:
        self._put("<I", 4, value)

    def f32(self, value: float) -> None:
        self._put("<f", 4, value)

    def f64(self, value: float) -> None:
        self._put("<d", 8, value)

    def f64s(self, *values: float) -> None:
        """Consecutive float64 fields (a Point, Quaternion, Vector3)."""
        self._align(8)
        self._chunks.append(struct.pack(f"<{len(values)}d", *values))
        self._pos += 8 * len(values)

    def f32s(self, *values: float) -> None:
        """Consecutive float32 fields (a ColorRGBA)."""
        self._align(4)
        self._chunks.append(struct.pack(f"<{len(values)}f", *values))
        self._pos += 4 * len(values)

    def string(self, value: str) -> None:
        data = value.encode("utf-8") + b"\x00"
        self.u32(len(data))
        self._chunks.append(data)
        self._pos += len(data)

    def sequence(self, array: np.ndarray, count: int, align: int) -> None:
        """A sequence of ``count`` elements whose packed little-endian bytes are ``array``."""
        self.u32(count)
        if count:
            self._align(align)
            data = np.ascontiguousarray(array)  # its buffer goes straight into getvalue's join: one copy, not two
            self._chunks.append(data)
            self._pos += data.nbytes

    def header(self, stamp: Stamp, frame_id: str) -> None:
        """std_msgs/Header: builtin_interfaces/Time stamp, string frame_id."""
        self.i32(stamp[0])
        self.u32(stamp[1])
        self.string(frame_id)

    def getvalue(self) -> bytes:
        return b"".join(self._chunks)


class CdrReader:
    """Reader for the bytes :class:`CdrWriter` (or rmw) writes."""

    __slots__ = ("_buf", "_pos")

    def __init__(self, data: bytes | memoryview) -> None:
        buf = memoryview(data)
        if bytes(buf[:2]) != CDR_LE_HEADER[:2]:
            raise ValueError(f"not CDR little-endian data: header {bytes(buf[:4]).hex()}, expected 00010000")
        self._buf = buf[4:]
        self._pos = 0

    def _align(self, n: int) -> None:
        self._pos += -self._pos % n

    def _get(self, fmt: str, size: int) -> float | int:
        self._align(size)
        (value,) = struct.unpack_from(fmt, self._buf, self._pos)
        self._pos += size
        return value

    def bool(self) -> bool:
        value = self._buf[self._pos] != 0
        self._pos += 1
        return value

    def u8(self) -> int:
        value = self._buf[self._pos]
        self._pos += 1
        return value

    def i32(self) -> int:
        return int(self._get("<i", 4))

    def u32(self) -> int:
        return int(self._get("<I", 4))

    def f32(self) -> float:
        return float(self._get("<f", 4))

    def f64(self) -> float:
        return float(self._get("<d", 8))

    def f64s(self, n: int) -> tuple[float, ...]:
        self._align(8)
        values = struct.unpack_from(f"<{n}d", self._buf, self._pos)
        self._pos += 8 * n
        return values

    def f32s(self, n: int) -> tuple[float, ...]:
        self._align(4)
        values = struct.unpack_from(f"<{n}f", self._buf, self._pos)
        self._pos += 4 * n
        return values

    def string(self) -> str:
        n = self.u32()
        value = bytes(self._buf[self._pos:self._pos + n - 1]).decode("utf-8") if n else ""
        self._pos += n
        return value

    def sequence(self, dtype: np.dtype | str, align: int, width: int = 1) -> np.ndarray:
        """A sequence of ``count`` elements of ``width`` values of ``dtype`` each, as an (count, width) copy."""
        dtype = np.dtype(dtype)
        count = self.u32()
        if count == 0:
            return np.zeros((0, width), dtype=dtype)
        self._align(align)
        nbytes = count * width * dtype.itemsize
        out = np.frombuffer(self._buf, dtype=dtype, count=count * width, offset=self._pos).reshape(count, width).copy()
        self._pos += nbytes
        return out

    def header(self) -> tuple[Stamp, str]:
        sec = self.i32()
        nsec = self.u32()
        return (sec, nsec), self.string()


# --------------------------------------------------------------------------- small messages


def encode_float64(value: float) -> bytes:
    """std_msgs/Float64."""
    w = CdrWriter()
    w.f64(value)
    return w.getvalue()


def decode_float64(data: bytes) -> float:
    return CdrReader(data).f64()


def encode_uint32(value: int) -> bytes:
    """std_msgs/UInt32."""
    w = CdrWriter()
    w.u32(int(value))
    return w.getvalue()


def decode_uint32(data: bytes) -> int:
    return CdrReader(data).u32()


def encode_float64_multiarray(data: np.ndarray, labels: list[str], sizes: list[int] | None = None) -> bytes:
    """std_msgs/Float64MultiArray of a row-major array with labelled dimensions.

    Parameters
    ----------
    data : ndarray
        The values, any shape, float64; written row-major (C order).
    labels : list of str
        One label per dimension of ``data`` (``layout.dim[i].label``).
    sizes : list of int, optional
        Dimension sizes; default ``data.shape``.
    """
    arr = np.ascontiguousarray(data, dtype="<f8")
    sizes = list(arr.shape) if sizes is None else sizes
    if len(labels) != len(sizes):
        raise ValueError(f"{len(labels)} labels for {len(sizes)} dimensions")
    w = CdrWriter()
    w.u32(len(sizes))
    for i, (label, size) in enumerate(zip(labels, sizes)):
        w.string(label)
        w.u32(int(size))
        w.u32(int(np.prod(sizes[i:])))  # stride: elements spanned by one step of the previous dimension
    w.u32(0)  # data_offset
    w.sequence(arr, arr.size, 8)
    return w.getvalue()


def decode_float64_multiarray(data: bytes) -> tuple[np.ndarray, list[str]]:
    """(values reshaped to the layout's sizes, labels) of a std_msgs/Float64MultiArray."""
    r = CdrReader(data)
    labels, sizes = [], []
    for _ in range(r.u32()):
        labels.append(r.string())
        sizes.append(r.u32())
        r.u32()
    r.u32()
    values = r.sequence("<f8", 8)[:, 0]
    return (values.reshape(sizes) if sizes and int(np.prod(sizes)) == values.size else values), labels


def encode_wrench_stamped(stamp: Stamp, frame_id: str, force: tuple[float, float, float],
                          torque: tuple[float, float, float]) -> bytes:
    """geometry_msgs/WrenchStamped: force [N] and torque [N m] in ``frame_id``."""
    w = CdrWriter()
    w.header(stamp, frame_id)
    w.f64s(*force, *torque)
    return w.getvalue()


def decode_wrench_stamped(data: bytes) -> tuple[Stamp, str, np.ndarray, np.ndarray]:
    """(stamp, frame_id, force (3,), torque (3,))."""
    r = CdrReader(data)
    stamp, frame = r.header()
    values = np.array(r.f64s(6))
    return stamp, frame, values[:3], values[3:]


def decode_pose_stamped(data: bytes) -> tuple[Stamp, str, np.ndarray, np.ndarray]:
    """(stamp, frame_id, position (3,), orientation xyzw (4,)) of a geometry_msgs/PoseStamped."""
    r = CdrReader(data)
    stamp, frame = r.header()
    values = np.array(r.f64s(7))
    return stamp, frame, values[:3], values[3:]


def encode_pose_stamped(stamp: Stamp, frame_id: str, x: float, y: float, yaw: float) -> bytes:
    """geometry_msgs/PoseStamped of a planar pose (z = 0, rotation about +z by ``yaw`` [rad])."""
    w = CdrWriter()
    w.header(stamp, frame_id)
    w.f64s(x, y, 0.0, 0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw))
    return w.getvalue()


def encode_joint_state(stamp: Stamp, frame_id: str, names: list[str], positions: list[float]) -> bytes:
    """sensor_msgs/JointState with names and positions (no velocity, no effort): ``tool/jaw`` is one joint, the
    jaw angle [rad] in ``position[0]`` (as the dVRK's ``jaw/measured_js``)."""
    w = CdrWriter()
    w.header(stamp, frame_id)
    w.u32(len(names))
    for name in names:
        w.string(name)
    w.sequence(np.asarray(positions, dtype="<f8"), len(positions), 8)
    w.u32(0)  # velocity
    w.u32(0)  # effort
    return w.getvalue()


def encode_twist_stamped(stamp: Stamp, frame_id: str, vx: float, vy: float, wz: float) -> bytes:
    """geometry_msgs/TwistStamped of a planar twist (linear [m/s] in the plane, angular [rad/s] about +z)."""
    w = CdrWriter()
    w.header(stamp, frame_id)
    w.f64s(vx, vy, 0.0, 0.0, 0.0, wz)
    return w.getvalue()


# --------------------------------------------------------------------------- markers


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


def _points3(points: np.ndarray | None) -> np.ndarray:
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
    pts = _points3(m.points)
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


def _read_marker(r: CdrReader) -> DecodedMarker:
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
    return [_read_marker(r) for _ in range(r.u32())]


# --------------------------------------------------------------------------- point cloud


def encode_point_cloud(stamp: Stamp, frame_id: str, points: np.ndarray, dense: bool = True) -> bytes:
    """sensor_msgs/PointCloud2 of a structured array (one row, unordered cloud).

    Parameters
    ----------
    points : ndarray
        Structured array, shape (N,), little-endian fields of the PointField
        types (e.g. :data:`POINT_DTYPE`); written as is, ``point_step = itemsize``.
        ``dense`` (``is_dense``): True when every value is finite (the node's clouds); a tracker's cloud with
        NaN for points it lost in a frame passes False.
    """
    dtype = points.dtype
    w = CdrWriter()
    w.header(stamp, frame_id)
    w.u32(1)  # height
    w.u32(points.shape[0])  # width
    w.u32(len(dtype.names))
    for name in dtype.names:
        sub, offset = dtype.fields[name][:2]
        w.string(name)
        w.u32(offset)
        w.u8(POINTFIELD_DATATYPES[sub.base.str.lstrip("<>|=")])
        w.u32(int(np.prod(sub.shape)) if sub.shape else 1)
    w.bool(False)  # is_bigendian
    w.u32(dtype.itemsize)  # point_step
    w.u32(dtype.itemsize * points.shape[0])  # row_step
    raw = np.ascontiguousarray(points).view(np.uint8)
    w.sequence(raw, raw.size, 1)
    w.bool(dense)  # is_dense: the node never publishes NaN
    return w.getvalue()


def decode_point_cloud(data: bytes) -> tuple[Stamp, str, np.ndarray]:
    """(stamp, frame_id, structured array of shape (height*width,)) of a little-endian PointCloud2."""
    r = CdrReader(data)
    stamp, frame = r.header()
    height, width = r.u32(), r.u32()
    names, formats, offsets = [], [], []
    for _ in range(r.u32()):
        names.append(r.string())
        offsets.append(r.u32())
        datatype = r.u8()
        count = r.u32()
        base = "<" + _POINTFIELD_NUMPY[datatype]
        formats.append(base if count == 1 else (base, (count,)))
    if r.bool():
        raise ValueError("big-endian PointCloud2 is not supported")
    point_step = r.u32()
    r.u32()
    raw = r.sequence("u1", 1)[:, 0]
    r.bool()
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step})
    return stamp, frame, raw.view(dtype)[: height * width]


# --------------------------------------------------------------------------- the scene as messages


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
        # flat index arrays and preallocated buffers: np.take into them is ~3x faster than fancy indexing
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


# --------------------------------------------------------------------------- one step's outputs

#: The energy terms of ``tissue/energy/bodies``' columns, in order.
ENERGY_TERMS = ("inertial", "spring", "area", "total")
#: Columns of ``tissue/contact`` per body: touched (1/0), d* [m] (inf: beyond reach), particles moved by the contact
CONTACT_FIELDS = ("in_contact", "distance", "moved")

#: The outputs of a step (topic relative to the node's namespace -> type), as the node publishes them.
STEP_TOPICS: dict[str, str] = {
    "tissue/energy": "std_msgs/msg/Float64",
    "tissue/energy/inertial": "std_msgs/msg/Float64",
    "tissue/energy/spring": "std_msgs/msg/Float64",
    "tissue/energy/area": "std_msgs/msg/Float64",
    "tissue/energy/strain": "std_msgs/msg/Float64",
    "tissue/energy/potential": "std_msgs/msg/Float64",
    "tissue/energy/bodies": "std_msgs/msg/Float64MultiArray",
    "tissue/contact": "std_msgs/msg/Float64MultiArray",
    "tool/wrench": "geometry_msgs/msg/WrenchStamped",
    "tissue/points": "sensor_msgs/msg/PointCloud2",
    "tissue/markers": "visualization_msgs/msg/MarkerArray",
}

#: The further outputs of a step when the tool is a grasper (msg_docs/topics.md): the attachment springs' term
#: dt^2 E_attach (a term of the total) and the number of particles held.
GRASP_TOPICS: dict[str, str] = {
    "tissue/energy/attach": "std_msgs/msg/Float64",
    "tool/grasped": "std_msgs/msg/UInt32",
}


@dataclass
class StepMessages:
    """The serialized outputs of one step, topic (relative, see :data:`STEP_TOPICS`) -> CDR bytes, in publishing order.

    A message that would carry NaN is left out: ``withheld`` says which and why.
    """

    messages: dict[str, bytes] = field(default_factory=dict)
    withheld: list[str] = field(default_factory=list)
    """Why a message was left out (non-finite positions, energy or reaction); empty when none was."""


class StepEncoder:
    """A step's outputs as CDR bytes, the one encoding the node publishes and ``tissue-sim replay`` writes.

    From a :class:`~tissue_sim_ros.core.sim.simulation.StepReport` and the state
    after the step: the scene energy and its terms (total and per body), the
    reaction wrench, the points with their signed strain, and the markers. So a
    replayed bag means what a live one means, message for message.

    Parameters
    ----------
    model : Model
        The simulation's model (mesh topology, rest lengths, bodies).
    tool : ToolShape, optional
        The tool (its marker's outline); None: no tool marker.
    strain_color_max, wire_width, wireframe
        Marker appearance (see :class:`SceneEncoder`).
    """

    def __init__(self, model: Any, tool: Any = None, *, strain_color_max: float = 0.2, wire_width: float = 0.002,
                 wireframe: bool = True) -> None:
        self.scene = SceneEncoder(model.tri_indices, model.edge_indices, model.edge_rest_length, model.particle_body,
                                  tool_rounded_box=tool.rounded_box() if tool is not None else None,
                                  strain_color_max=strain_color_max, wire_width=wire_width, wireframe=wireframe,
                                  tool_outline_local=tool.outline() if tool is not None and tool.kind == "grasper"
                                  else None, grasper=tool is not None and tool.kind == "grasper")
        self.body_label = body_label(model.body_names)
        """``tissue/energy/bodies``' row label: ``body:`` and the body names."""
        self._particle_body = np.asarray(model.particle_body, dtype=np.int64)
        self._n_bodies = len(model.body_names)
        self.grasper = tool is not None and tool.kind == "grasper"
        """Encode :data:`GRASP_TOPICS` too."""

    def strain(self, q: np.ndarray) -> np.ndarray:
        """Signed vertex strain of positions ``q`` (N, 2) [m], shape (N,)."""
        return self.scene.vertex_strain(q)

    def encode(self, stamp: Stamp, frame_id: str, report: Any, q: np.ndarray, *, points: bool = True,
               markers: bool = False, tool_pose: tuple[float, float, float] | None = None,
               tool_stamp: Stamp | None = None) -> StepMessages:
        """The messages of the step ``report`` that left positions ``q`` (N, 2) [m], all stamped ``stamp``.

        Energy is left out of a step that diverged (its state was restored); with
        non-finite positions nothing is encoded. ``points`` / ``markers`` choose
        whether this step carries them (the node's rates); the tool marker
        carries ``tool_stamp`` (default ``stamp``).
        """
        out = StepMessages()
        if not np.isfinite(q).all():
            # the Simulation restores the last good state, so this is a bug guard: never publish NaN
            out.withheld.append(f"step {report.step} left non-finite positions; nothing published")
            return out
        e = report.energy
        if not report.diverged:
            terms = np.stack([e.inertial, e.spring, e.area, e.total], axis=1)  # (B, 4)
            if np.isfinite(terms).all() and np.isfinite(e.potential).all():
                out.messages["tissue/energy"] = encode_float64(float(terms[:, 3].sum()))
                for i, term in enumerate(ENERGY_TERMS[:3]):
                    out.messages[f"tissue/energy/{term}"] = encode_float64(float(terms[:, i].sum()))
                # material: dt^2 E_strain (a term of the total) and the potential energy itself [J]
                out.messages["tissue/energy/strain"] = encode_float64(float(e.strain.sum()))
                out.messages["tissue/energy/potential"] = encode_float64(e.scene_potential)
                out.messages["tissue/energy/bodies"] = encode_float64_multiarray(
                    terms, [self.body_label, "term:" + ",".join(ENERGY_TERMS)])
            else:
                out.withheld.append(f"step {report.step}: non-finite energy not published")
        if self.grasper:
            attach = getattr(e, "attach", None)
            value = float(np.sum(attach)) if attach is not None else 0.0
            if not report.diverged and math.isfinite(value):
                out.messages["tissue/energy/attach"] = encode_float64(value)
            out.messages["tool/grasped"] = encode_uint32(len(getattr(report, "grasped", ())))
        out.messages["tissue/contact"] = self.contact(report)
        f, tz = report.reaction_force, report.reaction_torque
        if np.isfinite(f).all() and math.isfinite(tz):
            out.messages["tool/wrench"] = encode_wrench_stamped(stamp, frame_id, (float(f[0]), float(f[1]), 0.0),
                                                                (0.0, 0.0, float(tz)))
        else:
            out.withheld.append(f"step {report.step}: non-finite reaction not published")
        if points or markers:
            strain = self.strain(q)
            if points:
                out.messages["tissue/points"] = self.scene.point_cloud(stamp, frame_id, q, strain)
            if markers:
                out.messages["tissue/markers"] = self.scene.markers(
                    stamp, frame_id, q, strain, tool_pose=tool_pose, tool_stamp=tool_stamp,
                    contact_particles=report.contact_particles, grasped_particles=getattr(report, "grasped", None))
        return out

    def contact(self, report: Any) -> bytes:
        """``tissue/contact`` of a step: per body, whether the tool touches it (the Simulation's ``in_contact``:
        paper model d* < alpha, projection any particle pushed), d* [m] (+inf where the tool is beyond the
        contact's reach and d* was not computed; never NaN), and how many of its particles the contact moved."""
        moved = np.bincount(self._particle_body[np.asarray(report.contact_particles, dtype=np.int64)],
                            minlength=self._n_bodies)[: self._n_bodies]
        d_star = np.where(np.isnan(report.d_star), np.inf, report.d_star)
        table = np.column_stack([np.asarray(report.in_contact, dtype=np.float64), d_star, moved.astype(np.float64)])
        return encode_float64_multiarray(table, [self.body_label, "field:" + ",".join(CONTACT_FIELDS)])

    def state(self, stamp: Stamp, frame_id: str, q: np.ndarray) -> StepMessages:
        """Points and markers of a state outside a step (after a reset): no energy, no wrench, no tool."""
        strain = self.strain(q)
        return StepMessages({"tissue/points": self.scene.point_cloud(stamp, frame_id, q, strain),
                             "tissue/markers": self.scene.markers(stamp, frame_id, q, strain)})

    def rest_markers(self, stamp: Stamp, frame_id: str, model: Any) -> bytes:
        """``tissue/rest_mesh`` of ``model``."""
        return self.scene.rest_markers(stamp, frame_id, model.particle_q0, model.particle_pinned)
