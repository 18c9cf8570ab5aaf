"""Every way an action ends other than its normal end sends the stop first, then keeps the data.

The runner drives a scripted arm (``fake_arm``, a mock of hardware) on the real clock; for each
cause the arm records the controller cycle of the cause and of the stop: the stop must come
within 2 cycles, and what arrived must be kept as ``<trial>.incomplete.mcap``.
"""

from __future__ import annotations

import dataclasses
import errno
import os
import re
import signal
import threading
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from fake_arm import START, SURFACE_Z, FakeArm, FakeSkin, fake_rig
from mcap.reader import make_reader

from recorder import ActionStoppedError, RecorderError, RigError, load_actions, load_objects
from recorder._session import check_rig_ready
from recorder.runner import arm_lock
from recorder.runner._record import record_action
from recorder.runner._runner import SPEED_LEASE_S
from recorder.writing._stream import PhaseEvent, SkinBlock
from recorder.writing._writer import RecordingWriter
from replay import read_recording
from schemas import INCOMPLETE_RECORD, cli

if TYPE_CHECKING:
    from pathlib import Path

    from recorder.runner import ArmRig, ArmSample

OBJECT, ACTION = load_objects()["wood"], load_actions()["C1"]
SLIDE = load_actions()["S1"]
#: What a stop after the light contact says of the arm.
HELD = (
    "the arm was stopped touching wood (pressing on it, as the stop found it): the next "
    "action's move lifts it off first; to free the object now, jog the arm up at the teach "
    "pendant"
)
#: The largest delay from a cause to the stop, in controller cycles.
MOST_CYCLES = 2


def _incomplete(path: Path) -> Path:
    return path.with_name("001.incomplete.mcap")


def _kept(path: Path, reason: str) -> None:
    """The action's file is the incomplete one, with messages and the stop's reason."""
    assert not path.exists()
    kept = path.with_name("001.incomplete.mcap")
    with kept.open("rb") as stream:
        reader = make_reader(stream)
        messages = sum(1 for _ in reader.iter_messages())
        summary = reader.get_summary()
        assert summary is not None
        records = {r.name: r.metadata for r in reader.iter_metadata()}
    assert messages > 50
    assert reason in records[INCOMPLETE_RECORD]["reason"]


def _stopped_in_time(arm: FakeArm, cause_cycle: int | None) -> None:
    assert cause_cycle is not None
    assert arm.stop_cycle is not None, arm.commands
    assert 0 <= arm.stop_cycle - cause_cycle <= MOST_CYCLES, (cause_cycle, arm.stop_cycle)


@pytest.mark.parametrize(
    ("cause", "reason"),
    [
        ("force", "TCP force 100.00 N above [limits] max_force_n"),
        ("workspace", "left the [limits] workspace"),
        ("protective", "protective stop (fake) from the controller"),
        ("lost", "arm connection lost"),
    ],
)
def test_a_limit_or_a_controller_stop_sends_the_stop_first(
    tmp_path: Path, cause: str, reason: str
) -> None:
    path = tmp_path / "001.mcap"
    rig = fake_rig(cause)
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    with rig, pytest.raises(ActionStoppedError, match=r"kept in .*001\.incomplete\.mcap"):
        record_action(rig, OBJECT, ACTION, 1, path, seed=0)
    _stopped_in_time(arm, arm.cause_cycle)
    _kept(path, reason)


def test_a_limit_stops_the_arm_before_the_skin_is_read(tmp_path: Path) -> None:
    # the sample that breaks a limit sends the stop before anything else is done: a skin slow
    # to read (a ROS 2 skin converting its topics) or the hand-over to the writer never
    # delays it; what arrived with the sample is still kept
    path = tmp_path / "001.mcap"
    rig = fake_rig("force")
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    rig.skin.slow_after_cause_s = 0.5  # type: ignore[attr-defined]
    with rig, pytest.raises(ActionStoppedError, match="TCP force"):
        record_action(rig, OBJECT, ACTION, 1, path, seed=0)
    assert arm.cause_ns is not None
    assert arm.stop_ns is not None
    assert arm.stop_ns - arm.cause_ns < 0.25e9, (arm.stop_ns - arm.cause_ns) / 1e9
    _kept(path, "TCP force")


def test_silence_sends_the_stop_once_the_source_is_silent_too_long(tmp_path: Path) -> None:
    path = tmp_path / "001.mcap"
    rig = fake_rig("silence")
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    with rig, pytest.raises(ActionStoppedError, match="arm state silent"):
        record_action(rig, OBJECT, ACTION, 1, path, seed=0)
    assert arm.cause_cycle is not None
    assert arm.stop_cycle is not None
    # the last sample came a cycle before the cause; the threshold is silence_s after it
    threshold = arm.cause_cycle - 1 + rig.options.silence_s * 1e9 / arm.period_ns
    assert threshold - 1 <= arm.stop_cycle <= threshold + MOST_CYCLES
    _kept(path, "silent")


