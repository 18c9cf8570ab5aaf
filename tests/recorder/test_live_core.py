"""Live sources' core: sample accounting, skin block packing, reader threads, stopped actions."""

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from conftest import FakeRig
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from recorder import ActionSpec, ActionStoppedError, StreamItem
from recorder._catalog import ObjectSpec
from recorder.live import (
    SOURCES_RECORD,
    BlockPacker,
    Received,
    RecorderClock,
    SourceCounter,
    SourceLostError,
    SourceReader,
    SourceStats,
    parse_source_stats,
)
from recorder.live._accounting import encode_source_stats
from recorder.runner._record import record_action
from schemas import INCOMPLETE_RECORD, dataset_recordings, is_incomplete, is_recording

MS = 1_000_000


def _count(sequence: list[int], modulo: int = 0) -> SourceStats:
    counter = SourceCounter("skin", modulo=modulo)
    for i, number in enumerate(sequence):
        counter.observe(number, i * MS, i * MS + 100)
    return counter.stats()


def test_counter_every_fault_counted_exactly() -> None:
    # 0..9 sent; 3 lost, 5 duplicated, 7 arrives after 8
    stats = _count([0, 1, 2, 4, 5, 5, 6, 8, 7, 9])
    assert (stats.expected, stats.received) == (10, 10)
    assert (stats.missing, stats.duplicated, stats.out_of_order) == (1, 1, 1)
    assert not stats.complete
    assert stats.problems() == "1 of 10 missing, 1 duplicated, 1 out of order"


def test_counter_complete_stream() -> None:
    stats = _count(list(range(100)))
    assert stats.complete
    assert (stats.expected, stats.received, stats.missing) == (100, 100, 0)
    assert stats.problems() == ""


def test_counter_unwraps_a_16_bit_counter() -> None:
    numbers = [(65530 + i) % 65536 for i in range(12) if i != 8]
    stats = _count(numbers, modulo=65536)
    assert (stats.expected, stats.missing, stats.out_of_order) == (12, 1, 0)


def test_counter_by_the_source_clock() -> None:
    counter = SourceCounter("rtde", period_ns=8 * MS)
    stamps = [i * 8 * MS for i in range(50) if i not in {10, 11}]
    for stamp in stamps:
        counter.observe(None, stamp, stamp + 5 * MS)
    stats = counter.stats()
    assert stats.basis == "clock"
    assert (stats.expected, stats.missing) == (50, 2)
    assert stats.clock_offset_ns == 5 * MS


def test_counter_clock_offset_and_latency() -> None:
    counter = SourceCounter("skin")
    latency = [3, 1, 2, 7, 1]
    for i, extra in enumerate(latency):
        counter.observe(i, 1000 * MS + i * MS, 5000 * MS + i * MS + extra * MS)
    stats = counter.stats()
    assert stats.clock_offset_ns == 4000 * MS + 1 * MS
    assert stats.latency_max_ns == 6 * MS


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 199), min_size=1, max_size=400))
def test_counter_accounts_for_every_arrival(arrivals: list[int]) -> None:
    stats = _count(arrivals)
    unique = set(arrivals)
    assert stats.received == len(arrivals)
    assert stats.duplicated == len(arrivals) - len(unique)
    assert stats.expected == max(unique) - min(unique) + 1
    assert stats.missing == stats.expected - len(unique)


def test_sources_record_round_trips() -> None:
    stats = (_count([0, 2, 2, 1]), SourceStats("rtde", "clock", expected=5, received=5))
    record = encode_source_stats(stats)
    assert parse_source_stats(record) == tuple(sorted(stats, key=lambda s: s.name))
    with pytest.raises(ValueError, match="unknown key"):
        parse_source_stats({**record, "skin.colour": "red"})


def test_a_sources_origin_is_recorded_only_where_known() -> None:
    stats = (SourceStats("rtde", "clock", expected=5), SourceStats("skin", origin="10.0.0.7:5005"))
    record = encode_source_stats(stats)
    assert record["skin.origin"] == "10.0.0.7:5005"
    assert "rtde.origin" not in record  # a record without origins is as before
    assert parse_source_stats(record) == stats


