"""Publishing CDR bytes with the GIL released, for the 1 MB MarkerArray on the marker thread.

rclpy's ``Publisher.publish(bytes)`` (``publish_raw`` in rclpy's C++) copies the bytes into a ``std::string``
and calls ``rcl_publish_serialized_message`` while holding the GIL: for as long as DDS takes a 1 MB write, the
node's step thread cannot run a line of Python. rclpy offers no public call that lets the GIL go.
:class:`GilFreePublisher` calls the same rcl function through ctypes, which releases the GIL for the call's
duration, on the caller's own buffer (no copy). ``docs/benchmarks/ros.md`` measures the two side by side
(``tissue-sim bench ros``).

rcl documents ``rcl_publish_serialized_message`` as thread-safe for a publisher that is not being finalized; the
rclpy handle's context manager keeps it alive during the call, as rclpy's own ``publish`` does. The structure
passed is ``rcl_serialized_message_t`` (``rcutils_uint8_array_t``: buffer, length, capacity, then an
``rcutils_allocator_t`` of four function pointers and a state pointer); rcl does not use its allocator to
publish, so it is left zeroed. That layout, and the publisher handle's ``pointer``, were checked against the
rclpy releases of :data:`RCLPY_CHECKED` (``test_marker_publisher.py`` fails on another one); with any other
rclpy, with anything else than bytes, or where librcl is not found, it publishes through rclpy's ``publish``.
"""
from __future__ import annotations

import ctypes
import functools
import re
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

#: The rclpy releases (version prefixes: Jazzy's) whose publisher handle and serialized-message layout this
#: module was checked against.
RCLPY_CHECKED = ("7.",)


def rclpy_checked() -> bool:
    """Whether the installed rclpy is one of :data:`RCLPY_CHECKED`."""
    try:
        return version("rclpy").startswith(RCLPY_CHECKED)
    except PackageNotFoundError:
        return False


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
    """ctypes function for ``rcl_publish_serialized_message`` of the loaded librcl, or None (looked up once; None
    also with an rclpy this module was not checked against)."""
    if not rclpy_checked():
        return None
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
    found or rclpy is not one of :data:`RCLPY_CHECKED`: rclpy's publish then).
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
