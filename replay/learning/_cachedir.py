"""Where a dataset's feature cache lives: beside the data, or in the user's cache.

The cache is written next to the recordings (``<dataset>/features.parquet``) only where that
is harmless: the directory is writable and its files are not tracked by a version-controlled
checkout (``learn --recordings recordings/data`` must not add files to the repository).
Otherwise it lives in the user's cache (``$ATIKT_CACHE``, else ``$XDG_CACHE_HOME/atikt``),
under a directory named after the dataset and keyed by the SHA-256 of its absolute path, so
two datasets never share a cache.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
from pathlib import Path

from replay.learning._datasets import cache_root

#: File name of the feature cache.
FEATURES_NAME = "features.parquet"
#: Directory of the user cache that holds caches of datasets that cannot hold their own.
FEATURES_DIR = "features"
#: Seconds ``git ls-files`` may take before the dataset is treated as tracked.
GIT_TIMEOUT_S = 10


def _work_tree(directory: Path) -> Path | None:
    """Return the nearest directory at or above ``directory`` holding ``.git``, or None."""
    for candidate in (directory, *directory.parents):
        if (candidate / ".git").exists():
            return candidate
    return None


def is_tracked(directory: Path) -> bool:
    """Return True if files of ``directory`` are tracked by a git checkout around it.

    Without git installed (or when git fails, e.g. an unsafe repository), a ``.git`` above
    the directory is taken as tracked: the cache then goes to the user cache, which is safe.
    """
    directory = directory.resolve()
    if _work_tree(directory) is None:
        return False
    git = shutil.which("git")
    if git is None:
        return True
    try:
        done = subprocess.run(  # noqa: S603 (a fixed command on a local directory)
            [git, "-C", str(directory), "ls-files", "-z", "--", "."],
            capture_output=True,
            timeout=GIT_TIMEOUT_S,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return True
    return done.returncode != 0 or bool(done.stdout)


def feature_cache_path(root: Path) -> Path:
    """Return where the feature cache of the dataset at ``root`` is read and written."""
    directory = Path(root).resolve()
    if os.access(directory, os.W_OK | os.X_OK) and not is_tracked(directory):
        return directory / FEATURES_NAME
    key = hashlib.sha256(str(directory).encode("utf-8", "surrogateescape")).hexdigest()[:16]
    return cache_root() / FEATURES_DIR / f"{directory.name[:64] or 'root'}-{key}" / FEATURES_NAME
