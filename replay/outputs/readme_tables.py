"""Write README.md's result tables from the studies' results, so that they cannot drift.

``python -m replay.outputs.readme_tables`` reads ``studies/<name>/results.parquet`` for every
block of README.md between ``<!-- results:NAME -->`` and ``<!-- /results:NAME -->`` and
rewrites the block (running it twice changes nothing); ``--check`` only compares and exits 1
when README.md differs (for CI).

The headline numbers are the studies' own (``replay.studies._studies.headline``): "initial"
is step 0 (one observation per new object and action), "mean" the mean over steps
1..budget, "final" the last step, accuracies averaged over runs per step first. The gain is
ATIKT minus the baseline on the same splits, in percentage points, with a paired 95 %
bootstrap interval: the prior groups (the ``group`` and ``repetition`` of a run) are
resampled with replacement, :data:`RESAMPLES` times with numpy's generator seeded by
``--seed``, and the gain recomputed on each resample from the same groups of both methods.
The fusion block is the mean test accuracy per action and modality set over the training
sizes, as in the study's summary.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import polars as pl

from replay.errors import ReplayError
from replay.studies._studies import ATIKT, BASELINE, headline
from schemas import VOCABULARY, cli

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import NDArray

#: Bootstrap resamples of the prior groups behind every gain interval.
RESAMPLES = 10_000
#: Coverage of the gain intervals.
CONFIDENCE = 0.95
_HEADLINES = ("initial", "mean", "final")
_MARKER = re.compile(r"<!-- results:(?P<name>[a-z0-9_-]+) -->")
#: The column a study compares within (one table row group each); None: the whole study.
_BY = {"transfer": None, "negative": None, "single-action": "actions", "priors": "n_priors"}
_MODALITY_ORDER = ("multi-modal", *VOCABULARY.features)


def _units(frame: pl.DataFrame) -> list[str]:
    """Return the columns naming a run's prior group (resampled by the bootstrap)."""
    return [column for column in ("group", "repetition") if column in frame.columns]


def _per_unit_gain(frame: pl.DataFrame, budget: int) -> NDArray[np.float64]:
    """Return the gain of every prior group, one row per group, columns initial/mean/final."""
    units = _units(frame)
    table = headline(frame, [*units, "method"], budget)
    wide = table.pivot(on="method", index=units, values=list(_HEADLINES)).sort(units)
    gains = [wide[f"{c}_{ATIKT}"] - wide[f"{c}_{BASELINE}"] for c in _HEADLINES]
    return np.column_stack([g.to_numpy().astype(np.float64) for g in gains])


def gain_intervals(
    frame: pl.DataFrame, budget: int, seed: int, resamples: int = RESAMPLES
) -> NDArray[np.float64]:
    """Return the paired bootstrap interval of each gain: rows low/high, columns as headlines.

    Args:
        frame: Transfer-type results (ATIKT and baseline runs of the same prior groups).
        budget: The last step counted in "mean".
        seed: Seed of numpy's generator drawing the resamples.
        resamples: How many resamples of the prior groups.
    """
    gains = _per_unit_gain(frame, budget)
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, len(gains), size=(resamples, len(gains)))
    means = gains[draws].mean(axis=1)  # resamples x headlines
    tail = 100 * (1 - CONFIDENCE) / 2
    bounds: NDArray[np.float64] = np.percentile(means, [tail, 100 - tail], axis=0)
    return bounds


def _percent(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.1f} %"


def _points(value: float) -> str:
    return f"{100 * value:+.1f}"


def _transfer_rows(frame: pl.DataFrame, budget: int, seed: int) -> list[list[str]]:
    """Return the rows ATIKT, baseline and gain (with its interval) of one comparison."""
    table = headline(frame, ["method"], budget)
    rows = {row["method"]: row for row in table.iter_rows(named=True)}
    low, high = gain_intervals(frame, budget, seed)
    gain = [
        f"{_points(rows[ATIKT][c] - rows[BASELINE][c])} [{_points(lo)}, {_points(hi)}]"
        for c, lo, hi in zip(_HEADLINES, low, high, strict=True)
    ]
    return [
        [ATIKT, *(_percent(rows[ATIKT][c]) for c in _HEADLINES)],
        [BASELINE, *(_percent(rows[BASELINE][c]) for c in _HEADLINES)],
        ["gain, points [95 % interval]", *gain],
    ]


