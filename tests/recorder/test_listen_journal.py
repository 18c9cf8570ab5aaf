"""``listen``'s journal: a SIGKILL loses at most the step in flight, a rerun recovers it.

A scripted session published over DDS is recorded with its journals kept; replaying a journal
into an empty directory writes the same bytes as the run did, also from a journal cut at any
offset (the windows whose bytes are intact). Against the virtual lab, a ``listen`` process
is killed after an action's ``end`` arrived (before its window was written) and while the next
action is open; a rerun recovers both.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import forked
import pytest

pytest.importorskip("cyclonedds")

import ddsdata
import zstandard
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.stream_reader import StreamReader
from test_listen_live import _announce, _map, _play, _served

from recorder import load_actions, load_objects
from recorder.bagimport._journal import (
    EVENTS_TOPIC,
    JOURNAL_DIR,
    JOURNAL_SUFFIX,
    KEPT_DIR,
    _event,
    _messages,
    listen_lock,
    read_journal,
)
from recorder.bagimport._listen import listen, recover
from recorder.bagimport._source import typestore
from recorder.bagimport._topicmap import load_topic_map
from recorder.live.dds import DdsDomain
from replay.cli._main import main as replay_main
from schemas import dataset_recordings, is_incomplete

if TYPE_CHECKING:
    from recorder.bagimport._report import ImportReport
    from recorder.bagimport._topicmap import TopicMap

ROOT = Path(__file__).parents[2]


@pytest.fixture(scope="module")
def kept(
    module_dds_domain: int, tmp_path_factory: pytest.TempPathFactory
) -> tuple[ImportReport, TopicMap, list[Path]]:
    """Record the scripted session with ``listen``, keeping its journals."""
    root = tmp_path_factory.mktemp("journal")
    map_path = root / "map.toml"
    map_path.write_text(ddsdata.TOPIC_MAP, encoding="utf-8")
    topic_map = load_topic_map(map_path)
    store = typestore(topic_map)
    publisher = DdsDomain(module_dds_domain, store)
    stop = threading.Event()
    result: dict[str, Any] = {}

    def run() -> None:
        result["live"] = listen(
            topic_map,
            root / "live",
            objects=load_objects(None),
            actions=load_actions(None),
            domain_id=module_dds_domain,
            stop=stop,
            discovery_s=5.0,
            keep_journals=True,
        )

    thread = threading.Thread(target=run)
    thread.start()
    ddsdata.publish(publisher, ddsdata.script(store))
    stop.set()
    thread.join(20)
    journals = sorted((root / "live" / JOURNAL_DIR / KEPT_DIR).glob(f"*{JOURNAL_SUFFIX}"))
    return result["live"], topic_map, journals


def _recover(topic_map: TopicMap, journals: list[Path], out: Path, cut: int | None = None) -> Any:
    """Place journals (the last cut at ``cut`` bytes) in ``out/.listen`` and recover them."""
    place = out / JOURNAL_DIR
    place.mkdir(parents=True)
    for journal in journals:
        data = journal.read_bytes()
        if cut is not None and journal == journals[-1]:
            data = data[:cut]
        (place / journal.name).write_bytes(data)
    notes: list[str] = []
    done = recover(
        topic_map, out, objects=load_objects(None), actions=load_actions(None), on_note=notes.append
    )
    return done, notes


def test_a_journal_replays_into_the_same_bytes(
    kept: tuple[ImportReport, TopicMap, list[Path]], tmp_path: Path
) -> None:
    live, topic_map, journals = kept
    assert len(live.written) == len(ddsdata.WINDOWS)
    assert journals, "no journal kept"
    assert not list((live.out / JOURNAL_DIR).glob(f"*{JOURNAL_SUFFIX}"))  # retired at the end
    out = tmp_path / "out"
    done, notes = _recover(topic_map, journals, out)
    written = [p for r in done for p in r.written]
    already = [p for r in done for p in r.already]
    # the journal says the run wrote them: a recovery never writes them again
    assert [p.relative_to(out) for p in already] == [p.relative_to(live.out) for p in live.written]
    assert written == []
    assert len(notes) == len(journals)
    assert all(
        line.endswith(f"journal moved to {r.journal}") for line, r in zip(notes, done, strict=True)
    )
    # without the run's files nor its marks, the replay writes the run's bytes
    bare = tmp_path / "bare"
    stripped = [_without_written(j, tmp_path / "stripped") for j in journals]
    done, _ = _recover(topic_map, stripped, bare)
    written = [p for r in done for p in r.written]
    assert [p.relative_to(bare) for p in written] == [p.relative_to(live.out) for p in live.written]
    for mine, theirs in zip(written, live.written, strict=True):
        assert mine.read_bytes() == theirs.read_bytes(), mine


def _without_written(journal: Path, where: Path) -> Path:
    """Return a copy of a journal without its 'written' events (chunked per step, as it was)."""
    from mcap.writer import Writer  # noqa: PLC0415

    where.mkdir(exist_ok=True)
    target = where / journal.name
    with journal.open("rb") as source, target.open("wb") as sink:
        reader = make_reader(source)
        header = reader.get_header()
        writer = Writer(sink)
        writer.start(header.profile, header.library)
        for record in reader.iter_metadata():
            writer.add_metadata(record.name, dict(record.metadata))
        ids: dict[int, int] = {}
        schemas: dict[int, int] = {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if channel.topic == EVENTS_TOPIC and "written" in _event(message.data):
                continue
            if channel.id not in ids:
                if schema is not None and schema.id not in schemas:
                    schemas[schema.id] = writer.register_schema(
                        schema.name, schema.encoding, schema.data
                    )
                sid = schemas[schema.id] if schema is not None else 0
                ids[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, sid
                )
            writer.add_message(
                ids[channel.id], message.log_time, message.data, message.publish_time
            )
            if channel.topic == EVENTS_TOPIC:
                writer.flush()  # type: ignore[no-untyped-call]  # a chunk per step, as the run
        writer.finish()  # type: ignore[no-untyped-call]
    return target


def test_a_journal_cut_anywhere_recovers_every_intact_window(
    kept: tuple[ImportReport, TopicMap, list[Path]], tmp_path: Path
) -> None:
    live, topic_map, journals = kept
    journal = _without_written(journals[-1], tmp_path / "stripped")
    full = list(_messages(journal))
    size = journal.stat().st_size
    ends = _end_annotations(full)
    steps = [i for i, (_, _, _, event) in enumerate(full) if event and "now" in event]
    written_at = _written_steps(journals[-1], live)
    cases: set[str] = set()
    # even offsets, and those just past each window's 'end' (before its window was written)
    cuts = [60, 400, *(size * f // 12 for f in range(1, 12)), size - 7]
    cuts += [_cut_after(journal, end, tmp_path / "probe.mcap") for end in ends]
    for k, cut in enumerate(cuts):
        out = tmp_path / f"cut{k}"
        placed = out / JOURNAL_DIR / journal.name
        placed.parent.mkdir(parents=True)
        placed.write_bytes(journal.read_bytes()[:cut])
        intact = list(_messages(placed))
        assert intact == full[: len(intact)], cut  # a cut journal is a prefix of the whole
        done = recover(topic_map, out, objects=load_objects(None), actions=load_actions(None))
        assert len(done) <= 1  # a journal cut before its head is left where it is
        files = {p.relative_to(out) for p in dataset_recordings(out)}
        for window, theirs in enumerate(live.written):
            name = theirs.relative_to(live.out)
            if len(intact) > steps[written_at[window]]:  # all its messages reached the disk
                assert (out / name).read_bytes() == theirs.read_bytes(), (cut, name)
                cases.add("same bytes")
                print("SAME", cut, len(intact), window, steps[written_at[window]])
            elif len(intact) > ends[window]:  # its end came: recorded, maybe shorter
                assert name in files or list((out / name.parent).glob("*.incomplete.mcap"))
                cases.add("end intact")
            else:
                assert name not in files
                cases.add("end lost")
    assert cases == {"same bytes", "end intact", "end lost"}


def _cut_after(journal: Path, index: int, probe: Path) -> int:
    """Return the shortest prefix of a journal in which message ``index`` is intact."""
    data = journal.read_bytes()
    lo, hi = 0, len(data)
    while lo < hi:
        mid = (lo + hi) // 2
        probe.write_bytes(data[:mid])
        if sum(1 for _ in _messages(probe)) > index:
            hi = mid
        else:
            lo = mid + 1
    return lo


def _end_annotations(full: list[tuple[str, int, bytes, Any]]) -> list[int]:
    """Return the index of every window's 'end' annotation in a journal's messages."""
    return [
        i
        for i, (topic, _, raw, _) in enumerate(full)
        if topic == "/annotations" and json.loads(_event_text(raw))["phase"] == "end"
    ]


def _event_text(raw: bytes) -> str:
    size = int.from_bytes(raw[4:8], "little")
    return raw[8 : 8 + size - 1].decode()


def _written_steps(journal: Path, live: ImportReport) -> list[int]:
    """Return, per recording of the run, the index of the step in which it was written."""
    step = -1
    found: dict[str, int] = {}
    for _, _, _, event in _messages(journal):
        if event and "now" in event:
            step += 1
        elif event and "written" in event:
            found[event["written"]] = step
    return [found[p.relative_to(live.out).as_posix()] for p in live.written]


def test_a_full_disk_stops_the_run_in_one_line_and_keeps_the_journal(
    dds_domain: int, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import errno  # noqa: PLC0415

    from recorder.bagimport import _journal  # noqa: PLC0415

    map_path = tmp_path / "map.toml"
    map_path.write_text(ddsdata.TOPIC_MAP, encoding="utf-8")
    topic_map = load_topic_map(map_path)
    store = typestore(topic_map)
    original = _journal.JournalWriter.messages
    calls: list[int] = []

    def full(self: Any, items: Any) -> None:
        # the disk fills on the very messages that bring the first action's 'end': they are
        # not in the journal, yet they arrived, and the action is written from memory
        if calls or any(topic == "/annotations" and b'"end"' in raw for topic, _, raw in items):
            calls.append(len(items))
            err = OSError(errno.ENOSPC, "No space left on device")
            raise _journal._disk_error(self.path, err) from err
        original(self, items)

    monkeypatch.setattr(_journal.JournalWriter, "messages", full)
    notes: list[str] = []
    result: dict[str, Any] = {}
    out = tmp_path / "out"

    def run() -> None:
        result["report"] = listen(
            topic_map,
            out,
            objects=load_objects(None),
            actions=load_actions(None),
            domain_id=dds_domain,
            duration_s=20.0,
            discovery_s=5.0,
            on_note=notes.append,
        )

    thread = threading.Thread(target=run)
    thread.start()
    ddsdata.publish(DdsDomain(dds_domain, store), ddsdata.script(store))
    thread.join(20)
    assert not thread.is_alive(), "the run went on after the journal failed"
    report = result["report"]
    errors = [line for line in notes if "cannot write the journal" in line]
    assert len(errors) == 1, notes
    assert "No space left on device" in errors[0]
    assert report.interrupted == "the journal's write error"
    # the run stopped in the second action: the first written, what came after not received
    assert [p.relative_to(out).as_posix() for p in report.written] == ["wood/tap/001.mcap"]
    # then the journal is set aside (never removed): all it holds is written
    assert _journals(out) == []
    assert len(list((out / JOURNAL_DIR / "recovered").glob(f"*{JOURNAL_SUFFIX}"))) == 1


def test_journals_are_not_recordings_of_the_dataset(tmp_path: Path) -> None:
    recording = tmp_path / "wood" / "S1" / "001.mcap"
    for path in (
        recording,
        tmp_path / JOURNAL_DIR / f"20260101T000000Z-1-0001{JOURNAL_SUFFIX}",
        tmp_path / JOURNAL_DIR / "recovered" / f"20260101T000000Z-1-0001{JOURNAL_SUFFIX}",
    ):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"")
    assert dataset_recordings(tmp_path) == [recording]


# ------------------------------------------------------------------- SIGKILL, virtual lab


def _listen(map_path: Path, out: Path, domain: int, *extra: str) -> subprocess.Popen[str]:
    """Start ``atikt-record listen`` (this checkout) in a process."""
    command = [sys.executable, "-m", "recorder", "listen", "--topic-map", str(map_path)]
    command += ["--out", str(out), "--domain-id", str(domain), *extra]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return forked.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _line(process: subprocess.Popen[str], wanted: str, timeout_s: float = 15.0) -> str:
    """Return the process's next stdout line containing ``wanted`` (lines are read in order)."""
    assert process.stdout is not None
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = process.stdout.readline()
        if wanted in line:
            return line.strip()
        assert line, (
            f"listen ended before {wanted!r}: {process.stderr.read() if process.stderr else ''}"
        )
    raise AssertionError(wanted)


