"""Interruptions and leftovers: Ctrl-C is one line, stale files never block, indexes match."""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import forked
import polars as pl
import pytest
from conftest import copy_dataset

from recorder._cli import main as record
from replay.cli._main import main as replay
from replay.learning._features import build_features
from schemas import PART_SUFFIX, SET_ASIDE_DIR

if TYPE_CHECKING:
    from collections.abc import Callable

ROOT = Path(__file__).parents[2]
#: A process id above any the kernel hands out (Linux: pid_max is at most 2**22).
DEAD_PID = 2**22 + 12345


def _children(pid: int) -> list[int]:
    """Return the process ids whose parent is ``pid`` (Linux /proc)."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                found.append(int(entry.name))
    return found


def _workers_running(after_s: float = 0.5) -> Callable[[int], bool]:
    """Return a test of a process: it has had 2 children for ``after_s`` (workers running).

    Ctrl-C is ignored for the milliseconds in which workers are started (they inherit that,
    see ``schemas.cli.workers_ignore_interrupts``); half a second later it is not.
    """
    seen: list[float] = []

    def ready(pid: int) -> bool:
        if len(_children(pid)) >= 2:
            seen.append(time.monotonic())
        return bool(seen) and time.monotonic() - seen[0] >= after_s

    return ready


def _python(args: list[str], *, timeout_s: float) -> subprocess.CompletedProcess[str]:
    """Run this interpreter with ``args`` in the checkout; return what it printed."""
    return forked.run(
        [sys.executable, *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        check=False,
        timeout=timeout_s,
    )


def _interrupt(argv: list[str], ready: Callable[[int], bool]) -> subprocess.CompletedProcess[str]:
    """Run ``python -m argv`` in its own process group; Ctrl-C the group once ``ready()``.

    The whole group gets SIGINT, as from a terminal: the workers too.
    """
    process = forked.Popen(
        [sys.executable, "-m", *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
        process_group=0,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    deadline = time.monotonic() + 120
    while not ready(process.pid) and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert process.poll() is None, "the command ended before it could be interrupted"
    os.killpg(process.pid, signal.SIGINT)
    out, err = process.communicate(timeout=120)
    return subprocess.CompletedProcess(argv, process.returncode, out, err)


#: A plain progress line (printed every few seconds when stderr is not a terminal).
_PROGRESS_LINE = re.compile(
    r"[^\n]+: [0-9.]+(/[0-9.]+)?( [a-z]+)?(, ~[0-9]+ s left|, done)? \([0-9]+ s\)"
)


def _interrupted_line(stderr: str) -> str:
    """Return the one line Ctrl-C printed, checking that every other line is progress."""
    *progress, last = stderr.splitlines() or [""]
    assert all(_PROGRESS_LINE.fullmatch(line) for line in progress), stderr[-3000:]
    assert "Traceback" not in stderr
    return last


def _leftovers(*directories: Path) -> list[Path]:
    """Return temporary files (``*.part``, ``*.tmp``, hidden ``.*``) outside set-aside dirs."""
    found = []
    for directory in directories:
        for path in directory.rglob("*"):
            if SET_ASIDE_DIR in path.parts:
                continue
            if path.name.endswith((PART_SUFFIX, ".tmp")) or ".tmp" in path.name:
                found.append(path)
    return found


@pytest.mark.slow(15)
def test_ctrl_c_in_a_study_is_one_line_and_a_rerun_completes(tmp_path: Path) -> None:
    data = tmp_path / "data"
    shutil.copytree(ROOT / "recordings" / "data", data)
    out = tmp_path / "out"
    argv = ["replay", "study", "transfer", "--quick", "--workers", "2"]
    argv += ["--recordings", str(data), "--out", str(out)]
    result = _interrupt(argv, _workers_running())
    assert result.returncode == 130, result.stderr[-2000:]
    assert _interrupted_line(result.stderr).startswith("atikt-replay: interrupted")
    assert not out.exists()
    assert _leftovers(data, tmp_path) == []
    assert replay(argv[1:]) == 0  # the rerun: here, as the dataset's resume is
    assert (out / "results.parquet").is_file()


@pytest.mark.slow(5)
def test_ctrl_c_while_recording_a_dataset_leaves_no_part_and_resumes(tmp_path: Path) -> None:
    data = tmp_path / "data"
    argv = ["recorder", "dataset", "--out", str(data), "--workers", "2"]
    argv += ["--objects", "wood", "--actions", "P1,S1", "--trials", "6"]
    result = _interrupt(argv, lambda _: any(data.rglob(f"*{PART_SUFFIX}")))
    assert result.returncode == 130, result.stderr[-2000:]
    assert _interrupted_line(result.stderr).startswith("atikt-record: interrupted")
    assert list(data.rglob(f"*{PART_SUFFIX}")) == []  # killed workers' files removed
    assert record(argv[1:]) == 0
    assert len(list(data.rglob("*.mcap"))) == 12
    assert replay(["check", str(data), "--workers", "1"]) == 0


def test_a_stale_part_of_a_dead_recorder_is_set_aside_and_recorded_again(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = tmp_path / "data"
    argv = ["dataset", "--out", str(data), "--workers", "1"]
    argv += ["--objects", "wood", "--actions", "P1", "--trials", "2"]
    assert record(argv) == 0
    second = data / "wood" / "P1" / "002.mcap"
    stale = second.with_name(f"002.{DEAD_PID}-0123abcd{PART_SUFFIX}")
    second.rename(stale)
    running = second.with_name(f"002.{os.getpid()}-4567cdef{PART_SUFFIX}")  # alive: stays
    running.write_bytes(b"")
    _ = capsys.readouterr()
    assert record(argv) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert second.is_file()
    assert not stale.exists()
    assert (data / SET_ASIDE_DIR / "wood" / "P1" / stale.name).is_file()
    assert f"1 unfinished recordings of stopped recorders moved to {data / SET_ASIDE_DIR}" in out
    assert running.exists()
    running.unlink()
    assert replay(["check", str(data), "--workers", "1"]) == 0


def test_check_compares_the_index_with_the_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = tmp_path / "data"
    argv = ["dataset", "--out", str(data), "--workers", "1"]
    assert record([*argv, "--objects", "wood", "--actions", "P1", "--trials", "2"]) == 0
    index = data / "index.parquet"
    pl.read_parquet(index).head(0).write_parquet(index)
    _ = capsys.readouterr()
    assert replay(["check", str(data), "--workers", "1"]) == 1
    captured = capsys.readouterr()
    assert "index.parquet: lists 0 of the 2 recordings" in " ".join(captured.err.split())
    assert record(["index", str(data)]) == 0
    assert replay(["check", str(data), "--workers", "1"]) == 0


def test_an_index_of_nothing_or_of_two_seeds_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    assert record(["index", str(empty)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "no recordings (*.mcap) in it or below" in err
    assert not (empty / "index.parquet").exists()
    one, two = tmp_path / "one", tmp_path / "two"
    common = ["--objects", "wood", "--actions", "P1", "--workers", "1"]
    assert record(["dataset", "--out", str(one), "--trials", "1", *common]) == 0
    assert record(["dataset", "--out", str(two), "--trials", "2", "--seed", "7", *common]) == 0
    # Two runs that started at once into one empty dataset: both passed the seed check.
    (two / "wood" / "P1" / "002.mcap").rename(one / "wood" / "P1" / "002.mcap")
    _ = capsys.readouterr()
    assert record(["index", str(one)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "holds recordings of 2 different seeds (seed 0 (e.g. wood/P1/001.mcap)" in err


@pytest.mark.slow(5)
def test_a_hostile_feature_cache_is_rebuilt_with_a_line(
    small_dataset: Path, tmp_path: Path
) -> None:
    data = tmp_path / "data"
    copy_dataset(small_dataset, data)
    cache = data / "features.parquet"
    # 64 MB of values in a file of a few kB: more than its rows can hold.
    pl.DataFrame({"path": ["x" * (64 << 20)]}).write_parquet(cache, compression="zstd")
    assert cache.stat().st_size < 1 << 20
    table = build_features(data)
    assert "the feature cache does not match the dataset" in table.discarded
    assert "bytes of values, more than the" in table.discarded
    assert table.frame.height == len(list(data.rglob("*.mcap")))
    assert build_features(data).discarded == ""
    index = data / "index.parquet"
    pl.DataFrame({"path": ["x" * (64 << 20)]}).write_parquet(index, compression="zstd")
    assert replay(["check", str(data), "--workers", "1"]) == 1


def test_the_pools_resource_tracker_does_not_warn_after_an_interruption() -> None:
    # a run interrupted while its pool starts leaves the tracker semaphores to unlink, and it
    # warned twice after the interruption's one line: it gets this interpreter's -W options
    script = (
        "import os, subprocess, joblib\n"
        "from schemas import cli\n"
        "with cli.workers_ignore_interrupts():\n"
        "    done = joblib.Parallel(n_jobs=2)(joblib.delayed(os.getpid)() for _ in range(2))\n"
        "print(subprocess.run(['ps', '-o', 'args=', '--ppid', str(os.getpid())],\n"
        "                     capture_output=True, text=True, check=True).stdout)\n"
    )
    shown = _python(["-c", script], timeout_s=120)
    assert shown.returncode == 0, shown.stderr[-2000:]
    lines = shown.stdout.splitlines()
    trackers = [line for line in lines if "loky.backend.resource_tracker" in line]
    assert trackers, shown.stdout
    assert all("-Wignore:resource_tracker:UserWarning" in line for line in trackers), trackers
