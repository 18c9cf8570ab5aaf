"""Export recordings as tables, one per channel, for analysis in other tools (polars).

``export(paths, out, fmt="parquet" | "csv", layout="long" | "wide")`` writes into ``out``:

==================== =====================================================================
file                 rows
==================== =====================================================================
``recordings``       one per recording: path, object, action and its parameters, trial,
                     rig kind, seed, software and schema versions, first and last stamp
``phases``           one per phase: ``phase``, ``start_ns``, ``stop_ns`` (half-open)
``joint_states``     one per sample: ``position_<joint>`` (rad), ``velocity_<joint>``
                     (rad/s), ``effort_<joint>`` (N m)
``tcp_pose``         one per sample: ``x``, ``y``, ``z`` (m), ``qx``, ``qy``, ``qz``, ``qw``
``force``            skin force, N: ``force_0``, ``force_1``, ``force_2`` (the 3 sensors)
``temperature``      skin temperature, C: ``temperature``
``acceleration``     skin acceleration, m/s^2: ``acc_x``, ``acc_y``, ``acc_z``
``proximity``        skin proximity, m: ``proximity``
==================== =====================================================================

Every table starts with the key columns ``recording`` (the file's path relative to its
dataset directory, e.g. ``wood/P1/001.mcap``, or to the exported directory when that lies
higher up), ``object_id``, ``action_id``, ``trial``; the sample tables
add ``stamp_ns`` (int64, sensor time) and ``phase`` (the phase the sample falls in, half-open;
empty before the first phase).

Skin layouts: ``long`` (default) has one row per sample and cell, with a ``cell`` column and
the channel columns above; ``wide`` has one row per sample and one column per cell and
channel, named ``c<cell>_<channel>`` (``c3_force_1``). Robot and phase tables are the same
in both layouts. Values are exactly the reader's (float32 skin, float64 robot).

Every table is written, the same files for any recordings: a table of a channel no exported
recording has (``joint_states`` of a rig without an arm, ``force`` of a thermal probe) has no
rows and the columns known without data: the key columns, ``stamp_ns`` and ``phase``, and
those the contract names (``tcp_pose``'s, and in the ``long`` layout a skin table's ``cell``
and its default value columns); a script reads every file and finds zero rows.

Recordings are exported one at a time (memory stays that of one recording): CSV rows are
appended to the open files, parquet parts are written per recording and streamed into one
file at the end. Existing tables in ``out`` are never overwritten.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np
import polars as pl

from replay.errors import ReplayError
from replay.recording._reader import MODALITIES, read_recording
from schemas import VOCABULARY, atomic_path, create_exclusive, publish_temporary, temporary_name

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from numpy.typing import NDArray

    from replay.recording._reader import ActionRecording

#: Output formats.
FORMATS = ("parquet", "csv")
#: Skin table layouts.
LAYOUTS = ("long", "wide")
#: Tables written, in order.
TABLES = (
    "recordings",
    "phases",
    "joint_states",
    "tcp_pose",
    *MODALITIES,
)


def value_columns(modality: str, width: int) -> tuple[str, ...]:
    """Return the column names of a modality's values (names from the contract).

    One value per cell: the modality's name; else ``<modality>_<value name>`` (``force_s0``,
    ``acceleration_x``).
    """
    if width == 1:
        return (modality,)
    names = VOCABULARY.modalities[modality].value_names(width)
    return tuple(f"{modality}_{name}" for name in names)


#: Types of the key columns every table starts with, and of the sample tables' time columns.
_KEY_SCHEMA: dict[str, Any] = {
    "recording": pl.String,
    "object_id": pl.String,
    "action_id": pl.String,
    "trial": pl.Int64,
}
_TIME_SCHEMA: dict[str, Any] = {"stamp_ns": pl.Int64, "phase": pl.String}


def empty_table(name: str, layout: str = "long") -> pl.DataFrame:
    """Return table ``name`` with no rows: the columns known without a recording.

    Joint names and a wide skin table's cells come from the data; they are left out.
    """
    if name == "recordings":
        return pl.DataFrame(schema=_KEY_SCHEMA | {"path": pl.String})
    if name == "phases":
        return pl.DataFrame(
            schema=_KEY_SCHEMA | {"phase": pl.String, "start_ns": pl.Int64, "stop_ns": pl.Int64}
        )
    schema = _KEY_SCHEMA | _TIME_SCHEMA
    if name == "tcp_pose":
        schema |= dict.fromkeys(("x", "y", "z", "qx", "qy", "qz", "qw"), pl.Float64)
    elif name in VOCABULARY.modalities and layout == "long":
        width = len(VOCABULARY.modalities[name].values)
        schema |= {"cell": pl.UInt16} | dict.fromkeys(value_columns(name, width), pl.Float32)
    return pl.DataFrame(schema=schema)


def _key(recording: ActionRecording, name: str) -> dict[str, Any]:
    """Return the key columns of a recording."""
    meta = recording.metadata
    return {
        "recording": name,
        "object_id": meta.object_id,
        "action_id": meta.action_id,
        "trial": meta.trial,
    }


def _with_key(frame: pl.DataFrame, key: dict[str, Any]) -> pl.DataFrame:
    """Return ``frame`` with the key columns first."""
    columns = [
        pl.lit(key["recording"], pl.String).alias("recording"),
        pl.lit(key["object_id"], pl.String).alias("object_id"),
        pl.lit(key["action_id"], pl.String).alias("action_id"),
        pl.lit(key["trial"], pl.Int64).alias("trial"),
    ]
    return frame.select(*columns, pl.all())


def phase_labels(recording: ActionRecording, stamps_ns: NDArray[np.int64]) -> pl.Series:
    """Return the phase each stamp falls in (half-open ranges; "" before the first phase)."""
    starts = np.array([mark.start_ns for mark in recording.phases], dtype=np.int64)
    names = np.array(["", *(mark.phase for mark in recording.phases)], dtype=object)
    index = np.searchsorted(starts, stamps_ns, side="right")
    return pl.Series("phase", names[index], dtype=pl.String)


def recording_row(recording: ActionRecording, name: str) -> pl.DataFrame:
    """Return the one-row ``recordings`` table of a recording."""
    meta = recording.metadata
    row = {
        "path": str(recording.path),
        "object_name": meta.object_name,
        "action_kind": meta.action_kind,
        **{k: float(v) for k, v in sorted(meta.action_parameters.items())},
        "rig": str(meta.rig.get("kind", "")),
        "source": meta.source,
        "seed": meta.seed,
        "software_version": meta.software_version,
        "schema_version": meta.schema_version,
        "start_ns": min(int(s.stamps_ns[0]) for s in recording.signals.values()),
        "end_ns": recording.end_ns,
    }
    return _with_key(pl.DataFrame([row]), _key(recording, name))


def phase_table(recording: ActionRecording, name: str) -> pl.DataFrame:
    """Return the ``phases`` table: one row per phase with its half-open range."""
    rows = []
    for mark in recording.phases:
        start, stop = recording.phase_range(mark.phase)
        rows.append({"phase": mark.phase, "start_ns": start, "stop_ns": stop})
    schema = {"phase": pl.String, "start_ns": pl.Int64, "stop_ns": pl.Int64}
    return _with_key(pl.DataFrame(rows, schema=schema), _key(recording, name))


def _timed(recording: ActionRecording, stamps_ns: NDArray[np.int64]) -> dict[str, pl.Series]:
    """Return the ``stamp_ns`` and ``phase`` columns of a series."""
    return {
        "stamp_ns": pl.Series("stamp_ns", stamps_ns, dtype=pl.Int64),
        "phase": phase_labels(recording, stamps_ns),
    }


def joint_table(recording: ActionRecording, name: str) -> pl.DataFrame:
    """Return the ``joint_states`` table: one row per sample, one column per joint quantity."""
    joints = recording.joints
    if joints is None:
        msg = f"{recording.path}: the recording has no joint states (a rig without an arm)"
        raise ReplayError(msg)
    columns = _timed(recording, joints.stamps_ns)
    for quantity in ("position", "velocity", "effort"):
        values = getattr(joints, quantity)
        for index, joint in enumerate(joints.names):
            column = f"{quantity}_{joint}"
            columns[column] = pl.Series(column, values[:, index], dtype=pl.Float64)
    return _with_key(pl.DataFrame(columns), _key(recording, name))


def tcp_table(recording: ActionRecording, name: str) -> pl.DataFrame:
    """Return the ``tcp_pose`` table: position (m) and unit quaternion per sample."""
    tcp = recording.tcp
    if tcp is None:
        msg = f"{recording.path}: the recording has no TCP poses (a rig without an arm)"
        raise ReplayError(msg)
    columns = _timed(recording, tcp.stamps_ns)
    for index, column in enumerate(("x", "y", "z")):
        columns[column] = pl.Series(column, tcp.position[:, index], dtype=pl.Float64)
    for index, column in enumerate(("qx", "qy", "qz", "qw")):
        columns[column] = pl.Series(column, tcp.orientation[:, index], dtype=pl.Float64)
    return _with_key(pl.DataFrame(columns), _key(recording, name))


def skin_table(recording: ActionRecording, modality: str, name: str, layout: str) -> pl.DataFrame:
    """Return a skin modality's table in the ``long`` or ``wide`` layout (module docstring)."""
    series = recording.skin(modality)
    n, cells, width = series.data.shape
    names = value_columns(modality, width)
    if layout == "wide":
        columns = _timed(recording, series.stamps_ns)
        for c, cell in enumerate(series.cell_ids):
            for k, channel in enumerate(names):
                column = f"c{int(cell)}_{channel}"
                columns[column] = pl.Series(column, series.data[:, c, k], dtype=pl.Float32)
        return _with_key(pl.DataFrame(columns), _key(recording, name))
    stamps = np.repeat(series.stamps_ns, cells)
    flat = series.data.reshape(n * cells, len(names))
    columns = _timed(recording, stamps)
    columns["cell"] = pl.Series("cell", np.tile(series.cell_ids, n), dtype=pl.UInt16)
    for k, channel in enumerate(names):
        columns[channel] = pl.Series(channel, flat[:, k], dtype=pl.Float32)
    return _with_key(pl.DataFrame(columns), _key(recording, name))


