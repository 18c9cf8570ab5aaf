from collections.abc import Iterator
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from conftest import ACTIONS, NEW, OLD, TRIALS

from recorder import (
    ActionSpec,
    ObjectSpec,
    RigError,
    SimulatedRig,
    StreamItem,
    load_actions,
    load_objects,
)
from replay.errors import ReplayError
from replay.learning._executors import FeatureLookup, PoolExecutor, Split
from replay.learning._features import as_raw, build_features, raw_table
from replay.learning._session import (
    RunSpec,
    _ActionScores,
    fit_priors,
    learner_options,
    prior_data,
    run_learning,
    run_offline,
)
from replay.live import LiveExecutor


@pytest.fixture(scope="module")
def features(small_dataset: Path) -> pl.DataFrame:
    return build_features(small_dataset).frame


def test_split_is_disjoint_complete_and_seeded(features: pl.DataFrame) -> None:
    split = Split.random(features, NEW, ACTIONS, seed=3)
    for pair in split.pool:
        assert set(split.pool[pair]).isdisjoint(split.test[pair])
        assert sorted(split.pool[pair] + split.test[pair]) == list(range(1, TRIALS + 1))
    assert split == Split.random(features, NEW, ACTIONS, seed=3)
    assert split != Split.random(features, NEW, ACTIONS, seed=4)
    # a pair's split does not depend on which other objects take part
    alone = Split.random(features, NEW[:1], ACTIONS[:1], seed=3)
    assert alone.pool[NEW[0], ACTIONS[0]] == split.pool[NEW[0], ACTIONS[0]]


def test_pool_serves_each_recording_once_then_refuses(features: pl.DataFrame) -> None:
    split = Split.random(features, NEW, ACTIONS, seed=0)
    executor = PoolExecutor(FeatureLookup(features), NEW, split)
    pool = split.pool[NEW[1], "P1"]
    for _ in pool:
        assert executor.available(1, "P1")
        executor(1, "P1")
    assert not executor.available(1, "P1")
    assert [t for _, _, t in executor.served] == list(pool)
    with pytest.raises(ReplayError, match="pool recordings are used"):
        executor(1, "P1")


def test_test_set_holds_the_held_out_trials(features: pl.DataFrame) -> None:
    split = Split.random(features, NEW, ACTIONS, seed=0)
    test = PoolExecutor(FeatureLookup(features), NEW, split).test_set(ACTIONS)
    for action in ACTIONS:
        observations, labels = test[action]
        assert len(observations) == sum(len(split.test[o, action]) for o in NEW)
        assert sorted(set(labels)) == [0, 1, 2]


def test_offline_run_is_deterministic(features: pl.DataFrame) -> None:
    spec = RunSpec(
        new_objects=NEW,
        prior_objects=OLD,
        actions=ACTIONS,
        learner=learner_options("prediction", budget=4),
        seed=5,
    )
    models = fit_priors(prior_data(FeatureLookup(features), OLD, ACTIONS), seed=5)

    def run() -> pl.DataFrame:
        split = Split.random(features, NEW, ACTIONS, seed=5)
        executor = PoolExecutor(FeatureLookup(features), NEW, split)
        return run_learning(spec, executor, executor.test_set(ACTIONS), models).frame()

    first = run()
    assert first["step"].to_list() == list(range(5))
    assert first.equals(run())


def _assert_rows_converted(frame: pl.DataFrame, policy: str) -> None:
    """``raw_table`` gives every row what converting the row alone (``as_raw``) gives."""
    raw, kinds, blocks = raw_table(frame, policy)
    assert len(raw) == frame.height
    for row in frame.iter_rows(named=True):
        key = (row["object_id"], row["action_id"], row["trial"])
        expected = as_raw(row, blocks[row["action_id"]])
        assert raw[key].kind == expected.kind == kinds[row["action_id"]]
        assert list(raw[key].blocks) == list(expected.blocks)
        for name, values in expected.blocks.items():
            assert raw[key].blocks[name].dtype == values.dtype
            assert raw[key].blocks[name].tobytes() == values.tobytes()
            assert not raw[key].blocks[name].flags.writeable


