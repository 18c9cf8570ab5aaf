"""``atikt-record session``: the command (the session itself is ``recorder._session``)."""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from rich.console import Console
from rich.markup import escape

from recorder._catalog import load_actions, load_objects
from recorder._cli import (
    CATALOG_ARGUMENTS,
    arg,
    catalog_ids,
    command,
    rig_arguments,
    rig_from_args,
)
from recorder._dataset import plan_dataset
from recorder._rigconfig import ConfiguredRig, check_object_poses
from recorder._session import SessionCheck, check_session, run_session
from recorder.errors import RecorderError
from recorder.runner._viewer import open_viewer
from recorder.writing._foxglove import DEFAULT_ADDRESS, FoxgloveView
from schemas import cli, lost_samples

if TYPE_CHECKING:
    import argparse

    from recorder._dataset import RecordingTask
    from recorder.runner._viewer import LiveViewer, Viewer
    from recorder.writing._writer import WrittenRecording


@command(
    "session",
    "record actions at a rig object by object (objects presented by the rig or placed by "
    "hand); an interrupted session resumes",
    arg("--objects", type=catalog_ids, required=True, help="comma-separated object ids, in order"),
    arg("--actions", type=catalog_ids, required=True, help="comma-separated action ids"),
    arg("--trials", type=int, help="trials per (object, action) (default: the catalog's)"),
    arg("--out", type=Path, required=True, help="dataset directory (resumed if it exists)"),
    arg(
        "--yes",
        action="store_true",
        help="unattended: ask nobody; every object needs a pose in the rig configuration",
    ),
    arg("--seed", type=cli.rig_seed, default=0, help="seed of the rig (default: 0)"),
    arg(
        "--dry-run",
        action="store_true",
        help="check everything the session would (the directory, the plan, the limits, the "
        "disk; connected: the arm's state and a second of the arm's and the skin's streams) "
        "and say what it would do; nothing moves, nothing is written",
    ),
    arg(
        "--foxglove",
        nargs="?",
        const=DEFAULT_ADDRESS,
        default=None,
        metavar="HOST:PORT",
        help=f"serve the signals live to Foxglove (WebSocket, default {DEFAULT_ADDRESS})",
    ),
    arg(
        "--view",
        nargs="?",
        const="",
        default=None,
        type=str,
        metavar="FILE.rrd",
        help="show the signals live in rerun as they arrive, and each recording once written "
        "(a viewer listening on 127.0.0.1; FILE.rrd: written to it instead; without a "
        "display: written beside --out, OUT.live.rrd)",
    ),
    *rig_arguments(),
    *CATALOG_ARGUMENTS,
)
def _session(args: argparse.Namespace) -> int:
    objects = load_objects(args.objects_catalog)
    factory = rig_from_args(args)
    if isinstance(factory, ConfiguredRig):  # a pose for an object of no catalog: a typo
        check_object_poses(factory.config, objects)
    tasks = plan_dataset(
        objects,
        load_actions(args.actions_catalog),
        object_ids=args.objects,
        action_ids=args.actions,
        trials=args.trials,
    )
    order = {object_id: position for position, object_id in enumerate(args.objects)}
    tasks.sort(key=lambda task: order[task.obj.id])  # stable: actions and trials keep theirs
    console = Console(soft_wrap=True, highlight=False)
    save = _view_file(args)
    if args.dry_run:
        found = check_session(tasks, args.out, factory, seed=args.seed, unattended=args.yes)
        return _say_check(console, found)

    def recorded(task: RecordingTask, written: WrittenRecording) -> None:
        seconds = (written.end_ns - written.start_ns) / 1e9
        console.print(
            escape(
                f"{task.obj.id}  {task.action.id}  trial {task.trial}  {written.path}  "
                f"{seconds:.1f} s"
            )
        )
        if lost := lost_samples(written.sources):  # said now, while the object is still here
            console.print(
                f"[yellow]{escape(str(written.path))}: live sources lost samples "
                f"({escape(lost)}); check fails on it: move it aside and run the session again "
                "to record the trial again[/yellow]"
            )

    def started(task: RecordingTask) -> None:
        # at a terminal, the operator sees what the arm is doing; piped output stays one line
        # per recording
        if console.is_terminal:
            doing = escape(f"{task.obj.id}  {task.action.id}  trial {task.trial}  ...")
            console.print(f"[dim]{doing}[/dim]")

    def set_aside(path: Path) -> None:
        console.print(f"unfinished recording of a stopped recorder set aside: {path}", markup=False)

    with contextlib.ExitStack() as stack:
        viewers, watched = _open_views(args, save, console, stack)
        report = run_session(
            tasks,
            args.out,
            factory,
            seed=args.seed,
            unattended=args.yes,
            on_recorded=recorded,
            on_set_aside=set_aside,
            viewers=viewers,
            on_start=started,
        )
    _say_missed(console, watched)
    console.print(
        f"session {report.root}: {report.written} "
        f"{'recording' if report.written == 1 else 'recordings'} written, {report.kept} kept "
        f"(existed); index {report.index}",
        markup=False,
    )
    return 0


