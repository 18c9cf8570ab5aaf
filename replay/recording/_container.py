"""Container I/O: an MCAP file -> raw messages per topic, summary and metadata; no decoding.

The whole file is read into memory (recordings are a few MB) and every CRC is checked: the
data section CRC (DataEnd record), the summary CRC (Footer) and each chunk's CRC while its
messages are read. Messages are read by one walk through the data section, record by record
(:func:`walk_data_section`), which never trusts a length field: a record that claims more
bytes than the file holds, or a chunk whose uncompressed size is absurd, is refused before
anything is allocated for it. Foreign exceptions (``mcap``, ``struct``, ``zstandard``,
``OSError``) are translated here into :class:`replay.errors.RecordingError` naming the file
and the fix.

An unfinished recording (``*.mcap.part``, left by an interrupted recorder) or a truncated file
is never read as complete: the error says to salvage it with ``atikt-replay check --recover``
(:mod:`replay.recording._salvage`), which uses the same walk in its tolerant mode.
"""

from __future__ import annotations

import enum
import io
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from mcap.records import Channel, Header, Metadata, Schema
from numpy.typing import NDArray

from replay.errors import RecordingError
from schemas import PART_SUFFIX, unreadable

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping

    from mcap.summary import Summary

I64 = NDArray[np.int64]

#: Suffix of a recording the recorder has not finished (still writing, or interrupted).
#: Largest uncompressed chunk the reader accepts, bytes (the recorder's chunks are < 4 MiB).
MAX_CHUNK_BYTES = 256 * 2**20
#: Largest ratio of a chunk's uncompressed to compressed size (the contract's signals: ~3).
MAX_COMPRESSION_RATIO = 1000

MAGIC = b"\x89MCAP0\r\n"
_FOOTER_SIZE = 1 + 8 + 8 + 8 + 4
_DATA_END_SIZE = 1 + 8 + 4
_RECORD = struct.Struct("<BQ")  # opcode, body length
_MESSAGE = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_CHUNK = struct.Struct("<QQQI")  # start time, end time, uncompressed size, uncompressed CRC
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_MAX_TIME = 2**63 - 1  # times are int64 ns in the reader
#: Foreign exceptions that mean "this file is not a readable MCAP file".
_FORMAT_ERRORS = (
    McapError,
    ValueError,  # includes mcap's CRCValidationError and UnicodeDecodeError
    struct.error,
    zstandard.ZstdError,
    EOFError,
    KeyError,
    IndexError,
)


class Opcode(enum.IntEnum):
    """MCAP record types the walk handles (the others are skipped)."""

    HEADER = 0x01
    FOOTER = 0x02
    SCHEMA = 0x03
    CHANNEL = 0x04
    MESSAGE = 0x05
    CHUNK = 0x06
    METADATA = 0x0C
    DATA_END = 0x0F


class Damage(enum.StrEnum):
    """Why a file is not a complete, intact MCAP file; each kind has its own fix."""

    EMPTY = "empty"
    NOT_MCAP = "not MCAP"
    TRUNCATED = "truncated"
    CORRUPT = "corrupt"
    CONTRACT = "contract"


class FormatError(McapError):
    """A record of the file is malformed (internal: translated to :class:`RecordingError`)."""

    def __init__(self, detail: str, damage: Damage = Damage.CORRUPT) -> None:
        """Describe the problem and its kind."""
        super().__init__(detail)
        self.damage = damage


@dataclass(frozen=True, slots=True)
class ChannelInfo:
    """One channel of a recording.

    Attributes:
        topic: Topic name.
        msgtype: Schema name, the ROS 2 message type (``pkg/msg/Type``).
        schema_encoding: Schema encoding (``ros2msg`` for recordings).
        message_encoding: Message encoding (``cdr`` for recordings).
        message_count: Messages on the channel (from the statistics record).
        definition: The schema's text (the message definition the writer used).
    """

    topic: str
    msgtype: str
    schema_encoding: str
    message_encoding: str
    message_count: int
    definition: str = ""


