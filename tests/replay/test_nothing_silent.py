"""Nothing silent: progress lines without a terminal, checks before work, view without display."""

from __future__ import annotations

import io
import shutil
import time
from pathlib import Path

import pytest
from rich.console import Console

from recorder._cli import main as record
from replay.cli._main import main as replay
from replay.studies._running import QUICK_REFERENCE_SAMPLES, REFERENCE_SAMPLES, StudyConfig
from schemas import cli
from schemas._cli import PlainProgress

ROOT = Path(__file__).parents[2]
DATA = ROOT / "recordings" / "data"


def test_without_a_terminal_progress_is_a_plain_line_every_interval() -> None:
    stream = io.StringIO()
    console = Console(file=stream, force_terminal=False, width=200)
    assert isinstance(cli.progress(console, "{task.description}"), PlainProgress)
    bar = PlainProgress(console, interval_s=0.02)
    task = bar.add_task("extracting", total=3)
    with bar:
        time.sleep(0.2)  # no progress meanwhile: the line still comes
        bar.advance(task, 3)
    lines = stream.getvalue().splitlines()
    assert len(lines) >= 3, lines
    assert lines[0].startswith("extracting: 0/3 (")
    assert lines[-1].startswith("extracting: 3/3, done (")


def test_a_dataset_run_into_a_log_reports_progress(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    # a press is recorded in tens of milliseconds once the first has warmed the process up:
    # six of them and a line every 5 ms leave several lines between the first and the last
    monkeypatch.setattr("schemas._cli.PROGRESS_INTERVAL_S", 0.005)
    argv = ["dataset", "--out", str(tmp_path / "d"), "--objects", "wood", "--actions", "P1"]
    assert record([*argv, "--trials", "6", "--workers", "1"]) == 0
    err = " ".join(capsys.readouterr().err.split())
    assert "recording: 6/6 recordings, done (" in err
    assert "s left (" in err  # an estimate while it ran


def test_an_unknown_rig_option_fails_before_any_recording(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "d"
    argv = ["dataset", "--out", str(out), "--objects", "wood", "--actions", "P1", "--trials", "1"]
    assert record([*argv, "--rig-option", "bogus=1"]) == 1
    captured = capsys.readouterr()
    assert captured.err.count("\n") == 1
    assert "rig option 'bogus': the sim rig takes" in captured.err
    assert "recording" not in captured.err
    assert not list(out.rglob("*.mcap*"))


def test_unknown_new_objects_fail_before_feature_extraction(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = tmp_path / "data"
    shutil.copytree(DATA, data, ignore=shutil.ignore_patterns("features.parquet"))
    argv = ["study", "transfer", "--quick", "--recordings", str(data), "--out", str(tmp_path / "o")]
    assert replay([*argv, "--new", "marble"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "--new marble: not in the dataset" in err
    assert not (data / "features.parquet").exists()
    assert replay([*argv, "--actions", "X9"]) == 1
    assert "--actions X9: not in the dataset" in capsys.readouterr().err
    assert not (data / "features.parquet").exists()


def test_view_without_a_display_says_save_or_serve(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr("sys.platform", "linux")
    recording = next(DATA.rglob("*.mcap"))
    assert replay(["view", str(recording)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "no display to open the viewer on" in err
    assert "--save FILE.rrd" in err
    assert "--serve" in err


def test_quick_reduces_the_serial_hyperparameter_fit(tmp_path: Path) -> None:
    config = StudyConfig(out=tmp_path).quick()
    assert config.reference_samples == QUICK_REFERENCE_SAMPLES < REFERENCE_SAMPLES
    assert StudyConfig(out=tmp_path).reference_samples == REFERENCE_SAMPLES


@pytest.mark.parametrize("program", ["record", "replay"])
def test_an_over_long_path_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], program: str
) -> None:
    long = tmp_path / "/".join(["a" * 200] * 25)  # 5000 characters
    if program == "record":
        argv = ["dataset", "--out", str(long), "--objects", "wood", "--actions", "P1"]
        assert record([*argv, "--trials", "1", "--workers", "1"]) == 1
    else:
        assert replay(["check", str(long / "x.mcap")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err[-500:]
    assert "give a shorter path" in err or "File name too long" in err
