"""rosbag2 bags with the ``rosbags`` library: write, read, and tool trajectories from bags.

One piece (past 700 lines) on purpose: writing and reading share the type registry, the
two storage back ends (MCAP, sqlite3) and the stamp policy, and the recorder, the node and
replay use both sides of them.

No rclpy here: ``tissue-sim replay`` uses this module offline, ``tissue-sim
record`` and the ROS node write with :class:`BagWriter` (thread-safe, so an
executor's callbacks can call it). Bags are ordinary
rosbag2 bags (a directory with ``metadata.yaml`` and one ``.mcap`` or ``.db3``
file) with the Jazzy type names, message definitions and type hashes, so they
open in ``ros2 bag``, Foxglove and PlotJuggler.

Writing
    :class:`BagWriter` takes *serialized* CDR bytes (what ``raw=True``
    subscriptions deliver and what the node's encoders produce), so large
    messages are never decoded and re-encoded. It flushes every
    ``flush_period`` seconds (MCAP: closes the pending chunk; sqlite3:
    commits), so a crash loses at most that much, and :func:`recover_bag`
    (``tissue-sim record --recover``) turns what an interrupted recording
    wrote into a closed bag. ``custom_data`` goes into ``metadata.yaml`` when
    the bag closes; a value set with ``durable=True`` is also written into the
    storage file at once (MCAP: a Metadata record named ``tissue_sim``;
    sqlite3: the table ``tissue_sim_custom_data``), so a killed recording keeps
    it and ``recover_bag`` carries it over. ``close()`` is idempotent, serialised by a lock,
    and SIGINT/SIGTERM are held back while a record or the bag's index is
    being written, so an interrupt never leaves a half-written record.

Reading
    :class:`Bag` opens a bag (directory, ``.mcap`` or ``.db3``) and turns every
    failure (not a bag, empty, truncated, corrupt) into an
    :class:`~tissue_sim_ros.core.errors.InputError` naming the path.
    :func:`read_tool_track` extracts the tool's planar trajectory from any
    message that carries a pose (:data:`POSE_TYPES`), with an optional twist
    topic (:data:`TWIST_TYPES`).

Timestamp policy of :func:`read_tool_track` (documented, never silent):
    the time of a sample is its ``header.stamp`` when the type has a header and
    the stamp is non-zero, else the bag's receive time (``time_source="bag"``
    forces the receive time). A sample whose time equals the previous kept
    sample's (``repeated``) or precedes it (``out_of_order``) is skipped and
    counted; a sample with a non-finite position or an invalid quaternion is
    skipped and counted (``non_finite``, ``bad_quaternion``).
    ``on_bad_time="error"`` (times) and ``on_bad_pose="error"`` (positions,
    quaternions) raise :class:`BadSampleError` instead. The counts travel with
    the track (:attr:`ToolTrack.skipped`) and ``tissue-sim replay`` prints them.

One module for all three (about 900 lines): writing, recovering and reading
share the storage formats' details (MCAP records, the sqlite3 schema, the
custom data kept in both), which are kept in one place.
"""
from __future__ import annotations

import contextlib
import math
import signal
import struct
import threading
import time
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterator

import numpy as np

from ..core.contact.tool import interpolate_poses, yaw_from_quaternion
from ..core.errors import InputError
from ..core.timing.stamps import stamp_to_ns

if TYPE_CHECKING:
    from rosbags.interfaces import Connection
    from rosbags.typesys.store import Typestore

STORAGES = ("mcap", "sqlite3")
"""Storage plugins accepted by :class:`BagWriter` (rosbag2's own identifiers)."""

POSE_TYPES = (
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/Pose",
    "geometry_msgs/msg/TransformStamped",
    "tf2_msgs/msg/TFMessage",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    "nav_msgs/msg/Odometry",
)
"""Message types a tool pose is read from (TFMessage needs a child frame)."""

TWIST_TYPES = ("geometry_msgs/msg/TwistStamped", "geometry_msgs/msg/Twist")
"""Message types a tool velocity is read from."""

JAW_TYPE = "sensor_msgs/msg/JointState"
#: A grasper's jaw in a bag: a JointState topic named the node's ``tool/jaw`` or a dVRK arm's ``jaw/measured_js``.
JAW_SUFFIXES = ("tool/jaw", "jaw/measured_js")


def is_jaw_topic(topic: str, msgtype: str) -> bool:
    """Whether ``topic`` carries a grasper's jaw angle (a JointState named like :data:`JAW_SUFFIXES`)."""
    t = topic.rstrip("/")
    return msgtype == JAW_TYPE and any(t == s or t.endswith("/" + s) for s in JAW_SUFFIXES)

TF_TYPE = "tf2_msgs/msg/TFMessage"

SKIP_REASONS = ("repeated", "out_of_order", "non_finite", "bad_quaternion")
"""Why :func:`read_tool_track` skips a sample (the keys of :attr:`ToolTrack.skipped`)."""

NODE_TOOL_OUTPUTS = ("tool/applied_pose", "tool/applied_twist", "tool/applied_jaw")
"""The node's own tool outputs (relative names): the pose and twist it stepped with (msg_docs/topics.md).
They carry a pose and a twist, but they are what the node did, not a tool's input: neither ``read_tool_track``
without a topic nor ``tissue-sim play`` without ``--topics`` takes them (``replay --mode applied`` does)."""


