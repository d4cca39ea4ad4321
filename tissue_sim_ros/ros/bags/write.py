"""Writing a bag: :class:`BagWriter` takes serialized CDR bytes and keeps them, flushed, whatever interrupts it.

It writes through rosbags' :class:`~rosbags.rosbag2.Writer` (topics, Jazzy definitions and type hashes,
``metadata.yaml``) on the storages of :mod:`.storage`, and adds what a live recording needs:

* the bytes as given (what ``raw=True`` subscriptions deliver and the node's encoders produce): a large message
  is never decoded and encoded again;
* a flush every ``flush_period`` seconds (MCAP: the pending chunk is written; sqlite3: committed), so a crash
  loses at most that much, and ``tissue-sim record --recover`` (:func:`~.recover.recover_bag`) turns what an
  interrupted recording left into a closed bag;
* custom data in ``metadata.yaml``, and with ``durable=True`` in the storage file at once, so a killed recording
  keeps it;
* one writer at a time (a lock: the node's step, marker and executor threads all write), ``close()`` idempotent,
  and SIGINT/SIGTERM held back while a record or the index is written, so an interrupt never leaves half of one.
"""
from __future__ import annotations

import contextlib
import math
import signal
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterator

import numpy as np

from ...core.errors import InputError
from ..typestore import typestore
from .storage import STORAGES, McapStorage, Sqlite3Storage

if TYPE_CHECKING:
    from rosbags.interfaces import Connection

_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """Hold SIGINT/SIGTERM back for the duration; they are raised again right after.

    Python runs signal handlers in the main thread between bytecodes, so a
    KeyboardInterrupt could otherwise land in the middle of a storage record
    and corrupt the bag. Blocking the signal with pthread_sigmask is not
    enough (another thread - an executor, tqdm's monitor - takes it and the
    handler still runs here), so the Python handlers are swapped for one that
    only notes the signal. In other threads nothing is needed: Python handlers
    never run there. A handler installed from C (rclpy's) is left alone: it
    raises nothing in Python.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []
    saved: dict[int, Any] = {}
    note = lambda signum, _frame: pending.append(signum)  # noqa: E731
    for sig in _SIGNALS:
        handler = signal.getsignal(sig)
        if callable(handler):  # SIG_DFL/SIG_IGN (ints) or None: a handler installed from C may be behind it
            saved[sig] = handler
            signal.signal(sig, note)
    try:
        yield
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)
        for sig in pending:
            signal.raise_signal(sig)


def _rosbags_writer(path: Path, storage: str) -> tuple[Any, list[Any]]:
    """rosbags' Writer for ``path`` on the storage of :mod:`.storage`, and a list that holds that storage once
    the writer is opened (rosbags makes it from the class its ``STORAGE_PLUGINS`` names)."""
    from rosbags.rosbag2 import StoragePlugin, Writer  # noqa: PLC0415

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    made: list[Any] = []

    def make(storage_path: Path, compression: Any) -> Any:
        made.append((McapStorage if storage == "mcap" else Sqlite3Storage)(storage_path, compression))
        return made[-1]

    class _Writer(Writer):
        STORAGE_PLUGINS = {plugin: make}

    return _Writer(path, version=9, storage_plugin=plugin), made


def qos_profile(reliable: bool, transient_local: bool, depth: int) -> Any:
    """A rosbags Qos record (durations 0 = unspecified, i.e. the RMW default: infinite)."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime  # noqa: PLC0415

    zero = QosTime(0, 0)
    return Qos(history=QosHistory.KEEP_LAST, depth=int(depth),
               reliability=QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
               durability=QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE,
               deadline=zero, lifespan=zero, liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=zero,
               avoid_ros_namespace_conventions=False)


