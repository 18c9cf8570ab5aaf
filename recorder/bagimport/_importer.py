"""Import a lab's ROS 1 / ROS 2 bags as per-action recordings (``atikt-record import-bag``).

rosbags' ``AnyReader`` reads ROS 1 ``.bag`` files and ROS 2 bags (sqlite3 or MCAP storage). A topic
map (:mod:`recorder.bagimport._topicmap`) says which topics carry the joint states, the TCP pose
and each skin cell's modalities, in which units, and where the actions are annotated. Every action
window becomes one file ``<out>/<object>/<action>/<trial>.mcap`` written by the recorder's own
:class:`~recorder.RecordingWriter`, then the dataset index is rebuilt: the output is
indistinguishable in layout from a simulated dataset, so replay works unchanged.

Nothing is resampled. Per-cell skin samples are grouped into the recording's skin blocks:

1. Rows: the first cell of the map sets the rows. Every other cell contributes its sample
   nearest in time to the row's stamp if it is closer than half a sample period (the period
   is the median interval of the first cell's samples); a row missing a cell is dropped and
   counted. The row is stamped with the first cell's stamp; the largest offset of another
   cell's sample is reported.
2. Blocks: consecutive rows go into one block of about 0.1 s (``round(0.1 s / period)`` rows)
   while each stamp lies within ``max_jitter`` periods of ``first + i * period``; a larger
   deviation (a gap, a dropped row) starts a new block. The reader then sees every stamp
   within ``max_jitter`` periods of its measured value (the largest deviation is reported).

The window of an action is half-open, ``[first phase, end)``; samples, joint states and poses
with stamps inside it go into its file, and each skin modality's last row before the window
(the reader checks that the skin covers the first phase). Rows with a non-finite value, and
joint states or poses with a repeated stamp or a non-finite value, are dropped and counted;
an execute phase shorter than the action's ``duration_s`` is refused before anything is
written (the reader would refuse the file). Joint velocities or efforts that the lab's driver left
empty are written as zeros (the recording format has no "missing"; readers refuse NaN). The
recording's rig metadata has ``kind = imported``, the source bag, the map, the clock, the
lab's cell ids and the joint quantities that were not recorded (``joints_not_recorded``).
"""

from __future__ import annotations

import csv
import dataclasses
import itertools
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag1 import ReaderError as Ros1ReaderError
from rosbags.rosbag2 import ReaderError as Ros2ReaderError
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore

from recorder._dataset import recording_path, write_index
from recorder.bagimport._topicmap import CHANNELS_PER_CELL, TIME_UNITS
from recorder.errors import BagImportError
from recorder.writing._stream import JointSample, Modality, Phase, PhaseEvent, PoseSample, SkinBlock
from recorder.writing._writer import RecordingInfo, RecordingWriter
from schemas import SCHEMA_VERSION, RecordingMetadata, check_rig, software_version

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Mapping, Sequence

    from numpy.typing import NDArray
    from rosbags.typesys.store import Typestore

    from recorder._catalog import ActionSpec, ObjectSpec
    from recorder.bagimport._topicmap import TopicMap
    from recorder.writing._stream import StreamItem

#: Time of samples per skin block, ns, as in the recorder's own files.
BLOCK_NS = 100_000_000
#: How much shorter than the action's duration an execute phase may be (the reader's rule).
DURATION_TOLERANCE = 0.01
_NS_PER_S = 1_000_000_000
_JOINT_TYPE = "sensor_msgs/msg/JointState"
_POSE_TYPE = "geometry_msgs/msg/PoseStamped"
_ANNOTATION_TYPE = "std_msgs/msg/String"
_PHASE_ORDER = tuple(Phase)
_READ_ERRORS = (
    AnyReaderError,
    Ros1ReaderError,
    Ros2ReaderError,
    SerdeError,
    TypesysError,
    OSError,
)


# -------------------------------------------------------------------------------- reading


@dataclass(slots=True)
class _Topic:
    """What was read from one topic: stamps, receive times and extracted values."""

    stamps: list[int] = field(default_factory=list)
    receives: list[int] = field(default_factory=list)
    values: dict[str, list[Any]] = field(default_factory=dict)
    missing: set[str] = field(default_factory=set)

    def arrays(self) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """Return stamps and receive times as int64 arrays, in reading order."""
        return np.asarray(self.stamps, dtype=np.int64), np.asarray(self.receives, dtype=np.int64)


def _stamp(message: Any, topic: str, clock: str, receive_ns: int) -> int:  # noqa: ANN401
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


def _field_names(message: Any) -> list[str]:  # noqa: ANN401
    """Return the field names of a message, for error messages."""
    return [f.name for f in dataclasses.fields(message) if not f.name.startswith("__")]


