"""Every error path of ``atikt-record``: one line on stderr, a non-zero exit, no traceback."""

from __future__ import annotations

import pytest
from conftest import FakeRig

from recorder import _rigconfig as rigconfig
from recorder._cli import main

_ACTION = "action --object wood --action P1 --rig fake --out {data}"
_DATASET = "dataset --objects wood --actions P1 --trials 1 --rig fake --out {data}"
#: argv (``{data}``: a dataset of seed 0 holding wood/P1/001.mcap, ``{tmp}``: an empty
#: directory) -> a fragment the one-line message must contain.
CASES: list[tuple[str, str]] = [
    ("nosuch", "invalid choice: 'nosuch'"),
    ("action --object wood --action P1", "the following arguments are required: --out"),
    (_ACTION, "001.mcap: a recording with this name exists and is never overwritten"),
    (_ACTION + " --trial 0", "--trial: 0: give a trial number 1..999999"),
    # a trial or seed the recording's metadata cannot hold: written, then refused by check
    (_ACTION + " --trial 9999999", "--trial: 9999999: give a trial number 1..999999"),
    (_ACTION + " --seed 99999999999999999999", "--seed: 99999999999999999999: give a whole"),
    (_DATASET + " --seed -1", "--seed: -1: give a whole number in 0..9223372036854775807"),
    (_ACTION + " --object marble", "--objects marble: not in the objects catalog"),
    (_ACTION + " --action S9", "--actions S9: not in the actions catalog"),
    (_ACTION + " --rig nosuch", "--rig nosuch: unknown rig; known rigs: sim, ur"),
    (_ACTION + " --objects-catalog {tmp}/none.toml", "none.toml: cannot read the catalog"),
    (_DATASET + " --workers 0", "argument --workers: 0: give 1 or more worker processes"),
    (_DATASET + " --trials 0", "--trials 0: need at least one trial"),
    (_DATASET + " --trials 10000000000000000000", "trials are numbered 1..999999; give at most"),
    (_DATASET + " --objects woood", "--objects woood: not in the objects catalog; known:"),
    # recorded once, silently, before: a name given twice is a slip, more trials are --trials
    (_DATASET + " --objects wood,wood", "wood,wood: wood given twice; name each once (more"),
    (_DATASET + " --actions P1,S1,P1", "argument --actions: P1,S1,P1: P1 given twice"),
    # an empty list recorded nothing and said so as a success
    (_DATASET + " --objects ,", "argument --objects: ',': no id; give comma-separated ids"),
    (_DATASET + " --seed 1", "holds recordings of seed 0"),
    (_DATASET + " --seed 1", "give another --out, or --seed 0 to resume it"),
    (_DATASET + " --rig nosuch", "--rig nosuch: unknown rig"),
    ("index {tmp}/missing", "not a directory; give the dataset directory"),
    ("import-bag {tmp}/missing.bag --topics", "missing.bag: cannot read the bag"),
    ("import-bag {tmp}/missing.bag", "--topic-map and --out are required"),
    ("serve-sim --rtde-port 99999", "--rtde-port: 99999: give a port from 0 (any free port)"),
    ("serve-sim --script-port -1", "--script-port: -1: give a port from 0 (any free port)"),
    ("serve-sim --dashboard-port 80x", "--dashboard-port: 80x: give a port from 0"),
    ("serve-sim --host nosuch.invalid", "--host 'nosuch.invalid' is not an address here"),
    ("serve-sim --ros2 --domain-id 233", "--domain-id: 233: give a DDS domain id 0..232"),
    ("listen --topic-map x.toml --out {tmp} --domain-id -1", "--domain-id: -1: give a DDS"),
    # nan never ends the run, -1 ends it before it began
    ("listen --topic-map x.toml --out {tmp} --duration nan", "--duration: nan: give a positive"),
    ("listen --topic-map x.toml --out {tmp} --duration -1", "--duration: -1: give a positive"),
]


@pytest.fixture(scope="module")
def places(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    base = tmp_path_factory.mktemp("errors")
    (base / "tmp").mkdir()
    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(rigconfig._BUILDERS, "fake", lambda seed, _options: FakeRig(seed))
        assert main(_ACTION.format(data=base / "data").split()) == 0
    return {"data": str(base / "data"), "tmp": str(base / "tmp")}


@pytest.mark.parametrize(("argv", "expected"), CASES, ids=[argv for argv, _ in CASES])
def test_every_error_is_one_line_and_a_non_zero_exit(
    places: dict[str, str],
    argv: str,
    expected: str,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setitem(rigconfig._BUILDERS, "fake", lambda seed, _options: FakeRig(seed))
    capsys.readouterr()
    assert main(argv.format(**places).split()) != 0
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("atikt-record")
    assert expected in lines[0]
    assert "Traceback" not in err


def test_help_shows_every_default_and_version_is_printed(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.startswith("atikt-record ")
    assert main(["dataset", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    for option in ("--seed SEED dataset seed (default: 0)", "--rig RIG", "else sim)"):
        assert option in text
