"""Transfer: the no-prior / rho = 0 reductions, refusing irrelevant priors, learned rho."""

from __future__ import annotations

import dataclasses
from types import MappingProxyType

import numpy as np
import pytest
from atikt_synthetic import OLD_OBJECTS, pool

from atikt import (
    AtiktError,
    BinaryGPC,
    NotFittedError,
    OneVsAllGPC,
    RawFeatures,
    TransferGPC,
    choose_by_optimization,
    choose_by_prediction,
    fit_prior_models,
    modality_kernel,
    relatedness,
    shared_observations,
    transfer_strategy,
)
from atikt.strategies import ObjectFit
from atikt.transfer import held_out_threshold

SLICES = {"force": slice(0, 1), "thermal": slice(1, 3)}
CENTRES = np.array([[0.0, 0.0, 0.0], [3.0, 3.0, 0.0], [-3.0, 0.0, 3.0]])


def cluster(centre: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    return centre + 0.4 * rng.standard_normal((n, 3))


def old_model(rng: np.random.Generator) -> OneVsAllGPC:
    X = np.vstack([cluster(c, 15, rng) for c in CENTRES])
    labels = np.repeat([7, 8, 9], 15)
    return OneVsAllGPC(modality_kernel(SLICES), random_state=0).fit(X, labels)


def new_data(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    X = np.vstack([cluster(CENTRES[0], 4, rng), cluster(np.array([0.0, -4.0, -4.0]), 4, rng)])
    return X, np.repeat([1.0, 0.0], 4)


def test_no_auxiliary_data_is_the_plain_gpc() -> None:
    rng = np.random.default_rng(0)
    X, y = new_data(rng)
    kernel = modality_kernel(SLICES)
    plain = BinaryGPC(kernel, random_state=3).fit(X, y)
    for aux in (None, np.zeros((0, 3))):
        transfer = TransferGPC(kernel, rho=0.9, random_state=3).fit(X, y, aux)
        assert not transfer.transferred_
        assert transfer.rho_ == 0.0
        np.testing.assert_array_equal(transfer.predict_positive(X), plain.predict_positive(X))


def test_rho_zero_equals_the_plain_gpc_at_fixed_hyperparameters() -> None:
    rng = np.random.default_rng(1)
    X, y = new_data(rng)
    aux = cluster(CENTRES[1], 10, rng)
    kernel = modality_kernel(SLICES).with_theta([0.2, -0.1, 0.3, 0.5])
    Xt = rng.standard_normal((20, 3)) * 2
    plain = BinaryGPC(kernel, optimize=False).fit(X, y).predict_positive(Xt)
    # rho = 0 short-cuts to the plain GPC ...
    shortcut = TransferGPC(kernel, rho=0.0, optimize=False).fit(X, y, aux)
    np.testing.assert_array_equal(shortcut.predict_positive(Xt), plain)
    # ... and the dependent GP with a (tiny) rho converges to it: the blocks decouple
    coupled = TransferGPC(kernel, rho=1e-9, optimize=False).fit(X, y, aux)
    assert coupled.transferred_
    np.testing.assert_allclose(coupled.predict_positive(Xt), plain, atol=1e-7)


def test_auxiliary_positives_raise_the_probability_near_them() -> None:
    rng = np.random.default_rng(2)
    X, y = new_data(rng)
    aux = cluster(CENTRES[0] + 0.5, 15, rng)
    kernel = modality_kernel(SLICES)
    probe = np.array([[0.5, 0.5, 0.5]])
    weak = TransferGPC(kernel, rho=0.0, optimize=False).fit(X, y, aux).predict_positive(probe)
    strong = TransferGPC(kernel, rho=0.9, optimize=False).fit(X, y, aux).predict_positive(probe)
    assert strong[0] > weak[0]


def test_prediction_approach_picks_the_related_old_object() -> None:
    rng = np.random.default_rng(3)
    model = old_model(rng)
    related = cluster(CENTRES[1], 5, rng)
    choice = choose_by_prediction(model, related, eps_neg1=0.6)
    assert choice.candidates == (7, 8, 9)
    assert choice.source == 8
    assert choice.rho == pytest.approx(max(choice.scores))
    assert choice.rho >= 0.6
    np.testing.assert_allclose(choice.scores, relatedness(model, related))


def test_prediction_approach_refuses_irrelevant_priors() -> None:
    rng = np.random.default_rng(4)
    model = old_model(rng)
    far = cluster(np.array([10.0, -10.0, 10.0]), 5, rng)  # unlike every old object
    choice = choose_by_prediction(model, far, eps_neg1=0.6)
    assert choice.source is None
    assert choice.rho == 0.0
    assert max(choice.scores) < 0.6
    assert max(choice.scores) == pytest.approx(0.5, abs=0.05)  # the GP prior: no opinion


@pytest.mark.parametrize("eps", [0.5, 0.3, 1.2])
def test_threshold_must_exceed_one_half(eps: float) -> None:
    model = old_model(np.random.default_rng(5))
    with pytest.raises(AtiktError, match="eps_neg1"):
        choose_by_prediction(model, np.zeros((1, 3)), eps_neg1=eps)


def test_optimization_approach_prefers_the_related_old_object() -> None:
    rng = np.random.default_rng(6)
    X, y = new_data(rng)
    auxiliary = {
        7: cluster(CENTRES[0], 12, rng),  # the positives' own cluster
        9: cluster(np.array([0.0, -4.0, -4.0]), 12, rng),  # where the negatives are
    }
    choice, model = choose_by_optimization(
        modality_kernel(SLICES), X, y, auxiliary, eps_neg2=0.5, random_state=0
    )
    scores = dict(zip(choice.candidates, choice.scores, strict=True))
    assert scores[7] > scores[9]
    assert choice.source == 7
    assert model.transferred_
    assert model.rho_ == pytest.approx(scores[7])
    none, plain = choose_by_optimization(
        modality_kernel(SLICES), X, y, {9: auxiliary[9]}, eps_neg2=0.5, random_state=0
    )
    assert none.source is None
    assert not plain.transferred_


def test_transfer_errors() -> None:
    X, y = new_data(np.random.default_rng(7))
    with pytest.raises(AtiktError, match="rho"):
        TransferGPC(modality_kernel(SLICES), rho=1.5).fit(X, y)
    with pytest.raises(AtiktError, match="columns"):
        TransferGPC(modality_kernel(SLICES), rho=0.5).fit(X, y, np.zeros((2, 5)))
    with pytest.raises(NotFittedError):
        TransferGPC(modality_kernel(SLICES)).predict_positive(X)


def test_training_positive_and_warm_start_from_the_previous_update() -> None:
    rng = np.random.default_rng(5)
    X, y = new_data(rng)
    aux = cluster(CENTRES[0] + 0.5, 12, rng)
    kernel = modality_kernel(SLICES)
    for source in (None, aux):
        previous = TransferGPC(kernel, rho=0.7).fit(X[:-1], y[:-1], source)
        np.testing.assert_allclose(
            previous.training_positive(), previous.predict_positive(X[:-1]), atol=1e-8
        )
        for later_source in (None, aux):  # the source may change between updates
            start = kernel.with_theta(previous.base_kernel_.theta)
            cold = TransferGPC(start, rho=0.7).fit(X, y, later_source)
            warm = TransferGPC(start, rho=0.7, previous=previous)
            warm.fit(X, y, later_source)
            assert warm.estimator_.n_evaluations_ <= cold.estimator_.n_evaluations_
            np.testing.assert_allclose(
                warm.predict_positive(X), cold.predict_positive(X), atol=0.02
            )


def test_shared_observations_keep_the_named_blocks_under_the_new_kind() -> None:
    press = RawFeatures(
        "press",
        MappingProxyType({"force": np.array([2.0]), "thermal": np.arange(40.0)}),
    )
    (static,) = shared_observations([press], "static", ["thermal"])
    assert static.kind == "static"
    assert static.modalities == ("thermal",)
    assert np.array_equal(static.blocks["thermal"], press.blocks["thermal"])
    with pytest.raises(AtiktError, match=r"no \['texture'\] features"):
        shared_observations([press], "slide", ["texture", "thermal"])


def test_held_out_threshold_rises_to_what_unrelated_known_objects_reach_by_chance() -> None:
    # old object A, left out: unrelated to both others by all its observations (means < 0.6),
    # but single observations reach 0.9 under one of them
    a = np.array([[0.9, 0.1], [0.2, 0.1], [0.1, 0.2], [0.2, 0.1]])
    # old object B: related to the first other (mean >= 0.6), unrelated to the second, which
    # also reaches 0.9 from one observation by chance
    b = np.array([[0.95, 0.9], [0.9, 0.1], [0.9, 0.2], [0.95, 0.1]])
    assert held_out_threshold([b[:, :1]], 0.6, 1, 0.9) == 0.6  # no unrelated known object
    one = held_out_threshold([a, b], 0.6, 1, 0.9)
    chance = [0.9, 0.2, 0.2, 0.2, 0.9, 0.1, 0.2, 0.1]  # best unrelated score per observation
    assert one == pytest.approx(np.quantile(chance, 0.9))
    assert one > 0.6
    # from 2 observations, runs of 2 average the chance away: the threshold is eps again
    assert held_out_threshold([a, b], 0.6, 2, 0.9) == 0.6
    assert held_out_threshold([a], 0.95, 1, 0.5) == 0.95  # never below eps


def test_prediction_with_held_out_quantile_refuses_a_chance_score_at_one_observation() -> None:
    model = fit_prior_models(pool(OLD_OBJECTS, ["P1"], n_trials=6, seed=2), random_state=0)["P1"]
    assert len(model.held_out) == 3  # one per old object, left out
    assert all(p.shape == (6, 2) for p in model.held_out)
    # the old objects, each left out, reach 0.9 by chance from one observation (not from two)
    chance = np.array([[0.9, 0.1], [0.1, 0.2], [0.95, 0.1], [0.2, 0.1], [0.2, 0.1], [0.1, 0.1]])
    model = dataclasses.replace(model, held_out=(chance, chance, chance))
    plain = transfer_strategy("prediction")
    calibrated = transfer_strategy("prediction", held_out_quantile=0.9)
    fit = ObjectFit(
        modality_kernel(SLICES),
        np.zeros((2, 3)),
        np.array([1.0, 0.0]),
        model,
        {},
        related=np.array([[0.2, 0.85, 0.1]]),  # one observation scoring 0.85
    )
    assert plain.choose(fit).source == model.old_objects[1]
    assert calibrated.choose(fit).source is None
    fit.related = np.array([[0.2, 0.85, 0.1], [0.2, 0.8, 0.1]])  # two: chance is 0.55 at most
    assert calibrated.choose(fit).source == model.old_objects[1]
    with pytest.raises(AtiktError, match=r"held_out_quantile=1.5"):
        transfer_strategy("prediction", held_out_quantile=1.5)


def test_exclusive_prediction_leaves_a_shared_source_to_its_most_related_new_object() -> None:
    model = fit_prior_models(pool(OLD_OBJECTS, ["P1"], n_trials=6, seed=2), random_state=0)["P1"]
    source = model.old_objects[1]
    fit = ObjectFit(
        modality_kernel(SLICES),
        np.zeros((2, 3)),
        np.array([1.0, 0.0]),
        model,
        {},
        related=np.array([[0.2, 0.8, 0.1]]),
        rivals=(np.array([0.1, 0.9, 0.2]),),  # another new object, more related to it
    )
    plain = transfer_strategy("prediction")
    exclusive = transfer_strategy("prediction", exclusive=True)
    assert plain.choose(fit).source == source
    assert exclusive.choose(fit).source is None
    assert plain.keeps()
    assert not exclusive.keeps()  # the choice depends on the other objects' observations
    fit.rivals = (np.array([0.1, 0.7, 0.2]), np.array([0.9, 0.3, 0.2]))  # less related / other
    assert exclusive.choose(fit).source == source


def test_prediction_with_min_tail_admits_only_within_the_old_objects_distribution() -> None:
    model = fit_prior_models(pool(OLD_OBJECTS, ["P1"], n_trials=6, seed=2), random_state=0)["P1"]
    gated = transfer_strategy("prediction", min_tail=0.05)
    scorer = gated.scorer(model)
    assert scorer is not None
    inside = model.transformer.transform(list(model.observations[:1]))
    assert scorer(inside).shape == (1, 6)  # probabilities, then tail probabilities
    fit = ObjectFit(
        modality_kernel(SLICES),
        np.zeros((2, 3)),
        np.array([1.0, 0.0]),
        model,
        {},
        related=np.array([[0.2, 0.9, 0.1, 0.5, 0.01, 0.5]]),  # 0.9, but far out in its tail
    )
    assert transfer_strategy("prediction").choose(fit).source == model.old_objects[1]
    assert gated.choose(fit).source is None
    fit.related = np.array([[0.2, 0.9, 0.1, 0.5, 0.3, 0.5]])
    assert gated.choose(fit).source == model.old_objects[1]
    with pytest.raises(AtiktError, match=r"min_tail=1.0"):
        transfer_strategy("prediction", min_tail=1.0)
