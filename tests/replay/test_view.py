"""``atikt-replay view``: recordings and learn runs logged to rerun (.rrd) and read back."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
import pytest
import rerun as rr
from rerun_frames import nanoseconds, read_rrd
from test_plots import png_size_and_dpi

from replay import MODALITIES, read_recording
from replay.cli._main import main
from replay.learning._run_history import load_run
from replay.outputs._plots import DPI
from replay.outputs._run_figures import plot_run
from replay.outputs._view import log_recordings, new_stream, series_names

RECORDINGS = Path(__file__).parents[2] / "recordings" / "data"
NEW = ("aluminium_plate", "foam_block", "pine_board")
OLD = ("metal_toolbox", "soft_sponge", "wood")
ACTIONS = ("P2", "S2")
KEY = "sponge/S2/003"  # the fake recording: S2 on the sponge, trial 3


@pytest.fixture(scope="module")
def fake_view(fake_recording: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("view") / "view.rrd"
    assert main(["view", str(fake_recording), "--save", str(path)]) == 0
    return path


def test_every_skin_sample_is_a_scalar_on_the_recordings_clock(
    fake_recording: Path, fake_view: Path
) -> None:
    recording = read_recording(fake_recording)
    view = read_rrd(fake_view)
    for modality in MODALITIES:
        series = recording.skin(modality)
        for column, cell in enumerate(series.cell_ids):
            entity = f"/{KEY}/skin/{modality}/cell_{cell}"
            frame = view.temporal[entity]
            assert nanoseconds(frame["log_time"]) == series.stamps_ns.tolist()
            values = np.array(frame["Scalars:scalars"].to_list())
            np.testing.assert_array_equal(values, series.data[:, column, :])
            assert view.static[entity]["SeriesLines:names"] == list(
                series_names(modality, series.data.shape[2])
            )
    # the recording's own clock only: no wall-clock log_time/log_tick from rerun
    assert {name for names in view.timelines.values() for name in names} == {"log_time"}


def test_robot_state_and_phases(fake_recording: Path, fake_view: Path) -> None:
    recording = read_recording(fake_recording)
    view = read_rrd(fake_view)
    assert recording.joints is not None
    assert recording.tcp is not None
    for quantity in ("position", "velocity", "effort"):
        frame = view.temporal[f"/{KEY}/robot/joints/{quantity}"]
        assert nanoseconds(frame["log_time"]) == recording.joints.stamps_ns.tolist()
        expected = getattr(recording.joints, quantity)
        np.testing.assert_array_equal(np.array(frame["Scalars:scalars"].to_list()), expected)
    names = view.static[f"/{KEY}/robot/joints/position"]["SeriesLines:names"]
    assert tuple(names) == recording.joints.names
    tcp = view.temporal[f"/{KEY}/robot/tcp"]
    assert nanoseconds(tcp["log_time"]) == recording.tcp.stamps_ns.tolist()
    translation = np.array([row[0] for row in tcp["Transform3D:translation"].to_list()])
    quaternion = np.array([row[0] for row in tcp["Transform3D:quaternion"].to_list()])
    np.testing.assert_array_equal(translation, recording.tcp.position.astype(np.float32))
    np.testing.assert_array_equal(quaternion, recording.tcp.orientation.astype(np.float32))
    (strip,) = view.static[f"/{KEY}/robot/trajectory"]["LineStrips3D:strips"]
    np.testing.assert_array_equal(np.array(strip), recording.tcp.position.astype(np.float32))
    phases = view.temporal[f"/{KEY}/action/phases"]
    texts = [row[0] for row in phases["TextLog:text"].to_list()]
    assert list(zip(texts, nanoseconds(phases["log_time"]), strict=True)) == list(recording.phases)


def test_object_and_action_are_properties(fake_recording: Path, fake_view: Path) -> None:
    meta = read_recording(fake_recording).metadata
    view = read_rrd(fake_view)
    obj, action = view.static["/__properties/object"], view.static["/__properties/action"]
    assert (obj["id"], obj["name"]) == ([meta.object_id], [meta.object_name])
    assert obj["description"] == [meta.object_description]
    assert (action["id"], action["kind"], action["trial"]) == (["S2"], ["slide"], [3])
    assert action["speed_m_s"] == [meta.action_parameters["speed_m_s"]]
    assert view.static["/__properties/recording"]["key"] == [KEY]


def test_bulk_data_goes_through_the_columnar_api(
    fake_recording: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls: dict[str, list[Any]] = {"log": [], "send_columns": []}
    for name in calls:
        original = getattr(rr.RecordingStream, name)

        def spy(
            self: Any, *args: Any, _name: str = name, _original: Any = original, **kw: Any
        ) -> Any:
            calls[_name].append(kw)
            return _original(self, *args, **kw)

        monkeypatch.setattr(rr.RecordingStream, name, spy)
    recording = read_recording(fake_recording)
    stream = new_stream("test")
    stream.save(tmp_path / "spied.rrd")
    log_recordings(stream, [recording])
    stream.disconnect()
    cells = recording.skin("force").data.shape[1]
    assert len(calls["send_columns"]) == len(MODALITIES) * cells + 3 + 1 + 1
    assert all(kw.get("static") for kw in calls["log"])  # only names, axes, path: static
    samples = sum(recording.skin(m).stamps_ns.size for m in MODALITIES)
    assert len(calls["log"]) < 50 < samples


def test_several_recordings_each_under_its_own_key(
    fake_recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    dataset = tmp_path / "data"
    for name in ("a", "b"):
        (dataset / name).mkdir(parents=True)
        shutil.copy(fake_recording, dataset / name / fake_recording.name)
    rrd = tmp_path / "two.rrd"
    assert main(["view", str(dataset), "--save", str(rrd)]) == 0
    assert str(rrd) in capsys.readouterr().out
    view = read_rrd(rrd)
    assert view.static["/__properties/recording"]["key"] == [KEY, f"{KEY}-2"]
    assert f"/{KEY}-2/skin/force/cell_0" in view.temporal


def test_view_refuses_bad_arguments_in_one_line(
    tmp_path: Path, fake_recording: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["view", str(tmp_path / "missing.mcap"), "--save", str(tmp_path / "x.rrd")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("atikt-replay: error: ")
    assert err.count("\n") == 1
    both = ["view", str(fake_recording), "--save", str(tmp_path / "x.rrd"), "--serve"]
    assert main(both) == 1
    assert "choose one" in capsys.readouterr().err
    assert main(["view", str(tmp_path), "--save", str(tmp_path / "x.rrd")]) == 1
    assert "no recordings" in capsys.readouterr().err


# ------------------------------------------------------------------------------ learning runs


@pytest.fixture(scope="module")
def learn_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A short real learn run over the committed recordings (P2, S2; budget 4)."""
    root = tmp_path_factory.mktemp("learn")
    for obj in (*NEW, *OLD):
        for action in ACTIONS:
            for source in sorted((RECORDINGS / obj / action).glob("*.mcap")):
                target = root / "data" / obj / action / source.name
                target.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy(source, target)
    run = root / "run"
    argv = ["learn", "--recordings", str(root / "data"), "--new", ",".join(NEW)]
    argv += ["--priors", ",".join(OLD), "--actions", ",".join(ACTIONS), "--budget", "4"]
    argv += ["--seed", "1", "--out", str(run), "--workers", "1"]
    assert main(argv) == 0
    return run


