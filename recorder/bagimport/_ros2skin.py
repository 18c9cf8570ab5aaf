"""The live skin of a rig configuration's ``[skin] transport = "ros2"``: a topic map's skin topics.

The skin's ROS 2 topics are read over DDS (:mod:`recorder.live.dds`, no ROS installation) and
converted exactly as ``import-bag`` converts the same topics in a bag: the import's extractors
(:class:`SkinTopic`), cell alignment and packing (:mod:`._pack`); the transport, the reader
threads and the accounting are :mod:`recorder.live`'s. Found by name through
``recorder.live``'s skin transports (:func:`ros2_skin`); importing this module needs Cyclone
DDS's binding (``pip install 'atikt[ros2]'``).
"""

from __future__ import annotations

import bisect
import threading
from collections import deque
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Self

import numpy as np

from recorder.bagimport._pack import align_rows, block_period, left_out_by_topic, skin_blocks
from recorder.bagimport._source import SkinTopic, extractors, typestore
from recorder.bagimport._topicmap import load_topic_map
from recorder.errors import RecorderError, RigError
from recorder.live import SourceCounter, SourceReader, Verdict, window_samples
from recorder.live.dds import DdsDomain
from schemas import cli
from schemas.cdr import compile_cdr

if TYPE_CHECKING:
    from collections.abc import Mapping
    from types import TracebackType

    from recorder.bagimport._topicmap import TopicMap
    from recorder.live import RecorderClock


#: How far back a recording's clock offset may look into earlier recordings, s (a source's
#: clock drifts 0.1 ms a minute at 2 ppm; a publisher may lag for the whole first second).
OFFSET_MEMORY_S = 60
#: Blocks are cut at most this often while recording, s (of receive time).
POLL_BLOCK_S = 0.02


@dataclass(slots=True)
class _Modality:
    """One skin modality's packing state."""

    spec: Any
    period_ns: int
    emitted_ns: int = -(2**63)
    latest: Any = None
    recent: Any = None  # the last 20 ms of samples (total_force's mean)
    #: The clock offset this recording's blocks are shifted by, ns (taken with its first
    #: block: the counter's estimate keeps improving, and a later, smaller one would move a
    #: later block before an earlier one's samples).
    offset_ns: int | None = None


