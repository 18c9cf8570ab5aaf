"""``atikt-replay``: inspect and validate recordings (and, registered elsewhere, learn and study).

A subcommand is one function registered with :func:`command`; its arguments are declared
with :func:`arg`; it returns the exit status::

    from replay.cli._main import arg, command

    @command("features", "extract features of a dataset", arg("dir", type=Path))
    def _features(args: argparse.Namespace) -> int: ...

A module that registers subcommands is listed in :data:`COMMAND_MODULES`; it is imported
before the command line is parsed. Errors of the project (:class:`replay.errors.ReplayError`)
are printed as one line on stderr with exit status 1; anything else is a bug and keeps its
traceback.
"""

from __future__ import annotations

import dataclasses
import errno
import importlib
import json
import os
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import joblib
import polars as pl
from rich.console import Console
from rich.markup import escape
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.table import Table

from replay.errors import RecordingError, ReplayError
from replay.recording._checks import (
    check_gaps,
    dataset_root,
    index_problems,
    index_row_problem,
    pauses_explained,
    read_index,
)
from replay.recording._container import read_summary, recover_command
from replay.recording._reader import (
    location_facts,
    parse_metadata,
    parse_sources,
    read_recording,
    stopped_reason,
)
from replay.recording._salvage import salvage
from schemas import (
    INCOMPLETE_SUFFIX,
    PART_SUFFIX,
    SET_ASIDE_DIR,
    ContractError,
    SourceStats,
    cli,
    dataset_recordings,
    is_incomplete,
    lost_samples,
    part_writer,
    process_running,
    recorder_at_work,
    software_version,
    unreadable,
)

if TYPE_CHECKING:
    import argparse
    from collections.abc import Sequence

    from replay.recording._container import ContainerSummary
    from replay.recording._reader import ActionRecording
    from replay.recording._salvage import RecoveryReport
    from schemas import RecordingMetadata

PROG = "atikt-replay"
#: Modules whose import registers further subcommands (``learn``, ``study``, ...).
COMMAND_MODULES: tuple[str, ...] = ("replay.cli._learn", "replay.cli._view")
_NS_PER_S = 1e9


REGISTRY = cli.Registry()
#: The registered subcommands, by name.
COMMANDS = REGISTRY.commands
arg = cli.arg
command = REGISTRY.command
one_line = cli.one_line
#: ``--workers``: worker processes, at least 1 (default: all cores).
WORKERS = arg("--workers", type=cli.workers, help="worker processes (default: all cores)")


def _existing(path: Path) -> Path:
    """Return ``path`` if it exists.

    Raises:
        ReplayError: It does not.
    """
    if path.is_symlink() and not path.exists():  # a link whose target is gone: name it
        missing = FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT))
        raise ReplayError(unreadable(path, missing))
    if not path.exists():
        msg = f"{path}: no such file or directory; give a recording (.mcap) or a dataset directory"
        raise ReplayError(msg)
    return path


def dataset_files(root: Path) -> list[Path]:
    """Return the recordings (``*.mcap``) under a dataset directory, sorted by path."""
    return dataset_recordings(root)


def _seconds(ns: int) -> str:
    return f"{ns / _NS_PER_S:.3f} s"


output_console = cli.output_console  # tables full width into a file or a pipe


def _print_json(value: object) -> None:
    """Print ``value`` as JSON on stdout (``--json``)."""
    print(json.dumps(value, indent=1))  # noqa: T201 (the command's output)


def _about(path: Path, meta: RecordingMetadata) -> Table:
    """Return the table of a recording's metadata."""
    # a recording's values are text, never markup: a rig value or a path may hold "[...]"
    about = Table(title=escape(str(path)), show_header=False)
    for key in ("object_id", "object_name", "action_id", "action_kind", "trial", "source"):
        about.add_row(key, escape(str(getattr(meta, key))))
    about.add_row("action parameters", escape(str(dict(meta.action_parameters))))
    about.add_row("rig", escape(str(dict(meta.rig))))
    about.add_row("seed", str(meta.seed))
    about.add_row("software / schema", f"{meta.software_version} / {meta.schema_version}")
    return about


