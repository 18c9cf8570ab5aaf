"""``atikt-replay export``: one table per channel, long and wide, parquet and CSV."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from replay import MODALITIES, ReplayError, read_recording
from replay.cli._main import main
from replay.outputs._export import TABLES, export, phase_labels, value_columns

#: The joint states' topic: a recording without it is a rig without an arm.
_JOINTS = "/robot/joint_states"


def _dataset(fake_recording: Path, root: Path, trials: tuple[str, ...] = ("003", "004")) -> Path:
    for trial in trials:
        target = root / "sponge" / "S2" / f"{trial}.mcap"
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(fake_recording, target)
    return root


def test_long_tables_hold_every_value(fake_recording: Path, tmp_path: Path) -> None:
    recording = read_recording(fake_recording)
    report = export([fake_recording], tmp_path / "out", root=fake_recording.parent)
    assert [p.name for p in report.files] == [f"{t}.parquet" for t in TABLES]
    for modality in MODALITIES:
        series = recording.skin(modality)
        table = pl.read_parquet(tmp_path / "out" / f"{modality}.parquet")
        n, cells, _ = series.data.shape
        assert table.height == n * cells == report.rows[modality]
        assert table["recording"].unique().to_list() == ["sponge/S2/003.mcap"]
        table = table.sort("stamp_ns", "cell", maintain_order=True)
        assert table["stamp_ns"].to_list() == np.repeat(series.stamps_ns, cells).tolist()
        assert table["cell"].to_list() == np.tile(series.cell_ids, n).tolist()
        values = table.select(value_columns(modality, series.data.shape[2])).to_numpy()
        np.testing.assert_array_equal(values, series.data.reshape(n * cells, -1))
    assert recording.joints is not None
    assert recording.tcp is not None
    joints = pl.read_parquet(tmp_path / "out" / "joint_states.parquet")
    np.testing.assert_array_equal(
        joints.select(f"effort_{name}" for name in recording.joints.names).to_numpy(),
        recording.joints.effort,
    )
    tcp = pl.read_parquet(tmp_path / "out" / "tcp_pose.parquet")
    np.testing.assert_array_equal(
        tcp.select("qx", "qy", "qz", "qw").to_numpy(), recording.tcp.orientation
    )
    phases = pl.read_parquet(tmp_path / "out" / "phases.parquet")
    assert phases.select("phase", "start_ns").rows() == list(recording.phases)
    assert phases["stop_ns"].to_list()[:-1] == phases["start_ns"].to_list()[1:]
    meta = pl.read_parquet(tmp_path / "out" / "recordings.parquet").row(0, named=True)
    assert (meta["object_id"], meta["action_id"], meta["trial"]) == ("sponge", "S2", 3)
    assert meta["speed_m_s"] == recording.metadata.action_parameters["speed_m_s"]


def test_phase_labels_are_half_open(fake_recording: Path) -> None:
    recording = read_recording(fake_recording)
    starts = np.array([start for _, start in recording.phases], dtype=np.int64)
    labels = phase_labels(recording, np.concatenate([starts - 1, starts])).to_list()
    names = [phase for phase, _ in recording.phases]
    assert labels[len(starts) :] == names  # a sample at a phase's start belongs to it
    assert labels[: len(starts)] == ["", *names[:-1]]  # one ns earlier: the phase before


def test_wide_layout_has_a_column_per_cell_and_channel(
    fake_recording: Path, tmp_path: Path
) -> None:
    recording = read_recording(fake_recording)
    export([fake_recording], tmp_path / "out", layout="wide")
    force = pl.read_parquet(tmp_path / "out" / "force.parquet")
    series = recording.skin("force")
    assert force.height == series.stamps_ns.size
    for c, cell in enumerate(series.cell_ids):
        for k, channel in enumerate(value_columns("force", series.data.shape[2])):
            column = force[f"c{cell}_{channel}"].to_numpy()
            np.testing.assert_array_equal(column, series.data[:, c, k])


def test_csv_equals_parquet_over_a_dataset(
    fake_recording: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _dataset(fake_recording, tmp_path / "data")
    monkeypatch.chdir(tmp_path)  # a relative path, as typed by a user
    assert main(["export", "data", "--out", str(tmp_path / "pq")]) == 0
    assert main(["export", "data", "--format", "csv", "--out", str(tmp_path / "csv")]) == 0
    for table in TABLES:
        parquet = pl.read_parquet(tmp_path / "pq" / f"{table}.parquet")
        csv = pl.read_csv(tmp_path / "csv" / f"{table}.csv", schema=parquet.schema)
        assert csv.equals(parquet), table
    force = pl.read_parquet(tmp_path / "pq" / "force.parquet")
    assert force["recording"].unique(maintain_order=True).to_list() == [
        "sponge/S2/003.mcap",
        "sponge/S2/004.mcap",
    ]
    assert not list((tmp_path / "pq").glob(".*"))  # no parts left


def test_existing_tables_are_never_overwritten(fake_recording: Path, tmp_path: Path) -> None:
    export([fake_recording], tmp_path / "out")
    before = (tmp_path / "out" / "force.parquet").read_bytes()
    with pytest.raises(ReplayError, match=r"never overwritten"):
        export([fake_recording], tmp_path / "out")
    assert (tmp_path / "out" / "force.parquet").read_bytes() == before


def test_a_bad_recording_leaves_no_table(fake_recording: Path, tmp_path: Path) -> None:
    root = _dataset(fake_recording, tmp_path / "data")
    bad = root / "sponge" / "S2" / "004.mcap"
    bad.write_bytes(bad.read_bytes()[:-200])
    with pytest.raises(ReplayError, match=r"004.mcap"):
        export(sorted(root.rglob("*.mcap")), tmp_path / "out", fmt="csv")
    assert list((tmp_path / "out").iterdir()) == []


def test_one_file_of_a_dataset_is_named_from_the_dataset(
    fake_recording: Path, tmp_path: Path
) -> None:
    root = _dataset(fake_recording, tmp_path / "data")
    one = root / "sponge" / "S2" / "004.mcap"
    assert main(["export", str(one), "--out", str(tmp_path / "one")]) == 0
    names = pl.read_parquet(tmp_path / "one" / "recordings.parquet")["recording"].to_list()
    assert names == ["sponge/S2/004.mcap"]
    stray = tmp_path / "loose.mcap"
    shutil.copy(fake_recording, stray)  # not laid out as <object>/<action>/<trial>.mcap
    report = export([stray], tmp_path / "loose", root=tmp_path)
    assert pl.read_parquet(report.files[0])["recording"].to_list() == ["loose.mcap"]


def test_a_full_disk_is_one_line_and_leaves_nothing(
    fake_recording: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    def full(*_args: object, **_kwargs: object) -> None:
        message = "parquet: underlying IO error: No space left on device (os error 28)"
        raise pl.exceptions.ComputeError(message)

    monkeypatch.setattr(pl.DataFrame, "write_parquet", full)
    assert main(["export", str(fake_recording), "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "cannot write the export" in err
    assert "No space left on device" in err
    assert list((tmp_path / "out").iterdir()) == []


def test_an_out_that_is_a_file_is_named_so(
    fake_recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "notes").write_text("a file", encoding="utf-8")
    assert main(["export", str(fake_recording), "--out", str(tmp_path / "notes")]) == 1
    assert capsys.readouterr().err.endswith(
        "notes: is a file, not a directory; give a new directory\n"
    )
    assert (tmp_path / "notes").read_text(encoding="utf-8") == "a file"


@pytest.mark.parametrize("fmt", ["parquet", "csv"])
def test_a_channel_no_recording_has_is_an_empty_table_with_its_columns(
    fmt: str, fake_recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Every listed table is written: a rig without an arm gives empty robot tables."""
    from test_bad_input import _copy  # noqa: PLC0415 (the bad-input matrix's rewriter)

    armless = _copy(fake_recording, tmp_path / "armless" / "003.mcap", drop_channel=_JOINTS)
    assert read_recording(armless).joints is None
    out = tmp_path / "out"
    assert main(["export", str(armless), "--out", str(out), "--format", fmt]) == 0
    listed = [line.split()[0] for line in capsys.readouterr().out.splitlines()]
    assert listed == [str(out / f"{name}.{fmt}") for name in TABLES]
    assert all(Path(path).is_file() for path in listed)
    read = pl.read_parquet if fmt == "parquet" else pl.read_csv
    joints = read(out / f"joint_states.{fmt}")
    assert joints.height == 0
    assert joints.columns == ["recording", "object_id", "action_id", "trial", "stamp_ns", "phase"]
    assert read(out / f"force.{fmt}").height > 0
