"""Salvage: what an interrupted, truncated or damaged recording still holds -> a valid MCAP file.

The recorder flushes a complete, CRC-protected chunk at least every 0.5 s of log time, so a
killed recorder leaves a ``<trial>.<pid>-<token>.mcap.part`` file whose data section holds
every message up to the last flush, followed by a cut-off chunk and no summary. The reader
refuses such a file; :func:`salvage` walks its data section record by record
(:func:`replay.recording._container.walk_data_section` in its tolerant mode), keeps every record of
every intact chunk, skips chunks whose CRC or compression is damaged, stops at the first
record that is cut off, and writes what it kept to a new file:

- the original is never touched; the new file is ``<name>.recovered.mcap`` beside it (or a
  path of the user's choice) and an existing file is never overwritten;
- the new file is a complete MCAP file (chunked, zstd, CRCs, summary), with the original's
  header, metadata records, schemas and channels, and the kept messages in their file order;
- it carries one more metadata record, ``atikt.recovery``, with ``recovered = "true"``, the
  source file, how many bytes of it were intact, why the walk stopped, and per channel how
  many messages and seconds were kept.

Whether the salvaged file is a usable recording (a complete action) is for the reader to say:
a recorder killed during the execute phase leaves a recording the reader refuses as cut short.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING

from mcap.writer import CompressionType, Writer

from replay.errors import RecordingError
from replay.recording._container import (
    MAGIC,
    FormatError,
    walk_data_section,
)
from schemas import PART_SUFFIX, RECOVERED_SUFFIX, VOCABULARY, atomic_file

if TYPE_CHECKING:
    from replay.recording._container import ChannelMessages, DataSection

#: Name of the metadata record that marks a salvaged file.
RECOVERY_NAME = "atikt.recovery"
#: Suffix of a salvaged file, replacing ``.mcap`` or ``.mcap.part``.

_NS_PER_S = 1e9


@dataclass(frozen=True, slots=True)
class ChannelKept:
    """What was kept of one channel.

    Attributes:
        topic: Topic name.
        messages: Messages kept.
        start_ns: First kept log time, ns (0 without messages).
        end_ns: Last kept log time, ns (0 without messages).
    """

    topic: str
    messages: int
    start_ns: int
    end_ns: int

    @property
    def seconds(self) -> float:
        """Return the log time the kept messages span, s."""
        return (self.end_ns - self.start_ns) / _NS_PER_S


@dataclass(frozen=True, slots=True)
class RecoveryReport:
    """What :func:`salvage` kept.

    Attributes:
        source: The damaged or unfinished file (unchanged).
        target: The salvaged file.
        source_bytes: Size of the source.
        intact_bytes: Length of the source's prefix that the walk read or skipped intact.
        complete: Whether the source's data section was complete (it had a DataEnd record).
        chunks: Chunks kept.
        damaged_chunks: Chunks skipped as damaged (CRC, compression, malformed records).
        orphans: Messages skipped because their channel definition was lost.
        stopped: Why the walk stopped before the end of the data section ("" if it did not).
        channels: Per channel, what was kept (in channel order of the source).
    """

    source: Path
    target: Path
    source_bytes: int
    intact_bytes: int
    complete: bool
    chunks: int
    damaged_chunks: int
    orphans: int
    stopped: str
    channels: tuple[ChannelKept, ...]

    @property
    def messages(self) -> int:
        """Return the number of messages kept over all channels."""
        return sum(channel.messages for channel in self.channels)

    def to_metadata(self) -> dict[str, str]:
        """Return the ``atikt.recovery`` metadata record's key-value pairs."""
        channels = {
            c.topic: {"messages": c.messages, "start_ns": c.start_ns, "end_ns": c.end_ns}
            for c in self.channels
        }
        return {
            "recovered": "true",
            "source": self.source.name,
            "source_bytes": str(self.source_bytes),
            "intact_bytes": str(self.intact_bytes),
            "complete": json.dumps(self.complete),
            "messages": str(self.messages),
            "chunks": str(self.chunks),
            "damaged_chunks": str(self.damaged_chunks),
            "orphan_messages": str(self.orphans),
            "stopped": self.stopped,
            "channels": json.dumps(channels, sort_keys=True),
        }


def recovered_path(source: Path) -> Path:
    """Return the default name of the salvaged copy of ``source``.

    ``001.1234-ab12.mcap.part`` gives ``001.1234-ab12.recovered.mcap``; ``001.mcap`` gives
    ``001.recovered.mcap``.
    """
    source = Path(source)
    name = source.name
    for suffix in (PART_SUFFIX, ".mcap"):
        if name.endswith(suffix):
            name = name.removesuffix(suffix)
            break
    return source.with_name(name + RECOVERED_SUFFIX)


def _read_source(source: Path) -> bytes:
    """Return the bytes of the file to salvage.

    Raises:
        RecordingError: It cannot be read.
    """
    try:
        return source.read_bytes()
    except OSError as err:
        msg = f"{source}: cannot read the file to salvage ({err.strerror}); check the path"
        raise RecordingError(msg) from err


