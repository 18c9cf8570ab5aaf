"""Reading a lab's bags as one stream of typed samples (rosbags' ``AnyReader``).

Messages are read in bag order, one at a time (memory does not grow with the bag), and each
mapped topic's messages become samples: a stamp in integer ns on the map's clock, the receive
time, and values. A skin message may carry several samples (a driver that batches, e.g. 22
vibration samples per 100 Hz message): their stamps are the message stamp plus the exact
integer offsets of :meth:`SkinField.offsets_ns`. Stamps of one topic must increase: a stamp
that goes back is refused with the topic, the time and the fix, never re-sorted.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import Nodetype
from rosbags.rosbag1 import ReaderError as Ros1ReaderError
from rosbags.rosbag2 import ReaderError as Ros2ReaderError
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore

from recorder.errors import BagImportError

if TYPE_CHECKING:
    from collections.abc import Iterator, Sequence

    from numpy.typing import NDArray
    from rosbags.interfaces import Connection
    from rosbags.typesys.store import Typestore

    from recorder.bagimport._topicmap import SkinField, TopicMap

_NS_PER_S = 1_000_000_000
JOINT_TYPE = "sensor_msgs/msg/JointState"
POSE_TYPE = "geometry_msgs/msg/PoseStamped"
ANNOTATION_TYPE = "std_msgs/msg/String"
#: Largest message the import accepts (a skin block of a second at 10 kHz is ~1 MB).
MAX_MESSAGE_BYTES = 64 * 1024 * 1024
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


@dataclass(frozen=True, slots=True)
class Samples:
    """Samples of one series from one message.

    Attributes:
        key: The series: ``("skin", modality, cell index)``, ``("joints",)`` or ``("pose",)``.
        stamps: Stamps of the samples, int64 ns.
        receive_ns: Receive time of the message.
        values: Values, shape (samples, width), float64, raw units.
    """

    key: tuple[Any, ...]
    stamps: NDArray[np.int64]
    receive_ns: int
    values: NDArray[np.float64]


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


def _field_names(message: Any) -> list[str]:  # noqa: ANN401
    """Return the field names of a message, for error messages."""
    return [f.name for f in dataclasses.fields(message) if not f.name.startswith("_")]


def field_values(message: Any, path: str, topic: str) -> NDArray[np.float64]:  # noqa: ANN401
    """Return a (dotted) field of a message as a float64 vector.

    Raises:
        BagImportError: The field does not exist or is not numeric.
    """
    value = message
    for part in path.split("."):
        if not dataclasses.is_dataclass(value) or not hasattr(value, part):
            msg = (
                f"topic {topic} carries {message.__msgtype__}: no field {path!r} "
                f"(fields: {', '.join(_field_names(message))}); fix its 'field' in the topic map "
                "or map the topic that carries the values"
            )
            raise BagImportError(msg)
        value = getattr(value, part)
    if isinstance(value, str | bytes) or dataclasses.is_dataclass(value):
        msg = (
            f"topic {topic} carries {message.__msgtype__}: field {path!r} is not numeric; "
            "map a number or an array of numbers"
        )
        raise BagImportError(msg)
    try:
        return np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as err:
        msg = f"topic {topic} carries {message.__msgtype__}: field {path!r} is not numeric"
        raise BagImportError(msg) from err


@dataclass(slots=True)
class _Order:
    """The last stamp of a series: stamps must increase."""

    last: int | None = None

    def check(self, first: int, last: int, topic: str, fix: str) -> bool:
        """Return False for a repeated stamp (dropped); refuse a stamp that goes back.

        Raises:
            BagImportError: ``first`` precedes the previous stamp.
        """
        if self.last is not None and first <= self.last:
            if first == self.last:
                return False
            msg = (
                f"topic {topic}: stamp {first} ns precedes the previous sample's {self.last} ns; "
                f"stamps are never re-sorted: {fix}"
            )
            raise BagImportError(msg)
        self.last = last
        return True


@dataclass(slots=True)
class SkinTopic:
    """One skin cell topic: the modalities it carries for one cell."""

    topic: str
    cell: int
    fields: tuple[SkinField, ...]
    widths: dict[str, int] = field(default_factory=dict)
    order: dict[str, _Order] = field(default_factory=dict)
    offsets: dict[str, NDArray[np.int64]] = field(default_factory=dict)
    repeated: int = 0

    def __post_init__(self) -> None:
        """Precompute each modality's sample offsets."""
        for spec in self.fields:
            self.offsets[spec.modality] = np.asarray(spec.offsets_ns(), dtype=np.int64)
            self.order[spec.modality] = _Order()

    def _width(self, spec: SkinField, size: int, msgtype: str) -> int:
        """Return the values per sample, checked against the map and the first message."""
        count = spec.samples_per_message
        width = size // count if size % count == 0 else 0
        expected = spec.width or self.widths.get(spec.modality, width)
        if width == 0 or width != expected:
            msg = (
                f"topic {self.topic} carries {msgtype}: field {spec.field!r} has {size} values, "
                f"not {count} samples x {expected or 'n'} values; fix width or "
                f"samples_per_message of [skin.{spec.modality}] in the topic map"
            )
            raise BagImportError(msg)
        self.widths[spec.modality] = width
        return width

    def extract(self, message: Any, stamp: int, receive_ns: int) -> list[Samples]:  # noqa: ANN401
        """Return the samples of one message, per modality.

        Raises:
            BagImportError: A field is missing, has the wrong width, or stamps go back.
        """
        out = []
        for spec in self.fields:
            values = field_values(message, spec.field, self.topic)
            width = self._width(spec, values.size, message.__msgtype__)
            stamps = stamp + self.offsets[spec.modality]
            fix = (
                f"if the driver batches samples, set samples_per_message and rate_hz of "
                f"[skin.{spec.modality}] (now {spec.samples_per_message} per message); otherwise "
                'fix the driver\'s stamps or use [time] stamps = "log"'
            )
            if not self.order[spec.modality].check(
                int(stamps[0]), int(stamps[-1]), self.topic, fix
            ):
                self.repeated += 1
                continue
            key = ("skin", spec.modality, self.cell)
            out.append(Samples(key, stamps, receive_ns, values.reshape(-1, width)))
        return out


