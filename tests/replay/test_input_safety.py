"""No command deletes, replaces or writes into its inputs; caches go where they may."""

import os
import shutil
import subprocess
from pathlib import Path

import pytest
from conftest import copy_dataset

from recorder._cli import main as record_main
from replay.cli._main import main
from replay.learning import _cachedir
from replay.learning._cachedir import FEATURES_NAME, feature_cache_path
from replay.learning._features import build_features
from schemas import dataset_recordings


def _tree(root: Path) -> dict[str, bytes]:
    """Return every file under ``root`` with its bytes."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in root.rglob("*") if p.is_file()}


@pytest.fixture
def parent(small_dataset: Path, tmp_path: Path) -> Path:
    """A directory holding a copy of the small dataset (``ds``) and an unrelated file."""
    copy_dataset(small_dataset, tmp_path / "parent" / "ds")
    (tmp_path / "parent" / "notes.txt").write_text("keep me\n", "utf-8")
    return tmp_path / "parent"


def _refused(capsys: pytest.CaptureFixture[str], status: int, words: str) -> None:
    err = capsys.readouterr().err
    assert status == 1
    assert len(err.strip().splitlines()) == 1, err
    assert words in err


@pytest.mark.parametrize("where", ["parent", "parent/ds", "parent/ds/results", "link"])
def test_study_never_deletes_its_input_dataset_even_with_force(
    parent: Path, capsys: pytest.CaptureFixture[str], where: str
) -> None:
    (parent.parent / "link").symlink_to(parent)
    before = _tree(parent)
    out = parent.parent / where
    argv = ["study", "transfer", "--recordings", str(parent / "ds"), "--out", str(out)]
    status = main([*argv, "--force", "--quick", "--workers", "1"])
    _refused(capsys, status, "an input of this command")
    assert _tree(parent) == before


def test_learn_refuses_an_out_inside_its_dataset_before_any_cache_is_written(
    parent: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    dataset = parent / "ds"
    (dataset / FEATURES_NAME).unlink(missing_ok=True)
    before = _tree(parent)
    argv = ["learn", "--recordings", str(dataset), "--out", str(dataset / "run"), "--force"]
    _refused(capsys, main([*argv, "--workers", "1"]), "lies inside the dataset")
    assert _tree(parent) == before


def test_view_never_replaces_the_recording_it_shows(
    parent: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recording = dataset_recordings(parent / "ds")[0]
    before = recording.read_bytes()
    argv = ["view", str(recording), "--save", str(recording), "--force", "--no-figures"]
    _refused(capsys, main(argv), f"--save {recording}: is the input")
    assert recording.read_bytes() == before


def test_export_refuses_to_write_into_the_exported_dataset(
    parent: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    before = _tree(parent)
    status = main(["export", str(parent / "ds"), "--out", str(parent / "ds"), "--format", "csv"])
    _refused(capsys, status, "is the input")
    assert _tree(parent) == before


def test_recording_into_the_directory_of_its_catalog_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    catalog = tmp_path / "lab" / "actions.toml"
    catalog.parent.mkdir()
    catalog.write_text('[P9]\nkind = "press"\nduration_s = 1.0\ndepth_m = 0.001\n', "utf-8")
    argv = ["action", "--object", "wood", "--action", "P9", "--out", str(tmp_path / "lab")]
    _refused(capsys, record_main([*argv, "--actions-catalog", str(catalog)]), "contains the")
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["actions.toml", "lab"]


def _git(*args: str, cwd: Path) -> None:
    env = os.environ | {"GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@example.org"}
    env |= {"GIT_COMMITTER_NAME": "t", "GIT_COMMITTER_EMAIL": "t@example.org"}
    command = ["git", *args]
    subprocess.run(command, cwd=cwd, check=True, capture_output=True, env=env)  # noqa: S603


@pytest.fixture
def checkout(small_dataset: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A git checkout with the dataset committed under ``recordings/data``; a private cache."""
    if shutil.which("git") is None:
        pytest.skip("git is not installed")
    repo = tmp_path / "repo"
    dataset = repo / "recordings" / "data"
    copy_dataset(small_dataset, dataset)
    (dataset / FEATURES_NAME).unlink(missing_ok=True)
    _git("init", "-q", cwd=repo)
    _git("add", "recordings", cwd=repo)
    _git("commit", "-q", "-m", "data", cwd=repo)
    monkeypatch.setenv("ATIKT_CACHE", str(tmp_path / "cache"))
    return dataset


def test_the_feature_cache_of_a_tracked_dataset_goes_to_the_user_cache(
    checkout: Path, tmp_path: Path
) -> None:
    before = _tree(checkout)
    table = build_features(checkout, workers=1)
    assert _tree(checkout) == before
    cache = feature_cache_path(checkout)
    assert cache.is_file()
    assert cache.is_relative_to(tmp_path / "cache")
    assert table.frame.height == len(dataset_recordings(checkout))


def test_without_git_a_dot_git_above_the_dataset_counts_as_tracked(
    checkout: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(shutil, "which", lambda _name: None)
    assert feature_cache_path(checkout).is_relative_to(tmp_path / "cache")


def test_an_untracked_writable_dataset_keeps_its_cache_beside_the_data(
    parent: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("ATIKT_CACHE", str(tmp_path / "cache"))
    assert feature_cache_path(parent / "ds") == (parent / "ds" / FEATURES_NAME).resolve()


def test_two_datasets_never_share_a_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(_cachedir, "is_tracked", lambda _directory: True)
    monkeypatch.setenv("ATIKT_CACHE", str(tmp_path / "cache"))
    (tmp_path / "a" / "data").mkdir(parents=True)
    (tmp_path / "b" / "data").mkdir(parents=True)
    first, second = (feature_cache_path(tmp_path / x / "data") for x in "ab")
    assert first != second
    assert first.parent.parent == tmp_path / "cache" / "features"


def test_info_says_where_the_cache_of_a_dataset_is(
    checkout: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["info", str(checkout)]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert f"feature cache: {feature_cache_path(checkout)}" in out


@pytest.mark.parametrize("command", ["view", "export"])
def test_an_output_beside_a_named_recording_is_refused_inside_its_dataset(
    parent: Path, capsys: pytest.CaptureFixture[str], command: str
) -> None:
    """A saved view or an export named into the dataset of the recording read would become
    one of its files (``check`` fails an .rrd named 003.mcap; ``features`` reads it)."""
    root = parent / "ds"
    recording = root / "wood" / "P1" / "001.mcap"
    before = _tree(parent)
    if command == "view":
        option, target = "--save", root / "wood" / "P1" / "099.mcap"
        argv = ["view", str(recording), option, str(target), "--no-figures"]
    else:
        option, target = "--out", root / "exp"
        argv = ["export", str(recording), option, str(target)]
    _refused(capsys, main(argv), f"{option} {target}: lies inside the dataset {root.resolve()}")
    assert _tree(parent) == before
    outside = parent / "exp"  # beside the dataset: written
    assert main(["export", str(recording), "--out", str(outside)]) == 0
    assert (outside / "force.parquet").is_file()
