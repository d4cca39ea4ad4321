"""What a killed recording left, made a closed bag again (``tissue-sim record --recover``).

A writer killed before its close leaves an MCAP without its summary and footer (the ``mcap`` library reads its
records up to the first incomplete one: every chunk flushed before the kill), or a sqlite3 file without
``metadata.yaml`` (readable as it is: every committed message). Both keep the custom data written durably.
"""
from __future__ import annotations

import tempfile
from pathlib import Path

from ...core.errors import InputError
from .read import Bag, looks_like_cut_mcap
from .storage import LIBRARY, is_mcap, mcap_records
from .write import BagWriter


def recover_mcap(src: str | Path, dst: str | Path) -> int:
    """Copy every complete record of an MCAP file whose writer died into a new, finished MCAP file.

    Parameters
    ----------
    src : path of the damaged ``.mcap`` file (or a bag directory holding one).
    dst : path of the repaired ``.mcap`` file to write (must not exist).

    Returns
    -------
    int
        Number of messages kept (those of the chunks complete in ``src``).
    """
    from mcap.records import Channel, Header, Message, Metadata, Schema  # noqa: PLC0415
    from mcap.writer import CompressionType, Writer  # noqa: PLC0415

    src = Path(src)
    if src.is_dir():
        files = sorted(src.glob("*.mcap"))
        if len(files) != 1:
            raise InputError(f"{str(src)!r}: expected one .mcap file in the bag directory, found {len(files)}")
        src = files[0]
    dst = Path(dst)
    if dst.exists():
        raise InputError(f"{str(dst)!r} exists already")
    if not is_mcap(src):
        raise InputError(f"{str(src)!r} is not an MCAP file (no MCAP magic at its start)")
    schemas: dict[int, int] = {}
    channels: dict[int, int] = {}
    kept = 0
    with dst.open("xb") as f:
        out = Writer(f, compression=CompressionType.NONE)
        for record in mcap_records(src):
            if isinstance(record, Header):
                out.start(profile=record.profile, library=f"{LIBRARY} recover_mcap, from {record.library}")
            elif isinstance(record, Schema):
                schemas[record.id] = out.register_schema(record.name, record.encoding, record.data)
            elif isinstance(record, Channel):
                channels[record.id] = out.register_channel(record.topic, record.message_encoding,
                                                           schemas.get(record.schema_id, 0), dict(record.metadata))
            elif isinstance(record, Message) and record.channel_id in channels:
                out.add_message(channels[record.channel_id], record.log_time, record.data, record.publish_time,
                                record.sequence)
                kept += 1
            elif isinstance(record, Metadata):
                out.add_metadata(record.name, dict(record.metadata))
        out.finish()
    return kept


def recover_bag(src: str | Path, dst: str | Path, storage: str = "mcap") -> dict[str, int]:
    """Rewrite what an interrupted recording left as a proper, closed bag at ``dst``.

    ``src`` is a bag directory (or storage file) whose writer never closed: an MCAP without summary/footer
    (its complete chunks are salvaged, :func:`recover_mcap`) or a sqlite3 file without ``metadata.yaml``.
    Every message is copied as serialized bytes with its receive time, and the custom data the recording wrote
    durably (the node's parameters, ``tissue_sim.params``) into the new bag's ``metadata.yaml`` (and durably).

    Returns
    -------
    dict
        Messages copied per topic.
    """
    src = Path(src)
    if not src.exists():
        raise InputError(f"bag {str(src)!r} does not exist")
    files = [src] if src.is_file() else sorted(src.glob("*.mcap")) + sorted(src.glob("*.db3"))
    if len(files) != 1:
        raise InputError(f"{str(src)!r}: expected one .mcap or .db3 file to recover, found {len(files)}")
    with tempfile.TemporaryDirectory() as tmp:
        target = files[0]
        if looks_like_cut_mcap(target):
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
