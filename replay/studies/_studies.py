"""The thesis's studies over a dataset's feature cache: runs, results, plots, summary.

Every study is a list of independent tasks (a task carries its data and its own seed), run through
:func:`replay.learning._parallel.run_tasks`, so that results are the same bytes for any number of
local workers or a Dask cluster. Results are long-format parquet (one row per run and step, or per
repetition and training size), PNG figures, and ``summary.md``.
"""

from __future__ import annotations

import itertools
import json
import math
import zlib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import polars as pl

from atikt import MODALITIES, AtiktError, MultiModalGPC
from atikt.gpc import NOISE_PRIOR_SD
from atikt.kernels import fusion_kernel
from replay.errors import ReplayError
from replay.learning._executors import FeatureLookup, PoolExecutor, Split
from replay.learning._parallel import run_tasks
from replay.learning._session import (
    DEFAULT_HYPER_SD,
    DEFAULT_METRIC_CHECK,
    DEFAULT_METRIC_SD,
    DEFAULT_METRIC_UNTIL,
    RunSpec,
    fit_priors,
    learner_options,
    prior_data,
    run_learning,
)
from replay.outputs._plots import plot_learning_curves
from replay.recording._reader import read_recording
from replay.studies._borrow import (
    cross_action_tasks,
    cross_rig_tasks,
    report_borrow,
    run_borrow_task,
)
from replay.studies._relatedness import least_similar, most_similar, similarity_to_new
from replay.studies._stats import HEADLINES, RESAMPLES, fusion_margins, gain_cells, paired_gains
from schemas import VOCABULARY, atomic_write, atomic_write_text

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator, Sequence

    from atikt import RawFeatures

#: Label of the ATIKT runs and of the no-transfer baseline in results.
ATIKT, BASELINE = "ATIKT", "baseline"
#: Training samples per object of the other objects' model (``reference_theta``) and of the
#: saved hyperparameters (``write_hyperparameters``): ``StudyConfig.reference_samples``.
REFERENCE_SAMPLES = 10
#: The same with ``--quick``: the fit on every object of an action is serial and cubic in the
#: samples (10 per object: ~60 s of a 90 s quick fusion study on 2 cores; 3: a few seconds).
QUICK_REFERENCE_SAMPLES = 3
#: Training samples per object at which the fusion study measures accuracy.
FUSION_SIZES = (1, 2, 3, 5, 7, 10)


