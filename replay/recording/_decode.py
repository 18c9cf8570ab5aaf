"""Decoding: CDR payloads of one topic -> numpy arrays per field, vectorised over messages.

Messages of one topic usually share their byte layout: the same strings (frame ids, joint
names) and the same sequence lengths. Such messages are stacked into one ``(messages, bytes)``
array and every numeric field is read as a column slice, without a Python step per message.
The layout is found by walking the first message with the typestore's field definitions
(CDR rules: each primitive aligned to its size, counted from the end of the 4-byte
encapsulation header; strings and sequences prefixed by a uint32 length). A message whose
length prefixes or strings differ from the first one's starts a new group with its own layout,
so any valid message decodes; the tests compare the result with rosbags' ``deserialize_cdr``.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from rosbags.interfaces import Nodetype

from replay.errors import RecordingError

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from numpy.typing import NDArray
    from rosbags.typesys.store import Typestore

_HEADER = 4  # CDR encapsulation header: 0x00, 0x01 (little endian) or 0x00 (big), options
_PRIMITIVES: dict[str, str] = {
    "bool": "u1",
    "byte": "u1",
    "char": "u1",
    "octet": "u1",
    "int8": "i1",
    "uint8": "u1",
    "int16": "i2",
    "uint16": "u2",
    "int32": "i4",
    "uint32": "u4",
    "int64": "i8",
    "uint64": "u8",
    "float32": "f4",
    "float64": "f8",
}


@dataclass(slots=True)
class Layout:
    """Where a message's fields are in its bytes.

    Attributes:
        numeric: Numeric field path -> (offset, dtype, count).
        strings: String field path -> decoded value.
        fixed: (start, stop) byte ranges that determine the layout: encapsulation header,
            length prefixes and string bytes. Messages with equal length and equal bytes
            in these ranges share the layout.
    """

    numeric: dict[str, tuple[int, np.dtype[Any], int]] = field(default_factory=dict)
    strings: dict[str, str] = field(default_factory=dict)
    fixed: list[tuple[int, int]] = field(default_factory=list)


@dataclass(slots=True)
class _Walker:
    """Walks one CDR payload along the typestore's field definitions."""

    store: Typestore
    data: bytes
    order: str
    layout: Layout = field(default_factory=Layout)
    pos: int = _HEADER

    def align(self, size: int) -> None:
        self.pos = _HEADER + ((self.pos - _HEADER + size - 1) & -size)

    def length(self, path: str) -> int:
        """Read a uint32 length prefix; refuse one longer than the rest of the payload."""
        self.align(4)
        (value,) = struct.unpack_from(f"{self.order}I", self.data, self.pos)
        self.layout.fixed.append((self.pos, self.pos + 4))
        self.pos += 4
        if value > len(self.data) - self.pos:
            msg = (
                f"field {path}: length prefix {value} at byte {self.pos - 4} exceeds the "
                f"{len(self.data) - self.pos} bytes left in the payload"
            )
            raise RecordingError(msg)
        return int(value)

    def string(self, path: str) -> None:
        size = self.length(path)
        self.layout.fixed.append((self.pos, self.pos + size))
        raw = self.data[self.pos : self.pos + max(size - 1, 0)]
        try:
            self.layout.strings[path] = raw.decode("utf-8")
        except UnicodeDecodeError as err:
            msg = f"field {path}: the string is not UTF-8 ({err})"
            raise RecordingError(msg) from err
        self.pos += size

    def primitive(self, path: str, typename: str, count: int) -> None:
        dtype = np.dtype(self.order + _PRIMITIVES[typename])
        if count:
            self.align(dtype.itemsize)
        self.layout.numeric[path] = (self.pos, dtype, count)
        self.pos += dtype.itemsize * count

    def message(self, msgtype: str, prefix: str) -> None:
        for name, (nodetype, details) in self.store.fielddefs[msgtype][1]:
            self.field(f"{prefix}{name}", nodetype, details)

    def field(self, path: str, nodetype: int, details: Any) -> None:  # noqa: ANN401
        if nodetype == Nodetype.BASE and details[0] in {"string", "wstring"}:
            self.string(path)
        elif nodetype == Nodetype.BASE:
            self.element(path, (nodetype, details), 1)
        elif nodetype == Nodetype.NAME:
            self.message(details, f"{path}.")
        elif nodetype == Nodetype.ARRAY:
            self.element(path, details[0], details[1])
        else:
            self.element(path, details[0], self.length(path))

    def element(self, path: str, desc: tuple[int, Any], count: int) -> None:
        """Walk ``count`` elements of an array, a sequence, or one primitive."""
        nodetype, details = desc
        if nodetype == Nodetype.BASE and details[0] in _PRIMITIVES:
            self.primitive(path, details[0], count)
        elif nodetype == Nodetype.BASE and details[0] in {"string", "wstring"}:
            for index in range(count):
                self.string(f"{path}[{index}]")
        elif nodetype == Nodetype.NAME:
            for index in range(count):
                self.message(details, f"{path}[{index}].")
        else:
            msg = f"field {path}: type {details!r} is not supported by the decoder"
            raise RecordingError(msg)


