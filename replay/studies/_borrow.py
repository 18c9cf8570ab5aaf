"""Cross-action and cross-rig transfer studies: priors from another action or another rig.

Both compare, one target action at a time and on the same splits and seeds, three learners:

- ``baseline``: no transfer;
- ``within``: the old objects' recordings of the target action itself (the thesis's transfer);
- ``cross-action`` (another action of the same dataset, e.g. P1 for C1) or ``cross-rig``
  (another dataset's action, e.g. a skin's static contact for a heated probe's press): the old
  objects' recordings of the source action, through the feature blocks the target action uses
  (``atikt.shared_observations``). Relatedness decides, as for ``within``, what is transferred.

Gains are paired per prior group (the unit of the bootstrap, see ``_stats``).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Final

import polars as pl

from replay.errors import ReplayError
from replay.learning._executors import FeatureLookup
from replay.learning._session import (
    DEFAULT_LEARNER,
    RunSpec,
    borrow_pairs,
    fit_priors,
    prior_data,
    run_offline,
)
from replay.studies._report import Comparisons, Curves, Headlines, Report
from replay.studies._running import (
    BASELINE,
    Study,
    derive_seed,
    min_old,
    prior_groups,
    roles,
    rows,
    too_small,
)

if TYPE_CHECKING:
    from collections.abc import Sequence

    from atikt import LearnerOptions, PriorModel
    from replay.studies._running import StudyConfig

WITHIN, CROSS_ACTION, CROSS_RIG = "within", "cross-action", "cross-rig"
#: Target action <- source action of the cross-action study (the feature blocks the target
#: uses, same definition): stiffness and thermal from a press for a static contact, a press of
#: another force, and back; texture and thermal from one slide for another.
CROSS_ACTION_PAIRS: Final = (("C1", "P1"), ("P2", "P1"), ("P1", "C1"), ("S3", "S1"))


@dataclass(frozen=True, slots=True, kw_only=True)
class BorrowTask:
    """The runs of one prior group: baseline, within-action and borrowed priors.

    Attributes:
        frame: The feature table of the dataset learned.
        new: New object ids.
        within: Old object ids of the dataset learned (empty: no ``within`` runs).
        borrowed: Old object ids of the source (``source_frame``, else ``frame``).
        source_frame: The other rig's feature table (cross-rig), None for cross-action.
        pairs: (target action, source action) pairs, each run separately.
        trials: Runs per pair.
        seed: Seed of the group's splits and learners.
        method: ``cross-action`` or ``cross-rig`` (the borrowed runs' label).
        labels: Extra columns of every row.
        learner: The transferring runs' options; the baseline's are the same without transfer.
        features: Feature policy.
    """

    frame: pl.DataFrame
    new: tuple[str, ...]
    within: tuple[str, ...]
    borrowed: tuple[str, ...]
    source_frame: pl.DataFrame | None
    pairs: tuple[tuple[str, str], ...]
    trials: int
    seed: int
    method: str
    labels: dict[str, Any] = field(default_factory=dict)
    learner: LearnerOptions = DEFAULT_LEARNER
    features: str = "thesis"


def _models(task: BorrowTask, lookup: FeatureLookup) -> dict[str, dict[str, PriorModel]]:
    """The prior models of each method that has priors: method -> target action -> model."""
    targets = tuple(t for t, _ in task.pairs)
    features = task.features
    source = None if task.source_frame is None else FeatureLookup(task.source_frame, features)
    seed = derive_seed(task.seed, "prior")
    models = {}
    if task.within:
        within = prior_data(lookup, task.within, targets)
        models[WITHIN] = fit_priors(within, seed, task.learner)
    data = prior_data(lookup, task.borrowed, targets, source=source, borrow=dict(task.pairs))
    models[task.method] = fit_priors(data, seed, task.learner)
    return models


def run_borrow_task(task: BorrowTask) -> pl.DataFrame:
    """Run the baseline, ``within`` and the borrowed priors on the same splits."""
    lookup = FeatureLookup(task.frame, task.features)
    models = _models(task, lookup)
    names = {
        WITHIN: task.within,
        task.method: task.borrowed if task.source_frame is None else _rig(task.borrowed),
    }
    frames = []
    for (target, origin), trial in itertools.product(task.pairs, range(task.trials)):
        for method in (BASELINE, *models):
            if method != BASELINE and target not in models[method]:
                continue  # the source has no action for this target
            spec = RunSpec(
                new_objects=task.new,
                prior_objects=names.get(method, ()),
                actions=(target,),
                learner=task.learner,
                seed=derive_seed(task.seed, trial, target),
                features=task.features,
            )
            spec = spec.baseline() if method == BASELINE else spec
            priors = models.get(method)
            result = run_offline(task.frame, spec, priors=priors, lookup=lookup)
            labels = task.labels | {"method": method, "trial": trial, "actions": target}
            labels |= {"source": origin, "priors": ",".join(spec.prior_objects)}
            frames.append(rows(result.frame(), labels))
    return pl.concat(frames, how="diagonal_relaxed")


def _rig(objects: Sequence[str]) -> tuple[str, ...]:
    """The other rig's objects as prior names (never equal to a new object's id)."""
    return tuple(f"rig:{o}" for o in objects)


def cross_action_tasks(frame: pl.DataFrame, config: StudyConfig) -> list[BorrowTask]:
    """Tasks of the cross-action study: one per prior group of the dataset's old objects.

    The pairs are ``config.prior_actions`` if given, else :data:`CROSS_ACTION_PAIRS`, kept
    where both actions are in the study and the source has every block the target uses.

    Raises:
        ReplayError: No pair fits, or too few objects.
    """
    actions = roles(config, "cross-action")
    lookup = FeatureLookup(frame, config.features)
    wanted = config.prior_actions or CROSS_ACTION_PAIRS
    pairs = tuple(
        (t, s)
        for t, s in wanted
        if t in actions and s in lookup.blocks and set(lookup.blocks[t]) <= set(lookup.blocks[s])
    )
    if not pairs:
        has = f"actions {', '.join(actions)}"
        needs = "a target and a source action with the same feature blocks (--prior-actions T=S)"
        study = "cross-action"
        raise too_small(study, has, needs)
    size = min(config.group_size, len(config.old))
    groups = prior_groups(config.old, size, config.groups, config.seed)
    return [
        BorrowTask(
            frame=frame,
            new=config.new,
            within=group,
            borrowed=group,
            source_frame=None,
            pairs=pairs,
            trials=config.trials,
            seed=derive_seed(config.seed, "cross-action", number),
            method=CROSS_ACTION,
            labels={"group": number},
            learner=config.learner,
            features=config.features,
        )
        for number, group in enumerate(groups)
    ]


def cross_rig_tasks(frame: pl.DataFrame, config: StudyConfig) -> list[BorrowTask]:
    """Tasks of the cross-rig study: groups of the other rig's objects as priors.

    Each group of ``config.group_size`` objects of ``--prior-recordings`` (random, by seed)
    is paired with a group of the dataset's own old objects (``within``; none when it has too
    few for the transfer mode). Target actions borrow the other rig's action of the same id,
    else of the same kind with the blocks they use (``borrow_pairs``), or as named.

    Raises:
        ReplayError: No other dataset, no shared action, or too few objects.
    """
    if config.prior_frame is None:
        msg = "study cross-rig: give the other rig's dataset with --prior-recordings DIR"
        raise ReplayError(msg)
    if len(config.new) < 2 or not config.actions:  # noqa: PLR2004
        study, has = "cross-rig", f"{len(config.new)} new objects"
        raise too_small(study, has, ">= 2 new objects")
    lookup = FeatureLookup(frame, config.features)
    source = FeatureLookup(config.prior_frame, config.features)
    pairs = tuple(
        (t, s)
        for t, s in sorted(borrow_pairs(lookup, source, dict(config.prior_actions)).items())
        if t in config.actions
    )
    others = sorted(set(config.prior_frame["object_id"].to_list()))
    if not pairs or len(others) < min_old(config):
        has = f"{len(pairs)} shared actions, {len(others)} objects in --prior-recordings"
        study, needs = "cross-rig", f">= 1 shared action and {min_old(config)} objects"
        raise too_small(study, has, needs)
    size = min(config.group_size, len(others))
    groups = prior_groups(others, size, config.groups, config.seed)
    within: list[tuple[str, ...]] = [()]
    if len(config.old) >= min_old(config):
        own = min(config.group_size, len(config.old))
        within = prior_groups(config.old, own, config.groups, config.seed)
    return [
        BorrowTask(
            frame=frame,
            new=config.new,
            within=within[number % len(within)],
            borrowed=group,
            source_frame=config.prior_frame,
            pairs=pairs,
            trials=config.trials,
            seed=derive_seed(config.seed, "cross-rig", number),
            method=CROSS_RIG,
            labels={"group": number},
            learner=config.learner,
            features=config.features,
        )
        for number, group in enumerate(groups)
    ]


def _borrowed(frame: pl.DataFrame) -> str:
    """Return the label of the results' borrowed runs (``cross-rig`` or ``cross-action``)."""
    return CROSS_RIG if CROSS_RIG in set(frame["method"].to_list()) else CROSS_ACTION


