"""A ROS 1 bag reader that streams: chunk after chunk, without the bag's per-message index.

rosbags' ``rosbag1.Reader`` loads an index entry for every message when it opens a bag (about
130 bytes each: 0.4 GB for a 1 GB bag of small messages). An import reads every message once,
in order, so this reader keeps only the connections and the chunk list of the bag's index and
walks each chunk's records, merging chunks that overlap in time so that messages come in
receive-time order whatever the file order (a bag merged from several recorders). Memory: the
decompressed chunks that overlap the current time (one, for a bag from one recorder).
"""

from __future__ import annotations

import heapq
import os
import struct
from io import BytesIO
from operator import itemgetter
from typing import TYPE_CHECKING

from rosbags.rosbag1 import Reader, ReaderError
from rosbags.rosbag1.reader import Header, RecordType, read_bytes, read_uint32

from recorder.bagimport._bounded import MAX_CHUNK_BYTES, ROS1_DECOMPRESSORS
from recorder.errors import BagImportError

if TYPE_CHECKING:
    from collections.abc import Collection, Generator, Iterable, Iterator, Sequence

    from rosbags.interfaces import Connection
    from rosbags.rosbag1.reader import IndexData

#: Most message bytes of chunks overlapping in time held at once (a merged bag's k-way merge).
MAX_OPEN_BYTES = 512 * 1024 * 1024


class StreamingReader(Reader):
    """``rosbags.rosbag1.Reader`` that reads messages chunk by chunk, in receive-time order."""

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
        """Yield (connection, receive time ns, raw bytes) in receive-time order.

        A bag recorded by one ``rosbag record`` has chunks one after the other in time; a bag
        merged from several recorders (or written by a tool in another order) has chunks that
        overlap in time and messages out of order inside a chunk. Chunks are opened in the
        order of their first message's time, each chunk's messages sorted by time, and the
        open chunks merged (a k-way merge), so memory holds only the chunks that overlap the
        current time, at most :data:`MAX_OPEN_BYTES` of messages.
        """
        self._check_open()
        wanted = {c.id: c for c in (connections or self.connections)}
        infos = sorted(
            (info for info in self.chunk_infos if wanted.keys() & info.connection_counts.keys()),
            key=lambda info: (info.start_time, info.pos),
        )
        starts = [info.start_time for info in infos]
        chunks = (_in_time_order(_records(self._chunk(i.pos), wanted, start, stop)) for i in infos)
        yield from _merged(starts, chunks, str(self.path))


_Message = tuple["Connection", int, bytes]


def _in_time_order(messages: Iterable[_Message]) -> list[_Message]:
    """Return a chunk's messages sorted by receive time (stable; usually already sorted)."""
    out = list(messages)
    if any(out[i][1] > out[i + 1][1] for i in range(len(out) - 1)):
        out.sort(key=itemgetter(1))
    return out


def _merged(
    starts: Sequence[int], chunks: Iterator[list[_Message]], path: str
) -> Generator[_Message, None, None]:
    """Merge time-sorted chunks opened in the order of their ``starts`` (their first times).

    A chunk is opened once the merge reaches its first time; :mod:`heapq` merges what is open.
    ``heapq.merge`` would open every chunk at once (it reads the head of each): hence by hand.

    Raises:
        BagImportError: Chunks overlapping in time hold more than :data:`MAX_OPEN_BYTES`.
    """
    heap: list[tuple[int, int, int, list[_Message]]] = []
    held, opened = 0, 0
    while opened < len(starts) or heap:
        while opened < len(starts) and (not heap or starts[opened] <= heap[0][0]):
            messages = next(chunks)
            if messages:
                heapq.heappush(heap, (messages[0][1], opened, 0, messages))
                held += sum(len(m[2]) for m in messages)
            opened += 1
            if held > MAX_OPEN_BYTES:
                msg = (
                    f"{path}: more than {MAX_OPEN_BYTES >> 20} MB of chunks overlap in time at "
                    f"t={heap[0][0]} ns: the bag was merged from several recorders; re-sort it "
                    "with `rosbag filter in.bag sorted.bag True` (or convert it with "
                    "rosbags-convert) and import the sorted bag"
                )
                raise BagImportError(msg)
        if not heap:
            continue
        _, order, index, messages = heap[0]
        yield messages[index]
        if index + 1 < len(messages):
            heapq.heapreplace(heap, (messages[index + 1][1], order, index + 1, messages))
        else:
            heapq.heappop(heap)
            held -= sum(len(m[2]) for m in messages)


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
