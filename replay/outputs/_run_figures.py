"""Figures of one learning run as PNG (the same quantities as its rerun view), for papers.

:func:`plot_run` writes into a directory:

- ``accuracy.png``: test accuracy (%) after every step, all actions together and per action;
- ``decisions.png``: which (object, action) was chosen at every step (filled: the most
  uncertain pair, hollow: a random exploration), and below it the transfer coefficient rho
  of the explored object's classifier, labelled with the chosen prior object;
- ``weights.png``: the explored classifier's modality weights per step (stacked, sum 1);
- ``entropy.png``: the entropy map before every decision, one row per (action, object).

Each action and modality has one colour in every figure (``replay.outputs._plots.colour``);
each figure has one legend; step 0 is the initial round (one observation per new object and
action). The PNGs carry no version string: the same run gives the same bytes.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import matplotlib as mpl

mpl.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import polars as pl
from matplotlib.ticker import MaxNLocator

from replay.errors import ReplayError
from replay.outputs._plots import ACCURACY_LABEL, DPI, STEP_LABEL, colour
from schemas import atomic_write

if TYPE_CHECKING:
    from pathlib import Path

    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from replay.learning._run_history import LearnRun

_METADATA = {"Software": None}
_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*")


def _save(fig: Figure, path: Path) -> Path:
    """Write a figure as PNG (integer steps on every x axis) and close it.

    Raises:
        ReplayError: The file cannot be written.
    """
    for axes in fig.axes:
        if axes.get_xlabel() in {"step", STEP_LABEL}:
            axes.xaxis.set_major_locator(MaxNLocator(integer=True))
    try:
        atomic_write(path, lambda out: fig.savefig(out, format="png", dpi=DPI, metadata=_METADATA))
    except OSError as err:
        msg = f"{path}: cannot write the figure ({err.strerror}); check the --figures directory"
        raise ReplayError(msg) from err
    finally:
        plt.close(fig)
    return path


def plot_accuracy(run: LearnRun, path: Path) -> Path:
    """Plot the test accuracy after every step (all actions and each action)."""
    frame = run.frame.filter(pl.col("accuracy").is_not_null())
    fig, axes = plt.subplots(figsize=(7.0, 4.4), layout="constrained")
    steps = frame["step"].to_numpy()
    every = 100 * frame["accuracy"].to_numpy()
    axes.plot(steps, every, color="black", linewidth=2.0, label="all actions")
    for action in run.actions:
        values = 100 * frame[f"accuracy_{action}"].cast(pl.Float64).to_numpy()
        axes.plot(steps, values, color=_action_colour(run, action), linewidth=1.2, label=action)
    axes.set_xlabel(STEP_LABEL)
    axes.set_ylabel(ACCURACY_LABEL)
    axes.set_ylim(-2, 102)
    axes.grid(visible=True, alpha=0.3)
    fig.legend(loc="outside right upper", fontsize=8, frameon=False)
    axes.set_title("test accuracy of the run (held-out recordings)")
    return _save(fig, path)


def _action_colour(run: LearnRun, action: str) -> str:
    """Return the colour of an action, the same in every figure of the run."""
    return colour(action, run.actions)


def _decision_points(axes: Axes, run: LearnRun, decisions: pl.DataFrame) -> None:
    """Draw one marker per decision at (step, object), by action, hollow when explored."""
    rows = {obj: i for i, obj in enumerate(run.objects)}
    actions = list(run.actions) or sorted(set(decisions["action"].to_list()))
    for index, action in enumerate(actions):
        part = decisions.filter(pl.col("action") == action)
        if part.is_empty():
            continue
        ys = np.array([rows.setdefault(o, len(rows)) for o in part["object"].to_list()])
        explored = part["explored"].to_numpy()
        color = _action_colour(run, action)
        marker = _MARKERS[index % len(_MARKERS)]
        for mask, face in ((~explored, color), (explored, "none")):
            axes.scatter(
                part["step"].to_numpy()[mask],
                ys[mask],
                marker=marker,
                s=46,
                facecolors=face,
                edgecolors=color,
                label=action if face != "none" else None,
            )
    axes.set_yticks(range(len(rows)), list(rows))
    axes.set_ylim(-0.6, len(rows) - 0.4)
    axes.set_ylabel("object")
    axes.grid(visible=True, alpha=0.3)


def _rho_bars(axes: Axes, decisions: pl.DataFrame) -> None:
    """Draw rho per decision, labelled with the transferred prior object."""
    steps = decisions["step"].to_numpy()
    rho = decisions["rho"].fill_null(0.0).to_numpy()
    axes.bar(steps, rho, color="C7", width=0.7)
    for step, value, prior in zip(steps, rho, decisions["prior"].to_list(), strict=True):
        if prior:
            axes.text(step, value + 0.02, prior, rotation=90, fontsize=7, ha="center", va="bottom")
    axes.set_ylim(0.0, 1.6)
    axes.set_ylabel("rho (prior)")
    axes.set_xlabel(STEP_LABEL)
    axes.grid(visible=True, alpha=0.3)


def plot_decisions(run: LearnRun, path: Path) -> Path:
    """Plot the decision timeline and the chosen prior's rho per step."""
    decisions = run.decisions
    fig, (top, bottom) = plt.subplots(
        2,
        1,
        figsize=(8.0, 6.0),
        sharex=True,
        gridspec_kw={"height_ratios": [3, 2]},
        layout="constrained",
    )
    _decision_points(top, run, decisions)
    top.set_title("decisions (filled: most uncertain pair, hollow: random exploration)")
    fig.legend(loc="outside right upper", fontsize=8, title="action", frameon=False)
    _rho_bars(bottom, decisions)
    return _save(fig, path)


