"""The accounting of a live recording's sources: a metadata record every reader understands.

A live recording says, per source (the arm's state stream, the skin's links, ROS 2 topics),
how many samples the source sent in the recording's span (from its sequence counter or its
clock) and how many of them arrived once, twice, late or never, and how the source's clock
relates to the recorder's. The recorder writes it (``atikt.sources``); ``atikt-replay info``
shows it and ``check`` warns where anything is missing.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping, Sequence

#: Name of the MCAP metadata record that holds the per-source counts of a live recording.
SOURCES_RECORD = "atikt.sources"


@dataclass(frozen=True, slots=True)
class SourceStats:
    """The accounting of one source over one recording.

    Attributes:
        name: The source (``rtde``, ``skin``, a topic...).
        basis: What ``expected`` comes from: ``counter`` (sequence numbers), ``clock``
            (the source's timestamps and its nominal period: a controller's cycle clock), or
            ``stamps`` (a source without a sequence: its pauses are measured as ``gaps``
            against its period, and ``expected`` is what arrived).
        expected: Samples the source sent in the span from its first to its last received one.
        received: Samples that arrived (duplicates included).
        missing: Expected samples that never arrived (lost in transport or dropped by a full
            queue).
        duplicated: Samples that arrived more than once (the copies).
        out_of_order: Samples that arrived after a later one.
        overflowed: Samples the reader's queue could not hold (also counted in ``missing``).
        period_ns: The source's nominal sample period, ns (0: unknown).
        first_sensor_ns: Sensor time of the first sample, on the source's clock, ns.
        last_sensor_ns: Sensor time of the last sample, on the source's clock, ns.
        first_receive_ns: Receive time of the first sample, on the recorder's clock, ns.
        last_receive_ns: Receive time of the last sample, on the recorder's clock, ns.
        clock_offset_ns: Recorder time minus source time, from the lowest-latency samples of
            the first second (sensor stamp + offset = recorder time of the measurement).
        clock_drift_ns: How much that offset changed by the last second of the recording.
        latency_max_ns: Largest receive delay beyond the offset, ns.
        malformed: Frames or packets that could not be parsed (wrong sync bytes, length,
            type or recipe; a serial stream's sync losses) or held a NaN or infinite value;
            none of them is written, and where the source's counter covers them their
            samples are counted in ``missing``.
        out_of_range: Samples whose stamp left the source's plausible range (ahead of the
            time they arrived, or far behind it, given the source's clock offset and drift so
            far); never written, and they never shift or cut the series.
        counter_resets: Times the source's counter or clock jumped or ran backwards and a new
            run began (``expected`` is the sum over the runs).
        gaps: Pauses of a source without a sequence (``basis`` ``stamps``): steps between
            stamps longer than the period with its tolerance. A pause is the publisher's; it
            is not counted as missing samples.
        gap_ns: The pauses' total length beyond one period each, ns.
        unaligned: Stamps of this source that arrived valid but are not in the file: a skin
            whose cells come in separate messages is written in rows, one sample of every
            cell per row, and these stamps' row lacked another cell's sample within half a
            period (or repeated the previous row's stamp). Counted where the rows are made;
            the samples of the cell that had none are the other source's ``missing`` or
            ``gaps``, not these.
        origin: Where the samples came from, as learned while recording: a UDP skin's
            sender, ``host:port`` of the datagrams taken (without ``[skin] sender``, the first
            address that sent a valid frame); '' where the configuration says it all.
    """

    name: str
    basis: str = "counter"
    expected: int = 0
    received: int = 0
    missing: int = 0
    duplicated: int = 0
    out_of_order: int = 0
    overflowed: int = 0
    period_ns: int = 0
    first_sensor_ns: int = 0
    last_sensor_ns: int = 0
    first_receive_ns: int = 0
    last_receive_ns: int = 0
    clock_offset_ns: int = 0
    clock_drift_ns: int = 0
    latency_max_ns: int = 0
    malformed: int = 0
    out_of_range: int = 0
    counter_resets: int = 0
    gaps: int = 0
    gap_ns: int = 0
    unaligned: int = 0
    origin: str = ""

    @property
    def complete(self) -> bool:
        """Whether every expected sample arrived exactly once and in order."""
        return not (self.lost or self.warnings())

    @property
    def lost(self) -> int:
        """Samples the source sent that the recording lacks (counted loss)."""
        return max(self.missing, self.overflowed)

    def loss(self) -> str:
        """Return the counted loss, e.g. ``3 of 7500 missing`` (empty: nothing lost)."""
        parts = []
        if self.missing:
            parts.append(f"{self.missing} of {self.expected} missing")
        if self.overflowed:
            parts.append(f"{self.overflowed} dropped by a full queue")
        return ", ".join(parts)

    def warnings(self) -> str:
        """Return what was counted and left out, or paused, without loss (empty: nothing)."""
        parts = []
        if self.duplicated:
            parts.append(f"{self.duplicated} duplicated")
        if self.out_of_order:
            parts.append(f"{self.out_of_order} out of order")
        if self.malformed:
            parts.append(f"{self.malformed} malformed")
        if self.out_of_range:
            parts.append(f"{self.out_of_range} stamped out of range")
        if self.counter_resets:
            parts.append(f"{self.counter_resets} counter {_plural(self.counter_resets, 'reset')}")
        if self.gaps:
            parts.append(
                f"{self.gaps} {_plural(self.gaps, 'gap')} ({self.gap_ns / 1e9:.3f} s paused)"
            )
        if self.unaligned:
            parts.append(f"{self.unaligned} left out of the rows (another cell had no sample)")
        return ", ".join(parts)

    def problems(self) -> str:
        """Return what went wrong, e.g. ``3 of 7500 missing, 2 duplicated`` (empty: nothing)."""
        return ", ".join(part for part in (self.loss(), self.warnings()) if part)


def lost_samples(sources: Iterable[SourceStats]) -> str:
    """Return the counted loss of a recording's sources, e.g. ``rtde: 3 of 500 missing``.

    One entry per source that lost samples, ``; ``-separated (empty: nothing lost). A
    recording with counted loss fails ``check``.
    """
    return "; ".join(f"{item.name}: {item.loss()}" for item in sources if item.lost)


def _plural(count: int, noun: str) -> str:
    """Return ``noun``, with an ``s`` unless ``count`` is one."""
    return noun if count == 1 else f"{noun}s"


#: Fields that are text: written only when given (a record without them is as before).
_TEXT_FIELDS = ("origin",)
_INT_FIELDS = tuple(
    f.name
    for f in dataclasses.fields(SourceStats)
    if f.name not in {"name", "basis", *_TEXT_FIELDS}
)
_BASES = ("counter", "clock", "stamps")
#: Fields added after the first files were written: an older record lacks them (0).
_LATER_FIELDS = frozenset({"out_of_range", "counter_resets", "gaps", "gap_ns", "unaligned"})


def encode_source_stats(stats: Sequence[SourceStats]) -> dict[str, str]:
    """Return the ``atikt.sources`` metadata record of a recording's sources.

    Raises:
        ValueError: A source name is empty, holds a dot, or appears twice.
    """
    record: dict[str, str] = {}
    for item in stats:
        if not item.name or "." in item.name or f"{item.name}.basis" in record:
            msg = f"source name {item.name!r}: give every source a unique name without dots"
            raise ValueError(msg)
        record[f"{item.name}.basis"] = item.basis
        for name in _INT_FIELDS:
            record[f"{item.name}.{name}"] = str(getattr(item, name))
        for name in _TEXT_FIELDS:
            if value := getattr(item, name):
                record[f"{item.name}.{name}"] = value
    return record


def parse_source_stats(record: Mapping[str, str]) -> tuple[SourceStats, ...]:
    """Return the sources of an ``atikt.sources`` metadata record, in name order.

    Raises:
        ValueError: A key or value is malformed (the caller names the file).
    """
    fields: dict[str, dict[str, str]] = {}
    for key, value in record.items():
        name, sep, field = key.rpartition(".")
        if not sep or not name or field not in {*_INT_FIELDS, *_TEXT_FIELDS, "basis"}:
            msg = f"unknown key {key!r} in {SOURCES_RECORD!r}"
            raise ValueError(msg)
        fields.setdefault(name, {})[field] = value
    out = []
    for name, values in sorted(fields.items()):
        lacking = {*_INT_FIELDS, "basis"} - set(values) - _LATER_FIELDS
        if values.get("basis") not in _BASES or lacking:
            msg = f"source {name!r} in {SOURCES_RECORD!r} lacks fields or has an unknown basis"
            raise ValueError(msg)
        numbers = {key: int(values.get(key, "0")) for key in _INT_FIELDS}
        # the numbers are the int fields only (mypy cannot tell them from origin, a str)
        stats = SourceStats(name, values["basis"], **numbers)  # type: ignore[arg-type]
        out.append(dataclasses.replace(stats, origin=values.get("origin", "")))
    return tuple(out)
