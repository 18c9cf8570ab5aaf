"""Count every sample of a live source: expected, received, missing, duplicated, out of order.

Every sample is checked where it enters: a stamp that leaves the source's plausible range
(ahead of its arrival, or far behind it, given the lowest latency of its run so far and a
generous drift) is counted *out of range* and never written; a counter that jumps or runs
backwards against the time that passed, or a clock whose stamps jump and stay there, starts a
new *run* (counted as a counter reset), so one bad frame never shifts or hides the series.
A source without a sequence (``basis = "stamps"``: the header stamps of a ROS 2 topic whose
messages carry no counter the topic map names) has no notion of a missing sample; its pauses
are counted as *gaps* against its period.

What a source should have delivered comes from the source itself, not from what arrived:
its sequence counter (skin frames, DDS sample counters) or its own clock and nominal period
(RTDE's controller ``timestamp``). rosbag2 cannot say what it dropped; a recording here says,
per source, how many samples the source sent in the recording's span and how many of them
arrived once, twice, late or never, and how the source's clock relates to the recorder's
(the record: :mod:`schemas._sources`).
"""

from __future__ import annotations

import enum
import itertools
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from recorder.errors import RecorderError
from schemas import SOURCES_RECORD, SourceStats, encode_source_stats, parse_source_stats

if TYPE_CHECKING:
    from collections.abc import Iterable

__all__ = [
    "SOURCES_RECORD",
    "SourceCounter",
    "SourceStats",
    "Verdict",
    "counter_skipped",
    "encode_source_stats",
    "gap_periods",
    "parse_source_stats",
]

#: How many recent sequence numbers are remembered to tell a duplicate from a late sample
#: (at 1 kHz, 8 s of history: far beyond any reordering a network or a driver produces).
SEEN_WINDOW = 8192
#: Samples a counter without a known period waits for to measure it (the median step).
LEARN_SAMPLES = 16
#: Span of sensor time over which the lowest transport latency is taken as the clock offset.
OFFSET_WINDOW_NS = 1_000_000_000
#: How much earlier than its run's lowest latency allows a sample may seem to arrive (its
#: stamp ahead of the recorder's clock), ns; more is a stamp out of range.
EARLY_TOLERANCE_NS = 100_000_000
#: How much later than its run's lowest latency a sample may arrive, ns; more is out of range.
LATE_TOLERANCE_NS = 5_000_000_000
#: Drift allowed between the source's clock and the recorder's (1000 ppm: ten times a
#: crystal's worst), on top of the tolerances, per ns since the run began.
DRIFT_ALLOWED = 1e-3
#: A counter's advance may differ from the time that passed by this much (plus
#: :data:`COUNTER_RELATIVE` of it) before it counts as a reset, ns.
COUNTER_TOLERANCE_NS = 1_000_000_000
COUNTER_RELATIVE = 0.1
#: A step between stamps longer than this many periods is a gap of a source without a
#: sequence (below ``check``'s five periods: every pause ``check`` finds is counted).
GAP_PERIODS = 2.5
#: The gap threshold of a source whose stamps lie on its period's grid (see
#: :func:`gap_periods`): one skipped slot of the grid is a gap there.
GRID_GAP_PERIODS = 1.5
#: Stamps lie on the grid when every step is this close to a whole number of periods
#: (a fraction of a period).
GRID_TOLERANCE = 0.1
#: Steps needed before the stamps are judged to lie on the grid.
GRID_MIN_STEPS = 8


def gap_periods(stamps_ns: Iterable[int], period_ns: int) -> float:
    """Return the gap threshold, in periods, of a source without a sequence, from its stamps.

    A publisher that stamps with its own sample clock puts every stamp on its period's grid;
    one that stamps with the time it publishes jitters around it. The threshold between
    jitter and a pause must leave room for the jitter (:data:`GAP_PERIODS`), but when every
    step of the distinct stamps lies within :data:`GRID_TOLERANCE` of a whole number of
    periods (at least :data:`GRID_MIN_STEPS` steps, their median one period) there is no
    jitter to leave room for: a single skipped slot, a lost message, is then a gap of its own
    (:data:`GRID_GAP_PERIODS`) instead of passing unseen. Either way it is counted as a gap,
    never as a missing sample: without a sequence a pause cannot be told from a loss.
    """
    if period_ns <= 0:
        return GAP_PERIODS
    unique = np.unique(np.fromiter(stamps_ns, dtype=np.int64))
    if unique.size <= GRID_MIN_STEPS:
        return GAP_PERIODS
    ratio = np.diff(unique) / period_ns
    whole = np.rint(ratio)
    on_grid = (
        abs(float(np.median(ratio)) - 1.0) <= GRID_TOLERANCE
        and bool((whole >= 1).all())
        and float(np.abs(ratio - whole).max()) <= GRID_TOLERANCE
    )
    return GRID_GAP_PERIODS if on_grid else GAP_PERIODS


