import io
import json
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import FakeRig
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType

from recorder import (
    ActionSpec,
    JointSample,
    OutputExistsError,
    PoseSample,
    RecorderError,
    SkinBlock,
    StreamItem,
)
from recorder._catalog import ObjectSpec
from recorder.runner._record import record_action
from recorder.writing._writer import (
    METADATA_NAME,
    RecordingInfo,
    RecordingWriter,
    WrittenRecording,
    _Encoder,
)
from replay.errors import RecordingError
from replay.recording._reader import read_recording
from schemas import (
    CHANNELS,
    PART_SUFFIX,
    SCHEMA_VERSION,
    VOCABULARY,
    build_typestore,
    software_version,
)

Objects = dict[str, ObjectSpec]
Actions = dict[str, ActionSpec]


def _info(obj: ObjectSpec, action: ActionSpec, trial: int = 1, seed: int = 0) -> RecordingInfo:
    # the fake rig's description carries the time scale of its actions, for the reader
    return RecordingInfo.create(obj, action, trial, FakeRig(seed=seed), seed)


def _record(
    path: Path, obj: ObjectSpec, action: ActionSpec, seed: int = 3, **writer: Any
) -> tuple[list[StreamItem], WrittenRecording | None]:
    rig = FakeRig(seed=seed)
    items = list(rig.perform(obj, action, 2))
    with RecordingWriter(path, _info(obj, action, 2, seed), **writer) as out:
        for item in items:
            out.write(item)
    return items, out.result


@pytest.mark.parametrize(
    ("compression", "flush_interval_ns"),
    [(CompressionType.ZSTD, 500_000_000), (CompressionType.NONE, 10**12)],
)
def test_round_trip_gives_back_every_sample(
    tmp_path: Path,
    objects: Objects,
    actions: Actions,
    compression: CompressionType,
    flush_interval_ns: int,
) -> None:
    path = tmp_path / "r.mcap"
    items, result = _record(
        path,
        objects["wood"],
        actions["P1"],
        compression=compression,
        flush_interval_ns=flush_interval_ns,
    )
    recording = read_recording(path)
    assert result is not None
    assert result.path == path
    assert result.size_bytes == path.stat().st_size
    for modality in VOCABULARY.modalities:
        blocks = [i for i in items if isinstance(i, SkinBlock) and i.modality == modality]
        series = recording.skin(str(modality))
        np.testing.assert_array_equal(series.data, np.concatenate([b.data for b in blocks]))
        expected = np.concatenate(
            [b.stamp_ns + b.period_ns * np.arange(len(b.data)) for b in blocks]
        )
        np.testing.assert_array_equal(series.stamps_ns, expected)
        assert series.period_ns == blocks[0].period_ns
        assert result.message_counts[f"/skin/{modality}"] == len(blocks)
    assert recording.joints is not None
    assert recording.tcp is not None
    joints = [i for i in items if isinstance(i, JointSample)]
    np.testing.assert_array_equal(recording.joints.position, [j.position for j in joints])
    np.testing.assert_array_equal(recording.joints.effort, [j.effort for j in joints])
    np.testing.assert_array_equal(recording.joints.stamps_ns, [j.stamp_ns for j in joints])
    poses = [i for i in items if isinstance(i, PoseSample)]
    np.testing.assert_array_equal(recording.tcp.orientation, [p.orientation for p in poses])
    np.testing.assert_array_equal(recording.tcp.position, [p.position for p in poses])
    assert recording.tcp.frame_id == "base"
    assert [p.phase for p in recording.phases] == [
        "approach",
        "contact",
        "execute",
        "retract",
        "end",
    ]


def test_file_follows_the_container_contract(fake_recording: Path) -> None:
    store = build_typestore()
    with fake_recording.open("rb") as stream:
        reader = make_reader(stream)
        header = reader.get_header()
        summary = reader.get_summary()
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    assert header.profile == "ros2"
    assert summary is not None
    assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
    topics = {c.topic: c for c in summary.channels.values()}
    assert set(topics) == {c.topic for c in CHANNELS}  # the fake rig streams every channel
    for channel in CHANNELS:
        found = topics[channel.topic]
        schema = summary.schemas[found.schema_id]
        assert found.message_encoding == "cdr"
        assert (schema.name, schema.encoding) == (channel.msgtype, "ros2msg")
        assert schema.data.decode() == store.generate_msgdef(channel.msgtype, ros_version=2)[0]
        assert "=" * 80 + "\nMSG: std_msgs/Header" in schema.data.decode()
    record = metadata[METADATA_NAME]
    assert record["object_id"] == "sponge"
    assert record["action_id"] == "S2"
    assert record["trial"] == "3"
    assert record["seed"] == "7"
    assert json.loads(record["action_parameters"])["speed_m_s"] == 0.05
    assert json.loads(record["rig"])["kind"] == "fake"
    assert record["schema_version"] == str(SCHEMA_VERSION)
    assert record["software_version"] == software_version()


