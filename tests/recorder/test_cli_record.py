import subprocess
import sys
from pathlib import Path

import polars as pl
import pytest
from conftest import FakeRig

from recorder import _rigconfig as rigconfig
from recorder._cli import main
from replay import read_recording


@pytest.fixture(autouse=True)
def fake_rig(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(rigconfig._BUILDERS, "fake", lambda seed, _options: FakeRig(seed))


def _action(out: Path, *extra: str) -> list[str]:
    return [
        "action",
        "--object",
        "wood",
        "--action",
        "P1",
        "--out",
        str(out),
        "--rig",
        "fake",
        *extra,
    ]


def test_action_records_one_file_and_refuses_to_overwrite_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(_action(tmp_path, "--trial", "2", "--seed", "3")) == 0
    path = tmp_path / "wood" / "P1" / "002.mcap"
    assert path.is_file()
    assert str(path) in capsys.readouterr().out
    before = path.read_bytes()
    assert main(_action(tmp_path, "--trial", "2", "--seed", "3")) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith("atikt-record: error: ")
    assert "002.mcap" in err
    assert "never overwritten" in err
    assert "Traceback" not in err
    assert path.read_bytes() == before
    assert main(_action(tmp_path, "--trial", "3", "--seed", "4")) == 1  # another seed
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "holds recordings of seed 3" in err
    assert "--seed 3 to resume it" in err
    assert not (path.parent / "003.mcap").exists()


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (["--object", "marble"], "--objects marble: not in the objects catalog"),
        (["--action", "X9"], "--actions X9: not in the actions catalog"),
        (["--rig", "ur10-lab"], "--rig ur10-lab: unknown rig; known rigs: sim, ur"),
    ],
)
def test_user_mistakes_give_one_line_and_status_1(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], change: list[str], message: str
) -> None:
    assert main([*_action(tmp_path), *change]) == 1
    err = capsys.readouterr().err
    assert message in err
    assert err.count("\n") == 1
    assert not list(tmp_path.rglob("*.mcap"))


def test_dataset_records_selection_and_index(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    tmp_path /= "[lab]"  # a path is text, never a style of the console's markup
    args = ["dataset", "--out", str(tmp_path), "--objects", "wood,soft_sponge", "--actions", "S1"]
    args += ["--trials", "2", "--workers", "1", "--rig", "fake", "--seed", "1"]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "recordings written" in out
    assert "[lab]" in out
    index = pl.read_parquet(tmp_path / "index.parquet", glob=False)
    assert sorted(index["path"]) == [
        "soft_sponge/S1/001.mcap",
        "soft_sponge/S1/002.mcap",
        "wood/S1/001.mcap",
        "wood/S1/002.mcap",
    ]
    assert main(args) == 0
    assert "recordings kept (existed) │ 4" in capsys.readouterr().out
    (tmp_path / "index.parquet").unlink()
    assert main(["index", str(tmp_path)]) == 0
    assert f"{tmp_path / 'index.parquet'}" in capsys.readouterr().out
    assert pl.read_parquet(tmp_path / "index.parquet", glob=False).equals(index)


def test_default_rig_is_the_simulator(tmp_path: Path) -> None:
    args = ["action", "--object", "soft_sponge", "--action", "S1", "--out", str(tmp_path)]
    assert main(args) == 0
    recording = read_recording(tmp_path / "soft_sponge" / "S1" / "001.mcap")
    assert recording.metadata.rig["kind"] == "simulated"
    assert recording.metadata.object_name
    assert [p.phase for p in recording.phases] == [
        "approach",
        "contact",
        "execute",
        "retract",
        "end",
    ]


def test_catalog_files_are_used(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    catalog = tmp_path / "actions.toml"
    catalog.write_text('[Q1]\nkind = "press"\ndepth_m = 0.001\nduration_s = 0.5\n')
    args = _action(tmp_path / "out", "--actions-catalog", str(catalog))
    assert main(args) == 1
    assert "--actions P1: not in the actions catalog; known: Q1" in capsys.readouterr().err
    args[args.index("P1")] = "Q1"
    assert main(args) == 0
    assert (tmp_path / "out" / "wood" / "Q1" / "001.mcap").is_file()
    missing = _action(tmp_path / "out", "--objects-catalog", str(tmp_path / "none.toml"))
    assert main(missing) == 1
    assert "none.toml: cannot read the catalog" in capsys.readouterr().err


def test_index_of_a_missing_directory_is_a_user_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["index", str(tmp_path / "none")]) == 1
    assert "not a directory" in capsys.readouterr().err


def test_usage_errors_exit_2_with_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["action", "--object", "wood"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith("atikt-record action: error: the following arguments are required")


def test_python_dash_m_recorder_is_the_same_program() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "recorder", "--help"], capture_output=True, text=True, check=False
    )
    assert done.returncode == 0
    for name in ("action", "dataset", "index"):
        assert name in done.stdout


def test_the_command_line_starts_without_the_libraries_only_some_commands_use() -> None:
    # every atikt-record start imports the command line; polars, joblib and rosbags' readers
    # (about 0.25 s of a start) are imported by the commands that use them, when they do
    code = (
        "import sys\n"
        "import recorder._cli, recorder._session_command, recorder.virtuallab\n"
        "heavy = ('polars', 'joblib', 'cloudpickle', 'rosbags.highlevel', 'scipy')\n"
        "print(sorted(m for m in heavy if m in sys.modules))\n"
        "import recorder\n"
        "print(recorder.import_bag.__module__, recorder.TopicMap.__name__)\n"
    )
    result = subprocess.run(  # noqa: S603 (this interpreter, a fixed script)
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    )
    assert result.stdout.splitlines() == ["[]", "recorder.bagimport._importer TopicMap"]