def _walk(source: Path, data: bytes) -> DataSection:
    """Walk the data section tolerantly.

    Raises:
        RecordingError: The file is not MCAP or holds no message to salvage.
    """
    try:
        section = walk_data_section(data, tolerant=True)
    except FormatError as err:
        msg = f"{source}: nothing to salvage: {err} (not an MCAP file or empty)"
        raise RecordingError(msg) from err
    if section.header is None:
        msg = f"{source}: nothing to salvage: the MCAP header is missing or cut off"
        raise RecordingError(msg)
    if section.message_count == 0:
        msg = (
            f"{source}: nothing to salvage: no complete chunk of messages (a recorder killed "
            "before its first flush, 0.5 s into the action, leaves none); record the action again"
        )
        raise RecordingError(msg)
    return section


def _kept(section: DataSection) -> tuple[ChannelKept, ...]:
    """Return per channel what the walk kept."""
    kept = []
    for channel_id, channel in section.channels.items():
        lists = section.messages.get(channel_id)
        log = lists.log_ns if lists else []
        kept.append(ChannelKept(channel.topic, len(log), min(log, default=0), max(log, default=0)))
    return tuple(kept)


def _write(stream: IO[bytes], section: DataSection, report: RecoveryReport) -> None:
    """Write the kept records as a complete MCAP file."""
    header = section.header
    if header is None:  # pragma: no cover (checked by _walk)
        msg = "no header"
        raise RecordingError(msg)
    writer = Writer(stream, compression=CompressionType.ZSTD, enable_data_crcs=True)
    writer.start(profile=header.profile, library=header.library)
    for record in section.metadata:
        values = dict(record.metadata)
        if record.name == VOCABULARY.metadata_record:
            values["source"] = "salvage"  # it promises only what it kept: see schemas sources
        writer.add_metadata(record.name, values)
    writer.add_metadata(RECOVERY_NAME, report.to_metadata())
    ids = _register(writer, section)
    for channel_id, index, lists in _file_order(section):
        writer.add_message(
            ids[channel_id],
            lists.log_ns[index],
            lists.payloads[index],
            lists.publish_ns[index],
            lists.sequence[index],
        )
    writer.finish()  # type: ignore[no-untyped-call]


def _register(writer: Writer, section: DataSection) -> dict[int, int]:
    """Register the kept schemas and channels; return new channel ids by old id."""
    schema_ids = {
        old: writer.register_schema(schema.name, schema.encoding, schema.data)
        for old, schema in section.schemas.items()
    }
    ids = {}
    for old, channel in section.channels.items():
        ids[old] = writer.register_channel(
            channel.topic,
            channel.message_encoding,
            schema_ids.get(channel.schema_id, 0),
            dict(channel.metadata),
        )
    return ids


def _file_order(section: DataSection) -> list[tuple[int, int, ChannelMessages]]:
    """Return (channel id, index in its lists, lists) of every kept message, in file order."""
    located = [
        (order, channel_id, index, lists)
        for channel_id, lists in section.messages.items()
        for index, order in enumerate(lists.order)
    ]
    located.sort(key=lambda entry: entry[0])
    return [(channel_id, index, lists) for _, channel_id, index, lists in located]


def _exists(target: Path) -> RecordingError:
    return RecordingError(
        f"{target}: exists and is never overwritten; delete or move it, or give another "
        "--out path for the salvaged recording"
    )


def _save(section: DataSection, report: RecoveryReport) -> None:
    """Write the salvaged file under a temporary name, sync it and publish it.

    Raises:
        RecordingError: The target exists or the file cannot be written.
    """
    target = report.target
    try:
        with atomic_file(target, replace=False) as stream:  # never replaces a file
            _write(stream, section, report)
    except FileExistsError as err:
        raise _exists(target) from err
    except OSError as err:
        msg = f"{target}: cannot write the salvaged recording ({err.strerror}); check --out"
        raise RecordingError(msg) from err


def salvage(source: Path, target: Path | None = None) -> RecoveryReport:
    """Copy every intact message of ``source`` into a new, complete MCAP file.

    Args:
        source: An unfinished (``*.mcap.part``), truncated or damaged recording; never changed.
        target: The new file (default :func:`recovered_path`); it must not exist.

    Returns:
        What was kept, and where.

    Raises:
        RecordingError: ``target`` exists, ``source`` holds nothing to salvage, or a file
            cannot be read or written; the message names the file and the fix.
    """
    source = Path(source)
    target = Path(target) if target is not None else recovered_path(source)
    if target.exists() or target.resolve() == source.resolve():
        raise _exists(target)
    data = _read_source(source)
    section = _walk(source, data)
    report = RecoveryReport(
        source=source,
        target=target,
        source_bytes=len(data),
        intact_bytes=section.end if section.end > len(MAGIC) else 0,
        complete=section.complete,
        chunks=section.chunks,
        damaged_chunks=len(section.damaged_chunks),
        orphans=section.orphans,
        stopped=section.stopped,
        channels=_kept(section),
    )
    _save(section, report)
    return report
