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

import importlib
from pathlib import Path
from typing import TYPE_CHECKING, Any

import joblib
import polars as pl
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn
from rich.table import Table

from replay.errors import RecordingError, ReplayError
from replay.recording._checks import index_problems
from replay.recording._container import read_summary, recover_command
from replay.recording._reader import (
    check_dataset_location,
    parse_metadata,
    read_recording,
)
from replay.recording._salvage import salvage
from schemas import (
    PART_SUFFIX,
    SET_ASIDE_DIR,
    ContractError,
    cli,
    dataset_recordings,
    software_version,
)

if TYPE_CHECKING:
    import argparse
    from collections.abc import Sequence

    from replay.recording._container import ContainerSummary
    from replay.recording._reader import ActionRecording
    from replay.recording._salvage import RecoveryReport

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
    if not path.exists():
        msg = f"{path}: no such file or directory; give a recording (.mcap) or a dataset directory"
        raise ReplayError(msg)
    return path


def dataset_files(root: Path) -> list[Path]:
    """Return the recordings (``*.mcap``) under a dataset directory, sorted by path."""
    return dataset_recordings(root)


def _seconds(ns: int) -> str:
    return f"{ns / _NS_PER_S:.3f} s"


def _print_recording(console: Console, recording: ActionRecording) -> None:
    """Print what a recording holds: metadata, channels, phases."""
    meta = recording.metadata
    about = Table(title=str(recording.path), show_header=False)
    for key in ("object_id", "object_name", "action_id", "action_kind", "trial", "source"):
        about.add_row(key, str(getattr(meta, key)))
    about.add_row("action parameters", str(dict(meta.action_parameters)))
    about.add_row("rig", str(dict(meta.rig)))
    about.add_row("seed", str(meta.seed))
    about.add_row("software / schema", f"{meta.software_version} / {meta.schema_version}")
    console.print(about)
    channels = Table("channel", "samples", "shape", "rate (Hz)", title="channels")
    series = [(m, s.stamps_ns, s.data.shape) for m, s in recording.signals.items()]
    if recording.joints is not None:
        joints = recording.joints
        series += [("joint states", joints.stamps_ns, joints.position.shape)]
    if recording.tcp is not None:
        series += [("tcp pose", recording.tcp.stamps_ns, recording.tcp.position.shape)]
    for name, stamps, shape in series:
        span = int(stamps[-1] - stamps[0]) if stamps.size > 1 else 0
        rate = (stamps.size - 1) / (span / _NS_PER_S) if span else 0.0
        channels.add_row(name, str(stamps.size), str(shape[1:]), f"{rate:.1f}")
    console.print(channels)
    phases = Table("phase", "start", "duration", title="phases")
    origin = recording.phases[0].start_ns if recording.phases else 0
    for mark in recording.phases:
        start, stop = recording.phase_range(mark.phase)
        phases.add_row(mark.phase, _seconds(start - origin), _seconds(stop - start))
    console.print(phases)


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


def _print_dataset(console: Console, root: Path) -> None:
    """Print a dataset directory's recordings per object and action."""
    frame = _summaries(dataset_files(root))
    if frame.is_empty():
        msg = f"{root}: no recordings (*.mcap) in this directory; give a dataset directory"
        raise ReplayError(msg)
    counts = frame.pivot(
        on="action", index=["object"], values="size", aggregate_function="len"
    ).fill_null(0)
    table = Table(*counts.columns, title=f"{root}", caption="trials per object and action")
    for row in counts.iter_rows():
        table.add_row(*(str(value) for value in row))
    console.print(table)
    hours = int(frame["duration_ns"].sum()) / _NS_PER_S / 3600
    console.print(
        f"{frame.height} recordings, {int(frame['size'].sum()) / 1e6:.1f} MB, "
        f"{hours:.2f} h of recorded time"
    )
    if leftovers := sorted(root.rglob("*.mcap.part")):
        console.print(f"[yellow]{len(leftovers)} unfinished recordings (*.mcap.part)")


@command(
    "info",
    "print a summary of a recording or of a dataset directory",
    arg("path", type=Path, help="a recording (.mcap) or a dataset directory"),
)
def _info(args: argparse.Namespace) -> int:
    path = _existing(args.path)
    console = Console()
    if path.is_dir():
        _print_dataset(console, path)
    else:
        _print_recording(console, read_recording(path))
    return 0


def _check_one(path: Path) -> str | None:
    """Return None if the recording reads and validates, else the error message."""
    try:
        check_dataset_location(read_recording(path))
    except ReplayError as err:
        return one_line(str(err))
    return None


