"""What serve-sim tells the person at its console: injected faults, stops, a lab too loaded."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from recorder import SimulatedRig, load_actions, load_objects
from recorder.virtuallab._command import _print_fault
from recorder.virtuallab._events import EventLog
from recorder.virtuallab._world import MAX_BACKLOG, VirtualWorld

if TYPE_CHECKING:
    import pytest

ANNOUNCED = {"object": "wood", "action": "P1", "trial": "1"}


def test_a_stop_the_recorder_sends_is_printed_and_the_contacts_are_not(
    capsys: pytest.CaptureFixture[str],
) -> None:
    # a lab rehearsing its Ctrl-C and its limits sees the stop arrive; the stops within an
    # action (its light contact, an approach pausing, a slide's own stopl) are not news
    seen: list[str] = []
    log = EventLog(echo=lambda event: seen.append(event.kind))
    stop = ["textmsg", "stopl"]
    log.add(
        "program", 1, name="atikt_stop", calls=stop, announced={**ANNOUNCED, "phase": "contact"}
    )
    log.add("program", 2, name="atikt_slide", calls=["textmsg", "force_mode", "speedl", "stopl"])
    log.add("program", 3, name="atikt_move", calls=["textmsg", "movel"])
    pausing = {**ANNOUNCED, "phase": "approach"}  # an approach waiting for a late skin
    log.add("program", 4, name="atikt_stop", calls=stop, announced=pausing)
    assert seen == []
    event = log.add(
        "program",
        1_500_000_000,
        name="atikt_stop",
        calls=stop,
        announced={**ANNOUNCED, "phase": "stop"},
    )
    log.add("fault", 4, source="skin", fault="drop")
    assert seen == ["program", "fault"]
    _print_fault(event)
    said = capsys.readouterr().out
    assert (
        said == "stop: atikt_stop at controller 1.500 s object=wood action=P1 trial=1 phase=stop\n"
    )


class _Clock:
    def __init__(self) -> None:
        self.now = 0

    def __call__(self) -> int:
        return self.now


def test_a_lab_that_falls_behind_says_so_again_not_only_once(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # the lab fell behind at its start, and again minutes later: the second is said too
    # (at most every 10 s), with what was merged so far
    clock = _Clock()
    with SimulatedRig(0) as rig:
        world = VirtualWorld(rig, load_objects(None), load_actions(None), clock=clock)
        behind = (MAX_BACKLOG + 5) * world.period_ns
        with caplog.at_level(logging.WARNING):
            # behind at the start, again at once (not said again), 20 s later (said), at once
            for jump in (behind, behind, 20_000_000_000, behind):
                clock.now += jump
                world.advance_to(clock.now)
    lines = [r.getMessage() for r in caplog.records if "behind its clock" in r.getMessage()]
    assert len(lines) == 2, lines
    assert "(7 cycles merged so far)" in lines[0], lines
    assert f"({7 + 7 + 20_000_000_000 // world.period_ns - 1} cycles merged so far)" in lines[1]