def _markdown(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    return "\n".join([*lines, *("| " + " | ".join(row) + " |" for row in rows)])


def transfer_block(name: str, frame: pl.DataFrame, seed: int) -> str:
    """Return the markdown of a transfer-type study (transfer, negative, single-action, priors)."""
    if not {"method", "step", "accuracy"} <= set(frame.columns) or not _units(frame):
        msg = f"{name}: results lack method, step, accuracy or group columns; run the study again"
        raise ReplayError(msg)
    budget = int(frame["step"].max())  # type: ignore[arg-type]
    by = _BY.get(name)
    header = ["method", "initial", f"mean 1..{budget}", "final"]
    rows: list[list[str]] = []
    if by is None:
        rows = _transfer_rows(frame, budget, seed)
    else:
        header = [by, *header]
        for (value,), part in frame.sort(by).group_by([by], maintain_order=True):
            rows += [[str(value), *row] for row in _transfer_rows(part, budget, seed)]
    groups = frame.select(_units(frame)).unique().height
    runs = frame.filter(pl.col("step") == 0).height // 2
    note = (
        f"{runs} paired runs; gain = ATIKT - baseline in percentage points on the same splits; "
        f"interval: {RESAMPLES} paired bootstrap resamples of the {groups} prior groups "
        f"(numpy default_rng, seed {seed})."
    )
    return f"{_markdown(header, rows)}\n\n{note}"


def fusion_block(frame: pl.DataFrame) -> str:
    """Return the fusion table: mean test accuracy per action and modality set."""
    if not {"action", "modalities", "accuracy"} <= set(frame.columns):
        msg = "fusion: results lack action, modalities or accuracy columns; run the study again"
        raise ReplayError(msg)
    means = frame.group_by("action", "modalities").agg(pl.col("accuracy").mean())
    found = set(means["modalities"].to_list())
    columns = [m for m in _MODALITY_ORDER if m in found] + sorted(found - set(_MODALITY_ORDER))
    cells = {(a, m): v for a, m, v in means.iter_rows()}
    rows = [
        [action, *(_percent(cells.get((action, m))) for m in columns)]
        for action in sorted(set(means["action"].to_list()))
    ]
    sizes = ", ".join(str(s) for s in sorted(set(frame["samples"].to_list())))
    note = f"Mean test accuracy over {sizes} training samples per object."
    return f"{_markdown(['action', *columns], rows)}\n\n{note}"


def study_block(name: str, studies: Path, seed: int) -> str:
    """Return the markdown block of study ``name`` from ``studies/<name>/results.parquet``.

    Raises:
        ReplayError: The results file is missing or unreadable.
    """
    path = studies / name / "results.parquet"
    try:
        frame = pl.read_parquet(path)
    except (OSError, pl.exceptions.PolarsError) as err:
        reason = cli.one_line(str(err))
        msg = f"{path}: cannot read the results ({reason}); run 'atikt-replay study {name}'"
        raise ReplayError(msg) from err
    return fusion_block(frame) if name == "fusion" else transfer_block(name, frame, seed)


def rewrite(text: str, studies: Path, seed: int, readme: Path = Path("README.md")) -> str:
    """Return ``text`` with every results block rewritten from the studies' results.

    Raises:
        ReplayError: No markers, an unclosed marker, or a missing results file.
    """
    names = [match["name"] for match in _MARKER.finditer(text)]
    if not names:
        msg = f"{readme}: no '<!-- results:NAME -->' markers; put them around each result table"
        raise ReplayError(msg)
    for name in names:
        start, end = f"<!-- results:{name} -->", f"<!-- /results:{name} -->"
        head, _, rest = text.partition(start)
        if end not in rest:
            msg = f"{readme}: '{start}' is not closed; add '{end}' after its table"
            raise ReplayError(msg)
        _, _, tail = rest.partition(end)
        text = f"{head}{start}\n{study_block(name, studies, seed)}\n{end}{tail}"
    return text


def main(argv: Sequence[str] | None = None) -> int:
    """Rewrite (or, with ``--check``, compare) README.md's result tables; return the status."""
    parser = argparse.ArgumentParser(
        prog="python -m replay.outputs.readme_tables", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--readme", type=Path, default=Path("README.md"), help="the README")
    parser.add_argument("--studies", type=Path, default=Path("studies"), help="study outputs")
    parser.add_argument("--seed", type=cli.seed, default=0, help="seed of the bootstrap")
    parser.add_argument("--check", action="store_true", help="exit 1 if the README differs")
    args = parser.parse_args(argv)
    try:
        text = args.readme.read_text("utf-8")
        new = rewrite(text, args.studies, args.seed, args.readme)
        if new != text and not args.check:
            args.readme.write_text(new, "utf-8")
    except OSError as err:
        print(f"{parser.prog}: error: {args.readme}: {err.strerror}", file=sys.stderr)  # noqa: T201
        return 1
    except ReplayError as err:
        print(f"{parser.prog}: error: {cli.one_line(str(err))}", file=sys.stderr)  # noqa: T201
        return 1
    if args.check and new != text:
        message = f"{args.readme}: result tables differ from {args.studies}; run {parser.prog}"
        print(f"{parser.prog}: error: {message}", file=sys.stderr)  # noqa: T201
        return 1
    print(f"{args.readme}: {'up to date' if new == text else 'result tables rewritten'}")  # noqa: T201
    return 0


if __name__ == "__main__":
    sys.exit(main())
