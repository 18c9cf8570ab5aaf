"""The bad-input matrix: every way a recording can be bad gets the package's error, naming the
file and the fix, one line from the CLI, and bounded memory.

Each row builds one bad file from the fake recording (or a small dataset around it), then the
same assertions run on every row: the reader raises a ``RecordingError`` (a ``ReplayError``)
whose message names the file, the reason and the fix, while Python allocates less than
:data:`MEMORY_LIMIT`; ``atikt-replay check FILE`` (and ``info FILE`` for file-level rows)
exits 1 with exactly one line on stderr and no traceback.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import shutil
import struct
import sys
import tracemalloc
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import forked
import numpy as np
import polars as pl
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from recorder import write_index
from recorder.writing._writer import METADATA_NAME
from replay import RecordingError, ReplayError, read_recording
from replay.cli._main import main
from replay.recording._reader import check_dataset_location
from schemas import build_typestore

#: Largest Python allocation (tracemalloc peak) allowed while refusing any bad file.
MEMORY_LIMIT = 64 * 2**20
STORE = build_typestore()
NS = 1_000_000_000
_JOINTS = "/robot/joint_states"
_FORCE = "/skin/force"
_EVENTS = "/action/events"


@dataclass
class Entry:
    """One message of a recording being rewritten."""

    topic: str
    log_ns: int
    publish_ns: int
    payload: bytes


Edit = Callable[[list[Entry]], list[Entry]]


def _keep(entries: list[Entry]) -> list[Entry]:
    return entries


def _copy(
    source: Path,
    target: Path,
    *,
    edit: Edit = _keep,
    profile: str = "ros2",
    metadata: Mapping[str, str] | None = None,
    schemas: Mapping[str, tuple[str, bytes]] | None = None,
    drop_channel: str = "",
    split_topic: str = "",
) -> Path:
    """Copy a recording through the mcap writer, changing what the arguments say.

    ``split_topic``: a second channel on that topic carries every other message of it.
    """
    with source.open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None
        records = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        entries = [
            Entry(channel.topic, m.log_time, m.publish_time, m.data)
            for _, channel, m in reader.iter_messages(log_time_order=False)
        ]
    target.parent.mkdir(parents=True, exist_ok=True)
    with target.open("wb") as out:
        writer = Writer(out)
        writer.start(profile=profile, library="test")
        writer.add_metadata(METADATA_NAME, dict(metadata or records[METADATA_NAME]))
        ids = {}
        for channel in summary.channels.values():
            if channel.topic == drop_channel:
                continue
            schema = summary.schemas[channel.schema_id]
            name, text = (schemas or {}).get(channel.topic, (schema.name, schema.data))
            schema_id = writer.register_schema(name, schema.encoding, text)
            ids[channel.topic] = writer.register_channel(channel.topic, "cdr", schema_id)
            if channel.topic == split_topic:
                ids["split"] = writer.register_channel(channel.topic, "cdr", schema_id)
        count = 0
        for entry in edit(entries):
            if entry.topic in ids:
                key = entry.topic
                if key == split_topic:
                    count += 1
                    key = "split" if count % 2 else key
                writer.add_message(ids[key], entry.log_ns, entry.payload, entry.publish_ns)
        writer.finish()  # type: ignore[no-untyped-call]
    return target


def _msgtype(topic: str) -> str:
    return {
        _JOINTS: "sensor_msgs/msg/JointState",
        _FORCE: "tactile_msgs/msg/SkinForce",
        _EVENTS: "tactile_msgs/msg/ActionEvent",
    }[topic]


def _changed(entry: Entry, change: Callable[[Any], None]) -> Entry:
    """Return ``entry`` with its decoded message changed in place by ``change``."""
    msgtype = _msgtype(entry.topic)
    message = STORE.deserialize_cdr(entry.payload, msgtype)
    change(message)
    payload = bytes(STORE.serialize_cdr(message, msgtype))
    return dataclasses.replace(entry, payload=payload)


def _on(topic: str, index: int, change: Callable[[Any], None]) -> Edit:
    """Return an edit changing message ``index`` of ``topic``."""

    def edit(entries: list[Entry]) -> list[Entry]:
        positions = [i for i, e in enumerate(entries) if e.topic == topic]
        entries[positions[index]] = _changed(entries[positions[index]], change)
        return entries

    return edit


def _every(topic: str, change: Callable[[Any], None]) -> Edit:
    def edit(entries: list[Entry]) -> list[Entry]:
        return [_changed(e, change) if e.topic == topic else e for e in entries]

    return edit


def _duplicate(topic: str, index: int) -> Edit:
    def edit(entries: list[Entry]) -> list[Entry]:
        position = [i for i, e in enumerate(entries) if e.topic == topic][index]
        return [*entries[: position + 1], entries[position], *entries[position + 1 :]]

    return edit


def _swap(topic: str, index: int) -> Edit:
    def edit(entries: list[Entry]) -> list[Entry]:
        a, b = [i for i, e in enumerate(entries) if e.topic == topic][index : index + 2]
        entries[a], entries[b] = (
            dataclasses.replace(entries[a], payload=entries[b].payload),
            dataclasses.replace(entries[b], payload=entries[a].payload),
        )
        return entries

    return edit


def _cut_during_execute(entries: list[Entry]) -> list[Entry]:
    """Keep what a rig sends until a third into the execute phase (then it stopped)."""
    events: list[Any] = [
        STORE.deserialize_cdr(e.payload, _msgtype(_EVENTS)) for e in entries if e.topic == _EVENTS
    ]
    execute = next(e for e in events if e.phase == "execute")
    start = execute.header.stamp.sec * NS + execute.header.stamp.nanosec
    end = next(e for e in events if e.phase == "retract").header.stamp
    stop = start + (end.sec * NS + end.nanosec - start) // 3
    return [e for e in entries if e.log_ns < stop]


def _execute_start(entries: list[Entry]) -> int:
    events: list[Any] = [
        STORE.deserialize_cdr(e.payload, _msgtype(_EVENTS)) for e in entries if e.topic == _EVENTS
    ]
    stamp = next(e for e in events if e.phase == "execute").header.stamp
    return int(stamp.sec * NS + stamp.nanosec)


def _pause_in_execute(entries: list[Entry]) -> list[Entry]:
    """Delay every force block from the second one of the execute phase by 50 ms (a pause)."""
    start = _execute_start(entries)
    later = [i for i, e in enumerate(entries) if e.topic == _FORCE and e.publish_ns > start + 10**7]

    def delay(message: Any) -> None:
        stamp = message.header.stamp.sec * NS + message.header.stamp.nanosec + 50_000_000
        message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, NS)

    for i in later:
        entries[i] = _changed(entries[i], delay)
    return entries


def _without_end(entries: list[Entry]) -> list[Entry]:
    """Drop the retract and end events (a file cut after its execute phase)."""
    keep = []
    for entry in entries:
        if entry.topic == _EVENTS:
            event: Any = STORE.deserialize_cdr(entry.payload, _msgtype(_EVENTS))
            if event.phase in {"retract", "end"}:
                continue
        keep.append(entry)
    return keep


def _reordered_joint_state() -> dict[str, tuple[str, bytes]]:
    text = STORE.generate_msgdef("sensor_msgs/msg/JointState", ros_version=2)[0]
    swapped = text.replace("float64[] position", "@").replace(
        "float64[] velocity", "float64[] position"
    )
    return {
        _JOINTS: ("sensor_msgs/msg/JointState", swapped.replace("@", "float64[] velocity").encode())
    }


def _late(log_ns: int) -> Edit:
    """Return an edit giving one temperature message an out-of-range log time (found by fuzzing)."""

    def edit(entries: list[Entry]) -> list[Entry]:
        position = [i for i, e in enumerate(entries) if e.topic == "/skin/temperature"][3]
        entries[position] = dataclasses.replace(entries[position], log_ns=log_ns)
        return entries

    return edit


def _meta(path: Path, **changes: str) -> dict[str, str]:
    with path.open("rb") as stream:
        records = {m.name: dict(m.metadata) for m in make_reader(stream).iter_metadata()}
    return records[METADATA_NAME] | changes


def _chunk_offset(data: bytes | bytearray) -> int:
    """Return the offset of the first chunk record."""
    pos = 8
    while data[pos] != 0x06:
        (length,) = struct.unpack_from("<Q", data, pos + 1)
        pos += 9 + length
    return pos


def _zero_crcs(data: bytearray) -> bytearray:
    """Set the data section and summary CRCs to 0 ("not computed"), so deeper checks run."""
    footer = len(data) - 8 - 29
    summary_start = struct.unpack_from("<Q", data, footer + 9)[0]
    struct.pack_into("<I", data, footer + 25, 0)
    struct.pack_into("<I", data, summary_start - 4, 0)
    return data


def _bytes(change: Callable[[bytearray], bytearray | bytes]) -> Callable[[Path, Path], Path]:
    def build(source: Path, target: Path) -> Path:
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(bytes(change(bytearray(source.read_bytes()))))
        return target

    return build


def _part(source: Path, target: Path) -> Path:
    target.parent.mkdir(parents=True, exist_ok=True)
    return Path(shutil.copyfile(source, target))


def _truncated(fraction: float) -> Callable[[Path, Path], Path]:
    return _bytes(lambda data: data[: int(len(data) * fraction)])


def _flip_chunk_bit(data: bytearray) -> bytearray:
    data[_chunk_offset(data) + 200] ^= 0x10
    return data


def _huge_length(zero_crcs: bool) -> Callable[[bytearray], bytearray]:  # noqa: FBT001
    def change(data: bytearray) -> bytearray:
        struct.pack_into("<Q", data, _chunk_offset(data) + 1, 2**62)
        return _zero_crcs(data) if zero_crcs else data

    return change


def _absurd_size(data: bytearray) -> bytearray:
    struct.pack_into("<Q", data, _chunk_offset(data) + 9 + 16, 2**50)
    return _zero_crcs(data)


def _rewritten(**options: Any) -> Callable[[Path, Path], Path]:
    def build(source: Path, target: Path) -> Path:
        if "metadata_changes" in options:
            options["metadata"] = _meta(source, **options.pop("metadata_changes"))
        return _copy(source, target, **options)

    return build


def _redefined() -> dict[str, tuple[str, bytes]]:
    text = STORE.generate_msgdef("tactile_msgs/msg/SkinForce", ros_version=2)[0]
    return {
        _FORCE: (
            "tactile_msgs/msg/SkinForce",
            text.replace("float32[] data", "float64[] data").encode(),
        )
    }


def _set(field: str, value: Any) -> Callable[[Any], None]:
    def change(message: Any) -> None:
        setattr(message, field, value)

    return change


def _poison(field: str, value: float, at: int) -> Callable[[Any], None]:
    def change(message: Any) -> None:
        array = np.array(getattr(message, field))
        array.reshape(-1)[at] = value
        setattr(message, field, array)

    return change


def _phase(name: str) -> Callable[[Any], None]:
    return _set("phase", name)


def _in_dataset(other_trial: bool) -> Callable[[Path, Path], Path]:  # noqa: FBT001
    """Place the recording in a dataset with an index; misplaced or with a stale index row."""

    def build(source: Path, target: Path) -> Path:
        root = target.parent / "dataset"
        good = root / "sponge" / "S2" / "003.mcap"
        good.parent.mkdir(parents=True)
        shutil.copyfile(source, good)
        if other_trial:  # the same recording again, under trial 4: the path contradicts it
            shutil.copyfile(source, good.with_name("004.mcap"))
            write_index(root)
            return good.with_name("004.mcap")
        index = write_index(root)
        pl.read_parquet(index).with_columns(seed=pl.lit(99, pl.Int64)).write_parquet(index)
        return good

    return build


@dataclass(frozen=True)
class Row:
    """One kind of bad input: how to build it, what the error says, what the fix says."""

    build: Callable[[Path, Path], Path]
    reason: str
    fix: str
    file_level: bool = True  # False: a dataset-level check (``check``, not ``info``)


ROWS: dict[str, Row] = {
    "empty file": Row(_bytes(lambda _: b""), "0 bytes", "record the action again"),
    "not MCAP": Row(
        _bytes(lambda _: b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4),
        "does not start with the MCAP magic",
        "give a recording written by atikt-record",
    ),
    "truncated 10 %": Row(_truncated(0.1), "missing MCAP magic at the end", "check --recover"),
    "truncated 50 %": Row(_truncated(0.5), "missing MCAP magic at the end", "check --recover"),
    "truncated 90 %": Row(_truncated(0.9), "missing MCAP magic at the end", "check --recover"),
    "truncated 99.9 %": Row(_truncated(0.999), "missing MCAP magic at the end", "check --recover"),
    "unfinished .part": Row(
        lambda source, target: _part(source, target.with_suffix(".mcap.part")),
        "unfinished recording",
        "check --recover",
    ),
    "flipped bit (CRC)": Row(
        _bytes(_flip_chunk_bit), "data section CRC mismatch", "record it again"
    ),
    "record length beyond the file (CRC)": Row(
        _bytes(_huge_length(zero_crcs=False)), "data section CRC mismatch", "restore it"
    ),
    "record length beyond the file (no CRC)": Row(
        _bytes(_huge_length(zero_crcs=True)), r"claims 4611686018427387904 bytes", "check --recover"
    ),
    "absurd uncompressed size": Row(
        _bytes(_absurd_size), r"claims 1125899906842624 uncompressed bytes", "restore it"
    ),
    "wrong profile": Row(
        _rewritten(profile="ros1"), "profile 'ros1', expected 'ros2'", "give one written by"
    ),
    "newer schema version": Row(
        _rewritten(metadata_changes={"schema_version": "99"}),
        "schema version 99 is newer",
        "pip install -U atikt",
    ),
    "unknown schema version": Row(
        _rewritten(metadata_changes={"schema_version": "0"}),
        "schema version 0 is not supported",
        "read it with the release that wrote it",
    ),
    "messages of another schema version": Row(
        _rewritten(edit=_every(_FORCE, _set("schema_version", 2))),
        "messages of schema version 2",
        "atikt release that wrote it",
    ),
    "message type defined differently": Row(
        _rewritten(schemas=_redefined()),
        "defines tactile_msgs/msg/SkinForce differently",
        "atikt release that wrote it",
    ),
    "unknown message type": Row(
        _rewritten(schemas={_FORCE: ("tactile_msgs/msg/SkinWrench", b"float32[] data")}),
        "carries tactile_msgs/msg/SkinWrench",
        "convert it with atikt-record import-bag",
    ),
    "missing needed modality": Row(
        _rewritten(drop_channel="/skin/acceleration"),
        r"a 'slide' action \(S2\) needs the skin modality acceleration, the recording has "
        "force, temperature, proximity",
        "record it with a skin that has it",
    ),
    "empty events channel": Row(
        _rewritten(edit=lambda entries: [e for e in entries if e.topic != _EVENTS]),
        r"the action events channel /action/events .* is missing or empty",
        "record the action again",
    ),
    "duplicated message": Row(
        _rewritten(edit=_duplicate(_JOINTS, 10)),
        r"/robot/joint_states: sample 11 .* repeats",
        "record the action again",
    ),
    "duplicated skin block": Row(
        _rewritten(edit=_duplicate(_FORCE, 2)),
        r"/skin/force: sample 75 .* goes back",
        "record the action again",
    ),
    "non-monotonic stamps": Row(
        _rewritten(edit=_swap(_JOINTS, 20)), r"sample 21 .* goes back", "record the action again"
    ),
    "time beyond int64": Row(
        _rewritten(edit=_late(2**64 - 1)), "a time beyond 2\\*\\*63 - 1 ns", "restore it"
    ),
    "NaN in a skin signal": Row(
        _rewritten(edit=_on(_FORCE, 3, _poison("data", math.nan, 17))),
        r"/skin/force: 1 force values are NaN or infinite",
        "check the rig and record the action again",
    ),
    "infinity in the joint states": Row(
        _rewritten(edit=_on(_JOINTS, 5, _poison("effort", math.inf, 2))),
        r"1 effort values are NaN or infinite, the first in sample 5",
        "record the action again",
    ),
    "NaN action parameter": Row(
        _rewritten(
            metadata_changes={
                "action_parameters": json.dumps({"duration_s": math.nan, "force_n": 0.1})
            }
        ),
        "action parameter duration_s=nan is not a finite number",
        "record it again",
    ),
    "recording cut during execute": Row(
        _rewritten(edit=_cut_during_execute),
        "the recording lacks the phases retract, end",
        "--recover",
    ),
    "action shorter than its parameters": Row(
        _rewritten(
            metadata_changes={
                "action_parameters": json.dumps(
                    {"duration_s": 9.0, "force_n": 0.1, "speed_m_s": 0.05}
                )
            }
        ),
        "the action was cut short",
        "record it again",
    ),
    "phases out of order": Row(
        _rewritten(edit=_on(_EVENTS, 1, _phase("retract"))),
        "are not phases of approach, contact, execute, retract, end",
        "record the action again",
    ),
    "events about another object": Row(
        _rewritten(edit=_every(_EVENTS, _set("object_id", "wood"))),
        "action events are about wood S2",
        "record the action again",
    ),
    "missing metadata record entry": Row(
        _rewritten(metadata={"object_id": "sponge"}),
        "metadata record lacks",
        "record it again",
    ),
    "malformed metadata": Row(
        _rewritten(metadata_changes={"trial": "third"}),
        "trial 'third' is not an integer",
        "record it again",
    ),
    "two channels on one topic": Row(
        _rewritten(split_topic=_FORCE),
        "two channels carry the topic /skin/force",
        "one channel per topic",
    ),
    "pause inside the execute phase": Row(
        _rewritten(edit=_pause_in_execute),
        r"force pauses 0\.05\d s .* inside the execute phase",
        "record the action again",
    ),
    "kind contradicting the action": Row(
        _rewritten(metadata_changes={"action_kind": "static"}),
        r"events are about sponge S2 \(slide\) .* \(static\)",
        "record the action again",
    ),
    "standard type reordered": Row(
        _rewritten(schemas=_reordered_joint_state()),
        r"defines sensor_msgs/msg/JointState differently from this software.*velocity",
        "convert it with atikt-record import-bag",
    ),
    "recording without its end": Row(
        _rewritten(edit=_without_end),
        "lacks the phases retract, end",
        "--recover",
    ),
    "salvage without its end in a dataset": Row(
        _rewritten(edit=_without_end, metadata_changes={"source": "salvage"}),
        "a salvaged recording that lost its end phase is not a recording of the dataset",
        "record the action again",
        file_level=False,
    ),
    "metadata contradicts the path": Row(
        _in_dataset(other_trial=True),
        "the metadata says trial 3, the dataset path says trial 4",
        "atikt-record index",
        file_level=False,
    ),
    "metadata contradicts the index": Row(
        _in_dataset(other_trial=False),
        r"index .* says seed 99 \(the file: 7\)",
        "rebuild it with 'atikt-record index",
        file_level=False,
    ),
}


def _load(path: Path) -> None:
    """Read a recording as ``atikt-replay check`` does: on its own and in its dataset."""
    check_dataset_location(read_recording(path))


@pytest.fixture(params=list(ROWS), ids=list(ROWS))
def bad(request: pytest.FixtureRequest, fake_recording: Path, tmp_path: Path) -> tuple[Row, Path]:
    row = ROWS[request.param]
    return row, row.build(fake_recording, tmp_path / "bad" / "003.mcap")


def test_reader_refuses_with_its_own_error_naming_file_reason_and_fix(
    bad: tuple[Row, Path],
) -> None:
    row, path = bad
    tracemalloc.start()
    try:
        with pytest.raises(RecordingError) as caught:
            _load(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    message = str(caught.value)
    assert isinstance(caught.value, ReplayError)
    assert f"{path}:" in message
    assert re.search(row.reason, message), message
    assert row.fix in message, message
    assert "\n" not in message
    assert peak < MEMORY_LIMIT


def test_cli_says_one_line_and_exits_non_zero(
    bad: tuple[Row, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    row, path = bad
    commands = [["check", str(path)]] + ([["info", str(path)]] if row.file_level else [])
    for command in commands:
        assert main(command) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1, err
        assert str(path) in err
        assert row.fix in err
        assert "Traceback" not in err


def test_the_good_file_passes_the_same_checks(
    fake_recording: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    _load(fake_recording)
    _load(_copy(fake_recording, tmp_path / "copy.mcap"))  # the rewriting itself breaks nothing
    root = tmp_path / "clean" / "dataset"
    (root / "sponge" / "S2").mkdir(parents=True)
    shutil.copyfile(fake_recording, root / "sponge" / "S2" / "003.mcap")
    write_index(root)
    _load(root / "sponge" / "S2" / "003.mcap")
    monkeypatch.chdir(root / "sponge")  # relative paths name the same dataset location
    _load(Path("S2/003.mcap"))
    monkeypatch.chdir(root / "sponge" / "S2")
    _load(Path("003.mcap"))
    shutil.copyfile("003.mcap", "004.mcap")  # misplaced: refused by a relative path too
    with pytest.raises(RecordingError, match=r"^004\.mcap: the metadata says trial 3"):
        _load(Path("004.mcap"))
    Path("004.mcap").unlink()
    assert main(["check", str(root), "--workers", "1"]) == 0
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("row", ["not MCAP", "truncated 50 %"])
def test_installed_command_prints_one_line_without_traceback(
    row: str, fake_recording: Path, tmp_path: Path
) -> None:
    path = ROWS[row].build(fake_recording, tmp_path / "003.mcap")
    done = forked.run(
        [sys.executable, "-m", "replay", "check", str(path)],
        capture_output=True,
        text=True,
        check=False,
        timeout=120,
    )
    assert done.returncode == 1
    assert done.stderr.count("\n") == 1, done.stderr
    assert "Traceback" not in done.stderr
    assert str(path) in done.stderr


def test_message_fields_are_really_changed(fake_recording: Path, tmp_path: Path) -> None:
    """The rows' edits do what they say (a row that changed nothing could pass by accident)."""
    path = ROWS["NaN in a skin signal"].build(fake_recording, tmp_path / "n.mcap")
    with path.open("rb") as stream:
        forces: list[Any] = [
            STORE.deserialize_cdr(m.data, "tactile_msgs/msg/SkinForce")
            for _, c, m in make_reader(stream).iter_messages(log_time_order=False)
            if c.topic == _FORCE
        ]
    assert int(np.isnan(np.concatenate([f.data for f in forces])).sum()) == 1
    assert bool(np.isnan(forces[3].data[17]))


def test_info_of_a_file_that_fails_its_checks_shows_what_it_holds(
    fake_recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # the lab needs to see what such a file holds (its channels, its sources' accounting)
    path = ROWS["pause inside the execute phase"].build(fake_recording, tmp_path / "003.mcap")
    assert main(["info", str(path)]) == 1
    out, err = capsys.readouterr()
    assert err.count("\n") == 1, err
    assert re.search(r"force pauses 0\.05\d s .* inside the execute phase", err), err
    assert "/skin/force" in out, out  # the channels, with their message counts
    assert main(["info", "--json", str(path)]) == 1
    shown = json.loads(capsys.readouterr().out)
    assert shown["kind"] == "failing"
    assert "force pauses" in shown["error"]
    assert any(c["name"] == "/skin/force" and c["messages"] > 0 for c in shown["channels"])
