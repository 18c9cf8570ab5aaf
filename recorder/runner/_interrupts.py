"""Ctrl-C and SIGTERM during an action: a flag the runner sees within one cycle.

A signal must not end an action from wherever Python happens to be (inside the writer, between
two halves of a message): while an action runs, SIGINT and SIGTERM only set a flag; the runner
sends the stop, keeps what arrived (``.incomplete.mcap``) and then ends the run with
:func:`raise_interrupt` (``KeyboardInterrupt``, or :class:`schemas.cli.Terminated` for SIGTERM,
which the commands turn into exit status 130 and 143). Outside an action the handlers of the
command (``schemas.cli``) apply: the run ends at once.
"""

from __future__ import annotations

import contextlib
import signal
from dataclasses import dataclass
from typing import TYPE_CHECKING, NoReturn

from schemas import cli

if TYPE_CHECKING:
    from collections.abc import Iterator
    from types import FrameType

#: The signals an action defers.
SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: Their names, for messages.
NAMES = {signal.SIGINT: "Ctrl-C (SIGINT)", signal.SIGTERM: "SIGTERM"}


@dataclass(slots=True)
class InterruptFlag:
    """Set by the first SIGINT or SIGTERM while an action runs.

    Attributes:
        signum: The signal (None: none came).
    """

    signum: int | None = None

    @property
    def reason(self) -> str:
        """Return the stop's reason, one line."""
        name = NAMES.get(signal.Signals(self.signum), str(self.signum)) if self.signum else ""
        return f"interrupted by {name}"


@contextlib.contextmanager
def deferred_interrupts() -> Iterator[InterruptFlag]:
    """Defer SIGINT and SIGTERM to a flag inside the block (main thread; elsewhere: no-op).

    The previous handlers come back when the block is left; the caller raises the deferred
    signal (:func:`raise_interrupt`) once what arrived is saved.
    """
    flag = InterruptFlag()

    def handler(signum: int, frame: FrameType | None) -> None:
        del frame
        if flag.signum is None:
            flag.signum = signum

    try:  # a signal ignored stays ignored (workers leave Ctrl-C to their parent)
        wanted = [n for n in SIGNALS if signal.getsignal(n) is not signal.SIG_IGN]
        previous = {number: signal.signal(number, handler) for number in wanted}
    except ValueError:  # not the main thread: signals are not ours to handle
        yield flag
        return
    try:
        yield flag
    finally:
        for number, old in previous.items():
            signal.signal(number, old)


def raise_interrupt(signum: int) -> NoReturn:
    """End the run for a deferred signal: KeyboardInterrupt, or Terminated for SIGTERM."""
    if signum == signal.SIGTERM:
        raise cli.Terminated
    raise KeyboardInterrupt