def _field(message: Any, path: str, topic: str) -> NDArray[np.float64]:  # noqa: ANN401
    """Return a (dotted) field of a message as a float64 vector.

    Raises:
        BagImportError: The field does not exist or is not numeric.
    """
    value = message
    for part in path.split("."):
        if not hasattr(value, part):
            msg = (
                f"topic {topic} ({message.__msgtype__}): no field {path!r} "
                f"(fields: {', '.join(_field_names(message))}); fix its 'field' in the topic map"
            )
            raise BagImportError(msg)
        value = getattr(value, part)
    try:
        return np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as err:
        msg = f"topic {topic} ({message.__msgtype__}): field {path!r} is not numeric"
        raise BagImportError(msg) from err


@dataclass(frozen=True, slots=True)
class _Extractor:
    """Turns one topic's messages into stamps and values (one extractor per topic)."""

    topic: str
    run: Callable[[Any, _Topic], None]


def _skin_extractor(topic: str, fields: Sequence[tuple[Modality, str, int]]) -> _Extractor:
    """Return the extractor of a skin cell topic carrying ``fields`` (modality, path, width)."""

    def run(message: Any, store: _Topic) -> None:  # noqa: ANN401
        for modality, path, width in fields:
            values = _field(message, path, topic)
            if values.size != width:
                msg = (
                    f"topic {topic} ({message.__msgtype__}): field {path!r} has {values.size} "
                    f"values; {modality} needs {width} per cell: fix the topic map's "
                    f"[skin.{modality}] field"
                )
                raise BagImportError(msg)
            store.values.setdefault(str(modality), []).append(values)

    return _Extractor(topic, run)


def _joint_extractor(topic_map: TopicMap) -> _Extractor:
    """Return the joint-state extractor: positions, velocities, efforts picked by name."""
    wanted = topic_map.joint_names
    cache: dict[tuple[str, ...], list[int]] = {}

    def pick(values: Any, index: list[int], count: int) -> NDArray[np.float64] | None:  # noqa: ANN401
        array = np.asarray(values, dtype=np.float64)
        return array[index] if array.size == count else None

    def run(message: Any, store: _Topic) -> None:  # noqa: ANN401
        names = tuple(message.name)
        if names not in cache:
            if missing := [n for n in wanted if n not in names]:
                msg = (
                    f"topic {topic_map.joint_topic}: joints {missing} not in the messages "
                    f"(they name {list(names)}); fix [joint_states] names in the topic map"
                )
                raise BagImportError(msg)
            cache[names] = [names.index(n) for n in wanted]
        index = cache[names]
        for quantity in ("position", "velocity", "effort"):
            values = pick(getattr(message, quantity), index, len(names))
            if values is None:  # drivers may leave velocity or effort empty: zeros, noted
                if quantity == "position":
                    msg = f"topic {topic_map.joint_topic}: a message has no joint positions"
                    raise BagImportError(msg)
                store.missing.add(quantity)
                values = np.zeros(len(index))
            elif quantity == "position":
                values = values * topic_map.joint_position_scale
            store.values.setdefault(quantity, []).append(values)

    return _Extractor(topic_map.joint_topic, run)


def _pose_extractor(topic_map: TopicMap) -> _Extractor:
    """Return the TCP pose extractor: position (scaled to m) and quaternion (x, y, z, w)."""

    def run(message: Any, store: _Topic) -> None:  # noqa: ANN401
        pose = message.pose
        position = np.array([pose.position.x, pose.position.y, pose.position.z])
        orientation = [pose.orientation.x, pose.orientation.y, pose.orientation.z]
        store.values.setdefault("position", []).append(position * topic_map.pose_position_scale)
        store.values.setdefault("orientation", []).append(
            np.array([*orientation, pose.orientation.w])
        )

    return _Extractor(topic_map.pose_topic, run)


def _annotation_extractor(topic: str) -> _Extractor:
    """Return the annotation extractor: the JSON text of std_msgs/String messages."""

    def run(message: Any, store: _Topic) -> None:  # noqa: ANN401
        store.values.setdefault("text", []).append(str(message.data))

    return _Extractor(topic, run)


def _skin_topics(topic_map: TopicMap) -> dict[str, list[tuple[Modality, str, int]]]:
    """Return, per cell topic, the (modality, field, width) it carries."""
    topics: dict[str, list[tuple[Modality, str, int]]] = {}
    for modality, spec in topic_map.skin.items():
        for cell in topic_map.cells:
            entry = (modality, spec.field, CHANNELS_PER_CELL[modality])
            topics.setdefault(spec.topic_of(cell), []).append(entry)
    return topics


