"""Bag import: lab-shaped ROS 1 and ROS 2 bags built with rosbags' writers, imported, read back."""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
import pytest
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Ros2Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from recorder import load_actions, load_objects
from recorder._cli import main
from recorder.bagimport._importer import import_bag
from recorder.bagimport._topicmap import EXAMPLE, TopicMap, load_topic_map
from recorder.bagimport._windows import parse_annotation
from recorder.errors import BagImportError
from replay import read_recording
from replay.learning._features import build_features

NS = 1_000_000_000
G = 9.80665
CELL_MSG = """std_msgs/Header header
uint16 cell_id
float32 prox
float32[3] force
float32[3] acc
float32 temp
"""
CELL_TYPE = "lab_skin/msg/CellData"
CELLS: tuple[int, ...] = (10, 11, 12, 13)
SKIN_PERIOD = 4_000_000  # 250 Hz
ROBOT_PERIOD = 8_000_000  # 125 Hz
START = 1_700_000_000 * NS  # a wall-clock-like origin, as in real bags
DURATION = 13 * NS // 2
#: Lab joint order: the contract's six joints shuffled, plus a gripper.
LAB_JOINTS = (
    "elbow_joint",
    "gripper_joint",
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
UR10 = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)


@dataclass(frozen=True)
class Note:
    """One annotated action: phase starts in seconds from START."""

    object: str
    action: str
    trial: int | None
    phases: tuple[float, ...]


ANNOTATIONS: tuple[Note, ...] = (
    Note("wood", "P1", None, (0.2, 0.5, 0.8, 3.9, 4.2)),
    Note("lab_mug", "S2", 5, (4.4, 4.6, 4.8, 5.9, 6.2)),
)
PHASES = ("approach", "contact", "execute", "retract", "end")
DROPPED = (2, 1300)  # cell index 2 loses its sample number 1300 (in the second action)


@dataclass
class LabData:
    """What a lab bag holds, seeded: skin per cell, joints, poses (lab units)."""

    seed: int
    skin_stamps: list[np.ndarray] = field(default_factory=list)
    prox: list[np.ndarray] = field(default_factory=list)
    force: list[np.ndarray] = field(default_factory=list)
    acc: list[np.ndarray] = field(default_factory=list)
    temp: list[np.ndarray] = field(default_factory=list)

    def __post_init__(self) -> None:
        rng = np.random.default_rng(self.seed)
        n = DURATION // SKIN_PERIOD
        first = START + np.arange(n, dtype=np.int64) * SKIN_PERIOD
        for index in range(len(CELLS)):
            # cell 0 is on a perfect grid; the others lag by up to 1 ms with jitter
            lag = 0 if index == 0 else 250_000 * index + rng.integers(-100_000, 100_000, n)
            stamps = first + lag
            keep = np.ones(n, dtype=bool)
            if index == DROPPED[0]:
                keep[DROPPED[1]] = False
            self.skin_stamps.append(stamps[keep])
            self.prox.append(rng.uniform(0.0, 0.2, n).astype(np.float32)[keep])
            self.force.append(rng.normal(1.0, 0.3, (n, 3)).astype(np.float32)[keep])
            self.acc.append(rng.normal(0.0, 0.5, (n, 3)).astype(np.float32)[keep])
            self.temp.append(rng.normal(30.0, 0.1, n).astype(np.float32)[keep])
        m = DURATION // ROBOT_PERIOD
        self.robot_stamps = START + np.arange(m, dtype=np.int64) * ROBOT_PERIOD
        self.joints = rng.normal(0.0, 1.0, (m, len(LAB_JOINTS)))
        self.efforts = rng.normal(0.0, 5.0, (m, len(LAB_JOINTS)))
        self.position_mm = rng.normal(500.0, 50.0, (m, 3))
        quaternion = rng.normal(0.0, 1.0, (m, 4))
        self.quaternion = quaternion / np.linalg.norm(quaternion, axis=1, keepdims=True)


