"""The command-line toolkit both CLIs share: registry, one-line errors, safe publishing."""

from __future__ import annotations

import argparse
import errno
import io
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from rich.console import Console

from schemas import ContractError, cli

ROOT = Path(__file__).resolve().parents[2]
ORIGINAL_ON_BROKEN_PIPE = Console.on_broken_pipe


def _program(run: object) -> argparse.ArgumentParser:
    registry = cli.Registry()
    registry.command("go", "do it", cli.arg("--workers", type=cli.workers))(run)  # type: ignore[arg-type]
    return cli.build_parser("prog", "a program", registry, "1.2.3")


def test_a_project_error_is_one_line_and_a_bug_keeps_its_traceback(
    capsys: pytest.CaptureFixture[str],
) -> None:
    def refuse(_args: argparse.Namespace) -> int:
        msg = "value: refused;\n  fix it"
        raise ContractError(msg)

    assert cli.run(_program(refuse), ["go"], (ContractError,)) == 1
    assert capsys.readouterr().err == "prog: error: value: refused; fix it\n"

    def bug(_args: argparse.Namespace) -> int:
        return 1 // 0

    with pytest.raises(ZeroDivisionError):
        cli.run(_program(bug), ["go"], (ContractError,))


@pytest.mark.parametrize(
    ("argv", "status", "fragment"),
    [
        (["go", "--workers", "0"], 2, "prog go: error: argument --workers: 0: give 1 or more"),
        (["go", "--workers", "x"], 2, "'x' is not a whole number"),
        (["nosuch"], 2, "prog: error: argument COMMAND: invalid choice"),
        (["--version"], 0, "prog 1.2.3"),
    ],
)
def test_usage_errors_are_one_line(
    argv: list[str], status: int, fragment: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli.run(_program(lambda _args: 0), argv, ()) == status
    captured = capsys.readouterr()
    text = captured.err or captured.out
    assert text.count("\n") == 1
    assert fragment in text


@pytest.mark.parametrize(
    ("signum", "status", "line"),
    [
        (signal.SIGINT, 130, "prog: interrupted"),
        (signal.SIGTERM, 143, "prog: terminated (SIGTERM)"),
        # the terminal or SSH connection closed: unwound like SIGTERM, not ended on the spot
        (signal.SIGHUP, 129, "prog: terminated (SIGHUP)"),
    ],
)
@pytest.mark.usefixtures("hangup_not_ignored")
def test_an_ending_signal_unwinds_the_command_with_its_status(
    signum: int, status: int, line: str, capsys: pytest.CaptureFixture[str]
) -> None:
    unwound = []

    def wait(_args: argparse.Namespace) -> int:
        try:
            os.kill(os.getpid(), signum)
            time.sleep(10)  # the handler raises in this frame
        finally:
            unwound.append(True)
        return 0

    assert cli.run(_program(wait), ["go"], ()) == status
    assert unwound == [True]
    assert capsys.readouterr().err.startswith(line)


def test_ctrl_z_deferred_while_an_arm_moves_ends_the_command_with_148(
    capsys: pytest.CaptureFixture[str],
) -> None:
    # the runner turns a Ctrl-Z that came while the arm moved into this exception, its line
    # naming the stop and the file (tests/recorder/test_runner_stops.py)
    def moving(_args: argparse.Namespace) -> int:
        err = cli.ending(signal.SIGTSTP)
        err.args = ("interrupted by Ctrl-Z (SIGTSTP): the arm was stopped; what arrived ...",)
        raise err

    assert cli.run(_program(moving), ["go"], ()) == cli.SUSPENDED_STATUS == 148
    said = capsys.readouterr().err
    assert said.startswith("prog: interrupted by Ctrl-Z (SIGTSTP): the arm was stopped; what")


def test_nohup_keeps_a_command_running_after_its_terminal_closed() -> None:
    previous = signal.signal(signal.SIGHUP, signal.SIG_IGN)  # as nohup starts it
    try:

        def hang_up(_args: argparse.Namespace) -> int:
            os.kill(os.getpid(), signal.SIGHUP)
            time.sleep(0.05)
            return 0

        assert cli.run(_program(hang_up), ["go"], ()) == 0
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGHUP, previous)


