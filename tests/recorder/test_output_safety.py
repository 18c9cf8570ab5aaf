"""Output safety: a full disk, an unwritable directory or an existing file gives a clear error
and leaves no file that looks complete; recorders sharing a dataset never overwrite each other."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import textwrap
import threading
from pathlib import Path
from typing import IO, Any

import polars as pl
import pytest
from conftest import FakeRig, fake_objects

from recorder import OutputExistsError, RecorderError, load_actions, write_index
from recorder import _rigconfig as rigconfig
from recorder._cli import main as record_main
from recorder.runner._record import record_action
from recorder.writing._writer import RecordingInfo, RecordingWriter
from replay import read_recording
from schemas import PART_SUFFIX

TESTS = Path(__file__).resolve().parents[1]


def _files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*") if p.is_file())


def _record(path: Path, seed: int = 0) -> None:
    with FakeRig(seed=seed) as rig:
        record_action(rig, fake_objects()["wood"], load_actions()["P1"], 1, path, seed=seed)


def _fail(err: int) -> Any:
    def raising(*_args: object, **_kwargs: object) -> None:
        raise OSError(err, os.strerror(err))

    return raising


def _kept_not_published(root: Path, final: Path) -> None:
    """Nothing under the final name; what was written is kept (incomplete, or its .part)."""
    left = _files(root)
    assert final not in left
    assert all(p.name.endswith((".incomplete.mcap", PART_SUFFIX)) for p in left)


@pytest.mark.parametrize(
    "where",
    [
        "recorder.writing._mcap.McapWriter.add_message",
        "recorder.writing._mcap.McapWriter.flush",
        "recorder.writing._mcap.McapWriter.finish",
    ],
)
def test_disk_full_at_any_stage_is_named_and_keeps_what_was_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, where: str
) -> None:
    monkeypatch.setattr(where, _fail(errno.ENOSPC))
    path = tmp_path / "wood" / "P1" / "001.mcap"
    with pytest.raises(RecorderError, match=r"001\.mcap: writing .*No space left.*disk is full"):
        _record(path)
    _kept_not_published(tmp_path, path)


def test_disk_full_when_syncing_keeps_what_was_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr("recorder.writing._writer.os.fsync", _fail(errno.ENOSPC))
    with pytest.raises(RecorderError, match=r"disk is full.*kept in .*\.part.*--recover"):
        _record(tmp_path / "001.mcap")
    _kept_not_published(tmp_path, tmp_path / "001.mcap")


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full (Linux)")
def test_a_real_full_device_is_a_recorder_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The kernel's own ENOSPC (from /dev/full), raised while the buffer is flushed or closed."""

    def full(path: Path) -> IO[bytes]:
        path.touch()  # the temporary name exists, as it would on a real disk
        return Path("/dev/full").open("wb")

    monkeypatch.setattr("recorder.writing._writer._open_exclusive", full)
    with pytest.raises(RecorderError, match=r"001\.mcap: .*No space left on device.*disk is full"):
        _record(tmp_path / "001.mcap")
    _kept_not_published(tmp_path, tmp_path / "001.mcap")


