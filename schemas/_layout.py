"""File names of the dataset layout, shared by the recorder and the replay side."""

from __future__ import annotations

from pathlib import Path

#: Suffix of a finished recording.
RECORDING_SUFFIX = ".mcap"
#: Suffix of a recording being written (renamed to its final name when complete).
PART_SUFFIX = ".mcap.part"
#: Suffix of a file salvaged from an incomplete or damaged recording.
RECOVERED_SUFFIX = ".recovered.mcap"
#: Where unfinished recordings of dead recorders are moved (``<dataset>/.incomplete/...``):
#: out of the way of the dataset, never deleted (``atikt-replay check FILE --recover``).
SET_ASIDE_DIR = ".incomplete"


def is_recording(path: Path) -> bool:
    """Return whether ``path`` names a finished recording of a dataset (not a salvaged file)."""
    name = path.name
    return name.endswith(RECORDING_SUFFIX) and not name.endswith(RECOVERED_SUFFIX)


def dataset_recordings(root: Path) -> list[Path]:
    """Return the finished recordings under a dataset directory, sorted by path.

    Salvaged files (``*.recovered.mcap``) and unfinished ones (``*.mcap.part``) are not
    recordings of the dataset: a salvaged file is checked and moved into place by hand.
    """
    return sorted(p for p in Path(root).rglob(f"*{RECORDING_SUFFIX}") if is_recording(p))
