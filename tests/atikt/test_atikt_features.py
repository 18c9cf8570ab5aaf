"""Features against hand-computed values; the transformer uses training statistics only."""

from __future__ import annotations

import copy
import pickle
from types import MappingProxyType

import numpy as np
import pytest
from atikt_synthetic import thesis_features

import atikt.features as features_module
from atikt import (
    AtiktError,
    FeatureTransformer,
    NotFittedError,
    RawFeatures,
    extract_features,
    hjorth,
    linear_correlation,
    stiffness,
    texture,
    thermal_sequence,
)

FS = 1000.0


def sine(n: int = 20_000, freq: float = 25.0, amplitude: float = 2.0) -> np.ndarray:
    return np.asarray(amplitude * np.sin(2 * np.pi * freq * np.arange(n) / FS))


def test_hjorth_of_a_sine() -> None:
    freq, amplitude = 25.0, 2.0
    activity, mobility, complexity = hjorth(sine(freq=freq, amplitude=amplitude))
    assert activity == pytest.approx(amplitude**2 / 2, rel=1e-9)
    # dx[n] = 2 A sin(pi f / fs) cos(...): Mob = 2 sin(pi f / fs), and Comp = 1 for a sinusoid
    assert mobility == pytest.approx(2 * np.sin(np.pi * freq / FS), rel=1e-3)
    assert complexity == pytest.approx(1.0, rel=1e-3)


def test_hjorth_of_a_ramp() -> None:
    n, slope = 101, 0.5
    activity, mobility, complexity = hjorth(slope * np.arange(n))
    assert activity == pytest.approx(slope**2 * (n**2 - 1) / 12)
    assert mobility == 0.0  # constant first difference
    assert complexity == 0.0  # defined as 0 where a variance is 0


def test_hjorth_of_white_noise() -> None:
    sigma = 0.7
    x = sigma * np.random.default_rng(0).standard_normal(200_000)
    activity, mobility, complexity = hjorth(x)
    # Var(dx) = 2 s^2, Var(ddx) = 6 s^2  =>  Mob = sqrt 2, Comp = sqrt(3) / sqrt(2)
    assert activity == pytest.approx(sigma**2, rel=0.02)
    assert mobility == pytest.approx(np.sqrt(2), rel=0.01)
    assert complexity == pytest.approx(np.sqrt(1.5), rel=0.01)


def test_hjorth_is_vectorised_over_signals() -> None:
    rng = np.random.default_rng(1)
    x = rng.standard_normal((500, 4, 3))
    together = hjorth(x, axis=0)
    for c in range(4):
        for a in range(3):
            single = hjorth(x[:, c, a])
            for p, q in zip(together, single, strict=True):
                assert p[c, a] == pytest.approx(float(q))


def test_linear_correlation() -> None:
    rng = np.random.default_rng(2)
    x = rng.standard_normal(50_000)
    assert linear_correlation(x, 3 * x + 1) == pytest.approx(1.0)
    assert linear_correlation(x, -x) == pytest.approx(-1.0)
    assert abs(linear_correlation(x, rng.standard_normal(50_000))) < 0.02
    assert linear_correlation(x, np.ones_like(x)) == 0.0  # constant signal


def texture_signal(n_cells: int = 7) -> np.ndarray:
    rng = np.random.default_rng(3)
    s = sine()
    acc = np.empty((s.shape[0], n_cells, 3))
    acc[:, :, 0] = s[:, None]
    acc[:, :, 1] = 2 * s[:, None]
    acc[:, :, 2] = rng.standard_normal((s.shape[0], n_cells))
    return acc


def test_texture_descriptor_per_axis() -> None:
    acc = texture_signal()
    descriptor = texture(acc)
    assert descriptor.shape == (12,)
    act, mob, comp, lcorr = descriptor[:3], descriptor[3:6], descriptor[6:9], descriptor[9:]
    assert act[0] == pytest.approx(2.0)  # A^2 / 2 with A = 2
    assert act[1] == pytest.approx(8.0)  # (2A)^2 / 2
    assert act[2] == pytest.approx(1.0, rel=0.05)
    assert mob[0] == pytest.approx(mob[1])  # scaling does not change mobility
    assert mob[2] == pytest.approx(np.sqrt(2), rel=0.02)
    assert comp[0] == pytest.approx(1.0, rel=1e-3)
    assert lcorr[0] == pytest.approx(1.0)  # xy
    assert abs(lcorr[1]) < 0.05  # yz
    assert abs(lcorr[2]) < 0.05  # xz


def test_texture_descriptor_averaged() -> None:
    acc = texture_signal()
    per_axis = texture(acc)
    averaged = texture(acc, per_axis=False)
    assert averaged.shape == (4,)
    expected = [per_axis[i : i + 3].mean() for i in (0, 3, 6, 9)]
    np.testing.assert_allclose(averaged, expected)


def test_stiffness_is_the_mean_force() -> None:
    force = np.full((750, 7, 3), 0.4)
    force[:, 0, :] = 1.1
    assert stiffness(force) == pytest.approx([(6 * 0.4 + 1.1) / 7])


