"""Generated decoders: a message's stamp and mapped fields straight from its ROS 1 or CDR bytes.

rosbags' deserializer builds a message object (the header, its stamp, an array per field) for
every message; the import needs only the stamp and a few numeric fields (or a joint state's
names and values), and building rosbags' objects was a third of its time. For a message type
whose layout it understands, :func:`compile_ros1` (ROS 1) and :func:`compile_cdr` (ROS 2,
little-endian CDR) generate a function that walks the serialized bytes as rosbags'
deserializer does (the same field order, lengths, padding, string and sequence checks, the
same end-of-message check) and returns the stamp's ``sec`` and ``nanosec`` and each mapped
field's bytes. The values are the same as rosbags': a field's bytes are read with the field's
own little-endian dtype (and converted to float64 in bulk, a window at a time). The bounds
checks (a length prefix beyond the message, a count beyond what the remaining bytes can hold,
nesting) are those of :mod:`schemas.cdr._rules`, inlined as source text.

A message the function cannot vouch for (a size mismatch, an invalid string, a sequence
longer than the bytes, big-endian CDR) makes it return None, and the caller decodes that
message with rosbags, which then refuses it with its own error or decodes it. A type with a
field it does not handle (float128, sequences of messages, a mapped field that is not an
integer or float) gets no function: its topic is decoded by rosbags.
"""

from __future__ import annotations

import struct
from typing import TYPE_CHECKING, Any

import numpy as np
from rosbags.interfaces import Nodetype
from rosbags.serde.utils import align, align_after

from schemas.cdr._rules import (
    BASES,
    MAX_DECODER_LINES,
    MAX_UNROLL,
    check_depth,
    count_fits_source,
    element_size,
    length_fits_source,
)
from schemas.errors import CdrError

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from rosbags.typesys.store import Typestore

#: Sizes and struct codes of the base types the generated code reads (octet: rosbags reads
#: it as byte, so it never reaches a decoder).
_BASE = {name: (base.size, base.code) for name, base in BASES.items() if name != "octet"}
#: Base types a mapped field may have (bool, byte and char stay with rosbags).
_VALUES = frozenset(name for name, base in BASES.items() if base.value)
#: The names of the generated code's helpers.
_GLOBALS: dict[str, Any] = {"u32": struct.Struct("<I").unpack_from}


class _UnsupportedError(Exception):
    """The layout has a field the generated code does not handle."""


class Decoder:
    """A generated reader of one message type's stamp and mapped fields.

    Attributes:
        decode: ``raw -> (sec, nanosec, field bytes...)`` or None (decode with rosbags).
        dtypes: The little-endian dtype of each mapped field (None: a list of strings).
        stamped: Whether ``sec`` and ``nanosec`` are read (else they are 0).
    """

    __slots__ = ("decode", "dtypes", "key", "stamped")

    def __init__(
        self,
        decode: Callable[[bytes], tuple[Any, ...] | None],
        dtypes: tuple[np.dtype[Any] | None, ...],
        key: str,
        *,
        stamped: bool,
    ) -> None:
        """Keep the function and what it returns."""
        self.decode = decode
        self.dtypes = dtypes
        self.key = key
        self.stamped = stamped


