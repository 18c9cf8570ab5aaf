"""File names of the dataset layout, shared by the recorder and the replay side."""

from __future__ import annotations

import re
from pathlib import Path

#: Suffix of a finished recording.
RECORDING_SUFFIX = ".mcap"
#: Suffix of a recording being written (renamed to its final name when complete).
PART_SUFFIX = ".mcap.part"
#: Suffix of a file salvaged from an incomplete or damaged recording.
RECOVERED_SUFFIX = ".recovered.mcap"
#: Suffix of a recording that a stop ended early (protective stop, lost connection...): it
#: keeps what arrived and is never taken as a recording of the dataset (``.incomplete-2.mcap``
#: and so on when the same trial stopped again).
INCOMPLETE_SUFFIX = ".incomplete.mcap"
#: Name of the metadata record that marks a recording as ended early, and why.
INCOMPLETE_RECORD = "atikt.incomplete"
_INCOMPLETE = re.compile(r"\.incomplete(-[0-9]+)?\.mcap$")


def is_incomplete(path: Path) -> bool:
    """Return whether ``path`` names a recording that a stop ended early."""
    return _INCOMPLETE.search(Path(path).name) is not None


def is_recording(path: Path) -> bool:
    """Return whether ``path`` names a finished recording of a dataset (not a salvaged file)."""
    name = path.name
    return (
        name.endswith(RECORDING_SUFFIX)
        and not name.endswith(RECOVERED_SUFFIX)
        and not is_incomplete(path)
    )


def dataset_recordings(root: Path) -> list[Path]:
    """Return the finished recordings under a dataset directory, sorted by path.

    Salvaged files (``*.recovered.mcap``), unfinished ones (``*.mcap.part``) and those a stop
    ended early (``*.incomplete.mcap``) are not recordings of the dataset: a salvaged file is
    checked and moved into place by hand; an incomplete one is kept for inspection.
    """
    return sorted(p for p in Path(root).rglob(f"*{RECORDING_SUFFIX}") if is_recording(p))
