"""Alignment of per-cell skin samples into rows, and packing of rows into skin blocks.

Nothing is resampled.

1. Rows: the first cell of the map sets the rows. Every other cell contributes its sample
   nearest in time to the row's stamp if it is closer than half a sample period; a row
   missing a cell, or holding a non-finite value, is dropped and counted. The row keeps the
   first cell's stamp; the largest offset of another cell's sample is reported.
2. Blocks: consecutive rows go into one block of about 0.1 s with stamps
   ``first + i * period`` (``period`` an integer number of ns) while each row's stamp lies
   within ``max_jitter`` periods of that grid; a larger deviation (a gap, a dropped row)
   starts a new block. The largest deviation kept is reported. With a period that is not a
   whole number of ns (22 samples per 10 ms: 454 545.45 ns), the sample stamps are exact to
   1 ns and a block's grid, with the rounded period, drifts from them by at most
   ``0.5 ns * samples per block`` (100 ns for 0.1 s at 2.2 kHz); that drift is part of the
   reported deviation.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from recorder.writing._stream import SkinBlock

if TYPE_CHECKING:
    from collections.abc import Sequence
    from fractions import Fraction

    from numpy.typing import NDArray

#: Time of samples per skin block, ns, as in the recorder's own files.
BLOCK_NS = 100_000_000


@dataclass(frozen=True, slots=True)
class Series:
    """One cell's samples of one modality inside a window (sorted, increasing stamps).

    Attributes:
        stamps: Sample stamps, int64 ns.
        receives: Receive time of each sample's message, int64 ns.
        values: Values in SI units, shape (samples, width), float64.
    """

    stamps: NDArray[np.int64]
    receives: NDArray[np.int64]
    values: NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class Rows:
    """Aligned rows of one modality in one window.

    Attributes:
        stamps: Row stamps (the first cell's), int64 ns.
        receives: Latest receive time of the row's samples, int64 ns.
        data: Values, shape (rows, cells, width).
        dropped: Rows dropped (a cell without a sample near the row, a non-finite value).
        max_offset_ns: Largest offset of another cell's sample from its row.
        left_out: Per cell, the dropped rows in which that cell had a valid sample (a
            sample that arrived and is not written because another cell had none), inside
            the span from the latest first sample of a cell to the earliest last one.
    """

    stamps: NDArray[np.int64]
    receives: NDArray[np.int64]
    data: NDArray[np.float64]
    dropped: int
    max_offset_ns: int
    left_out: tuple[int, ...] = ()


def measured_period(stamps: NDArray[np.int64]) -> int:
    """Return the median interval of increasing stamps, in integer ns (0 if under 2 samples)."""
    if stamps.size < 2:  # noqa: PLR2004
        return 0
    diffs = np.sort(np.diff(stamps))
    return int(diffs[diffs.size // 2])


def block_period(exact: Fraction | None, stamps: NDArray[np.int64]) -> int:
    """Return the integer period of blocks: the exact one rounded, else the measured one."""
    return round(exact) if exact is not None else measured_period(stamps)


def _nearest(stamps: NDArray[np.int64], targets: NDArray[np.int64]) -> NDArray[np.intp]:
    """Return, for each target, the index of the nearest stamp (sorted ``stamps``)."""
    right = np.clip(np.searchsorted(stamps, targets), 0, stamps.size - 1)
    left = np.clip(right - 1, 0, stamps.size - 1)
    closer_left = np.abs(stamps[left] - targets) <= np.abs(stamps[right] - targets)
    return np.where(closer_left, left, right)


def align_rows(cells: Sequence[Series], start_ns: int, stop_ns: int, period_ns: int) -> Rows:
    """Align the cells' samples on the first cell's samples of a window.

    The rows are the first cell's samples in ``[start_ns, stop_ns)`` and its last sample
    before ``start_ns`` (so that the skin covers the window's first instant).
    """
    first = cells[0].stamps
    lo = max(int(np.searchsorted(first, start_ns, side="right")) - 1, 0)
    hi = int(np.searchsorted(first, stop_ns, side="left"))
    stamps = first[lo:hi]
    receives = cells[0].receives[lo:hi].copy()
    data = np.empty((stamps.size, len(cells), cells[0].values.shape[1]))
    data[:, 0] = cells[0].values[lo:hi]
    # present[:, c]: cell c has a sample within half a period of the row, finite
    present = np.ones((stamps.size, len(cells)), dtype=bool)
    max_offset = 0
    for c in range(1, len(cells)):
        if cells[c].stamps.size == 0:
            present[:, c] = False
            continue
        index = _nearest(cells[c].stamps, stamps)
        offset = np.abs(cells[c].stamps[index] - stamps)
        ok = 2 * offset < period_ns
        present[:, c] = ok
        data[:, c] = cells[c].values[index]
        receives = np.maximum(receives, cells[c].receives[index])
        if bool(ok.any()):
            max_offset = max(max_offset, int(offset[ok].max()))
    present &= np.isfinite(data).all(axis=2)
    keep = present.all(axis=1)
    # left out: dropped rows inside the span every cell delivers in (before a cell's first
    # sample or after its last, a row is the recording's edge, not a sample lost to a row)
    inside = np.zeros(stamps.size, dtype=bool)
    if all(c.stamps.size for c in cells):
        half = period_ns // 2
        all_from = max(int(c.stamps[0]) for c in cells) - half
        all_until = min(int(c.stamps[-1]) for c in cells) + half
        inside = (stamps >= all_from) & (stamps <= all_until)
    left_out = tuple(int(n) for n in present[~keep & inside].sum(axis=0))
    return Rows(stamps[keep], receives[keep], data[keep], int((~keep).sum()), max_offset, left_out)


def window_rows(cells: Sequence[Series], start_ns: int, stop_ns: int, period_ns: int) -> Rows:
    """Return the aligned rows of a window, from the row covering its start to its end.

    The rows are the complete rows (every cell aligned, finite) stamped in
    ``[start_ns, stop_ns)``, led by the last complete row at or before ``start_ns`` (the skin
    covers the window's first instant) and, when those leave the window's last period
    uncovered, followed by the first complete row at or after ``stop_ns``. A publisher that
    paused across an edge of the window (its samples stamped when they were sent, later
    than the lab's schedule) then shows a pause at that edge, not a channel that began late
    or stopped early. The lead is the last *complete* row: one cell sent late (a jitter) drops
    the row nearest the start from the alignment, never the window's first instant.
    ``dropped`` counts the incomplete rows between the first row and the last.
    """
    # which rows are complete does not depend on the range aligned: find the two edge rows
    # among all, then align the rows between them
    stamps = align_rows(cells, -(2**63), 2**63 - 1, period_ns).stamps
    lead = max(int(np.searchsorted(stamps, start_ns, side="right")) - 1, 0)
    end = int(np.searchsorted(stamps, stop_ns, side="left"))
    if lead < end < stamps.size and int(stamps[end - 1]) + period_ns < stop_ns:
        end += 1  # the first row after the window closes the pause at its end
    if end <= lead:  # no complete row before the window's end
        width = cells[0].values.shape[1]
        empty = np.zeros((0, len(cells), width))
        return Rows(stamps[:0], stamps[:0], empty, 0, 0, (0,) * len(cells))
    return align_rows(cells, int(stamps[lead]), int(stamps[end - 1]) + 1, period_ns)


def _block_end(
    stamps: NDArray[np.int64], start: int, size: int, tolerance: int, period: int
) -> int:
    """Return the end of the block starting at row ``start`` (rows on the stamp grid)."""
    count = min(size, stamps.size - start)
    grid = int(stamps[start]) + np.arange(count, dtype=np.int64) * period
    off = np.abs(stamps[start : start + count] - grid) > tolerance
    bad = np.flatnonzero(off)
    return start + (int(bad[0]) if bad.size else count)


def skin_blocks(
    modality: str, rows: Rows, period_ns: int, max_jitter: float
) -> tuple[list[SkinBlock], int, int]:
    """Pack rows into blocks of about 0.1 s with stamps ``first + i * period``.

    A row whose stamp is not after the previous block's last grid stamp (possible only with
    stamps closer than the jitter tolerance) is dropped: stamps must strictly increase.

    Returns:
        The blocks, the largest deviation of a row's stamp from its block's grid (ns) and
        the number of rows dropped.
    """
    size = max(1, round(BLOCK_NS / period_ns))
    tolerance = int(max_jitter * period_ns)
    blocks: list[SkinBlock] = []
    deviation = dropped = 0
    last = None
    start = 0
    while start < rows.stamps.size:
        if last is not None and int(rows.stamps[start]) <= last:
            dropped, start = dropped + 1, start + 1
            continue
        stop = _block_end(rows.stamps, start, size, tolerance, period_ns)
        grid = int(rows.stamps[start]) + np.arange(stop - start, dtype=np.int64) * period_ns
        deviation = max(deviation, int(np.abs(rows.stamps[start:stop] - grid).max()))
        blocks.append(
            SkinBlock(
                modality=modality,
                stamp_ns=int(rows.stamps[start]),
                period_ns=period_ns,
                receive_ns=int(rows.receives[start:stop].max()),
                data=rows.data[start:stop].astype(np.float32),
            )
        )
        last, start = int(grid[-1]), stop
    return blocks, deviation, dropped


def left_out_by_topic(topics: Sequence[str], rows: Rows, repeated: int) -> dict[str, int]:
    """Return, per topic, the stamps it delivered valid that the rows left out.

    A topic's cells share their messages' stamps: a row it lost counts once, however many of
    its cells it carries (the most of its cells). ``repeated``: complete rows the blocks
    dropped (a repeated stamp), lost to every topic.
    """
    out: dict[str, int] = {}
    for topic, count in zip(topics, rows.left_out or (0,) * len(topics), strict=True):
        out[topic] = max(out.get(topic, 0), count)
    return {topic: count + repeated for topic, count in out.items()}
