"""``atikt-record import-bag`` and ``listen``: a lab's bags or live ROS 2 topics -> recordings.

``import-bag`` cuts a lab's ROS 1 / ROS 2 bags into per-action recordings and the index;
``listen`` does the same with the topics as they arrive over DDS (:mod:`._listen`).
"""

from __future__ import annotations

import contextlib
import signal
from pathlib import Path
from typing import TYPE_CHECKING

from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, ProgressColumn, TextColumn
from rich.table import Table
from rich.text import Text

from recorder._catalog import load_actions, load_objects
from recorder._cli import CATALOG_ARGUMENTS, arg, command, refuse_overlap
from recorder._session import DUE_SAMPLES
from recorder.bagimport._importer import import_bag
from recorder.bagimport._journal import listen_lock
from recorder.bagimport._listen import check_listen, listen, on_signal, recover
from recorder.bagimport._source import SkinTopic, bag_topics, extractors
from recorder.bagimport._topicmap import EXAMPLE, load_topic_map
from recorder.errors import BagImportError
from recorder.writing._foxglove import DEFAULT_ADDRESS, TopicView
from schemas import cli

if TYPE_CHECKING:
    import argparse
    from collections.abc import Mapping

    from rich.console import Console
    from rich.progress import Task, TaskID

    from recorder._catalog import ActionSpec, ObjectSpec
    from recorder.bagimport._listen import TopicCheck
    from recorder.bagimport._report import ImportReport
    from recorder.bagimport._topicmap import TopicMap

_NS_PER_MS = 1e6
#: How long ``listen --dry-run`` reads the topics by default, s.
DRY_RUN_S = 2.0
#: listen's exit status by the signal that stopped it (as a shell reports it; none: 0).
_STATUS = {
    "SIGHUP": cli.HUNG_UP_STATUS,
    "SIGTERM": cli.TERMINATED_STATUS,
    "SIGINT": cli.INTERRUPTED_STATUS,
    "": 0,
}


class _Rate(ProgressColumn):
    """Messages per second of a task."""

    def render(self, task: Task) -> Text:
        """Return the task's speed."""
        speed = task.finished_speed or task.speed
        return Text(f"{speed:,.0f} msg/s" if speed else "- msg/s", style="progress.data.speed")


def _print_topics(console: Console, bags: list[Path]) -> None:
    """Print the bags' topics, types and message counts (to write a topic map)."""
    table = Table("topic", "type", "messages", title=escape(", ".join(map(str, bags))))
    for topic, msgtype, count in sorted(bag_topics(bags)):
        table.add_row(escape(topic), escape(msgtype), str(count))
    console.print(table)


def _print_report(console: Console, report: ImportReport) -> None:
    """Print what was written, what was skipped and how the skin cells were aligned."""
    names = ", ".join(b.path.name for b in report.bags)
    resumed = f" ({len(report.resumed)} written by an earlier run)" if report.resumed else ""
    table = Table(
        "modality",
        "rows dropped",
        "gaps (s)",
        "largest cell offset (ms)",
        "largest stamp jitter (ms)",
    )
    for modality, dropped in report.dropped_rows.items():
        offset = report.max_cell_offset_ns.get(modality, 0) / _NS_PER_MS
        jitter = report.max_jitter_ns.get(modality, 0) / _NS_PER_MS
        gaps = f"{report.gaps.get(modality, 0)} ({report.gap_ns.get(modality, 0) / 1e9:.3f})"
        table.add_row(modality, str(dropped), gaps, f"{offset:.3f}", f"{jitter:.6f}")
    for channel, dropped in report.dropped_samples.items():
        table.add_row(escape(channel), str(dropped), "-", "-", "-")
    if report.repeated_stamps:  # whole messages, before any row: a line of their own
        repeated = str(report.repeated_stamps)
        table.add_row("skin messages (stamp repeated)", repeated, "-", "-", "-")
    # the title on a line of its own: as a table's title rich wraps it to the table's width
    title = f"{len(report.written)} recordings{resumed} from {names} -> {report.out}"
    console.print(title, highlight=False, soft_wrap=True, markup=False)
    console.print(table)
    for topic, count in report.malformed.items():
        console.print(
            f"{topic}: {count} messages malformed (one of the arm's joints missing, or "
            "velocities or efforts of another count than the joint names), not written; fix the "
            "driver",
            highlight=False,
            soft_wrap=True,
            markup=False,
        )
    _print_timing(console, report)
    _print_counted(console, report)
    for window, reason in report.skipped:
        console.print(f"skipped {window}: {reason}", highlight=False, soft_wrap=True, markup=False)
    console.print(f"index -> {report.index}", highlight=False, soft_wrap=True, markup=False)
    console.print(f"report -> {report.json_path}", highlight=False, soft_wrap=True, markup=False)


