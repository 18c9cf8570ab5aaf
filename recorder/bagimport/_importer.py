"""Import a lab's ROS 1 / ROS 2 bags as per-action recordings (``atikt-record import-bag``).

rosbags' ``AnyReader`` reads ROS 1 ``.bag`` files and ROS 2 bags (sqlite3 or MCAP storage); the
bags of one call are one session (a recording split over files) read as one stream in
log-time order (a bag merged from several recorders too; a reader that cannot order its
messages is refused, naming the topic and the time). A topic map
(:mod:`recorder.bagimport._topicmap`) says which topics carry the skin (any cells, any subset
of the contract's modalities, any widths and rates, batched or not), the robot (any joints, or
none) and the tool pose (optional), and where the actions are.

The import streams: the action windows are known first (annotation topic or CSV), then every
message is read once and its samples go to the window whose ``[start - 1 s, stop + 1 s)``
holds their stamp. A window is packed and written as soon as the bag has passed its end by
``[time] max_delay_s`` (the longest a sample may arrive after its stamp), so memory holds
at most a few windows, whatever the bag's size. Every window becomes one file
``<out>/<object>/<action>/<trial>.mcap`` written by the recorder's own
:class:`~recorder.writing._writer.RecordingWriter`; then ``objects.toml``, the dataset index
and the import report (``<out>/imports/<id>.json``) are written. An import is all or nothing:
on an error the recordings it wrote are removed again. Alignment and packing of the skin:
:mod:`recorder.bagimport._pack`.
"""

from __future__ import annotations

import bisect
import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from recorder._catalog import ObjectSpec
from recorder._dataset import (
    declare_objects,
    first_metadata,
    rig_identity,
    set_aside_stale_parts,
    write_index,
)
from recorder.bagimport._pack import (
    Series,
    block_period,
    left_out_by_topic,
    skin_blocks,
    window_rows,
)
from recorder.bagimport._report import (
    BagIdentity,
    ImportReport,
    bag_identity,
    earlier_import,
    imported_bags,
    window_key,
)
from recorder.bagimport._source import (
    READ_ERRORS,
    JointTopic,
    PoseTopic,
    SkinTopic,
    check_connections,
    check_fields,
    extractors,
    message_stamp,
    open_reader,
    raw_messages,
    required_types,
    unreadable,
)
from recorder.bagimport._topicmap import LabAction, LabObject
from recorder.bagimport._windows import (
    PathPlanner,
    Window,
    check_no_overlap,
    windows_from_annotations,
    windows_from_csv,
)
from recorder.errors import BagImportError, RecorderError
from recorder.live import SourceStats, gap_periods
from recorder.runner._interrupts import deferred_interrupts, raise_interrupt
from recorder.writing._stream import JointSample, PhaseEvent, PoseSample
from recorder.writing._writer import RecordingInfo, RecordingWriter
from schemas import (
    SCHEMA_VERSION,
    VOCABULARY,
    RecordingMetadata,
    check_rig,
    lost_samples,
    software_version,
)
from schemas.cdr import compile_cdr, compile_ros1

if TYPE_CHECKING:
    from collections.abc import Callable, Hashable, Iterable, Iterator, Mapping, Sequence

    from numpy.typing import NDArray
    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import Connection
    from rosbags.typesys.store import Typestore

    from recorder._catalog import ActionSpec
    from recorder.bagimport._source import Extractor
    from recorder.bagimport._topicmap import TopicMap
    from recorder.writing._stream import SkinBlock, StreamItem

#: Samples kept around a window: the skin's rows at its edges, and alignment neighbours.
MARGIN_NS = 1_000_000_000
#: Most message bytes held between two written windows (a hostile bag cannot exhaust memory).
MAX_PENDING_BYTES = 160 * 1024 * 1024
#: How much shorter than the action's duration an execute phase may be (the reader's rule).
DURATION_TOLERANCE = 0.01
_NS_PER_S = 1_000_000_000
_PROGRESS_EVERY = 2000


@dataclass(frozen=True, slots=True)
class _Plan:
    """A window with its trial, path, object and action."""

    window: Window
    trial: int
    path: Path
    obj: LabObject
    action: LabAction
    #: Live: why the window is kept as an incomplete recording (empty: it is complete).
    incomplete: str = ""


# ------------------------------------------------------------------------- catalog entries


def _lab_action(spec: ActionSpec) -> LabAction:
    """Return a catalog action as a lab action."""
    return LabAction(spec.id, str(spec.kind), spec.parameters(), spec.description)


def _lab_object(spec: ObjectSpec) -> LabObject:
    """Return a catalog object as a lab object."""
    return LabObject(spec.id, spec.name, spec.description, spec.novel)


def _entry(
    kind: str, wanted: str, declared: Mapping[str, Any], catalog: Mapping[str, Any], where: str
) -> Any:  # noqa: ANN401
    """Return an object or action from the map's declarations, else from the catalog.

    Raises:
        BagImportError: Neither knows it.
    """
    if wanted in declared:
        return declared[wanted]
    if wanted in catalog:
        return catalog[wanted]
    msg = (
        f"{where}: {kind} {wanted!r} is neither in the {kind} catalog nor declared in the topic "
        f"map; add [{kind}s.{wanted}] to the map (or to the catalog)"
    )
    raise BagImportError(msg)


