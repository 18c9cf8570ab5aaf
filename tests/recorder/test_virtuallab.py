"""The virtual lab executes the URScript it receives on a kinematic UR10.

Cycle-level properties run on a stopped clock stepped by hand (deterministic); the rig, ur_rtde
and serve-sim tests run the lab on loopback in real time.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import forked
import numpy as np
import pytest
from ports import free_port
from ur_lab import POSE, virtual_lab

from recorder import RecorderError, SimulatedRig, load_actions, load_objects, record_action
from recorder._rigconfig import load_rig_config
from recorder._sim import ur10
from recorder._sim.rig import TOOL
from recorder.ur import build_ur_rig
from recorder.virtuallab._command import check_served, parse_faults, ros2_faults
from recorder.virtuallab._rtde_server import VARIABLES
from recorder.virtuallab._urscript import (
    MAX_PROGRAM_BYTES,
    Program,
    ProgramSplitter,
    parse_program,
)
from recorder.virtuallab._world import RobotState, VirtualWorld
from replay import read_recording
from replay.cli._main import main as replay_main
from replay.learning._features import file_features

ROOT = Path(__file__).resolve().parents[2]
OBJECTS, ACTIONS = load_objects(), load_actions()
PERIOD = 8_000_000


class Clock:
    """A controller clock moved by hand."""

    def __init__(self) -> None:
        self.now = 0

    def __call__(self) -> int:
        return self.now


def _world(clock: Clock, scale: float = 1.0, frequency: int = 125) -> VirtualWorld:
    sim = SimulatedRig(0).__enter__()
    return VirtualWorld(
        sim,
        OBJECTS,
        ACTIONS,
        time_scale=scale,
        clock=clock,
        frequency=frequency,
        poses={"wood": POSE},
    )


def _cycles(world: VirtualWorld, clock: Clock, count: int) -> list[RobotState]:
    states = []
    for _ in range(count):
        clock.now += world.period_ns
        states.append(world.robot_at(clock.now))
    return states


def _program(*lines: str) -> Program:
    return parse_program("def t():\n" + "".join(f"  {line}\n" for line in lines) + "end\n")


def _skin(world: VirtualWorld, modality: str, at_ns: int) -> np.ndarray:
    found = world.skin_at(modality, at_ns)
    assert found is not None
    return found


def _fk(q: np.ndarray) -> np.ndarray:
    return ur10.forward(np.asarray(q)[None], TOOL)[0, :3, 3]


def test_every_state_is_the_forward_kinematics_of_its_joints() -> None:
    clock = Clock()
    world = _world(clock)
    world.run(_program("movel(p[-0.7, -0.2, 0.15, 0.0, 3.14159, 0.0], a=0.5, v=0.05)"))
    states = _cycles(world, clock, 400)
    for state in states:
        assert np.abs(_fk(state.q) - state.tcp_pose[:3]).max() < 1e-4  # 0.1 mm
    assert np.linalg.norm(states[-1].tcp_pose[:3] - POSE[:3]) < 1e-3
    speeds = [float(np.linalg.norm(s.tcp_speed[:3])) for s in states]
    assert 0.049 < max(speeds) <= 0.05 * (1 + 1e-4)  # resolved rate: to first order
    assert speeds[-1] == 0.0


def test_a_press_left_alone_leaves_the_object_by_itself() -> None:
    # the UR driver's press: movel to depth, then, if no program replaced it (a recorder
    # killed mid-press), sleep out its lease and movel back to the contact
    from recorder.ur._script import move_program  # noqa: PLC0415

    clock = Clock()
    world = _world(clock)
    contact = np.array([-0.7, -0.2, 0.15, 0.0, 3.14159, 0.0])
    depth = contact.copy()
    depth[2] -= 0.002
    text = move_program(None, "execute", depth, 0.005, 0.5, back=tuple(contact), lease_s=1.0)
    assert "sleep(1.000)" in text
    world.place(contact)  # at the light contact
    world.run(parse_program(text))
    pressed = _cycles(world, clock, 125)  # 1 s: at depth
    assert abs(pressed[-1].tcp_pose[2] - depth[2]) < 1e-4
    later = _cycles(world, clock, 250)  # the lease out, and the way back
    assert abs(later[-1].tcp_pose[2] - contact[2]) < 1e-4
    assert float(np.linalg.norm(later[-1].tcp_speed)) == 0.0


def test_stopl_decelerates_within_its_deceleration() -> None:
    clock = Clock()
    world = _world(clock)
    world.run(_program("speedl([0.0, 0.0, 0.05, 0.0, 0.0, 0.0], 1.0, 10.0)"))
    moving = _cycles(world, clock, 20)
    assert np.isclose(moving[-1].target_tcp_speed[2], 0.05)
    world.run(_program("stopl(0.5)"))
    stopping = _cycles(world, clock, 30)
    commanded = [float(np.linalg.norm(s.target_tcp_speed[:3])) for s in [moving[-1], *stopping]]
    steps = -np.diff(commanded)
    assert steps.max() <= 0.5 * PERIOD / 1e9 + 1e-12  # never faster than a = 0.5 m/s^2
    zero = commanded.index(0.0)
    assert zero == int(np.ceil(0.05 / (0.5 * PERIOD / 1e9)))  # v / a, to the cycle
    actual = [float(np.linalg.norm(s.tcp_speed[:3])) for s in stopping]
    assert actual[zero] < 1e-6
    events = {e.kind: e for e in world.events()}
    assert events["start"].details["frequency"] == 125
    assert events["commanded_zero"].controller_ns <= events["actual_zero"].controller_ns
    assert events["program"].details["name"] == "t"


def test_a_press_on_the_rigid_block_reads_the_contact_model() -> None:
    clock = Clock()
    world = _world(clock)
    world.place(np.array(POSE))
    said = 'textmsg("atikt: object=wood action=P1 trial=1 phase=approach")'
    world.run(_program(said, "speedl([0.0, 0.0, -0.002, 0.0, 0.0, 0.0], 0.5, 30.0)"))
    touched = None
    for _ in range(2000):
        clock.now += PERIOD
        if float(_skin(world, "force", clock.now).sum()) > 0.05:
            touched = world.robot_at(clock.now).tcp_pose[2]
            break
    assert touched is not None
    assert 0.15 - 0.02 - 0.002 < touched < 0.15 - 0.02 + 0.002  # the face: 20 mm below the pose
    world.run(_program("stopl(0.5)"))
    _cycles(world, clock, 10)
    force = world.robot_at(clock.now).tcp_force
    assert force[2] > 0  # the block pushes the tool up
    cells = _skin(world, "force", clock.now)
    assert cells.shape == (7, 3)
    assert _skin(world, "temperature", clock.now).shape == (7, 1)
    assert _skin(world, "proximity", clock.now).max() < 0.01


def test_force_mode_slides_at_its_force_and_vibrates() -> None:
    clock = Clock()
    world = _world(clock)
    world.place(np.array(POSE))
    said = 'textmsg("atikt: object=wood action=S3 trial=1 phase=approach")'
    world.run(_program(said, "speedl([0.0, 0.0, -0.005, 0.0, 0.0, 0.0], 0.5, 30.0)"))
    while float(_skin(world, "force", clock.now).sum()) < 0.05:
        _cycles(world, clock, 1)
    world.run(
        _program(
            "force_mode(get_actual_tcp_pose(), [0, 0, 1, 0, 0, 0], [0.0, 0.0, 0.2, 0.0, 0.0, "
            "0.0], 2, [0.1, 0.1, 0.01, 0.3, 0.3, 0.3])",
            "speedl([0.01, 0.0, 0.0, 0.0, 0.0, 0.0], 0.5, 1.0)",
            "end_force_mode()",
            "stopl(0.5)",
        )
    )
    _cycles(world, clock, 60)
    forces, vibration = [], []
    for _ in range(60):
        clock.now += PERIOD
        world.robot_at(clock.now)
        forces.append(world.robot_at(clock.now).tcp_force[2])
        vibration.append(_skin(world, "acceleration", clock.now)[:, 0])
    assert abs(np.median(forces) - 0.2) < 0.05
    assert np.std(vibration) > 0.05  # the texture's ridges, m/s^2


def test_a_new_program_replaces_the_running_one_and_a_stop_refuses_programs() -> None:
    clock = Clock()
    world = _world(clock)
    world.run(_program("speedl([0.0, 0.0, 0.02, 0.0, 0.0, 0.0], 0.5, 10.0)"))
    _cycles(world, clock, 10)
    world.run(_program("speedl([0.0, 0.02, 0.0, 0.0, 0.0, 0.0], 0.5, 10.0)"))
    state = _cycles(world, clock, 40)[-1]
    assert np.allclose(state.target_tcp_speed[:3], [0.0, 0.02, 0.0])
    world.stop("protective")
    assert not world.run(_program("stopl(0.5)"))
    assert "protective or emergency stop" in world.log[-1]
    after = _cycles(world, clock, 3)[-1]
    assert after.safety_status == 3
    assert np.all(after.tcp_speed == 0)
    world.unlock()
    assert world.run(_program("stopl(0.5)"))


def test_the_program_state_is_served_and_a_paused_program_holds_the_arm() -> None:
    clock = Clock()
    world = _world(clock)
    assert _cycles(world, clock, 2)[-1].runtime_state == 1  # stopped: no program
    world.run(_program("speedl([0.0, 0.0, 0.02, 0.0, 0.0, 0.0], 0.5, 1.0)"))
    moving = _cycles(world, clock, 30)[-1]
    assert moving.runtime_state == 2  # playing
    assert moving.tcp_speed[2] > 0.01
    world.pause()
    held = _cycles(world, clock, 30)
    assert {state.runtime_state for state in held} == {4}  # paused
    assert np.all(held[-1].tcp_speed == 0)  # braked, and held
    world.play()
    going = _cycles(world, clock, 30)[-1]
    assert going.runtime_state == 2
    assert going.tcp_speed[2] > 0.01  # the same program goes on
    after = _cycles(world, clock, 200)  # past its second: it ends, the arm brakes, it stops
    assert [s.runtime_state for s in after][-1] == 1
    assert 0 in {s.runtime_state for s in after}  # stopping while the arm brakes
    assert [e.kind for e in world.events_log.events() if e.kind in {"pause", "play"}] == [
        "pause",
        "play",
    ]


def test_the_speed_slider_slows_the_motion_and_the_speeds_the_arm_reports() -> None:
    states = {}
    for fraction in (1.0, 0.5):
        clock = Clock()
        world = _world(clock)
        world.slide_speed(fraction)
        world.run(_program("speedl([0.0, 0.0, 0.02, 0.0, 0.0, 0.0], 0.5, 10.0)"))
        start = _cycles(world, clock, 1)[-1].tcp_pose[2]
        states[fraction] = (_cycles(world, clock, 125)[-1], start)
    (full, full_start), (half, half_start) = states[1.0], states[0.5]
    assert full.tcp_speed[2] == pytest.approx(0.02, rel=1e-3)
    assert half.tcp_speed[2] == pytest.approx(0.01, rel=1e-3)
    # the joints too (at another pose after a second: their share differs by a few %)
    ratio = np.linalg.norm(half.qd) / np.linalg.norm(full.qd)
    assert ratio == pytest.approx(0.5, rel=0.05)
    # and where it went: half as far in the same second
    assert half.tcp_pose[2] - half_start == pytest.approx(
        (full.tcp_pose[2] - full_start) / 2, rel=0.05
    )


def test_programs_and_the_log_are_bounded() -> None:
    splitter = ProgramSplitter()
    chunk = "x" * 65536
    programs, refusals = splitter.feed("def huge():\n")
    for _ in range(50 * 16):  # 50 MB without an end
        more, refused = splitter.feed(chunk)
        programs += more
        refusals += refused
    assert programs == []
    assert len(refusals) == 1
    assert f"more than {MAX_PROGRAM_BYTES} bytes" in refusals[0]
    assert len(splitter.rest) <= MAX_PROGRAM_BYTES
    more, refused = splitter.feed("\nend\nstopl(0.5)\n")
    assert (more, refused) == (["stopl(0.5)\n"], [])
    clock = Clock()
    world = _world(clock)
    for index in range(5000):
        world.note(f"line {index}")
    assert len(world.log) == 1000
    assert world.log[-1] == "line 4999"


def test_the_served_variables_include_the_tcp_speed() -> None:
    assert VARIABLES["actual_TCP_speed"][0] == "VECTOR6D"
    assert VARIABLES["target_TCP_speed"][0] == "VECTOR6D"


def test_faults_for_sources_not_served_are_refused_in_one_line(tmp_path: Path) -> None:
    faults = parse_faults(["skin.drop=3"])
    with pytest.raises(RecorderError) as info:
        check_served(faults, {"skin": False, "ros2": False})
    assert str(info.value) == (
        "--fault skin.*: the skin server is not served; add --skin URL or drop the fault"
    )
    with pytest.raises(RecorderError, match=r"no such server"):
        check_served(parse_faults(["arm.drop=1"]), {})
    from recorder.virtuallab._ros2_server import Ros2Faults  # noqa: PLC0415

    made = ros2_faults(Ros2Faults, {"drop": 3.0}, ROOT / "recorder/data/topic_map.example.toml")
    assert made.drop
    assert set(made.drop.values()) == {3}
    del tmp_path


def _served_lab(tmp_path: Path) -> tuple[Path, list[str]]:
    """Return the served-actions test's rig configuration and its serve-sim command."""
    # serve-sim in its own process (as at a robot: the lab never competes with the rig for
    # this interpreter), the UR rig with the example configuration and a UDP skin here.
    rtde, script = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_STREAM)
    udp = free_port(socket.SOCK_DGRAM)
    text = (ROOT / "recorder/data/ur_rig.example.toml").read_text("utf-8")
    text = text.replace("rtde_port = 30004", f"rtde_port = {rtde}")
    text = text.replace("script_port = 30001", f"script_port = {script}")
    text = text.replace("# time_scale = 0.1", "time_scale = 0.2")
    # The skin's 21 force sensors sum their noise (sd 0.009 N) and drift (0.002 N/s): over an
    # approach the peak of single samples may cross the catalog's 0.05 N before the touch (a
    # false light contact). A lab raises the threshold: 0.15 N. The approach is the example's:
    # its speed from proximity (up to 20 mm/s far from the block), 2 mm/s at the contact.
    text = text.replace("contact_force_n = 0.05", "contact_force_n = 0.15")
    text = text.replace("silence_s = 0.5", "silence_s = 2.0")
    skin = (ROOT / "recorder/data/skin_udp.example.toml").read_text("utf-8")
    skin = skin.replace('bind = "127.0.0.1:5005"', f'bind = "127.0.0.1:{udp}"')
    text = text[: text.index("\n[skin]\n") + 1] + skin[skin.index("\n[skin]\n") + 1 :]
    lab = tmp_path / "lab.toml"
    lab.write_text(text, "utf-8")
    command = [sys.executable, "-m", "recorder", "serve-sim", "--time-scale", "0.2"]
    command += ["--rtde-port", str(rtde), "--script-port", str(script), "--rig-config", str(lab)]
    command += ["--skin", f"udp://127.0.0.1:{udp}", "--events", str(tmp_path / "events.jsonl")]
    return lab, command