@dataclass(frozen=True, slots=True)
class StudyConfig:
    """Options shared by every study.

    Attributes:
        out: Directory for results, plots and summary.
        seed: Seed of group selection, splits and learners.
        groups: Random groups of prior objects (transfer, single-action, priors).
        trials: Runs per group.
        budget: Actively collected observations per run.
        workers: Local worker processes.
        scheduler: Dask scheduler address, or None for local processes.
        fusion_groups: Random groups of objects in the fusion study.
        fusion_repetitions: Repetitions per fusion group.
        fusion_objects: Objects per fusion group.
        prior_counts: Prior-object counts of the priors study.
        transfer: Transfer mode of the ATIKT runs.
        new: New objects (the dataset's declared ones unless chosen; see ``dataset_roles``).
        old: Old objects, the candidates for priors.
        actions: Actions of the study (every action of the dataset unless chosen).
        features: Feature policy (``thesis`` or ``all``).
        group_size: Prior objects per group in the transfer and single-action studies.
        reduced: A reduced run (``--quick``); its summary says so.
        max_sources: Old objects transferred at once (1: the thesis).
        hyper_sd: Standard deviation of a Gaussian prior on the active learners' log
            hyperparameters around the initial kernel (``DEFAULT_HYPER_SD``; None: maximum
            likelihood, the thesis).
        metric_sd: Prior sd of the ATIKT learners' log hyperparameters around the old
            objects' kernel (``DEFAULT_METRIC_SD``; None: no metric transfer, the thesis).
        metric_check: When the old objects' kernel is used (``DEFAULT_METRIC_CHECK``).
        metric_until: Most observations of a new object for which it is used
            (``DEFAULT_METRIC_UNTIL``; None: always).
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
    budget: int = 40
    workers: int = 1
    scheduler: str | None = None
    fusion_groups: int = 10
    fusion_repetitions: int = 10
    fusion_objects: int = 5
    prior_counts: tuple[int, ...] = (3, 5, 7, 10)
    transfer: str = "prediction"
    new: tuple[str, ...] = ()
    old: tuple[str, ...] = ()
    actions: tuple[str, ...] = ()
    features: str = "thesis"
    group_size: int = 3
    reduced: bool = False
    max_sources: int = 1
    hyper_sd: float | None = DEFAULT_HYPER_SD
    metric_sd: float | None = DEFAULT_METRIC_SD
    metric_check: str = DEFAULT_METRIC_CHECK
    metric_until: int | None = DEFAULT_METRIC_UNTIL
    fusion_prior: str = "others"
    reference_samples: int = REFERENCE_SAMPLES
    action_parameters: tuple[tuple[str, tuple[str, ...]], ...] = ()
    fusion_kernel: str = "sum"
    fusion_parts: tuple[tuple[str, str], ...] = ()
    prior_frame: pl.DataFrame | None = field(default=None, compare=False)
    prior_actions: tuple[tuple[str, str], ...] = ()

    def quick(self) -> StudyConfig:
        """Return a reduced version of this configuration for a first look."""
        return replace(
            self,
            reduced=True,
            groups=2,
            trials=2,
            budget=min(self.budget, 10),
            fusion_groups=2,
            fusion_repetitions=2,
            prior_counts=(3, 7),
            reference_samples=QUICK_REFERENCE_SAMPLES,
        )


def _seed(*parts: int | str) -> int:
    """Derive a 31-bit seed from parts, the same in every process."""
    words = [p if isinstance(p, int) else zlib.crc32(p.encode()) for p in parts]
    return int(np.random.SeedSequence(words).generate_state(1)[0] >> 1)


def dataset_actions(frame: pl.DataFrame) -> tuple[str, ...]:
    """Return the action ids of a feature table, sorted (whatever a lab named them)."""
    return tuple(sorted(set(frame["action_id"].to_list())))


def _too_small(study: str, has: str, needs: str) -> ReplayError:
    msg = (
        f"study {study}: the dataset has {has}; the study needs {needs} (choose roles with "
        "--new/--priors, or record more)"
    )
    return ReplayError(msg)


def _roles(config: StudyConfig, study: str) -> tuple[str, ...]:
    """Return the study's actions after checking its roles fit the design.

    The model prediction approach compares old objects' one-vs-all models, so it needs two
    old objects in every group; the other approaches work with one.

    Raises:
        ReplayError: Fewer than 2 new or too few old objects, or no action.
    """
    min_old = 2 if config.transfer == "prediction" else 1
    if len(config.new) < 2 or len(config.old) < min_old or not config.actions:  # noqa: PLR2004
        has = f"{len(config.new)} new, {len(config.old)} old objects, {len(config.actions)} actions"
        needs = f">= 2 new, >= {min_old} old objects and >= 1 action"
        if min_old > 1:
            needs += " (--transfer optimization or density needs 1 old object)"
        raise _too_small(study, has, needs)
    return config.actions


def prior_groups(old: Sequence[str], size: int, count: int, seed: int) -> list[tuple[str, ...]]:
    """Return ``count`` distinct random groups of ``size`` old objects (fewer if not possible)."""
    combos = list(itertools.combinations(sorted(old), size))
    rng = np.random.default_rng(_seed(seed, "groups", size))
    chosen = rng.choice(len(combos), size=min(count, len(combos)), replace=False)
    return [combos[i] for i in sorted(chosen)]


@dataclass(frozen=True, slots=True)
class TransferTask:
    """Runs of ATIKT and baseline for one group of prior objects (one parallel task).

    Attributes:
        frame: The feature table (the rows the task needs).
        new: New object ids.
        priors: Prior object ids.
        actions: Action sets, each run separately (one set: all actions together).
        trials: Runs per action set.
        budget: Actively collected observations per run.
        seed: Seed of the group's splits and learners.
        transfer: Transfer mode of the ATIKT runs.
        labels: Extra columns written into every row (group, prior count, ...).
        features: Feature policy.
        max_sources: Old objects transferred at once.
        hyper_sd: Prior sd of the learners' log hyperparameters (None: maximum likelihood).
        metric_sd: Prior sd around the old objects' kernel (None: no metric transfer).
        metric_check: When the old objects' kernel is used.
        metric_until: Most observations of a new object for which it is used.
    """

    frame: pl.DataFrame
    new: tuple[str, ...]
    priors: tuple[str, ...]
    actions: tuple[tuple[str, ...], ...]
    trials: int
    budget: int
    seed: int
    transfer: str = "prediction"
    labels: dict[str, Any] = field(default_factory=dict)
    features: str = "thesis"
    max_sources: int = 1
    hyper_sd: float | None = DEFAULT_HYPER_SD
    metric_sd: float | None = DEFAULT_METRIC_SD
    metric_check: str = DEFAULT_METRIC_CHECK
    metric_until: int | None = DEFAULT_METRIC_UNTIL


def run_transfer_task(task: TransferTask) -> pl.DataFrame:
    """Run ATIKT and the baseline on the same splits; return one row per run and step."""
    lookup = FeatureLookup(task.frame, task.features)
    every_action = tuple(sorted({a for group in task.actions for a in group}))
    models = fit_priors(prior_data(lookup, task.priors, every_action), _seed(task.seed, "prior"))
    frames = []
    for actions, trial in itertools.product(task.actions, range(task.trials)):
        run_seed = _seed(task.seed, trial, *actions)
        split = Split.random(task.frame, task.new, actions, seed=run_seed)
        for method, mode in ((ATIKT, task.transfer), (BASELINE, "none")):
            spec = RunSpec(
                new_objects=task.new,
                prior_objects=task.priors,
                actions=actions,
                learner=learner_options(
                    mode,
                    budget=task.budget,
                    max_sources=task.max_sources,
                    hyper_sd=task.hyper_sd,
                    metric_sd=task.metric_sd,
                    metric_check=task.metric_check,
                    metric_until=task.metric_until,
                ),
                seed=run_seed,
                features=task.features,
            )
            executor = PoolExecutor(lookup, task.new, split)
            result = run_learning(spec, executor, executor.test_set(actions), models)
            labels = task.labels | {"method": method, "trial": trial}
            labels |= {"actions": ",".join(actions), "priors": ",".join(task.priors)}
            frames.append(_rows(result.frame(), labels))
    return pl.concat(frames, how="diagonal_relaxed")


def _rows(frame: pl.DataFrame, labels: dict[str, Any]) -> pl.DataFrame:
    """Return the columns of a run kept in study results, with the run's labels."""
    keep = [c for c in frame.columns if c.startswith("accuracy")]
    keep += [c for c in ("step", "object", "action", "explored", "prior", "rho") if c in frame]
    return frame.select(keep).with_columns(
        *(pl.lit(value).alias(name) for name, value in labels.items())
    )


def _columns_first(frame: pl.DataFrame, first: Sequence[str]) -> pl.DataFrame:
    """Return ``frame`` with the label columns first, then the rest in a fixed order."""
    rest = sorted(c for c in frame.columns if c not in first)
    return frame.select([*first, *rest])


# ------------------------------------------------------------------------------ studies


def _run(
    tasks: Sequence[Any],
    function: Callable[[Any], pl.DataFrame],
    config: StudyConfig,
    on_progress: Callable[[int, int], Any] | None,
) -> pl.DataFrame:
    """Run tasks in parallel and stack their tables."""

    def done(count: int) -> None:
        if on_progress is not None:
            on_progress(count, len(tasks))

    frames = run_tasks(
        function, tasks, workers=config.workers, scheduler=config.scheduler, on_done=done
    )
    return pl.concat(frames, how="diagonal_relaxed")


