"""Contract checks on what a recording holds, beyond an intact container.

Each check raises :class:`replay.errors.RecordingError` naming the file, the offending value
and the fix; none of them repairs or reorders data silently:

- message definitions: every contract channel's type (the project's own and the standard ROS
  types alike) must be defined as this software defines it, field by field and in order (a
  file written under another schema version or by another tool is refused, not misread);
- stamps: every channel's sensor stamps strictly increase in file order (a duplicated or
  reordered message is refused);
- values: no NaN or infinity in any signal or action parameter;
- phases: the action events are known phases in their order (approach, contact, execute,
  retract, end), strictly increasing in time, and include every phase the recording's
  source promises (the recorder all five, an import execute and end);
- gaps: inside the execute phase no skin channel pauses longer than :data:`MAX_GAP_PERIODS`
  sample periods;
- duration: the execute phase lasts as long as the action's ``duration_s`` says, and every
  skin channel covers it. A rig that runs actions faster than real time (a test rig) says
  so with a ``time_scale`` entry in its description (``rig`` metadata); durations are scaled
  by it. The tolerance is :data:`DURATION_TOLERANCE` of the duration plus 1 ms;
- location: a recording inside a dataset (``<root>/<object>/<action>/<trial>.mcap`` with
  ``<root>/index.parquet``) must say the object, action and trial its path says, and agree
  with its row of the index.
"""

from __future__ import annotations

import contextlib
import functools
import itertools
import math
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import polars as pl

from replay.errors import RecordingError
from schemas import (
    SCHEMA_VERSION,
    VOCABULARY,
    ParquetMismatchError,
    build_typestore,
    dataset_recordings,
    read_checked_parquet,
    rows_allowed,
)

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from numpy.typing import NDArray

    from replay.recording._container import ChannelInfo

#: The action phases, in the order a recording has them.
PHASES = VOCABULARY.phases
#: Longest pause inside the execute phase, in sample periods of the channel.
MAX_GAP_PERIODS = 5
#: How much shorter than ``duration_s`` an execute phase may be (relative; plus 1 ms).
DURATION_TOLERANCE = 0.01
#: File name of a dataset's index, beside the object directories.
INDEX_NAME = "index.parquet"

_NS_PER_S = 1_000_000_000
_SLACK_NS = 1_000_000
_TRIAL_NAME = re.compile(r"(\d+)(?:\..*)?\.mcap")
_RERECORD = "the file is damaged or was not written by atikt-record: record the action again"


def _normalized(definition: str) -> list[str]:
    """Return the main message of a ``ros2msg`` definition without comments or layout."""
    main = re.split(r"^=+\s*$", definition, maxsplit=1, flags=re.MULTILINE)[0]
    lines = (" ".join(line.split("#", 1)[0].split()) for line in main.splitlines())
    return [line.replace("/msg/", "/") for line in lines if line]


@functools.cache
def _own_definition(msgtype: str) -> tuple[str, ...]:
    """Return this software's normalized definition of ``msgtype``."""
    text, _ = build_typestore().generate_msgdef(msgtype, ros_version=2)
    return tuple(_normalized(text))


def check_definitions(path: Path, channels: Sequence[ChannelInfo]) -> None:
    """Check that every channel's message type is defined as this software defines it.

    Standard ROS types are compared too: a JointState whose fields are reordered would
    otherwise decode velocities as positions.

    Raises:
        RecordingError: A channel's definition is missing or differs; names the first field.
    """
    for info in channels:
        theirs, ours = tuple(_normalized(info.definition)), _own_definition(info.msgtype)
        if theirs == ours:
            continue
        first = next(
            (
                f"{a!r} where this software has {b!r}"
                for a, b in zip(theirs, ours, strict=False)
                if a != b
            ),
            f"{len(theirs)} fields where this software has {len(ours)}",
        )
        msg = (
            f"{path}: channel {info.topic} defines {info.msgtype} differently from this "
            f"software (schema version {SCHEMA_VERSION}): {first}; the file was written under "
            "another schema or by another tool: convert it with atikt-record import-bag, or "
            "read it with the atikt release that wrote it"
        )
        raise RecordingError(msg)


