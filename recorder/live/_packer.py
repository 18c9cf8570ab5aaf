"""Consecutive samples of one skin modality -> :class:`~recorder.SkinBlock` messages.

A live skin delivers one sample per frame (1 kHz); a message per sample would make files
large and replay slow, so samples are packed into blocks of consecutive samples (the
contract's block messages: stamp of the first, period, samples x cells x values). A block ends
when it is full, when the next sample is not exactly one period later (a missing sample
stays a gap, never a compressed time axis), or when its shape changes. Block latency is one
block (0.1 s by default), within the recorder's promise of losing under 0.5 s on a kill.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from recorder.writing._stream import SkinBlock

if TYPE_CHECKING:
    from numpy.typing import NDArray

#: Default samples per block: 0.1 s at 1 kHz.
DEFAULT_BLOCK = 100


@dataclass(slots=True)
class _Open:
    stamp_ns: int
    receive_ns: int
    rows: list[NDArray[np.float32]] = field(default_factory=list)


class BlockPacker:
    """Packs one modality's samples into blocks; ``push`` returns blocks that are complete."""

    def __init__(self, modality: str, period_ns: int, *, block: int = DEFAULT_BLOCK) -> None:
        """Start packing.

        Args:
            modality: The contract's modality of the samples.
            period_ns: The modality's sample period, ns (> 0).
            block: Most samples per block.
        """
        self.modality = modality
        self.period_ns = period_ns
        self._block = max(1, block)
        self._open: _Open | None = None

    def push(self, stamp_ns: int, receive_ns: int, values: NDArray[np.float32]) -> list[SkinBlock]:
        """Add one sample (shape (cells, values)); return the blocks it completed.

        Args:
            stamp_ns: The sample's sensor time on the recorder's time base, ns.
            receive_ns: Its receive time, ns (a block's receive time is its last sample's).
            values: The sample, float32, shape (cells, values).
        """
        row = np.asarray(values, dtype=np.float32)
        done: list[SkinBlock] = []
        current = self._open
        if current is not None:
            expected = current.stamp_ns + len(current.rows) * self.period_ns
            if stamp_ns != expected or row.shape != current.rows[0].shape:
                done.extend(self.flush())
                current = None
        if current is None:
            current = self._open = _Open(stamp_ns, receive_ns)
        current.rows.append(row)
        current.receive_ns = receive_ns
        if len(current.rows) >= self._block:
            done.extend(self.flush())
        return done

    def flush(self) -> list[SkinBlock]:
        """Return the open block (if any) and start a new one."""
        current, self._open = self._open, None
        if current is None or not current.rows:
            return []
        data = np.stack(current.rows).astype(np.float32, copy=False)
        return [
            SkinBlock(self.modality, current.stamp_ns, self.period_ns, current.receive_ns, data)
        ]