def message_layout(store: Typestore, msgtype: str, data: bytes) -> Layout:
    """Return the layout of one CDR payload of ``msgtype``.

    Raises:
        RecordingError: The payload is shorter than its layout, has an unknown header, a
            length prefix beyond its end, or a string that is not UTF-8.
        struct.error: A length prefix lies beyond the payload.
    """
    if len(data) < _HEADER or data[0] != 0 or data[1] not in {0, 1}:
        msg = f"{msgtype}: payload does not start with a CDR encapsulation header"
        raise RecordingError(msg)
    walker = _Walker(store, data, "<" if data[1] == 1 else ">")
    walker.layout.fixed.append((0, 2))
    walker.message(msgtype, "")
    if walker.pos > len(data):
        msg = f"{msgtype}: payload of {len(data)} bytes is shorter than its layout ({walker.pos})"
        raise RecordingError(msg)
    return walker.layout


@dataclass(frozen=True, slots=True)
class DecodedGroup:
    """Messages of one topic that share a layout, decoded together.

    Attributes:
        indices: Positions of the group's messages in the topic, shape (n,).
        numeric: Field path -> array of shape (n, count) in the field's dtype.
        strings: Field path -> the value shared by the group's messages.
    """

    indices: NDArray[np.intp]
    numeric: Mapping[str, NDArray[Any]]
    strings: Mapping[str, str]


def _matches(rows: NDArray[np.uint8], first: NDArray[np.uint8], layout: Layout) -> NDArray[Any]:
    """Return which rows share ``first``'s bytes in the layout-determining ranges."""
    columns = np.concatenate([np.arange(start, stop) for start, stop in layout.fixed])
    keep: NDArray[np.bool_] = (rows[:, columns] == first[columns]).all(axis=1)
    return keep


def _columns(rows: NDArray[np.uint8], layout: Layout) -> dict[str, NDArray[Any]]:
    """Read every numeric field of ``rows`` (messages sharing ``layout``) as columns."""
    columns: dict[str, NDArray[Any]] = {}
    for path, (offset, dtype, count) in layout.numeric.items():
        raw = np.ascontiguousarray(rows[:, offset : offset + dtype.itemsize * count])
        values = raw.view(dtype).reshape(rows.shape[0], count)
        columns[path] = values.astype(dtype.newbyteorder("="), copy=False)
    return columns


def decode_topic(store: Typestore, msgtype: str, payloads: Sequence[bytes]) -> list[DecodedGroup]:
    """Decode all payloads of one topic, vectorised per group of messages sharing a layout.

    Args:
        store: Typestore that knows ``msgtype``.
        msgtype: ROS 2 message type of every payload.
        payloads: CDR payloads in file order.

    Returns:
        Groups covering every message exactly once, in order of their first message.

    Raises:
        RecordingError: A payload is not a valid ``msgtype`` message.
    """
    lengths = np.array(list(map(len, payloads)), dtype=np.int64)
    remaining = np.arange(len(payloads))
    groups: list[DecodedGroup] = []
    while remaining.size:
        first = int(remaining[0])
        try:
            layout = message_layout(store, msgtype, payloads[first])
        except (struct.error, RecordingError) as err:
            msg = f"{msgtype}: message {first} is malformed ({err})"
            raise RecordingError(msg) from err
        same = remaining[lengths[remaining] == lengths[first]]
        if same.size == len(payloads):  # the usual case: one length for the whole topic
            joined = b"".join(payloads)
        else:
            joined = b"".join([payloads[i] for i in same])
        rows = np.frombuffer(joined, dtype=np.uint8).reshape(same.size, -1)
        keep = _matches(rows, rows[0], layout)
        if not bool(keep.all()):
            same, rows = same[keep], rows[keep]
        groups.append(DecodedGroup(same, _columns(rows, layout), layout.strings))
        if same.size == remaining.size:
            break
        remaining = remaining[~np.isin(remaining, same, assume_unique=True)]
    return groups


def gather(groups: Sequence[DecodedGroup], path: str, total: int) -> NDArray[Any]:
    """Return field ``path`` of every message in message order, shape (total, count).

    Raises:
        RecordingError: The field's count differs between groups (use per-group access).
    """
    counts = {group.numeric[path].shape[1] for group in groups}
    if len(counts) > 1:
        msg = f"field {path} has different lengths across messages: {sorted(counts)}"
        raise RecordingError(msg)
    dtype = groups[0].numeric[path].dtype if groups else np.dtype(np.float64)
    out = np.empty((total, counts.pop() if counts else 0), dtype=dtype)
    for group in groups:
        out[group.indices] = group.numeric[path]
    return out