def _extractors(topic_map: TopicMap) -> dict[str, tuple[str | None, _Extractor]]:
    """Return topic -> (required message type or None, extractor) for every mapped topic."""
    extractors: dict[str, tuple[str | None, _Extractor]] = {
        topic: (None, _skin_extractor(topic, fields))
        for topic, fields in _skin_topics(topic_map).items()
    }
    extractors[topic_map.joint_topic] = (_JOINT_TYPE, _joint_extractor(topic_map))
    extractors[topic_map.pose_topic] = (_POSE_TYPE, _pose_extractor(topic_map))
    if topic_map.windows.source == "topic":
        topic = topic_map.windows.topic
        extractors[topic] = (_ANNOTATION_TYPE, _annotation_extractor(topic))
    return extractors


def _typestore(topic_map: TopicMap) -> Typestore:
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


def _check_connections(reader: AnyReader, wanted: Mapping[str, str | None]) -> None:
    """Check that every mapped topic exists in the bag with the expected type.

    Raises:
        BagImportError: A topic is missing or has another type; the message names it.
    """
    types = {c.topic: c.msgtype for c in reader.connections}
    if missing := [topic for topic in wanted if topic not in types]:
        known = ", ".join(sorted(types)) or "none"
        msg = (
            f"topic {missing[0]} of the topic map is not in the bag (its topics: {known}); "
            "fix the topic map"
        )
        raise BagImportError(msg)
    for topic, required in wanted.items():
        if required is not None and types[topic] != required:
            msg = (
                f"topic {topic} carries {types[topic]}, but the topic map uses it as "
                f"{required}; map the right topic or convert the bag"
            )
            raise BagImportError(msg)


def read_bag(bag: Path, topic_map: TopicMap) -> dict[str, _Topic]:
    """Read every mapped topic of a bag: stamps on the map's clock, receive times, values.

    Raises:
        BagImportError: The bag cannot be read, or a topic is missing, mistyped or malformed.
    """
    extractors = _extractors(topic_map)
    read: dict[str, _Topic] = {topic: _Topic() for topic in extractors}
    receive_clock = {topic_map.windows.topic}  # annotations have no header
    try:
        with AnyReader([Path(bag)], default_typestore=_typestore(topic_map)) as reader:
            _check_connections(reader, {t: kind for t, (kind, _) in extractors.items()})
            connections = [c for c in reader.connections if c.topic in extractors]
            for connection, receive_ns, raw in reader.messages(connections=connections):
                message = reader.deserialize(raw, connection.msgtype)
                store = read[connection.topic]
                clock = "log" if connection.topic in receive_clock else topic_map.stamps
                stamp = _stamp(message, connection.topic, clock, receive_ns)
                store.stamps.append(stamp)
                store.receives.append(receive_ns)
                extractors[connection.topic][1].run(message, store)
    except BagImportError as err:
        msg = f"{bag}: {err}"
        raise BagImportError(msg) from err
    except _READ_ERRORS as err:
        msg = f"{bag}: cannot read the bag ({err}); check the path and the [types] of the map"
        raise BagImportError(msg) from err
    return read


# -------------------------------------------------------------------------------- windows


@dataclass(frozen=True, slots=True)
class Window:
    """One annotated action: its object, action, trial and phase starts.

    Attributes:
        object_id: Object id (catalog or map).
        action_id: Action id (catalog or map).
        trial: Trial number, or None to number it on after the existing ones.
        events: Phase starts in time order; the last one is ``end``.
    """

    object_id: str
    action_id: str
    trial: int | None
    events: tuple[tuple[Phase, int], ...]

    @property
    def start_ns(self) -> int:
        """Return the first phase's start."""
        return self.events[0][1]

    @property
    def stop_ns(self) -> int:
        """Return the end (exclusive)."""
        return self.events[-1][1]

    def describe(self) -> str:
        """Return the window for messages."""
        return f"window {self.object_id}/{self.action_id} [{self.start_ns}, {self.stop_ns}) ns"


def _check_window(window: Window, where: str) -> Window:
    """Check phase names, order and the required execute and end.

    Raises:
        BagImportError: The phases are out of order or incomplete.
    """
    phases = [phase for phase, _ in window.events]
    ranks = [_PHASE_ORDER.index(phase) for phase in phases]
    stamps = [stamp for _, stamp in window.events]
    ordered = all(b > a for a, b in itertools.pairwise(ranks))
    increasing = all(b > a for a, b in itertools.pairwise(stamps))
    if not (ordered and increasing) or Phase.EXECUTE not in phases or phases[-1] != Phase.END:
        listed = ", ".join(f"{p}@{s}" for p, s in window.events)
        msg = (
            f"{where}: {window.describe()} has phases {listed}; an action needs execute and end, "
            "in the order approach, contact, execute, retract, end, at increasing times"
        )
        raise BagImportError(msg)
    return window