class _Gen:
    """Emits the lines of a decoder, field after field."""

    def __init__(
        self, store: Typestore, wanted: dict[str, int], max_sequence: int, *, stamped: bool
    ) -> None:
        self.store = store
        self.stamped = stamped
        self.wanted = wanted
        self.max_sequence = max_sequence
        self.lines: list[str] = []
        self.dtypes: dict[int, str | None] = {}
        self.found: set[str] = set()
        self.caches: list[int] = []
        self._inside = False  # emitting the body of a cached list of strings
        self._nested = 0  # messages entered and not left

    def emit(self, line: str, depth: int) -> None:
        """Append a line; refuse past :data:`MAX_DECODER_LINES` (rosbags decodes the type)."""
        if len(self.lines) >= MAX_DECODER_LINES:
            raise _UnsupportedError
        self.lines.append("    " * depth + line)

    def cached(self, k: int, depth: int, body: Callable[[int], object]) -> None:
        """Emit ``body`` (a mapped list of strings into ``f<k>``) behind a cache of its bytes.

        A joint state repeats the same names in every message: when the bytes at ``pos``
        (at the same alignment) equal those the last full decode read, its list is reused and
        ``pos`` moves past them, which is what decoding the same bytes again would give. The
        list is shared between messages; its consumer never changes it.
        """
        self.caches.append(k)
        cache = f"c{k}"
        self.emit(
            f"if {cache}[0] is not None and pos % 8 == {cache}[1] "
            f"and raw[pos:pos + {cache}[2]] == {cache}[0]:",
            depth,
        )
        self.emit(f"    f{k} = {cache}[3]", depth)
        self.emit(f"    pos += {cache}[2]", depth)
        self.emit("else:", depth)
        self.emit("    start = pos", depth)
        body(depth + 1)
        self.emit(f"    {cache}[:] = [bytes(raw[start:pos]), start % 8, pos - start, f{k}]", depth)

    def string(self, depth: int, into: str = "") -> None:
        # rosbags: uint32 length, the bytes must fit and decode as UTF-8.
        self.emit("length = u32(raw, pos)[0]", depth)
        self.emit("end = pos + 4 + length", depth)
        self.emit(f"if not {length_fits_source('length', 'pos + 4')}:", depth)
        self.emit("    return None", depth)
        if into:
            self.emit(f"{into}.append(raw[pos + 4:end].decode())", depth)
        else:
            self.emit("raw[pos + 4:end].decode()", depth)
        self.emit("pos = end", depth)

    def message(self, msgtype: str, prefix: str, depth: int) -> None:
        check_depth(self._nested, msgtype)
        self._nested += 1
        for name, desc in self.store.fielddefs[msgtype][1]:
            if name == "structure_needs_at_least_one_member":
                continue
            self.field(desc, f"{prefix}{name}", depth)
        self._nested -= 1

    def capture(self, path: str, base: str, count: str, depth: int) -> None:
        """Keep the bytes of a mapped field (``count`` values of ``base``) as ``f<k>``."""
        k = self.wanted[path]
        if base not in _VALUES:
            raise _UnsupportedError
        self.found.add(path)
        self.dtypes[k] = "<" + _BASE[base][1]
        self.emit(f"f{k} = raw[pos:pos + {count} * {_BASE[base][0]}]", depth)

    def field(self, desc: tuple[Any, ...], path: str, depth: int) -> None:
        kind = desc[0]
        if kind == Nodetype.NAME:
            self.message(desc[1], f"{path}.", depth)
        elif self.stamped and path in {"header.stamp.sec", "header.stamp.nanosec"}:
            if kind != Nodetype.BASE or desc[1][0] not in _VALUES:
                raise _UnsupportedError
            size, code = _BASE[desc[1][0]]
            self.found.add(path)
            name = path.rsplit(".", 1)[1]
            self.emit(f"{name} = struct.unpack_from('<{code}', raw, pos)[0]", depth)
            self.emit(f"pos += {size}", depth)
        elif kind == Nodetype.BASE:
            self.base(desc[1][0], path, depth)
        elif kind == Nodetype.ARRAY:
            self.array(desc[1][0], desc[1][1], path, depth)
        else:
            self.sequence(desc[1][0], path, depth)

    def base(self, base: str, path: str, depth: int) -> None:
        if base == "string":
            self.string(depth)
            return
        if base not in _BASE:
            raise _UnsupportedError
        if path in self.wanted:
            self.capture(path, base, "1", depth)
        self.emit(f"pos += {_BASE[base][0]}", depth)

    def array(self, sub: tuple[Any, ...], length: int, path: str, depth: int) -> None:
        if sub[0] == Nodetype.BASE and sub[1][0] in _BASE:
            if path in self.wanted:
                self.capture(path, sub[1][0], str(length), depth)
            self.emit(f"pos += {length * _BASE[sub[1][0]][0]}", depth)
            return
        if length > MAX_UNROLL or path in self.wanted:
            raise _UnsupportedError
        for _ in range(length):
            if sub[0] == Nodetype.BASE and sub[1][0] == "string":
                self.string(depth)
            elif sub[0] == Nodetype.NAME:
                self.message(sub[1], f"{path}[].", depth)
            else:
                raise _UnsupportedError

    def sequence(self, sub: tuple[Any, ...], path: str, depth: int) -> None:
        # A uint32 count, checked as rosbags checks it, then the elements.
        if sub[0] != Nodetype.BASE or (sub[1][0] not in _BASE and sub[1][0] != "string"):
            raise _UnsupportedError
        if sub[1][0] == "string" and path in self.wanted and not self._inside:
            self._inside = True
            self.cached(self.wanted[path], depth, lambda d: self.sequence(sub, path, d))
            self._inside = False
            return
        width = element_size(sub)
        self.emit("count = u32(raw, pos)[0]", depth)
        self.emit("pos += 4", depth)
        self.emit(f"if not ({count_fits_source(width, self.max_sequence)}):", depth)
        self.emit("    return None", depth)
        if sub[1][0] in _BASE:
            if path in self.wanted:
                self.capture(path, sub[1][0], "count", depth)
            self.emit(f"pos += count * {width}", depth)
            return
        if path not in self.wanted:
            self.emit("for _ in range(count):", depth)
            self.string(depth + 1)
            return
        # A mapped list of strings (joint names): decoded as rosbags decodes them.
        k = self.wanted[path]
        self.found.add(path)
        self.dtypes[k] = None
        self.emit(f"f{k} = []", depth)
        self.emit("for _ in range(count):", depth)
        self.string(depth + 1, into=f"f{k}")


