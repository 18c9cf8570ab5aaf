"""Kernels: analytic gradients against finite differences, PSD, weights, parameter handling."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest
from sklearn.gaussian_process.kernels import Matern

from atikt import AtiktError, DependentKernel, Kernel, ModalityKernel, SliceRBF, modality_kernel
from atikt.kernels import ProductKernel, SliceMatern, fusion_kernel
from atikt.transfer import with_domain

if TYPE_CHECKING:
    from collections.abc import Callable

SLICES = {"force": slice(0, 1), "texture": slice(1, 4), "thermal": slice(4, 7)}


def features(n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).standard_normal((n, 7))


def flagged(n_old: int, n_new: int, seed: int) -> np.ndarray:
    return np.vstack(
        [with_domain(features(n_old, seed), 0.0), with_domain(features(n_new, seed + 1), 1.0)]
    )


def finite_difference(kernel: Kernel, X: np.ndarray, h: float = 1e-6) -> np.ndarray:
    theta = kernel.theta
    out = np.empty((theta.shape[0], X.shape[0], X.shape[0]))
    for i in range(theta.shape[0]):
        step = np.zeros_like(theta)
        step[i] = h
        out[i] = (kernel.with_theta(theta + step)(X) - kernel.with_theta(theta - step)(X)) / (2 * h)
    return out


def kernels() -> list[object]:
    rng = np.random.default_rng(0)
    thesis = modality_kernel(SLICES, amplitude=False)
    amp = modality_kernel(SLICES, amplitude=True)
    thesis = thesis.with_theta(rng.uniform(-1, 1, thesis.n_params))
    amp = amp.with_theta(rng.uniform(-1, 1, amp.n_params))
    biased = modality_kernel(SLICES, bias=0.5)
    biased = biased.with_theta(rng.uniform(-1, 1, biased.n_params))
    fixed_parts = [SliceRBF(c, 0.8, "fixed", name=n) for n, c in SLICES.items()]
    generic = ModalityKernel(fixed_parts, [0.3, -0.2], variance=1.5, bias=0.7)
    X = features(12, 1)
    Xf = flagged(5, 7, 2)
    matern = {"force": "matern32", "texture": "matern52"}
    mixed_sum = modality_kernel(SLICES, parts=matern)
    mixed_sum = mixed_sum.with_theta(rng.uniform(-1, 1, mixed_sum.n_params))
    product = fusion_kernel(SLICES, combination="product", parts=matern)
    product = product.with_theta(rng.uniform(-1, 1, product.n_params))
    return [
        pytest.param(SliceMatern(slice(1, 4), 0.7, nu=1.5), X, id="matern32"),
        pytest.param(SliceMatern(slice(1, 4), 1.3, nu=2.5), X, id="matern52"),
        pytest.param(SliceMatern(slice(1, 4), 1.3, "fixed", nu=2.5), X, id="matern-fixed"),
        pytest.param(mixed_sum, X, id="sum-matern-parts"),
        pytest.param(product, X, id="product"),
        pytest.param(fusion_kernel(SLICES, combination="product", amplitude=False), X, id="prod-1"),
        pytest.param(DependentKernel(product, 0.4, (1e-3, 1.0)), Xf, id="dependent-product"),
        pytest.param(biased, X, id="bias"),
        pytest.param(modality_kernel(SLICES, amplitude=False, bias=2.0), X, id="bias-thesis"),
        pytest.param(generic, X, id="bias-fixed-length-scales"),
        pytest.param(DependentKernel(biased, 0.4, (1e-3, 1.0)), Xf, id="dependent-bias"),
        pytest.param(SliceRBF(slice(1, 4), 0.7), X, id="rbf"),
        pytest.param(thesis, X, id="thesis"),
        pytest.param(amp, X, id="amplitude"),
        pytest.param(DependentKernel(amp, 0.4), Xf, id="dependent-fixed"),
        pytest.param(DependentKernel(thesis, 0.4, (1e-3, 1.0)), Xf, id="dependent-learned"),
    ]


@pytest.mark.parametrize(("kernel", "X"), kernels())
def test_gradient_matches_finite_differences(kernel: Kernel, X: np.ndarray) -> None:
    K, dK = kernel.gradient(X)
    np.testing.assert_allclose(K, kernel(X), rtol=1e-12)
    assert dK.shape == (kernel.n_params, X.shape[0], X.shape[0])
    np.testing.assert_allclose(dK, finite_difference(kernel, X), rtol=1e-5, atol=1e-8)


@pytest.mark.parametrize(("kernel", "X"), kernels())
def test_kernel_properties(kernel: Kernel, X: np.ndarray) -> None:
    K = kernel(X)
    np.testing.assert_allclose(K, K.T, atol=1e-15)
    np.testing.assert_allclose(np.diag(K), kernel.diag(X), rtol=1e-12)
    assert np.linalg.eigvalsh(K).min() > -1e-10
    Y = X[:3]
    np.testing.assert_allclose(kernel(X, Y), K[:, :3], rtol=1e-12)
    assert kernel.bounds.shape == (kernel.n_params, 2)
    assert len(kernel.names) == kernel.n_params
    np.testing.assert_allclose(kernel.with_theta(kernel.theta).theta, kernel.theta)


@pytest.mark.parametrize("rho", [0.0, 0.1, 0.5, 0.9, 0.999, 1.0])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_dependent_kernel_is_psd_for_rho_in_unit_interval(rho: float, seed: int) -> None:
    base = modality_kernel(SLICES).with_theta(np.random.default_rng(seed).uniform(-2, 2, 6))
    X = flagged(15, 20, seed)
    K = DependentKernel(base, rho)(X)
    assert np.linalg.eigvalsh(K).min() > -1e-9
    cross = K[:15, 15:]
    np.testing.assert_allclose(cross, rho * base(X[:15], X[15:]))


def test_dependent_kernel_with_rho_one_is_the_base_kernel() -> None:
    base = modality_kernel(SLICES)
    X = flagged(4, 6, 3)
    np.testing.assert_allclose(DependentKernel(base, 1.0)(X), base(X))


def test_dependent_kernel_with_rho_zero_is_block_diagonal() -> None:
    X = flagged(4, 6, 4)
    K = DependentKernel(modality_kernel(SLICES), 0.0)(X)
    np.testing.assert_array_equal(K[:4, 4:], 0.0)


def test_modality_weights_are_a_convex_combination() -> None:
    kernel = modality_kernel(SLICES, amplitude=False).with_theta([0.1, 0.2, 0.3, 4.0, -4.0])
    assert isinstance(kernel, ModalityKernel)
    weights = kernel.weights
    assert np.all(weights >= 0)
    assert weights.sum() == pytest.approx(1.0)
    assert weights[1] > weights[0] > weights[2]
    X = features(5, 5)
    expected = sum(w * p(X) for w, p in zip(weights, kernel.parts, strict=True))
    np.testing.assert_allclose(kernel(X), expected)
    np.testing.assert_allclose(np.diag(kernel(X)), 1.0)


def test_signal_variance_scales_the_kernel() -> None:
    base = modality_kernel(SLICES, amplitude=False)
    amp = modality_kernel(SLICES, amplitude=True, variance=3.0)
    X = features(6, 6)
    np.testing.assert_allclose(amp(X), 3.0 * base(X))
    assert amp.names[-1] == "signal_variance"
    assert amp.n_params == base.n_params + 1


def test_rbf_ignores_columns_outside_its_slice() -> None:
    X = features(5, 7)
    Y = X.copy()
    Y[:, 4:] += 100.0
    rbf = SliceRBF(slice(0, 4))
    np.testing.assert_allclose(rbf(X), rbf(Y))


def test_fixed_hyperparameters_are_not_free() -> None:
    assert SliceRBF(slice(0, 1), 2.0, "fixed").n_params == 0
    _, dK = SliceRBF(slice(0, 1), 2.0, "fixed").gradient(features(3, 8))
    assert dK.shape == (0, 3, 3)


@pytest.mark.parametrize(
    ("build", "match"),
    [
        (lambda: SliceRBF(slice(0, 1), -1.0), "length_scale"),
        (lambda: SliceRBF(slice(0, 1), 1.0, (2.0, 1.0)), "bounds"),
        (lambda: ModalityKernel([]), "at least one"),
        (lambda: ModalityKernel([SliceRBF(slice(0, 1))], logits=[1.0]), "logits"),
        (lambda: ModalityKernel([SliceRBF(slice(0, 1))], variance=0.0), "variance"),
        (lambda: DependentKernel(modality_kernel(SLICES), 1.5), "rho"),
        (lambda: DependentKernel(modality_kernel(SLICES), 0.0, (1e-3, 1.0)), "rho"),
        (lambda: modality_kernel(SLICES).with_theta([1.0]), "theta"),
        (lambda: modality_kernel(SLICES).with_theta([np.nan] * 6), "theta"),
    ],
)
def test_bad_parameters_are_refused(build: Callable[[], object], match: str) -> None:
    with pytest.raises(AtiktError, match=match):
        build()


def test_bias_adds_a_learned_constant() -> None:
    X = features(6, 3)
    plain = modality_kernel(SLICES)
    biased = modality_kernel(SLICES, bias=0.25)
    assert biased.names[-1] == "bias"
    assert biased.n_params == plain.n_params + 1
    np.testing.assert_allclose(biased(X), plain(X) + 0.25, rtol=1e-12)
    np.testing.assert_allclose(biased.diag(X), plain.diag(X) + 0.25)
    moved = biased.with_theta([*biased.theta[:-1], np.log(4.0)])
    assert moved.constant == pytest.approx(4.0)
    assert moved.signal_variance == pytest.approx(biased.signal_variance)
    with pytest.raises(AtiktError, match="bias=0"):
        modality_kernel(SLICES, bias=0.0)


def assert_same_kernel(actual: np.ndarray, expected: np.ndarray) -> None:
    """Equal up to rounding (K_j - mixture cancels to ~1e-16 of the kernel's scale, >= 1)."""
    scale = max(1.0, float(np.abs(expected).max(initial=0.0)))
    np.testing.assert_allclose(actual, expected, rtol=1e-12, atol=1e-14 * scale)


@pytest.mark.parametrize(("kernel", "X"), kernels())
def test_evaluator_equals_with_theta_gradient(kernel: Kernel, X: np.ndarray) -> None:
    evaluate = kernel.evaluator(X)
    rng = np.random.default_rng(9)
    for _ in range(3):
        theta = rng.uniform(kernel.bounds[:, 0], kernel.bounds[:, 1])
        K, dK = evaluate(theta)
        K_ref, dK_ref = kernel.with_theta(theta).gradient(X)
        assert_same_kernel(K, K_ref)
        assert_same_kernel(dK, dK_ref)
    scale = rng.uniform(0.0, 1.0, (X.shape[0], X.shape[0]))
    scaled = kernel.evaluator(X, scale)(theta)
    assert_same_kernel(scaled[0], K_ref * scale)
    assert_same_kernel(scaled[1], dK_ref * scale)


@pytest.mark.parametrize("nu", [1.5, 2.5])
def test_matern_equals_scikit_learn(nu: float) -> None:
    X = features(9, 3)
    ours = SliceMatern(slice(1, 4), 0.8, nu=nu)
    reference = Matern(length_scale=0.8, nu=nu)(X[:, 1:4])
    np.testing.assert_allclose(ours(X), reference, rtol=1e-12, atol=1e-15)


def test_product_is_the_product_of_its_parts() -> None:
    X = features(10, 4)
    product = fusion_kernel(SLICES, combination="product", parts={"thermal": "matern52"})
    product = product.with_theta([0.1, -0.3, 0.2, np.log(2.0)])
    assert isinstance(product, ProductKernel)
    expected = 2.0 * np.prod([part(X) for part in product.parts], axis=0)
    np.testing.assert_allclose(product(X), expected, rtol=1e-12)
    assert product.names == (
        "force.length_scale",
        "texture.length_scale",
        "thermal.length_scale",
        "signal_variance",
    )


def test_product_switches_a_modality_off_with_a_long_length_scale() -> None:
    X = features(10, 5)
    product = fusion_kernel({"a": slice(0, 1), "b": slice(1, 4)}, combination="product")
    long_b = product.with_theta([0.0, np.log(1e6), 0.0])
    only_a = SliceRBF(slice(0, 1))(X)
    np.testing.assert_allclose(long_b(X), only_a, rtol=1e-9)


@pytest.mark.parametrize(
    ("build", "match"),
    [
        (lambda: SliceMatern(slice(0, 1), nu=0.5), "nu=0.5"),
        (lambda: fusion_kernel(SLICES, combination="max"), "combination='max'"),
        (lambda: modality_kernel(SLICES, parts={"force": "cubic"}), "cubic"),
        (lambda: ProductKernel([]), "at least one"),
    ],
)
def test_bad_kernel_choices_are_refused(build: Callable[[], object], match: str) -> None:
    with pytest.raises(AtiktError, match=match):
        build()


def test_theta_is_the_callers_copy_and_follows_with_theta() -> None:
    # theta is put together once per kernel: changing the array a caller got must change
    # neither the kernel nor what it gives the next caller; a new kernel has its own theta
    kernel = modality_kernel(SLICES, amplitude=True, bias=0.5)
    first = kernel.theta
    first[:] = 7.0
    np.testing.assert_array_equal(
        kernel.theta, modality_kernel(SLICES, amplitude=True, bias=0.5).theta
    )
    moved = kernel.with_theta(np.linspace(-1.0, 1.0, kernel.n_params))
    assert not np.array_equal(moved.theta, kernel.theta)
    np.testing.assert_allclose(moved.theta, np.linspace(-1.0, 1.0, kernel.n_params), atol=1e-12)


def test_values_from_squared_distances_are_the_kernel_calls_bit_for_bit() -> None:
    X, Y = features(7, 5), features(4, 6)
    for kernel in (modality_kernel(SLICES), modality_kernel(SLICES, bias=0.3)):
        moved = kernel.with_theta(np.random.default_rng(2).uniform(-1.0, 1.0, kernel.n_params))
        distances = [part.sq_dist(X, Y) for part in moved.parts]
        values = moved.from_sq_dists(distances)
        assert values is not None
        assert np.array_equal(values, moved(X, Y))
        # any subset of the entries: the same values as those entries of the full call
        rows, columns = np.array([0, 3, 6]), np.array([1, 1, 3])
        picked = [D[rows, columns] for D in distances]
        values = moved.from_sq_dists(picked)
        assert values is not None
        assert np.array_equal(values, moved(X, Y)[rows, columns])
    # a Matern part is not a function of the squared distance alone in this form: no values
    matern = modality_kernel(SLICES, parts={"texture": "matern52"})
    assert matern.from_sq_dists([np.zeros((7, 7))] * 3) is None
