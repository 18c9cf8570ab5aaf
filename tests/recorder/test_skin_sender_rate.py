"""A UDP skin that is not alone or not at its rate: counted, never mixed in, said with the fix.

A second sender on the skin's port (``[skin] sender`` unset) is left out, counted by its
address and named once per action; a dry run with two senders, or with a skin at ten times
its ``rate_hz``, is not ready and says why in one line; malformed frames are said once per
action with their count, their size and the fix. Loopback only (127.0.0.1), in process.
"""

from __future__ import annotations

import contextlib
import re
import socket
import threading
import time
from typing import TYPE_CHECKING, Any, Self

import numpy as np
from fake_arm import FakeArm
from skinframes import TWO_CELL_LAYOUT, TWO_CELLS, poll_until

from recorder.live import Received, RecorderClock
from recorder.live._framelayout import parse_layout
from recorder.live._frames import UdpSkin
from recorder.runner import ArmRig, Limits, RunnerOptions

if TYPE_CHECKING:
    from pathlib import Path

    import pytest

    from recorder._session import RigCheck
    from recorder.writing._stream import SkinBlock
    from schemas import SourceStats

CELLS = TWO_CELLS
SIZE = 32  # 8 header bytes, 2 cells x 12 bytes of force
LAYOUT = TWO_CELL_LAYOUT


def _layout(rate_hz: float = 1000, **changes: Any) -> dict[str, Any]:
    fast = LAYOUT["frames"]["fast"] | {"rate_hz": rate_hz}
    return LAYOUT | {"frames": {"fast": fast}} | changes


def _frames(numbers: np.ndarray[Any, Any], period_us: int, value: float) -> list[bytes]:
    """Return one datagram per number: its counter, its stamp (number x period), force."""
    layout = parse_layout(LAYOUT, "lab.toml")
    frames = np.zeros(len(numbers), dtype=layout.frames[0].dtype(layout.byte_order, CELLS))
    raw = frames.view(np.uint8).reshape(len(numbers), -1)
    raw[:, 0], raw[:, 1] = 0xAA, 0x55
    frames["sequence"] = numbers % 65536
    frames["stamp"] = (numbers * period_us) % 2**32
    for cell in range(CELLS):
        frames[f"force_{cell}"] = value
    return [frames[i : i + 1].tobytes() for i in range(len(numbers))]


class _Sender(threading.Thread):
    """A skin on loopback: frames at ``rate_hz`` until stopped, its counter and its stamps
    (its own clock) from ``first``."""

    def __init__(
        self, target: tuple[str, int], rate_hz: float, value: float, first: int = 0
    ) -> None:
        super().__init__(daemon=True)
        self.target, self.rate_hz, self.value, self.first = target, rate_hz, value, first
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.socket.bind(("127.0.0.1", 0))
        self.address = f"127.0.0.1:{self.socket.getsockname()[1]}"
        self.sent = 0
        self.done = threading.Event()

    def run(self) -> None:
        period_us = round(1e6 / self.rate_hz)
        start = time.monotonic()
        while not self.done.is_set():
            due = int((time.monotonic() - start) * self.rate_hz) + 1
            numbers = self.first + np.arange(self.sent, due)
            for payload in _frames(numbers, period_us, self.value) if len(numbers) else []:
                self.socket.sendto(payload, self.target)
            self.sent = due
            time.sleep(0.002)

    def __enter__(self) -> Self:
        self.start()
        return self

    def __exit__(self, *_: object) -> None:
        self.done.set()
        self.join()
        self.socket.close()


def _values(blocks: list[SkinBlock]) -> set[float]:
    return {float(v) for block in blocks for v in np.asarray(block.data).ravel()}