def _print_sources(console: Console, sources: Sequence[SourceStats]) -> None:
    """Print what each live source delivered (nothing for a recording without live sources)."""
    if not sources:
        return
    origins = any(item.origin for item in sources)  # where a source's samples came from
    table = Table(
        "source", "basis", *(["from"] if origins else []), "expected", "received", "missing",
        "duplicated", "out of order", "overflow", "malformed", "out of range", "resets", "gaps",
        "unaligned", "clock offset", "drift", "max latency", title="live sources",
    )  # fmt: skip
    for item in sources:
        table.add_row(
            escape(item.name),
            item.basis,
            *([escape(item.origin or "-")] if origins else []),
            *(str(n) for n in (item.expected, item.received, item.missing, item.duplicated)),
            str(item.out_of_order),
            str(item.overflowed),
            str(item.malformed),
            str(item.out_of_range),
            str(item.counter_resets),
            f"{item.gaps} ({item.gap_ns / 1e9:.3f} s)" if item.gaps else "0",
            str(item.unaligned),
            _seconds(item.clock_offset_ns),
            f"{item.clock_drift_ns / 1e6:.3f} ms",
            f"{item.latency_max_ns / 1e6:.3f} ms",
        )
    console.print(table)


def _metadata_json(meta: RecordingMetadata) -> dict[str, Any]:
    """Return a recording's metadata as JSON values (every field of the metadata record)."""
    values = {f.name: getattr(meta, f.name) for f in dataclasses.fields(meta)}
    return {k: dict(v) if isinstance(v, Mapping) else v for k, v in values.items()}


def _sources_json(sources: Sequence[SourceStats]) -> list[dict[str, Any]]:
    """Return every live source's accounting, every field (counts, ns)."""
    return [dataclasses.asdict(item) for item in sources]


def _incomplete_channels(path: Path) -> tuple[ContainerSummary, list[tuple[str, int]]]:
    """Return the summary of an incomplete recording and its (topic, messages) per channel."""
    summary = read_summary(path)
    channels = [(t, c.message_count) for t, c in sorted(summary.channels.items())]
    return summary, channels


def _print_undecoded(
    console: Console, path: Path, summary: ContainerSummary, rows: list[tuple[str, int]], said: str
) -> None:
    """Print a recording from its summary alone (not decoded): ``said`` after its metadata."""
    console.print(_about(path, parse_metadata(path, summary.metadata)))
    if said:
        console.print(said, highlight=False, soft_wrap=True)
    channels = Table("channel", "messages", title="channels")
    for topic, count in rows:
        channels.add_row(escape(topic), str(count))
    console.print(channels)
    _print_sources(console, parse_sources(path, summary.metadata))


def _undecoded_json(
    path: Path, summary: ContainerSummary, rows: list[tuple[str, int]], **said: str
) -> dict[str, Any]:
    """Return ``info --json`` of a recording from its summary alone; ``said``: kind and why."""
    return {
        **said,
        "path": str(path),
        "metadata": _metadata_json(parse_metadata(path, summary.metadata)),
        "channels": [{"name": topic, "messages": count} for topic, count in rows],
        "sources": _sources_json(parse_sources(path, summary.metadata)),
    }


def _print_incomplete(console: Console, path: Path) -> None:
    """Print what a recording that a stop ended early holds (it is not decoded)."""
    summary, rows = _incomplete_channels(path)
    reason = stopped_reason(summary.metadata) or "unknown"
    said = f"[yellow]incomplete: the action was stopped ({escape(reason)})"
    _print_undecoded(console, path, summary, rows, said)


def _failing(path: Path, err: RecordingError) -> tuple[Any, list[tuple[str, int]], str] | None:
    """Return what a recording that fails its checks holds, if its container is readable.

    A file ``check`` refuses (a channel that started late, a pause) is still what a lab needs
    to look into: its metadata, its channels and its sources' accounting (which say what
    was lost) are shown with the reason. None when even its summary cannot be read.
    """
    try:
        summary, rows = _incomplete_channels(path)
        parse_metadata(path, summary.metadata)
        parse_sources(path, summary.metadata)
    except (ReplayError, ContractError, OSError, ValueError):
        return None
    return summary, rows, one_line(str(err))


