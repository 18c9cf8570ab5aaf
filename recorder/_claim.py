"""A dataset directory claimed by one seed and rig configuration, atomically.

Two recorders started together into one empty directory both find no recording, so a check of
the recordings (:func:`recorder._dataset.check_configuration`) lets both in, and the directory
ends up holding two datasets. The first run into a directory therefore *claims* it: it writes
``.atikt-dataset.json`` (the seed and the rig configuration) to a temporary file and links it
to that name, which fails when the name exists (``os.link`` never replaces), so exactly one of
two runs started together creates the claim, and the other reads a whole claim and is refused
unless it has the same seed and configuration (a resumed run, or a second worker of the same
dataset). The claim is never removed by the program; a directory without recordings can be
reused with another seed by deleting it.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

from recorder.errors import RecorderError
from recorder.runner._limits import MOTION_PREFIX
from schemas import CLAIM_NAME, recorder_at_work

if TYPE_CHECKING:
    from collections.abc import Mapping

__all__ = ["CLAIM_NAME", "check_writable", "claim_dataset", "differing_settings"]

#: Settings (by prefix) that rig descriptions gained after datasets were recorded without
#: them; see :func:`differing_settings`.
_ADDED = (MOTION_PREFIX,)


def _claim_text(seed: int, configuration: Mapping[str, Any]) -> str:
    """Return the claim's JSON text (sorted keys: equal claims are equal bytes)."""
    return json.dumps({"seed": seed, "rig": dict(configuration)}, sort_keys=True, default=str)


def _publish(root: Path, text: str) -> bool:
    """Link a new claim to its name; return False when a claim exists already.

    Raises:
        RecorderError: The directory cannot be written.
    """
    target = root / CLAIM_NAME
    try:
        root.mkdir(parents=True, exist_ok=True)
        handle, name = tempfile.mkstemp(prefix=f"{CLAIM_NAME}.", suffix=".tmp", dir=root)
        temporary = Path(name)
        with os.fdopen(handle, "w", encoding="utf-8") as stream:
            stream.write(text)
            stream.flush()
            os.fsync(stream.fileno())
        try:
            os.link(temporary, target)  # atomic, and fails if the name exists
        except FileExistsError:
            return False
        finally:
            with contextlib.suppress(OSError):
                temporary.unlink()
    except OSError as err:
        raise RecorderError(_unclaimable(root, err)) from err
    return True


def _unclaimable(root: Path, err: OSError) -> str:
    """Return the one line for a dataset directory that cannot be claimed (``err``: why)."""
    if root.exists() and not root.is_dir():
        return f"--out {root}: is a file, not a directory; give a directory (new or a dataset)"
    return f"{root / CLAIM_NAME}: cannot claim the dataset directory ({err.strerror}); check --out"


def check_writable(root: Path) -> None:
    """Refuse, as :func:`claim_dataset` would, a directory the run could not write into.

    A dry run writes nothing, so it creates and removes a temporary file in ``root``, or in its
    first existing parent when ``root`` is to be made (a read-only file system, a directory of
    another user): the real run would be refused there, after its dry run said ready.

    Raises:
        RecorderError: The same line :func:`claim_dataset` gives.
    """
    root = Path(root)
    where = root
    while not where.exists() and where != where.parent:
        where = where.parent
    try:
        if not where.is_dir():
            raise NotADirectoryError(errno.ENOTDIR, os.strerror(errno.ENOTDIR), str(where))
        handle, name = tempfile.mkstemp(prefix=f"{CLAIM_NAME}.", suffix=".tmp", dir=where)
        os.close(handle)
        Path(name).unlink()
    except OSError as err:
        raise RecorderError(_unclaimable(root, err)) from err


