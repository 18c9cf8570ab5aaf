"""Hostile live sources: malformed, non-finite, jumping and flooding samples at the source.

Each case feeds a live source what a faulty or hostile peer sends and checks that every valid
sample is kept (exactly once, in order, on a time base that never jumps), nothing invalid is
written, and the source's accounting says what happened (malformed, out of range, counter
resets, missing) and nothing else.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from skinframes import TWO_CELL_LAYOUT, TWO_CELLS

from recorder.errors import RigError
from recorder.live import Received, RecorderClock
from recorder.live._accounting import (
    GAP_PERIODS,
    GRID_GAP_PERIODS,
    GRID_MIN_STEPS,
    SourceCounter,
    SourceStats,
    Verdict,
    gap_periods,
)
from recorder.live._framelayout import parse_layout
from recorder.live._frames import UdpSkin

if TYPE_CHECKING:
    from recorder.writing._stream import SkinBlock

MS = 1_000_000
T0 = 1_700_000_000 * 1_000_000_000
CELLS, LAYOUT = TWO_CELLS, TWO_CELL_LAYOUT


def _skin() -> UdpSkin:
    return UdpSkin(parse_layout(LAYOUT, "hostile.toml"), RecorderClock())


def _frames(count: int, *, start: int = 0) -> np.ndarray[Any, Any]:
    """Return ``count`` valid frames: sequence i, stamp i ms (in us), force = i."""
    layout = parse_layout(LAYOUT, "hostile.toml")
    frames = np.zeros(count, dtype=layout.frames[0].dtype(layout.byte_order, CELLS))
    numbers = np.arange(start, start + count)
    raw = frames.view(np.uint8).reshape(count, -1)
    raw[:, 0], raw[:, 1] = 0xAA, 0x55
    frames["sequence"] = numbers % 65536
    frames["stamp"] = (numbers * 1000) % 2**32
    for cell in range(CELLS):
        frames[f"force_{cell}"] = numbers[:, None] + cell
    return frames


def _feed(skin: UdpSkin, payloads: list[bytes], receives: list[int]) -> list[SkinBlock]:
    """Feed datagrams in batches of 100 as the reader thread would queue them."""
    blocks: list[SkinBlock] = []
    items = [Received(r, p) for p, r in zip(payloads, receives, strict=True)]
    for at in range(0, len(items), 100):
        blocks += skin._consume(items[at : at + 100])
    return blocks + skin.finish()


def _written(blocks: list[SkinBlock]) -> tuple[np.ndarray[Any, Any], np.ndarray[Any, Any]]:
    """Return the written force samples' stamps and their first value (the frame number)."""
    blocks = sorted(blocks, key=lambda b: b.stamp_ns)
    stamps = np.concatenate([b.stamp_ns + np.arange(len(b.data)) * b.period_ns for b in blocks])
    values = np.concatenate([np.asarray(b.data)[:, 0, 0] for b in blocks])
    return stamps, values


def _receives(count: int) -> list[int]:
    return [T0 + i * MS + 200_000 for i in range(count)]


def test_one_frame_stamp_jump_hides_nothing() -> None:
    frames = _frames(18_000)
    frames["stamp"][5000] = (int(frames["stamp"][5000]) + 2**31) % 2**32
    skin = _skin()
    stamps, values = _written(_feed(skin, [f.tobytes() for f in frames], _receives(18_000)))
    (stats,) = skin.stats()
    assert values.size == 17_999
    assert 5000 not in values.tolist()
    assert bool(np.all(np.diff(stamps) > 0))
    assert (stats.out_of_range, stats.missing, stats.counter_resets) == (1, 1, 0)


