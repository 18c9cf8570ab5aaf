"""The rig option ``rt_priority``: the recorder's threads under SCHED_FIFO while connected."""

from __future__ import annotations

import dataclasses
import errno
import json
import os
import threading
from pathlib import Path

import pytest
from fake_arm import fake_rig
from mcap.reader import make_reader

from recorder import RigError, load_actions, load_objects, load_rig_config
from recorder.runner import real_time
from recorder.runner._record import record_action
from recorder.ur._rig import build_ur_rig
from recorder.writing._writer import METADATA_NAME

EXAMPLE = Path(__file__).parents[2] / "recorder" / "data" / "ur_rig.example.toml"
needs_fifo = pytest.mark.skipif(
    not hasattr(os, "sched_setscheduler"), reason="no SCHED_FIFO on this system"
)


def _may_use_fifo() -> bool:
    """Whether this process may switch a thread to SCHED_FIFO (root or an rtprio limit)."""
    if not hasattr(os, "sched_setscheduler"):
        return False
    policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
    except OSError:
        return False
    os.sched_setscheduler(0, policy, param)
    return True


def _config(tmp_path: Path, line: str) -> Path:
    text = EXAMPLE.read_text("utf-8")
    path = tmp_path / "lab.toml"
    path.write_text(text.replace("silence_s = 0.5 ", f"{line}\nsilence_s = 0.5 "), "utf-8")
    return path


@pytest.mark.parametrize(
    ("value", "said"),
    [
        ("100", "rt_priority = 100: give 1-99"),
        ("-1", "rt_priority = -1: give 1-99"),
        ("5.5", "rt_priority = 5.5: give a whole number 1-99"),
        ("true", "rt_priority = True: give a whole number 1-99"),
        ('"high"', "rt_priority = 'high': give a whole number 1-99"),
    ],
)
def test_a_priority_sched_fifo_has_not_is_refused_in_one_line_before_connecting(
    tmp_path: Path, value: str, said: str
) -> None:
    config = load_rig_config(_config(tmp_path, f"rt_priority = {value}"))
    with pytest.raises(RigError) as refused:
        build_ur_rig(0, config)  # nothing connects: the rig is only built
    assert str(refused.value).count("\n") == 0
    assert str(tmp_path / "lab.toml") in str(refused.value)
    assert said in str(refused.value)


def test_a_valid_priority_is_the_runners_and_not_the_rigs_identity(tmp_path: Path) -> None:
    plain = build_ur_rig(0, load_rig_config(_config(tmp_path, "")))
    rig = build_ur_rig(0, load_rig_config(_config(tmp_path, "rt_priority = 50")))
    assert rig.options.rt_priority == 50
    assert plain.options.rt_priority == 0
    # a dataset's rig is its configuration's identity: scheduling is not part of it
    assert rig.describe() == plain.describe()


@needs_fifo
def test_refused_real_time_scheduling_is_one_line_and_the_recorder_goes_on(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def refuse(*_: object) -> None:
        raise PermissionError(errno.EPERM, os.strerror(errno.EPERM))

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    with real_time(50, "lab.toml") as got:
        assert got == "normal"
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "lab.toml: rt_priority = 50: real-time scheduling refused" in err
    assert "rtprio" in err


def test_no_priority_asked_changes_nothing_and_says_nothing(
    capsys: pytest.CaptureFixture[str],
) -> None:
    before = os.sched_getscheduler(0) if hasattr(os, "sched_getscheduler") else None
    with real_time(0, "lab.toml") as got:
        assert got == "normal"
        if before is not None:
            assert os.sched_getscheduler(0) == before
    assert capsys.readouterr().err == ""


@pytest.mark.skipif(not _may_use_fifo(), reason="this process may not use SCHED_FIFO")
def test_the_connecting_thread_and_the_threads_it_starts_run_fifo_until_it_disconnects() -> None:
    before = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
    seen: list[tuple[int, int]] = []

    def reader() -> None:  # started while connected, as the arm's and skin's readers are
        seen.append((os.sched_getscheduler(0), os.sched_getparam(0).sched_priority))

    with real_time(7, "lab.toml") as got:
        assert got == "SCHED_FIFO 7"
        assert (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority) == (
            os.SCHED_FIFO,
            7,
        )
        thread = threading.Thread(target=reader)
        thread.start()
        thread.join()
    assert seen == [(os.SCHED_FIFO, 7)]
    assert (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority) == before


def test_each_recording_says_which_scheduling_it_got(tmp_path: Path) -> None:
    # the recording says what the system granted
    expected = "SCHED_FIFO 3" if _may_use_fifo() else "normal"
    rig = fake_rig()
    rig.options = dataclasses.replace(rig.options, time_scale=0.1, rt_priority=3)
    obj, action = load_objects()["wood"], load_actions()["P1"]
    with rig:
        written = record_action(rig, obj, action, 1, tmp_path / "001.mcap", seed=0)
    with written.path.open("rb") as stream:
        records = {r.name: r.metadata for r in make_reader(stream).iter_metadata()}
    assert json.loads(records[METADATA_NAME]["rig"])["fact:scheduling"] == expected
    plain = fake_rig()
    with plain:
        assert "scheduling" not in plain.facts()