def _check_action(window: Window, action: LabAction, topic_map: TopicMap) -> None:
    """Refuse a window the reader would refuse: short execute phase, missing modality.

    Raises:
        BagImportError: The execute phase is shorter than ``duration_s`` or a needed
            modality is not mapped.
    """
    if missing := [m for m in VOCABULARY.kind(action.kind).needs if m not in topic_map.skin]:
        msg = (
            f"{window.describe()}: action {action.id} of kind {action.kind} needs {missing[0]}, "
            f"which the topic map does not map; add [skin.{missing[0]}] or declare the action "
            "with another kind"
        )
        raise BagImportError(msg)
    start, stop = window.phase_start("execute"), window.phase_stop("execute")
    needed = round(action.duration_s * (1 - DURATION_TOLERANCE) * _NS_PER_S) - 1_000_000
    if stop - start < needed:
        msg = (
            f"{window.describe()}: its execute phase lasts {(stop - start) / _NS_PER_S:.3f} s, "
            f"action {action.id} lasts {action.duration_s:g} s; fix the window, or declare the "
            f"lab's action under [actions.<id>] in the topic map with its duration_s"
        )
        raise BagImportError(msg)


def lab_catalogs(
    objects: Mapping[str, ObjectSpec], actions: Mapping[str, ActionSpec]
) -> tuple[dict[str, LabObject], dict[str, LabAction]]:
    """Return the catalogs' objects and actions as the map declares its own."""
    return (
        {k: _lab_object(v) for k, v in objects.items()},
        {k: _lab_action(v) for k, v in actions.items()},
    )


def plan_window(
    planned: tuple[Window, int, Path],
    topic_map: TopicMap,
    catalogs: tuple[Mapping[str, LabObject], Mapping[str, LabAction]],
    incomplete: str = "",
) -> _Plan:
    """Resolve a window's object and action and check it (``planned``: from ``plan_paths``).

    An incomplete window (live: its action was cut or joined part-way; ``incomplete`` says
    why) is not checked against the action's duration: it is kept as what arrived.

    Raises:
        BagImportError: Unknown object or action, or a window the reader would refuse.
    """
    window, trial, path = planned
    where = window.describe()
    obj = _entry("object", window.object_id, topic_map.objects, catalogs[0], where)
    action = _entry("action", window.action_id, topic_map.actions, catalogs[1], where)
    if not incomplete:
        _check_action(window, action, topic_map)
    return _Plan(window, trial, path, obj, action, incomplete)


def _plans(
    windows: Sequence[Window],
    topic_map: TopicMap,
    out: Path,
    objects: Mapping[str, ObjectSpec],
    actions: Mapping[str, ActionSpec],
    *,
    earlier: Mapping[str, str] | None = None,
) -> list[_Plan]:
    """Resolve every window's object and action, check it, and give it a path.

    A window an earlier run of the same bags wrote (``earlier``: window key -> recording
    relative to ``out``) keeps its recording; the others number on after the trials in
    ``out``. The windows an interrupted run wrote are the first ones in time, so the rest get
    the trials an uninterrupted run would have given them.
    """
    catalogs = lab_catalogs(objects, actions)
    planner = PathPlanner(out)
    plans = []
    for window in check_no_overlap(windows):
        written = (earlier or {}).get(window_key(window.object_id, window.action_id, window.events))
        if written is None:
            planned = planner.plan(window)
        else:
            path = out / written
            planned = (window, int(path.stem) if path.stem.isdigit() else 0, path)
        plans.append(plan_window(planned, topic_map, catalogs))
    return plans


# -------------------------------------------------------------------------------- windows


def _first_stamp(
    reader: AnyReader, connection: Connection, topic_map: TopicMap, extractor: Extractor
) -> int | None:
    """Return the stamp of a topic's first message (its earliest: stamps increase)."""
    for _, receive_ns, raw in reader.messages(connections=[connection]):
        message = reader.deserialize(raw, connection.msgtype)
        stamp = message_stamp(message, connection.topic, topic_map.stamps, receive_ns)
        if isinstance(extractor, SkinTopic):
            stamp += min(int(o.min()) for o in extractor.offsets.values())
        return stamp
    return None


def _windows(
    reader: AnyReader,
    connections: Sequence[Connection],
    topic_map: TopicMap,
    found: Mapping[str, Extractor],
) -> list[Window]:
    """Return the action windows named by the map (annotation topic or CSV)."""
    source = topic_map.windows
    if source.source == "topic":
        annotation = [c for c in connections if c.topic == source.topic]
        texts = (
            (str(reader.deserialize(raw, c.msgtype).data), receive_ns)  # type: ignore[attr-defined]
            for c, receive_ns, raw in raw_messages(reader, annotation)
        )
        return windows_from_annotations(texts, source.topic)
    if source.csv is None:
        msg = f"{topic_map.path}: [windows] source = 'csv' needs csv = 'file' or --windows FILE"
        raise BagImportError(msg)
    origin = 0
    if source.relative:
        firsts = [
            _first_stamp(reader, c, topic_map, found[c.topic])
            for c in connections
            if c.topic in found
        ]
        origin = min((f for f in firsts if f is not None), default=0)
    return windows_from_csv(source.csv, source.time_unit, origin)


# -------------------------------------------------------------------------------- packing


def _cells(
    found: Mapping[str, Extractor], topic_map: TopicMap, lo: int, hi: int
) -> dict[str, list[tuple[str, Series]]]:
    """Return, per mapped modality, every cell's topic and samples reaching ``[lo, hi)``."""
    columns: dict[str, list[tuple[int, str, Series]]] = {m: [] for m in topic_map.skin}
    for topic, extractor in found.items():
        if isinstance(extractor, SkinTopic):
            for modality, series in extractor.take_cells(lo, hi).items():
                columns[modality].extend((cell, topic, s) for cell, s in series)
    return {
        m: [(topic, s) for _, topic, s in sorted(c, key=lambda cell: cell[0])]
        for m, c in columns.items()
    }


