"""A lab's ROS 2 topics recorded live, one file per action (the ``listen`` command's library).

The lab's own system drives the robot and publishes; this subscribes over DDS (Cyclone DDS,
no ROS installation: :mod:`recorder.live.dds`) to the topics of a topic map and cuts one
recording per action window, exactly as ``import-bag`` cuts a bag of the same data: the
samples are the same CDR bytes and go through the same conversion (:func:`feed` of the
import's streaming session: decoders, extractors, alignment, packing, checks, file names).

Windows come from the annotation topic as it arrives (a window is known when its ``end``
annotation came, and written once ``[time] max_delay_s`` has passed beyond its end plus the
import's one-second margin and every topic still sending has sent a sample stamped beyond
that) or from a CSV (known up front). Each file also records, per topic,
the samples expected (from the header stamps and the topic's period), received, missing,
duplicated and out of order, and those its reader dropped (``atikt.sources``): a full queue's
as overflowed, too large ones as malformed, each in the file of the window it was stamped in
(its header stamp, read from its first 12 bytes), none between actions; the run's lines say
the totals. At ``--duration``, Ctrl-C or SIGTERM the windows whose ``end`` arrived
are written and the one being annotated is kept as incomplete, with a line saying so.

Every message is also journaled as it arrives (:mod:`._journal`), so a run killed before it
could write its windows loses at most the step in flight: :func:`recover` (run first by
:func:`listen`) replays the journals of runs that died into the recordings they would have
written.
"""

from __future__ import annotations

import bisect
import hashlib
import time
from collections import deque
from dataclasses import dataclass, field
from operator import attrgetter, itemgetter
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from recorder._dataset import declare_objects, write_index
from recorder.bagimport._importer import (
    MARGIN_NS,
    Route,
    _object_spec,
    _Plan,
    _Session,
    feed,
    lab_catalogs,
    plan_window,
    routes,
    tally,
)
from recorder.bagimport._journal import (
    JOURNAL_DIR,
    KEPT_DIR,
    RECOVERED_DIR,
    JournalContents,
    JournalError,
    JournalHead,
    JournalStep,
    JournalWriter,
    held,
    left_journals,
    listen_lock,
    read_journal,
)
from recorder.bagimport._report import BagIdentity, ImportReport
from recorder.bagimport._source import (
    ANNOTATION_TYPE,
    SkinTopic,
    check_fields,
    extractors,
    required_types,
    typestore,
)
from recorder.bagimport._windows import (
    AnnotationGrouper,
    PathPlanner,
    ReplayPlanner,
    Window,
    check_no_overlap,
    parse_annotation,
    windows_from_csv,
)
from recorder.errors import BagImportError, RecorderError
from recorder.live import RecorderClock, SourceCounter, SourceReader, SourceStats, gap_periods
from recorder.runner import deferred_interrupts
from schemas import cli
from schemas.cdr import compile_cdr, header_stamp

if TYPE_CHECKING:
    import threading
    from collections.abc import Callable, Mapping, Sequence
    from types import ModuleType

    from rosbags.typesys.store import Typestore

    from recorder._catalog import ActionSpec, ObjectSpec
    from recorder.bagimport._topicmap import TopicMap
    from recorder.live import Drop, Received
    from recorder.live.dds import DdsDomain, Publication, RawReader
    from recorder.writing._foxglove import TopicView

_NS_PER_S = 1_000_000_000
#: How often idle windows are closed and old messages forgotten, s.
_TICK_S = 0.05
#: An open action is cut (kept as incomplete, with a line) once it lasts its declared
#: ``duration_s`` plus this, ns: a lost ``end`` never holds data without bound.
OPEN_MARGIN_NS = 30 * _NS_PER_S
#: How long an open action of an action without a declared duration may last, ns.
OPEN_DEFAULT_NS = 300 * _NS_PER_S
#: A topic whose latest stamp lies this far behind the newest of every topic has stopped: the
#: windows no longer wait for it, ns.
WAIT_NS = 10 * _NS_PER_S
#: How long beyond ``[time] max_delay_s`` the windows wait when every topic stopped, ns.
STOPPED_NS = 60 * _NS_PER_S


def _dds() -> ModuleType:
    """Return :mod:`recorder.live.dds` (Cyclone DDS's binding is an optional extra).

    Raises:
        BagImportError: The binding is not installed.
    """
    try:
        from recorder.live import dds  # noqa: PLC0415 (optional dependency)
    except ImportError as err:
        msg = f"listen needs Cyclone DDS ({err}); install it with pip install 'atikt[ros2]'"
        raise BagImportError(msg) from err
    return dds


@dataclass(slots=True)
class _Dropped:
    """Messages of one topic its reader dropped (of one kind: a full queue, too large).

    Each is placed in time, on the windows' clock, and counted in the file of the window whose
    ``[start, stop)`` holds it: between actions (or in a window written already) in none.
    """

    #: The reader's count (since the run's start) placed so far.
    seen: int = 0
    #: Where each lies, ns.
    at: list[int] = field(default_factory=list)

    def place(self, count: int, places: Sequence[int], step_ns: int) -> None:
        """Place the drops counted since the last call: those read at ``places``.

        ``count``: the reader's count since the start. A drop counted that its reader kept
        nothing of (a journal of an older version; more in one step than the reader keeps) is
        placed at ``step_ns``, the step's time on the windows' clock: it was dropped within a
        step of its arrival.
        """
        self.at.extend(places)
        self.at.extend([step_ns] * (count - self.seen - len(places)))
        self.seen = max(self.seen, count)

    def within(self, lo: int, hi: int) -> int:
        """Return how many lie in ``[lo, hi)``."""
        return sum(lo <= at < hi for at in self.at)

    def forget(self, before_ns: int) -> None:
        """Forget those placed before ``before_ns`` (no window left can hold them)."""
        self.at = [at for at in self.at if at >= before_ns]


