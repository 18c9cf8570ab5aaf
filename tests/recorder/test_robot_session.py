"""Sessions at the robot, rehearsed end to end: `atikt-record serve-sim` in its own process
serves the simulator over RTDE, URScript and the skin's own transport (UDP frames, or ROS 2
topics over DDS on loopback); `atikt-record session --rig-config LAB.toml` drives the UR rig
against it; every file passes `check` with every source's samples accounted for."""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import forked
import pytest
from ports import free_port

from recorder._cli import main as record
from replay import read_recording
from replay.cli._main import main as replay
from schemas import dataset_recordings

if TYPE_CHECKING:
    from collections.abc import Iterator

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "recorder" / "data"
#: Real seconds per world second of the virtual lab, which executes the rig's URScript: the
#: rig's reaction time (UDP ~10 ms, DDS ~50 ms) counts 1 / TIME_SCALE times over in world
#: motion; keep it large enough for the 1 mm press check.
TIME_SCALE = "0.1"
#: The ROS 2 lab (DDS latency ~50 ms) at 0.5: the rig's reaction time counts twice over in world
#: motion, half as much as at 0.25, which a test machine running other tests beside it needs.
ROS2_TIME_SCALE = "0.5"


def _lab(tmp_path: Path, rtde: int, script: int, skin: str, scale: str = TIME_SCALE) -> Path:
    """Write the example UR configuration with this test's ports and a skin table."""
    text = (DATA / "ur_rig.example.toml").read_text("utf-8")
    text = text.replace("rtde_port = 30004", f"rtde_port = {rtde}")
    text = text.replace("script_port = 30001", f"script_port = {script}")
    text = text.replace("# time_scale = 0.1", f"time_scale = {scale}")
    # the session's workflow is under test here, not the silence check (test_runner_stops):
    # a test machine running other tests beside this one may pause a process for 0.5 s
    text = text.replace("silence_s = 0.5 ", "silence_s = 2.0 ")
    text = text[: text.index("\n[skin]\n") + 1] + skin
    lab = tmp_path / "lab.toml"
    lab.write_text(text, "utf-8")
    return lab


@contextlib.contextmanager
def _serve_sim(*options: str, scale: str = TIME_SCALE) -> Iterator[subprocess.Popen[str]]:
    """Run the virtual lab in its own process until the block ends (then Ctrl-C it)."""
    command = [sys.executable, "-m", "recorder", "serve-sim", "--time-scale", scale]
    env = os.environ | {"PYTHONPATH": str(ROOT)}
    process = forked.Popen(
        [*command, *options], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    failed = True
    try:
        assert process.stdout is not None
        assert process.stderr is not None
        line = process.stdout.readline()
        assert line.startswith("virtual lab listening"), line + process.stderr.read()
        assert "127.0.0.1" in line
        yield process
        failed = False
    finally:
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=20)
        if failed:  # the controller's log (refused programs, faults) beside the failure
            sys.stderr.write(f"virtual lab's log:\n{err}")
    assert process.returncode == 0, err
    said = [line for line in out.splitlines() if not line.startswith(("fault: ", "stop: "))]
    assert said == ["virtual lab stopped"], out


def _session(
    lab: Path, out: Path, capsys: pytest.CaptureFixture[str], objects: str = "wood,foam_block"
) -> str:
    argv = ["session", "--rig-config", str(lab), "--objects", objects]
    argv += ["--actions", "P1,S1", "--trials", "1", "--out", str(out), "--yes"]
    status = record(argv)
    printed = capsys.readouterr()
    assert status == 0, printed.err
    return printed.out


def _check_every_sample(
    out: Path,
    capsys: pytest.CaptureFixture[str],
    sources: set[str],
    objects: tuple[str, ...] = ("foam_block", "wood"),
) -> None:
    files = dataset_recordings(out)
    assert [f.relative_to(out).as_posix() for f in files] == [
        f"{obj}/{action}/001.mcap" for obj in objects for action in ("P1", "S1")
    ]
    status = replay(["check", str(out), "--workers", "1"])
    checked = capsys.readouterr()
    assert status == 0, checked.out + checked.err
    assert f"{len(files)} of {len(files)} recordings valid" in checked.out
    assert "WARN" not in checked.err, checked.err
    for file in files:
        recording = read_recording(file)
        assert recording.metadata.rig["kind"] == "ur"
        assert [mark.phase for mark in recording.phases] == [
            "approach",
            "contact",
            "execute",
            "retract",
            "end",
        ]
        named = {item.name for item in recording.sources}
        assert sources <= named, named
        for item in recording.sources:
            assert item.expected > 0
            assert item.missing == item.duplicated == item.out_of_order == 0, item


