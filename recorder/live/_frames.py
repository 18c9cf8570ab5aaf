"""A skin read live from UDP datagrams or a serial byte stream, laid out as configured.

One :class:`~recorder.live.SourceReader` thread per link receives frames and stamps them with
the recorder's clock; :meth:`FrameSkin.poll` parses what is queued in batches (one numpy
structured dtype per frame type, one ``np.frombuffer`` per batch), counts every frame with a
:class:`~recorder.live.SourceCounter` per frame type, maps sensor time onto the recorder's time
base and packs each modality into blocks. Frames that match no frame type (wrong sync bytes,
length or type) are counted as malformed, never raised.

Sensor time of a frame is its stamp (``[skin.frames.<name>] stamp``) or its counter times the
period. It is put on the recorder's time base with one offset per frame type, fixed for the
recording at its start from the lowest latency among the frames received since the previous
recording and the first frames after :meth:`FrameSkin.begin` (one late frame cannot shift a
recording's stamps), so stamps never go back; how much the offset drifts over a recording is
reported in the source's ``clock_drift_ns``. Samples are placed on the frame type's nominal grid
(``first + round((sensor - first) / period) * period``) so consecutive samples pack into one
block; a late or duplicated frame is counted and left out (a block never goes back in time).

What is counted and left out is also judged, once per action (:meth:`FrameSkin.findings`, said
in one line each when the action ends, and shown by a dry run): frames from another sender
(UDP: without ``[skin] sender`` the first address that sends a valid frame is the skin's, and
every other address's datagrams are counted as malformed of the first frame type's source,
never written), malformed frames by what was wrong with them, a frame type that arrives at
another rate than its ``rate_hz`` (measured on the recorder's clock, see
:class:`ArrivalRate`) and frames stamped out of range.
"""

from __future__ import annotations

import dataclasses
import ipaddress
import socket
import sys
import threading
from collections import Counter, deque
from typing import TYPE_CHECKING, Any, Self

import numpy as np

from recorder.errors import RigError
from recorder.live._accounting import EARLY_TOLERANCE_NS, SourceCounter, SourceStats, Verdict
from recorder.live._framelayout import FrameType, SkinLayout, block_samples, parse_layout
from recorder.live._packer import BlockPacker
from recorder.live._reader import Received, SourceReader
from recorder.live._skin import SkinFinding, window_samples

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping
    from types import TracebackType

    from numpy.typing import NDArray

    from recorder.live._clock import RecorderClock
    from recorder.writing._stream import SkinBlock

#: How long a reader waits in one receive call, s (how fast it notices it is stopped).
RECEIVE_TIMEOUT_S = 0.05
#: A frame that carries one cell: how many newer samples may start before an incomplete
#: sample is given up (its missing cells are counted; the sample becomes a gap).
PENDING_SAMPLES = 3
#: Without ``[skin] sender``: another address has sent for this long, ns, and the address
#: whose frames are taken nothing meanwhile, when its valid frames take their place (a skin
#: that restarted on another source port); while it sends, every other address is left out.
REPIN_NS = 250_000_000
#: The least-latency frames that measure a frame type's rate are taken in windows this long
#: (the first after :meth:`FrameSkin.begin`, and the latest two), ns.
RATE_WINDOW_NS = 200_000_000
#: A rate is measured between frames at least this far apart, ns, of at least this many.
RATE_MIN_SPAN_NS = 300_000_000
RATE_MIN_FRAMES = 10
#: A frame type that arrives this much faster or slower than its ``rate_hz`` (a fraction of
#: it) is off its rate: a dry run is not ready, an action says so.
RATE_TOLERANCE = 0.2
#: Frames of one type stamped out of range in an action, beyond this share of those received,
#: are said with their likely cause.
OUT_OF_RANGE_SHARE = 0.01
#: Kinds of malformed frames a line names (the most frequent), the rest counted together.
MALFORMED_KINDS = 3


class Unwrap:
    """Unwraps a counter that wraps at ``modulo`` (a 16-bit frame counter, a 32-bit stamp)."""

    def __init__(self, modulo: int) -> None:
        """Start with nothing seen."""
        self.modulo = modulo
        self._max: int | None = None

    def __call__(self, raw: int) -> int:
        """Return the unwrapped value nearest to the largest so far."""
        if self._max is None or not self.modulo:
            self._max = raw if self._max is None else max(self._max, raw)
            return raw
        m, top = self.modulo, self._max
        base = top - top % m
        value = min((base - m + raw, base + raw, base + m + raw), key=lambda c: abs(c - top))
        self._max = max(top, value)
        return value