@pytest.mark.parametrize("policy", ["thesis", "all"])
def test_table_conversion_gives_each_rows_own_features(features: pl.DataFrame, policy: str) -> None:
    _assert_rows_converted(features, policy)
    # a missing value inside a row's list (NaN, as numpy converts it), a row without a block
    broken = features.with_columns(
        pl.when(pl.int_range(pl.len()) == 0)
        .then(pl.lit([None, 1.0], dtype=pl.List(pl.Float64)))
        .otherwise(pl.col("thermal"))
        .alias("thermal"),
        pl.when(pl.int_range(pl.len()) == 1)
        .then(None)
        .otherwise(pl.col("texture"))
        .alias("texture"),
    )
    _assert_rows_converted(broken, policy)


def test_kept_accuracies_are_those_of_scoring_every_action_again(
    features: pl.DataFrame,
) -> None:
    """Scores are computed again exactly for the action a step refits, and are the same."""
    from atikt import ActiveLearner  # noqa: PLC0415

    spec = RunSpec(
        new_objects=NEW,
        prior_objects=OLD,
        actions=ACTIONS,
        learner=learner_options("prediction", budget=6),
        seed=2,
    )
    lookup = FeatureLookup(features)
    executor = PoolExecutor(lookup, NEW, Split.random(features, NEW, ACTIONS, seed=2))
    test = executor.test_set(ACTIONS)
    learner = ActiveLearner(
        ACTIONS,
        len(NEW),
        observe=executor,
        capacity=executor.capacity,
        priors=fit_priors(prior_data(lookup, OLD, ACTIONS), seed=2),
        options=spec.learner,
        random_state=2,
    )
    learner.initialise()
    scores = _ActionScores(test)
    calls: list[str] = []
    score_per_action = learner.score_per_action

    def counted(part: dict[str, object]) -> dict[str, float]:
        calls.extend(part)
        return score_per_action(part)  # type: ignore[arg-type]

    learner.score_per_action = counted  # type: ignore[method-assign,assignment]
    assert scores(learner) == score_per_action(test)
    assert calls == list(ACTIONS)
    while not learner.done:
        calls.clear()
        record = learner.step()
        assert scores(learner) == score_per_action(test)
        assert calls == [record.action]  # the refitted action alone


def test_live_run_then_offline_replay_of_its_session_agree(
    features: pl.DataFrame, tmp_path: Path
) -> None:
    spec = RunSpec(
        new_objects=NEW,
        prior_objects=OLD,
        actions=ACTIONS,
        learner=learner_options("prediction", budget=3),
        seed=2,
    )
    models = fit_priors(prior_data(FeatureLookup(features), OLD, ACTIONS), seed=2)
    objects = load_objects()
    session = tmp_path / "session"
    live = LiveExecutor(
        SimulatedRig(seed=9), [objects[o] for o in NEW], load_actions(), session, seed=9
    )
    with live:
        test = live.record_test_set(ACTIONS, trials=1)
        live_run = run_learning(spec, live, test, models).frame()

    offline_features = build_features(session).frame
    split = Split.from_session(session)
    pool = PoolExecutor(FeatureLookup(offline_features), NEW, split, like_rig=True)
    offline_run = run_learning(spec, pool, pool.test_set(ACTIONS), models).frame()

    assert offline_run.equals(live_run)
    served = [(o, a) for o, a, _ in pool.served]
    assert served == [(r["object_id"], r["action_id"]) for r in live.made if r["role"] == "pool"]


class _FailingRig(SimulatedRig):
    """The simulator, failing at its ``fail_at``-th action (a rig that lost its connection)."""

    def __init__(self, seed: int, fail_at: int) -> None:
        super().__init__(seed=seed)
        self.fail_at, self.performed = fail_at, 0

    def perform(self, obj: ObjectSpec, action: ActionSpec, trial: int) -> Iterator[StreamItem]:
        self.performed += 1
        if self.performed == self.fail_at:
            msg = "connection lost"
            raise RigError(msg)
        return super().perform(obj, action, trial)


