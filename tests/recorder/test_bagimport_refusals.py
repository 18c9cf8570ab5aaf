"""Import refusals (one line, never a traceback), sessions split over bags, hostile bags."""

from __future__ import annotations

import dataclasses
import json
import resource
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import polars as pl
import pytest
from labbags import NS, PROBE_MAP, START, TYPES, Session, probe_messages, write_bag
from rosbags.typesys import get_types_from_msg

from recorder import declare_objects, load_actions, load_objects
from recorder._cli import main as record
from recorder.bagimport._importer import import_bag
from recorder.bagimport._topicmap import load_topic_map
from recorder.errors import BagImportError
from replay import read_recording

if TYPE_CHECKING:
    from recorder.bagimport._report import ImportReport

PROBE = "probe_msgs/msg/Probe"
SMALL = Session(("wood", "foam"), ("hold5",), trials=1, execute_s=5.0, gap_s=0.4)
ROOT = Path(__file__).parents[2]


def _map(directory: Path, text: str = PROBE_MAP) -> Path:
    path = directory / "map.toml"
    path.write_text(text, encoding="utf-8")
    return path


def _import(bags: Any, map_path: Path, out: Path) -> ImportReport:
    topic_map = load_topic_map(map_path)
    return import_bag(bags, topic_map, out, objects=load_objects(), actions=load_actions())


@pytest.fixture(scope="module")
def small(tmp_path_factory: pytest.TempPathFactory) -> Path:
    messages, store = probe_messages(ros1=True, session=SMALL)
    return write_bag(tmp_path_factory.mktemp("small") / "probe.bag", "ros1", messages, store)


def _cli_error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    assert record(argv) == 1
    err = capsys.readouterr().err
    assert err.startswith("atikt-record: error: ")
    assert err.count("\n") == 1
    return err


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        (
            '[skin.force]\ntopic = "/probe"',
            '[joint_states]\ntopic = "/annotations"\n\n[skin.force]\ntopic = "/probe"',
            (
                r"topic /annotations carries std_msgs/msg/String, but the topic map uses it as "
                r"sensor_msgs/msg/JointState"
            ),
        ),
        (
            'topic = "/probe"\nfield = "force"',
            'topic = "/annotations"\nfield = "force"',
            r"topic /annotations carries std_msgs/msg/String: no field 'force' \(fields: data\)",
        ),
        (
            'field = "temperatures"',
            'field = "temperatures"\nwidth = 1',
            r"field 'temperatures' has 2 values, not 1 samples x 1 values; fix width",
        ),
        (
            'field = "force"',
            'field = "header.frame_id"',
            (
                r"topic /probe carries probe_msgs/msg/Probe: a field that is not numeric: "
                r"'header.frame_id'"
            ),
        ),
        (
            'kind = "static"',
            'kind = "squeeze"',
            r"\[actions.hold5\] kind = 'squeeze' must be one of \['press', 'slide', 'static'\]",
        ),
        (
            'kind = "static"\nduration_s = 5.0',
            'kind = "static"',
            r"\[actions.hold5\] a 'static' action needs the parameters duration_s",
        ),
        (
            "[skin.force]",
            "[robot]\nname = 'ur10'\n\n[skin.force]",
            r"\[top level\] robot changed: the robot is mapped by \[joint_states\]",
        ),
        (
            'kind = "static"',
            'kind = "slide"',
            r"action hold5 of kind slide needs acceleration, which the topic map does not map",
        ),
    ],
)
def test_map_and_bag_mismatches_are_one_line_each(
    small: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    *,
    old: str,
    new: str,
    expected: str,
) -> None:
    assert old in PROBE_MAP
    path = _map(tmp_path, PROBE_MAP.replace(old, new, 1))
    err = _cli_error(["import-bag", str(small), "--topic-map", str(path), "--out", "x"], capsys)
    assert pytest.importorskip("re").search(expected, err), err
    assert not (tmp_path / "x").exists()


def test_a_map_that_is_not_utf8(tmp_path: Path) -> None:
    path = tmp_path / "map.toml"
    path.write_bytes(PROBE_MAP.encode("utf-8").replace(b"Cooled wood", b"K\xfchlholz"))
    with pytest.raises(BagImportError, match=r"map.toml: the topic map is not UTF-8 \(byte \d+\)"):
        load_topic_map(path)


def _csv_map(directory: Path, rows: str, unit: str = "s") -> Path:
    (directory / "windows.csv").write_text("start,stop,object,action,trial\n" + rows, "utf-8")
    windows = f'[windows]\nsource = "csv"\ncsv = "windows.csv"\ntime_unit = "{unit}"\n'
    text = PROBE_MAP.replace('[windows]\nsource = "topic"\ntopic = "/annotations"\n', windows)
    return _map(directory, text)