def check_stamps(path: Path, topic: str, stamps: NDArray[np.int64]) -> None:
    """Check that a channel's sensor stamps strictly increase in file order.

    Raises:
        RecordingError: A stamp repeats or goes back; the message gives the first one.
    """
    if stamps.size < 2:  # noqa: PLR2004 (a pair is the smallest step)
        return
    steps = np.diff(stamps)
    bad = np.flatnonzero(steps <= 0)
    if bad.size == 0:
        return
    index = int(bad[0]) + 1
    what = "repeats" if steps[index - 1] == 0 else "goes back from"
    msg = (
        f"{path}: {topic}: sample {index} has stamp {int(stamps[index])} ns, which {what} "
        f"{int(stamps[index - 1])} ns (duplicated or reordered messages); {_RERECORD}"
    )
    raise RecordingError(msg)


def check_finite(
    path: Path, topic: str, stamps: NDArray[np.int64], values: NDArray[Any], what: str
) -> None:
    """Check that a signal has no NaN or infinite value.

    Args:
        path: The recording.
        topic: Its channel.
        stamps: One stamp per sample, shape (n,).
        values: Samples, shape (n, ...).
        what: Name of the signal in the message.

    Raises:
        RecordingError: A value is not finite; the message gives the first one.
    """
    finite = np.isfinite(values).reshape(values.shape[0], -1).all(axis=1)
    if bool(finite.all()):
        return
    index = int(np.argmin(finite))
    count = int(np.size(values) - np.count_nonzero(np.isfinite(values)))
    msg = (
        f"{path}: {topic}: {count} {what} values are NaN or infinite, the first in sample "
        f"{index} (stamp {int(stamps[index])} ns); a sensor or driver fault: check the rig "
        "and record the action again"
    )
    raise RecordingError(msg)


def check_phases(
    path: Path, phases: Sequence[tuple[str, int]], promised: Sequence[str] = ("execute",)
) -> None:
    """Check the action events: known phases, in order, strictly increasing, none missing.

    Args:
        path: The recording.
        phases: (phase, start ns) in file order.
        promised: Phases the recording's source promises (``schemas`` sources).

    Raises:
        RecordingError: The first violation.
    """
    names = [name for name, _ in phases]
    ranks = [PHASES.index(name) if name in PHASES else -1 for name in names]
    stamps = [stamp for _, stamp in phases]
    in_order = all(b > a for a, b in itertools.pairwise(ranks))
    increasing = all(b > a for a, b in itertools.pairwise(stamps))
    listed = ", ".join(f"{name} at {stamp} ns" for name, stamp in phases) or "none"
    if -1 in ranks or not in_order or not increasing:
        msg = (
            f"{path}: the action events ({listed}) are not phases of "
            f"{', '.join(PHASES)} in this order with increasing stamps; {_RERECORD}"
        )
        raise RecordingError(msg)
    if missing := [name for name in promised if name not in names]:
        msg = (
            f"{path}: the recording lacks the phases {', '.join(missing)} (it has: {listed}): "
            f"it is incomplete; salvage it with 'atikt-replay check {path} --recover' (a "
            "salvage stays a salvage) or record the action again"
        )
        raise RecordingError(msg)