def test_an_interrupted_live_session_resumes_with_the_same_decisions(
    features: pl.DataFrame, tmp_path: Path
) -> None:
    spec = RunSpec(
        new_objects=NEW,
        prior_objects=OLD,
        actions=ACTIONS,
        learner=learner_options("prediction", budget=4),
        seed=9,
    )
    models = fit_priors(prior_data(FeatureLookup(features), OLD, ACTIONS), seed=2)
    objects, actions = [load_objects()[o] for o in NEW], load_actions()

    def run(rig: SimulatedRig, session: Path) -> tuple[pl.DataFrame, LiveExecutor]:
        live = LiveExecutor(rig, objects, actions, session, seed=9)
        with live:
            test = live.record_test_set(ACTIONS, trials=1)
            return run_learning(spec, live, test, models).frame(), live

    whole, _ = run(SimulatedRig(seed=9), tmp_path / "whole")
    session = tmp_path / "interrupted"
    with pytest.raises(RigError, match="connection lost"):
        run(_FailingRig(9, fail_at=6), session)
    made = sorted(session.rglob("*.mcap"))
    assert len(made) == 5  # every recording made before the failure is kept
    resumed, live = run(SimulatedRig(seed=9), session)
    assert resumed.equals(whole)
    assert live.reused == 5
    assert set(made) <= set(session.rglob("*.mcap"))
    assert Split.from_session(session) == Split.from_session(tmp_path / "whole")


def test_a_live_run_continued_with_a_larger_budget_is_the_longer_run(
    features: pl.DataFrame, tmp_path: Path
) -> None:
    models = fit_priors(prior_data(FeatureLookup(features), OLD, ACTIONS), seed=2)
    objects, actions = [load_objects()[o] for o in NEW], load_actions()

    def run(session: Path, budget: int) -> tuple[pl.DataFrame, LiveExecutor]:
        spec = RunSpec(
            new_objects=NEW,
            prior_objects=OLD,
            actions=ACTIONS,
            learner=learner_options("prediction", budget=budget),
            seed=9,
        )
        live = LiveExecutor(SimulatedRig(seed=9), objects, actions, session, seed=9)
        with live:
            test = live.record_test_set(ACTIONS, trials=1)
            return run_learning(spec, live, test, models).frame(), live

    longer, _ = run(tmp_path / "longer", 4)
    session = tmp_path / "continued"
    shorter, _ = run(session, 2)
    made = sorted(session.rglob("*.mcap"))
    continued, live = run(session, 4)
    assert continued.equals(longer)  # the learner's choices do not depend on its budget
    assert shorter.equals(longer.head(shorter.height))
    assert live.reused == len(made)  # nothing recorded again: only the new steps were made
    assert set(made) < set(session.rglob("*.mcap"))


def test_spec_refuses_an_object_that_is_new_and_prior() -> None:
    with pytest.raises(ReplayError, match="new and prior"):
        RunSpec(new_objects=NEW, prior_objects=(NEW[0],), actions=ACTIONS)
    with pytest.raises(ReplayError, match=r"transfer='maybe' must be one of \('prediction'"):
        learner_options("maybe")


def test_a_stopped_run_names_the_fix_as_the_command_line_option(features: pl.DataFrame) -> None:
    """atikt words its fix for Python (transfer='optimization'); a command's user, --transfer."""
    spec = RunSpec(
        new_objects=NEW,
        prior_objects=OLD[:1],
        actions=ACTIONS[:1],
        learner=learner_options("prediction", budget=1),
        seed=0,
    )
    models = fit_priors(prior_data(FeatureLookup(features), OLD[:1], ACTIONS[:1]), seed=0)
    with pytest.raises(ReplayError, match="one old object only") as caught:
        run_offline(features, spec, priors=models)
    assert "(use --transfer optimization)" in str(caught.value)
    assert "transfer='" not in str(caught.value)


def test_a_message_names_a_numpy_string_as_plain_text(features: pl.DataFrame) -> None:
    one = features.filter(pl.col("trial") == 1)
    with pytest.raises(ReplayError, match=r"^object 'wood', action 'P1': 1 usable") as caught:
        Split.random(one, [np.str_("wood")], [np.str_("P1")], seed=0)
    assert "np.str_" not in str(caught.value)