def recording_tables(
    recording: ActionRecording, name: str, layout: str = "long"
) -> dict[str, pl.DataFrame]:
    """Return every table of one recording, by table name (:data:`TABLES`)."""
    tables = {
        "recordings": recording_row(recording, name),
        "phases": phase_table(recording, name),
    }
    if recording.joints is not None:
        tables["joint_states"] = joint_table(recording, name)
    if recording.tcp is not None:
        tables["tcp_pose"] = tcp_table(recording, name)
    for modality in recording.modalities:
        tables[modality] = skin_table(recording, modality, name, layout)
    return tables


# ------------------------------------------------------------------------------------ writing


#: What writing a table may raise: the operating system's error, or polars' (ComputeError
#: "underlying IO error: No space left on device" on a full disk).
_WRITE_ERRORS = (OSError, pl.exceptions.PolarsError)


def _write_error(path: Path, err: OSError | pl.exceptions.PolarsError) -> ReplayError:
    """Return the error of a table that cannot be written, naming it and the fix."""
    if path.exists() and not path.is_dir() and isinstance(err, FileExistsError):
        return ReplayError(f"--out {path}: is a file, not a directory; give a new directory")
    reason = err.strerror if isinstance(err, OSError) else " ".join(str(err).split())
    return ReplayError(f"{path}: cannot write the export ({reason}); check free space and --out")


