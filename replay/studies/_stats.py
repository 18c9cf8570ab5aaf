"""Paired gains of ATIKT over the baseline with bootstrap intervals over independent units.

ATIKT and the baseline run on the same splits and seeds, so a gain is measured per unit (a
prior group, or a repetition where the priors are fixed) as ATIKT's headline accuracy minus the
baseline's on that unit. The reported gain is the mean over units; its 95 % interval is the
percentile bootstrap of that mean, resampling units with replacement (Efron & Tibshirani 1993,
ch. 13). Runs inside a unit share the unit's priors and are not independent, so they are
averaged first and never resampled on their own.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import polars as pl

if TYPE_CHECKING:
    from collections.abc import Sequence

#: Bootstrap resamples of every interval.
RESAMPLES = 4000
#: Coverage of the intervals.
LEVEL = 0.95
#: Headline columns: after the initial round (one observation per object and action), the
#: mean over observations 1..budget, and after the last observation.
HEADLINES = ("initial", "mean", "final")


def headline(frame: pl.DataFrame, by: Sequence[str], budget: int) -> pl.DataFrame:
    """Return accuracy after the initial observations, mean over steps 1..budget, and final.

    Accuracies are averaged over runs first per step, then over steps.
    """
    # in a fixed order (a float mean summed in another order can round a table's last digit
    # the other way)
    per_step = frame.group_by([*by, "step"], maintain_order=True).agg(pl.col("accuracy").mean())
    return (
        per_step.group_by(by, maintain_order=True)
        .agg(
            pl.col("accuracy").filter(pl.col("step") == 0).first().alias("initial"),
            pl.col("accuracy").filter(pl.col("step").is_between(1, budget)).mean().alias("mean"),
            pl.col("accuracy").sort_by("step").last().alias("final"),
        )
        .sort(by)
    )


def mean_steps(frame: pl.DataFrame, budget: int) -> str:
    """Return the steps the ``mean`` headline averages, as its label says them: ``1..8``.

    The mean is over steps 1..budget that the runs reached: where the recordings ran out
    before the budget (every run stopped at step 8 of 40) that is ``1..8``, not ``1..40``;
    where runs stopped at different steps (5 to 8), ``1..last (5-8)``. With no step beyond
    the initial round, ``1..budget`` (its cells say ``not reached``).

    Args:
        frame: Results: one row per run and step, every run with its step 0.
        budget: Observations after the initial round.
    """
    steps = frame.filter(pl.col("step") <= budget)["step"].value_counts()
    counts = dict(zip(steps["step"].to_list(), steps["count"].to_list(), strict=True))
    reached = max(counts, default=0)
    if reached == 0:
        return f"1..{budget}"
    runs = counts.get(0, 0)
    shortest = next((s - 1 for s in range(1, reached + 1) if counts.get(s, 0) < runs), reached)
    return f"1..{reached}" if shortest == reached else f"1..last ({shortest}-{reached})"


def unit_headlines(frame: pl.DataFrame, by: Sequence[str], unit: str, budget: int) -> pl.DataFrame:
    """Return the headline accuracies per (by, unit, method), runs of a unit averaged first."""
    keys = [*by, unit, "method"]
    per_step = frame.group_by([*keys, "step"], maintain_order=True).agg(pl.col("accuracy").mean())
    return per_step.group_by(keys, maintain_order=True).agg(
        pl.col("accuracy").filter(pl.col("step") == 0).first().alias("initial"),
        pl.col("accuracy").filter(pl.col("step").is_between(1, budget)).mean().alias("mean"),
        pl.col("accuracy").sort_by("step").last().alias("final"),
    )


def _interval(values: np.ndarray, rng: np.random.Generator) -> tuple[float, float]:
    """Return the percentile bootstrap interval of the mean of ``values``."""
    if values.size < 2:  # noqa: PLR2004 (one unit: no spread to resample)
        return float("nan"), float("nan")
    picks = rng.integers(0, values.size, size=(RESAMPLES, values.size))
    means = values[picks].mean(axis=1)
    tail = (1 - LEVEL) / 2
    low, high = np.quantile(means, [tail, 1 - tail])
    return float(low), float(high)


def paired_gains(
    frame: pl.DataFrame,
    by: Sequence[str],
    unit: str,
    budget: int,
    *,
    methods: tuple[str, str] = ("ATIKT", "baseline"),
    seed: int = 0,
) -> pl.DataFrame:
    """Return per ``by`` group the mean paired gain of each headline and its 95 % interval.

    Args:
        frame: Study results: one row per run and step with ``method`` and ``accuracy``.
        by: Grouping columns of the table (e.g. ``n_priors``); may be empty.
        unit: The independent unit resampled (``group``, or ``repetition``).
        budget: Observations after the initial round.
        methods: (treatment, reference) labels in ``method``.
        seed: Seed of the resampling (the same table gives the same intervals).

    Returns:
        Columns ``by``, ``units``, and per headline ``gain_<h>``, ``low_<h>``, ``high_<h>``
        (fractions; the interval is NaN with a single unit).
    """
    heads = unit_headlines(frame, by, unit, budget)
    treated, reference = methods
    keys = [*by, unit]
    paired = (
        heads.filter(pl.col("method") == treated)
        .join(heads.filter(pl.col("method") == reference), on=keys, suffix="_ref")
        .sort(keys)
    )
    rows = []
    groups = paired.partition_by(list(by), maintain_order=True) if by else [paired]
    for part in groups:
        rng = np.random.default_rng([seed, part.height])
        row: dict[str, object] = {key: part[key][0] for key in by} | {"units": part.height}
        for head in HEADLINES:
            gains = (part[head] - part[f"{head}_ref"]).to_numpy().astype(np.float64)
            low, high = _interval(gains, rng)
            row |= {f"gain_{head}": float(gains.mean()), f"low_{head}": low, f"high_{head}": high}
        rows.append(row)
    return pl.DataFrame(rows)


def gain_cells(row: dict[str, object], head: str) -> str:
    """Render one gain as ``+3.6 pts [+2.2, +4.9]`` (percentage points, 95 % interval).

    A headline no run reached (``mean`` when the recordings allowed no step beyond the
    initial round) is ``not reached``, not ``+nan pts``.
    """
    gain, low, high = (float(row[f"{k}_{head}"]) for k in ("gain", "low", "high"))  # type: ignore[arg-type]
    if np.isnan(gain):
        return "not reached"
    if np.isnan(low):
        return f"{100 * gain:+.1f} pts"
    return f"{100 * gain:+.1f} pts [{100 * low:+.1f}, {100 * high:+.1f}]"


def fusion_margins(frame: pl.DataFrame, *, seed: int = 0) -> pl.DataFrame:
    """Return per action and training size the multi-modal kernel minus the best single modality.

    The best single modality is the one of the highest mean accuracy at that action and size;
    the margin is paired per group (repetitions of a group averaged first), its interval the
    bootstrap over groups.

    Args:
        frame: Fusion study results: ``action``, ``group``, ``repetition``, ``modalities``
            (``multi-modal`` or one modality), ``samples``, ``accuracy``.
        seed: Seed of the resampling.

    Returns:
        Columns ``action``, ``samples``, ``best`` (the modality), ``margin``, ``low``,
        ``high`` (fractions).
    """
    per_group = frame.group_by("action", "samples", "group", "modalities", maintain_order=True).agg(
        pl.col("accuracy").mean()
    )
    rng = np.random.default_rng(seed)
    rows = []
    for (action, samples), part in sorted(
        per_group.group_by("action", "samples", maintain_order=True),
        key=lambda item: (str(item[0][0]), item[0][1]),
    ):
        wide = part.pivot(on="modalities", index="group", values="accuracy").sort("group")
        # sorted: the pivot's columns come in the unordered group_by's order, and a tie goes
        # to the first (the same modality in every run)
        singles = sorted(c for c in wide.columns if c not in {"group", "multi-modal"})
        if "multi-modal" not in wide.columns or not singles:
            continue
        best = max(singles, key=lambda c: float(wide[c].mean()))  # type: ignore[arg-type]
        diff = (wide["multi-modal"] - wide[best]).to_numpy()
        low, high = _interval(diff, rng)
        rows.append(
            {"action": action, "samples": samples, "best": best}
            | {"margin": float(diff.mean()), "low": low, "high": high}
        )
    return pl.DataFrame(rows)


def fusion_differences(frame: pl.DataFrame, other: pl.DataFrame, *, seed: int = 0) -> pl.DataFrame:
    """Return per action and training size one fusion study's multi-modal minus another's.

    Two runs of the fusion study on the same dataset and seed have the same groups, splits
    and single-modality fits; only the multi-modal kernel differs (its prior, combination or
    parts). The difference is paired per group (repetitions averaged first), its interval the
    bootstrap over groups, as :func:`fusion_margins`.

    Args:
        frame: The fusion study's results whose multi-modal accuracy is the minuend.
        other: The other fusion study's results (the subtrahend).
        seed: Seed of the resampling.

    Returns:
        Columns ``action``, ``samples``, ``difference``, ``low``, ``high`` (fractions).
    """

    def multi_modal(results: pl.DataFrame, name: str) -> pl.DataFrame:
        return (
            results.filter(pl.col("modalities") == "multi-modal")
            .group_by("action", "samples", "group", maintain_order=True)
            .agg(pl.col("accuracy").mean().alias(name))
        )

    paired = multi_modal(frame, "a").join(
        multi_modal(other, "b"), on=["action", "samples", "group"], how="inner"
    )
    rng = np.random.default_rng(seed)
    rows = []
    for (action, samples), part in sorted(
        paired.group_by("action", "samples", maintain_order=True),
        key=lambda item: (str(item[0][0]), item[0][1]),
    ):
        diff = (part.sort("group")["a"] - part.sort("group")["b"]).to_numpy()
        low, high = _interval(diff, rng)
        rows.append(
            {"action": action, "samples": samples, "difference": float(diff.mean())}
            | {"low": low, "high": high}
        )
    return pl.DataFrame(rows)
