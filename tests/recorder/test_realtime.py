"""The rig option ``rt_priority``: the readers and the runner's loop under SCHED_FIFO, alone."""

from __future__ import annotations

import errno
import json
import os
import threading
from pathlib import Path

import pytest
from mcap.reader import make_reader
from ur_lab import POSE, virtual_lab

from recorder import RigError, load_actions, load_objects, load_rig_config
from recorder.live import Received, SourceReader, readers_at, real_time, rt_refusal
from recorder.runner._record import record_action
from recorder.ur._rig import build_ur_rig
from recorder.writing._writer import METADATA_NAME

EXAMPLE = Path(__file__).parents[2] / "recorder" / "data" / "ur_rig.example.toml"
OBJECTS = load_objects()
ACTIONS = load_actions()


def _may_use_fifo() -> bool:
    """Whether this process may switch a thread to SCHED_FIFO (root or an rtprio limit)."""
    return hasattr(os, "sched_setscheduler") and rt_refusal(1) is None


needs_fifo = pytest.mark.skipif(not _may_use_fifo(), reason="this process may not use SCHED_FIFO")


def _policy(tid: int = 0) -> tuple[int, int]:
    """A thread's policy (without SCHED_RESET_ON_FORK) and priority."""
    return (
        os.sched_getscheduler(tid) & ~os.SCHED_RESET_ON_FORK,
        os.sched_getparam(tid).sched_priority,
    )


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


def test_no_priority_asked_changes_nothing() -> None:
    before = _policy() if hasattr(os, "sched_getscheduler") else None
    with real_time(0) as got:
        assert got == "normal"
        if before is not None:
            assert _policy() == before
    assert rt_refusal(0) is None


@needs_fifo
def test_the_thread_alone_runs_fifo_and_what_it_starts_does_not() -> None:
    before = _policy()
    seen: list[tuple[int, int]] = []

    def started() -> None:  # a writer, a BLAS pool, a viewer started meanwhile
        seen.append(_policy())

    def loop() -> None:
        with real_time(7) as got:
            assert got == "SCHED_FIFO 7"
            seen.append(_policy())
            thread = threading.Thread(target=started)
            thread.start()
            thread.join()
        seen.append(_policy())

    runner = threading.Thread(target=loop)
    runner.start()
    runner.join()
    normal = (os.SCHED_OTHER, 0)
    assert seen == [(os.SCHED_FIFO, 7), normal, normal]
    assert _policy() == before  # the test's own thread never changed


@needs_fifo
def test_readers_created_under_a_priority_run_at_it_for_their_life() -> None:
    got: list[tuple[int, int]] = []

    def receive() -> Received | None:
        got.append(_policy())
        threading.Event().wait(0.001)
        return None

    with readers_at(9):
        fast = SourceReader("fast", receive)
    plain = SourceReader("plain", receive)  # created outside: normal scheduling
    with fast:
        while not got:
            threading.Event().wait(0.001)
    assert fast.scheduling == "SCHED_FIFO 9"
    assert got[0] == (os.SCHED_FIFO, 9)
    got.clear()
    with plain:
        while not got:
            threading.Event().wait(0.001)
    assert plain.scheduling == "normal"
    assert got[0] == (os.SCHED_OTHER, 0)


def test_refused_real_time_scheduling_is_one_line_and_the_action_is_recorded(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def refuse(*_: object) -> None:
        raise PermissionError(errno.EPERM, os.strerror(errno.EPERM))

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    with virtual_lab() as lab:
        lab.world.prepare("wood", "P1", 1)
        with lab.rig({"wood": POSE}, rt_priority=50) as rig:
            assert rig.present(OBJECTS["wood"])
            written = record_action(
                rig, OBJECTS["wood"], ACTIONS["P1"], 1, tmp_path / "1.mcap", seed=0
            )
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "lab.toml: rt_priority = 50: real-time scheduling refused" in err
    assert "rtprio" in err
    assert _fact(written.path) == "normal"


@pytest.mark.slow(5)
@needs_fifo
def test_during_an_action_the_loop_and_readers_are_fifo_and_nothing_else(tmp_path: Path) -> None:
    threads: dict[str, tuple[int, int]] = {}
    started: list[tuple[int, int]] = []

    def put(_item: object) -> None:  # called by the runner's loop as items arrive
        if threads:
            return
        for thread in threading.enumerate():
            if thread.native_id is not None and thread is not threading.current_thread():
                threads[thread.name] = _policy(thread.native_id)
        threads["runner"] = _policy()
        child = threading.Thread(target=lambda: started.append(_policy()))
        child.start()
        child.join()

    before = _policy()
    with virtual_lab() as lab:
        lab.world.prepare("wood", "P1", 1)
        with lab.rig({"wood": POSE}, rt_priority=11) as rig:
            assert rig.present(OBJECTS["wood"])
            assert _policy() == before  # between actions: normal (a session may be learning)
            assert rig.run(OBJECTS["wood"], ACTIONS["P1"], 1, put) is None
            assert _policy() == before
            written = record_action(
                rig, OBJECTS["wood"], ACTIONS["P1"], 2, tmp_path / "2.mcap", seed=0
            )
    fifo, normal = (os.SCHED_FIFO, 11), (os.SCHED_OTHER, 0)
    assert threads["runner"] == fifo
    assert threads["atikt-rtde"] == fifo
    assert started == [normal]
    others = {name: p for name, p in threads.items() if name not in {"runner", "atikt-rtde"}}
    assert set(others.values()) == {normal}, others
    assert _fact(written.path) == "SCHED_FIFO 11"


def _fact(path: Path) -> str:
    with path.open("rb") as stream:
        records = {r.name: r.metadata for r in make_reader(stream).iter_metadata()}
    return str(json.loads(records[METADATA_NAME]["rig"])["fact:scheduling"])
