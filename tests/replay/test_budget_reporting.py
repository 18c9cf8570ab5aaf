"""A run or a study that made fewer steps than its budget says so, and labels what it averaged.

The recordings allow a run as many steps as its pools of trials hold (half of each object and
action's recordings are held out for testing): a table's "mean 1..budget" then averages only
the steps the runs made, and names them; ``learn`` prints the line the studies' summaries hold;
``--test-trials`` is refused where it would be ignored.
"""

from pathlib import Path

import numpy as np
import polars as pl
import pytest

from replay.cli._main import main
from replay.errors import ReplayError
from replay.learning._budget import LIVE_TEST_TRIALS, held_out_trials, steps_short
from replay.learning._executors import SESSION_NAME
from replay.learning._session import DEFAULT_LEARNER
from replay.outputs.readme_tables import transfer_block
from replay.studies._registry import STUDIES
from replay.studies._report import Comparisons, summary
from replay.studies._running import ATIKT, BASELINE, StudyConfig
from replay.studies._transfer_check import step_gains


def _results(last_step: dict[int, int]) -> pl.DataFrame:
    """Paired results of groups whose runs stop at ``last_step[group]``; gain 0.01 x step."""
    rng = np.random.default_rng(0)
    rows = []
    for group, last in last_step.items():
        for step in range(last + 1):
            base = 0.5 + 0.02 * step + 0.01 * rng.standard_normal()
            for method, accuracy in ((BASELINE, base), (ATIKT, base + 0.01 * step + 0.001 * group)):
                rows.append(
                    {"group": group, "trial": 0, "step": step, "method": method}
                    | {"accuracy": accuracy, "actions": "all"}
                )
    return pl.DataFrame(rows)


def test_transfer_check_mean_row_names_the_steps_the_recordings_allowed() -> None:
    results = _results(dict.fromkeys(range(4), 8))  # every run stopped at step 8 of 40
    gains = step_gains(results, 40)
    assert gains["step"].to_list() == ["0", "1", "2", "5", "mean 1..8"]
    mean = gains.filter(pl.col("step") == "mean 1..8")["gain"].item()
    per_step = results.filter(pl.col("step").is_between(1, 8)).pivot(
        on="method", index=["group", "step"], values="accuracy"
    )
    assert mean == pytest.approx((per_step[ATIKT] - per_step[BASELINE]).to_numpy().mean())


def test_a_full_budget_keeps_its_label_and_uneven_runs_say_where_they_ended() -> None:
    assert step_gains(_results(dict.fromkeys(range(3), 5)), 5)["step"][-1] == "mean 1..5"
    uneven = _results({0: 3, 1: 5, 2: 5})
    assert step_gains(uneven, 40)["step"][-1] == "mean 1..last (3-5)"
    assert "| method | initial | mean 1..last (3-5) | final |" in transfer_block(
        "transfer", uneven, 0
    )


def test_the_transfer_summary_names_the_steps_its_gains_average() -> None:
    results = _results(dict.fromkeys(range(3), 2))
    config = StudyConfig(out=Path("out"), seed=0, workers=1)  # budget 40
    text = summary(STUDIES["transfer"], results, config)
    assert "| groups | gain after 1 observation | gain mean 1..2 | gain final |" in text
    assert "1..budget" not in text
    assert (
        "> The recordings allowed 2 of the budget's 40 steps: the pool of trials ran out " in text
    )
    compare = Comparisons(("actions",), lambda _: [(ATIKT, BASELINE)])(results, config)
    assert "mean: over observations 1..2; final: after the last." in compare


def test_a_learner_with_patience_may_have_stopped_on_it() -> None:
    assert steps_short(4, 4) == ""
    assert steps_short(1, 4, patience=3).startswith("the recordings allowed 1 of the budget's 4")
    assert steps_short(3, 4, patience=3) == (
        "the run made 3 of the budget's 4 steps: the pool of trials ran out after step 3, or "
        "the uncertainty did not improve for 3 steps (the learner's patience)"
    )
    assert steps_short(3, 4, pool=False, patience=2).endswith(
        "for 2 steps (the learner's patience)"
    )
    config = StudyConfig(out=Path("out"), learner=DEFAULT_LEARNER.replace(patience=2))
    text = summary(STUDIES["transfer"], _results(dict.fromkeys(range(2), 2)), config)
    assert (
        "> The run made 2 of the budget's 40 steps: the pool of trials ran out after step 2" in text
    )


def _learn(data: Path, out: Path, *extra: str) -> list[str]:
    """A learn command line of two new objects and one action (no transfer: no priors to fit)."""
    argv = ["learn", "--recordings", str(data), "--new", "foam_block,pine_board"]
    argv += ["--actions", "P1"]
    return [*argv, "--transfer", "none", "--workers", "1", "--out", str(out), *extra]


def test_learn_says_the_recordings_allowed_fewer_steps_than_its_budget(
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # 5 trials per object: 2 held out, 1 in the initial round, 2 left for the learner
    assert main(_learn(small_dataset, tmp_path / "run", "--budget", "6")) == 0
    out = capsys.readouterr().out.splitlines()
    assert pl.read_parquet(tmp_path / "run" / "history.parquet")["step"].to_list() == [
        0,
        1,
        2,
        3,
        4,
    ]
    assert out[-2] == (
        "the recordings allowed 4 of the budget's 6 steps: the pool of trials ran out after "
        "step 4; give more trials per object and action, or a smaller --budget"
    )
    assert main(_learn(small_dataset, tmp_path / "full", "--budget", "2")) == 0
    assert "the recordings allowed" not in capsys.readouterr().out


def test_test_trials_offline_is_refused_in_one_line_before_any_work(
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(_learn(small_dataset, tmp_path / "run", "--test-trials", "1")) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "--test-trials 1 applies to a live run (--rig/--rig-config); offline, half" in err
    assert not (tmp_path / "run").exists()


def test_a_session_replay_takes_test_trials_only_as_the_session_held_them(tmp_path: Path) -> None:
    rows = [
        {"order": i, "role": role, "object_id": "wood", "action_id": "P1", "trial": i + 1}
        for i, role in enumerate(("test", "pool", "pool"))
    ]
    pl.DataFrame(rows).write_parquet(tmp_path / SESSION_NAME)
    assert held_out_trials(1, live=False, session=tmp_path) == 1
    assert held_out_trials(None, live=False, session=tmp_path) is None
    with pytest.raises(ReplayError, match=r"--test-trials 2: the session .* held out 1 per"):
        held_out_trials(2, live=False, session=tmp_path)
    assert held_out_trials(None, live=True, session=None) == LIVE_TEST_TRIALS
    assert held_out_trials(1, live=True, session=None) == 1
