"""Replay the committed recordings against their golden summaries (recordings/README.md)."""

import json
import math
import tomllib
from pathlib import Path
from typing import Any

import polars as pl
import pytest

from recordings.regenerate import DATA, golden_path, summarize
from replay import MODALITIES, read_recording

RECORDINGS = sorted(DATA.rglob("*.mcap"))
RELATIVE_TOLERANCE = 1e-6


def _compare(actual: Any, expected: Any, where: str) -> None:
    """Compare JSON values: exact for ints, strings and structure, 1e-6 relative for floats."""
    if isinstance(expected, dict):
        assert isinstance(actual, dict), where
        assert sorted(actual) == sorted(expected), where
        for key, value in expected.items():
            _compare(actual[key], value, f"{where}.{key}")
    elif isinstance(expected, list):
        assert isinstance(actual, list), where
        assert len(actual) == len(expected), where
        for index, (a, e) in enumerate(zip(actual, expected, strict=True)):
            _compare(a, e, f"{where}[{index}]")
    elif isinstance(expected, float):
        assert math.isclose(actual, expected, rel_tol=RELATIVE_TOLERANCE, abs_tol=1e-12), where
    else:
        assert actual == expected, where


def test_the_committed_set_covers_every_action_channel_and_kind_of_object() -> None:
    index = pl.read_parquet(DATA / "index.parquet")
    assert index.height == len(RECORDINGS) > 0
    assert set(index["action_id"]) == {"P1", "P2", "S1", "S2", "S3", "S4", "C1"}
    declared = tomllib.loads((DATA / "objects.toml").read_text("utf-8"))
    assert {v["novel"] for v in declared.values()} == {True, False}
    assert (index.select(pl.col("^n_.*$")).min_horizontal() > 0).all()
    assert sum(path.stat().st_size for path in DATA.rglob("*") if path.is_file()) <= 35e6


@pytest.mark.parametrize("path", RECORDINGS, ids=lambda p: p.relative_to(DATA).as_posix())
def test_recording_decodes_to_its_golden_summary(path: Path) -> None:
    expected = json.loads(golden_path(path).read_text())
    _compare(summarize(read_recording(path)), expected, path.name)


def test_goldens_catch_a_changed_value() -> None:
    recording = read_recording(RECORDINGS[0])
    expected = json.loads(golden_path(RECORDINGS[0]).read_text())
    actual = summarize(recording)
    actual["skin"][MODALITIES[0]]["data"]["mean"][0] *= 1 + 1e-5
    with pytest.raises(AssertionError):
        _compare(actual, expected, "changed")