def test_packer_cuts_at_gaps_and_when_full() -> None:
    packer = BlockPacker("force", MS, block=4)
    blocks = []
    for i in [*range(6), 7, 8]:  # sample 6 is missing
        blocks += packer.push(i * MS, i * MS + 2, np.full((2, 3), i, np.float32))
    blocks += packer.flush()
    assert [(b.stamp_ns // MS, b.data.shape[0]) for b in blocks] == [(0, 4), (4, 2), (7, 2)]
    assert blocks[1].data[:, 0, 0].tolist() == [4.0, 5.0]
    assert blocks[0].receive_ns == 3 * MS + 2
    assert packer.flush() == []


def test_reader_counts_overflow_and_reports_a_lost_connection() -> None:
    sent = iter(range(30))
    release = threading.Event()

    def receive() -> Received | None:
        try:
            value = next(sent)
        except StopIteration:
            release.wait(1.0)
            msg = "socket closed"
            raise ConnectionResetError(msg) from None
        return Received(value, value)

    reader = SourceReader("skin", receive, capacity=10)
    reader.start()
    deadline = time.monotonic() + 5
    while reader.received < 30 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert reader.overflowed == 20
    assert [item.payload for item in reader.drain()] == list(range(10))
    release.set()
    reader.stop()
    with pytest.raises(SourceLostError, match="skin: connection lost"):
        reader.drain()


def test_clock_never_goes_back() -> None:
    clock = RecorderClock()
    stamps = [clock.now_ns() for _ in range(1000)]
    assert stamps == sorted(stamps)
    assert abs(stamps[0] - time.time_ns()) < 10**9


class _StoppingRig(FakeRig):
    """Stops every action after a quarter of its items, like a protective stop."""

    def perform(self, obj: ObjectSpec, action: ActionSpec, trial: int) -> Iterator[StreamItem]:
        items = list(super().perform(obj, action, trial))
        yield from items[: len(items) // 4]
        msg = "protective stop"
        raise ActionStoppedError(msg, at_ns=items[len(items) // 4].receive_ns)

    def source_stats(self) -> list[SourceStats]:
        return [SourceStats("skin", expected=10, received=9, missing=1)]


def test_a_stopped_action_is_kept_incomplete(
    tmp_path: Path, objects: dict[str, ObjectSpec], actions: dict[str, ActionSpec]
) -> None:
    final = tmp_path / "wood" / "P1" / "001.mcap"
    with _StoppingRig() as rig:
        with pytest.raises(ActionStoppedError) as stopped:
            record_action(rig, objects["wood"], actions["P1"], 1, final, seed=0)
        with pytest.raises(ActionStoppedError) as again:
            record_action(rig, objects["wood"], actions["P1"], 1, final, seed=0)
    assert not final.exists()
    first, second = stopped.value.path, again.value.path
    assert first is not None
    assert second is not None
    assert (first.name, second.name) == ("001.incomplete.mcap", "001.incomplete-2.mcap")
    assert "protective stop" in str(stopped.value)
    assert str(first) in str(stopped.value)
    assert is_incomplete(first)
    assert not is_recording(first)
    assert dataset_recordings(tmp_path) == []
    with first.open("rb") as stream:
        reader = make_reader(stream)
        records = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        messages = sum(1 for _ in reader.iter_messages())
    assert records[INCOMPLETE_RECORD]["reason"] == "protective stop"
    assert parse_source_stats(records[SOURCES_RECORD])[0].missing == 1
    assert messages > 0


def test_counter_learns_the_period_of_a_source_without_a_rate() -> None:
    counter = SourceCounter("topic")
    stamps = [1000 * MS + i * 4 * MS for i in range(60) if i not in {3, 30, 31}]
    for stamp in stamps:
        counter.observe(None, stamp, stamp + MS)
    counter.observe(None, stamps[-1], stamps[-1] + 2 * MS)  # a duplicate
    stats = counter.stats()
    assert (stats.period_ns, stats.expected, stats.missing, stats.duplicated) == (4 * MS, 60, 3, 1)


def test_counter_with_too_few_samples_to_learn_still_counts_them() -> None:
    counter = SourceCounter("topic")
    counter.observe(None, 5 * MS, 6 * MS)
    counter.observe(None, 9 * MS, 10 * MS)
    stats = counter.stats()
    assert (stats.expected, stats.received, stats.missing) == (2, 2, 0)


def test_a_counter_counts_what_was_lost_across_the_edges_of_a_window() -> None:
    # a window holds the samples counted 250..255, 0..3 (a uint8 that wraps); the last one
    # before it was 247 and the first after it 6: 2 lost before it, 2 after it
    period = 1_000_000
    counter = SourceCounter("topic", period_ns=period, modulo=256)
    numbers = [*range(250, 256), *range(4)]
    for k, number in enumerate(numbers):
        counter.observe(number, (k + 10) * period, (k + 10) * period + 5)
    counter.edge_loss((247, 7 * period), (6, 20 * period))
    stats = counter.stats()
    assert (stats.expected, stats.received, stats.missing) == (14, 10, 4)


def test_a_counter_that_jumps_across_an_edge_counts_no_loss_there() -> None:
    # the sample after the window says 5000 with only two periods passed (a reset: 4,895
    # lost would have taken 4.9 s), and the one before it counts back: nothing is counted
    period = 1_000_000
    counter = SourceCounter("topic", period_ns=period)
    for k in range(5):
        counter.observe(100 + k, (k + 10) * period, (k + 10) * period + 5)
    counter.edge_loss((101, 9 * period), (5000, 16 * period))
    assert counter.stats().missing == 0
