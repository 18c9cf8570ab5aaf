"""The layout of a skin's UDP or serial frames, described by the rig configuration's ``[skin]``.

A lab describes its own skin as data (see ``recorder/data/skin_udp.example.toml``): the link
(UDP address or serial device), the byte order, the cells, a header (sync bytes and where the
frame-type byte is) and one ``[skin.frames.<name>]`` table per frame type the skin sends, each
with its rate, its sequence counter and/or sensor stamp, and where each modality's values are
and how they convert to SI units (``SI = raw * scale + offset``). Every mistake is refused in
one line naming the file, the key, the value and the fix.

A layout becomes one numpy structured dtype per frame type (:meth:`FrameType.dtype`), so a
batch of frames is parsed in one ``np.frombuffer`` call and written in one ``tobytes``.
"""

from __future__ import annotations

import dataclasses
import ipaddress
import itertools
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, NoReturn

import numpy as np

from recorder.errors import RigError
from schemas import MAX_CELLS, VOCABULARY

if TYPE_CHECKING:
    from collections.abc import Mapping

    from numpy.typing import NDArray

#: Field types of a frame and their numpy codes (without byte order).
FIELD_TYPES: dict[str, str] = {
    "u8": "u1",
    "i8": "i1",
    "u16": "u2",
    "i16": "i2",
    "u32": "u4",
    "i32": "i4",
    "u64": "u8",
    "i64": "i8",
    "f32": "f4",
    "f64": "f8",
}
_INTEGER = tuple(name for name in FIELD_TYPES if not name.startswith("f"))
_NAME = re.compile(r"[A-Za-z0-9_-]+")
#: Default UDP receive buffer: several seconds of a 7-cell 1 kHz skin (the kernel may cap it).
RECEIVE_BUFFER_BYTES = 4 * 1024 * 1024
#: Samples per block, in seconds of the modality's rate (0.1 s, as the contract's blocks).
BLOCK_S = 0.1
_MISSING = object()


@dataclass(frozen=True, slots=True)
class Field:
    """An integer field of a frame: its byte position and type.

    Attributes:
        at: Byte position from the start of the frame.
        type: One of :data:`FIELD_TYPES`.
        modulo: The value wraps at this number (counters and stamps; 0: not a counter).
    """

    at: int
    type: str
    modulo: int = 0

    @property
    def size(self) -> int:
        """Return the field's size, bytes."""
        return np.dtype(FIELD_TYPES[self.type]).itemsize


@dataclass(frozen=True, slots=True)
class Stamp:
    """The sensor's clock in a frame.

    Attributes:
        field: Where the stamp is (its modulo: ticks at which it wraps).
        unit_ns: Nanoseconds per tick.
    """

    field: Field
    unit_ns: int


@dataclass(frozen=True, slots=True)
class ModalityField:
    """Where one modality's values are in a frame and how they convert to SI units.

    Attributes:
        modality: The contract's modality.
        at: Byte position of the first value of the first cell (of the frame's cell).
        type: One of :data:`FIELD_TYPES`.
        count: Values per cell (consecutive in the frame).
        cell_stride: Bytes from one cell's values to the next (frames with every cell).
        scale: SI value = raw * scale + offset.
        offset: See ``scale``.
    """

    modality: str
    at: int
    type: str
    count: int
    cell_stride: int
    scale: float
    offset: float

    @property
    def size(self) -> int:
        """Return the size of one cell's values, bytes."""
        return int(np.dtype(FIELD_TYPES[self.type]).itemsize) * self.count


