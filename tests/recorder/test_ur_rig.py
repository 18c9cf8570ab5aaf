"""The UR rig against the virtual lab: full actions, limits, stops, accounting."""

import math
import re
import socket
import threading
import time
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from ur_lab import POSE, TIME_SCALE, Lab, WorldSkin, config, program_kind, virtual_lab

import recorder
from recorder import (
    ActionStoppedError,
    RecorderError,
    RigError,
    load_actions,
    load_objects,
    record_action,
)
from recorder.live import SOURCES_RECORD, SourceLostError, parse_source_stats
from recorder.runner import Motion, check_motion
from recorder.runner import _runner as runner_module
from recorder.runner import peak_total as _peak_total
from recorder.ur import Limits, UROptions, URRig, build_ur_rig
from recorder.virtuallab._command import parse_faults, rtde_faults, script_faults
from recorder.virtuallab._events import Event
from recorder.virtuallab._rtde_server import RtdeFaults
from recorder.virtuallab._script_server import ScriptFaults, check_program, split_programs
from recorder.writing._stream import SkinBlock
from replay import read_recording
from replay.cli._main import main as replay_main

OBJECTS = load_objects()
ACTIONS = load_actions()


def _record(lab_rig: URRig, action: str, path: Path) -> Path:
    obj = OBJECTS["wood"]
    with lab_rig as rig:
        assert rig.present(obj)
        written = record_action(rig, obj, ACTIONS[action], 1, path, seed=0)
    return written.path


@pytest.mark.slow(6)
def test_full_action_passes_check_and_opens_everywhere(tmp_path: Path) -> None:
    faults = RtdeFaults(drop=2, duplicate=1, reorder=1, after=20, at_action_s=0.0)
    path = tmp_path / "wood" / "C1" / "001.mcap"
    with virtual_lab(rtde_faults=faults) as lab:
        lab.world.prepare("wood", "C1", 1)
        _record(lab.rig({"wood": POSE}), "C1", path)
        injected = lab.rtde.injected
        assert lab.controller.log == ()
        # every program says its phase, but the renewals of the approach's speed (its lease)
        firsts = [p.splitlines()[1].strip() for p in lab.script.programs]
        said = [line.startswith('textmsg("atikt:') for line in firsts]
        renewals = [
            p.startswith("def atikt_approach_") and line.startswith("speedl(")
            for p, line in zip(lab.script.programs, firsts, strict=True)
        ]
        assert all(s or r for s, r in zip(said[1:], renewals[1:], strict=True))
        assert any(renewals)
        # the press returns to the contact by itself if no program replaces it in time
        (press,) = [p for p in lab.script.programs if "phase=execute" in p]
        assert [line.split("(")[0].strip() for line in press.splitlines()[2:-1]] == [
            "movel",
            "sleep",
            "movel",
        ], press
    recording = read_recording(path)
    assert recording.metadata.rig["kind"] == "ur"
    assert float(recording.metadata.rig["time_scale"]) == TIME_SCALE
    # the two dropped packages are counted loss: check refuses the file (it agrees with the
    # accounting); everything else in it reads
    assert replay_main(["check", str(path)]) == 1
    with AnyReader([path]) as reader:
        assert sum(1 for _ in reader.messages()) > 100
    with path.open("rb") as stream:
        mcap = make_reader(stream)
        sources = {
            s.name: s
            for s in parse_source_stats(
                next(m.metadata for m in mcap.iter_metadata() if m.name == SOURCES_RECORD)
            )
        }
        assert sum(1 for _ in mcap.iter_messages()) > 100
    rtde = sources["rtde"]
    assert (injected.dropped, injected.duplicated, injected.reordered) == (2, 1, 1)
    assert (rtde.missing, rtde.duplicated, rtde.out_of_order) == (2, 1, 1)
    assert "skin_force" in sources


def test_protective_stop_keeps_an_incomplete_file(tmp_path: Path) -> None:
    path = tmp_path / "001.mcap"
    with virtual_lab(script_faults=ScriptFaults(protective_stop_s=0.2)) as lab:
        lab.world.prepare("wood", "C1", 1)
        with pytest.raises(ActionStoppedError) as info:
            _record(lab.rig({"wood": POSE}), "C1", path)
        assert lab.script.stops_injected == 1
    error = info.value
    assert "protective stop (RTDE safety_status 3; " in error.reason
    assert "unlock it at the teach pendant or with the dashboard's" in error.reason  # the way on
    assert "\n" not in str(error)
    assert error.path == tmp_path / "001.incomplete.mcap"
    assert error.path.exists()
    assert not path.exists()


def test_an_arm_that_is_not_running_is_refused_before_anything_moves(tmp_path: Path) -> None:
    path = tmp_path / "wood" / "P1" / "001.mcap"
    with virtual_lab() as lab:
        lab.world.power(5)  # powered on, brakes engaged: the state of a morning
        with lab.rig({"wood": POSE}) as rig:
            with pytest.raises(RigError) as presenting:
                rig.present(OBJECTS["wood"])
            with pytest.raises(RigError) as starting:  # an object placed by hand
                record_action(rig, OBJECTS["wood"], ACTIONS["P1"], 1, path, seed=0)
        moving = [p for p in lab.script.programs if "movel(" in p or "speedl(" in p]
    said = "arm not running (idle, brakes engaged: RTDE robot_mode 5; power it on and release"
    assert said in str(presenting.value)
    assert said in str(starting.value)
    assert "the arm cannot start an action" in str(starting.value)
    assert "\n" not in str(starting.value)
    assert moving == []  # nothing that moves was sent
    assert not any(tmp_path.rglob("*.mcap*"))  # and no file for an action that never began