_Key = tuple[str, str, int | None]


def _annotation(text: str, stamp_ns: int, topic: str) -> tuple[_Key, Phase, int]:
    """Parse one annotation: ((object, action, trial), phase, stamp).

    Raises:
        BagImportError: The text is not the documented JSON object.
    """
    try:
        data = json.loads(text)
        phase = Phase(data["phase"])
        trial = None if data.get("trial") is None else int(data["trial"])
        key = (str(data["object"]), str(data["action"]), trial)
        stamp = int(data.get("stamp_ns", stamp_ns))
    except (ValueError, KeyError, TypeError) as err:
        msg = (
            f"topic {topic}: annotation at {stamp_ns} ns is {text!r} ({err!r}); annotations are "
            'JSON like {"object": "wood", "action": "P1", "trial": 1, "phase": "execute"}'
        )
        raise BagImportError(msg) from err
    return key, phase, stamp


def windows_from_annotations(read: _Topic, topic: str) -> list[Window]:
    """Group annotation events into windows: each runs from its first event to its ``end``.

    Raises:
        BagImportError: An annotation is malformed, or actions overlap or lack an end.
    """
    events = sorted(
        (
            _annotation(text, stamp, topic)
            for text, stamp in zip(read.values.get("text", []), read.stamps, strict=True)
        ),
        key=lambda event: event[2],
    )
    windows: list[Window] = []
    current: list[tuple[Phase, int]] = []
    current_key: _Key | None = None
    for key, phase, stamp in events:
        if current_key is not None and key != current_key:
            msg = (
                f"topic {topic}: at {stamp} ns a phase of {key[0]}/{key[1]} starts before the "
                f"'end' of {current_key[0]}/{current_key[1]}; annotate an end for every action"
            )
            raise BagImportError(msg)
        current_key = key
        current.append((phase, stamp))
        if phase == Phase.END:
            windows.append(_check_window(Window(*key, tuple(current)), f"topic {topic}"))
            current, current_key = [], None
    if current_key is not None:
        msg = f"topic {topic}: {current_key[0]}/{current_key[1]} has no 'end' annotation"
        raise BagImportError(msg)
    return windows


def _csv_time(row: dict[str, str], column: str, scale: int, origin: int, where: str) -> int:
    """Return a CSV time in ns on the map's clock.

    Raises:
        BagImportError: The value is not a number.
    """
    try:
        return origin + round(float(row[column]) * scale)
    except (ValueError, TypeError) as err:
        msg = f"{where}: {column} = {row.get(column)!r} is not a time; fix the row"
        raise BagImportError(msg) from err


def _csv_window(row: dict[str, str], scale: int, origin: int, where: str) -> Window:
    """Return the window of one CSV row (execute at start, end at stop, optional phases)."""
    events = [(Phase.EXECUTE, _csv_time(row, "start", scale, origin, where))]
    events.append((Phase.END, _csv_time(row, "stop", scale, origin, where)))
    events.extend(
        (phase, _csv_time(row, str(phase), scale, origin, where))
        for phase in (Phase.APPROACH, Phase.CONTACT, Phase.RETRACT)
        if (row.get(str(phase)) or "").strip()
    )
    events.sort(key=lambda event: _PHASE_ORDER.index(event[0]))
    trial = (row.get("trial") or "").strip()
    try:
        number = int(trial) if trial else None
    except ValueError as err:
        msg = f"{where}: trial = {trial!r} is not a whole number"
        raise BagImportError(msg) from err
    window = Window(row["object"].strip(), row["action"].strip(), number, tuple(events))
    return _check_window(window, where)


def windows_from_csv(path: Path, time_unit: str, origin_ns: int) -> list[Window]:
    """Read windows from a CSV: start, stop, object, action[, trial][, approach, ...].

    Raises:
        BagImportError: The file cannot be read, lacks a column, or a row is malformed.
    """
    try:
        with Path(path).open(newline="", encoding="utf-8") as handle:
            rows = list(csv.DictReader(handle))
    except OSError as err:
        msg = f"{path}: cannot read the windows ({err.strerror}); check the [windows] csv path"
        raise BagImportError(msg) from err
    required = ("start", "stop", "object", "action")
    if rows and (missing := [c for c in required if c not in rows[0]]):
        msg = f"{path}: no column {', '.join(missing)}; the header needs {', '.join(required)}"
        raise BagImportError(msg)
    scale = TIME_UNITS[time_unit]
    return [
        _csv_window(row, scale, origin_ns, f"{path} row {number}")
        for number, row in enumerate(rows, start=2)
    ]