@dataclass(frozen=True, slots=True)
class FrameType:
    """One kind of frame a skin sends.

    Attributes:
        name: Its name in the configuration (``[skin.frames.<name>]``).
        id: Value of the header's frame-type field (None: the link carries one frame type).
        rate_hz: Frames per second (per cell when a frame carries one cell).
        period_ns: Nominal time between samples, ns.
        size: Frame length, bytes.
        sequence: The frame counter (None: counted by the sensor stamp).
        stamp: The sensor's clock (None: time is counter x period).
        cell: The field naming the cell a frame carries (None: a frame carries every cell).
        modalities: The modalities the frame carries.
    """

    name: str
    id: int | None
    rate_hz: float
    period_ns: int
    size: int
    sequence: Field | None
    stamp: Stamp | None
    cell: Field | None
    modalities: tuple[ModalityField, ...]

    def dtype(self, byte_order: str, cells: int) -> np.dtype[np.void]:
        """Return the frame's numpy structured dtype.

        Fields ``sequence``, ``stamp``, ``cell`` and ``<modality>_<cell>`` of shape (count,);
        a frame that carries one cell has ``<modality>_0``.
        """
        order = "<" if byte_order == "little" else ">"
        names: list[str] = []
        formats: list[Any] = []
        offsets: list[int] = []
        for key, found in (("sequence", self.sequence), ("cell", self.cell)):
            if found is not None:
                names.append(key)
                formats.append(order + FIELD_TYPES[found.type])
                offsets.append(found.at)
        if self.stamp is not None:
            names.append("stamp")
            formats.append(order + FIELD_TYPES[self.stamp.field.type])
            offsets.append(self.stamp.field.at)
        for item in self.modalities:
            for cell in range(1 if self.cell is not None else cells):
                names.append(f"{item.modality}_{cell}")
                formats.append((order + FIELD_TYPES[item.type], (item.count,)))
                offsets.append(item.at + cell * item.cell_stride)
        spec = {"names": names, "formats": formats, "offsets": offsets, "itemsize": self.size}
        return np.dtype(spec)  # type: ignore[call-overload,no-any-return]

    def decode(self, frames: NDArray[np.void], cells: int) -> dict[str, NDArray[np.float32]]:
        """Return each modality's SI values of a batch of frames.

        Args:
            frames: Frames of this type (its :meth:`dtype`).
            cells: Cells of the skin.

        Returns:
            Modality -> values, shape (frames, cells, count), or (frames, 1, count) for
            frames that carry one cell.
        """
        out: dict[str, NDArray[np.float32]] = {}
        per_frame = 1 if self.cell is not None else cells
        for item in self.modalities:
            raw = np.stack([frames[f"{item.modality}_{c}"] for c in range(per_frame)], axis=1)
            values = raw.astype(np.float64) * item.scale + item.offset
            out[item.modality] = values.astype(np.float32)
        return out


@dataclass(frozen=True, slots=True)
class SkinLayout:
    """A skin's link and frames, from the rig configuration's ``[skin]`` table.

    Attributes:
        transport: ``udp`` or ``serial``.
        bind: UDP: the address the recorder listens on, ``host:port``.
        device: Serial: the device (``/dev/ttyUSB0``).
        baud: Serial: the baud rate.
        byte_order: ``little`` or ``big``.
        cells: Number of cells.
        magic: Sync bytes at the start of every frame (empty: none; needed on serial).
        id_field: Where the frame-type value is (None: one frame type).
        frames: The frame types.
        name: The source name prefix (``skin``; ``skin-<frame>`` with several frame types).
        receive_buffer: UDP socket receive buffer, bytes (SO_RCVBUF).
        where: The configuration file, for messages.
        sender: UDP: the only address whose datagrams are taken, ``host`` or ``host:port``
            (empty: the first address that sends a valid frame, see
            :class:`recorder.live.UdpSkin`). Datagrams from another address are dropped and
            counted as malformed (another rig's skin sending to the same port, stray traffic);
            they never keep a silent skin from being seen.
    """

    transport: str
    bind: tuple[str, int]
    device: str
    baud: int
    byte_order: Literal["little", "big"]
    cells: int
    magic: bytes
    id_field: Field | None
    frames: tuple[FrameType, ...]
    name: str
    receive_buffer: int
    where: str
    sender: str = ""

    def source(self, frame: FrameType) -> str:
        """Return the accounting source name of a frame type."""
        return self.name if len(self.frames) == 1 else f"{self.name}-{frame.name}"

    @property
    def modalities(self) -> tuple[str, ...]:
        """Return the modalities some frame type carries, in the contract's order."""
        carried = {item.modality for frame in self.frames for item in frame.modalities}
        return tuple(m for m in VOCABULARY.modalities if m in carried)

    def frame_of(self, modality: str) -> FrameType | None:
        """Return the frame type carrying ``modality`` (None: the skin lacks it)."""
        for frame in self.frames:
            if any(item.modality == modality for item in frame.modalities):
                return frame
        return None


class _Shown(str):
    """A value shown as written (no quotes) in a message."""

    __slots__ = ()

    def __repr__(self) -> str:
        """Return the text itself."""
        return str(self)