def test_thermal_sequence_of_a_ramp() -> None:
    rate, slope = 20.0, -0.1
    t = np.arange(60) / rate
    temperature = 30.0 + slope * t[:, None] + np.linspace(-0.3, 0.3, 7)[None, :]
    features = thermal_sequence(temperature, n_points=10, rate_hz=rate)
    expected_t = 30.0 + slope * np.linspace(0, t[-1], 10)
    np.testing.assert_allclose(features[:10], expected_t)
    np.testing.assert_allclose(features[10:], slope)


def test_thermal_sequence_has_a_fixed_length_for_any_duration() -> None:
    short = thermal_sequence(np.full((20, 7), 29.0), n_points=16)
    long = thermal_sequence(np.full((300, 7), 29.0), n_points=16)
    assert short.shape == long.shape == (32,)


def test_extract_features_per_kind() -> None:
    rng = np.random.default_rng(4)
    force = rng.uniform(0, 1, (750, 7, 3))
    acc = rng.standard_normal((1000, 7, 3))
    temp = 29 + rng.standard_normal((60, 7)) * 0.01
    press = thesis_features("press", force, None, temp, n_thermal_points=12)
    slide = thesis_features("slide", None, acc, temp, n_thermal_points=12)
    assert press.modalities == ("force", "thermal")
    assert press.modality("thermal").shape == (24,)
    assert slide.modalities == ("texture", "thermal")
    assert slide.modality("texture").shape == (12,)
    with pytest.raises(ValueError, match="read-only"):
        press.modality("thermal")[0] = 1.0
    with pytest.raises(AtiktError, match="texture"):
        press.modality("texture")


@pytest.mark.parametrize(
    ("kind", "force", "acc", "temp", "match"),
    [
        ("press", np.ones((5, 7)), None, np.ones((5, 7)), "3-d array"),
        ("press", np.ones((0, 7, 3)), None, np.ones((5, 7)), "no samples"),
        ("press", np.full((5, 7, 3), np.nan), None, np.ones((5, 7)), "NaN"),
        ("press", np.ones((5, 7, 3)), None, np.ones((1, 7)), ">= 2 samples"),
        ("slide", None, np.ones((2, 7, 3)), np.ones((5, 7)), "n_samples >= 3"),
    ],
)
def test_extract_features_rejects_bad_input(
    kind: str, force: np.ndarray | None, acc: np.ndarray | None, temp: np.ndarray, match: str
) -> None:
    with pytest.raises(AtiktError, match=match):
        thesis_features(kind, force, acc, temp)


def test_extract_features_takes_any_subset_of_blocks_and_widths() -> None:
    rng = np.random.default_rng(9)
    scalar_force = rng.uniform(0, 1, (100, 1, 1))
    one_axis = rng.standard_normal((400, 1, 1))
    two_sensors = 29 + rng.standard_normal((80, 1, 2)) * 0.01
    features = extract_features(
        "slide",
        {
            "force": (scalar_force, 100.0),
            "texture": (one_axis, 2200.0),
            "thermal": (two_sensors, 200.0),
        },
    )
    assert features.modalities == ("force", "texture", "thermal")
    assert features.modality("texture").shape == (3,)  # Act, Mob, Comp: no axis pairs
    assert features.modality("force")[0] == pytest.approx(scalar_force.mean())
    with pytest.raises(AtiktError, match="non-empty subset"):
        extract_features("slide", {})
    with pytest.raises(AtiktError, match="non-empty subset"):
        extract_features("slide", {"vision": (one_axis, 1.0)})


def random_observations(
    n: int, seed: int, kind: str = "press", shift: float = 0.0
) -> list[RawFeatures]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        force = rng.uniform(0, 2, (1, 1, 1)) + shift + 0.1 * rng.standard_normal((50, 7, 3))
        temp = 29 + np.cumsum(rng.standard_normal((60, 7)) * 0.05, axis=0) + shift
        acc = rng.standard_normal((200, 7, 3)) * (1 + shift)
        out.append(thesis_features(kind, force, acc, temp))
    return out


def test_transformer_blocks_have_unit_total_variance_on_training_data() -> None:
    train = random_observations(40, seed=5, kind="slide")
    transformer = FeatureTransformer(n_thermal_components=10)
    X = transformer.fit_transform(train)
    assert transformer.modalities_ == ("texture", "thermal")
    assert X.shape == (40, 12 + 10)
    for cols in transformer.slices_.values():
        block = X[:, cols]
        np.testing.assert_allclose(block.mean(axis=0), 0.0, atol=1e-12)
        assert block.var(axis=0).sum() == pytest.approx(1.0)


