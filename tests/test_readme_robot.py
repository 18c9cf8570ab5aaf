"""The manual's "Record at the robot" (docs/robot.md), run as printed against the virtual lab,
command by command.

The walk-through's commands run in their order in a fresh directory, against `serve-sim` on
free loopback ports and ten times faster than real time (the only changes to what is
printed): the session is interrupted with Ctrl-C in the middle of an action (the arm stops,
what arrived is kept), resumed, extended with more trials; the dataset passes `check`; live
learning runs headless with `--view` and its replay offline gives the same decisions.
"""

from __future__ import annotations

import contextlib
import os
import re
import shlex
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

import forked
import pytest
from ports import free_port

from recorder import load_actions

if TYPE_CHECKING:
    from collections.abc import Iterator

ROOT = Path(__file__).resolve().parents[1]
PAGE = (ROOT / "docs" / "robot.md").read_text("utf-8")
BLOCKS = re.findall(r"```bash\n(.*?)```", PAGE, flags=re.DOTALL)
EXAMPLE = "recorder/data/ur_rig.example.toml"
TOPIC_MAP = "recorder/data/topic_map.example.toml"
SCALE = "0.1"
#: The listen rehearsal's: the virtual lab's ROS 2 announcements of a phase come up to tens of
#: ms off on a loaded machine, and listen holds each action to its duration within 1 %.
LISTEN_SCALE = "0.5"
PROGRAMS = {"atikt-record": "recorder", "atikt-replay": "replay"}


def _steps(block: str) -> list[tuple[str, str]]:
    """Return a block's commands with their comments (continuations joined)."""
    joined = re.sub(r"\\\n\s*", " ", block)
    steps = []
    for line in joined.splitlines():
        command, _, comment = line.partition("#")
        if command.strip():
            steps.append((command.strip(), comment.strip()))
    return steps


class _Lab:
    """The example configuration on this test's ports, and how commands name it."""

    def __init__(self, tmp: Path, domain: int = 0, scale: str = SCALE) -> None:
        self.rtde = free_port(socket.SOCK_STREAM)
        self.script = free_port(socket.SOCK_STREAM)
        self.udp = free_port(socket.SOCK_DGRAM)
        self.dashboard = free_port(socket.SOCK_STREAM)
        self.domain, self.scale = domain, scale
        self.topic_map = tmp / "topic_map.toml"
        self.topic_map.write_text(_scaled_map(scale), "utf-8")
        text = (ROOT / EXAMPLE).read_text("utf-8")
        text = text.replace("rtde_port = 30004", f"rtde_port = {self.rtde}")
        text = text.replace("script_port = 30001", f"script_port = {self.script}")
        text = text.replace("dashboard_port = 29999", f"dashboard_port = {self.dashboard}")
        text = text.replace("# time_scale = 0.1", f"time_scale = {scale}")
        text = text.replace('bind = "127.0.0.1:5005"', f'bind = "127.0.0.1:{self.udp}"')
        self.config = tmp / "lab.toml"
        self.config.write_text(text, "utf-8")

    def argv(self, command: str) -> list[str]:
        """Return a printed command as this test runs it (its ports, its copy of the file)."""
        command = command.replace(EXAMPLE, str(self.config))
        command = command.replace(TOPIC_MAP, str(self.topic_map))
        command = command.replace("udp://127.0.0.1:5005", f"udp://127.0.0.1:{self.udp}")
        command = command.replace("--domain-id 0", f"--domain-id {self.domain}")
        command = command.replace("--dashboard-port 29999", f"--dashboard-port {self.dashboard}")
        program, *argv = shlex.split(command)
        if argv[0] == "serve-sim":
            argv += ["--rtde-port", str(self.rtde), "--script-port", str(self.script)]
            argv += ["--time-scale", self.scale]
        return [sys.executable, "-m", PROGRAMS[program], *argv]


def _scaled_map(scale: str) -> str:
    """Return the example topic map with the catalog's actions at a time scale.

    ``listen`` holds every announced action to its declared duration; in a virtual lab at
    ``scale`` times real time the actions last ``scale`` times as long, so the map declares
    them so (the rig configuration's ``time_scale`` does the same for the driven path).
    """
    lines = [(ROOT / TOPIC_MAP).read_text("utf-8")]
    for action in load_actions().values():
        lines += [f"[actions.{action.id}]", f'kind = "{action.kind}"']
        lines.append(f"duration_s = {action.duration_s * float(scale):g}")
    return "\n".join(lines) + "\n"


