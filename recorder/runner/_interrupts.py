"""Ctrl-C, SIGTERM and SIGHUP during an action: a flag the runner sees within one cycle.

A signal must not end an action from wherever Python happens to be (inside the writer, between
two halves of a message): while an action runs, SIGINT, SIGTERM and SIGHUP (the terminal or the
SSH connection closed) only set a flag; the runner sends the stop, keeps what arrived
(``.incomplete.mcap``) and then ends the run with :func:`raise_interrupt` (``KeyboardInterrupt``,
or :class:`schemas.cli.Terminated` for SIGTERM and SIGHUP, which the commands turn into exit
status 130, 143 and 129). Outside an action the handlers of the command (``schemas.cli``)
apply: the run ends at once. A signal ignored when the block starts (``nohup``) stays ignored.
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

#: The signals an action defers: Ctrl-C, SIGTERM and SIGHUP (a closed terminal or SSH link).
SIGNALS = cli.ENDING_SIGNALS


@dataclass(slots=True)
class InterruptFlag:
    """Set by the first SIGINT, SIGTERM or SIGHUP while an action runs.

    Attributes:
        signum: The signal (None: none came).
    """

    signum: int | None = None

    @property
    def reason(self) -> str:
        """Return the stop's reason, one line."""
        name = cli.signal_name(self.signum) if self.signum else ""
        return f"interrupted by {'Ctrl-C (SIGINT)' if name == 'SIGINT' else name}"


@contextlib.contextmanager
def deferred_interrupts() -> Iterator[InterruptFlag]:
    """Defer the ending signals to a flag inside the block (main thread; elsewhere: no-op).

    The previous handlers come back when the block is left (after a signal came, a command's
    handler as it would be after its first one: further ones ignored); the caller raises the
    deferred signal (:func:`raise_interrupt`) once what arrived is saved.
    """
    flag = InterruptFlag()

    def handler(signum: int, frame: FrameType | None) -> None:
        del frame
        if flag.signum is None:
            flag.signum = signum

    try:  # a signal ignored stays ignored (workers leave Ctrl-C to their parent; nohup)
        wanted = [n for n in SIGNALS if signal.getsignal(n) is not signal.SIG_IGN]
        previous = {number: signal.signal(number, handler) for number in wanted}
    except ValueError:  # not the main thread: signals are not ours to handle
        yield flag
        return
    try:
        yield flag
    finally:
        for number, old in previous.items():
            taken = flag.signum is not None  # the command's first signal: further ones ignored
            signal.signal(number, cli.after_deferred_interrupt(old) if taken else old)


def raise_interrupt(signum: int) -> NoReturn:
    """End the run for a deferred signal: KeyboardInterrupt, or Terminated (SIGHUP: HungUp)."""
    raise cli.ending(signum)