def _unfinished(root: Path) -> list[str]:
    """Return one problem per unfinished recording (``*.mcap.part``) under ``root``."""
    return [
        f"{part}: an unfinished recording (the recorder was interrupted); salvage it with "
        f"{recover_command(part)}"
        for part in sorted(root.rglob(f"*{PART_SUFFIX}"))
        if not part.is_relative_to(root / SET_ASIDE_DIR)  # set aside: reported, not failed
    ]


def _print_salvage(report: RecoveryReport) -> None:
    """Print what a salvage kept, per channel."""
    console = Console()
    lost = f"; the rest is lost ({report.stopped})" if report.stopped else ""
    console.print(
        f"salvaged {report.messages} messages from {report.source} into {report.target}: "
        f"{report.intact_bytes} of {report.source_bytes} bytes intact, "
        f"{report.damaged_chunks} damaged chunks skipped{lost}",
        highlight=False,
        soft_wrap=True,
    )
    table = Table("channel", "messages kept", "seconds kept", title="kept per channel")
    for channel in report.channels:
        table.add_row(channel.topic, str(channel.messages), f"{channel.seconds:.3f}")
    console.print(table)


def _recover(path: Path, out: Path | None) -> int:
    """Salvage one file (``check --recover``)."""
    if path.is_dir():
        msg = f"{path}: --recover salvages one file; give the *.mcap.part or damaged *.mcap file"
        raise ReplayError(msg)
    _print_salvage(salvage(path, out))
    return 0


def progress_bar(console: Console) -> Progress:
    """Return a progress bar (description, bar, done of total, elapsed) on ``console``.

    Not a terminal (a log, a pipe): a plain line every few seconds (:func:`schemas.cli.progress`).
    """
    return cli.progress(
        console,
        "[progress.description]{task.description}",
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
    )


def _check_all(files: Sequence[Path], workers: int) -> list[str]:
    """Check every file on ``workers`` processes with a progress bar; return the problems."""
    bar = progress_bar(Console(stderr=True))
    task = bar.add_task("checking", total=len(files))
    problems: list[str] = []
    with bar:
        with cli.workers_ignore_interrupts():  # the call starts the workers; Ctrl-C is ours
            results = joblib.Parallel(
                n_jobs=min(workers, max(len(files), 1)), return_as="generator"
            )(joblib.delayed(_check_one)(file) for file in files)
        for problem in results:
            bar.advance(task)
            if problem is not None:
                problems.append(problem)
    return problems


@command(
    "check",
    "validate recordings (CRCs, schema version, channels, decoding, dataset path and index); "
    "exit 1 if any is bad; --recover salvages an unfinished or damaged file",
    arg("path", type=Path, help="a recording (.mcap or .mcap.part) or a dataset directory"),
    WORKERS,
    arg(
        "--recover",
        action="store_true",
        help="copy every intact message of PATH into <name>.recovered.mcap (PATH is unchanged)",
    ),
    arg("--out", type=Path, help="with --recover: the salvaged file (must not exist)"),
)
def _check(args: argparse.Namespace) -> int:
    path = _existing(args.path)
    if args.recover:
        return _recover(path, args.out)
    files = dataset_files(path) if path.is_dir() else [path]
    bad = _check_all(files, cli.worker_count(args.workers))
    console = Console(stderr=True)
    unfinished = _unfinished(path) if path.is_dir() else []
    try:
        index = index_problems(path, files) if path.is_dir() else []
    except RecordingError as err:
        index = [str(err)]
    for problem in bad + index + unfinished:
        console.print(f"[red]FAIL[/red] {escape(problem)}", highlight=False, soft_wrap=True)
    Console().print(f"{len(files) - len(bad)} of {len(files)} recordings valid")
    if unfinished:
        Console().print(f"{len(unfinished)} unfinished recordings (*{PART_SUFFIX})")
    if path.is_dir() and (aside := sorted((path / SET_ASIDE_DIR).rglob(f"*{PART_SUFFIX}"))):
        Console().print(
            f"{len(aside)} unfinished recordings of stopped recorders set aside in "
            f"{path / SET_ASIDE_DIR} (salvage one with {recover_command(aside[0])})",
            highlight=False,
            soft_wrap=True,
        )
    if not files and not unfinished:
        msg = f"{path}: no recordings (*.mcap) found"
        raise ReplayError(msg)
    return 1 if bad or index or unfinished else 0


def build_parser() -> argparse.ArgumentParser:
    """Return the argument parser with every registered subcommand."""
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
    return cli.run(build_parser(), argv, (ReplayError, ContractError))