def test_log_time_is_receive_time_and_publish_time_the_sensor_stamp(
    tmp_path: Path, objects: Objects, actions: Actions
) -> None:
    items, _ = _record(tmp_path / "r.mcap", objects["wood"], actions["S1"])
    with (tmp_path / "r.mcap").open("rb") as stream:
        messages = [m for _, _, m in make_reader(stream).iter_messages(log_time_order=False)]
    assert [m.log_time for m in messages] == [i.receive_ns for i in items]
    assert [m.publish_time for m in messages] == [i.stamp_ns for i in items]


def test_chunks_are_flushed_every_0_35_s_of_log_time(fake_recording: Path) -> None:
    with fake_recording.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    chunks = summary.chunk_indexes
    spans = [c.message_end_time - c.message_start_time for c in chunks]
    duration = chunks[-1].message_end_time - chunks[0].message_start_time
    assert max(spans) < 360_000_000  # 0.35 s plus one message interval
    assert len(chunks) >= duration // 360_000_000


def test_same_seed_gives_identical_bytes_and_another_seed_does_not(
    tmp_path: Path, objects: Objects, actions: Actions
) -> None:
    paths = []
    for name, seed in (("a", 5), ("b", 5), ("c", 6)):
        path = tmp_path / name / "001.mcap"
        with FakeRig(seed=seed) as rig:
            record_action(rig, objects["sponge"], actions["C1"], 1, path, seed=seed)
        paths.append(path)
    assert paths[0].read_bytes() == paths[1].read_bytes()
    assert paths[0].read_bytes() != paths[2].read_bytes()


def test_existing_recording_is_never_overwritten(
    tmp_path: Path, objects: Objects, actions: Actions
) -> None:
    path = tmp_path / "001.mcap"
    path.write_bytes(b"precious")
    with pytest.raises(OutputExistsError, match=r"001\.mcap.*never overwritten"), FakeRig() as rig:
        record_action(rig, objects["wood"], actions["P1"], 1, path, seed=0)
    assert path.read_bytes() == b"precious"
    assert list(tmp_path.iterdir()) == [path]


def test_recording_that_appears_while_writing_is_kept(
    tmp_path: Path, objects: Objects, actions: Actions
) -> None:
    path = tmp_path / "001.mcap"
    with (
        pytest.raises(OutputExistsError),
        RecordingWriter(path, _info(objects["wood"], actions["P1"])),
    ):
        path.write_bytes(b"written by another recorder meanwhile")
    assert path.read_bytes() == b"written by another recorder meanwhile"
    assert list(tmp_path.iterdir()) == [path]


def test_failed_action_keeps_what_arrived_as_incomplete(
    tmp_path: Path, objects: Objects, actions: Actions
) -> None:
    path = tmp_path / "o" / "P1" / "001.mcap"
    with pytest.raises(RuntimeError, match="fake rig failure"), FakeRig(fail_after=50) as rig:
        record_action(rig, objects["wood"], actions["P1"], 1, path, seed=0)
    assert [p.name for p in path.parent.iterdir()] == ["001.incomplete.mcap"]
    with pytest.raises(
        RecordingError, match=r"incomplete recording \(the action was stopped: fake"
    ):
        read_recording(path.parent / "001.incomplete.mcap")  # kept for inspection, not learned
    with (path.parent / "001.incomplete.mcap").open("rb") as stream:
        assert sum(1 for _ in make_reader(stream).iter_messages()) > 10  # the samples before


def test_malformed_items_are_rejected(tmp_path: Path, objects: Objects, actions: Actions) -> None:
    block = SkinBlock("force", 0, 1, 0, np.zeros((4, 7), dtype=np.float32))
    joint = JointSample(0, 0, np.zeros(5), np.zeros(6), np.zeros(6))
    for item, match in ((block, "shape"), (joint, "joint position has 5 values"), ("x", "str")):
        with (
            pytest.raises(RecorderError, match=match),
            RecordingWriter(tmp_path / "r.mcap", _info(objects["wood"], actions["P1"])) as w,
        ):
            w.write(item)  # type: ignore[arg-type]
        assert not list(tmp_path.iterdir())


def test_write_outside_the_with_block_is_an_error(
    tmp_path: Path, objects: Objects, actions: Actions
) -> None:
    writer = RecordingWriter(tmp_path / "r.mcap", _info(objects["wood"], actions["P1"]))
    with pytest.raises(RecorderError, match="outside"):
        writer.write(JointSample(0, 0, np.zeros(6), np.zeros(6), np.zeros(6)))


_KILLED_RECORDER = textwrap.dedent(
    """
    import os, signal, sys
    from pathlib import Path
    import numpy as np
    from recorder import JointSample, load_actions, load_objects
    from recorder.writing._writer import RecordingInfo, RecordingWriter

    class FakeArm:
        joint_names = tuple(f"joint_{i}" for i in range(6))

        def describe(self):
            return {"kind": "fake"}

    action = load_actions()["C1"]
    info = RecordingInfo.create(load_objects()["wood"], action, 1, FakeArm(), 0)
    kill_at = int(sys.argv[2])
    with RecordingWriter(Path(sys.argv[1]), info) as writer:
        for i in range(10_000):
            stamp = 1_000_000_000 + i * 8_000_000
            writer.write(JointSample(stamp, stamp, np.full(6, i), np.zeros(6), np.zeros(6)))
            if stamp >= kill_at:
                os.kill(os.getpid(), signal.SIGKILL)
    """
)