@pytest.mark.slow(25)
def test_over_ten_actions_served_every_action_starts_where_the_first_did(
    tmp_path: Path,
) -> None:
    # Fifty actions run in process (test_sim_ur10_runner): the same world and driver code,
    # stepped on a simulated clock. Here ten go over the wires, with serve-sim at real time.
    lab, command = _served_lab(tmp_path)
    env = os.environ | {"PYTHONPATH": str(ROOT)}
    served = forked.Popen(
        command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    obj, out = OBJECTS["wood"], tmp_path / "out"
    starts: list[float] = []
    try:
        assert served.stdout is not None
        assert served.stdout.readline().startswith("virtual lab listening")
        with build_ur_rig(0, load_rig_config(lab)) as rig:
            assert rig.present(obj)
            for trial in range(1, 11):
                path = out / f"{trial:03d}.mcap"
                record_action(rig, obj, ACTIONS["P1"], trial, path, seed=0)
                recording = read_recording(path)
                assert recording.tcp is not None
                starts.append(float(recording.tcp.position[0, 2]))
            slide = out / "slide" / "001.mcap"
            record_action(rig, obj, ACTIONS["S1"], 1, slide, seed=0)
    finally:
        served.send_signal(signal.SIGINT)
        served.communicate(timeout=30)
    first = starts[0]
    # The lab keeps the block and the arm where they are, and each retract returns to where
    # the approach began (the object's pose): every start within 1 mm of the first.
    off = [(trial, round(z, 6)) for trial, z in enumerate(starts, 1) if abs(z - first) >= 1e-3]
    assert not off, f"first start z {first:.6f}; trials off by 1 mm: {off}"
    assert abs(np.median(starts[-3:]) - np.median(starts[:3])) < 2e-4, off  # no sinking
    events = [json.loads(line) for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    assert sum(1 for e in events if e["event"] == "program") > 30
    assert replay_main(["check", str(out)]) == 0
    pressed = file_features(out / "001.mcap")
    slid = file_features(slide)
    assert set(pressed.blocks) == {"force", "thermal"}
    assert set(slid.blocks) == {"texture", "thermal"}
    for features in (pressed, slid):
        assert all(np.isfinite(np.asarray(v)).all() for v in features.blocks.values())


def test_ur_rtde_and_the_lab_agree_on_joints_and_tcp() -> None:
    pytest.importorskip("rtde_receive")
    script = """
import json, time, rtde_receive
receiver = rtde_receive.RTDEReceiveInterface(
    "127.0.0.1", 125.0, ["timestamp", "actual_q", "actual_TCP_pose"]
)
rows = []
for _ in range(40):
    # the TCP read before and after the joints: equal when no package came in between
    rows.append([receiver.getActualTCPPose(), receiver.getActualQ(), receiver.getActualTCPPose()])
    time.sleep(0.02)
print(json.dumps(rows))
receiver.disconnect()
"""
    with socket.socket() as probe:
        try:
            probe.bind(("127.0.0.1", 30004))
        except OSError:
            pytest.skip("127.0.0.1:30004 is in use; ur_rtde connects to no other port")
    from recorder.virtuallab._controller import VirtualController  # noqa: PLC0415
    from recorder.virtuallab._rtde_server import RtdeServer  # noqa: PLC0415

    with virtual_lab(time_scale=1.0) as lab:
        lab.script.run("movel(p[-0.7, -0.25, 0.12, 0.0, 3.14159, 0.0], a=0.5, v=0.05)\n")
        with RtdeServer(VirtualController(lab.world), "127.0.0.1", 30004, frequency=125):
            done = forked.run(
                [sys.executable, "-c", script],
                capture_output=True,
                text=True,
                timeout=60,
                check=True,
            )
    rows = json.loads(done.stdout.strip().splitlines()[-1])
    poses = np.array([tcp for tcp, _, _ in rows])
    assert np.ptp(poses[:, 1]) > 0.005  # read while the arm moved
    # ur_rtde reads one value at a time: a row is one package's when both TCP reads agree
    clean = [(q, tcp) for tcp, q, again in rows if tcp == again]
    assert len(clean) >= 10, f"only {len(clean)} of 40 reads within one package"
    for q, tcp in clean:
        assert np.abs(_fk(np.array(q)) - np.array(tcp)[:3]).max() < 1e-4


def test_a_skin_that_cannot_be_served_ends_the_lab_with_one_line(tmp_path: Path) -> None:
    # 6000 cells: a frame larger than a UDP datagram. The lab does not go on serving an arm
    # without its skin (a session would only see a silent skin): it ends, and says why
    lab, command = _served_lab(tmp_path)
    lab.write_text(lab.read_text("utf-8").replace("cells = 7 ", "cells = 6000 "), "utf-8")
    env = os.environ | {"PYTHONPATH": str(ROOT)}
    done = forked.run(command, env=env, capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 1, done.stdout + done.stderr
    assert done.stdout.startswith("virtual lab listening")
    # one error line (a loaded machine may add the lab's own note that it runs behind)
    (line,) = [said for said in done.stderr.splitlines() if "error" in said]
    assert line.startswith("atikt-record: error: skin server to udp://127.0.0.1:"), line
    assert "sending failed ([Errno 90] Message too long)" in line


def test_serve_sim_prints_and_writes_what_it_injected(tmp_path: Path) -> None:
    events, summary = tmp_path / "events.jsonl", tmp_path / "faults.json"
    ports = [free_port(), free_port()]
    command = [sys.executable, "-m", "recorder", "serve-sim", "--rtde-port", str(ports[0])]
    command += ["--script-port", str(ports[1]), "--events", str(events)]
    command += ["--fault-summary", str(summary), "--fault", "script.protective_stop=0.05"]
    env = os.environ | {"PYTHONPATH": str(ROOT)}
    process = forked.Popen(
        command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    assert process.stdout is not None
    assert process.stdout.readline().startswith("virtual lab listening")
    with socket.create_connection(("127.0.0.1", ports[1])) as sock:
        said = 'textmsg("atikt: object=wood action=P1 trial=1 phase=approach")'
        move = "speedl([0, 0, -0.002, 0, 0, 0], 0.5, 5)"
        sock.sendall(f"def a():\n  {said}\n  {move}\nend\n".encode())
        time.sleep(0.5)
    process.send_signal(signal.SIGINT)
    out, err = process.communicate(timeout=30)
    assert process.returncode == 0, err
    lines = out.strip().splitlines()
    faults = [line for line in lines if line.startswith("fault: ")]
    assert len(faults) == 1, out
    assert faults[0].startswith("fault: script.protective_stop at controller"), out
    assert json.loads(summary.read_text("utf-8")) == {"faults": {"script": {"protective_stop": 1}}}
    records = [json.loads(line) for line in events.read_text("utf-8").splitlines()]
    kinds = [record["event"] for record in records]
    assert kinds[:2] == ["start", "program"]
    assert {"action", "fault", "stop", "summary"} <= set(kinds)
    program = records[1]
    assert program["received_monotonic_ns"] <= program["monotonic_ns"]
    refused = forked.run(
        [sys.executable, "-m", "recorder", "serve-sim", "--fault", "ros2.drop=3"],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert refused.returncode != 0
    assert (
        refused.stderr.strip()
        .splitlines()[-1]
        .endswith("--fault ros2.*: the ros2 server is not served; add --ros2 or drop the fault")
    )


def test_the_dashboard_releases_a_protective_stop() -> None:
    from recorder.virtuallab._dashboard import DashboardServer  # noqa: PLC0415

    with virtual_lab() as lab, DashboardServer(lab.controller, "127.0.0.1", 0) as dashboard:
        lab.world.stop("protective")
        with socket.create_connection(("127.0.0.1", dashboard.address[1]), timeout=5) as sock:
            reader = sock.makefile("r")
            assert reader.readline().startswith("Connected: Universal Robots Dashboard")

            def ask(command: str) -> str:
                sock.sendall(f"{command}\n".encode())
                return reader.readline().strip()

            assert ask("robotmode") == "Robotmode: RUNNING"
            assert ask("safetymode") == "Safetymode: PROTECTIVE_STOP"
            assert ask("unlock protective stop") == "Protective stop releasing"
            assert ask("safetymode") == "Safetymode: NORMAL"
            lab.script.run("speedl([0.0, 0.0, 0.01, 0.0, 0.0, 0.0], 0.5, 100.0)\n")
            time.sleep(0.2)
            assert ask("stop") == "Stopped"
            assert ask("explode") == "could not understand: 'explode'"
        time.sleep(0.3)
        state = lab.world.robot_at(lab.world.controller_ns())
        assert np.all(state.target_tcp_speed == 0)


#: ur_rtde's dashboard client, in its own process (its calls hold the GIL while they wait).
_UR_RTDE_DASHBOARD = """
import json, sys
from dashboard_client import DashboardClient
client = DashboardClient("127.0.0.1", int(sys.argv[1]))
client.connect()
answers = {
    "version": client.polyscopeVersion(),
    "remote": client.isInRemoteControl(),
    "running": client.running(),
    "model": client.getRobotModel(),
    "mode": str(client.robotmode()),
}
client.powerOff()
answers["off"] = str(client.robotmode())
client.powerOn()
client.brakeRelease()
answers["on"] = str(client.robotmode())
client.disconnect()
print(json.dumps(answers))
"""


@pytest.mark.parametrize(
    ("frequency", "version", "remote"), [(125, "3.15.7", False), (500, "5.11.0", True)]
)
def test_ur_rtdes_dashboard_client_drives_the_lab(
    frequency: int, version: str, *, remote: bool
) -> None:
    # a lab rehearses its own ur_rtde scripts: what they ask before they start is answered,
    # and the e-Series' remote-control query only where PolyScope 5.6+ knows it
    pytest.importorskip("dashboard_client")
    from recorder.virtuallab._dashboard import DashboardServer  # noqa: PLC0415

    with (
        virtual_lab(frequency=frequency) as lab,
        DashboardServer(lab.controller, "127.0.0.1", 0) as dashboard,
    ):
        done = forked.run(
            [sys.executable, "-c", _UR_RTDE_DASHBOARD, str(dashboard.address[1])],
            capture_output=True,
            text=True,
            timeout=60,
            check=True,
        )
    answers = json.loads(done.stdout.strip().splitlines()[-1])
    assert answers["version"].startswith(f"{version}.")  # parsed from 'URSoftware 5.11.0.0 ...'
    assert answers["remote"] is remote
    assert answers["running"] is False
    assert answers["model"] == "UR10"
    modes = (answers["mode"], answers["off"], answers["on"])
    assert modes == ("Robotmode: RUNNING", "Robotmode: POWER_OFF", "Robotmode: RUNNING")


def test_the_dashboard_powers_the_arm_off_and_on() -> None:
    from recorder.virtuallab._dashboard import DashboardServer  # noqa: PLC0415

    with virtual_lab() as lab, DashboardServer(lab.controller, "127.0.0.1", 0) as dashboard:
        with socket.create_connection(("127.0.0.1", dashboard.address[1]), timeout=5) as sock:
            reader = sock.makefile("r")
            reader.readline()

            def ask(command: str) -> str:
                sock.sendall(f"{command}\n".encode())
                return reader.readline().strip()

            def mode() -> int:
                time.sleep(0.05)  # the next cycles' states (what RTDE sends) carry it
                return lab.world.robot_at(lab.world.controller_ns()).robot_mode

            assert ask("power off") == "Powering off"
            assert (ask("robotmode"), mode()) == ("Robotmode: POWER_OFF", 3)
            assert ask("brake release") == "Brake releasing"  # not from powered off
            assert mode() == 3
            start = lab.world.robot_at(lab.world.controller_ns()).tcp_pose.copy()
            lab.script.run("speedl([0.0, 0.0, 0.05, 0.0, 0.0, 0.0], 0.5, 100.0)\n")
            time.sleep(0.3)
            assert "the arm is not running" in " ".join(lab.controller.log)
            assert ask("power on") == "Powering on"
            assert (ask("robotmode"), mode()) == ("Robotmode: IDLE", 5)
            lab.script.run("speedl([0.0, 0.0, 0.05, 0.0, 0.0, 0.0], 0.5, 100.0)\n")
            time.sleep(0.3)
            held = lab.world.robot_at(lab.world.controller_ns()).tcp_pose
            np.testing.assert_allclose(held, start, atol=1e-9)  # brakes engaged: no motion
            assert ask("brake release") == "Brake releasing"
            assert (ask("robotmode"), mode()) == ("Robotmode: RUNNING", 7)
            lab.script.run("speedl([0.0, 0.0, 0.05, 0.0, 0.0, 0.0], 0.5, 100.0)\n")
            time.sleep(0.3)
            moved = lab.world.robot_at(lab.world.controller_ns()).tcp_pose
            assert moved[2] > start[2] + 1e-3
            assert ask("programState") == "PLAYING"
            assert ask("play") == "Failed to execute: play"  # nothing paused
            assert ask("pause") == "Pausing program"
            time.sleep(0.05)
            assert ask("programState") == "PAUSED"
            assert ask("play") == "Starting program"
            time.sleep(0.05)
            assert ask("programState") == "PLAYING"
            assert ask("stop") == "Stopped"
            time.sleep(0.05)
            assert ask("programState") == "STOPPED"
        modes = [e.details["robot_mode"] for e in lab.world.events_log.events("mode")]
        assert modes == [3, 5, 7]


def test_the_skins_readings_go_on_from_one_action_to_the_next() -> None:
    clock = Clock()
    world = _world(clock)

    def mean_force(cycles: int) -> np.ndarray:
        samples = []
        for _ in range(cycles):
            _cycles(world, clock, 1)
            samples += [_skin(world, "force", clock.now - k * 1_000_000) for k in range(8)]
        mean: np.ndarray = np.mean(samples, axis=0)
        return mean

    said = 'textmsg("atikt: object=foam_block action={} trial=1 phase=approach")'
    world.run(_program(said.format("P1")))
    _cycles(world, clock, 400)  # 3.2 s: the offsets drift
    before = mean_force(20)
    world.run(_program(said.format("S1")))  # a new execution: its own spot and gains
    after = mean_force(20)
    assert world.action_at(clock.now) == ("foam_block", "S1", 1)
    # in free air a reading is offset, drift and noise: the offsets go on (redrawn, they would
    # move by 0.003 N per sensor; the means of 160 samples differ by noise and drift only)
    assert np.abs(after - before).max() < 0.0015


def test_every_phase_announced_is_kept_in_order_for_a_late_reader() -> None:
    clock = Clock()
    world = _world(clock)
    said = "atikt: object=wood action=P1 trial=1 phase="
    world.run(_program(f'textmsg("{said}approach")', f'textmsg("{said}contact")'))
    _cycles(world, clock, 2)
    world.run(
        _program(f'textmsg("{said}execute")', "speedl([0.0, 0.0, 0.01, 0.0, 0.0, 0.0], 0.5, 0.1)")
    )
    _cycles(world, clock, 5)
    world.run(_program(f'textmsg("{said}retract")'))
    _cycles(world, clock, 2)
    early, position = world.announcements(0, 2 * world.period_ns)
    assert [phase for _, _, phase in early] == ["approach", "contact"]  # one cycle, both kept
    late, end = world.announcements(position, clock.now)  # a reader that ran late
    assert [phase for _, _, phase in late] == ["execute", "retract"]
    stamps = [at for at, _, _ in early + late]
    assert stamps == sorted(stamps)
    assert all(key == ("wood", "P1", 1) for _, key, _ in early + late)
    assert world.announcements(end, clock.now) == ([], end)