@pytest.mark.parametrize("load", [0.5, 40.0])
@pytest.mark.parametrize("skin_too", [True, False])
def test_silence_on_a_busy_computer_says_so(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    load: float,
    skin_too: bool,  # noqa: FBT001
) -> None:
    # a computer too busy to read its sources makes them all look silent: the line says so
    # rather than only blaming the source and its settings; a skin that kept arriving shows
    # the computer read it, and the arm's link is blamed whatever the load (a reset link)
    monkeypatch.setattr(os, "getloadavg", lambda: (load, load, load))
    rig = fake_rig("silence")
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    skin: FakeSkin = rig.skin  # type: ignore[assignment]
    if skin_too:  # the skin falls silent with the arm: its last arrival stays where it was
        heard, last = skin.last_receive_ns, [0]

        def frozen() -> int | None:
            if arm.cause_cycle is None:
                last[0] = heard() or 0
            return last[0]

        monkeypatch.setattr(skin, "last_receive_ns", frozen)
    with rig, pytest.raises(ActionStoppedError) as info:
        record_action(rig, OBJECT, ACTION, 1, tmp_path / "001.mcap", seed=0)
    said = str(info.value)
    busy = f"(this computer is busy: load average {load:.1f} on {os.cpu_count()} cores"
    loaded = load > 1.5 * (os.cpu_count() or 1)
    assert (busy in said) == (skin_too and loaded), said
    assert ("(the skin kept sending meanwhile: look at the arm's link" in said) == (not skin_too)
    assert ("; this computer is busy too: load average 40.0" in said) == (loaded and not skin_too)
    assert "arm state silent for " in said


@pytest.mark.parametrize(
    ("cause", "qd"),
    # 0.005 rad/s: a UR10's slowest approach, below what counts as moving before an action
    [("silence", 0.05), ("lost", 0.05), ("silence", 0.005)],
)
def test_a_stop_the_arms_state_cannot_confirm_is_said(
    tmp_path: Path, cause: str, qd: float
) -> None:
    # mid-slide the arm's state stops arriving (a cable out, a stalled controller): the stop
    # goes out, but nothing shows the arm at rest; the line must not claim a stopped arm
    path = tmp_path / "001.mcap"
    rig = fake_rig(cause)
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    arm.moving_qd = qd
    with rig, pytest.raises(ActionStoppedError) as info:
        record_action(rig, OBJECT, SLIDE, 1, path, seed=0)
    said = str(info.value)
    assert arm.stop_cycle is not None  # the stop went out
    assert (
        "the arm's state stopped arriving, so the stop cannot be confirmed (last seen moving, "
        f"a joint at {qd:.3f} rad/s); check the arm at the teach pendant now" in said
    ), said
    _kept(path, "the stop cannot be confirmed")


def test_no_motion_is_commanded_on_a_stale_state(tmp_path: Path) -> None:
    # the arm's state stalls mid-approach: the approach's speed is not renewed on the last
    # state (its lease runs out, the arm stops by itself) until the silence check ends it
    path = tmp_path / "001.mcap"
    rig = fake_rig()
    rig.options = dataclasses.replace(rig.options, silence_s=0.5)  # 62 cycles of silence
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    arm.silent_from = 30  # cycles into the approach, before the contact
    with rig, pytest.raises(ActionStoppedError, match="arm state silent"):
        record_action(rig, OBJECT, ACTION, 1, path, seed=0)
    assert arm._contact_cycle is None  # stalled before the contact
    renewals = [cycle for cycle, command in arm.commands if command == "speed approach"]
    assert any(cycle < arm.silent_from for cycle in renewals)  # renewed while the state came
    # none after FRESH_CYCLES (10) without a state; a renewal went out every 2 cycles before
    assert max(renewals) <= arm.silent_from + 12, (renewals, arm.silent_from)


def test_a_consumer_held_up_after_a_read_is_not_a_silent_arm() -> None:
    # the writer (or an import, a collection) holds the runner up for three times silence_s
    # right after it read the sources; the arm went on sending: not silence, no stop
    rig = fake_rig()
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    held = 3 * rig.options.silence_s
    with rig:
        items = rig.perform(OBJECT, ACTION, 1)
        count = 0
        try:
            while True:
                next(items)
                count += 1
                if count == 1:
                    threading.Event().wait(held)
        except StopIteration as end:
            reason = end.value
    assert not reason, reason  # a normal end
    assert arm.stop_cycle is None
    assert count > 50


def _after_contact(rig: ArmRig, then: object) -> dict[str, int]:
    """Call ``then()`` from a thread 5 cycles after the contact; return the cycle it did."""
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    seen: dict[str, int] = {}

    def watch() -> None:
        while arm._contact_cycle is None or arm._cycle < arm._contact_cycle + 5:
            threading.Event().wait(0.001)
        seen["cycle"] = arm._cycle
        then()  # type: ignore[operator]

    threading.Thread(target=watch, daemon=True).start()
    return seen


@pytest.mark.parametrize(
    ("signum", "raised", "name"),
    [
        (signal.SIGINT, KeyboardInterrupt, "Ctrl-C"),
        (signal.SIGTERM, cli.Terminated, "SIGTERM"),
        # the terminal or the SSH connection of the session closed: by default SIGHUP ends
        # the process at once, the arm still running its last program
        (signal.SIGHUP, cli.HungUp, "SIGHUP"),
        # Ctrl-Z: a suspended recorder would leave the arm unwatched until resumed
        (signal.SIGTSTP, cli.Suspended, "Ctrl-Z"),
    ],
)
@pytest.mark.usefixtures("hangup_not_ignored", "suspend_caught")
def test_a_signal_stops_the_arm_keeps_the_data_then_ends_the_run(
    tmp_path: Path, signum: int, raised: type[BaseException], name: str
) -> None:
    path = tmp_path / "001.mcap"
    rig = fake_rig()
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    seen = _after_contact(rig, lambda: os.kill(os.getpid(), signum))
    with rig, pytest.raises(raised, match=f"interrupted by {name}.*kept in .*incomplete"):
        record_action(rig, OBJECT, ACTION, 1, path, seed=0)
    _stopped_in_time(arm, seen["cycle"])
    _kept(path, f"interrupted by {name}")


