"""A watchdog on the runner's calls into its drivers: a call that holds the loop gets the stop.

The runner checks the limits on every state sample in its own loop; a driver call that does
not return (a lab's driver waiting on a dead socket, a vendor library stuck on a lock) holds
that loop, and with it every check, the silence detection and every deferred signal. The
watchdog, a thread of its own, sends the stop when a call has lasted longer than the runner
allows a source to be silent (the arm unseen that long ends an action anyway), says so at once
in one line, and from then on a signal ends the run at once
(:func:`recorder.runner._interrupts.runner_held`): the loop that would see the deferred signal
may never run again. When the call returns, the action ends as a stop does.

Written by hand: no library watches a call in progress and acts for it; this is a thread, a
slot naming the call and a deadline.
"""

from __future__ import annotations

import contextlib
import sys
import threading
import time
from typing import TYPE_CHECKING, Self

from recorder.runner._interrupts import runner_held

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator, Mapping
    from types import TracebackType

    import numpy as np
    from numpy.typing import NDArray

    from recorder.runner._arm import ArmDriver, ArmSample, Context
    from schemas import SourceStats

_NS = 1_000_000_000
#: The least a call may hold the loop before the watchdog acts, s: a loaded machine (the tests
#: beside the recorder, a browser) can hold a thread for a tenth of a second, which is not a
#: hung driver.
LEAST_S = 0.5
#: What the watchdog calls the driver's stop in its lines (it never sends a second one then).
STOP_CALL = "the arm driver's stop()"


