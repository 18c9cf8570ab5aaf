"""Decompression with a limit on what it produces, for every codec the bag readers accept.

A chunk header declares its uncompressed size, but a hostile bag can declare a small size and
carry a bomb (a 510 kB bz2 ROS 1 bag decompressed to 3.4 GB): rosbags decompresses a whole
chunk (``bz2.decompress``, ``lz4.frame.decompress``, ``zstd.decompress``) and compares sizes
only afterwards. These functions decompress incrementally and stop one byte past the limit.

rosbags' ROS 2 reader calls module-level decompressors (``storage_mcap.DECOMPRESSORS`` for
MCAP chunks; ``reader.zstd`` for the ``message`` and ``file`` compression modes) and offers
no hook, so :func:`install` replaces those entries with the bounded ones below (same results
for every bag under the limits). Written here because no library offers the bounded call.
"""

from __future__ import annotations

import bz2
import os
from typing import IO, TYPE_CHECKING, Self

import zstandard
from lz4.frame import LZ4FrameDecompressor  # type: ignore[import-untyped]
from rosbags.rosbag1 import ReaderError as Ros1ReaderError
from rosbags.rosbag2 import ReaderError as Ros2ReaderError

if TYPE_CHECKING:
    from collections.abc import Callable

#: Largest uncompressed chunk accepted (rosbag record writes 768 kB chunks, ros2 bag record
#: MCAP chunks of 4 MB by default; 256 MB leaves room for any recorder's settings).
MAX_CHUNK_BYTES = 256 * 1024 * 1024
#: Largest message accepted (a skin block of a second at 10 kHz is ~1 MB).
MAX_MESSAGE_BYTES = 64 * 1024 * 1024
#: Largest ratio of decompressed to compressed bytes of a ``file``-compressed ROS 2 bag:
#: sensor data compresses 2-20x; a file expanding more than this is a bomb, not a log.
MAX_FILE_RATIO = 1000
#: Decompressed bytes allowed for a file even when it is tiny (its headers alone).
_FILE_SLACK = 1 << 20


class DecompressionLimitError(Ros1ReaderError, Ros2ReaderError):
    """Decompression would produce more than its limit (a ReaderError of either reader)."""


def _checked(out: bytes, codec: str, limit: int, produced: int = -1) -> bytes:
    """Return ``out`` if it (or ``produced`` bytes, if given) is at most ``limit`` bytes.

    Raises:
        DecompressionLimitError: More than ``limit`` bytes were produced.
    """
    if max(len(out), produced) > limit:
        msg = (
            f"{codec} data decompresses to more than {limit} bytes (the declared size or the "
            "reader's limit); the bag is damaged or hostile"
        )
        raise DecompressionLimitError(msg)
    return out


def bz2_bounded(data: bytes, limit: int) -> bytes:
    """Return bz2 ``data`` decompressed, refusing more than ``limit`` bytes.

    Raises:
        DecompressionLimitError: The data decompresses to more than ``limit`` bytes.
        OSError: The data is not bz2.
    """
    out = bz2.BZ2Decompressor().decompress(data, max_length=limit + 1)
    return _checked(out, "bz2", limit)


def lz4_bounded(data: bytes, limit: int) -> bytes:
    """Return lz4-frame ``data`` decompressed, refusing more than ``limit`` bytes.

    Raises:
        DecompressionLimitError: The data decompresses to more than ``limit`` bytes.
        Ros2ReaderError: The data is not an lz4 frame.
    """
    try:
        out: bytes = LZ4FrameDecompressor().decompress(data, max_length=limit + 1)
    except RuntimeError as err:  # lz4 raises RuntimeError for corrupt frames
        msg = f"lz4: {err}"
        raise Ros2ReaderError(msg) from err
    return _checked(out, "lz4", limit)


def zstd_bounded(data: bytes, limit: int) -> bytes:
    """Return zstd ``data`` (one or more frames) decompressed, refusing more than ``limit``.

    Raises:
        DecompressionLimitError: The data decompresses to more than ``limit`` bytes.
        zstandard.ZstdError: The data is not zstd.
    """
    reader = zstandard.ZstdDecompressor().stream_reader(data, read_across_frames=True)
    out = reader.read(limit + 1)
    return _checked(out, "zstd", limit)


#: ROS 1 chunk decompressors by the chunk header's ``compression`` field.
ROS1_DECOMPRESSORS: dict[str, Callable[[bytes, int], bytes]] = {
    "none": lambda data, _: data,
    "bz2": bz2_bounded,
    "lz4": lz4_bounded,
}


def _chunk(codec: Callable[[bytes, int], bytes]) -> Callable[[bytes, int], bytes]:
    """Return a rosbags MCAP chunk decompressor (data, declared size) bounded by both sizes."""

    def decompress(data: bytes, size: int) -> bytes:
        return codec(data, min(size, MAX_CHUNK_BYTES))

    return decompress


class _BoundedFile:
    """A binary file decompressing zstd that refuses to read past a limit."""

    def __init__(self, reader: IO[bytes], limit: int) -> None:
        """Wrap a zstd stream reader."""
        self._reader = reader
        self._limit = limit
        self._read = 0

    def read(self, size: int = -1) -> bytes:
        """Return up to ``size`` decompressed bytes.

        Raises:
            DecompressionLimitError: More than the limit would be read.
        """
        want = self._limit + 1 - self._read if size < 0 else min(size, self._limit + 1 - self._read)
        out = self._reader.read(max(want, 1))
        self._read += len(out)
        return _checked(out, "zstd file", self._limit, self._read)

    def __enter__(self) -> Self:
        """Return self."""
        return self

    def __exit__(self, *args: object) -> None:
        """Close the stream reader."""
        self._reader.close()


class _Zstd:
    """Stand-in for the ``zstd`` module in rosbags' ROS 2 reader (bounded decompress, open)."""

    @staticmethod
    def decompress(data: bytes) -> bytes:
        """Return a ``message``-compressed message, refusing more than a message's limit."""
        return zstd_bounded(data, MAX_MESSAGE_BYTES)

    @staticmethod
    def open(fileobj: IO[bytes], mode: str = "rb") -> _BoundedFile:
        """Return a ``file``-compressed bag file's reader, bounded by :data:`MAX_FILE_RATIO`."""
        del mode
        size = os.fstat(fileobj.fileno()).st_size
        stream = zstandard.ZstdDecompressor().stream_reader(fileobj, read_across_frames=True)
        return _BoundedFile(stream, MAX_FILE_RATIO * size + _FILE_SLACK)


def install() -> None:
    """Make rosbags' ROS 2 reader decompress through the bounded functions (idempotent)."""
    from rosbags.rosbag2 import reader, storage_mcap  # noqa: PLC0415 (patched modules)

    storage_mcap.DECOMPRESSORS["zstd"] = _chunk(zstd_bounded)
    storage_mcap.DECOMPRESSORS["lz4"] = _chunk(lz4_bounded)
    reader.zstd = _Zstd  # type: ignore[attr-defined,assignment]