def test_device_restart_starts_a_new_run() -> None:
    # counter and stamp both restart at 0 (the skin rebooted) while time goes on
    frames = _frames(18_000)
    frames["sequence"][9000:] = np.arange(9000)
    frames["stamp"][9000:] = np.arange(9000) * 1000
    skin = _skin()
    stamps, values = _written(_feed(skin, [f.tobytes() for f in frames], _receives(18_000)))
    (stats,) = skin.stats()
    assert stats.counter_resets == 1
    assert stats.out_of_range <= 1
    assert values.size == 18_000 - stats.out_of_range
    assert bool(np.all(np.diff(stamps) > 0))
    # the time base follows the recorder's clock: no jump to +77,000 s
    assert stamps[-1] - stamps[0] < 20_000 * MS
    assert stats.missing == 0


def test_counter_reset_alone_loses_nothing() -> None:
    frames = _frames(6000)
    frames["sequence"][3000:] = np.arange(3000) + 40_000  # the counter jumps, time runs on
    skin = _skin()
    _, values = _written(_feed(skin, [f.tobytes() for f in frames], _receives(6000)))
    (stats,) = skin.stats()
    assert values.size == 6000
    assert (stats.counter_resets, stats.missing, stats.out_of_range) == (1, 0, 0)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_values_are_counted_never_written(bad: float) -> None:
    frames = _frames(4000)
    broken = set(range(100, 4000, 37))
    for i in broken:
        frames["force_1"][i][2] = bad
    skin = _skin()
    _, values = _written(_feed(skin, [f.tobytes() for f in frames], _receives(4000)))
    (stats,) = skin.stats()
    assert values.size == 4000 - len(broken)
    assert not broken & set(values.astype(int).tolist())
    assert (stats.malformed, stats.missing) == (len(broken), len(broken))


def test_garbage_between_frames_is_counted_and_every_frame_kept() -> None:
    rng = np.random.default_rng(7)
    frames = _frames(3000)
    payloads: list[bytes] = []
    receives: list[int] = []
    garbage = 0
    for i, frame in enumerate(frames):
        payloads.append(frame.tobytes())
        receives.append(T0 + i * MS)
        if i % 10 == 0:
            payloads.append(rng.bytes(int(rng.integers(0, 200))))
            receives.append(T0 + i * MS + 1)
            garbage += 1
    skin = _skin()
    _, values = _written(_feed(skin, payloads, receives))
    (stats,) = skin.stats()
    assert values.size == 3000
    assert (stats.malformed, stats.missing) == (garbage, 0)


def test_counter_out_of_range_then_back() -> None:
    counter = SourceCounter("rtde", period_ns=2 * MS)
    verdicts = []
    for i in range(100):
        sensor = i * 2 * MS + (10**12 if i == 50 else 0)
        verdicts.append(counter.count(None, sensor, T0 + i * 2 * MS))
    stats = counter.stats()
    assert verdicts[50] is Verdict.OUT_OF_RANGE
    assert all(v is Verdict.NEW for i, v in enumerate(verdicts) if i != 50)
    assert (stats.out_of_range, stats.missing, stats.expected) == (1, 1, 100)


def test_stamps_basis_counts_gaps_not_missing() -> None:
    rng = np.random.default_rng(3)
    counter = SourceCounter("force", period_ns=MS, gaps=True)
    t = 0
    for i in range(5000):
        t += MS + int(rng.integers(-400_000, 400_000)) + (100 * MS if i == 2500 else 0)
        counter.observe(None, t, T0 + t + 50_000)
    stats = counter.stats()
    assert stats.basis == "stamps"
    assert (stats.missing, stats.duplicated, stats.out_of_order) == (0, 0, 0)
    assert stats.gaps == 1
    assert stats.lost == 0


def _stamps_counter(steps_ms: list[float], **options: Any) -> SourceStats:
    counter = SourceCounter("force", period_ns=MS, gaps=True, **options)
    t = 0
    for step in steps_ms:
        t += round(step * MS)
        counter.observe(None, t, T0 + t + 50_000)
    return counter.stats()


