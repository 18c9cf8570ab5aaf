"""Reading the project's own parquet files (index, feature cache) without trusting them.

A parquet file is small on disk and large in memory: a 3.6 MB file that declares gigabytes of
compressible values made polars abort the process (exit 134, no message). Before anything is
decompressed, :func:`read_checked_parquet` reads the footer only (``pyarrow``, installed
with ``rerun-sdk``; polars has no footer API) and refuses a file whose footer is too long,
whose row count exceeds what it describes, whose declared uncompressed size is out of
proportion, or whose columns are not the expected ones; then it reads the expected columns and
compares their dtypes. Callers rebuild derived files that do not match.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from collections.abc import Mapping

    import polars as pl

__all__ = [
    "MAX_FOOTER_BYTES",
    "MAX_ROW_BYTES",
    "ParquetMismatchError",
    "read_checked_parquet",
    "rows_allowed",
]

#: Longest parquet footer read: the project's files have a few dozen columns and one row group
#: per 100 000 rows (a footer of a few kB); 8 MB bounds what a hostile footer costs to parse.
MAX_FOOTER_BYTES = 8 * 1024 * 1024
#: Largest declared uncompressed size per row: a feature row is ~540 bytes, an index row ~170
#: (measured on recordings/data); 16 kB leaves a 30-fold margin and bounds a hostile file to
#: 16 MB per 1000 rows allowed.
MAX_ROW_BYTES = 16 * 1024
#: Uncompressed bytes allowed whatever the row count (the file's own structures).
_SLACK_BYTES = 1024 * 1024
_TAIL = struct.Struct("<I4s")


def rows_allowed(described: int) -> int:
    """Return the most rows a derived file of ``described`` recordings may have.

    A cache or index may still list recordings deleted since it was written (a rebuild drops
    them); twice the recordings plus 1024 allows that and still bounds a hostile file.
    """
    return 2 * described + 1024


class ParquetMismatchError(ValueError):
    """A parquet file is unreadable or does not match what it should describe."""


def _footer_length(path: Path) -> int:
    """Return the footer length a parquet file declares.

    Raises:
        ParquetMismatchError: The file does not end like a parquet file.
        OSError: The file cannot be read.
    """
    with path.open("rb") as stream:
        size = stream.seek(0, 2)
        if size < 12:  # noqa: PLR2004 (magic, footer length, magic)
            msg = f"{size} bytes, too short for parquet"
            raise ParquetMismatchError(msg)
        _ = stream.seek(size - _TAIL.size)
        length, magic = _TAIL.unpack(stream.read(_TAIL.size))
    if magic != b"PAR1" or length > size - 12:
        msg = "not a parquet file (no footer)"
        raise ParquetMismatchError(msg)
    return int(length)


def _check_footer(path: Path, columns: Mapping[str, Any], max_rows: int, *, exact: bool) -> None:
    """Check a parquet file's footer: length, row count, declared size, column names.

    Raises:
        ParquetMismatchError: A check fails or the footer does not parse.
        OSError: The file cannot be read.
    """
    import pyarrow as pa  # type: ignore[import-untyped]  # noqa: PLC0415 (only when read)
    import pyarrow.parquet as pq  # type: ignore[import-untyped]  # noqa: PLC0415

    if (length := _footer_length(path)) > MAX_FOOTER_BYTES:
        msg = f"a footer of {length} bytes (at most {MAX_FOOTER_BYTES})"
        raise ParquetMismatchError(msg)
    try:
        meta = pq.read_metadata(path)
    except (pa.ArrowException, ValueError) as err:
        msg = f"the footer does not parse ({' '.join(str(err).split())})"
        raise ParquetMismatchError(msg) from err
    if meta.num_rows > max_rows:
        msg = f"{meta.num_rows} rows, more than the {max_rows} it can describe"
        raise ParquetMismatchError(msg)
    declared = sum(
        meta.row_group(g).column(c).total_uncompressed_size
        for g in range(meta.num_row_groups)
        for c in range(meta.num_columns)
    )
    if declared > (limit := max_rows * MAX_ROW_BYTES + _SLACK_BYTES):
        msg = f"{declared} bytes of values, more than the {limit} its rows can hold"
        raise ParquetMismatchError(msg)
    names = list(meta.schema.to_arrow_schema().names)
    if names != list(columns) if exact else not set(columns) <= set(names):
        missing, extra = sorted(set(columns) - set(names)), sorted(set(names) - set(columns))
        msg = f"columns missing {missing[:4]}, unexpected {extra[:4]}, or in another order"
        raise ParquetMismatchError(msg)


def read_checked_parquet(
    path: Path, columns: Mapping[str, Any], max_rows: int, *, exact: bool = True
) -> pl.DataFrame:
    """Return a parquet file of the project, checked against what it should hold.

    Args:
        path: The file.
        columns: The expected columns and their polars dtypes, in order; only these are read.
        max_rows: The most rows it can have (e.g. the recordings it describes).
        exact: The file has exactly ``columns``, in order (else: at least them).

    Raises:
        ParquetMismatchError: The file is not parquet, is larger than ``max_rows`` rows can
            be, or has other columns or dtypes; the message says which.
        OSError: The file cannot be read.
    """
    import polars as pl  # noqa: PLC0415 (on use: `import schemas` stays light for the CLIs)

    path = Path(path)
    _check_footer(path, columns, max_rows, exact=exact)
    try:
        frame = pl.read_parquet(path, columns=list(columns), n_rows=max_rows, glob=False)
    except pl.exceptions.PolarsError as err:
        msg = f"cannot read it ({' '.join(str(err).split())})"
        raise ParquetMismatchError(msg) from err
    if frame.schema != pl.Schema(columns):
        wrong = [c for c, t in columns.items() if frame.schema.get(c) != t]
        msg = f"columns {wrong[:4]} have other dtypes than expected"
        raise ParquetMismatchError(msg)
    return frame
