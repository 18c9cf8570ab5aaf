"""What identifies a live learning run (its rig configuration, its priors); what refusals leave.

Live runs on the closed-form simulator (``rig = "sim"``, in-process) with the smallest plan:
one action, one held-out trial, budgets of 0 to 2.
"""

from __future__ import annotations

import json
import shutil
import socket
from typing import TYPE_CHECKING

import pytest
from conftest import NEW

from replay.cli._main import _only_incomplete, main

if TYPE_CHECKING:
    from pathlib import Path

#: The smallest live plan: one action, one held-out trial.
PLAN = ["--actions", "P1", "--new", ",".join(NEW[:2]), "--test-trials", "1", "--workers", "1"]


def _learn(dataset: Path, out: Path, *extra: str) -> list[str]:
    """Return a live learn command line into ``out``."""
    return ["learn", "--recordings", str(dataset), *PLAN, "--out", str(out), *extra]


def _sim_config(path: Path, room_c: str) -> Path:
    """Write a rig configuration of the simulator with ``room_c``; return its path."""
    path.write_text(f'rig = "sim"\n[options]\nroom_c = {room_c}\n', encoding="utf-8")
    return path


def _recordings(out: Path) -> list[Path]:
    """Return a live run's recordings."""
    return sorted((out / "session").glob("*/*/*.mcap"))


