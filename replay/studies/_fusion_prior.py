"""The fusion study's prior: the multi-modal kernel's hyperparameters from outside a group.

Where the fusion study's multi-modal kernel starts and what prior holds it there: the
hyperparameters fitted on the other objects of the dataset (``reference_theta``), those an
earlier fusion study saved (``hyperparameters.json``, written by :func:`write_hyperparameters`
and read by :func:`load_hyperparameters`), or the sensors' declared noise (``declared_noise``).
"""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING, Any

import polars as pl

from atikt import FEATURE_BLOCKS, MultiModalGPC
from atikt.kernels import fusion_kernel
from replay.errors import ReplayError
from replay.learning._executors import FeatureLookup
from replay.recording._reader import read_recording
from replay.studies._running import REFERENCE_SAMPLES, dataset_actions, derive_seed
from schemas import VOCABULARY, atomic_write_text

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence
    from pathlib import Path

    import numpy as np

    from replay.studies._running import StudyConfig

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

    In the order ``atikt.FeatureTransformer`` stacks the modalities (``atikt.FEATURE_BLOCKS``).
    """
    held = [m for m in FEATURE_BLOCKS if m in lookup.blocks[action]]
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


def kernel_record(
    combination: str = "sum", parts: Sequence[tuple[str, str]] = ()
) -> dict[str, Any]:
    """Return the multi-modal kernel's form as ``hyperparameters.json`` records it.

    The hyperparameter names do not tell an RBF part from a Matern part, so the form is
    written out: a file fitted with one form is refused as the prior of another.
    """
    return {"combination": combination, "parts": dict(sorted(parts))}


def _kernel_text(kernel: Mapping[str, Any]) -> str:
    parts = ", ".join(f"{k}={v}" for k, v in kernel["parts"].items()) or "RBF parts"
    return f"--fusion-kernel {kernel['combination']} ({parts})"


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
        seed = derive_seed(config.seed, action, "saved")
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
        "kernel": kernel_record(config.fusion_kernel, config.fusion_parts),
        "seed": config.seed,
        "use": "atikt-replay study fusion --fusion-prior THIS_FILE (log hyperparameters of the "
        "multi-modal kernel, the prior's centre)",
        "actions": actions,
    }
    path = config.out / HYPERPARAMETERS
    atomic_write_text(path, json.dumps(document, indent=1) + "\n")
    return path


def load_hyperparameters(
    path: Path, kernel: Mapping[str, Any] | None = None
) -> dict[str, tuple[tuple[str, ...], tuple[float, ...]]]:
    """Read a fusion study's ``hyperparameters.json``: per action, names and log values.

    ``kernel``: the form of the multi-modal kernel they are to centre (``kernel_record``); a
    file that records another form is refused (files without the record are taken as they are).

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
    recorded = document.get("kernel")
    if kernel is not None and recorded is not None and recorded != kernel:
        shown = _kernel_text(recorded) if _is_kernel_record(recorded) else repr(recorded)
        msg = (
            f"--fusion-prior {path}: it was fitted with {shown}, this study uses "
            f"{_kernel_text(kernel)}; run both with the same --fusion-kernel and --fusion-parts"
        )
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


def _is_kernel_record(value: object) -> bool:
    return (
        isinstance(value, dict)
        and isinstance(value.get("combination"), str)
        and isinstance(value.get("parts"), dict)
    )


def saved_thetas(
    frame: pl.DataFrame, config: StudyConfig, path: Path
) -> dict[str, tuple[float, ...]]:
    """Return the saved hyperparameters of each of the study's actions, checked against it.

    Raises:
        ReplayError: The file lacks an action, or its kernel has other modalities.
    """
    saved = load_hyperparameters(path, kernel_record(config.fusion_kernel, config.fusion_parts))
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
