"""A rig configuration's mistakes refused in one line before anything connects or moves.

Pure checks on a UR rig built from a configuration file: no virtual lab is started, and a
check that reached for the network would fail with another message (nothing listens on the
configuration's ports).
"""

from __future__ import annotations

import contextlib
import socket
import threading
from typing import TYPE_CHECKING

import pytest

from recorder import (
    RecorderError,
    RigConfig,
    check_object_poses,
    check_rig_ready,
    load_actions,
    load_objects,
    load_rig_config,
    plan_dataset,
    refuse_unrecordable,
    rig_factory,
)
from recorder._cli import main as record
from recorder._session import check_session, run_session
from recorder.errors import RigError
from recorder.live import RecorderClock
from recorder.ur._arm import Connection, URArm
from schemas import CLAIM_NAME

if TYPE_CHECKING:
    from pathlib import Path

#: A 1-cell skin that measures force only (the trial's rig1.toml); ports nobody listens on.
FORCE_ONLY = """\
rig = "ur"
[options]
host = "127.0.0.1"
rtde_port = 9
script_port = 7
dashboard_port = 0
[limits]
max_tcp_speed_m_s = 0.1
max_force_n = 20.0
max_acceleration_m_s2 = 1.0
workspace_min_m = [-0.9, -0.5, 0.0]
workspace_max_m = [-0.4, 0.2, 0.4]
[objects.wood]
pose = [-0.70, -0.20, 0.15, 0.0, 3.14159, 0.0]
[skin]
transport = "udp"
bind = "127.0.0.1:0"
cells = 1
[skin.header]
magic = [0xAA]
[skin.frames.f]
rate_hz = 250
sequence = { at = 1, type = "u16" }
[skin.frames.f.force]
at = 3
type = "u16"
count = 1
scale = 0.001
"""


def _rig_file(tmp_path: Path, text: str = FORCE_ONLY) -> Path:
    path = tmp_path / "rig1.toml"
    path.write_text(text)
    return path


def test_an_action_the_skin_cannot_record_is_refused_naming_the_skin(tmp_path: Path) -> None:
    path = _rig_file(tmp_path)
    rig = rig_factory(load_rig_config(path))(0)
    actions = load_actions()
    refuse_unrecordable(rig, [actions["P1"]])  # force is all a press needs
    with pytest.raises(RecorderError) as caught:
        refuse_unrecordable(rig, [actions["P1"], actions["S1"], actions["C1"]])
    said = str(caught.value)
    assert said.startswith(f"{path}: [skin] delivers force only")
    assert "a 'slide' action (S1) needs the skin modality acceleration" in said
    assert "a 'static' action (C1) needs the skin modality temperature" in said
    assert "leave S1,C1 out of --actions" in said
    assert "P1" not in said
    assert "\n" not in said


def test_the_dry_run_and_the_session_refuse_it_before_connecting(tmp_path: Path) -> None:
    factory = rig_factory(load_rig_config(_rig_file(tmp_path)))
    objects, actions = load_objects(), load_actions()
    pattern = r"a 'slide' action \(S1\) needs the skin modality acceleration"
    with pytest.raises(RecorderError, match=pattern):  # nothing listens: a connection would fail
        check_rig_ready(factory, 0, [objects["wood"]], [actions["P1"], actions["S1"]], tmp_path)
    tasks = plan_dataset(objects, actions, object_ids=["wood"], action_ids=["P1", "S1"], trials=1)
    root = tmp_path / "lab"
    with pytest.raises(RecorderError, match=pattern):
        check_session(tasks, root, factory, seed=0)
    with pytest.raises(RecorderError, match=pattern):
        run_session(tasks, root, factory, seed=0, unattended=True)
    assert not (root / CLAIM_NAME).exists()  # refused before the directory was claimed


