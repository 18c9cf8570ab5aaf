"""Active learner: determinism, the no-prior reduction, budget, exploration, evaluation."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from atikt_synthetic import NEW_OBJECTS, OLD_OBJECTS, PoolObserver, pool

from atikt import (
    ActiveLearner,
    AtiktError,
    NotFittedError,
    RawFeatures,
    StepRecord,
    fit_prior_models,
)

ACTIONS = ["P2", "S2", "C1"]
N_NEW = len(NEW_OBJECTS)
FAST = {"n_restarts": 0, "max_iter_initial": 15, "max_iter_step": 5}


@pytest.fixture(scope="module")
def train() -> dict[str, dict[int, list[RawFeatures]]]:
    return pool(NEW_OBJECTS, ACTIONS, n_trials=8, seed=1)


@pytest.fixture(scope="module")
def priors() -> dict[str, dict[int, list[RawFeatures]]]:
    return pool(OLD_OBJECTS, ACTIONS, n_trials=8, seed=2)


@pytest.fixture(scope="module")
def test_set() -> dict[str, tuple[list[RawFeatures], list[int]]]:
    data = pool(NEW_OBJECTS, ACTIONS, n_trials=4, seed=3)
    return {
        a: (
            [o for j in range(N_NEW) for o in data[a][j]],
            [j for j in range(N_NEW) for _ in data[a][j]],
        )
        for a in ACTIONS
    }


def run(
    train: dict[str, dict[int, list[RawFeatures]]],
    budget: int,
    **kwargs: object,
) -> tuple[ActiveLearner, PoolObserver]:
    observer = PoolObserver(train)
    settings: dict[str, object] = {**FAST, "random_state": 0, **kwargs}
    learner = ActiveLearner(ACTIONS, N_NEW, observe=observer, budget=budget, **settings)  # type: ignore[arg-type]
    learner.initialise()
    while not learner.done:
        learner.step()
    return learner, observer


def rows(learner: ActiveLearner) -> list[dict[str, object]]:
    return [record.as_row() for record in learner.history_]


def test_initialise_observes_each_object_and_action_once(
    train: dict[str, dict[int, list[RawFeatures]]],
) -> None:
    learner, observer = run(train, budget=0, transfer="none")
    assert observer.calls == [(j, a) for a in ACTIONS for j in range(N_NEW)]
    assert learner.n_observations_ == len(ACTIONS) * N_NEW
    assert learner.uncertainty_.shape == (len(ACTIONS), N_NEW)
    assert np.all(learner.uncertainty_ >= 0)
    assert np.all(learner.uncertainty_ <= np.log(N_NEW) + 1e-12)
    assert learner.done


def test_budget_and_history(
    train: dict[str, dict[int, list[RawFeatures]]], priors: dict[str, dict[int, list[RawFeatures]]]
) -> None:
    learner, observer = run(train, budget=6, priors=priors, transfer="prediction")
    assert len(learner.history_) == 6
    assert len(observer.calls) == len(ACTIONS) * N_NEW + 6
    for i, record in enumerate(learner.history_):
        assert isinstance(record, StepRecord)
        assert record.step == i
        assert (record.object, record.action) == observer.calls[len(ACTIONS) * N_NEW + i]
        assert record.n_observations == len(ACTIONS) * N_NEW + i + 1
        assert len(record.entropies) == len(ACTIONS)
        assert record.uncertainty == record.entropies[ACTIONS.index(record.action)][record.object]
        assert sum(record.weights) == pytest.approx(1.0)
        assert len(record.weights) == len(record.modalities) == 2
        assert record.candidates == (0, 1, 2)
        assert len(record.relatedness) == 3
        assert (record.prior is None) == (record.rho == 0.0)
        assert record.priors[record.object] == record.prior
        assert record.rho == 0.0 or record.rho >= 0.6
        row = record.as_row()
        assert row["prior"] == (-1 if record.prior is None else record.prior)
    with pytest.raises(AtiktError, match="done"):
        learner.step()


def test_same_inputs_same_decisions_bit_for_bit(
    train: dict[str, dict[int, list[RawFeatures]]], priors: dict[str, dict[int, list[RawFeatures]]]
) -> None:
    first, obs1 = run(train, budget=5, priors=priors, random_state=7)
    second, obs2 = run(train, budget=5, priors=priors, random_state=7)
    assert obs1.calls == obs2.calls
    assert rows(first) == rows(second)  # floats compared exactly
    for action in ACTIONS:
        for m1, m2 in zip(first.states_[action].models, second.states_[action].models, strict=True):
            np.testing.assert_array_equal(m1.base_kernel_.theta, m2.base_kernel_.theta)
    other, _ = run(train, budget=5, priors=priors, random_state=8, eps_explore=1.0)
    assert rows(other) != rows(first)


def test_no_prior_data_reduces_to_the_baseline(
    train: dict[str, dict[int, list[RawFeatures]]], priors: dict[str, dict[int, list[RawFeatures]]]
) -> None:
    baseline, calls = run(train, budget=4, transfer="none", priors=priors)
    for transfer in ("prediction", "optimization"):
        empty, empty_calls = run(train, budget=4, transfer=transfer, priors=None)
        assert empty_calls.calls == calls.calls
        assert rows(empty) == rows(baseline)
    assert all(r.prior is None and r.candidates == () for r in baseline.history_)


def test_prior_models_can_be_fitted_once_for_many_learners(
    train: dict[str, dict[int, list[RawFeatures]]], priors: dict[str, dict[int, list[RawFeatures]]]
) -> None:
    fitted = fit_prior_models(priors, n_restarts=0, max_iter=15, random_state=0)
    assert set(fitted) == set(ACTIONS)
    assert fitted["P2"].old_objects == (0, 1, 2)
    learner, _ = run(train, budget=2, priors=fitted)
    assert len(learner.history_) == 2
    again, _ = run(train, budget=2, priors=fitted)
    assert rows(again) == rows(learner)


def test_prior_model_derives_its_objects_and_metric_centre_once(
    priors: dict[str, dict[int, list[RawFeatures]]],
) -> None:
    prior = fit_prior_models(priors, n_restarts=0, max_iter=15, random_state=0)["P2"]
    assert prior.model is not None
    thetas = [e.kernel_.theta for e in prior.model.estimators_]
    centre = prior.median_theta()
    assert centre is not None
    assert np.array_equal(centre, np.median(thetas, axis=0))
    centre += 1.0  # the caller's copy: the next call is unchanged
    assert np.array_equal(prior.median_theta(), np.median(thetas, axis=0))  # type: ignore[arg-type]
    assert prior.old_objects == tuple(int(v) for v in np.unique(prior.labels))
    # a copy with other labels derives its own (dataclasses.replace runs __post_init__ again)
    fewer = dataclasses.replace(prior, labels=np.where(prior.labels == 2, 1, prior.labels))
    assert fewer.old_objects == (0, 1)
    assert dataclasses.replace(prior, model=None).median_theta() is None


def test_exploitation_picks_the_largest_uncertainty(
    train: dict[str, dict[int, list[RawFeatures]]],
) -> None:
    learner, _ = run(train, budget=4, transfer="none", eps_explore=0.0)
    for record in learner.history_:
        assert not record.explored
        assert record.uncertainty == max(max(row) for row in record.entropies)
    explorer, _ = run(train, budget=4, transfer="none", eps_explore=1.0)
    assert all(record.explored for record in explorer.history_)


def test_patience_stops_early(train: dict[str, dict[int, list[RawFeatures]]]) -> None:
    learner, _ = run(train, budget=30, transfer="none", patience=1, min_improvement=10.0)
    assert len(learner.history_) == 1


def test_scores_and_probabilities(
    train: dict[str, dict[int, list[RawFeatures]]],
    priors: dict[str, dict[int, list[RawFeatures]]],
    test_set: dict[str, tuple[list[RawFeatures], list[int]]],
) -> None:
    learner, _ = run(train, budget=3, priors=priors)
    transformers = {a: learner.states_[a].transformer for a in ACTIONS}
    per_action = learner.score_per_action(test_set)
    assert set(per_action) == set(ACTIONS)
    assert all(0.0 <= v <= 1.0 for v in per_action.values())
    assert learner.score(test_set) == pytest.approx(np.mean(list(per_action.values())))
    assert learner.score(test_set) > 1.0 / N_NEW  # better than chance on separable objects
    p = learner.predict_proba("S2", test_set["S2"][0])
    assert p.shape == (len(test_set["S2"][0]), N_NEW)
    np.testing.assert_allclose(p.sum(axis=1), 1.0)
    assert {a: learner.states_[a].transformer for a in ACTIONS} == transformers  # untouched
    with pytest.raises(AtiktError, match="unknown action"):
        learner.predict_proba("X9", test_set["S2"][0])


def test_misuse_is_reported(train: dict[str, dict[int, list[RawFeatures]]]) -> None:
    learner = ActiveLearner(ACTIONS, N_NEW, observe=PoolObserver(train))
    assert not learner.done
    with pytest.raises(NotFittedError):
        learner.step()
    with pytest.raises(NotFittedError):
        learner.score({})
    bad = ActiveLearner(ACTIONS, N_NEW, observe=lambda _obj, _action: "not features")  # type: ignore[arg-type,return-value]
    with pytest.raises(AtiktError, match="must return RawFeatures"):
        bad.initialise()
    swapped = {"P2": train["S2"], "S2": train["S2"], "C1": train["C1"]}
    learner = ActiveLearner(
        ACTIONS,
        N_NEW,
        observe=PoolObserver(swapped),
        priors=pool(OLD_OBJECTS, ACTIONS, 2, 5),
        n_restarts=0,
        max_iter_initial=15,
    )
    with pytest.raises(AtiktError, match="kind"):
        learner.initialise()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"n_new_objects": 1}, "n_new_objects"),
        ({"transfer": "magic"}, "transfer"),
        ({"eps_explore": 1.5}, "eps_explore"),
        ({"eps_neg1": 0.5}, "eps_neg1"),
        ({"eps_neg2": 0.0}, "eps_neg2"),
        ({"actions": []}, "actions"),
        ({"budget": -1}, "budget"),
    ],
)
def test_bad_parameters(kwargs: dict[str, object], match: str) -> None:
    settings: dict[str, object] = {"actions": ACTIONS, "n_new_objects": N_NEW, **kwargs}
    with pytest.raises(AtiktError, match=match):
        ActiveLearner(observe=lambda _o, _a: None, **settings)  # type: ignore[arg-type,return-value]


def test_single_old_object_needs_the_optimization_approach(
    train: dict[str, dict[int, list[RawFeatures]]],
) -> None:
    single = pool(OLD_OBJECTS[:1], ACTIONS, n_trials=4, seed=6)
    learner = ActiveLearner(ACTIONS, N_NEW, observe=PoolObserver(train), priors=single)
    with pytest.raises(AtiktError, match="one old object"):
        learner.initialise()
    learner, _ = run(train, budget=1, priors=single, transfer="optimization")
    assert learner.history_[0].candidates == (0,)


def test_only_available_pairs_are_chosen(train: dict[str, dict[int, list[RawFeatures]]]) -> None:
    observer = PoolObserver(train)
    capacity = {(1, "S2"): 3, (3, "S2"): 3}  # every other pair: its initial observation only

    for eps in (0.0, 1.0):
        observer.used.clear()
        learner = ActiveLearner(
            ACTIONS,
            N_NEW,
            observe=observer,
            capacity=capacity,
            transfer="none",
            budget=20,
            eps_explore=eps,
            random_state=0,
            **FAST,  # type: ignore[arg-type]
        )
        learner.initialise()
        while not learner.done:
            record = learner.step()
            assert record.action == "S2"
            assert record.object in (1, 3)
        assert len(learner.history_) == 4  # two pairs, two more recordings each


def test_refusing_every_prior_is_the_baseline(
    train: dict[str, dict[int, list[RawFeatures]]],
    priors: dict[str, dict[int, list[RawFeatures]]],
) -> None:
    baseline, calls = run(train, budget=4, transfer="none")
    refused, refused_calls = run(
        train, budget=4, transfer="prediction", priors=priors, eps_neg1=1.0, metric_sd=None
    )
    assert refused_calls.calls == calls.calls
    assert all(r.candidates == (0, 1, 2) and r.prior is None for r in refused.history_)
    ignore = {"relatedness", "candidates"}
    strip = [{k: v for k, v in row.items() if k not in ignore} for row in rows(refused)]
    assert strip == [{k: v for k, v in row.items() if k not in ignore} for row in rows(baseline)]


def test_relatedness_scores_each_observation_once_and_equals_a_fresh_prediction(
    train: dict[str, dict[int, list[RawFeatures]]], priors: dict[str, dict[int, list[RawFeatures]]]
) -> None:
    fitted = fit_prior_models(priors, n_restarts=0, max_iter=15, random_state=0)
    learner, _ = run(train, budget=6, priors=fitted)
    for action in ACTIONS:
        state, prior = learner.states_[action], fitted[action]
        assert prior.model is not None
        cached = state.prior_probabilities
        assert cached is not None
        assert cached.shape == (len(state.observations), len(prior.old_objects))
        fresh = prior.model.predict_binary(prior.transformer.transform(state.observations))
        np.testing.assert_allclose(cached, fresh, rtol=0, atol=1e-12)
        labels = np.asarray(state.labels)
        for obj, choice in enumerate(state.choices):  # each choice is its object's mean score
            scores = fresh[labels == obj].mean(axis=0)
            np.testing.assert_allclose(choice.scores, scores, rtol=0, atol=1e-12)
            expected = prior.old_objects[int(np.argmax(scores))] if scores.max() >= 0.6 else None
            assert choice.source == expected