def _say_failing(reason: str) -> None:
    """Say on stderr, in one line, why a recording fails its checks (what it holds follows)."""
    print(f"atikt-replay: error: {reason}", file=sys.stderr)  # noqa: T201


def _print_failing(console: Console, path: Path, err: RecordingError) -> bool:
    """Print what a recording that fails its checks holds; False when it cannot be read."""
    found = _failing(path, err)
    if found is None:
        return False
    summary, rows, reason = found
    _say_failing(reason)
    _print_undecoded(console, path, summary, rows, "")
    return True


def _incomplete_json(path: Path) -> dict[str, Any]:
    """Return ``info --json`` of a recording a stop ended early."""
    summary, rows = _incomplete_channels(path)
    stopped = stopped_reason(summary.metadata) or "unknown"
    return _undecoded_json(path, summary, rows, kind="incomplete", stopped=stopped)


def _channels(recording: ActionRecording) -> list[tuple[str, int, tuple[int, ...], float]]:
    """Return (name, samples, sample shape, rate in Hz) of every decoded series."""
    series = [(m, s.stamps_ns, s.data.shape) for m, s in recording.signals.items()]
    if recording.joints is not None:
        joints = recording.joints
        series += [("joint states", joints.stamps_ns, joints.position.shape)]
    if recording.tcp is not None:
        series += [("tcp pose", recording.tcp.stamps_ns, recording.tcp.position.shape)]
    rows = []
    for name, stamps, shape in series:
        span = int(stamps[-1] - stamps[0]) if stamps.size > 1 else 0
        rate = (stamps.size - 1) / (span / _NS_PER_S) if span else 0.0
        rows.append((name, int(stamps.size), tuple(int(n) for n in shape[1:]), rate))
    return rows


def _phases(recording: ActionRecording) -> list[tuple[str, int, int]]:
    """Return (phase, start from the first phase, duration) of every phase, ns."""
    origin = recording.phases[0].start_ns if recording.phases else 0
    rows = []
    for mark in recording.phases:
        start, stop = recording.phase_range(mark.phase)
        rows.append((str(mark.phase), int(start - origin), int(stop - start)))
    return rows


def _print_recording(console: Console, recording: ActionRecording) -> None:
    """Print what a recording holds: metadata, channels, phases, live sources."""
    console.print(_about(recording.path, recording.metadata))
    channels = Table("channel", "samples", "shape", "rate (Hz)", title="channels")
    for name, samples, shape, rate in _channels(recording):
        channels.add_row(name, str(samples), str(shape), f"{rate:.1f}")
    console.print(channels)
    phases = Table("phase", "start", "duration", title="phases")
    for phase, start, duration in _phases(recording):
        phases.add_row(phase, _seconds(start), _seconds(duration))
    console.print(phases)
    _print_sources(console, recording.sources)


def _recording_json(recording: ActionRecording) -> dict[str, Any]:
    """Return ``info --json`` of a recording."""
    return {
        "kind": "recording",
        "path": str(recording.path),
        "metadata": _metadata_json(recording.metadata),
        "channels": [
            {"name": name, "samples": samples, "shape": list(shape), "rate_hz": rate}
            for name, samples, shape, rate in _channels(recording)
        ],
        "phases": [
            {"phase": phase, "start_ns": start, "duration_ns": duration}
            for phase, start, duration in _phases(recording)
        ],
        "sources": _sources_json(recording.sources),
    }


def _summaries(files: Sequence[Path]) -> pl.DataFrame:
    """Return one row per recording from its summary and metadata (no decoding)."""
    rows = []
    for path in files:
        summary: ContainerSummary = read_summary(path)
        meta = parse_metadata(path, summary.metadata)
        rows.append(
            {
                "object": meta.object_id,
                "action": meta.action_id,
                "size": summary.size_bytes,
                "duration_ns": summary.end_ns - summary.start_ns,
            }
        )
    schema: dict[str, Any] = {"object": pl.String, "action": pl.String}
    schema |= {"size": pl.Int64, "duration_ns": pl.Int64}
    return pl.DataFrame(rows, schema=schema)


