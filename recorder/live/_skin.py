"""A live skin, whatever carries it: the interface a real rig reads its skin through.

A lab's skin reaches the recorder as UDP or serial frames (layout described in the rig
configuration's ``[skin]`` table) or as ROS 2 topics (mapped by a topic map). Each transport
implements :class:`LiveSkin`; the rig configuration's ``[skin] transport = "udp" | "serial"
| "ros2"`` picks one through :data:`SKIN_TRANSPORTS` (loaded by import string, so a rig that
does not use DDS never imports it).
"""

from __future__ import annotations

import importlib
import importlib.metadata
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, Self, runtime_checkable

from recorder.errors import RigError

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping
    from types import TracebackType

    from recorder.live._accounting import SourceStats
    from recorder.live._clock import RecorderClock
    from recorder.writing._stream import SkinBlock


class LiveSkin(Protocol):
    """A skin read live: reader threads while inside ``with``, blocks polled by the rig.

    Sensor stamps of the blocks are on the recorder's time base (the source's clock plus the
    estimated offset); receive times are the recorder's clock.
    """

    def __enter__(self) -> Self:
        """Open the transport and start its reader thread(s)."""
        ...

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Stop the threads and close the transport."""
        ...

    @property
    def cells(self) -> int:
        """Return the number of cells."""
        ...

    def begin(self) -> None:
        """Start a new recording: fresh accounting, drop what was queued before."""
        ...

    def poll(self) -> list[SkinBlock]:
        """Return the blocks completed since the last poll (does not wait).

        Raises:
            SourceLostError: The connection was lost.
        """
        ...

    def finish(self) -> list[SkinBlock]:
        """Return everything still open or queued (the end of a recording)."""
        ...

    def total_force(self) -> float | None:
        """Return the total normal force over every cell and sensor, N (None: none yet).

        The mean over the last :data:`FORCE_WINDOW_NS` of samples: the sum of a skin's many
        sensors is noisy sample by sample (21 sensors of 0.009 N: 0.04 N, near a light
        contact's 0.05 N); the window's mean is quiet and still sees a short touch.
        """
        ...

    def nearest(self) -> float | None:
        """Return the latest smallest proximity reading, m (None: no proximity sensing)."""
        ...

    def last_receive_ns(self) -> int | None:
        """Return the receive time of the latest sample (None: nothing yet)."""
        ...

    def stats(self) -> list[SourceStats]:
        """Return the accounting of each of its sources since :meth:`begin`."""
        ...


@runtime_checkable
class SensingSkin(Protocol):
    """A live skin that says, from its configuration, which modalities it delivers.

    Known before it connects, so an action the skin cannot record is refused before anything
    moves; a plug-in skin without it is not checked there (``check`` judges its files).
    """

    @property
    def modalities(self) -> tuple[str, ...]:
        """Return the contract's modalities this skin delivers."""
        ...


@runtime_checkable
class ExplainingSkin(Protocol):
    """A live skin that can say why nothing of it arrives (a silent skin's line names it)."""

    def silence_hint(self) -> str:
        """Return what it knows of its silence, one clause ('': nothing to add)."""
        ...


@dataclass(frozen=True, slots=True)
class SkinFinding:
    """Something a skin counted and left out that a person should fix, said in one line.

    Attributes:
        line: What was counted, where it came from, and the fix (naming the configuration
            file, the key and its value).
        blocking: Whether a dry run is not ready for it: the recordings could hold another
            sender's frames instead of the skin's, or place the frames on a wrong time base
            (``check`` sees neither). Otherwise it is said only (every valid frame is kept).
        short: A clause for the dry run's ``rig: not ready: ...`` (blocking findings).
    """

    line: str
    blocking: bool = False
    short: str = ""


@runtime_checkable
class ReportingSkin(Protocol):
    """A live skin that judges what it counted since :meth:`LiveSkin.begin`.

    The UDP and serial skins (:class:`recorder.live.FrameSkin`) say their findings once
    per action, when it ends (:meth:`LiveSkin.finish`); a dry run shows them with the
    sources and is not ready for a blocking one.
    """

    def origin(self) -> str:
        """Return where the skin's frames are taken from (``host:port``; '': not known)."""
        ...

    def findings(self) -> list[SkinFinding]:
        """Return what was counted and left out since ``begin`` that needs a fix."""
        ...


#: The window of :meth:`LiveSkin.total_force`'s mean, ns.
FORCE_WINDOW_NS = 20_000_000


def window_samples(period_ns: int) -> int:
    """Return how many samples of ``period_ns`` make up :data:`FORCE_WINDOW_NS` (at least 1)."""
    return max(1, round(FORCE_WINDOW_NS / max(period_ns, 1)))


#: ``build(section, clock, where) -> LiveSkin`` of the project's transports, by import string
#: (the same as pyproject.toml's ``atikt.skins`` entry points; these win over an installed entry
#: point of the same name). The ROS 2 skin converts a topic map's topics as the bag import does,
#: so it is :mod:`recorder.bagimport`'s, named here and imported only when a rig uses it.
SKIN_TRANSPORTS: dict[str, str] = {
    "udp": "recorder.live._frames:udp_skin",
    "serial": "recorder.live._frames:serial_skin",
    "ros2": "recorder.bagimport._ros2skin:ros2_skin",
}
#: Entry point group of skin transports: a lab's package adds its own skin by name
#: (``[project.entry-points."atikt.skins"] myskin = "mypkg:build"``), as rigs in ``atikt.rigs``.
SKIN_ENTRY_POINTS = "atikt.skins"


def skin_transports() -> dict[str, str]:
    """Return every skin transport by name: the project's, then installed plug-ins."""
    found = dict(SKIN_TRANSPORTS)
    for entry in importlib.metadata.entry_points(group=SKIN_ENTRY_POINTS):
        found.setdefault(entry.name, entry.value)
    return found


def open_skin(section: Mapping[str, Any], clock: RecorderClock, where: str) -> LiveSkin:
    """Build the live skin a rig configuration's ``[skin]`` table describes (not yet open).

    Args:
        section: The ``[skin]`` table (``transport`` and the transport's own keys).
        clock: The recorder's clock (receive times).
        where: The configuration file, for messages.

    Raises:
        RigError: No or an unknown transport, or the transport refuses the table.
    """
    transport = section.get("transport")
    transports = skin_transports()
    target = transports.get(str(transport))
    if target is None:
        known = ", ".join(transports)
        msg = f"{where}: [skin] transport = {transport!r}: give one of {known}"
        raise RigError(msg)
    module, _, name = target.partition(":")
    try:
        build: Callable[[Mapping[str, Any], RecorderClock, str], LiveSkin] = getattr(
            importlib.import_module(module), name
        )
    except (ImportError, AttributeError) as err:
        if transport in SKIN_TRANSPORTS:
            extra = "ros2" if transport == "ros2" else "serial"
            fix = f"install it with pip install 'atikt[{extra}]'"
        else:
            fix = f"reinstall or fix the package that provides the {transport!r} skin"
        msg = f"{where}: the {transport} skin transport is not available ({err}); {fix}"
        raise RigError(msg) from err
    return build(section, clock, where)
