"""A source's counter judged against its own clock: late delivery is not a counter reset.

A recorder held by a busy machine (or a sender that fell behind and sends what it owes in a
burst) receives samples late; their counter and their stamps still move together. Only a
counter that moves unlike both clocks is a reset (a device that restarted, a counter that
jumped): the accounting must not report jitter in delivery as a break in the series.
"""

from __future__ import annotations

from recorder.live._accounting import SourceCounter, Verdict

MS = 1_000_000
T0 = 5_000_000_000
LATENCY = 200_000


def _count(
    counter: SourceCounter, numbers: range, *, held_ns: int = 0, jump: int = 0
) -> list[Verdict]:
    """Samples ``numbers`` stamped on the source's 1 ms clock; received ``held_ns`` late."""
    return [counter.count(n + jump, n * MS, T0 + n * MS + LATENCY + held_ns) for n in numbers]


def test_a_recorder_held_for_1_5_s_counts_no_reset_and_no_loss() -> None:
    counter = SourceCounter("skin-force", period_ns=MS)
    _count(counter, range(1000))
    # the reader was held 1.5 s: what the source sent meanwhile arrives at once, late
    late = [
        counter.count(n, n * MS, T0 + 2500 * MS + LATENCY + (n - 1000) * 1000)
        for n in range(1000, 2500)
    ]
    assert set(late) == {Verdict.NEW}
    _count(counter, range(2500, 3000))
    stats = counter.stats()
    assert (stats.counter_resets, stats.missing, stats.expected, stats.out_of_range) == (
        0,
        0,
        3000,
        0,
    )


def test_a_counter_that_restarts_while_its_clock_runs_on_is_a_reset() -> None:
    counter = SourceCounter("skin-force", period_ns=MS)
    _count(counter, range(2000))
    verdicts = [counter.count(n - 2000, n * MS, T0 + n * MS + LATENCY) for n in range(2000, 3000)]
    assert verdicts[0] is Verdict.NEW_RUN
    stats = counter.stats()
    assert (stats.counter_resets, stats.missing, stats.expected) == (1, 0, 3000)


def test_a_counter_that_jumps_ahead_of_its_clock_is_a_reset_even_when_received_late() -> None:
    counter = SourceCounter("skin-force", period_ns=MS)
    _count(counter, range(1000))
    # held 1.5 s, and the counter jumps by 100,000 though its clock moved 1 ms per sample
    verdicts = _count(counter, range(1000, 1500), held_ns=1500 * MS, jump=100_000)
    assert verdicts[0] is Verdict.NEW_RUN
    assert counter.stats().counter_resets == 1