class _Table:
    """A TOML table being checked: typed getters and a refusal of unknown keys."""

    def __init__(self, data: object, label: str, where: str) -> None:
        if not isinstance(data, dict):
            self._fail(label, "", data, "give a table", where)
        self.data: dict[str, Any] = data
        self.label = label
        self.where = where
        self._used: set[str] = set()

    @staticmethod
    def _fail(label: str, key: str, value: object, fix: str, where: str) -> NoReturn:
        name = f"[{label}] {key} = {value!r}" if key else f"[{label}] = {value!r}"
        msg = f"{where}: {name}: {fix}"
        raise RigError(msg)

    def fail(self, key: str, value: object, fix: str) -> NoReturn:
        """Refuse ``key = value`` with ``fix``.

        Raises:
            RigError: Always.
        """
        self._fail(self.label, key, value, fix, self.where)

    def get(self, key: str, default: object = _MISSING) -> object:
        """Return a value (``default`` when absent; refused when absent without default)."""
        self._used.add(key)
        if key in self.data:
            return self.data[key]
        if default is _MISSING:
            self.fail(key, "missing", "this key is required")
        return default

    def integer(
        self, key: str, default: object = _MISSING, low: int = 0, high: int | None = None
    ) -> int:
        """Return an integer at least ``low`` (and at most ``high``)."""
        value = self.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            self.fail(key, value, f"give an integer >= {low}")
        if high is not None and value > high:
            self.fail(key, value, f"give an integer {low}..{high}")
        return int(value)

    def number(self, key: str, default: object = _MISSING, *, positive: bool = False) -> float:
        """Return a finite number (positive when asked)."""
        value = self.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int | float):
            self.fail(key, value, "give a number")
        number = float(value)
        if not np.isfinite(number) or (positive and number <= 0):
            self.fail(key, value, "give a finite number" + (" > 0" if positive else ""))
        return number

    def choice(self, key: str, choices: tuple[str, ...], default: object = _MISSING) -> str:
        """Return one of ``choices``."""
        value = self.get(key, default)
        if value not in choices:
            self.fail(key, value, f"give one of {', '.join(choices)}")
        return str(value)

    def table(self, key: str, *, required: bool = False) -> _Table | None:
        """Return a sub-table (None when absent and not required)."""
        value = self.get(key, _MISSING if required else None)
        if value is None:
            return None
        if not isinstance(value, dict):
            self.fail(key, value, "give a table (key = { ... } or a [section])")
        return _Table(value, f"{self.label}.{key}", self.where)

    def done(self) -> None:
        """Refuse keys that were not read."""
        for key in self.data:
            if key not in self._used:
                self.fail(key, self.data[key], f"unknown key; known: {', '.join(self._used)}")


def _address(table: _Table, key: str, default: str) -> tuple[str, int]:
    text = table.get(key, default)
    host, sep, port = str(text).rpartition(":")
    if not isinstance(text, str) or not sep or not host or not port.isdigit():
        table.fail(key, text, 'give "host:port", e.g. "127.0.0.1:5005"')
    if not 0 <= int(port) < 65536:  # noqa: PLR2004 (the port range)
        table.fail(key, text, "give a port from 0 (any free port) to 65535")
    return host, int(port)


def _sender(table: _Table) -> str:
    """Return the ``sender`` address, ``host`` or ``host:port`` (empty: not given).

    A port tells apart two senders on one computer (a skin and a replay on its loopback).
    """
    text = table.get("sender", "")
    if text == "":
        return ""
    fix = 'give the skin\'s IP address, e.g. "192.168.1.20" or "192.168.1.20:5006"'
    if not isinstance(text, str):
        table.fail("sender", text, fix)
    host, port = text, ""
    if text.count(":") == 1:  # an IPv4 address with its port (an IPv6 address has more)
        host, _, port = text.partition(":")
        if not port.isdigit() or not 0 < int(port) < 65536:  # noqa: PLR2004 (the port range)
            table.fail("sender", text, "give the skin's port as 1..65535, or leave it out")
    try:
        address = ipaddress.ip_address(host)
    except ValueError:
        table.fail("sender", text, fix)
    if address.version != 4:  # noqa: PLR2004 (the skin's socket is IPv4)
        table.fail("sender", text, "give an IPv4 address: the skin's UDP socket is IPv4")
    return f"{address}:{int(port)}" if port else str(address)


def _field(table: _Table, *, counter: bool) -> Field:
    at = table.integer("at")
    kind = table.choice("type", _INTEGER)
    bits = 8 * np.dtype(FIELD_TYPES[kind]).itemsize
    modulo = table.integer("modulo", 2**bits if counter else 0, low=0)
    if counter and not 2 <= modulo <= 2**bits:  # noqa: PLR2004 (a counter counts 2 values)
        table.fail("modulo", modulo, f"give 2..{2**bits} (the counter's wrap for {kind})")
    table.done()
    return Field(at, kind, modulo if counter else 0)


