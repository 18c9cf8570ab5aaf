"""Subcommands of ``atikt-replay`` that show and hand over data: ``view`` and ``export``.

rerun and matplotlib are imported when a command runs, not when the command line is parsed.
"""

from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from rich.console import Console

from replay.cli._main import arg, command, dataset_files, progress_bar
from replay.errors import ReplayError
from replay.learning._run_history import LearnRun, is_run_directory
from replay.outputs._export import FORMATS, LAYOUTS, export
from replay.outputs._foxglove import DEFAULT_ADDRESS as FOXGLOVE_ADDRESS
from replay.outputs._foxglove import serve_recordings
from replay.outputs._serve import DEFAULT_HOST, Served, serve_viewer, wait_until_interrupted
from replay.recording._container import read_summary
from replay.recording._reader import parse_metadata
from schemas import cli, enclosing_dataset

if TYPE_CHECKING:
    import argparse
    from collections.abc import Sequence

    import rerun as rr

_CONSOLE = Console(stderr=True)
#: Default ports of the web viewer and of the gRPC server it reads from.
WEB_PORT = 9090
GRPC_PORT = 9876


@dataclass(frozen=True, slots=True)
class Inputs:
    """What the command line named: recordings and learn-run directories.

    Attributes:
        recordings: Recording files, in the order given (directories expanded, sorted).
        runs: Learn output directories.
        root: The deepest directory holding every input (names in exports are relative to it).
    """

    recordings: tuple[Path, ...]
    runs: tuple[Path, ...]
    root: Path


def collect_inputs(paths: Sequence[Path], *, allow_runs: bool = True) -> Inputs:
    """Sort the given paths into recordings and learn runs.

    A file is a recording; a directory holding ``history.parquet`` is a learn run (when
    ``allow_runs``); any other directory contributes every ``*.mcap`` below it.

    Raises:
        ReplayError: A path does not exist, or nothing to show was found.
    """
    recordings: list[Path] = []
    runs: list[Path] = []
    for path in paths:
        if not path.exists():
            msg = f"{path}: no such file or directory; give recordings (.mcap) or directories"
            raise ReplayError(msg)
        if path.is_file():
            recordings.append(path)
        elif allow_runs and is_run_directory(path):
            runs.append(path)
        else:
            recordings.extend(dataset_files(path))
    if not recordings and not runs:
        names = ", ".join(str(p) for p in paths)
        msg = f"{names}: no recordings (*.mcap){' or learn runs' if allow_runs else ''} found"
        raise ReplayError(msg)
    parents = [p if p.is_dir() else p.parent for p in paths]
    root = Path(os.path.commonpath([p.resolve() for p in parents]))
    return Inputs(tuple(recordings), tuple(runs), root)


def _named(paths: Sequence[Path]) -> list[tuple[str, Path | None]]:
    """Return the inputs named on the command line, for :func:`schemas.cli.refuse_overlap`.

    A recording's dataset is an input too: a saved view or an export written beside the
    recording would become a file of the dataset (``check`` fails it, ``features`` reads it).
    """
    named: list[tuple[str, Path | None]] = [("input", path) for path in paths]
    roots = (enclosing_dataset(path, _object_action(path)) for path in paths if path.is_file())
    return named + [("dataset", root) for root in roots if root is not None]


def _object_action(path: Path) -> tuple[str, str] | None:
    """Return the object and action a recording's metadata says (None: it cannot be read).

    Only the summary is read; a file that cannot be read is refused by the command itself.
    """
    try:
        meta = parse_metadata(path, read_summary(path).metadata)
    except ReplayError:
        return None
    return meta.object_id, meta.action_id


def _view_name(inputs: Inputs) -> str:
    """Return the name of the rerun recording of a view."""
    items = [*inputs.recordings, *inputs.runs]
    if len(items) == 1:
        return str(items[0])
    return f"{len(inputs.recordings)} recordings, {len(inputs.runs)} runs under {inputs.root}"