def plot_weights(run: LearnRun, path: Path) -> Path:
    """Plot the explored classifier's modality weights per step, stacked."""
    decisions = run.decisions
    fig, axes = plt.subplots(figsize=(7.0, 4.0), layout="constrained")
    if {"weights", "modalities"} <= set(decisions.columns):
        table = decisions.select("step", "modalities", "weights").explode("modalities", "weights")
        table = table.drop_nulls().pivot(on="modalities", index="step", values="weights")
        table = table.sort("step").fill_null(0.0)
        bottom = np.zeros(table.height)
        for modality in table.columns[1:]:
            values = table[modality].to_numpy()
            shade = colour(modality, table.columns[1:])
            steps = table["step"].to_numpy()
            axes.bar(steps, values, bottom=bottom, width=0.8, label=modality, color=shade)
            bottom += values
        fig.legend(loc="outside right upper", fontsize=8, title="modality", frameon=False)
    axes.set_xlabel(STEP_LABEL)
    axes.set_ylabel("modality weight")
    axes.set_ylim(0.0, 1.05)
    axes.set_title("modality weights of the explored classifier")
    return _save(fig, path)


def plot_entropy(run: LearnRun, path: Path) -> Path:
    """Plot the entropy map before every decision: rows (action, object), columns steps."""
    decisions = run.decisions
    rows = (
        [r for r in decisions.iter_rows(named=True) if r["entropies"]]
        if "entropies" in decisions.columns
        else []
    )
    fig, axes = plt.subplots(
        figsize=(8.0, 1.2 + 0.32 * max(len(run.actions) * len(run.objects), 4)),
        layout="constrained",
    )
    if rows:
        maps = np.array([r["entropies"] for r in rows], dtype=np.float64)
        n_steps, n_actions, n_objects = maps.shape
        image = maps.reshape(n_steps, n_actions * n_objects).T
        steps = [int(r["step"]) for r in rows]
        shown = axes.imshow(
            image,
            aspect="auto",
            cmap="viridis",
            interpolation="nearest",
            extent=(steps[0] - 0.5, steps[-1] + 0.5, image.shape[0] - 0.5, -0.5),
        )
        labels = [f"{a} {o}" for a in run.actions[:n_actions] for o in run.objects[:n_objects]]
        axes.set_yticks(range(len(labels)), labels, fontsize=7)
        fig.colorbar(shown, ax=axes, label="mean posterior entropy")
    axes.set_xlabel(STEP_LABEL)
    axes.set_title("entropy map before each decision")
    return _save(fig, path)


def plot_run(run: LearnRun, directory: Path) -> tuple[Path, ...]:
    """Write the run's figures (accuracy, decisions, weights, entropy) as PNG.

    Args:
        run: The learning run.
        directory: Where to write; created if needed.

    Returns:
        The written files.

    Raises:
        ReplayError: The directory or a file cannot be written.
    """
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        msg = f"{directory}: cannot create the figures directory ({err.strerror})"
        raise ReplayError(msg) from err
    return (
        plot_accuracy(run, directory / "accuracy.png"),
        plot_decisions(run, directory / "decisions.png"),
        plot_weights(run, directory / "weights.png"),
        plot_entropy(run, directory / "entropy.png"),
    )
