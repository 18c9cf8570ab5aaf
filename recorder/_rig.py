"""The rig protocol: anything that can perform an exploratory action and stream its signals."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol, Self

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator, Mapping
    from types import TracebackType

    from recorder._catalog import ActionSpec, ObjectSpec
    from recorder.writing._stream import StreamItem


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


def rig_hook(rig: Rig, name: str) -> Callable[[ObjectSpec], Any] | None:
    """Return a rig's optional method ``name`` (``present``, ``can_present``), if it has one.

    ``present(obj) -> bool`` brings the object under the skin when the rig's configuration has
    its pose (False: a person must place it); ``can_present(obj) -> bool`` says whether it
    could, before anything moves.
    """
    method: Callable[[ObjectSpec], Any] | None = getattr(rig, name, None)
    return method
