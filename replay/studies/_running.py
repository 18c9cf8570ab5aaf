"""What every study shares: its options, what a study is, seeds, role checks and task running.

Every study is a list of independent tasks (a task carries its data and its own seed), run through
:func:`replay.learning._parallel.run_tasks`, so that results are the same bytes for any number of
local workers or a Dask cluster. Results are long-format parquet: one row per run and step, or
per repetition and training size.
"""

from __future__ import annotations

import itertools
import zlib
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
import polars as pl

from replay.errors import ReplayError
from replay.learning._parallel import run_tasks
from replay.learning._session import DEFAULT_LEARNER

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from pathlib import Path

    from atikt import LearnerOptions
    from replay.studies._report import Report

#: Label of the ATIKT runs and of the no-transfer baseline in results.
ATIKT, BASELINE = "ATIKT", "baseline"
#: Training samples per object of the other objects' model (``reference_theta``) and of the
#: saved hyperparameters (``write_hyperparameters``): ``StudyConfig.reference_samples``.
REFERENCE_SAMPLES = 10
#: The same with ``--quick``: the fit on every object of an action is serial and cubic in the
#: samples (10 per object: ~60 s of a 90 s quick fusion study on 2 cores; 3: a few seconds).
QUICK_REFERENCE_SAMPLES = 3


@dataclass(frozen=True, slots=True, kw_only=True)
class StudyConfig:
    """Options shared by every study.

    Attributes:
        out: Directory for results, plots and summary.
        seed: Seed of group selection, splits and learners.
        groups: Random groups of prior objects (transfer, single-action, priors).
        trials: Runs per group.
        workers: Local worker processes.
        scheduler: Dask scheduler address, or None for local processes.
        fusion_groups: Random groups of objects in the fusion study.
        fusion_repetitions: Repetitions per fusion group.
        fusion_objects: Objects per fusion group.
        prior_counts: Prior-object counts of the priors study.
        learner: The ATIKT learners' options (budget, transfer strategy, hyperpriors, metric
            transfer, kernels); the baseline is the same without transfer.
        new: New objects (the dataset's declared ones unless chosen; see ``dataset_roles``).
        old: Old objects, the candidates for priors.
        actions: Actions of the study (every action of the dataset unless chosen).
        features: Feature policy (``thesis`` or ``all``).
        group_size: Prior objects per group in the transfer and single-action studies.
        reduced: A reduced run (``--quick``); its summary says so.
        fusion_prior: ``others``: the multi-modal kernel's hyperparameters get a prior
            centred on those of the other objects of the dataset (``reference_theta``), and
            where fewer than two objects lie outside a group, the modality weights get the
            prior of the sensors' declared noise (``noise``); ``noise``: always that one;
            ``none``: maximum likelihood on the group's samples alone (the thesis); any other
            value is the path of a ``hyperparameters.json`` an earlier fusion study wrote
            (another session or dataset of the same rig), whose hyperparameters centre the
            prior instead (``load_hyperparameters``).
        reference_samples: Trials per object of the fits on other objects and of the saved
            hyperparameters (``REFERENCE_SAMPLES``; ``--quick``: ``QUICK_REFERENCE_SAMPLES``).
        action_parameters: Per action, the names of the parameters it states
            (``action_parameter_names``): an action stating a modality's ``controlled_by``
            (e.g. ``force_n``) sets that modality, whose feature the declared-noise prior
            then counts as uninformative. Empty: none known.
        fusion_kernel: Combination of the per-modality kernels (``atikt.kernels.COMBINATIONS``).
        fusion_parts: Kernel per feature block (``atikt.kernels.PART_KERNELS``; RBF where
            not named), as (block, kernel) pairs.
        prior_frame: The feature table of another rig's dataset (``--prior-recordings``): the
            cross-rig study's priors.
        prior_actions: (target action, source action) pairs of the cross-action and
            cross-rig studies (``--prior-actions``; empty: their defaults).
    """

    out: Path
    seed: int = 0
    groups: int = 10
    trials: int = 5
    workers: int = 1
    scheduler: str | None = None
    fusion_groups: int = 10
    fusion_repetitions: int = 10
    fusion_objects: int = 5
    prior_counts: tuple[int, ...] = (3, 5, 7, 10)
    learner: LearnerOptions = DEFAULT_LEARNER
    new: tuple[str, ...] = ()
    old: tuple[str, ...] = ()
    actions: tuple[str, ...] = ()
    features: str = "thesis"
    group_size: int = 3
    reduced: bool = False
    fusion_prior: str = "others"
    reference_samples: int = REFERENCE_SAMPLES
    action_parameters: tuple[tuple[str, tuple[str, ...]], ...] = ()
    fusion_kernel: str = "sum"
    fusion_parts: tuple[tuple[str, str], ...] = ()
    prior_frame: pl.DataFrame | None = field(default=None, compare=False)
    prior_actions: tuple[tuple[str, str], ...] = ()

    @property
    def budget(self) -> int:
        """Actively collected observations per run (the learner's budget)."""
        return self.learner.budget

    def quick(self) -> StudyConfig:
        """Return a reduced version of this configuration for a first look."""
        return replace(
            self,
            reduced=True,
            groups=2,
            trials=2,
            learner=self.learner.replace(budget=min(self.learner.budget, 10)),
            fusion_groups=2,
            fusion_repetitions=2,
            prior_counts=(3, 7),
            reference_samples=QUICK_REFERENCE_SAMPLES,
        )