class ArrivalRate:
    """Measures how fast frames arrive on the recorder's clock, unmoved by a held reader.

    Frame ``k`` of a sender that sends one frame every ``period_ns`` arrives at
    ``k * period + latency``. A reader held up (a loaded recorder) delays frames, never makes
    one early, so the frames of least ``receive - k * period`` lie on the sender's own
    schedule: the rate is taken between the least-latency frame of the first
    :data:`RATE_WINDOW_NS` and that of the latest two windows. Frames are counted as they
    arrive (a lost frame moves the rate by its share only).
    """

    def __init__(self, period_ns: int) -> None:
        """Start with no frame; ``period_ns`` is the nominal time between frames."""
        self.period_ns = period_ns
        self.count = 0
        self._start: int | None = None
        self._window_start = 0
        #: (receive - k * period, k, receive) of the least-latency frame of each window.
        self._first: tuple[int, int, int] | None = None
        self._previous: tuple[int, int, int] | None = None
        self._current: tuple[int, int, int] | None = None

    def add(self, receives: list[int]) -> None:
        """Count frames that arrived at ``receives`` (recorder clock, ns, in arrival order)."""
        for receive_ns in receives:
            point = (receive_ns - self.count * self.period_ns, self.count, receive_ns)
            self.count += 1
            if self._start is None:
                self._start = self._window_start = receive_ns
            if receive_ns - self._start < RATE_WINDOW_NS:
                self._first = point if self._first is None else min(self._first, point)
            if receive_ns - self._window_start >= RATE_WINDOW_NS:
                self._previous, self._current = self._current, None
                self._window_start = receive_ns
            self._current = point if self._current is None else min(self._current, point)

    def hz(self) -> float | None:
        """Return the frames per second (None: too few frames, or too short a span)."""
        latest = [p for p in (self._previous, self._current) if p is not None]
        if self._first is None or not latest or self.count < RATE_MIN_FRAMES:
            return None
        _, first, first_ns = self._first
        _, last, last_ns = min(latest)
        if last_ns - first_ns < RATE_MIN_SPAN_NS:
            return None
        return (last - first) * 1e9 / (last_ns - first_ns)


def classify(
    layout: SkinLayout, payload: bytes, by_id: Mapping[int | None, FrameType]
) -> tuple[FrameType | None, str]:
    """Return a frame's type and, when it is malformed, why (a clause; '': a valid frame).

    A frame is valid when it starts with the sync bytes, its type field names a frame type
    (``by_id``) and it has that type's size. The type is None when it cannot be told.
    """
    if payload[: len(layout.magic)] != layout.magic:
        return None, f"without the sync bytes {layout.magic.hex(' ').upper()}"
    frame = by_id.get(None)
    if (field := layout.id_field) is not None:
        raw = payload[field.at : field.at + field.size]
        if len(raw) < field.size:
            return None, f"of {len(payload)} bytes (no frame-type field)"
        value = int.from_bytes(raw, layout.byte_order, signed=field.type.startswith("i"))
        frame = by_id.get(value)
        if frame is None:
            known = ", ".join(f"{f.name} is {f.id}" for f in layout.frames)
            return None, f"of frame type {value} (none in the layout: {known})"
    assert frame is not None  # noqa: S101 (a layout without an id field has one frame type)
    if len(payload) != frame.size:
        return frame, f"of {len(payload)} bytes (frame type {frame.name} is {frame.size} bytes)"
    return frame, ""


def _about(hz: float) -> str:
    """Return a rate to two significant digits, e.g. ``10,000`` or ``0.52``."""
    rounded = float(f"{hz:.2g}")
    return f"{rounded:,.0f}" if rounded >= 10 else f"{rounded:g}"  # noqa: PLR2004


def _plural(count: int, noun: str) -> str:
    """Return ``noun``, with an ``s`` unless ``count`` is one."""
    return noun if count == 1 else f"{noun}s"


@dataclasses.dataclass(slots=True)
class _Pending:
    """A sample of a frame type that carries one cell per frame, being assembled."""

    values: dict[str, NDArray[np.float32]]
    filled: NDArray[np.bool_]
    receive_ns: int = 0


