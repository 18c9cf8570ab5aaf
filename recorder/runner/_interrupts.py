r"""Ctrl-C, SIGTERM, SIGHUP (and Ctrl-Z, Ctrl-\) during an action: a flag the runner sees.

A signal must not end an action from wherever Python happens to be (inside the writer, between
two halves of a message): while an action runs, SIGINT, SIGTERM and SIGHUP (the terminal or the
SSH connection closed) only set a flag; the runner sends the stop, keeps what arrived
(``.incomplete.mcap``) and then ends the run with :func:`raise_interrupt` (``KeyboardInterrupt``,
or :class:`schemas.cli.Terminated` for SIGTERM and SIGHUP, which the commands turn into exit
status 130, 143 and 129). While an arm moves, Ctrl-Z (SIGTSTP) and Ctrl-\ (SIGQUIT) are
deferred too and end the run (exit status 148, 131): a suspended recorder would leave the arm
unwatched, a quit one the arm running. Outside an action
the handlers of the command (``schemas.cli``) apply: the run ends at once (Ctrl-Z suspends).
A signal ignored when the block starts (``nohup``) stays ignored.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING, NoReturn

from schemas import cli

if TYPE_CHECKING:
    from collections.abc import Iterator
    from types import FrameType

#: The signals an action defers: Ctrl-C, SIGTERM and SIGHUP (a closed terminal or SSH link).
SIGNALS = cli.ENDING_SIGNALS
#: Deferred too while an arm moves: Ctrl-Z would leave it unwatched (``schemas.cli.Suspended``).
SUSPEND = getattr(signal, "SIGTSTP", None)
#: Deferred too while an arm moves: Ctrl-\ would end the process at once, the arm running on
#: (``schemas.cli.Quit``).
QUIT = getattr(signal, "SIGQUIT", None)
#: What an arm's block defers besides :data:`SIGNALS` (where the platform has them).
ARM_SIGNALS = tuple(n for n in (SUSPEND, QUIT) if n is not None)
#: Sent when a stopped process goes on (after SIGSTOP, which no process can catch).
CONTINUE = getattr(signal, "SIGCONT", None)


@dataclass(slots=True)
class InterruptFlag:
    """Set by the first SIGINT, SIGTERM or SIGHUP while an action runs.

    Attributes:
        signum: The signal (None: none came).
        continued: The process was stopped (SIGSTOP) and went on while the arm moved: the
            arm went unwatched meanwhile.
    """

    signum: int | None = None
    continued: bool = False
    #: Why a driver call holds the runner's loop (empty: it does not): a signal then ends
    #: the run at once, as nothing else would ever see this flag.
    held: str = ""

    @property
    def stopped_meanwhile(self) -> str:
        """Return why the action must end after the process was stopped (empty: it was not)."""
        if not self.continued:
            return ""
        return (
            "the recorder was stopped (SIGSTOP) while the arm moved, and continued: the arm "
            "went unwatched meanwhile"
        )

    @property
    def reason(self) -> str:
        """Return the stop's reason, one line."""
        name = cli.signal_name(self.signum) if self.signum else ""
        keys = {
            "SIGINT": "Ctrl-C (SIGINT)",
            "SIGTSTP": "Ctrl-Z (SIGTSTP)",
            "SIGQUIT": "Ctrl-\\ (SIGQUIT)",
        }
        return f"interrupted by {keys.get(name, name)}"


@contextlib.contextmanager
def deferred_interrupts(*, arm: bool = False) -> Iterator[InterruptFlag]:
    r"""Defer the ending signals to a flag inside the block (main thread; elsewhere: no-op).

    With ``arm`` (the block moves an arm), Ctrl-Z (SIGTSTP) and Ctrl-\ (SIGQUIT) too: they end
    the run as Ctrl-C does rather than suspend or quit the process with the arm unwatched.

    The previous handlers come back when the block is left (after a signal came, a command's
    handler as it would be after its first one: further ones ignored); the caller raises the
    deferred signal (:func:`raise_interrupt`) once what arrived is saved.
    """
    flag = InterruptFlag()

    def handler(signum: int, frame: FrameType | None) -> None:
        del frame
        if flag.signum is None:
            flag.signum = signum
        if flag.held:  # the loop that would see the flag is held by a driver call
            raise cli.ending(flag.signum)

    def continued(signum: int, frame: FrameType | None) -> None:
        del signum, frame
        flag.continued = True

    try:  # a signal ignored stays ignored (workers leave Ctrl-C to their parent; nohup)
        deferred = (*SIGNALS, *ARM_SIGNALS) if arm else SIGNALS
        wanted = [n for n in deferred if signal.getsignal(n) is not signal.SIG_IGN]
        previous = {number: signal.signal(number, handler) for number in wanted}
        if arm and CONTINUE is not None:
            previous[CONTINUE] = signal.signal(CONTINUE, continued)
    except ValueError:  # not the main thread: signals are not ours to handle
        yield flag
        return
    _DEFERRING.append(flag)
    try:
        yield flag
    finally:
        _DEFERRING.remove(flag)
        for number, old in previous.items():
            taken = flag.signum is not None  # the command's first signal: further ones ignored
            ending = taken and number != CONTINUE
            signal.signal(number, cli.after_deferred_interrupt(old) if ending else old)


#: The flags of the deferring blocks open now (the main thread's; usually one).
_DEFERRING: list[InterruptFlag] = []


def runner_held(why: str) -> None:
    """Let a signal end the run at once: a driver call holds the runner's loop (the watchdog).

    Called from the watchdog's thread after it sent the stop. A signal that came already is
    sent to the main thread again: its handler now raises, which also ends a wait the signal
    interrupts (a socket, a sleep, a lock; PEP 475), so the run ends and what arrived is kept.
    """
    for flag in _DEFERRING:
        flag.held = why
        if flag.signum is not None and (main := threading.main_thread().ident) is not None:
            signal.pthread_kill(main, flag.signum)


def raise_interrupt(signum: int) -> NoReturn:
    """End the run for a deferred signal: KeyboardInterrupt, or Terminated (SIGHUP: HungUp)."""
    raise cli.ending(signum)