@dataclass(frozen=True, slots=True)
class ContainerSummary:
    """What a recording's summary says, read without touching the messages.

    Attributes:
        path: The file.
        size_bytes: File size in bytes.
        profile: MCAP profile from the header.
        library: Writer library from the header.
        metadata: Metadata records by name (key-value pairs).
        channels: Channels by topic.
        start_ns: First message log time, ns (0 without messages).
        end_ns: Last message log time, ns (0 without messages).
        chunk_count: Number of chunks.
    """

    path: Path
    size_bytes: int
    profile: str
    library: str
    metadata: Mapping[str, Mapping[str, str]]
    channels: Mapping[str, ChannelInfo]
    start_ns: int
    end_ns: int
    chunk_count: int

    @property
    def message_count(self) -> int:
        """Return the number of messages over all channels."""
        return sum(channel.message_count for channel in self.channels.values())


@dataclass(frozen=True, slots=True)
class RawChannel:
    """The undecoded messages of one topic, in file order.

    Attributes:
        info: The channel.
        log_ns: Log (receive) times, ns, shape (messages,).
        publish_ns: Publish (sensor) times, ns, shape (messages,).
        payloads: Message payloads (CDR bytes).
    """

    info: ChannelInfo
    log_ns: I64
    publish_ns: I64
    payloads: tuple[bytes, ...]


@dataclass(frozen=True, slots=True)
class Container:
    """A recording's summary and its raw messages per topic."""

    summary: ContainerSummary
    topics: Mapping[str, RawChannel]


@dataclass(slots=True)
class ChannelMessages:
    """The messages of one channel found by a walk, in file order (parallel lists).

    ``order`` numbers every message of the file, over all channels, in file order.
    """

    order: list[int] = field(default_factory=list)
    sequence: list[int] = field(default_factory=list)
    log_ns: list[int] = field(default_factory=list)
    publish_ns: list[int] = field(default_factory=list)
    payloads: list[bytes] = field(default_factory=list)


@dataclass(slots=True)
class DataSection:
    """What a walk through a file's data section found, in file order.

    Attributes:
        header: The header record (None if the file has none).
        schemas: Schema records by id.
        channels: Channel records by id.
        metadata: Metadata records.
        messages: Messages by channel id.
        message_count: Messages found over all channels.
        end: Offset just past the last record the walk used or skipped intact.
        complete: Whether the walk reached the DataEnd record.
        chunks: Chunks whose messages were read.
        damaged_chunks: (offset, reason) of every chunk skipped as damaged (tolerant walks).
        orphans: Messages skipped because their channel was never defined.
        stopped: Why a tolerant walk stopped before the DataEnd record ("" if it did not).
    """

    header: Header | None = None
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    metadata: list[Metadata] = field(default_factory=list)
    messages: dict[int, ChannelMessages] = field(default_factory=dict)
    message_count: int = 0
    end: int = 0
    complete: bool = False
    chunks: int = 0
    damaged_chunks: list[tuple[int, str]] = field(default_factory=list)
    orphans: int = 0
    stopped: str = ""


def is_part(path: Path) -> bool:
    """Return whether ``path`` names an unfinished recording (``*.mcap.part``)."""
    return Path(path).name.endswith(PART_SUFFIX)


def recover_command(path: Path) -> str:
    """Return the command line that salvages ``path``."""
    return f"'atikt-replay check --recover {path}'"


def _read_bytes(path: Path) -> bytes:
    """Return the content of a finished recording.

    Raises:
        RecordingError: The file is an unfinished recording or cannot be read.
    """
    if is_part(path):
        msg = (
            f"{path}: an unfinished recording (*{PART_SUFFIX}): the recorder was interrupted "
            f"or is still writing, so it is never read as complete; salvage the flushed "
            f"messages with {recover_command(path)}"
        )
        raise RecordingError(msg)
    try:
        return Path(path).read_bytes()
    except OSError as err:
        raise RecordingError(unreadable(path, err, "check the path", "the recording")) from err