@dataclass(slots=True)
class _Arrivals:
    """Header stamps and receive times of one topic as they arrived (duplicates too).

    A topic whose messages carry a counter (``counter`` in the topic map) is counted by it:
    a message lost is *missing*, exactly, whatever the publisher's jitter; without one, the
    stamps' pauses are *gaps*.
    """

    period_ns: int
    #: Reads a message's counter from its CDR bytes (None: the topic has none; the reader
    #: returns None for a message it cannot read).
    read_counter: Callable[[bytes], int | None] | None = None
    #: The counter wraps at this value (0: it does not wrap).
    modulo: int = 0
    stamps: list[int] = field(default_factory=list)
    receives: list[int] = field(default_factory=list)
    #: Per arrival, its counter (with :attr:`read_counter`).
    sequences: list[int | None] = field(default_factory=list)
    #: The latest stamp received (None: nothing yet).
    latest: int | None = None
    #: The lowest receive time minus stamp seen: the stamps' clock offset to the receive
    #: clock plus the lowest transport latency (None: nothing yet).
    offset: int | None = None
    #: Messages its reader's full queue dropped: counted as overflowed where they lie.
    overflowed: _Dropped = field(default_factory=_Dropped)
    #: Messages dropped for their size: counted as malformed where they lie.
    oversize: _Dropped = field(default_factory=_Dropped)

    def stats(self, name: str, lo: int, hi: int) -> SourceStats | None:
        """Return the accounting of the arrivals and drops in ``[lo, hi)`` (None: none).

        A pause across an edge of the range (from the last arrival before it, to the first
        after it) is counted as the range's: the file's skin reaches across its edges. The
        messages dropped count where they lie (:class:`_Dropped`), not where they were read.
        """
        inside = [i for i, s in enumerate(self.stamps) if lo <= s < hi]
        overflowed, oversize = self.overflowed.within(lo, hi), self.oversize.within(lo, hi)
        if not inside:
            return self._lost_only(name, overflowed, oversize)
        stamps = [self.stamps[i] for i in inside]
        before = max((s for s in self.stamps if s < lo), default=None)
        after = min((s for s in self.stamps if s >= hi), default=None)
        period = self.period_ns
        if period <= 0:  # no rate in the map: the median step of the distinct stamps
            steps = np.diff(np.unique(np.asarray(stamps, dtype=np.int64)))
            period = int(np.median(steps)) if steps.size else 0
        if period <= 0:
            return None
        if self.read_counter is not None:
            counter = self._by_counter(name, period, inside, lo, hi)
        else:
            edges = [s for s in (before, after) if s is not None]
            threshold = gap_periods([*stamps, *edges], period)
            counter = SourceCounter(name, period_ns=period, gaps=True, gap_periods=threshold)
            for i in inside:
                counter.observe(None, self.stamps[i], self.receives[i])
            if before is not None:
                counter.pause(min(stamps) - before)
            if after is not None:
                counter.pause(after - max(stamps))
        counter.overflow(overflowed)
        counter.malformed(oversize)
        return counter.stats()

    def _lost_only(self, name: str, overflowed: int, oversize: int) -> SourceStats | None:
        """Return the accounting of a range whose every message was dropped (None: none was).

        The samples a full queue dropped are missing, as where some arrived (a counter
        expected them; stamps expect what arrived: none).
        """
        if not overflowed and not oversize:
            return None
        counted = self.read_counter is not None
        return SourceStats(
            name,
            basis="counter" if counted else "stamps",
            expected=overflowed if counted else 0,
            missing=overflowed,
            overflowed=overflowed,
            period_ns=self.period_ns,
            malformed=oversize,
        )

    def _by_counter(
        self, name: str, period: int, inside: list[int], lo: int, hi: int
    ) -> SourceCounter:
        """Count the arrivals ``inside`` by their counters; messages unread count malformed."""
        counter = SourceCounter(name, period_ns=period, modulo=self.modulo)
        unread = 0
        for i in inside:
            sequence = self.sequences[i]
            if sequence is None:
                unread += 1
                continue
            counter.observe(sequence, self.stamps[i], self.receives[i])
        read = [(s, q) for s, q in zip(self.stamps, self.sequences, strict=True) if q is not None]
        before = max(((q, s) for s, q in read if s < lo), key=lambda e: e[1], default=None)
        after = min(((q, s) for s, q in read if s >= hi), key=lambda e: e[1], default=None)
        counter.edge_loss(before, after)
        counter.malformed(unread)
        return counter

    def note(self, stamp: int, receive_ns: int) -> None:
        """Note an arrival's stamp (on the session's clock) for the time windows may be written."""
        self.latest = stamp if self.latest is None else max(self.latest, stamp)
        offset = receive_ns - stamp
        self.offset = offset if self.offset is None else min(self.offset, offset)

    def forget(self, before_ns: int) -> None:
        """Drop arrivals stamped before ``before_ns`` (they arrive in about stamp order)."""
        keep = next((i for i, s in enumerate(self.stamps) if s >= before_ns), len(self.stamps))
        del self.stamps[:keep]
        del self.receives[:keep]
        del self.sequences[:keep]
        self.overflowed.forget(before_ns)
        self.oversize.forget(before_ns)


