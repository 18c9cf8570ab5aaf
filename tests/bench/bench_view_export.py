"""Benchmark views, exports and bag import (a script: ``python tests/bench/bench_view_export.py``).

Prints medians measured side by side in one run:

1. rerun logging of one recording's acceleration channel, one cell: the columnar API
   (``send_columns``, what ``atikt-replay view`` does) against one ``log`` call per sample;
   and a whole recording logged by ``replay.outputs._view.log_recording`` against reading it;
2. export of a recording to parquet and CSV (long layout) against reading it;
3. import of a lab-shaped ROS 1 bag (7 cells at 250 Hz, joint states and poses at 125 Hz):
   bag messages per second.

``--quick`` runs each part once on the shortest bag (a check that the benchmark runs).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from recorder import load_actions, load_objects
from recorder.bagimport._importer import import_bag
from recorder.bagimport._topicmap import load_topic_map
from replay import read_recording
from replay.outputs._export import export
from replay.outputs._view import log_recording, new_stream

if TYPE_CHECKING:
    from collections.abc import Callable

ROOT = Path(__file__).parents[2]
RECORDING = ROOT / "recordings" / "data" / "wood" / "C1" / "001.mcap"


def _median(function: Callable[[], object], repeat: int) -> float:
    """Return the median wall time of ``repeat`` calls, s."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def _stream() -> rr.RecordingStream:
    """Return a stream writing an .rrd file (what ``view --save`` does)."""
    stream = new_stream("bench")
    stream.save(Path(tempfile.gettempdir()) / "atikt-bench-view.rrd")
    return stream


def bench_logging(repeat: int, samples: int | None = None) -> None:
    """Columnar against row-wise logging (of the first ``samples`` if given), and a whole
    recording against reading it.
    """
    recording = read_recording(RECORDING)
    series = recording.skin("acceleration")
    stamps = series.stamps_ns[:samples].view("datetime64[ns]")
    values = np.ascontiguousarray(series.data[:samples, 0, :])

    def columnar() -> None:
        stream = _stream()
        stream.send_columns(
            "acc",
            indexes=[rr.TimeColumn("log_time", timestamp=stamps)],
            columns=rr.Scalars.columns(scalars=values),
        )
        stream.flush()

    def row_wise() -> None:
        stream = _stream()
        for stamp, row in zip(series.stamps_ns[:samples], values, strict=True):
            stream.set_time("log_time", timestamp=np.datetime64(int(stamp), "ns"))
            stream.log("acc", rr.Scalars(row))
        stream.flush()

    t_col, t_row = _median(columnar, repeat), _median(row_wise, max(1, repeat // 3))
    n = values.shape[0]
    print(f"rerun, {n} acceleration samples of one cell ({RECORDING.relative_to(ROOT)}):")
    print(f"  send_columns {1e3 * t_col:8.1f} ms   one log per sample {1e3 * t_row:8.1f} ms")
    print(f"  row-wise / columnar = {t_row / t_col:.0f}x")

    def whole() -> None:
        stream = _stream()
        log_recording(stream, recording, "r")
        stream.flush()

    t_read = _median(lambda: read_recording(RECORDING), repeat)
    t_view = _median(whole, repeat)
    samples = sum(recording.skin(m).data.shape[0] for m in ("force", "acceleration"))
    print(f"whole recording ({samples} force + acceleration samples x 7 cells):")
    print(f"  read {1e3 * t_read:.1f} ms, log to rerun {1e3 * t_view:.1f} ms")
    print(f"  log / read = {t_view / t_read:.2f}")


def bench_export(repeat: int, work: Path) -> None:
    """Export one recording in both formats, against reading it."""
    t_read = _median(lambda: read_recording(RECORDING), repeat)
    counter = iter(range(1000))
    for fmt in ("parquet", "csv"):

        def run(fmt: str = fmt) -> None:
            export([RECORDING], work / f"{fmt}-{next(counter)}", fmt=fmt)

        t_export = _median(run, repeat)
        size = sum(p.stat().st_size for p in next((work).glob(f"{fmt}-*")).iterdir())
        print(
            f"export {fmt:7} {1e3 * t_export:7.1f} ms  ({t_export / t_read:.1f}x reading), "
            f"{size / 1e6:.1f} MB for a {RECORDING.stat().st_size / 1e6:.1f} MB recording"
        )


def bench_import(work: Path, seconds: float) -> None:
    """Import a lab-shaped ROS 1 bag; print messages per second."""
    sys.path.insert(0, str(ROOT / "tests" / "recorder"))
    import test_bagimport as lab  # noqa: PLC0415 (the tests' lab-bag builder)

    lab.DURATION = round(seconds * 1e9)
    lab.CELLS = tuple(range(7))
    lab.ANNOTATIONS = (lab.Note("wood", "C1", None, (0.2, 0.5, 0.8, 16.0, seconds - 0.5)),)
    bag = lab.write_lab_bag(work / "lab.bag", "ros1", lab.LabData(seed=0))
    topic_map = load_topic_map(lab.write_map(work))
    messages = 7 * 250 * seconds + 2 * 125 * seconds + 5
    start = time.perf_counter()
    report = import_bag(
        bag, topic_map, work / "imported", objects=load_objects(), actions=load_actions()
    )
    elapsed = time.perf_counter() - start
    print(
        f"import-bag: {messages:.0f} messages ({seconds:.0f} s, 7 cells at 250 Hz) in "
        f"{elapsed:.2f} s = {messages / elapsed:.0f} messages/s; {len(report.written)} recording"
    )


def main() -> None:
    """Run the benchmarks."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeat", type=int, default=5, help="repetitions (median)")
    parser.add_argument("--bag-seconds", type=float, default=20.0, help="length of the lab bag")
    parser.add_argument(
        "--quick", action="store_true", help="one repetition, the shortest bag (untimed)"
    )
    args = parser.parse_args()
    if args.quick:  # the bag's one annotated C1 action ends at 16 s
        args.repeat, args.bag_seconds = 1, 17.0
    with tempfile.TemporaryDirectory() as directory:
        work = Path(directory)
        bench_logging(args.repeat, 500 if args.quick else None)
        bench_export(args.repeat, work)
        bench_import(work, args.bag_seconds)


if __name__ == "__main__":
    main()