def _modality(table: _Table, modality: str, cells: int, stride: int | None) -> ModalityField:
    at = table.integer("at")
    kind = table.choice("type", tuple(FIELD_TYPES))
    count = table.integer("count", len(VOCABULARY.modalities[modality].values), low=1)
    own_stride = table.get("cell_stride", stride)
    scale = table.number("scale", 1.0)
    if scale == 0:
        table.fail("scale", scale, "give a non-zero scale (SI = raw * scale + offset)")
    offset = table.number("offset", 0.0)
    table.done()
    size = int(np.dtype(FIELD_TYPES[kind]).itemsize) * count
    if own_stride is None and cells > 1:
        table.fail("cell_stride", None, "give the bytes from one cell's values to the next")
    cell_stride = int(own_stride) if isinstance(own_stride, int) else 0
    if cells > 1 and cell_stride < size:
        table.fail("cell_stride", own_stride, f"give at least {size} (one cell's values)")
    return ModalityField(modality, at, kind, count, cell_stride, scale, offset)


def _extent(frame: FrameType, cells: int) -> list[tuple[int, int, str]]:
    """Return every field's byte range (start, stop, key) in a frame."""
    spans: list[tuple[int, int, str]] = []
    for key, found in (("sequence", frame.sequence), ("cell", frame.cell)):
        if found is not None:
            spans.append((found.at, found.at + found.size, f"{key}.at"))
    if frame.stamp is not None:
        spans.append(
            (frame.stamp.field.at, frame.stamp.field.at + frame.stamp.field.size, "stamp.at")
        )
    per_frame = 1 if frame.cell is not None else cells
    for item in frame.modalities:
        for cell in range(per_frame):
            start = item.at + cell * item.cell_stride
            key = f"{item.modality}.at" + (f" + {cell} x cell_stride" if cell else "")
            spans.append((start, start + item.size, key))
    return spans


def _check_overlaps(table: _Table, spans: list[tuple[int, int, str]], header: int) -> None:
    ordered = sorted(spans)
    for start, _, key in ordered:
        if start < header:
            table.fail(key, start, f"overlaps the header (bytes 0..{header - 1}); move it")
    for (start, stop, key), (other, _, key2) in itertools.pairwise(ordered):
        if other < stop:
            table.fail(key2, other, f"overlaps {key} (bytes {start}..{stop - 1}); move one")


def _counting(table: _Table) -> tuple[Field | None, Stamp | None, Field | None]:
    """Return a frame type's sequence counter, sensor stamp and cell field."""
    sequence = stamp = cell = None
    if (sub := table.table("sequence")) is not None:
        sequence = _field(sub, counter=True)
    if (sub := table.table("stamp")) is not None:
        unit = sub.integer("unit_ns", low=1)
        stamp = Stamp(_field(sub, counter=True), unit)
    if (sub := table.table("cell")) is not None:
        cell = _field(sub, counter=False)
    if sequence is None and (stamp is None or cell is not None):
        need = "a sequence" if cell is not None else "a sequence or a stamp"
        table.fail("sequence", None, f"give {need} = {{ at, type }} so every frame is counted")
    return sequence, stamp, cell


def _frame_id(table: _Table, *, typed: bool) -> int | None:
    frame_id = table.get("id", None)
    if typed and (isinstance(frame_id, bool) or not isinstance(frame_id, int)):
        table.fail("id", frame_id, "give the value of the header's frame-type field")
    if not typed and frame_id is not None:
        table.fail("id", frame_id, "give [skin.header] id = { at, type } to tell frames apart")
    return frame_id  # type: ignore[return-value]


def _frame_size(table: _Table, value: object, end: int) -> int:
    if value is None:
        return end
    if isinstance(value, bool) or not isinstance(value, int) or value < end:
        table.fail("size", value, f"give at least {end} (the end of the last field)")
    return int(value)


def _frame(table: _Table, name: str, cells: int, header: int, *, typed: bool) -> FrameType:
    if not _NAME.fullmatch(name):
        table.fail("", name, "name frame types with letters, digits, - and _")
    frame_id = _frame_id(table, typed=typed)
    rate = table.number("rate_hz", positive=True)
    sequence, stamp, cell = _counting(table)
    stride = table.get("cell_stride", None)
    if stride is not None and (not isinstance(stride, int) or isinstance(stride, bool)):
        table.fail("cell_stride", stride, "give an integer (bytes from one cell to the next)")
    per_frame = 1 if cell is not None else cells
    found = tuple(
        _modality(sub, modality, per_frame, stride)
        for modality in VOCABULARY.modalities
        if (sub := table.table(modality)) is not None
    )
    size_value = table.get("size", None)
    table.done()
    if not found:
        table.fail("", "no modality", f"give at least one of {', '.join(VOCABULARY.modalities)}")
    period = round(1e9 / rate)
    frame = FrameType(name, frame_id, rate, period, 0, sequence, stamp, cell, found)
    spans = _extent(frame, cells)
    _check_overlaps(table, spans, header)
    size = _frame_size(table, size_value, max([header, *(stop for _, stop, _ in spans)]))
    return dataclasses.replace(frame, size=size)


