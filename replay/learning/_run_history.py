"""A learning run's history (``<run>/history.parquet``) with the names of its map's axes.

``atikt-replay learn`` writes one row per step: step 0 is the state after the initial
observations, every later row one decision (object, action, explored, prior, rho, modality
weights, the entropy map before the decision, accuracies after the update, and
``metric_share``: the share of all new objects' classifiers fitted under metric transfer, the
old objects' kernel as their hyperprior's centre; ``metrics`` per new object of the action).
The entropy map is a list of lists, actions x objects, in the learner's order; the history
does not store that order, so it is recovered from the history itself:

- actions: the order of the ``accuracy_<action>`` columns (the run scores its actions in the
  learner's order);
- objects: each decision's ``uncertainty`` is the map's entry of the chosen (action, object),
  so matching it in the map's row of the action names that column. Columns never chosen keep
  the label ``object <index>``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import polars as pl

from replay.errors import ReplayError

if TYPE_CHECKING:
    from collections.abc import Sequence

#: File name of a run's history inside a learn output directory.
HISTORY_NAME = "history.parquet"
#: The run's settings beside its history: objects and actions in label order, seed, ...
SETTINGS_NAME = "run.json"
_REQUIRED = ("step", "object", "action", "explored", "prior", "rho", "accuracy")


@dataclass(frozen=True, slots=True)
class LearnRun:
    """One learning run, read from its output directory.

    Attributes:
        path: The run's directory (or its history file).
        frame: The history, one row per step, sorted by step.
        actions: Action ids, in the order of the entropy map's rows.
        objects: New-object ids, in the order of the entropy map's columns.
    """

    path: Path
    frame: pl.DataFrame
    actions: tuple[str, ...]
    objects: tuple[str, ...]

    @property
    def decisions(self) -> pl.DataFrame:
        """Return the rows of the decisions (every step after step 0)."""
        return self.frame.filter(pl.col("step") > 0)


def is_run_directory(path: Path) -> bool:
    """Return True if ``path`` is a learn output directory (it holds a history)."""
    return (Path(path) / HISTORY_NAME).is_file()


def _actions(frame: pl.DataFrame) -> tuple[str, ...]:
    """Return the actions in the order of the ``accuracy_<action>`` columns."""
    return tuple(c.removeprefix("accuracy_") for c in frame.columns if c.startswith("accuracy_"))


def _map_width(frame: pl.DataFrame) -> int:
    """Return the number of objects (columns) of the entropy maps, 0 if there are none."""
    if "entropies" not in frame.columns:
        return 0
    maps = [m for m in frame["entropies"].to_list() if m]
    return max((len(row) for m in maps for row in m), default=0)


def _object_columns(frame: pl.DataFrame, actions: Sequence[str]) -> dict[int, str]:
    """Return map column -> object id, found where a decision's uncertainty sits in the map."""
    columns: dict[int, str] = {}
    if "uncertainty" not in frame.columns or "entropies" not in frame.columns:
        return columns
    for row in frame.filter(pl.col("step") > 0).iter_rows(named=True):
        if row["action"] not in actions or not row["entropies"]:
            continue
        values = row["entropies"][actions.index(row["action"])]
        hits = [i for i, v in enumerate(values) if _same(v, row["uncertainty"])]
        if len(hits) == 1:
            columns.setdefault(hits[0], row["object"])
    return columns


def _same(a: Any, b: Any) -> bool:  # noqa: ANN401 (floats or None from the table)
    """Return True if two table values are the same number (the map's value is copied)."""
    return a is not None and b is not None and float(a) == float(b)


def _objects(frame: pl.DataFrame, actions: Sequence[str]) -> tuple[str, ...]:
    """Return the object label of every entropy-map column (see the module docstring)."""
    found = _object_columns(frame, actions)
    width = max(_map_width(frame), len(found))
    return tuple(found.get(i, f"object {i}") for i in range(width))


def _read(path: Path) -> pl.DataFrame:
    """Read a history file.

    Raises:
        ReplayError: The file is missing, unreadable or lacks a required column.
    """
    try:
        frame = pl.read_parquet(path, glob=False)
    except (OSError, pl.exceptions.PolarsError) as err:
        msg = f"{path}: cannot read the run's history ({err}); run atikt-replay learn again"
        raise ReplayError(msg) from err
    if missing := [c for c in _REQUIRED if c not in frame.columns]:
        msg = (
            f"{path}: not a learn history (no column {', '.join(missing)}); give the --out "
            "directory of atikt-replay learn"
        )
        raise ReplayError(msg)
    return frame.sort("step")


def load_run(path: Path) -> LearnRun:
    """Read a learning run from its output directory (or its ``history.parquet``).

    Args:
        path: The ``--out`` directory of ``atikt-replay learn``, or the history file itself.

    Returns:
        The run with the labels of its entropy map.

    Raises:
        ReplayError: No readable history at ``path``.
    """
    path = Path(path)
    history = path / HISTORY_NAME if path.is_dir() else path
    frame = _read(history)
    settings = _settings(history.with_name(SETTINGS_NAME))
    if settings is not None:
        actions, objects = tuple(settings["actions"]), tuple(settings["new_objects"])
        return LearnRun(path=path, frame=frame, actions=actions, objects=objects)
    actions = _actions(frame)
    return LearnRun(path=path, frame=frame, actions=actions, objects=_objects(frame, actions))


def _settings(path: Path) -> dict[str, Any] | None:
    """Return the run's settings (``run.json`` written by ``learn``), None for older runs."""
    try:
        settings: dict[str, Any] = json.loads(path.read_text("utf-8"))
    except (OSError, ValueError):
        return None
    if not {"actions", "new_objects"} <= settings.keys():
        return None
    return settings