def is_node_tool_output(topic: str) -> bool:
    """Whether ``topic`` is one of :data:`NODE_TOOL_OUTPUTS` in any namespace (``/left/tool/applied_pose``)."""
    t = topic.rstrip("/")
    return any(t == name or t.endswith("/" + name) for name in NODE_TOOL_OUTPUTS)


class BadSampleError(InputError):
    """A tool sample :func:`read_tool_track` was told to refuse (``on_bad_time``/``on_bad_pose`` "error")."""


_MCAP_MAGIC = b"\x89MCAP0\r\n"
_SIGNALS = (int(signal.SIGINT), int(signal.SIGTERM))
try:  # the C functions: the signal module wraps them in enum conversions that cost ~10 us a call
    from _signal import getsignal as _getsignal
    from _signal import signal as _setsignal
except ImportError:  # pragma: no cover
    _getsignal, _setsignal = signal.getsignal, signal.signal


@lru_cache(maxsize=1)
def typestore() -> "Typestore":
    """The ROS 2 Jazzy typestore of ``rosbags`` (type names, definitions, hashes, CDR)."""
    from rosbags.typesys import Stores, get_typestore  # noqa: PLC0415

    return get_typestore(Stores.ROS2_JAZZY)


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
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
        handler = _getsignal(sig)
        if callable(handler):  # SIG_DFL/SIG_IGN (ints) or None: a handler installed from C may be behind it
            saved[sig] = handler
            _setsignal(sig, note)
    try:
        yield
    finally:
        for sig, handler in saved.items():
            _setsignal(sig, handler)
        for sig in pending:
            signal.raise_signal(sig)


# --------------------------------------------------------------------------- writing