def _hint(path: Path, damage: Damage) -> str:
    """Return the fix for a damaged file."""
    recover = recover_command(path)
    if damage is Damage.EMPTY:
        return "the file is empty: nothing was recorded; record the action again"
    if damage is Damage.NOT_MCAP:
        return "give a recording written by atikt-record (*.mcap)"
    if damage is Damage.CONTRACT:
        return "it was not written by atikt-record or atikt-record import-bag; convert it"
    if damage is Damage.TRUNCATED:
        return (
            "the file is truncated or corrupt (an interrupted recorder or an incomplete "
            f"copy): salvage its complete chunks with {recover}, or record it again"
        )
    return (
        "the file is truncated or corrupt: restore it from a copy or record it again "
        f"({recover} salvages the intact chunks)"
    )


def _format_error(path: Path, err: BaseException) -> RecordingError:
    """Return the error for a file that is not a complete, intact MCAP file."""
    damage = err.damage if isinstance(err, FormatError) else Damage.CORRUPT
    detail = " ".join(str(err).split()) or type(err).__name__
    if damage is Damage.CONTRACT:
        return RecordingError(f"{path}: {detail}; {_hint(path, damage)}")
    return RecordingError(f"{path}: not a valid MCAP recording ({detail}); {_hint(path, damage)}")


def _check_ends(data: bytes) -> None:
    """Check the magic at both ends of a complete file.

    Raises:
        FormatError: The file is empty, not MCAP, or truncated.
    """
    if not data:
        msg = "the file has 0 bytes"
        raise FormatError(msg, Damage.EMPTY)
    if not data.startswith(MAGIC):
        msg = "it does not start with the MCAP magic bytes"
        raise FormatError(msg, Damage.NOT_MCAP)
    if len(data) < 2 * len(MAGIC) + _FOOTER_SIZE or not data.endswith(MAGIC):
        msg = "missing MCAP magic at the end of the file"
        raise FormatError(msg, Damage.TRUNCATED)


def _check_crcs(data: bytes) -> int:
    """Check both magics, the summary CRC and the data section CRC.

    Returns:
        The offset of the DataEnd record.

    Raises:
        FormatError: A check fails.
    """
    _check_ends(data)
    footer = len(data) - len(MAGIC) - _FOOTER_SIZE
    opcode, _, summary_start, _, summary_crc = struct.unpack_from("<BQQQI", data, footer)
    if opcode != Opcode.FOOTER:
        msg = "no footer record before the closing magic"
        raise FormatError(msg, Damage.TRUNCATED)
    if not len(MAGIC) + _DATA_END_SIZE <= (summary_start or footer) <= footer:
        msg = f"the footer points the summary at offset {summary_start}, outside the file"
        raise FormatError(msg)
    if summary_crc != 0 and zlib.crc32(data[summary_start or footer : footer + 25]) != summary_crc:
        msg = "summary CRC mismatch"
        raise FormatError(msg)
    data_end = (summary_start or footer) - _DATA_END_SIZE
    opcode, length, data_crc = struct.unpack_from("<BQI", data, data_end)
    if opcode != Opcode.DATA_END or length != 4:  # noqa: PLR2004 (DataEnd record length)
        msg = "no DataEnd record before the summary"
        raise FormatError(msg)
    if data_crc != 0 and zlib.crc32(data[:data_end]) != data_crc:
        msg = "data section CRC mismatch"
        raise FormatError(msg)
    return data_end


def _next_record(data: memoryview, pos: int, stop: int) -> tuple[int, int, int]:
    """Return (opcode, body start, body end) of the record at ``pos``, trusting no length.

    Raises:
        FormatError: The record's head or body extends beyond ``stop`` (TRUNCATED).
    """
    if stop - pos < _RECORD.size:
        msg = f"the record at offset {pos} is cut off after {stop - pos} bytes"
        raise FormatError(msg, Damage.TRUNCATED)
    opcode, length = _RECORD.unpack_from(data, pos)
    body = pos + _RECORD.size
    if length > stop - body:
        msg = (
            f"the record at offset {pos} claims {length} bytes, but only {stop - body} "
            "bytes follow in the file"
        )
        raise FormatError(msg, Damage.TRUNCATED)
    return opcode, body, body + length


