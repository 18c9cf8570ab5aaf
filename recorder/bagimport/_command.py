"""``atikt-record import-bag``: a lab's ROS 1 / ROS 2 bags -> per-action recordings + index."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, ProgressColumn, TextColumn
from rich.table import Table
from rich.text import Text

from recorder._catalog import load_actions, load_objects
from recorder._cli import _CATALOGS, arg, command, refuse_overlap
from recorder.bagimport._importer import import_bag
from recorder.bagimport._source import bag_topics
from recorder.bagimport._topicmap import EXAMPLE, load_topic_map
from recorder.errors import BagImportError
from schemas import cli

if TYPE_CHECKING:
    import argparse

    from rich.progress import Task, TaskID

    from recorder.bagimport._report import ImportReport

_NS_PER_MS = 1e6


class _Rate(ProgressColumn):
    """Messages per second of a task."""

    def render(self, task: Task) -> Text:
        """Return the task's speed."""
        speed = task.finished_speed or task.speed
        return Text(f"{speed:,.0f} msg/s" if speed else "- msg/s", style="progress.data.speed")


def _print_topics(console: Console, bags: list[Path]) -> None:
    """Print the bags' topics, types and message counts (to write a topic map)."""
    table = Table("topic", "type", "messages", title=", ".join(map(str, bags)))
    for topic, msgtype, count in sorted(bag_topics(bags)):
        table.add_row(topic, msgtype, str(count))
    console.print(table)


def _print_report(console: Console, report: ImportReport) -> None:
    """Print what was written, what was skipped and how the skin cells were aligned."""
    names = ", ".join(b.path.name for b in report.bags)
    table = Table(
        "modality",
        "rows dropped",
        "largest cell offset (ms)",
        "largest stamp jitter (ms)",
        title=f"{len(report.written)} recordings from {names} -> {report.out}",
    )
    for modality, dropped in report.dropped_rows.items():
        offset = report.max_cell_offset_ns.get(modality, 0) / _NS_PER_MS
        jitter = report.max_jitter_ns.get(modality, 0) / _NS_PER_MS
        table.add_row(modality, str(dropped), f"{offset:.3f}", f"{jitter:.6f}")
    for channel, dropped in report.dropped_samples.items():
        table.add_row(channel, str(dropped), "-", "-")
    console.print(table)
    _print_timing(console, report)
    for window, reason in report.skipped:
        console.print(f"skipped {window}: {reason}", highlight=False, soft_wrap=True)
    console.print(f"index -> {report.index}", highlight=False, soft_wrap=True)
    console.print(f"report -> {report.json_path}", highlight=False, soft_wrap=True)


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
            table.add_row(topic, modality, runs, gaps, lost, jitter, drift)
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
    *_CATALOGS,
)
def _import_bag(args: argparse.Namespace) -> int:
    console = Console()
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
        )
    if report.already_imported:
        bag, file = next(iter(report.already_imported.items()))
        console.print(
            f"{bag}: imported into {args.out} already ({args.out}/imports/{file}); nothing added",
            highlight=False,
            soft_wrap=True,
        )
        return 0
    _print_report(console, report)
    return 0
