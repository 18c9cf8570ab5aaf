"""The transfer check: does transfer help on this lab's own known objects, and from when?

Before robot time is spent on new objects, the objects a lab already knows answer the
question. Each task takes some known objects as if they were new (``pseudo-new``) and others
as their priors, and learns them with ATIKT and with the no-transfer baseline on the same
splits and seeds (the transfer study's task, :func:`~replay.studies._transfer.run_transfer_task`).
The summary says, per number of observations, ATIKT's paired gain with its 95 % interval over
the tasks, and whether transfer helped (the interval above 0), hurt (below 0) or neither.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import polars as pl

from replay.studies._report import Report
from replay.studies._running import (
    ATIKT,
    BASELINE,
    Study,
    StudyConfig,
    derive_seed,
    min_old,
    too_small,
)
from replay.studies._stats import RESAMPLES, _interval, mean_steps
from replay.studies._transfer import TransferTask, run_transfer_task

#: Known objects learned as new ones in each task (fewer when the lab knows fewer objects).
PSEUDO_NEW = 3
#: Steps (actively collected observations after the first of each object and action) shown.
SHOWN_STEPS = (0, 1, 2, 5, 10, 20, 40)


def known_objects(config: StudyConfig) -> tuple[str, ...]:
    """The lab's known objects: every object of the study (new and old roles), sorted.

    All of them have labelled recordings, which is all the check needs.
    """
    return tuple(sorted({*config.new, *config.old}))


def check_tasks(frame: pl.DataFrame, config: StudyConfig) -> list[TransferTask]:
    """Return one task per random split of the known objects into pseudo-new and priors.

    Each task draws ``PSEUDO_NEW`` pseudo-new objects (at least 2) and up to
    ``config.group_size`` priors from the rest (at least the transfer strategy's minimum).

    Raises:
        ReplayError: Too few known objects or no action.
    """
    known = known_objects(config)
    fewest = max(min_old(config), 2)
    if len(known) < 2 + fewest or not config.actions:
        has = f"{len(known)} known objects and {len(config.actions)} actions"
        needs = f">= {2 + fewest} known objects (2 learned as new, {fewest} as priors), >= 1 action"
        study = "transfer-check"
        raise too_small(study, has, needs)
    n_new = max(2, min(PSEUDO_NEW, len(known) - fewest))
    n_prior = max(fewest, min(config.group_size, len(known) - n_new))
    tasks: list[TransferTask] = []
    for number, (new, priors) in enumerate(_splits(known, n_new, n_prior, config)):
        tasks.append(
            TransferTask(
                frame=frame.filter(pl.col("object_id").is_in([*new, *priors])),
                new=new,
                priors=priors,
                actions=(config.actions,),
                trials=config.trials,
                seed=derive_seed(config.seed, "transfer-check-task", number),
                learner=config.learner,
                labels={"group": number, "pseudo_new": ",".join(new)},
                features=config.features,
            )
        )
    return tasks


def _splits(
    known: tuple[str, ...], n_new: int, n_prior: int, config: StudyConfig
) -> list[tuple[tuple[str, ...], tuple[str, ...]]]:
    """Return ``config.groups`` distinct random splits (pseudo-new, priors), as many as exist.

    A split drawn twice would count twice in the interval, which resamples tasks as if they
    were independent: with few known objects (4 give 6 splits) ten draws repeat some, and the
    interval came out narrower than the data allow. Drawn in order from seeded generators;
    a repeat is skipped.
    """
    total = math.comb(len(known), n_new) * math.comb(len(known) - n_new, n_prior)
    wanted = min(config.groups, total)
    seen: list[tuple[tuple[str, ...], tuple[str, ...]]] = []
    for attempt in itertools.count():
        if len(seen) == wanted or attempt >= 1000 * wanted:  # the cap: never reached in practice
            break
        rng = np.random.default_rng(derive_seed(config.seed, "transfer-check", attempt))
        order = [known[i] for i in rng.permutation(len(known))]
        split = tuple(sorted(order[:n_new])), tuple(sorted(order[n_new : n_new + n_prior]))
        if split not in seen:
            seen.append(split)
    return seen


def step_gains(frame: pl.DataFrame, budget: int, *, seed: int = 0) -> pl.DataFrame:
    """ATIKT minus baseline per shown step and over the steps 1..budget reached, per task.

    Runs of a task are averaged first; the interval is the percentile bootstrap over tasks.

    Returns:
        Columns ``step`` (str: a number, or the mean's label, ``mean 1..8`` where the
        recordings allowed 8 steps of the budget: :func:`~replay.studies._stats.mean_steps`),
        ``tasks``, ``gain``, ``low``, ``high`` (fractions), ``verdict``; a step no run reached
        is left out.
    """
    per = frame.group_by(["group", "method", "step"], maintain_order=True).agg(
        pl.col("accuracy").mean()
    )
    wide = per.pivot(on="method", index=["group", "step"], values="accuracy").sort(
        ["group", "step"]
    )
    wide = wide.with_columns((pl.col(ATIKT) - pl.col(BASELINE)).alias("gain"))
    rows: list[dict[str, object]] = []
    shown = [s for s in SHOWN_STEPS if s <= budget]
    selections: list[tuple[str, pl.Expr]] = [(str(s), pl.col("step") == s) for s in shown]
    mean = f"mean {mean_steps(frame, budget)}"
    selections.append((mean, pl.col("step").is_between(1, budget)))
    for name, where in selections:
        gains = (
            wide.filter(where)
            .group_by("group", maintain_order=True)
            .agg(pl.col("gain").mean())
            .sort("group")
        )
        values = gains["gain"].to_numpy().astype(np.float64)
        if values.size == 0:  # no run reached this step (the recordings ran out first)
            continue
        rng = np.random.default_rng([seed, values.size, len(rows)])
        low, high = _interval(values, rng)
        rows.append(
            {
                "step": name,
                "tasks": int(values.size),
                "gain": float(values.mean()),
                "low": low,
                "high": high,
                "verdict": verdict(low, high),
            }
        )
    return pl.DataFrame(rows)


def verdict(low: float, high: float) -> str:
    """``helped`` (interval above 0), ``hurt`` (below 0), else ``no clear difference``."""
    if np.isnan(low):
        return "one task: no interval"
    if low > 0.0:
        return "helped"
    if high < 0.0:
        return "hurt"
    return "no clear difference"


def _table(frame: pl.DataFrame, config: StudyConfig) -> str:
    """The summary's table: gain and verdict per number of observations."""
    gains = step_gains(frame, config.budget, seed=config.seed)
    lines = [
        "| observations | tasks | ATIKT - baseline (points) [95 % interval] | transfer |",
        "|---|---|---|---|",
    ]
    for row in gains.iter_rows(named=True):
        step = row["step"]
        label = (
            "1 per object and action"
            if step == "0"
            else (f"first + {step}" if step.isdigit() else step)
        )
        cell = f"{100 * row['gain']:+.1f}"
        if not np.isnan(row["low"]):
            cell += f" [{100 * row['low']:+.1f}, {100 * row['high']:+.1f}]"
        lines.append(f"| {label} | {row['tasks']} | {cell} | {row['verdict']} |")
    note = (
        f"Known objects learned as new ones ({PSEUDO_NEW} per task, at least 2), the others "
        f"as priors; {ATIKT} minus {BASELINE} test accuracy in percentage points, paired on "
        f"the same splits, mean over tasks; [95 % interval]: percentile bootstrap over tasks "
        f'({RESAMPLES} resamples). "first + k": after k actively collected observations '
        "beyond the first of each (object, action). helped / hurt: the interval lies above / "
        "below 0."
    )
    return "\n".join(lines) + "\n\n" + note


def _rho(frame: pl.DataFrame, config: StudyConfig) -> str:  # noqa: ARG001
    """Share of ATIKT's steps that transferred, and their rho."""
    atikt = frame.filter(pl.col("method") == ATIKT)
    if "rho" not in atikt.columns or atikt.height == 0:
        return ""
    steps = atikt.filter(pl.col("step") >= 1)
    used = steps.filter(pl.col("rho") > 0)
    share = used.height / steps.height if steps.height else 0.0
    text = f"{ATIKT} transferred in {share:.0%} of its {steps.height} collected observations"
    if used.height:
        q = used["rho"].quantile
        text += f" (rho median {q(0.5):.2f}, 10-90 % {q(0.1):.2f}-{q(0.9):.2f})"
    return text + "."


def _design(frame: pl.DataFrame, config: StudyConfig) -> str:
    """The summary's sentence on the design."""
    tasks = frame.select("group").n_unique()
    known = ", ".join(known_objects(config))
    return (
        f"{tasks} tasks over the known objects ({known}), each a distinct split of them into "
        "pseudo-new objects and priors (fewer than asked when fewer exist); budget "
        f"{config.budget}; test accuracy of all actions together."
    )


TRANSFER_CHECK = Study(
    name="transfer-check",
    title="Does transfer help on the known objects?",
    tasks=check_tasks,
    run=run_transfer_task,
    labels=("method", "group", "trial", "step"),
    report=Report((_design, _table, _rho)),
)