def _print_counted(console: Console, report: ImportReport) -> None:
    """Print, per topic counted by its messages' counter, the messages it shows lost."""
    if not report.counted:
        return
    table = Table(
        "topic", "messages", "lost", "duplicated", "counter resets", title="counted by counter"
    )
    for topic, c in report.counted.items():
        counts = (c["messages"], c["lost"], c["duplicated"], c["resets"])
        table.add_row(escape(topic), *(str(n) for n in counts))
    console.print(table)


def _print_timing(console: Console, report: ImportReport) -> None:
    """Print, per topic stamped by rate, its runs, gaps, lost frames, jitter and drift."""
    if not report.timing:
        return
    table = Table(
        "topic",
        "modality",
        "runs",
        "gaps (s)",
        "lost frames",
        "stamp jitter max / sd (ms)",
        "drift (ppm)",
        title='stamped from the sensor\'s rate (timing = "rate")',
    )
    for column in table.columns[:2]:
        column.no_wrap = True
    for topic, modalities in report.timing.items():
        for modality, t in modalities.items():
            drift = "-" if t["drift_ppm"] is None else f"{t['drift_ppm']:+.1f}"
            jitter = f"{t['jitter_max_ms']:.3f} / {t['jitter_sd_ms']:.3f}"
            gaps = f"{t['gaps']} ({t.get('gap_s', 0.0):.3f})"
            runs, lost = str(t["runs"]), str(t["lost_frames"])
            table.add_row(escape(topic), modality, runs, gaps, lost, jitter, drift)
    console.print(table)


@command(
    "import-bag",
    "import a lab's ROS 1 / ROS 2 bags as per-action recordings <out>/<object>/<action>/<trial>",
    arg(
        "bag",
        type=Path,
        nargs="+",
        help="ROS 1 .bag files or ROS 2 bag directories (sqlite3 or MCAP) of one session",
    ),
    arg("--topic-map", type=Path, help=f"topic map TOML (commented example: {EXAMPLE})"),
    arg("--out", type=Path, help="dataset directory (existing recordings are kept)"),
    arg("--windows", type=Path, help="CSV of action windows (instead of the map's [windows])"),
    arg("--topics", action="store_true", help="list the bags' topics and types, then stop"),
    *CATALOG_ARGUMENTS,
)
def _import_bag(args: argparse.Namespace) -> int:
    console = cli.output_console()  # into a pipe or a file: the table uncut
    bags = list(args.bag)
    if args.topics:
        _print_topics(console, bags)
        return 0
    if args.topic_map is None or args.out is None:
        msg = f"--topic-map and --out are required (start from recorder/data/{EXAMPLE})"
        raise BagImportError(msg)
    bags_named: list[tuple[str, Path | None]] = [("bag", bag) for bag in bags]
    refuse_overlap(args, *bags_named, ("--topic-map", args.topic_map), ("--windows", args.windows))
    topic_map = load_topic_map(args.topic_map)
    if args.windows is not None:
        topic_map = topic_map.with_csv(args.windows)
    objects, actions = load_objects(args.objects_catalog), load_actions(args.actions_catalog)
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), _Rate())
    with cli.progress(console, *columns) as progress:
        tasks: dict[str, TaskID] = {}
        report = import_bag(
            bags,
            topic_map,
            args.out,
            objects=objects,
            actions=actions,
            on_written=lambda path: progress.console.print(
                str(path), highlight=False, soft_wrap=True
            ),
            on_progress=lambda bag, done: progress.update(tasks[bag], completed=done),
            on_start=lambda bag, total: tasks.setdefault(bag, progress.add_task(bag, total=total)),
            on_set_aside=lambda path: progress.console.print(
                f"unfinished recording of a stopped import set aside: {path}",
                highlight=False,
                soft_wrap=True,
                markup=False,
            ),
        )
    if report.already_imported:
        bag, file = next(iter(report.already_imported.items()))
        console.print(
            f"{bag}: imported into {args.out} already ({args.out}/imports/{file}); nothing added",
            markup=False,
            highlight=False,
            soft_wrap=True,
        )
        return 0
    _print_report(console, report)
    return 0