def test_window_tables_are_checked(small: Path, tmp_path: Path) -> None:
    start = SMALL.windows()[0][3]
    path = _csv_map(tmp_path, f"{start},{start + 5 * 10**9 + 1},wood,hold5,-2\n", "ns")
    with pytest.raises(BagImportError, match=r"row 2: trial = '-2' is not a trial number"):
        _import(small, path, tmp_path / "out")
    finer = f"{start // 10**9}.{start % 10**9:09d}1"  # a tenth of a ns
    path = _csv_map(tmp_path, f"{finer},{start // 10**9 + 6},wood,hold5,1\n")
    with pytest.raises(
        BagImportError, match=r"row 2 column start: '1700000000\.5000000001' is not a time in whole"
    ):
        _import(small, path, tmp_path / "out")
    # seconds are parsed exactly: 1700000000.500000001 s is that many ns
    seconds = f"{start // 10**9}.{start % 10**9:09d}"
    path = _csv_map(tmp_path, f"{seconds},{start // 10**9 + 6}.{start % 10**9:09d},wood,hold5,1\n")
    report = _import(small, path, tmp_path / "out")
    assert dict(read_recording(report.written[0]).phases)["execute"] == start


def test_stamps_that_go_back_are_refused_with_the_fix(tmp_path: Path) -> None:
    messages, store = probe_messages(ros1=False, session=SMALL)
    probe = [m for m in messages if m[1] == "/probe"]
    receive, topic, msgtype, message = probe[300]
    earlier = probe[299][3].header.stamp
    message.header.stamp = type(earlier)(sec=earlier.sec, nanosec=earlier.nanosec - 1)
    bag = write_bag(tmp_path / "bag", "mcap", messages, store)
    with pytest.raises(
        BagImportError,
        match=r"topic /probe: stamp \d+ ns precedes .*never re-sorted.*samples_per_message",
    ):
        _import(bag, _map(tmp_path), tmp_path / "out")
    assert receive > START
    assert topic == "/probe"
    assert msgtype


def test_late_samples_are_refused_with_the_fix(tmp_path: Path) -> None:
    messages, store = probe_messages(ros1=False, session=SMALL)
    # the thermistors arrive on their own topic, 3 s after their stamps
    delayed = [
        (r + 3 * 10**9, "/probe_t", t, m) for r, topic, t, m in messages if topic == "/probe"
    ]
    bag = write_bag(tmp_path / "bag", "mcap", messages + delayed, store)
    old = 'topic = "/probe"\nfield = "temperatures"'
    text = PROBE_MAP.replace(old, 'topic = "/probe_t"\nfield = "temperatures"')
    with pytest.raises(
        BagImportError,
        match=r"topic /probe_t: a sample stamped .* raise \[time\] max_delay_s \(now 2 s\)",
    ):
        _import(bag, _map(tmp_path, text), tmp_path / "out")
    assert not list((tmp_path / "out").rglob("*.mcap"))  # all or nothing
    text = text.replace('stamps = "header"', 'stamps = "header"\nmax_delay_s = 3.5')
    report = _import(bag, _map(tmp_path, text), tmp_path / "out")
    assert len(report.written) == 2


def test_a_session_split_over_two_bags(tmp_path: Path) -> None:
    messages, store = probe_messages(ros1=True, session=SMALL)
    split = SMALL.windows()[0][3] + 2 * 10**9  # inside the first window
    first = write_bag(tmp_path / "part_0.bag", "ros1", [m for m in messages if m[0] < split], store)
    second = write_bag(
        tmp_path / "part_1.bag", "ros1", [m for m in messages if m[0] >= split], store
    )
    whole = write_bag(tmp_path / "whole.bag", "ros1", messages, store)
    report = _import([first, second], _map(tmp_path), tmp_path / "split")
    single = _import(whole, _map(tmp_path), tmp_path / "single")
    assert [p.relative_to(tmp_path / "split") for p in report.written] == [
        p.relative_to(tmp_path / "single") for p in single.written
    ]
    for a, b in zip(report.written, single.written, strict=True):
        ra, rb = read_recording(a), read_recording(b)
        for modality in ra.signals:
            np.testing.assert_array_equal(ra.skin(modality).stamps_ns, rb.skin(modality).stamps_ns)
            np.testing.assert_array_equal(ra.skin(modality).data, rb.skin(modality).data)
    assert pl.read_parquet(tmp_path / "split" / "index.parquet").height == 2
    saved = json.loads((report.json_path or Path()).read_text("utf-8"))
    assert [b["name"] for b in saved["bags"]] == ["part_0.bag", "part_1.bag"]
    assert read_recording(report.written[0]).metadata.rig["source"] == "part_0.bag, part_1.bag"
    # one of the bags again, with another: refused; both again: nothing added
    with pytest.raises(BagImportError, match=r"part_1.bag: this bag was imported into .* already"):
        _import([second, whole], _map(tmp_path), tmp_path / "split")
    assert _import([first, second], _map(tmp_path), tmp_path / "split").written == []


