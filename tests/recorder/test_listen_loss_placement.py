"""``listen`` counts a message its reader dropped in the window it was stamped in, and only there.

A message too large for the topic's budget (dropped by the DDS reader) and a sample the
reader's full queue could not hold (the listener fell behind) are counted in the file of the
window whose ``[start, stop)`` holds the message's own header stamp: not in the window being
read when the drop was noticed, and between actions in no file (the run's line gives the
total). The listener runs as ``listen`` runs it (:meth:`Listener.start`: its DDS readers, their
reader threads' queues), on a participant of a loopback domain of the test's own; what DDS
would deliver is handed to the readers by the test, one message at a time at its receive time
(no DDS traffic: the same result on every run), and the listener steps every 50 ms unless the
test holds it up.
"""

from __future__ import annotations

import json
import struct
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any

import pytest
from mcap.reader import make_reader

pytest.importorskip("cyclonedds")

from recorder import load_actions, load_objects
from recorder.bagimport._listen import Listener, recover
from recorder.bagimport._source import typestore
from recorder.bagimport._topicmap import load_topic_map
from recorder.live import _dds
from recorder.live.dds import DdsDomain, Publication
from schemas import SOURCES_RECORD, parse_source_stats

if TYPE_CHECKING:
    from collections.abc import Collection, Sequence
    from pathlib import Path

    from rosbags.typesys.store import Typestore

    from recorder.bagimport._report import ImportReport
    from recorder.bagimport._topicmap import TopicMap
    from schemas import SourceStats

MS = 1_000_000
#: The lab's clock at tick 0, ns (the listener's receive clock is the same here).
WALL = 1_700_000_000 * 1_000_000_000
#: Transport latency of a message of the steady stream, ns.
LATENCY = MS // 5
STEP_MS = 50
TEMP = "/skin/temp_0"
TYPES = {
    TEMP: "edge_msgs/msg/Scalar",
    "/annotations": "std_msgs/msg/String",
}
_STAMP = struct.Struct("<iI").pack_into

#: A message (topic, receive ms, CDR bytes) as DDS would hand it to the topic's reader.
Message = tuple[str, float, bytes]


def _map(root: Path) -> TopicMap:
    """Write and load the map: one cell's temperature at 50 Hz, messages of at most 1 KiB."""
    (root / "Scalar.msg").write_text("std_msgs/Header header\nfloat32 data\n", encoding="utf-8")
    text = """
[time]
stamps = "header"
max_delay_s = 0.2

[skin]
cells = [0]

[skin.temperature]
topic = "/skin/temp_{cell}"
field = "data"
rate_hz = 50
max_message_kib = 1

[windows]
source = "topic"
topic = "/annotations"

[actions.tap]
kind = "static"
duration_s = 0.5

[objects.wood]
name = "Wood"

[types]
"edge_msgs/msg/Scalar" = "Scalar.msg"
"""
    path = root / "map.toml"
    path.write_text(text, encoding="utf-8")
    return load_topic_map(path)


