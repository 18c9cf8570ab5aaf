"""Real-time scheduling of the recorder's threads at the robot (the rig option ``rt_priority``).

At 500 Hz a controller cycle is 2 ms, and on a busy computer the operating system may keep a
thread that has a state sample to check, or a stop to send, waiting for several of them. UR's
own drivers (``ur_rtde``'s ``rt_priority``, the ROS driver's communication thread) run their
real-time threads under ``SCHED_FIFO`` for that reason; so does the recorder when a rig sets
``rt_priority``: the thread that connects the rig (the runner's loop) is switched to
``SCHED_FIFO`` at that priority *before* the arm's and the skin's readers start, so they and
the writer inherit it (Linux threads inherit their creator's policy), and it is restored when
the rig disconnects. The interpreter still hands its lock over within a quarter cycle
(``ArmRig``), and the kernel's real-time throttling keeps a runaway thread from taking a core.

It needs the right to use real-time scheduling (root, ``CAP_SYS_NICE``, or an ``rtprio``
limit: ``ulimit -r``, ``/etc/security/limits.conf``); without it the recorder says so in one
line and records at normal priority. Either way each recording's metadata says which it got
(fact ``scheduling``).
"""

from __future__ import annotations

import contextlib
import os
import sys
from typing import TYPE_CHECKING

from recorder.errors import RigError

if TYPE_CHECKING:
    from collections.abc import Iterator

#: The priorities ``SCHED_FIFO`` accepts on Linux.
PRIORITIES = range(1, 100)
#: What the recordings say when no real-time scheduling was asked for.
NORMAL = "normal"


def check_priority(priority: int, where: str) -> None:
    """Refuse a priority ``SCHED_FIFO`` does not have (0: none asked for).

    Raises:
        RigError: One line naming the file, the value and the range.
    """
    if priority != 0 and priority not in PRIORITIES:
        msg = (
            f"{where}: rig option rt_priority = {priority}: give 1-99 (real-time priority of "
            "the recorder's threads; leave it out for normal scheduling)"
        )
        raise RigError(msg)


@contextlib.contextmanager
def real_time(priority: int, where: str) -> Iterator[str]:
    """Run the calling thread, and the threads it starts, under ``SCHED_FIFO`` at ``priority``.

    Yields:
        What the thread got, for the recordings: ``"SCHED_FIFO 50"``, or ``"normal"`` (nothing
        asked for, or refused by the system: then one line on standard error says why and
        what to do).
    """
    if priority == 0:
        yield NORMAL
        return
    setscheduler = getattr(os, "sched_setscheduler", None)
    if setscheduler is None:  # not Linux: no SCHED_FIFO from Python
        _say(
            f"{where}: rt_priority = {priority}: this system has no SCHED_FIFO; recording at "
            "normal priority"
        )
        yield NORMAL
        return
    policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as err:
        _say(
            f"{where}: rt_priority = {priority}: real-time scheduling refused ({err.strerror}); "
            "recording at normal priority (allow it with an rtprio limit, e.g. "
            "'@robot - rtprio 99' in /etc/security/limits.conf, or CAP_SYS_NICE)"
        )
        yield NORMAL
        return
    try:
        yield f"SCHED_FIFO {priority}"
    finally:
        with contextlib.suppress(OSError):
            setscheduler(0, policy, param)


def _say(line: str) -> None:
    """Print one line for the operator (the recorder goes on)."""
    print(line, file=sys.stderr, flush=True)  # noqa: T201 (a warning for the operator)
