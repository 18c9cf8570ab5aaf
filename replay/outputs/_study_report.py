"""The one writer of every study's output: results, figure and summary.

``replay.studies`` computes a study (its tasks' rows) and declares how it is reported (its
:class:`~replay.studies._report.Report`); this module writes ``results.parquet``, the
``learning_curves.png`` its :class:`~replay.studies._report.Curves` describe, and
``summary.md`` (title, notes, the report's sections with their paired 95 % intervals, the
study's further files and the quarantined recordings).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

import polars as pl

from replay.errors import ReplayError
from replay.outputs._plots import plot_learning_curves
from replay.studies._registry import find_study
from replay.studies._report import summary
from replay.studies._running import study_results
from schemas import atomic_write, atomic_write_text

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    from replay.studies._running import Study, StudyConfig

#: File names of a study's output directory.
RESULTS, PLOT, SUMMARY = "results.parquet", "learning_curves.png", "summary.md"
#: The study's options (the learner's whole; ``--learner-config study.json`` repeats them).
OPTIONS = "study.json"


@dataclass(frozen=True, slots=True)
class StudyOutput:
    """Where a study wrote its results."""

    name: str
    results: Path
    plot: Path
    summary: Path
    text: str


def run_study(
    name: str,
    frame: pl.DataFrame,
    config: StudyConfig,
    *,
    quarantined: pl.DataFrame | None = None,
    on_progress: Callable[[int, int], Any] | None = None,
) -> StudyOutput:
    """Run one study over a feature table and write results, plot and summary.

    Args:
        name: A key of ``replay.studies._registry.STUDIES``.
        frame: The dataset's feature table.
        config: Study options; ``config.out`` is created.
        quarantined: Recordings refused while building the features (listed in the summary).
        on_progress: Called with (tasks done, tasks).

    Raises:
        ReplayError: Unknown study, or a run failed.
    """
    study = find_study(name)
    results = study_results(study, frame, config, on_progress)
    return write_report(study, results, frame, config, quarantined=quarantined)


def study_options(study: Study, config: StudyConfig) -> dict[str, Any]:
    """The study's name and options as JSON values (``learner`` whole, as a run.json has it)."""
    skipped = {"out", "workers", "scheduler", "prior_frame", "learner"}
    values = {f.name: getattr(config, f.name) for f in fields(config) if f.name not in skipped}
    return {"study": study.name, "learner": config.learner.as_dict(), **values}


def write_report(
    study: Study,
    results: pl.DataFrame,
    frame: pl.DataFrame,
    config: StudyConfig,
    *,
    quarantined: pl.DataFrame | None = None,
) -> StudyOutput:
    """Write a study's results, figure and summary into ``config.out`` (created).

    Args:
        study: The study.
        results: Its rows (``study_results``).
        frame: The dataset's feature table (for the study's further files).
        config: Study options.
        quarantined: Recordings refused while building the features (listed in the summary).

    Raises:
        ReplayError: A file cannot be written (one line naming the directory and the fix).
    """
    out = config.out
    path, plot, text_path = out / RESULTS, out / PLOT, out / SUMMARY
    curves = study.report.curves
    try:
        out.mkdir(parents=True, exist_ok=True)
        atomic_write(path, results.write_parquet)
        plot_learning_curves(
            results,
            plot,
            x=curves.x,
            label=curves.label,
            panel=curves.panel,
            title=study.title,
            xlabel=curves.xlabel,
        )
        text = summary(study, results, config)
        if study.further_files is not None:
            text += study.further_files(frame, config)
        if quarantined is not None and quarantined.height:
            listing = "\n".join(f"- `{p}`: {r}" for p, r in quarantined.iter_rows())
            text += f"\n## Quarantined recordings ({quarantined.height})\n\n{listing}\n"
        atomic_write_text(text_path, text)
        atomic_write_text(out / OPTIONS, json.dumps(study_options(study, config), indent=1) + "\n")
    except (OSError, pl.exceptions.PolarsError) as err:  # polars: ComputeError on a full disk
        reason = err.strerror if isinstance(err, OSError) else " ".join(str(err).split())
        msg = f"{out}: cannot write the study's results ({reason}); check free space and --out"
        raise ReplayError(msg) from err
    return StudyOutput(study.name, path, plot, text_path, text)