@pytest.mark.slow(5)
def test_a_dry_run_checks_the_rig_and_moves_and_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rtde, script = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_STREAM)
    dashboard, udp = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_DGRAM)
    skin = (DATA / "skin_udp.example.toml").read_text("utf-8")
    skin = skin.replace('bind = "127.0.0.1:5005"', f'bind = "127.0.0.1:{udp}"')
    lab = _lab(tmp_path, rtde, script, skin[skin.index("\n[skin]\n") + 1 :])
    lab.write_text(
        lab.read_text("utf-8").replace("dashboard_port = 29999", f"dashboard_port = {dashboard}")
    )
    out, events = tmp_path / "session", tmp_path / "events.jsonl"
    served = ["--rtde-port", str(rtde), "--script-port", str(script), "--rig-config", str(lab)]
    served += ["--skin", f"udp://127.0.0.1:{udp}", "--dashboard-port", str(dashboard)]
    argv = ["session", "--rig-config", str(lab), "--objects", "wood,glass_plate"]
    argv += ["--actions", "P1,S1", "--trials", "2", "--out", str(out), "--dry-run"]
    with _serve_sim(*served, "--events", str(events)):
        ready = record(argv)
        said = capsys.readouterr()
        with socket.create_connection(("127.0.0.1", dashboard), timeout=5) as sock:
            reader = sock.makefile("r")
            reader.readline()
            sock.sendall(b"power off\n")
            assert reader.readline().startswith("Powering off")
        refused = record(argv)
        refusal = capsys.readouterr()
    assert ready == 0, said.err
    lines = said.out.splitlines()
    assert lines[0] == (
        f"dry run of session {out}: 8 to record, 0 on disk (kept); nothing moved, nothing written"
    )
    assert lines[1] == "objects presented by the rig: wood; placed by hand: glass_plate"
    assert lines[2].startswith("rig: ready (controller_version ")
    assert f"dashboard port {dashboard} answers" in lines[2], lines[2]  # the stop's second way
    assert any(line.startswith("  rtde: ") and line.endswith(", complete") for line in lines)
    assert any(line.startswith("  skin-") for line in lines)
    assert refused == 1
    assert "the arm cannot start an action: arm not running (powered off" in refusal.err
    assert refusal.err.count("\n") == 1
    assert not out.exists()  # nothing written
    kinds = [json.loads(line)["event"] for line in events.read_text().splitlines()]
    assert {"start", "mode"} <= set(kinds)  # the lab's log, read: the start, the power off
    assert "program" not in kinds  # and nothing sent that moves


@pytest.mark.slow(9)
def test_a_session_with_a_udp_skin(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rtde, script = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_STREAM)
    udp = free_port(socket.SOCK_DGRAM)
    skin = (DATA / "skin_udp.example.toml").read_text("utf-8")
    skin = skin.replace('bind = "127.0.0.1:5005"', f'bind = "127.0.0.1:{udp}"')
    lab = _lab(tmp_path, rtde, script, skin[skin.index("\n[skin]\n") + 1 :])
    out = tmp_path / "session"
    served = ["--rtde-port", str(rtde), "--script-port", str(script), "--rig-config", str(lab)]
    with _serve_sim(*served, "--skin", f"udp://127.0.0.1:{udp}"):
        printed = _session(lab, out, capsys)
    assert len(re.findall(r"\btrial 1\b", printed)) == 4, printed
    _check_every_sample(out, capsys, {"rtde", "skin-fast", "skin-proximity", "skin-temperature"})
    for file in dataset_recordings(out):  # the skin's sender is recorded with its samples
        origins = {item.name: item.origin for item in read_recording(file).sources}
        assert re.fullmatch(r"127\.0\.0\.1:\d+", origins["skin-fast"]), origins
        assert origins["skin-proximity"] == origins["skin-temperature"] == origins["skin-fast"]
        assert origins["rtde"] == ""  # the configuration names the controller


