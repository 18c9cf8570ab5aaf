"""A stop that does not bring the arm to rest: the driver's second way (a UR's dashboard).

A URScript link that takes the bytes but delivers none (half dead: no error, no end) looks like
a live one; the stop goes into it and the arm runs on. The runner then stops the arm the
driver's second way, which shares nothing with the first, and says so.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest
from fake_arm import FakeArm, fake_rig
from test_runner_stops import OBJECT, _kept

from recorder import ActionStoppedError, load_actions
from recorder.live import SourceLostError
from recorder.runner import StopsOtherwise
from recorder.runner._record import record_action

if TYPE_CHECKING:
    from pathlib import Path

SLIDE = load_actions()["S1"]


def _second_way(arm: FakeArm, *, fails: str = "") -> list[int]:
    """Give the fake arm a second way to stop; return the cycles it was used at."""
    used: list[int] = []

    def stop_otherwise() -> str:
        used.append(arm._cycle)
        if fails:
            raise SourceLostError(fails)
        arm.target, arm.velocity, arm._pending = None, np.zeros(6), []
        return "the fake dashboard took the stop"

    arm.stop_otherwise = stop_otherwise  # type: ignore[attr-defined]
    assert isinstance(arm, StopsOtherwise)
    return used


def test_an_arm_the_stop_did_not_halt_is_stopped_the_second_way(tmp_path: Path) -> None:
    path = tmp_path / "001.mcap"
    rig = fake_rig("workspace")
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    arm.stop_ignored, arm.moving_qd = True, 0.05
    used = _second_way(arm)
    with rig, pytest.raises(ActionStoppedError) as info:  # during the slide: the arm moves
        record_action(rig, OBJECT, SLIDE, 1, path, seed=0)
    said = str(info.value)
    assert "left the [limits] workspace" in said
    assert (
        "the arm did not come to rest after the stop: the fake dashboard took the stop" in said
    ), said
    assert "stop it at the teach pendant" not in said
    assert arm.stop_cycle is not None
    (cycle,) = used
    assert cycle - arm.stop_cycle >= 125  # tried once the stop had its cycles to work
    _kept(path, "the fake dashboard took the stop")


def test_a_second_way_that_fails_is_said_and_the_arm_still_moving_too(tmp_path: Path) -> None:
    path = tmp_path / "001.mcap"
    rig = fake_rig("workspace")
    arm: FakeArm = rig.arm  # type: ignore[assignment]
    arm.stop_ignored, arm.moving_qd = True, 0.05
    used = _second_way(arm, fails="port 29999: Connection refused")
    with rig, pytest.raises(ActionStoppedError) as info:
        record_action(rig, OBJECT, SLIDE, 1, path, seed=0)
    said = str(info.value)
    assert len(used) == 1  # tried once, not again and again
    assert "the driver's second way to stop failed (port 29999: Connection refused" in said, said
    assert (
        "the arm did not come to rest after the stop (a joint at 0.050 rad/s); stop it at the "
        "teach pendant now" in said
    )
