"""``atikt-record``: record one action, generate a dataset, rebuild a dataset's index.

Subcommands live in a registry: a function decorated with :func:`command` (its arguments
declared with :func:`arg`) becomes ``atikt-record <name>``. Errors of the project are printed
as one line on stderr with a non-zero exit status; anything else is a bug and keeps its
traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from rich.console import Console
from rich.markup import escape
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.table import Table

from recorder._catalog import load_actions, load_objects
from recorder._dataset import (
    INDEX_NAME,
    TaskResult,
    check_configuration,
    generate_dataset,
    incomplete_files,
    plan_dataset,
    recording_path,
    recordings,
    write_index,
)
from recorder._rig import Presenting
from recorder._rigconfig import (
    RigFactory,
    is_exclusive,
    load_rig_config,
    rig_factory,
    rig_names,
)
from recorder.errors import RecorderError
from recorder.runner._record import record_action
from schemas import SET_ASIDE_DIR, ContractError, cli, software_version

if TYPE_CHECKING:
    from collections.abc import Sequence

    from recorder._dataset import DatasetReport

PROG = "atikt-record"
DEFAULT_RIG = "sim"
#: Modules whose import registers further subcommands (``import-bag``).
COMMAND_MODULES: tuple[str, ...] = (
    "recorder.bagimport._command",
    "recorder._session_command",
    "recorder.virtuallab._command",
)


REGISTRY = cli.Registry()
#: The registered subcommands, by name.
COMMANDS = REGISTRY.commands
arg = cli.arg
command = REGISTRY.command


def catalog_ids(text: str) -> list[str]:
    """Parse a comma-separated list of catalog ids.

    Raises:
        argparse.ArgumentTypeError: No id (an empty list would record nothing), or an id is
            given twice (a session would record it once: more trials are ``--trials``).
    """
    names = [name.strip() for name in text.split(",") if name.strip()]
    if not names:
        msg = f"{text!r}: no id; give comma-separated ids (e.g. wood,foam_block)"
        raise argparse.ArgumentTypeError(msg)
    if twice := sorted({name for name in names if names.count(name) > 1}):
        msg = f"{text}: {', '.join(twice)} given twice; name each once (more trials: --trials)"
        raise argparse.ArgumentTypeError(msg)
    return names


#: ``--objects-catalog`` and ``--actions-catalog`` (every command that reads the catalogs).
CATALOG_ARGUMENTS = (
    arg("--objects-catalog", type=Path, help="object catalog TOML (default: the packaged one)"),
    arg("--actions-catalog", type=Path, help="action catalog TOML (default: the packaged one)"),
)


def rig_arguments() -> tuple[cli.Argument, ...]:
    """Return ``--rig``, ``--rig-config`` and ``--rig-option`` (every command that uses a rig)."""
    return (
        arg(
            "--rig",
            default=None,
            help=f"rig to use, one of {', '.join(rig_names())} (default: "
            f"the --rig-config file's, else {DEFAULT_RIG})",
        ),
        arg("--rig-config", type=Path, default=None, help="TOML file: rig = NAME, [options]"),
        arg(
            "--rig-option",
            action="append",
            default=[],
            metavar="KEY=VALUE",
            help="a rig setting, over the file's (repeatable; e.g. room_c=21.0)",
        ),
    )


def refuse_overlap(args: argparse.Namespace, *more: tuple[str, Path | None]) -> None:
    """Refuse an ``--out`` that equals, contains or lies inside an input (catalogs, rig file).

    Raises:
        schemas.cli.CliError: It does; the message names the input.
    """
    named = [
        ("--objects-catalog", args.objects_catalog),
        ("--actions-catalog", args.actions_catalog),
        ("--rig-config", getattr(args, "rig_config", None)),
    ]
    cli.refuse_overlap(args.out, [*named, *more])


def rig_from_args(args: argparse.Namespace) -> RigFactory:
    """Return the factory of the rig the options configure."""
    config = load_rig_config(args.rig_config, args.rig, args.rig_option)
    return rig_factory(config)


@command(
    "action",
    "record one exploratory action into <out>/<object>/<action>/<trial>.mcap",
    arg("--object", required=True, help="object id from the object catalog"),
    arg("--action", required=True, help="action id from the action catalog (P1, S2, C1, ...)"),
    arg("--trial", type=cli.trial, default=1, help="trial number, from 1 (default: 1)"),
    arg("--out", type=Path, required=True, help="dataset directory"),
    arg("--seed", type=cli.rig_seed, default=0, help="seed of the rig (default: 0)"),
    *rig_arguments(),
    *CATALOG_ARGUMENTS,
)
def _action(args: argparse.Namespace) -> int:
    refuse_overlap(args)
    objects = load_objects(args.objects_catalog)
    actions = load_actions(args.actions_catalog)
    (task,) = plan_dataset(
        objects, actions, object_ids=[args.object], action_ids=[args.action], trials=1
    )
    path = recording_path(args.out, task.obj.id, task.action.id, args.trial)
    factory = rig_from_args(args)
    check_configuration(args.out, args.seed, factory)
    with factory(args.seed) as rig:
        if isinstance(rig, Presenting) and rig.can_present(task.obj):
            rig.present(task.obj)  # the rig's configuration has the object's pose: go there
        written = record_action(rig, task.obj, task.action, args.trial, path, seed=args.seed)
    seconds = (written.end_ns - written.start_ns) / 1e9
    Console().print(
        f"{written.path}  {seconds:.1f} s  {written.size_bytes / 1e6:.2f} MB",
        markup=False,
        soft_wrap=True,
    )
    return 0


def _progress(console: Console) -> Progress:
    return cli.progress(  # a log or a pipe gets a plain line every few seconds, not a bar
        console,
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )


def _report(console: Console, report: DatasetReport) -> None:
    table = Table(title=escape(f"dataset {report.root}"), show_header=False)
    table.add_row("recordings written", str(report.written))
    table.add_row("recordings kept (existed)", str(report.skipped))
    table.add_row("size of all recordings", f"{report.size_bytes / 1e6:.1f} MB")
    table.add_row("index", escape(str(report.index)))
    console.print(table)
    if report.set_aside:
        console.print(
            f"[yellow]{len(report.set_aside)} unfinished recordings of stopped recorders moved "
            f"to {escape(str(report.root / SET_ASIDE_DIR))} (salvage one with 'atikt-replay "
            "check FILE --recover'); their trials were recorded again",
            soft_wrap=True,
        )
    if report.incomplete:
        console.print(
            f"[yellow]{len(report.incomplete)} unfinished recordings (*.mcap.part) from "
            "interrupted runs; salvage one with 'atikt-replay check FILE --recover', or "
            "delete them when no recorder is running (the run records those trials again)",
            soft_wrap=True,
        )


@command(
    "dataset",
    "record the simulated thesis dataset (every object x action x trial) and its index",
    arg("--out", type=Path, required=True, help="dataset directory"),
    arg("--objects", type=catalog_ids, help="comma-separated object ids (default: all)"),
    arg("--actions", type=catalog_ids, help="comma-separated action ids (default: all)"),
    arg("--trials", type=int, help="trials per (object, action) (default: the catalog's)"),
    arg("--seed", type=cli.rig_seed, default=0, help="dataset seed (default: 0)"),
    arg("--workers", type=cli.workers, help="worker processes (default: all cores)"),
    *rig_arguments(),
    *CATALOG_ARGUMENTS,
)
def _dataset(args: argparse.Namespace) -> int:
    refuse_overlap(args)
    tasks = plan_dataset(
        load_objects(args.objects_catalog),
        load_actions(args.actions_catalog),
        object_ids=args.objects,
        action_ids=args.actions,
        trials=args.trials,
    )
    factory = rig_from_args(args)
    console = Console(stderr=True)
    if is_exclusive(factory) and (args.workers or 1) > 1:
        note = f"{PROG}: rig {factory.config.name} is exclusive hardware: one action at a time"
        print(f"{note} in this process (--workers {args.workers} not used)", file=sys.stderr)  # noqa: T201
    with _progress(console) as progress:
        bar = progress.add_task("recording", total=len(tasks), unit="recordings")

        def advance(_result: TaskResult) -> None:
            progress.advance(bar)

        report = generate_dataset(
            tasks,
            args.out,
            factory,
            seed=args.seed,
            workers=cli.worker_count(args.workers),
            on_result=advance,
        )
    _report(cli.output_console(), report)  # into a pipe or a file: the table uncut
    return 0


@command(
    "index",
    f"rebuild <dir>/{INDEX_NAME} from the recordings in a dataset directory",
    arg("dir", type=Path, help="dataset directory"),
)
def _index(args: argparse.Namespace) -> int:
    if not args.dir.is_dir():
        msg = f"{args.dir}: not a directory; give the dataset directory (--out of 'dataset')"
        raise RecorderError(msg)
    if not recordings(args.dir):
        msg = (
            f"{args.dir}: no recordings (*.mcap) in it or below; give the dataset directory "
            "(--out of 'dataset', 'action' or 'import-bag')"
        )
        raise RecorderError(msg)
    path = write_index(args.dir)
    console = Console()
    console.print(str(path), markup=False, soft_wrap=True)
    if leftovers := incomplete_files(args.dir):
        console.print(
            f"[yellow]{len(leftovers)} unfinished recordings (*.mcap.part) ignored; "
            "salvage one with 'atikt-replay check FILE --recover'",
            soft_wrap=True,
        )
    return 0


def build_parser() -> argparse.ArgumentParser:
    """Return the argument parser with every registered subcommand."""
    for module in COMMAND_MODULES:
        importlib.import_module(module)
    return cli.build_parser(
        PROG,
        "Record exploratory actions of a UR10 with skin into MCAP files.",
        REGISTRY,
        software_version(),
    )


RECORDING = ("action", "dataset", "session", "listen")
"""The commands that record: a closed standard output is said on stderr, not passed over."""


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``atikt-record``; return the exit status (1 for a project error, 2 for usage)."""
    interrupted = "interrupted; finished recordings are kept, run it again to resume"
    try:
        return cli.run(build_parser(), argv, (RecorderError, ContractError), interrupted, RECORDING)
    except KeyboardInterrupt:  # while the parser is built
        print(f"{PROG}: {interrupted}", file=sys.stderr)  # noqa: T201
        return 130


__all__ = [
    "CATALOG_ARGUMENTS",
    "COMMANDS",
    "REGISTRY",
    "arg",
    "build_parser",
    "catalog_ids",
    "command",
    "main",
    "refuse_overlap",
    "rig_arguments",
    "rig_from_args",
    "rig_names",
]
