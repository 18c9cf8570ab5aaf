"""A chunked MCAP writer with a fast message path; the same bytes as ``mcap``'s own ``Writer``.

``mcap.writer.Writer`` builds every message record through a dataclass and five small
``struct`` writes into a ``BytesIO`` (and every message index entry through two more): about
10 us per message in Python, a third of the time it takes to record the simulated dataset
(3 million messages). This writer keeps the library for every other record (header, metadata,
schemas, channels, chunks, indexes, statistics, summary: ``mcap.records``) and for the format's
rules, and hand-writes only the two records written once per message: the message record (one
``struct.pack`` of its fixed fields, the payload appended by reference) and the message index
(one ``numpy`` conversion of its (log time, offset) pairs). For the settings the recorder uses
(chunked; every index, the statistics and the summary offsets; CRCs, data CRC optional) it
writes byte for byte what ``mcap.writer.Writer`` writes for the same calls
(``tests/recorder/test_mcap_writer.py`` compares the two on random call sequences), so a
recording's bytes, and the dataset's digests, do not depend on which of the two wrote it.
"""

from __future__ import annotations

import importlib
import struct
import zlib
from collections import defaultdict
from typing import IO, TYPE_CHECKING, Any

import numpy as np
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.writer import MCAP0_MAGIC, CompressionType

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping

#: A message record's opcode, length and fixed fields: channel id, sequence, log and publish
#: time (the MCAP specification's Message record), followed by the payload.
_MESSAGE = struct.Struct("<BQHIQQ")
_MESSAGE_FIXED = _MESSAGE.size - 9  # the record's fields before the payload
#: A message index record's opcode, length, channel id and the byte length of its entries.
_MESSAGE_INDEX = struct.Struct("<BQHI")
_INDEX_ENTRY = 16  # uint64 log time, uint64 offset of the message record in the chunk
_FOOTER_FIELDS = struct.Struct("<BQQQ")


def _compressor(compression: CompressionType) -> tuple[str, Callable[[bytes], bytes]]:
    """Return the chunk compression's name and function, as ``mcap.writer.Writer`` uses them."""
    if compression == CompressionType.ZSTD:
        # zstandard.compress(data) is ZstdCompressor(level=3).compress(data); one compressor
        # reused gives the same bytes without a new context per chunk
        return "zstd", zstandard.ZstdCompressor(level=3).compress
    if compression == CompressionType.LZ4:
        frame = importlib.import_module("lz4.frame")  # optional, as for mcap's Writer
        return "lz4", frame.compress
    return "", bytes


