"""Action windows of a bag import: from an annotation topic or a CSV, checked, given paths.

A window is one action execution: its object, action, trial and the stamps (integer ns) at
which its phases start; it covers ``[first phase, end)``. Windows never overlap (an import
refuses two that do, naming both). CSV times are parsed as integers (``ns``) or as decimals
(``s``, ``ms``, ``us``), never through binary floats.
"""

from __future__ import annotations

import csv
import itertools
import json
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import TYPE_CHECKING

from recorder._dataset import recording_path
from recorder.bagimport._topicmap import TIME_UNITS
from recorder.errors import BagImportError
from schemas import MAX_TRIAL, VOCABULARY, ContractError, check_id

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence

_PHASES = VOCABULARY.phases
_REQUIRED = VOCABULARY.sources["import"].phases
_CSV_COLUMNS = ("start", "stop", "object", "action")
#: Largest size of a windows CSV (a table of actions, not of samples).
MAX_CSV_BYTES = 64 * 1024 * 1024


@dataclass(frozen=True, slots=True)
class Window:
    """One annotated action: its object, action, trial and phase starts.

    Attributes:
        object_id: Object id (catalog or map).
        action_id: Action id (catalog or map).
        trial: Trial number, or None to number it on after the existing ones.
        events: (phase, start ns) in time order; the last one is ``end``.
        where: Where it was annotated (topic or CSV row), for messages.
    """

    object_id: str
    action_id: str
    trial: int | None
    events: tuple[tuple[str, int], ...]
    where: str = ""

    @property
    def start_ns(self) -> int:
        """Return the first phase's start."""
        return self.events[0][1]

    @property
    def stop_ns(self) -> int:
        """Return the end (exclusive)."""
        return self.events[-1][1]

    def phase_start(self, phase: str) -> int:
        """Return the start of ``phase`` (a phase the window has)."""
        return next(stamp for name, stamp in self.events if name == phase)

    def phase_stop(self, phase: str) -> int:
        """Return the end of ``phase``: the next phase's start."""
        start = self.phase_start(phase)
        return next(stamp for _, stamp in self.events if stamp > start)

    def describe(self) -> str:
        """Return the window for messages."""
        return (
            f"{self.where + ': ' if self.where else ''}window {self.object_id}/{self.action_id} "
            f"[{self.start_ns}, {self.stop_ns}) ns"
        )


def check_window(window: Window) -> Window:
    """Check ids, phase names and order, and the phases an import promises.

    Raises:
        BagImportError: An id is malformed or the phases are out of order or incomplete.
    """
    try:
        check_id("object", window.object_id)
        check_id("action", window.action_id)
    except ContractError as err:
        msg = f"{window.where}: {err}"
        raise BagImportError(msg) from err
    phases = [phase for phase, _ in window.events]
    ranks = [_PHASES.index(phase) if phase in _PHASES else -1 for phase in phases]
    stamps = [stamp for _, stamp in window.events]
    ordered = min(ranks, default=0) >= 0 and all(b > a for a, b in itertools.pairwise(ranks))
    increasing = all(b > a for a, b in itertools.pairwise(stamps))
    complete = all(p in phases for p in _REQUIRED) and phases[-1] == _PHASES[-1]
    if not (ordered and increasing and complete):
        listed = ", ".join(f"{p}@{s}" for p, s in window.events)
        msg = (
            f"{window.describe()} has phases {listed}; an action needs {' and '.join(_REQUIRED)}, "
            f"in the order {', '.join(_PHASES)}, at increasing times"
        )
        raise BagImportError(msg)
    return window


def _trial(value: object, where: str) -> int | None:
    """Return a trial number 1..MAX_TRIAL, or None for "number it on".

    Raises:
        BagImportError: Not a whole number in range.
    """
    if value is None or value == "":
        return None
    text = str(value).strip()
    if isinstance(value, bool) or not text.isdigit() or not 1 <= int(text) <= MAX_TRIAL:
        msg = f"{where}: trial = {value!r} is not a trial number 1..{MAX_TRIAL}; fix or empty it"
        raise BagImportError(msg)
    return int(text)


