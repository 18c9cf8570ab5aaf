"""Output for people and for files: full-width tables when piped, ``--json``, progress lines."""

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import polars as pl
import pytest
from conftest import FakeRig
from rich.console import Console
from rich.progress import Progress

from recorder import ActionSpec
from recorder._catalog import ObjectSpec
from recorder._cli import main as record
from recorder.runner._record import record_action
from replay.cli._main import main, progress_line
from replay.studies._registry import STUDIES
from replay.studies._running import StudyConfig, study_results
from schemas import CLAIM_NAME, SourceStats, recording_into

ROOT = Path(__file__).resolve().parents[2]
RECORDING = ROOT / "recordings" / "data" / "wood" / "C1" / "001.mcap"
#: Every accounting count of a live source, each a different value so a column mix-up shows.
STATS = SourceStats(
    "skin-temperature-and-proximity",
    "counter",
    expected=1000,
    received=991,
    missing=13,
    duplicated=2,
    out_of_order=3,
    overflowed=4,
    malformed=5,
)


class _LiveRig(FakeRig):
    """A fake rig reporting one live source's accounting."""

    def source_stats(self) -> list[SourceStats]:
        return [STATS]


@pytest.fixture
def live_recording(
    tmp_path: Path, objects: dict[str, ObjectSpec], actions: dict[str, ActionSpec]
) -> Path:
    path = tmp_path / "data" / "wood" / "P1" / "001.mcap"
    with _LiveRig(seed=0) as rig:
        written: Path = record_action(rig, objects["wood"], actions["P1"], 1, path, seed=0).path
        return written


def test_info_piped_prints_every_column_whole(
    live_recording: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["info", str(live_recording)]) == 0
    shown = capsys.readouterr().out
    assert "…" not in shown
    header = next(line for line in shown.splitlines() if "source" in line and "basis" in line)
    for column in ("expected", "received", "missing", "duplicated", "out of order", "overflow"):
        assert column in header
    assert "malformed" in header
    row = next(line for line in shown.splitlines() if STATS.name in line)
    cells = [cell.strip() for cell in row.strip("│┃ ").split("│")]
    assert cells[:9] == [STATS.name, "counter", "1000", "991", "13", "2", "3", "4", "5"]
    assert str(live_recording) in shown


