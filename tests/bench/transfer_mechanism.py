"""What transfer does to the new objects' classifiers, whatever the source: signal variances.

Runs the ``negative`` (3 least similar priors) and ``related`` (3 most similar) run sets of
``relatedness_candidates.py`` for a few runs, the baseline and ATIKT that always transfers
from the old object of the largest evidence gain (``transfer="evidence"``,
``eps_evidence=-1e9``, ``evidence_rho`` as given), and prints, after the initial round (one
observation per new object and action), the signal variance every new object's classifier
fitted (median, min, max over objects, actions and runs) and the accuracy at step 0.

Run: ``python tests/bench/transfer_mechanism.py [--runs 3] [--rho 0.9]`` (about 20 s);
``--quick``: one run on the committed recordings (a check that the script runs).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import polars as pl

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's packages

import replay.learning._session
from atikt.active import TRANSFER_MODES, ActiveLearner, LearnerOptions
from replay.learning._datasets import dataset_roles
from replay.learning._session import DEFAULT_LEARNER
from replay.studies._negative import similarity_tasks
from replay.studies._running import StudyConfig, dataset_actions
from replay.studies._transfer import run_transfer_task

SIM = Path.home() / ".cache/atikt/sim2-seed0-schema2-v0.2.0/features.parquet"
FITS: list[dict[str, Any]] = []


class Logged(ActiveLearner):
    """The session's learner, recording every classifier's signal variance after an update."""

    settings: dict[str, Any] = {}  # noqa: RUF012 - set per mode before the runs

    def __init__(self, *positional: Any, options: LearnerOptions, **keywords: Any) -> None:
        if options.transfer.name == "evidence":  # the baseline has no evidence options
            options = options.replace(**self.settings)
        super().__init__(*positional, options=options, **keywords)

    def _update(self, action: str, **keywords: Any) -> None:
        super()._update(action, **keywords)
        state = self.states_[action]
        method = "ATIKT" if self.strategy.transfers else "baseline"
        n = len(state.observations)
        FITS.extend(
            {"method": method, "action": action, "n": n, "signal_variance": variance}
            for variance in (float(m.base_kernel_.signal_variance) for m in state.models)  # type: ignore[attr-defined]
        )


def main() -> None:
    """Run and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--features", type=Path, default=SIM)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--rho", type=float, default=0.9)
    parser.add_argument(
        "--quick", action="store_true", help="one run on the committed recordings (a check)"
    )
    args = parser.parse_args()
    if args.quick:
        from _quick import quick_features  # noqa: PLC0415

        args.features, args.runs = quick_features(), 1
    frame = pl.read_parquet(args.features)
    roles = dataset_roles(args.features.parent, sorted(set(frame["object_id"])))
    config = StudyConfig(
        out=Path(),
        groups=1,
        trials=args.runs,
        learner=DEFAULT_LEARNER.replace(budget=1, transfer="evidence"),
        new=roles.new,
        old=roles.old,
        actions=dataset_actions(frame),
    )
    Logged.settings = {"eps_evidence": -1e9, "evidence_rho": args.rho}
    replay.learning._session.TRANSFER_MODES = TRANSFER_MODES
    replay.learning._session.ActiveLearner = Logged  # type: ignore[assignment,attr-defined]
    n_new = len(roles.new)
    rows = []
    for study in ("negative", "related"):
        for task in similarity_tasks(frame, config, study, nearest=study == "related"):
            FITS.clear()
            result = run_transfer_task(replace(task, labels=task.labels | {"study": study}))
            initial = pl.DataFrame(FITS).filter(pl.col("n") == n_new)  # the initial round
            accuracy = result.filter(pl.col("step") == 0).select("method", "accuracy")
            joined = initial.join(accuracy, on="method")
            rows.append(joined.with_columns(pl.lit(study).alias("study")))
    table = pl.concat(rows)
    pl.Config.set_tbl_hide_dataframe_shape(True)
    print(f"signal variance after the initial round (rho {args.rho}), {args.runs} runs each:")
    print(
        table.group_by("study", "method")
        .agg(
            pl.col("signal_variance").median().round(2).alias("median"),
            pl.col("signal_variance").min().round(2).alias("min"),
            pl.col("signal_variance").max().round(2).alias("max"),
            (pl.col("accuracy").mean() * 100).round(1).alias("accuracy step 0, %"),
        )
        .sort("study", "method")
    )


if __name__ == "__main__":
    main()