def test_killed_recorder_loses_less_than_a_second(tmp_path: Path) -> None:
    kill_at = 4_321_000_000
    script = tmp_path / "record.py"
    script.write_text(_KILLED_RECORDER)
    final = tmp_path / "001.mcap"
    done = subprocess.run(  # noqa: S603 (our own interpreter and script)
        [sys.executable, str(script), str(final), str(kill_at)], check=False, timeout=120
    )
    assert done.returncode != 0
    assert not final.exists()
    (part,) = tmp_path.glob(f"*{PART_SUFFIX}")
    log_times, metadata = [], []
    try:
        for record in StreamReader(io.BytesIO(part.read_bytes()), validate_crcs=True).records:
            if type(record).__name__ == "Message":
                log_times.append(record.log_time)  # type: ignore[attr-defined]
            if type(record).__name__ == "Metadata":
                metadata.append(record)
    except Exception:  # noqa: BLE001, S110 (the file ends mid-record: expected)
        pass
    assert metadata, "the metadata record is written first"
    assert kill_at - max(log_times) < 1_000_000_000


def test_fixed_layout_messages_match_rosbags_serialization(
    objects: Objects, actions: Actions
) -> None:
    encoder = _Encoder(_info(objects["wood"], actions["P1"]))
    rng = np.random.default_rng(11)
    for stamp in (0, 1, 999_999_999, 1_700_000_000_123_456_789):
        q = rng.normal(size=(3, 6))
        joint = JointSample(stamp, stamp, q[0], q[1], q[2])
        assert encoder.encode(joint)[2] == encoder._joint_message(stamp, *q)
        position, orientation = rng.normal(size=3), rng.normal(size=4)
        pose = PoseSample(stamp, stamp, position, orientation)
        assert encoder.encode(pose)[2] == encoder._pose_message(stamp, position, orientation)


def test_fixed_layout_messages_take_any_float_sequence(objects: Objects, actions: Actions) -> None:
    encoder = _Encoder(_info(objects["wood"], actions["P1"]))
    q = np.random.default_rng(12).normal(size=(3, 6))
    reference = encoder._joint_message(5, *q)
    as_lists = JointSample(5, 5, q[0].tolist(), list(q[1]), tuple(q[2]))  # type: ignore[arg-type]
    as_float32 = JointSample(5, 5, q[0], q[1].astype(">f8"), q[2][None, :])
    assert encoder.encode(as_lists)[2] == reference
    assert encoder.encode(as_float32)[2] == reference
    with pytest.raises(RecorderError, match="joint velocity has 5 values"):
        encoder.encode(JointSample(5, 5, q[0], q[1][:5], q[2]))


@pytest.mark.parametrize("modality", list(VOCABULARY.modalities))
def test_skin_blocks_match_rosbags_serialization(
    objects: Objects, actions: Actions, modality: str
) -> None:
    encoder = _Encoder(_info(objects["wood"], actions["P1"]))
    rng = np.random.default_rng(13)
    msgtype = VOCABULARY.modalities[modality].msgtype
    for shape in ((1, 1, 1), (100, 7, 3), (7, 3, 2), (10, 5, 1), (3, 1, 22), (100, 7, 3)):
        for stamp, period in ((0, 1), (1_700_000_000_123_456_789, 1_000_000), (999, 2**63)):
            data = rng.normal(size=shape).astype(np.float32)
            block = SkinBlock(modality, stamp, period, stamp, data)
            topic, _, payload = encoder.encode(block)
            assert topic == VOCABULARY.modalities[modality].topic
            assert payload == encoder._block_message(msgtype, stamp, period, data)
    wide = rng.normal(size=(4, 6, 3))  # float64 and not contiguous: converted like rosbags
    block = SkinBlock(modality, 7, 8, 9, wide[:, ::2].astype(np.float64))
    expected = encoder._block_message(msgtype, 7, 8, wide[:, ::2].astype(np.float32))
    assert encoder.encode(block)[2] == expected


def test_full_disk_is_a_recorder_error_and_keeps_what_was_written(
    tmp_path: Path, objects: Objects, actions: Actions, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls = []

    def add_message(*args: object) -> None:
        calls.append(args)
        if len(calls) > 100:
            raise OSError(28, "No space left on device")

    monkeypatch.setattr("recorder.writing._mcap.McapWriter.add_message", add_message)
    with (
        pytest.raises(RecorderError, match=r"001\.mcap: writing .*No space left on device"),
        FakeRig() as rig,
    ):
        record_action(rig, objects["wood"], actions["P1"], 1, tmp_path / "001.mcap", seed=0)
    left = sorted(p.name for p in tmp_path.iterdir())
    assert "001.mcap" not in left  # never published as complete
    assert left == ["001.incomplete.mcap"]  # what was written before the disk filled is kept
