"""A dataset's recordings count once: copies, misplaced files, dangling links, a broken index.

A study splits each (object, action)'s trials into a test set and a pool; a recording counted
twice can be in both. The feature table leaves such rows out with a line naming both files,
``check`` says where a misplaced file belongs without overwriting another, a dangling link is
one line naming its missing target, and an unreadable index is one problem of its own.
"""

import shutil
from pathlib import Path

import polars as pl
import pytest

from recorder import write_index
from replay.cli._main import main
from replay.errors import ReplayError
from replay.learning._features import _one_row_per_trial, build_features

#: The few recordings of the small dataset a test copies (each test's dataset is its own).
_FILES = ("wood/P1/001.mcap", "wood/P1/002.mcap", "foam_block/P1/001.mcap")


def _tiny(small_dataset: Path, root: Path) -> Path:
    """Copy three recordings of the small dataset into ``root``; return it."""
    for name in _FILES:
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(small_dataset / name, root / name)
    return root


def test_a_copy_in_another_objects_directory_is_left_out_naming_both_files(
    small_dataset: Path, tmp_path: Path
) -> None:
    root = _tiny(small_dataset, tmp_path / "ds")
    shutil.copyfile(root / "wood/P1/002.mcap", root / "foam_block/P1/002.mcap")
    table = build_features(root)
    assert sorted(table.frame["path"].to_list()) == sorted(_FILES)  # wood trial 2 once
    ((path, reason),) = table.quarantined.iter_rows()
    assert path == "foam_block/P1/002.mcap"
    assert "the metadata says object_id wood" in reason
    assert f"it is a copy of {root / 'wood/P1/002.mcap'} (the same bytes): delete it" in reason
    assert "\n" not in reason


def test_identical_files_of_two_datasets_in_one_directory_count_once(
    small_dataset: Path, tmp_path: Path
) -> None:
    _tiny(small_dataset, tmp_path / "data" / "a")
    _tiny(small_dataset, tmp_path / "data" / "b")
    table = build_features(tmp_path / "data")
    assert table.frame["sha256"].n_unique() == table.frame.height == len(_FILES)
    assert table.frame["path"].to_list() == sorted(f"a/{name}" for name in _FILES)
    assert table.quarantined.height == len(_FILES)
    for path, reason in table.quarantined.iter_rows():
        assert path.startswith("b/")
        assert f"the same bytes as {tmp_path / 'data' / 'a' / path[2:]}" in reason


def test_two_recordings_of_one_trial_keep_the_first() -> None:
    """Different bytes saying the same object, action and trial: the second is left out."""
    frame = pl.DataFrame(
        {
            "path": ["a/wood/P1/001.mcap", "b/wood/P1/001.mcap", "b/wood/P1/002.mcap"],
            "sha256": ["1", "2", "3"],
            "object_id": ["wood"] * 3,
            "action_id": ["P1"] * 3,
            "trial": [1, 1, 2],
        }
    )
    kept, refused = _one_row_per_trial(Path("data"), frame)
    assert kept["path"].to_list() == ["a/wood/P1/001.mcap", "b/wood/P1/002.mcap"]
    assert [r["path"] for r in refused] == ["b/wood/P1/001.mcap"]
    assert "as data/a/wood/P1/001.mcap says too" in refused[0]["reason"]


def test_a_valid_dataset_loses_no_row(small_dataset: Path, tmp_path: Path) -> None:
    table = build_features(_tiny(small_dataset, tmp_path / "ds"))
    assert table.quarantined.height == 0
    assert table.frame.height == len(_FILES)


def test_check_does_not_advise_overwriting_another_recording(
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = _tiny(small_dataset, tmp_path / "ds")
    # wood's trial 2 copied over foam_block's trial 1: moving it back would overwrite wood's
    shutil.copyfile(root / "wood/P1/002.mcap", root / "foam_block/P1/001.mcap")
    write_index(root)
    assert main(["check", str(root), "--workers", "1"]) == 1
    err = capsys.readouterr().err
    assert f"it is a copy of {root / 'wood/P1/002.mcap'} (the same bytes): delete it" in err
    assert "move the file to" not in err
    # a different recording at the target: the fix names a free trial instead of moving there
    shutil.copyfile(small_dataset / "wood/P1/003.mcap", root / "wood/P1/002.mcap")
    write_index(root)
    assert main(["check", str(root), "--workers", "1"]) == 1
    err = capsys.readouterr().err
    assert "holds another recording of that trial" in err
    assert f"trial 3 ({root / 'wood/P1/003.mcap'} is free)" in err


def test_a_dangling_link_is_one_line_naming_its_missing_target(
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = _tiny(small_dataset, tmp_path / "ds")
    write_index(root)
    link = root / "wood/P1/005.mcap"
    link.symlink_to("nowhere.mcap")
    line = (
        f"{link}: a symbolic link to {root / 'wood/P1/nowhere.mcap'}, which does not exist: "
        f"remove the link or restore {root / 'wood/P1/nowhere.mcap'}"
    )
    assert main(["check", str(root), "--workers", "1"]) == 1
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [f"FAIL {line}"]
    assert "3 of 4 recordings valid" in captured.out
    with pytest.raises(ReplayError, match=r"a symbolic link to .*which does not exist"):
        build_features(root)
    assert main(["info", str(link)]) == 1
    assert line in capsys.readouterr().err


@pytest.mark.parametrize("index", ["garbage", "other columns"])
def test_an_unreadable_index_is_one_failure_and_the_recordings_are_judged_alone(
    index: str, small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = _tiny(small_dataset, tmp_path / "ds")
    if index == "garbage":
        (root / "index.parquet").write_text("garbage\n")
    else:
        pl.DataFrame({"a": [1]}).write_parquet(root / "index.parquet")
    assert main(["check", str(root), "--workers", "1"]) == 1  # the index is bad
    captured = capsys.readouterr()
    (line,) = captured.err.splitlines()
    assert line.startswith(f"FAIL {root / 'index.parquet'}: the dataset index cannot be read")
    assert line.endswith(f"rebuild it with 'atikt-record index {root}'")
    assert "3 of 3 recordings valid" in captured.out
