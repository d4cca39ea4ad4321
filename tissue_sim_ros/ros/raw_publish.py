"""Publishing CDR bytes with the GIL released, for the ~1 MB MarkerArray on the marker thread.

rclpy's ``Publisher.publish(bytes)`` (``publish_raw`` in rclpy's C++) copies
the bytes into a ``std::string`` and calls ``rcl_publish_serialized_message``
while holding the GIL. For a 5,000-triangle MarkerArray (1 MB, reliable) the
DDS write takes 0.7-1.8 ms at the median and up to ~6 ms, and the node's step
thread cannot run a line of Python meanwhile. Measured in one process (a
Python loop beside a thread publishing 1 MB at 30 Hz to a subscriber in
another process, 150 arrays, 2 runs each): the loop was held more than 1 ms
17-25 times by rclpy's publish, 0-1 times by this one (longest hold 4.1-4.8 ms
against 0.7-2.9 ms).

:class:`GilFreePublisher` calls the same rcl function through ctypes, which
releases the GIL for the call's duration, on the caller's own buffer (no
copy). rcl documents ``rcl_publish_serialized_message`` as thread-safe for a
publisher that is not being finalized; the rclpy handle's context manager
keeps it alive during the call, as rclpy's own ``publish`` does. Anything
else than bytes, or a process where librcl is not found, goes through
rclpy's ``publish`` unchanged.

The structure passed is ``rcl_serialized_message_t`` (``rcutils_uint8_array_t``:
buffer, length, capacity, then an ``rcutils_allocator_t`` of four function
pointers and a state pointer), unchanged from Foxy to Jazzy; rcl does not
use its allocator to publish, so it is left zeroed.
"""
from __future__ import annotations

import ctypes
import functools
import re
from pathlib import Path
from typing import Any


class _Allocator(ctypes.Structure):
    _fields_ = [("allocate", ctypes.c_void_p), ("deallocate", ctypes.c_void_p),
                ("reallocate", ctypes.c_void_p), ("zero_allocate", ctypes.c_void_p),
                ("state", ctypes.c_void_p)]


class _SerializedMessage(ctypes.Structure):
    _fields_ = [("buffer", ctypes.c_void_p), ("buffer_length", ctypes.c_size_t),
                ("buffer_capacity", ctypes.c_size_t), ("allocator", _Allocator)]


def _loaded_librcl() -> str | None:
    """Path of the librcl.so this process already loaded (through rclpy), from /proc/self/maps."""
    try:
        maps = Path("/proc/self/maps").read_text()
    except OSError:
        return None
    found = re.search(r"(/\S*/librcl\.so(?:\.\d+)*)\s*$", maps, re.MULTILINE)
    return found.group(1) if found else None


@functools.cache
def rcl_publish_serialized() -> Any:
    """ctypes function for ``rcl_publish_serialized_message`` of the loaded librcl, or None (looked up once)."""
    path = _loaded_librcl()
    if path is None:
        return None
    try:
        fn = ctypes.CDLL(path).rcl_publish_serialized_message  # CDLL: the GIL is released per call
    except (OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_void_p, ctypes.POINTER(_SerializedMessage), ctypes.c_void_p]
    fn.restype = ctypes.c_int
    return fn


class GilFreePublisher:
    """Wraps an rclpy Publisher: ``publish(bytes)`` without holding the GIL; everything else as the Publisher.

    ``gil_free`` tells which path it takes (False where librcl could not be
    found: rclpy's publish then).
    """

    def __init__(self, publisher: Any) -> None:
        self._publisher = publisher
        self._fn = rcl_publish_serialized()
        self.gil_free = self._fn is not None

    def publish(self, msg: Any) -> None:
        if self._fn is None or not isinstance(msg, bytes):
            self._publisher.publish(msg)
            return
        # a bytes object's buffer, not a copy: ``msg`` is referenced until the call returns
        message = _SerializedMessage(ctypes.cast(ctypes.c_char_p(msg), ctypes.c_void_p), len(msg), len(msg))
        with self._publisher.handle:
            ret = self._fn(self._publisher.handle.pointer, ctypes.byref(message), None)
        if ret != 0:
            raise RuntimeError(f"rcl_publish_serialized_message on {self._publisher.topic_name} returned {ret}")

    def __getattr__(self, name: str) -> Any:  # topic_name, msg_type, qos_profile, destroy, ...
        return getattr(self._publisher, name)
