"""The declared-noise prior on the modality weights: feature noise, logits, the fused fit."""

from __future__ import annotations

import numpy as np
import pytest

from atikt import AtiktError, ModalityKernel, MultiModalGPC, RawFeatures
from atikt.gpc import with_prior
from atikt.kernels import modality_kernel
from atikt.noise import feature_noise, noise_length_scales, noise_logits, signal_to_noise

NOISE = {"force": 0.05, "thermal": 0.03125}


def test_feature_noise_per_block() -> None:
    np.testing.assert_array_equal(feature_noise("force", 1, 0.05), [0.05])
    thermal = feature_noise("thermal", 6, 0.5)
    np.testing.assert_array_equal(thermal[:3], [0.5, 0.5, 0.5])
    assert np.isnan(thermal[3:]).all()  # the gradient's noise is not derived
    texture = feature_noise("texture", 12, 0.1)
    np.testing.assert_allclose(texture[:3], 0.01)  # activities: the noise's own variance
    assert np.isnan(texture[3:]).all()
    np.testing.assert_allclose(feature_noise("texture", 4, 0.1)[:1], 0.01)
    assert np.isnan(feature_noise("force", 1, 0.0)).all()  # not declared


def test_feature_noise_refuses_unknown_layouts() -> None:
    with pytest.raises(AtiktError, match="texture block of 5"):
        feature_noise("texture", 5, 0.1)
    with pytest.raises(AtiktError, match="'sound'"):
        feature_noise("sound", 2, 0.1)


def test_signal_to_noise_is_variance_over_noise_power() -> None:
    raw = np.array([[0.0, 1.0], [2.0, 1.0]])
    assert signal_to_noise(raw, np.array([0.5, np.nan])) == pytest.approx(1.0 / 0.25)
    assert np.isnan(signal_to_noise(raw, np.array([np.nan, np.nan])))


def test_noise_logits_favour_the_block_far_above_its_noise() -> None:
    blocks = {"force": np.array([[1.0], [1.1], [0.9]]), "thermal": np.array([[0.0], [5.0], [9.0]])}
    noise = {m: feature_noise(m, 1 if m == "force" else 2, NOISE[m]) for m in blocks}
    noise["thermal"] = np.array([NOISE["thermal"]])
    logits = noise_logits(blocks, noise, ("force", "thermal"), (-6.0, 6.0))
    assert logits is not None
    snr_force = np.var([1.0, 1.1, 0.9]) / 0.05**2
    snr_thermal = np.var([0.0, 5.0, 9.0]) / 0.03125**2
    np.testing.assert_allclose(logits, [min(6.0, np.log(snr_thermal / snr_force))])
    # a modality without declared noise is neutral (the geometric mean of the others)
    three = noise_logits(
        blocks | {"texture": blocks["force"]}, noise, ("force", "texture", "thermal"), (-20.0, 20.0)
    )
    assert three is not None
    np.testing.assert_allclose(three[0], 0.5 * np.log(snr_thermal / snr_force))
    assert noise_logits(blocks, {}, ("force", "thermal"), (-6.0, 6.0)) is None


def test_with_prior_takes_one_sd_per_hyperparameter() -> None:
    kernel = modality_kernel({"a": slice(0, 1), "b": slice(1, 2)})
    function = with_prior(
        lambda t: (0.0, np.zeros_like(t)), kernel, np.array([np.inf, 1.0, 0.5, 2.0])
    )
    theta = np.array([3.0, 1.0, 1.0, 2.0])
    value, gradient = function(theta)
    assert value == pytest.approx(0.5 * (1.0 + 4.0 + 1.0))
    np.testing.assert_allclose(gradient, [0.0, 1.0, 4.0, 0.5])
    with pytest.raises(AtiktError, match="need sd > 0"):
        with_prior(lambda t: (0.0, t), kernel, np.array([1.0, 0.0, 1.0, 1.0]))


def probe_like(n_per_object: int, seed: int) -> tuple[list[RawFeatures], list[int]]:
    """Three objects: force the same (spread 0.3 N, a few times its noise), temperatures apart."""
    rng = np.random.default_rng(seed)
    observations, labels = [], []
    for label, level in enumerate([20.0, 22.0, 25.0]):
        for _ in range(n_per_object):
            curve = level + 0.3 * rng.standard_normal() + np.linspace(0.0, -1.0, 20) * (label + 1)
            blocks = {
                "force": np.array([4.0 + 0.3 * rng.standard_normal()]),
                "thermal": np.concatenate([curve, np.gradient(curve)]),
            }
            observations.append(RawFeatures("static", blocks))
            labels.append(label)
    return observations, labels


def test_declared_noise_weights_the_informative_modality_with_one_sample() -> None:
    train, labels = probe_like(1, 0)
    test, test_labels = probe_like(30, 1)
    fused = MultiModalGPC(sensor_noise=NOISE, prior_sd=1.0, random_state=0).fit(train, labels)
    kernel = fused.model_.estimators_[0].kernel_
    assert isinstance(kernel, ModalityKernel)
    weights = kernel.weights
    assert weights[1] > 0.95  # thermal
    thermal = MultiModalGPC(["thermal"], random_state=0).fit(train, labels)
    assert fused.score(test, test_labels) >= thermal.score(test, test_labels) - 0.02


def test_without_declared_noise_the_fit_is_unchanged() -> None:
    train, labels = probe_like(2, 2)
    plain = MultiModalGPC(random_state=0).fit(train, labels)
    undeclared = MultiModalGPC(sensor_noise={}, random_state=0).fit(train, labels)
    np.testing.assert_array_equal(plain.theta_, undeclared.theta_)


def test_a_block_the_action_sets_has_unit_signal_to_noise() -> None:
    blocks = {"force": np.array([[1.0], [9.0]]), "thermal": np.array([[0.0], [1.0]])}
    noise = {"force": np.array([0.01]), "thermal": np.array([0.1])}
    free = noise_logits(blocks, noise, ("force", "thermal"), (-20.0, 20.0))
    controlled = noise_logits(blocks, noise, ("force", "thermal"), (-20.0, 20.0), ("force",))
    assert free is not None
    assert controlled is not None
    assert free[0] < 0  # force's spread is far above its noise
    np.testing.assert_allclose(controlled, [np.log(0.25 / 0.01)])  # SNR^2 of thermal over 1


def test_a_product_mutes_the_weaker_modality_with_a_long_length_scale() -> None:
    bounds = np.log([[0.05, 20.0]] * 3)
    logs = noise_length_scales(np.array([np.log(100.0), np.log(1e6)]), bounds)
    # SNR^2 relative to the best: 1e-6, 1e-4, 1 -> l = 1000 (clipped to 20), 100 (20), 1
    np.testing.assert_allclose(logs, [np.log(20.0), np.log(20.0), 0.0])
    train, labels = probe_like(1, 0)
    fused = MultiModalGPC(
        sensor_noise=NOISE, controlled=("force",), combination="product", random_state=0
    ).fit(train, labels)
    force_length, thermal_length = np.exp(fused.theta_[:2])
    assert force_length > 5 * thermal_length