def _comparisons(frame: pl.DataFrame) -> list[tuple[str, str]]:
    """Return the (treated, reference) pairs of the summary's table of differences."""
    borrowed = _borrowed(frame)
    return [(borrowed, BASELINE), (WITHIN, BASELINE), (borrowed, WITHIN)]


def _learners(frame: pl.DataFrame, config: StudyConfig) -> str:
    """Return the summary's sentence on the three learners and where the priors come from."""
    borrowed = _borrowed(frame)
    sources = (
        frame.select("actions", "source").unique().sort("actions").iter_rows()
        if "source" in frame.columns
        else []
    )
    pairs = ", ".join(f"{t} <- {s}" for t, s in sources)
    runs = frame.filter((pl.col("step") == 0) & (pl.col("method") == BASELINE)).height
    source = (
        f"the old objects' recordings of another rig (`--prior-recordings`, {pairs})"
        if borrowed == CROSS_RIG
        else f"the old objects' recordings of another action ({pairs})"
    )
    return (
        f"One target action at a time; {runs} runs of each learner on the same splits and "
        f"seeds, budget {config.budget}: no transfer (`{BASELINE}`), the target action's own "
        f"priors (`{WITHIN}`), and {source} (`{borrowed}`), fed through the feature blocks the "
        "target action uses."
    )


_LABELS: Final = ("actions", "method", "group", "trial", "step")
_REPORT: Final = Report(
    (_learners, Headlines(("actions", "method")), Comparisons(("actions",), _comparisons)),
    Curves(panel="actions"),
)
CROSS_ACTION_STUDY: Final = Study(
    name=CROSS_ACTION,
    title="Cross-action transfer: priors from another action",
    tasks=cross_action_tasks,
    run=run_borrow_task,
    labels=_LABELS,
    report=_REPORT,
)
CROSS_RIG_STUDY: Final = Study(
    name=CROSS_RIG,
    title="Cross-rig transfer: priors from another rig's recordings",
    tasks=cross_rig_tasks,
    run=run_borrow_task,
    labels=_LABELS,
    report=_REPORT,
    needs_prior_frame=True,
)
