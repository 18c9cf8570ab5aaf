"""The ``listen`` journal: every message received is on disk within a step, as a ROS 2 MCAP.

``listen`` holds an action's messages in memory until its window is written (its ``end``
plus ``[time] max_delay_s`` plus a second). So that a SIGKILL, an OOM kill or a power loss
in between loses no more than the step in flight, every message of the map's topics (data and
annotations) is also appended, as received (its CDR bytes, the receive time as log time), to
a journal ``<out>/.listen/<UTC start>-<pid>-<n>.journal.mcap``: a ``ros2`` MCAP (a channel
per topic with its ``ros2msg`` schema, ``cdr`` messages), one small zstd chunk per step
(:data:`~recorder.bagimport._listen` steps every 50 ms), handed to the operating system at
the end of every step. A channel of its own (:data:`EVENTS_TOPIC`, JSON in a
``std_msgs/msg/String``) records, per step, the step's time, the readers' counters and each
message they dropped (a full queue, too large) with its receive time and header stamp, and
every recording written; a metadata record (:data:`HEAD_RECORD`) the run's identity, the
topics' types, the topic map's hash and the trial numbers taken so far. With these a journal
replays the run exactly: the same windows, the same files, the same names.

The journal is a staging copy of what ``listen`` writes: when no action is open and every
window that ended is written, the run starts a new journal and removes the old one (all of
whose windows are written). A new journal begins with a *prelude*: the messages of the last
``max_delay_s`` + 2 s again (what a window that begins next may reach back to) and the
accounting so far (the counters, and the drops placed in time that a window may still count),
so that it replays alone as the run went on: every drop is in exactly one step or prelude.
Memory: the chunks go to disk at every step; mcap's writer keeps only one index entry per
chunk (for the summary) until the journal is finished, which the rotation after each action
bounds (actions that follow each other without a pause of ``max_delay_s`` + 1 s grow it until
the next pause).

A running ``listen`` holds an exclusive lock on ``<out>/.listen/lock`` for its lifetime
(:func:`listen_lock`): a second ``listen`` into the same directory would number the same trials
and die on the first name the other took, so it is refused at its start in one line naming
the first. It also holds an exclusive lock on its journal (``fcntl.flock``); a journal
nobody holds was left by a run that died, and the next ``listen`` on the directory (or
``listen --recover``) recovers it and moves it to ``.listen/recovered/``; it is never deleted
there.

A killed run leaves its journal without the MCAP summary and footer, and rosbags (0.11) refuses
such a file ("File end magic is invalid"); :func:`read_journal` therefore walks the records
with mcap's ``StreamReader`` and stops at the first one cut off, which keeps every step whose
chunk reached the disk. The journal lies outside the object/action tree under a hidden
directory, so the dataset's index and ``check`` never take it for a recording.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import struct
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from mcap.exceptions import McapError
from mcap.records import Channel, Message, Metadata
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer
from zstandard import ZstdError

from recorder.errors import BagImportError
from schemas import software_version

if TYPE_CHECKING:
    from collections.abc import Iterable, Iterator, Mapping, Sequence

    from rosbags.typesys.store import Typestore

    from recorder.live import Drop

#: The journals' directory under the output directory (hidden: not part of the dataset).
JOURNAL_DIR = ".listen"
#: Where recovered journals are moved (never deleted).
RECOVERED_DIR = "recovered"
#: Where retired journals go when a run keeps them (``keep_journals``).
KEPT_DIR = "kept"
#: The lock a running ``listen`` holds in :data:`JOURNAL_DIR` (:func:`listen_lock`).
LOCK_NAME = "lock"
#: A journal's file name ends so.
JOURNAL_SUFFIX = ".journal.mcap"
#: The journal's metadata record: the run's identity and what replaying it needs.
HEAD_RECORD = "atikt.listen"
#: The journal's own channel: steps, counters and recordings written (JSON text).
EVENTS_TOPIC = "/atikt_listen/journal"
EVENTS_TYPE = "std_msgs/msg/String"
#: Largest uncompressed chunk, bytes (a step usually ends its chunk first).
CHUNK_BYTES = 256 * 1024


class JournalError(BagImportError):
    """The journal cannot be written (a full disk) or read."""


@dataclass(frozen=True, slots=True)
class JournalHead:
    """What a journal says of its run (its metadata record).

    Attributes:
        started_ns: The run's start (wall clock), part of its recordings' source name.
        domain_id: The DDS domain listened to.
        map_sha256: SHA-256 of the topic map's text.
        types: Topic -> message type of every topic listened to.
        trials: ``object/action`` -> highest trial number taken when the journal began.
    """

    started_ns: int
    domain_id: int
    map_sha256: str
    types: Mapping[str, str]
    trials: Mapping[str, int]

    def to_metadata(self) -> dict[str, str]:
        """Return the metadata record's key-value pairs."""
        return {
            "started_ns": str(self.started_ns),
            "domain_id": str(self.domain_id),
            "map_sha256": self.map_sha256,
            "types": json.dumps(dict(self.types)),  # in the run's order: its files' order
            "trials": json.dumps(dict(self.trials), sort_keys=True),
            "software_version": software_version(),
        }

    @classmethod
    def from_metadata(cls, path: Path, values: Mapping[str, str]) -> JournalHead:
        """Return the head of a journal's metadata record.

        Raises:
            JournalError: The record is not a journal's.
        """
        try:
            return cls(
                int(values["started_ns"]),
                int(values["domain_id"]),
                str(values["map_sha256"]),
                {str(k): str(v) for k, v in json.loads(values["types"]).items()},
                {str(k): int(v) for k, v in json.loads(values["trials"]).items()},
            )
        except (KeyError, ValueError, TypeError, AttributeError) as err:
            msg = f"{path}: not a listen journal ({HEAD_RECORD} record: {err!r}); move it away"
            raise JournalError(msg) from err