def _say_missed(console: Console, watched: list[tuple[str, LiveViewer | FoxgloveView]]) -> None:
    """Say what each view could not show (the recordings hold everything)."""
    for name, view in watched:
        if view.dropped:
            console.print(
                f"{name}: the viewer fell behind; {view.dropped} items were not shown (the "
                "recordings hold everything)",
                markup=False,
            )
        if isinstance(view, FoxgloveView) and (line := view.behind_line()):
            console.print(line, markup=False)


def _open_views(
    args: argparse.Namespace, save: Path | None, console: Console, stack: contextlib.ExitStack
) -> tuple[list[Viewer], list[tuple[str, LiveViewer | FoxgloveView]]]:
    """Open ``--view`` and ``--foxglove`` (closed with ``stack``).

    Returns:
        The viewers to hand the session, and by option the views whose dropped items are
        said at the end.
    """
    viewers: list[Viewer] = []
    watched: list[tuple[str, LiveViewer | FoxgloveView]] = []
    if args.view is not None:
        fallback = args.out.with_name(f"{args.out.name}.live.rrd")
        live = open_viewer("rerun", f"session {args.out}", save, fallback=fallback)
        if live.note:  # no display: where the view goes instead; the session goes on
            print(live.note, file=sys.stderr, flush=True)  # noqa: T201
        viewers.append(stack.enter_context(live).sink)
        watched.append(("--view", live))
    if args.foxglove is not None:
        view = stack.enter_context(FoxgloveView(args.foxglove))
        console.print(f"foxglove: live on {view.url} (Foxglove: open connection, WebSocket)")
        viewers.append(view)
        watched.append(("--foxglove", view))
    return viewers, watched


def _view_file(args: argparse.Namespace) -> Path | None:
    """Return ``--view FILE.rrd`` (None: a viewer, or no view), refused where it cannot be.

    Raises:
        RecorderError: A dry run (it records nothing to show), or a file that exists (a
            session has no --force: nothing is overwritten).
    """
    if args.view is None:
        return None
    if args.dry_run:
        msg = "--view: a dry run records nothing to show; leave out --view or --dry-run"
        raise RecorderError(msg)
    save = Path(args.view) if args.view else None
    if save is not None and save.exists():
        msg = f"--view {save}: exists, and files are never overwritten; give a new file"
        raise RecorderError(msg)
    return save


def _say_check(console: Console, found: SessionCheck) -> int:
    """Print what a dry run found: the plan, the objects, the rig, the sources.

    Returns:
        The exit status: 1 when a source lost samples during the check, or sent nothing
        though its rate says it should have (the session's recordings would fail ``check``),
        else 0. A source slower than the check (a thermal sensor at 0.5 Hz) is said only.
    """
    console.print(
        f"dry run of session {found.root}: {found.to_record} to record, {found.kept} on disk "
        f"(kept); nothing moved, nothing written",
        markup=False,
    )
    if found.stale:
        console.print(
            f"{len(found.stale)} unfinished recordings of stopped recorders would be set aside "
            f"(e.g. {found.stale[0]})",
            markup=False,
        )
    for line in found.rig.lines():
        console.print(line, markup=False)  # plain text: a [skin] is not a style
    return 0 if found.rig.ready else 1
