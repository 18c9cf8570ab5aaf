"""Sessions at the robot, rehearsed end to end: `atikt-record serve-sim` in its own process
serves the simulator over RTDE, URScript and the skin's own transport (UDP frames, or ROS 2
topics over DDS on loopback); `atikt-record session --rig-config LAB.toml` drives the UR rig
against it; every file passes `check` with every source's samples accounted for."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import socket
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from recorder._cli import main as record
from replay import read_recording
from replay.cli._main import main as replay
from schemas import dataset_recordings

if TYPE_CHECKING:
    from collections.abc import Iterator

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "recorder" / "data"
TIME_SCALE = "0.05"


def _free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def _lab(tmp_path: Path, rtde: int, script: int, skin: str) -> Path:
    """Write the example UR configuration with this test's ports and a skin table."""
    text = (DATA / "ur_rig.example.toml").read_text("utf-8")
    text = text.replace("rtde_port = 30004", f"rtde_port = {rtde}")
    text = text.replace("script_port = 30002", f"script_port = {script}")
    text = text.replace("# time_scale = 0.1", f"time_scale = {TIME_SCALE}")
    text = text[: text.index("\n[skin]\n") + 1] + skin
    lab = tmp_path / "lab.toml"
    lab.write_text(text, "utf-8")
    return lab


@contextlib.contextmanager
def _serve_sim(*options: str) -> Iterator[subprocess.Popen[str]]:
    """Run the virtual lab in its own process until the block ends (then Ctrl-C it)."""
    command = [sys.executable, "-m", "recorder", "serve-sim", "--time-scale", TIME_SCALE]
    env = os.environ | {"PYTHONPATH": str(ROOT)}
    process = subprocess.Popen(  # noqa: S603 (this project's command)
        [*command, *options], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert process.stdout is not None
        assert process.stderr is not None
        line = process.stdout.readline()
        assert line.startswith("virtual lab listening"), line + process.stderr.read()
        assert "127.0.0.1" in line
        yield process
    finally:
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=20)
    assert process.returncode == 0, err
    assert out.strip() == "virtual lab stopped"


def _session(lab: Path, out: Path, capsys: pytest.CaptureFixture[str]) -> str:
    argv = ["session", "--rig-config", str(lab), "--objects", "wood,foam_block"]
    argv += ["--actions", "P1,S1", "--trials", "1", "--out", str(out), "--yes"]
    status = record(argv)
    printed = capsys.readouterr()
    assert status == 0, printed.err
    return printed.out


def _check_every_sample(out: Path, capsys: pytest.CaptureFixture[str], sources: set[str]) -> None:
    files = dataset_recordings(out)
    assert [f.relative_to(out).as_posix() for f in files] == [
        "foam_block/P1/001.mcap",
        "foam_block/S1/001.mcap",
        "wood/P1/001.mcap",
        "wood/S1/001.mcap",
    ]
    assert replay(["check", str(out), "--workers", "1"]) == 0
    checked = capsys.readouterr()
    assert "4 of 4 recordings valid" in checked.out
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


def test_a_session_with_a_udp_skin(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rtde, script = _free_port(socket.SOCK_STREAM), _free_port(socket.SOCK_STREAM)
    udp = _free_port(socket.SOCK_DGRAM)
    skin = (DATA / "skin_udp.example.toml").read_text("utf-8")
    skin = skin.replace('bind = "127.0.0.1:5005"', f'bind = "127.0.0.1:{udp}"')
    lab = _lab(tmp_path, rtde, script, skin[skin.index("\n[skin]\n") + 1 :])
    out = tmp_path / "session"
    served = ["--rtde-port", str(rtde), "--script-port", str(script), "--rig-config", str(lab)]
    with _serve_sim(*served, "--skin", f"udp://127.0.0.1:{udp}"):
        printed = _session(lab, out, capsys)
    assert len(re.findall(r"\btrial 1\b", printed)) == 4, printed
    _check_every_sample(out, capsys, {"rtde", "skin-fast", "skin-proximity", "skin-temperature"})


def test_a_session_with_a_ros2_skin(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], dds_domain: int
) -> None:
    pytest.importorskip("cyclonedds")
    rtde, script = _free_port(socket.SOCK_STREAM), _free_port(socket.SOCK_STREAM)
    topic_map = DATA / "topic_map.example.toml"
    skin = f'[skin]\ntransport = "ros2"\ntopic_map = "{topic_map}"\ndomain_id = {dds_domain}\n'
    lab = _lab(tmp_path, rtde, script, skin)
    out = tmp_path / "session"
    served = ["--rtde-port", str(rtde), "--script-port", str(script), "--ros2"]
    served += ["--topic-map", str(topic_map), "--domain-id", str(dds_domain)]
    with _serve_sim(*served):
        _session(lab, out, capsys)
    _check_every_sample(out, capsys, {"rtde", *(f"skin/cell_{c}" for c in range(7))})
