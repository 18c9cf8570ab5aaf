"""The controller's stream on the URScript connection falls silent, the connection open.

A controller sends its state on its primary interface ten times a second; a link that forwards
one way only hides its key messages (another client's program started), so the driver says so.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from ur_lab import POSE, virtual_lab

if TYPE_CHECKING:
    import pytest


def test_a_silent_controller_stream_is_said_once(caplog: pytest.LogCaptureFixture) -> None:
    with virtual_lab() as lab, lab.rig({"wood": POSE}) as rig:
        arm = rig.arm
        arm.begin()
        for _ in range(50):  # its state messages arrive (a hang guard: 5 s)
            arm.poll(0.1)
            if arm.script_bytes:  # type: ignore[attr-defined]
                break
        lab.script.state_message = lambda: b""  # type: ignore[method-assign]  # sends nothing
        end = time.monotonic() + 3.0
        while time.monotonic() < end:
            arm.poll(0.05)
    said = [r.getMessage() for r in caplog.records if r.name == "atikt.ur"]
    assert len(said) == 1, said
    assert "the controller's messages on port" in said[0]
    assert "stopped arriving 2." in said[0]
    assert "a program another client starts is not seen" in said[0]
