"""Datasets: where the cache lives, object declarations and the roles of a run's objects.

The default simulated dataset is recorded by ``replay.live`` (the recorder's side) under
:func:`cache_root`.
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from replay.errors import ReplayError
from schemas import load_toml

if TYPE_CHECKING:
    from collections.abc import Sequence

#: Seed of the default simulated dataset.
DEFAULT_SEED = 0


def cache_root() -> Path:
    """Return the cache directory: ``$ATIKT_CACHE``, else ``$XDG_CACHE_HOME/atikt``."""
    if configured := os.environ.get("ATIKT_CACHE"):
        return Path(configured)
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "atikt"


#: A dataset's object declarations (``<dataset>/objects.toml``): per object id a table with
#: ``name``, ``description`` and ``novel`` (the default role: new, or old = prior knowledge).
#: Written by ``atikt-record dataset`` and ``import-bag``; which objects are new is chosen per
#: run (``--new``, ``--priors``) with these flags as the default.
OBJECTS_FILE = "objects.toml"


@dataclass(frozen=True, slots=True)
class Roles:
    """Which objects of a dataset a run learns (new) and may transfer from (old).

    Attributes:
        new: New objects, sorted.
        old: Old objects (the candidates for priors), sorted.
    """

    new: tuple[str, ...]
    old: tuple[str, ...]


def declared_novel(root: Path) -> set[str]:
    """Return the objects a dataset's ``objects.toml`` flags as new (none without the file).

    Raises:
        ReplayError: The file is not valid TOML or a flag is not a boolean.
    """
    path = Path(root) / OBJECTS_FILE
    if not path.is_file():
        return set()
    try:
        table = load_toml(path)
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as err:
        msg = f"{path}: cannot read the object declarations ({err}); fix or delete the file"
        raise ReplayError(msg) from err
    novel = set()
    for object_id, entry in table.items():
        flag = entry.get("novel", False) if isinstance(entry, dict) else None
        if not isinstance(flag, bool):
            msg = f"{path}: [{object_id}] novel = {flag!r} is not true or false; fix the entry"
            raise ReplayError(msg)
        if flag:
            novel.add(object_id)
    return novel


def check_names(option: str, names: Sequence[str], known: Sequence[str]) -> tuple[str, ...]:
    """Return ``names`` if every one is in ``known``.

    Raises:
        ReplayError: An unknown name; the message lists the known ones.
    """
    if unknown := [name for name in names if name not in known]:
        msg = (
            f"{option} {','.join(unknown)}: not in the dataset; it has "
            f"{', '.join(sorted(known)) or 'none'}"
        )
        raise ReplayError(msg)
    if len(set(names)) != len(names):
        msg = f"{option} {','.join(names)}: a name is given twice"
        raise ReplayError(msg)
    return tuple(names)


def dataset_roles(
    root: Path,
    objects: Sequence[str],
    new: Sequence[str] | None = None,
    priors: Sequence[str] | None = None,
) -> Roles:
    """Return the run's roles: the options where given, else the dataset's declarations.

    Args:
        root: The dataset (its ``objects.toml`` gives the default new objects).
        objects: The objects the dataset has.
        new: ``--new`` (None: the declared new objects).
        priors: ``--priors`` (None: every object that is not new).

    Raises:
        ReplayError: An unknown object, or an object both new and prior.
    """
    known = sorted(set(objects))
    chosen_new = (
        check_names("--new", new, known)
        if new is not None
        else tuple(o for o in known if o in declared_novel(root))
    )
    chosen_old = (
        check_names("--priors", priors, known)
        if priors is not None
        else tuple(o for o in known if o not in chosen_new)
    )
    if both := sorted(set(chosen_new) & set(chosen_old)):
        msg = f"{', '.join(both)}: both new (--new) and prior (--priors); give each object one role"
        raise ReplayError(msg)
    return Roles(tuple(sorted(chosen_new)), tuple(sorted(chosen_old)))