@dataclass
class Ros2Skin:
    """A live skin read from the ROS 2 topics of a topic map (a :class:`LiveSkin`).

    The samples go through the import's own extractors (:class:`SkinTopic`: fields, scales,
    batching, widths) and cell alignment (:func:`align_rows`); blocks are cut where every
    cell has samples, shifted onto the recorder's time base by each source's clock offset.
    """

    topic_map: TopicMap
    clock: RecorderClock
    domain_id: int = 0
    discovery_s: float = 10.0
    capacity: int = 10_000
    _domain: DdsDomain | None = field(default=None, init=False)
    _readers: dict[str, SourceReader] = field(default_factory=dict, init=False)
    _found: dict[str, Any] = field(default_factory=dict, init=False)
    _decoders: dict[str, Any] = field(default_factory=dict, init=False)
    _counters: dict[str, Any] = field(default_factory=dict, init=False)
    #: Per topic: the index of its message counter among the decoded fields (None: none).
    _sequence_at: dict[str, int | None] = field(default_factory=dict, init=False)
    _overflow0: dict[str, int] = field(default_factory=dict, init=False)
    #: Each topic's DDS reader (its count of messages dropped for their size) and that count
    #: at the recording's start.
    _raw: dict[str, Any] = field(default_factory=dict, init=False)
    _oversize0: dict[str, int] = field(default_factory=dict, init=False)
    _modalities: dict[str, _Modality] = field(default_factory=dict, init=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, init=False)
    _last_receive: int | None = field(default=None, init=False)
    _cut_ns: int = field(default=0, init=False)
    #: Per topic, the lowest latency (receive minus stamp) of each second of receive time,
    #: kept across recordings (:meth:`_offset`).
    _floors: dict[str, deque[tuple[int, int]]] = field(default_factory=dict, init=False)

    def __enter__(self) -> Self:
        """Join the domain, find the skin topics' types and start one reader per topic.

        Raises:
            RigError: A skin topic has no publisher within ``discovery_s``.
        """
        store = typestore(self.topic_map)
        self._domain = DdsDomain(self.domain_id, store)
        self._found = {
            t: e for t, e in extractors(self.topic_map).items() if isinstance(e, SkinTopic)
        }
        seen = self._domain.wait_for(self._found, self.discovery_s)
        if missing := sorted(set(self._found) - set(seen)):
            msg = (
                f"{self.topic_map.path}: no publisher of skin topic {missing[0]} on DDS domain "
                f"{self.domain_id} within {self.discovery_s:g} s; start the skin's driver or fix "
                "the topic map or domain_id"
            )
            raise RigError(msg)
        for topic, extractor in self._found.items():
            publications = seen[topic]
            msgtype = publications[0].msgtype
            reliable = all(p.reliable for p in publications)
            fields = list(extractor.paths)
            decoder = compile_cdr(store, msgtype, fields, stamped=True)
            if decoder is None:
                msg = f"topic {topic} ({msgtype}): its layout cannot be read live; map plain fields"
                raise RigError(msg)
            extractor.dtypes = decoder.dtypes
            self._decoders[topic] = decoder.decode
            raw = self._domain.reader(topic, msgtype, reliable=reliable)
            raw.clock = self.clock.now_ns
            raw.max_bytes, _ = self.topic_map.message_budget(topic)  # larger: malformed
            self._raw[topic] = raw
            reader = SourceReader(f"dds{topic}", raw.receive, capacity=self.capacity)
            self._readers[topic] = reader
            reader.start()
        for modality, spec in self.topic_map.skin.items():
            period = int(spec.period_ns) if spec.period_ns is not None else 0
            self._modalities[modality] = _Modality(spec, period)
        self.begin()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Stop the reader threads."""
        for reader in self._readers.values():
            reader.stop()

    @property
    def cells(self) -> int:
        """Return the number of cells."""
        return len(self.topic_map.cells)

    @property
    def modalities(self) -> tuple[str, ...]:
        """Return the modalities the topic map maps (a :class:`recorder.live.SensingSkin`)."""
        return tuple(self.topic_map.skin)

    def begin(self) -> None:
        """Start a new recording: fresh accounting, forget what was received before."""
        for topic, reader in self._readers.items():
            reader.drain()
            extractor = self._found[topic]
            spec = extractor.fields[0]
            period = int(spec.period_ns * spec.samples_per_message) if spec.period_ns else 0
            name = topic.lstrip("/").replace(".", "_")
            sequence = extractor.sequence
            self._counters[topic] = (
                SourceCounter(name, period_ns=period, gaps=True)
                if sequence is None  # pauses of its stamps are gaps
                else SourceCounter(name, period_ns=period, modulo=sequence[1])  # loss is missing
            )
            self._sequence_at[topic] = (
                None if sequence is None else extractor.paths.index(sequence[0])
            )
            self._overflow0[topic] = reader.overflowed
            raw = self._raw.get(topic)
            self._oversize0[topic] = raw.oversize if raw is not None else 0
            extractor.forget(2**62)
        for state in self._modalities.values():
            state.emitted_ns = -(2**63)
            state.offset_ns = None

    def _ingest(self) -> None:
        """Move every queued sample into the extractors, counting it."""
        for topic, reader in self._readers.items():
            extractor, decode, counter = (
                self._found[topic],
                self._decoders[topic],
                self._counters[topic],
            )
            for item in reader.drain():
                fields = decode(item.payload[1])
                if fields is None:
                    continue
                stamp = fields[0] * 1_000_000_000 + fields[1]
                at = self._sequence_at[topic]
                sequence = None
                if at is not None and extractor.dtypes is not None:
                    sequence = int(np.frombuffer(fields[2 + at], extractor.dtypes[at])[0])
                verdict = counter.count(sequence, stamp, item.receive_ns)
                if verdict is Verdict.NEW_RUN:  # the source's clock jumped: forget its past
                    self._floors.pop(topic, None)
                if verdict.fresh and counter.period_ns > 0:  # checked against its range
                    _lowest(self._floors.setdefault(topic, deque()), stamp, item.receive_ns)
                last = extractor.buffer.last
                if verdict.fresh and (last is None or stamp > last):  # never an invalid stamp
                    extractor.push_fields(fields, stamp, item.receive_ns)
                self._last_receive = item.receive_ns

    def _blocks(self, *, final: bool) -> list[Any]:
        """Return the blocks of every modality that all cells have samples for."""
        out: list[Any] = []
        # each topic's messages from a few before the earliest not yet emitted, converted
        # once per poll: converting the whole buffer for every modality made a poll cost
        # grow with the buffer (2 s), and a busy recorder polled the skin late
        since = min((s.emitted_ns for s in self._modalities.values()), default=-(2**62))
        taken = {
            topic: e.take_cells(_take_from(e.buffer.stamps, since), 2**62)
            for topic, e in self._found.items()
            if e.size() >= 2  # noqa: PLR2004 (a period needs two)
        }
        for modality, state in self._modalities.items():
            mine = [t for t, e in self._found.items() if modality in e.offsets]
            if any(t not in taken for t in mine):
                continue
            cells = sorted(
                ((cell, t, s) for t in mine for cell, s in taken[t][modality]),
                key=lambda cell: cell[0],
            )
            series = [s for _, _, s in cells]
            if any(s.stamps.size < 2 for s in series):  # noqa: PLR2004
                continue
            exact = state.spec.period_ns if state.spec.timing == "message" else None
            period = block_period(exact, series[0].stamps)
            if period <= 0:
                continue
            hi = min(int(s.stamps[-1]) for s in series) + (1 if final else -period)
            lo = max(state.emitted_ns, int(series[0].stamps[0]))
            if hi <= lo:
                continue
            rows = align_rows(series, lo, hi, period)
            blocks, _, repeated = skin_blocks(modality, rows, period, self.topic_map.max_jitter)
            topics = [t for _, t, _ in cells]
            for topic, count in left_out_by_topic(topics, rows, repeated).items():
                self._counters[topic].unaligned(count)
            state.emitted_ns = hi
            if state.offset_ns is None:
                state.offset_ns = self._offset(modality)
            out.extend(_shift(b, state.offset_ns) for b in blocks)
            if len(blocks):
                state.latest = np.asarray(blocks[-1].data[-1], dtype=np.float64)
                count = window_samples(blocks[-1].period_ns)
                state.recent = np.asarray(blocks[-1].data[-count:], dtype=np.float64)
        for extractor in self._found.values():
            keep = min((s.emitted_ns for s in self._modalities.values()), default=0)
            extractor.forget(keep - 2_000_000_000)
        return out

    def _offset(self, modality: str) -> int:
        """Return the clock offset of the first cell's topic of a modality.

        The offset is the lowest latency seen: this recording's (its first second, the
        counter's), or that of the last :data:`OFFSET_MEMORY_S` of earlier recordings. A
        source's clock does not change between actions, and a recording whose first second
        arrived late (a publisher catching up) would otherwise place its samples too late.
        """
        for topic, extractor in self._found.items():
            if modality in extractor.offsets:
                own = self._counters[topic].clock_offset_ns
                floor = self._floors.get(topic)
                if floor:
                    recent = floor[-1][0] - OFFSET_MEMORY_S
                    remembered = min(low for second, low in floor if second >= recent)
                    own = remembered if own is None else min(own, remembered)
                return int(own or 0)
        return 0

    def poll(self) -> list[Any]:
        """Return the blocks completed since the last poll.

        Raises:
            SourceLostError: A reader thread failed.
        """
        with self._lock:
            self._ingest()
            # blocks are cut every POLL_BLOCK_S of received samples, not at every poll of a
            # runner that polls with each arm state (500 Hz): cutting costs the same for one
            # new sample as for ten, and a recorder busy cutting polls everything late
            newest = self._last_receive or 0
            if newest - self._cut_ns < POLL_BLOCK_S * 1_000_000_000:
                return []
            self._cut_ns = newest
            return self._blocks(final=False)

    def finish(self) -> list[Any]:
        """Return everything received (the end of a recording)."""
        with self._lock:
            self._ingest()
            return self._blocks(final=True)

    def total_force(self) -> float | None:
        """Return the total force, mean of the last 20 ms of samples, N (None: none yet)."""
        state = self._modalities.get("force")
        if state is None or state.recent is None:
            return None
        totals = state.recent.reshape(len(state.recent), -1).sum(axis=1)
        return float(totals.mean())

    def nearest(self) -> float | None:
        """Return the latest smallest proximity, m (None: no proximity sensing)."""
        state = self._modalities.get("proximity")
        return None if state is None or state.latest is None else float(state.latest.min())

    def last_receive_ns(self) -> int | None:
        """Return the receive time of the latest sample (None: nothing yet)."""
        return self._last_receive

    def stats(self) -> list[Any]:
        """Return each topic's accounting since :meth:`begin` (overflow included)."""
        out = []
        for topic, counter in self._counters.items():
            overflowed = self._readers[topic].overflowed
            counter.overflow(overflowed - self._overflow0[topic])
            self._overflow0[topic] = overflowed
            raw = self._raw.get(topic)
            if raw is not None:  # messages over the topic's max_message_kib
                counter.malformed(raw.oversize - self._oversize0[topic])
                self._oversize0[topic] = raw.oversize
            out.append(counter.stats())
        return out