def _dataset_frame(root: Path) -> pl.DataFrame:
    """Return the dataset's per-recording summaries.

    Raises:
        ReplayError: No recordings in ``root``.
    """
    frame = _summaries(dataset_files(root))
    if frame.is_empty():
        msg = f"{root}: no recordings (*.mcap) in this directory; give a dataset directory"
        raise ReplayError(msg)
    return frame


def _trials(frame: pl.DataFrame) -> pl.DataFrame:
    """Return the recordings per object (rows) and action (columns)."""
    return frame.pivot(
        on="action", index=["object"], values="size", aggregate_function="len"
    ).fill_null(0)


def _print_dataset(console: Console, root: Path) -> None:
    """Print a dataset directory's recordings per object and action."""
    frame = _dataset_frame(root)
    counts = _trials(frame)
    table = Table(*counts.columns, title=escape(str(root)), caption="trials per object and action")
    for row in counts.iter_rows():
        table.add_row(*(escape(str(value)) for value in row))
    console.print(table)
    hours = int(frame["duration_ns"].sum()) / _NS_PER_S / 3600
    console.print(
        f"{frame.height} recordings, {int(frame['size'].sum()) / 1e6:.1f} MB, "
        f"{hours:.2f} h of recorded time",
        soft_wrap=True,
    )
    if leftovers := sorted(root.rglob("*.mcap.part")):
        console.print(
            f"[yellow]{len(leftovers)} unfinished recordings (*.mcap.part)", soft_wrap=True
        )
    from replay.learning._cachedir import feature_cache_path  # noqa: PLC0415 (info on datasets)

    console.print(
        f"feature cache: {escape(str(feature_cache_path(root)))}", highlight=False, soft_wrap=True
    )


def _dataset_json(root: Path) -> dict[str, Any]:
    """Return ``info --json`` of a dataset directory."""
    from replay.learning._cachedir import feature_cache_path  # noqa: PLC0415 (info on datasets)

    frame = _dataset_frame(root)
    counts = _trials(frame)
    actions = [c for c in counts.columns if c != "object"]
    return {
        "kind": "dataset",
        "path": str(root),
        "recordings": frame.height,
        "size_bytes": int(frame["size"].sum()),
        "recorded_ns": int(frame["duration_ns"].sum()),
        "trials": {
            row["object"]: {a: int(row[a]) for a in actions} for row in counts.iter_rows(named=True)
        },
        "unfinished": len(sorted(root.rglob("*.mcap.part"))),
        "feature_cache": str(feature_cache_path(root)),
    }


#: ``--json`` of ``info`` and ``check``.
JSON = arg("--json", action="store_true", help="print JSON for scripts (fields: the manual)")


def _existing_all(paths: Sequence[Path], command: str) -> list[Path]:
    """Return ``paths`` if they exist; several must all be recordings (a shell's glob).

    Raises:
        ReplayError: A path does not exist, or one of several is a directory.
    """
    found = [_existing(path) for path in paths]
    if len(found) > 1 and (folder := next((p for p in found if p.is_dir()), None)):
        msg = (
            f"{folder}: a directory among {len(found)} paths; {command} takes one dataset "
            "directory, or one or more recordings (.mcap)"
        )
        raise ReplayError(msg)
    return found


def _info_json(path: Path) -> dict[str, Any]:
    """Return ``info --json`` of one path."""
    if path.is_dir():
        return _dataset_json(path)
    if is_incomplete(path):
        return _incomplete_json(path)
    try:
        return _recording_json(read_recording(path))
    except RecordingError as err:
        found = _failing(path, err)
        if found is None:
            raise
        summary, rows, reason = found
        return _undecoded_json(path, summary, rows, kind="failing", error=reason)