@command(
    "listen",
    "record a lab's ROS 2 topics live over DDS: one file per annotated action, as import-bag",
    arg("--topic-map", type=Path, required=True, help=f"topic map TOML (example: {EXAMPLE})"),
    arg("--out", type=Path, required=True, help="dataset directory (existing recordings kept)"),
    arg(
        "--duration", type=cli.seconds, default=None, help="stop after S seconds (default: Ctrl-C)"
    ),
    arg(
        "--domain-id",
        type=cli.domain_id,
        default=0,
        help="DDS domain id (ROS_DOMAIN_ID; default: 0)",
    ),
    arg("--windows", type=Path, help="CSV of action windows (instead of the map's [windows])"),
    arg(
        "--loopback",
        action="store_true",
        help="join DDS on the loopback interface only (default: the interfaces Cyclone DDS "
        "picks, or those CYCLONEDDS_URI names)",
    ),
    arg(
        "--foxglove",
        nargs="?",
        const=DEFAULT_ADDRESS,
        default=None,
        metavar="HOST:PORT",
        help=f"serve the topics to Foxglove as received (WebSocket, default {DEFAULT_ADDRESS})",
    ),
    arg(
        "--recover",
        action="store_true",
        help="only write what stopped runs left in --out's journals (listen does it first)",
    ),
    arg(
        "--dry-run",
        action="store_true",
        help="find the map's topics, check their types and fields, read them for --duration "
        f"seconds (default {DRY_RUN_S:g}) and say what arrived; nothing is written",
    ),
    *CATALOG_ARGUMENTS,
)
def _listen(args: argparse.Namespace) -> int:
    topic_map = load_topic_map(args.topic_map)
    if args.windows is not None:
        topic_map = topic_map.with_csv(args.windows)
    objects, actions = load_objects(args.objects_catalog), load_actions(args.actions_catalog)
    if args.dry_run:
        return _listen_check(args, topic_map, objects, actions)
    if args.recover:
        say = lambda line: print(line, flush=True)  # noqa: E731, T201 (one line per file, journal)
        with listen_lock(args.out):  # not beside a listen into the same directory
            if not recover(
                topic_map, args.out, objects=objects, actions=actions, on_written=say, on_note=say
            ):
                print(f"{args.out}: no journal left by a stopped run")  # noqa: T201
        return 0
    ending = [number for number in cli.handled_signals() if number != signal.SIGINT]
    previous = {number: signal.signal(number, on_signal) for number in ending}
    try:
        with contextlib.ExitStack() as stack:
            view = None
            if args.foxglove is not None:
                view = stack.enter_context(TopicView(args.foxglove))
                print(f"foxglove: live on {view.url} (Foxglove: open connection, WebSocket)")  # noqa: T201
            report = _listen_run(args, topic_map, objects, actions, view)
            if view is not None and view.dropped:
                print(f"foxglove: the client fell behind; {view.dropped} messages not shown")  # noqa: T201
            if view is not None and (line := view.behind_line()):
                print(line)  # noqa: T201
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
    kept = f", {len(report.incomplete)} kept as incomplete" if report.incomplete else ""
    with contextlib.suppress(OSError):  # after SIGHUP the terminal may be gone
        print(f"{len(report.written)} recordings -> {args.out}{kept}")  # noqa: T201
    return _STATUS.get(report.interrupted, 1)


def _listen_check(
    args: argparse.Namespace,
    topic_map: TopicMap,
    objects: Mapping[str, ObjectSpec],
    actions: Mapping[str, ActionSpec],
) -> int:
    """Print what ``listen`` would record; 1 when a topic lost messages (a full queue, size)."""
    seconds = DRY_RUN_S if args.duration is None else args.duration
    found = check_listen(
        topic_map,
        args.out,
        objects=objects,
        actions=actions,
        domain_id=args.domain_id,
        seconds=seconds,
        loopback=args.loopback,
    )
    print(  # noqa: T201
        f"dry run of listen: DDS domain {args.domain_id}, {len(found)} topics of the map found, "
        f"their types and fields as it says; read for {seconds:g} s; nothing written"
    )
    for topic in found:
        print(f"  {topic.line()}")  # noqa: T201
    silent = [t.topic for t in found if not t.received]
    lossy = [t.topic for t in found if t.lost]
    # a skin topic that should have sent some messages in the check and sent none: the
    # session's rule (a slow one, or the annotations between actions, is said, not refused)
    skin = {t for t, e in extractors(topic_map).items() if isinstance(e, SkinTopic)}
    nothing = [t.topic for t in found if not t.received and t.topic in skin and _due(t, seconds)]
    wrong = [f"{', '.join(lossy)} lost messages"] if lossy else []
    if nothing:
        wrong.append(f"{', '.join(nothing)} sent nothing")
    if wrong:
        print(f"listen: not ready: {'; '.join(wrong)}")  # noqa: T201
        return 1
    quiet = f" ({', '.join(silent)} sent nothing: idle, or slower than the check)" if silent else ""
    print(f"listen: ready{quiet}")  # noqa: T201
    return 0


def _due(topic: TopicCheck, seconds: float) -> bool:
    """Whether a topic's rate says the check should have seen messages of it (none: yes)."""
    return topic.declared_hz is None or topic.declared_hz * seconds >= DUE_SAMPLES


def _listen_run(
    args: argparse.Namespace,
    topic_map: TopicMap,
    objects: Mapping[str, ObjectSpec],
    actions: Mapping[str, ActionSpec],
    view: TopicView | None,
) -> ImportReport:
    """Run ``listen`` with the command line's options, printing a line per file and note."""
    return listen(
        topic_map,
        args.out,
        objects=objects,
        actions=actions,
        domain_id=args.domain_id,
        duration_s=args.duration,
        discovery_s=10.0 if args.duration is None else min(10.0, args.duration),
        on_written=lambda path: print(path, flush=True),  # noqa: T201 (one line per file)
        on_note=lambda line: print(line, flush=True),  # noqa: T201
        loopback=args.loopback,
        view=view,
    )
