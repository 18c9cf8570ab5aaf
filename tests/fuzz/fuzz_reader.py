"""Fuzz the recording reader with mutated committed recordings.

    python tests/fuzz/fuzz_reader.py --mutations 10000 --seed 0

Every mutation of a committed recording (bit flips, byte overwrites, truncation, splices,
insertions and deletions, record length fields set to extreme values, CDR length prefixes
inside messages, the summary section) must end in either a valid recording or the package's
own error (:class:`replay.errors.ReplayError`); every few mutations the salvage
(``atikt-replay check --recover``) runs on the same bytes under the same rule. Anything else
(another exception, a ``MemoryError`` under the address-space limit, a case running longer
than ``--timeout`` seconds) is a failure: the file and its traceback are saved under
``--failures`` and the script exits 1.

Mutations reach every layer because the corpus holds each recording three ways: as committed
(zstd chunks, CRCs), with the data section and summary CRCs zeroed ("not computed" in MCAP,
so a change inside a chunk is caught by the chunk's own CRC or decompression), and re-encoded
without compression or CRCs (so a change inside a message reaches the CDR decoder and the
contract checks). The run is determined by ``--seed``.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import io
import resource
import signal
import struct
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from replay import read_recording
from replay.errors import ReplayError
from replay.recording._salvage import salvage

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator, Sequence
    from types import FrameType

ROOT = Path(__file__).resolve().parents[2]
#: Committed recordings the mutations start from: one per action kind, small ones first.
DEFAULT_FILES = (
    "recordings/data/metal_toolbox/S1/001.mcap",
    "recordings/data/wood/P1/001.mcap",
    "recordings/data/foam_block/C1/001.mcap",
)
_INTERESTING_64 = (0, 1, 2**31, 2**32, 2**62, 2**63 - 1, 2**64 - 1)
_INTERESTING_32 = (0, 1, 3, 2**15, 2**31 - 1, 2**31, 2**32 - 1)
_INTERESTING_BYTES = (0x00, 0x01, 0x7F, 0x80, 0xFF)
_CHUNK, _MESSAGE = 0x06, 0x05  # MCAP opcodes


class Hang(Exception):  # noqa: N818 (a hang, not an error of the code under test)
    """A case ran longer than the time limit."""


@dataclass(frozen=True)
class Seed:
    """One corpus entry: its bytes and where its records are."""

    name: str
    data: bytes
    records: tuple[tuple[int, int], ...]  # (offset, length) of every top-level record
    inner: tuple[tuple[int, int], ...]  # (offset, length) of messages inside plain chunks
    summary_start: int


@dataclass
class Tally:
    """Outcomes of a run."""

    outcomes: collections.Counter[tuple[str, str]] = field(default_factory=collections.Counter)
    errors: collections.Counter[str] = field(default_factory=collections.Counter)
    failures: list[str] = field(default_factory=list)
    slowest: tuple[float, str] = (0.0, "")
    mutations: int = 0


def _top_records(data: bytes, stop: int) -> list[tuple[int, int]]:
    """Return (offset, length) of the records of an intact file's data and summary sections."""
    records, pos = [], 8
    while pos + 9 <= stop:
        (length,) = struct.unpack_from("<Q", data, pos + 1)
        records.append((pos, length))
        pos += 9 + length
    return records


def _inner_messages(data: bytes, records: Sequence[tuple[int, int]]) -> list[tuple[int, int]]:
    """Return (offset, length) of message records inside uncompressed chunks."""
    found = []
    for offset, _ in records:
        if data[offset] != _CHUNK:
            continue
        body = offset + 9
        (name_length,) = struct.unpack_from("<I", data, body + 28)
        start = body + 32 + name_length + 8
        (size,) = struct.unpack_from("<Q", data, start - 8)
        pos = start
        while pos + 9 <= start + size:
            (length,) = struct.unpack_from("<Q", data, pos + 1)
            if data[pos] == _MESSAGE:
                found.append((pos, length))
            pos += 9 + length
    return found