@pytest.mark.slow(15)
def test_a_session_with_a_ros2_skin(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], dds_domain: int
) -> None:
    pytest.importorskip("cyclonedds")
    rtde, script = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_STREAM)
    topic_map = DATA / "topic_map.example.toml"
    skin = f'[skin]\ntransport = "ros2"\ntopic_map = "{topic_map}"\ndomain_id = {dds_domain}\n'
    lab = _lab(tmp_path, rtde, script, skin, ROS2_TIME_SCALE)
    out = tmp_path / "session"
    served = ["--rtde-port", str(rtde), "--script-port", str(script), "--ros2"]
    served += ["--topic-map", str(topic_map), "--domain-id", str(dds_domain)]
    # one object (a press and a slide): the ROS 2 lab runs at half real time, and two objects'
    # presentation is the UDP session's test
    with _serve_sim(*served, scale=ROS2_TIME_SCALE):
        _session(lab, out, capsys, objects="wood")
    cells = {"rtde", *(f"skin/cell_{c}" for c in range(7))}
    _check_every_sample(out, capsys, cells, objects=("wood",))


def _last_log_ns(path: Path) -> int:
    from mcap.reader import make_reader  # noqa: PLC0415

    with path.open("rb") as stream:
        return max(message.log_time for _, _, message in make_reader(stream).iter_messages())


@pytest.mark.slow(8)
def test_a_killed_live_recorder_loses_less_than_half_a_second(tmp_path: Path) -> None:
    from replay import salvage  # noqa: PLC0415

    rtde, script = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_STREAM)
    udp = free_port(socket.SOCK_DGRAM)
    skin = (DATA / "skin_udp.example.toml").read_text("utf-8")
    skin = skin.replace('bind = "127.0.0.1:5005"', f'bind = "127.0.0.1:{udp}"')
    lab = _lab(tmp_path, rtde, script, skin[skin.index("\n[skin]\n") + 1 :], "0.3")
    out = tmp_path / "data"
    served = ["--rtde-port", str(rtde), "--script-port", str(script), "--rig-config", str(lab)]
    served += ["--skin", f"udp://127.0.0.1:{udp}"]
    command = [sys.executable, "-m", "recorder", "action", "--rig-config", str(lab)]
    command += ["--object", "wood", "--action", "C1", "--trial", "1", "--out", str(out)]
    with _serve_sim(*served, scale="0.3") as lab_process:
        del lab_process
        recorder = forked.Popen(
            command, env=os.environ | {"PYTHONPATH": str(ROOT)}, stderr=subprocess.PIPE
        )
        deadline = time.monotonic() + 30
        parts: list[Path] = []
        while not parts and time.monotonic() < deadline and recorder.poll() is None:
            parts = sorted(out.rglob("*.mcap.part"))
            time.sleep(0.05)
        assert parts, recorder.stderr.read() if recorder.stderr else ""
        time.sleep(2.0)  # well inside the 4.5 s hold (C1 at time_scale 0.3)
        killed_ns = time.time_ns()
        recorder.send_signal(signal.SIGKILL)
        recorder.communicate(timeout=10)  # reaps it and closes its pipe
    assert recorder.returncode == -signal.SIGKILL
    assert not (out / "wood" / "C1" / "001.mcap").exists()
    report = salvage(parts[0])
    lost_s = (killed_ns - _last_log_ns(report.target)) / 1e9
    assert 0 <= lost_s < 0.5, lost_s