@dataclass(slots=True)
class _Table:
    """One output table being written: the first frame's columns fix the schema."""

    path: Path
    columns: list[str] | None = None
    rows: int = 0
    parts: list[Path] = field(default_factory=list)
    handle: IO[bytes] | None = None
    temporary: Path | None = None

    def check(self, frame: pl.DataFrame, source: str) -> None:
        """Refuse a frame whose columns differ from the table's first frame.

        Raises:
            ReplayError: The columns differ (e.g. cells differ between recordings in ``wide``).
        """
        if self.columns is None:
            self.columns = frame.columns
        elif frame.columns != self.columns:
            msg = (
                f"{source}: its {self.path.stem} columns differ from the recordings exported "
                f"before it ({len(frame.columns)} vs {len(self.columns)} columns); export it "
                "separately or use --layout long"
            )
            raise ReplayError(msg)


class _Writer:
    """Appends frames to one file per table (CSV directly, parquet through parts)."""

    def __init__(self, out: Path, fmt: str, layout: str = "long") -> None:
        self.out = out
        self.fmt = fmt
        self.layout = layout
        self.tables = {name: _Table(out / f"{name}.{fmt}") for name in TABLES}
        self._parts: Path | None = None

    def open(self) -> None:
        """Create the output directory; refuse existing tables.

        Raises:
            ReplayError: A table exists, or the directory cannot be created.
        """
        if existing := [t.path.name for t in self.tables.values() if t.path.exists()]:
            msg = (
                f"{self.out}: holds {', '.join(existing)} already; exports are never "
                "overwritten: choose another --out or delete them"
            )
            raise ReplayError(msg)
        try:
            self.out.mkdir(parents=True, exist_ok=True)
            if self.fmt == "parquet":  # a fresh private directory (mode 0700, random name)
                self._parts = Path(tempfile.mkdtemp(prefix=".export-parts-", dir=self.out))
        except OSError as err:
            raise _write_error(self.out, err) from err

    def append(self, tables: dict[str, pl.DataFrame], source: str) -> None:
        """Append one recording's tables.

        Raises:
            ReplayError: A table's columns changed or a file cannot be written.
        """
        for name, frame in tables.items():
            table = self.tables[name]
            table.check(frame, source)
            try:
                self._append(name, table, frame)
            except _WRITE_ERRORS as err:
                raise _write_error(table.path, err) from err
            table.rows += frame.height

    def _append(self, name: str, table: _Table, frame: pl.DataFrame) -> None:
        """Append to the open CSV file (header once), or write the next parquet part."""
        if self.fmt == "csv":
            first = table.handle is None
            if table.handle is None:
                table.temporary = temporary_name(table.path, "part")
                table.handle = create_exclusive(table.temporary)
            frame.write_csv(table.handle, include_header=first)
            return
        if self._parts is None:
            msg = "parquet parts written before the export was opened"
            raise RuntimeError(msg)
        part = self._parts / f"{name}-{len(table.parts):06d}.parquet"
        frame.write_parquet(part)
        table.parts.append(part)

    def finish(self) -> dict[str, int]:
        """Complete every table under its final name.

        Returns:
            Rows per table.

        Raises:
            ReplayError: A file cannot be written.
        """
        for table in self.tables.values():
            try:
                self._finish(table)
            except _WRITE_ERRORS as err:
                raise _write_error(table.path, err) from err
        self._remove_parts()
        return {name: table.rows for name, table in self.tables.items()}

    def _finish(self, table: _Table) -> None:
        """Close or merge one table's temporary output and give it its final name.

        The final name is never replaced (a file that appeared meanwhile is refused). A table
        no recording had is written empty (:func:`empty_table`): the same files every time.
        """
        if table.handle is None and not table.parts:
            empty = empty_table(table.path.stem, self.layout)
            with atomic_path(table.path, replace=False) as temporary:
                if self.fmt == "csv":
                    empty.write_csv(temporary)
                else:
                    empty.write_parquet(temporary)
        elif self.fmt == "csv":
            if table.handle is not None and table.temporary is not None:
                table.handle.flush()
                os.fsync(table.handle.fileno())
                table.handle.close()
                publish_temporary(table.temporary, table.path, replace=False)
        elif table.parts:
            with atomic_path(table.path, replace=False) as temporary:
                pl.scan_parquet(table.parts, glob=False).sink_parquet(temporary)

    def _remove_parts(self) -> None:
        """Remove the parquet parts' private directory."""
        if self._parts is not None:
            shutil.rmtree(self._parts, ignore_errors=True)

    def abort(self) -> None:
        """Remove everything written so far (the final tables were never created)."""
        for table in self.tables.values():
            if table.handle is not None:
                table.handle.close()
            if table.temporary is not None:
                table.temporary.unlink(missing_ok=True)
        self._remove_parts()


