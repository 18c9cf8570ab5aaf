"""Write the documentation's result tables from the studies' results, so that they cannot drift.

``python -m replay.outputs.readme_tables`` finds every block between ``<!-- results:NAME -->``
and ``<!-- /results:NAME -->`` in README.md and the manual's pages (``docs/**/*.md``; or in the
files given with ``--readme``), reads ``studies/<name>/results.parquet`` for each and rewrites
the block (running it twice changes nothing); ``--check`` only compares and exits 1 when a file
differs (for CI). A block may appear in several files (README's headline table is the results
page's); each is written from the same results. ``NAME`` is a study's output directory, or a
fusion study's plus ``-margins`` (multi-modal minus best single modality), or two fusion
studies' ``A-vs-B`` (A's multi-modal kernel minus B's, paired per group: runs that differ only
in ``--fusion-prior``, ``--fusion-kernel`` or ``--fusion-parts``); ``real-NAME`` reads
``studies-real/`` (``--real-studies``), the studies on the real data.

The numbers are the studies' own, computed by the same functions as their summaries
(``replay.studies._stats.headline``, ``replay.studies._stats.paired_gains`` and
``fusion_margins``, same seed): "initial" is step 0 (one observation per new object and
action), "mean" the mean over steps 1..budget, "final" the last step, accuracies averaged over
runs per step first; the gain is ATIKT minus the baseline on the same splits, in percentage
points, with a paired 95 % percentile bootstrap interval over the independent units (prior
groups; repetitions where the priors are fixed). The fusion block is the mean test accuracy
per action and modality set over the training sizes, as in the study's summary.
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
from replay.studies._borrow import CROSS_ACTION, CROSS_RIG, WITHIN
from replay.studies._fusion import fusion_means
from replay.studies._running import ATIKT, BASELINE
from replay.studies._stats import (
    HEADLINES,
    RESAMPLES,
    fusion_differences,
    fusion_margins,
    gain_cells,
    headline,
    mean_steps,
    paired_gains,
)
from schemas import VOCABULARY, atomic_write_text, cli

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import NDArray

_MARKER = re.compile(r"<!-- results:(?P<name>[a-z0-9_-]+) -->")
#: The column a study compares within (one table row group each); None: the whole study.
_BY = {"transfer": None, "negative": None, "single-action": "actions", "priors": "n_priors"}
_MODALITY_ORDER = ("multi-modal", *VOCABULARY.features)
#: Marker prefix of studies on the real data (read from ``--real-studies``).
REAL = "real-"


def _unit(frame: pl.DataFrame) -> str:
    """Return the independent unit a study's summary resamples (as ``report_transfer``)."""
    return "repetition" if "repetition" in frame.columns else "group"


def gain_intervals(frame: pl.DataFrame, budget: int, seed: int) -> NDArray[np.float64]:
    """Return the paired bootstrap interval of each gain: rows low/high, columns as headlines.

    The same computation (``replay.studies._stats.paired_gains``) and seed as the study's
    summary, so README and summary print the same intervals.
    """
    gains = paired_gains(frame, [], _unit(frame), budget, seed=seed).row(0, named=True)
    return np.array([[gains[f"{k}_{h}"] for h in HEADLINES] for k in ("low", "high")])


def _percent(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.1f} %"