def _seed(name: str, data: bytes) -> Seed:
    footer = len(data) - 8 - 29
    (summary_start,) = struct.unpack_from("<Q", data, footer + 9)
    records = _top_records(data, len(data) - 8)
    return Seed(name, data, tuple(records), tuple(_inner_messages(data, records)), summary_start)


def _zero_crcs(data: bytes) -> bytes:
    """Return ``data`` with the data section and summary CRCs set to 0 (not computed)."""
    out = bytearray(data)
    footer = len(out) - 8 - 29
    (summary_start,) = struct.unpack_from("<Q", out, footer + 9)
    struct.pack_into("<I", out, footer + 25, 0)
    struct.pack_into("<I", out, summary_start - 4, 0)
    return bytes(out)


def _plain(data: bytes) -> bytes:
    """Return the recording re-encoded without compression and without any CRC."""
    reader = make_reader(io.BytesIO(data))
    summary = reader.get_summary()
    if summary is None:  # pragma: no cover (committed recordings have summaries)
        msg = "a committed recording without summary"
        raise ValueError(msg)
    out = io.BytesIO()
    writer = Writer(
        out, compression=CompressionType.NONE, enable_crcs=False, enable_data_crcs=False
    )
    header = reader.get_header()
    writer.start(profile=header.profile, library=header.library)
    for record in reader.iter_metadata():
        writer.add_metadata(record.name, dict(record.metadata))
    ids = {}
    for channel in summary.channels.values():
        schema = summary.schemas[channel.schema_id]
        schema_id = writer.register_schema(schema.name, schema.encoding, schema.data)
        ids[channel.id] = writer.register_channel(channel.topic, "cdr", schema_id)
    for _, channel, message in reader.iter_messages(log_time_order=False):
        writer.add_message(
            ids[channel.id], message.log_time, message.data, message.publish_time, message.sequence
        )
    writer.finish()  # type: ignore[no-untyped-call]
    return out.getvalue()


def load_corpus(files: Sequence[Path]) -> list[Seed]:
    """Return every file as committed, with zeroed CRCs, and re-encoded plainly."""
    corpus = []
    for path in files:
        data = path.read_bytes()
        name = path.relative_to(ROOT).as_posix() if path.is_relative_to(ROOT) else str(path)
        corpus += [
            _seed(f"{name}", data),
            _seed(f"{name} (no CRC)", _zero_crcs(data)),
            _seed(f"{name} (plain)", _plain(data)),
        ]
    return corpus


Mutation = "Callable[[np.random.Generator, Seed, Sequence[Seed]], bytes]"


def _flip_bits(rng: np.random.Generator, seed: Seed, _corpus: Sequence[Seed]) -> bytes:
    data = bytearray(seed.data)
    for _ in range(int(rng.integers(1, 9))):
        data[int(rng.integers(len(data)))] ^= 1 << int(rng.integers(8))
    return bytes(data)


def _overwrite(rng: np.random.Generator, seed: Seed, _corpus: Sequence[Seed]) -> bytes:
    data = bytearray(seed.data)
    for _ in range(int(rng.integers(1, 5))):
        data[int(rng.integers(len(data)))] = int(rng.choice(_INTERESTING_BYTES))
    return bytes(data)


def _truncate(rng: np.random.Generator, seed: Seed, _corpus: Sequence[Seed]) -> bytes:
    return seed.data[: int(rng.integers(len(seed.data)))]


def _splice(rng: np.random.Generator, seed: Seed, corpus: Sequence[Seed]) -> bytes:
    """Copy a block of another (or the same) file over, into, or out of this one."""
    other = corpus[int(rng.integers(len(corpus)))].data
    size = int(rng.integers(1, 4096))
    start = int(rng.integers(max(len(other) - size, 1)))
    block = other[start : start + size]
    at = int(rng.integers(len(seed.data)))
    kind = int(rng.integers(3))
    if kind == 0:
        return seed.data[:at] + block + seed.data[at + len(block) :]
    if kind == 1:
        return seed.data[:at] + block + seed.data[at:]
    return seed.data[:at] + seed.data[at + size :]