class _CdrGen(_Gen):
    """Emits the lines of a decoder of little-endian CDR (ROS 2).

    Alignment follows rosbags' CDR deserializer line by line: it tracks the alignment it
    knows after each field and pads before the next field only where it does not know it
    (``rosbags.serde.cdr.generate_deserialize_cdr``), which differs from padding every field
    in corner cases (an empty sequence of 8-byte values); the decoder must pad where rosbags
    pads, so it uses rosbags' own ``align`` and ``align_after``.
    """

    def string(self, depth: int, into: str = "") -> None:
        # rosbags: uint32 length with the terminating NUL, which must be there; UTF-8.
        self.emit("length = u32(raw, pos)[0]", depth)
        self.emit("end = pos + 4 + length", depth)
        fits = length_fits_source("length", "pos + 4")
        self.emit(f"if length < 1 or not ({fits}) or raw[end - 1] != 0:", depth)
        self.emit("    return None", depth)
        if into:
            self.emit(f"{into}.append(raw[pos + 4:end - 1].decode())", depth)
        else:
            self.emit("raw[pos + 4:end - 1].decode()", depth)
        self.emit("pos = end", depth)

    def pad(self, alignment: int, depth: int) -> None:
        self.emit(f"pos = (pos + {alignment - 1}) & -{alignment}", depth)

    def message(self, msgtype: str, prefix: str, depth: int) -> None:
        check_depth(self._nested, msgtype)
        self._nested += 1
        fields = self.store.fielddefs[msgtype][1]
        aligned = 8
        for (name, desc), following in zip(fields, [*fields[1:], None], strict=True):
            aligned = self.cdr_field(desc, f"{prefix}{name}", depth)
            if following is not None and aligned < (before := align(following[1], self.store)):
                self.pad(before, depth)
                aligned = before
        self._nested -= 1

    def cdr_field(self, desc: tuple[Any, ...], path: str, depth: int) -> int:
        """Emit one field; return the alignment known after it (as rosbags computes it)."""
        kind = desc[0]
        if kind == Nodetype.NAME:
            self.message(desc[1], f"{path}.", depth)
            return int(align_after(desc, self.store))
        if kind == Nodetype.BASE:
            self.field(desc, path, depth)
            return 1 if desc[1][0] == "string" else _BASE[desc[1][0]][0]
        sub = desc[1][0]
        if kind == Nodetype.ARRAY:
            length = desc[1][1]
            if sub[0] == Nodetype.BASE and sub[1][0] == "string":
                if length > MAX_UNROLL or path in self.wanted:
                    raise _UnsupportedError
                for idx in range(length):
                    if idx:
                        self.pad(4, depth)
                    self.string(depth)
                return 1
            if sub[0] != Nodetype.BASE:
                raise _UnsupportedError
            self.array(sub, length, path, depth)
            return _BASE[sub[1][0]][0]
        return self.cdr_sequence(sub, path, depth)

    def cdr_sequence(self, sub: tuple[Any, ...], path: str, depth: int) -> int:
        """Emit a sequence; return the alignment known after it (as rosbags computes it)."""
        if sub[0] != Nodetype.BASE or (sub[1][0] not in _BASE and sub[1][0] != "string"):
            raise _UnsupportedError
        if sub[1][0] == "string" and path in self.wanted and not self._inside:
            self._inside = True
            self.cached(self.wanted[path], depth, lambda d: self.cdr_sequence(sub, path, d))
            self._inside = False
            return 1
        string = sub[1][0] == "string"
        width = element_size(sub)
        self.emit("count = u32(raw, pos)[0]", depth)
        self.emit("pos += 4", depth)
        self.emit(f"if not ({count_fits_source(width, self.max_sequence)}):", depth)
        self.emit("    return None", depth)
        if string:
            into = ""
            if path in self.wanted:
                k = self.wanted[path]
                self.found.add(path)
                self.dtypes[k] = None
                into = f"f{k}"
                self.emit(f"{into} = []", depth)
            self.emit("for _ in range(count):", depth)
            self.pad(4, depth + 1)
            self.string(depth + 1, into=into)
            return 1
        if width > 4:  # noqa: PLR2004 (rosbags pads before 8-byte values only if there are any)
            self.emit("if count:", depth)
            self.pad(width, depth + 1)
        if path in self.wanted:
            self.capture(path, sub[1][0], "count", depth)
        self.emit(f"pos += count * {width}", depth)
        return min(4, width)