# -------------------------------------------------------------------------------- skin rows


@dataclass(frozen=True, slots=True)
class _Cells:
    """One modality's per-cell samples over the whole bag."""

    stamps: list[NDArray[np.int64]]
    receives: list[NDArray[np.int64]]
    values: list[NDArray[np.float64]]
    period_ns: int


def _cells(read: Mapping[str, _Topic], topic_map: TopicMap, modality: Modality) -> _Cells:
    """Collect a modality's samples per cell (sorted by stamp) and the first cell's period.

    Raises:
        BagImportError: A cell topic has fewer than two samples.
    """
    spec = topic_map.skin[modality]
    stamps, receives, values = [], [], []
    for cell in topic_map.cells:
        topic = read[spec.topic_of(cell)]
        order = np.argsort(np.asarray(topic.stamps, dtype=np.int64), kind="stable")
        if order.size < 2:  # noqa: PLR2004
            msg = f"topic {spec.topic_of(cell)}: {order.size} messages; a cell needs at least 2"
            raise BagImportError(msg)
        stamp, receive = topic.arrays()
        raw = np.asarray(topic.values[str(modality)], dtype=np.float64)
        stamps.append(stamp[order])
        receives.append(receive[order])
        values.append(raw[order] * spec.scale + spec.offset)
    period = round(float(np.median(np.diff(stamps[0]))))
    if period <= 0:
        msg = f"topic {spec.topic_of(topic_map.cells[0])}: samples share stamps; check the clock"
        raise BagImportError(msg)
    return _Cells(stamps, receives, values, period)


@dataclass(frozen=True, slots=True)
class _Rows:
    """Aligned rows of one modality in one window."""

    stamps: NDArray[np.int64]
    receives: NDArray[np.int64]
    data: NDArray[np.float64]  # (rows, cells, channels)
    dropped: int
    max_offset_ns: int


def _nearest(stamps: NDArray[np.int64], targets: NDArray[np.int64]) -> NDArray[np.intp]:
    """Return, for each target, the index of the nearest stamp (sorted ``stamps``)."""
    right = np.clip(np.searchsorted(stamps, targets), 0, stamps.size - 1)
    left = np.clip(right - 1, 0, stamps.size - 1)
    closer_left = np.abs(stamps[left] - targets) <= np.abs(stamps[right] - targets)
    return np.where(closer_left, left, right)


def align_rows(cells: _Cells, start_ns: int, stop_ns: int) -> _Rows:
    """Align the cells' samples on the first cell's samples of a window.

    The rows are the first cell's samples in ``[start_ns, stop_ns)`` and its last sample
    before ``start_ns`` (so that the skin covers the window's first instant). Rows missing a
    cell or holding a non-finite value are dropped.
    """
    first = cells.stamps[0]
    lo = max(int(np.searchsorted(first, start_ns, side="right")) - 1, 0)
    hi = int(np.searchsorted(first, stop_ns, side="left"))
    stamps = first[lo:hi]
    receives = cells.receives[0][lo:hi].copy()
    data = np.empty((stamps.size, len(cells.stamps), cells.values[0].shape[1]))
    data[:, 0] = cells.values[0][lo:hi]
    keep = np.ones(stamps.size, dtype=bool)
    max_offset = 0
    for c in range(1, len(cells.stamps)):
        index = _nearest(cells.stamps[c], stamps)
        offset = np.abs(cells.stamps[c][index] - stamps)
        ok = 2 * offset < cells.period_ns
        keep &= ok
        data[:, c] = cells.values[c][index]
        receives = np.maximum(receives, cells.receives[c][index])
        if bool(ok.any()):
            max_offset = max(max_offset, int(offset[ok].max()))
    keep &= np.isfinite(data).reshape(stamps.size, -1).all(axis=1)
    return _Rows(stamps[keep], receives[keep], data[keep], int((~keep).sum()), max_offset)


def _block_end(
    stamps: NDArray[np.int64], start: int, size: int, tolerance: float, period: int
) -> int:
    """Return the end of the block starting at row ``start`` (rows on the stamp grid)."""
    stop = start + 1
    while stop < stamps.size and stop - start < size:
        grid = int(stamps[start]) + (stop - start) * period
        if abs(int(stamps[stop]) - grid) > tolerance:
            break
        stop += 1
    return stop


