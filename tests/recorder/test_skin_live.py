"""A live skin over UDP and a serial line against the virtual lab's sender, on loopback."""

from __future__ import annotations

import itertools
import os
import time
from typing import TYPE_CHECKING, Self

import numpy as np
import pytest
from skinframes import RampWorld, example, poll_until, received_past, serial_example

from recorder.live import RecorderClock, SourceStats
from recorder.live._frames import FrameSkin, serial_skin, udp_skin
from recorder.runner._record import record_action
from recorder.virtuallab._skin_server import SkinFaults, serve_skin
from recorder.writing._stream import PhaseEvent
from replay import read_recording

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path

    from recorder import ActionSpec, StreamItem
    from recorder._catalog import ObjectSpec
    from recorder.writing._stream import SkinBlock

MS = 1_000_000


def _url(skin: FrameSkin) -> str:
    return f"udp://127.0.0.1:{skin.address[1]}"  # type: ignore[attr-defined]


def _by_name(stats: list[SourceStats]) -> dict[str, SourceStats]:
    return {item.name: item for item in stats}


def _check_blocks(blocks: list[SkinBlock]) -> None:
    """Blocks of each modality never go back in time and hold finite values."""
    for modality in {block.modality for block in blocks}:
        own = sorted((b for b in blocks if b.modality == modality), key=lambda b: b.receive_ns)
        for before, after in itertools.pairwise(own):
            assert after.stamp_ns >= before.stamp_ns + before.period_ns * before.data.shape[0]
        assert all(np.isfinite(b.data).all() for b in own)


def test_udp_every_injected_fault_is_counted_exactly() -> None:
    faults = SkinFaults(drop=3, duplicate=2, reorder=2, truncate=1, start=20, spacing=10)
    with udp_skin(example(), RecorderClock(), "lab.toml") as skin:
        skin.begin()
        with serve_skin(RampWorld(), _url(skin), example(), faults) as server:
            blocks = poll_until(skin, received_past(skin, 0, 200 * MS))
        blocks += skin.finish()
        injected = server.injected
    fast = _by_name(skin.stats())["skin-fast"]
    assert (injected.dropped, injected.duplicated) == (3, 2)
    assert (injected.reordered, injected.truncated) == (2, 1)
    assert fast.missing == injected.dropped + injected.truncated
    assert fast.duplicated == injected.duplicated
    assert fast.out_of_order == injected.reordered
    assert fast.malformed == injected.truncated
    assert fast.expected == fast.received - fast.duplicated + fast.missing
    for name in ("skin-proximity", "skin-temperature"):
        assert _by_name(skin.stats())[name].complete
    _check_blocks(blocks)
    assert {b.modality for b in blocks} == {"force", "acceleration", "proximity", "temperature"}


def test_udp_values_arrive_as_sent() -> None:
    world = RampWorld()
    with udp_skin(example(), RecorderClock(), "lab.toml") as skin:
        skin.begin()
        with serve_skin(world, _url(skin), example()):
            blocks = poll_until(skin, received_past(skin, 0, 100 * MS))
        blocks += skin.finish()
        assert skin.total_force() is not None
        assert skin.nearest() is not None
    force = np.concatenate([b.data for b in blocks if b.modality == "force"])
    steps = np.rint(force[:, 0, 0] / 0.001)
    expected = np.arange(len(steps)) + steps[0]
    assert np.array_equal(steps, expected % 1000)  # force ramps 1 count per sample
    assert force.shape[1:] == (7, 3)


@pytest.mark.parametrize("cells", [5, 9])
def test_a_layout_of_another_size_is_served_the_simulated_cells_in_turn(cells: int) -> None:
    # the virtual lab rehearses a lab's own skin: cell i carries simulated cell i mod 7
    world = RampWorld()  # seven cells
    section = example(cells=cells)
    with udp_skin(section, RecorderClock(), "lab.toml") as skin:
        skin.begin()
        with serve_skin(world, _url(skin), section) as server:
            blocks = poll_until(skin, received_past(skin, 0, 100 * MS))
        blocks += skin.finish()
        assert server.error is None
    force = np.concatenate([b.data for b in blocks if b.modality == "force"])
    assert force.shape[1:] == (cells, 3)
    for cell in range(cells):
        assert np.array_equal(force[:, cell], force[:, cell % 7])
    assert not np.array_equal(force[:, 0], force[:, 1])
    assert _by_name(skin.stats())["skin-fast"].malformed == 0


def test_per_cell_frames_are_assembled_and_counted() -> None:
    section = example()
    fast = dict(section["frames"]["fast"])
    fast["cell"] = {"at": 9, "type": "u8"}
    del fast["cell_stride"]
    fast["force"] = {**fast["force"], "at": 10}
    fast["acceleration"] = {**fast["acceleration"], "at": 16}
    section["frames"] = {"fast": fast}
    section["header"] = {"magic": [0xAA, 0x55]}
    del fast["id"]
    faults = SkinFaults(drop=2, start=30, spacing=20)
    with udp_skin(section, RecorderClock(), "lab.toml") as skin:
        skin.begin()
        with serve_skin(RampWorld(), _url(skin), section, faults):
            blocks = poll_until(skin, received_past(skin, 0, 100 * MS))
        blocks += skin.finish()
    (stats,) = skin.stats()
    assert stats.name == "skin"
    assert stats.missing == 2  # two cells' frames; their two samples are gaps
    force = [b for b in blocks if b.modality == "force"]
    assert all(b.data.shape[1:] == (7, 3) for b in force)
    _check_blocks(blocks)


