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
"""

from __future__ import annotations

import dataclasses
import ipaddress
import socket
from collections import deque
from typing import TYPE_CHECKING, Any, Self

import numpy as np

from recorder.errors import RigError
from recorder.live._accounting import EARLY_TOLERANCE_NS, SourceCounter, SourceStats, Verdict
from recorder.live._framelayout import FrameType, SkinLayout, block_samples, parse_layout
from recorder.live._packer import BlockPacker
from recorder.live._reader import Received, SourceReader
from recorder.live._skin import window_samples

if TYPE_CHECKING:
    from collections.abc import Mapping
    from types import TracebackType

    from numpy.typing import NDArray

    from recorder.live._clock import RecorderClock
    from recorder.writing._stream import SkinBlock

#: How long a reader waits in one receive call, s (how fast it notices it is stopped).
RECEIVE_TIMEOUT_S = 0.05
#: A frame that carries one cell: how many newer samples may start before an incomplete
#: sample is given up (its missing cells are counted; the sample becomes a gap).
PENDING_SAMPLES = 3


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
                    continue
                number = (number or 0) * self.layout.cells + cells[i]  # noqa: PLW2901
            if not finite[i]:
                self.malformed += 1
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
        self._reader: SourceReader | None = None
        self._streams: list[_Stream] = []
        self._by_id: dict[int | None, _Stream] = {}
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
        ``sender``.
        """
        return 0

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
        """Return the frame type of a frame (None: malformed, counted)."""
        layout = self.layout
        if payload[: len(layout.magic)] != layout.magic:
            self._streams[0].malformed += 1
            return None
        stream = self._streams[0]
        if (field := layout.id_field) is not None:
            raw = payload[field.at : field.at + field.size]
            signed = field.type.startswith("i")
            found = self._by_id.get(int.from_bytes(raw, layout.byte_order, signed=signed))
            if found is None or len(raw) < field.size:
                stream.malformed += 1
                return None
            stream = found
        if len(payload) != stream.frame.size:
            stream.malformed += 1
            return None
        return stream

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
        """Return everything still queued or open (the end of a recording)."""
        blocks = self.poll()
        for stream in self._streams:
            blocks += stream.flush()
        return sorted(blocks, key=lambda block: (block.receive_ns, block.modality))

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
                )
            )
        return out


class UdpSkin(FrameSkin):
    """A skin that sends its frames as UDP datagrams to the recorder (one frame a datagram)."""

    def __init__(self, layout: SkinLayout, clock: RecorderClock) -> None:
        """Prepare to listen on ``layout.bind``."""
        #: Datagrams from another address than the layout's ``sender``, dropped.
        self.foreign = 0
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
        clock, sender = self.clock, self.layout.sender

        def receive() -> Received | None:
            try:
                if not sender:
                    return Received(clock.now_ns(), sock.recv(65536))
                data, origin = sock.recvfrom(65536)
            except TimeoutError:
                return None
            if _host(origin) != sender:  # not the skin: dropped, and no sign of life either
                self.foreign += 1
                return None
            return Received(clock.now_ns(), data)

        return SourceReader(self.layout.name, receive)

    def _framer_malformed(self) -> int:
        return self.foreign

    def silence_hint(self) -> str:
        """Say what arrived at the skin's address: nothing, or datagrams of another sender."""
        host, port = self.address
        if self.foreign:
            return (
                f"{self.foreign} datagrams came from another address than [skin] sender = "
                f"{self.layout.sender!r} and were dropped: is sender the skin's address?"
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