class BagWriter:
    """Write a rosbag2 bag from serialized CDR messages.

    Parameters
    ----------
    path : str or Path
        The bag directory to create (must not exist; rosbag2 never overwrites).
    storage : {"mcap", "sqlite3"}
        Storage plugin; MCAP by default, as in Jazzy's ``ros2 bag record``.
    flush_period : float
        Seconds between flushes to disk (MCAP: the pending chunk is closed and
        written; sqlite3: the transaction is committed). A crash loses at most
        this much. 0 flushes after every message.

    Examples
    --------
    >>> with BagWriter("run1") as bag:                       # doctest: +SKIP
    ...     bag.add_topic("/tissue/energy", "std_msgs/msg/Float64")
    ...     bag.write("/tissue/energy", cdr_bytes, t_ns)
    """

    def __init__(self, path: str | Path, storage: str = "mcap", *, flush_period: float = 1.0,
                 hold_signals: bool = True) -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer  # noqa: PLC0415
        from rosbags.rosbag2.errors import WriterError  # noqa: PLC0415

        if storage not in STORAGES:
            raise InputError(f"bag storage {storage!r}: expected one of {', '.join(STORAGES)}")
        if not math.isfinite(flush_period) or flush_period < 0:
            raise InputError(f"flush_period={flush_period!r}: expected seconds >= 0")
        self.path = Path(path)
        self.storage = storage
        self.flush_period = float(flush_period)
        # a process whose signals rclpy handles from C (a node) must not have its handlers swapped: there a
        # signal raises nothing mid-write, and restoring Python's table would uninstall rclpy's handler
        self._hold = _signals_held if hold_signals else contextlib.nullcontext
        if self.path.exists():
            raise InputError(f"bag {str(self.path)!r} exists already: choose a new output path (rosbag2 never overwrites)")
        if not self.path.parent.exists():
            raise InputError(f"bag {str(self.path)!r}: the directory {str(self.path.parent)!r} does not exist")
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        self._writer = Writer(self.path, version=9, storage_plugin=plugin)
        try:
            self._writer.open()
        except (WriterError, OSError) as exc:
            raise InputError(f"cannot create bag {str(self.path)!r}: {exc}") from None
        if storage == "sqlite3":
            self._share_sqlite_connection()
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
            qos = () if reliable is None else (_qos_profile(reliable, transient_local, depth),)
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

        ``durable``: also written into the storage file now and put on disk (MCAP: a Metadata record named
        ``tissue_sim`` in the data section; sqlite3: a row of the table ``tissue_sim_custom_data``), so a
        recording killed before its close still holds it: :class:`Bag` reads it from there, and
        :func:`recover_bag` copies it into the bag it writes.
        """
        if not isinstance(key, str) or not isinstance(value, str):
            raise InputError(f"custom_data {key!r}: expected a string key and value, got {type(value).__name__}")
        with self._lock:
            self._check_open()
            self._writer.set_custom_data(key, value)
            if durable:
                with self._hold():
                    self._write_durable(key, value)

    def _write_durable(self, key: str, value: str) -> None:
        st = self._writer.storage
        if hasattr(st, "close_chunk"):  # MCAP: a top-level record (pending chunks stay in memory until closed)
            st.bio.write(_mcap_metadata_record(CUSTOM_DATA_RECORD, {key: value}))
            st.bio.flush()
        else:  # sqlite3
            st.conn.execute(f"CREATE TABLE IF NOT EXISTS {CUSTOM_DATA_TABLE}(key TEXT PRIMARY KEY, value TEXT NOT NULL)")
            st.conn.execute(f"INSERT OR REPLACE INTO {CUSTOM_DATA_TABLE}(key, value) VALUES(?, ?)", (key, value))
            st.conn.commit()

    # -- messages
    def write(self, name: str, data: bytes | bytearray | memoryview | np.ndarray, t_ns: int) -> None:
        """Write one serialized (CDR, with encapsulation header) message at receive time ``t_ns`` [ns].

        The bytes are stored as given: no decoding, no re-encoding.
        """
        conn = self._connections.get(name)
        if conn is None:
            raise InputError(f"topic {name!r} was not added to bag {str(self.path)!r}; added: "
                             f"{', '.join(sorted(self._connections)) or 'none'}")
        t_ns = int(t_ns)
        if t_ns < 0:
            raise InputError(f"timestamp {t_ns} ns for topic {name!r}: expected >= 0")
        if isinstance(data, np.ndarray):
            data = memoryview(np.ascontiguousarray(data).view(np.uint8).reshape(-1))
        with self._lock:
            self._check_open()
            with self._hold():
                self._writer.write(conn, t_ns, data)
                self._counts[name] += 1
                now = time.monotonic()
                if now - self._last_flush >= self.flush_period:
                    self._flush_locked()
                    self._last_flush = now

    def write_many(self, items: list[tuple[str, bytes | bytearray | memoryview, int]]) -> None:
        """Write several ``(name, data, t_ns)`` at once (one lock and one signal hold: cheaper per message)."""
        conns = []
        for name, data, t_ns in items:
            conn = self._connections.get(name)
            if conn is None:
                raise InputError(f"topic {name!r} was not added to bag {str(self.path)!r}; added: "
                                 f"{', '.join(sorted(self._connections)) or 'none'}")
            if int(t_ns) < 0:
                raise InputError(f"timestamp {t_ns} ns for topic {name!r}: expected >= 0")
            conns.append(conn)
        with self._lock:
            self._check_open()
            with self._hold():
                for conn, (name, data, t_ns) in zip(conns, items):
                    self._writer.write(conn, int(t_ns), data)
                    self._counts[name] += 1
                now = time.monotonic()
                if now - self._last_flush >= self.flush_period:
                    self._flush_locked()
                    self._last_flush = now

    def write_message(self, name: str, msg: Any, t_ns: int) -> None:
        """Serialize a ``rosbags`` message object with the Jazzy typestore and write it."""
        conn = self._connections.get(name)
        if conn is None:
            raise InputError(f"topic {name!r} was not added to bag {str(self.path)!r}")
        self.write(name, typestore().serialize_cdr(msg, conn.msgtype), t_ns)

    def flush(self) -> None:
        """Put everything written so far on disk (MCAP: close the pending chunk; sqlite3: commit)."""
        with self._lock:
            if not self._closed:
                with self._hold():
                    self._flush_locked()

    def _share_sqlite_connection(self) -> None:
        """Let every thread write: rosbags' sqlite3 storage opens its connection in the opening thread with
        Python's default ``check_same_thread=True``, so the node's marker thread (or any writer but the one that
        opened the bag) got "SQLite objects created in a thread can only be used in that same thread" and its
        messages never reached the bag. The connection is reopened shared; this class's lock already
        serialises every use of it, which is what that check protects."""
        import sqlite3  # noqa: PLC0415

        st = self._writer.storage
        st.conn.commit()
        st.conn.close()
        st.conn = sqlite3.connect(f"file:{st.path}", uri=True, check_same_thread=False)
        st.cursor = st.conn.cursor()

    def _flush_locked(self) -> None:
        # rosbags has no public flush; these are its storage writers' own steps (rosbags 0.10/0.11).
        st = self._writer.storage
        if st is None:
            return
        if hasattr(st, "close_chunk") and hasattr(st, "chunk"):
            if st.chunk.bio.tell():
                st.close_chunk()
            st.bio.flush()
        elif hasattr(st, "conn"):
            st.conn.commit()

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


def _qos_profile(reliable: bool, transient_local: bool, depth: int) -> Any:
    """A rosbags Qos record (durations 0 = unspecified, i.e. the RMW default: infinite)."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime  # noqa: PLC0415

    zero = QosTime(0, 0)
    return Qos(history=QosHistory.KEEP_LAST, depth=int(depth),
               reliability=QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
               durability=QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE,
               deadline=zero, lifespan=zero, liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=zero,
               avoid_ros_namespace_conventions=False)


CUSTOM_DATA_RECORD = "tissue_sim"
"""Name of the MCAP Metadata records that hold a bag's durable custom data (:meth:`BagWriter.set_custom_data`)."""

CUSTOM_DATA_TABLE = "tissue_sim_custom_data"
"""The sqlite3 table (key, value) that holds a bag's durable custom data."""


def _mcap_string(text: str) -> bytes:
    data = text.encode()
    return struct.pack("<I", len(data)) + data


def _mcap_metadata_record(name: str, values: dict[str, str]) -> bytes:
    """An MCAP Metadata record (opcode 0x0C): the name, then a map of strings prefixed by its byte length."""
    entries = b"".join(_mcap_string(k) + _mcap_string(v) for k, v in values.items())
    body = _mcap_string(name) + struct.pack("<I", len(entries)) + entries
    return b"\x0c" + struct.pack("<Q", len(body)) + body


