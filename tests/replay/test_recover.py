"""Crash safety: a killed recorder or a truncated file is never read as complete, and
``atikt-replay check --recover`` salvages every flushed message into a valid file marked as
recovered, without touching the original."""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import io
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from conftest import FakeRig, fake_objects
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader

from recorder import load_actions
from recorder.runner._record import record_action
from recorder.writing._writer import FLUSH_INTERVAL_NS, RecordingInfo, _Encoder
from replay import MODALITIES, RecordingError, read_recording
from replay.cli._main import main
from replay.recording._salvage import RECOVERY_NAME, recovered_path, salvage
from schemas import PART_SUFFIX

NS = 1_000_000_000
TESTS = Path(__file__).resolve().parents[1]

#: Records C1 on the wood with a real-time fake rig and kills itself (SIGKILL) as soon as it
#: has written the first item received at or after ``argv[2]`` ns.
_KILLED_RECORDER = textwrap.dedent(
    """
    import os, signal, sys
    from pathlib import Path
    sys.path[:0] = [str(Path(sys.argv[3]).parent)]  # the packages: tests/recorder is not
    sys.path.append(sys.argv[3])  # recorder; conftest (the fake rig) after them
    from conftest import FakeRig, fake_objects
    from recorder import load_actions
    from recorder.writing._writer import RecordingInfo, RecordingWriter

    obj, action = fake_objects()["wood"], load_actions()["C1"]
    rig = FakeRig(seed=5, time_scale=1.0)
    info = RecordingInfo.create(obj, action, 1, rig, 5)
    kill_at = int(sys.argv[2])
    with rig, RecordingWriter(Path(sys.argv[1]), info) as writer:
        for item in rig.perform(obj, action, 1):
            writer.write(item)
            if item.receive_ns >= kill_at:
                os.kill(os.getpid(), signal.SIGKILL)
    """
)


@functools.cache
def _stream_messages() -> list[tuple[str, int, bytes]]:
    """Return (topic, log time, payload) of everything the killed recorder would write."""
    obj, action = fake_objects()["wood"], load_actions()["C1"]
    rig = FakeRig(seed=5, time_scale=1.0)
    encoder = _Encoder(RecordingInfo.create(obj, action, 1, rig, 5))
    messages = []
    for item in rig.perform(obj, action, 1):
        topic, _, payload = encoder.encode(item)
        messages.append((topic, item.receive_ns, payload))
    return messages


def _messages(path: Path) -> list[tuple[str, int, bytes]]:
    """Return (topic, log time, payload) of a complete file, in file order, CRCs checked."""
    with path.open("rb") as stream:
        reader = make_reader(stream, validate_crcs=True)
        return [
            (channel.topic, message.log_time, message.data)
            for _, channel, message in reader.iter_messages(log_time_order=False)
        ]


def _recovery(path: Path) -> dict[str, str]:
    with path.open("rb") as stream:
        records = {m.name: dict(m.metadata) for m in make_reader(stream).iter_metadata()}
    return records[RECOVERY_NAME]


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _kill_recorder(tmp_path: Path, kill_at: int) -> Path:
    script = tmp_path / "record.py"
    script.write_text(_KILLED_RECORDER)
    final = tmp_path / "wood" / "C1" / "001.mcap"
    done = subprocess.run(  # noqa: S603 (our own interpreter and script)
        [sys.executable, str(script), str(final), str(kill_at), str(TESTS)],
        check=False,
        timeout=120,
    )
    assert done.returncode == -9  # killed by SIGKILL
    assert not final.exists()
    (part,) = final.parent.glob(f"*{PART_SUFFIX}")
    return part


