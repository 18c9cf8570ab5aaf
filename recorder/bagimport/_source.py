"""Reading a lab's bags as one stream of typed samples (rosbags' ``AnyReader``).

Messages are read in log-time order, one at a time (memory does not grow with the bag), and
each mapped topic's messages become samples: a stamp in integer ns on the map's clock, the
receive time, and values. A skin message may carry several samples (a driver that batches,
e.g. 22 vibration samples per 100 Hz message): their stamps are the message stamp plus the
exact integer offsets of :meth:`SkinField.offsets_ns`, or, for a driver that stamps messages
when they arrive (``timing = "rate"``), from the sensor's rate (:mod:`._timing`). A message
may carry one cell or, through a field indexed by ``{cell}``, several; a modality's values may
come from several fields side by side. Stamps of one topic must increase: a stamp that goes
back is refused with the topic, the time and the fix, never re-sorted.
"""

from __future__ import annotations

import bisect
import collections
from dataclasses import dataclass, field
from operator import attrgetter
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import Nodetype
from rosbags.rosbag1 import ReaderError as Ros1ReaderError
from rosbags.rosbag2 import ReaderError as Ros2ReaderError
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore

from recorder.bagimport import _bounded
from recorder.bagimport._bounded import MAX_MESSAGE_BYTES
from recorder.bagimport._pack import Series
from recorder.bagimport._ros1 import StreamingReader
from recorder.bagimport._timing import MessageCount, Timeline
from recorder.errors import BagImportError

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator, Sequence

    from numpy.typing import NDArray
    from rosbags.interfaces import Connection
    from rosbags.typesys.store import Typestore

    from recorder.bagimport._topicmap import FieldPart, SkinField, TopicMap

_NS_PER_S = 1_000_000_000
JOINT_TYPE = "sensor_msgs/msg/JointState"
POSE_TYPE = "geometry_msgs/msg/PoseStamped"
ANNOTATION_TYPE = "std_msgs/msg/String"
READ_ERRORS = (
    AnyReaderError,
    Ros1ReaderError,
    Ros2ReaderError,
    SerdeError,
    TypesysError,
    OSError,
    AssertionError,  # rosbags asserts on some malformed records
    KeyError,
    IndexError,
    ValueError,
    EOFError,
    UnicodeDecodeError,
    MemoryError,
)


def message_stamp(message: Any, topic: str, clock: str, receive_ns: int) -> int:  # noqa: ANN401
    """Return a message's stamp on the map's clock.

    Raises:
        BagImportError: The clock is ``header`` and the message has none.
    """
    if clock == "log":
        return receive_ns
    header = getattr(message, "header", None)
    if header is None:
        msg = (
            f"topic {topic} ({message.__msgtype__}) has no header.stamp; "
            'set [time] stamps = "log" in the topic map to use the receive time'
        )
        raise BagImportError(msg)
    return int(header.stamp.sec) * _NS_PER_S + int(header.stamp.nanosec)


@dataclass(slots=True)
class _Buffer:
    """Messages of one topic kept until the windows that reach them are written.

    Stamps of a topic must increase: a repeated stamp is dropped (counted), a stamp that goes
    back is refused. Values are kept as decoded and converted in bulk when a window is cut.
    """

    topic: str
    fix: str
    stamps: list[int] = field(default_factory=list)
    receives: list[int] = field(default_factory=list)
    last: int | None = None
    repeated: int = 0

    def accept(self, stamp: int, receive_ns: int) -> bool:
        """Record a message's stamp; return False for a repeated stamp (dropped).

        Raises:
            BagImportError: The stamp precedes the previous one.
        """
        last = self.last
        if last is not None and stamp <= last:
            if stamp == last:
                self.repeated += 1
                return False
            msg = (
                f"topic {self.topic}: stamp {stamp} ns precedes the previous message's {last} ns; "
                f"stamps are never re-sorted: {self.fix}"
            )
            raise BagImportError(msg)
        self.last = stamp
        self.stamps.append(stamp)
        self.receives.append(receive_ns)
        return True

    def span(self, lo: int, hi: int, before: int, after: int) -> tuple[int, int]:
        """Return the indices of the messages with samples in ``[lo, hi)``.

        A message's samples lie in ``[stamp + before, stamp + after]``.
        """
        return bisect.bisect_left(self.stamps, lo - after), bisect.bisect_left(
            self.stamps, hi - before
        )

    def cut(self, index: int) -> None:
        """Forget the messages before ``index``."""
        del self.stamps[:index]
        del self.receives[:index]