@pytest.mark.parametrize(
    ("err", "fix"),
    [
        (errno.EACCES, "not writable"),
        (errno.EROFS, "read-only"),
        (errno.ENOSPC, "disk is full"),
    ],
)
def test_unwritable_output_is_named_with_its_fix(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, err: int, fix: str
) -> None:
    monkeypatch.setattr("recorder.writing._writer._open_exclusive", _fail(err))
    with pytest.raises(RecorderError, match=rf"001\.mcap: cannot create the recording.*{fix}"):
        _record(tmp_path / "001.mcap")
    assert _files(tmp_path) == []


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root writes anywhere")
def test_read_only_directory(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    out.chmod(0o555)
    try:
        with pytest.raises(RecorderError, match="not writable"):
            _record(out / "001.mcap")
        assert _files(out) == []
    finally:
        out.chmod(0o755)


def test_cli_says_one_line_for_an_unwritable_output(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setitem(rigconfig._BUILDERS, "fake", lambda seed, _options: FakeRig(seed))
    args = ["action", "--object", "wood", "--action", "P1", "--out", str(tmp_path), "--rig"]
    assert record_main([*args, "fake"]) == 0
    path = tmp_path / "wood" / "P1" / "001.mcap"
    before = path.read_bytes()
    assert record_main([*args, "fake"]) == 1  # the same trial again: never overwritten
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "never overwritten" in err
    assert path.read_bytes() == before
    monkeypatch.setattr("recorder.writing._writer._open_exclusive", _fail(errno.EROFS))
    assert record_main([*args, "fake", "--trial", "2"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "read-only" in err
    assert "Traceback" not in err
    assert _files(tmp_path) == [path]


def test_failed_index_write_keeps_the_old_index(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _record(tmp_path / "wood" / "P1" / "001.mcap")
    index = write_index(tmp_path)
    before = index.read_bytes()
    monkeypatch.setattr(pl.DataFrame, "write_parquet", _fail(errno.ENOSPC))
    with pytest.raises(RecorderError, match=r"index\.parquet: cannot write the index.*free space"):
        write_index(tmp_path)
    assert index.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_writers_racing_for_one_name_leave_exactly_one_complete_file(tmp_path: Path) -> None:
    """Eight writers finish the same recording at the same moment: one wins, none clobbers."""
    path = tmp_path / "wood" / "P1" / "001.mcap"
    obj, action = fake_objects()["wood"], load_actions()["P1"]
    barrier = threading.Barrier(8)
    outcomes: dict[int, str] = {}

    def write(seed: int) -> None:
        rig = FakeRig(seed=seed)
        try:
            with RecordingWriter(path, RecordingInfo.create(obj, action, 1, rig, seed)) as out:
                for item in rig.perform(obj, action, 1):
                    out.write(item)
                barrier.wait()
            outcomes[seed] = "written"
        except OutputExistsError:
            outcomes[seed] = "refused"

    threads = [threading.Thread(target=write, args=(seed,)) for seed in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert sorted(outcomes.values()) == ["refused"] * 7 + ["written"]
    (winner,) = [seed for seed, outcome in outcomes.items() if outcome == "written"]
    assert read_recording(path).metadata.seed == winner
    assert _files(tmp_path) == [path]


_GENERATE = textwrap.dedent(
    """
    import sys
    from pathlib import Path
    sys.path[:0] = [str(Path(sys.argv[3]).parent)]
    sys.path.append(sys.argv[3])
    from conftest import FakeRig, fake_objects
    from recorder import generate_dataset, load_actions, plan_dataset

    tasks = plan_dataset(fake_objects(), load_actions(), action_ids=["P1", "S2"], trials=4)
    report = generate_dataset(tasks, Path(sys.argv[1]), FakeRig, seed=int(sys.argv[2]), workers=1)
    print(report.written, report.skipped)
    """
)


def test_two_recorders_into_one_dataset_never_overwrite_each_other(tmp_path: Path) -> None:
    script = tmp_path / "generate.py"
    script.write_text(_GENERATE)
    root = tmp_path / "dataset"
    runs = [
        subprocess.Popen(  # noqa: S603 (our own interpreter and script)
            [sys.executable, str(script), str(root), str(seed), str(TESTS)],
            stdout=subprocess.PIPE,
            text=True,
        )
        for seed in (1, 1)  # the same dataset resumed from two terminals (other seeds are refused)
    ]
    counts = []
    for run in runs:
        out, _ = run.communicate(timeout=300)
        assert run.returncode == 0
        counts.append([int(v) for v in out.split()])
    tasks = 2 * 2 * 4
    assert sum(written for written, _ in counts) == tasks  # each file written exactly once
    assert all(written + skipped == tasks for written, skipped in counts)
    recordings = sorted(root.rglob("*.mcap"))
    assert len(recordings) == tasks
    assert not list(root.rglob(f"*{PART_SUFFIX}"))
    writers = {read_recording(path).metadata.seed for path in recordings}
    assert writers == {1}
    index = pl.read_parquet(root / "index.parquet")
    assert sorted(index["path"]) == sorted(p.relative_to(root).as_posix() for p in recordings)
