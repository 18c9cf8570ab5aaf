"""Known objects learned as new from one observation: does transfer help them? (A predictor?)

The question behind a transfer gate: can a dataset's known objects tell whether borrowing
observations from the first observation of a new object helps *this* dataset? Per action,
``--repeats`` random splits of the known objects into pseudo-new objects (as many as the
dataset's new ones, leaving at least two) and pseudo-priors (the rest, their one-vs-all models
searched on them alone); one random observation per pseudo-new object; the learner's initial
fit with observations borrowed from the first (``transfer_from=1``, the thesis) and without
(``transfer_from=2``; the old objects' kernel is used by both); accuracy on the pseudo-new
objects' other observations (at most 20 each). Prints per action the mean paired difference
and its standard error, to set beside the single-action study's "gain after 1 observation"
of the same dataset (what the gate would have had to predict)::

    python tests/bench/held_out_check.py --recordings DIR [--repeats 8]

``--quick``: the committed recordings, one split per action (a check that it runs).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's packages

from atikt import ActiveLearner, LearnerOptions, PriorModel, RawFeatures, fit_prior_model
from replay.learning._datasets import dataset_roles
from replay.learning._executors import FeatureLookup
from replay.learning._features import build_features
from replay.learning._session import DEFAULT_LEARNER, fit_priors, prior_data
from replay.studies._running import dataset_actions

if TYPE_CHECKING:
    from collections.abc import Callable

MAX_TEST = 20


def split_differences(
    prior: PriorModel,
    action: str,
    n_new: int,
    options: LearnerOptions,
    *,
    repeats: int,
    seed: int,
) -> np.ndarray:
    """Per split: accuracy borrowing from the first observation minus from the second."""
    groups = prior.by_object()
    objects = sorted(groups)
    m = min(n_new, len(objects) - 2)
    if m < 2:
        return np.zeros(0)
    rng = np.random.default_rng(seed)
    differences = []
    for _ in range(repeats):
        chosen = sorted(int(o) for o in rng.choice(objects, m, replace=False))
        pseudo = fit_prior_model(
            {o: groups[o] for o in objects if o not in chosen},
            amplitude=options.amplitude,
            n_thermal_components=options.n_thermal_components,
            n_restarts=0,
            parts=options.parts,
            random_state=int(rng.integers(2**31)),
        )
        first = [int(rng.integers(len(groups[o]))) for o in chosen]
        train = [groups[o][i] for o, i in zip(chosen, first, strict=True)]
        test: list[RawFeatures] = []
        labels: list[int] = []
        for index, (o, i) in enumerate(zip(chosen, first, strict=True)):
            others = [obs for j, obs in enumerate(groups[o]) if j != i][:MAX_TEST]
            test += others
            labels += [index] * len(others)
        seed_r = int(rng.integers(2**31))
        scores = []
        for start in (1, 2):
            learner = ActiveLearner(
                [action],
                m,
                observe=_observer(train),
                priors={action: pseudo},
                options=options.replace(budget=0, transfer_from=start),
                random_state=seed_r,
            )
            learner.initialise()
            scores.append(learner.score({action: (test, labels)}))
        differences.append(scores[0] - scores[1])
    return np.asarray(differences)


def _observer(train: list[RawFeatures]) -> Callable[[int, str], RawFeatures]:
    """Each pseudo-new object's one training observation, whatever the action."""
    return lambda obj, _action: train[obj]


def main(argv: list[str] | None = None) -> int:
    """Print the check of every action of a dataset."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recordings", type=Path, help="the dataset (required unless --quick)")
    parser.add_argument("--repeats", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--all-known", action="store_true", help="every object counts as known (small datasets)"
    )
    parser.add_argument("--quick", action="store_true", help="committed recordings, one split")
    args = parser.parse_args(argv)
    if args.quick:
        from _quick import RECORDINGS  # noqa: PLC0415

        args.recordings, args.repeats, args.all_known = RECORDINGS, 1, True
    if args.recordings is None:
        parser.error("--recordings is required (unless --quick)")
    frame = build_features(args.recordings, workers=1).frame
    roles = dataset_roles(args.recordings, frame["object_id"].to_list(), None, None)
    actions = dataset_actions(frame)
    known = tuple(sorted({*roles.old, *roles.new})) if args.all_known else roles.old
    n_new = 2 if args.all_known else len(roles.new)
    data = prior_data(FeatureLookup(frame, "thesis"), known, actions)
    models = fit_priors(data, args.seed, DEFAULT_LEARNER)
    print(f"{args.recordings}: {len(known)} known objects, {n_new} new")
    for action in actions:
        start = time.perf_counter()
        d = 100 * split_differences(
            models[action],
            action,
            n_new,
            DEFAULT_LEARNER,
            repeats=args.repeats,
            seed=args.seed,
        )
        if d.size == 0:
            print(f"{action}: too few known objects to split")
            continue
        se = d.std(ddof=1) / np.sqrt(d.size) if d.size > 1 else float("nan")
        print(
            f"{action}: borrowing from the first minus from the second observation "
            f"{d.mean():+.1f} points (standard error {se:.1f}, {d.size} splits, "
            f"{time.perf_counter() - start:.1f} s)"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