def _read_mcap_string(data: bytes, pos: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", data, pos)
    return data[pos + 4:pos + 4 + n].decode(), pos + 4 + n


def durable_custom_data(path: str | Path) -> dict[str, str]:
    """The durable custom data a storage file (``.mcap`` or ``.db3``) holds, also when its writer never closed it.

    MCAP: the Metadata records named :data:`CUSTOM_DATA_RECORD` among the top-level records, later ones winning
    (a record cut short at the end of a killed recording is ignored); sqlite3: the table
    :data:`CUSTOM_DATA_TABLE`. Anything unreadable gives what could be read (empty at worst).
    """
    path = Path(path)
    out: dict[str, str] = {}
    if path.suffix == ".db3":
        import sqlite3  # noqa: PLC0415

        with contextlib.suppress(sqlite3.Error):
            conn = sqlite3.connect(f"file:{path}?immutable=1", uri=True)
            try:
                if conn.execute("SELECT 1 FROM sqlite_master WHERE type='table' AND name=?",
                                (CUSTOM_DATA_TABLE,)).fetchone():
                    out.update(conn.execute(f"SELECT key, value FROM {CUSTOM_DATA_TABLE}").fetchall())
            finally:
                conn.close()
        return out
    if path.suffix != ".mcap":
        return out
    with contextlib.suppress(OSError, struct.error, UnicodeDecodeError), path.open("rb") as f:
        size = path.stat().st_size
        if f.read(len(_MCAP_MAGIC)) != _MCAP_MAGIC:
            return out
        pos = len(_MCAP_MAGIC)
        while pos + 9 <= size:
            f.seek(pos)
            op, length = struct.unpack("<BQ", f.read(9))
            if op in (0x0F, 0x02) or pos + 9 + length > size:  # data end / footer, or a record cut short
                break
            if op == 0x0C:
                body = f.read(length)
                name, p = _read_mcap_string(body, 0)
                if name == CUSTOM_DATA_RECORD:
                    (n,) = struct.unpack_from("<I", body, p)
                    p, end = p + 4, p + 4 + n
                    while p < end:
                        key, p = _read_mcap_string(body, p)
                        value, p = _read_mcap_string(body, p)
                        out[key] = value
            pos += 9 + length
    return out


def recover_mcap(src: str | Path, dst: str | Path) -> int:
    """Salvage an MCAP file whose writer died before its summary and footer were written.

    Copies every complete top-level record (header, chunks with their
    schemas, channels and messages) of ``src`` into ``dst`` and ends it with a
    data-end record and a footer without summary, which readers then scan.

    Parameters
    ----------
    src : path of the damaged ``.mcap`` file (or a bag directory holding one).
    dst : path of the repaired ``.mcap`` file to write (must not exist).

    Returns
    -------
    int
        Number of bytes of ``src`` kept (the rest was an incomplete record).
    """
    src = Path(src)
    if src.is_dir():
        files = sorted(src.glob("*.mcap"))
        if len(files) != 1:
            raise InputError(f"{str(src)!r}: expected one .mcap file in the bag directory, found {len(files)}")
        src = files[0]
    dst = Path(dst)
    if dst.exists():
        raise InputError(f"{str(dst)!r} exists already")
    blob = src.read_bytes()
    if not blob.startswith(_MCAP_MAGIC):
        raise InputError(f"{str(src)!r} is not an MCAP file (no MCAP magic at its start)")
    pos = end = len(_MCAP_MAGIC)
    while pos + 9 <= len(blob):
        op = blob[pos]
        (size,) = struct.unpack_from("<Q", blob, pos + 1)
        if op in (0x0F, 0x02) or pos + 9 + size > len(blob):  # data end / footer, or a record cut short
            break
        pos += 9 + size
        end = pos
    with dst.open("xb") as out:
        out.write(blob[:end])
        out.write(b"\x0f" + struct.pack("<QI", 4, 0))             # DataEnd, no CRC
        out.write(b"\x02" + struct.pack("<QQQI", 20, 0, 0, 0))    # Footer: no summary
        out.write(_MCAP_MAGIC)
    return end


def recover_bag(src: str | Path, dst: str | Path, storage: str = "mcap") -> dict[str, int]:
    """Rewrite what an interrupted recording left as a proper, closed bag at ``dst``.

    ``src`` is a bag directory (or storage file) whose writer never closed: an
    MCAP without summary/footer (its complete chunks are salvaged, see
    :func:`recover_mcap`) or a sqlite3 file without ``metadata.yaml``. Every
    message is copied as serialized bytes with its receive time, and the
    custom data the recording wrote durably (the node's parameters,
    ``tissue_sim.params``) into the new bag's ``metadata.yaml`` (and durably).

    Returns
    -------
    dict
        Messages copied per topic.
    """
    import tempfile  # noqa: PLC0415

    src = Path(src)
    if not src.exists():
        raise InputError(f"bag {str(src)!r} does not exist")
    files = [src] if src.is_file() else sorted(src.glob("*.mcap")) + sorted(src.glob("*.db3"))
    if len(files) != 1:
        raise InputError(f"{str(src)!r}: expected one .mcap or .db3 file to recover, found {len(files)}")
    with tempfile.TemporaryDirectory() as tmp:
        target = files[0]
        if target.suffix == ".mcap" and _looks_like_cut_mcap(target):
            recover_mcap(target, Path(tmp) / "salvaged.mcap")
            target = Path(tmp) / "salvaged.mcap"
        with Bag(target) as bag, BagWriter(dst, storage) as out:
            for key, value in bag.custom_data.items():
                out.set_custom_data(key, value, durable=True)
            for conn in bag.connections:
                out.add_topic(conn.topic, conn.msgtype)
            for topic, _, t_ns, raw in bag.messages():
                out.write(topic, raw, t_ns)
            return out.counts


# --------------------------------------------------------------------------- reading


class Bag:
    """A rosbag2 bag opened for reading; every failure is an InputError naming the path.

    Parameters
    ----------
    path : str or Path
        A bag directory (``metadata.yaml`` + storage file), or a bare ``.mcap`` /
        ``.db3`` file. A directory without ``metadata.yaml`` but with exactly one
        storage file (a recording that never closed) is read from that file.
    """

    def __init__(self, path: str | Path) -> None:
        from rosbags.rosbag2 import Reader  # noqa: PLC0415

        self.path = Path(path)
        p = self.path
        if not p.exists():
            raise InputError(f"bag {str(p)!r} does not exist")
        target = p
        if p.is_dir() and not (p / "metadata.yaml").is_file():
            files = sorted(p.glob("*.mcap")) + sorted(p.glob("*.db3"))
            if len(files) != 1:
                raise InputError(f"{str(p)!r} is not a rosbag2 bag: no metadata.yaml and "
                                 f"{len(files)} .mcap/.db3 files (expected a bag directory or a .mcap/.db3 file)")
            target = files[0]
        elif p.is_file() and p.suffix not in (".mcap", ".db3"):
            raise InputError(f"{str(p)!r} is not a rosbag2 bag: expected a bag directory or a .mcap/.db3 file")
        if target.is_file() and target.stat().st_size == 0:
            raise InputError(f"bag {str(p)!r} is empty: {target.name} has 0 bytes")
        self._storage_files = [target] if target.is_file() else sorted(target.glob("*.mcap")) + sorted(
            target.glob("*.db3"))
        try:
            self._reader = Reader(target)
            self._reader.open()
        except Exception as exc:  # rosbags raises ReaderError, sqlite3, struct, zstd, YAML and OS errors
            raise InputError(f"bag {str(p)!r} cannot be read (truncated, corrupt or not a rosbag2 bag): "
                             f"{type(exc).__name__}: {exc}"
                             + (" - if it is a recording that was killed, salvage its complete chunks with "
                                f"`tissue-sim record --recover {str(p)} -o NEW_BAG` (bags.recover_bag)"
                                if _looks_like_cut_mcap(target) else "")) from None
        self.connections = list(self._reader.connections)

    @property
    def topics(self) -> dict[str, str]:
        """Topic name -> message type."""
        return {c.topic: c.msgtype for c in self.connections}

    def offered_qos(self, topic: str) -> tuple[bool, bool, int] | None:
        """(reliable, transient_local, depth) the bag recorded as ``topic``'s offered QoS; None when it recorded none.

        rosbag2 (and :class:`BagWriter`) store the QoS the recorded publishers offered; with several, a
        topic is taken as reliable / transient local only when every one of them was (what a subscriber
        matching them all would have used), and the deepest history.
        """
        profiles = [q for c in self.connections if c.topic == topic
                    for q in (getattr(c.ext, "offered_qos_profiles", None) or [])]
        if not profiles:
            return None
        from rosbags.interfaces import QosDurability, QosReliability  # noqa: PLC0415

        reliable = all(q.reliability == QosReliability.RELIABLE for q in profiles)
        latched = all(q.durability == QosDurability.TRANSIENT_LOCAL for q in profiles)
        return reliable, latched, max(int(q.depth) for q in profiles)

    @property
    def message_counts(self) -> dict[str, int]:
        counts: dict[str, int] = {}
        for c in self.connections:
            counts[c.topic] = counts.get(c.topic, 0) + int(c.msgcount)
        return counts

    @property
    def message_count(self) -> int:
        return int(self._reader.message_count)

    @property
    def custom_data(self) -> dict[str, str]:
        """The ``custom_data`` of ``metadata.yaml``, over what the storage file holds durably
        (:func:`durable_custom_data`: all there is for a bare storage file or a recording that never closed)."""
        out: dict[str, str] = {}
        for f in self._storage_files:
            out.update(durable_custom_data(f))
        meta = getattr(self._reader.storage, "metadata", None)
        out.update(getattr(meta, "custom", None) or {})
        return out

    def describe_topics(self) -> str:
        """The bag's topics with types and counts, for error messages."""
        if not self.connections:
            return "no topics"
        counts = self.message_counts
        return "; ".join(f"{t} ({ty}, {counts.get(t, 0)} msgs)" for t, ty in sorted(self.topics.items()))

    def messages(self, topics: list[str] | None = None) -> Iterator[tuple[str, str, int, bytes]]:
        """Yield ``(topic, msgtype, t_ns, raw_cdr)`` in receive-time order; corrupt data -> InputError."""
        conns = [c for c in self.connections if topics is None or c.topic in topics]
        if topics is not None and not conns:
            return
        try:
            for conn, t_ns, raw in self._reader.messages(connections=conns):
                yield conn.topic, conn.msgtype, int(t_ns), raw
        except InputError:
            raise
        except Exception as exc:
            raise InputError(f"bag {str(self.path)!r} is corrupt: reading its messages failed with "
                             f"{type(exc).__name__}: {exc}") from None

    def decode(self, raw: bytes, msgtype: str) -> Any:
        """Deserialize CDR bytes with the Jazzy typestore; corrupt bytes -> InputError."""
        try:
            return typestore().deserialize_cdr(raw, msgtype)
        except Exception as exc:
            raise InputError(f"bag {str(self.path)!r}: a {msgtype} message cannot be decoded "
                             f"({type(exc).__name__}: {exc})") from None

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._reader.close()

    def __enter__(self) -> "Bag":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _looks_like_cut_mcap(path: Path) -> bool:
    if not path.is_file() or path.suffix != ".mcap":
        return False
    with path.open("rb") as f:
        head = f.read(8)
        f.seek(max(0, path.stat().st_size - 8))
        tail = f.read(8)
    return head == _MCAP_MAGIC and tail != _MCAP_MAGIC


# --------------------------------------------------------------------------- tool trajectories


@dataclass
class ToolTrack:
    """A planar tool trajectory read from a bag."""

    t_ns: np.ndarray
    """Sample times [ns], strictly increasing, shape (M,), int64."""
    pose: np.ndarray
    """Tool pose per sample: x [m], y [m], yaw [rad], shape (M, 3), float64."""
    twist: np.ndarray | None
    """Tool velocity per sample: vx, vy [m/s], wz [rad/s], shape (M, 3), float64; NaN rows where no
    twist had been received yet (the simulation then derives it from poses); None without a twist topic."""
    topic: str
    """Topic the poses came from."""
    msgtype: str
    """Its message type."""
    child_frame: str | None = None
    """For TF messages: the child frame that is the tool."""
    frame_ids: tuple[str, ...] = ()
    """Parent/header frames seen on the pose samples."""
    twist_topic: str | None = None
    twist_t_ns: np.ndarray | None = None
    """Time of the twist each row holds [ns], shape (M,), int64, -1 where none; equal to ``t_ns`` where the
    twist carries the pose's own stamp (the only twists the node uses in lock-step)."""
    n_messages: int = 0
    """Pose-topic messages read (kept + skipped, TF messages without the frame not counted)."""
    skipped: dict[str, int] = field(default_factory=dict)
    """Samples skipped per reason: repeated, out_of_order, non_finite, bad_quaternion."""
    time_source: str = "header"
    """``header`` (stamps, receive time where a stamp is 0 or absent) or ``bag`` (receive times)."""
    received_ns: np.ndarray | None = None
    """Bag receive time of each pose sample [ns], shape (M,), int64."""
    twist_received_ns: np.ndarray | None = None
    """Bag receive time of the twist each row holds [ns], shape (M,), int64, -1 where none: a twist with the
    pose's stamp received after the pose is one the node in lock-step had not got when it stepped."""

    @property
    def n(self) -> int:
        return int(self.t_ns.shape[0])

    @property
    def duration(self) -> float:
        """Time from first to last sample [s]."""
        return float(self.t_ns[-1] - self.t_ns[0]) * 1e-9 if self.n else 0.0

    def interpolate(self, t_ns: np.ndarray) -> np.ndarray:
        """Pose at times ``t_ns`` [ns] (clamped to the track's span): linear in x, y and unwrapped yaw.

        Returns shape (K, 3), float64.
        """
        return interpolate_poses(self.t_ns, self.pose, np.asarray(t_ns, dtype=np.int64))

    def summary(self) -> str:
        """One line: topic, frame, samples, duration, rate, skips."""
        rate = (self.n - 1) / self.duration if self.duration > 0 else float("nan")
        frame = f" child frame {self.child_frame!r}" if self.child_frame else ""
        skips = ", ".join(f"{k} {v}" for k, v in sorted(self.skipped.items()) if v) or "none"
        tw = f", twist from {self.twist_topic}" if self.twist_topic else ""
        return (f"tool track: {self.topic} ({self.msgtype}){frame}, {self.n} samples over {self.duration:.3f} s "
                f"(~{rate:.1f} Hz, {self.time_source} time){tw}; skipped: {skips}")


def _stamp_ns(header: Any) -> int:
    return stamp_to_ns((header.stamp.sec, header.stamp.nanosec))


def _yaw(q: Any) -> float | None:
    """Heading about +z of a quaternion message; None when it is not a rotation (the node's formula)."""
    return yaw_from_quaternion(float(q.x), float(q.y), float(q.z), float(q.w))


# each extractor: msg -> list of (stamp_ns or 0, x, y, quaternion, frame_id, child_frame)
def _samples(msg: Any, msgtype: str, child: str | None) -> list[tuple[int, float, float, Any, str]]:
    if msgtype == "geometry_msgs/msg/PoseStamped":
        p = msg.pose
        return [(_stamp_ns(msg.header), p.position.x, p.position.y, p.orientation, msg.header.frame_id)]
    if msgtype == "geometry_msgs/msg/Pose":
        return [(0, msg.position.x, msg.position.y, msg.orientation, "")]
    if msgtype in ("geometry_msgs/msg/PoseWithCovarianceStamped", "nav_msgs/msg/Odometry"):
        p = msg.pose.pose
        return [(_stamp_ns(msg.header), p.position.x, p.position.y, p.orientation, msg.header.frame_id)]
    if msgtype == "geometry_msgs/msg/TransformStamped":
        tr = msg.transform
        return [(_stamp_ns(msg.header), tr.translation.x, tr.translation.y, tr.rotation, msg.header.frame_id)]
    if msgtype == TF_TYPE:
        out = []
        for ts in msg.transforms:
            if ts.child_frame_id.lstrip("/") == child:
                tr = ts.transform
                out.append((_stamp_ns(ts.header), tr.translation.x, tr.translation.y, tr.rotation, ts.header.frame_id))
        return out
    raise AssertionError(msgtype)


def tool_candidates(bag: Bag) -> list[tuple[str, str, str | None]]:
    """Every (topic, type, child frame) in the bag that can carry the tool pose.

    TF topics contribute one candidate per child frame they carry (found by
    reading them).
    """
    out: list[tuple[str, str, str | None]] = []
    tf_topics = []
    for topic, msgtype in sorted(bag.topics.items()):
        if msgtype == TF_TYPE:
            tf_topics.append(topic)
        elif msgtype in POSE_TYPES:
            out.append((topic, msgtype, None))
    for topic in tf_topics:
        frames: set[str] = set()
        for _, msgtype, _, raw in bag.messages([topic]):
            frames.update(ts.child_frame_id.lstrip("/") for ts in bag.decode(raw, msgtype).transforms)
        out += [(topic, TF_TYPE, f) for f in sorted(frames)]
    return out


def _format_candidates(cands: list[tuple[str, str, str | None]]) -> str:
    return "; ".join(f"--tool-topic {t}" + (f" --frame {f}" if f else "") + f" ({ty})" for t, ty, f in cands)


def _choose(bag: Bag, topic: str | None, frame: str | None) -> tuple[str, str, str | None]:
    """Resolve the tool topic (and TF child frame) from the options, or explain what is there."""
    topics = bag.topics
    frame = frame.lstrip("/") if frame else frame
    if topic is not None:
        if topic not in topics:
            alt = "/" + topic if not topic.startswith("/") else topic.lstrip("/")
            if alt in topics:
                topic = alt
            else:
                raise InputError(f"bag {str(bag.path)!r} has no topic {topic!r}; it has: {bag.describe_topics()}")
        msgtype = topics[topic]
        if msgtype not in POSE_TYPES:
            raise InputError(f"topic {topic!r} in bag {str(bag.path)!r} has type {msgtype}, which carries no tool pose; "
                             f"supported: {', '.join(POSE_TYPES)}")
        if msgtype != TF_TYPE:
            return topic, msgtype, None
        if frame is not None:
            return topic, msgtype, frame  # checked while reading (a scan of a large /tf only if it is absent)
        cands = [c for c in tool_candidates(bag) if c[0] == topic]
    else:
        found = tool_candidates(bag)
        # the node's own outputs (tool/applied_*) are what it did with a tool, not a tool: never chosen unasked
        cands = [c for c in found if not is_node_tool_output(c[0])]
        outputs = [c for c in found if is_node_tool_output(c[0])]
        if not cands and outputs and frame is None:
            raise InputError(f"bag {str(bag.path)!r}: its only tool pose is the node's own output "
                             f"{', '.join(c[0] for c in outputs)} (the tool it applied): expected a tool input; "
                             f"replay a node's recording with --mode applied, or name it with --tool-topic "
                             f"{outputs[0][0]}")
    if frame is not None:
        matching = [c for c in cands if c[2] == frame]
        if not matching:
            tf = [c for c in cands if c[1] == TF_TYPE]
            raise InputError(f"bag {str(bag.path)!r}: no TF child frame {frame!r}"
                             + (f" on {topic}" if topic else "")
                             + f"; TF child frames there: {', '.join(sorted({c[2] for c in tf if c[2]})) or 'none'}")
        cands = matching
    if not cands:
        raise InputError(f"bag {str(bag.path)!r} has no topic carrying a tool pose (supported types: "
                         f"{', '.join(POSE_TYPES)}); it has: {bag.describe_topics()}")
    if len(cands) > 1:
        raise InputError(f"bag {str(bag.path)!r}: {len(cands)} possible tool poses, choose one with --tool-topic "
                         f"and --frame: {_format_candidates(cands)}")
    return cands[0]


def read_tool_track(path: str | Path | Bag, topic: str | None = None, frame: str | None = None,
                    twist_topic: str | None = None, time_source: str = "header",
                    on_bad_time: str = "skip", on_bad_pose: str = "skip") -> ToolTrack:
    """Extract the tool's planar trajectory from a bag.

    Parameters
    ----------
    path : bag path, or an open :class:`Bag`
    topic : str, optional
        The pose topic; when None, the one topic (or TF child frame) that can
        carry a pose, else an InputError listing the candidates. The node's own
        outputs (:data:`NODE_TOOL_OUTPUTS`) are never candidates: name them to read them.
    frame : str, optional
        TF child frame that is the tool (for ``tf2_msgs/msg/TFMessage`` topics).
    twist_topic : str, optional
        A TwistStamped/Twist topic; each pose sample gets the latest twist at or
        before its time.
    time_source : {"header", "bag"}
        Sample time: header stamps (receive time where absent or 0) or receive times.
    on_bad_time : {"skip", "error"}
        Repeated or out-of-order sample times: skip and count, or raise :class:`BadSampleError`.
    on_bad_pose : {"skip", "error"}
        Non-finite positions and invalid quaternions: skip and count, or raise :class:`BadSampleError`.

    Returns
    -------
    ToolTrack
        Poses projected onto the tissue plane: x, y and the heading about +z.
    """
    if time_source not in ("header", "bag"):
        raise InputError(f"time_source={time_source!r}: expected 'header' or 'bag'")
    if on_bad_time not in ("skip", "error"):
        raise InputError(f"on_bad_time={on_bad_time!r}: expected 'skip' or 'error'")
    if on_bad_pose not in ("skip", "error"):
        raise InputError(f"on_bad_pose={on_bad_pose!r}: expected 'skip' or 'error'")
    own = not isinstance(path, Bag)
    bag = Bag(path) if own else path
    try:
        if bag.message_count == 0:
            raise InputError(f"bag {str(bag.path)!r} holds no messages (topics: {bag.describe_topics()})")
        topic, msgtype, child = _choose(bag, topic, frame)
        if twist_topic is not None:
            if twist_topic not in bag.topics:
                raise InputError(f"bag {str(bag.path)!r} has no twist topic {twist_topic!r}; it has: {bag.describe_topics()}")
            if bag.topics[twist_topic] not in TWIST_TYPES:
                raise InputError(f"twist topic {twist_topic!r} has type {bag.topics[twist_topic]}: expected one of "
                                 f"{', '.join(TWIST_TYPES)}")
        skipped = dict.fromkeys(SKIP_REASONS, 0)
        times: list[int] = []
        received: list[int] = []
        poses: list[tuple[float, float, float]] = []
        frames: set[str] = set()
        n_messages = 0
        last = -1
        for _, _, t_bag, raw in bag.messages([topic]):
            msg = bag.decode(raw, msgtype)
            for stamp, x, y, q, frame_id in _samples(msg, msgtype, child):
                n_messages += 1
                t = t_bag if (time_source == "bag" or stamp == 0) else stamp
                yaw = _yaw(q)
                where = f"bag {str(bag.path)!r}, topic {topic}: sample {n_messages}"
                if not (math.isfinite(x) and math.isfinite(y)):
                    if on_bad_pose == "error":
                        raise BadSampleError(f"{where} has a non-finite position ({x}, {y}) (non_finite): "
                                             "expected finite coordinates")
                    skipped["non_finite"] += 1
                    continue
                if yaw is None:
                    if on_bad_pose == "error":
                        raise BadSampleError(f"{where} has an invalid quaternion ({q.x}, {q.y}, {q.z}, {q.w}) "
                                             "(bad_quaternion): expected a finite, non-zero quaternion")
                    skipped["bad_quaternion"] += 1
                    continue
                if t <= last:
                    reason = "repeated" if t == last else "out_of_order"
                    if on_bad_time == "error":
                        raise BadSampleError(f"{where} has time {t} ns, "
                                             f"{'equal to' if t == last else 'before'} the previous sample's {last} ns "
                                             f"({reason}): expected increasing sample times")
                    skipped[reason] += 1
                    continue
                last = t
                times.append(t)
                received.append(int(t_bag))
                poses.append((float(x), float(y), yaw))
                frames.add(frame_id)
        if not times and msgtype == TF_TYPE and n_messages == 0:
            frames_there = sorted({c[2] for c in tool_candidates(bag) if c[0] == topic and c[2]})
            raise InputError(f"bag {str(bag.path)!r}: no TF child frame {child!r} on {topic}; TF child frames "
                             f"there: {', '.join(frames_there) or 'none'}")
        if not times:
            raise InputError(f"bag {str(bag.path)!r}: topic {topic}"
                             + (f" frame {child!r}" if child else "")
                             + f" gave no usable tool pose ({n_messages} samples; skipped {skipped})")
        t_arr = np.asarray(times, dtype=np.int64)
        twist, twist_t, twist_rx = (_read_twist(bag, twist_topic, t_arr, time_source) if twist_topic
                                    else (None, None, None))
        return ToolTrack(t_ns=t_arr, pose=np.asarray(poses, dtype=np.float64), twist=twist, twist_t_ns=twist_t,
                         received_ns=np.asarray(received, dtype=np.int64), twist_received_ns=twist_rx,
                         topic=topic,
                         msgtype=msgtype, child_frame=child, frame_ids=tuple(sorted(frames)),
                         twist_topic=twist_topic, n_messages=n_messages, skipped=skipped, time_source=time_source)
    finally:
        if own:
            bag.close()


def _read_twist(bag: Bag, topic: str, t_pose: np.ndarray,
                time_source: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Latest twist at or before each pose time (sample and hold; NaN rows before the first twist), its time
    and its bag receive time."""
    t_tw: list[int] = []
    rx: list[int] = []
    vals: list[tuple[float, float, float]] = []
    for _, msgtype, t_bag, raw in bag.messages([topic]):
        msg = bag.decode(raw, msgtype)
        if msgtype == "geometry_msgs/msg/TwistStamped":
            stamp, tw = _stamp_ns(msg.header), msg.twist
        else:
            stamp, tw = 0, msg
        t = t_bag if (time_source == "bag" or stamp == 0) else stamp
        v = (float(tw.linear.x), float(tw.linear.y), float(tw.angular.z))
        if not all(math.isfinite(c) for c in v) or (t_tw and t < t_tw[-1]):
            continue  # a bad or late twist: the pose-derived velocity stands in
        t_tw.append(t)
        rx.append(int(t_bag))
        vals.append(v)
    out = np.full((t_pose.shape[0], 3), np.nan)
    times = np.full(t_pose.shape[0], -1, dtype=np.int64)
    received = np.full(t_pose.shape[0], -1, dtype=np.int64)
    if t_tw:
        t_arr = np.asarray(t_tw, dtype=np.int64)
        idx = np.searchsorted(t_arr, t_pose, side="right") - 1
        ok = idx >= 0
        out[ok] = np.asarray(vals)[idx[ok]]
        times[ok] = t_arr[idx[ok]]
        received[ok] = np.asarray(rx, dtype=np.int64)[idx[ok]]
    return out, times, received


__all__ = ["STORAGES", "POSE_TYPES", "TWIST_TYPES", "NODE_TOOL_OUTPUTS", "SKIP_REASONS", "BagWriter", "Bag",
           "ToolTrack", "BadSampleError", "read_tool_track", "is_node_tool_output", "tool_candidates",
           "recover_mcap", "recover_bag", "typestore"]
