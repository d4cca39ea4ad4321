"""How a bag's messages sit on disk: the two storages :class:`~.write.BagWriter` writes, and what a storage file
holds durably.

rosbags' :class:`~rosbags.rosbag2.Writer` keeps the bag (its topics, their Jazzy definitions and type hashes, the
counts, ``metadata.yaml``) and hands the bytes to a storage object of the class its ``STORAGE_PLUGINS`` maps the
storage plugin to: ``add_msgtype``, ``add_connection``, ``write``, ``close(version, metadata)`` and ``abort``
(rosbags 0.11's storage protocol; ``test_bags`` checks it). The storages here add what a live recording needs
and rosbags' own do not offer: :meth:`flush` (a crash loses at most what came after it) and
:meth:`set_durable` (a custom-data value on disk at once, so a killed recording keeps the node's parameters).

* :class:`McapStorage`: written by the ``mcap`` library (chunks of at most 1 MiB, uncompressed, with message
  indexes and a summary; schemas ``ros2msg``; a channel's offered QoS in its metadata, and at close the bag's
  metadata in a Metadata record ``rosbag2``, as rosbag2 writes them). Durable custom data is a Metadata record
  :data:`CUSTOM_DATA_RECORD`.
* :class:`Sqlite3Storage`: rosbag2's sqlite3 schema (version 4), on a connection every thread may use (the
  writer's lock serialises them); durable custom data is the table :data:`CUSTOM_DATA_TABLE`.

:func:`durable_custom_data` reads those back from a storage file, also one whose writer never closed it.
"""
from __future__ import annotations

import contextlib
import sqlite3
from importlib.metadata import version
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterator

if TYPE_CHECKING:
    from rosbags.interfaces import Connection

STORAGES = ("mcap", "sqlite3")
"""Storage plugins accepted by :class:`~.write.BagWriter` (rosbag2's own identifiers)."""

CUSTOM_DATA_RECORD = "tissue_sim"
"""Name of the MCAP Metadata records that hold a bag's durable custom data."""

CUSTOM_DATA_TABLE = "tissue_sim_custom_data"
"""The sqlite3 table (key, value) that holds a bag's durable custom data."""

ROSBAG2_RECORD = "rosbag2"
"""The MCAP Metadata record in which rosbag2 (and this writer) keep the bag's metadata at close."""

LIBRARY = "tissue_sim_ros"
"""The start of the MCAP header's ``library`` in the files :class:`McapStorage` writes."""

CHUNK_SIZE = 1 << 20
"""An MCAP chunk is written once it holds this many bytes (and at every flush)."""


def _schema_encoding(connection: "Connection") -> str:
    from rosbags.interfaces import MessageDefinitionFormat  # noqa: PLC0415

    return "ros2msg" if connection.msgdef.format == MessageDefinitionFormat.MSG else "ros2idl"


class McapStorage:
    """rosbags' storage protocol on the ``mcap`` library's writer (module docstring)."""

    def __init__(self, path: Path, compression: Any) -> None:
        from mcap.writer import CompressionType, Writer  # noqa: PLC0415
        from rosbags.rosbag2 import CompressionMode  # noqa: PLC0415

        if compression not in (CompressionMode.NONE, None):
            raise ValueError("the MCAP storage writes uncompressed chunks")
        self.path = path / f"{path.name}.mcap"
        self._file = self.path.open("xb")
        self._writer = Writer(self._file, chunk_size=CHUNK_SIZE, compression=CompressionType.NONE)
        self._writer.start(profile="ros2", library=f"{LIBRARY}, mcap {version('mcap')}")
        self._schemas: dict[str, int] = {}
        self._channels: dict[int, int] = {}

    def add_msgtype(self, connection: "Connection") -> None:
        self._schemas[connection.msgtype] = self._writer.register_schema(
            connection.msgtype, _schema_encoding(connection), connection.msgdef.data.encode())

    def add_connection(self, connection: "Connection", offered_qos_profiles: str) -> None:
        self._channels[connection.id] = self._writer.register_channel(
            connection.topic, connection.ext.serialization_format, self._schemas[connection.msgtype],
            {"offered_qos_profiles": offered_qos_profiles})

    def write(self, connection: "Connection", timestamp: int, data: bytes | memoryview) -> None:
        self._writer.add_message(self._channels[connection.id], timestamp, data, timestamp)

    def flush(self) -> None:
        """Write the pending chunk and put the file on disk."""
        self._writer.flush()

    def set_durable(self, key: str, value: str) -> None:
        self._writer.add_metadata(CUSTOM_DATA_RECORD, {key: value})
        self._writer.flush()

    def close(self, version: int, metadata: str) -> None:
        self._writer.add_metadata(ROSBAG2_RECORD, {"serialized_metadata": metadata})
        self._writer.finish()
        self._file.close()

    def abort(self) -> None:
        self._file.close()


