"""The walk through a chunk's records: messages read in bulk, every malformed record refused."""

from __future__ import annotations

import struct

import pytest

from replay.recording._container import FormatError, Opcode, walk_data_section

MAGIC = b"\x89MCAP0\r\n"


def _record(opcode: int, body: bytes) -> bytes:
    return struct.pack("<BQ", opcode, len(body)) + body


def _string(text: str) -> bytes:
    raw = text.encode()
    return struct.pack("<I", len(raw)) + raw


def _header() -> bytes:
    return _record(Opcode.HEADER, _string("ros2") + _string("test"))


def _channel(channel_id: int, topic: str) -> bytes:
    body = struct.pack("<HH", channel_id, 0) + _string(topic) + _string("cdr")
    return _record(Opcode.CHANNEL, body + struct.pack("<I", 0))


def _message(channel_id: int, sequence: int, log_ns: int, payload: bytes) -> bytes:
    head = struct.pack("<HIQQ", channel_id, sequence, log_ns, log_ns + 1)
    return _record(Opcode.MESSAGE, head + payload)


def _chunk(records: bytes) -> bytes:
    body = struct.pack("<QQQI", 0, 0, len(records), 0) + _string("")
    return _record(Opcode.CHUNK, body + struct.pack("<Q", len(records)) + records)


def _file(*records: bytes) -> bytes:
    return MAGIC + _header() + b"".join(records) + _record(Opcode.DATA_END, b"\0\0\0\0")


def test_messages_of_a_chunk_are_read_in_file_order_per_channel() -> None:
    records = (
        _channel(1, "/a")
        + _channel(2, "/b")
        + _message(1, 7, 100, b"x")
        + _message(2, 8, 101, b"")
        + _message(1, 9, 102, b"yz")
    )
    section = walk_data_section(_file(_channel(3, "/c"), _chunk(records), _message(3, 1, 5, b"q")))
    assert section.complete
    assert section.message_count == 4
    a, b, c = section.messages[1], section.messages[2], section.messages[3]
    assert (a.order, a.sequence, a.log_ns, a.publish_ns, a.payloads) == (
        [0, 2],
        [7, 9],
        [100, 102],
        [101, 103],
        [b"x", b"yz"],
    )
    assert (b.order, b.payloads, c.order, c.payloads) == ([1], [b""], [3], [b"q"])


@pytest.mark.parametrize(
    ("records", "reason"),
    [
        (_channel(1, "/a") + _record(Opcode.MESSAGE, b"\x01\x00" + b"\0" * 10), "too short"),
        (_message(4, 0, 1, b"x"), "on channel 4, which is not defined"),
        (_channel(1, "/a") + _message(1, 0, 1, b"x")[:-3], "inside a chunk: the record at"),
        (_channel(1, "/a") + b"\x05\x00", "inside a chunk: the record at offset"),
    ],
    ids=["short-message", "undefined-channel", "cut-off-body", "cut-off-head"],
)
def test_a_malformed_record_in_a_chunk_is_refused_or_its_chunk_skipped(
    records: bytes, reason: str
) -> None:
    data = _file(_chunk(_channel(9, "/kept") + _message(9, 0, 1, b"k")), _chunk(records))
    with pytest.raises(FormatError, match=reason):
        walk_data_section(data)
    salvaged = walk_data_section(data, tolerant=True)
    kept = salvaged.messages[9].payloads
    if "not defined" in reason:  # an orphan message is counted, the chunk kept
        assert (salvaged.orphans, kept, salvaged.damaged_chunks) == (1, [b"k"], [])
    else:  # the damaged chunk is skipped as a whole, the one before it kept
        assert kept == [b"k"]
        assert len(salvaged.damaged_chunks) == 1
        assert set(salvaged.messages) == {9}