def _robot_items(
    window: Window, found: Mapping[str, Extractor], report: ImportReport
) -> list[StreamItem]:
    """Return the joint samples and poses stamped inside the window (finite values only)."""
    items: list[StreamItem] = []
    for extractor in found.values():
        if isinstance(extractor, SkinTopic):
            continue
        series = extractor.take(window.start_ns, window.stop_ns)
        if isinstance(extractor, JointTopic):
            series = extractor.not_recorded(series)
        finite = np.isfinite(series.values).all(axis=1)
        name = "joint_states" if isinstance(extractor, JointTopic) else "tcp_pose"
        report.dropped_samples[name] = report.dropped_samples.get(name, 0) + int((~finite).sum())
        for i in np.flatnonzero(finite):
            stamp, receive, v = int(series.stamps[i]), int(series.receives[i]), series.values[i]
            if isinstance(extractor, JointTopic):
                n = v.size // 3
                items.append(JointSample(stamp, receive, v[:n], v[n : 2 * n], v[2 * n :]))
            else:
                items.append(PoseSample(stamp, receive, v[:3], v[3:]))
    return items


def _uncovered(
    plan: _Plan,
    modality: str,
    topics: tuple[str, str],
    blocks: Sequence[SkinBlock],
    *,
    live: bool = False,
) -> str:
    """Return why a modality's blocks do not cover the window's execute phase (empty: they do).

    The reader's rule (``atikt-replay check``): a skin channel begins at or before the
    execute phase and covers the action's duration (its last sample plus a period). A bag's
    window is fixed by the lab; live (``live``), the data is what it is: no fix is named.
    ``topics``: the cells' topics that begin last and that end first.
    """
    if plan.incomplete:  # live: kept as what arrived, said incomplete
        return ""
    window, start = plan.window, plan.window.phase_start("execute")
    where = window.where or "the annotation"
    first, last = blocks[0], blocks[-1]
    end = last.stamp_ns + last.period_ns * last.data.shape[0]
    needed = round(plan.action.duration_s * (1 - DURATION_TOLERANCE) * _NS_PER_S) - 1_000_000
    if first.stamp_ns > start:
        return (
            f"the data does not cover it: {modality} of {topics[0]} begins "
            f"{(first.stamp_ns - start) / _NS_PER_S:.3f} s after its execute phase began"
            + ("" if live else f"; fix the window's start ({where})")
        )
    if end - start < needed:
        return (
            f"the data does not cover it: {modality} of {topics[1]} ends "
            f"{(window.phase_stop('execute') - end) / _NS_PER_S:.3f} s before its execute "
            f"phase ends ({plan.action.id} lasts {plan.action.duration_s:g} s)"
            + ("" if live else f"; fix the window's stop ({where})")
        )
    return ""


def _too_few(
    modality: str,
    cells: Sequence[tuple[str, Series]],
    found: Mapping[str, Extractor],
    topic_map: TopicMap,
) -> str:
    """Return why a modality has too few samples near a window, naming the cell's topic.

    A topic whose messages all carry one stamp (a driver that never fills ``header.stamp``)
    has its messages dropped as repeats: that is said, with the receive time as the way out.
    """
    topic = next((t for t, s in cells if s.stamps.size < 2), cells[0][0])  # noqa: PLR2004
    extractor = found.get(topic)
    repeated = extractor.repeated if extractor is not None else 0
    last = extractor.buffer.last if extractor is not None else None
    if repeated and last is not None and last <= 0:
        return (
            f"the {modality} stamps of {topic} are all {last} ({repeated} messages dropped as "
            'repeated stamps): the driver does not fill header.stamp; set [time] stamps = "log" '
            f"in {topic_map.path.name} to use the receive time"
        )
    dropped = f" ({repeated} of its messages dropped for a repeated stamp)" if repeated else ""
    return f"fewer than 2 {modality} samples of {topic} near it{dropped}"


def _gaps(stamps: NDArray[np.int64], period_ns: int) -> tuple[int, int]:
    """Return the pauses of written stamps as ``listen`` counts them: (gaps, their length).

    A step longer than :func:`recorder.live.gap_periods` periods is a gap; its length is
    counted beyond one period, in ns.
    """
    if stamps.size < 2 or period_ns <= 0:  # noqa: PLR2004 (a pair is the smallest step)
        return 0, 0
    steps = np.diff(stamps)
    paused = steps[steps > gap_periods(stamps.tolist(), period_ns) * period_ns]
    return int(paused.size), int((paused - period_ns).sum())


def _window_items(
    plan: _Plan,
    cells: Mapping[str, list[tuple[str, Series]]],
    found: Mapping[str, Extractor],
    topic_map: TopicMap,
    report: ImportReport,
    *,
    live: bool = False,
) -> tuple[list[StreamItem], str, dict[str, int], list[SourceStats], str]:
    """Return every stream item of one window ordered by receive time, or why it is skipped.

    A bag's window that its data does not cover is skipped (the bag keeps the data: the lab
    fixes the window and imports again); a live window is written whatever it holds, its data
    exists nowhere else: the last value returned says why it does not cover the action (it is
    then kept as incomplete; empty: it does).

    Also returns, per skin topic, the stamps it delivered valid that cell alignment left out
    (summed over its modalities; see :func:`left_out_by_topic`), and the pauses of the skin
    inside the window as sources' accounting (a topic without a counter cannot tell a pause
    from loss: counted as gaps, as ``listen`` counts them, and written into the file).
    """
    window = plan.window
    items: list[StreamItem] = [PhaseEvent(s, s, p) for p, s in window.events]
    left_out: dict[str, int] = {}
    paused: dict[str, SourceStats] = {}
    short = ""
    for modality, spec in topic_map.skin.items():
        topics = [topic for topic, _ in cells[modality]]
        series = [s for _, s in cells[modality]]
        # stamped by rate: the period on the stamps' clock is the fitted one (the drift)
        exact = spec.period_ns if spec.timing == "message" else None
        period = block_period(exact, series[0].stamps)
        where = topics[0] if topics else spec.topic
        if period <= 0 or any(s.stamps.size == 0 for s in series):
            return [], _too_few(modality, cells[modality], found, topic_map), {}, [], ""
        rows = window_rows(series, window.start_ns, window.stop_ns, period)
        blocks, jitter, dropped = skin_blocks(modality, rows, period, topic_map.max_jitter)
        if not blocks:
            return [], f"no {modality} samples of {where} with every cell inside it", {}, [], ""
        edges = (
            topics[int(np.argmax([s.stamps[0] for s in series]))],
            topics[int(np.argmin([s.stamps[-1] for s in series]))],
        )
        if reason := _uncovered(plan, modality, edges, blocks, live=live):
            if not live:
                return [], reason, {}, [], ""
            short = short or reason
        report.note(modality, rows, jitter, dropped)
        count, length = _gaps(rows.stamps, period)
        if count:
            report.gaps[modality] = report.gaps.get(modality, 0) + count
            report.gap_ns[modality] = report.gap_ns.get(modality, 0) + length
            for topic in dict.fromkeys(topics):
                had = paused.get(topic, SourceStats(topic, basis="stamps", period_ns=period))
                more = dataclasses.replace(had, gaps=had.gaps + count, gap_ns=had.gap_ns + length)
                paused[topic] = more
        for topic, count in left_out_by_topic(topics, rows, dropped).items():
            left_out[topic] = left_out.get(topic, 0) + count
        items.extend(blocks)
    robot = _robot_items(window, found, report)
    if reason := _robot_missing(robot, topic_map):
        return [], reason, {}, [], ""
    items.extend(robot)
    items.sort(key=lambda item: item.receive_ns)
    return items, "", left_out, list(paused.values()), short


