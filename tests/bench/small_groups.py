"""The learner's classifier against scikit-learn's on small groups of objects, few samples each.

For one dataset and every action: random groups of ``--objects`` objects (5), ``n`` training
recordings per object (1, 2, 5, 10; the rest are the test set), repeated over groups and
splits. Three classifiers on the same splits:

- ``atikt``: the learner's one-vs-all GP classifier without transfer (its features: the
  action's modality blocks standardised, thermal PCA; its multi-modal kernel with signal
  variance; a hyperprior of sd 5 around the initial kernel, as the replay tool's learners);
- ``sklearn-own``: scikit-learn's ``GaussianProcessClassifier`` (``1.0 * RBF(1.0)``, one-vs-rest,
  L-BFGS-B with 2 restarts) on the same features;
- ``sklearn-simple``: the same on simple features: every raw feature block concatenated and
  standardised on the training set (no PCA, no per-modality kernel);
- ``atikt-others``: the fusion study's default learner (``--fusion-prior others``): the
  multi-modal classifier whose kernel starts at, and is held (sd 0.5) near, the
  hyperparameters fitted on the dataset's objects outside the group (the multi-modal
  classifier without a prior where fewer than two are left).

With ``--breakdown`` more, to tell the features from the classifier and the hyperparameter
search: ``atikt-simple`` (the learner's classifier on the simple features, one block), the
nearest neighbour on each feature set (``1nn-own``, ``1nn-simple``), and three ways of sharing
the hyperparameters of the learner's one-vs-all classifiers: ``atikt-shared`` (one set for all
classes, the sum of their evidences, hyperprior sd 5 as ``atikt``), ``atikt-shared-ml`` (the
same by maximum likelihood) and ``atikt-hier`` (each class its own, with a hyperprior of sd 1
around ``atikt-shared``'s).

Printed per training size: mean test accuracy of each and the paired differences of each of
the learner's two forms minus each reference, with a 95 % percentile bootstrap interval over
groups.

Run: ``python tests/bench/small_groups.py [--recordings DIR] [--groups 10] [--splits 2]``.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from sklearn.gaussian_process import GaussianProcessClassifier
from sklearn.gaussian_process.kernels import RBF, ConstantKernel
from sklearn.preprocessing import StandardScaler

from atikt import FeatureTransformer, MultiModalGPC, OneVsAllGPC, modality_kernel
from atikt.features import stack_features
from replay.learning._executors import FeatureLookup
from replay.learning._features import build_features
from replay.live._default import ensure_default_dataset
from replay.studies._fusion_prior import REFERENCE_PRIOR_SD, reference_theta

SIZES = (1, 2, 5, 10)
METHODS = ("atikt", "sklearn-own", "sklearn-simple", "atikt-others")
BREAKDOWN = (
    "atikt-simple",
    "atikt-shared",
    "atikt-shared-ml",
    "atikt-hier",
    "1nn-own",
    "1nn-simple",
)


def _simple(observations: list[Any]) -> np.ndarray:
    """Every raw block of the observations concatenated, shape (n, d)."""
    stacked = stack_features(observations)
    return np.hstack([stacked.blocks[m] for m in sorted(stacked.blocks)])


def _sklearn(X: np.ndarray, y: np.ndarray, Xt: np.ndarray, seed: int) -> np.ndarray:
    """scikit-learn's GPC prediction (one-vs-rest, RBF with a signal variance)."""
    model = GaussianProcessClassifier(
        ConstantKernel(1.0) * RBF(1.0), n_restarts_optimizer=2, random_state=seed
    )
    return np.asarray(model.fit(X, y).predict(Xt))


def accuracies(
    observations: dict[str, list[Any]],
    n: int,
    rng: np.random.Generator,
    seed: int,
    reference: np.ndarray | None = None,
    *,
    breakdown: bool = False,
) -> dict[str, float] | None:
    """Test accuracy of each method on one split with ``n`` training recordings per object."""
    train, test, ytr, yte = [], [], [], []
    for label, obs in enumerate(observations.values()):
        if len(obs) <= n:
            return None
        order = rng.permutation(len(obs))
        train += [obs[i] for i in order[:n]]
        test += [obs[i] for i in order[n:]]
        ytr += [label] * n
        yte += [label] * (len(obs) - n)
    y, yt = np.array(ytr), np.array(yte)
    transformer = FeatureTransformer()
    X = transformer.fit_transform(train)
    Xt = transformer.transform(test)
    ours = OneVsAllGPC(
        modality_kernel(transformer.slices_), n_restarts=1, prior_sd=5.0, random_state=seed
    ).fit(X, y)
    others = MultiModalGPC(
        random_state=seed,
        initial_theta=reference,
        prior_sd=None if reference is None else REFERENCE_PRIOR_SD,
    )
    scaler = StandardScaler().fit(_simple(train))
    S, St = scaler.transform(_simple(train)), scaler.transform(_simple(test))
    out = {
        "atikt": float(np.mean(ours.predict(Xt) == yt)),
        "sklearn-own": float(np.mean(_sklearn(X, y, Xt, seed) == yt)),
        "sklearn-simple": float(np.mean(_sklearn(S, y, St, seed) == yt)),
        "atikt-others": float(np.mean(others.fit(train, y).predict(test) == yt)),
    }
    if breakdown:
        width = np.sqrt(S.shape[1])  # the learner's blocks have unit total variance
        one = OneVsAllGPC(
            modality_kernel({"all": slice(0, S.shape[1])}),
            n_restarts=1,
            prior_sd=5.0,
            random_state=seed,
        ).fit(S / width, y)
        out["atikt-simple"] = float(np.mean(one.predict(St / width) == yt))
        shared = OneVsAllGPC(
            modality_kernel(transformer.slices_),
            n_restarts=1,
            prior_sd=5.0,
            random_state=seed,
            shared=True,
        ).fit(X, y)
        out["atikt-shared"] = float(np.mean(shared.predict(Xt) == yt))
        ml = OneVsAllGPC(
            modality_kernel(transformer.slices_), n_restarts=1, random_state=seed, shared=True
        ).fit(X, y)
        out["atikt-shared-ml"] = float(np.mean(ml.predict(Xt) == yt))
        centre = shared.estimators_[0].kernel_
        hier = OneVsAllGPC(centre, n_restarts=0, prior_sd=1.0, random_state=seed).fit(X, y)
        out["atikt-hier"] = float(np.mean(hier.predict(Xt) == yt))
        out["1nn-own"] = float(np.mean(_nearest(X, y, Xt) == yt))
        out["1nn-simple"] = float(np.mean(_nearest(S, y, St) == yt))
    return out


