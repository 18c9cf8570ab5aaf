"""The virtual lab's skin: the simulated skin sent as frames in the lab's own layout.

:func:`serve_skin` sends the simulated skin's samples (``world.skin_at``) as UDP datagrams or
serial bytes in exactly the layout of the rig configuration's ``[skin]`` table, at each frame
type's rate, with sequence counters and sensor stamps, so a lab rehearses its own
configuration and the tests exercise the real receiving code. Faults are injected on request
(dropped, duplicated, reordered, truncated frames, a stall, a sender that stops) and reported
exactly (:class:`InjectedFaults`), so tests can compare the recorder's counts with them.

Python cannot sleep 1 ms precisely: the sender wakes every few milliseconds and sends every
frame due since the last wake-up (their stamps and counters are those of their nominal times).
"""

from __future__ import annotations

import contextlib
import os
import socket
import threading
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol
from urllib.parse import urlsplit

import numpy as np

from recorder.errors import RigError
from recorder.live import FIELD_TYPES, FrameType, SkinLayout, parse_layout

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator, Mapping

    from numpy.typing import NDArray

#: Shortest sleep of the sending loop, s (a wake-up sends every frame due since the last).
MIN_SLEEP_S = 0.002


class SkinWorld(Protocol):
    """What the sender reads: the controller's clock and the skin's latest samples."""

    def controller_ns(self) -> int:
        """Return the controller's time, ns."""
        ...

    def skin_at(self, modality: str, controller_ns: int) -> NDArray[np.float64] | None:
        """Return the latest sample of ``modality`` (cells, values); None: none yet."""
        ...


@dataclass(frozen=True, slots=True)
class SkinFaults:
    """Faults to inject into one frame type's frames (tests), at fixed frame numbers.

    The ``k``-th fault is injected at frame ``start + k * spacing`` of the frame type (frames
    of one cell count one by one): first the drops, then the duplicates, the reordered pairs
    (a frame sent after the next one) and the truncated frames; then the stall.

    Attributes:
        frame: The frame type (its ``[skin.frames.<name>]``; empty: the first).
        drop: Frames never sent.
        duplicate: Frames sent twice.
        reorder: Pairs of consecutive frames sent in swapped order.
        truncate: Frames cut to half their length (malformed; a sync loss on serial).
        stall_s: The link is silent for this long after the last of the faults above (the
            frames due meanwhile are never sent), s.
        stop_after_s: Nothing is sent after this long, s (0: never stop).
        start: Frame number of the first fault.
        spacing: Frames between two faults.
        at_action_s: Number the frames (for ``start`` and the stall) from this long after the
            first announced action began instead of from the sender's start, so that the
            faults hit a recording (negative: from the start).
    """

    frame: str = ""
    drop: int = 0
    duplicate: int = 0
    reorder: int = 0
    truncate: int = 0
    stall_s: float = 0.0
    stop_after_s: float = 0.0
    start: int = 20
    spacing: int = 10
    at_action_s: float = -1.0

    def check(self) -> None:
        """Refuse impossible faults.

        Raises:
            RigError: A negative count or time, or faults closer than 2 frames.
        """
        counts = (self.drop, self.duplicate, self.reorder, self.truncate, self.start)
        if min(counts) < 0 or min(self.stall_s, self.stop_after_s) < 0 or self.spacing < 2:  # noqa: PLR2004
            msg = f"skin faults {self}: give counts and times >= 0 and spacing >= 2"
            raise RigError(msg)

    def plan(self) -> dict[int, str]:
        """Return the fault of every affected frame number."""
        kinds = (
            ["drop"] * self.drop
            + ["duplicate"] * self.duplicate
            + ["reorder"] * self.reorder
            + ["truncate"] * self.truncate
        )
        return {self.start + k * self.spacing: kind for k, kind in enumerate(kinds)}

    @property
    def stall_at(self) -> int:
        """Return the frame number where the stall starts."""
        count = self.drop + self.duplicate + self.reorder + self.truncate
        return self.start + count * self.spacing


