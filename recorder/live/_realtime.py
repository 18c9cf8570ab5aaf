"""Real-time scheduling of the threads that keep a robot safe (the rig option ``rt_priority``).

At 500 Hz a controller cycle is 2 ms, and on a busy computer the operating system may keep a
thread that has a state sample to check, or a stop to send, waiting for several of them. UR's
own drivers (``ur_rtde``'s ``rt_priority``, the ROS driver's communication thread) run such
threads under ``SCHED_FIFO``; so does the recorder when a rig sets ``rt_priority``, but only
these threads, each for itself:

- the live sources' readers (:class:`recorder.live.SourceReader`) created while
  :func:`readers_at` is in effect, for their whole life;
- the runner's loop while an action (or a presentation) runs (:func:`real_time`), and not
  between actions, where a session may be learning.

Each switches with ``SCHED_RESET_ON_FORK``: a thread or process it starts (the writer, a BLAS
pool, a viewer) runs at normal priority, never inheriting the real-time one.

Python's standard library has the system call (``os.sched_setscheduler``); what is written
here is only the policy of which thread gets it and when, which no library knows.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
from typing import TYPE_CHECKING

from recorder.errors import RigError

if TYPE_CHECKING:
    from collections.abc import Iterator

#: The priorities ``SCHED_FIFO`` accepts on Linux.
PRIORITIES = range(1, 100)
#: What a thread got when no real-time scheduling was asked for or granted.
NORMAL = "normal"

#: The priority of the readers created in this context (0: normal scheduling).
_READERS: contextvars.ContextVar[int] = contextvars.ContextVar("atikt_readers_rt", default=0)


def check_rt_priority(priority: int, where: str) -> None:
    """Refuse a priority ``SCHED_FIFO`` does not have (0: none asked for).

    Raises:
        RigError: One line naming the file, the value and the range.
    """
    if priority != 0 and priority not in PRIORITIES:
        msg = (
            f"{where}: rig option rt_priority = {priority}: give 1-99 (real-time priority of "
            "the threads that read the arm and the skin and check the limits; leave it out "
            "for normal scheduling)"
        )
        raise RigError(msg)


def _switch(priority: int) -> tuple[int, os.sched_param] | str:
    """Put the calling thread under ``SCHED_FIFO`` at ``priority`` (``SCHED_RESET_ON_FORK``).

    Returns:
        The thread's previous policy and parameters (to restore), or why it was refused.
    """
    if not hasattr(os, "sched_setscheduler"):
        return "this system has no SCHED_FIFO"
    policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(priority))
    except OSError as err:
        return f"real-time scheduling refused ({err.strerror})"
    return policy, param


def rt_refusal(priority: int) -> str | None:
    """Return why this thread may not use ``SCHED_FIFO`` at ``priority`` (None: it may).

    The calling thread is switched and switched back, so that a refusal is known (and said
    once) before anything moves.
    """
    if priority == 0:
        return None
    switched = _switch(priority)
    if isinstance(switched, str):
        return switched
    os.sched_setscheduler(0, *switched)
    return None


@contextlib.contextmanager
def real_time(priority: int) -> Iterator[str]:
    """Run the calling thread alone under ``SCHED_FIFO`` at ``priority`` for the block.

    Threads and processes started meanwhile run at normal priority (``SCHED_RESET_ON_FORK``).
    A system that refuses it (no right to real-time scheduling) leaves the thread as it was.

    Yields:
        What the thread got: ``"SCHED_FIFO 50"``, or ``"normal"`` (nothing asked for, or
        refused: :func:`rt_refusal` says why, once, before anything moves).
    """
    switched = NORMAL if priority == 0 else _switch(priority)
    if isinstance(switched, str):
        yield NORMAL
        return
    try:
        yield f"SCHED_FIFO {priority}"
    finally:
        with contextlib.suppress(OSError):  # lowering one's own priority is always allowed
            os.sched_setscheduler(0, *switched)


@contextlib.contextmanager
def readers_at(priority: int) -> Iterator[None]:
    """Give the live sources' readers created in the block ``SCHED_FIFO`` at ``priority``."""
    token = _READERS.set(priority)
    try:
        yield
    finally:
        _READERS.reset(token)


def reader_priority() -> int:
    """Return the priority a reader created now runs at (0: normal scheduling)."""
    return _READERS.get()
