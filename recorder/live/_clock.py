"""The recorder's clock: monotonic, in integer nanoseconds, anchored to wall time once."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import ClassVar


@dataclass(slots=True)
class RecorderClock:
    """Receive time of live samples: ``time.monotonic_ns`` shifted to wall time at creation.

    A wall clock can jump (NTP, a person setting it); receive times must not. The clock reads
    the monotonic clock and adds the wall-clock offset measured once, so its values are
    near Unix time (readable log times) and never go back.
    """

    #: Whether the clock runs in real time (False: a simulated clock a virtual lab moves).
    real: ClassVar[bool] = True
    _offset_ns: int = field(init=False)

    def __post_init__(self) -> None:
        """Measure the offset between the wall clock and the monotonic clock."""
        self._offset_ns = time.time_ns() - time.monotonic_ns()

    def now_ns(self) -> int:
        """Return the current receive time, ns."""
        return time.monotonic_ns() + self._offset_ns