def _time(store: Any, stamp: int) -> Any:
    return store.types["builtin_interfaces/msg/Time"](sec=stamp // NS, nanosec=stamp % NS)


def _header(store: Any, stamp: int, frame: str, *, ros1: bool) -> Any:
    extra = {"seq": 0} if ros1 else {}
    return store.types["std_msgs/msg/Header"](stamp=_time(store, stamp), frame_id=frame, **extra)


def _messages(data: LabData, store: Any, *, ros1: bool) -> list[tuple[int, str, str, Any]]:
    """Return (receive time, topic, type, message) of the whole bag."""
    out: list[tuple[int, str, str, Any]] = []
    cell = store.types[CELL_TYPE]
    for index, cell_id in enumerate(CELLS):
        for k, stamp in enumerate(data.skin_stamps[index]):
            message = cell(
                header=_header(store, int(stamp), f"cell{cell_id}", ros1=ros1),
                cell_id=cell_id,
                prox=float(data.prox[index][k]),
                force=data.force[index][k],
                acc=data.acc[index][k],
                temp=float(data.temp[index][k]),
            )
            out.append((int(stamp) + 300_000, f"/skin/cell_{cell_id}", CELL_TYPE, message))
    joint_state, pose_stamped = "sensor_msgs/msg/JointState", "geometry_msgs/msg/PoseStamped"
    types = store.types
    for k, stamp in enumerate(data.robot_stamps):
        joints = types[joint_state](
            header=_header(store, int(stamp), "", ros1=ros1),
            name=list(LAB_JOINTS),
            position=data.joints[k],
            velocity=np.zeros(0),
            effort=data.efforts[k],
        )
        out.append((int(stamp) + 200_000, "/joint_states", joint_state, joints))
        x, y, z = data.position_mm[k]
        qx, qy, qz, qw = data.quaternion[k]
        pose = types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=x, y=y, z=z),
            orientation=types["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
        )
        message = types[pose_stamped](
            header=_header(store, int(stamp), "base", ros1=ros1), pose=pose
        )
        out.append((int(stamp) + 200_000, "/tool_pose", pose_stamped, message))
    for note in ANNOTATIONS:
        for phase, seconds in zip(PHASES, note.phases, strict=True):
            text: dict[str, Any] = {"object": note.object, "action": note.action, "phase": phase}
            if note.trial is not None:
                text["trial"] = note.trial
            message = types["std_msgs/msg/String"](data=json.dumps(text))
            stamp = START + round(seconds * NS)
            out.append((stamp, "/annotations", "std_msgs/msg/String", message))
    return sorted(out, key=lambda entry: entry[0])


def write_lab_bag(path: Path, storage: str, data: LabData) -> Path:
    """Write a lab bag: ``ros1`` (.bag), ``sqlite3`` or ``mcap`` (ROS 2 directories)."""
    ros1 = storage == "ros1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(CELL_MSG, CELL_TYPE))
    if ros1:
        writer: Any = Ros1Writer(path)
    else:
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        writer = Ros2Writer(path, version=9, storage_plugin=plugin)
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    with writer:
        connections: dict[str, Any] = {}
        for receive, topic, msgtype, message in _messages(data, store, ros1=ros1):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], receive, serialize(message, msgtype))
    return path


MAP = """
[time]
stamps = "header"

[joint_states]
topic = "/joint_states"
names = {ur10}
position_scale = 1.0

[tool_pose]
topic = "/tool_pose"
position_scale = 0.001

[skin]
cells = {cells}
max_jitter = 0.1

[skin.force]
topic = "/skin/cell_{{cell}}"
field = "force"

[skin.acceleration]
topic = "/skin/cell_{{cell}}"
field = "acc"
scale = 9.80665

[skin.temperature]
topic = "/skin/cell_{{cell}}"
field = "temp"

[skin.proximity]
topic = "/skin/cell_{{cell}}"
field = "prox"

[windows]
{windows}

[objects.lab_mug]
name = "Lab mug"
novel = true
"""