def skin_blocks(
    modality: Modality, rows: _Rows, period_ns: int, max_jitter: float
) -> tuple[list[SkinBlock], int, int]:
    """Pack rows into blocks of about 0.1 s with stamps ``first + i * period``.

    A row whose stamp is not after the previous block's last grid stamp (possible only with
    stamps closer than the jitter tolerance) is dropped: stamps must strictly increase.

    Returns:
        The blocks, the largest deviation of a row's stamp from its block's grid (ns) and
        the number of rows dropped.
    """
    size = max(1, round(BLOCK_NS / period_ns))
    tolerance = max_jitter * period_ns
    blocks: list[SkinBlock] = []
    deviation = dropped = 0
    last = None
    start = 0
    while start < rows.stamps.size:
        if last is not None and int(rows.stamps[start]) <= last:
            dropped, start = dropped + 1, start + 1
            continue
        stop = _block_end(rows.stamps, start, size, tolerance, period_ns)
        grid = int(rows.stamps[start]) + np.arange(stop - start, dtype=np.int64) * period_ns
        deviation = max(deviation, int(np.abs(rows.stamps[start:stop] - grid).max()))
        blocks.append(
            SkinBlock(
                modality=modality,
                stamp_ns=int(rows.stamps[start]),
                period_ns=period_ns,
                receive_ns=int(rows.receives[start:stop].max()),
                data=rows.data[start:stop].astype(np.float32),
            )
        )
        last, start = int(grid[-1]), stop
    return blocks, deviation, dropped


# -------------------------------------------------------------------------------- writing


@dataclass(slots=True)
class ImportReport:
    """What an import did.

    Attributes:
        bag: The bag.
        out: The dataset directory.
        written: The recordings written, in window order.
        dropped_rows: Skin rows dropped (a cell without a sample, a non-finite value, a stamp
            out of order), per modality.
        dropped_samples: Joint states and poses dropped (repeated stamp, non-finite value).
        max_cell_offset_ns: Largest time offset of an aligned cell sample, per modality.
        max_jitter_ns: Largest deviation of a stamp from its block's grid, per modality.
        index: The rebuilt dataset index.
    """

    bag: Path
    out: Path
    written: list[Path] = field(default_factory=list)
    dropped_rows: dict[str, int] = field(default_factory=dict)
    dropped_samples: dict[str, int] = field(default_factory=dict)
    max_cell_offset_ns: dict[str, int] = field(default_factory=dict)
    max_jitter_ns: dict[str, int] = field(default_factory=dict)
    index: Path | None = None

    def note(self, modality: Modality, rows: _Rows, jitter_ns: int, dropped: int) -> None:
        """Add one window's alignment figures of a modality."""
        key = str(modality)
        self.dropped_rows[key] = self.dropped_rows.get(key, 0) + rows.dropped + dropped
        offset = max(self.max_cell_offset_ns.get(key, 0), rows.max_offset_ns)
        self.max_cell_offset_ns[key] = offset
        self.max_jitter_ns[key] = max(self.max_jitter_ns.get(key, 0), jitter_ns)


@dataclass(frozen=True, slots=True)
class _Robot:
    """One robot topic over the whole bag: sorted, strictly increasing stamps, finite values."""

    topic: str
    stamps: NDArray[np.int64]
    receives: NDArray[np.int64]
    values: dict[str, NDArray[np.float64]]
    dropped: int

    @classmethod
    def create(cls, topic: str, read: _Topic) -> _Robot:
        """Sort by stamp; drop repeated stamps and samples with a non-finite value."""
        stamps, receives = read.arrays()
        values = {k: np.asarray(v, dtype=np.float64) for k, v in read.values.items()}
        order = np.argsort(stamps, kind="stable")
        stamps, receives = stamps[order], receives[order]
        values = {k: v[order] for k, v in values.items()}
        keep = np.ones(stamps.size, dtype=bool)
        keep[1:] = np.diff(stamps) > 0
        for array in values.values():
            keep &= np.isfinite(array).reshape(stamps.size, -1).all(axis=1)
        kept = {k: v[keep] for k, v in values.items()}
        return cls(topic, stamps[keep], receives[keep], kept, int((~keep).sum()))

    def between(self, start_ns: int, stop_ns: int) -> range:
        """Return the sample indices with stamps in ``[start_ns, stop_ns)``."""
        lo, hi = np.searchsorted(self.stamps, [start_ns, stop_ns], side="left")
        return range(int(lo), int(hi))


def _robot_items(joints: _Robot, poses: _Robot, start_ns: int, stop_ns: int) -> list[StreamItem]:
    """Return the joint samples and poses stamped inside ``[start_ns, stop_ns)``."""
    items: list[StreamItem] = []
    j = joints.values
    for i in joints.between(start_ns, stop_ns):
        stamp, receive = int(joints.stamps[i]), int(joints.receives[i])
        items.append(
            JointSample(stamp, receive, j["position"][i], j["velocity"][i], j["effort"][i])
        )
    p = poses.values
    for i in poses.between(start_ns, stop_ns):
        stamp, receive = int(poses.stamps[i]), int(poses.receives[i])
        items.append(PoseSample(stamp, receive, p["position"][i], p["orientation"][i]))
    return items