def test_a_recorder_stopped_and_continued_mid_action_stops_the_arm_and_says_so(
    tmp_path: Path,
) -> None:
    # SIGSTOP cannot be caught: only the SIGCONT that follows says the arm went unwatched
    # (sent here alone: the process is not stopped, the handler runs as after a real stop)
    path = tmp_path / "001.mcap"
    rig = fake_rig()
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    seen = _after_contact(rig, lambda: os.kill(os.getpid(), signal.SIGCONT))
    reason = "the recorder was stopped (SIGSTOP) while the arm moved, and continued"
    with rig, pytest.raises(ActionStoppedError, match=re.escape(reason)):
        record_action(rig, OBJECT, ACTION, 1, path, seed=0)
    _stopped_in_time(arm, seen["cycle"])
    _kept(path, reason)
    assert signal.getsignal(signal.SIGCONT) is signal.SIG_DFL  # put back after the action


def test_the_stop_is_timed_when_it_goes_to_the_arm(tmp_path: Path) -> None:
    # a loaded machine holds the recorder's thread after the stop left (another thread runs):
    # the stop's recorded time is not after its arrival at the arm (a latency benchmark
    # matches the controller's log against it)
    rig = fake_rig()
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    arm.hold_after_stop_s = 0.05
    _after_contact(rig, lambda: os.kill(os.getpid(), signal.SIGINT))
    with rig, pytest.raises(KeyboardInterrupt, match="interrupted by Ctrl-C"):
        record_action(rig, OBJECT, ACTION, 1, tmp_path / "001.mcap", seed=0)
    assert arm.stop_ns is not None
    ((cause, sent, why),) = rig.stops_sent
    assert why == "interrupted by Ctrl-C (SIGINT)"
    assert cause <= sent <= arm.stop_ns


def _disk_full_after_contact(arm: FakeArm, monkeypatch: pytest.MonkeyPatch) -> dict[str, int]:
    """Make every write fail (disk full) from 5 cycles after the contact; the dict gets the
    cycle of the first failure (``cycle``)."""
    failed: dict[str, int] = {}
    write = RecordingWriter.write

    def full_after_contact(self: RecordingWriter, item: object) -> None:
        if arm._contact_cycle is not None and arm._cycle > arm._contact_cycle + 5:
            failed.setdefault("cycle", arm._cycle)
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        write(self, item)  # type: ignore[arg-type]

    monkeypatch.setattr(RecordingWriter, "write", full_after_contact)
    return failed


def test_a_failed_write_stops_the_arm_and_keeps_what_was_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "001.mcap"
    rig = fake_rig()
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    failed = _disk_full_after_contact(arm, monkeypatch)
    with rig, pytest.raises(RecorderError, match="No space left on device") as info:
        record_action(rig, OBJECT, ACTION, 1, path, seed=0)
    _stopped_in_time(arm, failed["cycle"])
    _kept(path, "No space left on device")
    said = str(info.value)  # the line says the arm stopped and where the data is
    # stopped after the light contact: where the stop found it, on the object
    assert said.endswith(f"; {HELD}; what arrived is kept in {_incomplete(path)}"), said
    assert "\n" not in said


