"""Read what rerun stored (an .rrd file or an MCAP file through rerun's loader) as polars frames.

rerun 0.41 reads its files back through ``rerun.chunk`` (``RrdReader``, ``McapReader``): a
stream of chunks, each an Arrow record batch of one entity. These helpers concatenate the
chunks of every entity, static and temporal apart.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import polars as pl
from rerun.chunk import McapReader, RrdReader
from rerun.error_utils import RerunWarning

if TYPE_CHECKING:
    from collections.abc import Iterable
    from pathlib import Path


@dataclass(frozen=True)
class Entities:
    """Every entity's rows: temporal (sorted by ``index``) and static (one row)."""

    temporal: dict[str, pl.DataFrame]
    static: dict[str, dict[str, Any]]
    timelines: dict[str, set[str]]

    def column(self, entity: str, column: str) -> list[Any]:
        """Return a temporal column as Python values."""
        return self.temporal[entity][column].to_list()


def _series(name: str, array: Any) -> pl.Series:
    """Convert one Arrow column; tensors (Arrow unions) stay Python objects."""
    if name.startswith("Tensor:"):
        return pl.Series(name, array.to_pylist(), dtype=pl.Object)
    series = pl.from_arrow(array)
    assert isinstance(series, pl.Series)
    return series.alias(name)


def _frame(batch: Any) -> pl.DataFrame:
    names = [n for n in batch.schema.names if not n.startswith("rerun.controls")]
    return pl.DataFrame([_series(n, batch.column(n)) for n in names])


def entities(chunks: Iterable[Any], index: str) -> Entities:
    """Group chunks by entity; temporal rows sorted by the timeline ``index``."""
    parts: dict[str, list[pl.DataFrame]] = {}
    static: dict[str, dict[str, Any]] = {}
    timelines: dict[str, set[str]] = {}
    for chunk in chunks:
        frame = _frame(chunk.to_record_batch())
        if chunk.is_static:
            static.setdefault(chunk.entity_path, {}).update(frame.row(0, named=True))
        else:
            parts.setdefault(chunk.entity_path, []).append(frame)
            timelines.setdefault(chunk.entity_path, set()).update(chunk.timeline_names)
    temporal = {}
    for entity, frames in parts.items():
        frame = pl.concat(frames, how="diagonal_relaxed")
        temporal[entity] = frame.sort(index) if index in frame.columns else frame
    return Entities(temporal, static, timelines)


def read_rrd(path: Path, index: str = "log_time") -> Entities:
    """Read an .rrd file written by ``atikt-replay view``."""
    return entities(_rrd(path).stream().to_chunks(), index)


def temporal_entities(path: Path) -> set[str]:
    """Return the entities of an .rrd file that have temporal rows, converting no column.

    A live run's view holds tens of thousands of chunks: :func:`read_rrd` converts each to a
    frame (seconds), where a test of what was logged needs only the entity paths.
    """
    return {c.entity_path for c in _rrd(path).stream().to_chunks() if not c.is_static}


def read_mcap_with_rerun(path: Path, index: str = "message_log_time") -> Entities:
    """Read an MCAP file through rerun's own MCAP loader (the one of ``rerun mcap convert``)."""
    return entities(McapReader(path).stream().to_chunks(), index)


def nanoseconds(column: pl.Series) -> list[int]:
    """Return a timestamp column as int nanoseconds."""
    return column.cast(pl.Int64).to_list()


def _rrd(path: Path) -> RrdReader:
    """Open an .rrd file; a file without rerun's footer (a stream never closed) fails."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", RerunWarning)
        return RrdReader(path)