@dataclass(frozen=True, slots=True)
class _Signals:
    """Everything a window's file is cut from."""

    cells: Mapping[Modality, _Cells]
    joints: _Robot
    poses: _Robot


def _check_duration(window: Window, action: ActionSpec) -> None:
    """Refuse a window whose execute phase is shorter than the action's duration.

    The reader refuses such a file (tolerance 1 % + 1 ms), so the import stops first.

    Raises:
        BagImportError: The execute phase is too short.
    """
    start = next(stamp for phase, stamp in window.events if phase == Phase.EXECUTE)
    stop = next(stamp for phase, stamp in window.events if stamp > start)
    needed = round(action.duration_s * (1 - DURATION_TOLERANCE) * _NS_PER_S) - 1_000_000
    if stop - start < needed:
        msg = (
            f"{window.describe()}: its execute phase lasts {(stop - start) / _NS_PER_S:.3f} s, "
            f"action {action.id} lasts {action.duration_s:g} s; fix the window, or declare the "
            f"lab's action under [actions.<id>] in the topic map with its duration_s"
        )
        raise BagImportError(msg)


def _window_items(
    window: Window, signals: _Signals, topic_map: TopicMap, report: ImportReport
) -> list[StreamItem]:
    """Return every stream item of one window, ordered by receive time.

    Raises:
        BagImportError: A channel has no sample inside the window.
    """
    start, stop = window.start_ns, window.stop_ns
    items: list[StreamItem] = [PhaseEvent(stamp, stamp, phase) for phase, stamp in window.events]
    for modality, cells in signals.cells.items():
        rows = align_rows(cells, start, stop)
        blocks, jitter, dropped = skin_blocks(modality, rows, cells.period_ns, topic_map.max_jitter)
        if not blocks:
            topic = topic_map.skin[modality].topic
            msg = f"{window.describe()}: no {modality} samples of {topic} with every cell inside it"
            raise BagImportError(msg)
        report.note(modality, rows, jitter, dropped)
        items.extend(blocks)
    robot = _robot_items(signals.joints, signals.poses, start, stop)
    for kind, topic in ((JointSample, topic_map.joint_topic), (PoseSample, topic_map.pose_topic)):
        if not any(isinstance(item, kind) for item in robot):
            msg = f"{window.describe()}: no message of {topic} inside it; check the window"
            raise BagImportError(msg)
    items.extend(robot)
    items.sort(key=lambda item: item.receive_ns)
    return items


def _catalog_entry(
    kind: str, wanted: str, declared: Mapping[str, Any], catalog: Mapping[str, Any], where: str
) -> Any:  # noqa: ANN401 (ObjectSpec or ActionSpec)
    """Return an object or action from the map's declarations, else from the catalog.

    Raises:
        BagImportError: Neither knows it.
    """
    if wanted in declared:
        return declared[wanted]
    if wanted in catalog:
        return catalog[wanted]
    msg = (
        f"{where}: {kind} {wanted!r} is neither in the {kind} catalog nor declared in the topic "
        f"map; add [{kind}s.{wanted}] to the map (or to the catalog)"
    )
    raise BagImportError(msg)


def _existing_trials(out: Path, object_id: str, action_id: str) -> int:
    """Return the highest trial number recorded in ``out`` for (object, action), 0 if none."""
    numbers = [int(p.stem) for p in (Path(out) / object_id / action_id).glob("*.mcap")]
    return max((n for n in numbers if n > 0), default=0)


def plan_paths(windows: Sequence[Window], out: Path) -> list[tuple[Window, int, Path]]:
    """Give every window its trial number and output path.

    Windows without a trial continue after the highest trial in ``out`` (and in this import).

    Raises:
        BagImportError: A path exists already or two windows get the same path.
    """
    used: dict[tuple[str, str], int] = {}
    planned: list[tuple[Window, int, Path]] = []
    seen: set[Path] = set()
    for window in windows:
        pair = (window.object_id, window.action_id)
        if pair not in used:
            used[pair] = _existing_trials(out, *pair)
        trial = window.trial if window.trial is not None else used[pair] + 1
        used[pair] = max(used[pair], trial)
        path = recording_path(out, window.object_id, window.action_id, trial)
        if path.exists() or path in seen:
            msg = (
                f"{path}: {window.describe()} would overwrite a recording; recordings are never "
                "overwritten: remove its trial number to number it on, or choose another --out"
            )
            raise BagImportError(msg)
        seen.add(path)
        planned.append((window, trial, path))
    return planned