class Watchdog:
    """Watches one call at a time; sends the stop when it outlasts its deadline."""

    def __init__(self, stop: Callable[[str], None], where: str, allowed_s: float) -> None:
        """Keep how to stop the arm and how long a call may hold the loop.

        Args:
            stop: Sends the stop from the watchdog's thread, given why; raises when it could
                not. The driver's ``stop`` must allow this (see
                :class:`recorder.runner.ArmDriver`).
            where: The rig configuration, for the line.
            allowed_s: How long a call may last beyond its own wait, s (at least
                :data:`LEAST_S`).
        """
        self._stop, self.where, self.allowed_s = stop, where, allowed_s
        #: The call in progress: (what, how long it may last, when it began, the starvation
        #: counted when it began), ns.
        self._call: tuple[str, int, int, int] | None = None
        #: How long the watchdog itself was held beyond its own waits, ns: the whole process
        #: was (a loaded machine), and the call's time meanwhile is not the driver's.
        self._starved_ns = 0
        #: Why the watchdog sent the stop in this action (empty: it did not).
        self.fired = ""
        self._closed = threading.Event()
        self._thread: threading.Thread | None = None

    def __enter__(self) -> Self:
        """Start watching."""
        self._closed.clear()
        self._thread = threading.Thread(target=self._watch, name="runner-watchdog", daemon=True)
        self._thread.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Stop watching (a stop it is still sending goes on in its own thread)."""
        self._closed.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        self._thread = None

    def rearm(self) -> None:
        """Forget an earlier firing (a new action or move begins)."""
        self.fired = ""

    @contextlib.contextmanager
    def calling(self, what: str, wait_s: float = 0.0) -> Iterator[None]:
        """Watch the call made inside the block: ``what``, which may wait ``wait_s`` itself."""
        allowed = round((wait_s + max(self.allowed_s, LEAST_S)) * _NS)
        self._call = (what, allowed, time.monotonic_ns(), self._starved_ns)
        try:
            yield
        finally:
            self._call = None

    def _watch(self) -> None:
        every = min(max(self.allowed_s, LEAST_S) / 10, 0.05)
        last = time.monotonic_ns()
        while not self._closed.wait(every):
            now = time.monotonic_ns()
            self._starved_ns += max(0, now - last - round(2 * every * _NS))
            last = now
            call = self._call
            if call is None or self.fired:
                continue
            what, allowed, began, starved = call
            if now - began - (self._starved_ns - starved) > allowed:
                self._fire(what, (now - began) / _NS)

    def _fire(self, what: str, held: float) -> None:
        """Send the stop (unless the stop is what hangs), say so, let a signal end the run."""
        why = f"{what} held the runner for {held:.2f} s"
        self.fired = why
        if what == STOP_CALL:
            said = "the stop may not have reached the arm; stop it at the teach pendant now"
        else:
            said = self._send(why)
        runner_held(f"{why}; {said}")
        print(  # noqa: T201 (at once, for the person at the robot: the loop is held)
            f"{self.where}: {what} has not returned for {held:.2f} s: {said}; the action ends "
            "when it returns, Ctrl-C ends the run now",
            file=sys.stderr,
            flush=True,
        )

    def _send(self, why: str) -> str:
        """Send the stop from a thread of its own, waiting for it at most ``allowed_s``."""
        failed: list[str] = []

        def send() -> None:
            try:
                self._stop(why)
                failed.append("")
            except Exception as err:  # noqa: BLE001 (whatever failed, the line must say so)
                failed.append(str(err) or type(err).__name__)

        sender = threading.Thread(target=send, name="runner-watchdog-stop", daemon=True)
        sender.start()
        sender.join(self.allowed_s)
        if not failed:
            return "the stop sent has not returned either; stop the arm at the teach pendant now"
        if failed[0]:
            return f"the stop did not reach the arm ({failed[0]}); stop it at the teach pendant now"
        return "the stop was sent (the arm unseen since)"


class WatchedArm:
    """An arm driver whose calls the watchdog watches (what the runner calls, by name)."""

    def __init__(self, arm: ArmDriver, dog: Watchdog) -> None:
        """Wrap ``arm``."""
        self._arm, self._dog = arm, dog

    def __enter__(self) -> Self:  # pragma: no cover (the runner connects the driver itself)
        """Connect the driver."""
        self._arm.__enter__()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:  # pragma: no cover (the runner disconnects the driver itself)
        """Disconnect the driver."""
        self._arm.__exit__(exc_type, exc, tb)

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Return the driver's joint names."""
        return self._arm.joint_names

    @property
    def period_ns(self) -> int:
        """Return the driver's controller cycle, ns."""
        return self._arm.period_ns

    def describe(self) -> Mapping[str, str]:
        """Return the driver's configuration."""
        return self._arm.describe()

    def facts(self) -> Mapping[str, str]:
        """Return what the driver learned on connecting."""
        return self._arm.facts()

    def stats(self) -> list[SourceStats]:
        """Return the driver's accounting."""
        return self._arm.stats()

    def begin(self) -> None:
        """Start a new action (watched)."""
        with self._dog.calling("the arm driver's begin()"):
            self._arm.begin()

    def poll(self, wait_s: float) -> list[ArmSample]:
        """Read the state (watched beyond its own wait)."""
        with self._dog.calling("the arm driver's poll()", wait_s):
            return self._arm.poll(wait_s)

    def speed(
        self, velocity: NDArray[np.float64], acceleration: float, duration_s: float, at: Context
    ) -> None:
        """Command a speed (watched)."""
        with self._dog.calling("the arm driver's speed()"):
            self._arm.speed(velocity, acceleration, duration_s, at)

    def move(
        self, pose: NDArray[np.float64], speed: float, acceleration: float, at: Context | None
    ) -> None:
        """Command a move (watched)."""
        with self._dog.calling("the arm driver's move()"):
            self._arm.move(pose, speed, acceleration, at)

    def force_slide(
        self,
        force_n: float,
        velocity: NDArray[np.float64],
        duration_s: float,
        acceleration: float,
        at: Context,
    ) -> None:
        """Command a force-controlled slide (watched)."""
        with self._dog.calling("the arm driver's force_slide()"):
            self._arm.force_slide(force_n, velocity, duration_s, acceleration, at)

    def announce(self, at: Context) -> None:
        """Mark a phase (watched)."""
        with self._dog.calling("the arm driver's announce()"):
            self._arm.announce(at)

    def stop(self, acceleration: float, at: Context | None) -> str:
        """Stop the arm (watched: a stop that hangs is said, never sent again)."""
        with self._dog.calling(STOP_CALL):
            return self._arm.stop(acceleration, at)
