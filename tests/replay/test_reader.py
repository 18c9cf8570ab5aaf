import dataclasses
import itertools
import zlib
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from recorder.writing._writer import METADATA_NAME
from replay import MODALITIES, ActionRecording, RecordingError, read_recording
from replay.recording._container import read_container, read_summary
from schemas import SCHEMA_VERSION


def _rewrite(
    source: Path,
    target: Path,
    *,
    profile: str = "ros2",
    metadata: Mapping[str, str] | None = None,
    drop_topic: str = "",
    retype: tuple[str, str] = ("", ""),
) -> Path:
    """Copy a recording through the mcap writer, changing one aspect of it."""
    with source.open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None
        records = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        messages = list(reader.iter_messages(log_time_order=False))
    with target.open("wb") as out:
        writer = Writer(out)
        writer.start(profile=profile, library="test")
        writer.add_metadata(METADATA_NAME, dict(metadata or records[METADATA_NAME]))
        ids = {}
        for channel in summary.channels.values():
            schema = summary.schemas[channel.schema_id]
            name = retype[1] if channel.topic == retype[0] else schema.name
            schema_id = writer.register_schema(name, schema.encoding, schema.data)
            ids[channel.id] = writer.register_channel(channel.topic, "cdr", schema_id)
        for _, channel, message in messages:
            if channel.topic != drop_topic:
                writer.add_message(
                    ids[channel.id], message.log_time, message.data, message.publish_time
                )
        writer.finish()  # type: ignore[no-untyped-call]
    return target


#: Two recordings of schema 1 (atikt 0.1), kept to show they stay readable.
SCHEMA_1 = Path(__file__).resolve().parents[1] / "data" / "schema1"


def test_recording_is_typed_and_immutable(fake_recording: Path) -> None:
    recording = read_recording(fake_recording)
    assert isinstance(recording, ActionRecording)
    assert recording.metadata.object_id == "sponge"
    assert recording.metadata.action_id == "S2"
    assert recording.metadata.trial == 3
    assert recording.metadata.source == "recorder"
    assert recording.modalities == MODALITIES  # the fake rig streams every modality
    assert recording.metadata.action_parameters["speed_m_s"] == 0.05
    assert recording.metadata.schema_version == SCHEMA_VERSION
    for modality in MODALITIES:
        series = recording.skin(modality)
        assert series.data.dtype == np.float32
        assert series.stamps_ns.dtype == np.int64
        assert series.data.ndim == 3
        assert series.data.shape[:2] == (series.stamps_ns.size, 7)
        assert not series.data.flags.writeable
        assert not series.stamps_ns.flags.writeable
        assert bool(np.all(np.diff(series.stamps_ns) > 0))
    widths = {m: s.data.shape[2] for m, s in recording.signals.items()}
    assert widths == {"force": 3, "temperature": 1, "acceleration": 3, "proximity": 1}
    assert recording.joints is not None
    assert recording.tcp is not None
    assert recording.joints.position.shape == (recording.joints.stamps_ns.size, 6)
    assert recording.joints.names[0] == "joint_0"
    assert recording.tcp.orientation.shape == (recording.tcp.stamps_ns.size, 4)
    for array in (recording.joints.velocity, recording.tcp.position):
        assert not array.flags.writeable
        with pytest.raises(ValueError, match="read-only"):
            array[0] = 1.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        recording.signals = recording.signals  # type: ignore[misc]
    with pytest.raises(TypeError):
        recording.signals["force"] = recording.skin("force")  # type: ignore[index]
    with pytest.raises(TypeError):
        recording.metadata.rig["kind"] = "other"  # type: ignore[index]


def test_phase_ranges_are_half_open_and_tile_the_recording(fake_recording: Path) -> None:
    recording = read_recording(fake_recording)
    ranges = [recording.phase_range(mark.phase) for mark in recording.phases]
    assert all(stop == start for (_, stop), (start, _) in itertools.pairwise(ranges))
    start, stop = recording.phase_range("execute")
    force = recording.skin("force")
    inside = recording.during("execute", "force")
    assert inside.stamps_ns[0] >= start
    assert inside.stamps_ns[-1] < stop
    assert inside.stamps_ns.size == int(
        np.sum((force.stamps_ns >= start) & (force.stamps_ns < stop))
    )
    # A sample exactly at ``stop`` belongs to the next phase, one at ``start`` to this one.
    at = force.between(int(force.stamps_ns[10]), int(force.stamps_ns[20]))
    np.testing.assert_array_equal(at.stamps_ns, force.stamps_ns[10:20])
    assert force.between(5, 5).data.shape == (0, 7, 3)
    with pytest.raises(RecordingError, match=r"no phase 'squeeze'.*approach, contact"):
        recording.phase_range("squeeze")
    with pytest.raises(RecordingError, match=r"has no 'smell' channel"):
        recording.skin("smell")