def counter_skipped(
    a: tuple[int, int], b: tuple[int, int], *, modulo: int = 0, period_ns: int = 0
) -> int | None:
    """Return how many numbers a counter skipped from sample ``a`` to ``b`` (each ``(number, ns)``).

    ``-1``: ``b`` repeats ``a``'s number. None: the counter went back (beyond half its
    ``modulo``, when it wraps), or advanced unlike the time that passed (by more than
    :data:`COUNTER_TOLERANCE_NS` plus :data:`COUNTER_RELATIVE` of it, when ``period_ns`` is
    known): a reset, where nothing is counted lost.
    """
    step = b[0] - a[0]
    if modulo:
        step %= modulo
    if step < 0 or (modulo and 2 * step > modulo):
        return None
    if step and period_ns > 0 and not _agrees(step * period_ns, b[1] - a[1]):
        return None
    return step - 1


def _agrees(moved_ns: int, passed_ns: int) -> bool:
    """Whether a counter's advance matches the time that passed (see :func:`counter_skipped`)."""
    return abs(moved_ns - passed_ns) <= COUNTER_TOLERANCE_NS + COUNTER_RELATIVE * abs(passed_ns)


class Verdict(enum.Enum):
    """What a counted sample is (only ``NEW`` and ``NEW_RUN`` samples may be written)."""

    NEW = "new"
    NEW_RUN = "new run"
    LATE = "late"
    DUPLICATE = "duplicate"
    OUT_OF_RANGE = "out of range"

    @property
    def fresh(self) -> bool:
        """Whether the sample is new and in order (write it)."""
        return self in {Verdict.NEW, Verdict.NEW_RUN}


@dataclass(frozen=True, slots=True)
class _Suspect:
    """A sample out of range, kept to tell a one-off bad stamp from a clock that jumped."""

    latency_ns: int
    sensor_ns: int