def test_learn_run_labels_of_the_entropy_map(learn_run: Path) -> None:
    run = load_run(learn_run)
    assert run.actions == ACTIONS
    assert len(run.objects) == len(NEW)
    for index, label in enumerate(run.objects):
        assert label in {NEW[index], f"object {index}"}
    chosen = set(run.decisions["object"].to_list())
    assert chosen <= set(run.objects)


def test_label_inference_matches_the_decisions_uncertainty(tmp_path: Path) -> None:
    maps = [[[0.9, 0.8, 0.7], [0.6, 0.5, 0.4]], [[0.9, 0.3, 0.7], [0.6, 0.5, 0.4]]]
    frame = pl.DataFrame(
        {
            "step": [0, 1, 2],
            "object": ["", "b", "c"],
            "action": ["", "X", "Y"],
            "explored": [False, False, True],
            "prior": ["", "", ""],
            "rho": [None, 0.0, 0.0],
            "accuracy": [0.5, 0.6, 0.7],
            "accuracy_X": [0.5, 0.6, 0.7],
            "accuracy_Y": [0.5, 0.6, 0.7],
            "uncertainty": [None, 0.8, 0.4],
            "entropies": [None, *maps],
        }
    )
    frame.write_parquet(tmp_path / "history.parquet")
    run = load_run(tmp_path)
    assert run.actions == ("X", "Y")
    assert run.objects == ("object 0", "b", "c")