class McapWriter:
    """Write a chunked, indexed MCAP file to a binary stream (not closed by the writer).

    The methods are those of ``mcap.writer.Writer`` that the recorder uses, with the same
    arguments and the same output.
    """

    def __init__(
        self,
        output: IO[bytes],
        *,
        chunk_size: int = 1024 * 1024,
        compression: CompressionType = CompressionType.ZSTD,
        enable_data_crcs: bool = False,
    ) -> None:
        """Prepare to write to ``output``; nothing is written before :meth:`start`.

        Args:
            output: The binary stream (its ``tell`` gives the offsets of the indexes).
            chunk_size: A chunk ends once its records exceed this many bytes (uncompressed).
            compression: Chunk compression.
            enable_data_crcs: Write the data section's CRC into the DataEnd record.
        """
        self._stream = output
        self._chunk_size = chunk_size
        self._compression, self._compress = _compressor(compression)
        self._data_crcs = enable_data_crcs
        self._data_crc = 0
        self._records = RecordBuilder()
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._metadata_indexes: list[MetadataIndex] = []
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_count = 0
        self._message_count = 0
        self._start_ns = 0
        self._end_ns = 0
        self._channel_counts: defaultdict[int, int] = defaultdict(int)
        # the open chunk: its records, their size, and per channel (log time, offset) pairs
        self._chunk_parts: list[bytes] = []
        self._chunk_bytes = 0
        self._chunk_messages = 0
        self._chunk_start_ns = 0
        self._chunk_end_ns = 0
        self._chunk_index: dict[int, list[int]] = {}

    def start(self, profile: str, library: str) -> None:
        """Write the magic and the header record."""
        self._stream.write(MCAP0_MAGIC)
        if self._data_crcs:
            self._data_crc = zlib.crc32(MCAP0_MAGIC, self._data_crc)
        Header(profile, library).write(self._records)
        self._write_records()

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Write a metadata record (outside any chunk) and index it."""
        self._write_records()
        offset = self._stream.tell()
        self._metadata_count += 1
        Metadata(name=name, metadata=dict(data)).write(self._records)
        self._metadata_indexes.append(
            MetadataIndex(offset=offset, length=self._records.count, name=name)
        )
        self._write_records()

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Add a schema to the open chunk; return its id (1, 2, ...)."""
        schema = Schema(id=len(self._schemas) + 1, data=data, encoding=encoding, name=name)
        self._schemas[schema.id] = schema
        self._add_to_chunk(schema)
        return schema.id

    def register_channel(
        self,
        topic: str,
        message_encoding: str,
        schema_id: int,
        metadata: Mapping[str, str] | None = None,
    ) -> int:
        """Add a channel to the open chunk; return its id (1, 2, ...)."""
        channel = Channel(
            id=len(self._channels) + 1,
            topic=topic,
            message_encoding=message_encoding,
            schema_id=schema_id,
            metadata=dict(metadata or {}),
        )
        self._channels[channel.id] = channel
        self._add_to_chunk(channel)
        return channel.id

    def _add_to_chunk(self, record: Schema | Channel) -> None:
        """Put a schema or channel record into the open chunk."""
        builder = RecordBuilder()
        record.write(builder)
        data: bytes = builder.end()  # type: ignore[no-untyped-call]
        self._chunk_parts.append(data)
        self._chunk_bytes += len(data)
        if self._chunk_bytes > self._chunk_size:
            self._finish_chunk()

    def add_message(
        self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int = 0
    ) -> None:
        """Add a message to the open chunk; end the chunk once it exceeds the chunk size."""
        record = _MESSAGE.pack(
            Opcode.MESSAGE,
            _MESSAGE_FIXED + len(data),
            channel_id,
            sequence,
            log_time,
            publish_time,
        )
        if self._message_count == 0 or log_time < self._start_ns:
            self._start_ns = log_time
        self._end_ns = max(self._end_ns, log_time)
        self._channel_counts[channel_id] += 1
        self._message_count += 1
        if self._chunk_messages == 0 or log_time < self._chunk_start_ns:
            self._chunk_start_ns = log_time
        self._chunk_end_ns = max(self._chunk_end_ns, log_time)
        entries = self._chunk_index.get(channel_id)
        if entries is None:
            entries = self._chunk_index[channel_id] = []
        entries += (log_time, self._chunk_bytes)
        self._chunk_messages += 1
        self._chunk_parts += (record, data)
        self._chunk_bytes += len(record) + len(data)
        if self._chunk_bytes > self._chunk_size:
            self._finish_chunk()

    def flush(self) -> None:
        """End the open chunk and hand everything written so far to the operating system."""
        self._finish_chunk()
        self._write_records()
        self._stream.flush()

    def _write_records(self) -> None:
        """Write the records built so far to the stream (and into the data section's CRC)."""
        data: bytes = self._records.end()  # type: ignore[no-untyped-call]
        if self._data_crcs:
            self._data_crc = zlib.crc32(data, self._data_crc)
        self._stream.write(data)

    def _finish_chunk(self) -> None:
        """Compress and write the open chunk and its message indexes (nothing without messages).

        Schema and channel records of a chunk without messages stay for the next chunk.
        """
        if self._chunk_messages == 0:
            return
        data = b"".join(self._chunk_parts)
        compressed = self._compress(data)
        chunk = Chunk(
            compression=self._compression,
            data=compressed,
            message_start_time=self._chunk_start_ns,
            message_end_time=self._chunk_end_ns,
            uncompressed_crc=zlib.crc32(data),
            uncompressed_size=len(data),
        )
        self._write_records()
        chunk_start = self._stream.tell()
        chunk.write(self._records)
        index = ChunkIndex(
            message_start_time=chunk.message_start_time,
            message_end_time=chunk.message_end_time,
            chunk_start_offset=chunk_start,
            chunk_length=self._records.count,
            message_index_offsets={},
            message_index_length=0,
            compression=chunk.compression,
            compressed_size=len(compressed),
            uncompressed_size=chunk.uncompressed_size,
        )
        self._write_records()
        index_start = self._stream.tell()
        indexes: list[bytes] = []
        length = 0
        for channel_id, entries in self._chunk_index.items():
            index.message_index_offsets[channel_id] = index_start + length
            size = len(entries) * 8
            head = _MESSAGE_INDEX.pack(Opcode.MESSAGE_INDEX, 6 + size, channel_id, size)
            indexes += (head, np.array(entries, dtype="<u8").tobytes())
            length += len(head) + size
        index.message_index_length = length
        self._records.write(b"".join(indexes))
        self._write_records()
        self._chunk_indexes.append(index)
        self._chunk_parts = []
        self._chunk_bytes = 0
        self._chunk_messages = 0
        self._chunk_start_ns = self._chunk_end_ns = 0
        self._chunk_index = {}

    def finish(self) -> None:
        """End the open chunk; write the data end, the summary, the footer and the magic."""
        self._finish_chunk()
        DataEnd(self._data_crc).write(self._records)
        self._write_records()
        summary_start = self._stream.tell()
        summary = RecordBuilder()
        offsets = []

        def group(opcode: Opcode, records: list[Any]) -> None:
            start = summary.count
            for record in records:
                record.write(summary)
            offsets.append(SummaryOffset(opcode, summary_start + start, summary.count - start))

        group(Opcode.SCHEMA, list(self._schemas.values()))
        group(Opcode.CHANNEL, list(self._channels.values()))
        group(Opcode.STATISTICS, [self._statistics()])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.ATTACHMENT_INDEX, [])
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        offset_start = summary_start + summary.count
        for offset in offsets:
            offset.write(summary)
        data: bytes = summary.end()  # type: ignore[no-untyped-call]
        crc = zlib.crc32(data)
        fields = _FOOTER_FIELDS.pack(Opcode.FOOTER, 8 + 8 + 4, summary_start, offset_start)
        crc = zlib.crc32(fields, crc)
        self._stream.write(data)
        Footer(
            summary_start=summary_start, summary_offset_start=offset_start, summary_crc=crc
        ).write(self._records)
        self._write_records()
        self._stream.write(MCAP0_MAGIC)

    def _statistics(self) -> Statistics:
        """Return the statistics record of what was written."""
        return Statistics(
            attachment_count=0,
            channel_count=len(self._channels),
            channel_message_counts=self._channel_counts,
            chunk_count=len(self._chunk_indexes),
            message_count=self._message_count,
            message_end_time=self._end_ns,
            message_start_time=self._start_ns,
            metadata_count=self._metadata_count,
            schema_count=len(self._schemas),
        )
