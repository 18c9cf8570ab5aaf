"""What happened in the virtual lab, with both clocks: for measuring stops and auditing faults.

Every event carries the controller's clock (``controller_ns``: ns since the lab started, the
clock of RTDE's ``timestamp``) and the raw ``time.monotonic_ns()`` of this machine when the
lab computed it (comparable with a recorder's monotonic clock on the same machine). Events of
a cycle (a program's first call, a speed reaching zero) carry the cycle's end as their
controller time and are computed when a server or the lab's ticking thread reaches that
cycle: on time within a cycle, unless the machine is too loaded (``VirtualWorld.overruns``).
The controller's clock is the monotonic clock shifted: ``monotonic = origin_monotonic_ns +
controller_ns`` (``origin_monotonic_ns`` is in the first event). Kinds:

- ``start``: the lab started (``origin_monotonic_ns``, ``frequency``, ``time_scale``);
- ``program``: a program's first function call ran (``received_monotonic_ns``: when its text
  arrived on the URScript port; ``name``: its ``def`` name; ``calls``; ``announced``: the
  ``atikt:`` message's pairs);
- ``program_refused``: a program that does not run (``reason``, one line);
- ``fault``: a fault injected (``source``: rtde, script, skin, ros2; ``fault``; details);
- ``commanded_zero`` / ``actual_zero``: the commanded (``target_TCP_speed``) or the actual
  (``actual_TCP_speed``) TCP speed reached zero, after moving;
- ``action``: an announced action began (``object``, ``action``, ``trial``);
- ``stop`` / ``unlock``: a protective or emergency stop, and its release;
- ``halt``: the running program ended by the dashboard's ``stop`` (``program``: its name);
- ``mode``: the robot mode changed (``robot_mode``: 3 powered off, 5 idle with the brakes
  engaged, 7 running), by the dashboard's ``power off``, ``power on`` and ``brake release``;
- ``slider``: the teach pendant's speed slider moved (``fraction``, 0..1).

``serve-sim --events FILE`` writes each as one JSON line as it happens (an object with
``event``, ``controller_ns``, ``monotonic_ns`` and the details above); in process,
``VirtualWorld.events()`` returns them.
"""

from __future__ import annotations

import json
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TextIO

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping

#: Events kept in memory (the oldest go first; the file keeps every one).
MAX_EVENTS = 100_000


@dataclass(frozen=True, slots=True)
class Event:
    """One thing that happened.

    Attributes:
        kind: What (see the module's docstring).
        controller_ns: The controller's clock, ns.
        monotonic_ns: ``time.monotonic_ns()`` when the lab saw it.
        details: What else is known, JSON values.
    """

    kind: str
    controller_ns: int
    monotonic_ns: int
    details: Mapping[str, Any] = field(default_factory=dict)

    def json(self) -> str:
        """Return the event as one JSON line (without the newline)."""
        record = {
            "event": self.kind,
            "controller_ns": self.controller_ns,
            "monotonic_ns": self.monotonic_ns,
            **self.details,
        }
        return json.dumps(record, sort_keys=False)


class EventLog:
    """Thread-safe record of events, optionally written to a stream as JSON lines."""

    def __init__(
        self, sink: TextIO | None = None, echo: Callable[[Event], None] | None = None
    ) -> None:
        """Start empty.

        Args:
            sink: Receives every event as a JSON line, flushed.
            echo: Called with every ``fault`` event and every stop program the recorder sent
                to end an action or a move early (serve-sim prints one line each).
        """
        self._lock = threading.Lock()
        self._events: deque[Event] = deque(maxlen=MAX_EVENTS)
        self.sink = sink
        self.echo = echo

    def add(self, kind: str, controller_ns: int, /, **details: Any) -> Event:  # noqa: ANN401
        """Record an event now (monotonic time read here)."""
        event = Event(kind, controller_ns, time.monotonic_ns(), details)
        with self._lock:
            self._events.append(event)
            if self.sink is not None:
                self.sink.write(event.json() + "\n")
                self.sink.flush()
        if self.echo is not None and _echoed(event):
            self.echo(event)
        return event

    def events(self, kind: str | None = None) -> tuple[Event, ...]:
        """Return the events so far (of one kind)."""
        with self._lock:
            return tuple(e for e in self._events if kind is None or e.kind == kind)

    def faults(self) -> dict[str, dict[str, int]]:
        """Return how many faults of each kind each source injected (the summary)."""
        summary: dict[str, dict[str, int]] = {}
        for event in self.events("fault"):
            source = summary.setdefault(str(event.details.get("source", "")), {})
            name = str(event.details.get("fault", ""))
            source[name] = source.get(name, 0) + int(event.details.get("count", 1))
        return summary


def _echoed(event: Event) -> bool:
    """Say whether serve-sim prints the event: a fault, or a stop a lab should see.

    The stops within an action (at the light contact, an approach pausing for a late skin,
    a slide's end) are part of it (not printed); a stop program announced as ``stop`` (or
    not announced: between actions) is a stop the recorder sent on a limit, Ctrl-C or an
    error, and a lab rehearsing wants to see it arrive.
    """
    if event.kind == "fault":
        return True
    if event.kind != "program" or "stopl" not in event.details.get("calls", ()):
        return False
    announced = event.details.get("announced") or {}
    return announced.get("phase", "stop") == "stop" and "speedl" not in event.details["calls"]
