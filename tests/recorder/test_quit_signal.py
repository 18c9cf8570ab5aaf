r"""Ctrl-\ (SIGQUIT) while the arm moves: the stop first, what arrived kept, then the run ends.

By default SIGQUIT ends a process at once (with a core dump): the arm would run its last program
unwatched. While an action moves the arm it is deferred as Ctrl-C is.
"""

from __future__ import annotations

import os
import signal
from typing import TYPE_CHECKING

import pytest
from fake_arm import FakeArm, fake_rig
from test_runner_stops import ACTION, OBJECT, _after_contact, _kept, _stopped_in_time

from recorder.runner._record import record_action
from schemas import cli

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path


@pytest.fixture
def quit_caught() -> Iterator[None]:
    """SIGQUIT taken by a no-op for the test: code that does not take it fails the test
    instead of ending the test process."""
    previous = signal.signal(signal.SIGQUIT, lambda *_: None)
    try:
        yield
    finally:
        signal.signal(signal.SIGQUIT, previous)


@pytest.mark.usefixtures("quit_caught")
def test_ctrl_backslash_stops_the_arm_keeps_the_data_then_ends_the_run(tmp_path: Path) -> None:
    path = tmp_path / "001.mcap"
    rig = fake_rig()
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    seen = _after_contact(rig, lambda: os.kill(os.getpid(), signal.SIGQUIT))
    name = r"Ctrl-\\ \(SIGQUIT\)"
    with rig, pytest.raises(cli.Quit, match=f"interrupted by {name}.*kept in .*incomplete") as err:
        record_action(rig, OBJECT, ACTION, 1, path, seed=0)
    assert err.value.status == 131
    _stopped_in_time(arm, seen["cycle"])
    _kept(path, "interrupted by Ctrl-\\ (SIGQUIT)")