def _check_size(compression: str, compressed: int, size: int) -> None:
    """Refuse an absurd uncompressed chunk size before anything is allocated for it.

    Raises:
        FormatError: The size is above :data:`MAX_CHUNK_BYTES` or the compression ratio
            above :data:`MAX_COMPRESSION_RATIO` (or differs from the data without compression).
    """
    if compression == "" and size != compressed:
        msg = f"an uncompressed chunk of {compressed} bytes claims {size} bytes"
        raise FormatError(msg)
    if size > MAX_CHUNK_BYTES or size > MAX_COMPRESSION_RATIO * compressed + 4096:
        msg = (
            f"a chunk of {compressed} compressed bytes claims {size} uncompressed bytes "
            f"(the reader accepts at most {MAX_CHUNK_BYTES} bytes and a ratio of "
            f"{MAX_COMPRESSION_RATIO})"
        )
        raise FormatError(msg)


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    """Return a chunk's records, decompressing into at most ``size`` + 1 bytes.

    Raises:
        FormatError: Unknown compression, or the data does not decompress to ``size`` bytes.
    """
    _check_size(compression, len(data), size)
    if compression == "":
        out = data
    elif compression == "zstd":
        out = zstandard.ZstdDecompressor().stream_reader(data).read(size + 1)
    elif compression == "lz4":
        out = _lz4(data, size)
    else:
        msg = f"unknown chunk compression {compression!r} (the reader knows zstd, lz4, none)"
        raise FormatError(msg)
    if len(out) != size:
        msg = f"a chunk decompresses to {len(out)} bytes, its header says {size}"
        raise FormatError(msg)
    return out


def _lz4(data: bytes, size: int) -> bytes:
    """Return lz4-frame ``data`` decompressed into at most ``size`` + 1 bytes."""
    try:
        from lz4.frame import (  # type: ignore[import-untyped]  # noqa: PLC0415 (optional)
            LZ4FrameDecompressor,
        )
    except ImportError:  # pragma: no cover (lz4 comes with mcap's extras)
        msg = "an lz4-compressed chunk, but the lz4 package is not installed (pip install lz4)"
        raise FormatError(msg) from None
    try:
        out: bytes = LZ4FrameDecompressor().decompress(data, max_length=size + 1)
    except RuntimeError as err:  # lz4 raises RuntimeError for corrupt frames
        raise FormatError(str(err)) from err
    return out


@dataclass(frozen=True, slots=True)
class _Chunk:
    """A chunk record's fields."""

    size: int
    crc: int
    compression: str
    data: bytes


def _parse_chunk(body: memoryview) -> _Chunk:
    """Parse a chunk record's body, checking that its fields add up to the body length.

    Raises:
        FormatError: The fields do not fit the body.
    """
    _, _, size, crc = _CHUNK.unpack_from(body, 0)
    (name_length,) = _U32.unpack_from(body, _CHUNK.size)
    start = _CHUNK.size + _U32.size + name_length
    if start + _U64.size > len(body):
        msg = "a chunk's compression name runs beyond the chunk"
        raise FormatError(msg)
    (records_length,) = _U64.unpack_from(body, start)
    if start + _U64.size + records_length != len(body):
        msg = f"a chunk claims {records_length} bytes of records, its record has room for "
        msg += f"{len(body) - start - _U64.size}"
        raise FormatError(msg)
    compression = bytes(body[_CHUNK.size + _U32.size : start]).decode("utf-8")
    return _Chunk(size, crc, compression, bytes(body[start + _U64.size :]))


def _stream(body: memoryview) -> ReadDataStream:
    return ReadDataStream(io.BytesIO(body))