@pytest.mark.slow(14)
def test_live_learning_at_the_virtual_robot_replays_offline(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rtde, script = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_STREAM)
    udp = free_port(socket.SOCK_DGRAM)
    skin = (DATA / "skin_udp.example.toml").read_text("utf-8")
    skin = skin.replace('bind = "127.0.0.1:5005"', f'bind = "127.0.0.1:{udp}"')
    lab = _lab(tmp_path, rtde, script, skin[skin.index("\n[skin]\n") + 1 :])
    served = ["--rtde-port", str(rtde), "--script-port", str(script), "--rig-config", str(lab)]
    run = ["--new", "wood,foam_block", "--actions", "P1", "--budget", "2", "--test-trials", "1"]
    # priors from the committed recordings (not the default dataset: nothing to generate)
    run += ["--recordings", str(ROOT / "recordings" / "data"), "--priors", "soft_sponge,pine_board"]
    out = tmp_path / "live"
    events = tmp_path / "events.jsonl"
    with _serve_sim(*served, "--skin", f"udp://127.0.0.1:{udp}", "--events", str(events)):
        learn = ["learn", "--rig-config", str(lab), *run, "--out", str(out)]
        # the dry run first: the plan and the rig, nothing moved, nothing written
        ready = replay([*learn, "--dry-run"])
        said = capsys.readouterr()
        absent = [*learn[:3], "--new", "wood,metal_toolbox", *learn[5:], "--dry-run"]
        refused = replay(absent)
        refusal = capsys.readouterr()
        assert not out.exists()
        moved = "program" in events.read_text()
        live = replay(learn)
    printed = capsys.readouterr()
    assert ready == 0, said.err
    lines = said.out.splitlines()
    assert lines[0] == (
        f"dry run of live learning: a new run into {out}; 2 held-out recordings, then 2 first "
        "observations and up to 2 the learner chooses; 0 on disk (reused); nothing moved, "
        "nothing written"
    )
    assert lines[1] == "objects presented by the rig: foam_block, wood; placed by hand: -"
    assert lines[2].startswith("rig: ready (controller_version ")
    assert any(line.startswith("  rtde: ") and line.endswith(", complete") for line in lines)
    assert refused == 1
    assert "the rig has no pose for metal_toolbox: live learning presents" in refusal.err
    assert refusal.err.count("\n") == 1
    assert not moved  # the lab received no program during either dry run
    assert live == 0, printed.err
    steps = [line for line in printed.out.splitlines() if line.startswith("step")]
    assert len(steps) == 3
    session = tmp_path / "live" / "session"
    again = replay(["learn", "--session", str(session), *run, "--out", str(tmp_path / "off")])
    replayed = capsys.readouterr()
    assert again == 0, replayed.err
    assert [line for line in replayed.out.splitlines() if line.startswith("step")] == steps


_STOPPED = {
    "SIGTERM": 143,
    "SIGKILL": -signal.SIGKILL,
    "SIGSTOP": 1,  # cannot be caught: when continued, the action ends (the arm was unwatched)
    "disconnect": 1,
    "protective": 1,
}
_FAULTS = {
    "disconnect": ["--fault", "rtde.disconnect=1"],
    "protective": ["--fault", "script.protective_stop=0.5"],
}


def _interrupted_session(
    argv: list[str], out: Path, cause: str, capsys: pytest.CaptureFixture[str]
) -> tuple[int, str]:
    """Run a session stopped by ``cause``; return its exit status and what it said on stderr.

    A signal is sent to a session in its own process, during its second action. A fault of
    the lab's stops a session run in this process, as the resumed one is: the same command,
    and no signal of the test's to send it, so no process of its own (a Python start saved).
    """
    if cause in _FAULTS:
        status = record(argv)
        return status, capsys.readouterr().err
    command = [sys.executable, "-m", "recorder", *argv]
    run = forked.Popen(
        command, env=os.environ | {"PYTHONPATH": str(ROOT)}, stderr=subprocess.PIPE, text=True
    )
    number = getattr(signal, cause)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and run.poll() is None:
        # a part being written: not the one a finished recording leaves for a moment while
        # it is published (both names exist between the link and the unlink)
        parts = out.rglob("*.mcap.part")  # <trial>.<pid>-<token>.mcap.part of <trial>.mcap
        writing = [p for p in parts if not p.with_name(f"{p.name.split('.')[0]}.mcap").exists()]
        if list(out.rglob("???.mcap")) and writing:
            # well inside the action (about 0.4 s at this time scale), also on a loaded machine
            time.sleep(0.05)
            run.send_signal(number)
            if number == signal.SIGSTOP:  # stopped for a second, as a debugger or kill -STOP
                time.sleep(1.0)
                run.send_signal(signal.SIGCONT)
            break
        time.sleep(0.02)
    _, err = run.communicate(timeout=120)
    return run.returncode, err