@pytest.mark.parametrize("kill_s", [5.3, 14.6], ids=["early in execute", "late in execute"])
def test_killed_recorder_loses_at_most_one_flush_interval(
    tmp_path: Path, kill_s: float, capsys: pytest.CaptureFixture[str]
) -> None:
    kill_at = round(kill_s * NS)
    part = _kill_recorder(tmp_path, kill_at)
    before = _sha(part)
    with pytest.raises(RecordingError, match=r"unfinished recording.*check --recover"):
        read_recording(part)
    assert main(["check", str(part.parent.parent.parent)]) == 1
    assert "check --recover" in capsys.readouterr().err

    assert main(["check", str(part), "--recover"]) == 0
    out = capsys.readouterr().out
    target = recovered_path(part)
    assert _sha(part) == before  # the original is untouched
    assert target.name.endswith(".recovered.mcap")
    assert f"into {target}" in " ".join(out.split())

    expected = _stream_messages()
    kept = _messages(target)
    assert kept == expected[: len(kept)]  # a prefix of what was written, byte for byte
    flushed = [m for m in expected if m[1] <= kill_at - FLUSH_INTERVAL_NS]
    assert len(kept) >= len(flushed)  # nothing older than one flush interval is lost
    assert len(kept) < len(expected)
    recovery = _recovery(target)
    assert recovery["recovered"] == "true"
    assert recovery["source"] == part.name
    assert int(recovery["messages"]) == len(kept)
    channels = json.loads(recovery["channels"])
    for topic in {m[0] for m in expected}:
        count = sum(1 for m in kept if m[0] == topic)
        assert channels[topic]["messages"] == count
        assert f"{topic}" in out
    # killed during the 15 s hold: the salvaged recording is refused as cut short
    with pytest.raises(RecordingError, match="cut short"):
        read_recording(target)


