"""File names of the dataset layout, shared by the recorder and the replay side."""

from __future__ import annotations

import re
from pathlib import Path

from schemas._metadata import check_id
from schemas.errors import ContractError

#: Suffix of a finished recording.
RECORDING_SUFFIX = ".mcap"
#: Suffix of a recording being written (renamed to its final name when complete).
PART_SUFFIX = ".mcap.part"
#: Suffix of a file salvaged from an incomplete or damaged recording.
RECOVERED_SUFFIX = ".recovered.mcap"
#: Where unfinished recordings of dead recorders are moved (``<dataset>/.incomplete/...``):
#: out of the way of the dataset, never deleted (``atikt-replay check FILE --recover``).
SET_ASIDE_DIR = ".incomplete"
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
    checked and moved into place by hand; an incomplete one is kept for inspection. Files
    under a hidden directory (``.listen/``: ``listen``'s journals) are not part of the dataset.
    """
    root = Path(root)
    return sorted(
        p
        for p in root.rglob(f"*{RECORDING_SUFFIX}")
        if is_recording(p) and not any(d.startswith(".") for d in p.relative_to(root).parts[:-1])
    )


def check_inside(root: Path, path: Path) -> Path:
    """Return ``path`` if it lies inside ``root`` once both are resolved (links followed).

    Every path builder that joins names to an output directory asserts this, so no name
    (``..``, an absolute path, a link in the tree) makes the project write outside it.

    Raises:
        ContractError: ``path`` resolves outside ``root``.
    """
    resolved_root, resolved = Path(root).resolve(), Path(path).resolve()
    if resolved != resolved_root and resolved_root not in resolved.parents:
        msg = (
            f"{path}: resolves to {resolved}, outside the output directory {resolved_root}; "
            "names in a dataset are plain ids and links must stay inside it"
        )
        raise ContractError(msg)
    return Path(path)


def recording_path(root: Path, object_id: str, action_id: str, trial: int) -> Path:
    """Return where a dataset keeps trial ``trial`` of ``action_id`` on ``object_id``.

    ``<root>/<object>/<action>/<trial:03d>.mcap``; both ids follow the id rule and the
    path is checked to lie inside ``root``.

    Raises:
        ContractError: An id breaks the id rule, or the path resolves outside ``root``.
    """
    name = f"{trial:03d}{RECORDING_SUFFIX}"
    path = Path(root) / check_id("object", object_id) / check_id("action", action_id) / name
    return check_inside(root, path)