@pytest.mark.slow(14)
@pytest.mark.parametrize(
    # Ctrl-Z (SIGTSTP) is sent to a recording process in tests/recorder/test_runner_stops.py;
    # SIGSTOP cannot be caught, so only a process of its own can be stopped
    "cause",
    ["SIGTERM", "SIGKILL", "SIGSTOP", "disconnect", "protective"],
)
def test_a_session_resumes_after_anything_with_exactly_the_planned_trials(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], cause: str
) -> None:
    rtde, script = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_STREAM)
    udp = free_port(socket.SOCK_DGRAM)
    skin = (DATA / "skin_udp.example.toml").read_text("utf-8")
    skin = skin.replace('bind = "127.0.0.1:5005"', f'bind = "127.0.0.1:{udp}"')
    lab = _lab(tmp_path, rtde, script, skin[skin.index("\n[skin]\n") + 1 :])
    out = tmp_path / "session"
    served = ["--rtde-port", str(rtde), "--script-port", str(script), "--rig-config", str(lab)]
    served += ["--skin", f"udp://127.0.0.1:{udp}"]
    argv = ["session", "--rig-config", str(lab), "--objects", "wood,foam_block"]
    argv += ["--actions", "S1", "--out", str(out), "--yes", "--trials"]
    with _serve_sim(*served, *_FAULTS.get(cause, [])):
        status, err = _interrupted_session([*argv, "1"], out, cause, capsys)
    assert status == _STOPPED[cause], err
    if cause == "SIGTERM":
        assert "interrupted by SIGTERM: the arm was stopped" in err
    if cause == "SIGSTOP":
        assert "the recorder was stopped (SIGSTOP) while the arm moved, and continued" in err
        assert err.count("\n") == 1, err
    if cause == "protective":  # in an action, or while moving to the next object
        assert "protective stop" in err
        assert err.count("\n") == 1
    if cause == "disconnect":  # in an action or while moving to an object: one line either way
        assert "connection lost" in err
        assert err.count("\n") == 1
    with _serve_sim(*served):  # a fresh lab: after a protective stop the arm waits for the pendant
        assert record([*argv, "2"]) == 0
    printed = capsys.readouterr()
    if cause == "SIGKILL":
        assert "unfinished recording of a stopped recorder set aside" in printed.out
    files = [f.relative_to(out).as_posix() for f in dataset_recordings(out)]
    assert files == [f"{o}/S1/{t:03d}.mcap" for o in ("foam_block", "wood") for t in (1, 2)]
    assert replay(["check", str(out), "--workers", "1"]) == 0, capsys.readouterr().err


def test_a_dry_run_whose_sources_lost_samples_is_not_ready(tmp_path: Path) -> None:
    from rich.console import Console  # noqa: PLC0415

    from recorder._session import RigCheck, SessionCheck  # noqa: PLC0415
    from recorder._session_command import _say_check  # noqa: PLC0415
    from schemas import SourceStats  # noqa: PLC0415

    def said(*sources: SourceStats) -> tuple[int, str]:
        console = Console(record=True, width=200, file=(tmp_path / "out.txt").open("w"))
        rig = RigCheck(("wood",), (), {"v": "1"}, sources, window_ns=1_000_000_000)
        found = SessionCheck(tmp_path, 4, 0, (), rig)
        status = _say_check(console, found)
        return status, console.export_text()

    rtde = SourceStats("rtde", expected=125, received=125)
    assert said(rtde)[0] == 0
    lossy = SourceStats("skin-fast", expected=1000, received=995, missing=5)
    status, text = said(rtde, lossy)
    assert status == 1
    assert "rig: not ready: skin-fast lost samples (v 1)" in text
    assert "  skin-fast: 995 received, 5 of 1000 missing" in text
    status, text = said(rtde, SourceStats("skin-temperature"))  # its rate unknown
    assert status == 0
    assert "  skin-temperature: 0 received, nothing in the check's second" in text
    slow = SourceStats("skin-temperature", period_ns=2_000_000_000)  # 0.5 Hz: none due
    status, text = said(rtde, slow)
    assert status == 0
    assert "  skin-temperature: 0 received, nothing in the check's second (a source that slow" in (
        text
    )
    garbled = SourceStats("skin-fast", period_ns=1_000_000, malformed=109)  # another layout
    status, text = said(rtde, garbled)
    assert status == 1
    assert "rig: not ready: skin-fast sent only malformed frames (v 1)" in text
    assert (
        "  skin-fast: 0 received, 109 malformed: what arrives does not match the rig "
        "configuration's [skin] layout (cells, frame sizes, byte order); check it against the skin"
    ) in text
    unplugged = SourceStats("skin-proximity", period_ns=20_000_000)  # 50 Hz: 50 due
    status, text = said(rtde, unplugged, lossy)
    assert status == 1
    assert "rig: not ready: skin-fast lost samples; skin-proximity sent nothing (v 1)" in text
    assert "  skin-proximity: 0 received, nothing, 50 due at its rate: check it and its " in text
