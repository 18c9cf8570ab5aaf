"""Live recording at the robot over loopback: samples missing, latency, recorder CPU.

Two runs, figures printed side by side:

* **UDP** (the project drives): ``atikt-record serve-sim`` in its own process serves an
  e-Series UR arm over RTDE at 500 Hz and a 7-cell skin over UDP in the layout of
  ``recorder/data/skin_udp.example.toml`` (force and acceleration at 1 kHz, proximity 50 Hz,
  temperature 20 Hz); this process is the recorder: the UR rig (RTDE client, URScript, the UDP
  skin) records contact actions (C1, 15 s each, in real time) into MCAP files for
  ``--seconds``. Latency: from a sample's sensor time (on the recorder's time base) to its
  hand-off to the file writer, for every sample written. CPU: this process's CPU time per
  second (reader threads, the rig's loop, packing, encoding and writing).
* **DDS** (the lab drives): ``tests/bench/bench_live_dds.py``'s publisher process sends a UR
  driver's JointState at 500 Hz and the same skin as one ROS 2 topic per cell and modality
  (15 k messages/s); this process runs ``listen``'s listener on them.

    python tests/bench/bench_live.py --seconds 60

``--quick`` records one C1 action with the virtual lab and the rig 10 times faster than real
time and leaves out DDS, which ``bench_live_dds.py --quick`` runs (a check that the benchmark
runs).
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import resource
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.append(str(ROOT / "tests"))  # the tests' helpers (ports), after the packages
DATA = ROOT / "recorder" / "data"
NS = 1_000_000_000

_spec = importlib.util.spec_from_file_location(
    "bench_live_dds", Path(__file__).with_name("bench_live_dds.py")
)
assert _spec is not None
assert _spec.loader is not None
bench_live_dds = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench_live_dds)  # sets CYCLONEDDS_URI to loopback first

from ports import free_port  # noqa: E402

from recorder import load_actions, load_objects, load_rig_config, rig_factory  # noqa: E402
from recorder.live import RecorderClock  # noqa: E402
from recorder.writing._stream import SkinBlock  # noqa: E402
from recorder.writing._writer import RecordingInfo, RecordingWriter  # noqa: E402


def _cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _lab(root: Path, rtde: int, script: int, udp: int, scale: float) -> Path:
    """The example UR configuration at 500 Hz with the example UDP skin, on this run's ports,
    at ``scale`` real seconds per action second.
    """
    text = (DATA / "ur_rig.example.toml").read_text("utf-8")
    if scale != 1:
        text = text.replace("# time_scale = 0.1", f"time_scale = {scale}")
    text = text.replace("rtde_port = 30004", f"rtde_port = {rtde}")
    text = text.replace("script_port = 30001", f"script_port = {script}")
    text = text.replace("frequency = 125", "frequency = 500")
    skin = (DATA / "skin_udp.example.toml").read_text("utf-8")
    skin = skin.replace('bind = "127.0.0.1:5005"', f'bind = "127.0.0.1:{udp}"')
    text = text[: text.index("\n[skin]\n") + 1] + skin[skin.index("\n[skin]\n") + 1 :]
    lab = root / "lab.toml"
    lab.write_text(text, "utf-8")
    return lab


def _latencies(item: Any, now: int) -> np.ndarray:
    if isinstance(item, SkinBlock):
        stamps = item.stamp_ns + item.period_ns * np.arange(item.data.shape[0], dtype=np.int64)
        return now - stamps
    return np.array([now - item.stamp_ns])


def udp_case(seconds: float, scale: float = 1.0) -> dict[str, Any]:
    """Record C1 actions with the UR rig against serve-sim for ``seconds``; return figures.

    ``scale``: real seconds per simulated second (< 1: the virtual lab and the rig run faster
    than real time, ``--quick``).
    """
    root = Path(tempfile.mkdtemp(prefix="bench-live-"))
    rtde, script, udp = (
        free_port(socket.SOCK_STREAM),
        free_port(socket.SOCK_STREAM),
        free_port(socket.SOCK_DGRAM),
    )
    lab = _lab(root, rtde, script, udp, scale)
    command = [sys.executable, "-m", "recorder", "serve-sim", "--frequency", "500"]
    command += ["--time-scale", str(scale)]
    command += ["--rtde-port", str(rtde), "--script-port", str(script), "--rig-config", str(lab)]
    command += ["--skin", f"udp://127.0.0.1:{udp}"]
    lab_process = subprocess.Popen(  # noqa: S603 (this project's command)
        command, stdout=subprocess.PIPE, text=True, env=os.environ | {"PYTHONPATH": str(ROOT)}
    )
    try:  # the lab stops whatever happens: a lab left running ticks on (5000 cycles/s here)
        assert lab_process.stdout is not None
        print("  ", lab_process.stdout.readline().strip())
        objects, actions = load_objects(), load_actions()
        rig: Any = rig_factory(load_rig_config(lab))(0)  # the UR rig: present, source_stats
        clock = RecorderClock()
        latency: list[np.ndarray] = []
        totals: dict[str, list[int]] = {}
        files = 0
        cpu0, wall0 = _cpu(), time.monotonic()
        with rig:
            trial = 1
            while time.monotonic() - wall0 < seconds:
                obj = objects["wood" if trial % 2 else "foam_block"]
                rig.present(obj)
                info = RecordingInfo.create(obj, actions["C1"], trial, rig, 0)
                path = root / obj.id / "C1" / f"{trial:03d}.mcap"
                with RecordingWriter(path, info) as writer:
                    for item in rig.perform(obj, actions["C1"], trial):
                        latency.append(_latencies(item, clock.now_ns()))
                        writer.write(item)
                    writer.add_sources(rig.source_stats())
                for stats in rig.source_stats():
                    counts = totals.setdefault(stats.name, [0, 0, 0, 0])
                    values = (stats.expected, stats.received, stats.missing, stats.overflowed)
                    totals[stats.name] = [a + b for a, b in zip(counts, values, strict=True)]
                files += 1
                trial += 1
        cpu, wall = _cpu() - cpu0, time.monotonic() - wall0
    finally:
        lab_process.send_signal(signal.SIGINT)
        try:
            lab_process.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            lab_process.kill()
            lab_process.communicate()
    samples = np.concatenate(latency) / 1e6
    return {
        "files": files,
        "wall": wall,
        "totals": totals,
        "p50": float(np.percentile(samples, 50)),
        "p99": float(np.percentile(samples, 99)),
        "cpu": cpu / wall,
    }


def main() -> None:
    """Run both cases and print their figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--domain", type=int, default=1 + os.getpid() % 200)
    parser.add_argument(
        "--quick", action="store_true", help="one C1 action 10x faster, no DDS (untimed)"
    )
    args = parser.parse_args()
    scale = 0.1 if args.quick else 1.0
    if args.quick:
        args.seconds = 1.0
    print(f"UDP: UR rig (RTDE 500 Hz) + 7-cell UDP skin -> MCAP files, {args.seconds:g} s")
    udp = udp_case(args.seconds, scale)
    for name, (expected, received, missing, overflowed) in sorted(udp["totals"].items()):
        print(
            f"  {name:17s} expected {expected:7d}  received {received:7d}  missing {missing}"
            f"  queue overflow {overflowed}"
        )
    missing = sum(t[2] for t in udp["totals"].values())
    print(f"  {udp['files']} files in {udp['wall']:.1f} s; samples missing in all: {missing}")
    print(
        f"  latency sensor -> writer, every sample: p50 {udp['p50']:.1f} ms"
        f"  p99 {udp['p99']:.1f} ms (skin blocks hold 0.1 s)"
    )
    print(f"  recorder CPU: {udp['cpu']:.2f} s per s")
    if args.quick:  # the DDS part is bench_live_dds.py's, whose own --quick runs it
        return
    print(f"DDS: JointState 500 Hz + 7-cell skin topics -> listen, {args.seconds:g} s")
    with tempfile.TemporaryDirectory() as root:
        bench_live_dds.record(bench_live_dds.write_map(Path(root)), args.domain, args.seconds)


if __name__ == "__main__":
    main()
