"""Paired difference of two transfer-style studies that differ in one learner option.

Two runs of ``atikt-replay study transfer`` (or ``negative``, ``priors``, ``single-action``)
with the same dataset, roles and seed draw the same groups, splits and seeds; only the option
under test differs (e.g. ``--kernel-parts texture=matern32,thermal=matern32``). This prints,
per arm (ATIKT, baseline), the mean accuracy of A minus B after the initial observations, the
mean over steps 1..budget and the last step, in points, paired per run, with a 95 %
percentile bootstrap interval over the study's independent unit (groups; repetitions where
the priors are fixed), computed by the studies' own ``paired_gains``::

    atikt-replay study transfer --kernel-parts texture=matern32,thermal=matern32 --out A
    atikt-replay study transfer --out B
    python tests/bench/paired_studies.py A B

``--quick`` pairs a short transfer study on the committed recordings with itself (a check that
the script runs; every difference is 0).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import polars as pl

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's packages

from replay.studies._running import ATIKT, BASELINE
from replay.studies._stats import HEADLINES, paired_gains

KEYS = ("group", "trial", "step", "actions", "priors")


def _arm(results: pl.DataFrame, method: str, label: str) -> pl.DataFrame:
    """One arm of a study, relabelled for pairing."""
    keys = [k for k in (*KEYS, "repetition", "n_priors") if k in results.columns]
    arm = results.filter(pl.col("method") == method)
    return arm.select([*keys, "accuracy"]).with_columns(pl.lit(label).alias("method"))


def main() -> None:
    """Print the paired differences A minus B of both arms."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("a", type=Path, nargs="?", help="study output directory A")
    parser.add_argument("b", type=Path, nargs="?", help="study output directory B (the reference)")
    parser.add_argument(
        "--quick",
        action="store_true",
        help="pair a short transfer study on the committed recordings with itself (a check)",
    )
    args = parser.parse_args()
    if args.quick:
        from _quick import quick_study  # noqa: PLC0415

        with tempfile.TemporaryDirectory() as scratch:
            args.a = args.b = quick_study("transfer", Path(scratch) / "study")
            _print(args.a, args.b)
        return
    if args.a is None or args.b is None:
        parser.error("A and B are required (unless --quick)")
    _print(args.a, args.b)


def _print(a: Path, b: Path) -> None:
    """Print the paired differences of study outputs ``a`` minus ``b``."""
    args = argparse.Namespace(a=a, b=b)
    first, second = (pl.read_parquet(d / "results.parquet") for d in (args.a, args.b))
    options = json.loads((args.a / "study.json").read_text("utf-8"))
    budget, seed = int(options["learner"]["budget"]), int(options["seed"])
    unit = "repetition" if "repetition" in first.columns else "group"
    by = [c for c in ("n_priors",) if c in first.columns]
    print(f"{args.a} minus {args.b}, points, paired per run; [95 % bootstrap over {unit}s]")
    for method in (ATIKT, BASELINE):
        pair = pl.concat([_arm(first, method, ATIKT), _arm(second, method, BASELINE)])
        for row in paired_gains(pair, by, unit, budget, seed=seed).iter_rows(named=True):
            cells = []
            for head in HEADLINES:
                mean, low, high = (100 * row[f"{p}_{head}"] for p in ("gain", "low", "high"))
                cells.append(f"{head} {mean:+.1f} [{low:+.1f}, {high:+.1f}]")
            where = ", ".join(f"{k} {row[k]}" for k in by)
            print(f"{method}{' (' + where + ')' if where else ''}: " + "; ".join(cells))


if __name__ == "__main__":
    main()
