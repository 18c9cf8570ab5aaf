from pathlib import Path

import numpy as np
import polars as pl
import pytest

from replay.studies._registry import STUDIES
from replay.studies._report import steps_note, summary
from replay.studies._running import StudyConfig
from replay.studies._stats import gain_cells, paired_gains


def _results(gains_by_group: list[float], runs: int = 3, budget: int = 4) -> pl.DataFrame:
    rows = []
    rng = np.random.default_rng(0)
    for group, gain in enumerate(gains_by_group):
        for trial in range(runs):
            for step in range(budget + 1):
                base = 0.5 + 0.05 * step + 0.01 * rng.standard_normal()
                rows.append(
                    {"group": group, "trial": trial, "step": step}
                    | {"method": "baseline", "accuracy": base}
                )
                rows.append(
                    {"group": group, "trial": trial, "step": step}
                    | {"method": "ATIKT", "accuracy": base + gain}
                )
    return pl.DataFrame(rows)


def test_gain_is_the_paired_mean_over_groups_with_a_bootstrap_interval() -> None:
    gains = [0.02, 0.05, 0.01, 0.04, 0.03, 0.06, 0.00, 0.03]
    table = paired_gains(_results(gains), [], "group", budget=4, seed=3)
    row = table.row(0, named=True)
    assert row["units"] == len(gains)
    for head in ("initial", "mean", "final"):
        assert row[f"gain_{head}"] == pytest.approx(np.mean(gains))
        assert row[f"low_{head}"] < np.mean(gains) < row[f"high_{head}"]
        assert row[f"high_{head}"] - row[f"low_{head}"] < 0.04
    again = paired_gains(_results(gains), [], "group", budget=4, seed=3)
    assert again.equals(table)
    assert gain_cells(row, "mean").startswith("+3.0 pts [+")


def test_a_single_unit_has_no_interval() -> None:
    row = paired_gains(_results([0.1]), [], "group", budget=4).row(0, named=True)
    assert np.isnan(row["low_mean"])
    assert gain_cells(row, "mean") == "+10.0 pts"


def test_no_gain_gives_an_interval_around_zero() -> None:
    row = paired_gains(_results([0.03, -0.03] * 5), [], "group", budget=4).row(0, named=True)
    assert row["low_final"] < 0 < row["high_final"]


def test_recordings_that_ran_out_after_the_initial_round_print_no_nan() -> None:
    """Too few trials: every run stops at step 0; the mean over 1..budget was never reached."""
    results = _results([0.02, 0.05], budget=0)  # only step 0, as from 3 trials per object
    row = paired_gains(results, [], "group", budget=10, seed=0).row(0, named=True)
    assert gain_cells(row, "mean") == "not reached"
    assert gain_cells(row, "initial").startswith("+3.5 pts [")
    study = STUDIES["transfer"]
    config = StudyConfig(out=Path("out"), seed=0, workers=1)
    text = summary(study, results.with_columns(actions=pl.lit("all")), config)
    assert "nan" not in text
    assert (
        f"> The recordings allowed 0 of the budget's {config.budget} steps: the pool of trials "
        "ran out after the initial round; give more trials per object and action, or a "
        "smaller `--budget`." in text
    )
    assert steps_note(_results([0.02], budget=3), 3) == ""  # the budget ran: no note


def test_the_headlines_of_one_table_are_the_same_floats_every_time() -> None:
    """A mean summed in another order can round a summary's last digit the other way (a
    study's summary read +15.4 or +15.5 from one run to the next on the same results): the
    headlines of one table are the same floats every time they are computed."""
    from replay.studies._stats import headline, unit_headlines  # noqa: PLC0415

    rng = np.random.default_rng(1)
    rows = [
        {"group": g, "method": m, "run": r, "step": s, "accuracy": int(rng.integers(0, 50)) / 49}
        for g in range(5)
        for m in ("ATIKT", "baseline")
        for r in range(3)
        for s in range(41)
    ]
    frame = pl.DataFrame(rows)
    seen = {
        (
            *headline(frame, ["method"], 40)["mean"].to_list(),
            *unit_headlines(frame, [], "group", 40).sort("group", "method")["mean"].to_list(),
            *paired_gains(frame, [], "group", 40)["gain_mean"].to_list(),
        )
        for _ in range(20)
    }
    assert len(seen) == 1
