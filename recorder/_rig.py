"""The rig protocol: anything that can perform an exploratory action and stream its signals."""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, Self, runtime_checkable

if TYPE_CHECKING:
    from collections.abc import Iterator, Mapping
    from types import TracebackType

    from recorder._catalog import ActionSpec, ObjectSpec
    from recorder.writing._stream import StreamItem
    from schemas import SourceStats


class Rig(Protocol):
    """A robot with skin that performs exploratory actions.

    A rig is a context manager: ``__enter__`` connects, ``__exit__`` disconnects, also when
    the action failed. ``perform`` streams one action execution: the approach, the light
    contact, the action itself and the retract, as items ordered by receive time.
    """

    def __enter__(self) -> Self:
        """Connect to the rig."""
        ...

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Disconnect from the rig, whatever happened."""
        ...

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Return the arm's joint names in the order of its joint states (empty: no arm)."""
        ...

    def describe(self) -> Mapping[str, str]:
        """Return the rig's kind and configuration, for the recording's metadata."""
        ...

    def perform(self, obj: ObjectSpec, action: ActionSpec, trial: int) -> Iterator[StreamItem]:
        """Perform ``action`` on ``obj`` as trial number ``trial``; stream what is measured."""
        ...


@runtime_checkable
class Presenting(Protocol):
    """A rig that can bring an object under its skin (an arm visiting the object's pose)."""

    def can_present(self, obj: ObjectSpec) -> bool:
        """Return whether the rig could present ``obj`` (checked before anything moves)."""
        ...

    def present(self, obj: ObjectSpec) -> bool:
        """Bring ``obj`` under the skin; False: a person must place it (no pose)."""
        ...


@runtime_checkable
class Moving(Protocol):
    """A rig whose actions move an arm: recorded the way a robot asks for.

    Before each action :meth:`check_ready` may refuse it (nothing moves, no file is made) and
    the disk must have room for it; during it, Ctrl-Z ends the run as Ctrl-C does (a suspended
    recorder leaves the arm unwatched), and the file is written by a thread of its own, so
    the rig's stream never waits for the disk. The runner's arms
    (:class:`recorder.runner.ArmRig`) are such rigs; a lab's own rig that moves an arm by
    itself declares it by this method, and stops its arm when its ``perform`` generator is
    closed early (a signal, a writer in trouble).
    """

    def check_ready(self) -> None:
        """Refuse an action that cannot start now (``recorder.RigError``, one line)."""
        ...


@runtime_checkable
class Accounting(Protocol):
    """A live rig that counts what its sources delivered in the last action."""

    def source_stats(self) -> list[SourceStats]:
        """Return the accounting of the last action, one entry per source."""
        ...


@runtime_checkable
class Connecting(Protocol):
    """A rig that learns facts when it connects (a controller's version): recorded only."""

    def facts(self) -> Mapping[str, str]:
        """Return what was learned on connecting (never compared between runs)."""
        ...


def facts(rig: Rig) -> Mapping[str, str]:
    """Return what ``rig`` learned on connecting (empty for rigs that learn nothing)."""
    return rig.facts() if isinstance(rig, Connecting) else {}


def source_stats(rig: Rig) -> list[SourceStats]:
    """Return the accounting of ``rig``'s last action (empty for rigs without live sources)."""
    return rig.source_stats() if isinstance(rig, Accounting) else []