def _robot_missing(robot: Sequence[StreamItem], topic_map: TopicMap) -> str:
    """Return which mapped robot topic has no message inside a window (empty: none)."""
    for kind, mapped in ((JointSample, topic_map.joints), (PoseSample, topic_map.pose)):
        if mapped is not None and not any(isinstance(item, kind) for item in robot):
            return f"no message of {mapped.topic} inside it"
    return ""


def _rig(
    bags: Sequence[BagIdentity],
    topic_map: TopicMap,
    joints: JointTopic | None,
    widths: Mapping[str, int],
) -> dict[str, str]:
    """Return the rig metadata of imported recordings (with the bags' identities)."""
    return {
        "kind": "imported",
        "source": ", ".join(b.path.name for b in bags),
        "bag_sha256": ", ".join(b.sha256 for b in bags),
        "topic_map": topic_map.path.name,
        "stamps": topic_map.stamps,
        "cells": json.dumps(list(topic_map.cells)),
        "widths": json.dumps(dict(widths), sort_keys=True),
        "joints_not_recorded": json.dumps(sorted(joints.missing) if joints else []),
    }


# ------------------------------------------------------------------------------ streaming


@dataclass(slots=True)
class _Session:
    """The streaming state of one import: which windows are written, what is held."""

    plans: list[_Plan]
    topic_map: TopicMap
    found: dict[str, Extractor]
    bags: Sequence[BagIdentity]
    report: ImportReport
    on_written: Callable[[Path], Any] | None
    done: int = 0
    pending_bytes: int = 0
    los: list[int] = field(default_factory=list)
    his: list[int] = field(default_factory=list)
    closed_ns: int = -(2**63)
    version: str = ""
    #: Live (``listen``): windows are added as their annotations arrive, every message is
    #: kept until :meth:`trim`, and a sample of a written window is counted, not refused.
    live: bool = False
    #: Returns the per-source accounting written into a window's file (live recordings).
    sources: Callable[[_Plan], Sequence[SourceStats]] | None = None
    #: Windows (by planned path) written before: a recovery replays them without writing.
    skip: set[Path] = field(default_factory=set)
    #: The windows of ``skip`` met so far.
    already: list[Path] = field(default_factory=list)
    #: Import: called with each recording as soon as it is published (the import's progress
    #: is saved there); Ctrl-C, SIGTERM and SIGHUP wait until both are done.
    progress: Callable[[_Plan, Path], Any] | None = None

    def __post_init__(self) -> None:
        """Index the windows' reach ``[start - margin, stop + margin)``; read the version."""
        self.version = software_version()
        self.los = [p.window.start_ns - MARGIN_NS for p in self.plans]
        self.his = [p.window.stop_ns + MARGIN_NS for p in self.plans]

    def add(self, plan: _Plan) -> None:
        """Add a window that follows every window known (live: its ``end`` arrived)."""
        self.plans.append(plan)
        self.los.append(plan.window.start_ns - MARGIN_NS)
        self.his.append(plan.window.stop_ns + MARGIN_NS)

    def trim(self, before_ns: int) -> int:
        """Forget messages stamped before ``before_ns`` that no window still to write needs.

        Returns:
            The stamp before which messages were forgotten.
        """
        if self.done < len(self.plans):
            before_ns = min(before_ns, self.los[self.done])
        for extractor in self.found.values():
            extractor.forget(before_ns)
        self.pending_bytes = 0
        return before_ns

    def wanted(self, receive_ns: int) -> tuple[int, int, bool]:
        """Return whether a message received at ``receive_ns`` may hold a window's sample.

        Returns:
            ``(start, stop, wanted)``: receive times in ``[start, stop)`` share the answer.
        """
        if self.live:
            return -(2**63), 2**63, True
        delay, count = self.topic_map.max_delay_ns, len(self.plans)
        i = bisect.bisect_right(self.his, receive_ns - delay)
        if i < count and self.los[i] <= receive_ns + delay:
            return self.los[i] - delay, self.his[i] + delay, True
        start = self.his[i - 1] + delay if i else -(2**63)
        return start, self.los[i] - delay if i < count else 2**63, False

    def close_at(self) -> int:
        """Return the receive time at which the next window is written.

        Live, never: ``listen`` writes windows by the time on the stamps' clock (a lab's
        stamps may be on another clock than the receive time, e.g. sim time).
        """
        if self.done < len(self.plans) and not self.live:
            return self.his[self.done] + self.topic_map.max_delay_ns
        return 2**63

    def push(
        self, extractor: Extractor, message: object, stamp: int, receive_ns: int, size: int
    ) -> None:
        """Keep a message for the windows to come.

        Raises:
            BagImportError: It belongs to a window written already (it came too late), or
                more than :data:`MAX_PENDING_BYTES` wait for the next window.
        """
        if stamp < self.closed_ns:
            self.check_late(extractor, stamp, receive_ns)
        extractor.push(message, stamp, receive_ns)
        self.grow(size)

    def grow(self, size: int) -> None:
        """Count a kept message's bytes.

        Raises:
            BagImportError: More than :data:`MAX_PENDING_BYTES` wait for the next window.
        """
        self.pending_bytes += size
        if self.pending_bytes > MAX_PENDING_BYTES and self.done < len(self.plans):
            msg = (
                f"{self.plans[self.done].window.describe()}: more than "
                f"{MAX_PENDING_BYTES >> 20} MB of messages reach it; split the window or check "
                "the bag's stamps"
            )
            raise BagImportError(msg)

    def check_late(self, extractor: Extractor, stamp: int, receive_ns: int) -> None:
        """Refuse a sample of a window written already.

        Raises:
            BagImportError: The sample came too late.
        """
        reach = extractor.reach if isinstance(extractor, SkinTopic) else (0, 0)
        first, last = stamp + reach[0], stamp + reach[1]
        j = bisect.bisect_right(self.his, first)
        if j < self.done and self.los[j] <= last:
            if self.live:
                topic = extractor.buffer.topic
                self.report.late_samples[topic] = self.report.late_samples.get(topic, 0) + 1
                return
            msg = (
                f"topic {extractor.buffer.topic}: a sample stamped {stamp} ns arrived at "
                f"{receive_ns} ns, after {self.plans[j].window.describe()} was written; raise "
                f"[time] max_delay_s (now {self.topic_map.max_delay_ns / _NS_PER_S:g} s) in the "
                "topic map"
            )
            raise BagImportError(msg)

    def advance(self, receive_ns: int) -> None:
        """Write every window the bag has passed by more than ``max_delay_s``."""
        delay = self.topic_map.max_delay_ns
        while self.done < len(self.plans) and receive_ns >= self.his[self.done] + delay:
            self.finish_one()

    def finish_one(self) -> None:
        """Pack and write the next window (or note why it is skipped), then forget its data."""
        i = self.done
        plan = self.plans[i]
        cells = _cells(self.found, self.topic_map, self.los[i], self.his[i])
        self.done, self.closed_ns, self.pending_bytes = i + 1, self.his[i], 0
        # live: the next window is not known yet, but it cannot start before this one ends
        last = plan.window.stop_ns - MARGIN_NS if self.live else self.his[i]
        forget = self.los[i + 1] if i + 1 < len(self.plans) else last
        items, reason, left_out, paused, short = _window_items(
            plan, cells, self.found, self.topic_map, self.report, live=self.live
        )
        for extractor in self.found.values():
            extractor.forget(forget)
        if reason:
            self.report.skipped.append((plan.window.describe(), reason))
            return
        if short:  # live: what arrived is kept, as incomplete (check would fail it)
            plan = self.plans[i] = dataclasses.replace(plan, incomplete=short)
        self._write(plan, items, left_out, paused)
        if short and plan.path not in self.skip:
            self.report.cut_short[self.report.incomplete[-1]] = short

    def _write(
        self,
        plan: _Plan,
        items: Sequence[StreamItem],
        left_out: Mapping[str, int],
        paused: Sequence[SourceStats] = (),
    ) -> None:
        """Write a window's recording (once: a window written before is only noted)."""
        if plan.path in self.skip:  # written before the run was killed: never again
            if self.sources is not None:
                self.sources(plan)  # the accounting moves on as it did
            self.already.append(plan.path)
            if self.progress is not None:  # an import resumed: the report lists it as written
                self.report.written.append(plan.path)
                self.report.resumed.append(plan.path)
            return
        if self.progress is None:
            path = self._publish(plan, items, left_out)
        else:
            # a signal waits until the file is published and the progress saved: an import
            # stopped at any moment resumes from exactly the recordings it published
            with deferred_interrupts() as stopped:
                path = self._publish(plan, items, left_out, paused)
                self.progress(plan, path)
            if stopped.signum is not None:
                if self.on_written is not None:
                    self.on_written(path)
                raise_interrupt(stopped.signum)
        if self.on_written is not None:
            self.on_written(path)

    def _publish(
        self,
        plan: _Plan,
        items: Sequence[StreamItem],
        left_out: Mapping[str, int],
        paused: Sequence[SourceStats] = (),
    ) -> Path:
        """Write a window's recording and note it in the report; return its path.

        ``paused``: an import's skin topics that paused inside the window (their gaps go
        into the file, so that ``check`` knows the pause was counted).
        """
        joints = next((e for e in self.found.values() if isinstance(e, JointTopic)), None)
        widths = {
            m: w
            for e in self.found.values()
            if isinstance(e, SkinTopic)
            for m, w in e.widths.items()
        }
        metadata = RecordingMetadata(
            object_id=plan.obj.id,
            object_name=plan.obj.name,
            object_description=plan.obj.description,
            action_id=plan.action.id,
            action_kind=plan.action.kind,
            action_parameters=plan.action.parameters,
            trial=plan.trial,
            rig=check_rig(_rig(self.bags, self.topic_map, joints, widths)),
            seed=0,
            source="import",
            software_version=self.version,
            schema_version=SCHEMA_VERSION,
        )
        names = joints.names if joints is not None else ()
        with RecordingWriter(plan.path, RecordingInfo(metadata, tuple(names))) as writer:
            if plan.incomplete:
                writer.mark_incomplete(plan.incomplete, plan.window.stop_ns)
            for item in items:
                writer.write(item)
            if self.sources is not None:
                writer.add_sources(
                    [
                        dataclasses.replace(stats, unaligned=left_out.get(stats.name, 0))
                        for stats in self.sources(plan)
                    ]
                )
            elif paused:
                writer.add_sources(paused)
        path = writer.result.path if writer.result is not None else plan.path
        if writer.result is not None and (lost := lost_samples(writer.result.sources)):
            self.report.lost_samples[path] = lost
        if plan.incomplete:
            self.report.incomplete.append(path)
        else:
            self.report.written.append(path)
        return path