@dataclass(frozen=True, slots=True)
class InjectedFaults:
    """What the sender really did (all counts in frames of the faulted frame type).

    Attributes:
        dropped: Frames never sent.
        duplicated: Frames sent twice.
        reordered: Pairs sent in swapped order.
        truncated: Frames sent cut short.
        stalled: Frames of each frame type not sent during the stall, by frame type name.
        stall_start_ns: Controller time the stall began (0: no stall yet).
        stopped: Whether the sender stopped sending (``stop_after_s``).
        sent: Frames sent of each frame type (duplicates included), by name.
    """

    dropped: int = 0
    duplicated: int = 0
    reordered: int = 0
    truncated: int = 0
    stalled: Mapping[str, int] = field(default_factory=dict)
    stall_start_ns: int = 0
    stopped: bool = False
    sent: Mapping[str, int] = field(default_factory=dict)


class _Encoder:
    """Builds the frames of one frame type from SI samples (the inverse of parsing)."""

    def __init__(self, layout: SkinLayout, frame: FrameType) -> None:
        self.layout = layout
        self.frame = frame
        base = frame.dtype(layout.byte_order, layout.cells)
        fields: dict[str, Any] = dict(base.fields or {})
        names = list(fields)
        formats = [fields[name][0] for name in names]
        offsets = [fields[name][1] for name in names]
        if layout.magic:
            names.append("magic")
            formats.append(("u1", (len(layout.magic),)))
            offsets.append(0)
        if layout.id_field is not None:
            order = "<" if layout.byte_order == "little" else ">"
            names.append("id")
            formats.append(order + FIELD_TYPES[layout.id_field.type])
            offsets.append(layout.id_field.at)
        spec = {"names": names, "formats": formats, "offsets": offsets, "itemsize": frame.size}
        self.dtype: np.dtype[np.void] = np.dtype(spec)  # type: ignore[call-overload]
        self.per_frame = 1 if frame.cell is not None else layout.cells

    def _raw(self, values: NDArray[np.float64], kind: str, scale: float, offset: float) -> Any:  # noqa: ANN401
        raw = (values - offset) / scale
        code = np.dtype(FIELD_TYPES[kind])
        if code.kind in "iu":
            info = np.iinfo(code)
            return np.clip(np.rint(raw), info.min, info.max).astype(code)
        return raw.astype(code)

    def encode(self, numbers: range, samples: Mapping[str, NDArray[np.float64]]) -> bytes:
        """Return the frames of sample numbers ``numbers`` (``samples``: (n, cells, count))."""
        frame, cells = self.frame, self.layout.cells
        rows = len(numbers) * (cells // self.per_frame)
        out = np.zeros(rows, dtype=self.dtype)
        index = np.repeat(np.asarray(numbers, dtype=np.int64), cells // self.per_frame)
        if self.layout.magic:
            out["magic"] = np.frombuffer(self.layout.magic, np.uint8)
        if self.layout.id_field is not None:
            out["id"] = frame.id
        if frame.sequence is not None:
            out["sequence"] = index % frame.sequence.modulo
        if frame.stamp is not None:
            ticks = (index * frame.period_ns) // frame.stamp.unit_ns
            out["stamp"] = ticks % frame.stamp.field.modulo
        if frame.cell is not None:
            out["cell"] = np.tile(np.arange(cells), len(numbers))
        for item in frame.modalities:
            values = samples[item.modality]
            if frame.cell is not None:
                values = values.reshape(rows, 1, item.count)
            raw = self._raw(values, item.type, item.scale, item.offset)
            for cell in range(self.per_frame):
                out[f"{item.modality}_{cell}"] = raw[:, cell, :]
        return out.tobytes()


class FrameLink(Protocol):
    """Where a skin server's frames go."""

    def send(self, frames: list[bytes]) -> None:
        """Send frames (each one whole frame), in order."""
        ...

    def close(self) -> None:
        """Close the link."""
        ...


class _Link:
    """Where frames go: UDP datagrams to an address, or bytes to a serial line or descriptor."""

    def __init__(self, url: str, layout: SkinLayout) -> None:
        parts = urlsplit(url)
        self._socket: socket.socket | None = None
        self._fd: int | None = None
        self._port: Any = None
        self.datagrams = parts.scheme == "udp"
        if parts.scheme == "udp" and parts.hostname and parts.port is not None:
            self._socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self._target = (parts.hostname, parts.port)
        elif parts.scheme == "fd" and parts.netloc.isdigit():
            self._fd = int(parts.netloc)
        elif parts.scheme == "serial" and parts.path:
            import serial  # type: ignore[import-untyped]  # noqa: PLC0415 (the serial extra)

            self._port = serial.Serial(parts.path, layout.baud)
        else:
            msg = (
                f"skin url {url!r}: give udp://127.0.0.1:PORT (where the recorder listens), "
                "serial:///dev/DEVICE or fd://N (an open descriptor, tests)"
            )
            raise RigError(msg)

    def send(self, frames: list[bytes]) -> None:
        """Send frames (one datagram each over UDP; one write on a byte stream)."""
        if self._socket is not None:
            for frame in frames:
                self._socket.sendto(frame, self._target)
        elif self._fd is not None:
            os.write(self._fd, b"".join(frames))
        elif self._port is not None:
            self._port.write(b"".join(frames))

    def close(self) -> None:
        """Close what the link opened (a given descriptor stays open)."""
        if self._socket is not None:
            self._socket.close()
        if self._port is not None:
            self._port.close()


class SkinServer:
    """Sends a simulated skin's frames from a thread; see :func:`serve_skin`."""

    def __init__(  # noqa: PLR0917 (the sender and its two optional hooks)
        self,
        world: SkinWorld,
        link: FrameLink,
        layout: SkinLayout,
        faults: SkinFaults,
        action_start: Callable[[], int | None] | None = None,
        on_fault: Callable[..., object] | None = None,
    ) -> None:
        """Prepare; :meth:`start` starts sending.

        Args:
            world: What is sent.
            link: Where.
            layout: The frames' layout.
            faults: Faults to inject.
            action_start: Controller time the first action began (None: not yet), for
                ``faults.at_action_s``.
            on_fault: Called as ``on_fault(fault, controller_ns, **details)`` per fault.
        """
        names = [frame.name for frame in layout.frames]
        if faults.frame and faults.frame not in names:
            msg = f"skin faults: frame {faults.frame!r} is no frame type; give one of {names}"
            raise RigError(msg)
        faults.check()
        self.world = world
        self.layout = layout
        self.faults = faults
        self._link = link
        self._encoders = [_Encoder(layout, frame) for frame in layout.frames]
        self._faulted = faults.frame or names[0]
        self._plan = faults.plan()
        self._next = dict.fromkeys(names, 0)
        self._held: bytes | None = None
        self._counts: dict[str, int] = dict.fromkeys(
            ("dropped", "duplicated", "reordered", "truncated"), 0
        )
        self._stalled = dict.fromkeys(names, 0)
        self._sent = dict.fromkeys(names, 0)
        self._stall: tuple[int, int] | None = None
        self._stopped = False
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="atikt-skin-server", daemon=True)
        self._origin = 0
        self.error: BaseException | None = None
        self._action_start = action_start
        self._on_fault = on_fault
        self._base: int | None = 0 if faults.at_action_s < 0 else None

    def start(self, *, thread: bool = True) -> None:
        """Start sending (sensor time and counters start at 0 now).

        Args:
            thread: Send from the server's own thread; False: the caller calls
                :meth:`send_due` (the in-process virtual lab, stepped on its own clock).
        """
        self._origin = self.world.controller_ns()
        if thread:
            self._thread.start()

    def stop(self) -> None:
        """Stop sending and wait for the thread."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(5.0)

    @property
    def injected(self) -> InjectedFaults:
        """Return what was injected and sent so far."""
        with self._lock:
            return InjectedFaults(
                **self._counts,
                stalled=dict(self._stalled),
                stall_start_ns=self._stall[0] if self._stall else 0,
                stopped=self._stopped,
                sent=dict(self._sent),
            )

    def _samples(self, encoder: _Encoder, numbers: range) -> dict[str, NDArray[np.float64]]:
        """The world's values of each frame's modalities, in the layout's cells.

        A layout of another number of cells than the simulated skin's (7) gets the simulated
        cells in turn (cell ``i`` is simulated cell ``i mod 7``): a lab rehearses its own
        skin's layout, whatever its size.
        """
        frame, cells = encoder.frame, self.layout.cells
        out: dict[str, NDArray[np.float64]] = {}
        for item in frame.modalities:
            rows = np.zeros((len(numbers), cells, item.count))
            for row, number in enumerate(numbers):
                found = self.world.skin_at(item.modality, self._origin + number * frame.period_ns)
                if found is not None:
                    simulated = np.asarray(found, dtype=np.float64).reshape(-1, item.count)
                    rows[row] = simulated[np.arange(cells) % simulated.shape[0]]
            out[item.modality] = rows
        return out

    def _relative(self, encoder: _Encoder, number: int) -> int | None:
        """Return a frame's number for the fault plan (None: faults not armed yet)."""
        if self._base is None and encoder.frame.name == self._faulted:
            began = self._action_start() if self._action_start is not None else None
            at = self._origin + number * encoder.frame.period_ns
            if began is not None and at >= began + self.faults.at_action_s * 1e9:
                self._base = number
        return None if self._base is None else number - self._base

    def _report(self, fault: str, encoder: _Encoder, number: int, **details: object) -> None:
        if self._on_fault is not None:
            at = self._origin + number * encoder.frame.period_ns
            self._on_fault(fault, at, frame=encoder.frame.name, number=number, **details)

    def _stalling(self, encoder: _Encoder, number: int) -> bool:
        """Whether frame ``number`` falls in the stall (which starts at its frame)."""
        faults, frame = self.faults, encoder.frame
        if faults.stall_s <= 0:
            return False
        relative = self._relative(encoder, number) if frame.name == self._faulted else None
        if self._stall is None and relative is not None and relative >= faults.stall_at:
            start = self._origin + number * frame.period_ns
            self._stall = (start, start + round(faults.stall_s * 1e9))
            self._report("stall", encoder, number, seconds=faults.stall_s)
        if self._stall is None:
            return False
        t = self._origin + number * frame.period_ns
        return self._stall[0] <= t < self._stall[1]

    def _fault(self, frames: list[bytes], out: list[bytes], number: int, encoder: _Encoder) -> None:
        """Send (into ``out``) the frames of one sample, with the planned faults."""
        names = {"duplicate": "duplicated", "truncate": "truncated", "drop": "dropped"}
        relative = self._relative(encoder, number)
        for position, item in enumerate(frames):
            kind = None if relative is None else self._plan.get(relative * len(frames) + position)
            if kind is not None:
                self._report(kind, encoder, number, position=position)
            if kind is not None and kind != "reorder":
                self._counts[names[kind]] += 1
            if kind == "drop":
                continue
            if kind == "reorder":
                self._held = item  # sent after the next frame
                continue
            out.append(item[: len(item) // 2] if kind == "truncate" else item)
            if kind == "duplicate":
                out.append(item)
            if self._held is not None:
                out.append(self._held)
                self._held = None
                self._counts["reordered"] += 1

    def _due(self, encoder: _Encoder, now: int) -> list[bytes]:
        """Return the frames of ``encoder`` due by controller time ``now``."""
        frame = encoder.frame
        first, stop = self._next[frame.name], (now - self._origin) // frame.period_ns + 1
        if stop <= first:
            return []
        self._next[frame.name] = stop
        numbers = range(first, stop)
        data = encoder.encode(numbers, self._samples(encoder, numbers))
        size = frame.size
        chunks = [data[i : i + size] for i in range(0, len(data), size)]
        per_sample = len(chunks) // len(numbers)
        out: list[bytes] = []
        for row, number in enumerate(numbers):
            sample = chunks[row * per_sample : (row + 1) * per_sample]
            if self._stalling(encoder, number):
                self._stalled[frame.name] += len(sample)
            elif frame.name == self._faulted and self._plan:
                self._fault(sample, out, number, encoder)
            else:
                out += sample
        return out

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                now = self.world.controller_ns()
                if self._stopping(now):
                    self._stop.wait(MIN_SLEEP_S * 10)
                    continue
                self.send_due(now)
                self._stop.wait(self._sleep(now))
        except BaseException as err:  # noqa: BLE001 (reported by serve_skin's exit)
            self.error = err

    def _stopping(self, now: int) -> bool:
        """Return whether the sender has stopped by controller time ``now`` (``stop_after_s``).

        The stop is a fault like the others: reported once, as it happens, so that it is
        printed, logged as an event and counted in the summary.
        """
        stop_after = self.faults.stop_after_s
        if stop_after <= 0 or now - self._origin < stop_after * 1e9:
            return False
        with self._lock:
            first, self._stopped = not self._stopped, True
            sent = sum(self._sent.values())
        if first and self._on_fault is not None:
            self._on_fault("stop", now, frame=self._faulted, after_s=stop_after, sent=sent)
        return True

    def send_due(self, now: int) -> None:
        """Send every frame due by controller time ``now`` (the sending thread's step).

        The in-process virtual lab calls it from its own loop instead of :meth:`start`.
        """
        for encoder in self._encoders:
            with self._lock:
                frames = self._due(encoder, now)
                self._sent[encoder.frame.name] += len(frames)
            if frames:
                self._link.send(frames)

    def _sleep(self, now: int) -> float:
        """Return the time until the next frame is due (at least :data:`MIN_SLEEP_S`), s."""
        due = min(
            self._origin + self._next[e.frame.name] * e.frame.period_ns for e in self._encoders
        )
        return max(MIN_SLEEP_S, (due - now) / 1e9)


@contextlib.contextmanager
def serve_skin(
    world: SkinWorld,
    url: str,
    skin_section: Mapping[str, Any],
    faults: SkinFaults | None = None,
    *,
    where: str = "the virtual lab's [skin] table",
    action_start: Callable[[], int | None] | None = None,
    on_fault: Callable[..., object] | None = None,
) -> Iterator[SkinServer]:
    """Send the world's skin as frames laid out as ``skin_section`` describes.

    Args:
        world: What is sent (the virtual lab's :class:`~recorder.virtuallab.VirtualWorld`).
        url: Where: ``udp://127.0.0.1:PORT`` (where the recorder listens),
            ``serial:///dev/DEVICE``, or ``fd://N`` (an open descriptor, e.g. a
            pseudo-terminal's master side in tests).
        skin_section: The rig configuration's ``[skin]`` table (its link keys are ignored:
            ``url`` says where to send).
        faults: Faults to inject (None: none).
        where: The configuration file, for messages.
        action_start: Controller time the first action began (``faults.at_action_s``).
        on_fault: Called as ``on_fault(fault, controller_ns, **details)`` per fault injected.

    Yields:
        The running server (``injected``: what it did so far).

    Raises:
        RigError: The table is malformed, the url is not understood, or sending failed.
    """
    layout = parse_layout(skin_section, where)
    link = _Link(url, layout)
    server = SkinServer(world, link, layout, faults or SkinFaults(), action_start, on_fault)
    try:
        server.start()
        yield server
    finally:
        server.stop()
        link.close()
    if server.error is not None:
        msg = f"skin server to {url}: sending failed ({server.error})"
        raise RigError(msg) from server.error
