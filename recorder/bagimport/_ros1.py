"""A ROS 1 bag reader that streams: chunk after chunk, without the bag's per-message index.

rosbags' ``rosbag1.Reader`` loads an index entry for every message when it opens a bag (about
130 bytes each: 0.4 GB for a 1 GB bag of small messages). An import reads every message once,
in order, so this reader keeps only the connections and the chunk list of the bag's index and
walks each chunk's records in the order they were written (the order ``rosbag record`` received
them). Memory: one decompressed chunk at a time.
"""

from __future__ import annotations

import os
import struct
from io import BytesIO
from typing import TYPE_CHECKING

from rosbags.rosbag1 import Reader, ReaderError
from rosbags.rosbag1.reader import Header, RecordType, read_bytes, read_uint32

from recorder.bagimport._bounded import MAX_CHUNK_BYTES, ROS1_DECOMPRESSORS

if TYPE_CHECKING:
    from collections.abc import Collection, Generator

    from rosbags.interfaces import Connection
    from rosbags.rosbag1.reader import IndexData


class StreamingReader(Reader):
    """``rosbags.rosbag1.Reader`` that reads messages chunk by chunk, in file order."""

    def read_index_data(self, pos: int, indexes: dict[int, list[IndexData]]) -> None:
        """Skip the per-message index (messages are found by walking the chunks)."""
        del pos, indexes

    def open(self) -> None:
        """Open the bag: connections and chunk list; message counts from the chunk infos."""
        super().open()
        counts: dict[int, int] = {}
        for info in self.chunk_infos:
            for conn, count in info.connection_counts.items():
                counts[conn] = counts.get(conn, 0) + count
        self.connections = [c._replace(msgcount=counts.get(c.id, 0)) for c in self.connections]

    def _chunk(self, pos: int) -> bytes:
        """Return the decompressed records of the chunk at ``pos``.

        Decompression stops one byte past the declared size (a chunk that lies about its
        size is refused without producing the rest: a bz2 bomb of 500 kB makes gigabytes).

        Raises:
            ReaderError: The chunk claims more than :data:`MAX_CHUNK_BYTES`, its data
                decompresses to another size, or its compression is unknown.
        """
        assert self.bio  # noqa: S101 (open() set it)
        _ = self.bio.seek(pos)
        header = Header.read(self.bio, RecordType.CHUNK)
        size = header.get_uint32("size")
        if size > MAX_CHUNK_BYTES:
            msg = f"a chunk at byte {pos} claims {size} bytes"
            raise ReaderError(msg)
        compression = header.get_string("compression")
        if compression not in ROS1_DECOMPRESSORS:
            msg = f"a chunk at byte {pos} has compression {compression!r} (known: bz2, lz4, none)"
            raise ReaderError(msg)
        chunk = self.chunks[pos]
        _ = self.bio.seek(chunk.datapos)
        records = ROS1_DECOMPRESSORS[compression](read_bytes(self.bio, chunk.datasize), size)
        if len(records) != size:
            msg = f"a chunk at byte {pos} decompresses to {len(records)} bytes, it claims {size}"
            raise ReaderError(msg)
        return records

    def messages(
        self,
        connections: Collection[Connection] = (),
        start: int | None = None,
        stop: int | None = None,
    ) -> Generator[tuple[Connection, int, bytes], None, None]:
        """Yield (connection, receive time ns, raw bytes) chunk by chunk, in file order."""
        self._check_open()
        wanted = {c.id: c for c in (connections or self.connections)}
        infos = sorted(self.chunk_infos, key=lambda info: (info.start_time, info.pos))
        for info in infos:
            if not wanted.keys() & info.connection_counts.keys():
                continue
            yield from _records(self._chunk(info.pos), wanted, start, stop)


_U32 = struct.Struct("<I").unpack_from
_TIME = struct.Struct("<II").unpack
_NS_PER_S = 1_000_000_000


def _records(  # noqa: C901, PLR0912 (one loop over a chunk's records, the import's hot path)
    records: bytes, wanted: dict[int, Connection], start: int | None, stop: int | None
) -> Generator[tuple[Connection, int, bytes], None, None]:
    """Yield the wanted messages of a chunk's records.

    rosbags' ``Header.read`` builds a dict per record from a file object; this loop reads the
    three fields of a message record (``op``, ``conn``, ``time``) from the chunk's bytes with
    the same meaning. A record it does not vouch for (another field, a size that does not fit)
    is read, with the rest of the chunk, by :func:`_records_checked` (rosbags' reading, which
    raises rosbags' errors for a damaged chunk).
    """
    end, pos = len(records), 0
    while pos < end:
        if pos + 4 > end:
            break
        stop_at = pos + 4 + _U32(records, pos)[0]
        if stop_at + 4 > end:
            break
        op = conn = time = None
        at = pos + 4
        while at + 4 <= stop_at:
            size = _U32(records, at)[0]
            if at + 4 + size > stop_at:
                break
            name, sep, value = records[at + 4 : at + 4 + size].partition(b"=")
            if not sep:
                break
            if name == b"op":
                op = value
            elif name == b"conn":
                conn = value
            elif name == b"time":
                time = value
            elif not name.isascii():  # rosbags decodes every name (UTF-8)
                break
            at += 4 + size
        if at != stop_at or op is None or len(op) != 1:
            break
        size = _U32(records, stop_at)[0]
        data = stop_at + 4
        if op[0] != RecordType.MSGDATA:
            pos = data + size
            continue
        if conn is None or len(conn) < 4 or time is None or len(time) != 8:  # noqa: PLR2004
            break
        connection = wanted.get(_U32(conn, 0)[0])
        sec, nsec = _TIME(time)
        stamp = sec * _NS_PER_S + nsec
        if connection is None or not (
            (start is None or stamp >= start) and (stop is None or stamp < stop)
        ):
            pos = data + size
            continue
        if data + size > end:
            break
        yield connection, stamp, records[data : data + size]
        pos = data + size
    if pos < end:
        reader = BytesIO(records)
        _ = reader.seek(pos)
        yield from _records_checked(reader, end, wanted, start, stop)


def _records_checked(
    records: BytesIO,
    end: int,
    wanted: dict[int, Connection],
    start: int | None,
    stop: int | None,
) -> Generator[tuple[Connection, int, bytes], None, None]:
    """Yield the wanted messages of a chunk's records from ``records``' position (rosbags)."""
    while records.tell() < end:
        header = Header.read(records)
        size = read_uint32(records)
        if header.get_uint8("op") != RecordType.MSGDATA:
            _ = records.seek(size, os.SEEK_CUR)
            continue
        connection = wanted.get(header.get_uint32("conn"))
        time = header.get_time("time")
        inside = (start is None or time >= start) and (stop is None or time < stop)
        if connection is None or not inside:
            _ = records.seek(size, os.SEEK_CUR)
            continue
        yield connection, time, read_bytes(records, size)
