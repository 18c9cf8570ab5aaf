"""Benchmark recording and replay (a script, not a test: ``python tests/bench/bench_recording.py``).

Prints medians and ratios measured side by side in one run:

1. recording speed: recorded (simulated) seconds per wall-clock second on one core, for
   every action, simulation included; also the simulation alone, without writing;
2. read + decode throughput of ``replay.read_recording`` as a fraction of raw ``mcap``
   iteration over the same files without decoding (target >= 0.5);
3. with ``--full``: the whole dataset generated on ``--workers`` cores (target <= 5 minutes
   on 2 cores) and its size on disk (target <= 1.5 GB).

``--quick`` runs 1 and 2 on one object once (a check that the benchmark runs, no figures).
"""

from __future__ import annotations

import argparse
import io
import statistics
import tempfile
import time
from pathlib import Path

from mcap.reader import make_reader

from recorder import load_actions, plan_dataset, record_action
from recorder._catalog import load_objects
from recorder._dataset import generate_dataset, rig_factory
from replay import read_recording

NS = 1e9


def _median_time(function: object, repeat: int) -> float:
    """Return the median wall time of ``repeat`` calls of ``function``."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        function()  # type: ignore[operator]
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def bench_recording(rig_name: str, objects: list[str], out: Path, repeat: int) -> list[Path]:
    """Print recording speed per action; return the recorded files."""
    catalog, actions = load_objects(), load_actions()
    factory = rig_factory(rig_name)
    paths: list[Path] = []
    print(f"recording speed, rig {rig_name!r}, objects {', '.join(objects)} (median of {repeat})")
    print(f"{'action':8}{'recorded s':>12}{'record s':>11}{'x real time':>13}{'sim only x':>12}")
    for action in actions.values():
        durations, record_times, sim_times = [], [], []
        for object_id in objects:
            obj = catalog[object_id]
            for run in range(repeat):
                path = out / f"{object_id}-{action.id}-{run}.mcap"
                with factory(0) as rig:
                    start = time.perf_counter()
                    written = record_action(rig, obj, action, 1, path, seed=0)
                    record_times.append(time.perf_counter() - start)
                with factory(0) as rig:
                    start = time.perf_counter()
                    for _ in rig.perform(obj, action, 1):
                        pass
                    sim_times.append(time.perf_counter() - start)
                durations.append((written.end_ns - written.start_ns) / NS)
                paths.append(path)
        recorded, wall, sim = (statistics.median(v) for v in (durations, record_times, sim_times))
        speed, sim_speed = recorded / wall, recorded / sim
        print(f"{action.id:8}{recorded:12.2f}{wall:11.3f}{speed:13.1f}{sim_speed:12.1f}")
    return paths


def _raw_iteration(path: Path) -> int:
    """Iterate every message with mcap, without decoding (the baseline)."""
    reader = make_reader(io.BytesIO(path.read_bytes()))
    return sum(1 for _ in reader.iter_messages(log_time_order=False))


def bench_decoding(paths: list[Path], repeat: int) -> None:
    """Print read + decode time against raw mcap iteration over the same files."""

    def raw() -> None:
        for path in paths:
            _raw_iteration(path)

    def ours() -> None:
        for path in paths:
            read_recording(path)

    raw()  # warm the page cache and the typestore
    ours()
    raw_times, our_times = [], []
    for _ in range(repeat):  # interleaved, so that load from elsewhere hits both alike
        raw_times.append(_median_time(raw, 1))
        our_times.append(_median_time(ours, 1))
    raw_s, ours_s = statistics.median(raw_times), statistics.median(our_times)
    size = sum(p.stat().st_size for p in paths) / 1e6
    print(f"\nread + decode of {len(paths)} files ({size:.1f} MB), median of {repeat}")
    print(f"  raw mcap iteration, no decoding: {raw_s:8.3f} s  ({size / raw_s:6.1f} MB/s)")
    print(f"  replay.read_recording:           {ours_s:8.3f} s  ({size / ours_s:6.1f} MB/s)")
    print(f"  throughput ratio (target >= 0.5): {raw_s / ours_s:.2f}")


def bench_full(rig_name: str, workers: int, out: Path) -> None:
    """Generate the whole dataset and print time and disk size."""
    tasks = plan_dataset(load_objects(), load_actions())
    start = time.perf_counter()
    report = generate_dataset(tasks, out, rig_factory(rig_name), seed=0, workers=workers)
    elapsed = time.perf_counter() - start
    disk = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    print(f"\nfull dataset: {report.written} recordings written on {workers} workers")
    print(f"  generation time (target <= 300 s on 2 cores): {elapsed:8.1f} s")
    print(f"  size on disk (target <= 1.5 GB):              {disk / 1e9:8.3f} GB")


def main() -> None:
    """Run the benchmarks."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rig", default="sim")
    parser.add_argument("--objects", default="wood,soft_sponge,aluminium_plate")
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--full", action="store_true", help="also generate the whole dataset")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, help="keep the full dataset here (default: temp)")
    parser.add_argument(
        "--quick", action="store_true", help="one object, one repetition, no --full (untimed)"
    )
    args = parser.parse_args()
    if args.quick:
        args.objects, args.repeat, args.full = "wood", 1, False
    with tempfile.TemporaryDirectory() as scratch:
        root = Path(scratch)
        paths = bench_recording(args.rig, args.objects.split(","), root / "speed", args.repeat)
        bench_decoding(paths, args.repeat)
        if args.full:
            target = args.out or root / "full"
            if target.exists() and any(target.iterdir()):
                parser.error(f"--out {target}: not empty; a resumed run would not be timed")
            bench_full(args.rig, args.workers, target)


if __name__ == "__main__":
    main()