def check_no_overlap(windows: Sequence[Window]) -> list[Window]:
    """Return the windows sorted by start.

    Raises:
        BagImportError: Two windows overlap; the message names both.
    """
    ordered = sorted(windows, key=lambda w: w.start_ns)
    for a, b in itertools.pairwise(ordered):
        if b.start_ns < a.stop_ns:
            msg = (
                f"{b.describe()} overlaps {a.describe()}; a sample belongs to one action: "
                "fix the windows"
            )
            raise BagImportError(msg)
    return ordered


# ------------------------------------------------------------------------- annotation topic


_Key = tuple[str, str, int | None]


def parse_annotation(text: str, receive_ns: int, topic: str) -> tuple[_Key, str, int]:
    """Parse one annotation: ((object, action, trial), phase, stamp).

    Raises:
        BagImportError: The text is not the documented JSON object.
    """
    where = f"topic {topic} at {receive_ns} ns"
    example = '{"object": "wood", "action": "P1", "trial": 1, "phase": "execute"}'
    try:
        data = json.loads(text, parse_float=Decimal)
        if not isinstance(data, dict):
            msg = "not a JSON object"
            raise TypeError(msg)  # noqa: TRY301 (one translation below)
        phase = str(data["phase"])
        stamp = data.get("stamp_ns", receive_ns)
        if phase not in _PHASES:
            msg = f"phase {phase!r} is none of {', '.join(_PHASES)}"
            raise ValueError(msg)  # noqa: TRY301
        if isinstance(stamp, bool) or not isinstance(stamp, int):
            msg = f"stamp_ns {stamp!r} is not a whole number of ns"
            raise TypeError(msg)  # noqa: TRY301
        key = (str(data["object"]), str(data["action"]), _trial(data.get("trial"), where))
    except (ValueError, KeyError, TypeError, RecursionError) as err:
        reason = f"no key {err}" if isinstance(err, KeyError) else str(err) or repr(err)
        msg = f"{where}: annotation {text[:80]!r} ({reason}); annotations are JSON like {example}"
        raise BagImportError(msg) from err
    return key, phase, stamp


def _named(key: _Key) -> str:
    """Return an annotated action as ``object/action trial N`` (without a trial: no number)."""
    trial = f" trial {key[2]}" if key[2] is not None else ""
    return f"{key[0]}/{key[1]}{trial}"


class AnnotationGrouper:
    """Groups annotations into windows as they come: each window from its first phase to ``end``.

    The import feeds a bag's annotations in stamp order; ``listen`` feeds them as they arrive.
    """

    def __init__(self, topic: str) -> None:
        """Start with no open window."""
        self.topic = topic
        self._current: list[tuple[str, int]] = []
        self._key: _Key | None = None

    @property
    def open_start_ns(self) -> int | None:
        """Return the first stamp of the window being annotated (None: none is open)."""
        return self._current[0][1] if self._current else None

    @property
    def open_action(self) -> str | None:
        """Return the action id of the window being annotated (None: none is open)."""
        return self._key[1] if self._key is not None else None

    def add(self, key: _Key, phase: str, stamp: int) -> Window | None:
        """Add one parsed annotation; return the window it ends, if it is an ``end``.

        Raises:
            BagImportError: A phase of another action comes before this one's ``end``, or the
                window's phases are wrong.
        """
        if self._key is not None and key != self._key:
            msg = (
                f"topic {self.topic}: at {stamp} ns a phase of {_named(key)} starts before "
                f"the '{_PHASES[-1]}' of {_named(self._key)}; annotate an end for every action"
            )
            self._current, self._key = [], None
            raise BagImportError(msg)
        self._key = key
        self._current.append((phase, stamp))
        if phase != _PHASES[-1]:
            return None
        events, self._current, self._key = tuple(self._current), [], None
        return check_window(Window(*key, events, f"topic {self.topic}"))

    def abandon(self) -> tuple[_Key, tuple[tuple[str, int], ...]] | None:
        """Give up the window being annotated; return its key and phases (None: none open).

        ``listen`` keeps what arrived of an action it cuts (its ``end`` is overdue, or the
        run stops) as an incomplete recording; an ``end`` that comes later finds no open
        window and is refused with a line.
        """
        if self._key is None:
            return None
        key, events = self._key, tuple(self._current)
        self._current, self._key = [], None
        return key, events

    def close(self) -> None:
        """Refuse an action without its ``end``.

        Raises:
            BagImportError: A window is still open.
        """
        if self._key is not None:
            msg = f"topic {self.topic}: {_named(self._key)} has no '{_PHASES[-1]}' annotation"
            raise BagImportError(msg)