def _play_after(world: Any, server: Any, action: str, trial: int) -> None:
    """Play an action and return once its 'end' was published."""
    before = len(server.annotated)
    _play(world, action, trial)
    # a hang guard (90 s of 20 ms waits: a loaded machine's virtual lab plays slowly)
    for _ in range(4500):
        if any(json.loads(t)["phase"] == "end" for _, t in server.annotated[before:]):
            break
        time.sleep(0.02)
    else:
        pytest.fail("the server announced no end")


def _journals(out: Path) -> list[str]:
    return sorted(p.name for p in (out / JOURNAL_DIR).glob(f"*{JOURNAL_SUFFIX}"))


def _journaled(out: Path, text: bytes, since_ns: int) -> bool:
    """Whether a live journal holds a message containing ``text`` logged at ``since_ns`` or later.

    Only the chunks logged since then are decompressed: parsing a whole journal in the test's
    process four times a second would slow the virtual lab's publisher in that process.
    """
    for path in (out / JOURNAL_DIR).glob(f"*{JOURNAL_SUFFIX}"):
        try:
            with path.open("rb") as handle:
                for record in StreamReader(handle, skip_magic=False, emit_chunks=True).records:
                    if isinstance(record, Chunk) and record.message_end_time >= since_ns:
                        data = (
                            zstandard.ZstdDecompressor().decompress(
                                record.data, max_output_size=record.uncompressed_size
                            )
                            if record.compression
                            else record.data
                        )
                        if text in data:
                            return True
        except (OSError, McapError, zstandard.ZstdError):  # cut mid-write, rotated: look again
            continue
    return False