@dataclass(frozen=True, slots=True)
class ExportReport:
    """What an export wrote.

    Attributes:
        out: The output directory.
        recordings: Number of recordings exported.
        files: The tables written.
        rows: Rows per table.
    """

    out: Path
    recordings: int
    files: tuple[Path, ...]
    rows: dict[str, int]


def _name(path: Path, root: Path | None, recording: ActionRecording) -> str:
    """Return the ``recording`` column value: the path relative to its dataset or ``root``.

    A file laid out as ``<object>/<action>/<trial>.mcap`` (as its metadata says) is named
    from its dataset directory (``wood/P1/001.mcap``: unique in the dataset), or from
    ``root`` when that lies higher up (several datasets exported together).
    """
    resolved = Path(path).resolve()
    meta = recording.metadata
    anchors = [Path(root).resolve()] if root is not None else []
    if len(resolved.parents) > 2 and (resolved.parents[1].name, resolved.parent.name) == (  # noqa: PLR2004
        meta.object_id,
        meta.action_id,
    ):
        anchors.append(resolved.parents[2])
    usable = [anchor for anchor in anchors if resolved.is_relative_to(anchor)]
    if not usable:
        return path.name
    top = min(usable, key=lambda anchor: len(anchor.parts))
    return resolved.relative_to(top).as_posix()