def transfer_tasks(
    frame: pl.DataFrame, config: StudyConfig, *, single_action: bool = False
) -> list[TransferTask]:
    """Return the tasks of the transfer (or single-action) study: one per prior group.

    Groups hold ``config.group_size`` old objects (3 in the thesis), fewer when the dataset
    has fewer old objects.
    """
    actions = _roles(config, "single-action" if single_action else "transfer")
    sets = tuple((a,) for a in actions) if single_action else (actions,)
    size = min(config.group_size, len(config.old))
    return [
        TransferTask(
            frame,
            config.new,
            group,
            sets,
            config.trials,
            config.budget,
            _seed(config.seed, "transfer", number),
            config.transfer,
            {"group": number},
            config.features,
            config.max_sources,
            config.hyper_sd,
            config.metric_sd,
            config.metric_check,
            config.metric_until,
        )
        for number, group in enumerate(prior_groups(config.old, size, config.groups, config.seed))
    ]


def priors_tasks(frame: pl.DataFrame, config: StudyConfig) -> list[TransferTask]:
    """Return the tasks of the priors study: groups of each prior count the dataset allows."""
    actions = _roles(config, "priors")
    counts = [c for c in config.prior_counts if c <= len(config.old)]
    if not counts:
        has = f"{len(config.old)} old objects"
        needs = f"at least {min(config.prior_counts)} (prior counts {config.prior_counts})"
        study = "priors"
        raise _too_small(study, has, needs)
    tasks = []
    for count in counts:
        for number, group in enumerate(prior_groups(config.old, count, config.groups, config.seed)):
            seed = _seed(config.seed, "priors", count, number)
            labels = {"group": number, "n_priors": count}
            tasks.append(
                TransferTask(
                    frame,
                    config.new,
                    group,
                    (actions,),
                    config.trials,
                    config.budget,
                    seed,
                    config.transfer,
                    labels,
                    config.features,
                    config.max_sources,
                    config.hyper_sd,
                    config.metric_sd,
                    config.metric_check,
                    config.metric_until,
                )
            )
    return tasks


def negative_tasks(frame: pl.DataFrame, config: StudyConfig) -> list[TransferTask]:
    """Return the tasks of the negative-transfer study: the priors least like the new objects.

    Similarity is each old object's per-action rank by nearness in likelihood to the new
    objects (see ``_relatedness``); the least similar old objects (three, or all if fewer) are
    the priors of every run.
    """
    return similarity_tasks(frame, config, "negative", nearest=False)


def similarity_tasks(
    frame: pl.DataFrame, config: StudyConfig, study: str, *, nearest: bool
) -> list[TransferTask]:
    """Return runs of one prior group chosen by similarity to the new objects.

    Args:
        frame: The dataset's feature table.
        config: Study options; ``group_size`` priors, ``groups * trials`` runs.
        study: Name of the study (roles check and seeds).
        nearest: The most similar old objects if true, else the least similar.
    """
    actions = _roles(config, study)
    new, old = config.new, config.old
    objects = [*new, *old]
    frame = frame.filter(pl.col("object_id").is_in(objects))
    per_action = {}
    for action in actions:
        part = frame.filter(pl.col("action_id") == action).sort("path")
        matrix = np.vstack([_flat(row) for row in part.iter_rows(named=True)])
        labels = np.array([objects.index(o) for o in part["object_id"]], dtype=np.int64)
        per_action[action] = (matrix, labels)
    similarity = similarity_to_new(per_action, len(objects), range(len(new)))
    pick = most_similar if nearest else least_similar
    chosen = pick(similarity, range(len(new), len(objects)), min(config.group_size, len(old)))
    priors = tuple(objects[i] for i in chosen)
    runs = config.groups * config.trials
    return [
        TransferTask(
            frame,
            new,
            priors,
            (actions,),
            1,
            config.budget,
            _seed(config.seed, study, number),
            config.transfer,
            {"group": 0, "repetition": number},
            config.features,
            config.max_sources,
            config.hyper_sd,
            config.metric_sd,
            config.metric_check,
            config.metric_until,
        )
        for number in range(runs)
    ]


def _flat(row: dict[str, Any]) -> np.ndarray[Any, np.dtype[np.float64]]:
    """Return the raw features of a cache row as one vector (for the similarity)."""
    parts = [row[m] for m in VOCABULARY.features if row[m] is not None]
    return np.concatenate([np.asarray(p, dtype=np.float64) for p in parts])


@dataclass(frozen=True, slots=True)
class FusionTask:
    """Learning curves of one action and group of objects, all modality subsets.

    Attributes:
        frame: The feature table.
        action: The action.
        objects: Object ids of the group.
        repetitions: Random train/test splits.
        seed: Seed of the splits and fits.
        group: Group number (a result column).
        features: Feature policy.
        fusion_prior: ``others``, ``none`` or ``saved`` (see :class:`StudyConfig`).
        saved_theta: With ``saved``: the log hyperparameters that centre the prior.
        reference_samples: Trials per object of ``reference_theta``.
        controlled: Feature blocks the action sets (see ``StudyConfig.action_parameters``).
        kernel: ``MultiModalGPC`` options of the multi-modal kernel (combination, parts).
    """

    frame: pl.DataFrame
    action: str
    objects: tuple[str, ...]
    repetitions: int
    seed: int
    group: int
    features: str = "thesis"
    fusion_prior: str = "others"
    saved_theta: tuple[float, ...] | None = None
    reference_samples: int = REFERENCE_SAMPLES
    controlled: tuple[str, ...] = ()
    kernel: tuple[tuple[str, Any], ...] = ()


