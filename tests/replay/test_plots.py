"""Figures a reviewer accepts: one colour per label everywhere, one legend, percent, dpi."""

from __future__ import annotations

import struct
from typing import TYPE_CHECKING

import matplotlib.pyplot as plt
import numpy as np
import polars as pl
import pytest
from matplotlib.colors import to_hex
from scipy import stats

from replay.outputs._plots import (
    COLOURS,
    DPI,
    colour,
    curve_statistics,
    learning_curves_figure,
    plot_learning_curves,
)

if TYPE_CHECKING:
    from pathlib import Path

    from matplotlib.figure import Figure


def png_size_and_dpi(path: Path) -> tuple[int, int, float]:
    """Return width and height in pixels and dots per inch from a PNG's IHDR and pHYs chunks."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = struct.unpack(">II", data[16:24])
    at = data.index(b"pHYs")
    per_metre, _, unit = struct.unpack(">IIB", data[at + 4 : at + 13])
    assert unit == 1  # metres
    return width, height, per_metre * 0.0254


def _fusion(seed: int = 0) -> pl.DataFrame:
    rng = np.random.default_rng(seed)
    rows = [
        {"action": action, "group": group, "modalities": modality, "samples": samples}
        | {"accuracy": float(rng.uniform(0.3, 0.9))}
        for action, modalities in (("P1", ("force", "thermal")), ("S2", ("texture", "thermal")))
        for group in range(4)
        for modality in ("multi-modal", *modalities)
        for samples in (1, 2, 3)
    ]
    return pl.DataFrame(rows)


def _transfer(seed: int = 0) -> pl.DataFrame:
    rng = np.random.default_rng(seed)
    rows = [
        {"method": method, "group": group, "step": step, "accuracy": float(rng.uniform(0.4, 1))}
        for method in ("ATIKT", "baseline")
        for group in range(5)
        for step in range(4)
    ]
    return pl.DataFrame(rows)


def _lines_by_label(fig: Figure) -> dict[str, set[str]]:
    found: dict[str, set[str]] = {}
    for axes in fig.axes:
        for line in axes.get_lines():
            found.setdefault(str(line.get_label()), set()).add(to_hex(line.get_color()))
    return found


def test_fusion_figure_has_one_colour_per_modality_and_one_legend() -> None:
    fig = learning_curves_figure(
        _fusion(), x="samples", label="modalities", panel="action", xlabel="samples"
    )
    try:
        colours = _lines_by_label(fig)
        assert set(colours) == {"multi-modal", "force", "thermal", "texture"}
        for label, used in colours.items():
            assert used == {COLOURS[label].lower()}, label  # the same in every panel
        assert len({c for used in colours.values() for c in used}) == len(colours)
        assert len(fig.legends) == 1
        assert all(axes.get_legend() is None for axes in fig.axes)
        texts = [t.get_text() for t in fig.legends[0].get_texts()]
        assert sorted(texts[:-1]) == sorted(colours)  # each label once
        assert texts[-1] == "band: 95 % interval\nof the mean over 4 runs"
    finally:
        plt.close(fig)


def test_curves_are_percent_and_the_band_is_the_computed_interval() -> None:
    frame = _transfer()
    fig = learning_curves_figure(frame, x="step")
    try:
        (axes,) = fig.axes
        assert fig.get_supylabel() == "test accuracy (%)"
        assert "0: one per new object and action" in fig.get_supxlabel()
        assert axes.get_ylim() == (0, 100)
        atikt = frame.filter(pl.col("method") == "ATIKT", pl.col("step") == 2)["accuracy"]
        line = next(x for x in axes.get_lines() if x.get_label() == "ATIKT")
        assert np.asarray(line.get_ydata())[2] == pytest.approx(100 * atikt.to_numpy().mean())
        half = stats.t.ppf(0.975, 4) * atikt.to_numpy().std(ddof=1) / np.sqrt(5)
        table = curve_statistics(frame, "step", "accuracy", ["method"])
        row = table.filter(pl.col("method") == "ATIKT", pl.col("step") == 2).row(0, named=True)
        mean = float(atikt.to_numpy().mean())
        assert (row["low"], row["high"]) == pytest.approx((mean - half, mean + half))
        band = np.asarray(axes.collections[0].get_paths()[0].vertices)[:, 1]
        lowest = table.filter(pl.col("method") == "ATIKT")["low"].to_numpy().min()
        assert band.min() == pytest.approx(100 * lowest)
    finally:
        plt.close(fig)


def test_png_is_at_least_150_dpi_and_readable(tmp_path: Path) -> None:
    path = plot_learning_curves(
        _fusion(), tmp_path / "fusion.png", x="samples", label="modalities", panel="action"
    )
    width, height, dpi = png_size_and_dpi(path)
    assert dpi == pytest.approx(DPI, abs=0.5)
    assert DPI >= 150
    assert width >= 1000
    assert height >= 600


def test_labels_outside_the_fixed_map_get_distinct_spare_colours() -> None:
    labels = ("P1", "S2", "C1")
    shades = {colour(label, labels) for label in labels}
    assert len(shades) == 3
    assert not shades & set(COLOURS.values())
    assert colour("ATIKT (optimization)") == COLOURS["ATIKT"]


def test_one_run_has_no_band_in_the_legend() -> None:
    one = _transfer().filter(pl.col("group") == 0, pl.col("method") == "ATIKT")
    fig = learning_curves_figure(one, x="step")
    try:
        texts = [t.get_text() for t in fig.legends[0].get_texts()]
        assert texts == ["ATIKT"]
    finally:
        plt.close(fig)