def test_a_single_lost_message_of_a_publisher_on_its_grid_is_a_gap() -> None:
    # a publisher that stamps with its sample clock (steps within 2 % of a period): one lost
    # message is a step of two periods, a gap on its own topic (not a missing sample:
    # without a sequence it cannot be told from a skipped tick)
    rng = np.random.default_rng(5)
    steps = [1.0 + float(rng.uniform(-0.02, 0.02)) for _ in range(3000)]
    lost = [400, 1500, 2900]
    for i in lost:
        steps[i] += 1.0
    stats = _stamps_counter(steps)
    assert (stats.gaps, stats.missing, stats.lost) == (len(lost), 0, 0)
    assert stats.gap_ns == pytest.approx(len(lost) * MS, rel=0.05)
    # the same publisher without the losses: no gap
    assert _stamps_counter([1.0 + s % 0.01 for s in range(3000)]).gaps == 0


@pytest.mark.parametrize("at", [1, 3, 7, 8])
def test_a_message_lost_before_the_grid_can_be_told_is_a_gap_once_it_can(at: int) -> None:
    # the step of the lost message comes among the first steps, before there are enough to
    # tell a grid: it waits, and is counted once the grid shows; a publisher whose first
    # steps leave the grid (jitter) has no grid, and the step is no gap
    steps = [1.0] * 40
    steps[at] = 2.0
    stats = _stamps_counter(steps)
    assert (stats.gaps, stats.gap_ns) == (1, MS)
    assert _stamps_counter([1.4, 0.6, *steps]).gaps == 0


def test_a_jittery_publisher_is_judged_off_its_grid_and_its_jitter_is_no_gap() -> None:
    # stamped when sent: steps of 0.5..2.2 periods are jitter, never a gap (the grid is off
    # from the first step that leaves it, and stays off)
    rng = np.random.default_rng(6)
    steps = [1.0] * 20 + [float(rng.uniform(0.5, 1.5)) for _ in range(3000)] + [2.2, 0.5]
    assert _stamps_counter(steps).gaps == 0
    # a whole number of periods that are not one period each (a rate declared twice too
    # high): no grid either
    assert _stamps_counter([2.0] * 100).gaps == 0
    # the decision can also be given (listen judges a window from all its stamps)
    assert _stamps_counter([1.0] * 50 + [2.0] + [1.0] * 50, gap_periods=2.5).gaps == 0