#: Prior standard deviation of the log hyperparameters around the other objects' ones
#: (measured against 1.0 in tests/bench/fusion_candidates.py: smaller worst-case loss).
REFERENCE_PRIOR_SD = 0.5
#: Choices of ``StudyConfig.fusion_prior`` besides the path of a saved hyperparameters file.
FUSION_PRIORS = ("others", "noise", "none")
#: Prior sd of the length scales and signal variance around the initial kernel (1 in log
#: space) when the declared-noise prior sets the modality weights: with one sample per object
#: maximum likelihood drives every length scale to its lower bound, where the weights no
#: longer matter (measured on the heated probe, atikt/README.md *Fusion*).
NOISE_OTHER_SD = 1.0


def declared_noise() -> dict[str, float]:
    """Return the contract's declared noise of one sample per feature block (``noise``)."""
    return {m.feature: m.noise for m in VOCABULARY.modalities.values() if m.feature and m.noise}


def controlled_blocks(parameters: Sequence[str]) -> tuple[str, ...]:
    """Return the feature blocks an action stating ``parameters`` sets (``controlled_by``)."""
    return tuple(
        m.feature
        for m in VOCABULARY.modalities.values()
        if m.feature and m.controlled_by and m.controlled_by in parameters
    )


def action_parameter_names(
    root: Path, frame: pl.DataFrame
) -> tuple[tuple[str, tuple[str, ...]], ...]:
    """Return per action the parameters its first recording sets (metadata only).

    A parameter of value 0 is not set: the recorder writes every parameter and 0 for those
    the action's kind does not use (a press has ``force_n = 0``).

    Raises:
        ReplayError: The recording cannot be read (the reader's one-line message).
    """
    out = []
    for action in dataset_actions(frame):
        path = frame.filter(pl.col("action_id") == action).sort("path")["path"][0]
        metadata = read_recording(root / path).metadata
        parameters = metadata.action_parameters
        out.append((action, tuple(sorted(k for k, v in parameters.items() if v != 0))))
    return tuple(out)


#: The fusion study's file of the multi-modal kernel's hyperparameters, fitted per action on
#: every object of the dataset: what another study takes as ``--fusion-prior FILE``.
HYPERPARAMETERS = "hyperparameters.json"
_HYPERPARAMETERS_FORMAT = "atikt fusion hyperparameters"


def _fit_theta(
    lookup: FeatureLookup,
    action: str,
    objects: Sequence[str],
    seed: int,
    samples: int = REFERENCE_SAMPLES,
    *,
    kernel: Sequence[tuple[str, Any]] = (),
) -> tuple[tuple[str, ...], np.ndarray[Any, np.dtype[np.float64]]]:
    """Fit the fused kernel on up to ``samples`` trials of each object (the first).

    ``kernel``: ``MultiModalGPC`` options of the kernel (``StudyConfig.fusion_kernel``).

    Returns:
        The kernel's hyperparameter names and its fitted log hyperparameters.
    """
    train, labels = [], []
    for label, obj in enumerate(objects):
        for trial in lookup.trials(obj, action)[:samples]:
            train.append(lookup.get(obj, action, trial))
            labels.append(label)
    model = MultiModalGPC(random_state=seed, **dict(kernel)).fit(train, labels)
    return model.model_.estimators_[0].kernel_.names, model.theta_


def reference_theta(
    lookup: FeatureLookup,
    action: str,
    objects: Sequence[str],
    seed: int,
    samples: int = REFERENCE_SAMPLES,
    *,
    kernel: Sequence[tuple[str, Any]] = (),
) -> np.ndarray[Any, np.dtype[np.float64]] | None:
    """Return the fused kernel's hyperparameters fitted on the other objects of the dataset.

    The objects outside the group (up to ``samples`` trials each, the first by trial
    number) are what a lab already knows about this action: which modality separates objects
    and on what scale. None when fewer than two other objects have the action.
    """
    others = [
        o for o in lookup.objects(action) if o not in set(objects) and lookup.trials(o, action)
    ]
    if len(others) < 2:  # noqa: PLR2004 - a classifier needs two classes
        return None
    return _fit_theta(lookup, action, others, seed, samples, kernel=kernel)[1]


def kernel_names(
    lookup: FeatureLookup, action: str, kernel: Sequence[tuple[str, Any]] = ()
) -> tuple[str, ...]:
    """Return the hyperparameter names of the fused kernel of ``action`` (its modalities).

    In the order ``atikt.FeatureTransformer`` stacks the modalities (``atikt.MODALITIES``).
    """
    held = [m for m in MODALITIES if m in lookup.blocks[action]]
    options = dict(kernel)
    return fusion_kernel(
        {m: slice(i, i + 1) for i, m in enumerate(held)},
        combination=options.get("combination", "sum"),
        parts=options.get("parts"),
    ).names


def kernel_options(config: StudyConfig) -> tuple[tuple[str, Any], ...]:
    """Return the ``MultiModalGPC`` options of the configured multi-modal kernel."""
    options: list[tuple[str, Any]] = []
    if config.fusion_kernel != "sum":
        options.append(("combination", config.fusion_kernel))
    if config.fusion_parts:
        options.append(("parts", dict(config.fusion_parts)))
    return tuple(options)


def write_hyperparameters(features: pl.DataFrame, config: StudyConfig) -> Path:
    """Write the fused kernel's hyperparameters of every action, fitted on all its objects.

    The file is what this dataset teaches about its rig: which modality separates objects in
    each action and on what scale. A later fusion study of another session or dataset of the
    same rig takes it as ``--fusion-prior FILE`` (``load_hyperparameters``); floats are written
    in their shortest exact form, so the file is the same bytes for the same inputs and seed.

    Returns:
        The file's path.
    """
    lookup = FeatureLookup(features, config.features)
    actions = {}
    for action in config.actions:
        objects = [o for o in lookup.objects(action) if o in {*config.new, *config.old}]
        if len(objects) < 2:  # noqa: PLR2004 - a classifier needs two classes
            continue
        seed = _seed(config.seed, action, "saved")
        names, theta = _fit_theta(
            lookup, action, objects, seed, config.reference_samples, kernel=kernel_options(config)
        )
        actions[action] = {
            "objects": objects,
            "samples_per_object": config.reference_samples,
            "names": list(names),
            "theta": [float(v) for v in theta],
        }
    document = {
        "format": _HYPERPARAMETERS_FORMAT,
        "version": 1,
        "features": config.features,
        "seed": config.seed,
        "use": "atikt-replay study fusion --fusion-prior THIS_FILE (log hyperparameters of the "
        "multi-modal kernel, the prior's centre)",
        "actions": actions,
    }
    path = config.out / HYPERPARAMETERS
    atomic_write_text(path, json.dumps(document, indent=1) + "\n")
    return path