def _scalar(store: Typestore, stamp_ms: float, frame: str = "cell0") -> bytes:
    """Return a temperature message stamped at ``stamp_ms`` (a long ``frame``: too large)."""
    types = store.types
    header = types["std_msgs/msg/Header"](
        stamp=types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=frame
    )
    raw = bytearray(store.serialize_cdr(types[TYPES[TEMP]](header=header, data=1.0), TYPES[TEMP]))
    stamp = WALL + round(stamp_ms * MS)
    _STAMP(raw, 4, stamp // 1_000_000_000, stamp % 1_000_000_000)
    return bytes(raw)


def _annotation(store: Typestore, phase: str, tick_ms: int, trial: int) -> bytes:
    """Return the annotation of ``phase`` of trial ``trial``, stamped at ``tick_ms``."""
    text = {"object": "wood", "action": "tap", "phase": phase, "trial": trial}
    message = store.types["std_msgs/msg/String"](
        data=json.dumps({**text, "stamp_ns": WALL + tick_ms * MS})
    )
    return bytes(store.serialize_cdr(message, "std_msgs/msg/String"))


def _session(
    store: Typestore,
    windows: Sequence[tuple[int, int]],
    *,
    length_ms: int,
    too_large: Sequence[tuple[float, float]] = (),
    late_execute: dict[int, float] | None = None,
) -> list[Message]:
    """Return what the lab sends, in receive order: a sample every 20 ms, the annotations.

    ``windows``: (execute, end) ms per trial (1, 2...); ``too_large``: (stamp ms, receive ms)
    of extra messages above the topic's budget; ``late_execute``: trial -> how late its
    execute annotation arrives, ms.
    """
    late = late_execute or {}
    out: list[Message] = [
        (TEMP, tick + LATENCY / MS, _scalar(store, tick)) for tick in range(0, length_ms, 20)
    ]
    for trial, (execute, end) in enumerate(windows, start=1):
        for phase, at, delay in (("execute", execute, late.get(trial, 0)), ("end", end, 0)):
            out.append(("/annotations", at + 1 + delay, _annotation(store, phase, at, trial)))
    big = "x" * 2000
    out += [(TEMP, receive, _scalar(store, stamp, big)) for stamp, receive in too_large]
    out.sort(key=lambda message: message[1])
    return out


class _Clock:
    """The listener's clock (its readers' receive clock too), moved by the test."""

    def __init__(self) -> None:
        self.now = WALL

    def now_ns(self) -> int:
        return self.now


class _NoWait:
    """A DDS wait set with nothing to wait for: the test hands each reader its messages."""

    def wait(self, _timeout_ns: int) -> int:
        return 0


class _Lab:
    """Runs a :class:`Listener` as ``listen`` does, handing its DDS readers what the lab sent."""

    def __init__(
        self, monkeypatch: pytest.MonkeyPatch, topic_map: TopicMap, out: Path, domain: int
    ) -> None:
        self.clock = _Clock()
        #: reader handle -> the message DDS hands it at its next take
        self._script: dict[int, list[Any]] = {}
        valid = SimpleNamespace(valid_data=True)

        def take(ref: int, _mask: object, _count: int) -> list[Any]:
            return [(raw, valid) for raw in self._script.pop(ref, [])]

        def found(_self: DdsDomain, topics: Collection[str], _timeout_s: float) -> Any:
            return {t: [Publication(t, TYPES[t], reliable=True)] for t in topics}

        monkeypatch.setattr(_dds, "ddspy_take", take)
        monkeypatch.setattr(DdsDomain, "wait_for", found)
        self.notes: list[str] = []
        self.listener = Listener(
            topic_map,
            out,
            load_objects(None),
            load_actions(None),
            domain,
            discovery_s=0.1,
            capacity=3,
            on_note=self.notes.append,
            clock=self.clock,  # type: ignore[arg-type]
        )
        self.listener.start()
        for reader in self.listener._readers:  # the test delivers instead, in order
            reader.stop()
        #: topic -> its reader thread's queue
        self._sources = self.listener._overflow
        for raw in self.listener._raw.values():
            raw._waitset = _NoWait()

    def run(self, messages: Sequence[Message], until_ms: int, held: Collection[int] = ()) -> None:
        """Hand each message to its reader at its receive time; step every 50 ms but ``held``."""
        raws = self.listener._raw
        pending = list(messages)
        step = 0
        while step < until_ms:
            step += STEP_MS
            while pending and pending[0][1] <= step:
                topic, receive_ms, raw = pending.pop(0)
                self.clock.now = WALL + round(receive_ms * MS)
                reader = raws[topic]
                self._script[reader.reader._ref] = [raw]  # the binding's handle
                item = reader.receive()
                if item is not None:  # what the reader thread does with it
                    self._sources[topic].deliver(item)
            self.clock.now = WALL + step * MS
            if step not in held:
                self.listener.step(0)

    def finish(self) -> ImportReport:
        """Stop listening and write what is left (as ``listen`` ends)."""
        self.listener.stop()
        return self.listener.finish()


def _temp(path: Path) -> SourceStats:
    """Return the temperature topic's accounting in a recording (its sources record).

    Read from the record itself: ``check`` (and the reader) refuse a recording whose skin
    pauses this long inside the action, which is what a full queue leaves.
    """
    with path.open("rb") as stream:
        (record,) = [
            m.metadata for m in make_reader(stream).iter_metadata() if m.name == SOURCES_RECORD
        ]
    found = [s for s in parse_source_stats(record) if s.name == TEMP]
    assert len(found) == 1, f"{path.name}: no accounting of {TEMP}"
    return found[0]


def test_a_message_too_large_is_counted_in_the_window_it_was_stamped_in(
    monkeypatch: pytest.MonkeyPatch, dds_domain: int, tmp_path: Path
) -> None:
    # windows [500, 1000) and [1100, 1600) ms; four messages above the budget, each placed by
    # its stamp, whichever step read it: one stamped inside the first, read promptly; one
    # stamped 10 ms before its end that took 130 ms to arrive (read in the step at 1150,
    # inside the second); one stamped between the actions, read inside the second too; one
    # stamped inside the second
    topic_map = _map(tmp_path)
    store = typestore(topic_map)
    too_large = [(700.0, 700.5), (990.0, 1120.0), (1050.0, 1110.0), (1300.0, 1300.5)]
    messages = _session(store, [(500, 1000), (1100, 1600)], length_ms=3400, too_large=too_large)
    lab = _Lab(monkeypatch, topic_map, tmp_path / "out", dds_domain)
    lab.run(messages, 3400)
    report = lab.finish()
    first, second = report.written
    assert (_temp(first).malformed, _temp(second).malformed) == (2, 1)
    assert _temp(first).received == 25  # the 20 ms samples of [500, 1000): none dropped
    assert report.oversize == {TEMP: 4}  # the run's total: the one between actions too
    (line,) = [n for n in lab.notes if "larger than" in n]
    assert "4 in all" in line
    assert "stamped in (none between actions)" in line


def test_a_full_queue_is_charged_to_the_window_its_samples_were_stamped_in(
    monkeypatch: pytest.MonkeyPatch, dds_domain: int, tmp_path: Path
) -> None:
    # windows [500, 1000) and [2600, 3100) ms; the listener is held up four times (no step
    # for 100 or 150 ms) while the lab sends on, and the queue (3 samples) drops the rest:
    # in the first window (no steps 750, 800: samples 700-840 came, 760-840 dropped: 5);
    # between the actions, after the first was written (2400, 2450: 2420-2480 dropped: 4);
    # in the second (2800: 2820, 2840 dropped: 2); and after its end, before it is written
    # (3150: 3160, 3180 dropped: 2)
    topic_map = _map(tmp_path)
    store = typestore(topic_map)
    messages = _session(store, [(500, 1000), (2600, 3100)], length_ms=4800)
    lab = _Lab(monkeypatch, topic_map, tmp_path / "out", dds_domain)
    held = {750, 800, 2400, 2450, 2800, 3150}
    lab.run(messages, 4800, held)
    report = lab.finish()
    first, second = report.written
    assert (_temp(first).overflowed, _temp(second).overflowed) == (5, 2)
    assert (_temp(first).missing, _temp(second).missing) == (5, 2)
    lines = [n for n in lab.notes if "queue was full" in n]
    assert lines, lab.notes
    assert "(13 in all)" in lines[-1]  # the run's total: those between actions too
    assert report.overflowed == {TEMP: 13}  # and in the report's JSON
    assert report.to_json()["overflowed"] == {TEMP: 13}


def test_a_window_whose_every_sample_the_queue_dropped_says_so_not_the_next(
    monkeypatch: pytest.MonkeyPatch, dds_domain: int, tmp_path: Path
) -> None:
    # windows [500, 1000), [2500, 3000) and [4000, 4500) ms; the listener is held up from
    # 2450 to 3000 (its next step at 3050): the queue keeps 2400-2440 and drops 2460-3040,
    # every sample of the second window (25) and 5 between the actions. The second window's
    # file counts its 25 as dropped by the full queue and missing; the third's counts none
    topic_map = _map(tmp_path)
    store = typestore(topic_map)
    messages = _session(store, [(500, 1000), (2500, 3000), (4000, 4500)], length_ms=6200)
    lab = _Lab(monkeypatch, topic_map, tmp_path / "out", dds_domain)
    lab.run(messages, 6200, set(range(2450, 3001, STEP_MS)))
    report = lab.finish()
    first, second, third = (_temp(path) for path in report.written)
    assert [s.overflowed for s in (first, second, third)] == [0, 25, 0]
    assert (second.received, second.missing, second.lost) == (0, 25, 25)
    assert third.received == 25
    assert any(n.startswith(f"{report.written[1]}: live sources lost") for n in lab.notes)
    (line,) = [n for n in lab.notes if "queue was full" in n]
    assert "(30 in all)" in line


def test_a_killed_runs_journal_recovers_each_drop_where_it_was_stamped(
    monkeypatch: pytest.MonkeyPatch, dds_domain: int, tmp_path: Path
) -> None:
    # windows [500, 1000) and [2200, 2700) ms; the second's execute arrives 60 ms late, so
    # the run was idle at its step 2250 and began a new journal then (the first window was
    # written): a message too large stamped at 2230 was placed before, one at 2400 after;
    # the queue drops 2520 and 2540 (no step at 2500). The run is killed at 3000,
    # before the second window is written; the next listen recovers it from the journal
    topic_map = _map(tmp_path)
    store = typestore(topic_map)
    out = tmp_path / "out"
    messages = _session(
        store,
        [(500, 1000), (2200, 2700)],
        length_ms=3000,
        too_large=[(2230.0, 2231.0), (2400.0, 2401.0)],
        late_execute={2: 60},
    )
    lab = _Lab(monkeypatch, topic_map, out, dds_domain)  # journaled, as listen runs
    lab.run(messages, 3000, {2500})
    assert len(lab.listener.report.written) == 1
    lab.listener.stop()
    journal = lab.listener._journal
    assert journal is not None
    assert journal.path.name.endswith("-0002.journal.mcap")  # the first was retired
    journal.abandon()  # a SIGKILL: the journal stays, cut
    (recovered,) = recover(topic_map, out, objects=load_objects(None), actions=load_actions(None))
    (second,) = recovered.written
    assert (_temp(second).malformed, _temp(second).overflowed) == (2, 2)


def test_a_header_stamp_is_read_from_12_bytes_in_the_byte_order_the_cdr_header_names() -> None:
    from schemas.cdr import header_stamp  # noqa: PLC0415 (the fix's: the rest runs without)

    little = b"\x00\x01\x00\x00" + struct.pack("<iI", 5, 7) + b"\x00" * 3_000_000
    big = b"\x00\x00\x00\x00" + struct.pack(">iI", 5, 7)
    assert header_stamp(little) == header_stamp(big) == 5_000_000_007
    assert header_stamp(big[:11]) is None  # too short: placed by its receive time
    assert header_stamp(b"\x00\x03" + little[2:12]) is None  # parameter-list CDR: not there
    assert header_stamp(b"\x00\x07" + little[2:12]) == 5_000_000_007  # plain XCDR2, little