def _attach_sink(stream: rr.RecordingStream, save: Path | None, served: Served | None) -> None:
    """Connect the stream to a file (``save``), a served web viewer or a spawned viewer.

    Raises:
        ReplayError: The sink cannot be set up; the message says which option to change.
    """
    try:
        if save is not None:
            stream.save(save)
        elif served is not None:
            stream.connect_grpc(served.grpc_url)
        else:
            stream.spawn()
    except (OSError, RuntimeError, ValueError) as err:
        how = "--save" if save is not None else "--serve" if served is not None else "the viewer"
        msg = f"{how}: rerun could not start ({err}); use --save FILE.rrd to write a file instead"
        raise ReplayError(msg) from err


def _check_display(args: argparse.Namespace) -> None:
    """Refuse to spawn the desktop viewer where there is no display (before any work).

    Without ``DISPLAY`` or ``WAYLAND_DISPLAY`` on Linux the viewer spends many seconds
    logging before it fails; macOS and Windows always have a display.

    Raises:
        ReplayError: No display on Linux and neither ``--save`` nor ``--serve`` given.
    """
    if args.save is not None or args.serve or not sys.platform.startswith("linux"):
        return
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        msg = (
            "no display to open the viewer on (DISPLAY and WAYLAND_DISPLAY are unset); write "
            "a file with --save FILE.rrd, or serve a web viewer with --serve"
        )
        raise ReplayError(msg)


def _figures(args: argparse.Namespace, runs: Sequence[LearnRun]) -> None:
    """Write the PNG figures of every learn run and print where."""
    from replay.outputs._run_figures import plot_run  # noqa: PLC0415 (matplotlib only when needed)

    for run in runs:
        directory = run.path / "figures" if args.figures is None else args.figures
        if args.figures is not None and len(runs) > 1:
            directory = args.figures / run.path.name
        for path in plot_run(run, directory):
            print(f"figure -> {path}")  # noqa: T201 (the command's output)


@command(
    "view",
    "show recordings and learn runs in rerun (a file with --save, a web viewer with --serve)",
    arg("paths", nargs="*", type=Path, help="recordings (.mcap), dataset or learn --out dirs"),
    arg(
        "--save",
        type=Path,
        default=None,
        help="write FILE.rrd instead of opening a viewer (never overwritten without --force)",
    ),
    arg("--force", action="store_true", help="replace an existing --save file"),
    arg(
        "--serve",
        action="store_true",
        help="serve a web viewer until Ctrl-C, on --host (this machine only by default)",
    ),
    arg(
        "--host",
        default=DEFAULT_HOST,
        help="--serve: the address to listen on; 0.0.0.0 exposes the viewer and its data, "
        "without authentication, to every machine that reaches this one",
    ),
    arg("--web-port", type=cli.port, default=WEB_PORT, help="web viewer port"),
    arg("--grpc-port", type=cli.port, default=GRPC_PORT, help="data port"),
    arg("--figures", type=Path, default=None, help="learn runs: PNG directory (<run>/figures)"),
    arg("--no-figures", action="store_true", help="learn runs: do not write PNG figures"),
    arg(
        "--foxglove",
        nargs="?",
        const=FOXGLOVE_ADDRESS,
        default=None,
        metavar="HOST:PORT",
        help="play the recordings (a live run's too) to Foxglove over WebSocket, byte for byte "
        f"(default {FOXGLOVE_ADDRESS}), until Ctrl-C",
    ),
    arg(
        "--speed",
        type=float,
        default=1.0,
        help="--foxglove: times faster than recorded, 0: at once (default: 1)",
    ),
)
def _view_command(args: argparse.Namespace) -> int:
    from replay.learning._run_history import load_run  # noqa: PLC0415

    chosen = [o for o, on in (("--save", args.save), ("--serve", args.serve)) if on]
    if args.foxglove is not None:
        chosen.append("--foxglove")
    if len(chosen) > 1:
        msg = f"{' and '.join(chosen)}: choose one (a file, a web viewer, or Foxglove)"
        raise ReplayError(msg)
    if args.foxglove is not None and Path(args.foxglove).exists():  # `--foxglove FILE`
        args.paths.insert(0, Path(args.foxglove))
        args.foxglove = FOXGLOVE_ADDRESS
    if not args.paths:
        msg = "view: give recordings (.mcap), dataset or learn --out directories to show"
        raise ReplayError(msg)
    inputs = collect_inputs(args.paths)
    if args.foxglove is not None:
        return _foxglove(args, inputs)
    _check_display(args)
    if args.save is not None:
        cli.refuse_overlap(args.save, _named(args.paths), option="--save")
        cli.refuse_irreplaceable(args.save, "--save")
    runs = [load_run(path) for path in inputs.runs]
    if args.serve:
        return _serve(args, inputs, runs)
    if args.save is None:
        _log(inputs, runs, None, None)
    else:
        with cli.publish_file(args.save, force=args.force, option="--save") as temporary:
            _log(inputs, runs, temporary, None)
        print(f"view -> {args.save}  (open it with: rerun {args.save})")  # noqa: T201
    if not args.no_figures:
        _figures(args, runs)
    return 0


