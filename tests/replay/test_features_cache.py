import shutil
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from conftest import ACTIONS, NEW, OLD, TRIALS, copy_dataset

from replay.errors import ReplayError
from replay.learning._features import (
    FEATURES_NAME,
    as_raw,
    build_features,
    file_features,
    select_blocks,
)


@pytest.fixture
def dataset(small_dataset: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "dataset"
    copy_dataset(small_dataset, copy)
    (copy / FEATURES_NAME).unlink(missing_ok=True)
    return copy


def test_cache_has_one_row_per_recording_with_every_block_its_sensors_give(
    dataset: Path,
) -> None:
    table = build_features(dataset)
    assert table.frame.height == len(OLD + NEW) * len(ACTIONS) * TRIALS
    assert table.extracted == table.frame.height
    assert table.quarantined.height == 0
    for block in ("force", "texture", "thermal"):  # the simulated skin has every sensor
        assert table.frame[block].null_count() == 0
    assert (dataset / FEATURES_NAME).exists()
    # the learner sees the thesis's blocks per kind, or every block with the "all" policy
    press = table.frame.filter(pl.col("action_kind") == "press").row(0, named=True)
    slide = table.frame.filter(pl.col("action_kind") == "slide").row(0, named=True)
    assert as_raw(press).modalities == ("force", "thermal")
    assert as_raw(slide).modalities == ("texture", "thermal")
    every = ("force", "texture", "thermal")
    assert set(select_blocks("slide", every, "all")) == set(every)
    with pytest.raises(ReplayError, match="feature policy 'some'"):
        select_blocks("slide", ("force",), "some")


def test_cached_features_equal_the_file_path(dataset: Path) -> None:
    table = build_features(dataset)
    row = table.frame.row(0, named=True)
    direct = file_features(dataset / row["path"])
    cached = as_raw(row)
    np.testing.assert_array_equal(direct.modality("thermal"), cached.modality("thermal"))
    assert direct.kind == cached.kind


def test_rebuild_extracts_only_changed_files_and_drops_removed_ones(dataset: Path) -> None:
    first = build_features(dataset)
    assert build_features(dataset).extracted == 0
    paths = sorted(dataset.rglob("*.mcap"))
    shutil.copyfile(paths[1], paths[0])  # content changed: another recording's bytes
    paths[2].unlink()
    again = build_features(dataset)
    assert again.extracted == 1
    # the changed file is a copy of trial 2 at trial 1's place: extracted, then left out
    (copied,) = again.quarantined["path"].to_list()
    assert copied == paths[0].relative_to(dataset).as_posix()
    assert again.frame.height == first.frame.height - 2


def test_two_workers_give_the_same_cache_bytes(dataset: Path, tmp_path: Path) -> None:
    other = tmp_path / "other"
    shutil.copytree(dataset, other)
    build_features(dataset, workers=1)
    build_features(other, workers=2, chunk=7)
    assert (dataset / FEATURES_NAME).read_bytes() == (other / FEATURES_NAME).read_bytes()


def test_bad_recording_is_quarantined_with_its_reason(dataset: Path) -> None:
    bad = sorted(dataset.rglob("*.mcap"))[3]
    bad.write_bytes(bad.read_bytes()[: bad.stat().st_size // 2])
    table = build_features(dataset)
    assert table.quarantined["path"].to_list() == [bad.relative_to(dataset).as_posix()]
    assert str(bad.name) in table.quarantined["reason"][0]
    assert table.frame.height == len(OLD + NEW) * len(ACTIONS) * TRIALS - 1


def test_empty_directory_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(ReplayError, match="no recordings"):
        build_features(tmp_path)
