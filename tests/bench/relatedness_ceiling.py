"""How often can a relatedness score single out a new object's designed counterpart at all?

Every new object of the simulated catalog names the old object it resembles (``related_to`` in
recorder/data/objects.toml). This measures, outside the active loop, whether that counterpart
is the old object a relatedness score ranks first, per action, from m = 1, 2, 5 observations
of every new object, for random groups of 3, 5 and 10 prior objects (the priors study's
groups). Scores of each old object o, from its prior observations in the prior model's
feature space:

- ``prediction``: the thesis's model prediction, mean one-vs-all probability of o;
- ``tail``: the open-set score of ``transfer="density"``, mean chi-square tail probability
  under o's diagonal Gaussian;
- ``loglik``: summed Gaussian log density under o (nearest object in likelihood);
- ``evidence``: the dependent GP's evidence gain, ``log p(y_new | y_o; rho) - log p(y_new)``
  (Laplace approximation; the new object-vs-rest classifier's hyperparameters fitted without
  transfer, rho fixed): how much o's observations, as positives, make the new labels more
  probable.

Printed per score and m: the share of cases where the counterpart (among the priors) is ranked
first, and, for scores with a natural "transfer" decision (prediction >= 0.6, tail >= 0.1,
evidence > 0), how often something is transferred with the counterpart present and absent.
The counterpart hit rate of the nearest object (``loglik``) bounds what any score of feature
similarity can reach on this dataset.

Run: ``python tests/bench/relatedness_ceiling.py [--groups 3] [--reps 2] [--rho 0.9]``
(about 2 minutes on one core); ``--quick``: one group of 3 priors and m = 1 on the committed
recordings (a check that the script runs).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import sys
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's packages

from atikt.gpc import BinaryGPC
from atikt.kernels import DependentKernel, modality_kernel
from atikt.transfer import _stack_domains
from replay.learning._executors import FeatureLookup
from replay.learning._session import fit_priors, prior_data
from replay.studies._running import prior_groups

ROOT = Path(__file__).resolve().parents[2]
SIM = Path.home() / ".cache/atikt/sim2-seed0-schema2-v0.2.0/features.parquet"
THRESHOLDS = {"prediction": 0.6, "tail": 0.1, "evidence": 0.0}


def counterparts() -> dict[str, str]:
    """New object id -> its designed counterpart among the old objects."""
    with (ROOT / "recorder/data/objects.toml").open("rb") as handle:
        catalog = tomllib.load(handle)
    return {
        k: v["related_to"] for k, v in catalog.items() if isinstance(v, dict) and "related_to" in v
    }


def evidence_gains(Xn: Any, y: Any, aux: dict[int, Any], slices: Any, rho: float) -> Any:
    """Evidence gain of each old object for one new object's one-vs-rest labels."""
    base = BinaryGPC(modality_kernel(slices), n_restarts=0, max_iter=50, random_state=0)
    base.fit(Xn, y)
    kernel = base.kernel_
    alone = float(base.log_marginal_likelihood())  # type: ignore[arg-type]
    gains = []
    for obs in aux.values():
        positives = np.ones(obs.shape[0])
        own = BinaryGPC(kernel, optimize=False).fit(obs, positives).log_marginal_likelihood()
        joint = BinaryGPC(DependentKernel(kernel, rho), optimize=False)
        both = joint.fit(_stack_domains(obs, Xn), np.concatenate([positives, y]))
        gains.append(float(both.log_marginal_likelihood()) - float(own) - alone)  # type: ignore[arg-type]
    return np.array(gains)


