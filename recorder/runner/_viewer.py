"""What watches an action while it is recorded: a live view, never in the robot's way.

A viewer gets the action's description before it starts, every item as it arrives and the
finished file's path; each of its methods must return at once (a bounded queue and a thread
of its own: what it cannot take in time it counts as dropped, it never waits).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from pathlib import Path

    from recorder.writing._stream import StreamItem
    from recorder.writing._writer import RecordingInfo


class Viewer(Protocol):
    """A live view of the actions being recorded (rerun, Foxglove)."""

    def begin(self, info: RecordingInfo) -> None:
        """Show the next items as the action ``info`` describes."""
        ...

    def offer(self, item: StreamItem) -> None:
        """Take one item; never blocks (dropped and counted when the view is behind)."""
        ...

    def recorded(self, path: Path) -> None:
        """Take the finished recording (complete or incomplete)."""
        ...
