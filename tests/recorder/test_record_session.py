import io
from pathlib import Path

import polars as pl
import pytest
import rig_plugins
from rig_plugins import traces

from recorder import _rigconfig as rigconfig
from recorder._cli import main
from schemas import SourceStats


@pytest.fixture(autouse=True)
def presenting_rig(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(rigconfig._BUILDERS, "presenting", rig_plugins.PRESENTING)


def _lab(tmp_path: Path, poses: str) -> tuple[Path, Path]:
    """Return (rig configuration, log directory) of the presenting rig with ``poses``."""
    log = tmp_path / "log"
    log.mkdir(exist_ok=True)
    config = tmp_path / "lab.toml"
    config.write_text(f'rig = "presenting"\n[options]\nlog_dir = "{log}"\n[poses]\n{poses}')
    return config, log


def _session(config: Path, out: Path, *extra: str) -> list[str]:
    argv = ["session", "--rig-config", str(config), "--objects", "wood,foam_block"]
    return [*argv, "--actions", "P1,S1", "--trials", "2", "--out", str(out), *extra]


def test_a_session_visits_posed_objects_asks_for_others_and_resumes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    config, log = _lab(tmp_path, "wood = [0.4, 0.1, 0.2]\n")
    out = tmp_path / "session"
    monkeypatch.setattr("sys.stdin", io.StringIO(""))  # nobody answers: EOF at the prompt
    assert main(_session(config, out)) == 1
    captured = capsys.readouterr()
    err = captured.err.splitlines()
    assert len(err) == 1
    assert "session stopped at the prompt for foam_block" in err[0]
    assert "run the same command again to resume" in err[0]
    assert "place Foam block (foam_block), then Enter" in captured.out
    done = sorted(p.relative_to(out).as_posix() for p in out.rglob("*.mcap"))
    assert done == ["wood/P1/001.mcap", "wood/P1/002.mcap", "wood/S1/001.mcap", "wood/S1/002.mcap"]
    assert pl.read_parquet(out / "index.parquet").height == 4  # nothing lost
    assert "[wood]" in (out / "objects.toml").read_text()
    events = [event for _, event in traces(log)]
    assert events[:2] == ["present-wood", "perform-wood-P1-1"]
    assert events[-1] == "present-foam_block"

    monkeypatch.setattr("sys.stdin", io.StringIO("\n"))  # someone places the foam block
    assert main(_session(config, out)) == 0
    printed = capsys.readouterr().out
    lines = [line for line in printed.splitlines() if "trial" in line]
    assert len(lines) == 4
    assert "foam_block  P1  trial 1  " in lines[0]  # after the prompt (input not echoed)
    assert lines[0].endswith(" s")
    assert "4 recordings written, 4 kept (existed)" in printed
    assert pl.read_parquet(out / "index.parquet").height == 8
    assert "[foam_block]" in (out / "objects.toml").read_text()
    assert "present-wood" not in [event for _, event in traces(log)][len(events) :]

    assert main([*_session(config, out), "--seed", "1"]) == 1
    assert "holds recordings of seed 0" in capsys.readouterr().err


def test_yes_refuses_objects_without_a_pose_before_anything_moves(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config, log = _lab(tmp_path, "wood = [0.4, 0.1, 0.2]\n")
    out = tmp_path / "session"
    assert main([*_session(config, out), "--yes"]) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1
    assert "--yes: the rig has no pose for foam_block;" in err[0]
    assert traces(log) == []
    assert not list(out.rglob("*.mcap")) if out.exists() else True


def test_yes_runs_unattended_when_every_object_has_a_pose(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    config, log = _lab(tmp_path, "wood = [0.4, 0.1, 0.2]\nfoam_block = [0.5, 0.1, 0.2]\n")
    monkeypatch.setattr("sys.stdin", io.StringIO(""))
    assert main([*_session(config, tmp_path / "s"), "--yes"]) == 0
    assert "place" not in capsys.readouterr().out
    assert [event for _, event in traces(log)].count("present-foam_block") == 1
    assert len(list((tmp_path / "s").rglob("*.mcap"))) == 8


class _Interrupting(io.StringIO):
    def readline(self, size: int | None = -1, /) -> str:  # type: ignore[override]  # noqa: ARG002
        raise KeyboardInterrupt


def test_ctrl_c_at_the_prompt_is_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    config, log = _lab(tmp_path, "")
    monkeypatch.setattr("sys.stdin", _Interrupting())
    assert main(_session(config, tmp_path / "s")) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1
    assert "session stopped at the prompt for wood" in err[0]
    assert [event for _, event in traces(log)] == ["present-wood"]


def test_a_session_on_the_simulator_asks_nobody(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr("sys.stdin", io.StringIO(""))
    argv = ["session", "--rig", "sim", "--objects", "wood", "--actions", "P1", "--trials", "1"]
    assert main([*argv, "--out", str(tmp_path / "s")]) == 0
    printed = capsys.readouterr().out
    assert "place" not in printed
    assert "1 recording written, 0 kept" in printed
    assert (tmp_path / "s" / "wood" / "P1" / "001.mcap").is_file()


def test_a_recording_that_lost_samples_says_so_when_it_is_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # the operator learns at once, while the object is still there, that a trial lacks data
    # (check will fail it); a trial without loss says nothing more
    lossy = SourceStats("skin", "counter", expected=100, received=97, missing=3)
    trials = iter([[lossy], []])
    monkeypatch.setattr(
        rig_plugins.PresentingRig, "source_stats", lambda _self: next(trials), raising=False
    )
    config, _ = _lab(tmp_path, "wood = [0.4, 0.1, 0.2]\n")
    argv = ["session", "--rig-config", str(config), "--objects", "wood", "--actions", "P1"]
    assert main([*argv, "--trials", "2", "--out", str(tmp_path / "s"), "--yes"]) == 0
    lines = capsys.readouterr().out.splitlines()
    said = [line for line in lines if "lost samples" in line]
    assert len(said) == 1
    first = tmp_path / "s" / "wood" / "P1" / "001.mcap"
    assert said[0].startswith(f"{first}: live sources lost samples (skin: 3 of 100 missing)")
    assert "move it aside and run the session again" in said[0]
    assert lines.index(said[0]) == 1 + next(i for i, line in enumerate(lines) if str(first) in line)