def _foxglove(args: argparse.Namespace, inputs: Inputs) -> int:
    """Play the recordings, and those a live run recorded, to Foxglove until Ctrl-C."""
    recordings = list(inputs.recordings)
    for run in inputs.runs:
        recorded = dataset_files(run / "session") if (run / "session").is_dir() else []
        if not recorded:
            msg = (
                f"{run}: an offline learn run holds no recordings to play; view it without "
                "--foxglove (its figures), or give the recordings it learned from"
            )
            raise ReplayError(msg)
        recordings.extend(recorded)
    if not 0 <= args.speed < math.inf:  # nan too
        msg = f"--speed {args.speed:g}: give 0 (at once) or a positive factor"
        raise ReplayError(msg)
    serve_recordings(
        recordings,
        args.foxglove,
        speed=args.speed,
        say=lambda line: print(line, flush=True),  # noqa: T201
    )
    print("stopped serving", flush=True)  # noqa: T201
    return 0


def _serve(args: argparse.Namespace, inputs: Inputs, runs: Sequence[LearnRun]) -> int:
    """Serve the web viewer on ``--host`` until Ctrl-C (or SIGTERM)."""
    with serve_viewer(args.host, args.web_port, args.grpc_port) as served:
        _log(inputs, runs, None, served)
        if not args.no_figures:
            _figures(args, runs)
        print(f"web viewer on {served.address}; Ctrl-C stops serving", flush=True)  # noqa: T201
        wait_until_interrupted(served)
    print("stopped serving", flush=True)  # noqa: T201
    return 0


def _log(
    inputs: Inputs, runs: Sequence[LearnRun], save: Path | None, served: Served | None
) -> None:
    """Log recordings and runs to the chosen sink (a file, a served viewer, or a new viewer)."""
    from replay.outputs._view import log_recordings, log_run, new_stream  # noqa: PLC0415
    from replay.recording._reader import read_recording  # noqa: PLC0415 (keeps parsing fast)

    stream = new_stream(_view_name(inputs))
    _attach_sink(stream, save, served)
    log_recordings(stream, (read_recording(path) for path in inputs.recordings))
    for run in runs:
        log_run(stream, run, "run" if len(runs) == 1 else f"run/{run.path.name}")
    stream.flush()
    if save is not None:
        stream.disconnect()


@command(
    "export",
    "write each channel of recordings as one table (parquet or csv) for other tools",
    arg("paths", nargs="+", type=Path, help="recordings (.mcap) or dataset directories"),
    arg("--format", dest="fmt", choices=FORMATS, default="parquet", help="file format"),
    arg("--layout", choices=LAYOUTS, default="long", help="skin tables: long (a row per cell)"),
    arg("--out", type=Path, default=Path("export"), help="output directory (default: ./export)"),
)
def _export_command(args: argparse.Namespace) -> int:
    inputs = collect_inputs(args.paths, allow_runs=False)
    cli.refuse_overlap(args.out, _named(args.paths))
    progress = progress_bar(_CONSOLE)
    task = progress.add_task("exporting", total=len(inputs.recordings), unit="recordings")
    with progress:
        report = export(
            inputs.recordings,
            args.out,
            fmt=args.fmt,
            layout=args.layout,
            root=inputs.root,
            on_recording=lambda _path: progress.advance(task),
        )
    for path in report.files:
        print(f"{path}  {report.rows[path.stem]} rows")  # noqa: T201 (the command's output)
    return 0