class _Stream:
    """The consumer's state of one frame type: counting, time base, packing."""

    def __init__(self, layout: SkinLayout, frame: FrameType) -> None:
        self.layout = layout
        self.frame = frame
        self.dtype = frame.dtype(layout.byte_order, layout.cells)
        self.counter = SourceCounter(layout.source(frame), period_ns=frame.period_ns)
        self.sequence = Unwrap(frame.sequence.modulo if frame.sequence else 0)
        self.stamp = Unwrap(frame.stamp.field.modulo if frame.stamp else 0)
        self.packers = {
            item.modality: BlockPacker(item.modality, frame.period_ns, block=block_samples(frame))
            for item in frame.modalities
        }
        self.origin: int | None = None
        self.index_base = 0
        self.zero = 0
        self.offset: int | None = None
        self.offset_hint: int | None = None
        self.last_index = -1
        self.pending: dict[int, _Pending] = {}
        self.latest: dict[str, NDArray[np.float32]] = {}
        #: The latest totals of the force samples (the window of ``total_force``'s mean).
        self.totals: deque[float] = deque(maxlen=window_samples(frame.period_ns))
        self.malformed = 0
        self.out_of_range = 0
        #: Malformed frames of this type by what was wrong (the clause of the skin's line).
        self.rejected: Counter[str] = Counter()
        cells = layout.cells if frame.cell is not None else 1  # a frame per cell: cells x rate
        self.rate = ArrivalRate(round(frame.period_ns / cells))

    def times(self, frames: NDArray[np.void]) -> tuple[list[int], list[int | None]]:
        """Return each frame's sensor time, ns, and counter number (None: counted by time)."""
        frame = self.frame
        sequences: list[int | None] = [None] * len(frames)
        if frame.sequence is not None:
            sequences = [self.sequence(int(raw)) for raw in frames["sequence"].tolist()]
        if frame.stamp is not None:
            unit = frame.stamp.unit_ns
            sensor = [self.stamp(int(raw)) * unit for raw in frames["stamp"].tolist()]
        else:
            sensor = [number * frame.period_ns for number in sequences]  # type: ignore[operator]
        return sensor, sequences

    def consume(self, frames: NDArray[np.void], receives: list[int]) -> list[SkinBlock]:
        """Count, check, time and pack a batch of frames of this type (in arrival order).

        A frame with a NaN or infinite value is counted malformed and left out; a frame whose
        stamp is out of range is counted and left out (it never moves the time base); a
        counter reset starts a new run, placed after the last sample on the time base.
        """
        self.rate.add(receives)
        sensor, sequences = self.times(frames)
        decoded = self.frame.decode(frames, self.layout.cells)
        finite = _finite(decoded, len(frames))
        if self.offset is None:
            self.offset = _offset(receives, sensor, self.offset_hint)
        cells = frames["cell"].tolist() if self.frame.cell is not None else None
        blocks: list[SkinBlock] = []
        for i, (sensor_ns, number, receive_ns) in enumerate(
            zip(sensor, sequences, receives, strict=True)
        ):
            if cells is not None:
                if not 0 <= cells[i] < self.layout.cells:
                    self.malformed += 1
                    self.rejected[
                        f"of cell {cells[i]} (frame type {self.frame.name}; [skin] cells = "
                        f"{self.layout.cells})"
                    ] += 1
                    continue
                number = (number or 0) * self.layout.cells + cells[i]  # noqa: PLW2901
            if not finite[i]:
                self.malformed += 1
                self.rejected[f"with a NaN or infinite value (frame type {self.frame.name})"] += 1
                continue
            verdict = self.counter.count(number, sensor_ns, receive_ns)
            if not (verdict.fresh or (cells is not None and verdict is Verdict.LATE)):
                continue
            index = self._index(sensor_ns, receive_ns, new_run=verdict is Verdict.NEW_RUN)
            values = {name: rows[i] for name, rows in decoded.items()}
            if cells is None:
                if index <= self.last_index:  # its stamp falls on a place already written
                    self.out_of_range += 1
                    continue
                blocks += self._emit(index, values, receive_ns)
            else:
                blocks += self._assemble(index, cells[i], values, receive_ns)
        return blocks

    def _index(self, sensor_ns: int, receive_ns: int, *, new_run: bool) -> int:
        """Return a sample's place on the recorder's time base (a new run goes after the last).

        A new run (the skin's counter or clock was reset) is placed at its receive time, and
        never before the last sample written.
        """
        period = self.frame.period_ns
        if self.origin is None:
            self.origin = sensor_ns
            self.zero = sensor_ns + (self.offset or 0)
        elif new_run:
            self.origin = sensor_ns
            self.index_base = max(self.last_index + 1, round((receive_ns - self.zero) / period))
            self.pending.clear()
        return self.index_base + round((sensor_ns - self.origin) / period)

    def _assemble(
        self, index: int, cell: int, values: dict[str, NDArray[np.float32]], receive_ns: int
    ) -> list[SkinBlock]:
        """Add one cell's frame; emit the sample once every cell arrived."""
        if index <= self.last_index:
            return []
        sample = self.pending.get(index)
        if sample is None:
            shapes = {name: (self.layout.cells, row.shape[-1]) for name, row in values.items()}
            sample = _Pending(
                {name: np.zeros(shape, np.float32) for name, shape in shapes.items()},
                np.zeros(self.layout.cells, bool),
            )
            self.pending[index] = sample
        for name, row in values.items():
            sample.values[name][cell] = row[0]
        sample.filled[cell] = True
        sample.receive_ns = max(sample.receive_ns, receive_ns)
        for old in [key for key in self.pending if key < index - PENDING_SAMPLES]:
            del self.pending[old]
        if not sample.filled.all():
            return []
        for old in [key for key in self.pending if key <= index]:
            del self.pending[old]
        return self._emit(index, sample.values, sample.receive_ns)

    def _emit(
        self, index: int, values: Mapping[str, NDArray[np.float32]], receive_ns: int
    ) -> list[SkinBlock]:
        """Pack one whole sample (every cell) at its place on the recorder's time base."""
        if index <= self.last_index or self.origin is None:
            return []
        self.last_index = index
        stamp = self.zero + index * self.frame.period_ns
        blocks: list[SkinBlock] = []
        for name, row in values.items():
            self.latest[name] = row
            if name == "force":
                self.totals.append(float(row.sum()))
            blocks += self.packers[name].push(stamp, receive_ns, row)
        return blocks

    def flush(self) -> list[SkinBlock]:
        """Return every open block."""
        return [block for packer in self.packers.values() for block in packer.flush()]

    def findings(self, stats: SourceStats, *, rate_alone: bool = True) -> list[SkinFinding]:
        """Judge this frame type's rate and its frames stamped out of range (``stats``).

        A rate off ``rate_hz`` by more than :data:`RATE_TOLERANCE` is blocking: its samples
        would be placed on a wrong grid (most left out as out of range when it is faster).
        Out of range beyond :data:`OUT_OF_RANGE_SHARE` of the frames is said with its cause.
        Without ``rate_alone`` (an action's end) the rate is said only as the cause of frames
        left out: measured over one action on a busy computer it can be off by itself.
        """
        frame, layout = self.frame, self.layout
        who = f"{layout.name} frame type {frame.name}"
        key = f"[skin.frames.{frame.name}] rate_hz = {frame.rate_hz:g} in {layout.where}"
        out, received = stats.out_of_range, stats.received
        dropped = out > OUT_OF_RANGE_SHARE * received
        frames_hz = self.rate.hz()  # a frame per cell: cells frames a sample
        hz = None if frames_hz is None else frames_hz * self.rate.period_ns / frame.period_ns
        off = hz is not None and abs(hz / frame.rate_hz - 1) > RATE_TOLERANCE
        if hz is not None and off and (rate_alone or dropped):
            also = ""
            if dropped:
                also = f" ({out} of {received} frames stamped out of range, left out)"
            line = (
                f"{who}: arrives at about {_about(hz)} Hz, {key}{also}; fix rate_hz (or the "
                "skin's rate)"
            )
            short = f"{who} arrives at about {_about(hz)} Hz, not at its rate_hz"
            return [SkinFinding(line, blocking=True, short=short)]
        if not dropped:
            return []
        clock = "its counter"
        if frame.stamp is not None:
            clock = f"stamp unit_ns = {frame.stamp.unit_ns}"
        line = (
            f"{who}: {out} of {received} frames stamped out of range, left out: the skin's clock "
            f"jumped, or {key} ({clock}) is not the skin's; check them against the skin"
        )
        return [SkinFinding(line)]


