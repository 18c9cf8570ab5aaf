"""Count every sample of a live source: expected, received, missing, duplicated, out of order.

What a source should have delivered comes from the source itself, not from what arrived:
its sequence counter (skin frames, DDS sample counters) or its own clock and nominal period
(RTDE's controller ``timestamp``). rosbag2 cannot say what it dropped; a recording here says,
per source, how many samples the source sent in the recording's span and how many of them
arrived once, twice, late or never, and how the source's clock relates to the recorder's
(the record: :mod:`schemas._sources`).
"""

from __future__ import annotations

from collections import deque

from recorder.errors import RecorderError
from schemas import SOURCES_RECORD, SourceStats, encode_source_stats, parse_source_stats

__all__ = [
    "SOURCES_RECORD",
    "SourceCounter",
    "SourceStats",
    "encode_source_stats",
    "parse_source_stats",
]

#: How many recent sequence numbers are remembered to tell a duplicate from a late sample
#: (at 1 kHz, 8 s of history: far beyond any reordering a network or a driver produces).
SEEN_WINDOW = 8192
#: Span of sensor time over which the lowest transport latency is taken as the clock offset.
OFFSET_WINDOW_NS = 1_000_000_000


class SourceCounter:
    """Counts the samples of one source as they are consumed (not thread-safe: one consumer).

    Give each sample its sequence number (``sequence``) when the source has a counter, else
    its sensor time: the number is then ``round((sensor - first) / period)``, so a missing
    controller cycle is a missing sample. Counters that wrap (a 16-bit frame counter) are
    unwrapped with ``modulo``.
    """

    def __init__(self, name: str, *, period_ns: int = 0, modulo: int = 0) -> None:
        """Start counting.

        Args:
            name: The source's name (unique in a recording, no dots).
            period_ns: Nominal sample period, ns; needed when samples carry no sequence.
            modulo: The counter wraps at this value (0: it never wraps).
        """
        self.name = name
        self._period_ns = period_ns
        self._modulo = modulo
        self._basis = "counter"
        self._first: int | None = None
        self._max = 0
        self._seen: set[int] = set()
        self._order: deque[int] = deque()
        self._received = self._unique = self._duplicated = self._late = self._overflowed = 0
        self._first_sensor = self._last_sensor = self._first_receive = self._last_receive = 0
        self._offset_first: int | None = None
        self._offset_last: int | None = None
        self._last_window_start = 0
        self._latency_max = 0

    def _unwrap(self, raw: int) -> int:
        """Return the unwrapped sequence number nearest to the largest seen so far."""
        if not self._modulo or self._first is None:
            return raw
        base = self._max - self._max % self._modulo
        candidates = (base - self._modulo + raw, base + raw, base + self._modulo + raw)
        return min(candidates, key=lambda c: abs(c - self._max))

    def _number(self, sequence: int | None, sensor_ns: int) -> int:
        """Return the sample's sequence number (from the counter, or from the clock)."""
        if sequence is not None:
            return self._unwrap(sequence)
        if self._period_ns <= 0:
            msg = f"source {self.name}: a sample without a sequence number needs period_ns"
            raise RecorderError(msg)
        self._basis = "clock"
        origin = self._first_sensor if self._first is not None else sensor_ns
        return round((sensor_ns - origin) / self._period_ns)

    def observe(self, sequence: int | None, sensor_ns: int, receive_ns: int) -> bool:
        """Count one arrived sample; return whether it is new (not a duplicate).

        Args:
            sequence: The source's sequence number, or None to count by the sensor clock.
            sensor_ns: The sample's time on the source's clock, ns.
            receive_ns: The sample's receive time on the recorder's clock, ns.
        """
        number = self._number(sequence, sensor_ns)
        self._received += 1
        if self._first is None:
            self._first = self._max = number
            self._first_sensor = sensor_ns
            self._first_receive = receive_ns
        elif number in self._seen:
            self._duplicated += 1
            return False
        elif number > self._max:
            self._max = number
        else:
            self._late += 1
            self._first = min(self._first, number)
        self._remember(number)
        self._unique += 1
        self._clock(sensor_ns, receive_ns)
        return True

    def _remember(self, number: int) -> None:
        """Keep the recent sequence numbers (a bounded window)."""
        self._seen.add(number)
        self._order.append(number)
        if len(self._order) > SEEN_WINDOW:
            self._seen.discard(self._order.popleft())

    def _clock(self, sensor_ns: int, receive_ns: int) -> None:
        """Track the clock offset (lowest latency of the first and of the latest second)."""
        if sensor_ns >= self._last_sensor or self._unique == 1:
            self._last_sensor = sensor_ns
            self._last_receive = receive_ns
        offset = receive_ns - sensor_ns
        if sensor_ns - self._first_sensor < OFFSET_WINDOW_NS:
            self._offset_first = (
                offset if self._offset_first is None else min(self._offset_first, offset)
            )
        if sensor_ns - self._last_window_start >= OFFSET_WINDOW_NS:
            self._last_window_start = sensor_ns
            self._offset_last = offset
        elif self._offset_last is None or offset < self._offset_last:
            self._offset_last = offset
        if self._offset_first is not None:
            self._latency_max = max(self._latency_max, offset - self._offset_first)

    def overflow(self, count: int = 1) -> None:
        """Count samples the reader's queue had to drop."""
        self._overflowed += count

    @property
    def clock_offset_ns(self) -> int | None:
        """Recorder time minus source time (None before the first sample)."""
        return self._offset_first

    def stats(self) -> SourceStats:
        """Return the counts so far."""
        expected = 0 if self._first is None else self._max - self._first + 1
        offset = self._offset_first or 0
        return SourceStats(
            name=self.name,
            basis=self._basis,
            expected=expected,
            received=self._received,
            missing=max(expected - self._unique, 0),
            duplicated=self._duplicated,
            out_of_order=self._late,
            overflowed=self._overflowed,
            period_ns=self._period_ns,
            first_sensor_ns=self._first_sensor,
            last_sensor_ns=self._last_sensor,
            first_receive_ns=self._first_receive,
            last_receive_ns=self._last_receive,
            clock_offset_ns=offset,
            clock_drift_ns=(self._offset_last or offset) - offset,
            latency_max_ns=self._latency_max,
        )