def test_corrupt_chunk_is_caught_by_its_crc(fake_recording: Path, tmp_path: Path) -> None:
    data = bytearray(fake_recording.read_bytes())
    with fake_recording.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    chunk = summary.chunk_indexes[1]
    data[chunk.chunk_start_offset + chunk.chunk_length // 2] ^= 0xFF
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(RecordingError, match=r"bad\.mcap: .*CRC mismatch.*record it again"):
        read_recording(bad)


def test_every_byte_flip_in_the_summary_is_caught(fake_recording: Path, tmp_path: Path) -> None:
    data = fake_recording.read_bytes()
    rng = np.random.default_rng(0)
    for position in rng.integers(len(data) - 2000, len(data) - 8, 20):
        changed = bytearray(data)
        changed[position] ^= 0x01
        bad = tmp_path / "bad.mcap"
        bad.write_bytes(bytes(changed))
        with pytest.raises(RecordingError, match=r"bad.mcap"):
            read_recording(bad)


def test_truncated_and_unfinished_files_name_the_fix(fake_recording: Path, tmp_path: Path) -> None:
    data = fake_recording.read_bytes()
    truncated = tmp_path / "001.mcap"
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(RecordingError, match="truncated or corrupt"):
        read_recording(truncated)
    part = tmp_path / "001.1234-abcd.mcap.part"
    part.write_bytes(data[: len(data) // 2])
    with pytest.raises(RecordingError, match="interrupted"):
        read_summary(part)
    with pytest.raises(RecordingError, match="cannot read the recording"):
        read_recording(tmp_path / "missing.mcap")
    (tmp_path / "text.mcap").write_text("hello")
    with pytest.raises(RecordingError, match=r"text.mcap: not a valid MCAP"):
        read_recording(tmp_path / "text.mcap")


def test_data_section_crc_is_checked(fake_recording: Path, tmp_path: Path) -> None:
    data = bytearray(fake_recording.read_bytes())
    data[20] ^= 0x01  # inside the header record, which no chunk CRC covers
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(RecordingError, match="data section CRC"):
        read_container(bad)


def test_wrong_profile_is_rejected(fake_recording: Path, tmp_path: Path) -> None:
    bad = _rewrite(fake_recording, tmp_path / "x.mcap", profile="ros1")
    with pytest.raises(RecordingError, match="profile 'ros1', expected 'ros2'"):
        read_recording(bad)


def test_newer_schema_version_asks_for_an_upgrade(fake_recording: Path, tmp_path: Path) -> None:
    meta = dict(read_summary(fake_recording).metadata[METADATA_NAME])
    newer = _rewrite(fake_recording, tmp_path / "n.mcap", metadata=meta | {"schema_version": "99"})
    with pytest.raises(RecordingError, match=r"schema version 99 is newer.*pip install -U atikt"):
        read_recording(newer)
    older = _rewrite(fake_recording, tmp_path / "o.mcap", metadata=meta | {"schema_version": "0"})
    with pytest.raises(
        RecordingError, match=r"schema version 0 is not supported.*the release that wrote it"
    ):
        read_recording(older)


def test_missing_or_malformed_metadata_is_rejected(fake_recording: Path, tmp_path: Path) -> None:
    meta = dict(read_summary(fake_recording).metadata[METADATA_NAME])
    del meta["trial"]
    bad = _rewrite(fake_recording, tmp_path / "m.mcap", metadata=meta)
    with pytest.raises(RecordingError, match=r"lacks trial.*atikt-record"):
        read_recording(bad)
    meta["trial"] = "third"
    bad = _rewrite(fake_recording, tmp_path / "t.mcap", metadata=meta)
    with pytest.raises(RecordingError, match=r"trial '.*' is not an integer"):
        read_recording(bad)


def test_optional_channels_may_be_absent_and_needed_ones_are_named(
    fake_recording: Path, tmp_path: Path
) -> None:
    partial = _rewrite(fake_recording, tmp_path / "c.mcap", drop_topic="/skin/proximity")
    assert read_recording(partial).modalities == ("force", "temperature", "acceleration")
    armless = _rewrite(partial, tmp_path / "a.mcap", drop_topic="/robot/joint_states")
    armless = _rewrite(armless, tmp_path / "b.mcap", drop_topic="/robot/tcp_pose")
    recording = read_recording(armless)
    assert recording.joints is None
    assert recording.tcp is None
    bad = _rewrite(fake_recording, tmp_path / "d.mcap", drop_topic="/skin/acceleration")
    with pytest.raises(RecordingError, match=r"'slide' action \(S2\) needs .* acceleration"):
        read_recording(bad)


def test_schema_1_recordings_stay_readable() -> None:
    for path in sorted(SCHEMA_1.glob("*.mcap")):
        recording = read_recording(path)
        assert recording.metadata.schema_version == 1
        assert recording.modalities == MODALITIES
        assert recording.joints is not None
        assert recording.joints.names[0] == "shoulder_pan_joint"
        assert [p.phase for p in recording.phases][-1] == "end"


def test_channel_with_the_wrong_type_is_rejected(fake_recording: Path, tmp_path: Path) -> None:
    bad = _rewrite(
        fake_recording, tmp_path / "w.mcap", retype=("/skin/force", "tactile_msgs/msg/SkinWrench")
    )
    with pytest.raises(RecordingError, match="carries tactile_msgs/msg/SkinWrench"):
        read_recording(bad)


def test_reader_agrees_with_a_rewritten_copy(fake_recording: Path, tmp_path: Path) -> None:
    copy = _rewrite(fake_recording, tmp_path / "copy.mcap")
    assert zlib.crc32(copy.read_bytes()) != zlib.crc32(fake_recording.read_bytes())
    a, b = read_recording(fake_recording), read_recording(copy)
    for modality in MODALITIES:
        np.testing.assert_array_equal(a.skin(modality).data, b.skin(modality).data)
    assert a.phases == b.phases
    assert a.metadata == b.metadata
