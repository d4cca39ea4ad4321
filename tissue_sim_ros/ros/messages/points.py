"""sensor_msgs/PointCloud2 written from a structured NumPy array and read back into one, by hand: the cloud's
bytes are the array's (docs/benchmarks/ros.md)."""
from __future__ import annotations

import numpy as np

from .cdr import CdrReader, CdrWriter, Stamp

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


