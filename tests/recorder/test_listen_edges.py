"""``listen`` at the edges of an action: a publisher's jitter there is a pause, not a defect.

A lab's publisher stamps each sample when it sends it; when it is held up (the scheduler of a
loaded computer, between two cells' writes or before a tick), the samples it owed before an
edge of the action are stamped after it. The streams here are replayed through the listener
offline (as a recovery replays a journal: the same code as live, no DDS traffic, the same
result on every run): a cell sent late just before the execute phase, a publisher paused
across the action's end, and a listener that reads its topics late give files that pass
``check`` with nothing missing; a cell that really stops before the end still fails it.
"""

from __future__ import annotations

import json
import struct
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from mcap.reader import make_reader

pytest.importorskip("cyclonedds")

from recorder import load_actions, load_objects
from recorder.bagimport._journal import JournalStep
from recorder.bagimport._listen import Listener
from recorder.bagimport._source import typestore
from recorder.bagimport._topicmap import load_topic_map
from recorder.bagimport._windows import AnnotationGrouper
from recorder.errors import BagImportError
from recorder.live import Received
from replay.cli._main import _check_one
from replay.recording._reader import read_recording
from schemas import MAX_TRIAL

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping
    from pathlib import Path

    from rosbags.typesys.store import Typestore

    from recorder.bagimport._report import ImportReport

MS = 1_000_000
#: The lab's clock at the session's first tick, ns.
WALL = 1_700_000_000 * 1_000_000_000
#: Ticks (ms) of the execute annotation and the end; the session's length.
EXECUTE, END, LENGTH = 500, 1000, 1300
CELLS = 2
#: topic pattern -> (type, period in ms)
TOPICS = {
    "/skin/force_{cell}": ("edge_msgs/msg/Vec3", 1),
    "/skin/temp_{cell}": ("edge_msgs/msg/Scalar", 50),
}
TYPES = {
    "edge_msgs/msg/Vec3": "std_msgs/Header header\nfloat32[3] data\n",
    "edge_msgs/msg/Scalar": "std_msgs/Header header\nfloat32 data\n",
    # the force of a publisher that counts its messages (a uint8 that wraps at 256)
    "edge_msgs/msg/Vec3Seq": "std_msgs/Header header\nuint8 seq\nfloat32[3] data\n",
}
_STAMP = struct.Struct("<iI").pack_into

#: (tick ms, topic) -> how long the publisher is held up before it sends that message, ms
Stalls = dict[tuple[int, str], float]


def _map(root: Path, *, counted: bool = False) -> Path:
    """Write the topic map: force at 1 kHz and temperature at 20 Hz per cell, one action.

    ``counted``: the force messages carry a counter the map names.
    """
    lines = ["[time]", 'stamps = "header"', "max_delay_s = 0.2", "", "[skin]"]
    lines += [f"cells = {list(range(CELLS))}", ""]
    modalities = ("force", "temperature")
    for modality, (topic, (_, period)) in zip(modalities, TOPICS.items(), strict=True):
        lines += [f"[skin.{modality}]", f'topic = "{topic}"', 'field = "data"']
        lines += [f"rate_hz = {1000 // period}", ""]
        if counted and modality == "force":
            lines[-1:-1] = ['counter = "seq"', "counter_modulo = 256"]
    lines += ["[windows]", 'source = "topic"', 'topic = "/annotations"', ""]
    lines += ["[actions.tap]", 'kind = "static"', f"duration_s = {(END - EXECUTE) / 1000}", ""]
    lines += ["[objects.wood]", 'name = "Wood"', "", "[types]"]
    for name, text in TYPES.items():
        (root / (name.rsplit("/", 1)[-1] + ".msg")).write_text(text, encoding="utf-8")
        lines.append(f'"{name}" = "{name.rsplit("/", 1)[-1]}.msg"')
    path = root / "map.toml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _template(store: Typestore, msgtype: str) -> bytearray:
    """Return a message of ``msgtype`` whose stamp (CDR bytes 4..12) is patched per send.

    A counted message's ``seq`` (one byte, right after the header: byte 21) is patched too.
    """
    types = store.types
    header = types["std_msgs/msg/Header"](
        stamp=types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="edge"
    )
    fields: dict[str, Any] = {"header": header}
    fields["data"] = np.ones(3, np.float32) if "Vec3" in msgtype else 1.0
    if msgtype.endswith("Seq"):
        fields["seq"] = 0
    return bytearray(store.serialize_cdr(types[msgtype](**fields), msgtype))