def test_an_arm_powered_off_mid_action_stops_it(tmp_path: Path) -> None:
    path = tmp_path / "001.mcap"
    with virtual_lab() as lab:
        lab.world.prepare("wood", "C1", 1)
        with lab.rig({"wood": POSE}) as rig:
            assert rig.present(OBJECTS["wood"])
            timer = threading.Timer(0.3, lab.world.power, (3,))  # during the action
            timer.start()
            try:
                with pytest.raises(ActionStoppedError) as info:
                    record_action(rig, OBJECTS["wood"], ACTIONS["C1"], 1, path, seed=0)
            finally:
                timer.cancel()
    assert "arm not running (powered off: RTDE robot_mode 3" in info.value.reason
    assert info.value.path == tmp_path / "001.incomplete.mcap"
    assert info.value.path.exists()


def _until_playing(lab: Lab) -> None:
    """Wait until the lab plays the program sent, and has streamed that state a while."""
    for _ in range(2000):  # a hang guard (10 s), not a timing check
        if lab.world.robot_at(lab.world.controller_ns()).runtime_state == 2:  # 2: playing
            break
        time.sleep(0.005)
    else:
        pytest.fail("the lab never played the program")
    time.sleep(0.1)  # the state samples the rig reads next were taken since


def test_an_arm_that_keeps_moving_is_refused_before_an_action(tmp_path: Path) -> None:
    path = tmp_path / "wood" / "P1" / "001.mcap"
    with virtual_lab() as lab, lab.rig({"wood": POSE}) as rig:
        # another program (or a person guiding the arm) moves it, slowly and for long
        lab.script.run("speedl([0.0, 0.0, 0.005, 0.0, 0.0, 0.0], 0.5, 100.0)\n")
        _until_playing(lab)
        with pytest.raises(RigError) as refused:  # an object placed by hand: no movel first
            record_action(rig, OBJECTS["wood"], ACTIONS["P1"], 1, path, seed=0)
        ours = [p for p in lab.script.programs if p.startswith("def atikt")]
    assert "the arm cannot start an action: the arm is moving (a joint at" in str(refused.value)
    assert ours == []  # nothing of ours was sent
    assert not any(tmp_path.rglob("*.mcap*"))


def test_an_arm_standing_outside_the_workspace_is_refused_with_the_way_in(tmp_path: Path) -> None:
    path = tmp_path / "wood" / "P1" / "001.mcap"
    box = Limits(workspace_min_m=(-0.9, -0.5, 0.25), workspace_max_m=(-0.4, 0.2, 0.4))
    with virtual_lab() as lab:
        lab.world.place([-0.6, -0.2, 0.2, 0.0, np.pi, 0.0])  # left below the box
        with lab.rig({"wood": [-0.7, -0.2, 0.3, 0.0, np.pi, 0.0]}, box) as rig:
            with pytest.raises(RigError) as presenting:
                rig.present(OBJECTS["wood"])
            with pytest.raises(RigError) as starting:  # an object placed by hand
                record_action(rig, OBJECTS["wood"], ACTIONS["P1"], 1, path, seed=0)
        moving = [p for p in lab.script.programs if "movel(" in p or "speedl(" in p]
    way_in = (
        "bring the TCP inside [limits] workspace_min_m .. workspace_max_m at the teach pendant, "
        "or widen the workspace, then retry"
    )
    said = "the arm cannot move to wood: TCP at [-0.6, -0.2, 0.2] left the [limits] workspace; "
    assert said in str(presenting.value)
    assert str(presenting.value).endswith(way_in)
    assert str(starting.value).endswith(way_in)
    assert moving == []
    assert not any(tmp_path.rglob("*.mcap*"))


def test_an_approach_that_finds_nothing_stops_inside_the_workspace(tmp_path: Path) -> None:
    # the object's surface lies below the workspace's floor (20 mm below the pose in the lab)
    box = Limits(workspace_min_m=(-0.9, -0.5, 0.0), workspace_max_m=(-0.4, 0.2, 0.4))
    reasons, lowest, approaches = [], [], []
    for height in (0.015, 0.004):  # room to approach a little, and none
        pose = [-0.7, -0.2, height, 0.0, np.pi, 0.0]
        with virtual_lab() as lab, lab.rig({"wood": pose}, box) as rig:
            rig.present(OBJECTS["wood"])
            with pytest.raises(ActionStoppedError) as info:
                record_action(rig, OBJECTS["wood"], ACTIONS["P1"], 1, tmp_path / "1.mcap", seed=0)
            time.sleep(0.5)  # the arm comes to rest
            lowest.append(lab.world.robot_at(lab.world.controller_ns()).tcp_pose[2])
            approaches.append(sum("speedl(" in p for p in lab.script.programs))
        reasons.append(info.value.reason)
        (tmp_path / "1.incomplete.mcap").unlink()
    for reason in reasons:
        assert "no light contact (total skin force above" in reason
        assert "where the [limits] workspace ends (less the arm's stopping distance)" in reason
    assert 0.0 <= lowest[0] < 0.015  # it approached, and stopped inside the box
    assert approaches[0] > 0
    assert approaches[1] == 0  # no room at all: no approach was sent
    assert lowest[1] == pytest.approx(0.004, abs=5e-4)  # where it was presented


def test_the_reach_to_the_workspaces_edge_along_a_direction() -> None:
    box = Limits(workspace_min_m=(-1.0, -1.0, 0.0), workspace_max_m=(1.0, 1.0, 1.0))
    down = np.array([0.0, 0.0, -1.0])
    assert box.reach([0.0, 0.0, 0.2], down) == pytest.approx(0.2)
    slanted = np.array([0.6, 0.0, -0.8])  # the x side at 1.0 / 0.6, the floor at 0.2 / 0.8
    assert box.reach([0.0, 0.0, 0.2], slanted) == pytest.approx(0.25)
    assert box.reach([0.0, 0.0, -0.1], down) == 0.0  # outside: nowhere to go
    assert box.reach([0.0, 0.0, 0.2], np.zeros(3)) == math.inf


