"""Container I/O: an MCAP file -> raw messages per topic, summary and metadata; no decoding.

The whole file is read into memory (recordings are a few MB) and every CRC is checked: the
data section CRC (DataEnd record), the summary CRC (Footer) and each chunk's CRC while its
messages are read. Foreign exceptions (``mcap``, ``struct``, ``zstandard``, ``OSError``) are
translated here into :class:`replay.errors.RecordingError` naming the file and the fix.
"""

from __future__ import annotations

import io
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import zstandard
from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from numpy.typing import NDArray

from replay.errors import RecordingError

if TYPE_CHECKING:
    from collections.abc import Mapping

    from mcap.summary import Summary

I64 = NDArray[np.int64]

_MAGIC = b"\x89MCAP0\r\n"
_FOOTER_SIZE = 1 + 8 + 8 + 8 + 4
_DATA_END_SIZE = 1 + 8 + 4
_OPCODE_FOOTER = 0x02
_OPCODE_DATA_END = 0x0F
#: Foreign exceptions that mean "this file is not a readable MCAP file".
_FORMAT_ERRORS = (
    McapError,
    ValueError,  # includes mcap's CRCValidationError
    struct.error,
    zstandard.ZstdError,
    EOFError,
    KeyError,
    IndexError,
)


@dataclass(frozen=True, slots=True)
class ChannelInfo:
    """One channel of a recording.

    Attributes:
        topic: Topic name.
        msgtype: Schema name, the ROS 2 message type (``pkg/msg/Type``).
        schema_encoding: Schema encoding (``ros2msg`` for recordings).
        message_encoding: Message encoding (``cdr`` for recordings).
        message_count: Messages on the channel (from the statistics record).
    """

    topic: str
    msgtype: str
    schema_encoding: str
    message_encoding: str
    message_count: int


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


def _read_bytes(path: Path) -> bytes:
    """Return the file's content.

    Raises:
        RecordingError: The file cannot be read.
    """
    try:
        return Path(path).read_bytes()
    except OSError as err:
        msg = f"{path}: cannot read the recording ({err.strerror}); check the path"
        raise RecordingError(msg) from err


def _format_error(path: Path, err: BaseException) -> RecordingError:
    """Return the error for a file that is not a complete, intact MCAP file."""
    hint = (
        "the recorder was interrupted: record the action again"
        if path.name.endswith(".part")
        else "the file is truncated or corrupt: record it again or restore it from a copy"
    )
    return RecordingError(f"{path}: not a valid MCAP recording ({err}); {hint}")


def _check_crcs(path: Path, data: bytes) -> None:
    """Check the magic at both ends, the summary CRC and the data section CRC.

    Raises:
        RecordingError: A check fails.
    """
    if len(data) < 2 * len(_MAGIC) + _FOOTER_SIZE or not (
        data.startswith(_MAGIC) and data.endswith(_MAGIC)
    ):
        raise _format_error(path, McapError("missing MCAP magic at the start or the end"))
    footer = len(data) - len(_MAGIC) - _FOOTER_SIZE
    opcode, _, summary_start, _, summary_crc = struct.unpack_from("<BQQQI", data, footer)
    if opcode != _OPCODE_FOOTER:
        raise _format_error(path, McapError("no footer record before the closing magic"))
    if summary_crc != 0 and zlib.crc32(data[summary_start or footer : footer + 25]) != summary_crc:
        raise _format_error(path, McapError("summary CRC mismatch"))
    data_end = (summary_start or footer) - _DATA_END_SIZE
    opcode, length, data_crc = struct.unpack_from("<BQI", data, data_end)
    if opcode != _OPCODE_DATA_END or length != 4:  # noqa: PLR2004 (DataEnd record length)
        raise _format_error(path, McapError("no DataEnd record before the summary"))
    if data_crc != 0 and zlib.crc32(data[:data_end]) != data_crc:
        raise _format_error(path, McapError("data section CRC mismatch"))


def _channels(summary: Summary) -> dict[str, ChannelInfo]:
    """Return the channels of a summary by topic."""
    counts = summary.statistics.channel_message_counts if summary.statistics else {}
    channels: dict[str, ChannelInfo] = {}
    for channel in summary.channels.values():
        schema = summary.schemas.get(channel.schema_id)
        channels[channel.topic] = ChannelInfo(
            topic=channel.topic,
            msgtype=schema.name if schema else "",
            schema_encoding=schema.encoding if schema else "",
            message_encoding=channel.message_encoding,
            message_count=counts.get(channel.id, 0),
        )
    return channels


def _summarize(path: Path, size: int, reader: SeekingReader) -> ContainerSummary:
    """Read header, summary and metadata records."""
    header = reader.get_header()
    summary = reader.get_summary()
    if summary is None:
        raise _format_error(path, McapError("no summary section"))
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
        RecordingError: The file cannot be read or is not an intact MCAP file.
    """
    path = Path(path)
    data = _read_bytes(path)
    try:
        _check_crcs(path, data)
        return _summarize(path, len(data), SeekingReader(io.BytesIO(data), validate_crcs=True))
    except _FORMAT_ERRORS as err:
        raise _format_error(path, err) from err


def _collect(
    reader: SeekingReader, summary: ContainerSummary
) -> dict[str, tuple[list[int], list[int], list[bytes]]]:
    """Gather log times, publish times and payloads per topic, in file order."""
    collected: dict[str, tuple[list[int], list[int], list[bytes]]] = {
        topic: ([], [], []) for topic in summary.channels
    }
    by_channel: dict[int, tuple[list[int], list[int], list[bytes]]] = {}
    for _, channel, message in reader.iter_messages(log_time_order=False):
        lists = by_channel.get(channel.id)
        if lists is None:
            lists = by_channel[channel.id] = collected[channel.topic]
        lists[0].append(message.log_time)
        lists[1].append(message.publish_time)
        lists[2].append(message.data)
    return collected


def read_container(path: Path) -> Container:
    """Read a recording's summary and all its messages, undecoded, checking every CRC.

    Args:
        path: An MCAP file.

    Returns:
        Summary and raw messages per topic (every summary channel has an entry).

    Raises:
        RecordingError: The file cannot be read or is not an intact MCAP file.
    """
    path = Path(path)
    data = _read_bytes(path)
    try:
        _check_crcs(path, data)
        reader = SeekingReader(io.BytesIO(data), validate_crcs=True)
        summary = _summarize(path, len(data), reader)
        collected = _collect(reader, summary)
    except _FORMAT_ERRORS as err:
        raise _format_error(path, err) from err
    topics = {
        topic: RawChannel(
            info=summary.channels[topic],
            log_ns=np.array(log, dtype=np.int64),
            publish_ns=np.array(publish, dtype=np.int64),
            payloads=tuple(payloads),
        )
        for topic, (log, publish, payloads) in collected.items()
    }
    return Container(summary=summary, topics=topics)
