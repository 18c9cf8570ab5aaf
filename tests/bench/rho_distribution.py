"""Relatedness from few observations: rho of related and of dissimilar priors at 1, 2, 5.

For one dataset, the prior group most similar to the new objects and the least similar one
(``replay.studies._relatedness``, as the negative-transfer study chooses them) are fitted as
the learner fits priors; every new object's first ``n`` recordings of every action (n = 1, 2,
5, in trial order) are scored by the model prediction approach (mean one-vs-all probability,
the best old object admitted at ``eps_neg1``). Printed per group and ``n``: the share of
(new object, action) pairs admitted, and rho's median and 10-90 % range over all pairs (0 where
not admitted), for the thesis's rule and with ``held_out_quantile`` (the threshold calibrated on
the old objects left out one at a time).

Run: ``python tests/bench/rho_distribution.py [--recordings DIR] [--quantile 0.9]``
(default: the simulated dataset).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from atikt import transfer_strategy
from atikt.strategies import ObjectFit
from replay.learning._datasets import dataset_roles
from replay.learning._executors import FeatureLookup
from replay.learning._features import build_features
from replay.learning._session import DEFAULT_LEARNER, fit_priors, prior_data
from replay.live._default import ensure_default_dataset
from replay.studies._negative import similarity_tasks
from replay.studies._running import StudyConfig

if TYPE_CHECKING:
    import polars as pl

COUNTS = (1, 2, 5)


def rho_table(
    frame: pl.DataFrame, new: tuple[str, ...], priors: tuple[str, ...], quantile: float
) -> dict[str, dict[int, np.ndarray]]:
    """rho per (new object, action) at every count, by rule (``thesis``, ``calibrated``)."""
    actions = sorted(set(frame["action_id"].to_list()))
    lookup = FeatureLookup(frame, "thesis")
    models = fit_priors(prior_data(lookup, priors, actions), 0)
    rules = {
        "thesis": transfer_strategy("prediction"),
        "calibrated": transfer_strategy("prediction", held_out_quantile=quantile),
    }
    out: dict[str, dict[int, list[float]]] = {r: {n: [] for n in COUNTS} for r in rules}
    for action, model in models.items():
        assert model.model is not None
        for obj in new:
            trials = lookup.trials(obj, action)
            observations = [lookup.get(obj, action, t) for t in trials]
            if not observations:
                continue
            scores = model.model.predict_binary(model.transformer.transform(observations))
            for n in COUNTS:
                if scores.shape[0] < n:
                    continue
                fit: Any = ObjectFit(None, None, None, model, {}, related=scores[:n])  # type: ignore[arg-type]
                for name, rule in rules.items():
                    out[name][n].append(rule.choose(fit).rho)
    return {r: {n: np.array(v) for n, v in per.items()} for r, per in out.items()}


def main(argv: list[str] | None = None) -> int:
    """Print the table for one dataset."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recordings", type=Path, default=None)
    parser.add_argument(
        "--quick", action="store_true", help="the committed recordings, a few steps (tests)"
    )
    parser.add_argument("--quantile", type=float, default=0.9)
    args = parser.parse_args(argv)
    if args.quick:
        args.recordings = (
            args.recordings or Path(__file__).resolve().parents[2] / "recordings" / "data"
        )
    root = args.recordings or ensure_default_dataset()
    frame = build_features(root).frame
    roles = dataset_roles(root, sorted(set(frame["object_id"].to_list())))
    config = StudyConfig(
        out=Path("unused"),
        groups=1,
        trials=1,
        learner=DEFAULT_LEARNER,
        new=roles.new,
        old=roles.old,
        actions=tuple(sorted(set(frame["action_id"].to_list()))),
    )
    print(f"dataset {root}: new {', '.join(roles.new)}")
    for label, nearest in (("related", True), ("dissimilar", False)):
        priors = similarity_tasks(frame, config, "negative", nearest=nearest)[0].priors
        table = rho_table(frame, roles.new, priors, args.quantile)
        for rule, per in table.items():
            for n, rho in per.items():
                admitted = rho[rho > 0]
                spread = (
                    f"rho of admitted median {np.median(admitted):.2f}, 10-90 % "
                    f"{np.quantile(admitted, 0.1):.2f}-{np.quantile(admitted, 0.9):.2f}"
                    if admitted.size
                    else "none admitted"
                )
                print(
                    f"{label:10s} priors ({', '.join(priors)}), {rule:10s} n={n}: admitted "
                    f"{admitted.size}/{rho.size} ({admitted.size / max(rho.size, 1):.0%}); {spread}"
                )
    return 0


if __name__ == "__main__":
    sys.exit(main())