def write_map(directory: Path, windows: str = 'source = "topic"\ntopic = "/annotations"') -> Path:
    path = directory / "topic_map.toml"
    text = MAP.format(ur10=json.dumps(list(UR10)), cells=json.dumps(list(CELLS)), windows=windows)
    path.write_text(text, encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def data() -> LabData:
    return LabData(seed=11)


@pytest.fixture(scope="module")
def ros1_bag(tmp_path_factory: pytest.TempPathFactory, data: LabData) -> Path:
    return write_lab_bag(tmp_path_factory.mktemp("ros1") / "session.bag", "ros1", data)


def _import(bag: Path, topic_map: TopicMap, out: Path) -> Any:
    return import_bag(bag, topic_map, out, objects=load_objects(), actions=load_actions())


def _rows(data: LabData, start: int, stop: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """Expected row stamps and, per cell, the index of the sample of each row."""
    stamps = data.skin_stamps[0]
    rows = stamps[(stamps >= start) & (stamps < stop)]
    picks = []
    keep = np.ones(rows.size, dtype=bool)
    for cell in range(len(CELLS)):
        index = np.abs(data.skin_stamps[cell][None, :] - rows[:, None]).argmin(axis=1)
        keep &= 2 * np.abs(data.skin_stamps[cell][index] - rows) < SKIN_PERIOD
        picks.append(index)
    return rows[keep], [pick[keep] for pick in picks]


def test_ros1_bag_with_annotations_imports_every_value(
    ros1_bag: Path, data: LabData, tmp_path: Path
) -> None:
    report = _import(ros1_bag, load_topic_map(write_map(tmp_path)), tmp_path / "out")
    wood, mug = tmp_path / "out" / "wood" / "P1" / "001.mcap", tmp_path / "out/lab_mug/S2/005.mcap"
    assert report.written == [wood, mug]
    assert (tmp_path / "out" / "index.parquet").is_file()
    for path, note in ((wood, ANNOTATIONS[0]), (mug, ANNOTATIONS[1])):
        recording = read_recording(path)
        phases = [START + round(s * NS) for s in note.phases]
        assert list(recording.phases) == list(zip(PHASES, phases, strict=True))
        rows, picks = _rows(data, phases[0], phases[-1])
        np.testing.assert_array_equal(recording.skin("force").stamps_ns, rows)
        for c, pick in enumerate(picks):
            np.testing.assert_array_equal(recording.skin("force").data[:, c], data.force[c][pick])
            expected_acc = (data.acc[c][pick].astype(np.float64) * G).astype(np.float32)
            np.testing.assert_array_equal(recording.skin("acceleration").data[:, c], expected_acc)
            np.testing.assert_array_equal(
                recording.skin("proximity").data[:, c, 0], data.prox[c][pick]
            )
            np.testing.assert_array_equal(
                recording.skin("temperature").data[:, c, 0], data.temp[c][pick]
            )
        assert recording.joints is not None
        assert recording.tcp is not None
        robot = (data.robot_stamps >= phases[0]) & (data.robot_stamps < phases[-1])
        np.testing.assert_array_equal(recording.joints.stamps_ns, data.robot_stamps[robot])
        order = [LAB_JOINTS.index(name) for name in UR10]
        np.testing.assert_array_equal(recording.joints.position, data.joints[robot][:, order])
        np.testing.assert_array_equal(recording.joints.effort, data.efforts[robot][:, order])
        assert not recording.joints.velocity.any()  # not recorded by the lab: zeros
        np.testing.assert_allclose(recording.tcp.position, data.position_mm[robot] / 1000, 1e-15)
        np.testing.assert_array_equal(recording.tcp.orientation, data.quaternion[robot])
    meta = read_recording(mug).metadata
    assert (meta.object_id, meta.object_name, meta.source) == ("lab_mug", "Lab mug", "import")
    assert (meta.action_id, meta.action_kind, meta.trial) == ("S2", "slide", 5)
    assert meta.rig["kind"] == "imported"
    assert meta.rig["source"] == "session.bag"
    assert json.loads(str(meta.rig["cells"])) == list(CELLS)
    assert json.loads(str(meta.rig["joints_not_recorded"])) == ["velocity"]
    # the dropped sample of cell 2 falls in the second action: one row fewer, nothing else
    assert report.dropped_rows["force"] == 1
    assert 0 < report.max_cell_offset_ns["force"] < SKIN_PERIOD // 2
    assert report.max_jitter_ns["force"] == 0


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_ros2_bags_with_a_csv_of_windows(storage: str, data: LabData, tmp_path: Path) -> None:
    bag = write_lab_bag(tmp_path / "session", storage, data)
    csv = tmp_path / "windows.csv"
    csv.write_text("start,stop,object,action,trial\n0.8,3.9,wood,P1,\n3.9,6.3,wood,P1,\n")
    windows = 'source = "csv"\ncsv = "windows.csv"\ntime_unit = "s"\nrelative = true'
    out = tmp_path / "out"
    csv.write_text("start,stop,object,action,trial\n0.8,3.9,wood,P1,\n3.2,6.3,wood,P1,\n")
    with pytest.raises(BagImportError, match=r"row 3: window wood/P1 .*overlaps .*row 2"):
        _import(bag, load_topic_map(write_map(tmp_path, windows)), out)
    csv.write_text("start,stop,object,action,trial\n0.8,3.9,wood,P1,\n3.9,6.3,lab_mug,S2,\n")
    report = _import(bag, load_topic_map(write_map(tmp_path, windows)), out)
    assert [p.relative_to(out).as_posix() for p in report.written] == [
        "wood/P1/001.mcap",
        "lab_mug/S2/001.mcap",
    ]
    recording = read_recording(report.written[1])
    # relative to the earliest stamp of the mapped topics: the first skin sample, START
    assert list(recording.phases) == [
        ("execute", START + 3_900_000_000),
        ("end", START + 6_300_000_000),
    ]
    index = pl.read_parquet(out / "index.parquet")
    assert index["path"].to_list() == ["lab_mug/S2/001.mcap", "wood/P1/001.mcap"]
    # the same bag again, under another name: identified by content, adds nothing
    copy = tmp_path / "renamed"
    shutil.copytree(bag, copy)
    again = _import(copy, load_topic_map(write_map(tmp_path, windows)), out)
    assert again.written == []
    assert list(again.already_imported) == ["renamed"]


def test_imported_recordings_go_through_feature_extraction(ros1_bag: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    _import(ros1_bag, load_topic_map(write_map(tmp_path)), out)
    table = build_features(out, workers=1)
    assert table.quarantined.height == 0
    assert sorted(table.frame["object_id"].to_list()) == ["lab_mug", "wood"]


def test_an_explicit_trial_that_exists_is_refused(ros1_bag: Path, tmp_path: Path) -> None:
    topic_map = load_topic_map(write_map(tmp_path))
    _import(ros1_bag, topic_map, tmp_path / "out")
    shutil.rmtree(tmp_path / "out" / "imports")  # forget the import: the files stay
    with pytest.raises(BagImportError, match=r"lab_mug/S2/005.mcap.*never overwritten"):
        _import(ros1_bag, topic_map, tmp_path / "out")


def _broken_map(tmp_path: Path, old: str, new: str) -> TopicMap:
    path = write_map(tmp_path)
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))
    return load_topic_map(path)


def test_an_unknown_topic_names_the_topic(ros1_bag: Path, tmp_path: Path) -> None:
    topic_map = _broken_map(tmp_path, '"/tool_pose"', '"/tcp_pose"')
    with pytest.raises(BagImportError, match=r"topic /tcp_pose .*not in the bag.*/tool_pose"):
        _import(ros1_bag, topic_map, tmp_path / "out")


def test_a_type_mismatch_names_the_topic(ros1_bag: Path, tmp_path: Path) -> None:
    topic_map = _broken_map(tmp_path, '"/tool_pose"', '"/joint_states"')
    with pytest.raises(
        BagImportError, match=r"topic /joint_states carries sensor_msgs/msg/JointState.*PoseStamped"
    ):
        _import(ros1_bag, topic_map, tmp_path / "out")
    topic_map = _broken_map(tmp_path, '"/joint_states"', '"/tool_pose"')
    with pytest.raises(
        BagImportError, match=r"topic /tool_pose carries geometry_msgs/msg/PoseStamped.*JointState"
    ):
        _import(ros1_bag, topic_map, tmp_path / "out")
    topic_map = _broken_map(tmp_path, 'field = "force"', 'field = "prox"\nwidth = 3')
    with pytest.raises(
        BagImportError, match=r"topic /skin/cell_10: field 'prox' has 1 values.*force"
    ):
        _import(ros1_bag, topic_map, tmp_path / "out")
    topic_map = _broken_map(tmp_path, 'field = "acc"', 'field = "accel"')
    with pytest.raises(BagImportError, match=r"topic /skin/cell_10 .*no field 'accel'.*acc"):
        _import(ros1_bag, topic_map, tmp_path / "out")


def test_unknown_object_and_bad_annotations_are_explained(ros1_bag: Path, tmp_path: Path) -> None:
    topic_map = _broken_map(tmp_path, "[objects.lab_mug]", "[objects.other_mug]")
    with pytest.raises(BagImportError, match=r"object 'lab_mug' is neither in the object catalog"):
        _import(ros1_bag, topic_map, tmp_path / "out")
    csv = tmp_path / "windows.csv"
    csv.write_text("start,stop,object,action\n3.9,0.8,wood,P1\n")
    windows = 'source = "csv"\ncsv = "windows.csv"\nrelative = true'
    with pytest.raises(BagImportError, match=r"windows.csv row 2: .*execute and end"):
        _import(ros1_bag, load_topic_map(write_map(tmp_path, windows)), tmp_path / "out")
    # two rows of one trial: said as such (nothing exists to overwrite)
    csv.write_text("start,stop,object,action,trial\n0.8,3.9,wood,P1,1\n4.0,7.1,wood,P1,1\n")
    with pytest.raises(BagImportError, match=r"trial 1 of wood/P1 is given to another window"):
        _import(ros1_bag, load_topic_map(write_map(tmp_path, windows)), tmp_path / "out")
    # an annotation's stamp that is no integer: the value named
    with pytest.raises(BagImportError, match=r"stamp_ns Decimal\('1.5'\) is not a whole number"):
        parse_annotation('{"object": "a", "action": "b", "phase": "end", "stamp_ns": 1.5}', 0, "/a")
    with pytest.raises(BagImportError, match=r"\(no key 'phase'\)"):
        parse_annotation('{"object": "a", "action": "b"}', 0, "/a")


def test_topic_maps_are_checked_strictly(tmp_path: Path) -> None:
    with pytest.raises(BagImportError, match=r"\[skin.force\] has unknown keys \['feild'\]"):
        _broken_map(tmp_path, 'field = "force"', 'field = "force"\nfeild = "x"')
    with pytest.raises(BagImportError, match=r"\[time\] stamps = 'wall'"):
        _broken_map(tmp_path, 'stamps = "header"', 'stamps = "wall"')
    with pytest.raises(BagImportError, match=r"\[skin\] needs the key 'cells'"):
        _broken_map(tmp_path, "cells = ", "cellz = ")


def test_a_topic_has_its_own_message_budget_where_its_table_sets_one(tmp_path: Path) -> None:
    text = (Path(__file__).parents[2] / "recorder" / "data" / EXAMPLE).read_text("utf-8")
    force, accel = (f'[skin.{m}]\ntopic = "/skin/cell_{{cell}}"' for m in ("force", "acceleration"))
    assert force in text
    assert accel in text
    text = text.replace(force, force + "\nmax_message_kib = 16")
    text = text.replace(accel, accel + "\nmax_message_kib = 8")
    path = tmp_path / "map.toml"
    path.write_text(
        text.replace('topic = "/tool_pose"', 'topic = "/tool_pose"\nmax_message_kib = 1')
    )
    topic_map = load_topic_map(path)
    # every cell's topic carries force and acceleration: the smaller budget holds
    assert topic_map.message_budget("/skin/cell_3") == (8 << 10, "[skin.acceleration]")
    assert topic_map.message_budget("/tool_pose") == (1 << 10, "[tool_pose]")
    assert topic_map.message_budget("/joint_states") == (4096 << 10, "[time]")
    assert topic_map.message_budget("/skin/cell_7") == (4096 << 10, "[time]")  # not a cell
    path.write_text(text.replace("max_message_kib = 16", "max_message_kib = 0"))
    with pytest.raises(BagImportError, match=r"\[skin.force\] max_message_kib = 0 must be at"):
        load_topic_map(path)
    # a delay of hours keeps every action's messages in memory that long after its end
    for delay in ("-1.0", "61.0", "1e9"):
        path.write_text(text.replace("max_delay_s = 2.0", f"max_delay_s = {delay}"))
        with pytest.raises(
            BagImportError, match=r"\[time\] max_delay_s = .* must lie in \[0, 60\]"
        ):
            load_topic_map(path)
    # a budget beyond 1 GiB protects nothing: the other topics' memory is the point of it
    path.write_text(text.replace("max_message_kib = 16", "max_message_kib = 1048577"))
    with pytest.raises(BagImportError, match=r"max_message_kib = 1048577 must be at most 1048576"):
        load_topic_map(path)


def test_the_packaged_example_map_is_valid() -> None:
    example = Path(__file__).parents[2] / "recorder" / "data" / EXAMPLE
    topic_map = load_topic_map(example)
    assert topic_map.skin["acceleration"].scale == pytest.approx(G)
    assert topic_map.windows.topic == "/annotations"
    assert topic_map.cells == (0, 1, 2, 3, 4, 5, 6)


def test_cli_imports_and_reports_errors_in_one_line(
    ros1_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    topic_map = write_map(tmp_path)
    out = tmp_path / "out"
    argv = ["import-bag", str(ros1_bag), "--topic-map", str(topic_map), "--out", str(out)]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "wood/P1/001.mcap" in printed
    assert "index.parquet" in printed
    assert main(argv) == 0
    assert "nothing added" in capsys.readouterr().out
    argv[3] = str(_broken_map(tmp_path, '"/tool_pose"', '"/tcp_pose"').path)
    assert main([*argv[:-1], str(tmp_path / "out2")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("atikt-record: error: ")
    assert err.count("\n") == 1
    assert main(["import-bag", str(ros1_bag), "--topics"]) == 0
    assert "lab_skin/msg/CellData" in capsys.readouterr().out
