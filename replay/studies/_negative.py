"""The negative-transfer study: ATIKT with the priors least like the new objects.

One prior group, chosen by similarity to the new objects (``_relatedness``), learned
``groups * trials`` times on fresh splits; the repetition is the unit of its intervals.
:func:`similarity_tasks` also gives the most similar group (for benchmarks).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import polars as pl

from replay.studies._relatedness import least_similar, most_similar, similarity_to_new
from replay.studies._report import Gains, Headlines, Report
from replay.studies._running import Study, StudyConfig, derive_seed, roles
from replay.studies._transfer import TransferTask, paired_runs, run_transfer_task, transfer_task
from schemas import VOCABULARY


def negative_tasks(frame: pl.DataFrame, config: StudyConfig) -> list[TransferTask]:
    """Return the tasks of the negative-transfer study: the priors least like the new objects.

    Similarity is each old object's per-action rank by nearness in likelihood to the new
    objects (see ``_relatedness``); the least similar old objects (three, or all if fewer) are
    the priors of every run.
    """
    return similarity_tasks(frame, config, "negative", nearest=False)


def similarity_tasks(
    frame: pl.DataFrame,
    config: StudyConfig,
    study: str,
    *,
    nearest: bool,
    splits_of: str | None = None,
    priors: tuple[str, ...] | None = None,
) -> list[TransferTask]:
    """Return runs of one prior group chosen by similarity to the new objects.

    Args:
        frame: The dataset's feature table.
        config: Study options; ``group_size`` priors, ``groups * trials`` runs.
        study: Name of the study (roles check and seeds).
        nearest: The most similar old objects if true, else the least similar.
        splits_of: The study whose seeds (hence splits of the new objects) the runs take;
            ``study`` when None. The most and the least similar groups run on the same
            splits with one name, so their difference is paired run by run.
        priors: The group where it is known rather than estimated (then ``nearest`` is unused).
    """
    actions = roles(config, study)
    frame = frame.filter(pl.col("object_id").is_in([*config.new, *config.old]))
    if priors is None:
        priors = _similar_group(frame, config, actions, nearest=nearest)
    runs = config.groups * config.trials
    return [
        transfer_task(
            frame,
            config,
            priors=priors,
            actions=(actions,),
            trials=1,
            seed=derive_seed(config.seed, splits_of or study, number),
            labels={"group": 0, "repetition": number},
        )
        for number in range(runs)
    ]


def _similar_group(
    frame: pl.DataFrame, config: StudyConfig, actions: tuple[str, ...], *, nearest: bool
) -> tuple[str, ...]:
    """Return the old objects most (or least) like the new ones, ``group_size`` of them."""
    new, old = config.new, config.old
    objects = [*new, *old]
    per_action = {}
    for action in actions:
        part = frame.filter(pl.col("action_id") == action).sort("path")
        matrix = np.vstack([_flat(row) for row in part.iter_rows(named=True)])
        labels = np.array([objects.index(o) for o in part["object_id"]], dtype=np.int64)
        per_action[action] = (matrix, labels)
    similarity = similarity_to_new(per_action, len(objects), range(len(new)))
    pick = most_similar if nearest else least_similar
    chosen = pick(similarity, range(len(new), len(objects)), min(config.group_size, len(old)))
    return tuple(objects[i] for i in chosen)


def _flat(row: dict[str, Any]) -> np.ndarray[Any, np.dtype[np.float64]]:
    """Return the raw features of a cache row as one vector (for the similarity)."""
    parts = [row[m] for m in VOCABULARY.features if row[m] is not None]
    return np.concatenate([np.asarray(p, dtype=np.float64) for p in parts])


NEGATIVE = Study(
    name="negative",
    title="ATIKT with dissimilar priors (negative transfer)",
    tasks=negative_tasks,
    run=run_transfer_task,
    labels=("method", "repetition", "trial", "step"),
    report=Report((paired_runs, Headlines(("method",)), Gains((), "repetition"))),
)
