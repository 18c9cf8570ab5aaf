"""Live learning on a plug-in rig (exclusive hardware), its live view, and its offline replay."""

import json
import os
from pathlib import Path

import pytest
from conftest import NEW
from rerun_frames import temporal_entities

from recorder import RigConfig, RigPlugin, SimulatedRig, refuse_sections
from recorder import _rigconfig as rigconfig
from recorder._cli import main as record
from replay.cli._main import main
from schemas import SourceStats

PROCESSES: list[int] = []


class _TracedSim(SimulatedRig):
    def perform(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        PROCESSES.append(os.getpid())
        return super().perform(*args, **kwargs)


def build_lab_rig(seed: int, config: RigConfig) -> SimulatedRig:
    refuse_sections(config)
    return _TracedSim(seed)


LAB_RIG = RigPlugin(build_lab_rig, exclusive=True, description="the simulator as exclusive rig")


@pytest.fixture(autouse=True)
def lab_rig(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(rigconfig._BUILDERS, "lab", LAB_RIG)
    PROCESSES.clear()


@pytest.mark.slow(11)
def test_live_learning_on_an_exclusive_plugin_rig_replays_offline_with_the_same_steps(
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = tmp_path / "lab.toml"
    config.write_text('rig = "lab"\n')
    common = ["--recordings", str(small_dataset), "--budget", "2", "--actions", "P1,S2"]
    common += ["--new", ",".join(NEW), "--workers", "2", "--seed", "4"]
    live_out, replay_out, view = tmp_path / "live", tmp_path / "replay", tmp_path / "live.rrd"
    argv = ["learn", "--rig-config", str(config), *common, "--test-trials", "1"]
    assert main([*argv, "--out", str(live_out), "--view", str(view)]) == 0
    live = capsys.readouterr().out.splitlines()
    assert [os.getpid()] * (len(NEW) * 2 * 2 + 2) == PROCESSES  # test, initial, asked

    session = live_out / "session"
    assert main(["learn", "--session", str(session), *common, "--out", str(replay_out)]) == 0
    replay = capsys.readouterr().out.splitlines()
    steps = [line for line in live if line.startswith("step")]
    assert len(steps) == 3
    assert steps == [line for line in replay if line.startswith("step")]

    shown = temporal_entities(view)
    recorded = sorted(
        p.relative_to(session).with_suffix("").as_posix() for p in session.rglob("*.mcap")
    )
    files = {e for e in shown if e.count("/") >= 3 and not e.startswith("/live/")}
    keys = sorted({"/".join(e.split("/")[1:4]) for e in files})
    assert keys == recorded  # every file, logged once written
    streamed = {e for e in shown if e.startswith("/live/")}
    assert sorted({"/".join(e.split("/")[2:5]) for e in streamed}) == recorded  # and live
    assert any("/skin/" in e for e in streamed)
    assert len(recorded) == len(NEW) * 2 * 2 + 2


def test_view_and_dry_run_need_a_live_run(
    small_dataset: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["learn", "--recordings", str(small_dataset), "--view", "x.rrd", "--workers", "1"]
    assert main(argv) == 1
    err = capsys.readouterr().err.splitlines()
    assert err == [
        "atikt-replay: error: --view shows a live run's recordings as they are made; give --rig too"
    ]
    argv = ["learn", "--recordings", str(small_dataset), "--dry-run", "--workers", "1"]
    assert main(argv) == 1
    err = capsys.readouterr().err.splitlines()
    assert err == [
        "atikt-replay: error: --dry-run checks a live run before anything moves; give --rig too"
    ]


def test_live_learning_says_which_recordings_lost_samples(
    small_dataset: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # the rig's first recording lost samples: learned from all the same, and said, once
    lossy = SourceStats("skin", "counter", expected=100, received=98, missing=2)
    said = iter([[lossy]])

    class _Lossy(_TracedSim):  # a class of its own: the Accounting protocol's isinstance
        def source_stats(self) -> list[SourceStats]:  # check caches its answer per class
            return next(said, [])

    def build_lossy(seed: int, config: RigConfig) -> SimulatedRig:
        refuse_sections(config)
        return _Lossy(seed)

    monkeypatch.setitem(rigconfig._BUILDERS, "lab", RigPlugin(build_lossy, exclusive=True))
    config = tmp_path / "lab.toml"
    config.write_text('rig = "lab"\n')
    argv = ["learn", "--rig-config", str(config), "--recordings", str(small_dataset)]
    argv += ["--budget", "1", "--actions", "P1", "--new", ",".join(NEW), "--workers", "1"]
    assert main([*argv, "--test-trials", "1", "--out", str(tmp_path / "live")]) == 0
    err = [line for line in capsys.readouterr().err.splitlines() if "lost samples" in line]
    assert len(err) == 1
    assert err[0].endswith("live sources lost samples (skin: 2 of 100 missing); check fails on it")


def test_a_live_runs_directory_is_checked_without_writing_and_refused_by_its_leaf(
    tmp_path: Path,
) -> None:
    from replay.errors import ReplayError  # noqa: PLC0415
    from replay.live import check_live_run, claim_live_run  # noqa: PLC0415

    target = tmp_path / "run"
    settings = {"rig": "sim", "learner": {"budget": 2, "transfer": {"name": "prediction"}}}
    assert check_live_run(target, settings) is False  # a new run
    assert not target.exists()  # and nothing written by the check
    assert claim_live_run(target, settings) is False
    assert check_live_run(target, settings) is True  # it resumes
    assert claim_live_run(target, settings) is True
    other = {"rig": "sim", "learner": {"budget": 2, "transfer": {"name": "density"}}}
    with pytest.raises(ReplayError) as refused:
        check_live_run(target, other)
    assert str(refused.value) == (
        f"{target}: holds a live run of other settings (learner.transfer.name='prediction' "
        "(now 'density')); give another --out"
    )
    (target / "history.parquet").write_bytes(b"")
    with pytest.raises(ReplayError, match="this live run is finished"):
        check_live_run(target, settings)  # its budget unknown (no run.json): finished


def test_a_larger_budget_continues_a_live_run_and_a_smaller_one_is_refused(
    tmp_path: Path,
) -> None:
    from replay.errors import ReplayError  # noqa: PLC0415
    from replay.live import check_live_run, claim_live_run  # noqa: PLC0415

    def budget(steps: int) -> dict[str, object]:
        return {"rig": "sim", "learner": {"budget": steps, "transfer": {"name": "prediction"}}}

    target = tmp_path / "run"
    assert claim_live_run(target, budget(2)) is False
    (target / "history.parquet").write_bytes(b"")  # finished, with budget 2
    (target / "run.json").write_text(json.dumps(budget(2)), encoding="utf-8")
    with pytest.raises(ReplayError) as finished:
        check_live_run(target, budget(2))
    assert str(finished.value) == (
        f"{target}: this live run is finished (history.parquet); give a larger --budget to "
        "continue it (its steps are reused), or another --out"
    )
    assert check_live_run(target, budget(3)) is True  # continues: says so, writes nothing
    assert json.loads((target / "live.json").read_text(encoding="utf-8")) == budget(2)
    assert claim_live_run(target, budget(3)) is True
    assert json.loads((target / "live.json").read_text(encoding="utf-8")) == budget(3)
    # interrupted before its history was written again: the same command resumes it
    assert claim_live_run(target, budget(3)) is True
    with pytest.raises(ReplayError) as smaller:
        check_live_run(target, budget(2))
    assert str(smaller.value) == (
        f"{target}: holds a live run of other settings (learner.budget=3 (now 2)); give "
        "--budget 3 or more to continue it, or another --out"
    )


def test_a_killed_live_runs_unfinished_file_is_said_by_the_dry_run_then_set_aside(
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["learn", "--rig", "sim", "--recordings", str(small_dataset), "--budget", "0"]
    argv += ["--actions", "P1", "--new", ",".join(NEW), "--workers", "1", "--test-trials", "1"]
    out = tmp_path / "live"
    assert main([*argv, "--out", str(out)]) == 0
    capsys.readouterr()
    (out / "history.parquet").unlink()  # as if killed before its end: it resumes
    dead = 2**22 + 7  # above the default pid_max: no such process
    part = out / "session" / NEW[0] / "P1" / f"002.{dead}-ab12.mcap.part"
    part.write_bytes(b"what a killed recorder left")
    assert main([*argv, "--out", str(out), "--dry-run"]) == 0
    said = capsys.readouterr().out.splitlines()
    assert (
        said[1] == f"1 unfinished recordings of stopped recorders would be set aside (e.g. {part})"
    )
    assert part.exists()  # the dry run moves nothing
    assert main([*argv, "--out", str(out)]) == 0
    err = capsys.readouterr().err
    aside = out / "session" / ".incomplete" / NEW[0] / "P1" / part.name
    assert f"unfinished recording of a stopped recorder set aside: {aside}" in err
    assert not part.exists()
    assert aside.read_bytes() == b"what a killed recorder left"


@pytest.mark.slow(3)
def test_a_session_shows_its_signals_in_rerun_as_learn_does(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    out, view = tmp_path / "lab", tmp_path / "session.rrd"
    argv = ["session", "--rig", "sim-ur10", "--rig-option", "time_scale=0.2", "--yes"]
    argv += ["--objects", "wood", "--actions", "P1", "--trials", "1", "--out", str(out)]
    assert record([*argv, "--view", str(view)]) == 0
    shown = temporal_entities(view)
    streamed = {e for e in shown if e.startswith("/live/")}
    assert {"/".join(e.split("/")[2:5]) for e in streamed} == {"wood/P1/001"}  # as it came
    assert any("/skin/" in e for e in streamed)
    files = {e for e in shown if e.count("/") >= 3 and not e.startswith("/live/")}
    assert {"/".join(e.split("/")[1:4]) for e in files} == {"wood/P1/001"}  # once written
    capsys.readouterr()

    assert record([*argv, "--trials", "2", "--view", str(view)]) == 1  # never overwritten
    assert f"--view {view}: exists, and files are never overwritten" in capsys.readouterr().err
    assert record([*argv, "--view", "--dry-run"]) == 1
    assert "a dry run records nothing to show" in capsys.readouterr().err

    # no display (a server, ssh): one line, and the view goes beside the dataset
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert record([*argv, "--trials", "2", "--view"]) == 0
    fallback = tmp_path / "lab.live.rrd"
    assert f"--view: no display here; the live view is written to {fallback}" in (
        capsys.readouterr().err
    )
    assert {"/".join(e.split("/")[2:5]) for e in temporal_entities(fallback) if "/live/" in e} == {
        "wood/P1/002"
    }


def test_live_learning_refuses_an_action_its_skin_cannot_record_before_anything_moves(
    tmp_path: Path,
) -> None:
    from recorder import load_rig_config  # noqa: PLC0415
    from replay.errors import ReplayError  # noqa: PLC0415
    from replay.learning._session import RunSpec  # noqa: PLC0415
    from replay.live._run import learn_live  # noqa: PLC0415

    # a 1-cell force-only skin; nothing listens on its ports: a connection would fail otherwise
    config = tmp_path / "rig1.toml"
    config.write_text(
        'rig = "ur"\n[options]\nhost = "127.0.0.1"\nrtde_port = 9\nscript_port = 7\n'
        "dashboard_port = 0\n[objects.wood]\npose = [-0.7, -0.2, 0.15, 0.0, 3.14159, 0.0]\n"
        "[objects.foam_block]\npose = [-0.55, -0.2, 0.15, 0.0, 3.14159, 0.0]\n"
        '[skin]\ntransport = "udp"\nbind = "127.0.0.1:0"\ncells = 1\n'
        "[skin.header]\nmagic = [0xAA]\n[skin.frames.f]\nrate_hz = 250\n"
        'sequence = { at = 1, type = "u16" }\n[skin.frames.f.force]\nat = 3\ntype = "u16"\n'
        "count = 1\nscale = 0.001\n"
    )
    spec = RunSpec(new_objects=("wood", "foam_block"), prior_objects=(), actions=("P1", "S1"))
    session = tmp_path / "live" / "session"
    with pytest.raises(ReplayError) as refused:
        learn_live(load_rig_config(config), spec, None, session, test_trials=1, on_step=print)
    assert str(refused.value) == (
        f"--rig ur: {config}: [skin] delivers force only, and a 'slide' action (S1) needs the "
        "skin modality acceleration: leave S1 out of --actions, or describe what they need in "
        "[skin] if the skin has it"
    )
    assert not session.exists()  # refused before the run's directory, let alone a motion