@dataclass(slots=True)
class _Walk:
    """State of one walk through a data section (or through one chunk's records)."""

    data: memoryview
    tolerant: bool
    section: DataSection = field(default_factory=DataSection)

    def top(self, start: int, stop: int) -> None:
        """Handle the data section's records in ``[start, stop)`` up to the DataEnd record.

        Raises:
            FormatError: A record is malformed or cut off (a tolerant walk raises only for
                records outside chunks).
        """
        pos = start
        while pos < stop:
            opcode, body, end = _next_record(self.data, pos, stop)
            if opcode == Opcode.DATA_END:
                self.section.complete = True
                self.section.end = end
                return
            handler = _TOP.get(opcode)
            if handler is not None:
                handler(self, self.data[body:end], pos)
            pos = self.section.end = end

    def inner(self) -> None:
        """Handle a decompressed chunk's records (schemas, channels, messages).

        Message records, nearly all of a chunk, are read here without a call per record
        (the same checks as :func:`_next_record` and :meth:`message`): a recording holds
        thousands, and the calls were most of the time a file takes to read.

        Raises:
            FormatError: A record is malformed or runs beyond the chunk.
        """
        data, section = self.data, self.section
        pos, stop = 0, len(data)
        record, message = _RECORD.unpack_from, _MESSAGE.unpack_from
        head, fixed = _RECORD.size, _MESSAGE.size
        while pos < stop:
            if stop - pos < head or record(data, pos)[1] > stop - pos - head:
                try:
                    _next_record(data, pos, stop)  # raises, with the reason
                except FormatError as err:
                    msg = f"inside a chunk: {err}"
                    raise FormatError(msg) from err
            opcode, length = record(data, pos)
            body = pos + head
            end = body + length
            if opcode == Opcode.MESSAGE and length >= fixed:
                channel_id, sequence, log_ns, publish_ns = message(data, body)
                lists = section.messages.get(channel_id)
                if lists is None:
                    if channel_id not in section.channels:
                        self.message(data[body:end], pos)  # an orphan: counted or refused
                        pos = end
                        continue
                    lists = section.messages[channel_id] = ChannelMessages()
                lists.order.append(section.message_count)
                section.message_count += 1
                lists.sequence.append(sequence)
                lists.log_ns.append(log_ns)
                lists.publish_ns.append(publish_ns)
                lists.payloads.append(bytes(data[body + fixed : end]))
            else:
                handler = _IN_CHUNK.get(opcode)
                if handler is not None:
                    handler(self, data[body:end], pos)
            pos = end

    def header(self, body: memoryview, pos: int) -> None:
        if pos != len(MAGIC) or self.section.header is not None:
            msg = f"a header record at offset {pos}; MCAP has one, right after the magic"
            raise FormatError(msg)
        self.section.header = Header.read(_stream(body))

    def schema(self, body: memoryview, _pos: int) -> None:
        schema = Schema.read(_stream(body))
        self.section.schemas[schema.id] = schema

    def channel(self, body: memoryview, _pos: int) -> None:
        channel = Channel.read(_stream(body))
        self.section.channels[channel.id] = channel

    def metadata(self, body: memoryview, _pos: int) -> None:
        self.section.metadata.append(Metadata.read(_stream(body)))

    def message(self, body: memoryview, pos: int) -> None:
        if len(body) < _MESSAGE.size:
            msg = f"the message record at offset {pos} has {len(body)} bytes, too short"
            raise FormatError(msg)
        channel_id, sequence, log_ns, publish_ns = _MESSAGE.unpack_from(body, 0)
        if channel_id not in self.section.channels:
            if self.tolerant:
                self.section.orphans += 1
                return
            msg = f"a message at offset {pos} is on channel {channel_id}, which is not defined"
            raise FormatError(msg)
        lists = self.section.messages.get(channel_id)
        if lists is None:
            lists = self.section.messages[channel_id] = ChannelMessages()
        lists.order.append(self.section.message_count)
        self.section.message_count += 1
        lists.sequence.append(sequence)
        lists.log_ns.append(log_ns)
        lists.publish_ns.append(publish_ns)
        lists.payloads.append(bytes(body[_MESSAGE.size :]))

    def chunk(self, body: memoryview, pos: int) -> None:
        """Read a chunk's records; a tolerant walk skips a damaged chunk as a whole."""
        before = _snapshot(self.section) if self.tolerant else None
        try:
            records = _chunk_records(body)
            _Walk(memoryview(records), self.tolerant, self.section).inner()
        except _FORMAT_ERRORS as err:
            if before is None:
                raise
            _restore(self.section, before)
            self.section.damaged_chunks.append((pos, " ".join(str(err).split())))
            return
        self.section.chunks += 1


