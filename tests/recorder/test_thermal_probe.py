"""The real heated-probe recordings (recordings/thermal_probe, imported by import-bag) replay
through the reader, the features and a short fusion study."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np
import polars as pl
import pytest
from scripts import load_script

from replay import read_recording
from replay.learning._features import build_features
from replay.studies._studies import StudyConfig, run_study

if TYPE_CHECKING:
    from types import ModuleType

DATA = Path(__file__).parents[2] / "recordings" / "thermal_probe" / "data"
OBJECTS = ("aluminium", "cold_wood", "wood")


def test_the_committed_subset_is_what_the_converter_promises() -> None:
    index = pl.read_parquet(DATA / "index.parquet")
    assert index.height == 30
    assert sorted(set(index["object_id"].to_list())) == list(OBJECTS)
    assert set(index["source"].to_list()) == {"import"}
    assert (DATA / "LICENSE").read_text("utf-8").strip().startswith("MIT License")
    recording = read_recording(DATA / "aluminium" / "H5" / "001.mcap")
    assert recording.joints is None
    assert set(recording.signals) == {"force", "temperature"}
    temperature = recording.skin("temperature")
    assert temperature.data.shape[1:] == (1, 2)
    assert temperature.period_ns == 5_000_000
    execute = dict(recording.phases)["execute"]
    force = recording.skin("force")
    after = force.data[force.stamps_ns >= execute, 0, 0]
    assert after[0] > 1.0  # the window starts at the force onset
    # aluminium draws heat: the heated thermistor drops by more than 1 C during the hold
    heated = temperature.data[temperature.stamps_ns >= execute, 0, 0]
    assert heated[0] - heated.min() > 1.0
    report = json.loads(next((DATA / "imports").glob("*.json")).read_text("utf-8"))
    assert len(report["written"]) == 30


def test_features_and_a_fusion_study_run_on_real_data(tmp_path: Path) -> None:
    table = build_features(DATA, workers=1, cache=tmp_path / "features.parquet")
    assert table.quarantined.height == 0
    assert table.frame.height == 30
    config = StudyConfig(
        out=tmp_path / "fusion",
        new=("aluminium", "cold_wood"),
        old=("wood",),
        actions=("H5",),
        fusion_groups=1,
        fusion_repetitions=2,
    )
    output = run_study("fusion", table.frame, config)
    results = pl.read_parquet(next(Path(config.out).glob("*.parquet")))
    assert results.height > 0
    assert np.isfinite(results.select(pl.col(pl.Float64)).to_numpy()).any()
    assert output is not None


def _converter() -> ModuleType:
    return load_script(DATA.parent / "convert.py", "thermal_probe_convert")


def test_the_converter_selects_runs_and_refuses_bad_ones() -> None:
    convert = _converter()
    material = np.array(["W", "M", "CW"] * 4)
    run = np.repeat(np.arange(1, 5), 3)
    assert convert._select(material, None, run, range(2, 4)) == list(range(3, 9))
    assert convert._select(material, 1, run, range(3, 5)) == [6, 7, 8]
    assert convert._select(material, 2, run, None) == list(range(6))
    assert convert._runs("11-30") == range(11, 31)
    assert convert._runs("7") == range(7, 8)
    for text in ("10-1", "a-b", ""):
        with pytest.raises(argparse.ArgumentTypeError, match=r"e\.g\. 1-10"):
            convert._runs(text)


def test_the_converter_refuses_a_bad_study_file_in_one_line(tmp_path: Path) -> None:
    convert = _converter()
    with pytest.raises(SystemExit, match=r"robot_study\.npz: cannot read the study \(No such"):
        convert._load(tmp_path)
    arrays: dict[str, Any] = {k: np.zeros(2) for k in ("run", "t_s", "force_n", "heated_c")}
    arrays |= {"passive_c": np.zeros(2), "material": np.array(["W", "X"])}
    save = cast("Any", np.savez)  # numpy's stub types **arrays as its own keyword options
    save(tmp_path / "robot_study.npz", **arrays)
    with pytest.raises(SystemExit, match="no array source_file"):
        convert._load(tmp_path)
    save(tmp_path / "robot_study.npz", source_file=np.array(["a", "b"]), **arrays)
    with pytest.raises(SystemExit, match="material codes X are not the study's"):
        convert._load(tmp_path)
