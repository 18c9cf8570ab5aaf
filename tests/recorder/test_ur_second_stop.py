"""The UR driver's second way to stop: the dashboard server, when the URScript stop is lost.

A URScript connection that takes the bytes but delivers none (a half-dead link: the virtual
lab's ``deaf`` fault) looks alive: the stop goes into it and the arm runs on. The dashboard
server shares no socket with it.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np
import pytest
from ur_lab import POSE, virtual_lab

from recorder import ActionStoppedError, load_actions, load_objects, record_action
from recorder.live import SourceLostError
from recorder.runner import Context, StopsOtherwise
from recorder.virtuallab._script_server import ScriptFaults

if TYPE_CHECKING:
    from pathlib import Path

OBJECTS, ACTIONS = load_objects(), load_actions()

APPROACH = Context("wood", "P1", 1, "approach")


def _moving(arm: StopsOtherwise, seconds: float) -> bool:
    """Whether any state sample of the next ``seconds`` shows a joint turning."""
    end, seen = time.monotonic() + seconds, False
    while time.monotonic() < end:
        for sample in arm.poll(0.01):  # type: ignore[attr-defined]
            seen = seen or bool(np.abs(sample.qd).max() > 1e-3)
    return seen


def test_a_stop_lost_in_a_deaf_link_is_delivered_by_the_dashboard() -> None:
    with virtual_lab() as lab, lab.rig({"wood": POSE}) as rig:
        arm = rig.arm
        assert isinstance(arm, StopsOtherwise)
        arm.begin()
        arm.speed(np.array([0.0, 0.0, 0.02, 0.0, 0.0, 0.0]), 0.5, 20.0, APPROACH)
        assert _moving(arm, 0.3)
        lab.script.deafen_clients()
        assert arm.stop(0.5, None) == ""  # taken by the socket, never run
        assert _moving(arm, 0.3)  # the arm runs on
        how = arm.stop_otherwise()
        assert how == f"the dashboard server 127.0.0.1:{lab.dashboard.address[1]} took the stop"
        _moving(arm, 0.2)  # braking
        assert not _moving(arm, 0.3)


def test_without_a_dashboard_the_second_way_fails_in_one_line() -> None:
    failed = r"the dashboard's stop failed \(no dashboard_port\)"
    with virtual_lab() as lab, lab.rig({"wood": POSE}, dashboard_port=0) as rig:
        arm = rig.arm
        assert isinstance(arm, StopsOtherwise)
        with pytest.raises(SourceLostError, match=failed):
            arm.stop_otherwise()


def test_an_approach_whose_programs_are_never_run_stops_in_a_second(tmp_path: Path) -> None:
    # the link goes deaf 0.3 s into the approach: the arm's speed lease runs out and it stands
    # still while the runner renews the speed into the void; it waited up to the approach's
    # whole time limit (95 s at a lab's real time), printing nothing
    with virtual_lab(script_faults=ScriptFaults(deaf_s=0.3)) as lab:
        lab.world.prepare("wood", "P1", 1)
        with lab.rig({"wood": POSE}) as rig:
            assert rig.present(OBJECTS["wood"])
            with pytest.raises(ActionStoppedError, match="the arm stood still for") as info:
                record_action(rig, OBJECTS["wood"], ACTIONS["P1"], 1, tmp_path / "001.mcap", seed=0)
        assert lab.script.deafened == 1
    said = str(info.value)
    assert "controller cycles of the approach though its speed was sent" in said, said
    assert "001.incomplete.mcap" in said