def export(
    paths: Sequence[Path],
    out: Path,
    *,
    fmt: str = "parquet",
    layout: str = "long",
    root: Path | None = None,
    on_recording: Callable[[Path], Any] | None = None,
) -> ExportReport:
    """Export recordings as one table per channel (see the module docstring).

    Args:
        paths: Recordings to export, in this order.
        out: Output directory (created if needed); existing tables are never overwritten.
        fmt: ``parquet`` or ``csv``.
        layout: Skin tables in the ``long`` or ``wide`` layout.
        root: Directory the ``recording`` column is relative to when it lies above each
            file's dataset directory (see :func:`_name`).
        on_recording: Called after every exported recording (progress).

    Returns:
        What was written.

    Raises:
        ReplayError: An option is unknown, a recording cannot be read, or a table cannot be
            written; nothing is left under the final names then.
    """
    if fmt not in FORMATS or layout not in LAYOUTS:
        msg = f"--format {fmt} --layout {layout}: use one of {FORMATS} and one of {LAYOUTS}"
        raise ReplayError(msg)
    if not paths:
        msg = "no recordings to export; give .mcap files or a dataset directory"
        raise ReplayError(msg)
    writer = _Writer(Path(out), fmt, layout)
    writer.open()
    try:
        for path in paths:
            recording = read_recording(path)
            writer.append(
                recording_tables(recording, _name(path, root, recording), layout), str(path)
            )
            if on_recording is not None:
                on_recording(path)
        rows = writer.finish()
    except BaseException:
        writer.abort()
        raise
    files = tuple(table.path for table in writer.tables.values())
    return ExportReport(Path(out), len(paths), files, rows)