def _disk_error(path: Path, err: OSError) -> JournalError:
    """Return the one line of a journal that cannot be written."""
    return JournalError(
        f"{path}: cannot write the journal ({err.strerror or err}); free disk space or give "
        "another --out; the run stops and writes what it can"
    )


@dataclass
class JournalWriter:
    """Appends a run's messages to its journal, a step at a time (holds the journal's lock)."""

    path: Path
    head: JournalHead
    store: Typestore
    _stream: IO[bytes] = field(init=False)
    _writer: Writer = field(init=False)
    _channels: dict[str, int] = field(default_factory=dict, init=False)
    _last_ns: int = field(default=0, init=False)

    @classmethod
    def create(cls, out: Path, head: JournalHead, store: Typestore, serial: int) -> JournalWriter:
        """Start a journal of the run in ``<out>/.listen/`` (the ``serial``-th of the run).

        Raises:
            JournalError: It cannot be created.
        """
        stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(head.started_ns / 1e9))
        name = f"{stamp}-{os.getpid()}-{serial:04d}{JOURNAL_SUFFIX}"
        journal = cls(Path(out) / JOURNAL_DIR / name, head, store)
        journal.open()
        return journal

    def open(self) -> None:
        """Create the file under a temporary name, lock it, write its head, then name it.

        The lock is taken before the journal has its name, so a recovery never sees a
        journal of a running ``listen`` unlocked.

        Raises:
            JournalError: It cannot be created.
        """
        temporary = self.path.with_name(f".{self.path.name}.tmp")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._stream = temporary.open("xb")
            fcntl.flock(self._stream.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            self._writer = Writer(
                self._stream, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD
            )
            self._writer.start(profile="ros2", library=f"atikt/{software_version()}")
            self._writer.add_metadata(HEAD_RECORD, self.head.to_metadata())
            for topic, msgtype in sorted({**self.head.types, EVENTS_TOPIC: EVENTS_TYPE}.items()):
                text, _ = self.store.generate_msgdef(msgtype, ros_version=2)
                schema = self._writer.register_schema(msgtype, "ros2msg", text.encode())
                self._channels[topic] = self._writer.register_channel(topic, "cdr", schema)
            self._writer.flush()  # type: ignore[no-untyped-call]
            temporary.rename(self.path)
        except OSError as err:
            raise _disk_error(self.path, err) from err

    def messages(self, items: Sequence[tuple[str, int, bytes]]) -> None:
        """Append received messages ``(topic, receive ns, CDR bytes)`` in processing order.

        Raises:
            JournalError: The disk is full (or another write error).
        """
        channels, add = self._channels, self._writer.add_message
        try:
            for topic, receive_ns, raw in items:
                channel = channels.get(topic)
                if channel is not None:
                    add(channel, receive_ns, raw, receive_ns)
                    self._last_ns = max(self._last_ns, receive_ns)
        except OSError as err:
            raise _disk_error(self.path, err) from err

    def event(self, now_ns: int, **values: Any) -> None:  # noqa: ANN401
        """Append one event (a step's end, a recording written) and flush the journal.

        Raises:
            JournalError: The disk is full (or another write error).
        """
        text = json.dumps(values, sort_keys=True)
        message = self.store.types[EVENTS_TYPE](data=text)
        raw = bytes(self.store.serialize_cdr(message, EVENTS_TYPE))
        self._last_ns = max(self._last_ns, now_ns)
        try:
            self._writer.add_message(self._channels[EVENTS_TOPIC], self._last_ns, raw, now_ns)
            self._writer.flush()  # type: ignore[no-untyped-call]
        except OSError as err:
            raise _disk_error(self.path, err) from err

    def close(self, retire: Path | None) -> None:
        """Finish the journal (summary and footer); move it to ``retire`` or remove it.

        ``retire`` None removes it: every window it holds is written. A journal that cannot
        be finished (a full disk) is left where it is, for the next run to recover.

        Raises:
            JournalError: It cannot be finished.
        """
        try:
            self._writer.finish()  # type: ignore[no-untyped-call]
            self._stream.close()
        except OSError as err:
            with contextlib.suppress(OSError):
                self._stream.close()
            raise _disk_error(self.path, err) from err
        try:
            if retire is None:
                self.path.unlink()
            else:
                retire.mkdir(parents=True, exist_ok=True)
                self.path.rename(retire / self.path.name)
        except OSError as err:
            raise _disk_error(self.path, err) from err

    def abandon(self) -> None:
        """Close the file without finishing it (after a write error); it stays for recovery."""
        with contextlib.suppress(OSError):
            self._stream.close()


# ----------------------------------------------------------------------------------- read


@dataclass(frozen=True, slots=True)
class JournalStep:
    """One step of a journal: the messages taken, then (if it reached the disk) its end.

    Attributes:
        items: ``(topic, receive ns, CDR bytes)`` in processing order.
        now_ns: The step's time (None: the step was cut off before its end).
        counts: Topic -> (queue overflows, oversize drops, latest oversize bytes) since the
            run's start.
        seen: A journal's prelude: topic -> (overflows, oversize drops) placed in time so far.
        drops: Topic -> (messages its full queue dropped, messages dropped for their size) in
            the step, each ``(receive ns, header stamp or None)`` as its reader read it.
        held: A journal's prelude: topic -> (overflows, oversize drops) placed in time, on the
            windows' clock (ns), that a window still to be written may count.
    """

    items: list[tuple[str, int, bytes]]
    now_ns: int | None
    counts: dict[str, tuple[int, int, int]]
    seen: dict[str, tuple[int, int]] | None = None
    drops: Mapping[str, tuple[Sequence[Drop], Sequence[Drop]]] = field(default_factory=dict)
    held: Mapping[str, tuple[Sequence[int], Sequence[int]]] = field(default_factory=dict)


@dataclass
class JournalContents:
    """A journal read up to its first damaged or missing record."""

    path: Path
    head: JournalHead
    written: set[str] = field(default_factory=set)
    intact: bool = True

    def steps(self) -> Iterator[JournalStep]:
        """Yield the journal's steps in file order (read again: a journal may be large)."""
        items: list[tuple[str, int, bytes]] = []
        for topic, log_ns, raw, event in _messages(self.path):
            if event is None:
                items.append((topic, log_ns, raw))
            elif "now" in event or "prelude" in event:
                counts = {t: (c[0], c[1], c[2]) for t, c in event.get("counts", {}).items()}
                if "prelude" in event:
                    seen = {t: (c[0], c[1]) for t, c in event["seen"].items()}
                    held = {t: (h[0], h[1]) for t, h in event.get("held", {}).items()}
                    yield JournalStep(items, None, counts, seen, held=held)
                else:
                    found = event.get("drops", {})
                    drops = {t: (_drops(d[0]), _drops(d[1])) for t, d in found.items()}
                    yield JournalStep(items, int(event["now"]), counts, drops=drops)
                items = []
        if items:
            yield JournalStep(items, None, {})


def _drops(pairs: Iterable[Sequence[int | None]]) -> list[Drop]:
    """Return a step's drops of one kind from the JSON pairs ``[receive ns, stamp or null]``."""
    return [(int(r or 0), None if s is None else int(s)) for r, s in pairs]


#: What reading a journal cut off (or damaged by a power loss) raises at its end.
_CUT = (McapError, struct.error, EOFError, ValueError, OSError, ZstdError)


def _records(path: Path) -> Iterator[Any]:
    """Yield a journal's records up to the first one cut off or damaged (then stop)."""
    try:
        with path.open("rb") as handle:
            yield from StreamReader(handle, skip_magic=False, validate_crcs=True).records
    except _CUT:  # the journal's cut (or damaged) end: what came before is kept
        return


def _messages(path: Path) -> Iterator[tuple[str, int, bytes, dict[str, Any] | None]]:
    """Yield ``(topic, log ns, bytes, event or None)`` of a journal's intact messages."""
    topics: dict[int, str] = {}
    for record in _records(path):
        if isinstance(record, Channel):
            topics[record.id] = record.topic
        elif isinstance(record, Message) and record.channel_id in topics:
            topic = topics[record.channel_id]
            event = _event(record.data) if topic == EVENTS_TOPIC else None
            yield topic, record.log_time, record.data, event


def _event(raw: bytes) -> dict[str, Any]:
    """Return an event's JSON (a CDR ``std_msgs/String``: 4 bytes header, u32 length, text)."""
    size = int.from_bytes(raw[4:8], "little")
    data = json.loads(raw[8 : 8 + size - 1].decode())
    return data if isinstance(data, dict) else {}


def read_journal(path: Path) -> JournalContents:
    """Read a journal's head and the recordings it says were written.

    Raises:
        JournalError: It has no head (not a journal, or cut before its first record).
    """
    head: JournalHead | None = None
    for record in _records(path):
        if isinstance(record, Metadata) and record.name == HEAD_RECORD:
            head = JournalHead.from_metadata(path, record.metadata)
            break
    if head is None:
        msg = f"{path}: no {HEAD_RECORD} record (cut before it was written, or not a journal)"
        raise JournalError(msg)
    contents = JournalContents(path, head)
    for _, _, _, event in _messages(path):
        if event is not None and "written" in event:
            contents.written.add(str(event["written"]))
    return contents


@contextlib.contextmanager
def held(path: Path) -> Iterator[bool]:
    """Lock a journal for recovery; yield False if a running ``listen`` holds it."""
    with path.open("rb") as handle:
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            yield False
            return
        yield True


@contextlib.contextmanager
def listen_lock(out: Path) -> Iterator[None]:
    """Hold ``<out>/.listen/lock`` for the block: one ``listen`` at a time records into ``out``.

    The kernel releases the lock when the process ends, however it ends (a SIGKILL leaves no
    lock behind). A run that leaves nothing else in ``out`` (it failed at its start) removes
    the lock and the directories it made: it wrote nothing.

    Raises:
        BagImportError: Another process holds it (named), or it cannot be made.
    """
    out = Path(out)
    made = [d for d in (out / JOURNAL_DIR, *(out / JOURNAL_DIR).parents) if not d.exists()]
    path = out / JOURNAL_DIR / LOCK_NAME
    handle = _locked(path, out)
    with handle:
        try:
            yield
        finally:
            handle.seek(0)
            handle.truncate()
            if made and not any(p != path for p in out.rglob("*") if not p.is_dir()):
                with contextlib.suppress(OSError):
                    path.unlink()  # still held: a run starting now makes and locks a new one
                    for directory in made:
                        directory.rmdir()
            fcntl.flock(handle, fcntl.LOCK_UN)


def _locked(path: Path, out: Path) -> IO[str]:
    """Open and lock ``path`` (the lock file of a run that removed it is made again).

    Raises:
        BagImportError: Another process holds it (named), or it cannot be made.
    """
    for _ in range(3):
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            handle = path.open("a+", encoding="utf-8")
        except OSError as err:
            msg = f"{path}: cannot make listen's lock ({err.strerror}); check --out"
            raise BagImportError(msg) from err
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "another process"
            handle.close()
            msg = (
                f"{out}: {holder} records into it already; two would number the same trials: "
                "give this one another --out, or stop the other first"
            )
            raise BagImportError(msg) from None
        if path.exists() and path.stat().st_ino == os.fstat(handle.fileno()).st_ino:
            handle.seek(0)
            handle.truncate()
            started = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
            handle.write(f"listen (pid {os.getpid()}, since {started})")
            handle.flush()
            return handle
        handle.close()  # removed by the run that held it as this one opened it: again
    msg = f"{path}: listen's lock keeps being removed; check what else writes into {out}"
    raise BagImportError(msg)


def left_journals(out: Path) -> list[Path]:
    """Return the journals in ``<out>/.listen/`` (oldest first), held or not."""
    return sorted((Path(out) / JOURNAL_DIR).glob(f"*{JOURNAL_SUFFIX}"))
