"""Benchmark of the replay engine on the default simulated dataset (1950 recordings).

Printed, measured in one run:

- feature extraction of the whole dataset from the MCAP files (cold cache), with 1 and with
  ``--workers`` processes, their ratio, and the time against the 60 s target;
- the full ``transfer`` study with cached features (10 groups x 5 trials x ATIKT and baseline,
  40 observations each), against the 3 minute target;
- one ATIKT run of that study (5 new objects, 3 priors, 7 actions, 40 steps) on the dataset's
  features: every action update timed side by side with the same update done by the
  scikit-learn reference (tests/atikt/sklearn_reference.py), and their ratio.

The dataset is recorded into the cache on first use (see ``atikt-replay study``).

Run: ``python tests/bench/bench_replay.py [--workers 2] [--skip-study] [--skip-one-worker]``;
``--quick``: the extraction of 4 recordings, a study of one group and trial and a run, budget 2
each, on the committed recordings and one process (a check that the benchmark runs).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import statistics
import sys
import tempfile
import time
import warnings
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _quick import RECORDINGS, small_dataset
from bench_atikt import TimedLearner, print_quality, sklearn_old_models

from replay.learning._datasets import dataset_roles
from replay.learning._executors import FeatureLookup, PoolExecutor, Split
from replay.learning._features import build_features
from replay.learning._session import fit_priors, prior_data
from replay.live import ensure_default_dataset
from replay.outputs._study_report import run_study
from replay.studies._running import StudyConfig, dataset_actions, prior_groups


def extraction(root: Path, workers: int, *, one_worker: bool) -> None:
    """Time the cold feature extraction of the whole dataset."""
    times = {}
    for count in ([1] if one_worker else []) + [workers]:
        with tempfile.TemporaryDirectory() as scratch:
            start = time.perf_counter()
            table = build_features(root, workers=count, cache=Path(scratch) / "f.parquet")
            times[count] = time.perf_counter() - start
        rate = table.frame.height / times[count]
        print(f"feature extraction, {count} worker(s): {times[count]:.1f} s ({rate:.0f} files/s)")
    if one_worker:
        print(f"  speed-up {workers} workers vs 1: {times[1] / times[workers]:.2f}x")
    print(f"  against the 60 s target: {times[workers] / 60:.2f} of the budget")


def study(root: Path, workers: int, *, quick: bool = False) -> None:
    """Time the full transfer study with cached features (``quick``: its reduced design)."""
    frame = build_features(root, workers=workers).frame
    with tempfile.TemporaryDirectory() as scratch:
        roles = dataset_roles(root, frame["object_id"].to_list())
        config = StudyConfig(
            out=Path(scratch),
            workers=workers,
            new=roles.new,
            old=roles.old,
            actions=dataset_actions(frame),
        )
        if quick:
            config = replace(config, groups=1, trials=1, learner=config.learner.replace(budget=2))
        start = time.perf_counter()
        run_study("transfer", frame, config)
        elapsed = time.perf_counter() - start
    runs = f"{2 * config.groups * config.trials} runs of {config.budget} steps"
    print(f"transfer study ({runs}), {workers} workers: {elapsed:.1f} s")
    print(f"  against the 3 min target: {elapsed / 180:.2f} of the budget")


def one_run(root: Path, budget: int = 40) -> None:
    """Time every update of one ATIKT run next to the scikit-learn reference's."""
    frame = build_features(root).frame
    roles = dataset_roles(root, frame["object_id"].to_list())
    new, old = roles.new, roles.old
    ACTIONS = dataset_actions(frame)
    priors_ids = prior_groups(old, 3, 1, seed=0)[0]
    lookup = FeatureLookup(frame)
    priors = fit_priors(prior_data(lookup, priors_ids, ACTIONS), seed=0)
    split = Split.random(frame, new, ACTIONS, seed=0)
    executor = PoolExecutor(lookup, new, split)
    learner = TimedLearner(
        ACTIONS,
        len(new),
        observe=executor,
        capacity=executor.capacity,
        priors=priors,
        budget=budget,
        random_state=0,
        reference=sklearn_old_models(priors),
    )
    learner.initialise()
    learner.record = True
    while not learner.done:
        learner.step()
    learner.compare()
    ours, theirs = sum(learner.ours), sum(learner.theirs)
    print(f"one ATIKT run on the dataset ({len(learner.ours)} updates):")
    for name, times in (("atikt       ", learner.ours), ("scikit-learn", learner.theirs)):
        median = statistics.median(times) * 1e3
        print(f"  {name} total {sum(times):.2f} s, median update {median:.1f} ms")
    print(f"  speed ratio {theirs / ours:.1f}x")
    print_quality(learner)


def quick() -> None:
    """Run every part on the committed recordings, reduced to a few steps, on one process."""
    with tempfile.TemporaryDirectory() as scratch:
        extraction(small_dataset(Path(scratch)), 1, one_worker=False)
    study(RECORDINGS, 1, quick=True)
    one_run(RECORDINGS, budget=2)


def main() -> None:
    """Parse options and run the measurements."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--skip-study", action="store_true")
    parser.add_argument("--skip-one-worker", action="store_true")
    parser.add_argument(
        "--quick", action="store_true", help="tiny parts of the committed recordings (a check)"
    )
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    if args.quick:
        quick()
        return
    root = ensure_default_dataset(workers=args.workers)
    print(f"dataset: {root}")
    extraction(root, args.workers, one_worker=not args.skip_one_worker)
    if not args.skip_study:
        study(root, args.workers)
    one_run(root)


if __name__ == "__main__":
    main()