@command(
    "info",
    "print a summary of recordings or of a dataset directory",
    arg(
        "paths",
        type=Path,
        nargs="+",
        metavar="PATH",
        help="a dataset directory, or one or more recordings (.mcap)",
    ),
    JSON,
)
def _info(args: argparse.Namespace) -> int:
    paths = _existing_all(args.paths, "info")
    console = None if args.json else output_console()
    if len(paths) == 1:
        return 0 if _info_one(paths[0], console) else 1
    # several recordings (a shell's glob): each one readable is shown, each one not is one
    # line on stderr, and the status says whether all were read
    shown: list[dict[str, Any]] = []
    failed = 0
    for path in paths:
        try:
            if console is None:
                shown.append(entry := _info_json(path))
                if entry["kind"] == "failing":
                    failed += 1
                    _say_failing(entry["error"])
            else:
                failed += not _info_one(path, console)
        except ReplayError as err:
            failed += 1
            line = one_line(str(err))
            print(f"atikt-replay: error: {line}", file=sys.stderr)  # noqa: T201
            shown.append({"kind": "unreadable", "path": str(path), "error": line})
    if console is None:  # a list in the order given, an unreadable file's entry saying why
        _print_json(shown)
    if failed:
        said = f"{failed} of {len(paths)} recordings could not be read or fail their checks"
        print(said, file=sys.stderr)  # noqa: T201
    return 1 if failed else 0


def _info_one(path: Path, console: Console | None) -> bool:
    """Print ``info`` of one path on ``console``; JSON without one (``--json``).

    Returns:
        False when the path is a recording that fails its checks (shown, with the reason).
    """
    if console is None:
        shown = _info_json(path)
        if shown.get("kind") == "failing":
            _say_failing(shown["error"])
        _print_json(shown)
        return shown.get("kind") != "failing"
    if path.is_dir():
        _print_dataset(console, path)
    elif is_incomplete(path):
        _print_incomplete(console, path)
    else:
        try:
            recording = read_recording(path)
        except RecordingError as err:
            if not _print_failing(console, path, err):
                raise
            return False
        _print_recording(console, recording)
    return True


def _check_one(path: Path) -> tuple[str | None, str | None, dict[str, Any] | None]:
    """Return (the error or None, a warning or None, what the index row of the file holds).

    The third is None when the file cannot be read; the index itself is compared in the
    command's process (:func:`_against_index`), which reads it once.
    """
    try:
        recording = read_recording(path)
        facts = location_facts(recording)
    except ReplayError as err:
        return one_line(str(err)), None, None
    return (*_accounting_verdict(recording), facts)


def _against_index(
    path: Path, files: Sequence[Path], facts: Mapping[Path, Mapping[str, Any]]
) -> tuple[list[str], list[str]]:
    """Compare the checked recordings with their datasets' indexes, each index read once.

    An index that cannot be read is one problem of its own: the recordings are judged on
    their own then (the index is derived data, rebuilt from them), not failed one by one.

    Args:
        path: What was checked: a dataset directory (its index must list ``files``) or a
            recording.
        files: The recordings checked.
        facts: What each readable recording says (:func:`location_facts`).

    Returns:
        The recordings' problems (their row says something else), and the indexes' problems.
    """
    indexes: dict[Path, dict[str, dict[str, Any]] | None] = {}
    broken: list[str] = []

    def rows_of(root: Path) -> dict[str, dict[str, Any]] | None:
        key = root.resolve()
        if key not in indexes:
            try:
                indexes[key] = read_index(root)
            except RecordingError as err:
                indexes[key] = None
                broken.append(one_line(str(err)))
        return indexes[key]

    own = rows_of(path) if path.is_dir() else None  # named as given, read first
    bad: list[str] = []
    for file, fact in facts.items():
        root = dataset_root(file)
        rows = None if root is None else rows_of(root)
        if root is not None and rows is not None:
            bad += filter(None, [index_row_problem(file, root, rows, fact)])
    if own is not None:
        broken += index_problems(path, files, own)
    return bad, broken


def _seed_problem(seeds: Mapping[int, Path]) -> list[str]:
    """Return a problem when the checked recordings hold more than one seed (one dataset)."""
    if len(seeds) < 2:  # noqa: PLR2004 (one seed is one dataset)
        return []
    shown = "; ".join(f"seed {seed} (e.g. {path})" for seed, path in sorted(seeds.items())[:2])
    line = (
        f"the recordings hold {len(seeds)} seeds ({shown}): two runs wrote into one dataset; "
        "a dataset holds one seed: move the recordings of one seed to another directory"
    )
    return [line]