_HOSTILE = """
import resource, sys
resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))
from recorder._cli import main
sys.exit(main(sys.argv[1:]))
"""


def _hostile_bags(directory: Path) -> list[Path]:
    """Return bags that try to exhaust memory: a huge message, a lying sequence length."""
    messages, store = probe_messages(ros1=False, session=SMALL)
    bags = []
    huge = directory / "huge"
    raw = store.serialize_cdr(messages[0][3], messages[0][2])
    from rosbags.rosbag2 import StoragePlugin, Writer  # noqa: PLC0415

    with Writer(huge, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection("/probe", "probe_msgs/msg/Probe", typestore=store)
        writer.write(connection, START, raw)
        writer.write(connection, START + 10**6, bytes(raw[:4]) + bytes(100 << 20))
    bags.append(huge)
    lying = directory / "lying"
    joint = store.types["sensor_msgs/msg/JointState"]
    header = messages[0][3].header
    payload = bytearray(
        store.serialize_cdr(
            joint(
                header=header,
                name=[],
                position=np.zeros(0),
                velocity=np.zeros(0),
                effort=np.zeros(0),
            ),
            "sensor_msgs/msg/JointState",
        )
    )
    payload[-16:-12] = (0xFFFFFFF0).to_bytes(4, "little")  # names: 4 billion strings
    with Writer(lying, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        probe = writer.add_connection("/probe", "probe_msgs/msg/Probe", typestore=store)
        joints = writer.add_connection("/joints", "sensor_msgs/msg/JointState", typestore=store)
        for receive, topic, msgtype, message in messages[:2000]:
            if topic != "/probe":
                continue
            writer.write(probe, receive, store.serialize_cdr(message, msgtype))
            writer.write(joints, receive, bytes(payload))
    bags.append(lying)
    return bags


@pytest.mark.slow
def test_hostile_bags_are_refused_within_bounded_memory(tmp_path: Path) -> None:
    start = START + 10**6
    windows = f"{start},{start + 5 * 10**9 + 10**6},wood,hold5,1\n"
    probe = _csv_map(tmp_path, windows, "ns").read_text("utf-8")
    arm = probe.replace("[skin]", '[joint_states]\ntopic = "/joints"\n\n[skin]')
    expected = ("a message of 104857604 bytes", "topic /joints: the message at")
    for bag, text, fragment in zip(_hostile_bags(tmp_path), (probe, arm), expected, strict=True):
        path = _map(tmp_path, text)
        argv = ["import-bag", str(bag), "--topic-map", str(path), "--out", str(tmp_path / "o")]
        result = subprocess.run(  # noqa: S603 (this interpreter, a fixed script)
            [sys.executable, "-c", _HOSTILE, *argv],
            capture_output=True,
            text=True,
            check=False,
            cwd=ROOT,
            timeout=300,
        )
        assert result.returncode == 1, result.stderr[-2000:]
        assert result.stderr.startswith("atikt-record: error: "), result.stderr[-2000:]
        assert result.stderr.count("\n") == 1
        assert fragment in result.stderr, result.stderr
    assert resource.getrlimit(resource.RLIMIT_AS)[0] != 4 << 30  # only the subprocess


def test_an_mcap_bag_cut_off_names_the_salvage_that_makes_it_importable(tmp_path: Path) -> None:
    # a lab's recorder killed mid-bag leaves an MCAP file without its end: rosbags refuses
    # it whole; the refusal names the salvage, whose file rosbags then reads
    from rosbags.highlevel import AnyReader  # noqa: PLC0415

    whole = (ROOT / "recordings" / "data" / "wood" / "S1" / "001.mcap").read_bytes()
    cut = tmp_path / "lab.mcap"
    cut.write_bytes(whole[: len(whole) * 2 // 3])
    map_path = _map(tmp_path)
    with pytest.raises(BagImportError) as caught:
        _import(cut, map_path, tmp_path / "out")
    assert str(caught.value) == (
        f"{cut}: the MCAP file ends cut off (its recorder stopped without closing it); salvage "
        f"what it holds with atikt-replay check --recover {cut}, then import the .recovered.mcap "
        "it writes"
    )
    from replay.cli._main import main as replay_main  # noqa: PLC0415

    assert replay_main(["check", "--recover", str(cut)]) in {0, 1}  # the action is cut short
    with AnyReader([tmp_path / "lab.recovered.mcap"]) as reader:
        assert sum(1 for _ in reader.messages()) > 0
    assert cut.read_bytes() == whole[: len(whole) * 2 // 3]  # the original is never touched


@pytest.mark.parametrize(
    ("files", "said"),
    [
        (["lab.mcap"], r"without metadata.yaml \(its recorder did not close it\); give its MCAP"),
        (["lab_0.db3"], r"without metadata.yaml .*; rebuild it with ros2 bag reindex"),
        ([], r"holds no bag \(no metadata.yaml, .mcap or .db3 file\); give a bag"),
    ],
)
def test_a_bag_folder_without_metadata_says_what_to_do(
    files: list[str], said: str, tmp_path: Path
) -> None:
    folder = tmp_path / "session_1"
    folder.mkdir()
    for name in files:
        (folder / name).write_bytes(b"\0" * 64)
    map_path = _map(tmp_path)
    with pytest.raises(BagImportError, match=rf"^{folder}: .*{said}"):
        _import(folder, map_path, tmp_path / "out")


def test_a_ros1_bag_cut_off_or_still_active_names_the_reindex(tmp_path: Path) -> None:
    messages, store = probe_messages(ros1=True)
    data = write_bag(tmp_path / "lab.bag", "ros1", messages, store).read_bytes()
    map_path = _map(tmp_path)
    for name in ("cut.bag", "cut.bag.active"):  # killed: cut off; unfinished: still .active
        cut = tmp_path / name
        cut.write_bytes(data[: len(data) * 2 // 3])
        with pytest.raises(BagImportError) as caught:
            _import(cut, map_path, tmp_path / "out")
        assert str(caught.value).startswith(
            f"{cut}: a ROS 1 bag cut off or without its index (its recorder was killed); "
            f"rebuild the index with rosbag reindex {cut} (ROS 1)"
        )


def test_bags_of_two_rigs_never_make_one_dataset(
    small: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # a skin of other cells: refused before anything is read; recordings of two rigs put in
    # one directory by hand: its index is refused, naming a file of each
    one, other = tmp_path / "one", tmp_path / "other"
    _import(small, _map(tmp_path), one)
    (tmp_path / "wider").mkdir()
    wider = _map(tmp_path / "wider", PROBE_MAP.replace("cells = [0]", "cells = [3]"))
    before = sorted(one.rglob("*"))
    with pytest.raises(BagImportError, match=r"holds recordings of another rig \(imported, cells"):
        _import(small, wider, one)
    assert sorted(one.rglob("*")) == before
    _import(small, wider, other)
    moved = next(other.rglob("*.mcap"))
    (one / "extra").mkdir()
    moved.rename(one / "extra" / moved.name)
    err = _cli_error(["index", str(one)], capsys)
    assert "holds recordings of 2 different rigs (imported, cells=" in err, err
    assert "cells=[0]" in err
    assert "cells=[3]" in err
    assert "a dataset holds one rig: move the recordings of one to another directory" in err


def test_an_object_a_later_run_renames_keeps_its_declaration_and_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # a later topic map (or catalog) that renames a declared object: the dataset's
    # declaration stands, and the run says so instead of dropping the new name silently
    wood = load_objects()["wood"]
    declare_objects(tmp_path, [wood])
    assert capsys.readouterr().err == ""
    declare_objects(tmp_path, [dataclasses.replace(wood, name="Oak")])
    err = capsys.readouterr().err
    assert f"objects.toml: [wood] name = {wood.name!r} is kept (this run says 'Oak'); " in err
    assert err.count("\n") == 1
    assert "Oak" not in (tmp_path / "objects.toml").read_text("utf-8")


def test_a_message_whose_field_has_another_length_is_dropped_and_counted(tmp_path: Path) -> None:
    # one probe message cut short inside the first window, one too long between two windows:
    # each is left out where it lies, counted in its recording's rows; the bag imports whole
    messages, store = probe_messages(ros1=True, session=SMALL)
    name = "probe_msgs/msg/Probes"  # the probe's message with a variable-length array
    store.register(get_types_from_msg(TYPES[PROBE].replace("[2]", "[]"), name))
    windows = SMALL.windows()
    odd = {
        min((m for m in messages if m[1] == "/probe"), key=lambda m: abs(m[0] - at))[0]: values
        for at, values in (
            (windows[0][3] + NS, [29.0]),  # inside the first window
            ((windows[0][4] + windows[1][3]) // 2, [29.0, 22.0, 21.0]),  # between two
        )
    }
    for index, (receive, topic, _, msg) in enumerate(messages):
        if topic == "/probe":
            temperatures = np.asarray(odd.get(receive, msg.temperatures), dtype=np.float32)
            copy = store.types[name](msg.header, msg.force, temperatures)
            messages[index] = (receive, topic, name, copy)
    bag = write_bag(tmp_path / "probe.bag", "ros1", messages, store)
    report = _import(bag, _map(tmp_path), tmp_path / "out")
    assert len(report.written) == len(windows)
    assert report.dropped_rows.get("temperature") == 1, report.dropped_rows
