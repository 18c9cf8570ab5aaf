import argparse
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from replay.cli import _main as _cli
from replay.cli._main import arg, command, main


def _dataset(fake_recording: Path, tmp_path: Path) -> Path:
    root = tmp_path / "data"
    for trial in ("003", "004"):
        target = root / "sponge" / "S2" / f"{trial}.mcap"
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(fake_recording, target)
    return root


def test_info_of_a_file(fake_recording: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", str(fake_recording)]) == 0
    out = capsys.readouterr().out
    for text in ("sponge", "S2", "acceleration", "1000.0", "execute", "retract", "fake"):
        assert text in out


def test_info_of_a_dataset(
    fake_recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = _dataset(fake_recording, tmp_path)
    (root / "sponge" / "S2" / "005.1-ab.mcap.part").write_bytes(b"")
    assert main(["info", str(root)]) == 0
    out = capsys.readouterr().out
    assert "2 recordings" in out
    assert "1 unfinished" in out


def test_check_passes_good_files_and_fails_bad_ones(
    fake_recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = _dataset(fake_recording, tmp_path)
    assert main(["check", str(root), "--workers", "1"]) == 0
    assert "2 of 2 recordings valid" in capsys.readouterr().out
    bad = root / "sponge" / "S2" / "004.mcap"
    bad.write_bytes(bad.read_bytes()[:-100])
    assert main(["check", str(root), "--workers", "1"]) == 1
    captured = capsys.readouterr()
    assert "1 of 2 recordings valid" in captured.out
    assert "FAIL" in captured.err
    assert "004.mcap" in captured.err
    assert main(["check", str(bad)]) == 1


def test_missing_path_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", str(tmp_path / "nothing.mcap")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("atikt-replay: error: ")
    assert err.count("\n") == 1
    assert main(["check", str(tmp_path)]) == 1
    assert "no recordings" in capsys.readouterr().err


def test_a_subcommand_is_one_registered_function(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(_cli.REGISTRY, "commands", dict(_cli.REGISTRY.commands))

    @command("greet", "say hello", arg("name"), arg("--times", type=int, default=1))
    def _greet(args: argparse.Namespace) -> int:
        print("hello " * args.times + args.name)
        return 3

    assert main(["greet", "world", "--times", "2"]) == 3
    assert capsys.readouterr().out == "hello hello world\n"


@pytest.fixture(scope="module")
def replay_help() -> subprocess.CompletedProcess[str]:
    """``python -m replay --help``, run once for the tests that read it."""
    return subprocess.run(
        [sys.executable, "-m", "replay", "--help"], capture_output=True, text=True, check=False
    )


def test_python_dash_m_replay_is_the_same_program(
    replay_help: subprocess.CompletedProcess[str],
) -> None:
    done = replay_help
    assert done.returncode == 0
    assert "info" in done.stdout
    assert "check" in done.stdout


def test_a_command_of_its_own_starts_without_the_learner(
    replay_help: subprocess.CompletedProcess[str],
) -> None:
    # `check` and `info` read recordings: the learner (atikt, scipy) is not imported for them,
    # every other command (and --help, which lists them all) still finds its module
    recording = Path(__file__).parents[2] / "recordings/data/soft_sponge/P1/001.mcap"
    code = (
        "import sys\nfrom replay.cli._main import main\n"
        f"status = main(['info', {str(recording)!r}])\n"
        "print(status, 'atikt' in sys.modules, 'scipy' in sys.modules)\n"
    )
    done = subprocess.run(  # noqa: S603 (this interpreter, the code above)
        [sys.executable, "-c", code], capture_output=True, text=True, check=False
    )
    assert done.stdout.splitlines()[-1] == "0 False False", done.stdout + done.stderr
    listed = replay_help
    assert all(name in listed.stdout for name in ("learn", "study", "features", "view"))