def check_gaps(
    path: Path,
    execute: tuple[int, int],
    signals: Mapping[str, Any],
    explained: str = "",
) -> str | None:
    """Check that no skin channel pauses inside the execute phase.

    A live recording's accounting may explain a pause without loss: the publisher paused
    (``gaps``), or samples were counted and left out (malformed, stamped out of range, a
    counter reset). Then the pause is returned as a warning, not refused.

    Args:
        path: The recording.
        execute: The execute phase, ``[start_ns, stop_ns)``.
        signals: Modality -> series with ``stamps_ns`` and ``period_ns``.
        explained: What the accounting counted that explains a pause (empty: nothing).

    Returns:
        The longest explained pause, one line (None: no pause).

    Raises:
        RecordingError: A pause longer than :data:`MAX_GAP_PERIODS` periods that the
            accounting does not explain; names it.
    """
    start, stop = execute
    for modality, series in signals.items():
        stamps = series.stamps_ns
        lo, hi = np.searchsorted(stamps, [start, stop])
        inside = stamps[max(int(lo) - 1, 0) : int(hi) + 1]
        if inside.size < 2:  # noqa: PLR2004 (a pair is the smallest step)
            continue
        steps = np.diff(inside)
        worst = int(np.argmax(steps))
        if steps[worst] > MAX_GAP_PERIODS * series.period_ns and explained:
            return (
                f"{path}: {modality} pauses {steps[worst] / _NS_PER_S:.3f} s at "
                f"{int(inside[worst])} ns inside the execute phase; the live sources counted "
                f"it ({explained}), no sample they sent was lost, but the action has no "
                f"{modality} there: record it again if that part matters"
            )
        if steps[worst] > MAX_GAP_PERIODS * series.period_ns:
            msg = (
                f"{path}: {modality} pauses {steps[worst] / _NS_PER_S:.3f} s at "
                f"{int(inside[worst])} ns inside the execute phase (more than "
                f"{MAX_GAP_PERIODS} sample periods): samples were lost; check the skin "
                "driver and record the action again"
            )
            raise RecordingError(msg)
    return None


def pauses_explained(sources: Sequence[Any]) -> str:
    """Return what a recording's live sources counted that explains a pause without loss.

    Empty when a source lost samples (a pause is then loss) or nothing was counted.
    """
    if any(item.lost for item in sources):
        return ""
    return "; ".join(f"{item.name}: {item.warnings()}" for item in sources if item.warnings())


def time_scale(path: Path, rig: Mapping[str, object]) -> float:
    """Return the rig's ``time_scale`` (1 when it has none).

    Raises:
        RecordingError: The entry is not a positive finite number.
    """
    text = str(rig.get("time_scale", "1"))
    try:
        scale = float(text)
    except ValueError:
        scale = math.nan
    if not (math.isfinite(scale) and scale > 0):
        msg = f"{path}: rig time_scale {text!r} in the metadata record is not a positive number; "
        raise RecordingError(msg + _RERECORD)
    return scale


def check_duration(
    path: Path,
    action: tuple[str, float],
    execute: tuple[int, int],
    coverage: Mapping[str, tuple[int, int]],
) -> None:
    """Check that the execute phase and every skin channel last as long as the action says.

    Args:
        path: The recording.
        action: The action id and its (time-scaled) duration, s.
        execute: The execute phase, ``[start_ns, stop_ns)``.
        coverage: Per channel, ``[first stamp, last stamp + period)`` in ns.

    Raises:
        RecordingError: The phase or a channel ends too early, or a channel begins late.
    """
    action_id, duration_s = action
    needed = round(duration_s * (1 - DURATION_TOLERANCE) * _NS_PER_S) - _SLACK_NS
    start, stop = execute
    if stop - start < needed:
        msg = (
            f"{path}: the execute phase of {action_id} lasts {(stop - start) / _NS_PER_S:.3f} s, "
            f"its parameters say {duration_s:g} s: the action was cut short; record it again"
        )
        raise RecordingError(msg)
    for topic, (first, end) in coverage.items():
        if first > start:
            msg = (
                f"{path}: {topic} begins {(first - start) / _NS_PER_S:.3f} s after the "
                f"{duration_s:g} s execute phase of {action_id} began: the channel started "
                "late; check the skin driver and record the action again"
            )
            raise RecordingError(msg)
        if end - start < needed:
            msg = (
                f"{path}: {topic} covers {(max(end - start, 0)) / _NS_PER_S:.3f} s of the "
                f"{duration_s:g} s execute phase of {action_id}: the channel stopped early; "
                "check the skin driver and record the action again"
            )
            raise RecordingError(msg)


#: The index columns the checks compare (the index has more: see ``atikt-record index``).
INDEX_COLUMNS: dict[str, Any] = {
    "path": pl.String,
    "object_id": pl.String,
    "action_id": pl.String,
    "trial": pl.Int64,
    "seed": pl.Int64,
    "size_bytes": pl.Int64,
}