@dataclass(slots=True)
class JointTopic:
    """The joint-state topic: positions, velocities and efforts picked by name."""

    topic: str
    wanted: tuple[str, ...]
    scale: float
    names: tuple[str, ...] = ()
    missing: set[str] = field(default_factory=set)
    order: _Order = field(default_factory=_Order)
    skipped: int = 0
    repeated: int = 0
    _index: dict[tuple[str, ...], list[int] | None] = field(default_factory=dict)

    def _pick(self, names: tuple[str, ...]) -> list[int] | None:
        """Return the columns of the output joints in a message naming ``names``."""
        if names not in self._index:
            if not self.names:
                self.names = self.wanted or names
            present = [n for n in self.names if n in names]
            if present and len(present) != len(self.names):
                msg = (
                    f"topic {self.topic}: joints {[n for n in self.names if n not in names]} are "
                    f"not in a message naming {list(names)}; fix [joint_states] names"
                )
                raise BagImportError(msg)
            self._index[names] = [names.index(n) for n in self.names] if present else None
        return self._index[names]

    def extract(self, message: Any, stamp: int, receive_ns: int) -> list[Samples]:  # noqa: ANN401
        """Return one joint sample (positions scaled; empty velocities or efforts: zeros).

        Raises:
            BagImportError: A message lacks positions or stamps go back.
        """
        names = tuple(message.name)
        index = self._pick(names)
        if index is None:  # another part of the robot on the same topic (a gripper)
            self.skipped += 1
            return []
        rows = []
        for quantity in ("position", "velocity", "effort"):
            array = np.asarray(getattr(message, quantity), dtype=np.float64)
            if array.size != len(names):
                if quantity == "position":
                    msg = f"topic {self.topic}: a message at {stamp} ns has no joint positions"
                    raise BagImportError(msg)
                self.missing.add(quantity)
                array = np.zeros(len(names))
            rows.append(array[index] * (self.scale if quantity == "position" else 1.0))
        if not self.order.check(stamp, stamp, self.topic, "fix the robot driver's stamps"):
            self.repeated += 1
            return []
        stamps = np.array([stamp], dtype=np.int64)
        return [Samples(("joints",), stamps, receive_ns, np.concatenate(rows)[None, :])]


