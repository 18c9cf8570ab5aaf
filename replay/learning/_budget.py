"""What a run says about its budget and its held-out trials.

A run makes ``budget`` steps unless it stops first (``atikt.ActiveLearner.done``): offline,
when every (new object, action)'s pool of trials is used up (half of each pair's recordings
are held out for testing, and the initial round takes one more), or, with a ``patience``, when
the uncertainty stopped improving. A run that stops short says so, in a study's summary and
on the command line; a rig's pool is never used up.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from replay.errors import ReplayError
from replay.learning._executors import Split

if TYPE_CHECKING:
    from pathlib import Path

    import polars as pl

    from atikt import LearnerOptions

#: Held-out trials per (new object, action) a live run records first (``--test-trials``).
LIVE_TEST_TRIALS = 3


def steps_short(
    reached: int,
    budget: int,
    *,
    pool: bool = True,
    patience: int | None = None,
    markdown: bool = False,
) -> str:
    """Return the sentence that a run made ``reached`` of its ``budget`` steps (empty: all).

    It says why the run stopped: the pool of trials ran out (``pool``: a run over recordings),
    the uncertainty stopped improving for ``patience`` steps (possible from that many steps
    on), or either; and how to get the budget.

    Args:
        reached: The last step made (0: the initial round only).
        budget: The learner's budget.
        pool: The observations came from a finite pool of recordings (not a rig, nor the
            replay of a live session, which took its observations from a rig).
        patience: The learner's ``patience`` (None: it never stops early on its own).
        markdown: Options in backticks (a summary), else plain (a command's line).
    """
    if reached >= budget:
        return ""
    option = "`--budget`" if markdown else "--budget"
    after = "after the initial round" if reached == 0 else f"after step {reached}"
    ran_out = f"the pool of trials ran out {after}"
    fix = f"give more trials per object and action, or a smaller {option}"
    stalled = (
        f"the uncertainty did not improve for {patience} steps (the learner's patience)"
        if patience is not None and reached >= patience
        else ""
    )
    if pool and not stalled:
        return f"the recordings allowed {reached} of the budget's {budget} steps: {ran_out}; {fix}"
    made = f"the run made {reached} of the budget's {budget} steps"
    if pool:  # either could have stopped it
        return f"{made}: {ran_out}, or {stalled}"
    return f"{made}: {stalled}" if stalled else made


def budget_line(frame: pl.DataFrame, learner: LearnerOptions, *, pool: bool) -> str:
    """Return the line a learning run prints when it made fewer steps than its budget.

    Args:
        frame: The run's history (one row per step, step 0 the initial round).
        learner: The run's learner options (its budget and patience).
        pool: The run drew from a pool of recordings (offline, not a session's replay).

    Returns:
        E.g. ``the recordings allowed 0 of the budget's 6 steps: the pool of trials ran out
        after the initial round; give more trials per object and action, or a smaller
        --budget``; empty when the run made its budget.
    """
    reached = int(frame["step"].max()) if frame.height else 0  # type: ignore[arg-type]
    return steps_short(reached, learner.budget, pool=pool, patience=learner.patience)


def held_out_trials(value: int | None, *, live: bool, session: Path | None) -> int | None:
    """Return the held-out trials per (object, action) of a run (``--test-trials``).

    Live, the run records them first (default :data:`LIVE_TEST_TRIALS`). The replay of a live
    session uses the session's own: a different number is refused, as it would be ignored.
    Offline over recordings, half of each pair's recordings are held out, and the option is
    refused rather than ignored.

    Raises:
        ReplayError: ``--test-trials`` where it would be ignored, in one line; or the
            session's manifest cannot be read.
    """
    if live:
        return LIVE_TEST_TRIALS if value is None else value
    if value is None:
        return None
    if session is None:
        msg = (
            f"--test-trials {value} applies to a live run (--rig/--rig-config); offline, half "
            "of each object and action's recordings are held out for testing: leave it out"
        )
        raise ReplayError(msg)
    held = {len(trials) for trials in Split.from_session(session).test.values()}
    if held != {value}:
        counts = "/".join(str(n) for n in sorted(held)) or "no"
        msg = (
            f"--test-trials {value}: the session {session} held out {counts} per object and "
            "action, and its replay uses them; leave --test-trials out"
        )
        raise ReplayError(msg)
    return value
