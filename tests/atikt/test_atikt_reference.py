"""atikt agrees with the scikit-learn reference at fixed hyperparameters (to 1e-6)."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.gaussian_process import GaussianProcessClassifier
from sklearn_reference import fixed_gpc, reference_kernel, to_reference_theta

from atikt import BinaryGPC, DependentKernel, ModalityKernel, OneVsAllGPC, modality_kernel
from atikt.transfer import with_domain

SLICES = {"texture": slice(0, 4), "thermal": slice(4, 9)}


def data(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((n, 9))
    y = (X[:, 0] - X[:, 5] + 0.8 * rng.standard_normal(n) > 0).astype(float)
    return X, y


def kernel(seed: int, *, amplitude: bool) -> ModalityKernel:
    k = modality_kernel(SLICES, amplitude=amplitude)
    return k.with_theta(np.random.default_rng(seed).uniform(-1, 1, k.n_params))


@pytest.mark.parametrize("variant", ["thesis", "amplitude"])
@pytest.mark.parametrize("seed", [0, 1])
def test_binary_probabilities_and_lml_agree(variant: str, seed: int) -> None:
    amplitude = variant == "amplitude"
    X, y = data(30, seed)
    Xt, _ = data(20, seed + 100)
    k = kernel(seed, amplitude=amplitude)
    ours = BinaryGPC(k, optimize=False).fit(X, y)
    ref = fixed_gpc(reference_kernel(k), X, y)
    np.testing.assert_allclose(ours.predict_proba(Xt), ref.predict_proba(Xt), atol=1e-6, rtol=0)
    value, gradient = ours.log_marginal_likelihood(k.theta, eval_gradient=True)  # type: ignore[misc]
    ref_value, ref_gradient = ref.base_estimator_.log_marginal_likelihood(
        to_reference_theta(k), eval_gradient=True
    )
    assert value == pytest.approx(ref_value, abs=1e-6)
    expected = (
        ref_gradient if not amplitude else np.concatenate([ref_gradient[1:], ref_gradient[:1]])
    )
    np.testing.assert_allclose(gradient, expected, atol=1e-6)


@pytest.mark.parametrize("rho", [0.0, 0.3, 0.8, 1.0])
def test_dependent_kernel_probabilities_agree(rho: float) -> None:
    X, y = data(25, 2)
    Xo, _ = data(12, 3)
    X_all = np.vstack([with_domain(Xo, 0.0), with_domain(X, 1.0)])
    y_all = np.concatenate([np.ones(12), y])
    Xt = with_domain(data(15, 4)[0], 1.0)
    k = DependentKernel(kernel(5, amplitude=True), rho)
    ours = BinaryGPC(k, optimize=False).fit(X_all, y_all)
    ref = fixed_gpc(reference_kernel(k), X_all, y_all)
    np.testing.assert_allclose(ours.predict_proba(Xt), ref.predict_proba(Xt), atol=1e-6, rtol=0)


def test_learned_rho_gradient_agrees() -> None:
    X, y = data(20, 6)
    Xo, _ = data(10, 7)
    X_all = np.vstack([with_domain(Xo, 0.0), with_domain(X, 1.0)])
    y_all = np.concatenate([np.ones(10), y])
    k = DependentKernel(kernel(8, amplitude=False), 0.45, (1e-3, 1.0))
    ours = BinaryGPC(k, optimize=False).fit(X_all, y_all)
    ref = fixed_gpc(reference_kernel(k), X_all, y_all)
    value, gradient = ours.log_marginal_likelihood(k.theta, eval_gradient=True)  # type: ignore[misc]
    ref_value, ref_gradient = ref.base_estimator_.log_marginal_likelihood(
        to_reference_theta(k), eval_gradient=True
    )
    assert value == pytest.approx(ref_value, abs=1e-6)
    np.testing.assert_allclose(gradient, ref_gradient, atol=1e-6)


def test_one_vs_all_probabilities_agree() -> None:
    rng = np.random.default_rng(9)
    labels = np.repeat(np.arange(5), 6)
    X = rng.standard_normal((5, 9))[labels] * 2 + rng.standard_normal((30, 9))
    Xt = rng.standard_normal((12, 9)) * 2
    k = kernel(10, amplitude=True)
    ours = OneVsAllGPC(k, optimize=False).fit(X, labels)
    ref = GaussianProcessClassifier(kernel=reference_kernel(k), optimizer=None).fit(X, labels)
    np.testing.assert_allclose(ours.predict_proba(Xt), ref.predict_proba(Xt), atol=1e-6, rtol=0)