def test_gap_periods_is_judged_from_the_distinct_stamps() -> None:
    grid = [i * MS for i in range(100) if i != 50]
    assert gap_periods(grid + grid[:10], MS) == GRID_GAP_PERIODS  # duplicates are not steps
    assert gap_periods([s + (MS // 4 if i % 7 == 3 else 0) for i, s in enumerate(grid)], MS) == (
        GAP_PERIODS
    )
    assert gap_periods(grid[:GRID_MIN_STEPS], MS) == GAP_PERIODS  # too few to judge
    assert gap_periods([2 * s for s in grid], MS) == GAP_PERIODS  # median step 2 periods
    assert gap_periods(grid, 0) == GAP_PERIODS


# ---------------------------------------------------------------------------------- RTDE


class _HostileController:
    """An RTDE controller that answers the handshake, then sends the packages it is given."""

    def __init__(self, packages: list[bytes]) -> None:
        import socket  # noqa: PLC0415
        import threading  # noqa: PLC0415

        self.packages = packages
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        import struct  # noqa: PLC0415

        from recorder.ur._rtde import HEADER, pack_package  # noqa: PLC0415

        conn, _ = self.server.accept()
        with conn:
            buffer = b""
            while True:
                while len(buffer) < HEADER.size:
                    buffer += conn.recv(4096)
                size, kind = HEADER.unpack_from(buffer)
                while len(buffer) < size:
                    buffer += conn.recv(4096)
                buffer = buffer[size:]
                if kind == ord("V"):
                    conn.sendall(pack_package(kind, b"\x01"))
                elif kind == ord("O"):
                    conn.sendall(pack_package(kind, b"\x05DOUBLE,VECTOR6D"))
                elif kind == ord("S"):
                    conn.sendall(pack_package(kind, b"\x01"))
                    break
                else:
                    conn.sendall(pack_package(kind, struct.pack(">IIII", 5, 15, 0, 0)))
            for package in self.packages:
                conn.sendall(package)
            conn.recv(16)  # until the client closes

    def close(self) -> None:
        self.server.close()


def _package(stamp_s: float, q: float = 0.0, *, recipe: int = 5, extra: bytes = b"") -> bytes:
    import struct  # noqa: PLC0415

    from recorder.ur._rtde import DATA_PACKAGE, pack_package  # noqa: PLC0415

    return pack_package(DATA_PACKAGE, struct.pack(">Bd6d", recipe, stamp_s, *[q] * 6) + extra)


def _rtde_run(packages: list[bytes], expect: int, period_ns: int = 2 * MS) -> tuple[Any, int]:
    """Receive every package through a reader thread; return the accounting and malformed."""
    import time  # noqa: PLC0415

    from recorder.live import SourceReader  # noqa: PLC0415
    from recorder.ur._rtde import RtdeClient  # noqa: PLC0415

    controller = _HostileController(packages)
    counter = SourceCounter("rtde", period_ns=period_ns)
    kept: list[float] = []
    try:
        with RtdeClient("127.0.0.1", controller.port) as client:
            recipe = client.setup_outputs(["timestamp", "actual_q"], 500)
            client.start()
            with SourceReader("rtde", client.receive) as reader:
                for _ in range(10_000):  # a hang guard (20 s of 2 ms waits), not a time check
                    if len(kept) + counter.stats().duplicated >= expect:
                        break
                    for item in reader.drain():
                        values = recipe.parse(item.payload)
                        stamp = round(float(values["timestamp"]) * 1e9)
                        if counter.observe(None, stamp, item.receive_ns):
                            kept.append(float(values["actual_q"][0]))
                    time.sleep(0.002)
                else:
                    pytest.fail("the stream stalled")
            counter.malformed(client.malformed)
    finally:
        controller.close()
    return counter.stats(), len(kept)


def test_rtde_bad_packages_are_counted_and_skipped() -> None:
    rng = np.random.default_rng(11)
    packages = []
    bad = 0
    for i in range(3000):
        packages.append(_package(i * 0.002, float(i)))
        if i % 250 == 100:
            packages += [
                _package(i * 0.002 + 0.001, recipe=9),  # another recipe
                _package(i * 0.002 + 0.001, extra=b"\0" * 8),  # 8 bytes too long
                _package(i * 0.002 + 0.001, np.nan),  # NaN
                _package(i * 0.002 + 0.001, np.inf),  # inf
            ]
            from recorder.ur._rtde import DATA_PACKAGE, pack_package  # noqa: PLC0415

            packages.append(pack_package(DATA_PACKAGE, rng.bytes(int(rng.integers(1, 120)))))
            bad += 5
    stats, kept = _rtde_run(packages, 3000)
    assert kept == 3000
    assert (stats.malformed, stats.missing, stats.duplicated) == (bad, 0, 0)
    assert stats.lost == 0


def test_rtde_ten_times_the_rate_is_counted() -> None:
    packages = [_package(i * 0.0002, float(i)) for i in range(2000)]
    stats, kept = _rtde_run(packages, 2000)
    # ten packages per cycle: one kept per cycle, the others counted as duplicates
    assert kept in {200, 201}  # cycles 0..200 (the last one begun)
    assert stats.duplicated == 2000 - kept
    assert not stats.complete


@pytest.mark.slow(8)
def test_a_udp_flood_is_bounded_in_memory_and_keeps_only_valid_frames_once() -> None:
    """100,000 datagrams as fast as loopback takes them (valid frames, garbage between them),
    while the consumer polls as the runner does: memory stays bounded (the kernel's buffer and
    the reader's queue drop), every frame written is a valid one, once, in order, and what was
    not written is counted (the garbage as malformed; the frames whose 1 kHz stamps ran ahead
    of the flood's real time as out of range, each such jump starting a new run)."""
    import socket  # noqa: PLC0415
    import threading  # noqa: PLC0415
    import time  # noqa: PLC0415
    import tracemalloc  # noqa: PLC0415

    count = 100_000
    frames = _frames(count)
    payloads = [frames[i : i + 1].tobytes() for i in range(count)]
    garbage = b"\x00\x01garbage"
    tracemalloc.start()
    try:
        with _skin() as skin:
            sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            done = threading.Event()

            def flood() -> None:
                for i, payload in enumerate(payloads):
                    sender.sendto(payload, skin.address)
                    if i % 10 == 0:
                        sender.sendto(garbage, skin.address)
                done.set()

            threading.Thread(target=flood, daemon=True).start()
            blocks: list[SkinBlock] = []
            while not done.is_set():
                blocks += skin.poll()
                time.sleep(0.002)
            time.sleep(0.2)
            blocks += skin.poll() + skin.finish()
            stats = skin.stats()[0]
            sender.close()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    stamps, values = _written(blocks)
    refused = stats.out_of_range + stats.duplicated
    assert stats.received - refused == len(values) > 0
    assert np.all(np.diff(values) > 0)  # each valid frame once, in order, nothing invented
    assert np.all(np.diff(stamps) > 0)
    assert stats.malformed > 0  # the garbage, counted
    assert stats.received < count + 1
    assert peak < 300 * 2**20, f"peak {peak / 2**20:.0f} MiB of Python memory in the flood"


def test_datagrams_of_another_sender_are_dropped_counted_and_no_sign_of_life() -> None:
    """With ``sender``, a second skin sending valid frames to the same port (another rig, a
    stray replay) is dropped and counted as malformed: only the skin's own frames are kept,
    and the foreign ones never refresh the silence check (the last receive time)."""
    import socket  # noqa: PLC0415
    import time  # noqa: PLC0415

    count = 200
    payloads = [_frames(count)[i : i + 1].tobytes() for i in range(count)]
    with UdpSkin(parse_layout(LAYOUT | {"sender": "127.0.0.1"}, "h.toml"), RecorderClock()) as skin:
        ours, theirs = (socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(2))
        ours.bind(("127.0.0.1", 0))
        theirs.bind(("127.0.0.2", 0))  # the whole of 127/8 is this computer's loopback
        blocks: list[SkinBlock] = []
        for payload in payloads:
            ours.sendto(payload, skin.address)
            theirs.sendto(payload, skin.address)
            blocks += skin.poll()
        time.sleep(0.2)
        heard = skin.last_receive_ns()
        for payload in payloads[:50]:  # only the other sender now
            theirs.sendto(payload, skin.address)
        time.sleep(0.2)
        assert skin.last_receive_ns() == heard  # silence stays silence
        blocks += skin.poll() + skin.finish()
        stats = skin.stats()[0]
        ours.close()
        theirs.close()
    _, values = _written(blocks)
    assert list(values) == list(range(count))  # each of ours once, none of theirs
    assert stats.malformed == count + 50
    assert (stats.missing, stats.duplicated) == (0, 0)


@pytest.mark.parametrize(
    ("sender", "fix"),
    [("skin.local", "give the skin's IP address"), ("::1", "give an IPv4 address"), (7, "IP")],
)
def test_a_sender_that_is_no_ipv4_address_is_refused(sender: object, fix: str) -> None:
    with pytest.raises(RigError, match=rf"h.toml: \[skin\] sender = .*{fix}"):
        parse_layout(LAYOUT | {"sender": sender}, "h.toml")