class Sqlite3Storage:
    """rosbags' storage protocol on rosbag2's sqlite3 schema (module docstring)."""

    SCHEMA = """
        CREATE TABLE schema(schema_version INTEGER PRIMARY KEY, ros_distro TEXT NOT NULL);
        CREATE TABLE metadata(id INTEGER PRIMARY KEY, metadata_version INTEGER NOT NULL, metadata TEXT NOT NULL);
        CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
                            serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL,
                            type_description_hash TEXT NOT NULL);
        CREATE TABLE message_definitions(id INTEGER PRIMARY KEY, topic_type TEXT NOT NULL, encoding TEXT NOT NULL,
                                         encoded_message_definition TEXT NOT NULL,
                                         type_description_hash TEXT NOT NULL);
        CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, timestamp INTEGER NOT NULL,
                              data BLOB NOT NULL);
        CREATE INDEX timestamp_idx ON messages (timestamp ASC);
        INSERT INTO schema(schema_version, ros_distro) VALUES (4, 'rosbags');
    """

    def __init__(self, path: Path, compression: Any) -> None:
        from rosbags.rosbag2 import CompressionMode  # noqa: PLC0415

        if compression not in (CompressionMode.NONE, None):
            raise ValueError("the sqlite3 storage does not compress")
        self.path = path / f"{path.name}.db3"
        # every thread may write (the node's step and marker threads): the bag writer's lock serialises them
        self._conn = sqlite3.connect(f"file:{self.path}", uri=True, check_same_thread=False)
        self._conn.executescript(self.SCHEMA)

    def add_msgtype(self, connection: "Connection") -> None:
        self._conn.execute("INSERT INTO message_definitions (topic_type, encoding, encoded_message_definition, "
                           "type_description_hash) VALUES(?, ?, ?, ?)",
                           (connection.msgtype, _schema_encoding(connection), connection.msgdef.data,
                            connection.digest))

    def add_connection(self, connection: "Connection", offered_qos_profiles: str) -> None:
        self._conn.execute("INSERT INTO topics VALUES(?, ?, ?, ?, ?, ?)",
                           (connection.id, connection.topic, connection.msgtype,
                            connection.ext.serialization_format, offered_qos_profiles, connection.digest))

    def write(self, connection: "Connection", timestamp: int, data: bytes | memoryview) -> None:
        self._conn.execute("INSERT INTO messages (topic_id, timestamp, data) VALUES(?, ?, ?)",
                           (connection.id, timestamp, data))

    def flush(self) -> None:
        self._conn.commit()

    def set_durable(self, key: str, value: str) -> None:
        self._conn.execute(f"CREATE TABLE IF NOT EXISTS {CUSTOM_DATA_TABLE}(key TEXT PRIMARY KEY, "
                           "value TEXT NOT NULL)")
        self._conn.execute(f"INSERT OR REPLACE INTO {CUSTOM_DATA_TABLE}(key, value) VALUES(?, ?)", (key, value))
        self._conn.commit()

    def close(self, version: int, metadata: str) -> None:
        self._conn.execute("INSERT INTO metadata(metadata_version, metadata) VALUES(?, ?)", (version, metadata))
        self._conn.commit()
        self._conn.execute("PRAGMA optimize")
        self._conn.close()

    def abort(self) -> None:
        with contextlib.suppress(sqlite3.Error):
            self._conn.rollback()
        self._conn.close()


# --------------------------------------------------------------------------- reading what a file holds


def mcap_is_finished(path: Path) -> bool:
    """Whether an MCAP file ends with its footer (its writer closed it); False for a cut one or not an MCAP."""
    from mcap.reader import make_reader  # noqa: PLC0415

    try:
        with path.open("rb") as f:
            make_reader(f).get_summary()
    except Exception:  # noqa: BLE001  the mcap library's errors for a cut file: McapError, EndOfFile, struct
        return False
    return True


def is_mcap(path: Path) -> bool:
    """Whether ``path`` starts with the MCAP magic."""
    from mcap.reader import make_reader  # noqa: PLC0415

    try:
        with path.open("rb") as f:
            make_reader(f)
    except Exception:  # noqa: BLE001  InvalidMagic, or too short to hold it
        return False
    return True


def mcap_records(path: Path, chunks: bool = True) -> Iterator[Any]:
    """The records of an MCAP file in order, up to the first incomplete one (a writer killed mid-record); the
    messages inside its chunks unless ``chunks`` (then the chunks themselves, unread)."""
    from mcap.stream_reader import StreamReader  # noqa: PLC0415

    with path.open("rb") as f:
        records = StreamReader(f, emit_chunks=not chunks).records
        while True:
            try:
                record = next(records)
            except StopIteration:
                return
            except Exception:  # noqa: BLE001  a record cut short ends what there is to read
                return
            yield record


def mcap_metadata(path: Path) -> list[tuple[str, dict[str, str]]]:
    """(name, values) of every Metadata record of an MCAP file, in order: from its summary when this writer
    finished the file, else by reading it up to where it was cut (0.1's writer left its durable records out of
    the summary)."""
    from mcap.reader import make_reader  # noqa: PLC0415
    from mcap.records import Metadata  # noqa: PLC0415

    if mcap_is_finished(path):
        with path.open("rb") as f:
            reader = make_reader(f)
            if reader.get_header().library.startswith(LIBRARY):
                return [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
    return [(r.name, dict(r.metadata)) for r in mcap_records(path, chunks=False) if isinstance(r, Metadata)]


def durable_custom_data(path: str | Path) -> dict[str, str]:
    """The durable custom data a storage file (``.mcap`` or ``.db3``) holds, also when its writer never closed it.

    MCAP: the Metadata records named :data:`CUSTOM_DATA_RECORD`, later ones winning (a record cut short at the
    end of a killed recording is ignored); sqlite3: the table :data:`CUSTOM_DATA_TABLE`. Anything unreadable
    gives what could be read (empty at worst).
    """
    path = Path(path)
    out: dict[str, str] = {}
    if path.suffix == ".db3":
        with contextlib.suppress(sqlite3.Error):
            conn = sqlite3.connect(f"file:{path}?immutable=1", uri=True)
            try:
                if conn.execute("SELECT 1 FROM sqlite_master WHERE type='table' AND name=?",
                                (CUSTOM_DATA_TABLE,)).fetchone():
                    out.update(conn.execute(f"SELECT key, value FROM {CUSTOM_DATA_TABLE}").fetchall())
            finally:
                conn.close()
    elif path.suffix == ".mcap" and is_mcap(path):
        for name, values in mcap_metadata(path):
            if name == CUSTOM_DATA_RECORD:
                out.update(values)
    return out