def _chunk_records(body: memoryview) -> bytes:
    """Return a chunk's decompressed records, CRC checked.

    Raises:
        FormatError: The chunk is malformed, its size absurd, or its CRC wrong.
    """
    chunk = _parse_chunk(body)
    records = _decompress(chunk.compression, chunk.data, chunk.size)
    if chunk.crc != 0 and zlib.crc32(records) != chunk.crc:
        msg = "chunk CRC mismatch"
        raise FormatError(msg)
    return records


_IN_CHUNK: dict[int, Callable[[_Walk, memoryview, int], None]] = {
    Opcode.SCHEMA: _Walk.schema,
    Opcode.CHANNEL: _Walk.channel,
    Opcode.MESSAGE: _Walk.message,
}
_TOP: dict[int, Callable[[_Walk, memoryview, int], None]] = {
    Opcode.HEADER: _Walk.header,
    Opcode.METADATA: _Walk.metadata,
    Opcode.CHUNK: _Walk.chunk,
    **_IN_CHUNK,
}

_Snapshot = tuple[dict[int, Schema], dict[int, Channel], dict[int, int], int]


def _snapshot(section: DataSection) -> _Snapshot:
    """Return what a chunk may add to ``section``, to undo a chunk that fails half-way."""
    counts = {channel: len(lists.log_ns) for channel, lists in section.messages.items()}
    return dict(section.schemas), dict(section.channels), counts, section.message_count


def _restore(section: DataSection, before: _Snapshot) -> None:
    """Undo the records of a chunk that failed half-way (see :func:`_snapshot`)."""
    schemas, channels, counts, section.message_count = before
    section.schemas, section.channels = schemas, channels
    for channel in list(section.messages):
        keep = counts.get(channel, 0)
        if keep == 0:
            del section.messages[channel]
            continue
        lists = section.messages[channel]
        columns = (lists.order, lists.sequence, lists.log_ns, lists.publish_ns, lists.payloads)
        for column in columns:
            del column[keep:]


def walk_data_section(
    data: bytes, *, tolerant: bool = False, stop: int | None = None
) -> DataSection:
    """Read the records of a file's data section in file order, trusting no length field.

    Args:
        data: The file's bytes (starting with the MCAP magic).
        tolerant: Salvage mode: skip damaged chunks and stop quietly at the first record that
            is cut off or malformed (why is in ``stopped``); otherwise raise.
        stop: Offset where the walk ends (the DataEnd record or the end of ``data``).

    Returns:
        The header, schemas, channels, metadata and messages found.

    Raises:
        FormatError: A strict walk found a malformed or truncated record.
        McapError: Likewise, from the mcap record parsers.
    """
    if not data.startswith(MAGIC):
        msg = "it does not start with the MCAP magic bytes"
        raise FormatError(msg, Damage.NOT_MCAP if data else Damage.EMPTY)
    walk = _Walk(memoryview(data), tolerant=tolerant)
    walk.section.end = len(MAGIC)
    try:
        walk.top(len(MAGIC), len(data) if stop is None else stop)
    except _FORMAT_ERRORS as err:
        if not tolerant:
            raise
        walk.section.stopped = " ".join(str(err).split())
    if tolerant and not walk.section.complete and not walk.section.stopped:
        walk.section.stopped = "the file ends without a DataEnd record"
    return walk.section


def _channels(summary: Summary) -> dict[str, ChannelInfo]:
    """Return the channels of a summary by topic."""
    counts = summary.statistics.channel_message_counts if summary.statistics else {}
    channels: dict[str, ChannelInfo] = {}
    for channel in summary.channels.values():
        schema = summary.schemas.get(channel.schema_id)
        if channel.topic in channels:
            msg = (
                f"two channels carry the topic {channel.topic} (one channel per topic: the "
                "file was merged or written by another tool; split or rewrite it)"
            )
            raise FormatError(msg, Damage.CONTRACT)
        channels[channel.topic] = ChannelInfo(
            topic=channel.topic,
            msgtype=schema.name if schema else "",
            schema_encoding=schema.encoding if schema else "",
            message_encoding=channel.message_encoding,
            message_count=counts.get(channel.id, 0),
            definition=schema.data.decode("utf-8") if schema else "",
        )
    return channels


