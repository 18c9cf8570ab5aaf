"""Lab rigs through import-bag and the whole replay: a fingertip on a 7-joint arm (batched
vibration, a scalar pressure, one temperature, the lab's own slide actions) and a fixed probe
without an arm (one cell, force and two temperatures, a 5 s static hold)."""

from __future__ import annotations

import json
import sys
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest
from labbags import (
    FINGERTIP_MAP,
    PANDA,
    PROBE_MAP,
    PROBE_SESSION,
    START,
    TIP_SESSION,
    fingertip_messages,
    fingertip_windows_csv,
    probe_messages,
    write_bag,
)

from recorder import load_actions, load_objects
from recorder.bagimport._importer import import_bag
from recorder.bagimport._topicmap import load_topic_map
from replay import read_recording
from replay.cli._main import main as replay
from replay.learning._features import build_features

if TYPE_CHECKING:
    from recorder.bagimport._report import ImportReport


def _import(bag: Path, map_text: str, out: Path, directory: Path) -> ImportReport:
    path = directory / "map.toml"
    path.write_text(map_text, encoding="utf-8")
    return import_bag(
        bag, load_topic_map(path), out, objects=load_objects(), actions=load_actions()
    )


@pytest.fixture(scope="module")
def fingertip(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, ImportReport]:
    directory = tmp_path_factory.mktemp("fingertip")
    messages, store = fingertip_messages(ros1=True)
    bag = write_bag(directory / "tip.bag", "ros1", messages, store)
    (directory / "windows.csv").write_text(fingertip_windows_csv(), encoding="utf-8")
    out = directory / "out"
    return out, _import(bag, FINGERTIP_MAP, out, directory)


@pytest.fixture(scope="module")
def probe(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, ImportReport]:
    directory = tmp_path_factory.mktemp("probe")
    messages, store = probe_messages(ros1=False)
    bag = write_bag(directory / "probe", "mcap", messages, store)
    out = directory / "out"
    return out, _import(bag, PROBE_MAP, out, directory)


def test_fingertip_batched_vibration_has_exact_integer_stamps(
    fingertip: tuple[Path, ImportReport],
) -> None:
    out, report = fingertip
    assert len(report.written) == len(TIP_SESSION.windows())
    obj, action, trial, start, end = TIP_SESSION.windows()[5]
    recording = read_recording(out / obj / action / f"{trial:03d}.mcap")
    assert set(recording.signals) == {"force", "temperature", "acceleration"}
    vibration = recording.skin("acceleration")
    assert vibration.data.shape[1:] == (1, 1)
    # every sample's stamp: its message's stamp + floor(i * 10 ms / 22), within the
    # rounding drift of a block's integer period (at most 0.5 ns per sample of the block)
    messages = np.arange(START, START + 10**12, 10_000_000)
    exact = (messages[:, None] + (np.arange(22) * 10_000_000) // 22).ravel()
    first = int(np.searchsorted(exact, vibration.stamps_ns[0]))
    inside = exact[first : first + vibration.stamps_ns.size]
    assert np.abs(vibration.stamps_ns - inside).max() <= 0.5 * 220 + 1
    assert vibration.stamps_ns[-1] >= exact[np.searchsorted(exact, end) - 1] - 111
    assert report.max_jitter_ns["acceleration"] <= 111
    force = recording.skin("force")
    assert force.data.shape[1:] == (1, 1)
    assert recording.skin("temperature").data.shape[1:] == (1, 1)
    assert recording.joints is not None
    assert recording.joints.position.shape[1] == len(PANDA)
    assert recording.tcp is None
    meta = recording.metadata
    assert (meta.action_id, meta.action_kind, meta.source, meta.seed) == (
        action,
        "slide",
        "import",
        0,
    )
    assert meta.action_parameters["grit" if action == "SL-fast" else "speed_m_s"] > 0
    assert list(recording.phases) == [("execute", start), ("end", end)]
    objects = tomllib.loads((out / "objects.toml").read_text("utf-8"))
    assert objects["sandpaper"] == {
        "name": "Sandpaper P120",
        "description": "glued on a wood block",
        "novel": True,
    }
    saved = json.loads(report.json_path.read_text("utf-8")) if report.json_path else {}
    assert saved["bags"][0]["name"] == "tip.bag"
    assert len(saved["written"]) == len(TIP_SESSION.windows())


def test_probe_without_arm(probe: tuple[Path, ImportReport]) -> None:
    out, report = probe
    assert len(report.written) == len(PROBE_SESSION.windows())
    recording = read_recording(out / "wood" / "hold5" / "001.mcap")
    assert set(recording.signals) == {"force", "temperature"}
    assert recording.skin("temperature").data.shape[1:] == (1, 2)
    assert recording.joints is None
    assert recording.tcp is None
    assert recording.metadata.action_kind == "static"
    assert json.loads(str(recording.metadata.rig["widths"])) == {"force": 1, "temperature": 2}


@pytest.mark.parametrize("rig", ["fingertip", "probe"])
def test_features_of_lab_rigs(rig: str, request: pytest.FixtureRequest) -> None:
    out, report = request.getfixturevalue(rig)
    table = build_features(out, workers=1)
    assert table.quarantined.height == 0
    assert table.frame.height == len(report.written)


def _replay(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    status = replay(argv)
    err = capsys.readouterr().err
    return status, err


ROLES = {
    "fingertip": ("felt,sandpaper", "foam,cork"),
    "probe": ("cold_wood,foam", "wood,aluminium"),
}


@pytest.mark.parametrize("rig", ["fingertip", "probe"])
def test_replay_cli_checks_and_learns_on_lab_rigs(
    rig: str, request: pytest.FixtureRequest, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    out, _ = request.getfixturevalue(rig)
    new, priors = ROLES[rig]
    assert _replay(["check", str(out)], capsys)[0] == 0
    assert _replay(["features", str(out)], capsys)[0] == 0
    for mode in ("prediction", "optimization", "none"):
        argv = ["learn", "--recordings", str(out), "--new", new, "--priors", priors]
        argv += ["--budget", "3", "--transfer", mode, "--out", str(tmp_path / mode)]
        status, err = _replay(argv, capsys)
        assert status == 0, err


@pytest.mark.slow
@pytest.mark.parametrize(
    ("rig", "study"),
    [
        ("fingertip", "fusion"),
        ("fingertip", "transfer"),
        ("fingertip", "negative"),
        ("probe", "fusion"),
        ("probe", "transfer"),
        ("probe", "negative"),
    ],
)
def test_replay_studies_on_lab_rigs(
    rig: str,
    study: str,
    request: pytest.FixtureRequest,
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
) -> None:
    out, _ = request.getfixturevalue(rig)
    argv = ["study", study, "--recordings", str(out), "--quick", "--workers", "1"]
    status, err = _replay([*argv, "--out", str(tmp_path / study)], capsys)
    # a study whose design does not fit the data says so in one line
    assert status == 0 or (status == 1 and err.count("\n") == 1), err


def test_no_simulator_is_loaded_by_an_import() -> None:
    code = (
        "import sys\n"
        "from recorder.bagimport._command import _import_bag\n"
        "from recorder.bagimport._importer import import_bag\n"
        "names = [m for m in sys.modules if m.startswith('recorder._sim') or m == 'scipy.signal']\n"
        "print(sorted(names))\n"
    )
    import subprocess  # noqa: PLC0415

    result = subprocess.run(  # noqa: S603 (this interpreter, a fixed script)
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
        cwd=Path(__file__).parents[2],
    )
    assert result.stdout.strip() == "[]"
