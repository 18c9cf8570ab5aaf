"""Figures of runs and studies (PNG, matplotlib's non-interactive Agg backend)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import matplotlib as mpl

mpl.use("Agg")
import matplotlib.pyplot as plt
import polars as pl

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from matplotlib.axes import Axes

_METADATA = {"Software": None}  # no version strings: the same results give the same bytes


def curve_statistics(frame: pl.DataFrame, x: str, y: str, by: Sequence[str]) -> pl.DataFrame:
    """Return mean, standard deviation and count of ``y`` per ``by`` and ``x``, sorted."""
    return (
        frame.group_by([*by, x])
        .agg(
            pl.col(y).mean().alias("mean"),
            pl.col(y).std(ddof=0).alias("std"),
            pl.len().alias("n"),
        )
        .sort([*by, x])
    )


def draw_curves(axes: Axes, stats: pl.DataFrame, x: str, label: str) -> None:
    """Draw one mean line with a +-1 standard deviation band per value of column ``label``."""
    for (name,), part in stats.group_by([label], maintain_order=True):
        xs = part[x].to_numpy()
        mean = part["mean"].to_numpy()
        std = part["std"].fill_null(0.0).to_numpy()
        (line,) = axes.plot(xs, mean, label=str(name), linewidth=1.6)
        axes.fill_between(xs, mean - std, mean + std, color=line.get_color(), alpha=0.2)


def plot_learning_curves(
    frame: pl.DataFrame,
    path: Path,
    *,
    x: str,
    y: str = "accuracy",
    label: str = "method",
    panel: str | None = None,
    title: str = "",
    xlabel: str = "number of observations",
) -> Path:
    """Plot mean +- std learning curves, one panel per value of ``panel``; write a PNG.

    Args:
        frame: Long-format results with columns ``x``, ``y``, ``label`` (and ``panel``).
        path: The PNG to write.
        x: Column on the horizontal axis.
        y: Column averaged on the vertical axis.
        label: Column whose values become the lines of a panel.
        panel: Column whose values become separate panels, or None for one panel.
        title: Figure title.
        xlabel: Label of the horizontal axis.

    Returns:
        ``path``.
    """
    panels = [None] if panel is None else frame[panel].unique(maintain_order=True).to_list()
    columns = min(len(panels), 4)
    rows = -(-len(panels) // columns)
    fig, axes_grid = plt.subplots(
        rows, columns, figsize=(4.2 * columns, 3.3 * rows), squeeze=False, sharey=True
    )
    for axes, value in zip(axes_grid.flat, panels, strict=False):
        part = frame if panel is None else frame.filter(pl.col(panel) == value)
        draw_curves(axes, curve_statistics(part, x, y, [label]), x, label)
        axes.set_title("" if value is None else str(value), fontsize=10)
        axes.set_xlabel(xlabel)
        axes.grid(visible=True, alpha=0.3)
    for axes in axes_grid.flat[len(panels) :]:
        axes.set_visible(False)
    axes_grid[0, 0].set_ylabel(y)
    axes_grid[0, 0].legend(fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110, metadata=_METADATA)
    plt.close(fig)
    return path