def _kill_after_an_end(map_path: Path, out: Path, domain: int) -> tuple[str, int, bool]:
    """Listen to two actions and the start of a third; SIGKILL it once that start is journaled.

    Returns:
        The journal's name after the first action, the time of the kill (ns), and whether the
        listener had written the second action before the kill.
    """
    with _served(map_path, domain, 100, listen_process=True) as (world, server):
        process = _listen(map_path, out, domain)
        try:
            _line(process, "listening on DDS domain")
            first = _journals(out)
            assert len(first) == 1
            _play_after(world, server, "S1", 1)
            written = _line(process, "S1", 30.0)  # the first action's recording
            time.sleep(0.2)
            # rotation: the journal of the written action is gone, a new one holds what follows,
            # nothing else is removed
            second = _journals(out)
            assert len(second) == 1
            assert second != first
            assert second[0].endswith(f"-0002{JOURNAL_SUFFIX}")
            assert [p.name for p in (out / JOURNAL_DIR).iterdir() if p.name != "lock"] == second
            assert Path(written).exists()
            _play_after(world, server, "S1", 2)  # its end arrives ...
            opened_ns = time.time_ns()
            _announce(world, "P1", 1, "approach")  # ... and the next action opens at once
            for _ in range(240):  # a hang guard (60 s of 250 ms waits), not a time check
                if _journaled(out, b'"action": "P1"', opened_ns):
                    break
                time.sleep(0.25)  # every chunk record is scanned: not too often
            else:
                pytest.fail("the listener journaled no 'approach'")
            killed_ns = time.time_ns()
            process.send_signal(signal.SIGKILL)
            process.wait(10)
            ends = [stamp for stamp, text in server.annotated if json.loads(text)["phase"] == "end"]
            print(f"killed {(killed_ns - ends[-1]) / 1e9:.2f} s after the last end's stamp")
        finally:
            if process.poll() is None:
                process.kill()
            process.communicate(timeout=10)  # reaps it and closes its pipes
    return second[0], killed_ns, (out / "wood" / "S1" / "002.mcap").exists()


