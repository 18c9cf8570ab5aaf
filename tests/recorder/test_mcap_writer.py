"""The recorder's MCAP writer writes the same bytes as ``mcap``'s own ``Writer``."""

import io
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from recorder.writing._mcap import McapWriter

Call = tuple[str, tuple[Any, ...]]


def _calls(seed: int, messages: int) -> list[Call]:
    """Return a random recorder-like call sequence: channels appear mid-chunk, times jitter."""
    rng = np.random.default_rng(seed)
    calls: list[Call] = [
        ("start", ("ros2", "atikt/test")),
        ("add_metadata", ("atikt.recording", {"object": "wood", "trial": "1"})),
        ("register_schema", ("pkg/msg/A", "ros2msg", b"int32 a")),
        ("register_channel", ("/a", "cdr", 1)),
    ]
    channels = 1
    time = int(rng.integers(0, 10**12))
    sequences: dict[int, int] = {}
    for _ in range(messages):
        draw = rng.uniform()
        if draw < 0.01:
            calls.append(("register_schema", (f"pkg/msg/T{channels}", "ros2msg", b"x" * 40)))
            calls.append(("register_channel", (f"/t{channels}", "cdr", channels + 1)))
            channels += 1
        elif draw < 0.03:
            calls.append(("flush", ()))
        elif draw < 0.035:
            calls.append(("add_metadata", (f"note{len(calls)}", {"k": str(len(calls))})))
        channel = int(rng.integers(1, channels + 1))
        time += int(rng.integers(-3_000_000, 8_000_000))  # receive times may go back a little
        sequence = sequences.get(channel, 0)
        sequences[channel] = sequence + 1
        size = int(rng.choice([0, 3, 60, 400, 9_000]))
        data = rng.integers(0, 4, size, dtype=np.uint8).tobytes()  # compressible, like samples
        publish = max(time - int(rng.integers(0, 10**7)), 0)
        calls.append(("add_message", (channel, max(time, 0), data, publish, sequence)))
    calls.append(("add_metadata", ("atikt.sources", {"skin": "{}"})))
    calls.append(("finish", ()))
    return calls


def _write(make: Callable[[io.BytesIO], Any], calls: list[Call]) -> bytes:
    stream = io.BytesIO()
    writer = make(stream)
    for name, args in calls:
        getattr(writer, name)(*args)
    return stream.getvalue()


@pytest.mark.parametrize("compression", [CompressionType.ZSTD, CompressionType.NONE])
@pytest.mark.parametrize(("seed", "chunk_size"), [(1, 4 * 2**20), (2, 20_000), (3, 1), (4, 700)])
def test_same_bytes_as_the_mcap_library(
    seed: int, chunk_size: int, compression: CompressionType
) -> None:
    calls = _calls(seed, 3_000)

    def library(stream: io.BytesIO) -> Writer:
        return Writer(stream, chunk_size=chunk_size, compression=compression, enable_data_crcs=True)

    def ours(stream: io.BytesIO) -> McapWriter:
        return McapWriter(
            stream, chunk_size=chunk_size, compression=compression, enable_data_crcs=True
        )

    expected = _write(library, calls)
    written = _write(ours, calls)
    assert written == expected
    reader = make_reader(io.BytesIO(written))
    summary = reader.get_summary()
    assert summary is not None
    assert summary.statistics is not None
    assert summary.statistics.message_count == sum(c[0] == "add_message" for c in calls)
    assert sum(1 for _ in reader.iter_messages()) == summary.statistics.message_count


def test_same_bytes_without_data_crc_or_messages() -> None:
    calls: list[Call] = [("start", ("", "x")), ("add_metadata", ("m", {})), ("finish", ())]
    assert _write(McapWriter, calls) == _write(Writer, calls)
    calls.insert(1, ("register_schema", ("a", "ros2msg", b"")))
    calls.insert(2, ("register_channel", ("/a", "cdr", 1, {"k": "v"})))
    assert _write(McapWriter, calls) == _write(Writer, calls)


def test_a_message_time_out_of_range_is_refused_like_the_library() -> None:
    for make in (Writer, McapWriter):
        writer = make(io.BytesIO())
        writer.start("", "x")
        writer.register_schema("a", "ros2msg", b"")
        writer.register_channel("/a", "cdr", 1)
        with pytest.raises(Exception, match=r"format requires|argument out of range"):
            writer.add_message(1, -1, b"", 0, 0)
