"""The topic map of a bag import: which lab topics carry what, in which units (TOML).

The format is documented by the commented example ``recorder/data/topic_map.example.toml``;
:func:`load_topic_map` parses it strictly (unknown keys, wrong types and missing keys are
errors naming the file, the table and the fix). TOML floats are read as decimals, so rates
and times reach the importer as exact fractions, never as binary floats.

Maps written for atikt 0.1 (a UR10, a pose topic and all four HEX-o-SKIN modalities) keep
their meaning: every key they use is still valid. What is new is optional: the robot tables,
the per-modality ``width``, ``samples_per_message``, ``rate_hz``, ``batch_stamp``, ``timing``,
``counter`` and ``counter_modulo``, ``field`` as a list or indexed (``"electrodes[{cell}]"``),
and free action parameters.
"""

from __future__ import annotations

import dataclasses
import re
import tomllib
from dataclasses import dataclass
from decimal import Decimal
from fractions import Fraction
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, NoReturn

from recorder.errors import BagImportError
from schemas import (
    MAX_CELLS,
    VOCABULARY,
    ContractError,
    check_id,
    check_parameters,
    load_toml,
)

if TYPE_CHECKING:
    from collections.abc import Mapping

#: Clocks a map can cut windows on.
STAMP_CLOCKS = ("header", "log")
#: Sources of action windows.
WINDOW_SOURCES = ("topic", "csv")
#: Units of CSV window times, in ns.
TIME_UNITS = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "ns": 1}
#: Which sample of a batched message its header stamp belongs to.
BATCH_STAMPS = ("first", "last")
#: How a modality's sample stamps are made: from each message's stamp, or from the rate.
TIMINGS = ("message", "rate")
#: A mapped field: a dotted path, optionally indexed by the cell id or a fixed element.
_FIELD = re.compile(r"^(?P<path>[A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*)(?:\[(?P<index>\{cell\}|\d+)\])?$")
#: The packaged, commented example map.
EXAMPLE = "topic_map.example.toml"
#: Keys of an action table that are not parameters.
_ACTION_KEYS = ("kind", "description", "trials")
_NS_PER_S = 1_000_000_000
#: The largest lab cell id (the ids are kept in the recording's rig metadata).
MAX_CELL_ID = 2**31 - 1
#: The largest ``[time] max_delay_s``, s: a delay beyond it is a stalled topic, not transport.
MAX_DELAY_S = 60
#: The largest ``max_message_kib`` (1 GiB): a limit that protects the other topics' memory.
MAX_MESSAGE_KIB = 1 << 20
#: Keys that changed meaning or name, with the new syntax (one line each).
_RENAMED: Mapping[str, str] = MappingProxyType(
    {
        "robot": "the robot is mapped by [joint_states] and [tool_pose] tables (both optional)",
        "channels": "[skin.<modality>] with topic and field; the width comes from the data",
    }
)


@dataclass(frozen=True, slots=True)
class FieldPart:
    """One field a modality's values are read from (``field`` of a ``[skin.<m>]`` table).

    Attributes:
        path: Dotted path of the message field.
        index: A fixed element of an array field (``"temperatures[1]"``), or None.
        per_cell: The element is the cell id (``"electrodes[{cell}]"``): one message, many cells.
    """

    path: str
    index: int | None = None
    per_cell: bool = False

    def element(self, cell: int) -> int | None:
        """Return the element of the field read for ``cell`` (None: the whole field)."""
        return cell if self.per_cell else self.index


