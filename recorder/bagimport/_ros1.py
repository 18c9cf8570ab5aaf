"""A ROS 1 bag reader that streams: chunk after chunk, without the bag's per-message index.

rosbags' ``rosbag1.Reader`` loads an index entry for every message when it opens a bag (about
130 bytes each: 0.4 GB for a 1 GB bag of small messages). An import reads every message once,
in order, so this reader keeps only the connections and the chunk list of the bag's index and
walks each chunk's records in the order they were written (the order ``rosbag record`` received
them). Memory: one decompressed chunk at a time.
"""

from __future__ import annotations

import os
from io import BytesIO
from typing import TYPE_CHECKING

from rosbags.rosbag1 import Reader, ReaderError
from rosbags.rosbag1.reader import Header, RecordType, read_bytes, read_uint32

if TYPE_CHECKING:
    from collections.abc import Collection, Generator

    from rosbags.interfaces import Connection
    from rosbags.rosbag1.reader import IndexData

#: Largest uncompressed chunk accepted (rosbag record writes 768 kB chunks).
MAX_CHUNK_BYTES = 256 * 1024 * 1024


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

    def _chunk(self, pos: int) -> BytesIO:
        """Return the decompressed records of the chunk at ``pos``.

        Raises:
            ReaderError: The chunk claims more than :data:`MAX_CHUNK_BYTES`.
        """
        assert self.bio  # noqa: S101 (open() set it)
        _ = self.bio.seek(pos)
        header = Header.read(self.bio, RecordType.CHUNK)
        if header.get_uint32("size") > MAX_CHUNK_BYTES:
            msg = f"a chunk at byte {pos} claims {header.get_uint32('size')} bytes"
            raise ReaderError(msg)
        chunk = self.chunks[pos]
        _ = self.bio.seek(chunk.datapos)
        return BytesIO(chunk.decompressor(read_bytes(self.bio, chunk.datasize)))

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
            records = self._chunk(info.pos)
            end = len(records.getbuffer())
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
