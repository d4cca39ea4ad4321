"""sensor_msgs/PointCloud2 of a structured NumPy array and back, through ``rosbags``' typestore: its ``data`` is the
array's bytes as one NumPy array, so this is as fast as writing the bytes by hand (docs/benchmarks/ros.md)."""
from __future__ import annotations

import numpy as np

from ..typestore import msg_class
from .cdr import Stamp
from .small import decode, encode, header

POINT_CLOUD2 = "sensor_msgs/msg/PointCloud2"

# sensor_msgs/PointField datatypes
POINTFIELD_DATATYPES: dict[str, int] = {"i1": 1, "u1": 2, "i2": 3, "u2": 4, "i4": 5, "u4": 6, "f4": 7, "f8": 8}
_POINTFIELD_NUMPY = {v: k for k, v in POINTFIELD_DATATYPES.items()}

#: The fields of ``tissue/points``: position [m] (z = 0, the tissue plane), signed strain [-], body index.
POINT_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("strain", "<f4"), ("body", "<u4")])


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
    field = msg_class("sensor_msgs/msg/PointField")
    fields = []
    for name in dtype.names:
        sub, offset = dtype.fields[name][:2]
        fields.append(field(name=name, offset=int(offset), datatype=POINTFIELD_DATATYPES[sub.base.str.lstrip("<>|=")],
                            count=int(np.prod(sub.shape)) if sub.shape else 1))
    raw = np.ascontiguousarray(points).view(np.uint8).reshape(-1)
    msg = msg_class(POINT_CLOUD2)(header=header(stamp, frame_id), height=1, width=int(points.shape[0]),
                                  fields=fields, is_bigendian=False, point_step=dtype.itemsize,
                                  row_step=dtype.itemsize * int(points.shape[0]), data=raw, is_dense=bool(dense))
    return encode(msg, POINT_CLOUD2)


def decode_point_cloud(data: bytes) -> tuple[Stamp, str, np.ndarray]:
    """(stamp, frame_id, structured array of shape (height*width,)) of a PointCloud2 with little-endian points."""
    msg = decode(data, POINT_CLOUD2)
    if msg.is_bigendian:
        raise ValueError("big-endian PointCloud2 is not supported")
    names, formats, offsets = [], [], []
    for f in msg.fields:
        base = "<" + _POINTFIELD_NUMPY[f.datatype]
        names.append(f.name)
        offsets.append(f.offset)
        formats.append(base if f.count == 1 else (base, (f.count,)))
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": msg.point_step})
    raw = np.array(msg.data, dtype=np.uint8)  # a copy the caller may write into
    return (int(msg.header.stamp.sec), int(msg.header.stamp.nanosec)), msg.header.frame_id, \
        raw.view(dtype)[: msg.height * msg.width]
