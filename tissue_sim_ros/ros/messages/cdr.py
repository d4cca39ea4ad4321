"""The CDR writer and reader of the markers' fast path (:mod:`.markers`; a JointState's positions,
:mod:`.small`): XCDR1 little endian straight from and into NumPy arrays.

The byte layout is the one rmw_fastrtps writes (and ``rclpy.serialization.serialize_message`` produces): a
4-byte encapsulation header ``00 01 00 00`` (CDR, little endian), then the fields in declaration order, every
primitive aligned to its own size counted from the end of the header, strings as ``uint32`` length (with the
terminating NUL) + bytes + NUL, sequences as ``uint32`` count + elements.
"""
from __future__ import annotations

import struct

import numpy as np

from ...core.timing.stamps import Stamp

__all__ = ["CDR_LE_HEADER", "CdrReader", "CdrWriter", "Stamp"]

#: CDR little-endian encapsulation header (representation id 0x0001, options 0).
CDR_LE_HEADER = b"\x00\x01\x00\x00"


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


