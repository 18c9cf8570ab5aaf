"""The transfer check: known objects learned as new ones, gains per number of observations."""

from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import polars as pl
import pytest
from conftest import ACTIONS, NEW, OLD

from replay.errors import ReplayError
from replay.learning._features import build_features
from replay.learning._session import DEFAULT_LEARNER
from replay.outputs._study_report import run_study
from replay.studies._running import ATIKT, BASELINE, StudyConfig
from replay.studies._transfer_check import check_tasks, step_gains, verdict


@pytest.fixture(scope="module")
def features(small_dataset: Path) -> pl.DataFrame:
    return build_features(small_dataset).frame


def _config(out: Path, **changes: object) -> StudyConfig:
    base = StudyConfig(
        out=out,
        groups=2,
        trials=1,
        learner=DEFAULT_LEARNER.replace(budget=3),
        new=NEW,
        old=OLD,
        actions=ACTIONS,
    )
    return replace(base, **changes)  # type: ignore[arg-type]


def test_tasks_split_the_known_objects_into_pseudo_new_and_priors(
    features: pl.DataFrame, tmp_path: Path
) -> None:
    tasks = check_tasks(features, _config(tmp_path))
    assert len(tasks) == 2
    for task in tasks:
        assert len(task.new) == 3
        assert len(task.priors) == 3
        assert not set(task.new) & set(task.priors)
        assert set(task.new) | set(task.priors) == {*NEW, *OLD}
    again = check_tasks(features, _config(tmp_path))
    assert [t.new for t in tasks] == [t.new for t in again]


def test_too_few_known_objects_is_one_clear_error(features: pl.DataFrame, tmp_path: Path) -> None:
    config = _config(tmp_path, new=NEW[:1], old=OLD[:2])
    with pytest.raises(ReplayError, match=r"transfer-check: the dataset has 3 known objects"):
        check_tasks(features, config)


def test_the_summary_says_per_number_of_observations_whether_transfer_helped(
    features: pl.DataFrame, tmp_path: Path
) -> None:
    output = run_study("transfer-check", features, _config(tmp_path / "check"))
    results = pl.read_parquet(output.results)
    assert set(results["method"]) == {ATIKT, BASELINE}
    text = output.text
    assert "| 1 per object and action | 2 |" in text
    assert "| mean 1..3 | 2 |" in text
    assert "| first + 2 | 2 |" in text


def test_step_gains_pair_the_methods_per_task_and_give_a_verdict() -> None:
    rows = []
    for group, gain in enumerate((0.1, 0.2, 0.3)):
        for step in (0, 1, 2):
            rows.append({"group": group, "method": ATIKT, "step": step, "accuracy": 0.5 + gain})
            rows.append({"group": group, "method": BASELINE, "step": step, "accuracy": 0.5})
    gains = step_gains(pl.DataFrame(rows), 5)  # step 5 shown only where runs reached it
    assert gains["step"].to_list() == ["0", "1", "2", "mean 1..2"]  # the steps reached
    assert gains["gain"].to_list() == pytest.approx([0.2] * 4)
    assert set(gains["verdict"]) == {"helped"}
    assert verdict(-0.2, -0.1) == "hurt"
    assert verdict(-0.1, 0.1) == "no clear difference"


def test_the_splits_are_distinct_and_no_more_than_exist() -> None:
    # 4 known objects, 2 pseudo-new and 2 priors: 6 splits exist; ten asked for give six,
    # never one twice (a repeated split would count twice in the interval over tasks)
    from replay.studies._transfer_check import _splits  # noqa: PLC0415

    known = ("a", "b", "c", "d")
    config = SimpleNamespace(groups=10, seed=3)
    splits = _splits(known, 2, 2, config)  # type: ignore[arg-type]
    assert len(splits) == 6
    assert len(set(splits)) == 6
    config.groups = 4
    assert _splits(known, 2, 2, config) == splits[:4]  # type: ignore[arg-type]