def test_info_json_of_a_recording(live_recording: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", "--json", str(live_recording)]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["kind"] == "recording"
    assert info["path"] == str(live_recording)
    assert info["metadata"]["object_id"] == "wood"
    assert info["metadata"]["action_id"] == "P1"
    assert info["metadata"]["trial"] == 1
    assert info["metadata"]["action_parameters"]["duration_s"] > 0
    channels = {c["name"]: c for c in info["channels"]}
    assert channels["force"]["samples"] > 0
    assert channels["force"]["shape"] == [7, 3]
    assert channels["force"]["rate_hz"] > 0
    assert [p["phase"] for p in info["phases"]][:2] == ["approach", "contact"]
    assert info["phases"][0]["start_ns"] == 0
    assert all(p["duration_ns"] >= 0 for p in info["phases"])
    (source,) = info["sources"]
    assert source["name"] == STATS.name
    assert (source["missing"], source["malformed"], source["overflowed"]) == (13, 5, 4)


def test_info_json_of_a_committed_recording_matches_its_table(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["info", "--json", str(RECORDING)]) == 0
    info = json.loads(capsys.readouterr().out)
    assert main(["info", str(RECORDING)]) == 0
    table = capsys.readouterr().out
    for channel in info["channels"]:
        line = next(x for x in table.splitlines() if f" {channel['name']} " in x)
        assert f" {channel['samples']} " in line
    assert info["sources"] == []


def test_info_json_of_a_dataset(capsys: pytest.CaptureFixture[str]) -> None:
    data = RECORDING.parents[2]
    assert main(["info", "--json", str(data)]) == 0
    info = json.loads(capsys.readouterr().out)
    files = sorted(data.rglob("*.mcap"))
    assert info["kind"] == "dataset"
    assert info["recordings"] == len(files)
    assert info["size_bytes"] == sum(f.stat().st_size for f in files)
    assert info["recorded_ns"] > 0
    assert info["trials"]["wood"]["C1"] == len(list((data / "wood" / "C1").glob("*.mcap")))
    assert sum(sum(per.values()) for per in info["trials"].values()) == len(files)
    assert info["unfinished"] == 0
    assert info["feature_cache"].endswith("features.parquet")


def test_check_json_of_a_valid_and_of_a_broken_dataset(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = tmp_path / "data"
    shutil.copytree(RECORDING.parent, data / "wood" / "C1")
    assert main(["check", "--json", "--workers", "1", str(data)]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result == {
        "path": str(data),
        "recordings": 2,
        "valid": 2,
        "failures": [],
        "warnings": [],
        "unfinished": 0,
        "being_written": 0,
        "set_aside": [],
        "ok": True,
    }
    broken = data / "wood" / "C1" / "002.mcap"
    broken.write_bytes(broken.read_bytes()[: broken.stat().st_size // 2])
    assert main(["check", "--json", "--workers", "1", str(data)]) == 1
    result = json.loads(capsys.readouterr().out)
    assert (result["recordings"], result["valid"], result["ok"]) == (2, 1, False)
    assert len(result["failures"]) == 1
    assert "002.mcap" in result["failures"][0]


def test_check_beside_a_running_recorder_warns_where_it_would_fail_after_a_dead_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # a lab checks its dataset in a second terminal while a session records into it
    data = tmp_path / "data"
    shutil.copytree(RECORDING.parent, data / "wood" / "C1")
    second = data / "wood" / "C1" / "002.mcap"
    second.rename(tmp_path / "002.mcap")
    assert record(["index", str(data)]) == 0
    (tmp_path / "002.mcap").rename(second)  # written since: the index lags behind
    (data / CLAIM_NAME).write_text("{}", encoding="utf-8")
    writing = data / "wood" / "C1" / f"004.{os.getpid()}-ab12.mcap.part"
    writing.write_bytes(b"")
    capsys.readouterr()
    with recording_into(data):  # the session's lock on the dataset
        assert main(["check", "--json", "--workers", "1", str(data)]) == 0
    result = json.loads(capsys.readouterr().out)
    assert (result["ok"], result["failures"], result["being_written"]) == (True, [], 1)
    assert any("being written by a running recorder" in w for w in result["warnings"])
    assert any("it rebuilds the index when it finishes" in w for w in result["warnings"])
    # the recorder is gone (SIGKILL): its file is left over and the index stale
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    writing.rename(writing.with_name(f"004.{dead}-ab12.mcap.part"))
    assert main(["check", "--json", "--workers", "1", str(data)]) == 1
    result = json.loads(capsys.readouterr().out)
    assert result["unfinished"] == 1
    assert any("lists 1 of the 2 recordings" in f for f in result["failures"])


def test_check_json_counts_lost_samples_as_failures(
    live_recording: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["check", "--json", "--workers", "1", str(live_recording)]) == 1
    result = json.loads(capsys.readouterr().out)
    assert result["ok"] is False  # counted loss: check agrees with the accounting
    (failure,) = result["failures"]
    assert "lost samples" in failure


def test_several_recordings_as_a_shell_glob_gives_them(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # `atikt-replay check data/wood/C1/*.mcap`: each file checked, one verdict for all
    data = tmp_path / "data"
    shutil.copytree(RECORDING.parent, data / "wood" / "C1")
    files = [str(f) for f in sorted((data / "wood" / "C1").glob("*.mcap"))]
    assert len(files) == 2  # the committed C1 trials
    assert main(["check", "--workers", "1", *files]) == 0
    assert "2 of 2 recordings valid" in capsys.readouterr().out
    assert main(["info", "--json", *files]) == 0
    infos = json.loads(capsys.readouterr().out)
    assert [info["path"] for info in infos] == files
    assert main(["info", *files]) == 0
    shown = capsys.readouterr().out
    assert all(f in shown for f in files)
    broken = Path(files[1])
    broken.write_bytes(broken.read_bytes()[: broken.stat().st_size // 2])
    assert main(["check", "--json", "--workers", "1", *files]) == 1
    result = json.loads(capsys.readouterr().out)
    assert result["paths"] == files
    assert (result["recordings"], result["valid"], result["ok"]) == (2, 1, False)
    assert "002.mcap" in result["failures"][0]
    # info shows each file it can read and names each it cannot, in one line apiece
    empty = data / "wood" / "C1" / "003.mcap"
    empty.touch()
    assert main(["info", *files, str(empty)]) == 1
    out, err = capsys.readouterr()
    assert files[0] in out
    assert files[1] not in out
    lines = err.splitlines()
    assert len(lines) == 3
    assert files[1] in lines[0]
    assert "truncated" in lines[0]
    assert str(empty) in lines[1]
    assert lines[2] == "2 of 3 recordings could not be read or fail their checks"
    assert main(["info", "--json", *files]) == 1
    infos = json.loads(capsys.readouterr().out)
    assert [info["kind"] for info in infos] == ["recording", "unreadable"]
    assert infos[1]["path"] == files[1]
    assert "truncated" in infos[1]["error"]


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (["check", "DIR", "FILE"], "a directory among 2 paths; check takes one dataset"),
        (["info", "FILE", "DIR"], "a directory among 2 paths; info takes one dataset"),
        (["check", "--recover", "FILE", "FILE"], "--recover salvages one file; 2 were given"),
    ],
)
def test_several_paths_that_cannot_go_together_are_one_line(
    argv: list[str], said: str, capsys: pytest.CaptureFixture[str]
) -> None:
    given = {"DIR": str(RECORDING.parents[2]), "FILE": str(RECORDING)}
    assert main([given.get(word, word) for word in argv]) == 1
    err = capsys.readouterr().err
    assert said in err
    assert err.count("\n") == 1


def _task(total: float | None, completed: float, elapsed_s: float, unit: str = "tasks") -> str:
    progress = Progress(console=Console(file=None), disable=True)
    task_id = progress.add_task("study transfer", total=total, unit=unit)
    task = progress.tasks[task_id]
    task.start_time = time.monotonic() - elapsed_s  # what rich sets when the task starts
    task.completed = completed
    return progress_line(task)


def test_progress_lines_give_totals_and_an_estimate_of_the_time_left() -> None:
    assert _task(None, 0, 5.2) == "study transfer: 0 tasks (5 s)"
    assert _task(100, 0, 5.2) == "study transfer: 0/100 tasks (5 s)"
    assert _task(100, 12, 6.0) == "study transfer: 12/100 tasks, ~44 s left (6 s)"
    assert _task(100, 100, 50.0) == "study transfer: 100/100 tasks, done (50 s)"
    assert _task(4, 1, 2.0, unit="") == "study transfer: 1/4, ~6 s left (2 s)"


def test_a_study_reports_its_total_before_the_first_task_ends(tmp_path: Path) -> None:
    calls: list[tuple[int, int]] = []
    study = STUDIES["transfer"]
    config = StudyConfig(out=tmp_path)
    tasks = ["a", "b", "c"]
    fake = type(study)(
        name="fake",
        title="fake",
        tasks=lambda _frame, _config: tasks,
        run=_one_row,
        labels=("task",),
        report=study.report,
    )
    study_results(fake, None, config, on_progress=lambda d, t: calls.append((d, t)))  # type: ignore[arg-type]
    assert calls[0] == (0, 3)
    assert calls[-1] == (3, 3)


def _one_row(task: str) -> pl.DataFrame:
    return pl.DataFrame({"task": [task], "accuracy": [1.0]})


def test_the_estimate_follows_the_recent_rate_not_a_slow_start() -> None:
    now = [0.0]
    progress = Progress(console=Console(file=None), disable=True, get_time=lambda: now[0])
    task_id = progress.add_task("recording", total=100, unit="recordings")
    for at, done in ((40.0, 10), (50.0, 20)):  # 40 s to start the workers, then 1 per s
        now[0] = at
        progress.update(task_id, completed=done)
    line = progress_line(progress.tasks[task_id])
    assert line == "recording: 20/100 recordings, ~120 s left (50 s)"  # 20 in the last 30 s


def test_results_arriving_together_do_not_read_as_a_burst_rate() -> None:
    now = [0.0]
    progress = Progress(console=Console(file=None), disable=True, get_time=lambda: now[0])
    task_id = progress.add_task("study transfer", total=10, unit="tasks")
    for at, done in ((139.9, 1), (140.0, 2)):  # two workers finish their first tasks together
        now[0] = at
        progress.update(task_id, completed=done)
    now[0] = 145.0
    line = progress_line(progress.tasks[task_id])
    assert line == "study transfer: 2/10 tasks, ~120 s left (145 s)"  # 8 at 2 per 30 s


@pytest.mark.parametrize(("serial_bytes", "jobs"), [(32 * 2**20, 1), (0, 2)])
def test_check_starts_workers_only_for_more_than_a_few_mb(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    serial_bytes: int,
    jobs: int,
) -> None:
    import joblib  # noqa: PLC0415 (the class the command calls, wrapped)

    from replay.cli import _main  # noqa: PLC0415

    data = tmp_path / "data"
    shutil.copytree(RECORDING.parent, data / "wood" / "C1")
    asked: list[int | None] = []

    class Counted(joblib.Parallel):  # type: ignore[misc]
        def __init__(self, n_jobs: int | None = None, **options: object) -> None:
            asked.append(n_jobs)
            super().__init__(n_jobs=n_jobs, **options)

    monkeypatch.setattr(_main, "SERIAL_BYTES", serial_bytes)
    monkeypatch.setattr(joblib, "Parallel", Counted)
    assert main(["check", "--json", "--workers", "2", str(data)]) == 0
    result = json.loads(capsys.readouterr().out)
    assert (result["recordings"], result["valid"]) == (2, 2)
    assert asked == [jobs]


def test_a_quarantined_recording_is_one_line_in_a_pipe(
    small_dataset: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """rich wraps at 80 columns into a pipe; a message is one line a script can grep."""
    import replay.cli._learn  # noqa: PLC0415

    monkeypatch.setattr(replay.cli._learn, "_CONSOLE", Console(stderr=True, width=80))
    data = tmp_path / "data"
    for name in ("wood/P1/001.mcap", "foam_block/P1/001.mcap"):
        (data / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(small_dataset / name, data / name)
    shutil.copyfile(data / "wood/P1/001.mcap", data / "foam_block/P1/002.mcap")
    assert main(["features", str(data), "--workers", "1"]) == 1
    lines = capsys.readouterr().err.splitlines()
    quarantined = [line for line in lines if line.startswith("quarantined")]
    assert len(quarantined) == 1
    assert quarantined[0].endswith(f"then rebuild the index with 'atikt-record index {data}'")
    assert len(quarantined[0]) > 80


def test_the_dataset_report_is_whole_in_a_pipe(
    small_dataset: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """``atikt-record dataset ... | cat``: the table's cells are not cut with an ellipsis."""
    monkeypatch.delenv("COLUMNS")  # the tests' wide console: a pipe's 80 columns here
    data = tmp_path / ("a-directory-name-long-enough-for-the-index-path-to-pass-80-columns" * 2)
    (data / "wood" / "P1").mkdir(parents=True)
    shutil.copyfile(small_dataset / "wood/P1/001.mcap", data / "wood/P1/001.mcap")
    shutil.copyfile(small_dataset / CLAIM_NAME, data / CLAIM_NAME)
    argv = ["dataset", "--out", str(data), "--objects", "wood", "--actions", "P1"]
    assert record([*argv, "--trials", "1", "--seed", "0", "--workers", "1"]) == 0
    out = capsys.readouterr().out
    assert "…" not in out
    assert str(data / "index.parquet") in out
