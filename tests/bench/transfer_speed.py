"""Time ``atikt-replay learn --transfer MODE`` against the same command with ``--transfer none``.

Runs ``python -m replay learn --recordings DIR --new NEW --priors PRIORS --transfer T --out
TMP`` for T = none and MODE, alternating, ``--repeats`` times each (so a busy machine slows
both alike; the feature cache is built first), and prints the median wall time of each, their
ratio, and whether every repetition of a mode wrote the same decisions and accuracies.

Run: ``python tests/bench/transfer_speed.py --recordings DIR --new wood,aluminium --priors
cold_wood [--transfer optimization] [--repeats 5]`` (DIR: the 270 heated-probe recordings,
``python recordings/thermal_probe/convert.py --source ... --all --out DIR``). ``--quick``: each
mode once with budget 2 on two new and two prior objects of the committed recordings (a check
that the script runs).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import polars as pl

ROOT = Path(__file__).resolve().parents[2]
DECISIONS = ("step", "object", "action", "prior", "rho", "accuracy")
"""History columns that must not change between repetitions."""


def _learn(args: argparse.Namespace, mode: str, out: Path) -> tuple[float, pl.DataFrame]:
    """Run the command once; return its wall time and its decisions and accuracies."""
    command = [sys.executable, "-m", "replay", "learn", "--recordings", str(args.recordings)]
    command += ["--new", args.new, "--priors", args.priors, "--transfer", mode, "--workers", "1"]
    command += ["--seed", str(args.seed), "--out", str(out), "--force"]
    if args.budget is not None:
        command += ["--budget", str(args.budget)]
    env = os.environ | {"PYTHONPATH": str(ROOT)}
    start = time.perf_counter()
    subprocess.run(command, check=True, capture_output=True, env=env, cwd=ROOT)  # noqa: S603
    elapsed = time.perf_counter() - start
    return elapsed, pl.read_parquet(out / "history.parquet").select(DECISIONS)


def main() -> int:
    """Time both modes and print medians and their ratio."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--recordings", type=Path, help="the dataset (required unless --quick)")
    parser.add_argument("--new", help="new objects (required unless --quick)")
    parser.add_argument("--priors", help="prior objects (required unless --quick)")
    parser.add_argument("--transfer", default="optimization")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--budget", type=int, default=None, help="learn's --budget (its default)")
    parser.add_argument(
        "--quick", action="store_true", help="once each, budget 2, the committed recordings"
    )
    args = parser.parse_args()
    if args.quick:
        args.recordings, args.repeats, args.budget = ROOT / "recordings" / "data", 1, 2
        args.new, args.priors = "aluminium_plate,foam_block", "metal_toolbox,soft_sponge"
    if args.recordings is None or args.new is None or args.priors is None:
        parser.error("--recordings, --new and --priors are required (unless --quick)")
    env = os.environ | {"PYTHONPATH": str(ROOT)}
    if not args.quick:  # the cache is built before the timed runs (untimed with --quick)
        features = [sys.executable, "-m", "replay", "features", str(args.recordings)]
        subprocess.run(features, check=True, capture_output=True, env=env, cwd=ROOT)  # noqa: S603
    modes = ("none", args.transfer)
    times: dict[str, list[float]] = {mode: [] for mode in modes}
    first: dict[str, pl.DataFrame] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeats):
            for mode in modes:
                elapsed, history = _learn(args, mode, Path(tmp) / mode)
                times[mode].append(elapsed)
                if mode in first and not history.equals(first[mode]):
                    print(f"{mode}: decisions changed between repetitions")
                first.setdefault(mode, history)
    medians = {mode: statistics.median(times[mode]) for mode in modes}
    for mode in modes:
        accuracy = first[mode]["accuracy"].to_list()
        print(
            f"--transfer {mode:<12s} median {medians[mode]:6.2f} s over {args.repeats} "
            f"(min {min(times[mode]):.2f}, max {max(times[mode]):.2f}); accuracy step 0 "
            f"{100 * accuracy[0]:.1f} %, mean {100 * sum(accuracy) / len(accuracy):.2f} %"
        )
    ratio = medians[args.transfer] / medians["none"]
    print(f"ratio {args.transfer} / none: {ratio:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