@dataclass(frozen=True, slots=True)
class Route:
    """How the messages of one bag connection (or one live topic) are read.

    Attributes:
        topic: The topic.
        msgtype: Its message type.
        extractor: Where its samples go.
        deserialize: rosbags' ``(raw, msgtype) -> message`` for the bytes.
        decode: The generated decoder of its stamp and fields (None: rosbags decodes).
    """

    topic: str
    msgtype: str
    extractor: Extractor
    deserialize: Callable[[bytes, str], Any]
    decode: Callable[[bytes], tuple[Any, ...] | None] | None = None


def _decode(route: Route, receive_ns: int, raw: bytes) -> Any:  # noqa: ANN401
    """Return a decoded message.

    Raises:
        BagImportError: The bytes do not decode as the route's type.
    """
    try:
        return route.deserialize(raw, route.msgtype)
    except READ_ERRORS as err:
        msg = (
            f"topic {route.topic}: the message at {receive_ns} ns does not decode as "
            f"{route.msgtype} ({err}); the bag is damaged or its definitions differ "
            "(give the right ones under [types])"
        )
        raise BagImportError(msg) from err


def stamp_of(message: Any, topic: str, clock: str, receive_ns: int) -> int:  # noqa: ANN401
    """Return a message's stamp: ``header.stamp`` (fast path) or as :func:`message_stamp`."""
    if clock == "header":
        try:
            stamp = message.header.stamp
        except AttributeError:
            return message_stamp(message, topic, clock, receive_ns)
        return int(stamp.sec) * _NS_PER_S + int(stamp.nanosec)
    return receive_ns


