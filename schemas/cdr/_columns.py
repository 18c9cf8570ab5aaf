"""Column decoding: CDR payloads of one topic -> numpy arrays per field, vectorised over messages.

Messages of one topic usually share their byte layout: the same strings (frame ids, joint
names) and the same sequence lengths. Such messages are stacked into one ``(messages, bytes)``
array and every numeric field is read as a column slice, without a Python step per message
(the reader's fast path for the contract's skin blocks and fixed-layout joint states and
poses). The layout is found by walking the first message with the typestore's field
definitions (CDR rules: each primitive aligned to its size, counted from the end of the 4-byte
encapsulation header; strings and sequences prefixed by a uint32 length, bounded by the rules
of :mod:`schemas.cdr._rules`). A message whose length prefixes or strings differ from the
first one's starts a new group with its own layout, so any valid message decodes; the tests
compare the result with rosbags' ``deserialize_cdr``.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from rosbags.interfaces import Nodetype

from schemas.cdr._rules import (
    BASES,
    HEADER,
    STRINGS,
    check_depth,
    count_fits,
    element_size,
    length_fits,
)
from schemas.errors import CdrError

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from numpy.typing import NDArray
    from rosbags.typesys.store import Typestore

_PREFIX = struct.Struct("<I"), struct.Struct(">I")


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
    pos: int = HEADER

    def align(self, size: int) -> None:
        """Move to the next multiple of ``size`` counted from the end of the header."""
        self.pos = HEADER + ((self.pos - HEADER + size - 1) & -size)

    def prefix(self, path: str) -> int:
        """Read a uint32 length prefix (recorded as layout-determining).

        Raises:
            CdrError: The prefix itself lies beyond the payload.
        """
        self.align(4)
        if not length_fits(4, self.pos, len(self.data)):
            msg = f"field {path}: the length prefix at byte {self.pos} lies beyond the payload"
            raise CdrError(msg)
        (value,) = _PREFIX[self.order == ">"].unpack_from(self.data, self.pos)
        self.layout.fixed.append((self.pos, self.pos + 4))
        self.pos += 4
        return int(value)

    def count(self, path: str, element: tuple[int, Any]) -> int:
        """Read a sequence's count; refuse one the rest of the payload cannot hold.

        Raises:
            CdrError: The count exceeds the bytes left or the typestore's sequence limit.
        """
        value = self.prefix(path)
        width, left = element_size(element), len(self.data) - self.pos
        if not count_fits(value, width, self.pos, len(self.data), self.store.max_sequence_length):
            msg = (
                f"field {path}: count {value} at byte {self.pos - 4} needs at least "
                f"{value * width} bytes, {left} are left in the payload"
            )
            raise CdrError(msg)
        return value

    def string(self, path: str) -> None:
        """Read a string (the layout keeps its value).

        Raises:
            CdrError: Its length prefix reaches beyond the payload, or it is not UTF-8.
        """
        size = self.prefix(path)
        if not length_fits(size, self.pos, len(self.data)):
            msg = (
                f"field {path}: length prefix {size} at byte {self.pos - 4} exceeds the "
                f"{len(self.data) - self.pos} bytes left in the payload"
            )
            raise CdrError(msg)
        self.layout.fixed.append((self.pos, self.pos + size))
        raw = self.data[self.pos : self.pos + max(size - 1, 0)]
        try:
            self.layout.strings[path] = raw.decode("utf-8")
        except UnicodeDecodeError as err:
            msg = f"field {path}: the string is not UTF-8 ({err})"
            raise CdrError(msg) from err
        self.pos += size

    def primitive(self, path: str, typename: str, count: int) -> None:
        """Place ``count`` values of a primitive type."""
        dtype = np.dtype(self.order + BASES[typename].dtype)
        if count:
            self.align(dtype.itemsize)
        self.layout.numeric[path] = (self.pos, dtype, count)
        self.pos += dtype.itemsize * count

    def message(self, msgtype: str, prefix: str, depth: int) -> None:
        """Walk the fields of one (nested) message."""
        check_depth(depth, msgtype)
        for name, (nodetype, details) in self.store.fielddefs[msgtype][1]:
            self.field(f"{prefix}{name}", nodetype, details, depth)

    def field(self, path: str, nodetype: int, details: Any, depth: int) -> None:  # noqa: ANN401
        """Walk one field of any kind."""
        if nodetype == Nodetype.BASE and details[0] in STRINGS:
            self.string(path)
        elif nodetype == Nodetype.BASE:
            self.element(path, (nodetype, details), 1, depth)
        elif nodetype == Nodetype.NAME:
            self.message(details, f"{path}.", depth + 1)
        elif nodetype == Nodetype.ARRAY:
            self.element(path, details[0], details[1], depth)
        else:
            self.element(path, details[0], self.count(path, details[0]), depth)

    def element(self, path: str, desc: tuple[int, Any], count: int, depth: int) -> None:
        """Walk ``count`` elements of an array, a sequence, or one primitive.

        Raises:
            CdrError: The element type is not one the decoder reads.
        """
        nodetype, details = desc
        if nodetype == Nodetype.BASE and details[0] in BASES:
            self.primitive(path, details[0], count)
        elif nodetype == Nodetype.BASE and details[0] in STRINGS:
            for index in range(count):
                self.string(f"{path}[{index}]")
        elif nodetype == Nodetype.NAME:
            for index in range(count):
                self.message(details, f"{path}[{index}].", depth + 1)
        else:
            msg = f"field {path}: type {details!r} is not supported by the decoder"
            raise CdrError(msg)


def message_layout(store: Typestore, msgtype: str, data: bytes) -> Layout:
    """Return the layout of one CDR payload of ``msgtype``.

    Raises:
        CdrError: The payload is shorter than its layout, has an unknown header, a length
            prefix or a count beyond its end, a string that is not UTF-8, or nests too deep.
    """
    if len(data) < HEADER or data[0] != 0 or data[1] not in {0, 1}:
        msg = f"{msgtype}: payload does not start with a CDR encapsulation header"
        raise CdrError(msg)
    walker = _Walker(store, data, "<" if data[1] == 1 else ">")
    walker.layout.fixed.append((0, 2))
    walker.message(msgtype, "", 0)
    if walker.pos > len(data):
        msg = f"{msgtype}: payload of {len(data)} bytes is shorter than its layout ({walker.pos})"
        raise CdrError(msg)
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
        CdrError: A payload is not a valid ``msgtype`` message.
    """
    lengths = np.array(list(map(len, payloads)), dtype=np.int64)
    remaining = np.arange(len(payloads))
    groups: list[DecodedGroup] = []
    while remaining.size:
        first = int(remaining[0])
        try:
            layout = message_layout(store, msgtype, payloads[first])
        except CdrError as err:
            msg = f"{msgtype}: message {first} is malformed ({err})"
            raise CdrError(msg) from err
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
        CdrError: The field's count differs between groups (use per-group access).
    """
    counts = {group.numeric[path].shape[1] for group in groups}
    if len(counts) > 1:
        msg = f"field {path} has different lengths across messages: {sorted(counts)}"
        raise CdrError(msg)
    dtype = groups[0].numeric[path].dtype if groups else np.dtype(np.float64)
    out = np.empty((total, counts.pop() if counts else 0), dtype=dtype)
    for group in groups:
        out[group.indices] = group.numeric[path]
    return out