def test_a_stall_is_visible_and_its_frames_missing() -> None:
    faults = SkinFaults(stall_s=0.4, start=20)
    clock = RecorderClock()
    silence = 0
    with udp_skin(example(), clock, "lab.toml") as skin:
        skin.begin()

        def done() -> bool:
            nonlocal silence
            last = skin.last_receive_ns()
            if last is not None:
                silence = max(silence, clock.now_ns() - last)
            return skin.stats()[0].last_sensor_ns > 600 * MS

        with serve_skin(RampWorld(), _url(skin), example(), faults) as server:
            poll_until(skin, done)
        skin.finish()
        injected = server.injected
    assert silence > 200 * MS  # longer than a 0.2 s silence limit
    stats = _by_name(skin.stats())
    assert stats["skin-fast"].missing == injected.stalled["fast"] > 0
    assert stats["skin-proximity"].missing == injected.stalled["proximity"]


def test_a_sender_that_stops_goes_silent() -> None:
    with udp_skin(example(), RecorderClock(), "lab.toml") as skin:
        skin.begin()
        faults = SkinFaults(stop_after_s=0.1)
        reported: list[tuple[str, dict[str, object]]] = []

        def on_fault(fault: str, controller_ns: int, **details: object) -> None:
            assert controller_ns > 0
            reported.append((fault, details))

        with serve_skin(RampWorld(), _url(skin), example(), faults, on_fault=on_fault) as server:
            poll_until(skin, lambda: server.injected.stopped)
            skin.poll()
            last = skin.last_receive_ns()
            time.sleep(0.1)
            skin.poll()
            assert skin.last_receive_ns() == last
    assert server.injected.sent["fast"] <= 101
    # reported once, as the other faults are (serve-sim prints it and counts it)
    sent = sum(server.injected.sent.values())
    assert reported == [("stop", {"frame": "fast", "after_s": 0.1, "sent": sent})]


def test_serial_over_a_pseudo_terminal_resyncs() -> None:
    master, slave = os.openpty()
    try:
        section = serial_example(os.ttyname(slave))
        faults = SkinFaults(truncate=2, drop=1, start=20, spacing=10)
        with serial_skin(section, RecorderClock(), "lab.toml") as skin:
            skin.begin()
            with serve_skin(RampWorld(), f"fd://{master}", section, faults) as server:
                blocks = poll_until(skin, received_past(skin, 0, 150 * MS))
            blocks += skin.finish()
            injected = server.injected
    finally:
        os.close(master)
        os.close(slave)
    fast = _by_name(skin.stats())["skin-fast"]
    assert injected.truncated == 2
    assert fast.malformed == 2  # each cut frame is one sync loss, re-synced at the next
    assert fast.missing == 3
    assert (fast.duplicated, fast.out_of_order) == (0, 0)
    _check_blocks(blocks)


class _ProbeRig:
    """A fixed probe whose skin is a live UDP skin fed by the virtual lab's sender."""

    def __init__(self, skin: FrameSkin, clock: RecorderClock) -> None:
        self.skin = skin
        self.clock = clock

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *_: object) -> None:
        return None

    @property
    def joint_names(self) -> tuple[str, ...]:
        return ()

    def describe(self) -> dict[str, str]:
        return {"kind": "probe", "time_scale": "0.1"}  # P1 (3 s) lasts 0.3 s

    def perform(self, obj: ObjectSpec, action: ActionSpec, trial: int) -> Iterator[StreamItem]:
        del obj, action, trial
        self.skin.begin()
        items: list[StreamItem] = []
        for phase, span_s in (("approach", 0.05), ("contact", 0.05), ("execute", 0.32)):
            now = self.clock.now_ns()
            items.append(PhaseEvent(now, now, phase))
            deadline = time.monotonic() + span_s
            while time.monotonic() < deadline:
                items += self.skin.poll()
                time.sleep(0.005)
        items += self.skin.finish()
        for phase in ("retract", "end"):
            now = self.clock.now_ns()
            items.append(PhaseEvent(now, now, phase))
        yield from sorted(items, key=lambda item: item.receive_ns)

    def source_stats(self) -> list[SourceStats]:
        return self.skin.stats()


def test_live_blocks_make_a_readable_recording(
    tmp_path: Path, objects: dict[str, ObjectSpec], actions: dict[str, ActionSpec]
) -> None:
    clock = RecorderClock()
    path = tmp_path / "wood" / "P1" / "001.mcap"
    skin = udp_skin(example(), clock, "lab.toml")
    with skin, serve_skin(RampWorld(), _url(skin), example()), _ProbeRig(skin, clock) as rig:
        written = record_action(rig, objects["wood"], actions["P1"], 1, path, seed=0)
    recording = read_recording(written.path)
    assert {s.name for s in written.sources} == {
        "skin-fast",
        "skin-proximity",
        "skin-temperature",
    }
    assert all(s.complete for s in written.sources)
    assert set(recording.signals) >= {"force", "acceleration", "temperature", "proximity"}
    assert recording.signals["force"].period_ns == MS


def test_a_silent_udp_skin_says_what_arrived_at_its_address() -> None:
    # nothing at all: the address is named; datagrams of another sender: the sender is named
    with udp_skin(example(), RecorderClock(), "lab.toml") as skin:
        skin.begin()
        port = skin.address[1]
        hint = skin.silence_hint()
        assert hint == (
            f"no datagram arrived at [skin] bind = '127.0.0.1:{port}': does the skin send to "
            "this address and port?"
        ), hint
    with udp_skin(example(sender="127.0.0.2"), RecorderClock(), "lab.toml") as skin:
        skin.begin()
        with serve_skin(RampWorld(), _url(skin), example()):
            deadline = time.monotonic() + 5
            while not skin.foreign and time.monotonic() < deadline:
                skin.poll()
                time.sleep(0.01)
        hint = skin.silence_hint()
        assert "came from another address than [skin] sender = '127.0.0.2'" in hint, hint