def load_hyperparameters(path: Path) -> dict[str, tuple[tuple[str, ...], tuple[float, ...]]]:
    """Read a fusion study's ``hyperparameters.json``: per action, names and log values.

    Raises:
        ReplayError: The file is unreadable or not such a file, in one line naming the fix.
    """
    fix = f"pass the {HYPERPARAMETERS} a fusion study wrote (atikt-replay study fusion)"
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        if isinstance(err, UnicodeDecodeError):
            reason = "not UTF-8 JSON text"
        else:
            reason = (err.strerror if isinstance(err, OSError) else None) or str(err).split("\n")[0]
        msg = f"--fusion-prior {path}: cannot read it ({reason}); {fix}"
        raise ReplayError(msg) from err
    if not isinstance(document, dict) or document.get("format") != _HYPERPARAMETERS_FORMAT:
        msg = f"--fusion-prior {path}: not a fusion study's hyperparameters file; {fix}"
        raise ReplayError(msg)
    saved = {}
    for action, entry in (document.get("actions") or {}).items():
        names, theta = entry.get("names"), entry.get("theta")
        valid = isinstance(names, list) and isinstance(theta, list) and len(names) == len(theta)
        if not valid or not all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
            for v in theta
        ):
            msg = (
                f"--fusion-prior {path}: action {action!r} needs equally long 'names' and "
                f"finite 'theta' lists; {fix}"
            )
            raise ReplayError(msg)
        saved[str(action)] = (tuple(map(str, names)), tuple(float(v) for v in theta))
    if not saved:
        msg = f"--fusion-prior {path}: it holds no action's hyperparameters; {fix}"
        raise ReplayError(msg)
    return saved


def run_fusion_task(task: FusionTask) -> pl.DataFrame:
    """Fit multi-modal and single-modality GPCs on 1..n training samples; test accuracy rows."""
    lookup = FeatureLookup(task.frame, task.features)
    modalities = lookup.blocks[task.action]
    subsets = {"multi-modal": None} | {m: (m,) for m in modalities}
    reference, prior = None, "none"
    if task.fusion_prior == "others":
        reference = reference_theta(
            lookup,
            task.action,
            task.objects,
            task.seed,
            task.reference_samples,
            kernel=task.kernel,
        )
    elif task.saved_theta is not None:
        reference = np.asarray(task.saved_theta, dtype=np.float64)
    fused: dict[str, Any] = dict(task.kernel)
    if reference is not None:
        fused |= {"initial_theta": reference, "prior_sd": REFERENCE_PRIOR_SD}
        prior = task.fusion_prior
    elif task.fusion_prior in {"others", "noise"} and (noise := declared_noise()):
        fused |= {"sensor_noise": noise, "controlled": task.controlled}
        fused |= {"prior_sd": NOISE_OTHER_SD}
        prior = "noise"
    rows = []
    for split in fusion_splits(task, lookup):
        for name, subset in subsets.items():
            options = fused if subset is None else {}
            model = MultiModalGPC(subset, random_state=split.seed, **options)
            try:
                predicted = model.fit(split.train, split.labels).predict(split.test)
            except AtiktError as err:
                msg = f"fusion study, action {task.action}, {name}: {err}"
                raise ReplayError(msg) from err
            accuracy = float(np.mean(np.asarray(predicted) == np.asarray(split.test_labels)))
            rows.append(
                {"action": task.action, "group": task.group, "repetition": split.repetition}
                | {"modalities": name, "samples": split.size, "accuracy": accuracy}
                | {"fusion_prior": prior}
            )
    return pl.DataFrame(rows)


@dataclass(frozen=True, slots=True)
class FusionSplit:
    """One training set of the fusion study and its test set.

    Attributes:
        repetition: The random split's number.
        seed: Seed of the split and of the fits on it.
        size: Training samples per object.
        train: Training observations, object by object.
        labels: Their object indices.
        test: Held-out observations.
        test_labels: Their object indices.
    """

    repetition: int
    seed: int
    size: int
    train: list[RawFeatures]
    labels: list[int]
    test: list[RawFeatures]
    test_labels: list[int]


def fusion_splits(task: FusionTask, lookup: FeatureLookup) -> Iterator[FusionSplit]:
    """Yield the task's training sets: per repetition a random split, then each size."""
    for repetition in range(task.repetitions):
        seed = _seed(task.seed, repetition)
        split = Split.random(task.frame, task.objects, (task.action,), seed=seed)
        executor = PoolExecutor(lookup, task.objects, split)
        test_obs, test_labels = executor.test_set((task.action,))[task.action]
        pools = [split.pool[o, task.action] for o in task.objects]
        largest = min(len(p) for p in pools)
        for size in [n for n in FUSION_SIZES if n <= largest]:
            train = [
                lookup.get(o, task.action, t)
                for o, p in zip(task.objects, pools, strict=True)
                for t in p[:size]
            ]
            labels = [i for i, p in enumerate(pools) for _ in p[:size]]
            yield FusionSplit(
                repetition, seed, size, train, labels, list(test_obs), list(test_labels)
            )


