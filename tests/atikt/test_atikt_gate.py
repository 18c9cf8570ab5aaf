"""The transfer gate: nothing borrowed before ``transfer_from`` observations, unless the
known objects, learned as new, show that transfer helps from the first (the held-out check)."""

from __future__ import annotations

import numpy as np
import pytest
from atikt_synthetic import NEW_OBJECTS, OLD_OBJECTS, PoolObserver, SyntheticObject, pool

from atikt import ActiveLearner, AtiktError, RawFeatures, fit_prior_models
from atikt.check import CheckResult, transfer_check
from atikt.options import LearnerOptions

ACTIONS = ["P1", "S2"]
FAST = {"n_restarts": 0, "max_iter_initial": 8, "max_iter_step": 4, "hyper_sd": 5.0}
# more known objects than the synthetic set's three: each old one and a slightly changed twin
TWINS = tuple(
    SyntheticObject(o.stiffness * 1.3, o.roughness * 0.8, o.period_mm * 1.2, o.cooling, o.tau_s)
    for o in OLD_OBJECTS
)


@pytest.fixture(scope="module")
def train() -> dict[str, dict[int, list[RawFeatures]]]:
    return pool(NEW_OBJECTS, ACTIONS, n_trials=6, seed=1)


@pytest.fixture(scope="module")
def priors() -> dict[str, dict[int, list[RawFeatures]]]:
    return pool(OLD_OBJECTS, ACTIONS, n_trials=6, seed=2)


@pytest.fixture(scope="module")
def many_priors() -> dict[str, dict[int, list[RawFeatures]]]:
    return pool(OLD_OBJECTS + TWINS, ACTIONS, n_trials=6, seed=3)


def run(train: dict[str, dict[int, list[RawFeatures]]], **kwargs: object) -> ActiveLearner:
    settings: dict[str, object] = {**FAST, "budget": 8, "random_state": 0, **kwargs}
    learner = ActiveLearner(
        ACTIONS,
        len(NEW_OBJECTS),
        observe=PoolObserver(train),
        **settings,  # type: ignore[arg-type]
    )
    learner.initialise()
    while not learner.done:
        learner.step()
    return learner


def test_a_closed_gate_fits_the_baseline_until_the_second_observation(
    train: dict[str, dict[int, list[RawFeatures]]],
    priors: dict[str, dict[int, list[RawFeatures]]],
) -> None:
    gated = ActiveLearner(
        ACTIONS,
        len(NEW_OBJECTS),
        observe=PoolObserver(train),
        priors=priors,
        transfer_from=2,
        random_state=0,
        **FAST,  # type: ignore[arg-type]
    )
    gated.initialise()
    plain = ActiveLearner(
        ACTIONS,
        len(NEW_OBJECTS),
        observe=PoolObserver(train),
        transfer="none",
        random_state=0,
        **FAST,  # type: ignore[arg-type]
    )
    plain.initialise()
    # one observation each: exactly the baseline's classifiers, nothing borrowed
    assert np.array_equal(gated.uncertainty_, plain.uncertainty_)
    for action in ACTIONS:
        state = gated.states_[action]
        assert state.transfer_from == 2
        assert state.check is None
        assert all(c.source is None for c in state.choices)
        assert state.metrics == [False] * len(NEW_OBJECTS)
    # once objects have two observations, they may borrow: the ungated learner's choices
    full = run(train, priors=priors, transfer_from=2)
    borrowed = {
        (a, obj)
        for a in ACTIONS
        for obj, c in enumerate(full.states_[a].choices)
        if c.source is not None or full.states_[a].metrics[obj]
    }
    assert borrowed
    for action, obj in borrowed:
        assert np.bincount(full.states_[action].labels, minlength=len(NEW_OBJECTS))[obj] >= 2


def test_without_enough_known_objects_the_check_gives_no_evidence(
    train: dict[str, dict[int, list[RawFeatures]]],
    priors: dict[str, dict[int, list[RawFeatures]]],
) -> None:
    learner = run(train, priors=priors, transfer_from=2, check_repeats=4, budget=0)
    for action in ACTIONS:
        state = learner.states_[action]
        assert state.check is not None
        assert state.check.differences.size == 0  # three known objects: nothing to split
        assert not state.check.helps
        assert state.transfer_from == 2


def test_the_check_is_deterministic_cached_and_decides_the_gate(
    train: dict[str, dict[int, list[RawFeatures]]],
    many_priors: dict[str, dict[int, list[RawFeatures]]],
) -> None:
    models = fit_prior_models(many_priors, n_restarts=0, random_state=0)
    options = LearnerOptions(**FAST, transfer_from=2, check_repeats=3)  # type: ignore[arg-type]
    first = transfer_check(models["S2"], "S2", len(NEW_OBJECTS), options, repeats=3)
    again = transfer_check(models["S2"], "S2", len(NEW_OBJECTS), options, repeats=3)
    assert first.differences.shape == (3,)
    assert np.array_equal(first.differences, again.differences)
    assert np.all(np.abs(first.differences) <= 1.0)
    # the learner runs it once per prior model and options, and follows its verdict
    a = run(train, priors=models, transfer_from=2, check_repeats=3, budget=0)
    cached = dict(models["S2"].checks)
    b = run(train, priors=models, transfer_from=2, check_repeats=3, budget=0)
    assert models["S2"].checks == cached
    assert len(cached) == 1
    for learner in (a, b):
        for action in ACTIONS:
            state = learner.states_[action]
            assert state.check is models[action].checks[next(iter(models[action].checks))]
            assert state.transfer_from == (1 if state.check.helps else 2)
    assert np.array_equal(a.uncertainty_, b.uncertainty_)


def test_check_verdicts() -> None:
    assert CheckResult(np.array([0.1, 0.2, 0.15])).helps
    assert not CheckResult(np.array([0.1, -0.1, 0.05])).helps  # within a standard error
    assert not CheckResult(np.array([0.3])).helps  # one split is no evidence
    assert not CheckResult(np.zeros(0)).helps
    assert np.isnan(CheckResult(np.zeros(0)).mean)


def test_gate_options_are_checked() -> None:
    with pytest.raises(AtiktError, match="transfer_from=0 must be >= 1"):
        LearnerOptions(transfer_from=0)
    with pytest.raises(AtiktError, match="check_repeats=-1 must be >= 0"):
        LearnerOptions(check_repeats=-1)