def _length(rng: np.random.Generator, seed: Seed, _corpus: Sequence[Seed]) -> bytes:
    """Set a record's length field to an extreme or slightly wrong value."""
    offset, length = seed.records[int(rng.integers(len(seed.records)))]
    choices = (*_INTERESTING_64, length - 1, length + 1, length + 9, len(seed.data), 10**12)
    value = int(choices[int(rng.integers(len(choices)))]) % 2**64
    data = bytearray(seed.data)
    struct.pack_into("<Q", data, offset + 1, value)
    return bytes(data)


def _inner(rng: np.random.Generator, seed: Seed, corpus: Sequence[Seed]) -> bytes:
    """Change a message inside a chunk: its record length or a 32-bit word of its payload."""
    if not seed.inner:
        return _flip_bits(rng, seed, corpus)
    offset, length = seed.inner[int(rng.integers(len(seed.inner)))]
    data = bytearray(seed.data)
    if rng.random() < 1 / 4:  # a quarter of the cases: the record length
        struct.pack_into("<Q", data, offset + 1, int(rng.choice(_INTERESTING_64[:4])) + length)
    else:  # a length prefix, count or stamp of the CDR payload (4-byte aligned from its start)
        payload = offset + 9 + 22
        words = max((length - 22) // 4, 1)
        word = payload + 4 * int(rng.integers(words))
        value = int(rng.choice((*_INTERESTING_32, int(rng.integers(2**32)))))
        struct.pack_into("<I", data, min(word, len(data) - 4), value)
    return bytes(data)


def _summary(rng: np.random.Generator, seed: Seed, _corpus: Sequence[Seed]) -> bytes:
    """Overwrite bytes of the summary section (statistics, indexes, offsets)."""
    data = bytearray(seed.data)
    start = seed.summary_start or len(data) - 45
    for _ in range(int(rng.integers(1, 4))):
        at = int(rng.integers(start, len(data) - 8))
        data[at] = int(rng.integers(256))
    return bytes(data)


MUTATIONS: dict[str, Callable[[np.random.Generator, Seed, Sequence[Seed]], bytes]] = {
    "bit flips": _flip_bits,
    "byte overwrite": _overwrite,
    "truncation": _truncate,
    "splice": _splice,
    "record length": _length,
    "inside a message": _inner,
    "summary": _summary,
}


@contextlib.contextmanager
def _time_limit(seconds: float) -> Iterator[None]:
    """Raise :class:`Hang` in the block after ``seconds`` (SIGALRM; main thread only)."""

    def alarm(_signum: int, _frame: FrameType | None) -> None:
        raise Hang

    previous = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def _first_words(message: str) -> str:
    """Return an error message without the file name and numbers: its kind."""
    text = message.split(": ", 1)[-1].removeprefix("not a valid MCAP recording (")
    words = [w for w in text.replace("(", " ").split() if not any(c.isdigit() for c in w)]
    return " ".join(words[:6])


def _attempt(
    run: Callable[[], object], timeout: float, tally: Tally, label: str, what: str
) -> float:
    """Run one case; record its outcome; return its duration."""
    start = time.perf_counter()
    try:
        with _time_limit(timeout):
            run()
        outcome = "valid"
    except ReplayError as err:
        outcome = "refused"
        tally.errors[f"{what}: {_first_words(str(err))}"] += 1
    except Hang:
        outcome = "HANG"
        tally.failures.append(f"{label}: {what} ran longer than {timeout} s")
    except Exception:  # noqa: BLE001 (any other exception is what the fuzzer looks for)
        outcome = "FAILED"
        tally.failures.append(f"{label}: {what}\n{traceback.format_exc()}")
    tally.outcomes[(what, outcome)] += 1
    return time.perf_counter() - start


def fuzz(
    mutations: int,
    seed: int,
    files: Sequence[Path] | None = None,
    *,
    timeout: float = 10.0,
    salvage_every: int = 5,
    failures: Path | None = None,
) -> Tally:
    """Run ``mutations`` seeded mutations through the reader (and every few, the salvage).

    Args:
        mutations: Number of mutated files.
        seed: Seed of every random choice.
        files: Recordings to mutate (default :data:`DEFAULT_FILES`).
        timeout: Longest time one case may take, s.
        salvage_every: Salvage every this many mutated files too (0: never).
        failures: Where to save failing files (not saved when None).

    Returns:
        The outcomes.
    """
    corpus = load_corpus([ROOT / f for f in DEFAULT_FILES] if files is None else files)
    rng = np.random.default_rng(seed)
    names = list(MUTATIONS)
    tally = Tally()
    with tempfile.TemporaryDirectory() as work:
        path, target = Path(work) / "001.mcap", Path(work) / "001.recovered.mcap"
        for index in range(mutations):
            base = corpus[int(rng.integers(len(corpus)))]
            kind = names[int(rng.integers(len(names)))]
            data = MUTATIONS[kind](rng, base, corpus)
            path.write_bytes(data)
            label = f"#{index} {kind} of {base.name}"
            before = len(tally.failures)
            took = _attempt(lambda: read_recording(path), timeout, tally, label, "read")
            tally.slowest = max(tally.slowest, (took, label))
            if salvage_every and index % salvage_every == 0:
                _attempt(lambda: salvage(path, target), timeout, tally, label, "salvage")
                target.unlink(missing_ok=True)
            if failures is not None and len(tally.failures) > before:
                failures.mkdir(parents=True, exist_ok=True)
                (failures / f"case{index}.mcap").write_bytes(data)
                (failures / f"case{index}.txt").write_text("\n\n".join(tally.failures[before:]))
            tally.mutations += 1
    return tally


def _print(tally: Tally, seconds: float) -> None:
    each = seconds / max(tally.mutations, 1) * 1e3
    print(f"{tally.mutations} mutations in {seconds:.1f} s ({each:.1f} ms each)")
    for (what, outcome), count in sorted(tally.outcomes.items()):
        print(f"  {what:8s} {outcome:8s} {count:6d}")
    print(f"slowest case: {tally.slowest[0] * 1e3:.0f} ms ({tally.slowest[1]})")
    print("most frequent refusals:")
    for reason, count in tally.errors.most_common(12):
        print(f"  {count:6d}  {reason}")
    print(f"failures: {len(tally.failures)}")
    for failure in tally.failures[:5]:
        print(failure)


def _limit_memory(megabytes: int) -> None:
    """Cap the address space, so an unbounded allocation fails as a MemoryError (a failure)."""
    if megabytes > 0:
        limit = megabytes * 2**20
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))


def main(argv: Sequence[str] | None = None) -> int:
    """Run the fuzzer from the command line; exit 1 on any failure."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mutations", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--timeout", type=float, default=10.0, help="seconds per case")
    parser.add_argument("--salvage-every", type=int, default=5, help="0: never salvage")
    parser.add_argument("--memory-limit-mb", type=int, default=4096, help="0: no limit")
    parser.add_argument("--failures", type=Path, default=Path("fuzz-failures"))
    parser.add_argument("files", nargs="*", type=Path, help="recordings to mutate")
    args = parser.parse_args(argv)
    _limit_memory(args.memory_limit_mb)
    start = time.perf_counter()
    tally = fuzz(
        args.mutations,
        args.seed,
        args.files or None,
        timeout=args.timeout,
        salvage_every=args.salvage_every,
        failures=args.failures,
    )
    _print(tally, time.perf_counter() - start)
    return 1 if tally.failures else 0


if __name__ == "__main__":
    sys.exit(main())