def fusion_tasks(frame: pl.DataFrame, config: StudyConfig) -> list[FusionTask]:
    """Return the fusion study's tasks: per action, random groups of objects."""
    objects = sorted({*config.new, *config.old})
    actions = config.actions
    if len(objects) < 2 or not actions:  # noqa: PLR2004
        has = f"{len(objects)} objects and {len(actions)} actions"
        study = "fusion"
        raise _too_small(study, has, ">= 2 objects and >= 1 action")
    mode, saved = config.fusion_prior, {}
    if mode not in FUSION_PRIORS:
        mode, saved = "saved", _saved_thetas(frame, config, Path(config.fusion_prior))
    parameters = dict(config.action_parameters)
    kernel = kernel_options(config)
    rng = np.random.default_rng(_seed(config.seed, "fusion"))
    size = min(config.fusion_objects, len(objects))
    groups = [
        tuple(sorted(rng.choice(objects, size, replace=False))) for _ in range(config.fusion_groups)
    ]
    return [
        FusionTask(
            frame,
            action,
            group,
            config.fusion_repetitions,
            _seed(config.seed, action, number),
            number,
            config.features,
            mode,
            saved.get(action),
            config.reference_samples,
            controlled_blocks(parameters.get(action, ())),
            kernel,
        )
        for action in actions
        for number, group in enumerate(groups)
    ]


def _saved_thetas(
    frame: pl.DataFrame, config: StudyConfig, path: Path
) -> dict[str, tuple[float, ...]]:
    """Return the saved hyperparameters of each of the study's actions, checked against it.

    Raises:
        ReplayError: The file lacks an action, or its kernel has other modalities.
    """
    saved = load_hyperparameters(path)
    lookup = FeatureLookup(frame.filter(pl.col("action_id").is_in(config.actions)), config.features)
    thetas = {}
    for action in config.actions:
        if action not in saved:
            msg = (
                f"--fusion-prior {path}: no hyperparameters for action {action!r} (it has "
                f"{', '.join(sorted(saved))}); choose --actions, or save them from a dataset "
                "with that action"
            )
            raise ReplayError(msg)
        names, theta = saved[action]
        wanted = kernel_names(lookup, action, kernel_options(config))
        if names != wanted:
            msg = (
                f"--fusion-prior {path}: action {action!r} was saved for the kernel "
                f"{', '.join(names)}, this dataset's is {', '.join(wanted)}; save it with the same "
                "modalities and --features"
            )
            raise ReplayError(msg)
        thetas[action] = theta
    return thetas


# ------------------------------------------------------------------------------ reports


def headline(frame: pl.DataFrame, by: Sequence[str], budget: int) -> pl.DataFrame:
    """Return accuracy after the initial observations, mean over steps 1..budget, and final.

    Accuracies are averaged over runs first per step, then over steps.
    """
    per_step = frame.group_by([*by, "step"]).agg(pl.col("accuracy").mean())
    return (
        per_step.group_by(by)
        .agg(
            pl.col("accuracy").filter(pl.col("step") == 0).first().alias("initial"),
            pl.col("accuracy").filter(pl.col("step").is_between(1, budget)).mean().alias("mean"),
            pl.col("accuracy").sort_by("step").last().alias("final"),
        )
        .sort(by)
    )


def _cell(value: object, column: str) -> str:
    """Render one table cell: accuracies as percentages, gains as signed percentage points."""
    if value is None:
        return "-"
    if not isinstance(value, float):
        return str(value)
    return f"{100 * value:+.1f} pts" if column.startswith("gain") else f"{100 * value:.1f} %"


