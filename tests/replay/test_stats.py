import numpy as np
import polars as pl
import pytest

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