@functools.lru_cache(maxsize=8)
def _index_rows(index: Path, _mtime_ns: int, _size: int) -> dict[str, dict[str, Any]]:
    """Return a dataset index's rows by relative path (cached while the file is unchanged).

    The index is checked before it is read: rows for the recordings of its dataset.
    """
    recordings = len(dataset_recordings(index.parent))
    frame = read_checked_parquet(index, INDEX_COLUMNS, rows_allowed(recordings), exact=False)
    return {row["path"]: row for row in frame.iter_rows(named=True)}


def index_problems(
    root: Path, files: Sequence[Path], rows: Mapping[str, Mapping[str, Any]]
) -> list[str]:
    """Return how ``<root>/index.parquet`` disagrees with the recordings ``files`` (one each).

    The index must list every recording once, with its size, and nothing else. A file that
    cannot be read (a symbolic link whose target is gone) is left out here: its own check
    names it.

    Args:
        root: The dataset.
        files: Its recordings.
        rows: The index's rows (:func:`read_index`, read once by the caller).
    """
    index = Path(root) / INDEX_NAME
    sizes = {}
    for f in files:
        with contextlib.suppress(OSError):
            sizes[f.relative_to(root).as_posix()] = f.stat().st_size
    fix = f"rebuild it with 'atikt-record index {root}'"
    problems = []
    if missing := sorted(sizes.keys() - rows.keys()):
        problems.append(
            f"{index}: lists {len(sizes) - len(missing)} of the {len(sizes)} recordings "
            f"(not {missing[0]}{' and more' if len(missing) > 1 else ''}); {fix}"
        )
    if extra := sorted(rows.keys() - sizes.keys() - _unreadable(root, files)):
        problems.append(f"{index}: lists {len(extra)} files that are not there ({extra[0]}); {fix}")
    if changed := sorted(
        p for p in sizes.keys() & rows.keys() if rows[p]["size_bytes"] != sizes[p]
    ):
        problems.append(
            f"{index}: gives another size for {len(changed)} files ({changed[0]}); {fix}"
        )
    return problems


def _unreadable(root: Path, files: Sequence[Path]) -> set[str]:
    """Return the relative paths of ``files`` that cannot be stat'ed (checked on their own)."""
    return {f.relative_to(root).as_posix() for f in files if not f.exists()}


def read_index(root: Path) -> dict[str, dict[str, Any]] | None:
    """Return the rows of ``<root>/index.parquet`` by relative path (None: no index).

    Read once per command: a check of a dataset compares every recording with these rows.

    Raises:
        RecordingError: The index cannot be read or does not match its format; one line
            with the fix (``atikt-record index``).
    """
    index = Path(root) / INDEX_NAME
    if not index.is_file():
        return None
    try:
        stat = index.stat()
        return _index_rows(index, stat.st_mtime_ns, stat.st_size)
    except (OSError, pl.exceptions.PolarsError, KeyError, ParquetMismatchError) as err:
        msg = (
            f"{index}: the dataset index cannot be read ({' '.join(str(err).split())}); it is "
            f"derived data: rebuild it with 'atikt-record index {root}'"
        )
        raise RecordingError(msg) from err


def dataset_root(path: Path) -> Path | None:
    """Return the dataset holding the recording ``path`` (None: it lies in none).

    A file is inside a dataset when ``index.parquet`` lies three levels up
    (``<root>/<object>/<action>/<trial>.mcap``); the root is returned resolved.
    """
    full = Path(path).resolve()
    if len(full.parents) < 3:  # noqa: PLR2004 (<root>/<object>/<action>/<trial>.mcap)
        return None
    root = full.parents[2]
    return root if (root / INDEX_NAME).is_file() else None