def test_a_disk_too_full_to_finish_the_file_keeps_its_part_and_says_where(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # the disk is full: the writer cannot finish even the incomplete recording (its summary,
    # its sync): the .part holds what arrived, and the line names it
    path = tmp_path / "001.mcap"
    rig = fake_rig()
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    _disk_full_after_contact(arm, monkeypatch)

    def no_room(_fd: int) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", no_room)
    with rig, pytest.raises(RecorderError) as info:
        record_action(rig, OBJECT, ACTION, 1, path, seed=0)
    (part,) = tmp_path.glob("*.part")
    assert part.stat().st_size > 0
    said = str(info.value)
    assert said.startswith(f"{path}: writing the recording failed (")
    assert "No space left on device" in said
    assert f"; {HELD}; what arrived is kept in {part} (no room to finish it; " in said
    assert arm.stop_cycle is not None
    assert not list(tmp_path.glob("*.mcap"))


def test_any_exception_stops_the_arm_first(tmp_path: Path) -> None:
    path = tmp_path / "001.mcap"
    rig = fake_rig()
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    seen = _after_contact(rig, lambda: setattr(rig.skin, "fail", True))
    with rig, pytest.raises(RuntimeError, match="fake skin: a bug"):
        record_action(rig, OBJECT, ACTION, 1, path, seed=0)
    _stopped_in_time(arm, seen["cycle"])
    _kept(path, "fake skin: a bug")


LOST = "URScript connection to fake:30001 lost (closed by the controller); a new one failed"


def test_a_stop_that_cannot_reach_the_arm_is_said_not_claimed(tmp_path: Path) -> None:
    # the connection the stop goes over is gone and no new one is taken: the line must not
    # say the arm was stopped, but that a person has to stop it
    path = tmp_path / "001.mcap"
    rig = fake_rig("force")
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    arm.stop_fails = LOST
    with rig, pytest.raises(ActionStoppedError) as info:
        record_action(rig, OBJECT, ACTION, 1, path, seed=0)
    said = str(info.value)
    assert "TCP force 100.00 N above [limits] max_force_n" in said
    assert f"the stop did not reach the arm ({LOST}); stop it at the teach pendant now" in said
    assert "\n" not in said
    assert any(command.endswith("failed") for _, command in arm.commands)
    assert rig.stops_sent == []  # nothing to time: no stop went out
    _kept(path, "the stop did not reach the arm")


def test_a_contact_stop_that_cannot_reach_the_arm_is_said_once(tmp_path: Path) -> None:
    # the light contact's stop fails, then the action's stop fails the same way: the line
    # says the cause once, not twice in a row
    rig = fake_rig()
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    arm.stop_fails, arm.contact_stop_fails = LOST, True
    with rig, pytest.raises(ActionStoppedError) as info:
        record_action(rig, OBJECT, ACTION, 1, tmp_path / "001.mcap", seed=0)
    said = str(info.value)
    assert said.count(LOST) == 1, said
    assert "the stop did not reach the arm either; stop it at the teach pendant now" in said


def test_an_arm_still_moving_after_the_stop_is_said(tmp_path: Path) -> None:
    # the stop went out, but the arm goes on (a controller that did not take it): the line
    # must not claim a stopped arm; what arrived while it was watched is kept
    path = tmp_path / "001.mcap"
    rig = fake_rig("workspace")
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    arm.stop_ignored, arm.moving_qd = True, 0.05
    with rig, pytest.raises(ActionStoppedError) as info:  # during the slide: the arm moves
        record_action(rig, OBJECT, SLIDE, 1, path, seed=0)
    said = str(info.value)
    assert "left the [limits] workspace" in said
    assert (
        "the arm did not come to rest after the stop (a joint at 0.050 rad/s); stop it at the "
        "teach pendant now" in said
    )
    assert arm.stop_cycle is not None
    assert arm._cycle - arm.stop_cycle >= 125  # watched for the cycles it had to stop in
    _kept(path, "the arm did not come to rest after the stop")


def test_an_arm_at_rest_after_the_stop_is_not_watched_longer(tmp_path: Path) -> None:
    path = tmp_path / "001.mcap"
    rig = fake_rig("workspace")
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    arm.moving_qd = 0.05
    with rig, pytest.raises(ActionStoppedError) as info:
        record_action(rig, OBJECT, SLIDE, 1, path, seed=0)
    assert "did not come to rest" not in str(info.value)
    assert arm.stop_cycle is not None
    assert arm._cycle - arm.stop_cycle < 125


def test_an_interrupt_whose_stop_cannot_reach_the_arm_says_so(tmp_path: Path) -> None:
    rig = fake_rig()
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    arm.stop_fails = LOST
    _after_contact(rig, lambda: os.kill(os.getpid(), signal.SIGINT))
    with rig, pytest.raises(KeyboardInterrupt) as info:
        record_action(rig, OBJECT, ACTION, 1, tmp_path / "001.mcap", seed=0)
    said = str(info.value)
    assert said.startswith("interrupted by Ctrl-C (SIGINT): the stop did not reach the arm")
    assert "the arm was stopped" not in said
    assert "kept in" in said
    _kept(tmp_path / "001.mcap", "the stop did not reach the arm")


def test_an_error_whose_stop_cannot_reach_the_arm_prints_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rig = fake_rig()
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    arm.stop_fails = LOST
    _after_contact(rig, lambda: setattr(rig.skin, "fail", True))
    # an exception of a driver or a skin ends the action as a stop does: one line, data kept
    with rig, pytest.raises(ActionStoppedError) as info:
        record_action(rig, OBJECT, ACTION, 1, tmp_path / "001.mcap", seed=0)
    said = str(info.value)
    assert said.startswith(
        "action stopped: an error in the action (RuntimeError: fake skin: a bug at fake_arm.py:"
    ), said
    assert f"the stop did not reach the arm ({LOST}); stop it at the teach pendant now" in said
    assert "\n" not in said
    assert capsys.readouterr().err == ""
    _kept(tmp_path / "001.mcap", "an error in the action (RuntimeError")


def test_a_normal_end_sends_no_stop_and_publishes_the_file(tmp_path: Path) -> None:
    rig = fake_rig()
    # time scale 0.1: a lease of 6.25 cycles, so that the renewals' cadence is what is tested,
    # not whether a loaded machine schedules the runner within 3 cycles (0.05: 25 ms)
    rig.options = dataclasses.replace(rig.options, time_scale=0.1)
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    with rig:
        written = record_action(rig, OBJECT, ACTION, 1, tmp_path / "001.mcap", seed=0)
    assert written.path == tmp_path / "001.mcap"
    assert arm.stop_cycle is None
    commands = [c for _, c in arm.commands]
    assert [c for i, c in enumerate(commands) if i == 0 or c != commands[i - 1]] == [
        "speed approach",
        "stop contact",
        "move execute",
        "move retract",
        "announce end",
    ]
    # the approach's speed is renewed before its lease ends (a stalled recorder: the arm stops);
    # a renewal late by a machine that held this process up (seen: 10 cycles against 6.25 on
    # a loaded test machine, twice in 40 at load 10) is the lease at work, not a wrong cadence
    sent = [cycle for cycle, c in arm.commands if c == "speed approach"]
    lease = SPEED_LEASE_S * rig.options.time_scale * 1e9 / arm.period_ns
    assert len(sent) > 1
    gaps = np.diff(sent)
    assert np.median(gaps) < lease, gaps
    assert sum(gaps >= lease) <= max(1, len(gaps) // 10), gaps


@pytest.mark.parametrize("delay_s", [0.0, 0.3])
def test_a_late_skin_still_covers_the_action_to_its_end(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, delay_s: float
) -> None:
    # a skin whose samples arrive late (ROS 2 on a loaded machine: stamped on time, sent
    # late): the arm is done before the action's last skin samples came; the runner waits for
    # them (at most SKIN_DELAY_S) so that the file holds the skin up to the action's end
    rig = fake_rig()
    rig.options = dataclasses.replace(rig.options, silence_s=1.0)  # not under test here
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    rig.skin.delay_ns = round(delay_s * 1e9)  # type: ignore[attr-defined]
    written: list[object] = []
    write = RecordingWriter.write

    def keep(self: RecordingWriter, item: object) -> None:
        written.append(item)
        write(self, item)  # type: ignore[arg-type]

    monkeypatch.setattr(RecordingWriter, "write", keep)
    with rig:
        record_action(rig, OBJECT, ACTION, 1, tmp_path / "001.mcap", seed=0)
    blocks = [item for item in written if isinstance(item, SkinBlock)]
    covered = max(b.stamp_ns + b.data.shape[0] * b.period_ns for b in blocks)
    end = next(e.stamp_ns for e in written if isinstance(e, PhaseEvent) and e.phase == "end")
    done = arm.reached_ns["retract"]  # the arm back: the action's motion is over
    assert covered >= done, (covered - done) / 1e9
    assert end >= covered - blocks[-1].period_ns  # 'end' once the skin's samples came


@pytest.mark.parametrize("latency_cycles", [0, 25])
def test_a_shallow_press_holds_its_duration_at_depth_however_late_the_program_starts(
    tmp_path: Path, latency_cycles: int
) -> None:
    # P1 presses 1 mm: within REACHED_M of its target at the contact already; the hold must
    # still count from the arm at depth, not from the command (a program that starts late)
    press = load_actions()["P1"]
    rig = fake_rig(latency_cycles=latency_cycles)
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    with rig:
        record_action(rig, OBJECT, press, 1, tmp_path / "001.mcap", seed=0)
    hold_cycles = press.duration_s * 0.05 * 1e9 / arm.period_ns
    retract = next(cycle for cycle, command in arm.commands if command == "move retract")
    assert retract - arm.reached["execute"] >= hold_cycles - 1, arm.commands


def test_a_connected_rig_lets_its_threads_take_turns_within_a_quarter_cycle() -> None:
    import sys  # noqa: PLC0415

    rig = fake_rig()
    before = sys.getswitchinterval()
    try:
        sys.setswitchinterval(0.005)  # the interpreter's default
        with rig:
            assert sys.getswitchinterval() <= rig.arm.period_ns / 4e9
        assert sys.getswitchinterval() == pytest.approx(0.005)  # restored on disconnect
    finally:
        sys.setswitchinterval(before)


def test_one_process_drives_an_arm_and_a_second_is_told_which(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    with arm_lock("ur-127.0.0.1-30002", "lab.toml"):
        # another open of the lock file is another holder, as another process would be
        with (
            pytest.raises(RigError, match=rf"lab.toml: pid {os.getpid()} \(.*\) drives the arm "),
            arm_lock("ur-127.0.0.1-30002", "lab.toml"),
        ):
            pass
        with arm_lock("ur-10.0.0.2-30002", "lab.toml"):  # another arm is free
            pass
    with arm_lock("ur-127.0.0.1-30002", "lab.toml"):  # released with the block
        pass
    names = sorted(p.name for p in (tmp_path / "atikt").iterdir())
    assert names == ["ur-10.0.0.2-30002.lock", "ur-127.0.0.1-30002.lock"]


def test_an_unwritable_runtime_directory_falls_back_then_says_so(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    blocked = tmp_path / "runtime"
    blocked.mkdir()
    (blocked / "atikt").write_text("a file where the directory goes", encoding="utf-8")
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(blocked))
    monkeypatch.setattr("tempfile.gettempdir", lambda: str(tmp_path / "tmp"))
    with arm_lock("ur-127.0.0.1-30002", "lab.toml"):  # the temporary directory instead
        assert (tmp_path / "tmp").is_dir()
    monkeypatch.setattr("tempfile.gettempdir", lambda: str(blocked / "atikt"))
    with (
        pytest.raises(RigError, match=r"cannot make the arms' lock directory .*; set XDG_RUNTIME"),
        arm_lock("ur-127.0.0.1-30002", "lab.toml"),
    ):
        pass


def test_an_action_at_the_robot_is_refused_before_it_moves_on_a_nearly_full_disk(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import shutil  # noqa: PLC0415

    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr(shutil, "disk_usage", lambda _p: usage._replace(free=10_000_000))
    path = tmp_path / "wood" / "C1" / "001.mcap"
    rig = fake_rig()
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    with rig, pytest.raises(RecorderError) as refused:
        record_action(rig, OBJECT, ACTION, 1, path, seed=0)
    said = str(refused.value)
    assert said.startswith(f"{tmp_path}: 10.0 MB free on its disk, below the 64 MB"), said
    assert "run again to resume" in said
    assert arm.commands == []  # nothing was sent
    assert not any(tmp_path.rglob("*.mcap*"))


def test_the_room_an_action_asks_for_grows_with_its_recordings(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import shutil  # noqa: PLC0415

    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr(shutil, "disk_usage", lambda _p: usage._replace(free=150_000_000))
    action = tmp_path / "wood" / "C1"
    action.mkdir(parents=True)
    with (action / "001.mcap").open("wb") as earlier:  # a rig whose sources write a lot
        earlier.truncate(100_000_000)  # sparse: its size, not its room
    rig = fake_rig()
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    with rig, pytest.raises(RecorderError) as refused:
        record_action(rig, OBJECT, ACTION, 2, action / "002.mcap", seed=0)
    said = str(refused.value)
    assert said.startswith(f"{action}: 150.0 MB free on its disk, below the 200 MB this "), said
    assert "(twice its largest recording here)" in said
    assert arm.commands == []
    assert sorted(f.name for f in action.iterdir()) == ["001.mcap"]


@pytest.mark.parametrize("load", [0.5, 40.0])
def test_a_silent_skin_refuses_the_move_to_an_object_before_it_is_sent(
    monkeypatch: pytest.MonkeyPatch, load: float
) -> None:
    # a skin on the wrong port or address: found before the arm moves, named as the skin;
    # on an overloaded computer (a virtual lab's skin beside a test suite) the load is said too
    monkeypatch.setattr(os, "getloadavg", lambda: (load, load, load))
    rig = fake_rig()
    skin: FakeSkin = rig.skin  # type: ignore[assignment]
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    skin.mute = True
    rig._poses["wood"] = START + np.array([0.2, 0.0, 0.0, 0.0, 0.0, 0.0])
    with rig, pytest.raises(RigError) as info:
        rig.present(OBJECT)
    said = str(info.value)
    assert not [name for _, name in arm.commands if not name.startswith("stop")], arm.commands
    assert said.startswith("fake.toml: the arm cannot move to wood: skin silent for "), said
    busy = f"(this computer is busy too: load average 40.0 on {os.cpu_count()} cores)"
    assert (busy in said) == (load > 1.5 * (os.cpu_count() or 1)), said
    assert said.endswith(
        "; check that the skin sends (the dry run lists each source) and the rig "
        "configuration's [skin], then retry"
    )
    assert "\n" not in said


@pytest.mark.parametrize(
    ("signum", "raised", "name"),
    [
        (signal.SIGINT, KeyboardInterrupt, "Ctrl-C \\(SIGINT\\)"),
        (signal.SIGTERM, cli.Terminated, "SIGTERM"),
    ],
)
def test_a_signal_while_moving_to_an_object_stops_the_arm_then_ends_the_run(
    signum: int, raised: type[BaseException], name: str
) -> None:
    # the signal is deferred as in an action: it never lands inside a program being sent; the
    # stop goes out, then the run ends with a line that says what of the arm
    rig = fake_rig()
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    rig._poses["wood"] = START + np.array([0.2, 0.0, 0.0, 0.0, 0.0, 0.0])
    move = arm.move

    def move_then_signal(*args: Any) -> None:
        move(*args)
        os.kill(os.getpid(), signum)  # arrives once the move program went out whole

    arm.move = move_then_signal  # type: ignore[method-assign,assignment]
    skin: FakeSkin = rig.skin  # type: ignore[assignment]
    said = f"^interrupted by {name} while moving to wood: the arm was stopped$"
    with rig:
        skin.begin()  # the fake skin's samples from now (the runner reads them as it moves)
        with pytest.raises(raised, match=said):
            rig.present(OBJECT)
    sent = [command for _, command in arm.commands]
    assert sent[0] == "move present"
    assert arm.stop_cycle is not None


def test_a_second_ctrl_c_after_a_deferred_one_is_ignored_under_a_command() -> None:
    # the command's handler ignores further signals after its first; a block that took the
    # first itself leaves them ignored, so a second Ctrl-C cannot replace the line naming the
    # stop and the file. Without a signal, the handler comes back as it was.
    from recorder.runner import deferred_interrupts  # noqa: PLC0415

    before = signal.signal(signal.SIGINT, cli._interrupt)
    try:
        with deferred_interrupts():
            pass
        assert signal.getsignal(signal.SIGINT) is cli._interrupt
        with deferred_interrupts() as flag:
            os.kill(os.getpid(), signal.SIGINT)
        assert flag.signum == signal.SIGINT
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
        os.kill(os.getpid(), signal.SIGINT)  # ignored: nothing raised
        signal.signal(signal.SIGINT, signal.default_int_handler)
        with deferred_interrupts() as flag:  # outside a command: its handler comes back
            os.kill(os.getpid(), signal.SIGINT)
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, before)


def test_a_press_deeper_than_the_workspace_leaves_room_for_is_refused_before_anything_moves(
    tmp_path: Path,
) -> None:
    # the contact lies at the pose or beyond it: a press that leaves the box from the pose
    # leaves it from every contact (a 2 mm press, 1 mm of room below the pose)
    rig = fake_rig()
    floor = (-1.0, -1.0, float(START[2]) - 0.001)
    rig.limits = dataclasses.replace(rig.limits, workspace_min_m=floor)
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    with rig, pytest.raises(RigError) as info:
        record_action(rig, OBJECT, ACTION, 1, tmp_path / "001.mcap", seed=0)
    said = str(info.value)
    assert said.startswith("fake.toml: wood (its [objects] pose): the press of action C1 "), said
    assert "would leave the [limits] workspace" in said, said
    assert said.endswith("in the action catalog, or move the object or the workspace"), said
    assert not arm.commands
    assert not list(tmp_path.iterdir())
    # the dry run refuses it alike, moving nothing
    with pytest.raises(RigError, match=r"wood \(its \[objects\] pose\): the press of action C1"):
        check_rig_ready(lambda _seed: rig, 0, [OBJECT], [ACTION], tmp_path, seconds=0.1)
    assert not arm.commands


def test_a_slide_longer_than_the_room_at_the_contact_is_stopped_before_it_is_sent(
    tmp_path: Path,
) -> None:
    # an object placed by hand (no pose): the slide's path is checked from the contact found;
    # 1 cm at 1 cm/s plus its deceleration does not fit in 5 mm
    rig = fake_rig()
    rig._poses.pop("wood")
    x = float(START[0])  # the tool's x axis points along -x here
    rig.limits = dataclasses.replace(rig.limits, workspace_min_m=(x - 0.005, -1.0, 0.0))
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    path = tmp_path / "001.mcap"
    with rig, pytest.raises(ActionStoppedError) as info:
        record_action(rig, OBJECT, SLIDE, 1, path, seed=0)
    assert "the slide of action S1 (0.010 m from" in str(info.value), str(info.value)
    sent = [command for _, command in arm.commands]
    assert "speed approach" in sent
    assert not [c for c in sent if c.startswith("slide")], sent
    _kept(path, "would leave the [limits] workspace")


class _Misbehaving:
    """Make a fake arm misbehave as a third-party driver can, from a moment on."""

    def __init__(self, arm: FakeArm, how: str) -> None:
        self.arm, self.how, self.on = arm, how, False
        self.poll = arm.poll
        arm.poll = self._poll  # type: ignore[method-assign]

    def _poll(self, wait_s: float) -> list[ArmSample]:
        samples = self.poll(wait_s)
        if not self.on:
            return samples
        if self.how == "raises":
            raise ConnectionResetError(errno.ECONNRESET, "Connection reset by peer")
        if self.how == "nan force":
            nan = np.full(6, np.nan)
            return [dataclasses.replace(s, tcp_force=nan) for s in samples]
        if self.how == "short joints":
            return [dataclasses.replace(s, q=s.q[:-1]) for s in samples]
        return [*samples, *samples]  # every sample twice: stamps repeated


@pytest.mark.parametrize(
    ("how", "said"),
    [
        # a NaN force passes every comparison: the force limit would be off
        ("nan force", "the arm driver gave TCP force and torque values that are not finite"),
        ("short joints", "the arm driver gave 5 joint positions for its 6 joint_names"),
        (
            "raises",
            (
                "the arm driver failed reading the arm's state (ConnectionResetError: "
                "[Errno 104] Connection reset by peer at "
            ),
        ),
    ],
)
def test_a_misbehaving_arm_driver_stops_the_action_in_one_line(
    tmp_path: Path, how: str, said: str
) -> None:
    rig = fake_rig()
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    fault = _Misbehaving(arm, how)
    _after_contact(rig, lambda: setattr(fault, "on", True))
    path = tmp_path / "001.mcap"
    with rig, pytest.raises(ActionStoppedError) as info:
        record_action(rig, OBJECT, ACTION, 1, path, seed=0)
    assert said in str(info.value), str(info.value)
    assert "\n" not in str(info.value)
    assert arm.stop_cycle is not None  # the stop went out
    _kept(path, said[:40])


def test_state_samples_handed_twice_are_left_out_and_counted(tmp_path: Path) -> None:
    rig = fake_rig()
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    fault = _Misbehaving(arm, "twice")
    _after_contact(rig, lambda: setattr(fault, "on", True))
    path = tmp_path / "001.mcap"
    with rig:
        record_action(rig, OBJECT, load_actions()["P1"], 1, path, seed=0)
    recording = read_recording(path)  # valid: every stamp once
    assert recording.joints is not None
    assert (np.diff(recording.joints.stamps_ns) > 0).all()
    stats = {s.name: s for s in recording.sources}
    assert sum(s.duplicated for s in stats.values()) > 100, stats


def test_an_arm_driver_that_cannot_connect_is_one_line(monkeypatch: pytest.MonkeyPatch) -> None:
    rig = fake_rig()

    def refused(_arm: FakeArm) -> None:
        raise ConnectionRefusedError(errno.ECONNREFUSED, "Connection refused")

    monkeypatch.setattr(FakeArm, "__enter__", refused)
    with pytest.raises(RigError) as info, rig:
        pass
    assert str(info.value).startswith(
        "fake.toml: the arm could not connect (ConnectionRefusedError: [Errno 111] Connection "
        "refused at "
    ), str(info.value)


def test_an_arm_unseen_while_moving_to_an_object_is_said_unconfirmed() -> None:
    # the state stops arriving on the way to an object: nothing shows the stop taken
    rig = fake_rig()
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    arm.moving_qd = 0.05
    rig._poses["wood"] = START + np.array([0.2, 0.0, 0.0, 0.0, 0.0, 0.0])
    arm.silent_from = 20
    with rig, pytest.raises(RigError) as info:
        rig.present(OBJECT)
    said = str(info.value)
    assert said.startswith("fake.toml: moving to wood: arm state silent for "), said
    assert (
        "the arm's state stopped arriving, so the stop cannot be confirmed (last seen moving, "
        "a joint at 0.050 rad/s); check the arm at the teach pendant now" in said
    ), said
    assert arm.stop_cycle is not None


def _hung_rig(
    cause: str = "hang", hang_in: str = "poll"
) -> tuple[ArmRig, FakeArm, threading.Event]:
    """A fake rig whose driver hangs after the cause (its poll, or its stop)."""
    rig = fake_rig(cause)
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    arm.released, arm.hang_in = threading.Event(), hang_in
    return rig, arm, arm.released


def _release_after_stop(arm: FakeArm, released: threading.Event) -> None:
    """Let the hung driver go once the stop reached the arm (and 0.1 s more)."""

    def watch() -> None:
        for _ in range(3000):  # at most 15 s: were no stop sent, no hung test either
            if arm.stop_ns is not None or released.wait(0.005):
                break
        released.wait(0.1)
        released.set()

    threading.Thread(target=watch, daemon=True).start()


def test_a_driver_call_that_hangs_gets_the_stop_from_the_watchdog(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # a lab's driver whose poll waits on a dead socket holds the runner's loop: no limit, no
    # silence check, no deferred signal can act. The watchdog sends the stop once the call
    # has held the loop longer than a source may be silent (at least 0.5 s), says so at once,
    # and the action ends as a stop when the call returns, what arrived kept
    path = tmp_path / "001.mcap"
    rig, arm, released = _hung_rig()
    _release_after_stop(arm, released)
    with rig, pytest.raises(ActionStoppedError) as info:
        record_action(rig, OBJECT, ACTION, 1, path, seed=0)
    assert arm.stop_ns is not None
    assert arm.cause_ns is not None
    assert arm.stop_ns - arm.cause_ns >= 0.5e9, arm.commands
    said = str(info.value)
    assert "the arm driver's poll() held the runner for " in said, said
    assert "(the stop was sent then)" in said
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("fake.toml: the arm driver's poll() has not returned for "), err
    assert "the stop was sent (the arm unseen since); the action ends when it returns" in err[0]
    assert next(why for *_, why in rig.stops_sent).startswith("the arm driver's poll() held")
    _kept(path, "the arm driver's poll() held the runner")


@pytest.mark.parametrize("after_s", [0.02, 0.8], ids=["before-the-watchdog", "after-it"])
def test_ctrl_c_ends_a_run_held_by_a_hung_driver_at_once(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], after_s: float
) -> None:
    # the hung call never returns: a deferred Ctrl-C would wait for it forever. Once the
    # watchdog has sent the stop, a signal (one that came before, or one after) ends the run
    path = tmp_path / "001.mcap"
    rig, arm, released = _hung_rig()

    def interrupt() -> None:
        while arm.cause_ns is None:
            threading.Event().wait(0.002)
        threading.Event().wait(after_s)
        os.kill(os.getpid(), signal.SIGINT)

    threading.Thread(target=interrupt, daemon=True).start()
    let_go = threading.Timer(30, released.set)  # were the run held for good: no hung tests
    let_go.start()
    try:
        with rig, pytest.raises(KeyboardInterrupt) as info:
            record_action(rig, OBJECT, ACTION, 1, path, seed=0)
        assert not released.is_set()  # it ended with the driver still hung
    finally:
        let_go.cancel()
        released.set()
    said = str(info.value)
    assert said.startswith("interrupted by Ctrl-C (SIGINT): the arm driver's poll() held "), said
    assert "the stop was sent (the arm unseen since); what arrived is kept in " in said, said
    assert said.endswith("001.incomplete.mcap"), said
    assert arm.stop_ns is not None
    assert "has not returned for" in capsys.readouterr().err
    _kept(path, "interrupted by Ctrl-C")


def test_a_stop_that_hangs_is_said_and_not_sent_again(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rig, arm, released = _hung_rig("force", hang_in="stop")

    def release() -> None:  # the stop hangs 1 s after the cause
        while arm.cause_ns is None:
            threading.Event().wait(0.002)
        released.wait(1.0)
        released.set()

    threading.Thread(target=release, daemon=True).start()
    with rig, pytest.raises(ActionStoppedError, match=r"TCP force 100\.00 N above"):
        record_action(rig, OBJECT, ACTION, 1, tmp_path / "001.mcap", seed=0)
    err = capsys.readouterr().err.strip()
    assert err.startswith("fake.toml: the arm driver's stop() has not returned for "), err
    assert "the stop may not have reached the arm; stop it at the teach pendant now" in err
    assert [c for _, c in arm.commands if c.startswith("stop stop")] == ["stop stop"]


def test_a_press_is_sent_with_its_lease_and_its_way_back(tmp_path: Path) -> None:
    # a driver that can (the UR) brings a press back by itself when the recorder died; the
    # runner gives it how long the press may hold and where the contact was
    rig = fake_rig()
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    seen: list[Any] = []
    move = arm.move

    def watched(pose: Any, speed: float, acceleration: float, at: Any) -> None:
        seen.append(at)
        move(pose, speed, acceleration, at)

    arm.move = watched  # type: ignore[method-assign]
    with rig:
        record_action(rig, OBJECT, ACTION, 1, tmp_path / "001.mcap", seed=0)
    (press,) = [at for at in seen if at is not None and at.phase == "execute"]
    hold = ACTION.duration_s * rig.options.time_scale
    assert press.lease_s > hold + 5.0
    assert len(press.back) == 6
    assert press.back[2] > SURFACE_Z - 0.003  # the contact, above the press's depth
    (retract,) = [at for at in seen if at is not None and at.phase == "retract"]
    assert retract.lease_s == 0.0
