"""The transfer study (ATIKT vs no transfer, all actions) and its single-action variant.

Each task is one random group of prior objects; ATIKT and the baseline learn the same new
objects on the same splits and seeds, all actions together or one action at a time. The task
(:class:`TransferTask`) is also the priors and negative-transfer studies' task.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import polars as pl

from replay.learning._executors import FeatureLookup
from replay.learning._session import (
    DEFAULT_LEARNER,
    RunSpec,
    fit_priors,
    prior_data,
    run_offline,
)
from replay.studies._report import Curves, Gains, Headlines, Report
from replay.studies._running import (
    ATIKT,
    BASELINE,
    Study,
    derive_seed,
    prior_groups,
    roles,
    rows,
)

if TYPE_CHECKING:
    from atikt import LearnerOptions
    from replay.studies._running import StudyConfig


@dataclass(frozen=True, slots=True, kw_only=True)
class TransferTask:
    """Runs of ATIKT and baseline for one group of prior objects (one parallel task).

    Attributes:
        frame: The feature table (the rows the task needs).
        new: New object ids.
        priors: Prior object ids.
        actions: Action sets, each run separately (one set: all actions together).
        trials: Runs per action set.
        seed: Seed of the group's splits and learners.
        learner: The ATIKT runs' options; the baseline's are the same without transfer.
        labels: Extra columns written into every row (group, prior count, ...).
        features: Feature policy.
    """

    frame: pl.DataFrame
    new: tuple[str, ...]
    priors: tuple[str, ...]
    actions: tuple[tuple[str, ...], ...]
    trials: int
    seed: int
    learner: LearnerOptions = DEFAULT_LEARNER
    labels: dict[str, Any] = field(default_factory=dict)
    features: str = "thesis"


def transfer_task(
    frame: pl.DataFrame,
    config: StudyConfig,
    *,
    priors: tuple[str, ...],
    actions: tuple[tuple[str, ...], ...],
    trials: int,
    seed: int,
    labels: dict[str, Any],
) -> TransferTask:
    """Return a task of the study's new objects with the learner options of ``config``."""
    return TransferTask(
        frame=frame,
        new=config.new,
        priors=priors,
        actions=actions,
        trials=trials,
        seed=seed,
        learner=config.learner,
        labels=labels,
        features=config.features,
    )


def run_transfer_task(task: TransferTask) -> pl.DataFrame:
    """Run ATIKT and the baseline on the same splits; return one row per run and step."""
    lookup = FeatureLookup(task.frame, task.features)
    every_action = tuple(sorted({a for group in task.actions for a in group}))
    data = prior_data(lookup, task.priors, every_action)
    models = fit_priors(data, derive_seed(task.seed, "prior"), task.learner)
    frames = []
    for actions, trial in itertools.product(task.actions, range(task.trials)):
        spec = RunSpec(
            new_objects=task.new,
            prior_objects=task.priors,
            actions=actions,
            learner=task.learner,
            seed=derive_seed(task.seed, trial, *actions),
            features=task.features,
        )
        for method, run in ((ATIKT, spec), (BASELINE, spec.baseline())):
            result = run_offline(task.frame, run, priors=models, lookup=lookup)
            labels = task.labels | {"method": method, "trial": trial}
            labels |= {"actions": ",".join(actions), "priors": ",".join(task.priors)}
            frames.append(rows(result.frame(), labels))
    return pl.concat(frames, how="diagonal_relaxed")


def transfer_tasks(
    frame: pl.DataFrame, config: StudyConfig, *, single_action: bool = False
) -> list[TransferTask]:
    """Return the tasks of the transfer (or single-action) study: one per prior group.

    Groups hold ``config.group_size`` old objects (3 in the thesis), fewer when the dataset
    has fewer old objects.
    """
    actions = roles(config, "single-action" if single_action else "transfer")
    sets = tuple((a,) for a in actions) if single_action else (actions,)
    size = min(config.group_size, len(config.old))
    return [
        transfer_task(
            frame,
            config,
            priors=group,
            actions=sets,
            trials=config.trials,
            seed=derive_seed(config.seed, "transfer", number),
            labels={"group": number},
        )
        for number, group in enumerate(prior_groups(config.old, size, config.groups, config.seed))
    ]


def single_action_tasks(frame: pl.DataFrame, config: StudyConfig) -> list[TransferTask]:
    """Return the tasks of the single-action study: each action of a prior group on its own."""
    return transfer_tasks(frame, config, single_action=True)


def paired_runs(frame: pl.DataFrame, config: StudyConfig) -> str:
    """Return the summary's sentence on the paired runs of all actions together."""
    runs = frame.filter(pl.col("step") == 0).height // 2
    return (
        f"{runs} paired runs ({ATIKT} and {BASELINE} on the same splits), budget "
        f"{config.budget}; test accuracy of all actions together."
    )


def _one_action(frame: pl.DataFrame, config: StudyConfig) -> str:  # noqa: ARG001
    """Return the single-action summary's sentence."""
    return f"One action at a time, {ATIKT} vs {BASELINE}, budget {config.budget}."


TRANSFER = Study(
    name="transfer",
    title="ATIKT vs no transfer, all actions",
    tasks=transfer_tasks,
    run=run_transfer_task,
    labels=("method", "group", "trial", "step"),
    report=Report((paired_runs, Headlines(("method",)), Gains((), "group"))),
)
SINGLE_ACTION = Study(
    name="single-action",
    title="ATIKT vs no transfer, one action at a time",
    tasks=single_action_tasks,
    run=run_transfer_task,
    labels=("actions", "method", "group", "trial", "step"),
    report=Report(
        (_one_action, Gains(("actions",), "group"), Headlines(("actions", "method"))),
        Curves(panel="actions"),
    ),
)
