"""Live skin over UDP loopback: samples lost, sensor-to-writer-queue latency, recorder CPU.

The virtual lab's sender runs in a child process (a 7-cell skin: force and acceleration at
1 kHz, proximity 50 Hz, temperature 20 Hz, in the layout of
``recorder/data/skin_udp.example.toml``); this process is the recorder: a UdpSkin polled every
10 ms, as a rig would. Printed: samples expected/received/missing per source, the latency from
a sample's sensor time (on the recorder's time base) to its block being handed to the writer
(p50/p99, per sample and for the last sample of each block), and this process's CPU time per
second of recording.

    python tests/bench/bench_live_skin.py --seconds 60

``--quick`` records one second (a check that the benchmark runs).
"""

from __future__ import annotations

import argparse
import multiprocessing
import sys
import time
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from recorder.live import RecorderClock  # noqa: E402
from recorder.live._frames import udp_skin  # noqa: E402
from recorder.virtuallab._skin_server import serve_skin  # noqa: E402

EXAMPLE = ROOT / "recorder" / "data" / "skin_udp.example.toml"
COUNTS = {"force": 3, "acceleration": 3, "temperature": 1, "proximity": 1}


class _World:
    """A 7-cell skin with slowly varying values."""

    def __init__(self) -> None:
        self.origin = time.monotonic_ns()
        self.rng = np.random.default_rng(0)

    def controller_ns(self) -> int:
        return time.monotonic_ns() - self.origin

    def skin_at(self, modality: str, controller_ns: int) -> Any:
        phase = controller_ns / 1e9
        return np.full((7, COUNTS[modality]), 0.001 * (1 + np.sin(phase)))


def _section(port: int) -> dict[str, Any]:
    with EXAMPLE.open("rb") as stream:
        section: dict[str, Any] = tomllib.load(stream)["skin"]
    return {**section, "bind": f"127.0.0.1:{port}"}


def _send(port: int, seconds: float, result: Any) -> None:
    start = time.process_time()
    with serve_skin(_World(), f"udp://127.0.0.1:{port}", _section(port)) as server:
        time.sleep(seconds)
    result.put((dict(server.injected.sent), (time.process_time() - start) / seconds))


def main() -> None:
    """Run the benchmark and print its figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--quick", action="store_true", help="one second (untimed)")
    args = parser.parse_args()
    if args.quick:
        args.seconds = 1.0
    clock = RecorderClock()
    skin = udp_skin(_section(0), clock, str(EXAMPLE))
    per_sample: list[np.ndarray] = []
    per_block: list[int] = []
    with skin:
        skin.begin()
        port = skin.address[1]
        context = multiprocessing.get_context("spawn")
        result = context.Queue()
        sender = context.Process(target=_send, args=(port, args.seconds, result))
        cpu0, wall0 = time.process_time(), time.monotonic()
        sender.start()
        while sender.is_alive():
            blocks = skin.poll()
            now = clock.now_ns()
            for block in blocks:
                stamps = block.stamp_ns + block.period_ns * np.arange(block.data.shape[0])
                per_sample.append(now - stamps)
                per_block.append(now - int(stamps[-1]))
            time.sleep(0.01)
        time.sleep(0.05)
        blocks = skin.finish()
        cpu, wall = time.process_time() - cpu0, time.monotonic() - wall0
        sent, sender_cpu = result.get(timeout=10)
    print(f"live skin over UDP loopback, {args.seconds:g} s, 7 cells")
    print(f"  UDP receive buffer: {skin.receive_buffer} bytes")
    for stats in skin.stats():
        print(
            f"  {stats.name:17s} expected {stats.expected:7d}  received {stats.received:7d}  "
            f"missing {stats.missing}  duplicated {stats.duplicated}  "
            f"out of order {stats.out_of_order}  malformed {stats.malformed}  "
            f"overflowed {stats.overflowed}  drift {stats.clock_drift_ns / 1e3:.0f} us"
        )
    print(f"  frames sent: {sent}")
    samples = np.concatenate(per_sample) / 1e6
    last = np.asarray(per_block) / 1e6
    print(
        f"  latency sensor -> writer queue, every sample: p50 {np.percentile(samples, 50):.1f} ms"
        f"  p99 {np.percentile(samples, 99):.1f} ms (a block holds 0.1 s)"
    )
    print(
        f"  latency of each block's last sample: p50 {np.percentile(last, 50):.1f} ms"
        f"  p99 {np.percentile(last, 99):.1f} ms"
    )
    print(f"  recorder CPU: {cpu / wall:.3f} s per s (reader thread + polling + packing)")
    print(f"  sender CPU:   {sender_cpu:.3f} s per s")


if __name__ == "__main__":
    main()