def _env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in {"DISPLAY", "WAYLAND_DISPLAY"}}
    return env | {"PYTHONPATH": str(ROOT)}


class _Empty:
    @staticmethod
    def read() -> str:
        return ""


def _block(*words: str) -> str:
    """Return the page's one bash block holding every word."""
    found: list[str] = [block for block in BLOCKS if all(word in block for word in words)]
    (block,) = found
    return block


@contextlib.contextmanager
def _serving(argv: list[str], cwd: Path) -> Iterator[subprocess.Popen[str]]:
    lab = forked.Popen(
        argv, cwd=cwd, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert lab.stdout is not None
        line = lab.stdout.readline()
        assert line.startswith("virtual lab listening"), line + (lab.stderr or _Empty()).read()
        yield lab
    finally:
        lab.send_signal(signal.SIGINT)
        lab.communicate(timeout=30)


def _interrupt_mid_action(argv: list[str], cwd: Path, out: Path) -> tuple[int, str]:
    """Run a session; Ctrl-C it once its second recording is being written."""
    run = forked.Popen(
        argv, cwd=cwd, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and run.poll() is None:
        done = list(out.rglob("*.mcap")) if out.exists() else []
        # a part being written (a finished one keeps its .part name for a moment as it is
        # published: both names exist between the link and the unlink)
        parts = out.rglob("*.mcap.part")  # <trial>.<pid>-<token>.mcap.part of <trial>.mcap
        writing = [p for p in parts if not p.with_name(f"{p.name.split('.')[0]}.mcap").exists()]
        if done and writing:
            # inside the action at once: the part is opened inside the action's deferred
            # interrupts, and the in-process world at time scale 0.1 may end an action within
            # 0.2 s (a signal after its end lands between actions: another message)
            run.send_signal(signal.SIGINT)
            break
        time.sleep(0.02)
    _, err = run.communicate(timeout=60)
    return run.returncode, err


@pytest.mark.slow(56)
def test_the_robot_section_runs_as_printed(tmp_path: Path) -> None:
    (serve,) = [command for command, _ in _steps(BLOCKS[0]) if " serve-sim " in f" {command} "]
    steps = _steps(BLOCKS[1])
    lab = _Lab(tmp_path)
    outputs: dict[str, str] = {}
    with _serving(lab.argv(serve), tmp_path):
        for command, comment in steps:
            argv = lab.argv(command)
            if "Ctrl-C" in comment:
                status, err = _interrupt_mid_action(argv, tmp_path, tmp_path / "data" / "lab")
                assert status == 130, err
                assert "interrupted by Ctrl-C (SIGINT): the arm was stopped" in err, err
                assert "incomplete.mcap" in err
                continue
            done = forked.run(
                argv,
                cwd=tmp_path,
                env=_env(),
                capture_output=True,
                text=True,
                timeout=600,
                check=False,
            )
            assert done.returncode == 0, f"{command}\n{done.stderr}"
            outputs[command] = done.stdout + done.stderr
    lab_dir = tmp_path / "data" / "lab"
    made = sorted(p.relative_to(lab_dir).as_posix() for p in lab_dir.rglob("???.mcap"))
    assert made == [
        f"{o}/{a}/{t:03d}.mcap"
        for o in ("foam_block", "wood")
        for a in ("P1", "S1")
        for t in (1, 2, 3)
    ]
    assert list(lab_dir.rglob("*.incomplete.mcap"))  # the interrupted action's data, kept
    printed = "\n".join(outputs.values())
    assert "no display here; the live view is written to" in printed
    (checked,) = [
        text for command, text in outputs.items() if "learn" in command and "--dry" in command
    ]
    assert "dry run of live learning: a new run into runs/live; 4 held-out recordings" in checked
    assert "\nrig: ready (" in checked
    assert (tmp_path / "runs" / "live" / "live.rrd").stat().st_size > 0
    live, offline = (
        [line for line in text.splitlines() if line.startswith("step")]
        for text in (outputs[steps[-2][0]], outputs[steps[-1][0]])
    )
    assert live
    assert live == offline


@pytest.mark.slow(19)
def test_the_in_process_rehearsal_runs_as_printed(tmp_path: Path) -> None:
    steps = _steps(_block("--rig sim-ur10", "atikt-replay learn"))
    outputs: dict[str, str] = {}
    for command, comment in steps:
        program, *argv = shlex.split(command)
        if "sim-ur10" in argv:  # the world ten times faster (the only change)
            argv += ["--rig-option", "time_scale=0.1"]
        argv = [sys.executable, "-m", PROGRAMS[program], *argv]
        if "Ctrl-C" in comment:
            status, err = _interrupt_mid_action(argv, tmp_path, tmp_path / "data" / "rehearsal")
            assert status == 130, err
            assert "interrupted by Ctrl-C (SIGINT): the arm was stopped" in err, err
            continue
        done = _run(argv, tmp_path)
        assert done.returncode == 0, f"{command}\n{done.stderr}"
        outputs[command] = done.stdout + done.stderr
    out = tmp_path / "data" / "rehearsal"
    made = sorted(p.relative_to(out).as_posix() for p in out.rglob("???.mcap"))
    objects, actions, trials = ("foam_block", "wood"), ("P1", "S1"), (1, 2)
    assert made == [f"{o}/{a}/{t:03d}.mcap" for o in objects for a in actions for t in trials]
    assert list(out.rglob("*.incomplete.mcap"))  # the interrupted action's data, kept
    learned = outputs[steps[-1][0]]
    assert [line for line in learned.splitlines() if line.startswith("step  3")], learned
    assert list((tmp_path / "runs" / "rehearsal" / "session").rglob("*.mcap"))


def _run(argv: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    return forked.run(
        argv, cwd=cwd, env=_env(), capture_output=True, text=True, timeout=600, check=False
    )


@pytest.mark.slow(31)
def test_the_listen_rehearsal_runs_as_printed(tmp_path: Path, dds_domain: int) -> None:
    (serve,) = [c for c, _ in _steps(_block("serve-sim", "--ros2")) if " serve-sim " in f" {c} "]
    (dry, _), (listen, _), *steps = _steps(_block("atikt-record listen", "atikt-record session"))
    assert " listen " in f" {listen} "
    assert dry.endswith(" --dry-run")
    lab = _Lab(tmp_path, domain=dds_domain, scale=LISTEN_SCALE)
    with _serving(lab.argv(serve), tmp_path):
        checked = _run(lab.argv(dry), tmp_path)
        assert checked.returncode == 0, checked.stdout + checked.stderr
        assert checked.stdout.splitlines()[-1].startswith("listen: ready"), checked.stdout
        assert "/skin/cell_0 (atikt_msgs/msg/SkinCell): " in checked.stdout
        assert not (tmp_path / "data").exists()  # the dry run wrote nothing
        recorder = forked.Popen(
            lab.argv(listen),
            cwd=tmp_path,
            env=_env(),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        lines: list[str] = []
        reading = threading.Thread(target=lambda: lines.extend(recorder.stdout or ()))
        try:
            assert recorder.stdout is not None
            first = recorder.stdout.readline()
            if not first.startswith("listening on DDS domain"):
                recorder.kill()
                raise AssertionError(first + recorder.communicate(timeout=30)[1])
            session, check = steps
            reading.start()
            done = _run(lab.argv(session[0]), tmp_path)
            assert done.returncode == 0, f"{session[0]}\n{done.stderr}"
            # a hang guard (60 s of 100 ms waits: the lab's last 'end', then the window written)
            for _ in range(600):
                if sum(line.endswith(".mcap\n") for line in lines) >= 2:
                    break
                time.sleep(0.1)
            else:
                pytest.fail("".join(lines))
        finally:
            recorder.send_signal(signal.SIGINT)
            recorder.wait(timeout=60)
        reading.join(10)
        out = "".join(lines)
        err = recorder.stderr.read() if recorder.stderr is not None else ""
        for pipe in (recorder.stdout, recorder.stderr):
            if pipe is not None:
                pipe.close()
    assert recorder.returncode == 130, err
    assert "Traceback" not in err
    listened = tmp_path / "data" / "listened"
    made = sorted(p.relative_to(listened).as_posix() for p in listened.rglob("*.mcap"))
    assert made == ["wood/P1/001.mcap", "wood/P1/002.mcap"], out + err
    checked = _run(lab.argv(check[0]), tmp_path)
    assert checked.returncode == 0, checked.stdout + checked.stderr
    from replay import read_recording  # noqa: PLC0415 (the test's own process reads)

    recording = read_recording(listened / made[0])
    assert recording.joints is not None
    assert recording.tcp is not None  # the lab's tool pose, published by the virtual lab
    assert recording.tcp.stamps_ns.size > 100