def _accounting_verdict(recording: Any) -> tuple[str | None, str | None]:  # noqa: ANN401
    """Return (an error on counted loss, a warning on what was counted without loss).

    The check agrees with the file's accounting: samples a source sent that the file lacks
    (missing, dropped by a full queue) fail it; samples counted and left out (duplicated,
    out of order, malformed, stamped out of range, counter resets) and a publisher's pauses
    (gaps) are warnings.
    """
    path = recording.path
    if lost := lost_samples(recording.sources):
        error = (
            f"{path}: live sources lost samples ({lost}); the recording lacks data "
            "its sources sent: record the action again"
        )
        return error, None
    counted = pauses_explained(recording.sources)
    if not counted:
        return None, None
    pause = check_gaps(path, recording.phase_range("execute"), recording.signals, counted)
    if pause:
        return None, pause
    return None, (
        f"{path}: live sources counted ({counted}), no valid sample lost: the recording is "
        f"usable; {_counted_fix(recording.sources)}"
    )


def _counted_fix(sources: Sequence[Any]) -> str:
    """Return what to look at for what the live sources counted without loss (one clause)."""
    fixes = {
        "malformed": "malformed: check the source's layout (for a skin, [skin] in the rig "
        "configuration against its firmware) and its link",
        "out_of_range": "stamped out of range: check the source's clock (rate_hz, unit_ns)",
        "counter_resets": "counter resets: the source restarted during the action",
        "duplicated": "duplicated or out of order: the transport repeats or reorders",
        "out_of_order": "duplicated or out of order: the transport repeats or reorders",
        "gaps": "gaps: the publisher paused",
        "unaligned": "left out of the rows: a cell's samples came without the others'",
    }
    said = dict.fromkeys(fixes[kind] for kind in fixes if any(getattr(s, kind) for s in sources))
    return "; ".join(said) or "nothing to fix"


def _incomplete(root: Path) -> list[str]:
    """Return one warning per recording a stop ended early under ``root``."""
    return [
        f"{path}: incomplete, kept for inspection (the action was stopped: "
        f"{stopped_reason(read_summary(path).metadata) or 'unknown'}); not a recording of the "
        "dataset"
        for path in sorted(root.rglob("*.mcap"))
        if is_incomplete(path)
    ]


def _unfinished(root: Path) -> tuple[list[str], list[str]]:
    """Return the unfinished recordings (``*.mcap.part``) under ``root``: problems, and notes.

    A file whose recorder is still running (the process id in its name) is being written: a
    note, not a failure (a check beside a running session must not ask to salvage it). One
    whose recorder is gone was left by an interrupted recorder: a problem.
    """
    problems, writing = [], []
    for part in sorted(root.rglob(f"*{PART_SUFFIX}")):
        if part.is_relative_to(root / SET_ASIDE_DIR):  # set aside: reported, not failed
            continue
        if process_running(pid := part_writer(part)):
            writing.append(
                f"{part}: being written by a running recorder (process {pid}); checked once "
                "it is finished"
            )
            continue
        problems.append(
            f"{part}: an unfinished recording (the recorder was interrupted); salvage it with "
            f"{recover_command(part)}"
        )
    return problems, writing


def _print_salvage(report: RecoveryReport) -> None:
    """Print what a salvage kept, per channel."""
    console = Console()
    lost = f"; the rest is lost ({report.stopped})" if report.stopped else ""
    console.print(
        escape(
            f"salvaged {report.messages} messages from {report.source} into {report.target}: "
            f"{report.intact_bytes} of {report.source_bytes} bytes intact, "
            f"{report.damaged_chunks} damaged chunks skipped{lost}"
        ),
        highlight=False,
        soft_wrap=True,
    )
    table = Table("channel", "messages kept", "seconds kept", title="kept per channel")
    for channel in report.channels:
        table.add_row(escape(channel.topic), str(channel.messages), f"{channel.seconds:.3f}")
    console.print(table)


def _recover(path: Path, out: Path | None) -> int:
    """Salvage one file (``check --recover``)."""
    if path.is_dir():
        msg = f"{path}: --recover salvages one file; give the *.mcap.part or damaged *.mcap file"
        raise ReplayError(msg)
    if out is not None:
        cli.refuse_overlap(out, [("recording", path)])
    _print_salvage(salvage(path, out))
    return 0


progress_line = cli.progress_line  # a task's progress as one line for a log


