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
from replay.outputs._study_report import run_study
from replay.studies._running import StudyConfig

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
    with pytest.raises(SystemExit, match=r"holds neither robot_study/test/ \(a checkout\) nor"):
        convert._load(tmp_path)
    (tmp_path / "robot_study.npz").write_bytes(b"not a zip")
    with pytest.raises(SystemExit, match=r"robot_study\.npz: cannot read the study \("):
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


def test_the_converter_says_where_the_data_are_without_a_source() -> None:
    with pytest.raises(SystemExit) as raised:
        _converter().main([])
    message = str(raised.value)
    assert "\n" not in message
    assert message.startswith("no --source: ")
    for part in ("github.com/Healthcare-Robotics/thermal-ambiguity-ToH", "70dbe35", "MIT"):
        assert part in message


def _py2_string(data: bytes) -> bytes:
    """Python 2's repr of a str, as protocol 0 writes it (S'...')."""
    quote = b'"' if b"'" in data and b'"' not in data else b"'"
    escapes = {ord("\\"): b"\\\\", quote[0]: b"\\" + quote, 9: b"\\t", 10: b"\\n", 13: b"\\r"}
    out = bytearray(quote)
    for byte in data:
        if byte in escapes:
            out += escapes[byte]
        elif byte < 0x20 or byte >= 0x7F:
            out += b"\\x%02x" % byte
        else:
            out.append(byte)
    return bytes(out + quote)


def _study_pickle(array: np.ndarray[Any, np.dtype[np.float64]]) -> bytes:
    """A study trial file as Python 2's hrl_lib saved it: protocol 0, Fortran order.

    Byte-identical to the 270 upstream files when given their arrays (checked by hand).
    """
    n, k = array.shape
    head = (
        b"cnumpy.core.multiarray\n_reconstruct\np1\n(cnumpy\nndarray\np2\n(I0\ntS'b'\ntRp3\n"
        b"(I1\n(I%d\nI%d\ntcnumpy\ndtype\np4\n(S'f8'\nI0\nI1\ntRp5\n(I3\nS'<'\nNNNI-1\nI-1\n"
        b"I0\ntbI01\nS" % (n, k)
    )
    return head + _py2_string(array.tobytes(order="F")) + b"\ntb."


def _synthetic_checkout(root: Path) -> dict[str, Any]:
    """Write a tiny upstream tree (2 runs x 3 materials); return the arrays it must give."""
    rng = np.random.default_rng(7)
    t = np.round(np.arange(-200, 1401) * 0.005, 3)
    names = {
        1: ("CW_count_2", "M_count_0", "W_count_1"),
        10: ("CW_count_0", "M_count_2", "W_count_1"),
    }
    rows = []
    for run, stems in names.items():
        for stem in stems:
            force = np.where(t < 0, 0.0, 4.5) + rng.normal(0, 0.05, t.size)
            trial = np.column_stack(
                [
                    t,
                    rng.normal(22, 0.1, t.size),
                    rng.normal(29.5, 0.2, t.size),
                    rng.normal(-2, 0.1, t.size),
                    force,
                ]
            )
            relative = f"robot_study/test/R_{run}/{stem}_sensor_29.5.pkl"
            (root / relative).parent.mkdir(parents=True, exist_ok=True)
            (root / relative).write_bytes(_study_pickle(trial))
            rows.append((relative, stem.split("_")[0], run, int(stem[-1]), trial))
    (root / "License.txt").write_text("MIT License\n", "utf-8")
    rows.sort(key=lambda row: row[0])  # path order: R_1 before R_10
    return {
        "t_s": t,
        "passive_c": np.stack([r[4][:, 1] for r in rows]).astype(np.float32),
        "heated_c": np.stack([r[4][:, 2] for r in rows]).astype(np.float32),
        "force_n": np.stack([r[4][:, 4] for r in rows]).astype(np.float32),
        "material": np.array([r[1] for r in rows]),
        "run": np.array([r[2] for r in rows]),
        "count": np.array([r[3] for r in rows]),
        "source_file": np.array([r[0] for r in rows]),
    }


def test_an_upstream_checkout_gives_the_arrays_and_recordings_of_the_npz(tmp_path: Path) -> None:
    convert = _converter()
    checkout, export = tmp_path / "toh", tmp_path / "npz"
    expected = _synthetic_checkout(checkout)
    export.mkdir()
    cast("Any", np.savez)(export / "robot_study.npz", **expected)
    (export / "LICENSE").write_text("MIT License\n", "utf-8")
    from_pickles = convert._load(checkout)
    assert from_pickles.keys() == expected.keys()
    for key, value in expected.items():
        assert from_pickles[key].dtype == value.dtype, key
        assert np.array_equal(from_pickles[key], value), key
    for source, out in ((checkout, tmp_path / "a"), (export, tmp_path / "b")):
        assert convert.main(["--source", str(source), "--all", "--out", str(out)]) == 0
    made = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*.mcap"))
    assert len(made) == 6
    for relative in made:
        assert (tmp_path / "a" / relative).read_bytes() == (tmp_path / "b" / relative).read_bytes()
    assert (tmp_path / "a" / "LICENSE").read_text("utf-8") == "MIT License\n"


def test_a_study_pickle_naming_other_code_is_refused(tmp_path: Path) -> None:
    convert = _converter()
    marker = tmp_path / "ran"
    path = tmp_path / "evil.pkl"
    path.write_bytes(b"cos\nsystem\n(S'touch %s'\ntR." % str(marker).encode())
    with pytest.raises(SystemExit, match=r"evil\.pkl: cannot read the trial \(global os\.system"):
        convert.read_pickle(path)
    assert not marker.exists()
    path.write_bytes(b"I3\n.")
    with pytest.raises(SystemExit, match=r"holds int, not samples x 5 float64"):
        convert.read_pickle(path)