@pytest.mark.slow(12)
def test_sigkill_after_an_end_then_a_rerun_recovers(dds_domain: int, tmp_path: Path) -> None:
    # a window is written once every topic sent samples stamped max_delay_s + 1 s past its
    # end: 5 s here, and the next action opens at once, so the listener is killed before
    # writing the second action, unless a loaded machine's virtual lab published that action's
    # 'end' seconds late and then caught up. Either way, after the rerun every action that
    # ended is there once and the open one is kept as incomplete; the journal cut-anywhere
    # test above covers the recovery of an ended action deterministically
    map_path = _map(tmp_path, max_delay_s="4.0")
    out = tmp_path / "out"
    name, killed_ns, before = _kill_after_an_end(map_path, out, dds_domain)
    print(f"the second action was {'written' if before else 'not written'} before the kill")
    expected = ["001.mcap", "002.mcap"] if before else ["001.mcap"]
    assert sorted(p.name for p in (out / "wood" / "S1").iterdir()) == expected
    live = _journals(out)
    # a written action's journal is retired (a kill may come between the two steps)
    assert live == [name] if not before else name not in live[-1:]
    journal = out / JOURNAL_DIR / live[-1]
    contents = read_journal(journal)
    assert contents.head.types
    last = max(log_ns for topic, log_ns, _, _ in _messages(journal) if topic != EVENTS_TOPIC)
    print(f"journal: the SIGKILL lost the last {(killed_ns - last) / 1e6:.0f} ms")
    rerun = _listen(map_path, out, dds_domain, "--recover")
    stdout, stderr = rerun.communicate(timeout=60)
    assert rerun.returncode == 0, stderr
    assert "Traceback" not in stderr
    lines = stdout.splitlines()
    recovered_lines = [line for line in lines if "recovered" in line and "actions" in line]
    assert len(recovered_lines) == len(live), stdout
    assert sum(f"recovered {0 if before else 1} actions" in line for line in recovered_lines)
    assert sum("1 kept as incomplete" in line for line in recovered_lines) == 1, stdout
    recovered = out / "wood" / "S1" / "002.mcap"
    assert recovered.exists(), stdout
    assert replay_main(["check", str(recovered)]) == 0
    kept = list((out / "wood" / "P1").glob("*.incomplete.mcap"))
    assert len(kept) == 1
    assert is_incomplete(kept[0])
    assert all((out / JOURNAL_DIR / "recovered" / n).exists() for n in live)
    assert _journals(out) == []
    assert replay_main(["check", str(out)]) == 0
    # a second recovery finds nothing to do
    topic_map = load_topic_map(map_path)
    assert recover(topic_map, out, objects=load_objects(None), actions=load_actions(None)) == []


def test_a_second_listen_into_the_same_out_is_refused_at_its_start(
    dds_domain: int, tmp_path: Path
) -> None:
    # two runs into one --out would number the same trials, and one would die mid-run on a
    # name the other took: the second is refused at once, in one line naming the first
    map_path, out = _map(tmp_path), tmp_path / "out"
    first = _listen(map_path, out, dds_domain)
    try:
        lock = out / JOURNAL_DIR / "lock"
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline and not (
            lock.is_file() and lock.read_text(encoding="utf-8")
        ):
            time.sleep(0.05)
        second = _listen(map_path, out, dds_domain)
        _, err = second.communicate(timeout=30)
        recovering = _listen(map_path, out, dds_domain, "--recover")
        _, err_recover = recovering.communicate(timeout=30)
    finally:
        first.terminate()
        first.communicate(timeout=30)
    for process, text in ((second, err), (recovering, err_recover)):
        assert process.returncode == 1, text
        (line,) = text.splitlines()
        assert f"listen (pid {first.pid}, since " in line, line
        assert "records into it already" in line, line
        assert "delete" not in line
    with listen_lock(out):  # released when the first ended
        pass