@dataclass(slots=True)
class _Counts:
    """Messages read per bag, reported now and then."""

    owners: dict[int, str]
    on_progress: Callable[[str, int], Any] | None
    counts: dict[str, int] = field(default_factory=dict)
    total: int = 0

    def tick(self, owner: int) -> None:
        """Count a message of the bag read by ``owner``."""
        bag = self.owners[owner]
        self.counts[bag] = self.counts.get(bag, 0) + 1
        self.total += 1
        if self.on_progress is not None and self.total % _PROGRESS_EVERY == 0:
            self.on_progress(bag, self.counts[bag])

    def finish(self) -> dict[str, int]:
        """Report the final counts and return them (every bag, read or not)."""
        counts = {bag: self.counts.get(bag, 0) for bag in self.owners.values()}
        if self.on_progress is not None:
            for bag, count in counts.items():
                self.on_progress(bag, count)
        return counts


def routes(
    store: Typestore,
    channels: Sequence[tuple[Hashable, str, str]],
    found: Mapping[str, Extractor],
    *,
    clock: str,
    deserialize: Callable[[bytes, str], Any],
    ros1: bool = False,
) -> dict[Hashable, Route]:
    """Return key -> route of every channel ``(key, topic, msgtype)`` of a mapped topic.

    Skin and joint topics get generated decoders only if every channel carrying the topic has
    the same layout; its extractor then takes the decoded fields (``push_fields``).
    """
    make = compile_ros1 if ros1 else compile_cdr
    out: dict[Hashable, Route] = {}
    for topic, extractor in found.items():
        mine = [(key, msgtype) for key, name, msgtype in channels if name == topic]
        if isinstance(extractor, SkinTopic):
            fields = list(extractor.paths)
        elif isinstance(extractor, JointTopic):
            fields = ["name", "position", "velocity", "effort"]
        else:
            fields = []
        decoders = [
            make(store, msgtype, fields, stamped=clock == "header") if fields else None
            for _, msgtype in mine
        ]
        first = decoders[0] if decoders else None
        usable = first is not None and all(d is not None and d.key == first.key for d in decoders)
        if usable and first is not None:
            if isinstance(extractor, SkinTopic):
                extractor.dtypes = cast("tuple[np.dtype[Any], ...]", first.dtypes)
            elif isinstance(extractor, JointTopic):
                extractor.dtypes = first.dtypes
        for (key, msgtype), decoder in zip(mine, decoders, strict=True):
            decode = decoder.decode if usable and decoder is not None else None
            out[key] = Route(topic, msgtype, extractor, deserialize, decode)
    return out


def feed(messages: Iterable[tuple[Route, int, bytes]], session: _Session) -> None:
    """Push messages (route, receive ns, raw bytes) into the session, writing windows it passes.

    Skin and joint-state messages of a layout :mod:`schemas.cdr` reads are
    not decoded by rosbags: their stamp and fields come from the bytes (a message it cannot
    vouch for is decoded by rosbags, as every other message).
    """
    header = session.topic_map.stamps == "header"
    clock = session.topic_map.stamps
    close_at, (lo, hi, wanted) = session.close_at(), session.wanted(0)
    closed_ns = session.closed_ns
    for route, receive_ns, raw in messages:
        if receive_ns >= close_at:
            session.advance(receive_ns)
            close_at, closed_ns = session.close_at(), session.closed_ns
        if not lo <= receive_ns < hi:
            lo, hi, wanted = session.wanted(receive_ns)
        if not wanted:
            continue
        decode = route.decode
        fields = decode(raw) if decode is not None else None
        if fields is None:
            message = _decode(route, receive_ns, raw)
            stamp = stamp_of(message, route.topic, clock, receive_ns)
            session.push(route.extractor, message, stamp, receive_ns, len(raw))
            continue
        extractor = route.extractor
        stamp = fields[0] * _NS_PER_S + fields[1] if header else receive_ns
        if stamp < closed_ns:
            session.check_late(extractor, stamp, receive_ns)
        extractor.push_fields(fields, stamp, receive_ns)  # type: ignore[union-attr]
        session.grow(len(raw))