def test_recorder_killed_before_its_first_flush_leaves_nothing_to_salvage(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    part = _kill_recorder(tmp_path, 2 * NS + NS // 4)
    assert main(["check", str(part), "--recover"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "nothing to salvage" in err
    assert not recovered_path(part).exists()


@pytest.fixture(scope="module")
def long_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """C1 on the sponge at 0.3 of real time: 6.5 s, about a dozen chunks."""
    path = tmp_path_factory.mktemp("long") / "sponge" / "C1" / "002.mcap"
    with FakeRig(seed=11, time_scale=0.3) as rig:
        record_action(rig, fake_objects()["sponge"], load_actions()["C1"], 2, path, seed=11)
    return path


def _chunk_ends(path: Path) -> list[tuple[int, int]]:
    """Return (end offset, messages so far) after every chunk of a complete file."""
    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    ends, total = [], 0
    for chunk in summary.chunk_indexes:
        total += sum(1 for _ in _chunk_messages(path, chunk.chunk_start_offset))
        ends.append((chunk.chunk_start_offset + chunk.chunk_length, total))
    return ends


def _chunk_messages(path: Path, offset: int) -> list[object]:
    data = path.read_bytes()
    reader = StreamReader(io.BytesIO(data[offset:]), skip_magic=True)
    records = []
    for record in reader.records:
        if type(record).__name__ == "MessageIndex":
            break
        records.append(record)
    return [r for r in records if type(r).__name__ == "Message"]


def _offsets(size: int, ends: list[tuple[int, int]]) -> list[int]:
    """Return truncation offsets: around every chunk end, at the edges, and seeded random."""
    rng = np.random.default_rng(2024)
    around = [end + d for end, _ in ends for d in (-1, 0, 1)]
    edges = [9, 100, size - 200, size - 1]
    return sorted({*around, *edges, *(int(v) for v in rng.integers(9, size, 40))})


def test_truncated_at_any_offset_keeps_every_complete_chunk(
    long_recording: Path, tmp_path: Path
) -> None:
    data = long_recording.read_bytes()
    original = _messages(long_recording)
    ends = _chunk_ends(long_recording)
    assert len(ends) >= 10
    salvaged = 0
    for cut in _offsets(len(data), ends):
        path = tmp_path / f"cut{cut}.mcap"
        path.write_bytes(data[:cut])
        with pytest.raises(RecordingError, match="check --recover"):
            read_recording(path)
        complete = max((count for end, count in ends if end <= cut), default=0)
        if complete == 0:
            with pytest.raises(RecordingError, match="nothing to salvage"):
                salvage(path)
            continue
        report = salvage(path)
        kept = _messages(report.target)
        assert kept == original[: len(kept)], cut
        assert len(kept) >= complete, cut
        assert report.messages == len(kept)
        assert report.intact_bytes <= cut
        salvaged += 1
    assert salvaged > 30


def test_a_file_cut_in_its_summary_is_salvaged_whole(long_recording: Path, tmp_path: Path) -> None:
    data = long_recording.read_bytes()
    path = tmp_path / "002.mcap"
    path.write_bytes(data[: len(data) - 50])
    report = salvage(path)
    assert report.complete
    assert report.stopped == ""
    assert _messages(report.target) == _messages(long_recording)
    again, original = read_recording(report.target), read_recording(long_recording)
    for modality in MODALITIES:
        np.testing.assert_array_equal(again.skin(modality).data, original.skin(modality).data)
    assert again.joints is not None
    assert original.joints is not None
    np.testing.assert_array_equal(again.joints.position, original.joints.position)
    assert again.phases == original.phases
    assert again.metadata == dataclasses.replace(original.metadata, source="salvage")
    assert _recovery(report.target)["complete"] == "true"


def test_a_damaged_chunk_is_skipped_and_the_rest_kept(long_recording: Path, tmp_path: Path) -> None:
    data = bytearray(long_recording.read_bytes())
    with long_recording.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    chunk = summary.chunk_indexes[4]
    data[chunk.chunk_start_offset + chunk.chunk_length // 2] ^= 0x40
    path = tmp_path / "002.mcap"
    path.write_bytes(bytes(data))
    with pytest.raises(RecordingError, match=r"CRC mismatch.*check --recover"):
        read_recording(path)
    report = salvage(path)
    lost = len(_chunk_messages(long_recording, chunk.chunk_start_offset))
    original = _messages(long_recording)
    kept = _messages(report.target)
    assert report.damaged_chunks == 1
    assert len(kept) == len(original) - lost
    assert set(kept) < set(original)
    assert _recovery(report.target)["damaged_chunks"] == "1"


def test_salvage_never_overwrites_and_never_touches_the_source(
    long_recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    source = tmp_path / "002.mcap"
    source.write_bytes(long_recording.read_bytes()[:-1000])
    before = _sha(source)
    first = salvage(source)
    assert first.target == tmp_path / "002.recovered.mcap"
    content = _sha(first.target)
    with pytest.raises(
        RecordingError, match=r"002\.recovered\.mcap: exists and is never overwritten"
    ):
        salvage(source)
    assert main(["check", str(source), "--recover"]) == 1
    assert capsys.readouterr().err.count("\n") == 1
    assert _sha(first.target) == content
    elsewhere = tmp_path / "kept" / "mine.mcap"
    elsewhere.parent.mkdir()
    assert main(["check", str(source), "--recover", "--out", str(elsewhere)]) == 0
    assert _messages(elsewhere) == _messages(first.target)
    with pytest.raises(RecordingError, match="never overwritten"):
        salvage(source, source)
    assert _sha(source) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["002.mcap", "002.recovered.mcap", "kept"]


def test_recover_needs_one_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", str(tmp_path), "--recover"]) == 1
    assert "salvages one file" in capsys.readouterr().err
    (tmp_path / "x.mcap").write_bytes(b"not a recording")
    assert main(["check", str(tmp_path / "x.mcap"), "--recover"]) == 1
    assert "nothing to salvage" in capsys.readouterr().err


def test_recovered_names() -> None:
    assert recovered_path(Path("d/001.1234-ab12.mcap.part")) == Path(
        "d/001.1234-ab12.recovered.mcap"
    )
    assert recovered_path(Path("d/001.mcap")) == Path("d/001.recovered.mcap")
    assert recovered_path(Path("d/odd")) == Path("d/odd.recovered.mcap")
