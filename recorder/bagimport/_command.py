"""``atikt-record import-bag``: a lab's ROS 1 / ROS 2 bag -> per-action recordings + index."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from rich.console import Console
from rich.table import Table

from recorder._catalog import load_actions, load_objects
from recorder._cli import _CATALOGS, arg, command
from recorder.bagimport._importer import ImportReport, bag_topics, import_bag
from recorder.bagimport._topicmap import EXAMPLE, load_topic_map
from recorder.errors import BagImportError

if TYPE_CHECKING:
    import argparse

_NS_PER_MS = 1e6


def _print_topics(console: Console, bag: Path) -> None:
    """Print the bag's topics, types and message counts (to write a topic map)."""
    table = Table("topic", "type", "messages", title=str(bag))
    for topic, msgtype, count in sorted(bag_topics(bag)):
        table.add_row(topic, msgtype, str(count))
    console.print(table)


def _print_report(console: Console, report: ImportReport) -> None:
    """Print what was written and how the skin cells were aligned."""
    table = Table(
        "modality",
        "rows dropped",
        "largest cell offset (ms)",
        "largest stamp jitter (ms)",
        title=f"{len(report.written)} recordings from {report.bag.name} -> {report.out}",
    )
    for modality, dropped in report.dropped_rows.items():
        offset = report.max_cell_offset_ns[modality] / _NS_PER_MS
        jitter = report.max_jitter_ns[modality] / _NS_PER_MS
        table.add_row(modality, str(dropped), f"{offset:.3f}", f"{jitter:.3f}")
    console.print(table)
    console.print(f"index -> {report.index}", highlight=False, soft_wrap=True)


@command(
    "import-bag",
    "import a lab's ROS 1 / ROS 2 bag as per-action recordings <out>/<object>/<action>/<trial>",
    arg("bag", type=Path, help="a ROS 1 .bag file or a ROS 2 bag directory (sqlite3 or MCAP)"),
    arg("--topic-map", type=Path, help=f"topic map TOML (commented example: {EXAMPLE})"),
    arg("--out", type=Path, help="dataset directory (existing recordings are kept)"),
    arg("--windows", type=Path, help="CSV of action windows (instead of the map's [windows])"),
    arg("--topics", action="store_true", help="list the bag's topics and types, then stop"),
    *_CATALOGS,
)
def _import_bag(args: argparse.Namespace) -> int:
    console = Console()
    if args.topics:
        _print_topics(console, args.bag)
        return 0
    if args.topic_map is None or args.out is None:
        msg = f"--topic-map and --out are required (start from recorder/data/{EXAMPLE})"
        raise BagImportError(msg)
    topic_map = load_topic_map(args.topic_map)
    if args.windows is not None:
        topic_map = topic_map.with_csv(args.windows)
    report = import_bag(
        args.bag,
        topic_map,
        args.out,
        objects=load_objects(args.objects_catalog),
        actions=load_actions(args.actions_catalog),
        on_written=lambda path: console.print(str(path), highlight=False, soft_wrap=True),
    )
    _print_report(console, report)
    return 0
