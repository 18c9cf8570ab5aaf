"""Every error path of ``atikt-replay``: one line on stderr, a non-zero exit, no traceback."""

from __future__ import annotations

import argparse
import shutil
from typing import TYPE_CHECKING

import pytest

from recorder import _cli as record_cli
from replay.cli import _main as replay_cli
from replay.cli._main import main

if TYPE_CHECKING:
    from pathlib import Path

#: argv (``{data}``: a small dataset, ``{file}``: a recording, ``{tmp}``: an empty directory,
#: ``{taken}``: a directory holding a file) -> a fragment the one-line message must contain.
CASES: list[tuple[str, str]] = [
    ("nosuch", "invalid choice: 'nosuch'"),
    ("info {tmp}/missing.mcap", "no such file or directory"),
    ("info {tmp}", "no recordings"),
    ("check {tmp}/missing", "no such file or directory"),
    ("check {tmp}", "no recordings (*.mcap) found"),
    ("check {data} --workers 0", "0: give 1 or more worker processes"),
    ("check {data} --workers -1", "-1: give 1 or more worker processes"),
    ("check {data} --workers two", "'two' is not a whole number"),
    ("check {tmp} --recover", "--recover salvages one file"),
    ("features {tmp}/missing", "not a directory"),
    ("features {data} --workers 0", "give 1 or more worker processes"),
    ("learn --recordings {tmp}/missing", "not a directory"),
    ("learn --recordings {data} --budget -3", "--budget -3: give 0 or more observations"),
    # a test set of 0 trials failed deep in the learner ("pass at least one RawFeatures")
    ("learn --rig sim-ur10 --test-trials 0", "--test-trials: 0: give a number of trials 1.."),
    ("learn --rig sim-ur10 --test-trials 10000000", "--test-trials: 10000000: give a number"),
    ("learn --recordings {data} --hyper-sd 0", "--hyper-sd 0.0: give a positive standard"),
    ("learn --recordings {data} --hyper-sd nan", "--hyper-sd nan: give a positive standard"),
    ("learn --recordings {data} --hyper-sd abc", "'abc': give a positive standard deviation"),
    ("learn --recordings {data} --metric-check loose", "argument --metric-check: invalid choice"),
    ("learn --recordings {data} --metric-until 0", "'0': give a number of observations"),
    ("learn --recordings {data} --metric-until two", "'two': give a number of observations"),
    (
        "learn --recordings {data} --seed -1",
        "argument --seed: -1: give a whole number in 0..4294967295",
    ),
    ("learn --recordings {data} --rig nosuch", "--rig nosuch: unknown rig; known rigs: sim, ur"),
    ("learn --recordings {data} --priors woood", "--priors woood: not in the dataset; it has"),
    ("learn --recordings {data} --new woood,wood", "--new woood: not in the dataset; it has"),
    ("learn --recordings {data} --actions S9", "--actions S9: not in the dataset; it has P1, S2"),
    ("learn --recordings {data} --transfer bad", "argument --transfer: invalid choice"),
    (
        "learn --recordings {data} --priors wood",
        "--transfer prediction needs >= 2 old objects; the run has 1 (wood)",
    ),
    ("learn --recordings {data} --out {taken}", "exists, and outputs are never overwritten"),
    # a dataset given as --out by mistake: --force replaced it, its recordings gone
    ("learn --recordings {data} --out {recorded} --force", "holds recorded data ("),
    ("study transfer --recordings {data} --out {recorded} --force", "never recordings or bags"),
    ("learn --recordings {data} --workers 0", "give 1 or more worker processes"),
    ("study nosuch", "argument name: invalid choice"),
    ("study transfer --recordings {tmp}/missing", "not a directory"),
    ("study transfer --recordings {data} --out {taken}", "add --force to replace it"),
    ("study transfer --recordings {data} --actions S9", "--actions S9: not in the dataset"),
    ("study transfer --recordings {data} --new woood", "--new woood: not in the dataset"),
    ("study transfer --recordings {data} --actions ,", "--actions ',': no id; give comma-"),
    ("learn --recordings {data} --new ,,", "--new ',,': no id; give comma-separated ids, or"),
    ("study fusion --recordings {data} --workers 0", "give 1 or more worker processes"),
    (
        "study fusion --recordings {tmp}/missing --fusion-prior {tmp}/none.json",
        "--fusion-prior {tmp}/none.json: cannot read it",  # before the dataset is looked at
    ),
    ("study all --fusion-prior {file}", "cannot read it (not UTF-8 JSON text)"),
    (
        "study fusion --recordings {tmp}/missing --fusion-parts texture=cubic",
        "--fusion-parts 'texture=cubic': 'texture=cubic' is not BLOCK=KERNEL",
    ),
    ("view {tmp}/missing.mcap", "no such file or directory"),
    ("view {tmp}", "no recordings (*.mcap) or learn runs found"),
    ("view {file} --save {tmp}/v.rrd --serve", "--save and --serve: choose one"),
    ("view {file} --serve --web-port 70000", "--web-port: 70000: give a port from 0"),
    ("view {file} --serve --grpc-port 1.5", "--grpc-port: 1.5: give a port from 0"),
    ("view {file} --foxglove 127.0.0.1:0 --speed nan", "--speed nan: give 0 (at once) or a"),
    ("view {file} --foxglove 127.0.0.1:0 --speed -1", "--speed -1: give 0 (at once) or a"),
    ("view {file} --save {taken}/old.rrd", "--save {taken}/old.rrd: exists"),
    ("view {file} --save {taken}", "is a directory; give a file name"),
    ("export {tmp}/missing.mcap", "no such file or directory"),
    ("export {file} --format xml", "argument --format: invalid choice"),
    ("export {file} --out {exported}", "never overwritten"),
]