def _ticked(
    messages: Iterable[tuple[Connection, int, bytes]],
    counts: _Counts,
    by_connection: Mapping[Hashable, Route],
) -> Iterator[tuple[Route, int, bytes]]:
    """Yield a bag's messages with their routes, counting them per bag.

    Raises:
        BagImportError: A message's receive time precedes the previous message's (a reader
            that cannot put the bag in time order): the cause and the place, in one line.
    """
    previous = -(2**63)
    for connection, receive_ns, raw in messages:
        if receive_ns < previous:
            msg = (
                f"{counts.owners[id(connection.owner)]}: messages on {connection.topic} go back "
                f"in time at t={receive_ns} ns (after {previous} ns): the bag was merged from "
                "several recorders; re-sort it (ROS 1: `rosbag filter in.bag sorted.bag True`; "
                "ROS 2: `ros2 bag convert` or rosbags-convert) and import the sorted copy"
            )
            raise BagImportError(msg)
        previous = receive_ns
        counts.tick(id(connection.owner))
        yield by_connection[id(connection)], receive_ns, raw


def _stream(
    reader: AnyReader,
    connections: Sequence[Connection],
    session: _Session,
    on_progress: Callable[[str, int], Any] | None,
    on_start: Callable[[str, int], Any] | None = None,
) -> None:
    """Read every mapped data message once, feeding and closing windows as the bag passes."""
    found = session.found
    owners = {id(c.owner): Path(str(getattr(c.owner, "path", "bag"))).name for c in connections}
    data = [c for c in connections if c.topic in found]
    if on_start is not None:
        for bag in dict.fromkeys(owners.values()):
            on_start(bag, sum(c.msgcount for c in data if owners[id(c.owner)] == bag))
    counts = _Counts(owners, on_progress)
    by_connection = routes(
        reader.typestore,
        [(id(c), c.topic, c.msgtype) for c in data],
        found,
        clock=session.topic_map.stamps,
        deserialize=reader.deserialize,
        ros1=not reader.is2,
    )
    feed(_ticked(raw_messages(reader, data), counts, by_connection), session)
    session.report.messages = counts.finish()
    while session.done < len(session.plans):
        session.finish_one()


def _distinct(identities: Sequence[BagIdentity]) -> list[BagIdentity]:
    """Return the bags, each given once.

    Raises:
        BagImportError: Two of them hold the same content (a bag and its copy): its
            messages would be read twice.
    """
    first: dict[str, Path] = {}
    for bag in identities:
        if (other := first.setdefault(bag.sha256, bag.path)) is not bag.path:
            msg = (
                f"{other} and {bag.path} are the same bag (same content); give each bag of "
                "the session once"
            )
            raise BagImportError(msg)
    return list(identities)


def _already(identities: Sequence[BagIdentity], out: Path) -> dict[str, str]:
    """Return bag name -> report file for bags imported before; refuse a partial overlap.

    Raises:
        BagImportError: Some, but not all, of the bags were imported before.
    """
    known = imported_bags(out)
    seen = {b.path.name: known[b.sha256] for b in identities if b.sha256 in known}
    if seen and len(seen) != len(identities):
        name, report = next(iter(seen.items()))
        msg = (
            f"{name}: this bag was imported into {out} already ({out}/imports/{report}); "
            "import the other bags without it"
        )
        raise BagImportError(msg)
    return seen


def _run(
    bags: Sequence[Path],
    topic_map: TopicMap,
    report: ImportReport,
    out: Path,
    *,
    catalogs: tuple[Mapping[str, ObjectSpec], Mapping[str, ActionSpec]],
    on_written: Callable[[Path], Any] | None,
    on_progress: Callable[[str, int], Any] | None,
    on_start: Callable[[str, int], Any] | None,
) -> list[_Plan]:
    """Read the windows, then stream the bags into recordings (none if every one is written)."""
    found = extractors(topic_map)
    with open_reader(bags, topic_map) as reader:
        connections = check_connections(reader, required_types(topic_map))
        check_fields(reader, connections, topic_map)
        windows = _windows(reader, connections, topic_map, found)
        if not windows:
            msg = f"{bags[0]}: no action windows found; check the [windows] of {topic_map.path}"
            raise BagImportError(msg)
        plans = _plans(windows, topic_map, out, *catalogs, earlier=report.imported)
        skip = {out / path for path in report.imported.values()}
        if report.complete and all(p.path in skip for p in plans):
            return []  # an import that finished holds every window: nothing to add
        report.complete = False
        session = _Session(plans, topic_map, found, report.bags, report, on_written, skip=skip)
        session.progress = lambda plan, path: _progress(report, plan, path)
        _stream(reader, connections, session, on_progress, on_start)
    tally(found, report)
    return plans


def _progress(report: ImportReport, plan: _Plan, path: Path) -> None:
    """Note a published recording in ``<out>/imports/<id>.json`` (atomically): a rerun skips it."""
    window = plan.window
    key = window_key(window.object_id, window.action_id, window.events)
    report.imported[key] = path.relative_to(report.out).as_posix()
    report.save(replace=True)


