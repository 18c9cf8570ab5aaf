"""Figures of runs and studies (PNG, matplotlib's non-interactive Agg backend).

Every figure follows the same rules, so a reader compares them at a glance: one colour per
method and modality in every panel and figure (:data:`COLOURS`, colour-blind safe), one
legend for the whole figure that also says what the shaded band is, accuracies in percent,
axes that say what they count (step 0 is the initial round of one observation per new
object and action), and at least :data:`DPI` dots per inch.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import matplotlib as mpl

mpl.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import polars as pl
from matplotlib.patches import Patch
from matplotlib.ticker import MaxNLocator
from scipy import stats

from replay.errors import ReplayError
from schemas import VOCABULARY, atomic_write

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from matplotlib.artist import Artist
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

_METADATA = {"Software": None}  # no version strings: the same results give the same bytes
#: Resolution of every PNG figure (dots per inch).
DPI = 150
#: Colour of each method and modality, the same in every figure (Okabe-Ito palette).
#: The feature blocks take the palette's colours in the contract's order.
COLOURS: dict[str, str] = {
    "ATIKT": "#0072B2",
    "baseline": "#D55E00",
    "multi-modal": "#000000",
} | dict(zip(VOCABULARY.features, ("#E69F00", "#CC79A7", "#009E73", "#F0E442"), strict=False))
#: Colours of other labels (actions, further modalities), in the order of their labels.
SPARE_COLOURS = ("#56B4E9", "#882255", "#999933", "#44AA99", "#332288", "#AA4499", "#888888")
#: Coverage of the shaded band: a confidence interval of the mean over runs.
CONFIDENCE = 0.95
#: Horizontal axis of learning curves over steps.
STEP_LABEL = "observations after the initial round (0: one per new object and action)"
ACCURACY_LABEL = "test accuracy (%)"
_RANK = {name: rank for rank, name in enumerate(COLOURS)}


def colour(label: str, labels: Sequence[str] = ()) -> str:
    """Return the colour of ``label``: its fixed one, else a spare colour by its rank in ``labels``.

    ``ATIKT (optimization)`` has the colour of ``ATIKT``.
    """
    base = label.split(" (", maxsplit=1)[0]
    if base in COLOURS:
        return COLOURS[base]
    others = sorted({name for name in labels if name.split(" (")[0] not in COLOURS} | {label})
    return SPARE_COLOURS[others.index(label) % len(SPARE_COLOURS)]


def curve_statistics(frame: pl.DataFrame, x: str, y: str, by: Sequence[str]) -> pl.DataFrame:
    """Return mean, standard deviation, count and the 95 % interval of the mean of ``y``.

    One row per ``by`` and ``x``, sorted. ``low``/``high`` bound the confidence interval of the
    mean over the runs (Student's t, ``n - 1`` degrees of freedom; no width for one run).
    """
    table = (
        frame.group_by([*by, x], maintain_order=True)
        .agg(
            pl.col(y).mean().alias("mean"),
            pl.col(y).std(ddof=0).alias("std"),
            pl.col(y).std(ddof=1).fill_null(0.0).alias("sd"),
            pl.len().alias("n"),
        )
        .sort([*by, x])
    )
    n = table["n"].to_numpy()
    quantile = stats.t.ppf(0.5 + CONFIDENCE / 2, np.maximum(n - 1, 1))
    half = np.where(n > 1, quantile * table["sd"].to_numpy() / np.sqrt(n), 0.0)
    return table.drop("sd").with_columns(
        (pl.col("mean") - pl.Series(half)).alias("low"),
        (pl.col("mean") + pl.Series(half)).alias("high"),
    )


def draw_curves(
    axes: Axes, stats_table: pl.DataFrame, x: str, label: str, labels: Sequence[str] = ()
) -> None:
    """Draw per value of column ``label`` its mean line (percent) and its interval band."""
    for (name,), part in stats_table.group_by([label], maintain_order=True):
        xs = part[x].to_numpy()
        shade = colour(str(name), labels)
        axes.plot(xs, 100 * part["mean"].to_numpy(), color=shade, label=str(name), linewidth=1.6)
        low, high = 100 * part["low"].to_numpy(), 100 * part["high"].to_numpy()
        axes.fill_between(xs, low, high, color=shade, alpha=0.2, linewidth=0)


def _band_note(counts: pl.Series) -> str | None:
    """Return the legend text of the shaded band and the runs it is over (None: one run)."""
    values = counts.to_numpy()
    low, high = (int(values.min()), int(values.max())) if values.size else (1, 1)
    if high <= 1:
        return None
    runs = f"{low}" if low == high else f"{low}-{high}"
    return f"band: {100 * CONFIDENCE:.0f} % interval\nof the mean over {runs} runs"


def _figure_legend(fig: Figure, axes: Sequence[Axes], note: str | None) -> None:
    """Put one legend for the whole figure beside the panels: each label once, and the band."""
    handles: dict[str, Artist] = {}
    for panel in axes:
        for handle, text in zip(*panel.get_legend_handles_labels(), strict=True):
            handles.setdefault(text, handle)
    order = sorted(handles, key=lambda text: (_RANK.get(text.split(" (")[0], len(_RANK)), text))
    shown, texts = [handles[text] for text in order], list(order)
    if note is not None:
        shown.append(Patch(color="#888888", alpha=0.3, label=note))
        texts.append(note)
    fig.legend(
        shown,
        texts,
        loc="outside right upper",
        fontsize=9,
        frameon=False,
    )


def learning_curves_figure(
    frame: pl.DataFrame,
    *,
    x: str,
    y: str = "accuracy",
    label: str = "method",
    panel: str | None = None,
    title: str = "",
    xlabel: str | None = None,
) -> Figure:
    """Return the figure of mean learning curves (percent) with their intervals, per panel.

    Args:
        frame: Long-format results with columns ``x``, ``y`` (a fraction), ``label``
            (and ``panel``); every row is one run at one ``x``.
        x: Column on the horizontal axis.
        y: Column averaged on the vertical axis, a fraction shown in percent.
        label: Column whose values become the lines (one colour each, in every panel).
        panel: Column whose values become separate panels, or None for one panel.
        title: Figure title.
        xlabel: Label of the horizontal axis (steps: what step 0 is).
    """
    panels = [None] if panel is None else frame[panel].unique(maintain_order=True).to_list()
    columns = min(len(panels), 4)
    rows = -(-len(panels) // columns)
    fig, grid = plt.subplots(
        rows,
        columns,
        figsize=(max(8.0, 3.6 * columns + 1.6), 1.4 + 3.0 * rows),
        squeeze=False,
        sharey=True,
        layout="constrained",
    )
    labels = [str(v) for v in frame[label].unique(maintain_order=True).to_list()]
    stats_all = curve_statistics(frame, x, y, [label] if panel is None else [panel, label])
    for axes, value in zip(grid.flat, panels, strict=False):
        part = stats_all if panel is None else stats_all.filter(pl.col(panel) == value)
        draw_curves(axes, part, x, label, labels)
        axes.set_title("" if value is None else f"{panel} {value}", fontsize=10)
        axes.set_ylim(0, 100)
        axes.xaxis.set_major_locator(MaxNLocator(integer=True))
        axes.grid(visible=True, alpha=0.3)
    for axes in grid.flat[len(panels) :]:
        axes.set_visible(False)
    fig.supxlabel(xlabel or (STEP_LABEL if x == "step" else x), fontsize=10)
    fig.supylabel(ACCURACY_LABEL if y == "accuracy" else f"{y} (%)", fontsize=10)
    _figure_legend(fig, list(grid.flat[: len(panels)]), _band_note(stats_all["n"]))
    if title:
        fig.suptitle(title)
    return fig


def save_figure(fig: Figure, path: Path) -> Path:
    """Write ``fig`` as PNG at :data:`DPI` and close it.

    Raises:
        ReplayError: The file cannot be written.
    """
    try:
        atomic_write(path, lambda out: fig.savefig(out, format="png", dpi=DPI, metadata=_METADATA))
    except OSError as err:
        msg = f"{path}: cannot write the figure ({err.strerror}); check free space and the --out"
        raise ReplayError(msg) from err
    finally:
        plt.close(fig)
    return path


def plot_learning_curves(
    frame: pl.DataFrame,
    path: Path,
    *,
    x: str,
    y: str = "accuracy",
    label: str = "method",
    panel: str | None = None,
    title: str = "",
    xlabel: str | None = None,
) -> Path:
    """Plot learning curves (see :func:`learning_curves_figure`) and write them as PNG.

    Returns:
        ``path``.

    Raises:
        ReplayError: The file cannot be written.
    """
    figure = learning_curves_figure(
        frame, x=x, y=y, label=label, panel=panel, title=title, xlabel=xlabel
    )
    return save_figure(figure, path)
