"""File names of the dataset layout, shared by the recorder and the replay side."""

from __future__ import annotations

import contextlib
import os
import re
from pathlib import Path
from typing import TYPE_CHECKING

from schemas._metadata import check_id
from schemas.errors import ContractError

if TYPE_CHECKING:
    from collections.abc import Iterator

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


#: A recorder's temporary name: ``<trial>.<pid>-<token>.mcap.part`` (recorder.writing).
_PART_NAME = re.compile(r"\.(\d+)-[0-9a-f]+" + re.escape(PART_SUFFIX) + "$")


def part_writer(path: Path) -> int | None:
    """Return the process id in an unfinished recording's name (None: it names none)."""
    match = _PART_NAME.search(Path(path).name)
    return int(match.group(1)) if match else None


def process_running(pid: int | None) -> bool:
    """Return whether process ``pid`` exists on this computer (this process counts; None never).

    An unfinished recording whose writer runs is being written now; one whose writer is gone
    was left by a recorder that stopped.
    """
    if pid is None or not 0 < pid < 2**31:  # a name's number that is no process id
        return False
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, OverflowError):
        return False
    except PermissionError:  # another user's process
        return True
    return True


#: The claim of a dataset directory (its seed and rig configuration), written by the first run
#: recording into it (``recorder._claim``); a run recording into it holds a shared lock on it.
CLAIM_NAME = ".atikt-dataset.json"


@contextlib.contextmanager
def recording_into(root: Path) -> Iterator[None]:
    """Hold a shared lock on the dataset's claim while a run records into it (POSIX ``flock``).

    A reader (``atikt-replay check``) then sees that a recorder is at work: its unfinished
    files and an index that lags behind the recordings are expected. The lock goes with the
    process, however it ends; several runs may hold it together. Without ``fcntl`` or a claim,
    nothing is held.
    """
    descriptor = _open_claim(Path(root))
    if descriptor is None:
        yield
        return
    try:
        import fcntl  # noqa: PLC0415 (POSIX only)

        with contextlib.suppress(OSError):  # a file system without locks: nothing held
            fcntl.flock(descriptor, fcntl.LOCK_SH)
        yield
    finally:
        os.close(descriptor)  # releases the lock


def recorder_at_work(root: Path) -> bool:
    """Return whether a run records into the dataset ``root`` now (holds :func:`recording_into`)."""
    descriptor = _open_claim(Path(root))
    if descriptor is None:
        return False
    try:
        import fcntl  # noqa: PLC0415 (POSIX only)

        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:  # a file system without locks: not known, so not at work
        return False
    finally:
        os.close(descriptor)  # releases the lock taken to test
    return False


def _open_claim(root: Path) -> int | None:
    """Open the dataset's claim for locking (None: no claim, or no ``fcntl`` here)."""
    try:
        import fcntl  # noqa: F401, PLC0415 (POSIX only)
    except ImportError:  # pragma: no cover (Windows)
        return None
    try:
        return os.open(root / CLAIM_NAME, os.O_RDONLY)
    except OSError:
        return None


def unreadable(
    path: Path, err: OSError, fix: str = "check the file's permissions", what: str = ""
) -> str:
    """Return why ``path`` cannot be read, one line naming the fix (``err``: what reading raised).

    A symbolic link whose target is gone (a dataset copied without the files its links point
    to) names the link and the missing target: "check the file's permissions" would send the
    user looking at a file that does not exist.

    Args:
        path: The file that could not be read.
        err: The error opening or reading it raised.
        fix: The fix for any other error.
        what: What could not be read, in the message (``the recording``; default: nothing).
    """
    path = Path(path)
    if path.is_symlink() and not path.exists():
        target = path.parent / path.readlink()
        return (
            f"{path}: a symbolic link to {target}, which does not exist: remove the link or "
            f"restore {target}"
        )
    return f"{path}: cannot read{f' {what}' if what else ''} ({err.strerror or err}); {fix}"


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


#: Files that mark a dataset directory: its index (``atikt-record index``), its claim and its
#: object declarations.
DATASET_MARKERS = ("index.parquet", CLAIM_NAME, "objects.toml")


def enclosing_dataset(path: Path, said: tuple[str, str] | None = None) -> Path | None:
    """Return the dataset directory holding the recording ``path`` (None: it lies in none).

    A recording of a dataset lies at ``<root>/<object>/<action>/<trial>.mcap``: ``<root>`` is
    its dataset when it holds one of :data:`DATASET_MARKERS`, or when the two directories
    above the file are the object and action its metadata says (``said``; a file two levels
    below some directory is not a dataset's for its depth alone). Outputs (``view --save``,
    ``export --out``) must not be written into it. Links are resolved first.
    """
    full = Path(path).resolve()
    if len(full.parents) < 3:  # noqa: PLR2004 (<root>/<object>/<action>/<trial>.mcap)
        return None
    root = full.parents[2]
    if any((root / marker).exists() for marker in DATASET_MARKERS):
        return root
    laid_out = said is not None and (full.parents[1].name, full.parent.name) == tuple(said)
    return root if laid_out else None


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