def _summarize(path: Path, size: int, reader: SeekingReader) -> ContainerSummary:
    """Read header, summary and metadata records."""
    header = reader.get_header()
    summary = reader.get_summary()
    if summary is None:
        msg = "no summary section"
        raise FormatError(msg)
    stats = summary.statistics
    return ContainerSummary(
        path=path,
        size_bytes=size,
        profile=header.profile,
        library=header.library,
        metadata={record.name: dict(record.metadata) for record in reader.iter_metadata()},
        channels=_channels(summary),
        start_ns=stats.message_start_time if stats else 0,
        end_ns=stats.message_end_time if stats else 0,
        chunk_count=len(summary.chunk_indexes),
    )


def read_summary(path: Path) -> ContainerSummary:
    """Read a recording's header, summary and metadata, checking the file's CRCs.

    Args:
        path: An MCAP file.

    Returns:
        The summary; messages are not read.

    Raises:
        RecordingError: The file cannot be read, is unfinished (``*.mcap.part``), or is not
            an intact MCAP file.
    """
    path = Path(path)
    data = _read_bytes(path)
    try:
        _check_crcs(data)
        return _summarize(path, len(data), SeekingReader(io.BytesIO(data), validate_crcs=True))
    except _FORMAT_ERRORS as err:
        raise _format_error(path, err) from err


def _check_counts(section: DataSection, summary: ContainerSummary) -> None:
    """Check that the data section holds what the summary's statistics say.

    Raises:
        FormatError: A channel is missing from the data section or its count differs.
    """
    found = {channel.topic: channel.id for channel in section.channels.values()}
    for topic, info in summary.channels.items():
        if topic not in found:
            msg = f"the summary lists channel {topic}, which the data section never defines"
            raise FormatError(msg)
        lists = section.messages.get(found[topic])
        count = len(lists.log_ns) if lists else 0
        if count != info.message_count:
            msg = (
                f"the summary counts {info.message_count} messages on {topic}, "
                f"the data section holds {count}"
            )
            raise FormatError(msg)


def _raw_channels(section: DataSection, summary: ContainerSummary) -> dict[str, RawChannel]:
    """Return every summary channel's messages as arrays, in file order."""
    ids = {channel.topic: channel.id for channel in section.channels.values()}
    topics = {}
    for topic, info in summary.channels.items():
        lists = section.messages.get(ids[topic], ChannelMessages())
        if max(lists.log_ns, default=0) > _MAX_TIME or max(lists.publish_ns, default=0) > _MAX_TIME:
            msg = f"a message on {topic} has a time beyond 2**63 - 1 ns (the year 2262)"
            raise FormatError(msg)
        topics[topic] = RawChannel(
            info=info,
            log_ns=np.array(lists.log_ns, dtype=np.int64),
            publish_ns=np.array(lists.publish_ns, dtype=np.int64),
            payloads=tuple(lists.payloads),
        )
    return topics


def read_container(path: Path) -> Container:
    """Read a recording's summary and all its messages, undecoded, checking every CRC.

    Args:
        path: An MCAP file.

    Returns:
        Summary and raw messages per topic (every summary channel has an entry).

    Raises:
        RecordingError: The file cannot be read, is unfinished (``*.mcap.part``), or is not
            an intact MCAP file; the message names the file and the fix.
    """
    path = Path(path)
    data = _read_bytes(path)
    try:
        data_end = _check_crcs(data)
        reader = SeekingReader(io.BytesIO(data), validate_crcs=True)
        summary = _summarize(path, len(data), reader)
        section = walk_data_section(data, stop=data_end + _DATA_END_SIZE)
        _check_counts(section, summary)
        topics = _raw_channels(section, summary)
    except _FORMAT_ERRORS as err:
        raise _format_error(path, err) from err
    return Container(summary=summary, topics=topics)