def _header(table: _Table | None, transport: str, where: str) -> tuple[bytes, Field | None]:
    if table is None:
        if transport == "serial":
            msg = (
                f"{where}: [skin.header] = missing: give magic = [0xAA, 0x55] (the sync bytes "
                "that find frames in a serial byte stream)"
            )
            raise RigError(msg)
        return b"", None
    magic_value = table.get("magic", [])
    valid = isinstance(magic_value, list) and all(
        isinstance(b, int) and not isinstance(b, bool) and 0 <= b <= 255  # noqa: PLR2004
        for b in magic_value
    )
    if not valid or (transport == "serial" and not magic_value):
        table.fail("magic", magic_value, "give the sync bytes as a list, e.g. [0xAA, 0x55]")
    id_field = None
    if (sub := table.table("id")) is not None:
        id_field = _field(sub, counter=False)
    table.done()
    return bytes(magic_value), id_field  # type: ignore[call-overload]


def parse_layout(section: Mapping[str, Any], where: str) -> SkinLayout:
    """Check a ``[skin]`` table and return its layout.

    Args:
        section: The rig configuration's ``[skin]`` table.
        where: The configuration file, for messages.

    Raises:
        RigError: A key is unknown, missing or malformed; one line naming the file, the key,
            the value and the fix.
    """
    table = _Table(dict(section), "skin", where)
    transport = table.choice("transport", ("udp", "serial"))
    bind, device, baud, sender = ("127.0.0.1", 5005), "", 0, ""
    if transport == "udp":
        bind = _address(table, "bind", "127.0.0.1:5005")
        sender = _sender(table)
    else:
        device = str(table.get("device"))
        baud = table.integer("baud", 115200, low=1)
    byte_order: Literal["little", "big"] = (
        "big" if table.choice("byte_order", ("little", "big"), "little") == "big" else "little"
    )
    cells = table.integer("cells", low=1, high=MAX_CELLS)
    name = table.get("name", "skin")
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        table.fail("name", name, "give a source name of letters, digits, - and _")
    buffer = table.integer("receive_buffer_bytes", RECEIVE_BUFFER_BYTES, low=4096)
    magic, id_field = _header(table.table("header"), transport, where)
    header = len(magic)
    if id_field is not None:
        header = max(header, id_field.at + id_field.size)
    frames_table = table.table("frames", required=True)
    table.done()
    assert frames_table is not None  # noqa: S101 (required=True never returns None)
    frames = _frames(frames_table, cells, header, typed=id_field is not None)
    return SkinLayout(
        transport,
        bind,
        device,
        baud,
        byte_order,
        cells,
        magic,
        id_field,
        frames,
        str(name),
        buffer,
        where,
        sender,
    )


def _frames(table: _Table, cells: int, header: int, *, typed: bool) -> tuple[FrameType, ...]:
    frames = []
    for name in list(table.data):
        sub = table.table(name, required=True)
        assert sub is not None  # noqa: S101
        frames.append(_frame(sub, name, cells, header, typed=typed))
    if not frames:
        table.fail("", {}, "give at least one [skin.frames.<name>] table")
    if not typed and len(frames) > 1:
        table.fail("", list(table.data), "give [skin.header] id = { at, type } and each an id")
    ids = [frame.id for frame in frames]
    for frame in frames:
        if ids.count(frame.id) > 1:
            table.fail(f"{frame.name}.id", frame.id, "give every frame type its own id")
    seen: dict[str, str] = {}
    for frame in frames:
        for item in frame.modalities:
            if item.modality in seen:
                table.fail(
                    f"{frame.name}.{item.modality}",
                    _Shown("{...}"),
                    f"already sent in frames.{seen[item.modality]}: keep one",
                )
            seen[item.modality] = frame.name
    return tuple(frames)


def block_samples(frame: FrameType) -> int:
    """Return the samples per block of a frame type's modalities (0.1 s, at least 1)."""
    return max(1, round(frame.rate_hz * BLOCK_S))