def tally(found: Mapping[str, Extractor], report: ImportReport) -> None:
    """Add the extractors' repeated stamps to the report (after the last window)."""
    for name, kind in (("joint_states", JointTopic), ("tcp_pose", PoseTopic)):
        if repeated := [e.repeated for e in found.values() if isinstance(e, kind)]:
            report.dropped_samples[name] = report.dropped_samples.get(name, 0) + sum(repeated)
    for extractor in found.values():
        if isinstance(extractor, JointTopic) and extractor.malformed:
            report.malformed[extractor.topic] = extractor.malformed
        if isinstance(extractor, SkinTopic):
            for spec in extractor.fields:
                report.dropped_rows[spec.modality] = report.dropped_rows.get(spec.modality, 0)
            report.repeated_stamps += extractor.repeated
            for index, timeline in extractor.timelines.items():
                modality = extractor.fields[index].modality
                report.timing.setdefault(extractor.topic, {})[modality] = timeline.summary()
            if extractor.counted is not None:
                report.counted[extractor.topic] = extractor.counted[0].summary()


def import_bag(
    bag: Path | Sequence[Path],
    topic_map: TopicMap,
    out: Path,
    *,
    objects: Mapping[str, ObjectSpec],
    actions: Mapping[str, ActionSpec],
    on_written: Callable[[Path], Any] | None = None,
    on_progress: Callable[[str, int], Any] | None = None,
    on_start: Callable[[str, int], Any] | None = None,
    on_set_aside: Callable[[Path], Any] | None = None,
) -> ImportReport:
    """Import a session's bags: one recording per action window, then objects and index.

    The import resumes: each recording is noted in ``<out>/imports/<id>.json`` as soon as it
    is published (Ctrl-C waits for that), and a rerun with the same bags skips the windows
    noted there and writes the rest, as an uninterrupted import would have (same trials,
    same bytes); a rerun with other windows (a corrected table) adds the new ones, numbered
    on. An unfinished file of a killed import is set aside (``<out>/.incomplete/``), never
    deleted.

    Args:
        bag: A ROS 1 ``.bag`` file or a ROS 2 bag directory, or several (one session).
        topic_map: What the bags' topics carry (:func:`load_topic_map`).
        out: Dataset directory; existing recordings are never overwritten.
        objects: Object catalog (the map's declarations take precedence).
        actions: Action catalog (the map's declarations take precedence).
        on_written: Called with every recording written.
        on_progress: Called with (bag name, messages read so far) now and then.
        on_start: Called with (bag name, messages of the mapped topics) before reading.
        on_set_aside: Called with each unfinished file of a stopped recorder set aside.

    Returns:
        What was written and skipped, and the alignment figures. Bags whose every window is
        in ``out`` already add nothing (``already_imported`` names them).

    Raises:
        BagImportError: A bag, the map or a window is wrong; what this run wrote is removed
            again (what earlier runs wrote stays).
    """
    bags = [Path(bag)] if isinstance(bag, str | Path) else [Path(b) for b in bag]
    out = Path(out)
    identities = _distinct([bag_identity(b) for b in bags])
    report = ImportReport(identities, out, topic_map.path)
    seen = _already(identities, out)
    report.imported, report.complete = earlier_import(report.report_path)
    if seen and not report.imported:  # a report of an older version: its windows unlisted
        report.already_imported = seen
        return report
    _refuse_other_rig(out, topic_map)
    for moved in set_aside_stale_parts(out) if out.is_dir() else ():
        if on_set_aside is not None:
            on_set_aside(moved)
    plans: list[_Plan] = []
    try:
        plans = _run(
            bags,
            topic_map,
            report,
            out,
            catalogs=(objects, actions),
            on_written=on_written,
            on_progress=on_progress,
            on_start=on_start,
        )
    except READ_ERRORS as err:
        _undo(report)
        fix = "; check the path and the [types] of the map"
        raise BagImportError(unreadable(bags[:1], err, fix)) from err
    except RecorderError:
        _undo(report)
        raise
    if not plans:
        report.already_imported = seen
        return report
    if not report.written:
        reasons = "; ".join(f"{w}: {r}" for w, r in report.skipped[:2])
        msg = f"{bags[0]}: no recording written ({reasons}); check the topic map and the windows"
        raise BagImportError(msg)
    declare_objects(out, [_object_spec(p.obj) for p in plans if p.path in report.written])
    report.index = write_index(out)
    report.complete = True
    report.save(replace=True)
    return report


def _refuse_other_rig(out: Path, topic_map: TopicMap) -> None:
    """Refuse to import into a dataset of another rig (another kind, or a skin of other cells).

    One dataset holds one rig; the other cells are seen before anything is read (the widths
    only from the data: the index refuses those at the end).

    Raises:
        BagImportError: One line naming a recording of the other rig and the fix.
    """
    found = first_metadata(out)
    if found is None:
        return
    path, meta = found
    cells = json.dumps(list(topic_map.cells))
    if meta.rig.get("kind") == "imported" and meta.rig.get("cells") == cells:
        return
    msg = (
        f"{out}: holds recordings of another rig ({rig_identity(meta.rig)}, e.g. {path}); "
        f"{topic_map.path} maps a skin of cells={cells}; a dataset holds one rig: give "
        "another --out"
    )
    raise BagImportError(msg)


def _object_spec(obj: LabObject) -> ObjectSpec:
    """Return the declaration of an object for ``objects.toml``."""
    return ObjectSpec(id=obj.id, name=obj.name, description=obj.description, novel=obj.novel)


def _undo(report: ImportReport) -> None:
    """Remove what this run wrote before it failed, and its notes; earlier runs' stay.

    Raises:
        BagImportError: The progress cannot be written back.
    """
    resumed = set(report.resumed)
    mine = [path for path in report.written if path not in resumed]
    for path in mine:
        path.unlink(missing_ok=True)
    if not mine:
        return
    gone = {path.relative_to(report.out).as_posix() for path in mine}
    report.imported = {k: v for k, v in report.imported.items() if v not in gone}
    if report.imported:
        report.save(replace=True)
    else:
        report.report_path.unlink(missing_ok=True)