def _annotation(
    store: Typestore, phase: str, tick: int, trial: int = 1, clock_ns: int = 0
) -> bytes:
    """Return the annotation of ``phase`` scheduled at ``tick`` (the lab's schedule).

    ``clock_ns``: the lab's clock minus the listener's (its stamps are on the lab's).
    """
    text: dict[str, Any] = {"object": "wood", "action": "tap", "phase": phase, "trial": trial}
    text["stamp_ns"] = WALL + tick * MS + clock_ns
    message = store.types["std_msgs/msg/String"](data=json.dumps(text))
    return bytes(store.serialize_cdr(message, "std_msgs/msg/String"))


def _session(
    store: Typestore,
    stalls: Stalls,
    sends: Callable[[str, int], bool],
    length: int = LENGTH,
    types: Mapping[str, str] | None = None,
    *,
    trial: int = 1,
    clock_ns: int = 0,
    swap: bool = False,
) -> list[tuple[str, int, bytes]]:
    """Return the session's messages (topic, receive ns, CDR) as a publisher sends them.

    Every tick's messages are sent in topic order and stamped when sent: 10 us apart, no
    earlier than the tick, later after a stall (which holds up everything after it). A
    counted message's ``seq`` counts every message the publisher sent, lost ones included.
    ``clock_ns``: the publisher's clock minus the listener's (its stamps are on its own).
    ``swap``: the execute annotation is sent 1 ms after the end (both rightly stamped).
    """
    types = types or {t: m for t, (m, _) in TOPICS.items()}
    templates = {t: _template(store, types[t]) for t in TOPICS}
    now, out = WALL, []
    for tick in range(length):
        now = max(now, WALL + tick * MS)
        for phase, at in (("execute", EXECUTE), ("end", END)):
            if tick == at:
                annotation = _annotation(store, phase, tick, trial, clock_ns)
                sent = WALL + (END + 2) * MS if swap and phase == "execute" else now + MS
                out.append(("/annotations", sent, annotation))
        for pattern, (_, period) in TOPICS.items():
            for cell in range(CELLS):
                topic = pattern.format(cell=cell)
                if tick % period or not sends(topic, tick):
                    continue
                now += round(stalls.get((tick, topic), 0) * MS) + 10_000
                template = templates[pattern]
                stamp = now + clock_ns
                _STAMP(template, 4, stamp // 1_000_000_000, stamp % 1_000_000_000)
                if types[pattern].endswith("Seq"):
                    template[21] = (tick // period) % 256
                out.append((topic, now + MS // 5, bytes(template)))
    out.sort(key=lambda item: item[1])
    return out


def _listen(
    tmp_path: Path,
    stalls: Stalls,
    sends: Callable[[str, int], bool] = lambda _t, _k: True,
    *,
    lag_ms: int = 0,
    length: int = LENGTH,
    before_finish: list[int] | None = None,
    counted: bool = False,
    notes: list[str] | None = None,
    started_ns: int = WALL,
    clock_ns: int = 0,
    swap: bool = False,
    too_large: tuple[int, ...] = (),
) -> ImportReport:
    """Replay the session through ``listen``'s listener in 50 ms steps; return its report.

    With ``lag_ms``, the listener reads every message that much after it was received (a
    listener held up: its steps' time runs ahead of what its readers took). The session
    lasts ``length`` ms; ``before_finish`` gets the windows written before the run ended.
    ``too_large``: the ticks at which the reader drops a message of /skin/temp_0 for its size.
    """
    topic_map = load_topic_map(_map(tmp_path, counted=counted))
    store = typestore(topic_map)
    listener = Listener(
        topic_map,
        tmp_path / "out",
        load_objects(None),
        load_actions(None),
        journal=False,
        started_ns=started_ns,
        on_note=None if notes is None else notes.append,
    )
    kinds = {p: m for p, (m, _) in TOPICS.items()}
    if counted:
        kinds["/skin/force_{cell}"] = "edge_msgs/msg/Vec3Seq"
    types = {"/annotations": "std_msgs/msg/String"}
    types |= {p.format(cell=c): m for p, m in kinds.items() for c in range(CELLS)}
    listener.prepare(types)
    counts = dict.fromkeys(types, (0, 0, 0))
    items = _session(store, stalls, sends, length, kinds, clock_ns=clock_ns, swap=swap)
    step = WALL
    while step < WALL + (length + 2000) * MS:
        taken = [item for item in items if step <= item[1] + lag_ms * MS < step + 50 * MS]
        step += 50 * MS
        dropped = sum(WALL + tick * MS < step for tick in too_large)
        counts["/skin/temp_0"] = (0, dropped, 9000 if dropped else 0)
        listener.replay(JournalStep(taken, step, dict(counts)))
    if before_finish is not None:
        before_finish.append(listener.session.done)
    return listener.finish()


def _checked(report: ImportReport) -> tuple[str | None, str | None, int, int]:
    """Return the one file's check problem and warning, its missing samples and gaps."""
    assert len(report.written) == 1, (report.written, report.skipped)
    path = report.written[0]
    problem, warning, _ = _check_one(path)
    if problem is not None:
        return problem, warning, -1, -1
    sources = read_recording(path).sources
    return None, warning, sum(s.missing for s in sources), sum(s.gaps for s in sources)


def test_a_steady_publisher_gives_a_file_without_warnings(tmp_path: Path) -> None:
    assert _checked(_listen(tmp_path, {})) == (None, None, 0, 0)


def test_a_trial_recorded_already_is_written_as_the_next_never_dropped(tmp_path: Path) -> None:
    # the lab's system started a new session that numbers its trials from 1 again: live data
    # exists nowhere else, so it is kept under the next free trial (a bag is refused instead)
    first = _listen(tmp_path, {})
    notes: list[str] = []
    again = _listen(tmp_path, {}, notes=notes, started_ns=WALL + 1)  # another run
    out = tmp_path / "out" / "wood" / "tap"
    assert first.written == [out / "001.mcap"]
    assert again.written == [out / "002.mcap"], again.skipped
    assert not again.skipped
    (line,) = [n for n in notes if "trial 1 is recorded in" in n]
    assert line.endswith(f"written as trial 2: {out / '002.mcap'}"), line
    assert read_recording(out / "002.mcap").metadata.trial == 2
    assert _check_one(out / "002.mcap")[0] is None


class _StepClock:
    """The listener's clock, moved by the test (a step's time)."""

    def __init__(self) -> None:
        self.now = WALL

    def now_ns(self) -> int:
        return self.now


def test_the_journal_of_a_skipped_window_is_kept(tmp_path: Path) -> None:
    # annotations the run cannot take (a trial number out of range): the action is skipped
    # with a line, and its messages, which exist nowhere else, stay in the journal
    topic_map = load_topic_map(_map(tmp_path))
    store = typestore(topic_map)
    clock, notes = _StepClock(), list[str]()
    listener = Listener(
        topic_map,
        tmp_path / "out",
        load_objects(None),
        load_actions(None),
        started_ns=WALL,
        clock=clock,  # type: ignore[arg-type]
        on_note=notes.append,
    )
    types = {"/annotations": "std_msgs/msg/String"}
    types |= {p.format(cell=c): m for p, (m, _) in TOPICS.items() for c in range(CELLS)}
    listener.prepare(types)
    listener._open_journal()
    items = _session(store, {}, lambda _t, _k: True, trial=MAX_TRIAL + 1)
    while clock.now < WALL + (LENGTH + 2000) * MS:
        taken = [
            Received(r, (t, raw)) for t, r, raw in items if clock.now <= r < clock.now + 50 * MS
        ]
        listener._take = lambda _wait, taken=taken: taken  # type: ignore[method-assign,misc]
        clock.now += 50 * MS
        listener.step()
    report = listener.finish()
    assert report.written == []
    assert report.skipped, notes
    kept = sorted((tmp_path / "out" / ".listen" / "kept").glob("*.journal.mcap"))
    assert len(kept) == 1, notes
    assert any(line.startswith(f"{kept[0]}: kept, the messages of") for line in notes), notes
    skipped = [line for line in notes if line.startswith("skipped ")]
    assert skipped
    for line in skipped:  # each says where the only copy of its action's messages is
        assert line.endswith(f"its messages are kept in {kept[0].parent}/ (import-bag reads them)")
    with kept[0].open("rb") as stream:  # every message of the session is in it
        topics = [channel.topic for _, channel, _ in make_reader(stream).iter_messages()]
    assert topics.count("/skin/force_0") == LENGTH
    assert topics.count("/annotations") == 2


@pytest.mark.parametrize("late_ms", [1, 6, 20])
def test_a_cell_sent_late_before_the_execute_phase_passes_check(
    tmp_path: Path, late_ms: int
) -> None:
    # held up between cell 0's and cell 1's force of the tick before the execute phase: that
    # tick's row has no cell 1 sample near it, and the ticks after it are stamped late
    problem, _, missing, _ = _checked(_listen(tmp_path, {(EXECUTE - 1, "/skin/force_1"): late_ms}))
    assert problem is None
    assert missing == 0


def test_a_publisher_paused_across_the_end_passes_check_with_a_gap(tmp_path: Path) -> None:
    # held up for 60 ms 20 ticks before the end: every sample it owed before the end is
    # stamped after it, and the force inside the window ends 21 ms early
    problem, warning, missing, gaps = _checked(_listen(tmp_path, {(END - 20, "/skin/force_0"): 60}))
    assert problem is None
    assert warning is not None
    assert "force pauses 0.06" in warning
    assert missing == 0
    assert gaps > 0


def _short(report: ImportReport, notes: list[str]) -> tuple[str, str | None]:
    """Return the line of the one file kept as incomplete, and its check problem."""
    assert report.written == [], report.written
    (path,) = report.incomplete
    assert path.name == "001.incomplete.mcap"
    (line,) = [n for n in notes if n.startswith(f"{path}: kept as incomplete (")]
    return line, _check_one(path)[0]


def test_a_cell_that_stops_before_the_end_is_kept_as_incomplete_with_a_line(
    tmp_path: Path,
) -> None:
    # the file is kept (live data exists nowhere else), and said at once not to cover the
    # action, never written as a success that check then fails
    notes: list[str] = []
    report = _listen(
        tmp_path, {}, lambda topic, tick: topic != "/skin/force_1" or tick < END - 100, notes=notes
    )
    line, problem = _short(report, notes)
    assert "force of /skin/force_1 ends 0.100 s before its execute phase ends" in line
    assert line.endswith("record the action again")
    assert problem is not None


def test_a_publisher_paused_across_the_start_is_counted_as_a_gap(tmp_path: Path) -> None:
    # 30 ms held up just before the execute phase: the pause crosses the window's start, and
    # the window's accounting counts it (the file's skin reaches across the start)
    problem, warning, missing, gaps = _checked(
        _listen(tmp_path, {(EXECUTE - 5, "/skin/force_0"): 30})
    )
    assert problem is None
    assert warning is not None
    assert missing == 0
    assert gaps > 0


def test_a_cell_that_starts_late_is_kept_as_incomplete_with_a_line(tmp_path: Path) -> None:
    # cell 1 begins 30 ms into the execute phase (not late enough to count as a listener
    # that joined part-way): no row has both cells before then
    notes: list[str] = []
    report = _listen(
        tmp_path, {}, lambda topic, tick: topic != "/skin/force_1" or tick >= 530, notes=notes
    )
    line, problem = _short(report, notes)
    assert "begins 0.030 s after its execute phase began" in line
    assert problem is not None


def test_a_listener_held_up_writes_each_window_once_its_samples_came(tmp_path: Path) -> None:
    # every message is read 1.5 s after it arrived, longer than max_delay_s (0.2 s) and the
    # import's margin (1 s) together: the time alone would write the window before the last
    # 0.3 s of its samples were read
    report = _listen(tmp_path, {}, lag_ms=1500)
    assert report.late_samples == {}
    assert _checked(report) == (None, None, 0, 0)


@pytest.mark.parametrize(
    "clock_ns", [-5_000_000_000, 5_000_000_000, -WALL], ids=["behind", "ahead", "sim-time"]
)
def test_stamps_on_another_clock_lose_nothing_and_are_not_late(
    tmp_path: Path, clock_ns: int
) -> None:
    # the lab stamps its messages and annotations on its own clock: 5 s behind or ahead of
    # the listener's, or sim time from 0; the windows are written by the stamps' clock
    notes: list[str] = []
    report = _listen(tmp_path, {}, clock_ns=clock_ns, notes=notes)
    assert report.late_samples == {}
    assert not [n for n in notes if "arrived after" in n], notes
    assert _checked(report) == (None, None, 0, 0)
    (tmp_path / "same").mkdir()
    same = _listen(tmp_path / "same", {})  # the clocks agree: the rows it writes
    rows = read_recording(report.written[0]).skin("force").stamps_ns.size
    assert rows == read_recording(same.written[0]).skin("force").stamps_ns.size


def test_annotations_sent_out_of_order_are_grouped_by_their_stamps(tmp_path: Path) -> None:
    # the lab's system sends the end 1 ms before the execute, both with their stamp_ns: they
    # are put in stamp order within max_delay_s, and the action is written whole
    notes: list[str] = []
    report = _listen(tmp_path, {}, notes=notes, swap=True)
    assert report.skipped == []
    assert report.incomplete == []
    assert not notes, notes
    assert _checked(report) == (None, None, 0, 0)


def test_a_phase_before_the_end_of_another_trial_names_both_trials() -> None:
    grouper = AnnotationGrouper("/annotations")
    grouper.add(("wood", "tap", 1), "execute", 10)
    with pytest.raises(BagImportError, match=r"a phase of wood/tap trial 2 .* of wood/tap trial 1"):
        grouper.add(("wood", "tap", 2), "execute", 20)


def test_messages_too_large_are_counted_in_the_action_they_arrived_in(tmp_path: Path) -> None:
    # one before the action, three in it, one after: the file counts its three, and the run
    # says so once for the action, not once per step
    notes: list[str] = []
    report = _listen(tmp_path, {}, notes=notes, too_large=(100, 600, 700, 800, 1200))
    (path,) = report.written
    sources = {s.name: s for s in read_recording(path).sources}
    assert sources["/skin/temp_0"].malformed == 3
    assert sources["/skin/temp_1"].malformed == 0
    (line,) = [n for n in notes if "larger than" in n]
    assert line.startswith("/skin/temp_0: dropped 5 messages larger than"), line
    assert report.oversize == {"/skin/temp_0": 5}


def test_a_topic_that_stopped_does_not_hold_the_windows(tmp_path: Path) -> None:
    # cell 1's temperature stops for good after the action; the others go on: its window is
    # written while the listener runs (the others' stamps passed it), not only at its end
    written: list[int] = []
    report = _listen(
        tmp_path,
        {},
        lambda topic, tick: topic != "/skin/temp_1" or tick < END + 100,
        length=END + 15_000,
        before_finish=written,
    )
    assert written == [1]
    assert _checked(report)[0] is None


def test_rows_a_missing_cell_leaves_out_are_counted_on_the_topics_that_delivered_them(
    tmp_path: Path,
) -> None:
    # cell 1's force skips every 50th tick: each such row lacks cell 1, and cell 0's sample
    # of it arrived valid but is not written; the file counts it on cell 0's topic
    skipped = {t for t in range(LENGTH) if t % 50 == 7}
    report = _listen(
        tmp_path, {}, lambda topic, tick: topic != "/skin/force_1" or tick not in skipped
    )
    problem, warning, missing, _ = _checked(report)
    assert problem is None
    assert missing == 0
    recording = read_recording(report.written[0])
    sources = {s.name: s for s in recording.sources}
    force = recording.skin("force")
    first, last = (round((int(s) - WALL) / MS) for s in (force.stamps_ns[0], force.stamps_ns[-1]))
    left_out = sources["/skin/force_0"].unaligned
    assert left_out == len(skipped & set(range(first, last + 1))) > 0
    assert (
        force.stamps_ns.size + left_out == last - first + 1
    )  # every cell 0 sample: written or counted
    assert left_out == report.dropped_rows["force"]
    assert sources["/skin/force_1"].unaligned == 0  # it delivered none of those rows
    assert sources["/skin/force_1"].received < sources["/skin/force_0"].received
    assert all(s.unaligned == 0 for name, s in sources.items() if "temp" in name)
    assert warning is not None
    assert f"/skin/force_0: {left_out} left out of the rows" in warning


def test_a_lost_message_of_a_publisher_on_its_grid_is_a_gap_on_its_own_topic(
    tmp_path: Path,
) -> None:
    # the publisher stamps each tick's messages 10-40 us after the tick: on its grid. Two
    # force messages of cell 1 are lost in transport: each is a gap of one period on cell
    # 1's topic (2 periods apart is within the 2.5 periods a jittery publisher needs), and
    # cell 0's samples of those rows are counted as left out; nothing counts as missing
    lost = {640, 820}
    report = _listen(tmp_path, {}, lambda topic, tick: topic != "/skin/force_1" or tick not in lost)
    problem, warning, missing, _ = _checked(report)
    assert problem is None
    assert missing == 0
    sources = {s.name: s for s in read_recording(report.written[0]).sources}
    assert (sources["/skin/force_1"].gaps, sources["/skin/force_1"].gap_ns) == (2, 2 * MS)
    assert sources["/skin/force_0"].gaps == 0
    assert sources["/skin/force_0"].unaligned == 2
    assert warning is not None
    assert "/skin/force_1: 2 gaps (0.002 s paused)" in warning


#: A jittery publisher: held up 0.6 ms at every 7th tick before cell 1's force, so the steps
#: of its stamps are 0.4-1.6 periods, off the period's grid.
JITTER: Stalls = {(tick, "/skin/force_1"): 0.6 for tick in range(0, LENGTH, 7)}


@pytest.mark.parametrize("counted", [False, True])
def test_a_counter_counts_a_jittery_publishers_single_lost_messages_exactly(
    tmp_path: Path, *, counted: bool
) -> None:
    # three single force messages of cell 1 are lost inside the action, none next to a
    # stall: each is a step of about 2 periods, within the 2.5 a jittery publisher needs.
    # Without a counter that loss cannot be told from jitter and is counted nowhere; with
    # the publisher's counter (a uint8 that wraps 5 times in the session) it is counted
    # exactly, as missing, on its own topic, and check fails on it
    lost = {604, 745, 906}
    assert all(tick % 7 not in {0, 1} for tick in lost)
    report = _listen(
        tmp_path,
        JITTER,
        lambda topic, tick: topic != "/skin/force_1" or tick not in lost,
        counted=counted,
    )
    assert len(report.written) == 1
    path = report.written[0]
    sources = {s.name: s for s in read_recording(path).sources}
    force = sources["/skin/force_1"]
    problem, _, _ = _check_one(path)
    if not counted:
        assert (force.basis, force.missing, force.gaps) == ("stamps", 0, 0)
        assert problem is None
        assert report.lost_samples == {}
        return
    assert force.basis == "counter"
    assert (force.missing, force.gaps, force.duplicated, force.counter_resets) == (3, 0, 0, 0)
    # listen says so when it writes the file (the report keeps the line's figures)
    assert report.lost_samples == {path: "/skin/force_1: 3 of 500 missing"}
    # the run's report counts them too, over everything received
    assert report.counted["/skin/force_1"] == {
        "messages": LENGTH - 3,
        "lost": 3,
        "duplicated": 0,
        "resets": 0,
    }
    assert force.received == force.expected - 3
    assert sources["/skin/force_0"].missing == 0
    assert problem is not None
    assert "/skin/force_1" in problem


@pytest.mark.parametrize("where", ["first", "last"])
def test_a_counted_message_lost_at_an_edge_of_the_action_is_the_actions(
    tmp_path: Path, where: str
) -> None:
    # the message lost is the first (or the last) of the window: no message inside shows the
    # jump; the counter of the message next to it outside the window does
    (tmp_path / "all").mkdir()
    (tmp_path / "lost").mkdir()
    report = _listen(tmp_path / "all", {}, counted=True)
    first, last = _window_ticks(report.written[0], "/skin/force_0")
    lost = first if where == "first" else last
    report = _listen(
        tmp_path / "lost",
        {},
        lambda topic, tick: topic != "/skin/force_0" or tick != lost,
        counted=True,
    )
    sources = {s.name: s for s in read_recording(report.written[0]).sources}
    assert sources["/skin/force_0"].missing == 1
    assert sources["/skin/force_1"].missing == 0


def test_a_steady_counted_publisher_gives_a_file_without_warnings(tmp_path: Path) -> None:
    report = _listen(tmp_path, {}, counted=True)
    assert _checked(report) == (None, None, 0, 0)
    sources = read_recording(report.written[0]).sources
    counted = [s for s in sources if s.name.startswith("/skin/force")]
    assert [s.basis for s in counted] == ["counter", "counter"]


def _window_ticks(path: Path, topic: str) -> tuple[int, int]:
    """Return the ticks of the first and last message of ``topic`` counted in a file."""
    source = next(s for s in read_recording(path).sources if s.name == topic)
    return (
        round((source.first_sensor_ns - WALL) / MS),
        round((source.last_sensor_ns - WALL) / MS),
    )
