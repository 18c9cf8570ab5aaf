"""Analysis of a ``priors`` study: the transfer gain by related old objects among the priors.

Every new object of the catalog names the old object it resembles (``related_to`` in
recorder/data/objects.toml). For every paired run of the study (ATIKT and baseline on the same
split and priors), this counts how many of those related old objects are among the run's
priors and prints the mean gain over observations 1..40 (ATIKT minus baseline, points) per
count, and the mean count per number of priors.

Run: ``python tests/bench/priors_counterparts.py studies/priors/results.parquet``;
``--quick``: a short priors study on the committed recordings, analysed (a check that the
script runs).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import polars as pl

from recorder._catalog import load_objects


def main() -> None:
    """Print the gain by the number of related old objects among the priors."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path, nargs="?", help="results.parquet of a priors study")
    parser.add_argument(
        "--quick",
        action="store_true",
        help="analyse a short priors study on the committed recordings (a check)",
    )
    args = parser.parse_args()
    if args.quick:
        from _quick import quick_study  # noqa: PLC0415

        with tempfile.TemporaryDirectory() as scratch:
            out = quick_study("priors", Path(scratch) / "study", prior_counts=(3,))
            _print(out / "results.parquet")
        return
    if args.results is None:
        parser.error("RESULTS is required (unless --quick)")
    _print(args.results)


def _print(results: Path) -> None:
    """Print the gain by related old objects among the priors of a priors study's results."""
    args = argparse.Namespace(results=results)
    related = {o.related_to for o in load_objects().values() if o.related_to}
    table = pl.read_parquet(args.results)
    runs = (
        table.filter(pl.col("step") >= 1)
        .group_by(["n_priors", "group", "trial", "method", "priors"])
        .agg(pl.col("accuracy").mean())
        .pivot(on="method", index=["n_priors", "group", "trial", "priors"], values="accuracy")
        .with_columns(
            ((pl.col("ATIKT") - pl.col("baseline")) * 100).alias("gain"),
            pl.col("priors")
            .map_elements(lambda p: len(set(p.split(",")) & related), return_dtype=pl.Int64)
            .alias("related"),
        )
    )
    print(f"{runs.height} paired runs; related old objects: {', '.join(sorted(related))}")
    by_count = runs.group_by("related").agg(pl.col("gain").mean(), pl.len().alias("runs"))
    for row in by_count.sort("related").iter_rows(named=True):
        print(
            f"  {row['related']} related among the priors: gain {row['gain']:+.1f} points "
            f"({row['runs']} runs)"
        )
    per_size = runs.group_by("n_priors").agg(pl.col("related").mean()).sort("n_priors")
    for row in per_size.iter_rows(named=True):
        print(
            f"  {row['n_priors']} priors hold {row['related']:.1f} related old objects on average"
        )


if __name__ == "__main__":
    main()
