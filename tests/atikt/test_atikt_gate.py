"""The transfer gate: no old object's observations borrowed before ``transfer_from``
observations of the action (the old objects' kernel follows metric transfer's own rule)."""

from __future__ import annotations

import numpy as np
import pytest
from atikt_synthetic import NEW_OBJECTS, OLD_OBJECTS, PoolObserver, pool

from atikt import ActiveLearner, AtiktError, RawFeatures
from atikt.options import LearnerOptions

ACTIONS = ["P1", "S2"]
FAST = {"n_restarts": 0, "max_iter_initial": 8, "max_iter_step": 4, "hyper_sd": 5.0}


@pytest.fixture(scope="module")
def train() -> dict[str, dict[int, list[RawFeatures]]]:
    return pool(NEW_OBJECTS, ACTIONS, n_trials=6, seed=1)


@pytest.fixture(scope="module")
def priors() -> dict[str, dict[int, list[RawFeatures]]]:
    return pool(OLD_OBJECTS, ACTIONS, n_trials=6, seed=2)


def run(train: dict[str, dict[int, list[RawFeatures]]], **kwargs: object) -> ActiveLearner:
    settings: dict[str, object] = {**FAST, "budget": 6, "random_state": 0, **kwargs}
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


def test_a_closed_gate_borrows_no_observations_until_the_second(
    train: dict[str, dict[int, list[RawFeatures]]],
    priors: dict[str, dict[int, list[RawFeatures]]],
) -> None:
    gated = run(train, priors=priors, transfer_from=2, budget=0)
    never = run(train, priors=priors, eps_neg1=1.0, budget=0)  # admits no old object
    opened = run(train, priors=priors, budget=0)
    # one observation each: nothing borrowed, the old objects' kernel as without the gate
    assert np.array_equal(gated.uncertainty_, never.uncertainty_)
    assert any(c.source is not None for a in ACTIONS for c in opened.states_[a].choices)
    for action in ACTIONS:
        state = gated.states_[action]
        assert all(c.source is None for c in state.choices)
        assert state.metrics == opened.states_[action].metrics
    # objects with two observations may borrow; those with one never do
    full = run(train, priors=priors, transfer_from=2, budget=10)
    borrowed = 0
    for action in ACTIONS:
        state = full.states_[action]
        counts = np.bincount(state.labels, minlength=len(NEW_OBJECTS))
        for obj, choice in enumerate(state.choices):
            if choice.source is not None:
                borrowed += 1
                assert counts[obj] >= 2
    assert borrowed
    records = [r for r in full.history_ if r.prior is not None and r.prior >= 0]
    assert records  # the step records name the source once the gate opened


def test_gate_option_is_checked() -> None:
    with pytest.raises(AtiktError, match="transfer_from=0 must be >= 1"):
        LearnerOptions(transfer_from=0)


def test_without_initial_borrowing_the_first_round_borrows_nothing_then_the_steps_do(
    train: dict[str, dict[int, list[RawFeatures]]],
    priors: dict[str, dict[int, list[RawFeatures]]],
) -> None:
    held = run(train, priors=priors, borrow_initial=False, budget=0)
    never = run(train, priors=priors, eps_neg1=1.0, budget=0)
    assert np.array_equal(held.uncertainty_, never.uncertainty_)
    for action in ACTIONS:
        assert all(c.source is None for c in held.states_[action].choices)
    # after the first step every object may borrow, those seen once included
    stepped = run(train, priors=priors, borrow_initial=False, budget=10)
    once = [
        choice.source
        for action in ACTIONS
        for obj, choice in enumerate(stepped.states_[action].choices)
        if np.bincount(stepped.states_[action].labels, minlength=len(NEW_OBJECTS))[obj] == 1
    ]
    assert any(source is not None for source in once)


def test_naming_the_strategy_in_use_keeps_its_options() -> None:
    options = LearnerOptions().replace(borrow_initial=False, eps_neg1=0.7)
    assert options.replace(transfer="prediction").transfer == options.transfer
    assert options.replace(transfer="density").transfer.name == "density"
    again = options.replace(transfer="density").replace(transfer="prediction")
    assert again.transfer == LearnerOptions().transfer  # the thesis's defaults