def test_a_second_sender_is_counted_by_its_address_and_never_written(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Without [skin] sender the first address to send a valid frame is the skin's; a second
    one on the same computer (another source port) is left out, counted as malformed, and
    said once when the action ends, naming both addresses and the fix."""
    with UdpSkin(parse_layout(_layout(), "lab.toml"), RecorderClock()) as skin:
        skin.begin()
        with _Sender(skin.address, 1000, 1.0) as ours:
            blocks = poll_until(skin, lambda: skin.stats()[0].received > 50, 2.0)
            with _Sender(skin.address, 1000, 2.0, first=20_000) as theirs:
                blocks += poll_until(skin, lambda: theirs.sent > 300, 2.0)
            time.sleep(0.05)
        time.sleep(0.05)
        blocks += skin.finish()
        stats = skin.stats()[0]
    said = capsys.readouterr().err.splitlines()
    assert _values(blocks) == {1.0}  # none of the second sender's frames written
    assert stats.counter_resets == 0, stats
    assert stats.malformed == skin.foreign > 0  # every one of theirs counted
    assert stats.received + stats.malformed >= ours.sent + theirs.sent - 50
    lines = [line for line in said if theirs.address in line]
    assert len(lines) == 1, said  # once for the action
    line = lines[0]
    assert line.startswith("skin: frames from 2 senders at [skin] bind = '127.0.0.1:"), line
    assert f"{skin.foreign} left out from {theirs.address}" in line, line
    assert f"taken from {ours.address}" in line, line
    assert 'give [skin] sender = "HOST:PORT" in lab.toml' in line, line
    assert line.endswith(f"({ours.address} or {theirs.address}), or stop the other sender"), line


def test_a_sender_with_its_port_takes_only_that_port() -> None:
    """``sender = "HOST:PORT"`` tells apart two senders on one computer."""
    with _Sender(("127.0.0.1", 9), 1000, 1.0) as ours:  # its port, known before the skin
        layout = parse_layout(_layout(sender=ours.address), "lab.toml")
        with UdpSkin(layout, RecorderClock()) as skin:
            skin.begin()
            ours.target = skin.address
            with _Sender(skin.address, 1000, 2.0):  # sends first as often as not
                blocks = poll_until(skin, lambda: skin.stats()[0].received > 200, 2.0)
            blocks += skin.finish()
    assert _values(blocks) == {1.0}
    assert skin.origin() == ours.address


class _QuietArm(FakeArm):
    """The fake arm, without its accounting (the skin's is the one under test)."""

    def stats(self) -> list[SourceStats]:
        return []


def _dry_run(
    skin: UdpSkin, tmp_path: Path, *senders: tuple[float, float, int]
) -> tuple[RigCheck, list[str]]:
    """Run the session's dry run over a fake arm and ``skin`` with senders.

    Each sender is (rate_hz, value, its counter's first number).

    Returns:
        What the dry run found, and the senders' addresses.
    """
    from recorder._session import check_rig_ready  # noqa: PLC0415

    clock = skin.clock
    options = RunnerOptions(time_scale=1.0, silence_s=0.5)
    rig = ArmRig(_QuietArm(clock), skin, Limits(), options, {}, kind="fake", where="lab.toml")
    rig.clock = clock
    with contextlib.ExitStack() as stack:
        running = [stack.enter_context(_Sender(skin.layout.bind, *s)) for s in senders]
        found = check_rig_ready(lambda _seed: rig, 0, [], [], tmp_path, seconds=0.6)
    return found, [sender.address for sender in running]


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def test_a_dry_run_with_two_senders_is_not_ready(tmp_path: Path) -> None:
    """Either may be the first to send: the dry run is not ready and one line names both."""
    port = _free_udp_port()
    layout = parse_layout(_layout(bind=f"127.0.0.1:{port}"), "lab.toml")
    skin = UdpSkin(layout, RecorderClock())
    found, addresses = _dry_run(skin, tmp_path, (1000, 1, 0), (1000, 2, 20_000))
    lines = found.lines()
    assert not found.ready, lines
    assert lines[1].startswith("rig: not ready: skin frames from 2 senders ("), lines
    assert all(address in lines[1] for address in addresses), lines
    assert [line for line in lines if line.startswith("  skin: ")] == [
        line
        for line in lines
        if re.match(rf"  skin: \d+ received from ({'|'.join(addresses)}), ", line)
    ]
    named = [line for line in lines if all(a in line for a in addresses) and "sender =" in line]
    assert len(named) == 1, lines
    assert named[0].startswith(f"skin: frames from 2 senders at [skin] bind = '127.0.0.1:{port}'")
    assert 'give [skin] sender = "HOST:PORT" in lab.toml' in named[0], named


def test_a_dry_run_of_a_skin_at_ten_times_its_rate_is_not_ready(tmp_path: Path) -> None:
    """A skin sending at 1000 Hz, its layout saying 100 Hz: most of its frames would be left
    out as out of range; the dry run measures the rate and names rate_hz and the file."""
    port = _free_udp_port()
    layout = parse_layout(_layout(rate_hz=100, bind=f"127.0.0.1:{port}"), "lab.toml")
    found, _ = _dry_run(UdpSkin(layout, RecorderClock()), tmp_path, (1000, 1.0, 0))
    lines = found.lines()
    assert not found.ready, lines
    assert lines[1].startswith("rig: not ready: skin frame type fast arrives at about 1,000 Hz")
    rate = [line for line in lines if "rate_hz = 100 in lab.toml" in line]
    assert len(rate) == 1, lines
    assert rate[0].startswith(
        "skin frame type fast: arrives at about 1,000 Hz, [skin.frames.fast] rate_hz = 100 in "
        "lab.toml"
    ), rate
    assert rate[0].endswith("; fix rate_hz (or the skin's rate)"), rate


def test_a_dry_run_of_a_skin_at_its_rate_is_ready(tmp_path: Path) -> None:
    port = _free_udp_port()
    layout = parse_layout(_layout(bind=f"127.0.0.1:{port}"), "lab.toml")
    found, _ = _dry_run(UdpSkin(layout, RecorderClock()), tmp_path, (1000, 1.0, 0))
    assert found.ready, found.lines()
    assert not found.findings, found.findings


def test_malformed_frames_are_said_once_with_their_size_and_the_fix(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Frames one byte too long (a cell more, a checksum the layout lacks) are counted
    exactly and said in one line when the action ends: how many, their size, the frame
    type's size and the fix."""
    skin = UdpSkin(parse_layout(_layout(), "lab.toml"), RecorderClock())
    good = _frames(np.arange(200), 1000, 1.0)
    payloads = [frame + b"\x00" if i % 4 == 0 else frame for i, frame in enumerate(good)]
    start = time.monotonic_ns()
    items = [Received(start + i * 1_000_000, p) for i, p in enumerate(payloads)]
    skin.begin()
    skin._consume(items)
    skin.finish()
    stats = skin.stats()[0]
    said = capsys.readouterr().err.splitlines()
    assert stats.malformed == 50
    assert said == [
        (
            f"skin: 50 frames of {SIZE + 1} bytes (frame type fast is {SIZE} bytes) left out as "
            "malformed: check [skin] in lab.toml against the skin's firmware (cells, cell_stride, "
            "size, types, header)"
        )
    ]


def test_many_frames_out_of_range_in_an_action_are_said_with_their_cause(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A skin at ten times its rate_hz in an action: its frames fall on places already
    written and are left out as out of range; the action's one line names rate_hz."""
    skin = UdpSkin(parse_layout(_layout(rate_hz=100), "lab.toml"), RecorderClock())
    start = time.monotonic_ns()
    payloads = _frames(np.arange(1000), 1000, 1.0)  # 1 kHz, stamps 1 ms apart
    items = [Received(start + i * 1_000_000, p) for i, p in enumerate(payloads)]
    skin.begin()
    for at in range(0, len(items), 100):
        skin._consume(items[at : at + 100])
    skin.finish()
    stats = skin.stats()[0]
    said = capsys.readouterr().err.splitlines()
    assert stats.out_of_range > 800, stats
    assert said == [
        (
            f"skin frame type fast: arrives at about 1,000 Hz, [skin.frames.fast] rate_hz = 100 in "
            f"lab.toml ({stats.out_of_range} of {stats.received} frames stamped out of range, left "
            "out); fix rate_hz (or the skin's rate)"
        )
    ]


def test_a_rate_off_without_frames_left_out_is_left_to_the_dry_run(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Frames stamped at the skin's rate_hz but read in bursts (a busy computer) measure a
    rate off rate_hz over one action: nothing was left out, so the action's end says
    nothing; the dry run (which judges the rate) still names it."""
    skin = UdpSkin(parse_layout(_layout(rate_hz=1000), "lab.toml"), RecorderClock())
    start = time.monotonic_ns()
    payloads = _frames(np.arange(1000), 1000, 1.0)  # 1 kHz stamps, received twice as fast
    items = [Received(start + i * 500_000, p) for i, p in enumerate(payloads)]
    skin.begin()
    for at in range(0, len(items), 100):
        skin._consume(items[at : at + 100])
    stats = skin.stats()[0]
    assert [f.short for f in skin.findings()], "the dry run's judgement names the rate"
    skin.finish()
    assert stats.out_of_range == 0, stats
    assert capsys.readouterr().err == ""
