"""The fusion study: the multi-modal kernel vs single modalities, per action.

Per action, random groups of objects; per group, random train/test splits; per split, one
classifier per modality set (the multi-modal kernel and each modality alone) fitted on 1, 2,
3, 5, 7 and 10 training samples per object and tested on the held-out rest. Where the
multi-modal kernel starts and what prior holds it there is ``_fusion_prior``'s.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import polars as pl

from atikt import AtiktError, MultiModalGPC
from atikt.gpc import NOISE_PRIOR_SD
from replay.errors import ReplayError
from replay.learning._executors import FeatureLookup, PoolExecutor, Split
from replay.studies._fusion_prior import (
    FUSION_PRIORS,
    NOISE_OTHER_SD,
    REFERENCE_PRIOR_SD,
    controlled_blocks,
    declared_noise,
    kernel_options,
    reference_theta,
    saved_thetas,
    write_hyperparameters,
)
from replay.studies._report import Curves, Report, Text, markdown_table
from replay.studies._running import REFERENCE_SAMPLES, Study, derive_seed, too_small
from replay.studies._stats import fusion_margins

if TYPE_CHECKING:
    from collections.abc import Iterator

    from atikt import RawFeatures
    from replay.studies._running import StudyConfig

#: Training samples per object at which the fusion study measures accuracy.
FUSION_SIZES = (1, 2, 3, 5, 7, 10)


@dataclass(frozen=True, slots=True, kw_only=True)
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
        seed = derive_seed(task.seed, repetition)
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
        raise too_small(study, has, ">= 2 objects and >= 1 action")
    mode, saved = config.fusion_prior, {}
    if mode not in FUSION_PRIORS:
        mode, saved = "saved", saved_thetas(frame, config, Path(config.fusion_prior))
    parameters = dict(config.action_parameters)
    kernel = kernel_options(config)
    rng = np.random.default_rng(derive_seed(config.seed, "fusion"))
    size = min(config.fusion_objects, len(objects))
    groups = [
        tuple(sorted(rng.choice(objects, size, replace=False))) for _ in range(config.fusion_groups)
    ]
    return [
        FusionTask(
            frame=frame,
            action=action,
            objects=group,
            repetitions=config.fusion_repetitions,
            seed=derive_seed(config.seed, action, number),
            group=number,
            features=config.features,
            fusion_prior=mode,
            saved_theta=saved.get(action),
            reference_samples=config.reference_samples,
            controlled=controlled_blocks(parameters.get(action, ())),
            kernel=kernel,
        )
        for action in actions
        for number, group in enumerate(groups)
    ]


def fusion_means(frame: pl.DataFrame) -> pl.DataFrame:
    """Return the mean accuracy per action and modality set over all sizes, groups and splits.

    Rounded to 1e-9 so that the summation order of the aggregation never decides a printed
    digit (the summary and README print the same numbers).
    """
    return (
        frame.group_by("action", "modalities", maintain_order=True)
        .agg(pl.col("accuracy").mean().round(9))
        .sort("action", "modalities")
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


def _fusion_intro(frame: pl.DataFrame, config: StudyConfig) -> str:
    """Return the summary's sentence on the groups, the kernel and its prior."""
    return (
        f"Mean test accuracy over training sizes, groups of {_group_size(config)} objects, "
        f"multi-modal kernel vs single modalities{_kernel_note(config)}. "
        f"{_fusion_prior_note(frame)}"
    )


def _means_table(frame: pl.DataFrame, config: StudyConfig) -> str:  # noqa: ARG001
    """Return the mean accuracy per action (rows) and modality set (columns)."""
    return markdown_table(
        fusion_means(frame).pivot(on="modalities", index="action", values="accuracy")
    )


def _sizes_table(frame: pl.DataFrame, config: StudyConfig) -> str:  # noqa: ARG001
    """Return the mean accuracy per action and training size (rows) and modality set.

    Sorted before the pivot, whose columns follow the order in which it meets the modality
    sets (as the means table's): an unordered ``group_by`` made it random from run to run.
    """
    sizes = (
        frame.group_by("action", "modalities", "samples", maintain_order=True)
        .agg(pl.col("accuracy").mean())
        .sort("action", "samples", "modalities")
        .pivot(on="modalities", index=["action", "samples"], values="accuracy")
        .sort("action", "samples")
    )
    return markdown_table(sizes)


def _margins_table(frame: pl.DataFrame, config: StudyConfig) -> str:
    """Return the multi-modal kernel minus the best single modality, per action and size."""
    lines = [
        "| action | samples | best single | multi-modal - best (points) |",
        "|---|---|---|---|",
    ]
    lines += [
        f"| {r['action']} | {r['samples']} | {r['best']} | "
        f"{_signed_points(r['margin'], r['low'], r['high'])} |"
        for r in fusion_margins(frame, seed=config.seed).iter_rows(named=True)
    ]
    return "\n".join(lines)


def _save_hyperparameters(features: pl.DataFrame, config: StudyConfig) -> str:
    """Write ``hyperparameters.json`` (``write_hyperparameters``); return the summary's note."""
    saved = write_hyperparameters(features, config)
    return (
        f"\nThe multi-modal kernel's hyperparameters fitted on every object of each "
        f"action: `{saved.name}` (`--fusion-prior {saved.name}` centres a later "
        "study's prior on them, e.g. of another session of the same rig).\n"
    )


FUSION = Study(
    name="fusion",
    title="Multi-modal fusion vs single modalities",
    tasks=fusion_tasks,
    run=run_fusion_task,
    labels=("action", "group", "repetition", "modalities", "samples"),
    report=Report(
        (
            _fusion_intro,
            _means_table,
            Text("Per training size (samples per object):"),
            _sizes_table,
            Text(
                "Multi-modal minus the best single modality at each size, paired per group, "
                "with its 95 % bootstrap interval over groups:"
            ),
            _margins_table,
        ),
        Curves(
            x="samples", label="modalities", panel="action", xlabel="training samples per object"
        ),
        learners=False,
    ),
    further_files=_save_hyperparameters,
)