def test_pca_is_fitted_on_training_data_only() -> None:
    train = random_observations(30, seed=6)
    test = random_observations(10, seed=7, shift=3.0)
    transformer = FeatureTransformer(n_thermal_components=4).fit(train)
    X_test = transformer.transform(test)
    # the same numbers by hand, from training statistics only
    raw_train = np.vstack([o.modality("thermal") for o in train])
    raw_test = np.vstack([o.modality("thermal") for o in test])
    mean = raw_train.mean(axis=0)
    half = raw_train.shape[1] // 2
    scale = np.concatenate(
        [
            np.full(half, np.sqrt(np.mean((raw_train[:, :half] - mean[:half]) ** 2))),
            np.full(half, np.sqrt(np.mean((raw_train[:, half:] - mean[half:]) ** 2))),
        ]
    )
    _, s, vt = np.linalg.svd((raw_train - mean) / scale, full_matrices=False)
    scores = ((raw_test - mean) / scale) @ vt[:4].T / np.sqrt((s[:4] ** 2 / 30).sum())
    np.testing.assert_allclose(np.abs(X_test[:, 1:]), np.abs(scores), rtol=1e-9, atol=1e-12)
    f_train = np.array([o.modality("force")[0] for o in train])
    f_test = np.array([o.modality("force")[0] for o in test])
    np.testing.assert_allclose(X_test[:, 0], (f_test - f_train.mean()) / f_train.std())
    # fitting on training + test data would give other numbers: the check above can fail
    leaky = FeatureTransformer(n_thermal_components=4).fit(train + test).transform(test)
    assert not np.allclose(np.abs(leaky), np.abs(X_test))


def test_transform_does_not_change_the_fitted_statistics() -> None:
    train = random_observations(20, seed=8)
    transformer = FeatureTransformer().fit(train)
    before = transformer.transform(train)
    transformer.transform(random_observations(50, seed=9, shift=10.0))
    np.testing.assert_array_equal(transformer.transform(train), before)


def test_few_training_observations_pad_the_thermal_block_with_zeros() -> None:
    train = random_observations(4, seed=10)
    X = FeatureTransformer(n_thermal_components=10).fit_transform(train)
    assert X.shape == (4, 11)
    thermal = X[:, 1:]
    np.testing.assert_array_equal(thermal[:, 3:], 0.0)  # 4 centred points span 3 dimensions
    assert np.all(np.abs(thermal[:, :3]).sum(axis=0) > 0)


def test_single_observation_does_not_divide_by_zero() -> None:
    X = FeatureTransformer().fit_transform(random_observations(1, seed=11))
    np.testing.assert_array_equal(X, 0.0)


def test_modality_subset() -> None:
    train = random_observations(10, seed=12)
    X = FeatureTransformer(modalities=["thermal"], n_thermal_components=3).fit_transform(train)
    assert X.shape == (10, 3)
    with pytest.raises(AtiktError, match="not available"):
        FeatureTransformer(modalities=["texture"]).fit(train)


def test_transformer_errors() -> None:
    with pytest.raises(NotFittedError):
        FeatureTransformer().transform(random_observations(1, seed=13))
    with pytest.raises(AtiktError, match="different kinds"):
        FeatureTransformer().fit(random_observations(2, 14) + random_observations(2, 15, "slide"))
    transformer = FeatureTransformer().fit(random_observations(3, seed=16))
    with pytest.raises(AtiktError, match="fitted on 'press'"):
        transformer.transform(random_observations(1, seed=17, kind="slide"))
    with pytest.raises(AtiktError, match="no observations"):
        FeatureTransformer().fit([])


def test_thermal_pca_survives_an_svd_that_gesdd_cannot_converge(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    calls = []

    def failing_svd(z: np.ndarray, **_: object) -> object:
        calls.append(z.shape)
        message = "SVD did not converge"
        raise np.linalg.LinAlgError(message)

    monkeypatch.setattr(np.linalg, "svd", failing_svd)
    z = np.random.default_rng(0).standard_normal((12, 8))
    u, singular, vt = features_module._svd(z)
    assert calls == [(12, 8)]
    np.testing.assert_allclose((u * singular) @ vt, z, atol=1e-10)


def test_stacked_observations_transform_like_the_observations() -> None:
    train = random_observations(12, seed=8)
    test = random_observations(5, seed=9, shift=1.0)
    transformer = FeatureTransformer(n_thermal_components=4).fit(train)
    stacked = features_module.stack_features(test)
    assert len(stacked) == 5
    np.testing.assert_array_equal(transformer.transform(stacked), transformer.transform(test))
    np.testing.assert_array_equal(
        FeatureTransformer(n_thermal_components=4).fit_transform(train),
        transformer.transform(train),
    )
    other_kind = features_module.StackedFeatures("slide", {"texture": np.zeros((1, 4))})
    with pytest.raises(AtiktError, match="fitted on"):
        transformer.transform(other_kind)


def test_raw_features_pickle_and_deep_copy_with_read_only_blocks() -> None:
    raw = RawFeatures("press", MappingProxyType({"force": np.array([4.5]), "thermal": np.ones(4)}))
    for twin in (pickle.loads(pickle.dumps(raw)), copy.deepcopy(raw)):  # noqa: S301
        assert twin.kind == "press"
        assert twin.modalities == raw.modalities
        for name in raw.blocks:
            np.testing.assert_array_equal(twin.blocks[name], raw.blocks[name])
            assert not twin.blocks[name].flags.writeable
        with pytest.raises(TypeError):
            twin.blocks["texture"] = np.zeros(1)  # type: ignore[index]