def _finite(decoded: Mapping[str, NDArray[np.float32]], count: int) -> NDArray[np.bool_]:
    """Return, per frame, whether every decoded value is finite."""
    ok = np.ones(count, dtype=bool)
    for rows in decoded.values():
        ok &= np.isfinite(rows).reshape(count, -1).all(axis=1)
    return ok


def _offset(receives: list[int], sensor: list[int], hint: int | None) -> int:
    """Return a recording's clock offset: the lowest latency among the plausible frames.

    A frame whose latency is far from the batch's median (a stamp that jumped) does not
    count, nor does a hint (frames before the recording) that is far from it.
    """
    latencies = sorted(r - s for r, s in zip(receives, sensor, strict=True))
    median = latencies[len(latencies) // 2]
    lowest = min(x for x in latencies if abs(x - median) <= EARLY_TOLERANCE_NS)
    if hint is not None and abs(hint - median) <= EARLY_TOLERANCE_NS:
        return min(lowest, hint)
    return lowest


class ByteFramer:
    """Cuts a serial byte stream into frames at the sync bytes; re-syncs after a loss.

    A candidate frame is taken when the sync bytes start it, its type is known and the next
    frame's sync bytes follow it (so a sync pattern inside the values, or a frame cut short
    by a reset, is not taken for a frame); the last frame before the line goes idle is taken
    by :meth:`flush`. Every rejected candidate and every run of noise before a frame counts
    as one sync loss (:attr:`malformed`).
    """

    def __init__(self, layout: SkinLayout) -> None:
        """Prepare an empty buffer."""
        self.magic = layout.magic
        self.id_field = layout.id_field
        self.order = layout.byte_order
        self.sizes = {frame.id: frame.size for frame in layout.frames}
        self.malformed = 0
        self._buffer = bytearray()
        self._lost = False

    def _size(self) -> int | None:
        """Return the size of the frame at the buffer's start (None: need more; -1: unknown)."""
        if self.id_field is None:
            return self.sizes[None]
        stop = self.id_field.at + self.id_field.size
        if len(self._buffer) < stop:
            return None
        signed = self.id_field.type.startswith("i")
        value = int.from_bytes(self._buffer[self.id_field.at : stop], self.order, signed=signed)
        return self.sizes.get(value, -1)

    def _skip(self, count: int) -> None:
        """Throw away noise before the next sync bytes (one loss per run)."""
        if count <= 0:
            return
        if not self._lost:
            self.malformed += 1
            self._lost = True
        del self._buffer[:count]

    def _reject(self) -> None:
        """Throw away a false candidate's sync bytes (one loss each)."""
        self.malformed += 1
        self._lost = True
        del self._buffer[:1]

    def _take(self, size: int) -> bytes:
        frame = bytes(self._buffer[:size])
        del self._buffer[:size]
        self._lost = False
        return frame

    def feed(self, data: bytes) -> list[bytes]:
        """Add received bytes; return the whole frames they confirm."""
        self._buffer.extend(data)
        frames: list[bytes] = []
        keep = len(self.magic) - 1
        while True:
            start = self._buffer.find(self.magic)
            if start < 0:
                self._skip(len(self._buffer) - keep)
                return frames
            self._skip(start)
            size = self._size()
            if size is None or len(self._buffer) < size + len(self.magic):
                return frames
            if size < 0 or self._buffer[size : size + len(self.magic)] != self.magic:
                self._reject()
                continue
            frames.append(self._take(size))

    def flush(self) -> list[bytes]:
        """Return the frame the buffer holds exactly when the line went idle (if any)."""
        size = self._size()
        if size is not None and size == len(self._buffer) and self._buffer.startswith(self.magic):
            return [self._take(size)]
        return []


class FrameSkin:
    """The transport-independent part of a framed skin (a :class:`~recorder.live.LiveSkin`)."""

    def __init__(self, layout: SkinLayout, clock: RecorderClock) -> None:
        """Prepare; the link opens in ``__enter__``.

        Args:
            layout: The checked ``[skin]`` table.
            clock: The recorder's clock (receive times).
        """
        self.layout = layout
        self.clock = clock
        #: Says a finding, one line, when an action ends (:meth:`finish`): stderr.
        self.say: Callable[[str], object] = _to_stderr
        self._reader: SourceReader | None = None
        self._streams: list[_Stream] = []
        self._by_id: dict[int | None, _Stream] = {}
        self._types: dict[int | None, FrameType] = {frame.id: frame for frame in layout.frames}
        #: Malformed frames since :meth:`begin` whose type could not be told, by why.
        self._rejected: Counter[str] = Counter()
        self._overflow_base = 0
        self._framer_base = 0
        self._reset()

    def _open(self) -> SourceReader:
        """Open the link and return its (not yet started) reader."""
        raise NotImplementedError

    def _close(self) -> None:
        """Close the link (after the reader stopped)."""

    def _framer_malformed(self) -> int:
        """Return what the link dropped before decoding so far.

        Serial: sync losses of the byte stream; UDP: datagrams from another address than
        ``sender`` (or, without it, than the first address that sent a valid frame).
        """
        return 0

    def _link_findings(self) -> list[SkinFinding]:
        """Return the link's findings since :meth:`begin` (UDP: another sender)."""
        return []

    def _link_rejected(self) -> str:
        """Return what the link dropped as malformed since :meth:`begin`, a clause ('')."""
        return ""

    def origin(self) -> str:
        """Return where the skin's frames are taken from (``host:port``; '': not known)."""
        return ""

    def __enter__(self) -> Self:
        """Open the link and start reading."""
        self._reader = self._open()
        try:
            self._reader.start()
        except BaseException:
            self._close()
            raise
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Stop reading and close the link."""
        if self._reader is not None:
            self._reader.stop()
        self._close()

    @property
    def cells(self) -> int:
        """Return the number of cells."""
        return self.layout.cells

    @property
    def modalities(self) -> tuple[str, ...]:
        """Return the modalities the layout's frames carry (a :class:`SensingSkin`)."""
        return self.layout.modalities

    def _reset(self) -> None:
        self._streams = [_Stream(self.layout, frame) for frame in self.layout.frames]
        self._by_id = {stream.frame.id: stream for stream in self._streams}
        self._overflow_base = self._reader.overflowed if self._reader else 0
        self._framer_base = self._framer_malformed()
        self._rejected = Counter()

    def begin(self) -> None:
        """Start a new recording: fresh accounting and time base, drop what was queued.

        What was queued since the previous recording is not recorded, but its lowest latency
        per frame type seeds the new recording's clock offset.
        """
        drained = self._reader.drain() if self._reader is not None else []
        hints = self._lowest_offsets(drained)
        self._reset()
        for stream in self._streams:
            stream.offset_hint = hints.get(stream.frame.name)

    def _lowest_offsets(self, items: list[Received]) -> dict[str, int]:
        """Return, per frame type, the lowest receive-minus-sensor time among ``items``."""
        groups: dict[int, tuple[_Stream, list[bytes], list[int]]] = {}
        for item in items:
            stream = self._classify(item.payload)
            if stream is not None:
                group = groups.setdefault(id(stream), (stream, [], []))
                group[1].append(item.payload)
                group[2].append(item.receive_ns)
        lowest: dict[str, int] = {}
        for stream, payloads, receives in groups.values():
            sensor, _ = stream.times(np.frombuffer(b"".join(payloads), dtype=stream.dtype))
            lowest[stream.frame.name] = min(r - s for r, s in zip(receives, sensor, strict=True))
        return lowest

    def _classify(self, payload: bytes) -> _Stream | None:
        """Return the frame type of a frame (None: malformed, counted).

        A malformed frame is counted on its frame type's source, or the first one's when its
        type cannot be told; why it is malformed is kept for :meth:`findings`.
        """
        frame, why = classify(self.layout, payload, self._types)
        stream = self._streams[0] if frame is None else self._by_id[frame.id]
        if not why:
            return stream
        stream.malformed += 1
        if frame is None:
            self._rejected[why] += 1
        else:
            stream.rejected[why] += 1
        return None

    def _consume(self, items: list[Received]) -> list[SkinBlock]:
        groups: dict[int, tuple[_Stream, list[bytes], list[int]]] = {}
        for item in items:
            stream = self._classify(item.payload)
            if stream is not None:
                group = groups.setdefault(id(stream), (stream, [], []))
                group[1].append(item.payload)
                group[2].append(item.receive_ns)
        blocks: list[SkinBlock] = []
        for stream, payloads, receives in groups.values():
            frames = np.frombuffer(b"".join(payloads), dtype=stream.dtype)
            blocks += stream.consume(frames, receives)
        return blocks

    def poll(self) -> list[SkinBlock]:
        """Return the blocks completed since the last poll (does not wait).

        Raises:
            SourceLostError: The link was lost.
        """
        if self._reader is None:
            return []
        return self._consume(self._reader.drain())

    def finish(self) -> list[SkinBlock]:
        """Return everything still queued or open (the end of a recording).

        Each of the action's :meth:`findings` is said here, once, one line (:attr:`say`).
        """
        blocks = self.poll()
        for stream in self._streams:
            blocks += stream.flush()
        for finding in self.findings(rate_alone=False):
            self.say(finding.line)
        return sorted(blocks, key=lambda block: (block.receive_ns, block.modality))

    def findings(self, *, rate_alone: bool = True) -> list[SkinFinding]:
        """Return what was counted and left out since :meth:`begin` that needs a fix.

        One line each: another sender (the link's), the malformed frames by what was wrong
        with them, then per frame type a rate off its ``rate_hz`` (without ``rate_alone``:
        only as the cause of frames left out) or many frames stamped out of range
        (:meth:`_Stream.findings`).
        """
        found = self._link_findings()
        if malformed := self._malformed_finding():
            found.append(malformed)
        for stream, stats in zip(self._streams, self.stats(), strict=True):
            found += stream.findings(stats, rate_alone=rate_alone)
        return found

    def _malformed_finding(self) -> SkinFinding | None:
        """Return the malformed frames since :meth:`begin`, by kind, and the fix (one line)."""
        kinds = Counter(self._rejected)
        for stream in self._streams:
            kinds.update(stream.rejected)
        ranked = kinds.most_common()
        parts = [f"{n} {_plural(n, 'frame')} {why}" for why, n in ranked[:MALFORMED_KINDS]]
        if rest := sum(n for _, n in ranked[MALFORMED_KINDS:]):
            parts.append(f"{rest} of other kinds")
        if link := self._link_rejected():
            parts.append(link)
        if not parts:
            return None
        line = (
            f"{self.layout.name}: {', '.join(parts)} left out as malformed: check [skin] in "
            f"{self.layout.where} against the skin's firmware (cells, cell_stride, size, "
            "types, header)"
        )
        return SkinFinding(line)

    def _latest(self, modality: str) -> NDArray[np.float32] | None:
        for stream in self._streams:
            if modality in stream.latest:
                return stream.latest[modality]
        return None

    def total_force(self) -> float | None:
        """Return the total normal force, mean of the last 20 ms of samples, N (None: none)."""
        for stream in self._streams:
            if stream.totals:
                return float(np.mean(stream.totals))
        return None

    def nearest(self) -> float | None:
        """Return the latest smallest proximity reading, m (None: no proximity sensing)."""
        latest = self._latest("proximity")
        return None if latest is None else float(latest.min())

    def last_receive_ns(self) -> int | None:
        """Return the receive time of the latest frame (None: nothing yet)."""
        return None if self._reader is None else self._reader.last_receive_ns

    def stats(self) -> list[SourceStats]:
        """Return the accounting of each frame type since :meth:`begin`.

        A link's queue overflow and its sync losses cannot be told apart by frame type; they
        are counted on the first frame type's source.
        """
        out = []
        for position, stream in enumerate(self._streams):
            stats = stream.counter.stats()
            malformed = stream.malformed + stats.malformed
            overflowed = 0
            if position == 0:
                malformed += self._framer_malformed() - self._framer_base
                if self._reader is not None:
                    overflowed = self._reader.overflowed - self._overflow_base
            out.append(
                dataclasses.replace(
                    stats,
                    overflowed=overflowed,
                    malformed=malformed,
                    out_of_range=stats.out_of_range + stream.out_of_range,
                    origin=self.origin(),
                )
            )
        return out


class UdpSkin(FrameSkin):
    """A skin that sends its frames as UDP datagrams to the recorder (one frame a datagram).

    Datagrams are taken from one sender: ``[skin] sender`` (its host, and its port when
    given) or, without it, the first address that sends a valid frame; while that address
    sends, every other address's datagrams are left out (another skin or a replay sending to
    the same port would otherwise be mixed into the recording); when others have sent for
    :data:`REPIN_NS` with nothing from it in between, the next valid frame's address takes its
    place (a skin that restarted on another source port). Datagrams left out are counted per address
    (:attr:`foreign`, and as malformed of the first frame type's source), never written,
    never a sign of life, and said once per action (:meth:`findings`).
    """

    def __init__(self, layout: SkinLayout, clock: RecorderClock) -> None:
        """Prepare to listen on ``layout.bind``."""
        #: Datagrams left out: from another address than the skin's, since connecting.
        self.foreign = 0
        #: Datagrams by sender address (``host:port``), taken and left out, since connecting.
        self._taken: dict[str, int] = {}
        self._others: dict[str, int] = {}
        self._taken_base: dict[str, int] = {}
        self._others_base: dict[str, int] = {}
        self._lock = threading.Lock()  # the reader thread counts, the consumer reads
        #: The address frames are taken from, and since when another address has sent with
        #: nothing from it in between (reader thread only; None: it sent last).
        self._pinned = ""
        self._challenged_ns: int | None = None
        self._origin = ""
        host, _, port = layout.sender.partition(":")
        self._sender = (host, int(port) if port else None) if host else None
        super().__init__(layout, clock)
        self._socket: socket.socket | None = None
        self.address: tuple[str, int] = layout.bind
        self.receive_buffer = 0

    def _open(self) -> SourceReader:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            # A 1 kHz skin must not lose datagrams while the consumer is busy: a large buffer.
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, self.layout.receive_buffer)
            sock.bind(self.layout.bind)
        except OSError as err:
            sock.close()
            host, port = self.layout.bind
            msg = (
                f"{self.layout.where}: [skin] bind = '{host}:{port}': cannot listen ({err}); "
                "give a free port on an address of this computer"
            )
            raise RigError(msg) from err
        sock.settimeout(RECEIVE_TIMEOUT_S)
        self._socket = sock
        self.address = sock.getsockname()[:2]
        self.receive_buffer = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        clock = self.clock

        def receive() -> Received | None:
            try:
                data, origin = sock.recvfrom(65536)
            except TimeoutError:
                return None
            now = clock.now_ns()
            return Received(now, data) if self._admit(origin, data, now) else None

        return SourceReader(self.layout.name, receive)

    def _admit(self, origin: tuple[Any, ...], data: bytes, now_ns: int) -> bool:
        """Return whether a datagram is the skin's; count it by its sender either way."""
        host = _host(origin)
        address = f"{host}:{origin[1]}"
        if self._sender is not None:
            ours = host == self._sender[0] and self._sender[1] in {None, origin[1]}
        else:
            ours = self._pin(address, data, now_ns)
        with self._lock:
            book = self._taken if ours else self._others
            book[address] = book.get(address, 0) + 1
            if ours:
                self._origin = address
            else:
                self.foreign += 1
        return ours

    def _pin(self, address: str, data: bytes, now_ns: int) -> bool:
        """Without ``sender``: whether ``address`` is the skin's (the first to send a frame).

        Before any valid frame every datagram is taken (an invalid one is counted malformed
        where it is parsed). The pin moves only when other addresses have sent for
        :data:`REPIN_NS` with nothing from the pinned one in between: a reader held up reads
        the queued datagrams of both in the order they came, so a pause of the reader is no
        pause of the skin.
        """
        if address == self._pinned:
            self._challenged_ns = None
            return True
        if self._pinned:
            if self._challenged_ns is None:
                self._challenged_ns = now_ns
            if now_ns - self._challenged_ns <= REPIN_NS:
                return False
        if classify(self.layout, data, self._types)[1]:  # no valid frame: it pins nothing
            return not self._pinned
        self._pinned, self._challenged_ns = address, None
        return True

    def _reset(self) -> None:
        super()._reset()
        with self._lock:
            self._taken_base, self._others_base = dict(self._taken), dict(self._others)

    def _since_begin(self) -> tuple[dict[str, int], dict[str, int]]:
        """Return the datagrams taken and left out since :meth:`begin`, by sender address."""
        with self._lock:
            taken, others = dict(self._taken), dict(self._others)
        return _minus(taken, self._taken_base), _minus(others, self._others_base)

    def _framer_malformed(self) -> int:
        return self.foreign

    def origin(self) -> str:
        """Return the address of the latest datagram taken, ``host:port`` ('': none yet)."""
        return self._origin

    def _link_findings(self) -> list[SkinFinding]:
        """Return the datagrams of other senders since :meth:`begin`, one line.

        Without ``sender`` it is blocking: two senders' frames reached the skin's port, and
        which one is the skin only ``sender`` can say.
        """
        taken, others = self._since_begin()
        if not others and len(taken) <= 1:
            return []
        name, where = self.layout.name, self.layout.where
        said = [f"{n} taken from {a}" for a, n in taken.items()]
        said += [f"{n} left out from {a}" for a, n in others.items()]
        if self.layout.sender:
            line = (
                f"{name}: datagrams from another address than [skin] sender = "
                f"{self.layout.sender!r} in {where} ({', '.join(said)}): stop the other "
                "sender, or fix sender if it is the skin"
            )
            return [SkinFinding(line)]
        host, port = self.address
        addresses = [*taken, *others]
        line = (
            f"{name}: frames from {len(addresses)} senders at [skin] bind = '{host}:{port}' "
            f"({', '.join(said)}; frames are taken from the first to send); give [skin] "
            f'sender = "HOST:PORT" in {where} with the skin\'s address '
            f"({' or '.join(addresses)}), or stop the other sender"
        )
        short = f"{name} frames from {len(addresses)} senders ({', '.join(addresses)})"
        return [SkinFinding(line, blocking=True, short=short)]

    def silence_hint(self) -> str:
        """Say what arrived at the skin's address: nothing, or datagrams of another sender."""
        host, port = self.address
        if self.foreign and self.layout.sender:
            return (
                f"{self.foreign} datagrams came from another address than [skin] sender = "
                f"{self.layout.sender!r} and were dropped: is sender the skin's address?"
            )
        if self.foreign:
            return (
                f"{self.foreign} datagrams came from other addresses than {self._pinned}, the "
                "first to send a valid frame, and were left out: give [skin] sender = "
                f'"HOST:PORT" in {self.layout.where} with the skin\'s address'
            )
        if self.last_receive_ns() is None:
            return (
                f"no datagram arrived at [skin] bind = '{host}:{port}': does the skin send to "
                "this address and port?"
            )
        return ""

    def _close(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None


def _minus(counts: Mapping[str, int], base: Mapping[str, int]) -> dict[str, int]:
    """Return ``counts`` beyond ``base``, the keys that grew only (in ``counts``' order)."""
    return {key: n - base.get(key, 0) for key, n in counts.items() if n > base.get(key, 0)}


def _to_stderr(line: str) -> None:
    """Say one line to the operator: the recording goes on."""
    print(line, file=sys.stderr, flush=True)  # noqa: T201 (a finding for the operator)


def _host(address: tuple[Any, ...]) -> str:
    """Return a datagram's sender address in the form :func:`ipaddress.ip_address` prints."""
    try:
        return str(ipaddress.ip_address(address[0]))
    except ValueError:
        return str(address[0])


class SerialSkin(FrameSkin):
    """A skin that writes its frames to a serial line (pyserial), found by their sync bytes."""

    def __init__(self, layout: SkinLayout, clock: RecorderClock) -> None:
        """Prepare to open ``layout.device``."""
        super().__init__(layout, clock)
        self._port: Any = None
        self._framer = ByteFramer(layout)

    def _framer_malformed(self) -> int:
        framer: ByteFramer | None = getattr(self, "_framer", None)
        return 0 if framer is None else framer.malformed

    def _link_rejected(self) -> str:
        if lost := self._framer_malformed() - self._framer_base:
            return f"{lost} sync {'loss' if lost == 1 else 'losses'} of the byte stream"
        return ""

    def _open(self) -> SourceReader:
        import serial  # type: ignore[import-untyped]  # noqa: PLC0415 (optional: the serial extra)

        try:
            port = serial.Serial(self.layout.device, self.layout.baud, timeout=RECEIVE_TIMEOUT_S)
        except (serial.SerialException, OSError, ValueError) as err:
            msg = (
                f"{self.layout.where}: [skin] device = {self.layout.device!r}: cannot open it "
                f"({err}); give the skin's serial device and check its permissions"
            )
            raise RigError(msg) from err
        self._port = port
        framer, clock = self._framer, self.clock
        ready: deque[Received] = deque()

        def receive() -> Received | None:
            if not ready:
                data = port.read(max(1, port.in_waiting))
                now = clock.now_ns()
                frames = framer.feed(data) if data else framer.flush()
                ready.extend(Received(now, frame) for frame in frames)
            return ready.popleft() if ready else None

        return SourceReader(self.layout.name, receive)

    def _close(self) -> None:
        if self._port is not None:
            self._port.close()
            self._port = None


def _layout(section: Mapping[str, Any], where: str, transport: str) -> SkinLayout:
    """Return the layout a ``[skin]`` table describes, for the transport that was asked for.

    Raises:
        RigError: The table is malformed or names another transport (one line).
    """
    layout = parse_layout(section, where)
    if layout.transport != transport:
        msg = (
            f"{where}: [skin] transport = {layout.transport!r}: the "
            f"{'UDP' if transport == 'udp' else transport} skin needs '{transport}'"
        )
        raise RigError(msg)
    return layout


def udp_skin(section: Mapping[str, Any], clock: RecorderClock, where: str) -> UdpSkin:
    """Build the UDP skin a ``[skin]`` table describes (``transport = "udp"``; not yet open).

    Raises:
        RigError: The table is malformed (one line: file, key, value, fix).
    """
    return UdpSkin(_layout(section, where, "udp"), clock)


def serial_skin(section: Mapping[str, Any], clock: RecorderClock, where: str) -> SerialSkin:
    """Build the serial skin a ``[skin]`` table describes (``transport = "serial"``).

    Raises:
        RigError: The table is malformed (one line: file, key, value, fix).
    """
    return SerialSkin(_layout(section, where, "serial"), clock)
