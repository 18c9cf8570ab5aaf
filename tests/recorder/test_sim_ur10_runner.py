"""The simulated UR10 under the action runner (``--rig sim-ur10``): the virtual lab in-process.

The runner, the UR driver's programs and the UDP skin's parsing are the robot's; only the wires
are replaced and the clock is simulated. So these tests are deterministic and do not depend on
the machine's load: a session's files are byte-identical from run to run, and a stop's latency
is counted in controller cycles exactly.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from ur_lab import program_kind

from recorder import (
    ActionStoppedError,
    load_actions,
    load_objects,
    plan_dataset,
    record_action,
    rig_factory,
)
from recorder._cli import main
from recorder._rigconfig import find_rig, load_rig_config
from recorder._session import run_session
from recorder.errors import RecorderError
from recorder.runner import _runner as runner_module
from recorder.virtuallab import SimUR10Rig
from recorder.virtuallab._stepped import START_NS
from replay import read_recording
from replay.cli._main import main as replay_main

OBJECTS, ACTIONS = load_objects(), load_actions()
#: Worlds move five times faster than the simulated clock: a press takes ~2 s of it.
FAST = "time_scale=0.2"
EXAMPLE = Path(__file__).resolve().parents[2] / "recorder/data/ur_rig.example.toml"


def _rig(*options: str, seed: int = 0) -> SimUR10Rig:
    rig = find_rig("sim-ur10").build(seed, load_rig_config(None, "sim-ur10", options))
    assert isinstance(rig, SimUR10Rig)
    return rig


@pytest.mark.slow(5)
def test_a_session_is_byte_identical_run_to_run_and_valid(tmp_path: Path) -> None:
    def session(out: Path) -> None:
        args = ["session", "--rig", "sim-ur10", "--rig-option", FAST, "--yes"]
        args += ["--objects", "wood,foam_block", "--actions", "P1,S1", "--trials", "1"]
        assert main([*args, "--out", str(out)]) == 0

    session(tmp_path / "a")
    session(tmp_path / "b")
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*.mcap"))
    assert len(files) == 4
    for name in files:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    assert replay_main(["check", str(tmp_path / "a")]) == 0
    recording = read_recording(tmp_path / "a" / "foam_block" / "P1" / "001.mcap")
    assert recording.metadata.rig["kind"] == "sim-ur10"
    assert recording.tcp is not None
    # presented at the example configuration's pose for foam_block: x -0.55
    assert abs(float(recording.tcp.position[0, 0]) + 0.55) < 1e-3


@pytest.mark.slow(3)
def test_a_dataset_holds_one_way_of_moving_the_arm(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    def session(*options: str, trials: int = 1) -> int:
        args = ["session", "--rig", "sim-ur10", "--yes", "--objects", "wood", "--actions", "P1"]
        for option in (FAST, *options):
            args += ["--rig-option", option]
        return main([*args, "--trials", str(trials), "--out", str(tmp_path)])

    assert session() == 0
    recorded = read_recording(tmp_path / "wood" / "P1" / "001.mcap").metadata.rig
    assert recorded["motion.press_m_s"] == "0.005", recorded
    capsys.readouterr()
    # a slower press shapes the force signals: not resumed into this dataset
    assert session("press_m_s=0.004", trials=2) != 0
    said = capsys.readouterr().err
    assert "another rig configuration (motion.press_m_s='0.005'; this run: " in said, said
    assert "motion.press_m_s='0.004'" in said, said
    assert not (tmp_path / "wood" / "P1" / "002.mcap").exists()
    # how far the approach may go bounds it, as the limits do: resumed
    assert session("approach_limit_m=0.3", trials=2) == 0
    assert (tmp_path / "wood" / "P1" / "002.mcap").exists()


@pytest.mark.slow(12)
def test_over_fifty_actions_every_action_starts_where_the_first_did(tmp_path: Path) -> None:
    obj = OBJECTS["wood"]
    starts = []
    with _rig("time_scale=0.1") as rig:  # ten times faster: no reaction time is lost here
        assert rig.present(obj)
        for trial in range(1, 51):
            path = tmp_path / f"{trial:03d}.mcap"
            record_action(rig, obj, ACTIONS["P1"], trial, path, seed=0)
            tcp = read_recording(path).tcp
            assert tcp is not None
            starts.append(float(tcp.position[0, 2]))
    off = [(trial, z) for trial, z in enumerate(starts, 1) if abs(z - starts[0]) >= 1e-3]
    assert not off, f"first start z {starts[0]:.6f}; trials off by 1 mm: {off}"
    assert abs(np.median(starts[-10:]) - np.median(starts[:10])) < 2e-4  # no sinking
    assert replay_main(["check", str(tmp_path)]) == 0


def test_a_force_limit_stops_the_arm_in_the_cycle_after_the_sample_that_broke_it(
    tmp_path: Path,
) -> None:
    # the press to 1 mm into the rigid block needs more than 2 N: the limit ends it
    rig = _rig(FAST)
    rig.limits = dataclasses.replace(rig.limits, max_force_n=2.0)
    with rig:
        assert rig.present(OBJECTS["wood"])
        with pytest.raises(ActionStoppedError, match="force"):
            record_action(rig, OBJECTS["wood"], ACTIONS["P1"], 1, tmp_path / "001.mcap", seed=0)
        cause_ns, sent_ns, why = rig.stops_sent[-1]
        # the stop goes out before the clock moves again: within the cycle of the cause
        assert "force" in why
        assert 0 <= sent_ns - cause_ns < rig.arm.period_ns
        # the arm is still within its deceleration (5 mm/s at 0.5 m/s^2: 10 ms, 2 cycles)
        speeds = [float(np.abs(s.qd).max()) for _ in range(3) for s in rig.arm.poll(1.0)]
        assert speeds[-1] < 1e-6, speeds
        # the controller runs the stopl from the cycle after the cause's
        stop = rig.lab.world.events("program")[-1]
        assert stop.details["calls"][-1] == "stopl"
        assert 0 < stop.controller_ns - (cause_ns - START_NS) <= rig.arm.period_ns
    assert (tmp_path / "001.incomplete.mcap").stat().st_size > 0
    assert not (tmp_path / "001.mcap").exists()


def test_without_a_configuration_the_example_is_used_and_a_ros2_skin_is_refused(
    tmp_path: Path,
) -> None:
    rig = _rig()
    assert rig.where.endswith("ur_rig.example.toml")
    assert rig.can_present(OBJECTS["book"])  # every catalog object: the default pose
    text = EXAMPLE.read_text("utf-8")
    ros2 = text[: text.index("\n[skin]\n")] + '\n[skin]\ntransport = "ros2"\n'
    (tmp_path / "ros2.toml").write_text(ros2, "utf-8")
    with pytest.raises(RecorderError, match=r"transport = 'ros2'.*serve-sim --ros2"):
        find_rig("sim-ur10").build(0, load_rig_config(tmp_path / "ros2.toml", "sim-ur10"))


def test_the_seed_draws_the_skin_and_is_part_of_the_rigs_identity(tmp_path: Path) -> None:
    forces = []
    for seed in (0, 1):
        with _rig(FAST, seed=seed) as rig:
            assert rig.describe()["seed"] == str(seed)
            rig.present(OBJECTS["wood"])
            path = tmp_path / f"{seed}.mcap"
            record_action(rig, OBJECTS["wood"], ACTIONS["P1"], 1, path, seed=seed)
        skin = read_recording(path).skin("force")
        forces.append(np.asarray(skin.data[:200], dtype=np.float64))
    assert not np.array_equal(forces[0], forces[1])


@pytest.mark.parametrize("pause", ["on", "off"])
def test_a_skin_stalled_at_the_approach_pauses_the_arm_instead_of_pressing_on(
    tmp_path: Path, pause: str
) -> None:
    # the skin's frames are held for 1 s once the arm is 2.5 mm above the block (a transport
    # that stalls, a loaded recorder): without the pause the arm runs on into the rigid block,
    # 8 mm deep, to the edge of the force limit; with it, the action is as without the stall
    guarded = pause == "on"
    options = [FAST, "silence_s=2"] + ([] if guarded else ["approach_blind_m=1"])
    rig = _rig(*options)
    lab, step = rig.lab, rig.lab.step
    armed = [True]

    def stepping() -> int:
        now = step()
        if armed[0] and lab.world.robot_at(now).tcp_pose[2] < 0.1325:  # the face: z 0.13
            armed[0] = False
            lab.link.hold_until_ns = lab.clock.now_ns() + 1_000_000_000
        return now

    lab.step = stepping  # type: ignore[method-assign]
    path = tmp_path / "001.mcap"
    with rig:
        assert rig.present(OBJECTS["wood"])
        stopped = ""
        try:
            record_action(rig, OBJECTS["wood"], ACTIONS["P1"], 1, path, seed=0)
        except ActionStoppedError as err:
            stopped = str(err)
    if stopped:  # the unguarded arm may reach the force limit
        assert not guarded
        assert "max_force_n" in stopped
        return
    assert not armed[0]  # the stall happened
    recording = read_recording(path)
    assert recording.tcp is not None
    deepest = float(recording.tcp.position[:, 2].min())
    if not guarded:
        assert deepest < 0.13 - 0.005
        return
    # as deep as a press without a stall: 1 mm past the light contact at the face
    assert deepest > 0.13 - 0.0015
    assert float(recording.skin("force").data.sum(axis=(1, 2)).max()) < 4.0


@pytest.mark.parametrize("lease", ["on", "off"])
def test_a_stalled_recorder_lets_the_arm_move_for_the_speed_lease_at_most(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, lease: str
) -> None:
    # the recorder stops running for 1 s of its clock (5 s of the world's) once the arm is
    # 2.5 mm above the block: the controller goes on with the last command meanwhile. The
    # approach's speed command lasts SPEED_LEASE_S (0.5 s at 2 mm/s: 1 mm), so the arm stops
    # short of the block by itself; a command for the whole approach would take it 7.5 mm in.
    if lease == "off":
        monkeypatch.setattr(runner_module, "SPEED_LEASE_S", 1e9)
    rig = _rig(FAST, "silence_s=2")
    lab, step = rig.lab, rig.lab.step
    lowest: list[float] = []

    def stepping() -> int:
        now = step()
        if not lowest and lab.world.robot_at(now).tcp_pose[2] < 0.1325:  # the face: z 0.13
            for _ in range(125):  # the recorder stalls: the world goes on without it
                now = step()
            lowest.append(float(lab.world.robot_at(now).tcp_pose[2]))
        return now

    lab.step = stepping  # type: ignore[method-assign]
    with rig:
        assert rig.present(OBJECTS["wood"])
        stopped = ""
        try:
            record_action(rig, OBJECTS["wood"], ACTIONS["P1"], 1, tmp_path / "001.mcap", seed=0)
        except ActionStoppedError as err:
            stopped = str(err)
    assert lowest
    if lease == "off":
        assert lowest[0] < 0.13 - 0.005, lowest
        return
    assert lowest[0] > 0.13, lowest  # stopped above the face
    assert not stopped


def test_the_approach_renews_its_speed_and_says_its_phase_once(tmp_path: Path) -> None:
    with _rig(FAST) as rig:
        assert rig.present(OBJECTS["wood"])
        record_action(rig, OBJECTS["wood"], ACTIONS["P1"], 1, tmp_path / "001.mcap", seed=0)
        programs = [e.details for e in rig.lab.world.events("program")]
    approach = [p["calls"] for p in programs if program_kind(p["name"]) == "atikt_approach"]
    assert len(approach) > 3  # the lease renewed
    assert approach[0] == ["textmsg", "speedl"]
    assert all(calls == ["speedl"] for calls in approach[1:])


def test_a_session_says_which_recording_begins_before_the_arm_moves_for_it(
    tmp_path: Path,
) -> None:
    # at a terminal the operator sees each recording begin, not only end (an action takes
    # 5-12 s at the robot); a resumed session begins only the recordings still missing
    tasks = plan_dataset(OBJECTS, ACTIONS, object_ids=["wood"], action_ids=["P1"], trials=2)
    factory = rig_factory(load_rig_config(None, "sim-ur10", [FAST]))
    events: list[tuple[str, int]] = []

    def session() -> None:
        run_session(
            tasks,
            tmp_path,
            factory,
            seed=0,
            unattended=True,
            on_start=lambda task: events.append(("start", task.trial)),
            on_recorded=lambda task, _written: events.append(("written", task.trial)),
        )

    session()
    assert events == [("start", 1), ("written", 1), ("start", 2), ("written", 2)]
    (tmp_path / "wood" / "P1" / "002.mcap").rename(tmp_path / "kept.mcap")
    events.clear()
    session()
    assert events == [("start", 2), ("written", 2)]
