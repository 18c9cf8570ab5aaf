"""The real iCub grasps (recordings/icub_grasp, imported by import-bag) replay through the
reader, the features and a short learning run; the converter reads the author's format."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import polars as pl
import pytest
from scripts import load_script

from replay import read_recording
from replay.cli._main import main as replay
from replay.learning._features import build_features

if TYPE_CHECKING:
    from types import ModuleType

HERE = Path(__file__).parents[2] / "recordings" / "icub_grasp"
DATA = HERE / "data"
OBJECTS = (
    "blue_bear",
    "book",
    "empty_coke",
    "empty_vitamin_water",
    "full_vitamin_water",
    "lotion",
    "med_coke",
    "med_vitamin_water",
    "monkey_toy",
)
NEW = "med_vitamin_water,empty_coke,monkey_toy"


def _converter() -> ModuleType:
    return load_script(HERE / "convert.py", "icub_grasp_convert")


def test_the_committed_subset_is_what_the_converter_promises() -> None:
    index = pl.read_parquet(DATA / "index.parquet")
    assert index.height == 54
    assert sorted(set(index["object_id"].to_list())) == list(OBJECTS)
    assert index.group_by("object_id").len()["len"].to_list() == [6] * 9
    assert set(index["source"].to_list()) == {"import"}
    readme = (DATA / "README.txt").read_text("utf-8")
    assert "Copyright 2012 Harold Soh" in readme
    assert "keep the \ncopyright information intact" in readme.replace("\r", "")
    recording = read_recording(DATA / "med_coke" / "G1" / "001.mcap")
    assert recording.joints is not None
    assert len(recording.joints.names) == 9
    force = recording.skin("force")
    assert force.data.shape == (12, 5, 12)  # med_coke_1.txt: 12 slices, 5 tips x 12 taxels
    assert force.period_ns == 100_000_000
    phases = dict(recording.phases)
    assert phases["end"] - phases["execute"] == 700_000_000
    assert phases["contact"] == int(force.stamps_ns[0])
    # 255 - raw: the last slice's largest response per finger, as in med_coke_1.txt
    assert force.data[-1].max(axis=1).tolist() == [58.0, 24.0, 96.0, 12.0, 13.0]
    report = json.loads(next((DATA / "imports").glob("*.json")).read_text("utf-8"))
    assert len(report["written"]) == 54


def test_features_and_a_learning_run_on_real_grasps(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = tmp_path / "icub"
    shutil.copytree(DATA, data)  # features and learn write caches beside the recordings
    table = build_features(data, workers=1, cache=tmp_path / "features.parquet")
    assert table.quarantined.height == 0
    assert table.frame.height == 54
    argv = ["learn", "--recordings", str(data), "--new", NEW, "--budget", "3"]
    status = replay([*argv, "--workers", "1", "--out", str(tmp_path / "run")])
    assert status == 0, capsys.readouterr().err
    history = pl.read_parquet(tmp_path / "run" / "history.parquet")
    assert history.height > 0


def test_the_converter_says_where_the_data_are_without_a_source() -> None:
    with pytest.raises(SystemExit) as raised:
        _converter().main([])
    message = str(raised.value)
    assert "\n" not in message
    assert message.startswith("no --source: ")
    assert "github.com/clear-nus/icub_grasp_dataset" in message
    assert "copyright kept intact" in message


def _grasp_text(
    slices: int, seed: int
) -> tuple[str, np.ndarray[tuple[int, int, int], np.dtype[np.float64]]]:
    """A grasp file in the author's format (CRLF, a -10000 line), and its raw taxels."""
    rng = np.random.default_rng(seed)
    taxels = rng.integers(180, 256, (slices, 5, 12)).astype(np.float64)
    lines = ["-10000"]
    for s in range(slices):
        lines.append(" ".join(f"{v:g}" for v in rng.uniform(-5, 90, 9)) + " ")
        lines.append(" ".join(f"{v:.1f}" for v in (255 - taxels[s]).max(axis=1)))
        lines.extend(" ".join(f"{v:.1f}" for v in taxels[s, f]) for f in range(5))
    return "\r\n".join(lines) + "\r\n", taxels


def test_the_converter_imports_the_authors_format(tmp_path: Path) -> None:
    convert = _converter()
    folder = tmp_path / "src" / "iCubGraspDataset"
    folder.mkdir(parents=True)
    raw = {}
    for k, obj in enumerate(convert.OBJECTS):
        text, raw[obj] = _grasp_text(7 + k, seed=k)
        (folder / f"{obj}_1.txt").write_text(text, "ascii", newline="")
    out = tmp_path / "out"
    assert convert.convert(tmp_path / "src", out, 1, tmp_path) == 0
    for obj, taxels in raw.items():
        recording = read_recording(out / obj / "G1" / "001.mcap")
        force = recording.skin("force")
        assert np.array_equal(force.data, 255 - taxels)
        phases = dict(recording.phases)
        assert phases["end"] - phases["execute"] == 700_000_000
        assert ("contact" in phases) == (taxels.shape[0] > 7)


def test_the_converter_refuses_malformed_grasps_in_one_line(tmp_path: Path) -> None:
    convert = _converter()
    path = tmp_path / "book_1.txt"
    path.write_text("-10000\n1 2 3\n", "ascii")
    with pytest.raises(SystemExit, match=r"book_1\.txt: not a grasp \(a line -10000"):
        convert.read_grasp(path, "book", 1)
    text, _ = _grasp_text(2, seed=0)
    lines = text.splitlines()
    lines[3] = "1 2 3"
    path.write_text("\n".join(lines), "ascii")
    with pytest.raises(SystemExit, match=r"book_1\.txt slice 1: '1 2 3' is not 12 numbers"):
        convert.read_grasp(path, "book", 1)
    text, _ = _grasp_text(5, seed=1)
    short = tmp_path / "short" / "iCubGraspDataset"
    short.mkdir(parents=True)
    (short / "book_1.txt").write_text(text, "ascii")
    grasps = [convert.read_grasp(short / "book_1.txt", "book", 1)]
    with pytest.raises(SystemExit, match=r"book_1\.txt: 5 slices, fewer than the 7"):
        convert.write_bag(grasps, tmp_path / "bag")
    with pytest.raises(SystemExit, match=r"no iCubGraspDataset/"):
        convert.load(tmp_path / "nothing", 1)
