"""Reading a bag: :class:`Bag` opens a rosbag2 directory or a bare ``.mcap``/``.db3`` with rosbags'
:class:`~rosbags.rosbag2.Reader`, and turns every failure (not a bag, empty, truncated, corrupt) into an
:class:`~tissue_sim_ros.core.errors.InputError` naming the path."""
from __future__ import annotations

import contextlib
import sqlite3
from pathlib import Path
from typing import Any, Iterator

from ...core.errors import InputError
from ..typestore import typestore
from .storage import ROSBAG2_RECORD, durable_custom_data, is_mcap, mcap_is_finished, mcap_metadata


def looks_like_cut_mcap(path: Path) -> bool:
    """An MCAP file without its footer: a recording that was killed (``tissue-sim record --recover`` salvages it)."""
    return path.is_file() and path.suffix == ".mcap" and is_mcap(path) and not mcap_is_finished(path)


def _rosbag2_custom_data(path: Path) -> dict[str, str]:
    """The ``custom_data`` of a bag's rosbag2 metadata: ``metadata.yaml`` of a directory; the metadata a closed
    storage file keeps (MCAP: the Metadata record ``rosbag2``; sqlite3: the table ``metadata``)."""
    import yaml  # noqa: PLC0415

    text = ""
    with contextlib.suppress(OSError, sqlite3.Error):
        if path.is_dir():
            text = (path / "metadata.yaml").read_text()
        elif path.suffix == ".mcap" and mcap_is_finished(path):
            text = next((v.get("serialized_metadata", "") for name, v in mcap_metadata(path)
                         if name == ROSBAG2_RECORD), "")
        elif path.suffix == ".db3":
            conn = sqlite3.connect(f"file:{path}?immutable=1", uri=True)
            try:
                row = conn.execute("SELECT metadata FROM metadata ORDER BY id DESC LIMIT 1").fetchone()
            finally:
                conn.close()
            text = row[0] if row else ""
    try:
        data = yaml.safe_load(text) or {}
    except yaml.YAMLError:
        return {}
    info = data.get("rosbag2_bagfile_information", data) if isinstance(data, dict) else {}  # a file keeps the inside
    return dict(info.get("custom_data") or {}) if isinstance(info, dict) else {}


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
        self._target = target
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
                                if looks_like_cut_mcap(target) else "")) from None
        self.connections = list(self._reader.connections)

    @property
    def topics(self) -> dict[str, str]:
        """Topic name -> message type."""
        return {c.topic: c.msgtype for c in self.connections}

    def offered_qos(self, topic: str) -> tuple[bool, bool, int] | None:
        """(reliable, transient_local, depth) the bag recorded as ``topic``'s offered QoS; None when it recorded none.

        rosbag2 (and :class:`~.write.BagWriter`) store the QoS the recorded publishers offered; with several, a
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
        """The bag's ``custom_data`` (``metadata.yaml``, or the metadata a closed storage file keeps), over what
        the storage file holds durably (:func:`~.storage.durable_custom_data`: all there is for a recording that
        never closed)."""
        out: dict[str, str] = {}
        for f in self._storage_files:
            out.update(durable_custom_data(f))
        out.update(_rosbag2_custom_data(self._target))
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
