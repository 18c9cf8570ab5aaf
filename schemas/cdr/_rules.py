"""The CDR and ROS 1 byte rules every decoder of the project follows, written once.

Two decoders read message bytes: the column decoder (:mod:`schemas.cdr._columns`, the reader's
vectorised path over a topic's messages) and the generated per-type decoders
(:mod:`schemas.cdr._compiled`, the import's and the live skin's path). Both take their base
types, their limits and their bounds checks from here:

- a length prefix (a string's) must not reach beyond the message;
- a count (a sequence's) must not exceed what the remaining bytes can hold, at the element's
  smallest size, nor the typestore's ``max_sequence_length``;
- types may nest at most :data:`MAX_DEPTH` messages deep.

The column decoder calls the predicates below; the generated decoders inline the same
expressions as source text (a call per field would cost the import a tenth of its time), so each
rule is written here in both forms side by side, and a test checks that the two agree.
"""

from __future__ import annotations

import struct
from typing import Any, NamedTuple

from rosbags.interfaces import Nodetype

from schemas.errors import CdrError

#: CDR encapsulation header: 0x00, then 0x01 (little endian) or 0x00 (big endian), options.
HEADER = 4
#: Deepest nesting of messages in a type (a joint state: 3; a lab's skin message: 4 or 5).
MAX_DEPTH = 32
#: Longest fixed array of strings or messages unrolled into generated code.
MAX_UNROLL = 64
#: Most lines of a generated decoder: a joint state's is ~60 lines, a skin message's ~100.
#: Fixed arrays of messages nest multiplicatively (64 x 64 x 64 strings: 1.6 M lines, 3.4 GB to
#: compile), so a larger type is left to rosbags' deserializer (which calls, not unrolls).
MAX_DECODER_LINES = 20_000
#: Smallest size of a string in a sequence: its uint32 length prefix (CDR adds a NUL byte).
STRING_MIN = 4
#: Smallest size of a message in a sequence (a ROS 2 message has at least one member).
MESSAGE_MIN = 1


class Base(NamedTuple):
    """One primitive type of the message definitions.

    Attributes:
        size: Bytes (and CDR alignment).
        code: Its :mod:`struct` code.
        dtype: Its numpy dtype without byte order.
        value: Whether it is a number a decoder hands out as such (bool, byte, char: not).
    """

    size: int
    code: str
    dtype: str
    value: bool


#: Every primitive type the decoders read.
BASES: dict[str, Base] = {
    "bool": Base(1, "?", "u1", value=False),
    "byte": Base(1, "b", "u1", value=False),
    "char": Base(1, "B", "u1", value=False),
    "octet": Base(1, "B", "u1", value=False),
    "int8": Base(1, "b", "i1", value=True),
    "uint8": Base(1, "B", "u1", value=True),
    "int16": Base(2, "h", "i2", value=True),
    "uint16": Base(2, "H", "u2", value=True),
    "int32": Base(4, "i", "i4", value=True),
    "uint32": Base(4, "I", "u4", value=True),
    "int64": Base(8, "q", "i8", value=True),
    "uint64": Base(8, "Q", "u8", value=True),
    "float32": Base(4, "f", "f4", value=True),
    "float64": Base(8, "d", "f8", value=True),
}
#: String types: a uint32 length prefix, then the bytes.
STRINGS = frozenset({"string", "wstring"})


def element_size(desc: tuple[int, Any]) -> int:
    """Return the smallest size in bytes of one element of a sequence of ``desc``.

    Args:
        desc: The element's field description (rosbags' ``(nodetype, details)``).
    """
    nodetype, details = desc
    if nodetype == Nodetype.BASE and details[0] in BASES:
        return BASES[details[0]].size
    if nodetype == Nodetype.BASE:
        return STRING_MIN
    return MESSAGE_MIN


def length_fits(length: int, pos: int, size: int) -> bool:
    """Return whether ``length`` bytes from ``pos`` lie inside a message of ``size`` bytes."""
    return pos + length <= size


def length_fits_source(length: str, pos: str) -> str:
    """Return :func:`length_fits` as a Python expression over names (``size``: the message's)."""
    return f"{pos} + {length} <= size"


def count_fits(count: int, width: int, pos: int, size: int, limit: int) -> bool:
    """Return whether ``count`` elements of at least ``width`` bytes fit from ``pos``.

    Args:
        count: The sequence's length prefix.
        width: The smallest size of one element (:func:`element_size`).
        pos: Where the elements start.
        size: The message's size.
        limit: The typestore's ``max_sequence_length``.
    """
    return pos + count * width <= size and count <= limit


def count_fits_source(width: int, limit: int) -> str:
    """Return :func:`count_fits` as an expression over ``count``, ``pos`` and ``size``."""
    return f"pos + count * {width} <= size and count <= {limit}"


def check_depth(depth: int, msgtype: str) -> None:
    """Refuse a message nested deeper than :data:`MAX_DEPTH`.

    Raises:
        CdrError: ``depth`` exceeds the limit; names the type.
    """
    if depth > MAX_DEPTH:
        msg = f"{msgtype}: messages nest more than {MAX_DEPTH} deep; the definitions are hostile"
        raise CdrError(msg)


_STAMP_BE = struct.Struct(">iI").unpack_from
_STAMP_LE = struct.Struct("<iI").unpack_from
_NS_PER_S = 1_000_000_000
#: Encapsulation ids (second byte) of plain CDR: XCDR1 big, little; XCDR2 big, little.
_PLAIN = frozenset({0, 1, 6, 7})


def header_stamp(raw: bytes) -> int | None:
    """Return the header stamp of a message whose type begins with a std_msgs/Header, ns.

    Read from the message's first 12 bytes without decoding it (a message too large to keep is
    placed by it too): the CDR encapsulation header (:data:`HEADER` bytes), then the stamp's
    int32 sec and uint32 nanosec, in the byte order the encapsulation id names. None: the
    bytes are too short, or not plain CDR (the stamp is not there).
    """
    # plain CDR is encapsulation id 0x0000 (big-endian) or 0x0001 (little: ROS 2's), plain
    # XCDR2 0x0006 or 0x0007 (a final struct: no header of its own, the stamp first as well)
    if len(raw) < HEADER + 8 or raw[0] != 0 or raw[1] not in _PLAIN:
        return None
    sec, nanosec = (_STAMP_LE if raw[1] & 1 else _STAMP_BE)(raw, HEADER)
    return int(sec) * _NS_PER_S + int(nanosec)
