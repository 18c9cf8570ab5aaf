"""The topic map of a bag import: which lab topics carry what, in which units (TOML).

The format is documented by the commented example ``recorder/data/topic_map.example.toml``;
:func:`load_topic_map` parses it strictly (unknown keys, wrong types and missing keys are
errors naming the file, the table and the fix).
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, NoReturn

from recorder._catalog import ActionKind, ActionSpec, ObjectSpec
from recorder.errors import BagImportError
from recorder.writing._stream import Modality

if TYPE_CHECKING:
    from collections.abc import Mapping

#: Values per cell of each skin modality.
CHANNELS_PER_CELL = {
    Modality.FORCE: 3,
    Modality.TEMPERATURE: 1,
    Modality.ACCELERATION: 3,
    Modality.PROXIMITY: 1,
}
#: Clocks a map can cut windows on.
STAMP_CLOCKS = ("header", "log")
#: Sources of action windows.
WINDOW_SOURCES = ("topic", "csv")
#: Units of CSV window times.
TIME_UNITS = {"s": 1_000_000_000, "ns": 1}
#: The packaged, commented example map.
EXAMPLE = "topic_map.example.toml"
#: Joint names of a UR arm (ROS ur_robot_driver): the default of [joint_states] names.
UR10_JOINTS = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)


@dataclass(frozen=True, slots=True)
class SkinField:
    """Where one skin modality is found, per cell.

    Attributes:
        topic: Topic pattern; ``{cell}`` is replaced by each cell id.
        field: Field of the message, dotted for nested fields.
        scale: SI value = raw * scale + offset.
        offset: See ``scale``.
    """

    topic: str
    field: str
    scale: float = 1.0
    offset: float = 0.0

    def topic_of(self, cell: int) -> str:
        """Return the topic of one cell."""
        return self.topic.replace("{cell}", str(cell))


@dataclass(frozen=True, slots=True)
class WindowSource:
    """Where the action windows come from.

    Attributes:
        source: ``topic`` (JSON annotations on a std_msgs/String topic) or ``csv``.
        topic: The annotation topic (source ``topic``).
        csv: The CSV of windows (source ``csv``).
        time_unit: Unit of the CSV times: ``s`` or ``ns``.
        relative: CSV times count from the earliest stamp of the mapped topics.
    """

    source: str
    topic: str = ""
    csv: Path | None = None
    time_unit: str = "s"
    relative: bool = False


@dataclass(frozen=True, slots=True)
class TopicMap:
    """A parsed topic map (see ``recorder/data/topic_map.example.toml``).

    Attributes:
        path: The map file.
        stamps: ``header`` or ``log``: the clock of samples and windows.
        joint_topic: sensor_msgs/JointState topic.
        joint_names: The bag's joint names, in the contract's joint order.
        joint_position_scale: Joint positions to rad.
        pose_topic: geometry_msgs/PoseStamped topic of the TCP.
        pose_position_scale: TCP positions to m.
        cells: Lab cell ids, in output column order.
        max_jitter: Largest stamp deviation inside a block, in sample periods.
        skin: Where each modality is.
        windows: Where the action windows are.
        types: Message definitions by type name, for bags that lack them.
        objects: Objects declared in the map.
        actions: Actions declared in the map.
    """

    path: Path
    stamps: str
    joint_topic: str
    joint_names: tuple[str, ...]
    joint_position_scale: float
    pose_topic: str
    pose_position_scale: float
    cells: tuple[int, ...]
    max_jitter: float
    skin: Mapping[Modality, SkinField]
    windows: WindowSource
    types: Mapping[str, str]
    objects: Mapping[str, ObjectSpec]
    actions: Mapping[str, ActionSpec]

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

    def get(self, key: str, kind: type | tuple[type, ...], default: Any = ...) -> Any:  # noqa: ANN401
        """Return the value of ``key`` checked against ``kind`` (required without default)."""
        self._taken.add(key)
        if key not in self.data:
            if default is ...:
                self.fail(f"[{self.name}] needs the key {key!r}")
            return default
        value = self.data[key]
        if isinstance(value, bool) and kind in (int, float, (int, float)):
            self.fail(f"[{self.name}] {key} = {value!r} must be a number")
        if not isinstance(value, kind):
            self.fail(f"[{self.name}] {key} = {value!r} has the wrong type")
        return value

    def number(self, key: str, default: float) -> float:
        """Return a finite number."""
        value = float(self.get(key, (int, float), default))
        if not math.isfinite(value):
            self.fail(f"[{self.name}] {key} = {value} must be finite")
        return value

    def table(self, key: str) -> _Table:
        """Return a required sub-table."""
        return _Table(self.path, f"{self.name}.{key}" if self.name else key, self.get(key, dict))

    def done(self) -> None:
        """Refuse keys that were not taken."""
        if unknown := sorted(set(self.data) - self._taken):
            self.fail(f"[{self.name or 'top level'}] has unknown keys {unknown}")


def _skin(root: _Table) -> tuple[tuple[int, ...], float, dict[Modality, SkinField]]:
    table = root.table("skin")
    cells = table.get("cells", list)
    if not cells or not all(isinstance(c, int) and not isinstance(c, bool) for c in cells):
        table.fail("[skin] cells must be a non-empty list of integer cell ids")
    if len(set(cells)) != len(cells):
        table.fail(f"[skin] cells {cells} repeats an id")
    jitter = table.number("max_jitter", 0.1)
    if not 0 <= jitter < 0.5:  # noqa: PLR2004 (beyond half a period a block could skip one)
        table.fail(f"[skin] max_jitter = {jitter} must lie in [0, 0.5)")
    fields = {}
    for modality in Modality:
        sub = table.table(str(modality))
        fields[modality] = SkinField(
            topic=sub.get("topic", str),
            field=sub.get("field", str),
            scale=sub.number("scale", 1.0),
            offset=sub.number("offset", 0.0),
        )
        sub.done()
    table.done()
    return tuple(cells), jitter, fields


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
        except OSError as err:
            msg = f"[types] {name!r}: cannot read {file} ({err.strerror}); fix the path"
            raise table.error(msg) from err
    table.done()
    return texts


def _objects(root: _Table) -> dict[str, ObjectSpec]:
    objects = {}
    declared = root.get("objects", dict, {})
    for object_id in list(declared):
        table = _Table(root.path, f"objects.{object_id}", declared[object_id])
        objects[object_id] = ObjectSpec(
            id=object_id,
            name=table.get("name", str),
            description=table.get("description", str, ""),
            novel=table.get("novel", bool),
        )
        table.done()
    return objects


def _actions(root: _Table) -> dict[str, ActionSpec]:
    actions = {}
    declared = root.get("actions", dict, {})
    for action_id in list(declared):
        table = _Table(root.path, f"actions.{action_id}", declared[action_id])
        kind = table.get("kind", str)
        if kind not in set(ActionKind):
            table.fail(f"[actions.{action_id}] kind = {kind!r}: press, slide or static")
        if "duration_s" not in table.data:
            table.fail(f"[actions.{action_id}] needs duration_s (s)")
        actions[action_id] = ActionSpec(
            id=action_id,
            kind=ActionKind(kind),
            duration_s=table.number("duration_s", 0.0),
            depth_m=table.number("depth_m", 0.0),
            force_n=table.number("force_n", 0.0),
            speed_m_s=table.number("speed_m_s", 0.0),
            trials=int(table.get("trials", int, 1)),
            description=table.get("description", str, ""),
        )
        table.done()
    return actions


def _read(path: Path) -> dict[str, Any]:
    try:
        return tomllib.loads(Path(path).read_text("utf-8"))
    except OSError as err:
        msg = f"{path}: cannot read the topic map ({err.strerror}); check --topic-map"
        raise BagImportError(msg) from err
    except tomllib.TOMLDecodeError as err:
        msg = f"{path}: not valid TOML ({err}); fix the topic map's syntax"
        raise BagImportError(msg) from err


def load_topic_map(path: Path) -> TopicMap:
    """Read and check a topic map.

    Args:
        path: The map (TOML), documented by ``recorder/data/topic_map.example.toml``.

    Returns:
        The parsed map.

    Raises:
        BagImportError: The file is unreadable, not TOML, or a table is malformed; the message
            names the file, the table and the key.
    """
    path = Path(path)
    root = _Table(path, "", _read(path))
    time = root.table("time")
    stamps = time.get("stamps", str, "header")
    if stamps not in STAMP_CLOCKS:
        time.fail(f"[time] stamps = {stamps!r} must be one of {STAMP_CLOCKS}")
    time.done()
    joints = root.table("joint_states")
    names = tuple(joints.get("names", list, list(UR10_JOINTS)))
    if len(names) != len(UR10_JOINTS) or not all(isinstance(n, str) for n in names):
        joints.fail(f"[joint_states] names must list {len(UR10_JOINTS)} joint names")
    pose = root.table("tool_pose")
    cells, jitter, skin = _skin(root)
    topic_map = TopicMap(
        path=path,
        stamps=stamps,
        joint_topic=joints.get("topic", str),
        joint_names=names,
        joint_position_scale=joints.number("position_scale", 1.0),
        pose_topic=pose.get("topic", str),
        pose_position_scale=pose.number("position_scale", 1.0),
        cells=cells,
        max_jitter=jitter,
        skin=MappingProxyType(skin),
        windows=_windows(root),
        types=MappingProxyType(_types(root)),
        objects=MappingProxyType(_objects(root)),
        actions=MappingProxyType(_actions(root)),
    )
    for table in (joints, pose, root):
        table.done()
    return topic_map
