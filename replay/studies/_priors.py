"""The priors study: ATIKT vs no transfer with 3, 5, 7 and 10 prior objects.

Per prior count, random groups of that many old objects (the counts the dataset allows), each
one :class:`~replay.studies._transfer.TransferTask` of all actions together.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from replay.studies._report import Curves, Gains, Headlines, Report
from replay.studies._running import (
    ATIKT,
    BASELINE,
    Study,
    derive_seed,
    prior_groups,
    roles,
    too_small,
)
from replay.studies._transfer import TransferTask, run_transfer_task, transfer_task

if TYPE_CHECKING:
    import polars as pl

    from replay.studies._running import StudyConfig


def priors_tasks(frame: pl.DataFrame, config: StudyConfig) -> list[TransferTask]:
    """Return the tasks of the priors study: groups of each prior count the dataset allows."""
    actions = roles(config, "priors")
    counts = [c for c in config.prior_counts if c <= len(config.old)]
    if not counts:
        has = f"{len(config.old)} old objects"
        needs = f"at least {min(config.prior_counts)} (prior counts {config.prior_counts})"
        study = "priors"
        raise too_small(study, has, needs)
    tasks = []
    for count in counts:
        for number, group in enumerate(prior_groups(config.old, count, config.groups, config.seed)):
            task = transfer_task(
                frame,
                config,
                priors=group,
                actions=(actions,),
                trials=config.trials,
                seed=derive_seed(config.seed, "priors", count, number),
                labels={"group": number, "n_priors": count},
            )
            tasks.append(task)
    return tasks


def _counts(frame: pl.DataFrame, config: StudyConfig) -> str:  # noqa: ARG001
    """Return the summary's sentence naming the prior counts."""
    counts = ", ".join(str(c) for c in sorted(set(frame["n_priors"].to_list())))
    return f"{ATIKT} vs {BASELINE} with {counts} prior objects."


PRIORS = Study(
    name="priors",
    title="ATIKT vs no transfer with 3, 5, 7, 10 prior objects",
    tasks=priors_tasks,
    run=run_transfer_task,
    labels=("n_priors", "method", "group", "trial", "step"),
    report=Report(
        (_counts, Gains(("n_priors",), "group"), Headlines(("n_priors", "method"))),
        Curves(panel="n_priors"),
    ),
)