def progress_bar(console: Console) -> Progress:
    """Return a progress bar (description, bar, done of total, elapsed, time left) on ``console``.

    Not a terminal (a log, a pipe): a plain line every few seconds (:func:`cli.progress_line`).
    A task's ``unit`` field (``add_task(..., unit="tasks")``) names what is counted.
    """
    if not console.is_terminal:
        return cli.PlainProgress(console)
    return cli.progress(
        console,
        "[progress.description]{task.description}",
        BarColumn(),
        MofNCompleteColumn(),
        "{task.fields[unit]}",
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )


#: Files checked in the command's own process when they hold fewer bytes than this: starting
#: worker processes costs about 1.3 s here, and a check reads about 20 MB/s per core (a
#: default recording, 275 kB, in 14 ms); two workers gain only beyond about 50 MB (3 files:
#: 1.4 s in process against 2.6 s with 2 workers; 130 files: 3.2 s against 3.8 s; 1,950
#: files: 28.0 s against 13.1 s).
SERIAL_BYTES = 32 * 2**20


def _check_all(
    files: Sequence[Path], workers: int
) -> tuple[list[str], list[str], dict[Path, dict[str, Any]], dict[int, Path]]:
    """Check every file with a progress bar, on ``workers`` processes beyond a few MB.

    Returns:
        The problems (files refused), the warnings (files valid, but something was counted),
        what each valid file says for its index row (:func:`location_facts`), and the seeds
        of the readable files (with a file of each).
    """
    bar = progress_bar(Console(stderr=True))
    task = bar.add_task("checking", total=len(files), unit="recordings")
    problems: list[str] = []
    warnings: list[str] = []
    facts: dict[Path, dict[str, Any]] = {}
    seeds: dict[int, Path] = {}
    size = sum(_size(file) for file in files)
    jobs = 1 if size < SERIAL_BYTES else min(workers, max(len(files), 1))
    with bar:
        with cli.workers_ignore_interrupts():  # the call starts the workers; Ctrl-C is ours
            results = joblib.Parallel(n_jobs=jobs, return_as="generator")(
                joblib.delayed(_check_one)(file) for file in files
            )
        for file, (problem, warning, fact) in zip(files, results, strict=True):
            bar.advance(task)
            problems += [problem] if problem is not None else []
            warnings += [warning] if warning is not None else []
            if fact is not None:
                seeds.setdefault(fact["seed"], file)
            if fact is not None and problem is None:  # a refused file is failed once
                facts[file] = fact
    return problems, warnings, facts, seeds


def _size(file: Path) -> int:
    """Return a file's size (0 if it cannot be read: its check says why)."""
    try:
        return file.stat().st_size
    except OSError:
        return 0


@command(
    "check",
    "validate recordings (CRCs, schema version, channels, decoding, dataset path and index); "
    "exit 1 if any is bad; --recover salvages an unfinished or damaged file",
    arg(
        "paths",
        type=Path,
        nargs="+",
        metavar="PATH",
        help="a dataset directory, or one or more recordings (.mcap or .mcap.part)",
    ),
    WORKERS,
    arg(
        "--recover",
        action="store_true",
        help="copy every intact message of PATH into <name>.recovered.mcap (PATH is unchanged)",
    ),
    arg("--out", type=Path, help="with --recover: the salvaged file (must not exist)"),
    JSON,
)
def _check(args: argparse.Namespace) -> int:
    paths = _existing_all(args.paths, "check")
    if args.recover:
        if len(paths) > 1:
            msg = f"--recover salvages one file; {len(paths)} were given"
            raise ReplayError(msg)
        return _recover(paths[0], args.out)
    path = paths[0]  # a directory comes alone (several paths are recordings)
    files = dataset_files(path) if path.is_dir() else paths
    bad, warnings, facts, seeds = _check_all(files, cli.worker_count(args.workers))
    unfinished, writing = _unfinished(path) if path.is_dir() else ([], [])
    stale, index = _against_index(path, files, facts)
    bad += stale
    if index and (writing or (path.is_dir() and recorder_at_work(path))):
        # a run recording into the dataset rebuilds its index when it finishes
        now = f"; a recorder is writing into {path} now: it rebuilds the index when it finishes"
        warnings += [line + now for line in index]
        index = []
    index += _seed_problem(seeds) if path.is_dir() else []
    incomplete = _incomplete(path) if path.is_dir() else []
    warnings += incomplete + writing
    aside = sorted((path / SET_ASIDE_DIR).rglob(f"*{PART_SUFFIX}")) if path.is_dir() else []
    # only what stopped actions kept (a session stopped in its first action): listed, not
    # "no recordings", and a failure all the same: nothing here is a recording of the dataset
    only_incomplete = not files and not unfinished and not writing
    if only_incomplete and not incomplete:
        msg = f"{path}: no recordings (*.mcap) found"
        raise ReplayError(msg)
    empty = [_only_incomplete(path, len(incomplete))] if only_incomplete else []
    if args.json:
        _print_json(
            {
                **({"path": str(path)} if len(paths) == 1 else {"paths": list(map(str, paths))}),
                "recordings": len(files),
                "valid": len(files) - len(bad),
                "failures": bad + index + unfinished + empty,
                "warnings": warnings,
                "unfinished": len(unfinished),
                "being_written": len(writing),
                "set_aside": [str(p) for p in aside],
                "ok": not (bad or index or unfinished or empty),
            }
        )
    else:
        _print_check(path, files, (bad, index + empty, unfinished, warnings), aside)
    return 1 if bad or index or unfinished or empty else 0