def windows_from_annotations(events: Iterable[tuple[str, int]], topic: str) -> list[Window]:
    """Group annotation texts (text, receive ns) into windows: first event to its ``end``.

    Raises:
        BagImportError: An annotation is malformed, or actions overlap or lack an end.
    """
    parsed = sorted((parse_annotation(t, r, topic) for t, r in events), key=lambda e: e[2])
    grouper = AnnotationGrouper(topic)
    windows = [w for key, phase, stamp in parsed if (w := grouper.add(key, phase, stamp))]
    grouper.close()
    return windows


# ------------------------------------------------------------------------------------- CSV


def parse_time(text: str, scale: int, where: str) -> int:
    """Return a time in integer ns: ``text`` in units of ``scale`` ns, parsed exactly.

    Raises:
        BagImportError: Not a number, or finer than 1 ns.
    """
    try:
        value = Decimal(text.strip()) * scale
        if not value.is_finite() or value != value.to_integral_value():
            raise InvalidOperation  # noqa: TRY301
    except InvalidOperation as err:
        msg = f"{where}: {text!r} is not a time in whole ns; fix the row"
        raise BagImportError(msg) from err
    return int(value)


def _csv_window(row: dict[str, str | None], scale: int, origin: int, where: str) -> Window:
    """Return the window of one CSV row (execute at start, end at stop, optional phases)."""

    def at(column: str) -> int:
        return origin + parse_time(row.get(column) or "", scale, f"{where} column {column}")

    events = [("execute", at("start")), (_PHASES[-1], at("stop"))]
    events.extend(
        (p, at(p))
        for p in _PHASES
        if p not in ("execute", _PHASES[-1]) and (row.get(p) or "").strip()
    )
    events.sort(key=lambda event: _PHASES.index(event[0]))
    trial = _trial((row.get("trial") or "").strip(), where)
    window = Window(
        (row["object"] or "").strip(), (row["action"] or "").strip(), trial, tuple(events), where
    )
    return check_window(window)


def _csv_rows(path: Path) -> list[dict[str, str | None]]:
    """Return the rows of a windows CSV.

    Raises:
        BagImportError: Unreadable, not UTF-8, too large, or lacking a column.
    """
    try:
        if path.stat().st_size > MAX_CSV_BYTES:
            msg = f"{path}: larger than {MAX_CSV_BYTES >> 20} MB; a windows CSV lists actions"
            raise BagImportError(msg)
        # utf-8-sig: a table saved by Excel starts with a byte order mark, not part of "start";
        # names and values are stripped: "start, stop, object" is what a person types
        with path.open(newline="", encoding="utf-8-sig") as handle:
            rows = [
                {
                    key.strip() if isinstance(key, str) else key: (
                        value.strip() if isinstance(value, str) else value
                    )
                    for key, value in row.items()
                }
                for row in csv.DictReader(handle)
            ]
    except OSError as err:
        msg = f"{path}: cannot read the windows ({err.strerror}); check the [windows] csv path"
        raise BagImportError(msg) from err
    except (UnicodeDecodeError, csv.Error) as err:
        msg = f"{path}: not a UTF-8 CSV ({err}); save the windows as UTF-8 CSV"
        raise BagImportError(msg) from err
    if rows and (missing := [c for c in _CSV_COLUMNS if c not in rows[0]]):
        msg = f"{path}: no column {', '.join(missing)}; the header needs {', '.join(_CSV_COLUMNS)}"
        raise BagImportError(msg)
    return rows


def windows_from_csv(path: Path, time_unit: str, origin_ns: int) -> list[Window]:
    """Read windows from a CSV: start, stop, object, action[, trial][, approach, ...].

    Raises:
        BagImportError: The file cannot be read, lacks a column, or a row is malformed.
    """
    scale = TIME_UNITS[time_unit]
    return [
        _csv_window(row, scale, origin_ns, f"{path} row {number}")
        for number, row in enumerate(_csv_rows(Path(path)), start=2)
    ]


# ------------------------------------------------------------------------------------ paths