def _origin(read: Mapping[str, _Topic]) -> int:
    """Return the earliest stamp of every topic read (origin of relative CSV times)."""
    firsts = [min(topic.stamps) for topic in read.values() if topic.stamps]
    return min(firsts, default=0)


def bag_windows(topic_map: TopicMap, read: Mapping[str, _Topic]) -> list[Window]:
    """Return the action windows named by the map (annotation topic or CSV)."""
    source = topic_map.windows
    if source.source == "topic":
        return windows_from_annotations(read[source.topic], source.topic)
    if source.csv is None:
        msg = f"{topic_map.path}: [windows] source = 'csv' needs csv = 'file' or --windows FILE"
        raise BagImportError(msg)
    origin = _origin(read) if source.relative else 0
    return windows_from_csv(source.csv, source.time_unit, origin)


def import_bag(
    bag: Path,
    topic_map: TopicMap,
    out: Path,
    *,
    objects: Mapping[str, ObjectSpec],
    actions: Mapping[str, ActionSpec],
    on_written: Callable[[Path], Any] | None = None,
) -> ImportReport:
    """Import a bag: one recording per action window, then the dataset index.

    Args:
        bag: A ROS 1 ``.bag`` file or a ROS 2 bag directory (sqlite3 or MCAP).
        topic_map: What the bag's topics carry
            (:func:`recorder.bagimport._topicmap.load_topic_map`).
        out: Dataset directory; existing recordings are never overwritten.
        objects: Object catalog (the map's declarations take precedence).
        actions: Action catalog (the map's declarations take precedence).
        on_written: Called with every recording written.

    Returns:
        The written recordings and the alignment figures.

    Raises:
        BagImportError: The bag, the map or a window is wrong; files of windows written before
            the failing one are kept and indexed on the next import.
    """
    bag, out = Path(bag), Path(out)
    read = read_bag(bag, topic_map)
    windows = bag_windows(topic_map, read)
    if not windows:
        msg = f"{bag}: no action windows found; check the [windows] of {topic_map.path}"
        raise BagImportError(msg)
    planned = plan_paths(windows, out)
    specs = [
        (
            _catalog_entry("object", w.object_id, topic_map.objects, objects, w.describe()),
            _catalog_entry("action", w.action_id, topic_map.actions, actions, w.describe()),
        )
        for w, _, _ in planned
    ]
    for (window, _, _), (_, action) in zip(planned, specs, strict=True):
        _check_duration(window, action)
    signals = _Signals(
        cells={modality: _cells(read, topic_map, modality) for modality in Modality},
        joints=_Robot.create(topic_map.joint_topic, read[topic_map.joint_topic]),
        poses=_Robot.create(topic_map.pose_topic, read[topic_map.pose_topic]),
    )
    report = ImportReport(bag, out)
    report.dropped_samples = {
        "joint_states": signals.joints.dropped,
        "tcp_pose": signals.poses.dropped,
    }
    rig = _rig_description(bag, topic_map, read[topic_map.joint_topic].missing)
    for (window, trial, path), (obj, action) in zip(planned, specs, strict=True):
        items = _window_items(window, signals, topic_map, report)
        metadata = RecordingMetadata(
            object_id=obj.id,
            object_name=obj.name,
            object_description=obj.description,
            action_id=action.id,
            action_kind=str(action.kind),
            action_parameters=action.parameters(),
            trial=trial,
            rig=check_rig(rig),
            seed=0,
            source="import",
            software_version=software_version(),
            schema_version=SCHEMA_VERSION,
        )
        info = RecordingInfo(metadata, tuple(topic_map.joint_names))
        with RecordingWriter(path, info) as writer:
            for item in items:
                writer.write(item)
        report.written.append(path)
        if on_written is not None:
            on_written(path)
    report.index = write_index(out)
    return report


def _rig_description(bag: Path, topic_map: TopicMap, missing: Iterable[str]) -> dict[str, str]:
    """Return the rig metadata of imported recordings."""
    return {
        "kind": "imported",
        "source": bag.name,
        "topic_map": topic_map.path.name,
        "stamps": topic_map.stamps,
        "cells": json.dumps(list(topic_map.cells)),
        "joints_not_recorded": json.dumps(sorted(missing)),
    }


def bag_topics(bag: Path) -> Iterable[tuple[str, str, int]]:
    """Return (topic, type, message count) of every connection of a bag, for help messages.

    Raises:
        BagImportError: The bag cannot be read.
    """
    try:
        with AnyReader([Path(bag)]) as reader:
            return [(c.topic, c.msgtype, c.msgcount) for c in reader.connections]
    except _READ_ERRORS as err:
        msg = f"{bag}: cannot read the bag ({err})"
        raise BagImportError(msg) from err
