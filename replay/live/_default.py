"""The default simulated dataset: recorded by the recorder on first use, reused after."""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Any

from recorder import (
    SIMULATOR_VERSION,
    RecorderError,
    generate_dataset,
    load_actions,
    load_objects,
    plan_dataset,
    rig_factory,
    software_version,
)
from replay.errors import ReplayError
from replay.learning._datasets import DEFAULT_SEED, cache_root
from schemas import SCHEMA_VERSION, SET_ASIDE_DIR

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

_DONE = ".complete"


def default_dataset_dir(seed: int = DEFAULT_SEED) -> Path:
    """Return where the default simulated dataset of ``seed`` lives."""
    name = f"sim{SIMULATOR_VERSION}-seed{seed}-schema{SCHEMA_VERSION}-v{software_version()}"
    return cache_root() / name


def default_dataset_ready(seed: int = DEFAULT_SEED) -> bool:
    """Return True if the default simulated dataset of ``seed`` is complete (nothing to record)."""
    return (default_dataset_dir(seed) / _DONE).exists()


def ensure_default_dataset(
    *,
    seed: int = DEFAULT_SEED,
    workers: int | None = None,
    on_progress: Callable[[int, int], Any] | None = None,
) -> Path:
    """Return the default simulated dataset, recording it first if it is not complete.

    Generation resumes where an interrupted one stopped: finished recordings are kept.

    Raises:
        ReplayError: The recording failed; the message says why.
    """
    root = default_dataset_dir(seed)
    if (root / _DONE).exists():
        return root
    tasks = plan_dataset(load_objects(), load_actions())
    done = 0

    def progress(_result: object) -> None:
        nonlocal done
        done += 1
        if on_progress is not None:
            on_progress(done, len(tasks))

    try:
        report = generate_dataset(
            tasks,
            root,
            rig_factory("sim"),
            seed=seed,
            workers=workers,
            on_result=progress,
            durable=False,  # a cache recorded again from its seed: synced once, at the end
        )
    except RecorderError as err:
        msg = f"{root}: recording the default dataset failed ({err})"
        raise ReplayError(msg) from err
    if report.set_aside:
        print(  # noqa: T201 (generated on first use, outside any command's own output)
            f"{len(report.set_aside)} unfinished recordings of stopped runs moved to "
            f"{root / SET_ASIDE_DIR}; their trials were recorded again",
            file=sys.stderr,
        )
    if report.incomplete:
        msg = (
            f"{root}: {len(report.incomplete)} recordings are being written by another "
            "running recorder; run again when it has finished"
        )
        raise ReplayError(msg)
    (root / _DONE).write_text(f"{report.written + report.skipped} recordings\n", "utf-8")
    return root