@dataclass(frozen=True, slots=True)
class Study:
    """A study's design: how to make its tasks, run one, and report the results.

    Attributes:
        name: The study's name on the command line (``atikt-replay study NAME``).
        title: The title of its summary and figure.
        tasks: Makes the independent tasks from the feature table and the options.
        run: Runs one task (in a worker process): one table of result rows.
        labels: The result columns that identify a row, first in the results and their order.
        report: What the summary and the figure show (``replay.studies._report``).
        further_files: Writes further files into ``config.out`` from the feature table and
            returns the summary's paragraph about them (None: nothing more).
        needs_prior_frame: Runs only with another rig's dataset (``--prior-recordings``);
            ``study all`` leaves it out otherwise.
    """

    name: str
    title: str
    tasks: Callable[[pl.DataFrame, StudyConfig], Sequence[Any]]
    run: Callable[[Any], pl.DataFrame]
    labels: tuple[str, ...]
    report: Report
    further_files: Callable[[pl.DataFrame, StudyConfig], str] | None = None
    needs_prior_frame: bool = False


def derive_seed(*parts: int | str) -> int:
    """Derive a 31-bit seed from parts, the same in every process."""
    words = [p if isinstance(p, int) else zlib.crc32(p.encode()) for p in parts]
    return int(np.random.SeedSequence(words).generate_state(1)[0] >> 1)


def dataset_actions(frame: pl.DataFrame) -> tuple[str, ...]:
    """Return the action ids of a feature table, sorted (whatever a lab named them)."""
    return tuple(sorted(set(frame["action_id"].to_list())))


class StudyDoesNotApplyError(ReplayError):
    """The dataset does not fit a study's design (too few objects, no fitting action pair).

    ``study NAME`` stops on it; ``study all`` skips that study with its line.
    """


def too_small(study: str, has: str, needs: str) -> StudyDoesNotApplyError:
    """Return the error of a dataset too small for a study's design, naming the fix."""
    msg = (
        f"study {study}: the dataset has {has}; the study needs {needs} (choose roles with "
        "--new/--priors, or record more)"
    )
    return StudyDoesNotApplyError(msg)


def min_old(config: StudyConfig) -> int:
    """Old objects a prior group needs (two for the model prediction approach).

    The model prediction approach compares old objects' one-vs-all models, so it needs two
    old objects in every group; the other approaches work with one.
    """
    return config.learner.transfer.min_old_objects


def roles(config: StudyConfig, study: str) -> tuple[str, ...]:
    """Return the study's actions after checking its roles fit the design.

    Raises:
        ReplayError: Fewer than 2 new or too few old objects (:func:`min_old`), or no action.
    """
    fewest = min_old(config)
    if len(config.new) < 2 or len(config.old) < fewest or not config.actions:  # noqa: PLR2004
        has = f"{len(config.new)} new, {len(config.old)} old objects, {len(config.actions)} actions"
        needs = f">= 2 new, >= {fewest} old objects and >= 1 action"
        if fewest > 1:
            needs += " (--transfer optimization or density needs 1 old object)"
        raise too_small(study, has, needs)
    return config.actions


def prior_groups(old: Sequence[str], size: int, count: int, seed: int) -> list[tuple[str, ...]]:
    """Return ``count`` distinct random groups of ``size`` old objects (fewer if not possible)."""
    combos = list(itertools.combinations(sorted(old), size))
    rng = np.random.default_rng(derive_seed(seed, "groups", size))
    chosen = rng.choice(len(combos), size=min(count, len(combos)), replace=False)
    return [combos[i] for i in sorted(chosen)]


def rows(frame: pl.DataFrame, labels: dict[str, Any]) -> pl.DataFrame:
    """Return the columns of a run kept in study results, with the run's labels."""
    keep = [c for c in frame.columns if c.startswith("accuracy")]
    kept = ("step", "object", "action", "explored", "prior", "rho", "metric_share")
    keep += [c for c in kept if c in frame]
    return frame.select(keep).with_columns(
        *(pl.lit(value).alias(name) for name, value in labels.items())
    )


def study_results(
    study: Study,
    frame: pl.DataFrame,
    config: StudyConfig,
    on_progress: Callable[[int, int], Any] | None = None,
) -> pl.DataFrame:
    """Run a study's tasks in parallel; return their rows stacked, labels first and sorted.

    Args:
        study: The study.
        frame: The dataset's feature table.
        config: Study options (workers, scheduler and the design's options).
        on_progress: Called with (tasks done, tasks).

    Raises:
        ReplayError: The dataset does not fit the design, or a task failed.
    """
    tasks = study.tasks(frame, config)

    def done(count: int) -> None:
        if on_progress is not None:
            on_progress(count, len(tasks))

    done(0)  # the total is known before the first task ends (a progress line shows it)
    frames = run_tasks(
        study.run, tasks, workers=config.workers, scheduler=config.scheduler, on_done=done
    )
    results = pl.concat(frames, how="diagonal_relaxed")
    rest = sorted(c for c in results.columns if c not in study.labels)
    return results.select([*study.labels, *rest]).sort(list(study.labels))