def test_learn_run_in_rerun_on_the_step_timeline(learn_run: Path, tmp_path: Path) -> None:
    rrd = tmp_path / "run.rrd"
    assert main(["view", str(learn_run), "--save", str(rrd), "--no-figures"]) == 0
    history = pl.read_parquet(learn_run / "history.parquet").sort("step")
    view = read_rrd(rrd, index="step")
    accuracy = view.temporal["/run/accuracy/all"]
    assert accuracy["step"].to_list() == history["step"].to_list()
    assert [v[0] for v in accuracy["Scalars:scalars"].to_list()] == history["accuracy"].to_list()
    decisions = history.filter(pl.col("step") > 0)
    texts = [row[0] for row in view.column("/run/decisions", "TextLog:text")]
    for text, row in zip(texts, decisions.iter_rows(named=True), strict=True):
        assert text.startswith(f"{row['object']} {row['action']} (")
        assert ("prior " + row["prior"] in text) == bool(row["prior"])
    rho = [v[0] for v in view.column("/run/rho", "Scalars:scalars")]
    assert rho == decisions["rho"].to_list()
    assert view.timelines["/run/entropy/map"] == {"step"}  # no wall-clock timeline
    tensors = view.column("/run/entropy/map", "Tensor:data")
    for tensor, expected in zip(tensors, decisions["entropies"].to_list(), strict=True):
        (cell,) = tensor
        assert cell["shape"] == [len(ACTIONS), len(NEW)]
        assert cell["names"] == ["action", "object"]
        np.testing.assert_array_equal(np.array(cell["buffer"]).reshape(2, 3), expected)
    for row in decisions.iter_rows(named=True):
        for modality, weight in zip(row["modalities"], row["weights"], strict=True):
            frame = view.temporal[f"/run/weights/{modality}"]
            values = frame.filter(pl.col("step") == row["step"])["Scalars:scalars"].to_list()
            assert values == [[weight]]
    props = view.static["/__properties/run"]
    assert props["actions"] == list(ACTIONS)
    assert props["final_accuracy"] == [history["accuracy"][-1]]


def test_learn_run_figures_are_pngs_and_reproducible(learn_run: Path, tmp_path: Path) -> None:
    assert main(["view", str(learn_run), "--save", str(tmp_path / "run.rrd")]) == 0
    names = ("accuracy.png", "decisions.png", "weights.png", "entropy.png")
    for name in names:
        assert (learn_run / "figures" / name).read_bytes().startswith(b"\x89PNG")
    again = plot_run(load_run(learn_run), tmp_path / "again")
    for path in again:
        assert path.read_bytes() == (learn_run / "figures" / path.name).read_bytes()
        width, _, dpi = png_size_and_dpi(path)
        assert dpi == pytest.approx(DPI, abs=0.5)
        assert width >= 1000


def test_save_never_overwrites_without_force(fake_recording: Path, tmp_path: Path) -> None:
    target = tmp_path / "view.rrd"
    target.write_bytes(b"an earlier view")
    assert main(["view", str(fake_recording), "--save", str(target)]) == 1
    assert target.read_bytes() == b"an earlier view"
    assert main(["view", str(fake_recording), "--save", str(target), "--force"]) == 0
    assert target.read_bytes() != b"an earlier view"
    assert read_rrd(target).static  # a complete view
    assert [p.name for p in tmp_path.iterdir()] == ["view.rrd"]  # no temporary file left