class SourceCounter:
    """Counts the samples of one source as they are consumed (not thread-safe: one consumer).

    Give each sample its sequence number (``sequence``) when the source has a counter, else
    its sensor time: the number is then ``round((sensor - first) / period)`` (``basis
    "clock"``: a controller's cycle clock, so a missing cycle is a missing sample), or, with
    ``gaps=True``, the stamps only measure pauses (``basis "stamps"``: a publisher's header
    stamps jitter, and a pause is not a lost sample). Without a known period the first
    :data:`LEARN_SAMPLES` samples are held until their median step gives it. Counters that
    wrap (a 16-bit frame counter) are unwrapped with ``modulo``.
    """

    def __init__(
        self,
        name: str,
        *,
        period_ns: int = 0,
        modulo: int = 0,
        gaps: bool = False,
        gap_periods: float | None = None,
    ) -> None:
        """Start counting.

        Args:
            name: The source's name (unique in a recording, no dots).
            period_ns: Nominal sample period, ns; needed when samples carry no sequence.
            modulo: The counter wraps at this value (0: it never wraps).
            gaps: Samples without a sequence number are counted by gaps (``stamps``).
            gap_periods: A step longer than this many periods is a gap (see
                :func:`gap_periods`); None: judged from the steps so far, as they come
                (:data:`GRID_GAP_PERIODS` while every step has been on the period's grid,
                else :data:`GAP_PERIODS`; a step of the first :data:`GRID_MIN_STEPS` waits
                until the grid can be told).
        """
        self.name = name
        self._period_ns = period_ns
        self._modulo = modulo
        self._gaps = gaps
        self._gap_periods = gap_periods
        self._grid_steps = self._grid_whole = 0
        self._grid_broken = False
        #: Steps of the first GRID_MIN_STEPS that are gaps only if the stamps keep a grid.
        self._undecided: list[int] = []
        self._basis = "counter"
        self._first: int | None = None
        self._max = 0
        #: Recent numbers and their stamps (a repeat with another stamp is no duplicate).
        self._seen: dict[int, int] = {}
        self._order: deque[int] = deque()
        self._received = self._unique = self._duplicated = self._late = self._overflowed = 0
        self._malformed = self._out_of_range = self._resets = 0
        self._gap_count = self._gap_ns = self._unaligned = 0
        self._closed = self._edge_lost = 0
        self._first_sensor = self._last_sensor = self._first_receive = self._last_receive = 0
        self._run_sensor = self._run_receive = 0
        self._run_latency: int | None = None
        self._last_number = self._last_number_receive = self._last_number_sensor = 0
        self._suspect: _Suspect | None = None
        self._offset_first: int | None = None
        self._offset_last: int | None = None
        self._last_window_start = 0
        self._latency_max = 0
        self._learning: list[tuple[int, int]] | None = None if period_ns > 0 else []
        self.run = 0

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
        if self._gaps:
            self._basis = "stamps"
            return sensor_ns
        self._basis = "clock"
        origin = self._run_sensor if self._first is not None else sensor_ns
        return round((sensor_ns - origin) / self._period_ns)

    def observe(self, sequence: int | None, sensor_ns: int, receive_ns: int) -> bool:
        """Count one arrived sample; return whether it is new (not a duplicate, in range).

        Args:
            sequence: The source's sequence number, or None to count by the sensor clock.
            sensor_ns: The sample's time on the source's clock, ns.
            receive_ns: The sample's receive time on the recorder's clock, ns.
        """
        return self.count(sequence, sensor_ns, receive_ns) in {
            Verdict.NEW,
            Verdict.NEW_RUN,
            Verdict.LATE,
        }

    def count(self, sequence: int | None, sensor_ns: int, receive_ns: int) -> Verdict:
        """Count one arrived sample and return what it is (see :class:`Verdict`)."""
        if sequence is None and self._learning is not None:
            self._learning.append((sensor_ns, receive_ns))
            if len(self._learning) >= LEARN_SAMPLES:
                self._settle()
            return Verdict.NEW
        self._received += 1
        if self._first is None:
            number = self._number(sequence, sensor_ns)
            self._start(number, sensor_ns, receive_ns, first=True)
            return self._accept(number, sensor_ns, receive_ns, Verdict.NEW)
        if not self._plausible(sensor_ns, receive_ns):
            return self._stray(sequence, sensor_ns, receive_ns)
        self._suspect = None
        number = self._number(sequence, sensor_ns)
        jumped = sequence is not None and self._counter_jumped(number, sensor_ns, receive_ns)
        if number in self._seen and not (jumped and self._restamped(number, sensor_ns)):
            self._duplicated += 1
            return Verdict.DUPLICATE
        if jumped:  # a repeated number with a new stamp is a counter that began again
            return self._new_run(sequence, sensor_ns, receive_ns)
        return self._place(number, sensor_ns, receive_ns)

    def _place(self, number: int, sensor_ns: int, receive_ns: int) -> Verdict:
        """Count a new sample of the current run: the newest so far, or a late one."""
        assert self._first is not None  # noqa: S101 (a run is open)
        if number > self._max:
            if self._gaps:
                self._gap(number - self._max)
            self._max = number
            return self._accept(number, sensor_ns, receive_ns, Verdict.NEW)
        self._late += 1
        self._first = min(self._first, number)
        self._accept(number, sensor_ns, receive_ns, Verdict.LATE)
        return Verdict.LATE

    def _start(self, number: int, sensor_ns: int, receive_ns: int, *, first: bool) -> None:
        """Begin a run at this sample."""
        if first:
            self._first_sensor = sensor_ns
            self._first_receive = receive_ns
        self._first = self._max = number
        self._run_sensor, self._run_receive = sensor_ns, receive_ns
        self._run_latency = receive_ns - sensor_ns
        self._seen.clear()
        self._order.clear()

    def _accept(self, number: int, sensor_ns: int, receive_ns: int, verdict: Verdict) -> Verdict:
        """Remember an accepted sample and track the clocks."""
        self._remember(number, sensor_ns)
        self._unique += 1
        if verdict is not Verdict.LATE:
            self._last_number, self._last_number_receive = number, receive_ns
            self._last_number_sensor = sensor_ns
        latency = receive_ns - sensor_ns
        if self._run_latency is None or latency < self._run_latency:
            self._run_latency = latency
        self._clock(sensor_ns, receive_ns, late=verdict is Verdict.LATE)
        return verdict

    def _plausible(self, sensor_ns: int, receive_ns: int) -> bool:
        """Whether a stamp lies in its run's range (its latency near the run's lowest)."""
        if self._run_latency is None:
            return True
        drift = round(DRIFT_ALLOWED * abs(receive_ns - self._run_receive))
        deviation = receive_ns - sensor_ns - self._run_latency
        return -EARLY_TOLERANCE_NS - drift <= deviation <= LATE_TOLERANCE_NS + drift

    def _stray(self, sequence: int | None, sensor_ns: int, receive_ns: int) -> Verdict:
        """Count a stamp out of range; the second in a row that agrees with it starts a run."""
        latency = receive_ns - sensor_ns
        suspect, self._suspect = self._suspect, _Suspect(latency, sensor_ns)
        if (
            suspect is not None
            and sensor_ns > suspect.sensor_ns
            and abs(latency - suspect.latency_ns) <= EARLY_TOLERANCE_NS
        ):
            self._suspect = None
            return self._new_run(sequence, sensor_ns, receive_ns)
        self._out_of_range += 1
        return Verdict.OUT_OF_RANGE

    def _counter_jumped(self, number: int, sensor_ns: int, receive_ns: int) -> bool:
        """Whether the counter moved unlike the time that passed (a reset or a jump).

        The time that passed is the recorder's (from the receive times). A counter that moved
        forward with the source's own clock (its stamps) is no jump though, however late it
        arrived: the recorder, or the sender's loop, was held, and what was sent meanwhile
        arrives at once (late delivery is not a break in the series). Backwards, only the
        recorder's clock counts: a device that restarted restarts its counter and its clock
        together.
        """
        if self._period_ns <= 0 or self._basis != "counter":
            return False
        moved = (number - self._last_number) * self._period_ns
        if _agrees(moved, receive_ns - self._last_number_receive):
            return False
        return not (moved >= 0 and _agrees(moved, sensor_ns - self._last_number_sensor))

    def _restamped(self, number: int, sensor_ns: int) -> bool:
        """Whether a number seen before comes with another stamp (more than half a period)."""
        return 2 * abs(sensor_ns - self._seen[number]) > self._period_ns

    def _new_run(self, sequence: int | None, sensor_ns: int, receive_ns: int) -> Verdict:
        """Close the current run and start a new one at this sample."""
        assert self._first is not None  # noqa: S101 (a run is open)
        self._closed += self._max - self._first + 1
        self._resets += 1
        self.run += 1
        self._first = None
        number = self._number(sequence, sensor_ns)
        self._start(number, sensor_ns, receive_ns, first=False)
        return self._accept(number, sensor_ns, receive_ns, Verdict.NEW_RUN)

    def pause(self, step_ns: int) -> None:
        """Count the step to a sample that is not counted here as a pause, if it is one.

        A window of a publisher's stream counts the samples stamped inside it; the steps
        from the last sample before it and to the first after it cross its edges, and a
        pause there is the window's too (``gaps=True`` only; a counter counts loss).
        """
        if self._gaps and self._period_ns > 0:
            self._gap(step_ns)

    def edge_loss(self, before: tuple[int, int] | None, after: tuple[int, int] | None) -> None:
        """Count the samples a counter says were lost across the edges of a counted span.

        A window of a stream counts the samples stamped inside it; a sample lost between the
        last one before the window and its first (or between its last and the first after
        it) has no stamp to place it by, and is counted as the window's, as a pause across
        an edge is (:meth:`pause`). A counter that does not advance with the time that
        passed (a reset) counts nothing there.

        Args:
            before: ``(sequence, sensor ns)`` of the last sample before the span, or None.
            after: ``(sequence, sensor ns)`` of the first sample after it, or None.
        """
        if self._first is None or self._basis != "counter":
            return
        if before is not None and self.run == 0:  # the first run's first sample
            self._edge_lost += self._lost_between(before, self._first, self._first_sensor)
        if after is not None:
            self._edge_lost += self._lost_between((self._max, self._last_sensor), *after)

    def _lost_between(self, a: tuple[int, int], b_number: int, b_sensor_ns: int) -> int:
        """Samples lost between sample ``a`` (raw or unwrapped number, sensor ns) and ``b``."""
        skipped = counter_skipped(
            a, (b_number, b_sensor_ns), modulo=self._modulo, period_ns=self._period_ns
        )
        return max(skipped or 0, 0)

    def _gap(self, step_ns: int) -> None:
        """Count a pause of a source without a sequence (then learn whether it keeps a grid).

        Judged as the steps come (``gap_periods`` None): a step of the first
        :data:`GRID_MIN_STEPS`, before the grid can be told, that is a gap only on a grid
        (from :data:`GRID_GAP_PERIODS` to :data:`GAP_PERIODS` periods) waits until it can;
        every later step is judged at once by what the steps before it showed.
        """
        period = self._period_ns
        threshold = self._gap_periods
        judged = threshold is not None or self._grid_steps >= GRID_MIN_STEPS
        if threshold is None:
            threshold = GRID_GAP_PERIODS if self._on_grid() else GAP_PERIODS
        if step_ns > threshold * period:
            self._count_gap(step_ns)
        elif not judged and step_ns > GRID_GAP_PERIODS * period:
            self._undecided.append(step_ns)
        ratio = step_ns / period
        whole = round(ratio)
        self._grid_broken |= whole < 1 or abs(ratio - whole) > GRID_TOLERANCE
        self._grid_steps += 1
        self._grid_whole += whole == 1
        if not judged and self._grid_steps >= GRID_MIN_STEPS:  # the grid is told now
            for early in self._undecided if self._on_grid() else ():
                self._count_gap(early)
            self._undecided.clear()

    def _on_grid(self) -> bool:
        """Whether every step so far (enough of them, mostly one period) kept the grid."""
        return (
            not self._grid_broken
            and self._grid_steps >= GRID_MIN_STEPS
            and 2 * self._grid_whole > self._grid_steps
        )

    def _count_gap(self, step_ns: int) -> None:
        """Count one gap of ``step_ns``."""
        self._gap_count += 1
        self._gap_ns += step_ns - self._period_ns

    def _remember(self, number: int, sensor_ns: int) -> None:
        """Keep the recent sequence numbers (a bounded window)."""
        self._seen[number] = sensor_ns
        self._order.append(number)
        if len(self._order) > SEEN_WINDOW:
            self._seen.pop(self._order.popleft(), None)

    def _clock(self, sensor_ns: int, receive_ns: int, *, late: bool) -> None:
        """Track the clock offset (lowest latency of the first and of the latest second).

        The offset and its drift are those of the first run (a new run's clock is another).
        """
        if not late:
            self._last_sensor = sensor_ns
            self._last_receive = receive_ns
        if self.run:
            return
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

    def _settle(self) -> None:
        """Take the period from the held samples' median step, then count them."""
        held, self._learning = self._learning or [], None
        stamps = sorted({sensor for sensor, _ in held})
        steps = [b - a for a, b in itertools.pairwise(stamps)]
        self._period_ns = sorted(steps)[len(steps) // 2] if steps else 1
        for sensor, receive in held:
            self.count(None, sensor, receive)

    def overflow(self, count: int = 1) -> None:
        """Count samples the reader's queue had to drop."""
        self._overflowed += count

    def malformed(self, count: int = 1) -> None:
        """Count packages or frames that could not be parsed or held non-finite values."""
        self._malformed += count

    def unaligned(self, count: int = 1) -> None:
        """Count stamps received valid but left out of the skin's rows (a cell lacked one)."""
        self._unaligned += count

    @property
    def period_ns(self) -> int:
        """The nominal (or measured) period, ns (0: not known yet)."""
        return self._period_ns

    @property
    def clock_offset_ns(self) -> int | None:
        """Recorder time minus source time (None before the first sample)."""
        return self._offset_first

    def stats(self) -> SourceStats:
        """Return the counts so far."""
        if self._learning:
            self._settle()
        if self._gaps and self._basis == "stamps":
            expected = self._unique
            missing = self._overflowed
        else:
            expected = self._closed + (0 if self._first is None else self._max - self._first + 1)
            expected += self._edge_lost
            missing = max(expected - self._unique, 0)
        offset = self._offset_first or 0
        return SourceStats(
            name=self.name,
            basis=self._basis,
            expected=expected,
            received=self._received,
            missing=missing,
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
            malformed=self._malformed,
            out_of_range=self._out_of_range,
            counter_resets=self._resets,
            gaps=self._gap_count,
            gap_ns=self._gap_ns,
            unaligned=self._unaligned,
        )