def compile_cdr(
    store: Typestore, msgtype: str, fields: Sequence[str], *, stamped: bool
) -> Decoder | None:
    """Return a decoder of little-endian CDR messages (as :func:`compile_ros1`), or None."""
    return _compile(_CdrGen, store, msgtype, fields, stamped=stamped)


def compile_ros1(
    store: Typestore, msgtype: str, fields: Sequence[str], *, stamped: bool
) -> Decoder | None:
    """Return a decoder of ``msgtype``'s stamp (if ``stamped``) and ``fields``, or None.

    None: the layout has something the decoder does not handle; use rosbags.
    """
    return _compile(_Gen, store, msgtype, fields, stamped=stamped)


def _compile(
    kind: type[_Gen], store: Typestore, msgtype: str, fields: Sequence[str], *, stamped: bool
) -> Decoder | None:
    """Generate a decoder with ``kind`` (see :func:`compile_ros1`)."""
    wanted = {path: k for k, path in enumerate(fields)}
    gen = kind(store, wanted, store.max_sequence_length, stamped=stamped)
    try:
        gen.message(msgtype, "", 1)
    except (_UnsupportedError, CdrError, KeyError, RecursionError):  # CdrError: nests too deep
        return None
    needed = set(fields) | ({"header.stamp.sec", "header.stamp.nanosec"} if stamped else set())
    if gen.found != needed or len(wanted) != len(fields):
        return None
    stamp = "sec, nanosec" if stamped else "0, 0"
    captured = "".join(f", f{k}" for k in range(len(fields)))
    if kind is _CdrGen:
        # rosbags: a 4-byte encapsulation header (here: little-endian CDR only), then the
        # message, then at most 3 bytes of padding.
        start = [
            "    if raw[:2] != b'\\x00\\x01' or len(raw) < 4:",
            "        return None",
            "    raw = bytes(raw[4:])",
        ]
        end = "    if pos > size or pos + 3 < size:"
    else:
        start, end = [], "    if pos != size:"
    body = [
        "def decode(raw):",
        *start,
        "    size = len(raw)",
        "    pos = 0",
        "    try:",
        *("    " + line for line in gen.lines),
        "    except (struct.error, UnicodeDecodeError):",
        "        return None",
        end,
        "        return None",
        f"    return ({stamp}{captured})",
    ]
    source = "\n".join(body) + "\n"
    namespace: dict[str, Any] = {**_GLOBALS, "struct": struct}
    namespace |= {f"c{k}": [None, 0, 0, None] for k in gen.caches}
    exec(compile(source, f"<decoder of {msgtype}>", "exec"), namespace)  # noqa: S102 (our code)
    dtypes = tuple(
        None if gen.dtypes[k] is None else np.dtype(gen.dtypes[k]) for k in range(len(fields))
    )
    return Decoder(namespace["decode"], dtypes, source, stamped=stamped)
