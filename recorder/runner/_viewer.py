"""What watches an action while it is recorded: a live view, never in the robot's way.

A viewer gets the action's description before it starts, every item as it arrives and the
finished file's path; each of its methods must return at once (a bounded queue and a thread
of its own: what it cannot take in time it counts as dropped, it never waits).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Protocol, Self

from recorder.errors import RecorderError

if TYPE_CHECKING:
    from pathlib import Path
    from types import TracebackType

    from recorder.writing._stream import StreamItem
    from recorder.writing._writer import RecordingInfo

#: The live views ``session --view`` opens, by name: ``module:callable`` taking (title, file or
#: None, fallback file) and returning a :class:`LiveViewer`. The rerun view lives with the
#: replay's view code (``replay.live``), found by name when asked for: the recorder's library
#: imports none of it, and a recorder installed without it still records.
VIEWERS = {"rerun": "replay.live:session_view"}


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


class LiveViewer(Protocol):
    """A live view opened for a run: its sink takes the items, its note says where it went."""

    @property
    def sink(self) -> Viewer:
        """What the runner hands the items to (its ``dropped`` counts what it could not show)."""
        ...

    @property
    def dropped(self) -> int:
        """Items the view could not take in time (never waited for)."""
        ...

    @property
    def note(self) -> str:
        """One line for the operator (no display: where the view was written), or empty."""
        ...

    def __enter__(self) -> Self:
        """Start showing."""
        ...

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Show what is queued (a bounded wait for a viewer) and close."""
        ...


def open_viewer(name: str, title: str, save: Path | None, *, fallback: Path) -> LiveViewer:
    """Open the live view ``name`` (:data:`VIEWERS`) into ``save``, a viewer, or ``fallback``.

    Raises:
        RecorderError: The view is not installed or cannot start; one line.
    """
    module, _, attribute = VIEWERS[name].partition(":")
    try:
        factory = getattr(importlib.import_module(module), attribute)
    except ImportError as err:
        msg = f"--view: the {name} view is not installed ({err}); install atikt with its replay"
        raise RecorderError(msg) from err
    viewer: LiveViewer = factory(title, save, fallback=fallback)
    return viewer