def test_a_full_disk_is_one_line_and_a_reader_gone_is_quiet(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    dropped = []
    monkeypatch.setattr(cli, "_drop_stdout", lambda: dropped.append(True))

    def fail(number: int, name: str | None) -> object:
        def run(_args: argparse.Namespace) -> int:
            raise OSError(number, os.strerror(number), name)

        return run

    assert cli.run(_program(fail(errno.ENOSPC, None)), ["go"], ()) == 1
    err = capsys.readouterr().err
    assert err == (
        "prog: error: cannot write (No space left on device); free disk space or write elsewhere\n"
    )
    assert cli.run(_program(fail(errno.ENOSPC, "out/t.csv")), ["go"], ()) == 1
    assert capsys.readouterr().err.startswith("prog: error: out/t.csv: cannot write (No space")
    assert cli.run(_program(fail(errno.EPIPE, None)), ["go"], ()) == 1  # `| head` left
    assert capsys.readouterr().err == ""
    assert dropped == [True, True, True]
    with pytest.raises(PermissionError):  # not a full disk: a bug or a case of its own
        cli.run(_program(fail(errno.EACCES, "x")), ["go"], ())


def test_a_recording_command_says_its_output_was_closed(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(cli, "_drop_stdout", lambda: None)

    def closed(_args: argparse.Namespace) -> int:
        raise BrokenPipeError(errno.EPIPE, os.strerror(errno.EPIPE))

    said = "interrupted; finished recordings are kept, run it again to resume"
    assert cli.run(_program(closed), ["go"], (), said, recording=("go",)) == 1
    assert capsys.readouterr().err == (
        "prog: error: standard output was closed by its reader (broken pipe); "
        "finished recordings are kept, run it again to resume\n"
    )


def test_a_broken_pipe_met_by_rich_reaches_the_one_line(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """rich exits the process on its own (status 1, nothing said) unless told otherwise."""
    monkeypatch.setattr(cli, "_drop_stdout", lambda: None)

    class Closed(io.StringIO):
        def write(self, _text: str) -> int:
            raise BrokenPipeError(errno.EPIPE, os.strerror(errno.EPIPE))

    def prints(_args: argparse.Namespace) -> int:
        Console(file=Closed()).print("a line")
        return 0

    assert cli.run(_program(prints), ["go"], (), recording=("go",)) == 1
    assert "closed by its reader (broken pipe)" in capsys.readouterr().err
    assert cli.run(_program(prints), ["go"], ()) == 1  # not a recording command: quietly
    assert capsys.readouterr().err == ""
    assert Console.on_broken_pipe is ORIGINAL_ON_BROKEN_PIPE  # rich left as it was


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full here")
def test_output_to_a_full_disk_is_one_line_without_a_traceback() -> None:
    with Path("/dev/full").open("w") as full:
        done = subprocess.run(  # noqa: S603 (this interpreter, fixed arguments)
            [sys.executable, "-m", "replay", "info", str(ROOT / "recordings" / "data")],
            stdout=full,
            stderr=subprocess.PIPE,
            text=True,
            env=os.environ | {"PYTHONPATH": str(ROOT)},
            check=False,
            timeout=120,
        )
    assert done.returncode == 1
    assert done.stderr == (
        "atikt-replay: error: cannot write (No space left on device); free disk space or "
        "write elsewhere\n"
    )


def test_seed_type_bounds() -> None:
    assert cli.seed("0") == 0
    assert cli.seed(str(2**32 - 1)) == 2**32 - 1
    for bad in ("-1", str(2**32), "one"):
        with pytest.raises(argparse.ArgumentTypeError):
            cli.seed(bad)


def test_numbered_directory_takes_the_first_free_name(tmp_path: Path) -> None:
    base = tmp_path / "learn-0"
    assert cli.numbered_directory(base) == base
    (base / "x").mkdir(parents=True)
    (tmp_path / "learn-0-2").mkdir()  # empty: free
    assert cli.numbered_directory(base) == tmp_path / "learn-0-2"
    (tmp_path / "learn-0-2" / "y").touch()
    assert cli.numbered_directory(base) == tmp_path / "learn-0-3"


def test_publish_directory_refuses_then_replaces_with_force(tmp_path: Path) -> None:
    target = tmp_path / "out"
    target.mkdir()
    (target / "old.txt").write_text("old")
    with pytest.raises(cli.CliError, match=r"--out .*out: exists.*add --force"):
        cli.refuse_existing(target, force=False)
    with cli.publish_directory(target, force=True) as temporary:
        (temporary / "new.txt").write_text("new")
        assert (target / "old.txt").exists()  # the old output stays until the new one is done
    assert [p.name for p in target.iterdir()] == ["new.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


@pytest.mark.parametrize(
    "recorded", ["wood/P1/001.mcap", "wood/P1/002.1-ab.mcap.part", "bags/lab.bag", "b/b_0.db3"]
)
def test_force_never_replaces_recorded_data(tmp_path: Path, recorded: str) -> None:
    # a dataset given as --out by mistake: --force replaces outputs, never recordings
    target = tmp_path / "data"
    (target / recorded).parent.mkdir(parents=True)
    (target / recorded).write_bytes(b"recorded at the robot")
    with (
        pytest.raises(cli.CliError, match=r"--out .*data: holds recorded data \(.*never rec"),
        cli.publish_directory(target, force=True) as temporary,
    ):
        (temporary / "history.parquet").write_text("new")  # pragma: no cover (refused first)
    assert (target / recorded).read_bytes() == b"recorded at the robot"
    assert [p.name for p in tmp_path.iterdir()] == ["data"]
    with pytest.raises(cli.CliError, match=r"--out .*data: holds recorded data \("):
        cli.refuse_irreplaceable(target)
    with pytest.raises(cli.CliError, match=r"--save .*: is recorded data; --force replaces"):
        cli.refuse_irreplaceable(target / recorded, "--save")
    with (
        pytest.raises(cli.CliError, match=r"--save .*: is recorded data; --force replaces"),
        cli.publish_file(target / recorded, force=True, option="--save"),
    ):
        pass  # pragma: no cover (refused first)
    assert (target / recorded).read_bytes() == b"recorded at the robot"
    cli.refuse_irreplaceable(tmp_path / "new")  # nothing there: nothing to refuse


def test_force_replaces_only_what_an_output_holds(tmp_path: Path) -> None:
    # a previous study's output is replaced; a directory of other files (--out ~ or a project
    # given by mistake) is never deleted, --force or not
    study = tmp_path / "study"
    study.mkdir()
    for name in ("results.parquet", "summary.md", "learning_curves.png", "study.json"):
        (study / name).write_text("old")
    (study / ".DS_Store").write_text("a file manager's")
    with cli.publish_directory(study, force=True) as temporary:
        (temporary / "results.parquet").write_text("new")
    assert [p.name for p in study.iterdir()] == ["results.parquet"]
    home = tmp_path / "home"
    (home / "thesis").mkdir(parents=True)
    (home / "thesis" / "chapter.tex").write_text("three years of it")
    (home / "plot.png").write_text("a figure")
    with (
        pytest.raises(cli.CliError, match=r"--out .*home: holds files no output of this prog"),
        cli.publish_directory(home, force=True),
    ):
        pass  # pragma: no cover (refused first)
    assert (home / "thesis" / "chapter.tex").read_text() == "three years of it"


def test_a_failed_publish_keeps_the_old_output_and_removes_its_temporary(
    tmp_path: Path,
) -> None:
    target = tmp_path / "out"
    target.mkdir()
    (target / "old.txt").write_text("old")

    def half_written() -> None:
        with cli.publish_directory(target, force=True) as temporary:
            (temporary / "half.txt").write_text("half")
            raise RuntimeError

    with pytest.raises(RuntimeError):
        half_written()
    assert [p.name for p in target.iterdir()] == ["old.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_publish_file_refuses_an_existing_file_unless_forced(tmp_path: Path) -> None:
    target = tmp_path / "view.rrd"
    target.write_text("old")
    with pytest.raises(cli.CliError, match=r"--save .*view\.rrd: exists"):
        cli.check_new_file(target, force=False, option="--save")
    with cli.publish_file(target, force=True, option="--save") as temporary:
        temporary.write_text("new")
    assert target.read_text() == "new"
    assert [p.name for p in tmp_path.iterdir()] == ["view.rrd"]


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("8765", (cli.LOOPBACK, 8765)),
        ("0", (cli.LOOPBACK, 0)),
        ("0.0.0.0:9000", ("0.0.0.0", 9000)),  # noqa: S104 (asked for)
        ("here:65535", ("here", 65535)),
        ("here:65536", None),
        ("here:port", None),
        ("here:-1", None),
        ("here:", None),
        ("\uff18\uff17", None),  # full-width digits: str.isdigit says yes, int() reads them
    ],
)
def test_a_host_and_port_binds_loopback_unless_told(
    text: str, expected: tuple[str, int] | None
) -> None:
    assert cli.host_port(text) == expected


def test_a_broken_pipe_inside_a_published_directory_is_not_taken_for_its_disk(
    tmp_path: Path,
) -> None:
    # `learn ... | head -1`: printing a step fails while the run's directory is being made
    target = tmp_path / "run"

    def learn() -> None:
        with cli.publish_directory(target, force=False) as temporary:
            (temporary / "history.parquet").write_bytes(b"x")
            raise BrokenPipeError(errno.EPIPE, os.strerror(errno.EPIPE))

    with pytest.raises(BrokenPipeError):
        learn()
    assert not target.exists()  # nothing unfinished published