class BagWriter:
    """Write a rosbag2 bag from serialized CDR messages (module docstring).

    Parameters
    ----------
    path : str or Path
        The bag directory to create (must not exist; rosbag2 never overwrites).
    storage : {"mcap", "sqlite3"}
        Storage plugin; MCAP by default, as in Jazzy's ``ros2 bag record``.
    flush_period : float
        Seconds between flushes to disk. A crash loses at most this much. 0 flushes after every message.
    hold_signals : bool
        Hold SIGINT/SIGTERM back while writing (:func:`signals_held`). A process whose signals are handled from
        C (a node: rclpy's handlers, or its own) passes False: there a signal raises nothing mid-write, and
        swapping Python's handlers would uninstall the C one.

    Examples
    --------
    >>> with BagWriter("run1") as bag:                       # doctest: +SKIP
    ...     bag.add_topic("/tissue/energy", "std_msgs/msg/Float64")
    ...     bag.write("/tissue/energy", cdr_bytes, t_ns)
    """

    def __init__(self, path: str | Path, storage: str = "mcap", *, flush_period: float = 1.0,
                 hold_signals: bool = True) -> None:
        from rosbags.rosbag2 import WriterError  # noqa: PLC0415

        if storage not in STORAGES:
            raise InputError(f"bag storage {storage!r}: expected one of {', '.join(STORAGES)}")
        if not math.isfinite(flush_period) or flush_period < 0:
            raise InputError(f"flush_period={flush_period!r}: expected seconds >= 0")
        self.path = Path(path)
        self.storage = storage
        self.flush_period = float(flush_period)
        self._hold = signals_held if hold_signals else contextlib.nullcontext
        if self.path.exists():
            raise InputError(f"bag {str(self.path)!r} exists already: choose a new output path (rosbag2 never overwrites)")
        if not self.path.parent.exists():
            raise InputError(f"bag {str(self.path)!r}: the directory {str(self.path.parent)!r} does not exist")
        self._writer, made = _rosbags_writer(self.path, storage)
        try:
            self._writer.open()
        except (WriterError, OSError) as exc:
            raise InputError(f"cannot create bag {str(self.path)!r}: {exc}") from None
        self._storage = made[0]
        self._lock = threading.Lock()
        self._connections: dict[str, "Connection"] = {}
        self._counts: dict[str, int] = {}
        self._last_flush = time.monotonic()
        self._closed = False

    # -- topics
    def add_topic(self, name: str, msgtype: str, *, reliable: bool | None = None, transient_local: bool = False,
                  depth: int = 10) -> None:
        """Declare a topic with its ROS 2 type (``pkg/msg/Type``), definition and hash from the Jazzy typestore.

        Declaring the same topic again with the same type is a no-op; with
        another type it is an InputError (one type per topic, as in rosbag2).

        ``reliable`` (None: not recorded), ``transient_local`` and ``depth``
        are stored as the topic's offered QoS, which ``ros2 bag play`` uses to
        publish it again (a latched topic stays latched).
        """
        store = typestore()
        if msgtype not in store.fielddefs:
            raise InputError(f"topic {name!r}: message type {msgtype!r} is not in the ROS 2 Jazzy typestore "
                             "(expected e.g. 'std_msgs/msg/Float64')")
        with self._lock:
            self._check_open()
            existing = self._connections.get(name)
            if existing is not None:
                if existing.msgtype != msgtype:
                    raise InputError(f"topic {name!r} was added as {existing.msgtype}, not {msgtype}")
                return
            qos = () if reliable is None else (qos_profile(reliable, transient_local, depth),)
            with self._hold():
                self._connections[name] = self._writer.add_connection(name, msgtype, typestore=store,
                                                                      offered_qos_profiles=qos)
            self._counts[name] = 0

    @property
    def topics(self) -> dict[str, str]:
        """Declared topics and their types."""
        return {name: conn.msgtype for name, conn in self._connections.items()}

    @property
    def counts(self) -> dict[str, int]:
        """Messages written per topic so far."""
        return dict(self._counts)

    @property
    def closed(self) -> bool:
        return self._closed

    def set_custom_data(self, key: str, value: str, *, durable: bool = False) -> None:
        """A string in the bag's ``metadata.yaml`` ``custom_data`` (rosbag2's own field; written at close).

        ``durable``: also written into the storage file now and put on disk (:mod:`.storage`), so a recording
        killed before its close still holds it: :class:`~.read.Bag` reads it from there, and
        :func:`~.recover.recover_bag` copies it into the bag it writes.
        """
        if not isinstance(key, str) or not isinstance(value, str):
            raise InputError(f"custom_data {key!r}: expected a string key and value, got {type(value).__name__}")
        with self._lock:
            self._check_open()
            self._writer.set_custom_data(key, value)
            if durable:
                with self._hold():
                    self._storage.set_durable(key, value)

    # -- messages
    def _connection(self, name: str, t_ns: int) -> "Connection":
        conn = self._connections.get(name)
        if conn is None:
            raise InputError(f"topic {name!r} was not added to bag {str(self.path)!r}; added: "
                             f"{', '.join(sorted(self._connections)) or 'none'}")
        if int(t_ns) < 0:
            raise InputError(f"timestamp {t_ns} ns for topic {name!r}: expected >= 0")
        return conn

    def write(self, name: str, data: bytes | bytearray | memoryview | np.ndarray, t_ns: int) -> None:
        """Write one serialized (CDR, with encapsulation header) message at receive time ``t_ns`` [ns].

        The bytes are stored as given: no decoding, no re-encoding.
        """
        conn = self._connection(name, t_ns)
        if isinstance(data, np.ndarray):
            data = memoryview(np.ascontiguousarray(data).view(np.uint8).reshape(-1))
        with self._lock:
            self._check_open()
            with self._hold():
                self._writer.write(conn, int(t_ns), data)
                self._counts[name] += 1
                self._maybe_flush()

    def write_many(self, items: list[tuple[str, bytes | bytearray | memoryview, int]]) -> None:
        """Write several ``(name, data, t_ns)`` at once (one lock and one signal hold: cheaper per message)."""
        conns = [self._connection(name, t_ns) for name, _, t_ns in items]
        with self._lock:
            self._check_open()
            with self._hold():
                for conn, (name, data, t_ns) in zip(conns, items):
                    self._writer.write(conn, int(t_ns), data)
                    self._counts[name] += 1
                self._maybe_flush()

    def write_message(self, name: str, msg: Any, t_ns: int) -> None:
        """Serialize a ``rosbags`` message object with the Jazzy typestore and write it."""
        conn = self._connection(name, t_ns)
        self.write(name, typestore().serialize_cdr(msg, conn.msgtype), t_ns)

    def _maybe_flush(self) -> None:
        now = time.monotonic()
        if now - self._last_flush >= self.flush_period:
            self._storage.flush()
            self._last_flush = now

    def flush(self) -> None:
        """Put everything written so far on disk."""
        with self._lock:
            if not self._closed:
                with self._hold():
                    self._storage.flush()

    def close(self) -> None:
        """Write the index and ``metadata.yaml``; safe to call twice and from a signal handler's cleanup."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            with self._hold():
                self._writer.close()

    def _check_open(self) -> None:
        if self._closed:
            raise InputError(f"bag {str(self.path)!r} is closed")

    def __enter__(self) -> "BagWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:  # a forgotten close still leaves a readable bag
        with contextlib.suppress(Exception):
            if not self._closed:
                self.close()