def _one_answer(payload: bytes) -> tuple[socket.socket, threading.Thread]:
    """Serve ``payload`` to one client on a free loopback port, then close."""
    listener = socket.create_server(("127.0.0.1", 0))

    def serve() -> None:
        with contextlib.suppress(OSError):
            client, _ = listener.accept()
            with client:
                client.sendall(payload)
                with contextlib.suppress(OSError):  # the stop's command, if one is sent
                    client.recv(64)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    return listener, thread


@pytest.mark.parametrize("command", ["probe", "stop"])
def test_a_dashboard_answer_that_is_not_text_is_never_printed(command: str) -> None:
    # the primary interface's binary packages, as on a dashboard_port that is its port
    package = b"\x00\x00\x003\x10\x00\x00\x00.\x00\x00\x00\x00\x00$\xc1F\xe3" * 200 + b"\n"
    listener, thread = _one_answer(package)
    with listener:
        port = listener.getsockname()[1]
        arm = URArm(Connection("127.0.0.1", 9, 7, 125, port), RecorderClock(), "lab.toml")
        said = arm._probe_dashboard() if command == "probe" else arm._dashboard_stop()
        thread.join(5)
    assert said == (
        f"port {port} answered with bytes that are not text: not a UR dashboard server "
        "(is dashboard_port another interface's port?)"
    )
    listener, thread = _one_answer(b"Connected: Universal Robots Dashboard Server\nFailed\n")
    with listener:  # a dashboard's own text is said as it came
        port = listener.getsockname()[1]
        arm = URArm(Connection("127.0.0.1", 9, 7, 125, port), RecorderClock(), "lab.toml")
        said = arm._probe_dashboard() if command == "probe" else arm._dashboard_stop()
        thread.join(5)
    assert said == (
        f"port {port} answers" if command == "probe" else f"port {port} answered 'Failed'"
    )


def test_a_pose_for_an_object_of_no_catalog_is_refused_with_the_closest_id() -> None:
    catalog = load_objects()
    poses = {"wood": {"pose": [-0.7, -0.2, 0.15, 0.0, 3.14159, 0.0]}}
    check_object_poses(RigConfig("ur", sections={"objects": poses}, source="rig.toml"), catalog)
    typo = {**poses, "foam_blok": {"pose": [-0.55, -0.2, 0.15, 0.0, 3.14159, 0.0]}}
    with pytest.raises(RigError) as refused:
        check_object_poses(RigConfig("ur", sections={"objects": typo}, source="rig.toml"), catalog)
    assert str(refused.value) == (
        "rig.toml: [objects.foam_blok] names no object of the object catalog; did you mean "
        f"foam_block? (known: {', '.join(catalog)}); fix the id, or remove the table"
    )
    nothing_like = {"no_such_thing": {"pose": [-0.55, -0.2, 0.15, 0.0, 3.14159, 0.0]}}
    config = RigConfig("ur", sections={"objects": nothing_like}, source="rig.toml")
    with pytest.raises(RigError) as refused:
        check_object_poses(config, catalog)
    said = str(refused.value)
    assert said.startswith("rig.toml: [objects.no_such_thing] names no object of the object ")
    assert "did you mean" not in said


def test_a_session_refuses_a_pose_for_an_object_of_no_catalog_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # the trial's [objects.no_such_thing]: it said "placed by hand: foam_block" instead
    text = FORCE_ONLY.replace("[objects.wood]", "[objects.no_such_thing]")
    path = _rig_file(tmp_path, text)
    argv = ["session", "--rig-config", str(path), "--objects", "wood,foam_block"]
    argv += ["--actions", "P1", "--trials", "1", "--out", str(tmp_path / "lab")]
    for run in (["--dry-run"], ["--yes"]):
        assert record([*argv, *run]) == 1
        err = capsys.readouterr().err.splitlines()
        assert len(err) == 1
        assert err[0].startswith(f"atikt-record: error: {path}: [objects.no_such_thing] names no ")
    assert not (tmp_path / "lab").exists()