def _take_from(stamps: list[int], since: int) -> int:
    """Return the stamp of the third message before ``since`` (the first one if fewer)."""
    index = bisect.bisect_left(stamps, since)
    return stamps[max(index - 3, 0)] if stamps else since


def _lowest(floor: deque[tuple[int, int]], stamp: int, receive_ns: int) -> None:
    """Keep the lowest latency of the receive second of a sample (the last minutes only)."""
    second, latency = receive_ns // 1_000_000_000, receive_ns - stamp
    if floor and floor[-1][0] == second:
        if latency < floor[-1][1]:
            floor[-1] = (second, latency)
        return
    floor.append((second, latency))
    while floor[0][0] < second - OFFSET_MEMORY_S:
        floor.popleft()


def _shift(block: Any, offset_ns: int) -> Any:  # noqa: ANN401
    """Return a block with its stamp moved onto the recorder's time base."""
    return replace(block, stamp_ns=block.stamp_ns + offset_ns)


def ros2_skin(section: Mapping[str, Any], clock: RecorderClock, where: str) -> Ros2Skin:
    """Build the live skin of a rig configuration's ``[skin]`` table (``transport = "ros2"``).

    Keys: ``topic_map`` (path of the topic map, relative to the configuration), optional
    ``domain_id`` (default 0) and ``discovery_s`` (default 10).

    Raises:
        RigError: A key is missing, unknown or wrong, or the map does not load.
    """
    known = {"transport", "topic_map", "domain_id", "discovery_s"}
    if unknown := sorted(set(section) - known):
        msg = (
            f"{where}: [skin] key {unknown[0]!r} is unknown for transport ros2; use {sorted(known)}"
        )
        raise RigError(msg)
    path = section.get("topic_map")
    if not isinstance(path, str):
        msg = f'{where}: [skin] transport = "ros2" needs topic_map = "path/to/topic_map.toml"'
        raise RigError(msg)
    domain = section.get("domain_id", 0)
    largest = cli.MAX_DOMAIN_ID
    if isinstance(domain, bool) or not isinstance(domain, int) or not 0 <= domain <= largest:
        msg = f"{where}: [skin] domain_id = {domain!r}: give a DDS domain id 0..{cli.MAX_DOMAIN_ID}"
        raise RigError(msg)
    base = Path(where).parent if where else Path()
    try:
        topic_map = load_topic_map(base / path)
    except RecorderError as err:
        raise RigError(str(err)) from err
    discovery = float(section.get("discovery_s", 10.0))
    return Ros2Skin(topic_map, clock, domain, discovery)
