"""Shared hyperparameters, evidence selection, open-set relatedness and multi-source transfer."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pytest
from atikt_synthetic import NEW_OBJECTS, OLD_OBJECTS, PoolObserver, pool

from atikt import (
    ActiveLearner,
    AtiktError,
    BinaryGPC,
    Density,
    DependentKernel,
    LearnerOptions,
    MultiModalGPC,
    MultiSourceKernel,
    NoTransfer,
    ObjectDensities,
    OneVsAllGPC,
    RawFeatures,
    TransferGPC,
    TransferStrategy,
    choose_by_density,
    choose_by_evidence,
    evidence_gains,
    modality_kernel,
    register_strategy,
    strategies,
    strategy_names,
    transfer_strategy,
)
from atikt.active import SEPARATION_REPEATS, SeparationPairs, separation
from atikt.gpc import with_prior
from atikt.transfer import with_domain

SLICES = {"force": slice(0, 1), "thermal": slice(1, 3)}
ACTIONS = ["P1", "S1"]
FAST = {"n_restarts": 0, "max_iter_initial": 15, "max_iter_step": 5}


def three_domains(seed: int) -> np.ndarray:
    """Rows of source 0 (flag 0), source 1 (flag -1) and the new object (flag 1)."""
    rng = np.random.default_rng(seed)
    return np.vstack(
        [
            with_domain(rng.standard_normal((n, 3)), flag)
            for n, flag in ((4, 0.0), (3, -1.0), (5, 1.0))
        ]
    )


def finite_difference(kernel: MultiSourceKernel, X: np.ndarray, h: float = 1e-6) -> np.ndarray:
    theta = kernel.theta
    out = np.empty((theta.shape[0], X.shape[0], X.shape[0]))
    for i in range(theta.shape[0]):
        step = np.zeros_like(theta)
        step[i] = h
        out[i] = (kernel.with_theta(theta + step)(X) - kernel.with_theta(theta - step)(X)) / (2 * h)
    return out


# ------------------------------------------------------------------ multi-source kernel


@pytest.mark.parametrize("bounds", ["fixed", (1e-3, 1.0)])
def test_multi_source_gradient_matches_finite_differences(bounds: object) -> None:
    base = modality_kernel(SLICES).with_theta([0.2, -0.3, 0.4, 0.1])
    kernel = MultiSourceKernel(base, [0.7, 0.3], bounds)  # type: ignore[arg-type]
    X = three_domains(0)
    K, dK = kernel.gradient(X)
    np.testing.assert_allclose(K, kernel(X), rtol=1e-12)
    np.testing.assert_allclose(dK, finite_difference(kernel, X), atol=1e-6)
    K_eval, dK_eval = kernel.evaluator(X)(kernel.theta)
    np.testing.assert_allclose(K_eval, K, rtol=1e-12)
    np.testing.assert_allclose(dK_eval, dK, rtol=1e-12, atol=1e-15)


def test_multi_source_kernel_is_psd_and_has_the_designed_blocks() -> None:
    base = modality_kernel(SLICES)
    X = three_domains(1)
    rng = np.random.default_rng(2)
    for rhos in [[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], *rng.uniform(0, 1, (20, 2)).tolist()]:
        kernel = MultiSourceKernel(base, rhos)
        K = kernel(X)
        assert np.linalg.eigvalsh(K).min() > -1e-10
        mask = kernel.mask(X)
        assert mask[0, 4] == pytest.approx(rhos[0] * rhos[1])  # source 0 - source 1
        assert mask[0, 7] == pytest.approx(rhos[0])  # source 0 - new
        assert mask[4, 7] == pytest.approx(rhos[1])  # source 1 - new
        assert mask[0, 1] == mask[7, 8] == 1.0


def test_one_source_is_the_dependent_kernel() -> None:
    base = modality_kernel(SLICES).with_theta([0.2, -0.3, 0.4, 0.1])
    X = three_domains(3)
    X = X[X[:, -1] != -1.0]
    for bounds in ("fixed", (1e-3, 1.0)):
        multi = MultiSourceKernel(base, [0.6], bounds)
        single = DependentKernel(base, 0.6, bounds)
        np.testing.assert_allclose(multi.gradient(X)[0], single.gradient(X)[0], rtol=1e-14)
        np.testing.assert_allclose(multi.gradient(X)[1], single.gradient(X)[1], rtol=1e-14)


def test_multi_source_kernel_rejects_bad_values() -> None:
    base = modality_kernel(SLICES)
    with pytest.raises(AtiktError, match="rhos"):
        MultiSourceKernel(base, [1.2])
    with pytest.raises(AtiktError, match="rhos"):
        MultiSourceKernel(base, [])
    with pytest.raises(AtiktError, match="domain flags"):
        MultiSourceKernel(base, [0.5])(with_domain(np.zeros((2, 3)), -1.0))


# --------------------------------------------------------------- multi-source classifier


def data(seed: int) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    rng = np.random.default_rng(seed)
    X = np.vstack([rng.normal(0.0, 0.5, (4, 3)), rng.normal(3.0, 0.5, (4, 3))])
    sources = [rng.normal(0.2, 0.5, (6, 3)), rng.normal(-0.2, 0.5, (5, 3))]
    return X, np.repeat([1.0, 0.0], 4), sources


def test_multi_source_with_zero_rhos_is_the_plain_gpc() -> None:
    X, y, sources = data(0)
    kernel = modality_kernel(SLICES).with_theta([0.2, -0.1, 0.3, 0.5])
    Xt = np.random.default_rng(1).standard_normal((10, 3))
    plain = BinaryGPC(kernel, optimize=False).fit(X, y).predict_positive(Xt)
    shortcut = TransferGPC(kernel, rho=[0.0, 0.0], optimize=False).fit(X, y, sources)
    assert not shortcut.transferred_
    np.testing.assert_array_equal(shortcut.predict_positive(Xt), plain)
    # the full multi-source kernel with zero rhos: the sources do not inform the new object
    explicit = TransferGPC(kernel, rho=[1e-300, 1e-300], optimize=False).fit(X, y, sources)
    assert explicit.transferred_
    np.testing.assert_allclose(explicit.predict_positive(Xt), plain, atol=1e-8)


def test_a_list_of_one_source_is_the_single_source_classifier() -> None:
    X, y, sources = data(2)
    kernel = modality_kernel(SLICES)
    single = TransferGPC(kernel, rho=0.7, random_state=0).fit(X, y, sources[0])
    listed = TransferGPC(kernel, rho=[0.7], random_state=0).fit(X, y, [sources[0]])
    np.testing.assert_array_equal(single.predict_positive(X), listed.predict_positive(X))
    assert listed.rhos_.tolist() == [0.7]


def test_multi_source_fit_is_deterministic_and_uses_every_source() -> None:
    X, y, sources = data(3)
    kernel = modality_kernel(SLICES)
    first = TransferGPC(kernel, rho=[0.8, 0.5], random_state=0).fit(X, y, sources)
    again = TransferGPC(kernel, rho=[0.8, 0.5], random_state=0).fit(X, y, sources)
    assert first.n_auxiliary_ == 11
    assert first.rhos_.tolist() == [0.8, 0.5]
    np.testing.assert_array_equal(first.predict_positive(X), again.predict_positive(X))
    with pytest.raises(AtiktError, match="one rho per source"):
        TransferGPC(kernel, rho=[0.8, 0.5, 0.1]).fit(X, y, sources)


def test_learned_rhos_stay_in_their_box() -> None:
    X, y, sources = data(4)
    model = TransferGPC(modality_kernel(SLICES), rho=[0.5, 0.5], learn_rho=True, random_state=0)
    model.fit(X, y, sources)
    assert np.all((model.rhos_ >= 1e-3) & (model.rhos_ <= 1.0))


# ------------------------------------------------------------------ open-set relatedness


def test_tail_probabilities_separate_own_draws_from_other_objects() -> None:
    rng = np.random.default_rng(5)
    X = np.vstack([rng.normal(0.0, 1.0, (40, 4)), rng.normal(6.0, 1.0, (40, 4))])
    densities = ObjectDensities.fit(X, np.repeat([3, 4], 40))
    own = densities.tail_probabilities(rng.normal(0.0, 1.0, (400, 4)))
    assert own.shape == (400, 2)
    assert np.all((own >= 0.0) & (own <= 1.0))
    assert own[:, 0].mean() == pytest.approx(0.5, abs=0.06)
    assert own[:, 1].mean() < 1e-3
    assert densities.classes.tolist() == [3, 4]


def test_an_objects_score_does_not_depend_on_the_other_old_objects() -> None:
    rng = np.random.default_rng(6)
    groups = [rng.normal(c, 1.0, (20, 3)) for c in (0.0, 5.0, -5.0, 10.0)]
    query = rng.normal(0.3, 1.0, (5, 3))
    scores = []
    for k in (2, 3, 4):
        X = np.vstack(groups[:k])
        densities = ObjectDensities.fit(X, np.repeat(np.arange(k), 20), shrinkage=0.0)
        scores.append(densities.tail_probabilities(query)[:, 0])
    np.testing.assert_allclose(scores[0], scores[1], rtol=1e-12)
    np.testing.assert_allclose(scores[0], scores[2], rtol=1e-12)


def test_choose_by_density_threshold_rho_and_several_sources() -> None:
    choice = choose_by_density([0.02, 0.3, 0.2], [5, 6, 7], eps_density=0.1)
    assert choice.source == 6
    assert choice.rho == pytest.approx(0.6)
    assert choice.sources == (6,)
    refused = choose_by_density([0.02, 0.05], [5, 6], eps_density=0.1)
    assert refused.source is None
    assert refused.rho == 0.0
    assert refused.sources == ()
    several = choose_by_density([0.02, 0.3, 0.2, 0.4], [5, 6, 7, 8], max_sources=3)
    assert several.sources == (8, 6, 7)
    assert several.rhos == pytest.approx((0.8, 0.6, 0.4))
    halved = choose_by_density([0.02, 0.3], [5, 6], rho_scale=1.0)
    assert halved.rho == pytest.approx(0.3)
    assert choose_by_density([0.9], [5]).rho == 1.0  # capped
    with pytest.raises(AtiktError, match="eps_density"):
        choose_by_density([0.3], [1], eps_density=0.0)
    with pytest.raises(AtiktError, match="rho_scale"):
        choose_by_density([0.3], [1], rho_scale=0.0)


# ---------------------------------------------------------------- evidence relatedness


def test_evidence_gain_tells_related_from_confusing_and_unrelated_old_objects() -> None:
    rng = np.random.default_rng(7)
    X = np.vstack([rng.normal(0.0, 0.5, (4, 3)), rng.normal(3.0, 0.5, (8, 3))])
    y = np.r_[np.ones(4), np.zeros(8)]
    auxiliary = {
        1: rng.normal(0.0, 0.5, (6, 3)),  # like the new object
        2: rng.normal(3.0, 0.5, (6, 3)),  # like the other new objects: misleading
        3: rng.normal(-8.0, 0.5, (6, 3)),  # far from everything: no evidence either way
    }
    kernel = modality_kernel(SLICES)
    gains = evidence_gains(kernel, X, y, auxiliary)
    assert gains[0] > 0.5
    assert gains[1] < -1.0
    assert abs(gains[2]) < 1e-6
    # an old object's gain does not depend on which other old objects there are
    alone = evidence_gains(kernel, X, y, {1: auxiliary[1]})
    assert alone[0] == pytest.approx(gains[0], rel=1e-9)
    choice = choose_by_evidence(gains, [1, 2, 3], rho=0.8)
    assert choice.sources == (1,)
    assert choice.rho == 0.8
    assert choose_by_evidence(gains, [1, 2, 3], eps_evidence=5.0).source is None
    assert choose_by_evidence([0.0, 0.0], [1, 2]).source is None  # no evidence, no transfer
    several = choose_by_evidence([0.3, 2.0, -1.0, 0.1], [5, 6, 7, 8], max_sources=3)
    assert several.sources == (6, 5, 8)
    with pytest.raises(AtiktError, match=r"rho=0\.0"):
        evidence_gains(kernel, X, y, auxiliary, rho=0.0)


# ---------------------------------------------------------------- fusion: shared, evidence


def three_classes(seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    centres = np.array([[0.0, 0.0, 0.0], [0.0, 3.0, 0.0], [0.0, 0.0, 3.0]])  # thermal only
    X = np.vstack([c + 0.5 * rng.standard_normal((4, 3)) for c in centres])
    return X, np.repeat([0, 1, 2], 4)


def test_shared_hyperparameters_are_one_set_and_raise_the_summed_evidence() -> None:
    X, y = three_classes(7)
    kernel = modality_kernel(SLICES)
    shared = OneVsAllGPC(kernel, shared=True, random_state=0).fit(X, y)
    thetas = [e.kernel_.theta for e in shared.estimators_]
    for theta in thetas[1:]:
        np.testing.assert_array_equal(theta, thetas[0])
    start = OneVsAllGPC(kernel, optimize=False).fit(X, y)
    total = sum(e.log_marginal_likelihood_value_ for e in shared.estimators_)
    assert total >= sum(e.log_marginal_likelihood_value_ for e in start.estimators_)
    again = OneVsAllGPC(kernel, shared=True, random_state=0).fit(X, y)
    np.testing.assert_array_equal(shared.predict_proba(X), again.predict_proba(X))


def test_hyperprior_gradient_matches_finite_differences() -> None:
    kernel = modality_kernel(SLICES)
    X, y = three_classes(8)[0], np.repeat([1.0, 0.0], 6)

    def penalised(theta: np.ndarray) -> tuple[float, np.ndarray]:
        objective = BinaryGPC(kernel)._objective(X, y)  # fresh: no warm start
        return with_prior(objective, kernel, 0.7)(theta)

    theta = np.array([0.3, -0.2, 0.5, 0.1])
    value, gradient = penalised(theta)
    h = 1e-6
    numeric = [
        (penalised(theta + h * e)[0] - penalised(theta - h * e)[0]) / (2 * h)
        for e in np.eye(theta.shape[0])
    ]
    np.testing.assert_allclose(gradient, numeric, rtol=1e-4, atol=1e-6)
    plain = BinaryGPC(kernel)._objective(X, y)
    assert value > plain(theta)[0]
    assert with_prior(plain, kernel, None) is plain


def observations(seed: int) -> tuple[list[RawFeatures], list[int]]:
    rng = np.random.default_rng(seed)
    out, labels = [], []
    for label, level in enumerate((0.0, 1.0, 2.0)):
        for _ in range(3):
            force = np.array([4.5 + 0.3 * rng.standard_normal()])  # uninformative
            thermal = level + 0.1 * rng.standard_normal(40)
            out.append(RawFeatures("static", {"force": force, "thermal": thermal}))
            labels.append(label)
    return out, labels


@pytest.mark.parametrize("selection", ["fused", "evidence", "evidence-all"])
def test_multi_modal_selection(selection: str) -> None:
    train, labels = observations(9)
    model = MultiModalGPC(selection=selection, random_state=0).fit(train, labels)  # type: ignore[arg-type]
    assert len(model.selected_) == 3
    assert all(s in {("force", "thermal"), ("force",), ("thermal",)} for s in model.selected_)
    if selection == "fused":
        assert set(model.selected_) == {("force", "thermal")}
    if selection == "evidence-all":
        assert len(set(model.selected_)) == 1
    assert model.score(train, labels) > 0.9
    with pytest.raises(AtiktError, match="selection"):
        MultiModalGPC(selection="vote").fit(train, labels)  # type: ignore[arg-type]


def test_initial_theta_with_a_tight_prior_keeps_the_reference_weights() -> None:
    """A reference fitted on many samples decides the weights of a fit on one per class."""
    many, many_labels = observations(20)
    reference = MultiModalGPC(random_state=0).fit(many, many_labels)
    logit = 2  # theta: [log l_force, log l_thermal, thermal logit, log s^2]
    weights = reference.theta_[logit]
    first, first_labels = observations(1)
    few, few_labels = first[::3], first_labels[::3]  # one observation per class
    free = MultiModalGPC(random_state=0).fit(few, few_labels)
    tied = MultiModalGPC(initial_theta=reference.theta_, prior_sd=0.05, random_state=0).fit(
        few, few_labels
    )
    assert abs(tied.theta_[logit] - weights) < abs(free.theta_[logit] - weights)
    assert abs(tied.theta_[logit] - weights) < 0.2
    with pytest.raises(AtiktError, match="initial_theta"):
        MultiModalGPC(initial_theta=[0.0]).fit(few, few_labels)


# --------------------------------------------------------------------- the learner


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


@pytest.mark.parametrize(
    ("transfer", "max_sources"),
    [("density", 1), ("density", 3), ("prediction", 3), ("evidence", 1), ("evidence", 3)],
)
def test_density_and_multi_source_learners_are_deterministic(
    train: dict[str, dict[int, list[RawFeatures]]],
    priors: dict[str, dict[int, list[RawFeatures]]],
    transfer: str,
    max_sources: int,
) -> None:
    first = run(train, priors=priors, transfer=transfer, max_sources=max_sources)
    again = run(train, priors=priors, transfer=transfer, max_sources=max_sources)
    assert [r.as_row() for r in first.history_] == [r.as_row() for r in again.history_]
    for state in first.states_.values():
        for choice, model in zip(state.choices, state.models, strict=True):
            assert len(choice.sources) <= max_sources
            assert model.rhos_.shape[0] == len(choice.sources)


def test_a_hyperprior_keeps_the_hyperparameters_near_its_centre() -> None:
    rng = np.random.default_rng(3)
    X = np.vstack([rng.normal(0.0, 0.3, (3, 3)), rng.normal(2.0, 0.3, (6, 3))])
    y = np.r_[np.ones(3), np.zeros(6)]
    kernel = modality_kernel(SLICES)
    centre = kernel.theta
    distances = []
    for sd in (None, 3.0, 0.3):
        model = TransferGPC(kernel, prior_sd=sd, prior_mean=centre, random_state=0).fit(X, y)
        distances.append(float(np.linalg.norm(model.base_kernel_.theta - centre)))
    assert distances[0] > distances[1] > distances[2]
    # with a learned rho the prior covers rho too (one more entry), and the fit runs
    aux = rng.normal(0.0, 0.3, (4, 3))
    learned = TransferGPC(kernel, rho=0.5, learn_rho=True, prior_sd=1.0, random_state=0)
    assert 0.0 < learned.fit(X, y, aux).rho_ <= 1.0


def test_a_learner_with_a_hyperprior_is_deterministic_and_not_the_ml_learner(
    train: dict[str, dict[int, list[RawFeatures]]],
    priors: dict[str, dict[int, list[RawFeatures]]],
) -> None:
    first = run(train, priors=priors, hyper_sd=3.0, metric_sd=None)
    again = run(train, priors=priors, hyper_sd=3.0, metric_sd=None)
    assert [r.as_row() for r in first.history_] == [r.as_row() for r in again.history_]
    ml = run(train, priors=priors, metric_sd=None)
    theta = [m.base_kernel_.theta for s in first.states_.values() for m in s.models]
    ml_theta = [m.base_kernel_.theta for s in ml.states_.values() for m in s.models]
    assert any(not np.allclose(a, b) for a, b in zip(theta, ml_theta, strict=True))


@pytest.mark.parametrize(
    "refuse",
    [{"transfer": "density", "eps_density": 1.0}, {"transfer": "evidence", "eps_evidence": 1e9}],
)
def test_a_learner_refusing_every_prior_is_the_baseline(
    train: dict[str, dict[int, list[RawFeatures]]],
    priors: dict[str, dict[int, list[RawFeatures]]],
    refuse: dict[str, object],
) -> None:
    refusing = run(train, priors=priors, metric_sd=None, **refuse)
    baseline = run(train, transfer="none")
    assert all(r.prior is None for r in refusing.history_)
    assert [r.object for r in refusing.history_] == [r.object for r in baseline.history_]
    assert [r.mean_entropy for r in refusing.history_] == [
        r.mean_entropy for r in baseline.history_
    ]


def test_metric_transfer_starts_the_new_classifiers_at_the_old_objects_kernel(
    train: dict[str, dict[int, list[RawFeatures]]],
    priors: dict[str, dict[int, list[RawFeatures]]],
) -> None:
    # instance transfer refused: what differs from the baseline is the metric alone
    refuse = {"transfer": "evidence", "eps_evidence": 1e9, "budget": 0}
    metric = run(train, priors=priors, metric_sd=0.01, metric_check=False, **refuse)
    plain = run(train, transfer="none", budget=0)
    for action in ACTIONS:
        prior = metric.states_[action].prior
        assert prior is not None
        assert prior.model is not None
        centre = np.median([e.kernel_.theta for e in prior.model.estimators_], axis=0)
        start = modality_kernel(metric.states_[action].transformer.slices_).theta  # type: ignore[union-attr]
        assert not np.allclose(centre, start)
        for model, baseline in zip(
            metric.states_[action].models, plain.states_[action].models, strict=True
        ):
            # a tight prior keeps each fit at the old objects' kernel, far from the baseline's
            fitted = model.base_kernel_.theta
            assert np.abs(fitted - centre).max() < 0.1
            assert np.abs(baseline.base_kernel_.theta - centre).max() > 0.1
    again = run(train, priors=priors, metric_sd=0.01, metric_check=False, **refuse)
    assert [m.base_kernel_.theta.tolist() for s in again.states_.values() for m in s.models] == [
        m.base_kernel_.theta.tolist() for s in metric.states_.values() for m in s.models
    ]


@pytest.mark.parametrize("check", ["evidence", "separation", "either"])
def test_the_metric_check_keeps_the_old_kernel_only_when_it_passes(
    train: dict[str, dict[int, list[RawFeatures]]],
    priors: dict[str, dict[int, list[RawFeatures]]],
    check: str,
) -> None:
    refuse = {"transfer": "evidence", "eps_evidence": 1e9, "budget": 0, "metric_sd": 0.01}
    checked = run(train, priors=priors, metric_check=check, **refuse)
    plain = run(train, transfer="none", budget=0)
    for action in ACTIONS:
        state = checked.states_[action]
        assert state.prior is not None
        assert state.prior.model is not None
        initial = modality_kernel(state.transformer.slices_)  # type: ignore[union-attr]
        centre = np.median([e.kernel_.theta for e in state.prior.model.estimators_], axis=0)
        metric, labels = initial.with_theta(centre), np.asarray(state.labels)
        aux = checked._auxiliary(state, state.transformer)  # type: ignore[arg-type]
        by_evidence = checked._evidence(metric, state.X, labels) >= checked._evidence(
            initial, state.X, labels
        )
        by_separation = separation(metric, state.X, labels, aux) >= separation(
            initial, state.X, labels, aux
        )
        passed = {
            "evidence": by_evidence,
            "separation": by_separation,
            "either": by_evidence or by_separation,
        }[check]
        thetas = [m.base_kernel_.theta for m in state.models]
        baseline = [m.base_kernel_.theta for m in plain.states_[action].models]
        assert state.metrics == [bool(passed)] * len(NEW_OBJECTS)
        if passed:
            assert all(np.abs(t - centre).max() < 0.1 for t in thetas)
        else:  # the baseline's fits exactly
            assert all(np.array_equal(a, b) for a, b in zip(thetas, baseline, strict=True))


def test_metric_until_hands_a_well_observed_object_back_to_its_own_data(
    train: dict[str, dict[int, list[RawFeatures]]],
    priors: dict[str, dict[int, list[RawFeatures]]],
) -> None:
    # metric only, unchecked: an object past metric_until loses the old kernel's hyperprior
    settings = {
        "transfer": "evidence",
        "eps_evidence": 1e9,
        "metric_sd": 0.5,
        "metric_check": "none",
        "hyper_sd": 3.0,
        "budget": 8,
        "eps_explore": 0.0,
    }
    held = run(train, priors=priors, metric_until=1, **settings)
    always = run(train, priors=priors, metric_until=None, **settings)
    seen = set()
    for action in ACTIONS:
        state = held.states_[action]
        assert state.prior is not None
        assert state.prior.model is not None
        centre = np.median([e.kernel_.theta for e in state.prior.model.estimators_], axis=0)
        counts = np.bincount(state.labels, minlength=len(NEW_OBJECTS))
        for obj, (model, pulled) in enumerate(
            zip(state.models, always.states_[action].models, strict=True)
        ):
            assert pulled.prior_mean is not None
            assert model.prior_mean is not None
            assert (pulled.prior_sd, pulled.prior_mean.tolist()) == (0.5, centre.tolist())
            own = counts[obj] > 1
            seen.add(own)
            expected = 3.0 if own else 0.5
            assert model.prior_sd == expected
            assert np.allclose(model.prior_mean, centre) != own
            assert state.metrics[obj] != own
            assert always.states_[action].metrics[obj]
    assert seen == {True, False}
    # the records and the share say the same: per action, then over all classifiers
    last = {r.action: r.metrics for r in held.history_}
    assert all(list(last[a]) == held.states_[a].metrics for a in last)
    flags = [m for a in ACTIONS for m in held.states_[a].metrics]
    assert 0.0 < held.metric_share() == sum(flags) / len(flags) < 1.0
    assert always.metric_share() == 1.0
    with pytest.raises(AtiktError, match="metric_until=0 must be None or >= 1"):
        ActiveLearner(ACTIONS, 2, observe=PoolObserver({}), metric_until=0)


def test_separation_prefers_the_kernel_whose_modality_tells_the_new_objects_apart() -> None:
    rng = np.random.default_rng(0)
    # modality a (columns 0-1) tells objects apart, modality b (columns 2-3) is noise
    centres = rng.normal(0.0, 3.0, (8, 2))

    def observations(obj: int, n: int) -> np.ndarray:
        tight = centres[obj] + rng.normal(0.0, 0.1, (n, 2))
        return np.hstack([tight, rng.normal(0.0, 1.0, (n, 2))])

    aux = {old: observations(old, 6) for old in range(4)}
    X = np.vstack([observations(new, 1) for new in range(4, 8)])
    labels = np.arange(4)
    slices = {"a": slice(0, 2), "b": slice(2, 4)}
    kernel = modality_kernel(slices, length_scale=2.0)
    on_a = kernel.with_theta([np.log(2.0), np.log(2.0), -5.0, 0.0])
    on_b = kernel.with_theta([np.log(2.0), np.log(2.0), 5.0, 0.0])
    # every pair of new objects less alike than any repeat on a; not so on b
    assert separation(on_a, X, labels, aux) == 1.0 > separation(on_b, X, labels, aux)
    # a rank statistic: scaling the kernel's amplitude changes nothing
    louder = on_b.with_theta([np.log(2.0), np.log(2.0), 5.0, np.log(50.0)])
    assert separation(louder, X, labels, aux) == separation(on_b, X, labels, aux)
    # a long old recording counts with SEPARATION_REPEATS evenly spaced observations
    long = {0: np.vstack([observations(0, 1) for _ in range(100)])}
    spaced = {0: long[0][np.linspace(0, 99, SEPARATION_REPEATS).astype(int)]}
    assert separation(on_b, X, labels, long) == separation(on_b, X, labels, spaced)
    assert separation(on_b, X, labels, long) != separation(on_b, X, labels, {0: long[0][:50]})
    # one-observation old objects give no repeat pair, one new object no different pair
    assert separation(on_a, X, labels, {0: aux[0][:1]}) == -np.inf
    assert separation(on_a, X[:2], np.array([0, 0]), aux) == -np.inf
    # new objects observed twice as alike as repeats: no separation
    same = np.vstack([X[:1], X[:1] + 1e-3])
    assert separation(on_a, same, np.array([0, 1]), aux) < 0.05


def test_metric_check_must_be_a_known_check() -> None:
    with pytest.raises(AtiktError, match="metric_check='loose' must be one of"):
        ActiveLearner(ACTIONS, 2, observe=PoolObserver({}), metric_check="loose")
    learner = ActiveLearner(ACTIONS, 2, observe=PoolObserver({}), metric_check=True)
    assert learner.options.metric_check == "evidence"
    learner = ActiveLearner(ACTIONS, 2, observe=PoolObserver({}), metric_check=False)
    assert learner.options.metric_check == "none"


def test_metric_transfer_needs_two_old_objects_and_leaves_the_baseline_alone(
    train: dict[str, dict[int, list[RawFeatures]]],
    priors: dict[str, dict[int, list[RawFeatures]]],
) -> None:
    baseline = run(train, transfer="none")
    with_metric = run(train, transfer="none", priors=priors, metric_sd=0.01)
    assert [r.as_row() for r in with_metric.history_] == [r.as_row() for r in baseline.history_]
    assert with_metric.metric_share() == 0.0
    assert not any(any(r.metrics) for r in with_metric.history_)
    # a single old object has no one-vs-all model: the optimisation approach runs without
    one = {a: {k: v for k, v in groups.items() if k == min(groups)} for a, groups in priors.items()}
    single = run(train, priors=one, transfer="optimization", metric_sd=0.01, budget=1)
    plain = run(train, priors=one, transfer="optimization", metric_sd=None, budget=1)
    assert [r.as_row() for r in single.history_] == [r.as_row() for r in plain.history_]


def test_max_sources_and_rho_scale_must_be_positive() -> None:
    with pytest.raises(AtiktError, match="max_sources=0 must be >= 1"):
        ActiveLearner(ACTIONS, 2, observe=PoolObserver({}), max_sources=0)
    with pytest.raises(AtiktError, match=r"density_rho_scale=0\.0 must be > 0"):
        ActiveLearner(
            ACTIONS, 2, observe=PoolObserver({}), transfer="density", density_rho_scale=0.0
        )
    with pytest.raises(AtiktError, match=r"hyper_sd=0\.0 must be None or > 0"):
        ActiveLearner(ACTIONS, 2, observe=PoolObserver({}), hyper_sd=0.0)
    with pytest.raises(AtiktError, match=r"metric_sd=-1\.0 must be None or > 0"):
        ActiveLearner(ACTIONS, 2, observe=PoolObserver({}), metric_sd=-1.0)
    with pytest.raises(AtiktError, match=r"evidence_rho=1\.5 must lie in"):
        ActiveLearner(ACTIONS, 2, observe=PoolObserver({}), transfer="evidence", evidence_rho=1.5)
    with pytest.raises(AtiktError, match="eps_evidence=nan must be finite"):
        ActiveLearner(
            ACTIONS, 2, observe=PoolObserver({}), transfer="evidence", eps_evidence=float("nan")
        )


def test_a_strategy_refuses_options_it_does_not_own() -> None:
    with pytest.raises(AtiktError, match=r"transfer 'prediction' has no option eps_density"):
        ActiveLearner(ACTIONS, 2, observe=PoolObserver({}), eps_density=0.2)
    with pytest.raises(AtiktError, match="unknown learner option"):
        ActiveLearner(ACTIONS, 2, observe=PoolObserver({}), eps_neg3=0.2)


def test_options_round_trip_through_their_dict() -> None:
    options = LearnerOptions.from_dict(
        {"transfer": "density", "eps_density": 0.2, "kernel_parts": {"texture": "matern32"}}
    )
    assert LearnerOptions.from_dict(json.loads(json.dumps(options.as_dict()))) == options
    assert options.replace(transfer="none").transfer == NoTransfer()
    assert options.replace(max_sources=3).transfer == Density(eps_density=0.2, max_sources=3)


def test_a_registered_strategy_is_used_by_name(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(strategies, "_REGISTRY", dict(strategies._REGISTRY))

    @dataclass(frozen=True, slots=True)
    class Never(TransferStrategy):
        name: ClassVar[str] = "never-test"

    register_strategy(Never)
    assert "never-test" in strategy_names()
    assert transfer_strategy("never-test") == Never()

    @dataclass(frozen=True, slots=True)
    class Other(TransferStrategy):
        name: ClassVar[str] = "never-test"

    with pytest.raises(AtiktError, match="name 'never-test' is empty or taken"):
        register_strategy(Other)


def test_separation_and_evidence_from_shared_distances_equal_plain_kernel_calls() -> None:
    learner = ActiveLearner(
        ACTIONS, len(NEW_OBJECTS), observe=PoolObserver(pool(NEW_OBJECTS, ACTIONS, 3, seed=4))
    )
    rng = np.random.default_rng(5)
    slices = {"a": slice(0, 2), "b": slice(2, 5)}
    X, labels = rng.normal(size=(7, 5)), np.array([0, 1, 2, 0, 1, 2, 3])
    aux = {old: rng.normal(size=(9, 5)) for old in range(3)}
    initial = modality_kernel(slices)
    metric = initial.with_theta([0.4, -0.3, 1.2, 0.5])
    pairs = SeparationPairs.of(X, labels, aux)
    assert pairs is not None
    for kernel in (metric, initial, metric):  # the second call of a slice reads kept distances
        K = kernel(pairs.rows)
        scale = float(kernel.diag(pairs.first)[0])
        pooled, between = np.sort(K[pairs.repeats] / scale), K[pairs.between] / scale
        below = np.searchsorted(pooled, between, side="left")
        above = np.searchsorted(pooled, between, side="right")
        plain = float(np.mean(1.0 - (below + above) / (2.0 * pooled.size)))
        assert pairs.score(kernel) == plain
    distances = [part.sq_dist(X) for part in initial.parts]
    for kernel in (metric, initial):
        shared = learner._evidence(kernel, X, labels, distances)
        assert shared == learner._evidence(kernel, X, labels)