def _stack(values: list[Any], count: int, topic: str, path: str) -> NDArray[np.float64]:
    """Return decoded field values of ``count`` messages as a (messages, size) float64 array.

    A message whose field holds another number of values than most of the range's (a
    truncated or corrupted message among good ones) becomes a row of NaN: the skin's rows are
    then dropped and counted where it lies (``dropped_rows``), never the whole bag.

    Raises:
        BagImportError: The field's values are not numbers.
    """
    try:
        return np.asarray(values, dtype=np.float64).reshape(count, -1)
    except ValueError:
        pass
    try:
        rows = [np.asarray(v, dtype=np.float64).reshape(-1) for v in values]
    except (TypeError, ValueError) as err:
        msg = f"topic {topic}: field {path!r} holds values that are not numbers; map another"
        raise BagImportError(msg) from err
    sizes = collections.Counter(row.size for row in rows)
    size = max(sizes, key=lambda n: (sizes[n], n))  # the most common (ties: the longest)
    out = np.full((count, size), np.nan)
    for index, row in enumerate(rows):
        if row.size == size:
            out[index] = row
    return out


def _stack_bytes(
    values: list[bytes], dtype: np.dtype[Any], count: int, topic: str, path: str
) -> NDArray[np.float64]:
    """Return fields kept as bytes (:meth:`SkinTopic.push_fields`) as :func:`_stack` does."""
    if len(set(map(len, values))) > 1 or len(values[0]) % dtype.itemsize:
        whole = [v if len(v) % dtype.itemsize == 0 else b"" for v in values]  # a cut-off field
        return _stack([np.frombuffer(v, dtype) for v in whole], count, topic, path)
    return np.frombuffer(b"".join(values), dtype).astype(np.float64).reshape(count, -1)