@dataclass
class Listener:
    """One ``listen`` run: DDS readers, the import's streaming session, the windows."""

    topic_map: TopicMap
    out: Path
    objects: Mapping[str, ObjectSpec]
    actions: Mapping[str, ActionSpec]
    domain_id: int = 0
    discovery_s: float = 10.0
    capacity: int = 100_000
    loopback: bool = False
    on_written: Callable[[Path], Any] | None = None
    on_note: Callable[[str], Any] | None = None
    #: A Foxglove server shown every message as received (``--foxglove``).
    view: TopicView | None = None
    clock: RecorderClock = field(default_factory=RecorderClock)
    #: Journal every message received (:mod:`._journal`); off: a SIGKILL loses what is held.
    journal: bool = True
    #: Move retired journals to ``.listen/kept/`` instead of removing them (a raw copy).
    keep_journals: bool = False
    #: The run's start, ns (a recovery gives its journal's: the same source name).
    started_ns: int | None = None
    #: Plans windows (a recovery gives one that plans as its run did).
    planner: PathPlanner | None = None
    #: Why the run stopped on its own (a journal that cannot be written); empty: it did not.
    failed: str = field(default="", init=False)
    report: ImportReport = field(init=False)
    session: _Session = field(init=False)
    _domain: DdsDomain | None = field(default=None, init=False)
    _readers: list[SourceReader] = field(default_factory=list, init=False)
    _routes: dict[str, Route] = field(default_factory=dict, init=False)
    _arrivals: dict[str, _Arrivals] = field(default_factory=dict, init=False)
    _overflow: dict[str, SourceReader] = field(default_factory=dict, init=False)
    _grouper: AnnotationGrouper | None = field(default=None, init=False)
    #: Annotations (stamp, receive ns, parsed) waiting to be grouped in stamp order.
    _held: list[tuple[int, int, Any]] = field(default_factory=list, init=False)
    _planner: PathPlanner = field(init=False)
    _catalogs: Any = field(init=False)
    _store: Typestore = field(init=False)
    _raw: dict[str, Any] = field(default_factory=dict, init=False)
    _first_stamp: dict[str, int] = field(default_factory=dict, init=False)
    _latest_stamp: int | None = field(default=None, init=False)
    _noted: dict[str, int] = field(default_factory=dict, init=False)
    #: Windows skipped before the open journal began (one skipped since: it is kept).
    _skipped_before: int = field(default=0, init=False)
    _types: dict[str, str] = field(default_factory=dict, init=False)
    #: Topic -> (queue overflows, oversize drops, latest oversize bytes) as of the step.
    _counts: dict[str, tuple[int, int, int]] = field(default_factory=dict, init=False)
    _taken: int = field(default=0, init=False)
    _journal: JournalWriter | None = field(default=None, init=False)
    _serial: int = field(default=0, init=False)
    _journal_wrote: bool = field(default=False, init=False)
    #: A journal that could not be written (it stays for a recovery unless the run ends well).
    _dropped: Path | None = field(default=None, init=False)
    #: The messages journaled lately, for the next journal's prelude.
    _recent: deque[tuple[str, int, bytes]] = field(default_factory=deque, init=False)

    def __post_init__(self) -> None:
        """Prepare the report, the session and the windows (nothing is subscribed yet)."""
        started = self.started_ns = self.started_ns or time.time_ns()
        topics = ",".join(sorted(t for t, _ in required_types(self.topic_map)))
        digest = hashlib.sha256(f"dds {self.domain_id} {started} {topics}".encode()).hexdigest()
        identity = BagIdentity(Path(f"dds-domain{self.domain_id}-{started}"), digest, 0)
        self.report = ImportReport([identity], self.out, self.topic_map.path)
        found = extractors(self.topic_map)
        self.session = _Session(
            [],
            self.topic_map,
            found,
            self.report.bags,
            self.report,
            self._wrote,
            live=True,
            sources=self._sources,
        )
        self._planner = self.planner or PathPlanner(self.out, renumber=True)
        self._catalogs = lab_catalogs(self.objects, self.actions)
        windows = self.topic_map.windows
        if windows.source == "topic":
            self._grouper = AnnotationGrouper(windows.topic)
        else:
            for plan in self._csv_plans():
                self.session.add(plan)

    def _csv_plans(self) -> list[_Plan]:
        """Return the plans of a windows CSV (absolute times only).

        Raises:
            BagImportError: The CSV is missing or its times are relative.
        """
        source = self.topic_map.windows
        if source.csv is None or source.relative:
            msg = (
                f"{self.topic_map.path}: listen needs [windows] source = 'topic', or a csv "
                "with absolute times (relative = false)"
            )
            raise BagImportError(msg)
        windows = windows_from_csv(source.csv, source.time_unit, 0)
        return [
            plan_window(self._planner.plan(w), self.topic_map, self._catalogs)
            for w in check_no_overlap(windows)
        ]

    # --------------------------------------------------------------------------- subscribe

    def _find_types(self, seen: Mapping[str, Sequence[Publication]]) -> dict[str, tuple[str, bool]]:
        """Return topic -> (type, reliable) of every mapped topic, checked like a bag's.

        Raises:
            BagImportError: A topic without a known type, or with another type than its role.
        """
        out: dict[str, tuple[str, bool]] = {}
        for topic, required in required_types(self.topic_map):
            publications = seen.get(topic, ())
            msgtype = publications[0].msgtype if publications else required
            if msgtype is None:
                msg = (
                    f"topic {topic}: no publisher on DDS domain {self.domain_id} within "
                    f"{self.discovery_s:g} s, so its type is unknown; start the lab's system "
                    "first, or check the domain id and the topic map"
                )
                raise BagImportError(msg)
            if required is not None and msgtype != required:
                msg = (
                    f"topic {topic} carries {msgtype}, but the topic map uses it as "
                    f"{required}; map the topic that carries {required}"
                )
                raise BagImportError(msg)
            # a best-effort reader matches every publisher (one not seen yet, too)
            reliable = bool(publications) and all(p.reliable for p in publications)
            out[topic] = (msgtype, reliable)
        return out

    def start(self) -> None:
        """Join the domain, find the topics' types and start one reader thread per topic.

        Raises:
            BagImportError: DDS is not installed, or a topic cannot be mapped.
        """
        dds = _dds()

        self._store = typestore(self.topic_map)
        try:
            self._domain = domain = dds.DdsDomain(
                self.domain_id, self._store, loopback=self.loopback
            )
        except dds.DdsError as err:
            raise BagImportError(str(err)) from err
        topics = [t for t, _ in required_types(self.topic_map)]
        types = self._find_types(domain.wait_for(topics, self.discovery_s))
        self.prepare({topic: msgtype for topic, (msgtype, _) in types.items()})
        if self.journal:
            self._open_journal()
        for topic, (msgtype, reliable) in types.items():
            if self.view is not None:
                text, _ = self._store.generate_msgdef(msgtype, ros_version=2)
                self.view.declare(topic, msgtype, text)
            self._subscribe(topic, domain.reader(topic, msgtype, reliable=reliable))
        for source in self._readers:
            source.start()

    def _subscribe(self, topic: str, raw: RawReader) -> SourceReader:
        """Set up a topic's raw reader and its reader thread (not started) and return it.

        Both keep each message they drop with its header stamp (read from its first 12
        bytes), so that it is counted where it was stamped.
        """
        raw.clock = self.clock.now_ns
        raw.max_bytes, _ = self.topic_map.message_budget(topic)
        self._raw[topic] = raw
        source = SourceReader(f"dds{topic}", raw.receive, capacity=self.capacity, place=raw.place)
        self._readers.append(source)
        self._overflow[topic] = source
        return source

    def prepare(self, types: Mapping[str, str]) -> None:
        """Check the topics' types and make their routes (live, or replaying a journal).

        Raises:
            BagImportError: A topic's fields are not what the map says.
        """
        dds = _dds()
        if not hasattr(self, "_store"):  # a recovery: the store DDS would have made
            self._store = dds.register_atikt_types(typestore(self.topic_map))
        self._types = dict(types)
        channels = [_Channel(t, msgtype) for t, msgtype in types.items()]
        reader = cast("Any", _Store(self._store))
        check_fields(reader, cast("Any", channels), self.topic_map)
        found = self.session.found
        made = routes(
            self._store,
            [(c.topic, c.topic, c.msgtype) for c in channels if c.topic in found],
            found,
            clock=self.topic_map.stamps,
            deserialize=self._store.deserialize_cdr,
        )
        self._routes = cast("dict[str, Route]", made)
        for topic, msgtype in types.items():
            self._counts[topic] = (0, 0, 0)
            if topic in found and dds.leads_with_header(self._store, msgtype):
                extractor = found[topic]
                sequence = extractor.sequence if isinstance(extractor, SkinTopic) else None
                self._arrivals[topic] = _Arrivals(
                    _period(extractor),
                    None
                    if sequence is None
                    else _counter_reader(self._store, msgtype, sequence[0]),
                    0 if sequence is None else sequence[1],
                )

    # ----------------------------------------------------------------------------- journal

    def head(self) -> JournalHead:
        """Return what a journal of this run says of it (trial numbers as of now)."""
        digest = hashlib.sha256(self.topic_map.path.read_bytes()).hexdigest()
        return JournalHead(
            self.started_ns or 0, self.domain_id, digest, self._types, self._planner.taken()
        )

    def _open_journal(self) -> None:
        """Start the run's next journal.

        Raises:
            JournalError: It cannot be created.
        """
        self._serial += 1
        self._journal = JournalWriter.create(self.out, self.head(), self._store, self._serial)
        self._journal_wrote = False
        self._skipped_before = len(self.report.skipped)

    def _retire(self, *, reopen: bool) -> None:
        """Close the journal, all of whose windows are written, and remove it (or keep it).

        A journal during which a window was skipped is kept: it holds the only copy of that
        action's messages (live data exists nowhere else).
        """
        journal = self._journal
        if journal is None:
            return
        self._journal = None
        skipped = len(self.report.skipped) - self._skipped_before
        keep = self.keep_journals or skipped > 0
        kept = self.out / JOURNAL_DIR / KEPT_DIR if keep else None
        journal.close(kept)
        if kept is not None and skipped and not self.keep_journals:
            self._note(
                f"{kept / journal.path.name}: kept, the messages of {skipped} skipped "
                f"window{'s' if skipped > 1 else ''} as received (a ROS 2 MCAP: import-bag "
                "reads it, with a windows CSV where the annotations were wrong)"
            )
        if reopen:
            self._open_journal()

    def _rotate(self, now_ns: int) -> None:
        """Start a new journal when nothing is open and every window that ended is written.

        The new journal begins with the prelude: the recent messages again, and the
        accounting so far (a window that begins next reaches back ``max_delay_s`` + 1 s).
        """
        recent = self._recent
        keep = now_ns - self.topic_map.max_delay_ns - 2 * MARGIN_NS
        while recent and recent[0][1] < keep:
            recent.popleft()
        grouper, session = self._grouper, self.session
        idle = (grouper is None or grouper.open_start_ns is None) and not self._held
        if not (self._journal_wrote and idle and session.done == len(session.plans)):
            return
        self._retire(reopen=True)
        if self._journal is not None:
            arrivals = self._arrivals.items()
            seen = {t: (a.overflowed.seen, a.oversize.seen) for t, a in arrivals}
            # the drops placed that a window still to come may hold (the next steps add theirs)
            held = {t: (a.overflowed.at, a.oversize.at) for t, a in arrivals}
            annotation = self._grouper_topic()  # those of windows written already
            self._journal.messages([item for item in recent if item[0] != annotation])
            self._journal.event(now_ns, prelude=now_ns, counts=self._counts, seen=seen, held=held)

    def _wrote(self, path: Path) -> None:
        """Journal a recording written (a recovery does not write it again); tell the caller."""
        self._journal_wrote = True
        if self._journal is not None:
            plan = self.session.plans[self.session.done - 1]
            relative = plan.path.relative_to(self.out).as_posix()
            self._journal.event(self.clock.now_ns(), written=relative)
        if self.on_written is not None:
            self.on_written(path)

    def rehearse(self, seconds: float) -> tuple[TopicCheck, ...]:
        """Read every topic for ``seconds`` after :meth:`start`, writing nothing; what came.

        The messages are counted and dropped: no window is fed, no journal written.
        """
        counts: dict[str, int] = dict.fromkeys(self._raw, 0)
        first: dict[str, int] = {}
        last: dict[str, int] = {}
        deadline = time.monotonic() + seconds
        while (left := deadline - time.monotonic()) > 0:
            for item in self._take(min(_TICK_S, left)):
                topic = item.payload[0]
                counts[topic] = counts.get(topic, 0) + 1
                first.setdefault(topic, item.receive_ns)
                last[topic] = item.receive_ns
        found = []
        for topic, raw in self._raw.items():
            arrivals = self._arrivals.get(topic)
            period = arrivals.period_ns if arrivals is not None else 0
            span = last.get(topic, 0) - first.get(topic, 0)
            found.append(
                TopicCheck(
                    topic,
                    self._types.get(topic, ""),
                    counts[topic],
                    (counts[topic] - 1) * _NS_PER_S / span if span > 0 else None,
                    _NS_PER_S / period if period > 0 else None,
                    self._overflow[topic].overflowed,
                    raw.oversize,
                )
            )
        return tuple(found)

    def stop(self) -> None:
        """Stop the reader threads, then leave the domain (its peers see it go at once)."""
        for source in self._readers:
            source.stop()
        if self._domain is not None:
            self._domain.close()
            self._domain = None

    # ------------------------------------------------------------------------------ stream

    def _sources(self, plan: _Plan) -> list[SourceStats]:
        """Return the accounting of every topic over a window (for its file)."""
        out = []
        window = plan.window
        for topic, arrivals in self._arrivals.items():
            stats = arrivals.stats(topic, window.start_ns, window.stop_ns)
            if stats is not None:
                out.append(stats)
        return out

    def _annotate(self, raw: bytes, receive_ns: int) -> None:
        """Hold one annotation until it is grouped in stamp order (a malformed one is skipped)."""
        grouper = self._grouper
        if grouper is None:
            return
        try:
            text = str(self._store.deserialize_cdr(raw, ANNOTATION_TYPE).data)  # type: ignore[attr-defined]
            parsed = parse_annotation(text, receive_ns, grouper.topic)
        except RecorderError as err:
            self._skip_annotation(receive_ns, err)
            return
        bisect.insort(self._held, (parsed[2], receive_ns, parsed), key=itemgetter(0, 1))

    def _release(self, now_ns: int | None) -> None:
        """Group the annotations held ``max_delay_s`` (None: all) in the order of their stamps.

        A lab's system may send an action's annotations out of order (its ``end`` before its
        ``execute``, each with its right ``stamp_ns``): within ``[time] max_delay_s`` of
        arriving they are put in stamp order; a window whose ``end`` it is gets planned.
        """
        grouper, delay = self._grouper, self.topic_map.max_delay_ns
        while grouper is not None and self._held:
            _, receive_ns, parsed = self._held[0]
            if now_ns is not None and receive_ns + delay > now_ns:
                return
            del self._held[0]
            try:
                window = grouper.add(*parsed)
                if window is not None:
                    self._add(window, self._joined(window))
            except RecorderError as err:
                self._skip_annotation(receive_ns, err)

    def _skip_annotation(self, receive_ns: int, err: RecorderError) -> None:
        """Note an annotation that cannot be taken (one line at the step's end).

        Its action's messages stay in the journal, which is then kept (``.listen/kept/``,
        :meth:`_retire`): the line says where (e.g. an ``end`` whose ``execute`` was sent
        before this run joined: the data exists nowhere else).
        """
        where = f"topic {self._grouper_topic()} at {receive_ns} ns"
        reason = str(err).removeprefix(f"{where}: ")
        if self._journal is not None:
            kept = self.out / JOURNAL_DIR / KEPT_DIR
            reason += f"; its messages are kept in {kept}/ (import-bag reads them)"
        self.report.skipped.append((where, reason))

    def _joined(self, window: Window) -> str:
        """Return why a window began before this listener received its topics (empty: not)."""
        late = {
            topic: first - window.start_ns
            for topic, first in self._first_stamp.items()
            if first - window.start_ns > max(2 * self._arrivals[topic].period_ns, MARGIN_NS // 20)
        }
        if not late and len(self._first_stamp) == len(self._arrivals):
            return ""
        if not late:
            silent = sorted(set(self._arrivals) - set(self._first_stamp))
            return f"joined part-way: no message of {silent[0]} before the action ended"
        topic = max(late, key=lambda t: late[t])
        return (
            f"joined part-way: {topic} begins {late[topic] / _NS_PER_S:.3f} s after the "
            "action began"
        )

    def _add(self, window: Window, incomplete: str = "") -> None:
        """Plan a window (after every window known); an incomplete one is kept as such.

        Raises:
            BagImportError: It overlaps the previous window, or cannot be planned.
        """
        plans = self.session.plans
        if plans and window.start_ns < plans[-1].window.stop_ns:
            msg = f"{window.describe()} overlaps {plans[-1].window.describe()}"
            raise BagImportError(msg)
        planned = self._planner.plan(window)
        self.session.add(plan_window(planned, self.topic_map, self._catalogs, incomplete))
        if window.trial is not None and planned[1] != window.trial:
            self._note(
                f"{window.describe()}: trial {window.trial} is recorded in {self.out} already "
                f"(a new session of the lab's system); written as trial {planned[1]}: "
                f"{planned[2]}"
            )
        if incomplete:
            self._note(f"{window.describe()}: kept as incomplete ({incomplete})")

    def _cut_open(self, reason: str) -> None:
        """Keep the action being annotated as an incomplete recording, up to the latest data."""
        grouper = self._grouper
        opened = grouper.abandon() if grouper is not None else None
        if opened is None:
            return
        key, events = opened
        stop = max(self._latest_stamp or 0, events[-1][1]) + 1
        window = Window(*key, (*events, ("end", stop)), f"topic {self._grouper_topic()}")
        try:
            self._add(window, reason)
        except RecorderError as err:
            self.report.skipped.append((window.describe(), str(err)))

    def _grouper_topic(self) -> str:
        return self._grouper.topic if self._grouper is not None else ""

    def _bound_open(self) -> None:
        """Cut an open action that outlasted its declared duration (its ``end`` was lost)."""
        grouper = self._grouper
        start = grouper.open_start_ns if grouper is not None else None
        if start is None or self._latest_stamp is None:
            return
        action = grouper.open_action if grouper is not None else None
        declared = self.session.topic_map.actions.get(action or "") or self._catalogs[1].get(
            action or ""
        )
        limit = (
            round(declared.duration_s * _NS_PER_S) + OPEN_MARGIN_NS
            if declared is not None
            else OPEN_DEFAULT_NS
        )
        if self._latest_stamp - start > limit:
            self._cut_open(
                f"no 'end' annotation within {limit / _NS_PER_S:g} s of its start "
                "(declared duration + margin)"
            )

    def _notes(self, *, final: bool = False) -> None:
        """Print one line per window skipped or written with lost samples, late, too large.

        Messages dropped for their size or by a full queue are said once per action written
        (``final``: the rest, at the end of the run), with the run's total: those dropped
        between actions are in no file.
        """
        report = self.report
        for path, lost in list(report.lost_samples.items())[self._noted.get("lost", 0) :]:
            self._note(
                f"{path}: live sources lost samples ({lost}); check fails on it: the recording "
                "lacks data its sources sent: record the action again"
            )
        self._noted["lost"] = len(report.lost_samples)
        for path, reason in list(report.cut_short.items())[self._noted.get("short", 0) :]:
            self._note(
                f"{path}: kept as incomplete ({reason}); check fails a recording that does not "
                "cover its action: record the action again"
            )
        self._noted["short"] = len(report.cut_short)
        for where, reason in report.skipped[self._noted.get("", 0) :]:
            self._note(f"skipped {where}: {reason}")
        self._noted[""] = len(report.skipped)
        delay = self.topic_map.max_delay_ns / _NS_PER_S
        for topic, count in report.late_samples.items():
            new = count - self._noted.get(f"late {topic}", 0)
            if new > 0:
                self._note(
                    f"{topic}: {new} samples arrived after their action was written (more than "
                    f"[time] max_delay_s = {delay:g} s late) and are not in it; raise "
                    "max_delay_s in the topic map"
                )
                self._noted[f"late {topic}"] = count
        # messages dropped: one line per action written (and one at the end), not per step
        written = self.session.done > self._noted.get("size done", 0)
        if written or final:
            self._note_dropped()
        if written:
            self._noted["size done"] = self.session.done

    def _note_dropped(self) -> None:
        """Print one line per topic that dropped messages since the last (the run's total)."""
        report = self.report
        for topic, (_, oversize, size) in self._counts.items():
            new = oversize - self._noted.get(f"size {topic}", 0)
            if new > 0:
                report.oversize[topic] = oversize
                budget, where = self.topic_map.message_budget(topic)
                self._note(
                    f"{topic}: dropped {new} messages larger than {where} max_message_kib = "
                    f"{budget >> 10} (the latest {size} bytes; {oversize} in all); each is "
                    "counted as malformed in the action it was stamped in (none between actions)"
                )
                self._noted[f"size {topic}"] = oversize
        for topic, (overflowed, _, _) in self._counts.items():
            new = overflowed - self._noted.get(f"queue {topic}", 0)
            if new > 0:
                report.overflowed[topic] = overflowed
                self._note(
                    f"{topic}: the reader's queue was full: dropped {new} messages "
                    f"({overflowed} in all); each is counted as overflowed in the action it "
                    "was stamped in (none between actions); the listener fell behind: give "
                    "it a computer less loaded"
                )
                self._noted[f"queue {topic}"] = overflowed

    def _note(self, line: str) -> None:
        if self.on_note is not None:
            self.on_note(line)

    def step(self, wait_s: float = _TICK_S) -> int:
        """Journal and feed what arrived since the last step; write the windows it completes.

        Returns:
            The number of messages taken.

        Raises:
            JournalError: The journal cannot be written (the caller stops the run).
        """
        taken = [(*item.payload, item.receive_ns) for item in self._take(wait_s)]
        items = [(topic, receive_ns, raw) for topic, raw, receive_ns in taken]
        now = self.clock.now_ns()
        counts, drops = self._reader_drops()
        step = JournalStep(items, now, counts, drops=drops)
        if self._journal is not None:
            try:
                self._journal.messages(items)
                dropped = {"drops": drops} if drops else {}
                self._journal.event(now, now=now, counts=counts, **dropped)
            except JournalError:  # what arrived is in memory: it is still written
                self.replay(step)
                raise
            self._recent.extend(items)
        if self.view is not None:
            for topic, receive_ns, raw in items:
                self.view.offer_raw(topic, receive_ns, raw)
        self.replay(step)
        if self._journal is not None:
            self._rotate(now)
        return len(items)

    def _reader_drops(
        self,
    ) -> tuple[dict[str, tuple[int, int, int]], dict[str, tuple[list[Drop], list[Drop]]]]:
        """Return the readers' counters and take the drops they kept since the last step.

        Returns:
            Topic -> (queue overflows, oversize drops, latest oversize bytes) since the
            start; topic -> (the drops of its full queue, of its size limit) since the last
            step, each ``(receive ns, header stamp or None)`` (topics that dropped any).
        """
        counts, drops = {}, {}
        for topic, raw in self._raw.items():
            overflowed, queue = self._overflow[topic].dropped()
            oversize, size, large = raw.dropped()
            counts[topic] = (overflowed, oversize, size)
            if queue or large:
                drops[topic] = (queue, large)
        return counts, drops

    def _account(self, step: JournalStep) -> None:
        """Take a step's counters (a journal's prelude: the accounting of the files so far)."""
        if step.counts:
            self._counts = {**self._counts, **step.counts}
        if step.seen is None:
            self._taken += len(step.items)
            return
        for topic, (overflowed, oversize) in step.seen.items():  # placed by the run already
            self._arrivals[topic].overflowed.seen = overflowed
            self._arrivals[topic].oversize.seen = oversize
        for topic, (queue, size) in step.held.items():  # the run's, that a window may hold
            self._arrivals[topic].overflowed.at = list(queue)
            self._arrivals[topic].oversize.at = list(size)
        for topic, (overflowed, oversize, _) in self._counts.items():
            self._noted[f"size {topic}"] = oversize
            self._noted[f"queue {topic}"] = overflowed

    def replay(self, step: JournalStep) -> None:
        """Feed one step's messages, then close windows and forget old data at its time."""
        self._account(step)
        data: list[tuple[Route, int, bytes]] = []
        annotation = self._grouper.topic if self._grouper is not None else None
        header = self.topic_map.stamps == "header"
        for topic, receive_ns, raw in step.items:
            if topic == annotation:
                self._flush(data)
                self._annotate(raw, receive_ns)
                continue
            route = self._routes.get(topic)
            if route is None:
                continue
            arrivals = self._arrivals.get(topic)
            stamp = None if arrivals is None else header_stamp(raw)  # either byte order
            if arrivals is not None and stamp is not None:
                arrivals.stamps.append(stamp)
                arrivals.receives.append(receive_ns)
                if arrivals.read_counter is not None:
                    arrivals.sequences.append(arrivals.read_counter(raw))
                arrivals.note(stamp if header else receive_ns, receive_ns)
                self._first_stamp.setdefault(topic, stamp)
                if self._latest_stamp is None or stamp > self._latest_stamp:
                    self._latest_stamp = stamp
            data.append((route, receive_ns, raw))
        self._flush(data)
        if step.now_ns is not None:
            self._release(step.now_ns)
            if step.seen is None:  # the drops of a prelude were placed by the run already
                self._place_drops(step)
        self._bound_open()
        if step.now_ns is not None:
            writable = self._writable(step.now_ns)
            self.session.advance(writable)
            self._trim(writable)
        self._notes()

    def _writable(self, now_ns: int) -> int:
        """Return the time up to which windows may be written, on the session's clock.

        A window is written once ``max_delay_s`` has passed beyond its reach (its end and the
        import's margin) and every topic that sent anything has sent a sample stamped beyond
        it: a listener held up (a loaded computer) reads all its topics late, and the time
        that passed alone would write a window before its last samples were read. A topic
        whose stamps lag the others' by :data:`WAIT_NS` has stopped and is not waited for;
        when every topic stopped, the windows wait :data:`STOPPED_NS` at most.

        The windows are on the stamps' clock, which may be another than the receive clock
        (a lab's sim time, or a computer whose clock is off): ``now_ns`` is taken onto it by
        each topic's offset (its lowest receive time minus stamp), the earliest of them.
        """
        stamps = [a.latest for a in self._arrivals.values() if a.latest is not None]
        if not stamps:
            return now_ns
        now = self._on_stamps(now_ns)
        newest = max(stamps)
        going = min(s for s in stamps if s >= newest - WAIT_NS)
        delay = self.topic_map.max_delay_ns
        return min(now, max(going + delay, now - STOPPED_NS))

    def _place_drops(self, step: JournalStep) -> None:
        """Place the messages the readers dropped in a step where each belongs.

        Only topics with accounting (a leading header: :class:`_Arrivals`) have drops to
        place; see :meth:`_where` for each drop, and :meth:`_Dropped.place` for those counted
        with nothing read of them.
        """
        step_ns = self._on_stamps(step.now_ns or 0)
        for topic, arrivals in self._arrivals.items():
            overflowed, oversize, _ = self._counts.get(topic, (0, 0, 0))
            queue, size = step.drops.get(topic, ((), ()))
            arrivals.overflowed.place(
                overflowed, [self._where(arrivals, d) for d in queue], step_ns
            )
            arrivals.oversize.place(oversize, [self._where(arrivals, d) for d in size], step_ns)

    def _where(self, arrivals: _Arrivals, drop: Drop) -> int:
        """Return where one dropped message lies on the windows' clock, ns."""
        receive_ns, stamp = drop
        if stamp is not None and self.topic_map.stamps == "header":
            return stamp  # its own header stamp: the window it was stamped in
        # no stamp read (its bytes too short or not plain CDR), or windows on the receive
        # clock: its receive time, taken onto the stamps' clock by the topic's offset
        if arrivals.offset is not None:
            return receive_ns - arrivals.offset
        return self._on_stamps(receive_ns)

    def _on_stamps(self, now_ns: int) -> int:
        """Return a receive time on the stamps' clock: by each topic's offset, the earliest."""
        offsets = [a.offset for a in self._arrivals.values() if a.offset is not None]
        return min((now_ns - offset for offset in offsets), default=now_ns)

    def _flush(self, data: list[tuple[Route, int, bytes]]) -> None:
        """Feed the data messages collected so far."""
        if data:
            feed(data, self.session)
            data.clear()

    def _take(self, wait_s: float) -> list[Received]:
        """Return what every reader queued, in receive order (waiting ``wait_s`` once)."""
        time.sleep(wait_s)
        items = [item for source in self._readers for item in source.drain()]
        items.sort(key=lambda item: item.receive_ns)
        return items

    def _trim(self, now_ns: int) -> None:
        """Forget what no window can need any more (no window started before then).

        ``now_ns`` is the time up to which windows may be written (:meth:`_writable`): a
        listener held up keeps what its late windows need.
        """
        bound = now_ns - self.topic_map.max_delay_ns - MARGIN_NS
        if self._grouper is not None and (start := self._grouper.open_start_ns) is not None:
            bound = min(bound, start - MARGIN_NS)
        if self._held:  # annotations not grouped yet: their windows reach back to them
            bound = min(bound, min(stamp for stamp, _, _ in self._held) - MARGIN_NS)
        bound = self.session.trim(bound)
        for arrivals in self._arrivals.values():
            arrivals.forget(bound)

    def finish(self) -> ImportReport:
        """Write the windows whose ``end`` arrived, then objects, index and report."""
        session = self.session
        why = f"stopped by {self.report.interrupted}" if self.report.interrupted else "run ended"
        self._release(None)
        self._cut_open(f"{why} before its 'end' annotation")
        while session.done < len(session.plans):
            session.finish_one()
        self._notes(final=True)
        tally(session.found, self.report)
        self.report.messages = {self.report.bags[0].path.name: self._taken}
        if self.report.written:
            written = set(self.report.written)
            objects = [_object_spec(p.obj) for p in session.plans if p.path in written]
            declare_objects(self.out, objects)
            self.report.index = write_index(self.out)
            self.report.save()
        self._retire(reopen=False)  # every window it holds is written
        if self._dropped is not None:  # what it holds, the run held and wrote: set it aside
            _aside(self.out, self._dropped)
        return self.report

    def drop_journal(self, err: JournalError) -> None:
        """Stop journaling after a write error: say so; the journal stays for a recovery."""
        self.failed = str(err)
        self.report.interrupted = self.report.interrupted or "the journal's write error"
        if self._journal is not None:
            self._journal.abandon()
            self._dropped, self._journal = self._journal.path, None
        self._note(f"{err}")


@dataclass(frozen=True, slots=True)
class _Channel:
    """A live topic as :func:`check_fields` sees a bag connection."""

    topic: str
    msgtype: str


@dataclass(frozen=True, slots=True)
class _Store:
    """What :func:`check_fields` reads of a bag reader: its typestore."""

    typestore: Typestore


def _counter_reader(store: Typestore, msgtype: str, path: str) -> Callable[[bytes], int | None]:
    """Return a reader of a message's integer field ``path`` from its CDR bytes.

    The reader returns None for bytes it cannot read (the import counts such a message).
    """
    decoder = compile_cdr(store, msgtype, [path], stamped=False)
    if decoder is not None:
        decode, dtype = decoder.decode, decoder.dtypes[0]

        def read_compiled(raw: bytes) -> int | None:
            fields = decode(raw)
            return None if fields is None else int(np.frombuffer(fields[2], dtype)[0])

        return read_compiled
    get = attrgetter(path)

    def read(raw: bytes) -> int | None:
        try:
            return int(get(store.deserialize_cdr(raw, msgtype)))
        except Exception:  # noqa: BLE001 (any undecodable message: the import counts it)
            return None

    return read


def _period(extractor: Any) -> int:  # noqa: ANN401
    """Return a topic's message period from the map's rate (0: measured from the stamps)."""
    if isinstance(extractor, SkinTopic):
        spec = extractor.fields[0]
        if spec.period_ns is not None:
            return round(spec.period_ns * spec.samples_per_message)
    return 0


def on_signal(signum: int, _frame: object) -> None:
    """Raise the signal's :func:`schemas.cli.ending` exception in the main thread.

    SIGTERM and SIGHUP end ``listen`` as Ctrl-C does: the run stops and keeps what arrived.
    """
    raise cli.ending(signum)


def listen(
    topic_map: TopicMap,
    out: Path,
    *,
    objects: Mapping[str, ObjectSpec],
    actions: Mapping[str, ActionSpec],
    domain_id: int = 0,
    duration_s: float | None = None,
    stop: threading.Event | None = None,
    discovery_s: float = 10.0,
    on_written: Callable[[Path], Any] | None = None,
    on_note: Callable[[str], Any] | None = None,
    loopback: bool = False,
    keep_journals: bool = False,
    view: TopicView | None = None,
) -> ImportReport:
    """Record a lab's ROS 2 topics live: one recording per action window, then the index.

    Args:
        topic_map: What the topics carry (:func:`load_topic_map`), as for ``import-bag``.
        out: Dataset directory; existing recordings are never overwritten.
        objects: Object catalog (the map's declarations take precedence).
        actions: Action catalog (the map's declarations take precedence).
        domain_id: The DDS domain (``ROS_DOMAIN_ID``).
        duration_s: Stop after this long (None: at ``stop`` or Ctrl-C).
        stop: Set it to stop (another thread).
        discovery_s: How long to wait for the topics' publishers at the start.
        on_written: Called with every recording written.
        on_note: Called with one line per window skipped or dropped.
        loopback: Join DDS on the loopback interface only (this process's configuration,
            whatever ``CYCLONEDDS_URI`` says).
        keep_journals: Keep retired journals in ``<out>/.listen/kept/`` (a raw copy of
            the session) instead of removing them.
        view: A Foxglove server shown every message as received (``--foxglove``).

    Returns:
        What was written and skipped.

    Raises:
        BagImportError: DDS is missing, a topic or the map is wrong, or another ``listen``
            records into ``out``.
    """
    with listen_lock(Path(out)):  # one run at a time into ``out``: refused in one line
        recover(
            topic_map,
            Path(out),
            objects=objects,
            actions=actions,
            on_written=on_written,
            on_note=on_note,
        )
        listener = Listener(
            topic_map,
            Path(out),
            objects,
            actions,
            domain_id,
            discovery_s,
            loopback=loopback,
            on_written=on_written,
            on_note=on_note,
            keep_journals=keep_journals,
            view=view,
        )
        deadline = None if duration_s is None else time.monotonic() + duration_s
        try:
            listener.start()  # discovery; Ctrl-C here ends the run before anything arrived
        except KeyboardInterrupt as err:
            listener.stop()
            return _interrupted(
                listener, err.signal_name if isinstance(err, cli.Terminated) else "SIGINT"
            )
        # From here a signal only sets a flag: raised wherever Python happens to be, it could
        # fall between a journal's creation and its bookkeeping and leave a stray file.
        with deferred_interrupts() as flag:
            try:
                listener._note(  # noqa: SLF001
                    f"listening on DDS domain {domain_id} to {len(listener._readers)} topics "  # noqa: SLF001
                    "(Ctrl-C, SIGTERM or SIGHUP stops, keeping the open action as incomplete)"
                )
                while flag.signum is None and not (stop is not None and stop.is_set()):
                    if deadline is not None and time.monotonic() >= deadline:
                        break
                    listener.step()
            except JournalError as err:
                listener.drop_journal(err)
            finally:
                listener.stop()
            if flag.signum is not None:
                return _interrupted(listener, cli.signal_name(flag.signum))
            return _finish(listener)


@dataclass(frozen=True, slots=True)
class TopicCheck:
    """What one topic sent during ``listen --dry-run``.

    Attributes:
        topic: The topic.
        msgtype: Its type, as discovered (and checked against the map).
        received: Messages received.
        rate_hz: Their rate by receive time (None: fewer than two).
        declared_hz: The rate the map gives the topic (None: none, e.g. annotations).
        dropped: Messages lost to a full queue (the reader fell behind).
        oversize: Messages dropped as larger than the topic's budget.
    """

    topic: str
    msgtype: str
    received: int
    rate_hz: float | None
    declared_hz: float | None
    dropped: int
    oversize: int

    @property
    def lost(self) -> int:
        """Messages that arrived and could not be kept."""
        return self.dropped + self.oversize

    def line(self) -> str:
        """One line: the topic, what arrived, how fast, against the map."""
        said = f"{self.topic} ({self.msgtype}): {self.received} received"
        if self.rate_hz is not None:
            said += f", {self.rate_hz:.4g} Hz"
        if self.declared_hz is not None:
            said += f" (the map: {self.declared_hz:.4g} Hz)"
            if self.rate_hz is not None and abs(self.rate_hz / self.declared_hz - 1) > RATE_OFF:
                said += "; check the map's rate or the publisher"
        if self.dropped:
            said += f"; {self.dropped} dropped by a full queue"
        if self.oversize:
            said += f"; {self.oversize} larger than the topic's budget (max_message_kib)"
        return said


#: A topic's measured rate this far from the map's (a share) is said in a dry run.
RATE_OFF = 0.2


def check_listen(
    topic_map: TopicMap,
    out: Path,
    *,
    objects: Mapping[str, ObjectSpec],
    actions: Mapping[str, ActionSpec],
    domain_id: int = 0,
    seconds: float = 2.0,
    discovery_s: float = 10.0,
    loopback: bool = False,
) -> tuple[TopicCheck, ...]:
    """Check what ``listen`` would record, writing nothing (``listen --dry-run``).

    The map's topics are found on the domain, their types and fields checked as a run checks
    them, then every topic is read for ``seconds``.

    Raises:
        BagImportError: DDS is missing, or a topic or the map is wrong (one line).
    """
    listener = Listener(
        topic_map,
        Path(out),
        objects,
        actions,
        domain_id,
        discovery_s,
        loopback=loopback,
        journal=False,
    )
    try:
        listener.start()
        return listener.rehearse(seconds)
    finally:
        listener.stop()


def _interrupted(listener: Listener, signal_name: str) -> ImportReport:
    """End a run a signal stopped: say so, then write what arrived."""
    listener.report.interrupted = signal_name
    listener._note(  # noqa: SLF001
        f"interrupted ({signal_name}): writing the actions whose end arrived, the open "
        "one as incomplete"
    )
    return _finish(listener)


def _finish(listener: Listener) -> ImportReport:
    """Take what is still queued, then write the windows and the index."""
    try:
        listener.step(0)
    except JournalError as err:
        listener.drop_journal(err)
        listener.step(0)
    return listener.finish()


@dataclass(frozen=True, slots=True)
class Recovered:
    """What a recovery made of one journal.

    Attributes:
        journal: Where the journal was moved (``.listen/recovered/``).
        written: Recordings written from it.
        incomplete: Actions whose ``end`` never came, kept as incomplete recordings.
        already: Recordings its run had written (not written again).
    """

    journal: Path
    written: tuple[Path, ...]
    incomplete: tuple[Path, ...]
    already: tuple[Path, ...]

    def describe(self) -> str:
        """Return the recovery's one line."""
        return (
            f"recovered {len(self.written)} actions from a stopped run's journal, "
            f"{len(self.incomplete)} kept as incomplete ({len(self.already)} written before it "
            f"stopped); journal moved to {self.journal}"
        )


def recover(
    topic_map: TopicMap,
    out: Path,
    *,
    objects: Mapping[str, ObjectSpec],
    actions: Mapping[str, ActionSpec],
    on_written: Callable[[Path], Any] | None = None,
    on_note: Callable[[str], Any] | None = None,
) -> list[Recovered]:
    """Write the windows of the journals that runs which died left in ``out``.

    Every journal in ``<out>/.listen/`` that no running ``listen`` holds is replayed as its run
    processed it: the windows whose ``end`` it holds become the recordings the run would have
    written (same names, same bytes where the same messages arrived), those written already
    are not written again, an action whose ``end`` never came is kept as incomplete. Then the
    journal moves to ``.listen/recovered/`` (never deleted).

    Returns:
        One entry per journal recovered (``on_note`` gets its line).

    Raises:
        BagImportError: A journal was recorded with another topic map, or a window cannot
            be written.
    """
    done = []
    for path in left_journals(out):
        with held(path) as free:
            if not free:
                continue  # a running listen's
            try:
                contents = read_journal(path)
            except JournalError as err:  # cut before its head: it holds no message
                if on_note is not None:
                    on_note(f"{err}; nothing to recover, moved to {_aside(out, path)}")
                continue
            recovered = _recover_one(
                contents,
                topic_map,
                out,
                objects=objects,
                actions=actions,
                on_written=on_written,
                on_note=on_note,
            )
        done.append(recovered)
        if on_note is not None:
            on_note(f"{path}: {recovered.describe()}")
    return done


def _aside(out: Path, path: Path) -> Path:
    """Move a recovered journal to ``.listen/recovered/`` and return its new path.

    Raises:
        BagImportError: It cannot be moved.
    """
    aside = out / JOURNAL_DIR / RECOVERED_DIR
    try:
        aside.mkdir(parents=True, exist_ok=True)
        target = aside / path.name
        path.rename(target)
    except OSError as err:
        msg = f"{path}: cannot move the recovered journal aside ({err.strerror}); move it by hand"
        raise BagImportError(msg) from err
    return target


def _recover_one(
    contents: JournalContents,
    topic_map: TopicMap,
    out: Path,
    *,
    objects: Mapping[str, ObjectSpec],
    actions: Mapping[str, ActionSpec],
    on_written: Callable[[Path], Any] | None,
    on_note: Callable[[str], Any] | None,
) -> Recovered:
    """Replay one journal into ``out`` and move it aside.

    Raises:
        BagImportError: It was recorded with another topic map.
    """
    head, path = contents.head, contents.path
    if hashlib.sha256(topic_map.path.read_bytes()).hexdigest() != head.map_sha256:
        msg = (
            f"{path}: recorded with another topic map than {topic_map.path}; recover it with "
            "the run's map: atikt-record listen --recover --out OUT --topic-map THAT_MAP"
        )
        raise BagImportError(msg)
    written = {out / relative for relative in contents.written}
    listener = Listener(
        topic_map,
        out,
        objects,
        actions,
        head.domain_id,
        on_written=on_written,
        on_note=on_note,
        journal=False,
        started_ns=head.started_ns,
        planner=ReplayPlanner(out, dict(head.trials), written),
    )
    listener.session.skip = written
    listener.prepare(head.types)
    for step in contents.steps():
        listener.replay(step)
    listener.report.interrupted = "a kill (recovered from its journal)"
    report = listener.finish()
    return Recovered(
        _aside(out, path),
        tuple(report.written),
        tuple(report.incomplete),
        tuple(listener.session.already),
    )