@dataclass(frozen=True, slots=True)
class SkinField:
    """Where one skin modality is found, per cell.

    Attributes:
        modality: The contract's modality name.
        topic: Topic pattern; ``{cell}`` is replaced by each cell id.
        field: The field as the map names it (one path, or several joined by ", ").
        scale: SI value = raw * scale + offset.
        offset: See ``scale``.
        width: Values per cell and sample the map insists on (0: taken from the data).
        samples_per_message: Samples per message (a driver that batches, e.g. 22).
        period_ns: Exact sample period (from ``rate_hz``), or None to measure it.
        batch_stamp: ``first`` or ``last``: the sample the header stamp belongs to.
        parts: The fields whose values, side by side, are the modality's values per sample
            (empty: ``field`` itself).
        timing: ``message`` (sample stamps from each message's stamp) or ``rate`` (from the
            sensor's rate within runs of messages; the message stamps anchor the runs).
        counter: A field counting the messages, or "". With ``timing = "rate"`` its jumps are
            lost frames within a run (else they are seen in the stamps); with either timing,
            ``listen`` and a ROS 2 skin count the topic's loss by it (else they count pauses
            of its stamps as gaps).
        counter_modulo: The counter wraps at this value (0: it does not wrap).
        max_message_bytes: Largest message of this modality's topics ``listen`` takes (0:
            ``[time] max_message_kib``).
    """

    modality: str
    topic: str
    field: str
    scale: float = 1.0
    offset: float = 0.0
    width: int = 0
    samples_per_message: int = 1
    period_ns: Fraction | None = None
    batch_stamp: str = "first"
    parts: tuple[FieldPart, ...] = ()
    timing: str = "message"
    counter: str = ""
    counter_modulo: int = 0
    max_message_bytes: int = 0

    @property
    def fields(self) -> tuple[FieldPart, ...]:
        """Return the fields read, in the order their values are placed."""
        return self.parts or (FieldPart(self.field),)

    @property
    def per_cell(self) -> bool:
        """Return whether one message carries every cell (a field indexed by ``{cell}``)."""
        return any(part.per_cell for part in self.fields)

    def topic_of(self, cell: int) -> str:
        """Return the topic of one cell."""
        return self.topic.replace("{cell}", str(cell))

    def offsets_ns(self) -> tuple[int, ...]:
        """Return each sample's time after the message stamp, in integer ns (exact floor).

        Sample ``i`` of a batched message lies ``i * period`` after the first sample; with a
        period that is not a whole number of ns the offset is rounded down, so every stamp is
        within 1 ns of the true instant and errors never accumulate (each message re-anchors).
        """
        count = self.samples_per_message
        if count == 1 or self.period_ns is None:
            return (0,)
        num, den = self.period_ns.numerator, self.period_ns.denominator
        if self.batch_stamp == "first":
            return tuple((i * num) // den for i in range(count))
        return tuple(-(((count - 1 - i) * num) // den) for i in range(count))


@dataclass(frozen=True, slots=True)
class RobotTopic:
    """A robot topic: joint states or the tool pose.

    Attributes:
        topic: The topic.
        names: Joint names to keep, in output order (empty: all, as the messages list them).
        position_scale: Positions to SI (rad or m).
        max_message_bytes: Largest message ``listen`` takes (0: ``[time] max_message_kib``).
    """

    topic: str
    names: tuple[str, ...] = ()
    position_scale: float = 1.0
    max_message_bytes: int = 0


@dataclass(frozen=True, slots=True)
class WindowSource:
    """Where the action windows come from.

    Attributes:
        source: ``topic`` (JSON annotations on a std_msgs/String topic) or ``csv``.
        topic: The annotation topic (source ``topic``).
        csv: The CSV of windows (source ``csv``).
        time_unit: Unit of the CSV times (see :data:`TIME_UNITS`).
        relative: CSV times count from the earliest stamp of the mapped topics.
    """

    source: str
    topic: str = ""
    csv: Path | None = None
    time_unit: str = "s"
    relative: bool = False


@dataclass(frozen=True, slots=True)
class LabObject:
    """An object declared in a map.

    Attributes:
        id: Object id (a directory name).
        name: Human-readable name.
        description: One line.
        novel: Whether it is new by default (runs choose roles with --new/--priors).
    """

    id: str
    name: str
    description: str = ""
    novel: bool = False


@dataclass(frozen=True, slots=True)
class LabAction:
    """An action: a lab's own (declared in a map) or one of the catalog's.

    Attributes:
        id: Action id.
        kind: One of the contract's kinds.
        parameters: Parameters in SI units; ``duration_s`` always.
        description: One line.
    """

    id: str
    kind: str
    parameters: Mapping[str, float]
    description: str = ""

    @property
    def duration_s(self) -> float:
        """Return the execute phase's length, s."""
        return self.parameters["duration_s"]


@dataclass(frozen=True, slots=True)
class TopicMap:
    """A parsed topic map (see ``recorder/data/topic_map.example.toml``).

    Attributes:
        path: The map file.
        stamps: ``header`` or ``log``: the clock of samples and windows.
        max_delay_ns: Longest time between a sample's stamp and its arrival in the bag.
        joints: Joint-state topic, or None (no arm).
        pose: Tool-pose topic, or None.
        cells: Lab cell ids, in output column order.
        max_jitter: Largest stamp deviation inside a block, in sample periods.
        skin: Where each mapped modality is (a subset of the contract's).
        windows: Where the action windows are.
        types: Message definitions by type name, for bags that lack them.
        objects: Objects declared in the map.
        actions: Actions declared in the map.
        max_message_bytes: Largest message of a mapped topic ``listen`` takes; a larger one
            is counted (malformed) and dropped at the reader. A topic's own table may set
            its own (:meth:`message_budget`).
    """

    path: Path
    stamps: str
    max_delay_ns: int
    joints: RobotTopic | None
    pose: RobotTopic | None
    cells: tuple[int, ...]
    max_jitter: float
    skin: Mapping[str, SkinField]
    windows: WindowSource
    types: Mapping[str, str]
    objects: Mapping[str, LabObject]
    actions: Mapping[str, LabAction]
    max_message_bytes: int = 4 << 20

    def message_budget(self, topic: str) -> tuple[int, str]:
        """Return the largest message ``listen`` takes on ``topic``, bytes, and where it is set.

        A ``max_message_kib`` of the table that maps the topic (``[skin.<modality>]``,
        ``[joint_states]``, ``[tool_pose]``) wins over ``[time]``'s; a topic two skin tables
        map gets the smaller of theirs.
        """
        own = [
            (field.max_message_bytes, f"[skin.{field.modality}]")
            for field in self.skin.values()
            if field.max_message_bytes and topic in {field.topic_of(cell) for cell in self.cells}
        ]
        own += [
            (robot.max_message_bytes, f"[{key}]")
            for key, robot in (("joint_states", self.joints), ("tool_pose", self.pose))
            if robot is not None and robot.max_message_bytes and robot.topic == topic
        ]
        return min(own) if own else (self.max_message_bytes, "[time]")

    def with_csv(self, csv: Path) -> TopicMap:
        """Return the map with its windows taken from ``csv`` (the ``--windows`` option)."""
        windows = WindowSource(
            "csv", csv=csv, time_unit=self.windows.time_unit, relative=self.windows.relative
        )
        return dataclasses.replace(self, windows=windows)


class _Table:
    """One TOML table read strictly: every key must be taken, with the right type."""

    def __init__(self, path: Path, name: str, data: Any) -> None:  # noqa: ANN401 (TOML value)
        self.path, self.name = path, name
        if not isinstance(data, dict):
            self.fail(f"[{name}] must be a table")
        self.data: dict[str, Any] = dict(data)
        self._taken: set[str] = set()

    def error(self, problem: str) -> BagImportError:
        """Return the error for a problem of this table."""
        return BagImportError(
            f"{self.path}: {problem}; see the commented example recorder/data/{EXAMPLE}"
        )

    def fail(self, problem: str) -> NoReturn:
        """Raise the error for a problem of this table.

        Raises:
            BagImportError: Always.
        """
        raise self.error(problem)

    def has(self, key: str) -> bool:
        """Return whether the table has ``key``."""
        return key in self.data

    def get(self, key: str, kind: type | tuple[type, ...], default: Any = ...) -> Any:  # noqa: ANN401
        """Return the value of ``key`` checked against ``kind`` (required without default)."""
        self._taken.add(key)
        if key not in self.data:
            if default is ...:
                self.fail(f"[{self.name}] needs the key {key!r}")
            return default
        value = self.data[key]
        if isinstance(value, bool) and kind is not bool:
            self.fail(f"[{self.name}] {key} = {value!r} must not be a boolean")
        if not isinstance(value, kind):
            self.fail(f"[{self.name}] {key} = {value!r} has the wrong type")
        return value

    def exact(self, key: str, default: Fraction) -> Fraction:
        """Return a finite number exactly (TOML floats are read as decimals)."""
        value = self.get(key, (int, Decimal), default)
        if isinstance(value, Decimal) and not value.is_finite():
            self.fail(f"[{self.name}] {key} = {value} must be finite")
        return Fraction(value)

    def number(self, key: str, default: float) -> float:
        """Return a finite number as a float (for unit conversions of float data)."""
        return float(self.exact(key, Fraction(default)))

    def integer(self, key: str, default: int, low: int, high: int | None = None) -> int:
        """Return an integer of at least ``low`` (and at most ``high``)."""
        value = int(self.get(key, int, default))
        if value < low:
            self.fail(f"[{self.name}] {key} = {value} must be at least {low}")
        if high is not None and value > high:
            self.fail(f"[{self.name}] {key} = {value} must be at most {high}")
        return value

    def table(self, key: str) -> _Table:
        """Return a required sub-table."""
        return _Table(self.path, f"{self.name}.{key}" if self.name else key, self.get(key, dict))

    def optional(self, key: str) -> _Table | None:
        """Return a sub-table, or None if absent."""
        return self.table(key) if self.has(key) else None

    def done(self) -> None:
        """Refuse keys that were not taken (a renamed key gets its new syntax)."""
        unknown = sorted(set(self.data) - self._taken)
        for key in unknown:
            if key in _RENAMED:
                self.fail(f"[{self.name or 'top level'}] {key} changed: {_RENAMED[key]}")
        if unknown:
            self.fail(f"[{self.name or 'top level'}] has unknown keys {unknown}")


def _period(table: _Table, samples: int) -> Fraction | None:
    """Return the exact sample period from ``rate_hz`` (required for batched messages)."""
    if not table.has("rate_hz"):
        if samples > 1:
            table.fail(f"[{table.name}] samples_per_message = {samples} needs rate_hz")
        return None
    rate = table.exact("rate_hz", Fraction(0))
    if rate <= 0:
        table.fail(f"[{table.name}] rate_hz = {rate} must be > 0")
    return Fraction(_NS_PER_S) / rate


def _field_parts(table: _Table, topic: str, samples: int) -> tuple[str, tuple[FieldPart, ...]]:
    """Return the ``field`` key as text and as parts (one field, or a list side by side)."""
    value = table.get("field", (str, list))
    names = [value] if isinstance(value, str) else value
    if not names or not all(isinstance(n, str) for n in names):
        table.fail(f'[{table.name}] field = {value!r} must be a field or a list ["a", "b"]')
    parts = []
    for name in names:
        match = _FIELD.match(name)
        if match is None:
            table.fail(
                f'[{table.name}] field = {name!r} is not a field path ("force", "data.force", '
                '"electrodes[{cell}]" or "temperatures[1]")'
            )
        index = match["index"]
        parts.append(
            FieldPart(
                match["path"],
                int(index) if index is not None and index.isdigit() else None,
                per_cell=index == "{cell}",
            )
        )
    if any(p.per_cell for p in parts) and "{cell}" in topic:
        table.fail(
            f"[{table.name}] topic = {topic!r} and field = {value!r} both name {{cell}}; a cell is "
            "either a topic or an element of a field: keep one placeholder"
        )
    if samples > 1 and any(p.per_cell or p.index is not None for p in parts):
        table.fail(
            f"[{table.name}] field = {value!r} picks elements, which a batched message "
            f"(samples_per_message = {samples}) does not allow; map the whole field"
        )
    return ", ".join(names), tuple(parts)


def _skin_field(table: _Table, modality: str) -> SkinField:
    samples = table.integer("samples_per_message", 1, 1)
    batch_stamp = table.get("batch_stamp", str, "first")
    if batch_stamp not in BATCH_STAMPS:
        table.fail(f"[{table.name}] batch_stamp = {batch_stamp!r} must be one of {BATCH_STAMPS}")
    timing = table.get("timing", str, "message")
    if timing not in TIMINGS:
        table.fail(f"[{table.name}] timing = {timing!r} must be one of {TIMINGS}")
    if timing == "rate" and not table.has("rate_hz"):
        table.fail(f'[{table.name}] timing = "rate" needs rate_hz (the sensor\'s sample rate)')
    counter = table.get("counter", str, "")
    modulo = table.integer("counter_modulo", 0, 0)
    if (counter and _FIELD.match(counter) is None) or "[" in counter:
        table.fail(f'[{table.name}] counter = {counter!r} must be a field path ("seq", "frame.id")')
    if modulo and not counter:
        table.fail(f"[{table.name}] counter_modulo = {modulo} needs counter = '<field>'")
    topic = table.get("topic", str)
    text, parts = _field_parts(table, topic, samples)
    field = SkinField(
        modality=modality,
        topic=topic,
        field=text,
        scale=table.number("scale", 1.0),
        offset=table.number("offset", 0.0),
        width=table.integer("width", 0, 0),
        samples_per_message=samples,
        period_ns=_period(table, samples),
        batch_stamp=batch_stamp,
        parts=parts if len(parts) > 1 or parts[0] != FieldPart(text) else (),
        timing=timing,
        counter=counter,
        counter_modulo=modulo,
        max_message_bytes=_budget(table),
    )
    table.done()
    return field


def _budget(table: _Table) -> int:
    """Return a table's own ``max_message_kib`` in bytes (0: the ``[time]`` one)."""
    if not table.has("max_message_kib"):
        return 0
    return table.integer("max_message_kib", 0, 1, MAX_MESSAGE_KIB) * 1024


def _skin(root: _Table) -> tuple[tuple[int, ...], float, dict[str, SkinField]]:
    table = root.table("skin")
    cells = table.get("cells", list)
    if not cells or not all(isinstance(c, int) and not isinstance(c, bool) for c in cells):
        table.fail("[skin] cells must be a non-empty list of integer cell ids")
    bad = [c for c in cells if not 0 <= c <= MAX_CELL_ID]
    if bad:  # a negative id would index a field from its end: another cell's values, silently
        table.fail(f"[skin] cells {bad[:3]}: give cell ids 0..{MAX_CELL_ID}")
    if len(cells) > MAX_CELLS:
        table.fail(f"[skin] cells lists {len(cells)} ids: give at most {MAX_CELLS}")
    if len(set(cells)) != len(cells):
        table.fail(f"[skin] cells {cells} repeats an id")
    jitter = table.number("max_jitter", 0.1)
    if not 0 <= jitter < 0.5:  # noqa: PLR2004 (beyond half a period a block could skip one)
        table.fail(f"[skin] max_jitter = {jitter} must lie in [0, 0.5)")
    fields = {
        modality: _skin_field(table.table(modality), modality)
        for modality in VOCABULARY.modalities
        if table.has(modality)
    }
    if not fields:
        table.fail(
            f"[skin] maps no modality; add [skin.<m>] for some of {list(VOCABULARY.modalities)}"
        )
    table.done()
    return tuple(cells), jitter, fields


def _robot(root: _Table, key: str, *, names: bool) -> RobotTopic | None:
    table = root.optional(key)
    if table is None:
        return None
    joint_names: tuple[str, ...] = ()
    if names:
        joint_names = tuple(table.get("names", list, []))
        if not all(isinstance(n, str) and n for n in joint_names):
            table.fail(f"[{key}] names must be a list of joint names")
        if len(set(joint_names)) != len(joint_names):
            table.fail(f"[{key}] names {list(joint_names)} repeats a joint")
    robot = RobotTopic(
        table.get("topic", str),
        joint_names,
        table.number("position_scale", 1.0),
        _budget(table),
    )
    table.done()
    return robot


def _windows(root: _Table) -> WindowSource:
    table = root.table("windows")
    source = table.get("source", str)
    if source not in WINDOW_SOURCES:
        table.fail(f"[windows] source = {source!r} must be one of {WINDOW_SOURCES}")
    topic = table.get("topic", str, "")
    csv = table.get("csv", str, "")
    unit = table.get("time_unit", str, "s")
    if unit not in TIME_UNITS:
        table.fail(f"[windows] time_unit = {unit!r} must be one of {tuple(TIME_UNITS)}")
    relative = table.get("relative", bool, False)
    table.done()
    if source == "topic" and not topic:
        table.fail("[windows] source = 'topic' needs topic = '/your/annotations'")
    csv_path = (table.path.parent / csv) if csv else None
    return WindowSource(source, topic, csv_path, unit, relative)


def _types(root: _Table) -> dict[str, str]:
    table = _Table(root.path, "types", root.get("types", dict, {}))
    texts = {}
    for name in list(table.data):
        file = table.path.parent / table.get(name, str)
        try:
            texts[name] = file.read_text("utf-8")
        except (OSError, UnicodeDecodeError) as err:
            msg = f"[types] {name!r}: cannot read {file} ({err}); fix the path"
            raise table.error(msg) from err
    table.done()
    return texts


def _check_id(table: _Table, what: str, value: str) -> str:
    try:
        return check_id(what, value)
    except ContractError as err:
        table.fail(f"[{table.name}] {err}")


def _objects(root: _Table) -> dict[str, LabObject]:
    objects = {}
    declared = root.get("objects", dict, {})
    for object_id in list(declared):
        table = _Table(root.path, f"objects.{object_id}", declared[object_id])
        objects[object_id] = LabObject(
            id=_check_id(table, "object", object_id),
            name=table.get("name", str),
            description=table.get("description", str, ""),
            novel=table.get("novel", bool, False),
        )
        table.done()
    return objects


def _action(table: _Table, action_id: str) -> LabAction:
    kind = table.get("kind", str)
    if kind not in VOCABULARY.kinds:
        table.fail(f"[{table.name}] kind = {kind!r} must be one of {list(VOCABULARY.kinds)}")
    table.get("trials", int, 0)  # a catalog key: how many to record; meaningless for imports
    description = table.get("description", str, "")
    parameters: dict[str, float] = {}
    for key in sorted(set(table.data) - set(_ACTION_KEYS)):
        parameters[key] = table.number(key, 0.0)
    try:
        check_parameters(kind, parameters, ("duration_s", *VOCABULARY.kind(kind).parameters))
    except ContractError as err:
        table.fail(f"[{table.name}] {err}")
    table.done()
    return LabAction(
        _check_id(table, "action", action_id), kind, MappingProxyType(parameters), description
    )


def _actions(root: _Table) -> dict[str, LabAction]:
    declared = root.get("actions", dict, {})
    return {
        action_id: _action(
            _Table(root.path, f"actions.{action_id}", declared[action_id]), action_id
        )
        for action_id in list(declared)
    }


def _read(path: Path) -> dict[str, Any]:
    try:
        return load_toml(path, parse_float=Decimal)
    except OSError as err:
        msg = f"{path}: cannot read the topic map ({err.strerror}); check --topic-map"
        raise BagImportError(msg) from err
    except UnicodeDecodeError as err:
        msg = f"{path}: the topic map is not UTF-8 (byte {err.start}); save it as UTF-8"
        raise BagImportError(msg) from err
    except tomllib.TOMLDecodeError as err:
        msg = f"{path}: not valid TOML ({err}); fix the topic map's syntax"
        raise BagImportError(msg) from err


def _time(root: _Table) -> tuple[str, int, int]:
    time = root.table("time") if root.has("time") else _Table(root.path, "time", {})
    stamps = time.get("stamps", str, "header")
    if stamps not in STAMP_CLOCKS:
        time.fail(f"[time] stamps = {stamps!r} must be one of {STAMP_CLOCKS}")
    delay = time.exact("max_delay_s", Fraction(2))
    if not 0 <= delay <= MAX_DELAY_S:  # an action's messages wait in memory this long
        time.fail(
            f"[time] max_delay_s = {float(delay):g} must lie in [0, {MAX_DELAY_S}] s (an "
            "action's messages wait in memory this long after its end)"
        )
    largest = time.integer("max_message_kib", 4096, 1, MAX_MESSAGE_KIB)
    time.done()
    return stamps, int(delay * _NS_PER_S), largest * 1024


def load_topic_map(path: Path) -> TopicMap:
    """Read and check a topic map.

    Args:
        path: The map (TOML), documented by ``recorder/data/topic_map.example.toml``.

    Returns:
        The parsed map.

    Raises:
        BagImportError: The file is unreadable, not UTF-8 or TOML, or a table is malformed;
            the message names the file, the table and the key.
    """
    path = Path(path)
    root = _Table(path, "", _read(path))
    stamps, delay, largest = _time(root)
    cells, jitter, skin = _skin(root)
    topic_map = TopicMap(
        path=path,
        stamps=stamps,
        max_delay_ns=delay,
        joints=_robot(root, "joint_states", names=True),
        pose=_robot(root, "tool_pose", names=False),
        cells=cells,
        max_jitter=jitter,
        skin=MappingProxyType(skin),
        windows=_windows(root),
        types=MappingProxyType(_types(root)),
        objects=MappingProxyType(_objects(root)),
        actions=MappingProxyType(_actions(root)),
        max_message_bytes=largest,
    )
    root.done()
    return topic_map