def _read_claim(path: Path) -> dict[str, Any]:
    """Return a claim's seed and rig.

    Raises:
        RecorderError: The claim cannot be read or is not a claim.
    """
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        if not isinstance(data, dict) or not isinstance(data.get("rig"), dict):
            msg = "not a claim"
            raise TypeError(msg)  # noqa: TRY301 (one translation below)
        int(data["seed"])
    except (OSError, ValueError, TypeError, KeyError) as err:
        msg = (
            f"{path}: the dataset's claim cannot be read ({err}); it names the seed and rig "
            "configuration of the directory's recordings: restore it or give another --out"
        )
        raise RecorderError(msg) from err
    return data


def claim_dataset(root: Path, seed: int, configuration: Mapping[str, Any]) -> None:
    """Claim ``root`` for ``seed`` and ``configuration``, or accept an equal claim.

    Args:
        root: The dataset directory (created if needed).
        seed: The run's dataset seed.
        configuration: The rig's configuration as it describes itself before connecting
            (its identity; facts learned on connection are recorded, not compared).

    Raises:
        RecorderError: Another run with another seed or configuration claimed the directory
            (one line naming both and the fix), or the claim cannot be written or read.
    """
    root = Path(root)
    text = _claim_text(seed, configuration)
    if _publish(root, text):
        return
    _compare(root, _read_claim(root / CLAIM_NAME), json.loads(text), seed)


def check_claim(root: Path, seed: int, configuration: Mapping[str, Any]) -> None:
    """Refuse as :func:`claim_dataset` does, writing nothing (an unclaimed directory passes).

    Raises:
        RecorderError: Another seed or configuration claimed the directory, or its claim
            cannot be read.
    """
    path = Path(root) / CLAIM_NAME
    if path.exists():
        _compare(Path(root), _read_claim(path), json.loads(_claim_text(seed, configuration)), seed)


def _unused(root: Path) -> str:
    """Return how to take over a claimed directory that holds no recording yet ('' if it does).

    A run refused before its first recording (a rig not ready, a skin on the wrong port) leaves
    its claim: a run with a corrected configuration is told how to take the directory. Not
    while a run records into it (it holds :func:`schemas.recording_into`): its first
    recording may be seconds away, and a claim deleted under it would let this run in.
    """
    if recorder_at_work(root):
        return f": a recorder is writing into {root} now"
    recordings = (
        path for path in root.glob("*/*/*.mcap") if not path.name.endswith(".incomplete.mcap")
    )
    if next(recordings, None) is not None:
        return ""
    return f", or delete {root / CLAIM_NAME}: the directory holds no recording yet"


def differing_settings(theirs: Mapping[str, object], ours: Mapping[str, object]) -> list[str]:
    """Return the settings in which two rig descriptions differ, sorted.

    A setting added to the descriptions later (the ``motion.*`` settings) is
    compared only when ``theirs`` (recorded earlier) has it: a dataset recorded before it was
    part of a rig's identity still resumes.
    """
    keys = {*theirs, *ours}
    for added in _ADDED:
        if not any(key.startswith(added) for key in theirs):
            keys = {key for key in keys if not key.startswith(added)}
    return sorted(key for key in keys if theirs.get(key) != ours.get(key))


def _compare(root: Path, claim: Mapping[str, Any], ours: Mapping[str, Any], seed: int) -> None:
    """Refuse a claim of another seed or rig configuration than ``ours``."""
    if claim["seed"] != seed:
        msg = (
            f"{root}: is claimed by a run with seed {claim['seed']} ({root / CLAIM_NAME}), "
            f"this run has --seed {seed}; a dataset holds one seed: give another --out, or "
            f"--seed {claim['seed']} to resume it{_unused(root)}"
        )
        raise RecorderError(msg)
    if differ := differing_settings(claim["rig"], ours["rig"]):
        theirs = ", ".join(f"{k}={claim['rig'].get(k)!r}" for k in differ)
        wanted = ", ".join(f"{k}={ours['rig'].get(k)!r}" for k in differ)
        msg = (
            f"{root}: is claimed by another rig configuration ({theirs}; this run: {wanted}; "
            f"{root / CLAIM_NAME}); give another --out{_unused(root)}"
        )
        raise RecorderError(msg)