def _only_incomplete(root: Path, count: int) -> str:
    """Return the failure of a directory that holds only recordings stopped actions kept.

    A live learn run's session (``<out>/session`` beside ``<out>/live.json``) is resumed by
    its learn command, any other directory by its ``atikt-record session`` command.
    """
    from replay.live import live_run_of  # noqa: PLC0415 (the recorder on use)

    out = live_run_of(root)
    again = "the same session command resumes"
    if out is not None:
        again = f"the same live learn command resumes, with --out {out}"
    return (
        f"{root}: no recordings (*.mcap) found, only {count} incomplete "
        f"(*{INCOMPLETE_SUFFIX}, each listed) kept from actions a stop ended early; see what "
        f"one holds with atikt-replay info FILE, and record those actions again ({again})"
    )


def _print_check(
    path: Path,
    files: Sequence[Path],
    found: tuple[list[str], list[str], list[str], list[str]],
    aside: Sequence[Path],
) -> None:
    """Print a check's failures and warnings (stderr) and its counts (stdout)."""
    bad, index, unfinished, warnings = found
    console = Console(stderr=True)
    for problem in bad + index + unfinished:
        console.print(f"[red]FAIL[/red] {escape(problem)}", highlight=False, soft_wrap=True)
    for warning in warnings:
        console.print(f"[yellow]WARN[/yellow] {escape(warning)}", highlight=False, soft_wrap=True)
    Console().print(f"{len(files) - len(bad)} of {len(files)} recordings valid", soft_wrap=True)
    if unfinished:
        Console().print(f"{len(unfinished)} unfinished recordings (*{PART_SUFFIX})", soft_wrap=True)
    if aside:
        Console().print(
            f"{len(aside)} unfinished recordings of stopped recorders set aside in "
            f"{path / SET_ASIDE_DIR} (salvage one with {recover_command(aside[0])})",
            markup=False,
            highlight=False,
            soft_wrap=True,
        )


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """Return the argument parser with every registered subcommand.

    With ``command`` one of this module's own subcommands (``check``, ``info``, ...), the
    modules of :data:`COMMAND_MODULES` are not imported: the learner and its scipy take 0.6 s
    of a command's start, and a check of a dataset needs neither.
    """
    if command is None or command not in REGISTRY.commands:
        for module in COMMAND_MODULES:
            importlib.import_module(module)
    return cli.build_parser(
        PROG,
        "Replay, inspect and learn from tactile MCAP recordings.",
        REGISTRY,
        software_version(),
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``atikt-replay``; return the exit status (1 for a project error, 2 for usage)."""
    given = sys.argv[1:] if argv is None else list(argv)
    command = given[0] if given and not given[0].startswith("-") else None
    return cli.run(
        build_parser(command), argv, (ReplayError, ContractError), recording=("learn", "study")
    )