def test_another_program_running_is_refused_and_never_replaced(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # a program found playing is waited for (a killed recorder's press ends by itself), here
    # 0.3 s of the controller's time, then refused
    monkeypatch.setattr(runner_module, "PROGRAM_WAIT_S", 0.3)
    path = tmp_path / "wood" / "P1" / "001.mcap"
    with virtual_lab() as lab, lab.rig({"wood": POSE}) as rig:
        # a colleague's program, waiting at the controller: ours would replace it
        lab.script.run("def theirs():\n  sleep(100.0)\nend\n")
        _until_playing(lab)
        with pytest.raises(RigError) as presenting:
            rig.present(OBJECTS["wood"])
        with pytest.raises(RigError) as starting:  # an object placed by hand
            record_action(rig, OBJECTS["wood"], ACTIONS["P1"], 1, path, seed=0)
        ours = [p for p in lab.script.programs if p.startswith("def atikt")]
        still = lab.world.robot_at(lab.world.controller_ns()).runtime_state
    said = "a program is playing (RTDE runtime_state 2): another program runs on the controller"
    assert said in str(presenting.value)
    assert "the arm cannot move to wood" in str(presenting.value)
    assert said in str(starting.value)
    assert "\n" not in str(starting.value)
    assert ours == []  # nothing of ours was sent: theirs still runs
    assert still == 2
    assert not any(tmp_path.rglob("*.mcap*"))
    waits = capsys.readouterr().err.count("on the controller: waiting up to 0.3 s for it to end")
    assert waits == 2  # once for each refusal


@pytest.mark.parametrize("name", ["theirs", "atikt_slide_0a0a0a"])
def test_another_program_started_mid_action_stops_it(tmp_path: Path, name: str) -> None:
    # a colleague's computer sends a program mid-slide: it replaces ours at the controller
    # (RTDE still says "playing"); the controller's key message names it, and the action ends.
    # Also when that computer runs this recorder (its programs are atikt_* with its own tag)
    path = tmp_path / "001.mcap"
    with virtual_lab() as lab:
        lab.world.prepare("wood", "S1", 1)
        theirs = f"def {name}():\n  sleep(100.0)\nend\n"

        def colleague(started: str) -> None:  # mid-slide, when no program of ours is due
            if program_kind(started) == "atikt_slide" and started != name:
                timer = threading.Timer(0.1, lab.script.run, args=(theirs,))
                timer.daemon = True
                timer.start()

        lab.world.on_program(colleague)
        with pytest.raises(ActionStoppedError) as info:
            _record(lab.rig({"wood": POSE}), "S1", path)
        events = lab.world.events_log.events()
    said = str(info.value)
    assert f"another client's program '{name}' started on the controller and replaced ours" in said
    assert "did not reach" not in said
    programs = [e.details["name"] for e in events if e.kind == "program"]
    assert name in programs
    programs = [program_kind(p) for p in programs]
    assert programs[-1] == "atikt_stop", programs  # the stop came last: nothing of ours after it
    assert info.value.path is not None
    assert info.value.path.name == "001.incomplete.mcap"


def test_the_drivers_own_programs_are_not_taken_for_anothers() -> None:
    # every program of ours is announced by the controller too: none of them is another's
    with virtual_lab() as lab, lab.rig({"wood": POSE}) as rig:
        assert rig.present(OBJECTS["wood"])
        for _ in range(500):  # a hang guard: the key message of the move has arrived
            if rig.arm.own_starts > 0:  # type: ignore[attr-defined]
                break
            time.sleep(0.01)
        assert rig.arm.own_starts > 0  # type: ignore[attr-defined]
        assert rig.arm._foreign == ""  # type: ignore[attr-defined]
        lab.script.run("def theirs():\n  sleep(0.01)\nend\n")
        for _ in range(500):  # a hang guard, not a time check
            if rig.arm._foreign:  # type: ignore[attr-defined]
                break
            time.sleep(0.01)
        assert rig.arm._foreign == "theirs"  # type: ignore[attr-defined]


def test_a_program_paused_on_the_pendant_stops_an_action(tmp_path: Path) -> None:
    path = tmp_path / "001.mcap"
    with virtual_lab() as lab:
        lab.world.prepare("wood", "C1", 1)
        with lab.rig({"wood": POSE}) as rig:
            assert rig.present(OBJECTS["wood"])
            done = threading.Event()

            def state() -> int:
                return lab.world.robot_at(lab.world.controller_ns()).runtime_state

            def pause() -> None:  # during the action, while one of its programs runs
                done.wait(0.3)
                while not done.is_set() and state() != 4:  # 4: paused
                    if state() == 2:  # 2: playing
                        lab.world.pause()
                    done.wait(0.005)

            pausing = threading.Thread(target=pause)
            pausing.start()
            try:
                with pytest.raises(ActionStoppedError) as info:
                    record_action(rig, OBJECTS["wood"], ACTIONS["C1"], 1, path, seed=0)
            finally:
                done.set()
                pausing.join()
    assert "program paused (RTDE runtime_state 4" in info.value.reason
    assert info.value.path == tmp_path / "001.incomplete.mcap"
    assert info.value.path.exists()


def test_a_speed_slider_below_full_speed_is_refused_and_stops_an_action(tmp_path: Path) -> None:
    # a slide at half its speed would pass every check and still be another action
    with virtual_lab() as lab:
        lab.world.prepare("wood", "C1", 1)
        lab.world.slide_speed(0.5)
        with lab.rig({"wood": POSE}) as rig:
            with pytest.raises(RigError, match=r"speed slider at 50 % \(RTDE target_speed_frac"):
                rig.present(OBJECTS["wood"])
            lab.world.slide_speed(1.0)
            for _ in range(20):  # the packages already on their way (a loaded lab) carry 50 %
                try:
                    assert rig.present(OBJECTS["wood"])
                    break
                except RigError as err:
                    assert "speed slider at 50 %" in str(err)  # noqa: PT017
                    threading.Event().wait(0.2)
            else:
                pytest.fail("the speed slider at 100 % again was never seen")
            timer = threading.Timer(0.3, lab.world.slide_speed, (0.3,))  # during the action
            timer.start()
            try:
                with pytest.raises(ActionStoppedError) as info:
                    record_action(
                        rig, OBJECTS["wood"], ACTIONS["C1"], 1, tmp_path / "1.mcap", seed=0
                    )
            finally:
                timer.cancel()
    assert "speed slider at 30 %" in info.value.reason
    assert info.value.path == tmp_path / "1.incomplete.mcap"


@pytest.mark.parametrize(
    ("lacks", "safety"),
    [
        (("target_speed_fraction",), "safety_status"),
        (("safety_status",), "safety_mode"),  # older controllers
        (("safety_status", "target_speed_fraction"), "safety_mode"),
    ],
)
def test_an_older_controller_is_driven_with_what_it_provides(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, lacks: tuple[str, ...], safety: str
) -> None:
    from recorder.virtuallab import _rtde_server  # noqa: PLC0415

    served = {k: v for k, v in _rtde_server.VARIABLES.items() if k not in lacks}
    monkeypatch.setattr(_rtde_server, "VARIABLES", served)
    with virtual_lab(script_faults=ScriptFaults(protective_stop_s=0.2)) as lab:
        lab.world.prepare("wood", "C1", 1)
        with lab.rig({"wood": POSE}) as rig:
            assert rig.arm._rtde is not None  # type: ignore[attr-defined]
            names = rig.arm._rtde.recipe.names  # type: ignore[attr-defined]
            assert safety in names
            assert not set(lacks) & set(names)
            assert rig.present(OBJECTS["wood"])
            with pytest.raises(ActionStoppedError) as info:  # the safety state is still read
                record_action(rig, OBJECTS["wood"], ACTIONS["C1"], 1, tmp_path / "1.mcap", seed=0)
    assert f"protective stop (RTDE {safety} 3; " in info.value.reason


def test_a_controller_without_the_arms_state_is_refused_in_one_line(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from recorder.virtuallab import _rtde_server  # noqa: PLC0415

    lacks = {"safety_status", "safety_mode", "actual_TCP_force"}
    served = {k: v for k, v in _rtde_server.VARIABLES.items() if k not in lacks}
    monkeypatch.setattr(_rtde_server, "VARIABLES", served)
    with virtual_lab() as lab, pytest.raises(RigError) as refused:
        lab.rig({"wood": POSE}).__enter__()
    said = str(refused.value)
    assert "does not provide actual_TCP_force, safety_status" in said, said
    assert "target_speed_fraction" not in said
    assert "\n" not in said


def test_lost_rtde_connection_stops_the_action(tmp_path: Path) -> None:
    with virtual_lab(rtde_faults=RtdeFaults(disconnect_after_s=0.6, at_action_s=0.0)) as lab:
        lab.world.prepare("wood", "C1", 1)
        with pytest.raises(ActionStoppedError, match=r"arm connection lost \(RTDE") as info:
            _record(lab.rig({"wood": POSE}), "C1", tmp_path / "001.mcap")
        assert lab.rtde.injected.disconnects == 1
    assert info.value.path is not None
    assert info.value.path.name == "001.incomplete.mcap"


def _slide_under(
    faults: ScriptFaults, path: Path, **options: Any
) -> tuple[str, Sequence[Event], ActionStoppedError]:
    """Slide on wood under ``faults``; return the line, the lab's events and the error."""
    with virtual_lab(script_faults=faults) as lab:
        lab.world.prepare("wood", "S1", 1)
        with pytest.raises(ActionStoppedError) as info:
            _record(lab.rig({"wood": POSE}, **options), "S1", path)
        assert lab.script.drops_injected == 1
        events = lab.world.events_log.events()
    assert info.value.path is not None
    assert info.value.path.name == "001.incomplete.mcap"
    return str(info.value), events, info.value


def _after_fault(events: Sequence[Event], fault: str) -> list[Event]:
    (injected,) = [e for e in events if e.kind == "fault"]
    assert injected.details["fault"] == fault
    return [e for e in events if e.controller_ns > injected.controller_ns]


def test_a_lost_script_connection_ends_the_action_and_the_stop_takes_a_new_one(
    tmp_path: Path,
) -> None:
    # a cable or switch glitch closes the URScript connection mid-action: the programs still
    # to come would go into a dead socket (the retract, silently lost); the driver reads the
    # connection and knows at once, the action ends and the stop goes over a new connection
    said, events, _ = _slide_under(ScriptFaults(drop_s=0.3), tmp_path / "001.mcap")
    assert re.search(r"URScript connection to 127\.0\.0\.1:\d+ lost \(closed by the ", said), said
    assert "did not reach" not in said
    after = _after_fault(events, "drop")
    assert [program_kind(e.details["name"]) for e in after if e.kind == "program"] == ["atikt_stop"]
    assert any(e.kind == "actual_zero" for e in after)


def test_a_script_port_gone_mid_action_is_stopped_by_the_dashboard(tmp_path: Path) -> None:
    # the URScript port closes and takes no new connection: the stop goes to the dashboard
    # server, whose ``stop`` ends the running program; the line says how the arm was stopped
    said, events, _ = _slide_under(ScriptFaults(gone_s=0.3), tmp_path / "001.mcap")
    assert re.search(r"the arm was stopped by the dashboard server 127\.0\.0\.1:\d+ \(", said)
    assert "(no new URScript connection: cannot connect)" in said, said
    assert "did not reach" not in said
    assert "did not come to rest" not in said
    # RTDE kept coming: the lost URScript connection, said in the stop's clause, is not the
    # arm's state stopping (it was said so when the loss had not been raised before the stop)
    assert "cannot be confirmed" not in said, said
    after = _after_fault(events, "gone")
    assert not [e for e in after if e.kind == "program"]  # no program arrived: the port is gone
    assert any(e.kind == "actual_zero" for e in after)


def test_a_stop_taken_by_no_way_in_is_said(tmp_path: Path) -> None:
    # without a dashboard port (0), the lost port leaves the arm to a person: said, not claimed
    said, _, _ = _slide_under(ScriptFaults(gone_s=0.3), tmp_path / "001.mcap", dashboard_port=0)
    assert "the dashboard's stop failed (no dashboard_port)" in said, said
    assert "a new one failed (cannot connect)" in said, said
    assert "stop it at the teach pendant now" in said, said


@pytest.mark.parametrize("way", ["dashboard", "none"])
def test_a_stop_during_the_move_to_an_object_says_how_it_went(way: str) -> None:
    # the URScript port goes away while the arm moves to the object: the refusal says whether
    # the stop reached the arm (the dashboard's), or that a person must stop it
    with virtual_lab() as lab:

        def gone(name: str) -> None:
            if program_kind(name) == "atikt_move":
                timer = threading.Timer(0.05, lab.script.close_port)
                timer.daemon = True
                timer.start()

        lab.world.on_program(gone)
        port = lab.dashboard.address[1] if way == "dashboard" else 0
        with lab.rig({"wood": POSE}, dashboard_port=port) as rig, pytest.raises(RigError) as info:
            rig.present(OBJECTS["wood"])
    line = str(info.value)
    assert "moving to wood: arm connection lost (URScript connection to" in line, line
    if way == "dashboard":
        assert "the arm was stopped by the dashboard server 127.0.0.1:" in line, line
    else:
        assert "the stop did not reach the arm" in line, line
        assert "stop it at the teach pendant now" in line
    assert line.endswith("check the arm, then retry")


def _until_lost() -> None:
    """Wait until the driver's script reader has seen its connection end (its thread ends)."""
    for thread in threading.enumerate():
        if thread.name == "atikt-urscript":
            thread.join(10.0)  # a hang guard: the driver notes the loss before its reader ends


def test_a_lost_script_connection_is_said_by_the_next_state_poll_once() -> None:
    # mid-slide no program is due for seconds: the loss must not wait for the next one
    with virtual_lab() as lab, lab.rig({"wood": POSE}) as rig:
        arm = rig.arm
        arm.poll(0.05)
        lab.script.drop_clients()
        _until_lost()
        assert arm._script_lost  # type: ignore[attr-defined]
        with pytest.raises(SourceLostError, match=r"URScript connection to .* lost \(closed by"):
            arm.poll(0.05)
        assert arm.poll(0.05)  # once: what arrives after it is still read (kept)


def test_a_script_connection_lost_between_actions_is_made_again(tmp_path: Path) -> None:
    path = tmp_path / "001.mcap"
    with virtual_lab() as lab:
        lab.world.prepare("wood", "P1", 1)
        with lab.rig({"wood": POSE}) as rig:
            assert rig.present(OBJECTS["wood"])
            lab.script.drop_clients()  # while nothing moves
            _until_lost()
            assert rig.arm._script_lost  # type: ignore[attr-defined]
            written = record_action(rig, OBJECTS["wood"], ACTIONS["P1"], 1, path, seed=0)
            assert rig.arm.reconnects == 1  # type: ignore[attr-defined]
            # the controller's state stream on the script port is read (and dropped)
            assert rig.arm.script_bytes > 0  # type: ignore[attr-defined]
    assert written.path == path
    assert path.exists()


def test_an_arm_that_never_moves_ends_the_approach(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    with virtual_lab() as lab:
        execute = lab.controller.execute
        monkeypatch.setattr(  # every approach program is lost on its way: the arm stays put
            lab.controller,
            "execute",
            lambda program: any(c.name == "speedl" for c in program.calls) or execute(program),
        )
        # the slowest approach over the whole distance, twice: 2 x 0.02 / 0.02 s x 0.2 (scale)
        rig = lab.rig(
            {"wood": POSE}, approach_min_m_s=0.02, approach_max_m_s=0.02, approach_limit_m=0.02
        )
        # the arm stands still while the approach is renewed: said after the cycles a motion
        # must show in (or, whichever comes first, the approach's time limit)
        stood = r"the arm stood still for \d+ controller cycles|no light contact within 0\.4 s"
        with pytest.raises(ActionStoppedError, match=stood) as info:
            _record(rig, "P1", tmp_path / "001.mcap")
    assert info.value.path is not None
    assert info.value.path.name == "001.incomplete.mcap"


def test_a_program_the_controller_does_not_run_is_said_at_once(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    with virtual_lab() as lab:
        monkeypatch.setattr(lab.controller, "execute", lambda _program: False)  # local control
        with lab.rig({"wood": POSE}) as rig, pytest.raises(RigError) as refused:
            rig.present(OBJECTS["wood"])
    said = str(refused.value)  # said after 50 cycles, not after the present's deadline (5 s)
    assert "moving to wood: the arm did not start moving toward wood in 50 controller" in said
    assert "the controller did not run the program" in said


def test_a_program_the_controller_refuses_is_said_with_its_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # a controller that cannot compile a program (another firmware's signature) says why in
    # a runtime exception message on the primary interface: the line carries it
    from recorder.ur._script import FUNCTIONS  # noqa: PLC0415
    from recorder.virtuallab import _urscript  # noqa: PLC0415

    monkeypatch.setattr(_urscript, "FUNCTIONS", FUNCTIONS - {"force_mode"})
    path = tmp_path / "001.mcap"
    with virtual_lab() as lab:
        lab.world.prepare("wood", "S1", 1)
        with pytest.raises(ActionStoppedError) as info:
            _record(lab.rig({"wood": POSE}), "S1", path)
    said = str(info.value)
    assert "a runtime exception (line 2: unknown function force_mode()) from the controller" in (
        said
    ), said
    assert info.value.path is not None
    assert info.value.path.name == "001.incomplete.mcap"


def test_a_new_program_replaces_the_playing_action() -> None:
    with virtual_lab() as lab:
        lab.world.start_action("wood", "C1", 1)
        lab.world.start_action("foam_block", "P1", 1)  # a controller runs the newest program
        assert lab.world.playing() == ("foam_block", "P1", 1)


@pytest.mark.slow(6)
def test_the_light_contact_counts_every_force_sample_not_only_the_latest(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # the latest reading never shows the touch (every check falls between two samples of it):
    # the samples that arrived between the checks do
    monkeypatch.setattr(WorldSkin, "total_force", lambda _self: 0.0)
    with virtual_lab() as lab:
        lab.world.prepare("wood", "C1", 1)
        reason = ""
        try:
            _record(lab.rig({"wood": POSE}), "C1", tmp_path / "001.mcap")
        except ActionStoppedError as stop:
            reason = stop.reason
    # found from 0.1 s blocks, the contact comes late and the virtual lab's plan (which does
    # not wait for the rig) may have pressed on: a later phase may stop, not the approach
    assert "no light contact" not in reason, reason


def test_a_force_block_counts_for_the_contact_only_from_the_approach_on() -> None:
    ms = 1_000_000
    data = np.zeros((60, 7, 3), dtype=np.float32)
    data[0] = 1.0  # a jolt in the tare, before the approach program went out
    data[30:50] = 0.01  # a touch of 20 ms: total 0.21 N
    block = SkinBlock("force", stamp_ns=0, period_ns=ms, receive_ns=70 * ms, data=data)
    assert _peak_total(block, since_ns=ms) == pytest.approx(0.21, rel=1e-5)
    assert _peak_total(block, since_ns=0) == pytest.approx(21.0 / 20, rel=1e-5)  # in the window
    assert _peak_total(block, since_ns=61 * ms) is None


def test_one_noisy_sample_is_not_a_light_contact() -> None:
    ms = 1_000_000
    data = np.zeros((60, 7, 3), dtype=np.float32)
    data[40] = 0.01  # one sample's sum at 0.21 N: noise of 21 sensors, not a touch
    block = SkinBlock("force", stamp_ns=0, period_ns=ms, receive_ns=70 * ms, data=data)
    peak = _peak_total(block, since_ns=0)
    assert peak is not None
    assert peak < 0.05  # the catalog's light contact: not reached by one sample


def test_silent_rtde_stops_the_action(tmp_path: Path) -> None:
    with virtual_lab(rtde_faults=RtdeFaults(stall_s=1.0, after=70, at_action_s=0.0)) as lab:
        lab.world.prepare("wood", "C1", 1)
        with pytest.raises(ActionStoppedError, match="arm state silent for") as info:
            _record(lab.rig({"wood": POSE}, silence_s=0.3), "C1", tmp_path / "001.mcap")
    assert info.value.path is not None


def test_limits_are_refused_before_any_byte_is_sent() -> None:
    with virtual_lab() as lab, socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        rig = URRig(
            UROptions.from_options(
                {"rtde_port": lab.rtde.address[1], "script_port": listener.getsockname()[1]},
                "lab.toml",
            ),
            Limits(max_tcp_speed_m_s=0.03, max_force_n=0.15),
            {"transport": "test"},
            {},
            where="lab.toml",
            skin_factory=lambda _s, clock, _w: __import__("ur_lab").WorldSkin(lab.world, clock),
        )
        with rig:
            connection, _ = listener.accept()
            with pytest.raises(RigError) as speed:
                rig.perform(OBJECTS["wood"], ACTIONS["S2"], 1)
            with pytest.raises(RigError) as force:
                rig.perform(OBJECTS["wood"], ACTIONS["S3"], 1)
            connection.settimeout(0.2)
            with pytest.raises(TimeoutError):
                connection.recv(1)  # not one byte reached the script port
            connection.close()
    assert str(speed.value) == (
        "lab.toml: action S2 speed_m_s = 0.05 exceeds [limits] max_tcp_speed_m_s = 0.03; "
        "change action S2 in the action catalog or raise the limit"
    )
    assert "action S3 force_n = 0.2 exceeds [limits] max_force_n = 0.15" in str(force.value)


def test_builder_checks_options_limits_and_poses() -> None:
    example = Path(recorder.__file__).parent / "data" / "skin_udp.example.toml"
    skin = tomllib.loads(example.read_text())["skin"]
    rig = build_ur_rig(0, config({"host": "10.0.0.2", "frequency": 500}, {"skin": skin}))
    assert rig.options_ur.host == "10.0.0.2"
    assert rig.describe()["rtde_frequency_hz"] == "500"
    assert "time_scale" not in rig.describe()
    assert rig.joint_names[0] == "shoulder_pan_joint"
    outside = {"skin": skin, "objects": {"wood": {"pose": [2.0, 0, 0.1, 0, 3.14, 0]}}}
    with pytest.raises(RigError, match=r"lab.toml: \[objects.wood\] pose position \[2.0"):
        build_ur_rig(0, config({}, outside))
    with pytest.raises(RigError, match="rig option 'speed': the ur rig takes host"):
        build_ur_rig(0, config({"speed": 1}, {"skin": skin}))
    with pytest.raises(RigError, match="frequency = 200: give 125"):
        build_ur_rig(0, config({"frequency": 200}, {"skin": skin}))
    with pytest.raises(RigError, match=r"\[limits\] max_speed: unknown"):
        build_ur_rig(0, config({}, {"skin": skin, "limits": {"max_speed": 1}}))
    with pytest.raises(RigError, match=r"approach_max_m_s = 0\.5 exceeds"):
        build_ur_rig(0, config({"approach_max_m_s": 0.5}, {"skin": skin}))
    with pytest.raises(RigError, match=r"needs a \[skin\] table"):
        build_ur_rig(0, config({}, {}))
    with pytest.raises(RigError, match=r"\[skin\] cells = 'missing': this key is required"):
        build_ur_rig(0, config({}, {"skin": {"transport": "udp"}}))  # before any connection
    placed = build_ur_rig(0, config({}, {"skin": skin, "objects": {"wood": {"pose": POSE}}}))
    assert placed.can_present(OBJECTS["wood"])
    # a pose the arm could not be sent to: refused before connecting, with the value
    for pose in ([-0.7, -0.2, 0.15], [*POSE[:4], float("inf"), 0.0], [*POSE[:5], True]):
        bad = {"skin": skin, "objects": {"wood": {"pose": pose}}}
        with pytest.raises(RigError, match=r"\[objects.wood\] pose = .*six finite numbers"):
            build_ur_rig(0, config({}, bad))
    assert not placed.can_present(OBJECTS["glass_plate"])


def test_a_port_without_messages_is_said_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    # a secondary interface (30002) takes programs but names none: others' are not seen
    with virtual_lab() as lab:
        monkeypatch.setattr(lab.world, "_program_listeners", [])  # the lab names none
        lab.world.prepare("wood", "P1", 1)
        with lab.rig({"wood": POSE}) as rig:
            for trial in (1, 2):
                path = tmp_path / f"{trial:03d}.mcap"
                record_action(rig, OBJECTS["wood"], ACTIONS["P1"], trial, path, seed=0)
    said = [r.getMessage() for r in caplog.records if r.name == "atikt.ur"]
    assert len(said) == 1, said
    assert "it sends no messages there (a secondary interface)" in said[0]
    assert "give script_port = 30001" in said[0]


def test_a_program_not_yet_named_when_its_action_begins_is_not_said(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    # the move to an object the arm is at ends at once: the action begins before the
    # controller's message naming the move arrived (here 0.2 s late); a whole action later
    # it has, and the primary interface is not called a secondary one
    import threading  # noqa: PLC0415

    with virtual_lab() as lab:
        lab.world.prepare("wood", "P1", 1)
        with lab.rig({"wood": POSE}) as rig:  # the arm goes to the pose
            assert rig.present(OBJECTS["wood"])
            record_action(rig, OBJECTS["wood"], ACTIONS["P1"], 1, tmp_path / "001.mcap", seed=0)
        listeners = list(lab.world._program_listeners)

        def late(name: str) -> None:
            for listener in listeners:
                threading.Timer(0.2, listener, (name,)).start()

        monkeypatch.setattr(lab.world, "_program_listeners", [late])
        with lab.rig({"wood": POSE}) as rig:  # a new session: counted afresh
            assert rig.present(OBJECTS["wood"])  # as a session does: the arm is there already
            for trial in (2, 3):
                path = tmp_path / f"{trial:03d}.mcap"
                record_action(rig, OBJECTS["wood"], ACTIONS["P1"], trial, path, seed=0)
            assert rig.arm.own_starts > 0  # type: ignore[attr-defined]
    assert [r.getMessage() for r in caplog.records if r.name == "atikt.ur"] == []


def test_a_second_configuration_of_the_same_arm_is_locked_out_whatever_its_script_port(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    # an old configuration (script_port = 30002) and a new one (30001) reach one controller:
    # one process at a time drives it, whichever port its programs go to
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    with virtual_lab() as lab, lab.rig({"wood": POSE}):
        other = socket.socket()
        other.bind(("127.0.0.1", 0))
        with (
            other,
            pytest.raises(RigError, match=r"drives the arm ur-127\.0\.0\.1-\d+ from this computer"),
            lab.rig({"wood": POSE}, script_port=other.getsockname()[1]),
        ):
            pass


def test_the_script_stream_is_read_as_the_primary_protocol_whatever_its_chunks() -> None:
    from recorder.live import RecorderClock  # noqa: PLC0415
    from recorder.ur._arm import Connection, URArm  # noqa: PLC0415
    from recorder.virtuallab._script_server import key_message  # noqa: PLC0415

    arm = URArm(Connection("127.0.0.1", 1, 1, 125), RecorderClock())
    stream = (
        key_message("PROGRAM_XXX_STARTED", f"atikt_slide_{arm.tag}", 1)  # ours
        + key_message("PROGRAM_XXX_STOPPED", "theirs", 2)  # stopped: not a start
    )
    buffer = bytearray()
    for at in range(0, len(stream), 7):  # as the network cuts it
        buffer += stream[at : at + 7]
        assert arm._read_messages(buffer)
    assert (arm.own_starts, arm._foreign) == (1, "")
    assert not buffer
    # another computer running this recorder: its programs carry its own tag
    other = "atikt_slide_" + ("0" * 6 if arm.tag != "0" * 6 else "1" * 6)
    assert arm._read_messages(bytearray(key_message("PROGRAM_XXX_STARTED", other, 3)))
    assert (arm.own_starts, arm._foreign) == (1, other)
    assert arm._read_messages(bytearray(key_message("PROGRAM_XXX_STARTED", "theirs", 4)))
    assert arm._foreign == "theirs"
    arm._foreign = ""
    # a port that does not speak the primary protocol (a size of 'HTTP'): drained, not read
    assert not arm._read_messages(bytearray(b"HTTP/1.1 400 Bad Request\r\n"))
    assert arm._foreign == ""


def test_a_script_stream_that_is_not_the_primary_protocol_is_said(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    with virtual_lab() as lab:
        garbage = b"HTTP/1.1 400 Bad Request\r\n\r\n"
        monkeypatch.setattr(lab.script, "state_message", lambda: garbage)
        with lab.rig({"wood": POSE}):
            for _ in range(500):  # a hang guard: the reader has judged the stream's first bytes
                if any(r.name == "atikt.ur" for r in caplog.records):
                    break
                time.sleep(0.01)
            time.sleep(0.3)  # more of the stream: still said once
    said = [r.getMessage() for r in caplog.records if r.name == "atikt.ur"]
    assert len(said) == 1, said
    assert "is not the controller's primary protocol (a message of 1213486160 bytes)" in said[0]


def test_cb3_cannot_stream_at_500_hz() -> None:
    with virtual_lab(frequency=125) as lab, pytest.raises(RigError, match="125 Hz at most"):
        lab.rig(frequency=500).__enter__()


def test_script_subset_is_checked() -> None:
    programs, rest = split_programs(
        'def a():\n  textmsg("x")\n  explode(1)\nend\nstopl(1)\ndef b():\n'
    )
    assert len(programs) == 2
    assert rest == "def b():\n"
    assert check_program(programs[0]) == ["line 2: unknown function explode()"]
    assert check_program(programs[1]) == []
    with virtual_lab() as lab:
        lab.script.run("def a():\n  frobnicate()\nend\n")
        assert lab.controller.log == (
            "URScript error, program not run: line 1: unknown function frobnicate()",
        )


def test_fault_options_are_parsed() -> None:
    faults = parse_faults(["rtde.drop=3", "rtde.stall=1.5", "script.protective_stop=1"])
    assert rtde_faults(faults["rtde"]) == RtdeFaults(drop=3, stall_s=1.5)
    script = script_faults(parse_faults(["script.drop=0.5", "script.protective_stop=1"])["script"])
    assert script == ScriptFaults(protective_stop_s=1.0, drop_s=0.5)
    with pytest.raises(RecorderError, match="the URScript faults are protective_stop, drop"):
        script_faults(parse_faults(["script.stall=1"])["script"])
    for bad in ("drop=3", "rtde.stall=1e400", "rtde.stall=inf", "rtde.drop=nan", "rtde.drop=-1"):
        with pytest.raises(RecorderError, match=r"give server\.name=number \(finite, 0 or more\)"):
            parse_faults([bad])
    for off in ("script.drop=0", "rtde.stall=0", "skin.drop=0"):  # 0 is off: a fault that is not
        with pytest.raises(RecorderError, match=r"0 turns .* off, so it injects nothing"):
            parse_faults([off])
    starts = ["rtde.at_action=0", "ros2.drop_after=0", "ros2.stall_after=0"]  # times and counts
    assert parse_faults(starts) == {
        "rtde": {"at_action": 0.0},
        "ros2": {"drop_after": 0.0, "stall_after": 0.0},
    }


@pytest.mark.parametrize(
    ("option", "fragment"),
    [
        ({"rtde_port": 99999}, "rtde_port = 99999: give the controller's port 1..65535"),
        ({"script_port": 0}, "script_port = 0: give a positive finite number"),
        # nan passes every comparison: a silence that never ends an action, a speed unchecked
        ({"silence_s": float("nan")}, "silence_s = nan: give a positive finite number"),
        ({"press_m_s": float("inf")}, "press_m_s = inf: give a positive finite number"),
        ({"script_port": 30002.5}, "script_port = 30002.5: give a whole number"),
        ({"host": " 10.0.0.2"}, "host = ' 10.0.0.2': give an address"),
        ({"frequency": 125.5}, "frequency = 125.5: give a whole number"),
        # one port, two interfaces: the stop's second way in would reach the first
        ({"script_port": 31101, "dashboard_port": 31101}, "dashboard_port = 31101 is also "),
        ({"rtde_port": 31104, "dashboard_port": 31104}, "dashboard_port = 31104 is also rtde"),
        ({"rtde_port": 30001}, "script_port = 30001 is also rtde_port: a controller serves"),
    ],
)
def test_ports_out_of_range_are_refused_before_connecting(
    option: dict[str, object], fragment: str
) -> None:
    with pytest.raises(RigError) as info:
        UROptions.from_options(option, "lab.toml")
    assert str(info.value).startswith("lab.toml: rig option ")
    assert fragment in str(info.value)
    assert UROptions.from_options({"rtde_port": 30004.0}, "lab.toml").rtde_port == 30004


@pytest.mark.parametrize(
    ("limits", "motion", "fragment"),
    [
        ({"max_force_n": float("nan")}, {}, "max_force_n = nan: give a positive finite number"),
        ({"max_tcp_speed_m_s": float("inf")}, {}, "give a positive finite number"),
        ({"max_force_n": 0.1}, {"contact_force_n": 0.2}, "contact_force_n = 0.2 exceeds"),
        # an approach without proximity sensing runs at approach_min_m_s: at most the fastest
        # (checked against the limit, and the one the stopping margins are computed for)
        (
            {},
            {"approach_min_m_s": 0.05, "approach_max_m_s": 0.02},
            "approach_min_m_s = 0.05 exceeds approach_max_m_s = 0.02; give approach_min_m_s <=",
        ),
    ],
)
def test_limits_that_are_no_limits_are_refused(
    limits: dict[str, float], motion: dict[str, float], fragment: str
) -> None:
    with pytest.raises(RigError) as info:
        check_motion(Motion(**motion), Limits.from_section(limits, "lab.toml"), "lab.toml")
    assert str(info.value).startswith("lab.toml: ")
    assert fragment in str(info.value)
