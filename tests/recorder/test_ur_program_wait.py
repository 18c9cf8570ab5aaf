"""A program found playing before an action is waited for, moving nothing, before a refusal.

A recorder killed mid-press (SIGKILL, a power cut) leaves its press program at the controller,
which brings the arm back to the contact by itself when its lease ends. The next run finds it
playing: it waits for it to end instead of refusing and advising to stop it (which would leave
the arm pressed into the object).
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from ur_lab import POSE, virtual_lab

from recorder import load_objects

if TYPE_CHECKING:
    import pytest

OBJECTS = load_objects()


def test_a_killed_recorders_press_is_waited_for_then_the_object_is_presented(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with virtual_lab() as lab:
        # what a killed recorder left playing: its press, holding (15 s of the lab's world: 3 s
        # at its time scale), then back by itself; the next run connects after it started
        lab.script.run("def atikt_press_0b0b0b():\n  sleep(15.0)\nend\n")
        for _ in range(2000):  # a hang guard (10 s), not a timing check
            if lab.world.robot_at(lab.world.controller_ns()).runtime_state == 2:
                break
            time.sleep(0.005)
        with lab.rig({"wood": POSE}) as rig:
            assert rig.present(OBJECTS["wood"])
        moves = [p for p in lab.script.programs if p.startswith("def atikt_move")]
    err = capsys.readouterr().err
    assert (
        "a program is playing (RTDE runtime_state 2) on the controller: waiting up to 20 s" in err
    )
    assert len(moves) == 1  # sent once the press had ended, not over it