@pytest.fixture(scope="module")
def places(
    small_dataset: Path, fake_recording: Path, tmp_path_factory: pytest.TempPathFactory
) -> dict[str, str]:
    base = tmp_path_factory.mktemp("errors")
    (base / "tmp").mkdir()
    taken = base / "taken"
    taken.mkdir()
    (taken / "old.rrd").write_bytes(b"an earlier view")
    exported = base / "exported"
    assert main(["export", str(fake_recording), "--out", str(exported)]) == 0
    file = base / "recording" / "sponge" / "S2" / "003.mcap"
    file.parent.mkdir(parents=True)
    shutil.copy(fake_recording, file)
    return {
        "data": str(small_dataset),
        "file": str(file),
        "tmp": str(base / "tmp"),
        "taken": str(taken),
        "exported": str(exported),
        "recorded": str(base / "recording"),
    }


@pytest.mark.parametrize(("argv", "expected"), CASES, ids=[argv for argv, _ in CASES])
def test_every_error_is_one_line_and_a_non_zero_exit(
    places: dict[str, str], argv: str, expected: str, capsys: pytest.CaptureFixture[str]
) -> None:
    capsys.readouterr()
    status = main(argv.format(**places).split())
    err = capsys.readouterr().err
    assert status != 0
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("atikt-replay")
    assert expected.format(**places) in lines[0]
    assert "Traceback" not in err


@pytest.mark.parametrize("program", ["replay", "recorder"])
def test_help_shows_the_default_of_every_option(program: str) -> None:
    module = replay_cli if program == "replay" else record_cli
    parser = module.build_parser()
    subparsers = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for name, sub in subparsers.choices.items():
        formatter = sub._get_formatter()
        for action in sub._actions:
            if action.option_strings and action.default not in (None, False, argparse.SUPPRESS):
                shown = formatter._get_help_string(action) or ""
                assert "(default: " in shown, (name, action.dest)


def test_defaults_named_by_users_are_shown(capsys: pytest.CaptureFixture[str]) -> None:
    expected = {
        "learn": ["--transfer", "(default: prediction)", "(default: thesis)", "(default: 40)"],
        "study": ["(default: prediction)", "(default: thesis)"],
        "export": ["(default: parquet)", "(default: long)", "(default: ./export)"],
    }
    for command, fragments in expected.items():
        assert main([command, "--help"]) == 0
        text = " ".join(capsys.readouterr().out.split())
        for fragment in fragments:
            assert fragment in text, (command, fragment)
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.startswith("atikt-replay ")


def test_an_object_without_an_action_says_both_ways_on() -> None:
    """A lab's dataset without one (object, action): more trials, or the run without it."""
    from replay.errors import ReplayError  # noqa: PLC0415
    from replay.learning._executors import _trials  # noqa: PLC0415

    recorded = {("foam_block", "P1"): [1, 2], ("foam_block", "S2"): [3]}
    assert _trials(recorded, "foam_block", "P1") == [1, 2]
    with pytest.raises(ReplayError) as refused:
        _trials(recorded, "foam_block", "S2")
    assert str(refused.value) == (
        "object 'foam_block', action 'S2': 1 usable recording(s); a run needs >= 2 (one to "
        "learn, one to test); record more trials of it, or leave it out (--actions without "
        "'S2', or --new and --priors without 'foam_block')"
    )