def _existing_trials(out: Path, object_id: str, action_id: str) -> int:
    """Return the highest trial number recorded in ``out`` for (object, action), 0 if none."""
    names = (p.stem for p in (Path(out) / object_id / action_id).glob("*.mcap"))
    return max((int(n) for n in names if n.isdigit()), default=0)


class PathPlanner:
    """Gives windows trial numbers and output paths, one after the other.

    Windows without a trial continue after the highest trial in ``out`` (and in this import).
    A window whose trial is recorded already is refused (a bag can be imported again into
    another ``--out``), or, with ``renumber`` (``listen``: live data exists nowhere else), it
    continues after the highest trial as a window without one does.
    """

    def __init__(self, out: Path, *, renumber: bool = False) -> None:
        """Plan into ``out``."""
        self.out = out
        self.renumber = renumber
        self._used: dict[tuple[str, str], int] = {}
        self._seen: set[Path] = set()

    def _exists(self, path: Path) -> bool:
        """Return whether a recording exists at ``path``."""
        return path.exists()

    def _baseline(self, pair: tuple[str, str]) -> int:
        """Return the highest trial of (object, action) before this planner's first window."""
        return _existing_trials(self.out, *pair)

    def taken(self) -> dict[str, int]:
        """Return ``object/action`` -> highest trial in ``out`` or planned (every pair)."""
        found = {
            f"{d.parent.name}/{d.name}": _existing_trials(self.out, d.parent.name, d.name)
            for d in Path(self.out).glob("*/*")
            if d.is_dir() and not d.parent.name.startswith(".")
        }
        for (obj, action), trial in self._used.items():
            key = f"{obj}/{action}"
            found[key] = max(found.get(key, 0), trial)
        return {k: v for k, v in sorted(found.items()) if v}

    def plan(self, window: Window) -> tuple[Window, int, Path]:
        """Return the window with its trial and path.

        Raises:
            BagImportError: The path exists already or another window got it.
        """
        used = self._used
        pair = (window.object_id, window.action_id)
        if pair not in used:
            used[pair] = self._baseline(pair)
        trial = window.trial if window.trial is not None else used[pair] + 1
        path = recording_path(self.out, window.object_id, window.action_id, trial)
        if self.renumber and (self._exists(path) or path in self._seen):
            trial = used[pair] + 1
            path = recording_path(self.out, window.object_id, window.action_id, trial)
        if trial > MAX_TRIAL:
            msg = f"{window.describe()}: trial {trial} exceeds {MAX_TRIAL}; choose another --out"
            raise BagImportError(msg)
        if path in self._seen and not self._exists(path):  # two windows, one trial
            msg = (
                f"{window.describe()}: trial {trial} of {window.object_id}/{window.action_id} "
                "is given to another window of this import too; give each window its own "
                "trial, or none to number them on"
            )
            raise BagImportError(msg)
        if self._exists(path):
            msg = (
                f"{path}: {window.describe()} would overwrite a recording; recordings are never "
                "overwritten: remove its trial number to number it on, or choose another --out"
            )
            raise BagImportError(msg)
        used[pair] = max(used[pair], trial)
        self._seen.add(path)
        return window, trial, path


class ReplayPlanner(PathPlanner):
    """Plans a journal's windows as its run did (a recovery): same trials, same paths.

    The trials taken when the journal began stand for the directory (which now also holds
    what the run wrote), and a path the run wrote is not an overwrite.
    """

    def __init__(self, out: Path, trials: dict[str, int], written: set[Path]) -> None:
        """Plan into ``out`` from the journal's ``trials``; ``written``: the run's paths."""
        super().__init__(out, renumber=True)  # as the live run did
        self._trials = trials
        self._written = written

    def _exists(self, path: Path) -> bool:
        return path not in self._written and path.exists()

    def _baseline(self, pair: tuple[str, str]) -> int:
        return self._trials.get(f"{pair[0]}/{pair[1]}", 0)


def plan_paths(windows: Sequence[Window], out: Path) -> list[tuple[Window, int, Path]]:
    """Give every window its trial number and output path (see :class:`PathPlanner`).

    Raises:
        BagImportError: A path exists already or two windows get the same path.
    """
    planner = PathPlanner(out)
    return [planner.plan(window) for window in windows]