def _markdown(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    return "\n".join([*lines, *("| " + " | ".join(row) + " |" for row in rows)])


def transfer_block(name: str, frame: pl.DataFrame, seed: int) -> str:
    """Return the markdown of a transfer-type study (transfer, negative, single-action, priors)."""
    if not {"method", "step", "accuracy"} <= set(frame.columns) or "group" not in frame.columns:
        msg = f"{name}: results lack method, step, accuracy or group columns; run the study again"
        raise ReplayError(msg)
    budget = int(frame["step"].max())  # type: ignore[arg-type]
    column = _BY.get(name.removeprefix(REAL))
    by = [column] if column else []
    unit = _unit(frame)
    accuracies = {
        tuple(row[k] for k in [*by, "method"]): row
        for row in headline(frame, [*by, "method"], budget).iter_rows(named=True)
    }
    header = [*by, "method", "initial", f"mean {mean_steps(frame, budget)}", "final"]
    rows: list[list[str]] = []
    for gain in paired_gains(frame, by, unit, budget, seed=seed).iter_rows(named=True):
        key = [gain[k] for k in by]
        for method in (ATIKT, BASELINE):
            row = accuracies[(*key, method)]
            rows.append([*map(str, key), method, *(_percent(row[h]) for h in HEADLINES)])
        cells = [gain_cells(gain, h).replace(" pts", "") for h in HEADLINES]
        rows.append([*map(str, key), "gain, points [95 % interval]", *cells])
    runs = frame.filter(pl.col("step") == 0).height // 2
    units = frame.select(unit).unique().height
    note = (
        f"{runs} paired runs; gain = ATIKT - baseline in percentage points on the same splits; "
        + (
            f"interval: {RESAMPLES} paired bootstrap resamples of the {units} {unit}s "
            f"(numpy default_rng, seed {seed}), as in the study's summary."
            if units > 1
            else f"one {unit}: no interval."
        )
    )
    return f"{_markdown(header, rows)}\n\n{note}"


def borrow_block(frame: pl.DataFrame, seed: int) -> str:
    """Return the markdown of a cross-action or cross-rig study: accuracies and paired gains.

    Per target action: the headline accuracies of the baseline, ``within`` and the borrowed
    priors, then each paired difference (borrowed - baseline, within - baseline, borrowed -
    within) with its 95 % interval over prior groups, as in the study's summary. Where the
    results have ``rho``, the note says how often relatedness let the borrowed priors in.

    Raises:
        ReplayError: The results lack a column the table needs.
    """
    needed = {"actions", "source", "method", "group", "step", "accuracy"}
    if missing := sorted(needed - set(frame.columns)):
        msg = (
            f"cross-action/cross-rig results lack {', '.join(missing)}; run "
            "'atikt-replay study cross-action' or 'cross-rig' again"
        )
        raise ReplayError(msg)
    budget = int(frame["step"].max())  # type: ignore[arg-type]
    methods = set(frame["method"].to_list())
    borrowed = CROSS_RIG if CROSS_RIG in methods else CROSS_ACTION
    accuracies = {
        (row["actions"], row["method"]): row
        for row in headline(frame, ["actions", "method"], budget).iter_rows(named=True)
    }
    sources = dict(frame.select("actions", "source").unique().iter_rows())
    rows: list[list[str]] = []
    for action in sorted(sources):
        for method in (BASELINE, WITHIN, borrowed):
            if (row := accuracies.get((action, method))) is not None:
                cells = [_percent(row[h]) for h in HEADLINES]
                rows.append([f"{action} <- {sources[action]}", method, *cells])
        for treated, reference in ((borrowed, BASELINE), (WITHIN, BASELINE), (borrowed, WITHIN)):
            if not {treated, reference} <= methods:
                continue
            part = frame.filter(pl.col("actions") == action)
            gain = paired_gains(
                part, [], "group", budget, methods=(treated, reference), seed=seed
            ).row(0, named=True)
            cells = [gain_cells(gain, h).replace(" pts", "") for h in HEADLINES]
            rows.append([f"{action} <- {sources[action]}", f"{treated} - {reference}", *cells])
    groups = frame.select("group").unique().height
    mean = f"mean {mean_steps(frame, budget)}"
    header = ["action <- source", "method", "initial", mean, "final"]
    note = (
        "Differences in percentage points on the same splits; interval: "
        f"{RESAMPLES} paired bootstrap resamples of the {groups} prior groups (seed {seed})."
        + _admitted(frame, borrowed)
    )
    return f"{_markdown(header, rows)}\n\n{note}"


def _admitted(frame: pl.DataFrame, borrowed: str) -> str:
    """Return how often the borrowed priors were used, as a sentence (empty without ``rho``).

    Per target action: the share of the borrowed learner's steps 1..budget whose update
    transferred observations (``rho > 0``: relatedness admitted an old object of the source),
    and, where the results have ``metric_share`` (the share of the new objects' classifiers
    fitted under metric transfer, the old objects' kernel), its mean at step 0 and over
    1..budget.
    """
    if "rho" not in frame.columns:
        return ""
    runs = frame.filter(pl.col("method") == borrowed)
    shares = (
        runs.filter(pl.col("step") > 0)
        .group_by("actions", maintain_order=True)
        .agg((pl.col("rho").fill_null(0.0) > 0).mean().alias("share"))
        .sort("actions")
    )
    if shares.is_empty():
        return ""
    parts = ", ".join(f"{a} {100 * v:.0f} %" for a, v in shares.iter_rows())
    text = (
        f" Steps of `{borrowed}` that transferred a borrowed object's observations "
        f"(rho > 0): {parts}."
    )
    if "metric_share" not in frame.columns:
        return text + " (These results do not say how often metric transfer was used.)"
    metric = (
        runs.group_by("actions", maintain_order=True)
        .agg(
            pl.col("metric_share").filter(pl.col("step") == 0).mean().alias("initial"),
            pl.col("metric_share").filter(pl.col("step") > 0).mean().alias("later"),
        )
        .sort("actions")
    )
    parts = ", ".join(f"{a} {100 * i:.0f} / {100 * m:.0f} %" for a, i, m in metric.iter_rows())
    return (
        f"{text} Classifiers fitted under metric transfer (the old objects' kernel as the "
        f"centre of their hyperprior), step 0 / steps 1..budget: {parts}."
    )


def fusion_block(frame: pl.DataFrame) -> str:
    """Return the fusion table: mean test accuracy per action and modality set."""
    if not {"action", "modalities", "accuracy"} <= set(frame.columns):
        msg = "fusion: results lack action, modalities or accuracy columns; run the study again"
        raise ReplayError(msg)
    means = fusion_means(frame)
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


def margins_block(frame: pl.DataFrame, seed: int) -> str:
    """Return multi-modal minus the best single modality per action and size, with intervals."""
    if not {"action", "modalities", "accuracy", "samples", "group"} <= set(frame.columns):
        msg = "fusion: results lack action, modalities, samples or group; run the study again"
        raise ReplayError(msg)
    margins = fusion_margins(frame, seed=seed)
    sizes = sorted(set(margins["samples"].to_list()))
    cells = {(r["action"], r["samples"]): r for r in margins.iter_rows(named=True)}
    rows = []
    for action in sorted(set(margins["action"].to_list())):
        row = [action]
        for size in sizes:
            cell = cells.get((action, size))
            row.append(
                "-"
                if cell is None
                else f"{100 * cell['margin']:+.1f} [{100 * cell['low']:+.1f}, "
                f"{100 * cell['high']:+.1f}]"
            )
        rows.append(row)
    groups = frame.select("group").unique().height
    note = (
        "Multi-modal minus the best single modality at that size, in points, paired per group; "
        f"[95 % interval]: bootstrap over the {groups} groups ({RESAMPLES} resamples)."
    )
    return f"{_markdown(['action', *(f'{s} / object' for s in sizes)], rows)}\n\n{note}"


def _signed(value: float, low: float, high: float) -> str:
    """Format fractions as signed points with the interval (none with one group)."""
    text = f"{100 * value:+.1f}"
    return text + (f" [{100 * low:+.1f}, {100 * high:+.1f}]" if np.isfinite(low) else "")


def differences_block(name: str, frame: pl.DataFrame, other: pl.DataFrame, seed: int) -> str:
    """Return one fusion study's multi-modal minus another's per action and size."""
    needed = {"action", "modalities", "accuracy", "samples", "group"}
    if not (needed <= set(frame.columns) and needed <= set(other.columns)):
        msg = f"{name}: results lack {', '.join(sorted(needed))}; run both fusion studies again"
        raise ReplayError(msg)
    differences = fusion_differences(frame, other, seed=seed)
    if differences.is_empty():
        msg = f"{name}: the two fusion studies share no action, size and group; use one dataset"
        raise ReplayError(msg)
    sizes = sorted(set(differences["samples"].to_list()))
    cells = {(r["action"], r["samples"]): r for r in differences.iter_rows(named=True)}
    rows = [
        [action]
        + [
            "-"
            if (cell := cells.get((action, size))) is None
            else _signed(cell["difference"], cell["low"], cell["high"])
            for size in sizes
        ]
        for action in sorted(set(differences["action"].to_list()))
    ]
    groups = frame.select("group").unique().height
    first, second = name.removeprefix(REAL).split("-vs-", 1)
    note = (
        f"Multi-modal accuracy of `{first}` minus that of `{second}`, in points, paired per "
        f"group (same groups and splits); [95 % interval]: bootstrap over the {groups} groups "
        f"({RESAMPLES} resamples)."
    )
    return f"{_markdown(['action', *(f'{s} / object' for s in sizes)], rows)}\n\n{note}"


def _read_results(path: Path, study: str) -> pl.DataFrame:
    """Read a study's results.parquet.

    Raises:
        ReplayError: Missing or unreadable, in one line naming the command that writes it.
    """
    try:
        return pl.read_parquet(path, glob=False)
    except (OSError, pl.exceptions.PolarsError) as err:
        reason = cli.one_line(str(err))
        msg = f"{path}: cannot read the results ({reason}); run 'atikt-replay study {study}'"
        raise ReplayError(msg) from err


def study_block(name: str, studies: Path, seed: int, real: Path = Path("studies-real")) -> str:
    """Return the markdown block ``name`` from ``<studies>/<study>/results.parquet``.

    ``NAME`` is a study's output directory (``transfer``, ``fusion``, ...; a fusion study is
    told by its ``modalities`` column), or that of a fusion study plus ``-margins``; with the
    prefix ``real-`` it is read from ``real`` (the studies on the real probe data) instead.

    Raises:
        ReplayError: The results file is missing or unreadable.
    """
    base = name.removeprefix(REAL)
    root = real if name.startswith(REAL) else studies
    if "-vs-" in base:
        first, second = base.split("-vs-", 1)
        return differences_block(
            name,
            _read_results(root / first / "results.parquet", "fusion"),
            _read_results(root / second / "results.parquet", "fusion"),
            seed,
        )
    study = base.removesuffix("-margins")
    frame = _read_results(root / study / "results.parquet", study)
    if base.endswith("-margins"):
        return margins_block(frame, seed)
    if "modalities" in frame.columns:
        return fusion_block(frame)
    if "source" in frame.columns:
        return borrow_block(frame, seed)
    return transfer_block(name, frame, seed)


def rewrite(
    text: str,
    studies: Path,
    seed: int,
    readme: Path = Path("README.md"),
    real: Path = Path("studies-real"),
    *,
    only: Sequence[str] = (),
) -> str:
    """Return ``text`` with every results block (or those named in ``only``) rewritten.

    Raises:
        ReplayError: No markers, an unclosed marker, a name of ``only`` without a marker, or
            a missing results file.
    """
    names = [match["name"] for match in _MARKER.finditer(text)]
    if not names:
        msg = f"{readme}: no '<!-- results:NAME -->' markers; put them around each result table"
        raise ReplayError(msg)
    if unknown := sorted(set(only) - set(names)):
        msg = f"--only {','.join(unknown)}: {readme} has no such block; it has {', '.join(names)}"
        raise ReplayError(msg)
    for name in [n for n in names if n in only] if only else names:
        start, end = f"<!-- results:{name} -->", f"<!-- /results:{name} -->"
        head, _, rest = text.partition(start)
        if end not in rest:
            msg = f"{readme}: '{start}' is not closed; add '{end}' after its table"
            raise ReplayError(msg)
        _, _, tail = rest.partition(end)
        text = f"{head}{start}\n{study_block(name, studies, seed, real)}\n{end}{tail}"
    return text


#: Where the manual's pages live (searched for result blocks when no ``--readme`` is given).
DOCS = Path("docs")


def marked_files(readme: Path = Path("README.md"), docs: Path = DOCS) -> list[Path]:
    """Return README.md and the manual's pages (``docs/**/*.md``) that hold a results block.

    Raises:
        ReplayError: None of them holds one.
    """
    candidates = [readme, *sorted(docs.rglob("*.md"))] if docs.is_dir() else [readme]
    found = [p for p in candidates if p.is_file() and _MARKER.search(p.read_text("utf-8"))]
    if not found:
        msg = (
            f"{readme}, {docs}/: no '<!-- results:NAME -->' markers; put them around each "
            "result table"
        )
        raise ReplayError(msg)
    return found


def _rewrite_all(
    files: Sequence[Path], args: argparse.Namespace, only: Sequence[str]
) -> dict[Path, tuple[str, str]]:
    """Return each file's text and its text with the result blocks rewritten.

    With ``only``, a file holding none of those blocks is left out, and a name no file holds
    is refused.

    Raises:
        ReplayError: As :func:`rewrite`, or a name of ``only`` that no file holds.
        OSError: A file cannot be read.
    """
    texts = {path: path.read_text("utf-8") for path in files}
    held = {path: {m["name"] for m in _MARKER.finditer(text)} for path, text in texts.items()}
    if only and (unknown := sorted(set(only) - set().union(*held.values()))):
        found = ", ".join(sorted(set().union(*held.values())))
        names = ", ".join(str(p) for p in files)
        msg = f"--only {','.join(unknown)}: {names} hold no such block; they hold {found}"
        raise ReplayError(msg)
    result = {}
    for path, text in texts.items():
        wanted = [n for n in only if n in held[path]]
        if only and not wanted:
            continue
        new = rewrite(text, args.studies, args.seed, path, args.real_studies, only=wanted)
        result[path] = (text, new)
    return result


def main(argv: Sequence[str] | None = None) -> int:
    """Rewrite (or, with ``--check``, compare) the result tables; return the exit status."""
    parser = argparse.ArgumentParser(
        prog="python -m replay.outputs.readme_tables", description=__doc__.split("\n")[0]
    )
    parser.add_argument(
        "--readme",
        type=Path,
        action="append",
        metavar="FILE",
        help="a Markdown file with result blocks (repeat for several); default: README.md "
        "and every page under docs/ that holds one",
    )
    parser.add_argument("--studies", type=Path, default=Path("studies"), help="study outputs")
    parser.add_argument(
        "--real-studies",
        type=Path,
        default=Path("studies-real"),
        help="study outputs on the real data (blocks named real-NAME)",
    )
    parser.add_argument("--seed", type=cli.seed, default=0, help="seed of the bootstrap")
    parser.add_argument("--check", action="store_true", help="exit 1 if a file differs")
    parser.add_argument(
        "--only",
        default="",
        metavar="NAME,..",
        help="rewrite (or check) only these blocks, e.g. after running one study",
    )
    args = parser.parse_args(argv)
    only = [n for n in args.only.split(",") if n]
    path = Path("README.md")
    try:
        files = args.readme or marked_files()
        texts = _rewrite_all(files, args, only)
        if not args.check:
            for path, (text, new) in texts.items():
                if new != text:
                    atomic_write_text(path, new)
    except OSError as err:
        print(f"{parser.prog}: error: {err.filename or path}: {err.strerror}", file=sys.stderr)  # noqa: T201
        return 1
    except ReplayError as err:
        print(f"{parser.prog}: error: {cli.one_line(str(err))}", file=sys.stderr)  # noqa: T201
        return 1
    differ = [str(p) for p, (text, new) in texts.items() if new != text]
    if args.check and differ:
        message = (
            f"{', '.join(differ)}: result tables differ from {args.studies}; run {parser.prog}"
        )
        print(f"{parser.prog}: error: {message}", file=sys.stderr)  # noqa: T201
        return 1
    for path, (text, new) in texts.items():
        print(f"{path}: {'up to date' if new == text else 'result tables rewritten'}")  # noqa: T201
    return 0


if __name__ == "__main__":
    sys.exit(main())