def test_a_resumed_live_run_refuses_an_edited_rig_configuration(
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config, out = _sim_config(tmp_path / "rig.toml", "22.5"), tmp_path / "live"
    assert main([*_learn(small_dataset, out, "--budget", "0"), "--rig-config", str(config)]) == 0
    made = _recordings(out)
    capsys.readouterr()
    _sim_config(config, "21.0")  # the same file, edited: another rig configuration
    assert main([*_learn(small_dataset, out, "--budget", "1"), "--rig-config", str(config)]) == 1
    assert capsys.readouterr().err == (
        f"atikt-replay: error: {out}: holds a live run of another rig configuration "
        "(rig.room_c='22.5' (now '21.0')); give another --out\n"
    )
    assert _recordings(out) == made  # nothing recorded with the other configuration


def test_a_live_run_resumes_with_its_configuration_named_another_way(
    small_dataset: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.chdir(tmp_path)
    config, out = _sim_config(tmp_path / "rig.toml", "22.5"), tmp_path / "live"
    assert main([*_learn(small_dataset, out, "--budget", "0"), "--rig-config", "rig.toml"]) == 0
    capsys.readouterr()
    assert main([*_learn(small_dataset, out, "--budget", "1"), "--rig-config", str(config)]) == 0
    assert "step  1" in capsys.readouterr().out


def test_a_live_run_resumes_with_a_moved_copy_of_its_priors_and_refuses_changed_ones(
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out, moved = tmp_path / "live", tmp_path / "moved"
    assert main([*_learn(small_dataset, out, "--budget", "0"), "--rig", "sim"]) == 0
    shutil.copytree(small_dataset, moved, ignore=shutil.ignore_patterns(".*"))
    capsys.readouterr()
    assert main([*_learn(moved, out, "--budget", "1"), "--rig", "sim"]) == 0  # the same priors
    assert json.loads((out / "live.json").read_text("utf-8"))["priors"]["dataset"] == str(moved)
    prior = min(p for p in moved.glob("*/P1/*.mcap") if p.parts[-3] not in NEW[:2])
    prior.unlink()  # a prior object's recording less: other priors
    capsys.readouterr()
    assert main([*_learn(moved, out, "--budget", "2"), "--rig", "sim"]) == 1
    assert capsys.readouterr().err == (
        f"atikt-replay: error: {out}: holds a live run of another priors dataset "
        f"(priors='{moved}' (changed since: the prior objects' recordings differ)); give the "
        f"priors {moved} to continue it, or another --out\n"
    )
    assert main([*_learn(small_dataset, out, "--budget", "2"), "--rig", "sim"]) == 0


def test_a_larger_budget_is_no_conflict_beside_a_real_one(tmp_path: Path) -> None:
    from replay.errors import ReplayError  # noqa: PLC0415
    from replay.live import check_live_run, claim_live_run  # noqa: PLC0415

    def settings(budget: int, trials: int) -> dict[str, object]:
        return {"rig": {"kind": "simulated"}, "learner": {"budget": budget}, "test_trials": trials}

    target = tmp_path / "run"
    assert claim_live_run(target, settings(2, 1)) is False
    with pytest.raises(ReplayError) as refused:
        check_live_run(target, settings(3, 2))
    assert str(refused.value) == (
        f"{target}: holds a live run of other settings (test_trials=1 (now 2)); give another --out"
    )
    with pytest.raises(ReplayError) as smaller:
        check_live_run(target, settings(1, 2))
    assert "learner.budget=2 (now 1), test_trials=1 (now 2)" in str(smaller.value)


def _ur_config(path: Path) -> Path:
    """Write a UR rig configuration with a pose for wood only (nothing listens on its ports)."""
    path.write_text(
        'rig = "ur"\n[options]\nhost = "127.0.0.1"\nrtde_port = 9\nscript_port = 7\n'
        "dashboard_port = 0\n[objects.wood]\npose = [-0.7, -0.2, 0.15, 0.0, 3.14159, 0.0]\n"
        '[skin]\ntransport = "udp"\nbind = "127.0.0.1:0"\ncells = 1\n'
        "[skin.header]\nmagic = [0xAA]\n[skin.frames.f]\nrate_hz = 250\n"
        'sequence = { at = 1, type = "u16" }\n[skin.frames.f.force]\nat = 3\ntype = "u16"\n'
        "count = 1\nscale = 0.001\n",
        encoding="utf-8",
    )
    return path


def test_a_live_run_refused_for_a_missing_pose_leaves_no_claim_and_names_the_file(
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config, out = _ur_config(tmp_path / "rig.toml"), tmp_path / "live"
    argv = ["learn", "--recordings", str(small_dataset), "--new", "wood,foam_block"]
    argv += ["--actions", "P1", "--test-trials", "1", "--workers", "1", "--budget", "0"]
    assert main([*argv, "--rig-config", str(config), "--out", str(out)]) == 1
    assert capsys.readouterr().err == (
        f"atikt-replay: error: {config}: the rig has no pose for foam_block: live learning "
        "presents every new object by itself; give each a pose ([objects.foam_block] pose in "
        f"{config})\n"
    )
    assert not out.exists()  # no live.json to refuse the corrected command


def test_a_live_run_refused_for_a_foxglove_address_in_use_leaves_no_claim(
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("foxglove")
    out = tmp_path / "live"
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        address = f"127.0.0.1:{taken.getsockname()[1]}"
        argv = [*_learn(small_dataset, out, "--budget", "0"), "--rig", "sim"]
        assert main([*argv, "--foxglove", address]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert address in err
    assert not out.exists()


def test_an_unknown_object_names_the_dataset_and_the_closest_name(
    small_dataset: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["learn", "--recordings", str(small_dataset), "--new", "foam_blok"]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.startswith("atikt-replay: error: --new foam_blok: not in the dataset; it has ")
    assert err.endswith(f" ({small_dataset}); did you mean foam_block?\n")
    # a live run records its new objects (they need not be in the dataset): the catalog
    # names them, and the closest
    argv += ["wood,foam_blok", "--rig", "sim-ur10"]
    argv.remove("foam_blok")
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert "--new foam_blok: not in the catalog, so the rig cannot perform it" in err, err
    assert err.endswith("; did you mean foam_block?\n"), err


def test_check_of_a_live_session_says_the_learn_command_resumes(tmp_path: Path) -> None:
    run = tmp_path / "live"
    (run / "session").mkdir(parents=True)
    (run / "live.json").write_text("{}", encoding="utf-8")
    said = _only_incomplete(run / "session", 1)
    assert said.endswith(f"(the same live learn command resumes, with --out {run})")
    assert _only_incomplete(tmp_path, 1).endswith("(the same session command resumes)")


def test_an_offline_replay_of_an_unfinished_live_run_says_how_to_go_on(
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "live"
    assert main([*_learn(small_dataset, out, "--budget", "0"), "--rig", "sim"]) == 0
    live = json.loads((out / "live.json").read_text("utf-8"))
    live["learner"]["budget"] = 3  # continued with --budget 3, stopped before its step 1
    (out / "live.json").write_text(json.dumps(live), encoding="utf-8")
    capsys.readouterr()
    session = out / "session"
    offline = ["learn", "--recordings", str(small_dataset), "--session", str(session), *PLAN]
    assert main([*offline, "--budget", "3", "--out", str(tmp_path / "offline")]) == 1
    assert capsys.readouterr().err == (
        f"atikt-replay: error: {session}: the live run in {out} is unfinished (it made step 0 "
        f"only of its budget of 3); continue it with its live command (learn --rig or "
        f"--rig-config as before, --out {out}), or replay only the steps it made with "
        "--budget 0\n"
    )
    assert main([*offline, "--budget", "0", "--out", str(tmp_path / "offline")]) == 0