@dataclass(slots=True)
class SkinTopic:
    """One skin topic: the modalities it carries for one cell, or for several, buffered.

    A message carries one cell (a topic per cell) or every cell (a field indexed by
    ``{cell}``). Each distinct message field is kept once, whatever reads it.
    """

    topic: str
    cell: int
    fields: tuple[SkinField, ...]
    widths: dict[str, int] = field(default_factory=dict)
    buffer: _Buffer = field(init=False)
    values: list[list[Any]] = field(init=False)
    getters: list[Any] = field(init=False)
    offsets: dict[str, NDArray[np.int64]] = field(default_factory=dict)
    reach: tuple[int, int] = (0, 0)
    #: The fields' dtypes when their bytes are kept (:meth:`push_fields`), else None.
    dtypes: tuple[np.dtype[Any], ...] | None = None
    #: Per spec of :attr:`fields`: the cells it reads here, as (output column, lab cell id).
    cells: tuple[tuple[tuple[int, int], ...], ...] = ()
    #: The distinct message fields read (a decoder returns their bytes in this order).
    paths: tuple[str, ...] = field(init=False)
    #: Modalities stamped from their rate (``timing = "rate"``), by spec index.
    timelines: dict[int, Timeline] = field(default_factory=dict)
    #: The frame counter's index in :attr:`paths`, by spec index (``counter`` of the map).
    counters: dict[int, int] = field(default_factory=dict)
    #: A message counter of a topic stamped by its messages (``timing = "message"``), and
    #: its index in :attr:`paths` (None: the topic has none, or its counter counts frames).
    counted: tuple[MessageCount, int] | None = None

    def __post_init__(self) -> None:
        """Precompute field getters, each modality's sample offsets and timelines."""
        batched = ", ".join(f"[skin.{s.modality}]" for s in self.fields)
        fix = (
            f"if the driver batches samples, set samples_per_message and rate_hz of {batched}; "
            'otherwise fix the driver\'s stamps or use [time] stamps = "log"'
        )
        self.buffer = _Buffer(self.topic, fix)
        if not self.cells:
            self.cells = tuple(((self.cell, self.cell),) for _ in self.fields)
        counters = [s.counter for s in self.fields if s.counter]  # read for the accounting too
        read = [p.path for s in self.fields for p in s.fields]
        self.paths = tuple(dict.fromkeys([*read, *counters]))
        self.values = [[] for _ in self.paths]
        self.getters = [attrgetter(path) for path in self.paths]
        slack = 0
        for i, spec in enumerate(self.fields):
            self.offsets[spec.modality] = np.asarray(spec.offsets_ns(), dtype=np.int64)
            if spec.timing == "rate" and spec.period_ns is not None:
                count = spec.samples_per_message
                stamped = count - 1 if spec.batch_stamp == "last" else 0
                where = f"topic {self.topic} [skin.{spec.modality}]"
                timeline = Timeline(where, spec.period_ns, count, stamped, spec.counter_modulo)
                self.timelines[i] = timeline
                if spec.counter:
                    self.counters[i] = self.paths.index(spec.counter)
                # fitted stamps lie below the message stamps by the latency (< a frame or two)
                slack = max(slack, 2 * round(spec.period_ns * count))
        message_counters = [s for s in self.fields if s.counter and s.timing != "rate"]
        if message_counters and not self.counters:
            first = message_counters[0]
            period = round(first.period_ns * first.samples_per_message) if first.period_ns else 0
            tally = MessageCount(first.counter_modulo, period)
            self.counted = (tally, self.paths.index(first.counter))
        every = np.concatenate(list(self.offsets.values()))
        self.reach = (int(every.min()) - slack, int(every.max()) + slack)

    @property
    def sequence(self) -> tuple[str, int] | None:
        """Return the topic's message counter and its modulo (the first the map names), or None."""
        return next(((s.counter, s.counter_modulo) for s in self.fields if s.counter), None)

    @property
    def repeated(self) -> int:
        """Return the messages dropped for a repeated stamp."""
        return self.buffer.repeated

    def push(self, message: Any, stamp: int, receive_ns: int) -> None:  # noqa: ANN401
        """Keep one message's values.

        Raises:
            BagImportError: Its stamp precedes the previous one.
        """
        if self.buffer.accept(stamp, receive_ns):
            self._place(stamp, lambda path: int(self.getters[path](message)))
            if self.dtypes is None:
                for getter, values in zip(self.getters, self.values, strict=True):
                    values.append(getter(message))
                return
            for getter, values, dtype in zip(self.getters, self.values, self.dtypes, strict=True):
                values.append(np.asarray(getter(message), dtype=dtype).tobytes())

    def push_fields(self, fields: Sequence[Any], stamp: int, receive_ns: int) -> None:
        """Keep one message's fields as read from its bytes (:attr:`dtypes` is set).

        ``fields``: a decoder's ``(sec, nanosec, field bytes...)`` of :attr:`paths`.

        Raises:
            BagImportError: Its stamp precedes the previous one.
        """
        if self.buffer.accept(stamp, receive_ns):
            dtypes = self.dtypes or ()
            self._place(stamp, lambda path: int(np.frombuffer(fields[2 + path], dtypes[path])[0]))
            for values, data in zip(self.values, fields[2:], strict=True):
                values.append(data)

    def _place(self, stamp: int, counter: Callable[[int], int]) -> None:
        """Place an accepted message on the timelines of the modalities stamped by rate.

        ``counter``: reads the message's field ``paths[i]`` as an integer (a frame counter).
        """
        for index, timeline in self.timelines.items():
            path = self.counters.get(index)
            timeline.push(stamp, None if path is None else counter(path))
        if self.counted is not None:
            self.counted[0].push(stamp, counter(self.counted[1]))

    def _width(self, spec: SkinField, size: int) -> int:
        """Return the values per sample, checked against the map and earlier messages."""
        count = spec.samples_per_message
        width = size // count if size % count == 0 else 0
        expected = spec.width or self.widths.get(spec.modality, width)
        if width == 0 or width != expected:
            msg = (
                f"topic {self.topic}: field {spec.field!r} has {size} values, not {count} samples "
                f"x {expected or 'n'} values; fix width or samples_per_message of "
                f"[skin.{spec.modality}] in the topic map"
            )
            raise BagImportError(msg)
        self.widths[spec.modality] = width
        return width

    def _raw(self, path: int, first: int, last: int) -> NDArray[np.float64]:
        """Return a field of messages ``first:last`` as a (messages, size) float64 array."""
        count, values = last - first, self.values[path][first:last]
        if self.dtypes is None:
            return _stack(values, count, self.topic, self.paths[path])
        return _stack_bytes(values, self.dtypes[path], count, self.topic, self.paths[path])

    def _cell_values(
        self, spec: SkinField, lab_cell: int, raws: dict[int, NDArray[np.float64]]
    ) -> NDArray[np.float64]:
        """Return one cell's values of a modality, (messages, values), its fields side by side.

        Raises:
            BagImportError: An indexed element is beyond the field, or a field's values do
                not split into the message's samples.
        """
        parts = spec.fields
        stride = max(spec.width // len(parts), 1)
        pieces = []
        for part in parts:
            raw = raws[self.paths.index(part.path)]
            element = part.element(lab_cell)
            if element is not None:
                if (element + 1) * stride > raw.shape[1]:
                    key = "cells of [skin]" if part.per_cell else f"field of [skin.{spec.modality}]"
                    msg = (
                        f"topic {self.topic}: field {part.path!r} has {raw.shape[1]} values, no "
                        f"element {element} (x {stride}); fix the {key} in the topic map"
                    )
                    raise BagImportError(msg)
                raw = raw[:, element * stride : (element + 1) * stride]
            pieces.append(raw)
        if len(pieces) == 1:
            return pieces[0]
        count, samples = pieces[0].shape[0], spec.samples_per_message
        if any(p.shape[1] % samples for p in pieces):
            self._width(spec, sum(p.shape[1] for p in pieces) + 1)  # raises, naming the fix
        split = [p.reshape(count, samples, -1) for p in pieces]
        return np.concatenate(split, axis=2).reshape(count, -1)

    def _sample_stamps(
        self, index: int, spec: SkinField, stamps: NDArray[np.int64], first: int, last: int
    ) -> NDArray[np.int64]:
        """Return a modality's sample stamps of messages ``first:last``.

        Raises:
            BagImportError: Sample stamps do not increase.
        """
        timeline = self.timelines.get(index)
        if timeline is not None:
            samples = timeline.stamps(first, last)
            fix = (
                "frames arrive later than half a frame period after the fitted timeline and "
                "earlier frames are stamped after them; check rate_hz and samples_per_message"
            )
        else:
            samples = (stamps[:, None] + self.offsets[spec.modality][None, :]).reshape(-1)
            fix = (
                f"its {spec.samples_per_message} samples per message at the rate given overlap "
                "the next message; fix samples_per_message or rate_hz, or, if the driver stamps "
                'messages when they arrive, set timing = "rate"'
            )
        if samples.size > 1 and not bool((np.diff(samples) > 0).all()):
            at = int(samples[int(np.argmin(np.diff(samples) > 0)) + 1])
            msg = (
                f"topic {self.topic}: sample stamps of [skin.{spec.modality}] go back at "
                f"{at} ns: {fix}"
            )
            raise BagImportError(msg)
        return samples

    def take_cells(self, lo: int, hi: int) -> dict[str, list[tuple[int, Series]]]:
        """Return each modality's samples of the messages reaching ``[lo, hi)``, per cell.

        Returns:
            modality -> (output column, samples) of every cell this topic carries.

        Raises:
            BagImportError: A field's width is wrong or sample stamps do not increase.
        """
        first, last = self.buffer.span(lo, hi, *self.reach)
        if first == last:
            return self._empty()
        stamps = np.asarray(self.buffer.stamps[first:last], dtype=np.int64)
        receives = np.asarray(self.buffer.receives[first:last], dtype=np.int64)
        raws = {i: self._raw(i, first, last) for i in range(len(self.paths))}
        out: dict[str, list[tuple[int, Series]]] = {}
        for index, (spec, cells) in enumerate(zip(self.fields, self.cells, strict=True)):
            samples = self._sample_stamps(index, spec, stamps, first, last)
            repeated = np.repeat(receives, spec.samples_per_message)
            series = out.setdefault(spec.modality, [])
            for column, lab_cell in cells:
                raw = self._cell_values(spec, lab_cell, raws)
                width = self._width(spec, raw.shape[1])
                data = raw.reshape(samples.size, width) * spec.scale + spec.offset
                series.append((column, Series(samples, repeated, data)))
        return out

    def _empty(self) -> dict[str, list[tuple[int, Series]]]:
        """Return no samples of every modality and cell (no message reaches the range)."""
        out: dict[str, list[tuple[int, Series]]] = {}
        none = np.zeros(0, dtype=np.int64)
        for spec, cells in zip(self.fields, self.cells, strict=True):
            width = self.widths.get(spec.modality, max(spec.width, 1))
            empty = Series(none, none, np.zeros((0, width)))
            out.setdefault(spec.modality, []).extend((column, empty) for column, _ in cells)
        return out

    def take(self, lo: int, hi: int) -> dict[str, Series]:
        """Return each modality's samples of the messages reaching ``[lo, hi)`` (first cell).

        Raises:
            BagImportError: A field's width is wrong or sample stamps do not increase.
        """
        return {m: cells[0][1] for m, cells in self.take_cells(lo, hi).items()}

    def forget(self, before: int) -> None:
        """Drop the messages whose samples all precede ``before``."""
        index = bisect.bisect_left(self.buffer.stamps, before - self.reach[1])
        self.buffer.cut(index)
        for values in self.values:
            del values[:index]
        for timeline in self.timelines.values():
            timeline.cut(index)

    def size(self) -> int:
        """Return the number of buffered messages."""
        return len(self.buffer.stamps)


#: The columns of a joint-state message that lacks one of the arm's joints (not kept).
_MISSING_JOINT: NDArray[np.intp] = np.zeros(0, dtype=np.intp)


@dataclass(slots=True)
class JointTopic:
    """The joint-state topic: positions, velocities and efforts picked by name, buffered.

    A message with empty velocities or efforts keeps NaN for them (nothing measured); a
    window whose messages all lack a quantity records it as zeros, named "not recorded" in
    its file (:meth:`not_recorded`), and in a window where only some lack it those samples
    are dropped and counted, never filled. A message whose velocities or efforts number other
    than its names is malformed: counted (:attr:`malformed`) and not kept.
    """

    topic: str
    wanted: tuple[str, ...]
    scale: float
    names: tuple[str, ...] = ()
    #: The quantities the window cut last does not hold (its recording says "not recorded").
    missing: set[str] = field(default_factory=set)
    #: Messages not kept: velocities or efforts of another count than the names.
    malformed: int = 0
    buffer: _Buffer = field(init=False)
    rows: list[list[Any]] = field(default_factory=lambda: [[], [], []])
    skipped: int = 0
    _index: dict[tuple[str, ...], NDArray[np.intp] | None] = field(default_factory=dict)
    _last: list[str] = field(default_factory=list)
    _last_index: NDArray[np.intp] | None = None
    _nans: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    #: Dtypes of a decoder's (names, position, velocity, effort), for :meth:`push_fields`.
    dtypes: tuple[Any, ...] = ()

    def __post_init__(self) -> None:
        """Create the buffer."""
        self.buffer = _Buffer(self.topic, "fix the robot driver's stamps")

    @property
    def repeated(self) -> int:
        """Return the messages dropped for a repeated stamp."""
        return self.buffer.repeated

    def _pick(self, names: tuple[str, ...]) -> NDArray[np.intp] | None:
        """Return the columns of the output joints in a message naming ``names``."""
        if names not in self._index:
            if not self.names:
                self.names = self.wanted or names
            present = [n for n in self.names if n in names]
            if present and len(present) != len(self.names) and self.wanted:
                msg = (
                    f"topic {self.topic}: joints {[n for n in self.names if n not in names]} are "
                    f"not in a message naming {list(names)}; fix [joint_states] names"
                )
                raise BagImportError(msg)
            index: NDArray[np.intp] | None = None
            if present and len(present) != len(self.names):
                # the arm's joints (learned from the first message) with one missing: a
                # malformed message, counted and not kept (the map names none to fix)
                index = _MISSING_JOINT
            elif present:
                index = np.array([names.index(n) for n in self.names])
            self._index[names] = index
        return self._index[names]

    def push(self, message: Any, stamp: int, receive_ns: int) -> None:  # noqa: ANN401
        """Keep one joint sample (empty velocities or efforts: NaN, see the class).

        Raises:
            BagImportError: A message lacks positions or its stamp goes back.
        """
        self.push_values(
            message.name,
            message.position,
            message.velocity,
            message.effort,
            stamp=stamp,
            receive_ns=receive_ns,
        )

    def push_fields(self, fields: Sequence[Any], stamp: int, receive_ns: int) -> None:
        """Keep one joint sample from a decoder's ``(sec, nanosec, names, bytes x 3)``.

        Raises:
            BagImportError: A message lacks positions or its stamp goes back.
        """
        _, _, names, position, velocity, effort = fields
        _, dposition, dvelocity, deffort = self.dtypes
        self.push_values(
            names,
            np.frombuffer(position, dposition),
            np.frombuffer(velocity, dvelocity),
            np.frombuffer(effort, deffort),
            stamp=stamp,
            receive_ns=receive_ns,
        )

    def push_values(
        self,
        names: list[str],
        position: NDArray[Any],
        velocity: NDArray[Any],
        effort: NDArray[Any],
        *,
        stamp: int,
        receive_ns: int,
    ) -> None:
        """Keep one joint sample from its fields (as :meth:`push`).

        Raises:
            BagImportError: A message lacks positions or its stamp goes back.
        """
        if names != self._last:
            self._last_index = self._pick(tuple(names))
            self._last, self._nans = list(names), np.full(len(names), np.nan)
        index = self._last_index
        if index is None:  # another part of the robot on the same topic (a gripper)
            self.skipped += 1
            return
        if index is _MISSING_JOINT:
            self.malformed += 1
            return
        count = len(names)
        values = [position, velocity, effort]
        if len(values[0]) != count:
            msg = f"topic {self.topic}: a message at {stamp} ns has no joint positions"
            raise BagImportError(msg)
        for k in (1, 2):
            if len(values[k]) == 0:  # not measured: NaN until a window decides
                values[k] = self._nans
            elif len(values[k]) != count:  # a value per joint, or none: never made up
                self.malformed += 1
                return
        if self.buffer.accept(stamp, receive_ns):
            for rows, array in zip(self.rows, values, strict=True):
                rows.append(array[index])

    def take(self, lo: int, hi: int) -> Series:
        """Return the samples stamped in ``[lo, hi)`` (positions scaled)."""
        first, last = self.buffer.span(lo, hi, 0, 0)
        columns = [
            np.asarray(rows[first:last], dtype=np.float64).reshape(last - first, len(self.names))
            for rows in self.rows
        ]
        columns[0] = columns[0] * self.scale
        stamps = np.asarray(self.buffer.stamps[first:last], dtype=np.int64)
        receives = np.asarray(self.buffer.receives[first:last], dtype=np.int64)
        return Series(stamps, receives, np.concatenate(columns, axis=1))

    def not_recorded(self, series: Series) -> Series:
        """Return a window's samples with the quantities none of them holds as zeros.

        Sets :attr:`missing` to those quantities (the window's recording names them). A
        quantity some samples hold stays NaN where it is missing: those samples are dropped.
        """
        self.missing = set()
        n = len(self.names)
        values = series.values.copy()
        for k, quantity in ((1, "velocity"), (2, "effort")):
            block = values[:, k * n : (k + 1) * n]
            if block.size and bool(np.isnan(block).all()):
                block[:] = 0.0
                self.missing.add(quantity)
        return Series(series.stamps, series.receives, values)

    def forget(self, before: int) -> None:
        """Drop the samples before ``before``."""
        index = bisect.bisect_left(self.buffer.stamps, before)
        self.buffer.cut(index)
        for rows in self.rows:
            del rows[:index]

    def size(self) -> int:
        """Return the number of buffered messages."""
        return len(self.buffer.stamps)


def _robot_series(buffer: _Buffer, rows: list[Any], first: int, last: int, width: int) -> Series:
    """Return buffered robot samples ``first:last`` as a series."""
    values = np.asarray(rows[first:last], dtype=np.float64).reshape(last - first, width)
    stamps = np.asarray(buffer.stamps[first:last], dtype=np.int64)
    return Series(stamps, np.asarray(buffer.receives[first:last], dtype=np.int64), values)


@dataclass(slots=True)
class PoseTopic:
    """The tool-pose topic: position (scaled to m) and quaternion (x, y, z, w), buffered."""

    topic: str
    scale: float
    buffer: _Buffer = field(init=False)
    rows: list[tuple[float, ...]] = field(default_factory=list)

    def __post_init__(self) -> None:
        """Create the buffer."""
        self.buffer = _Buffer(self.topic, "fix the robot driver's stamps")

    @property
    def repeated(self) -> int:
        """Return the messages dropped for a repeated stamp."""
        return self.buffer.repeated

    def push(self, message: Any, stamp: int, receive_ns: int) -> None:  # noqa: ANN401
        """Keep one pose.

        Raises:
            BagImportError: Its stamp goes back.
        """
        if self.buffer.accept(stamp, receive_ns):
            p, q = message.pose.position, message.pose.orientation
            scale = self.scale
            self.rows.append((p.x * scale, p.y * scale, p.z * scale, q.x, q.y, q.z, q.w))

    def take(self, lo: int, hi: int) -> Series:
        """Return the samples stamped in ``[lo, hi)``."""
        first, last = self.buffer.span(lo, hi, 0, 0)
        return _robot_series(self.buffer, self.rows, first, last, 7)

    def forget(self, before: int) -> None:
        """Drop the samples before ``before``."""
        index = bisect.bisect_left(self.buffer.stamps, before)
        self.buffer.cut(index)
        del self.rows[:index]

    def size(self) -> int:
        """Return the number of buffered messages."""
        return len(self.buffer.stamps)


Extractor = SkinTopic | JointTopic | PoseTopic


def extractors(topic_map: TopicMap) -> dict[str, Extractor]:
    """Return topic -> extractor for every mapped data topic."""
    cells = list(enumerate(topic_map.cells))
    fields: dict[str, list[tuple[SkinField, tuple[tuple[int, int], ...]]]] = {}
    for spec in topic_map.skin.values():
        if spec.per_cell:  # one message carries every cell: a field indexed by {cell}
            fields.setdefault(spec.topic, []).append((spec, tuple(cells)))
            continue
        for column, cell in cells:
            mapped = fields.setdefault(spec.topic_of(cell), [])
            if any(s is spec for s, _ in mapped):
                msg = (
                    f"{topic_map.path}: topic {spec.topic} of [skin.{spec.modality}] is mapped "
                    f"to {len(cells)} cells; give its topic a {{cell}} placeholder, index its "
                    'field by cell (field = "values[{cell}]"), or map one cell'
                )
                raise BagImportError(msg)
            mapped.append((spec, ((column, cell),)))
    out: dict[str, Extractor] = {}
    for topic, specs in fields.items():
        first = min(column for _, mine in specs for column, _ in mine)
        out[topic] = SkinTopic(
            topic, first, tuple(s for s, _ in specs), cells=tuple(c for _, c in specs)
        )
    for robot, make in ((topic_map.joints, "joints"), (topic_map.pose, "pose")):
        if robot is None:
            continue
        if isinstance(out.get(robot.topic), SkinTopic):
            msg = f"{topic_map.path}: topic {robot.topic} is mapped as skin and robot; map it once"
            raise BagImportError(msg)
        out[robot.topic] = (
            JointTopic(robot.topic, robot.names, robot.position_scale)
            if make == "joints"
            else PoseTopic(robot.topic, robot.position_scale)
        )
    return out


def required_types(topic_map: TopicMap) -> list[tuple[str, str | None]]:
    """Return (topic, required message type or None for any type with the fields) per role."""
    wanted: list[tuple[str, str | None]] = [(t, None) for t in extractors(topic_map)]
    if topic_map.joints is not None:
        wanted.append((topic_map.joints.topic, JOINT_TYPE))
    if topic_map.pose is not None:
        wanted.append((topic_map.pose.topic, POSE_TYPE))
    if topic_map.windows.source == "topic":
        wanted.append((topic_map.windows.topic, ANNOTATION_TYPE))
    return wanted


def typestore(topic_map: TopicMap) -> Typestore:
    """Return the typestore for bags without definitions: ROS 2 Humble + the map's types.

    Raises:
        BagImportError: A definition of the map does not parse.
    """
    store = get_typestore(Stores.ROS2_HUMBLE)
    for name, text in topic_map.types.items():
        try:
            store.register(get_types_from_msg(text, name))
        except TypesysError as err:
            msg = f"{topic_map.path}: [types] {name!r}: the definition does not parse ({err})"
            raise BagImportError(msg) from err
    return store


def check_connections(
    reader: AnyReader, wanted: Sequence[tuple[str, str | None]]
) -> list[Connection]:
    """Return the connections of the mapped topics, each checked for its type.

    Raises:
        BagImportError: A topic is missing or has another type; the message names it.
    """
    types = {c.topic: c.msgtype for c in reader.connections}
    if missing := [topic for topic, _ in wanted if topic not in types]:
        known = ", ".join(sorted(types)) or "none"
        msg = (
            f"topic {missing[0]} of the topic map is not in the bag (its topics: {known}); "
            "fix the topic map"
        )
        raise BagImportError(msg)
    for topic, required in wanted:
        if required is not None and types[topic] != required:
            msg = (
                f"topic {topic} carries {types[topic]}, but the topic map uses it as "
                f"{required}; map the topic that carries {required}"
            )
            raise BagImportError(msg)
    topics = {topic for topic, _ in wanted}
    return [c for c in reader.connections if c.topic in topics]


_NUMERIC = frozenset(
    [
        *("bool", "byte", "char", "int8", "uint8", "int16", "uint16"),
        *("int32", "uint32", "int64", "uint64", "float32", "float64"),
    ]
)


def _field_type(store: Typestore, msgtype: str, path: str) -> tuple[Any, ...] | None:
    """Return the type node of a dotted field of ``msgtype``, or None if there is none."""
    node: tuple[Any, ...] = (Nodetype.NAME, msgtype)
    for part in path.split("."):
        if node[0] != Nodetype.NAME:
            return None
        fields = dict(store.fielddefs[node[1]][1])
        if part not in fields:
            return None
        node = fields[part]
    return node


def _numeric(node: tuple[Any, ...]) -> bool:
    """Return whether a type node is a number or an array/sequence of numbers."""
    if node[0] in {Nodetype.ARRAY, Nodetype.SEQUENCE}:
        node = node[1][0]
    return bool(node[0] == Nodetype.BASE and node[1][0] in _NUMERIC)


def _check_part(
    store: Typestore, topic: str, msgtype: str, spec: SkinField, part: FieldPart
) -> None:
    """Check that one field of a modality exists, is numeric, and is an array if indexed.

    Raises:
        BagImportError: The field is missing, not numeric, or indexed but not an array.
    """
    node = _field_type(store, msgtype, part.path)
    if node is None or not _numeric(node):
        names = [name for name, _ in store.fielddefs[msgtype][1]]
        problem = "no field" if node is None else "a field that is not numeric:"
        msg = (
            f"topic {topic} carries {msgtype}: {problem} {part.path!r} "
            f"(fields: {', '.join(names)}); fix 'field' of [skin.{spec.modality}] in "
            "the topic map or map the topic that carries the values"
        )
        raise BagImportError(msg)
    indexed = part.per_cell or part.index is not None
    if indexed and node[0] not in {Nodetype.ARRAY, Nodetype.SEQUENCE}:
        msg = (
            f"topic {topic} carries {msgtype}: field {part.path!r} is a number, not an array; "
            f"remove the [..] from 'field' of [skin.{spec.modality}] in the topic map"
        )
        raise BagImportError(msg)


_INTEGERS = frozenset(["int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64"])


def _check_counter(store: Typestore, topic: str, msgtype: str, spec: SkinField) -> None:
    """Check that a frame counter is an integer field.

    Raises:
        BagImportError: It is missing or not an integer.
    """
    node = _field_type(store, msgtype, spec.counter)
    if node is None or node[0] != Nodetype.BASE or node[1][0] not in _INTEGERS:
        names = [name for name, _ in store.fielddefs[msgtype][1]]
        msg = (
            f"topic {topic} carries {msgtype}: counter {spec.counter!r} is not an integer field "
            f"(fields: {', '.join(names)}); fix counter of [skin.{spec.modality}] in the topic map"
        )
        raise BagImportError(msg)


def check_fields(reader: AnyReader, connections: Sequence[Connection], topic_map: TopicMap) -> None:
    """Check, before reading, that every skin field exists, is numeric, and has a header.

    Raises:
        BagImportError: A field is missing or not numeric, or a header clock lacks a header.
    """
    store = reader.typestore
    types = {c.topic: c.msgtype for c in connections}
    for topic, msgtype in types.items():
        if msgtype not in store.fielddefs:  # a bag without definitions (ROS 2 Humble)
            package, _, name = msgtype.rpartition("/")
            msg = (
                f"topic {topic} carries {msgtype}, whose definition the bag does not store and "
                f'the topic map does not give; add [types] "{msgtype}" = """<the text of '
                f'{package.split("/")[0]}/msg/{name}.msg>""" to {topic_map.path}'
            )
            raise BagImportError(msg)
    for topic, extractor in extractors(topic_map).items():
        msgtype = types[topic]
        for spec in getattr(extractor, "fields", ()):
            for part in spec.fields:
                _check_part(store, topic, msgtype, spec, part)
            if spec.counter:
                _check_counter(store, topic, msgtype, spec)
        if topic_map.stamps == "header" and _field_type(store, msgtype, "header.stamp") is None:
            msg = (
                f'topic {topic} ({msgtype}) has no header.stamp; set [time] stamps = "log" '
                "in the topic map to use the receive time"
            )
            raise BagImportError(msg)


def open_reader(bags: Sequence[Path], topic_map: TopicMap) -> AnyReader:
    """Return an (unopened) reader of the bags with the map's fallback definitions.

    ROS 1 bags are read by :class:`~recorder.bagimport._ros1.StreamingReader` (no per-message
    index in memory); ROS 2 bags decompress through :mod:`~recorder.bagimport._bounded`.
    """
    _bounded.install()
    reader = AnyReader([Path(b) for b in bags], default_typestore=typestore(topic_map))
    if not reader.is2:
        reader.readers = [StreamingReader(Path(b)) for b in bags]
    return reader


def raw_messages(
    reader: AnyReader, connections: Sequence[Connection]
) -> Iterator[tuple[Connection, int, bytes]]:
    """Yield (connection, receive ns, raw bytes) in bag order, refusing oversized messages.

    Raises:
        BagImportError: A message is larger than :data:`MAX_MESSAGE_BYTES`.
    """
    for connection, receive_ns, raw in reader.messages(connections=connections):
        if len(raw) > MAX_MESSAGE_BYTES:
            msg = (
                f"topic {connection.topic}: a message of {len(raw)} bytes at {receive_ns} ns "
                f"exceeds {MAX_MESSAGE_BYTES >> 20} MB; the bag is damaged or not a sensor log"
            )
            raise BagImportError(msg)
        yield connection, receive_ns, raw


def unreadable(bags: Sequence[Path], err: BaseException, fix: str) -> str:
    """Return the one-line message for bags rosbags cannot read, with the way out if known.

    An MCAP file without its end (its recorder was killed, the disk filled, the power went)
    is refused whole by rosbags; what it holds up to the cut is salvaged by ``atikt-replay
    check --recover`` into a complete file beside it, which rosbags reads.
    """
    if "end magic" in str(err).lower():  # rosbags' words for an MCAP file without its end
        cut = [f for b in bags for f in ([b] if b.is_file() else sorted(b.glob("*.mcap")))]
        named = ", ".join(map(str, cut)) or ", ".join(map(str, bags))
        return (
            f"{named}: the MCAP file ends cut off (its recorder stopped without closing it); "
            f"salvage what it holds with atikt-replay check --recover {cut[0] if cut else 'FILE'}"
            ", then import the .recovered.mcap it writes"
        )
    text = str(err)
    active = [b for b in bags if b.name.endswith(".bag.active")]
    if active or "bag index looks damaged" in text.lower() or "not indexed" in text.lower():
        bag = (active or list(bags))[0]
        return (
            f"{bag}: a ROS 1 bag cut off or without its index (its recorder was killed); "
            f"rebuild the index with rosbag reindex {bag} (ROS 1)"
            + (", then rename it to end in .bag" if active else "")
        )
    folders = [b for b in bags if b.is_dir() and not (b / "metadata.yaml").exists()]
    if folders:  # rosbag2 writes metadata.yaml when its recorder closes the bag
        folder = folders[0]
        files = sorted(folder.glob("*.mcap"))
        if files:
            way = (
                f"give its MCAP file{'s' if len(files) > 1 else ''} instead of the folder "
                f"({', '.join(str(f) for f in files[:3])})"
            )
        elif any(folder.glob("*.db3")):
            way = f"rebuild it with ros2 bag reindex {folder} (ROS 2)"
        else:
            return f"{folder}: holds no bag (no metadata.yaml, .mcap or .db3 file); give a bag"
        return (
            f"{folder}: a ROS 2 bag folder without metadata.yaml (its recorder did not close "
            f"it); {way}"
        )
    return f"{', '.join(map(str, bags))}: cannot read the bag ({err!r}){fix}"


def bag_topics(bags: Sequence[Path]) -> list[tuple[str, str, int]]:
    """Return (topic, type, message count) of every connection of the bags, for help messages.

    Raises:
        BagImportError: A bag cannot be read.
    """
    _bounded.install()
    try:  # a ROS 2 Humble bag stores no definitions: the standard ones are Humble's
        store = get_typestore(Stores.ROS2_HUMBLE)
        with AnyReader([Path(b) for b in bags], default_typestore=store) as reader:
            return [(c.topic, c.msgtype, c.msgcount) for c in reader.connections]
    except READ_ERRORS as err:
        raise BagImportError(unreadable(bags, err, "")) from err