def _nearest(X: np.ndarray, y: np.ndarray, Xt: np.ndarray) -> np.ndarray:
    """The label of each test row's nearest training row (Euclidean)."""
    return np.asarray(y[np.argmin(((Xt[:, None, :] - X[None]) ** 2).sum(axis=-1), axis=1)])


def _interval(values: np.ndarray, rng: np.random.Generator) -> str:
    """Mean and 95 % percentile bootstrap interval, in points."""
    means = values[rng.integers(0, values.size, (4000, values.size))].mean(axis=1)
    low, high = np.quantile(means, [0.025, 0.975])
    return f"{100 * values.mean():+.1f} [{100 * low:+.1f}, {100 * high:+.1f}]"


def _arguments(argv: list[str] | None) -> argparse.Namespace:
    """Parse the command line (``--quick``: one small group of the committed recordings)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recordings", type=Path, default=None)
    parser.add_argument(
        "--quick", action="store_true", help="the committed recordings, a few steps (tests)"
    )
    parser.add_argument("--objects", type=int, default=5)
    parser.add_argument("--groups", type=int, default=10)
    parser.add_argument("--splits", type=int, default=2)
    parser.add_argument("--sizes", default=",".join(map(str, SIZES)))
    parser.add_argument("--breakdown", action="store_true", help="three more methods (see above)")
    args = parser.parse_args(argv)
    if args.quick:
        args.recordings = (
            args.recordings or Path(__file__).resolve().parents[2] / "recordings" / "data"
        )
    if args.quick:  # one small group, one size, every method
        args.groups, args.splits, args.sizes, args.objects = 1, 1, "1", 3
        args.breakdown = True
    return args


def main(argv: list[str] | None = None) -> int:
    """Print the comparison for one dataset."""
    args = _arguments(argv)
    warnings.simplefilter("ignore")
    root = args.recordings or ensure_default_dataset()
    lookup = FeatureLookup(build_features(root).frame, "thesis")
    actions = sorted({a for (_, a) in lookup._trials})
    print(f"dataset {root}; groups of {args.objects} objects; actions {', '.join(actions)}")
    for n in (int(v) for v in args.sizes.split(",")):
        methods = METHODS + (BREAKDOWN if args.breakdown else ())
        per_group: dict[str, list[float]] = {m: [] for m in methods}
        for group in range(args.groups):
            rng = np.random.default_rng([group, n])
            scores: dict[str, list[float]] = {m: [] for m in methods}
            for action in actions:
                objects = lookup.objects(action)
                chosen = sorted(rng.choice(objects, min(args.objects, len(objects)), replace=False))
                observations = {
                    o: [lookup.get(o, action, t) for t in lookup.trials(o, action)] for o in chosen
                }
                for split in range(args.splits):
                    seed = group * 100 + split
                    reference = reference_theta(lookup, action, chosen, seed)
                    result = accuracies(
                        observations, n, rng, seed, reference, breakdown=args.breakdown
                    )
                    if result is not None:
                        for m in methods:
                            scores[m].append(result[m])
            if scores["atikt"]:
                for m in methods:
                    per_group[m].append(float(np.mean(scores[m])))
        if not per_group["atikt"]:
            print(f"n={n}: too few recordings per object")
            continue
        values = {m: np.array(v) for m, v in per_group.items()}
        rng = np.random.default_rng(n)
        means = ", ".join(f"{m} {values[m].mean():.3f}" for m in methods)
        diffs = "; ".join(
            f"{ours} - {m} {_interval(values[ours] - values[m], rng)}"
            for ours in ("atikt", "atikt-others")
            for m in ("sklearn-own", "sklearn-simple")
        )
        print(f"n={n} per object ({values['atikt'].size} groups): {means}; {diffs} points")
    return 0


if __name__ == "__main__":
    sys.exit(main())