def _markdown(frame: pl.DataFrame) -> str:
    """Render a small table as GitHub markdown, floats as percentages."""
    header = "| " + " | ".join(frame.columns) + " |"
    rule = "|" + "|".join("---" for _ in frame.columns) + "|"
    lines = [header, rule]
    for row in frame.iter_rows():
        cells = [_cell(v, c) for v, c in zip(row, frame.columns, strict=True)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _gain_table(frame: pl.DataFrame, by: Sequence[str], unit: str, config: StudyConfig) -> str:
    """Return the markdown table of paired gains with their 95 % bootstrap intervals."""
    gains = paired_gains(frame, by, unit, config.budget, seed=config.seed)
    header = [*by, f"{unit}s", "gain after 1 observation", "gain mean 1..budget", "gain final"]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    for row in gains.iter_rows(named=True):
        cells = [str(row[key]) for key in by] + [str(row["units"])]
        cells += [gain_cells(row, head) for head in HEADLINES]
        lines.append("| " + " | ".join(cells) + " |")
    note = (
        f"Gains: ATIKT minus baseline in percentage points, paired on the same splits, mean "
        f"over {unit}s; [95 % interval]: percentile bootstrap over {unit}s "
        f'({RESAMPLES} resamples). "after 1 observation": after the initial round of one '
        "observation per (new object, action)."
    )
    return "\n".join(lines) + "\n\n" + note


_METRIC_WHEN = {
    "evidence": "when the new objects' evidence is at least as large there",
    "separation": "when it separates the new objects at least as well",
    "either": "when the new objects' evidence is at least as large there or it separates "
    "them at least as well",
    "none": "always",
}
"""The summary's words for each ``--metric-check``."""


def _reduced(config: StudyConfig, *, learners: bool = True) -> str:
    """Return the summary's notes on a reduced (``--quick``) run and on the learners' prior."""
    text = ""
    if learners:
        text += (
            "\nLearners: maximum likelihood hyperparameters, as in the thesis "
            "(`--hyper-sd none`).\n"
            if config.hyper_sd is None
            else f"\nLearners: maximum a posteriori hyperparameters, a Gaussian prior of sd "
            f"{config.hyper_sd:g} (log space) around the initial kernel (`--hyper-sd`).\n"
        )
        text += (
            "ATIKT learners: no metric transfer (`--metric-sd none`).\n"
            if config.metric_sd is None
            else "ATIKT learners: metric transfer, the new objects' classifiers start from the "
            f"old objects' kernel with a prior of sd {config.metric_sd:g} around it "
            f"({_METRIC_WHEN[config.metric_check]}"
            + (
                ""
                if config.metric_until is None
                else f", while a new object has at most {config.metric_until} observations "
                "of the action"
            )
            + "; `--metric-sd`, `--metric-check`, `--metric-until`).\n"
        )
    if config.reduced:
        text += (
            "\n> Reduced run (`--quick`): fewer groups, trials, steps and repetitions than the "
            "full study; its numbers vary widely and are for a first look only.\n"
        )
    return text


def report_transfer(frame: pl.DataFrame, config: StudyConfig, title: str) -> str:
    """Plot and summarise a transfer-type study; return the markdown summary."""
    table = headline(frame, ["method"], config.budget)
    unit = "repetition" if "repetition" in frame.columns else "group"
    plot_learning_curves(frame, config.out / "learning_curves.png", x="step", title=title)
    runs = frame.filter(pl.col("step") == 0).height // 2
    return (
        f"# {title}\n{_reduced(config)}\n{runs} paired runs (ATIKT and baseline on the same "
        f"splits), budget {config.budget}; test accuracy of all actions together.\n\n"
        f"{_markdown(table)}\n\n{_gain_table(frame, [], unit, config)}\n"
    )


def report_single_action(frame: pl.DataFrame, config: StudyConfig, title: str) -> str:
    """Plot and summarise the single-action study."""
    table = headline(frame, ["actions", "method"], config.budget)
    plot_learning_curves(
        frame, config.out / "learning_curves.png", x="step", panel="actions", title=title
    )
    return (
        f"# {title}\n{_reduced(config)}\nOne action at a time, ATIKT vs baseline, budget "
        f"{config.budget}.\n\n{_gain_table(frame, ['actions'], 'group', config)}\n\n"
        f"{_markdown(table)}\n"
    )


def report_priors(frame: pl.DataFrame, config: StudyConfig, title: str) -> str:
    """Plot and summarise the prior-count study."""
    table = headline(frame, ["n_priors", "method"], config.budget)
    plot_learning_curves(
        frame, config.out / "learning_curves.png", x="step", panel="n_priors", title=title
    )
    counts = ", ".join(str(c) for c in sorted(set(frame["n_priors"].to_list())))
    return (
        f"# {title}\n{_reduced(config)}\nATIKT vs baseline with {counts} prior objects.\n\n"
        f"{_gain_table(frame, ['n_priors'], 'group', config)}\n\n{_markdown(table)}\n"
    )


def fusion_means(frame: pl.DataFrame) -> pl.DataFrame:
    """Return the mean accuracy per action and modality set over all sizes, groups and splits.

    Rounded to 1e-9 so that the summation order of the aggregation never decides a printed
    digit (the summary and README print the same numbers).
    """
    return (
        frame.group_by("action", "modalities")
        .agg(pl.col("accuracy").mean().round(9))
        .sort("action", "modalities")
    )


def report_fusion(frame: pl.DataFrame, config: StudyConfig, title: str) -> str:
    """Plot and summarise the fusion study."""
    plot_learning_curves(
        frame,
        config.out / "learning_curves.png",
        x="samples",
        label="modalities",
        panel="action",
        title=title,
        xlabel="training samples per object",
    )
    table = fusion_means(frame).pivot(on="modalities", index="action", values="accuracy")
    sizes = (
        frame.group_by("action", "modalities", "samples")
        .agg(pl.col("accuracy").mean())
        .pivot(on="modalities", index=["action", "samples"], values="accuracy")
        .sort("action", "samples")
    )
    margins = fusion_margins(frame, seed=config.seed)
    margin_table = (
        "| action | samples | best single | multi-modal - best (points) |\n|---|---|---|---|\n"
    )
    margin_table += "".join(
        f"| {r['action']} | {r['samples']} | {r['best']} | "
        f"{_signed_points(r['margin'], r['low'], r['high'])} |\n"
        for r in margins.iter_rows(named=True)
    )
    return (
        f"# {title}\n{_reduced(config, learners=False)}\nMean test accuracy over training sizes, "
        "groups of "
        f"{_group_size(config)} objects, multi-modal kernel vs single modalities"
        f"{_kernel_note(config)}. "
        f"{_fusion_prior_note(frame)}\n\n"
        f"{_markdown(table)}\n\nPer training size (samples per object):\n\n"
        f"{_markdown(sizes)}\n\nMulti-modal minus the best single modality at each size, "
        "paired per group, with its 95 % bootstrap interval over groups:\n\n"
        f"{margin_table}"
    )


def _group_size(config: StudyConfig) -> int:
    """Return the number of objects per fusion group (``fusion_tasks``)."""
    return min(config.fusion_objects, len({*config.new, *config.old}))


def _kernel_note(config: StudyConfig) -> str:
    """Name the multi-modal kernel when it is not the thesis's weighted sum of RBFs."""
    parts = ", ".join(f"{block} {kind}" for block, kind in config.fusion_parts)
    if config.fusion_kernel == "sum" and not parts:
        return ""
    return f" (kernel: {config.fusion_kernel}" + (f"; {parts})" if parts else ")")


def _signed_points(value: float, low: float, high: float) -> str:
    """Format a fraction as signed points with its interval (none with one unit)."""
    text = f"{100 * value:+.1f}"
    if np.isfinite(low):
        text += f" [{100 * low:+.1f}, {100 * high:+.1f}]"
    return text


def _fusion_prior_note(frame: pl.DataFrame) -> str:
    """Say how the multi-modal kernel's hyperparameters were found, per action."""
    if "fusion_prior" not in frame.columns:
        return ""
    saved = frame.filter(pl.col("fusion_prior") == "saved")["action"].unique().sort().to_list()
    if saved:
        return (
            "Multi-modal hyperparameters: a prior centred on the saved hyperparameters of "
            f"{', '.join(saved)} (--fusion-prior FILE, sd {REFERENCE_PRIOR_SD} in log space)."
        )
    used = frame.filter(pl.col("fusion_prior") == "others")["action"].unique().sort().to_list()
    noise = frame.filter(pl.col("fusion_prior") == "noise")["action"].unique().sort().to_list()
    noise_note = (
        f" Modality weights (of a product kernel: its length scales) of {', '.join(noise)}: a "
        f"prior (sd {NOISE_PRIOR_SD}) centred on "
        "each feature's spread relative to its sensor's declared noise (contract `noise`; a "
        "modality the action sets, `controlled_by`, counts as noise), length scales and "
        f"signal variance a prior of sd {NOISE_OTHER_SD} around the initial kernel."
        if noise
        else ""
    )
    if not used and noise:
        return noise_note.lstrip()
    if not used:
        return (
            "Multi-modal hyperparameters by maximum likelihood on the group's samples (no prior "
            "from other objects: fewer than two objects outside the group, or --fusion-prior "
            "none)."
        )
    return (
        "Multi-modal hyperparameters: a prior centred on those fitted on the objects outside "
        f"the group (sd {REFERENCE_PRIOR_SD} in log space) for {', '.join(used)}"
        + (f".{noise_note}" if noise else "; maximum likelihood elsewhere.")
    )


@dataclass(frozen=True, slots=True)
class Study:
    """A study: how to make its tasks, run one, and report the results."""

    title: str
    tasks: Callable[[pl.DataFrame, StudyConfig], Sequence[Any]]
    run: Callable[[Any], pl.DataFrame]
    report: Callable[[pl.DataFrame, StudyConfig, str], str]
    labels: tuple[str, ...]
    #: Writes a further file from the feature table into the output (and returns its path).
    save: Callable[[pl.DataFrame, StudyConfig], Path] | None = None


def _single_action_tasks(frame: pl.DataFrame, config: StudyConfig) -> list[TransferTask]:
    return transfer_tasks(frame, config, single_action=True)


STUDIES: dict[str, Study] = {
    "fusion": Study(
        "Multi-modal fusion vs single modalities",
        fusion_tasks,
        run_fusion_task,
        report_fusion,
        ("action", "group", "repetition", "modalities", "samples"),
        write_hyperparameters,
    ),
    "transfer": Study(
        "ATIKT vs no transfer, all actions",
        transfer_tasks,
        run_transfer_task,
        report_transfer,
        ("method", "group", "trial", "step"),
    ),
    "single-action": Study(
        "ATIKT vs no transfer, one action at a time",
        _single_action_tasks,
        run_transfer_task,
        report_single_action,
        ("actions", "method", "group", "trial", "step"),
    ),
    "priors": Study(
        "ATIKT vs no transfer with 3, 5, 7, 10 prior objects",
        priors_tasks,
        run_transfer_task,
        report_priors,
        ("n_priors", "method", "group", "trial", "step"),
    ),
    "negative": Study(
        "ATIKT with dissimilar priors (negative transfer)",
        negative_tasks,
        run_transfer_task,
        report_transfer,
        ("method", "repetition", "trial", "step"),
    ),
    "cross-action": Study(
        "Cross-action transfer: priors from another action",
        cross_action_tasks,
        run_borrow_task,
        report_borrow,
        ("actions", "method", "group", "trial", "step"),
    ),
    "cross-rig": Study(
        "Cross-rig transfer: priors from another rig's recordings",
        cross_rig_tasks,
        run_borrow_task,
        report_borrow,
        ("actions", "method", "group", "trial", "step"),
    ),
}


@dataclass(frozen=True, slots=True)
class StudyOutput:
    """Where a study wrote its results."""

    name: str
    results: Path
    plot: Path
    summary: Path
    text: str


def run_study(
    name: str,
    frame: pl.DataFrame,
    config: StudyConfig,
    *,
    quarantined: pl.DataFrame | None = None,
    on_progress: Callable[[int, int], Any] | None = None,
) -> StudyOutput:
    """Run one study over a feature table and write results, plot and summary.

    Args:
        name: A key of :data:`STUDIES`.
        frame: The dataset's feature table.
        config: Study options; ``config.out`` is created.
        quarantined: Recordings refused while building the features (listed in the summary).
        on_progress: Called with (tasks done, tasks).

    Raises:
        ReplayError: Unknown study, or a run failed.
    """
    if name not in STUDIES:
        msg = f"unknown study {name!r}; choose one of {', '.join([*STUDIES, 'all'])}"
        raise ReplayError(msg)
    study = STUDIES[name]
    out = config.out
    results = _run(study.tasks(frame, config), study.run, config, on_progress)
    results = _columns_first(results, study.labels).sort(list(study.labels))
    path, summary = out / "results.parquet", out / "summary.md"
    try:
        out.mkdir(parents=True, exist_ok=True)
        atomic_write(path, results.write_parquet)
        text = study.report(results, config, study.title)
        if study.save is not None:
            saved = study.save(frame, config)
            text += (
                f"\nThe multi-modal kernel's hyperparameters fitted on every object of each "
                f"action: `{saved.name}` (`--fusion-prior {saved.name}` centres a later "
                "study's prior on them, e.g. of another session of the same rig).\n"
            )
        if quarantined is not None and quarantined.height:
            listing = "\n".join(f"- `{p}`: {r}" for p, r in quarantined.iter_rows())
            text += f"\n## Quarantined recordings ({quarantined.height})\n\n{listing}\n"
        atomic_write_text(summary, text)
    except (OSError, pl.exceptions.PolarsError) as err:  # polars: ComputeError on a full disk
        reason = err.strerror if isinstance(err, OSError) else " ".join(str(err).split())
        msg = f"{out}: cannot write the study's results ({reason}); check free space and --out"
        raise ReplayError(msg) from err
    return StudyOutput(name, path, out / "learning_curves.png", summary, text)
