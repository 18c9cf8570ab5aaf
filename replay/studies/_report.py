"""How a study is reported: its summary's sections and its figure, declared as data.

A study declares a :class:`Report`: the sections of its ``summary.md`` in order (each a function
of the results and the options that returns markdown; the common ones are here) and the
:class:`Curves` of its figure. One writer, ``replay.outputs._study_report``, writes every study's
results, figure and summary from it; this module computes text only and draws nothing.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import polars as pl

from replay.learning._budget import steps_short
from replay.studies._running import ATIKT, BASELINE, StudyConfig
from replay.studies._stats import (
    HEADLINES,
    RESAMPLES,
    gain_cells,
    headline,
    mean_steps,
    paired_gains,
)

if TYPE_CHECKING:
    from collections.abc import Sequence

    from atikt import LearnerOptions
    from replay.studies._running import Study

#: One section of a summary: markdown from the study's results and options.
Section = Callable[[pl.DataFrame, StudyConfig], str]


@dataclass(frozen=True, slots=True)
class Curves:
    """The study's figure: learning curves of the results (drawn by ``replay.outputs``).

    Attributes:
        x: Column of the horizontal axis.
        label: Column whose values are the curves of a panel.
        panel: Column whose values are the panels (None: one panel).
        xlabel: Label of the horizontal axis (None: the figure's default for ``x``).
    """

    x: str = "step"
    label: str = "method"
    panel: str | None = None
    xlabel: str | None = None


@dataclass(frozen=True, slots=True)
class Report:
    """What a study's summary and figure show.

    Attributes:
        sections: The summary's sections after its title and notes, in order.
        curves: The figure.
        learners: The notes state the active learners' options (studies of active learning).
    """

    sections: tuple[Section, ...]
    curves: Curves = Curves()
    learners: bool = True


def summary(study: Study, frame: pl.DataFrame, config: StudyConfig) -> str:
    """Return a study's markdown summary: title, notes, then its report's sections."""
    sections = "\n\n".join(section(frame, config) for section in study.report.sections)
    text = notes(config, learners=study.report.learners)
    if study.report.learners:
        text += steps_note(frame, config.budget, config.learner.patience)
    return f"# {study.title}\n{text}\n{sections}\n"


def steps_note(frame: pl.DataFrame, budget: int, patience: int | None = None) -> str:
    """Return the note that the recordings allowed fewer steps than the budget (empty if not).

    A run stops when every (new object, action)'s pool of trials is used up; with few trials
    per object (half of them held out for testing) that can be after the initial round. The
    tables' "mean" then names the steps it averaged (``mean 1..8``), and this note says why
    the budget did not run. With a ``patience`` (the learner's), a run may also have stopped
    on it, and the note says so.
    """
    if "step" not in frame.columns or frame.height == 0:
        return ""
    reached = int(frame["step"].max())  # type: ignore[arg-type]
    text = steps_short(reached, budget, patience=patience, markdown=True)
    return f"\n> {text[:1].upper()}{text[1:]}.\n" if text else ""


@dataclass(frozen=True, slots=True)
class Headlines:
    """The headline accuracies (``headline``) per ``by`` (ending with ``method``) as a table."""

    by: tuple[str, ...]

    def __call__(self, frame: pl.DataFrame, config: StudyConfig) -> str:
        """Return the table."""
        return markdown_table(headline(frame, list(self.by), config.budget))


@dataclass(frozen=True, slots=True)
class Gains:
    """ATIKT's paired gains over the baseline per ``by`` with 95 % intervals over ``unit``s."""

    by: tuple[str, ...]
    unit: str = "group"

    def __call__(self, frame: pl.DataFrame, config: StudyConfig) -> str:
        """Return the table and its note."""
        gains = paired_gains(frame, list(self.by), self.unit, config.budget, seed=config.seed)
        header = [
            *self.by,
            f"{self.unit}s",
            "gain after 1 observation",
            f"gain mean {mean_steps(frame, config.budget)}",
            "gain final",
        ]
        lines = _table_head(header)
        for row in gains.iter_rows(named=True):
            cells = [str(row[key]) for key in self.by] + [str(row["units"])]
            cells += [gain_cells(row, head) for head in HEADLINES]
            lines.append("| " + " | ".join(cells) + " |")
        note = (
            f"Gains: {ATIKT} minus {BASELINE} in percentage points, paired on the same splits, "
            f"mean over {self.unit}s; [95 % interval]: percentile bootstrap over {self.unit}s "
            f'({RESAMPLES} resamples). "after 1 observation": after the initial round of one '
            "observation per (new object, action)."
        )
        return "\n".join(lines) + "\n\n" + note


@dataclass(frozen=True, slots=True)
class Comparisons:
    """Paired differences of pairs of methods per ``by`` with 95 % intervals over groups.

    Attributes:
        by: Grouping columns.
        pairs: (treated, reference) method pairs; those whose methods the results lack are
            left out.
    """

    by: tuple[str, ...]
    pairs: Callable[[pl.DataFrame], Sequence[tuple[str, str]]]

    def __call__(self, frame: pl.DataFrame, config: StudyConfig) -> str:
        """Return the table and its note."""
        methods = set(frame["method"].to_list())
        header = [*self.by, "comparison", "groups", *(f"{h} (points)" for h in HEADLINES)]
        lines = _table_head(header)
        for treated, reference in (p for p in self.pairs(frame) if set(p) <= methods):
            gains = paired_gains(
                frame,
                list(self.by),
                "group",
                config.budget,
                methods=(treated, reference),
                seed=config.seed,
            )
            for row in gains.iter_rows(named=True):
                cells = [str(row[key]) for key in self.by]
                cells += [f"{treated} - {reference}", str(row["units"])]
                lines.append(
                    "| " + " | ".join(cells + [gain_cells(row, h) for h in HEADLINES]) + " |"
                )
        note = (
            "Paired differences in percentage points, mean over prior groups; [95 % interval]: "
            f"percentile bootstrap over groups ({RESAMPLES} resamples). initial: after one "
            "observation per new object; mean: over observations "
            f"{mean_steps(frame, config.budget)}; final: after the last."
        )
        return "\n".join(lines) + "\n\n" + note


@dataclass(frozen=True, slots=True)
class Text:
    """A fixed paragraph."""

    text: str

    def __call__(self, frame: pl.DataFrame, config: StudyConfig) -> str:  # noqa: ARG002
        """Return the paragraph."""
        return self.text


def _table_head(header: Sequence[str]) -> list[str]:
    """Return a markdown table's header and rule lines."""
    return ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]


def _cell(value: object, column: str) -> str:
    """Render one table cell: accuracies as percentages, gains as signed percentage points."""
    if value is None:
        return "-"
    if not isinstance(value, float):
        return str(value)
    return f"{100 * value:+.1f} pts" if column.startswith("gain") else f"{100 * value:.1f} %"


def markdown_table(frame: pl.DataFrame) -> str:
    """Render a small table as GitHub markdown, floats as percentages."""
    lines = _table_head(frame.columns)
    for row in frame.iter_rows():
        cells = [_cell(v, c) for v, c in zip(row, frame.columns, strict=True)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


_METRIC_WHEN = {
    "evidence": "when the new objects' evidence is at least as large there",
    "separation": "when it separates the new objects at least as well",
    "either": "when the new objects' evidence is at least as large there or it separates "
    "them at least as well",
    "none": "always",
}
"""The summary's words for each ``--metric-check``."""


def notes(config: StudyConfig, *, learners: bool = True) -> str:
    """Return the summary's notes on the learners' options and on a reduced (``--quick``) run."""
    text = _learner_notes(config) if learners else ""
    if config.reduced:
        text += (
            "\n> Reduced run (`--quick`): fewer groups, trials, steps and repetitions than the "
            "full study; its numbers vary widely and are for a first look only.\n"
        )
    return text


def _gate_notes(learner: LearnerOptions) -> str:
    """The note on when the ATIKT learners borrow old objects' observations (empty: always)."""
    parts = []
    if not learner.transfer.borrows_initial():
        parts.append("not in the initial round, where every new object has one observation")
    if learner.transfer_from > 1:
        parts.append(
            f"not before a new object has {learner.transfer_from} observations of the action "
            "(`--transfer-from`)"
        )
    if not parts:
        return ""
    return f"ATIKT learners borrow old objects' observations {'; '.join(parts)}.\n"


def _learner_notes(config: StudyConfig) -> str:
    """Return the notes on the learners' hyperparameter prior and metric transfer."""
    learner = config.learner
    text = (
        "\nLearners: maximum likelihood hyperparameters, as in the thesis (`--hyper-sd none`).\n"
        if learner.hyper_sd is None
        else f"\nLearners: maximum a posteriori hyperparameters, a Gaussian prior of sd "
        f"{learner.hyper_sd:g} (log space) around the initial kernel (`--hyper-sd`).\n"
    )
    text += _gate_notes(learner)
    if learner.metric_sd is None:
        return text + "ATIKT learners: no metric transfer (`--metric-sd none`).\n"
    until = (
        ""
        if learner.metric_until is None
        else f", while a new object has at most {learner.metric_until} observations of the action"
    )
    return text + (
        "ATIKT learners: metric transfer, the new objects' classifiers start from the old "
        f"objects' kernel with a prior of sd {learner.metric_sd:g} around it "
        f"({_METRIC_WHEN[learner.metric_check]}{until}; `--metric-sd`, `--metric-check`, "
        "`--metric-until`).\n"
    )