def measure(args: argparse.Namespace) -> pl.DataFrame:
    """One row per (group, action, repetition, m, new object, score)."""
    frame = pl.read_parquet(args.features)
    present = set(frame["object_id"].unique().to_list())
    related = {o: c for o, c in counterparts().items() if o in present}
    new = sorted(related)
    old = sorted(present - set(new))
    actions = sorted(frame["action_id"].unique().to_list())
    lookup = FeatureLookup(frame, "thesis")
    rng = np.random.default_rng(args.seed)
    rows = []
    for size in args.sizes:
        for number, group in enumerate(prior_groups(old, size, args.groups, args.seed)):
            models = fit_priors(prior_data(lookup, group, actions), args.seed + number)
            for action in actions:
                prior = models[action]
                assert prior.model is not None  # at least 2 old objects
                assert prior.densities is not None
                transform = prior.transformer.transform
                aux = {
                    o: transform(
                        [
                            x
                            for x, lab in zip(prior.observations, prior.labels, strict=True)
                            if lab == o
                        ]
                    )
                    for o in range(size)
                }
                for rep, m in ((r, m) for r in range(args.reps) for m in args.m):
                    observations, owners = [], []
                    for j, obj in enumerate(new):
                        trials = lookup.trials(obj, action)
                        for i in rng.choice(len(trials), size=m, replace=False):
                            observations.append(lookup.get(obj, action, trials[i]))
                            owners.append(j)
                    Xn, owner = transform(observations), np.array(owners)
                    probability = prior.model.predict_binary(Xn)
                    tail = prior.densities.tail_probabilities(Xn)
                    dens = prior.densities
                    d2 = (((Xn[:, None, :] - dens.means[None]) ** 2) / dens.variances[None]).sum(2)
                    loglik = -0.5 * d2 - 0.5 * np.log(dens.variances).sum(1)[None]
                    for j, obj in enumerate(new):
                        mine = owner == j
                        y = mine.astype(np.float64)
                        scores = {
                            "prediction": probability[mine].mean(0),
                            "tail": tail[mine].mean(0),
                            "loglik": loglik[mine].sum(0),
                            "evidence": evidence_gains(
                                Xn, y, aux, prior.transformer.slices_, args.rho
                            ),
                        }
                        target = group.index(related[obj]) if related[obj] in group else None
                        for score, values in scores.items():
                            best = int(np.argmax(values))
                            rows.append(
                                {
                                    "n_priors": size,
                                    "group": number,
                                    "action": action,
                                    "rep": rep,
                                    "m": m,
                                    "object": obj,
                                    "score": score,
                                    "present": target is not None,
                                    "hit": best == target,
                                    "transfer": bool(values[best] > THRESHOLDS[score])
                                    if score in THRESHOLDS
                                    else None,
                                }
                            )
    return pl.DataFrame(rows)


def main() -> None:
    """Measure and print the tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--features", type=Path, default=SIM)
    parser.add_argument("--groups", type=int, default=3, help="random groups per prior count")
    parser.add_argument("--reps", type=int, default=2, help="draws of the new observations")
    parser.add_argument("--rho", type=float, default=0.9, help="rho of the evidence gain")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--quick", action="store_true", help="one group of 3 priors, m = 1, the committed data"
    )
    args = parser.parse_args()
    args.sizes, args.m = (3, 5, 10), (1, 2, 5)
    if args.quick:
        from _quick import quick_features  # noqa: PLC0415

        args.features, args.groups, args.reps = quick_features(), 1, 1
        args.sizes, args.m = (3,), (1,)
    rows = measure(args)
    pl.Config.set_tbl_rows(200)
    pl.Config.set_tbl_hide_dataframe_shape(True)
    present = rows.filter(pl.col("present"))
    print("counterpart ranked first (counterpart among the priors), by m:")
    print(
        present.group_by("score", "m")
        .agg(pl.col("hit").mean().round(3).alias("hit"), pl.len().alias("cases"))
        .sort("score", "m")
    )
    for column in ("n_priors", "action"):
        print(f"counterpart ranked first, by {column} (all m):")
        table = present.pivot(column, index="score", values="hit", aggregate_function="mean")
        print(table.sort("score"))
    print("something transferred (score passes its threshold), counterpart present / absent:")
    print(
        rows.filter(pl.col("transfer").is_not_null())
        .group_by("score", "m", "present")
        .agg(pl.col("transfer").mean().round(3))
        .pivot("present", index=["score", "m"], values="transfer")
        .sort("score", "m")
    )


if __name__ == "__main__":
    main()
