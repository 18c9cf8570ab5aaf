"""Features of recordings: the one path MCAP file -> reader -> features, and its cache.

A dataset's features are extracted once into ``features.parquet`` (polars; beside the data, or
in the user cache where the data must not be written to, see :func:`feature_cache_path`), one row
per recording keyed by the SHA-256 of the file's bytes; a rebuild re-extracts only the files
whose content changed, and drops rows of files that are gone. Files that cannot be read are
quarantined: listed with the reason, never silently used.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import numpy as np
import polars as pl

from atikt import AtiktError, RawFeatures, extract_features
from replay.errors import ReplayError
from replay.learning._cachedir import FEATURES_NAME, feature_cache_path
from replay.learning._parallel import run_tasks
from replay.recording._checks import location_problem
from replay.recording._reader import check_not_partial, read_recording
from schemas import (
    VOCABULARY,
    ParquetMismatchError,
    atomic_write,
    dataset_recordings,
    read_checked_parquet,
    rows_allowed,
    unreadable,
)

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Mapping, Sequence

    from replay.recording._reader import ActionRecording

#: Version of the feature definition; a cache of another version is rebuilt.
FEATURES_VERSION = 2
#: Points of the resampled thermal sequence (the same for every action).
THERMAL_POINTS = 20
#: Which feature blocks an action's observations use: the thesis's assignment per action kind
#: (``schemas`` kinds' ``features``), or every block whose sensor the recording has.
FEATURE_POLICIES = ("thesis", "all")

_VECTOR = pl.List(pl.Float64)
_SCHEMA: dict[str, Any] = {
    "path": pl.String,
    "sha256": pl.String,
    "object_id": pl.String,
    "object_name": pl.String,
    "action_id": pl.String,
    "action_kind": pl.String,
    "trial": pl.Int64,
    "seed": pl.Int64,
    **dict.fromkeys(VOCABULARY.features, _VECTOR),
    "features_version": pl.Int64,
}
_QUARANTINE_SCHEMA: dict[str, Any] = {"path": pl.String, "reason": pl.String}
__all__ = [
    "FEATURES_NAME",
    "FEATURES_VERSION",
    "FEATURE_POLICIES",
    "THERMAL_POINTS",
    "FeatureTable",
    "as_raw",
    "build_features",
    "file_features",
    "recording_features",
    "row_blocks",
    "select_blocks",
]


def select_blocks(kind: str, available: Iterable[str], policy: str = "thesis") -> tuple[str, ...]:
    """Return the feature blocks an observation uses, in contract order.

    Args:
        kind: The action's kind.
        available: Blocks whose sensor the recordings have.
        policy: ``thesis`` (the kind's assigned blocks) or ``all`` (every available block).

    Raises:
        ReplayError: Unknown policy.
    """
    if policy not in FEATURE_POLICIES:
        msg = f"feature policy {policy!r}; use one of {', '.join(FEATURE_POLICIES)}"
        raise ReplayError(msg)
    have = set(available)
    wanted = VOCABULARY.kind(kind).features if policy == "thesis" else VOCABULARY.features
    return tuple(f for f in VOCABULARY.features if f in have and f in wanted)


def _all_features(recording: ActionRecording) -> RawFeatures:
    """Return every feature block whose sensor the recording has (its execute phase).

    Raises:
        ReplayError: The recording's signals do not give features; the message names the file.
    """
    start_ns, stop_ns = recording.phase_range("execute")
    signals = {}
    for feature in VOCABULARY.features:
        modality = VOCABULARY.modality_of_feature(feature).name
        if modality in recording.signals:
            series = recording.signals[modality].between(start_ns, stop_ns)
            signals[feature] = (series.data, 1e9 / series.period_ns)
    try:
        return extract_features(
            recording.metadata.action_kind, signals, n_thermal_points=THERMAL_POINTS
        )
    except AtiktError as err:
        msg = f"{recording.path}: no features from the execute phase ({err}); check the recording"
        raise ReplayError(msg) from err


def _subset(features: RawFeatures, blocks: Sequence[str], where: str) -> RawFeatures:
    """Return ``features`` restricted to ``blocks``.

    Raises:
        ReplayError: A block is missing or none is left.
    """
    if not blocks or any(b not in features.blocks for b in blocks):
        held = ", ".join(features.modalities) or "none"
        msg = (
            f"{where}: no features {', '.join(blocks) or '(none selected)'} (it has: {held}); "
            "the recording lacks the sensor, or choose another feature policy"
        )
        raise ReplayError(msg)
    return RawFeatures(features.kind, MappingProxyType({b: features.blocks[b] for b in blocks}))


def recording_features(
    recording: ActionRecording, blocks: Sequence[str] | None = None, policy: str = "thesis"
) -> RawFeatures:
    """Return the raw features of one recording, computed on its execute phase.

    Args:
        recording: The recording.
        blocks: The blocks to return; None selects them by ``policy`` from what it has.
        policy: See :func:`select_blocks`.

    Raises:
        ReplayError: The recording's signals do not give features; the message names the file.
    """
    features = _all_features(recording)
    if blocks is None:
        blocks = select_blocks(features.kind, features.modalities, policy)
    return _subset(features, blocks, str(recording.path))


def file_features(
    path: Path, blocks: Sequence[str] | None = None, policy: str = "thesis"
) -> RawFeatures:
    """Read one recording and return its raw features (the live and offline path)."""
    return recording_features(read_recording(path), blocks, policy)


def _vector(values: np.ndarray[Any, Any] | None) -> list[float] | None:
    return None if values is None else [float(v) for v in values]


def _row(root: Path, path: Path, digest: str) -> dict[str, Any]:
    """Return the cache row of one recording (raises ReplayError for a bad file)."""
    recording = read_recording(path)
    check_not_partial(recording)
    features = _all_features(recording)
    meta = recording.metadata
    return {
        "path": path.relative_to(root).as_posix(),
        "sha256": digest,
        "object_id": meta.object_id,
        "object_name": meta.object_name,
        "action_id": meta.action_id,
        "action_kind": meta.action_kind,
        "trial": meta.trial,
        "seed": meta.seed,
        **{f: _vector(features.blocks.get(f)) for f in VOCABULARY.features},
        "features_version": FEATURES_VERSION,
    }


@dataclass(frozen=True, slots=True)
class _Job:
    """Extract the features of some recordings of one dataset (one parallel task)."""

    root: Path
    files: tuple[tuple[str, str], ...]  # (relative path, sha256)


def _extract(job: _Job) -> tuple[list[dict[str, Any]], list[dict[str, str]]]:
    """Run one job: rows of the good files, (path, reason) of the bad ones."""
    rows, bad = [], []
    for relative, digest in job.files:
        try:
            rows.append(_row(job.root, job.root / relative, digest))
        except ReplayError as err:
            bad.append({"path": relative, "reason": str(err)})
    return rows, bad


def _digest(path: Path) -> str:
    """Return the SHA-256 of a file's bytes."""
    try:
        with path.open("rb") as stream:
            return hashlib.file_digest(stream, "sha256").hexdigest()
    except OSError as err:
        raise ReplayError(unreadable(path, err)) from err


def _cached(target: Path, recordings: int) -> tuple[pl.DataFrame, str]:
    """Return the usable rows of an existing cache and why it was discarded ("" if kept).

    The cache is checked before it is read (:func:`schemas.read_checked_parquet`): rows for
    the recordings it describes, the expected columns and dtypes, a size its rows can hold. A
    cache of another version is silently replaced (an upgrade); any other mismatch is said.
    """
    empty = pl.DataFrame(schema=_SCHEMA)
    if not target.exists():
        return empty, ""
    try:
        frame = read_checked_parquet(target, _SCHEMA, max_rows=rows_allowed(recordings))
    except (OSError, ParquetMismatchError) as err:
        return empty, f"{target}: the feature cache does not match the dataset ({err}); rebuilt"
    return frame.filter(pl.col("features_version") == FEATURES_VERSION), ""


@dataclass(frozen=True, slots=True)
class FeatureTable:
    """The features of a dataset and the recordings that were refused.

    Attributes:
        root: The dataset directory.
        frame: One row per good recording (see ``_SCHEMA``), sorted by path.
        quarantined: One row per refused recording: path and reason.
        extracted: How many recordings were (re-)extracted by this build.
        discarded: Why an existing cache was discarded and rebuilt (one line; "" if not).
    """

    root: Path
    frame: pl.DataFrame
    quarantined: pl.DataFrame
    extracted: int
    discarded: str = ""


def build_features(
    root: Path,
    *,
    workers: int = 1,
    chunk: int = 32,
    cache: Path | None = None,
    on_progress: Callable[[int, int], Any] | None = None,
) -> FeatureTable:
    """Extract (or update) the feature cache of the dataset at ``root``.

    Args:
        root: Dataset directory (``<object>/<action>/<trial>.mcap`` files).
        workers: Worker processes for the extraction.
        chunk: Recordings per parallel task.
        cache: The cache file; :func:`feature_cache_path` of ``root`` when None.
        on_progress: Called with (recordings done, recordings to extract).

    Returns:
        The features; the cache file is rewritten atomically.

    Raises:
        ReplayError: ``root`` holds no recordings or the cache cannot be written.
    """
    root = Path(root)
    paths = dataset_recordings(root)
    if not paths:
        msg = f"{root}: no recordings (*.mcap) found; record a dataset with atikt-record dataset"
        raise ReplayError(msg)
    digests = {p.relative_to(root).as_posix(): _digest(p) for p in paths}
    cache = feature_cache_path(root) if cache is None else Path(cache)
    cached, discarded = _cached(cache, len(paths))
    current = pl.DataFrame(
        {"path": list(digests), "sha256": list(digests.values())},
        schema={"path": pl.String, "sha256": pl.String},
    )
    keep = cached.join(current, on=["path", "sha256"], how="semi")
    known = set(keep["path"].to_list())
    todo = [(p, d) for p, d in digests.items() if p not in known]
    # worker processes may have another working directory (a reused pool): absolute paths
    jobs = [_Job(root.absolute(), tuple(todo[i : i + chunk])) for i in range(0, len(todo), chunk)]
    sizes = [len(job.files) for job in jobs]

    def progress(done: int) -> None:
        if on_progress is not None:
            on_progress(sum(sizes[:done]), len(todo))

    results = run_tasks(_extract, jobs, workers=workers, on_done=progress)
    rows = [row for good, _ in results for row in good]
    bad = [entry for _, entries in results for entry in entries]
    frame = pl.concat([keep, pl.DataFrame(rows, schema=_SCHEMA)]).sort("path")
    _write(frame, cache)  # every readable file's row: the cache is keyed by content
    frame, refused = _one_row_per_trial(root, frame)
    quarantined = pl.DataFrame([*bad, *refused], schema=_QUARANTINE_SCHEMA).sort("path")
    return FeatureTable(root, frame, quarantined, extracted=len(todo), discarded=discarded)


def _one_row_per_trial(
    root: Path, frame: pl.DataFrame
) -> tuple[pl.DataFrame, list[dict[str, str]]]:
    """Return the rows a study may use, and (path, reason) of those left out.

    A study splits each (object, action)'s trials into a held-out test set and a pool; a
    recording that counts twice can land in both, and the learner is then tested on what it
    was shown. So, in path order, a row is left out (quarantined with a line naming both
    files, never silently used) when:

    - its metadata says another object, action or trial than its place in the dataset (a
      file copied into another object's directory: it would be that object's trial too);
    - its bytes are those of a row kept before (the same SHA-256: a copy, e.g. a directory
      holding two datasets that share recordings);
    - it says the same object, action and trial as a row kept before (two datasets in one
      directory, or two runs' recordings mixed).

    Leaving the row out (rather than refusing the whole table) keeps one copy of everything
    in the study, so the study runs, and says in the summary what it left out. On a valid
    dataset nothing is left out and the table is unchanged.
    """
    keep: list[bool] = []
    refused: list[dict[str, str]] = []
    seen_bytes: dict[str, str] = {}
    seen_trials: dict[tuple[str, str, int], str] = {}
    columns = ("path", "sha256", "object_id", "action_id", "trial")
    for relative, digest, obj, action, trial in zip(*(frame[c] for c in columns), strict=True):
        reason = _location(root, relative, {"object_id": obj, "action_id": action, "trial": trial})
        if reason is None and digest in seen_bytes:
            reason = (
                f"the same bytes as {root / seen_bytes[digest]} (SHA-256 {digest[:12]}...): a "
                "copy would count as a second trial; delete the copy (or give one dataset, not "
                "a directory holding several)"
            )
        if reason is None and (obj, action, trial) in seen_trials:
            first = root / seen_trials[obj, action, trial]
            reason = (
                f"object {obj} action {action} trial {trial}, as {first} says too (another "
                "recording): a trial is one recording; give one dataset, not a directory "
                "holding several"
            )
        keep.append(reason is None)
        if reason is None:
            seen_bytes[digest] = relative
            seen_trials[obj, action, trial] = relative
        else:
            refused.append({"path": relative, "reason": reason})
    return frame.filter(pl.Series(keep, dtype=pl.Boolean)), refused


def _location(root: Path, relative: str, said: Mapping[str, Any]) -> str | None:
    """Return why a row's metadata contradicts its place ``<object>/<action>/<trial>.mcap``.

    None when it agrees, or when the file lies too shallow to say (a flat directory).
    """
    if len(Path(relative).parts) < 3:  # noqa: PLR2004 (<object>/<action>/<trial>.mcap)
        return None
    return location_problem(root.absolute() / relative, said, shown=root / relative)


def _write(frame: pl.DataFrame, target: Path) -> None:
    """Write the cache atomically (exclusive temporary file, then rename)."""
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(target, frame.write_parquet)
    except (OSError, pl.exceptions.PolarsError) as err:  # polars: ComputeError on a full disk
        reason = err.strerror if isinstance(err, OSError) else " ".join(str(err).split())
        msg = f"{target}: cannot write the feature cache ({reason}); check free space"
        raise ReplayError(msg) from err


def row_blocks(row: Mapping[str, Any]) -> tuple[str, ...]:
    """Return the feature blocks a cache row has."""
    return tuple(f for f in VOCABULARY.features if row.get(f) is not None)


def as_raw(row: Mapping[str, Any], blocks: Sequence[str] | None = None) -> RawFeatures:
    """Return the :class:`atikt.RawFeatures` of one cache row.

    Args:
        row: A row of the feature cache.
        blocks: Blocks to return; None: the kind's thesis blocks among those it has.

    Raises:
        ReplayError: The row lacks one of ``blocks``.
    """
    arrays = {feature: as_raw_array(row[feature]) for feature in row_blocks(row)}
    features = RawFeatures(row["action_kind"], MappingProxyType(arrays))
    if blocks is None:
        blocks = select_blocks(features.kind, features.modalities)
    return _subset(features, blocks, str(row["path"]))


def _block_values(frame: pl.DataFrame, feature: str) -> list[np.ndarray[Any, Any] | None] | None:
    """Return every row's values of one feature block, read-only (None: the row has none).

    One conversion of the whole column (its values laid end to end, then sliced per row)
    instead of a Python list per row: the same float64 values, ten times faster for a
    dataset's 2,000 rows (a study converts its table once per task). Returns None when the
    column cannot be converted this way (a missing value inside a row's list).
    """
    if feature not in frame.columns:
        return [None] * frame.height
    column = frame[feature]
    lengths = column.list.len()
    flat = column.filter(lengths > 0).explode()
    if flat.null_count():
        return None
    values = flat.to_numpy().astype(np.float64)
    values.setflags(write=False)
    ends = np.cumsum(lengths.fill_null(0).to_numpy()).tolist()
    out: list[np.ndarray[Any, Any] | None] = []
    start = 0
    for present, end in zip(lengths.is_not_null().to_list(), ends, strict=True):
        out.append(values[start:end] if present else None)
        start = end
    return out


def _rows_blocks(frame: pl.DataFrame) -> list[dict[str, np.ndarray[Any, Any]]]:
    """Return every row's feature blocks as read-only float64 arrays (the blocks it has)."""
    columns = {f: _block_values(frame, f) for f in VOCABULARY.features}
    if any(values is None for values in columns.values()):
        return [
            {f: as_raw_array(row[f]) for f in row_blocks(row)}
            for row in frame.iter_rows(named=True)
        ]
    rows: list[dict[str, np.ndarray[Any, Any]]] = [{} for _ in range(frame.height)]
    for feature, values in columns.items():
        for blocks, array in zip(rows, values or (), strict=True):
            if array is not None:
                blocks[feature] = array
    return rows


def as_raw_array(values: Any) -> np.ndarray[Any, Any]:  # noqa: ANN401 (a cell of the table)
    """Return one feature block's values as a read-only float64 array."""
    out = np.asarray(values, dtype=np.float64)
    out.setflags(write=False)
    return out


def raw_table(
    frame: pl.DataFrame, policy: str = "thesis"
) -> tuple[dict[tuple[str, str, int], RawFeatures], dict[str, str], dict[str, tuple[str, ...]]]:
    """Convert a feature table once: every row's features, each action's kind and blocks.

    Every observation of an action gets the same feature blocks: those ``policy`` selects
    (:func:`select_blocks`) among the blocks every recording of the action has.

    Returns:
        (object, action, trial) -> features; action -> kind; action -> feature blocks.

    Raises:
        ReplayError: A row lacks one of its action's blocks (cannot happen for a table's own).
    """
    keys = zip(
        frame["object_id"].to_list(),
        frame["action_id"].to_list(),
        frame["trial"].to_list(),
        strict=True,
    )
    rows = {key: index for index, key in enumerate(keys)}  # a key's last row, as a dict
    arrays = _rows_blocks(frame)
    kinds_of_rows = frame["action_kind"].to_list()
    paths = frame["path"].to_list()
    held: dict[str, set[str]] = {}
    kinds: dict[str, str] = {}
    for (_, action, _), index in rows.items():
        have = set(arrays[index])
        held[action] = held[action] & have if action in held else have
        kinds[action] = kinds_of_rows[index]
    blocks = {a: select_blocks(kinds[a], have, policy) for a, have in held.items()}
    raw = {}
    for key, index in rows.items():
        ordered = {f: arrays[index][f] for f in VOCABULARY.features if f in arrays[index]}
        features = RawFeatures(kinds_of_rows[index], MappingProxyType(ordered))
        raw[key] = _subset(features, blocks[key[1]], str(paths[index]))
    return raw, kinds, blocks
