"""Where datasets live: the default simulated dataset, made on first use and reused after."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from replay.errors import ReplayError

if TYPE_CHECKING:
    from collections.abc import Callable

#: Seed of the default simulated dataset.
DEFAULT_SEED = 0
_DONE = ".complete"


def cache_root() -> Path:
    """Return the cache directory: ``$ATIKT_CACHE``, else ``$XDG_CACHE_HOME/atikt``."""
    if configured := os.environ.get("ATIKT_CACHE"):
        return Path(configured)
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "atikt"


def default_dataset_dir(seed: int = DEFAULT_SEED) -> Path:
    """Return where the default simulated dataset of ``seed`` lives."""
    from recorder import software_version  # noqa: PLC0415 (generation is the recorder's job)
    from schemas import SCHEMA_VERSION  # noqa: PLC0415

    return cache_root() / f"sim-seed{seed}-schema{SCHEMA_VERSION}-v{software_version()}"


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
    from recorder import (  # noqa: PLC0415 (recording is live execution)
        RecorderError,
        generate_dataset,
        load_actions,
        load_objects,
        plan_dataset,
        rig_factory,
    )

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
            tasks, root, rig_factory("sim"), seed=seed, workers=workers, on_result=progress
        )
    except RecorderError as err:
        msg = f"{root}: recording the default dataset failed ({err})"
        raise ReplayError(msg) from err
    if report.incomplete:
        msg = f"{root}: {len(report.incomplete)} recordings are incomplete; run again to resume"
        raise ReplayError(msg)
    (root / _DONE).write_text(f"{report.written + report.skipped} recordings\n", "utf-8")
    return root