def check_location(path: Path, said: Mapping[str, Any]) -> None:
    """Check that a recording inside a dataset says the object, action and trial its path says.

    Elsewhere (:func:`dataset_root` is None) nothing is checked.

    Args:
        path: The recording.
        said: What its metadata says: ``object_id``, ``action_id``, ``trial``.

    Raises:
        RecordingError: The metadata contradicts the path; the fix names where it belongs
            (and, when that file exists, what to do instead of overwriting it).
    """
    root = dataset_root(path)
    if root is None:
        return
    problem = location_problem(Path(path).resolve(), said, shown=path)
    if problem is not None:
        raise RecordingError(problem)


def location_problem(
    path: Path, said: Mapping[str, Any], *, shown: Path | None = None
) -> str | None:
    """Return how a recording's metadata contradicts its dataset path (None: it agrees).

    The fix moves the file where its metadata says it belongs, unless a file is there already:
    moving it would overwrite that recording. Then the line says whether it is a copy (same
    bytes: delete it) or names the first free trial of that object and action.

    Args:
        path: The recording, ``<dataset>/<object>/<action>/<trial>.mcap``.
        said: What its metadata says: ``object_id``, ``action_id``, ``trial``.
        shown: How the message names the file (default: ``path``).
    """
    full = Path(path)
    match = _TRIAL_NAME.fullmatch(full.name)
    located: dict[str, Any] = {"object_id": full.parents[1].name, "action_id": full.parent.name}
    located["trial"] = int(match.group(1)) if match else said["trial"]
    wrong = [key for key, value in located.items() if said[key] != value]
    if not wrong:
        return None
    given = Path(shown or path)  # the fix names paths as the user gave them, where it can
    home = given.parents[2] if len(given.parents) > 2 else full.parents[2]  # noqa: PLR2004
    proper = home / str(said["object_id"]) / str(said["action_id"]) / f"{said['trial']:03d}.mcap"
    return (
        f"{shown or path}: the metadata says {', '.join(f'{k} {said[k]}' for k in wrong)}, the "
        f"dataset path says {', '.join(f'{k} {located[k]}' for k in wrong)}; "
        f"{_placing(full, proper)}, then rebuild the index with 'atikt-record index {home}'"
    )


def _placing(path: Path, proper: Path) -> str:
    """Return how to put a misplaced recording where its metadata says, overwriting nothing."""
    if not proper.exists():
        return f"move the file to {proper} (or record it again)"
    if _same_bytes(path, proper):
        return f"it is a copy of {proper} (the same bytes): delete it"
    trials = {
        int(m.group(1))
        for p in proper.parent.glob("*.mcap")
        if (m := _TRIAL_NAME.fullmatch(p.name))
    }
    free = next(t for t in itertools.count(1) if t not in trials)
    return (
        f"{proper} holds another recording of that trial (moving the file there would "
        f"overwrite it): take the file out of the dataset, or record the action again as "
        f"trial {free} ({proper.parent / f'{free:03d}'}.mcap is free)"
    )


def _same_bytes(a: Path, b: Path) -> bool:
    """Return whether two files hold the same bytes (False when one cannot be read)."""
    try:
        return a.stat().st_size == b.stat().st_size and a.read_bytes() == b.read_bytes()
    except OSError:
        return False


def index_row_problem(
    path: Path, root: Path, rows: Mapping[str, Mapping[str, Any]], facts: Mapping[str, Any]
) -> str | None:
    """Return how a recording's row of its dataset's index disagrees with the file (None: agrees).

    Args:
        path: The recording.
        root: Its dataset (:func:`dataset_root`).
        rows: The index's rows (:func:`read_index`).
        facts: What the file says (``object_id``, ``action_id``, ``trial``, ``seed``) and its
            ``size_bytes``.
    """
    row = rows.get(Path(path).resolve().relative_to(root).as_posix())
    if row is None:
        return None
    if wrong := [key for key in facts if key in row and row[key] != facts[key]]:
        listed = ", ".join(f"{key} {row[key]} (the file: {facts[key]})" for key in wrong)
        return (
            f"{path}: the dataset index {root / INDEX_NAME} says {listed}; the index is derived "
            f"data: rebuild it with 'atikt-record index {root}'"
        )
    return None