@dataclass(slots=True)
class PoseTopic:
    """The tool-pose topic: position (scaled to m) and quaternion (x, y, z, w)."""

    topic: str
    scale: float
    order: _Order = field(default_factory=_Order)
    repeated: int = 0

    def extract(self, message: Any, stamp: int, receive_ns: int) -> list[Samples]:  # noqa: ANN401
        """Return one pose sample.

        Raises:
            BagImportError: Stamps go back.
        """
        if not self.order.check(stamp, stamp, self.topic, "fix the robot driver's stamps"):
            self.repeated += 1
            return []
        p, q = message.pose.position, message.pose.orientation
        scale = self.scale
        values = np.array([[p.x * scale, p.y * scale, p.z * scale, q.x, q.y, q.z, q.w]])
        return [Samples(("pose",), np.array([stamp], dtype=np.int64), receive_ns, values)]


Extractor = SkinTopic | JointTopic | PoseTopic


def extractors(topic_map: TopicMap) -> dict[str, Extractor]:
    """Return topic -> extractor for every mapped data topic."""
    fields: dict[tuple[str, int], list[SkinField]] = {}
    for spec in topic_map.skin.values():
        for index, cell in enumerate(topic_map.cells):
            fields.setdefault((spec.topic_of(cell), index), []).append(spec)
    out: dict[str, Extractor] = {}
    for (topic, index), specs in fields.items():
        if topic in out:
            msg = (
                f"{topic_map.path}: topic {topic} is mapped to two cells; give [skin] topics a "
                "{cell} placeholder or map one cell"
            )
            raise BagImportError(msg)
        out[topic] = SkinTopic(topic, index, tuple(specs))
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


def check_fields(reader: AnyReader, connections: Sequence[Connection], topic_map: TopicMap) -> None:
    """Check, before reading, that every skin field exists, is numeric, and has a header.

    Raises:
        BagImportError: A field is missing or not numeric, or a header clock lacks a header.
    """
    store = reader.typestore
    types = {c.topic: c.msgtype for c in connections}
    for topic, extractor in extractors(topic_map).items():
        msgtype = types[topic]
        names = [name for name, _ in store.fielddefs[msgtype][1]]
        for spec in getattr(extractor, "fields", ()):
            node = _field_type(store, msgtype, spec.field)
            if node is None or not _numeric(node):
                problem = "no field" if node is None else "a field that is not numeric:"
                msg = (
                    f"topic {topic} carries {msgtype}: {problem} {spec.field!r} "
                    f"(fields: {', '.join(names)}); fix 'field' of [skin.{spec.modality}] in "
                    "the topic map or map the topic that carries the values"
                )
                raise BagImportError(msg)
        if topic_map.stamps == "header" and _field_type(store, msgtype, "header.stamp") is None:
            msg = (
                f'topic {topic} ({msgtype}) has no header.stamp; set [time] stamps = "log" '
                "in the topic map to use the receive time"
            )
            raise BagImportError(msg)


def open_reader(bags: Sequence[Path], topic_map: TopicMap) -> AnyReader:
    """Return an (unopened) reader of the bags with the map's fallback definitions."""
    return AnyReader([Path(b) for b in bags], default_typestore=typestore(topic_map))


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


def bag_topics(bags: Sequence[Path]) -> list[tuple[str, str, int]]:
    """Return (topic, type, message count) of every connection of the bags, for help messages.

    Raises:
        BagImportError: A bag cannot be read.
    """
    try:
        with AnyReader([Path(b) for b in bags]) as reader:
            return [(c.topic, c.msgtype, c.msgcount) for c in reader.connections]
    except READ_ERRORS as err:
        msg = f"{', '.join(map(str, bags))}: cannot read the bag ({err!r})"
        raise BagImportError(msg) from err
