"""Laplace GP classifier: marginal-likelihood gradient, mode, probabilities, errors."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
import scipy.optimize
from atikt_synthetic import NEW_OBJECTS, pool

from atikt import (
    AtiktError,
    BinaryGPC,
    DependentKernel,
    MultiModalGPC,
    NotFittedError,
    NumericalError,
    OneVsAllGPC,
    laplace_mode,
    modality_kernel,
)
from atikt import gpc as gpc_module
from atikt.gpc import laplace_evidences, predictive_probability
from atikt.transfer import with_domain

if TYPE_CHECKING:
    from atikt.kernels import Kernel

SLICES = {"force": slice(0, 1), "thermal": slice(1, 4)}


def problem(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((n, 4))
    y = (X[:, 0] + 0.5 * X[:, 1] + 0.7 * rng.standard_normal(n) > 0).astype(float)
    return X, y


def lml_kernels() -> list[object]:
    rng = np.random.default_rng(1)
    thesis = modality_kernel(SLICES, amplitude=False)
    amp = modality_kernel(SLICES, amplitude=True)
    thesis = thesis.with_theta(rng.uniform(-0.5, 0.5, thesis.n_params))
    amp = amp.with_theta(rng.uniform(-0.5, 1.5, amp.n_params))
    return [
        pytest.param(thesis, id="thesis"),
        pytest.param(amp, id="amplitude"),
        pytest.param(DependentKernel(amp, 0.6, (1e-3, 1.0)), id="dependent-learned-rho"),
    ]


@pytest.mark.parametrize("kernel", lml_kernels())
def test_lml_gradient_matches_finite_differences(kernel: Kernel) -> None:
    X, y = problem(30, seed=2)
    if isinstance(kernel, DependentKernel):
        X = np.vstack([with_domain(X[:10], 0.0), with_domain(X[10:], 1.0)])
        y = np.concatenate([np.ones(10), y[10:]])
    gpc = BinaryGPC(kernel, optimize=False, newton_tol=1e-14).fit(X, y)
    theta = kernel.theta
    value, gradient = gpc.log_marginal_likelihood(theta, eval_gradient=True)  # type: ignore[misc]
    assert value == pytest.approx(gpc.log_marginal_likelihood_value_)
    h = 1e-5
    numeric = []
    for i in range(theta.shape[0]):
        step = np.zeros_like(theta)
        step[i] = h
        up = gpc.log_marginal_likelihood(theta + step)
        down = gpc.log_marginal_likelihood(theta - step)
        numeric.append((up - down) / (2 * h))  # type: ignore[operator]
    np.testing.assert_allclose(gradient, numeric, rtol=1e-5, atol=1e-6)


def test_mode_is_stationary() -> None:
    X, y = problem(25, seed=3)
    K = modality_kernel(SLICES)(X)
    mode = laplace_mode(K, y, tol=1e-14)
    # at the mode f = K grad log p(y|f) = K (y - pi)  (R&W Eq. 3.17)
    np.testing.assert_allclose(mode.f, K @ (y - mode.pi), atol=1e-8)
    np.testing.assert_allclose(mode.a, y - mode.pi, atol=1e-8)
    warm = laplace_mode(K, y, mode.f, tol=1e-14)
    assert warm.n_iter == 1  # the step from the mode is (numerically) empty: converged
    np.testing.assert_allclose(warm.f, mode.f, atol=1e-10)
    assert warm.log_marginal_likelihood == pytest.approx(mode.log_marginal_likelihood, abs=1e-10)


def test_fit_increases_the_marginal_likelihood() -> None:
    X, y = problem(40, seed=4)
    start = modality_kernel(SLICES)
    fixed = BinaryGPC(start, optimize=False).fit(X, y)
    fitted = BinaryGPC(start, n_restarts=2, random_state=0).fit(X, y)
    assert fitted.log_marginal_likelihood_value_ > fixed.log_marginal_likelihood_value_
    bounds = start.bounds
    assert np.all(fitted.kernel_.theta >= bounds[:, 0] - 1e-12)
    assert np.all(fitted.kernel_.theta <= bounds[:, 1] + 1e-12)
    assert fitted.n_evaluations_ > 0


def test_probabilities_are_in_unit_interval_and_sensible() -> None:
    X, y = problem(60, seed=5)
    gpc = BinaryGPC(modality_kernel(SLICES), random_state=0).fit(X, y)
    Xt, yt = problem(200, seed=6)
    p = gpc.predict_proba(Xt)
    assert p.shape == (200, 2)
    assert np.all((p >= 0) & (p <= 1))
    np.testing.assert_allclose(p.sum(axis=1), 1.0)
    assert np.mean(gpc.predict(Xt) == yt) > 0.7
    far = gpc.predict_positive(np.full((1, 4), 1e3))
    assert far == pytest.approx(0.5, abs=1e-6)  # the prior far from all data


def test_predictive_probability_extremes() -> None:
    mean = np.array([-1e6, -3.0, 0.0, 3.0, 1e6, 2.0])
    var = np.array([0.0, 1.0, 5.0, 1.0, 1e9, -1e-12])
    p = predictive_probability(mean, var)
    assert np.all((p >= 0) & (p <= 1))
    assert p[2] == pytest.approx(0.5)
    assert p[0] < 1e-6
    assert p[4] > 0.5
    np.testing.assert_allclose(predictive_probability(-mean, var), 1 - p, atol=1e-7)
    # var = 0: the sigmoid itself (Williams & Barber's fit is accurate to a few 1e-4)
    assert predictive_probability(np.array([2.0]), np.array([0.0])) == pytest.approx(
        1 / (1 + np.exp(-2.0)), abs=1e-3
    )


def test_fit_is_deterministic_for_a_seed() -> None:
    X, y = problem(30, seed=7)
    a = BinaryGPC(modality_kernel(SLICES), n_restarts=3, random_state=11).fit(X, y)
    b = BinaryGPC(modality_kernel(SLICES), n_restarts=3, random_state=11).fit(X, y)
    np.testing.assert_array_equal(a.kernel_.theta, b.kernel_.theta)
    np.testing.assert_array_equal(a.predict_positive(X), b.predict_positive(X))


def test_single_class_training_set_is_allowed() -> None:
    X, _ = problem(10, seed=8)
    gpc = BinaryGPC(modality_kernel(SLICES), optimize=False).fit(X, np.ones(10))
    assert np.all(gpc.predict_positive(X) > 0.5)


def test_one_vs_all_normalises_over_classes() -> None:
    rng = np.random.default_rng(9)
    centres = rng.standard_normal((4, 4)) * 3
    labels = np.repeat(np.arange(4), 10)
    X = centres[labels] + rng.standard_normal((40, 4))
    model = OneVsAllGPC(modality_kernel(SLICES), random_state=0).fit(X, labels + 10)
    np.testing.assert_array_equal(model.classes_, [10, 11, 12, 13])
    p = model.predict_proba(X)
    np.testing.assert_allclose(p.sum(axis=1), 1.0)
    raw = model.predict_binary(X)
    np.testing.assert_allclose(p, raw / raw.sum(axis=1, keepdims=True))
    assert model.score(X, labels + 10) > 0.9


def test_errors() -> None:
    X, y = problem(5, seed=10)
    gpc = BinaryGPC(modality_kernel(SLICES))
    with pytest.raises(NotFittedError):
        gpc.predict_proba(X)
    with pytest.raises(AtiktError, match="binary"):
        gpc.fit(X, y * 2)
    with pytest.raises(AtiktError, match="shape"):
        gpc.fit(X, y[:3])
    with pytest.raises(AtiktError, match="finite"):
        gpc.fit(np.full_like(X, np.nan), y)
    with pytest.raises(AtiktError, match="two classes"):
        OneVsAllGPC(modality_kernel(SLICES)).fit(X, np.zeros(5, dtype=int))
    with pytest.raises(NotFittedError):
        OneVsAllGPC(modality_kernel(SLICES)).predict_proba(X)


def test_numerical_failures_raise_numerical_error() -> None:
    y = np.array([0.0, 1.0, 1.0])
    with pytest.raises(NumericalError, match="Cholesky"):
        laplace_mode(-100.0 * np.eye(3), y)
    with pytest.raises(NumericalError):
        laplace_mode(np.full((3, 3), np.nan), y)


def test_evidences_of_many_label_vectors_equal_one_mode_each() -> None:
    # the learner's smooth kernels, and covariances with anticorrelations (entries up to 1e4,
    # which amplify rounding)
    rng = np.random.default_rng(5)
    for case in range(300):
        n, m = int(rng.integers(2, 30)), int(rng.integers(1, 7))
        if case % 2:
            A = rng.standard_normal((n, n)) * 10 ** rng.uniform(0, 2)
            K = A @ A.T + 1e-6 * np.eye(n)
        else:
            X = rng.standard_normal((n, 4))
            K = modality_kernel(SLICES, variance=float(10 ** rng.uniform(-1, 2)))(X)
        Y = (rng.integers(0, m, n) == np.arange(m)[:, None]).astype(float)
        for max_iter in (2, 100):  # also vectors stopped by the iteration limit
            together = laplace_evidences(K, Y, max_iter=max_iter)
            one_by_one = [laplace_mode(K, y, max_iter=max_iter).log_marginal_likelihood for y in Y]
            np.testing.assert_allclose(together, one_by_one, rtol=1e-12, atol=1e-9)
    assert laplace_evidences(np.eye(3), np.zeros((0, 3))).shape == (0,)
    # not a covariance: what laplace_mode gives (a value where its Cholesky succeeds)
    indefinite = np.array([[1.0, 2.0], [2.0, 1.0]])
    labels = np.array([[0.0, 1.0], [1.0, 0.0]])
    expected = [laplace_mode(indefinite, y).log_marginal_likelihood for y in labels]
    assert laplace_evidences(indefinite, labels).tolist() == expected
    with pytest.raises(NumericalError, match="Cholesky"):
        laplace_evidences(-100.0 * np.eye(3), np.array([[0.0, 1.0, 1.0]]))
    with pytest.raises(NumericalError):
        laplace_evidences(np.full((3, 3), np.nan), np.array([[0.0, 1.0, 1.0]]))
    with pytest.raises(AtiktError, match="max_iter"):
        laplace_evidences(np.eye(3), np.array([[0.0, 1.0, 1.0]]), max_iter=0)


def test_a_damped_newton_step_is_laplace_modes_own(monkeypatch: pytest.MonkeyPatch) -> None:
    # strong anticorrelations of entries near 1e6: a Newton step from zero can lower the
    # objective; such a vector is handed to laplace_mode, so its evidence is laplace_mode's
    damped: list[int] = []
    real_damped = gpc_module._damped

    def counted(*args: Any) -> Any:
        damped.append(1)
        return real_damped(*args)

    monkeypatch.setattr(gpc_module, "_damped", counted)
    rng = np.random.default_rng(3)
    for _ in range(2000):
        n = int(rng.integers(2, 8))
        A = rng.standard_normal((n, n)) * 10 ** rng.uniform(2, 4)
        y = (rng.random(n) < 0.5).astype(float)
        before = len(damped)
        expected = laplace_mode(A @ A.T + 1e-6 * np.eye(n), y).log_marginal_likelihood
        if len(damped) > before:
            (together,) = laplace_evidences(A @ A.T + 1e-6 * np.eye(n), y[None, :])
            assert together == expected
            return
    pytest.fail("no damped Newton step in 2000 covariances")


def test_multimodal_gpc_on_chosen_modalities() -> None:
    data = pool(NEW_OBJECTS, ["P2"], n_trials=6, seed=12)["P2"]
    test = pool(NEW_OBJECTS, ["P2"], n_trials=4, seed=13)["P2"]
    train_obs = [o for j in data for o in data[j]]
    train_y = np.array([j for j in data for _ in data[j]])
    test_obs = [o for j in test for o in test[j]]
    test_y = np.array([j for j in test for _ in test[j]])
    accuracies = {}
    for modalities in (["force"], ["thermal"], None):
        model = MultiModalGPC(modalities, n_restarts=0, random_state=0).fit(train_obs, train_y)
        p = model.predict_proba(test_obs)
        np.testing.assert_allclose(p.sum(axis=1), 1.0)
        accuracies[str(modalities)] = model.score(test_obs, test_y)
    assert model.transformer_.modalities_ == ("force", "thermal")
    assert all(0.0 <= a <= 1.0 for a in accuracies.values())
    assert accuracies["None"] > 0.6  # five objects: chance is 0.2
    with pytest.raises(NotFittedError):
        MultiModalGPC().predict(test_obs)


def exact_lml(K: np.ndarray, y: np.ndarray, f: np.ndarray) -> float:
    """R&W Eq. 3.32 with W and B evaluated exactly at ``f`` (a mode)."""
    a = np.linalg.solve(K, f)
    pi = 1.0 / (1.0 + np.exp(-f))
    sqrt_w = np.sqrt(pi * (1.0 - pi))
    B = np.eye(len(y)) + sqrt_w[:, None] * K * sqrt_w
    log_lik = -np.logaddexp(0.0, -(2.0 * y - 1.0) * f).sum()
    return float(-0.5 * a @ f + log_lik - 0.5 * np.linalg.slogdet(B)[1])


def test_mode_from_a_bad_start_is_the_same_mode() -> None:
    X, y = problem(25, seed=11)
    K = modality_kernel(SLICES, variance=50.0)(X)
    cold = laplace_mode(K, y, tol=1e-14)
    for f0 in (30.0 * (1.0 - 2.0 * y), np.full(25, -40.0), cold.f + 5.0):
        warm = laplace_mode(K, y, f0, tol=1e-14)
        np.testing.assert_allclose(warm.f, cold.f, atol=1e-5)  # Newton stops at ~1e-6
        # W and L may be those of a point up to _SHORT_STEP from the mode (no refactorisation)
        assert warm.log_marginal_likelihood == pytest.approx(cold.log_marginal_likelihood, abs=1e-5)
        assert warm.log_marginal_likelihood == pytest.approx(exact_lml(K, y, warm.f), abs=1e-5)
    with pytest.raises(AtiktError, match="max_iter"):
        laplace_mode(K, y, max_iter=0)


def test_training_latent_equals_prediction_at_the_training_inputs() -> None:
    X, y = problem(30, seed=12)
    model = BinaryGPC(modality_kernel(SLICES), max_iter=5).fit(X, y)
    for rows in (slice(None), slice(10, None)):
        mean, var = model.training_latent(rows)
        expected_mean, expected_var = model.latent(X[rows])
        np.testing.assert_allclose(mean, expected_mean, atol=1e-8)
        np.testing.assert_allclose(var, expected_var, atol=1e-8)
    np.testing.assert_allclose(model.latent_mean(X[:7]), model.latent(X[:7])[0], atol=1e-12)


def test_warm_start_from_a_previous_fit() -> None:
    # the previous fit saw all points but the last (as in active learning); over a few data
    # sets the carried curvature saves evaluations and reaches the same optimum
    kernel = modality_kernel(SLICES)
    evaluations = {"cold": 0, "warm": 0}
    for seed in (13, 14, 15, 16):
        X, y = problem(30, seed=seed)
        previous = BinaryGPC(kernel, max_iter=50, tol=1e-9).fit(X[:-1], y[:-1])
        assert previous.inverse_hessian_ is not None
        assert previous.inverse_hessian_.shape == (kernel.n_params, kernel.n_params)
        start = previous.kernel_
        best = BinaryGPC(start, max_iter=200, tol=1e-12).fit(X, y).log_marginal_likelihood_value_
        cold = BinaryGPC(start, max_iter=50, tol=1e-6).fit(X, y)
        warm = BinaryGPC(
            start,
            max_iter=50,
            tol=1e-6,
            inverse_hessian=previous.inverse_hessian_,
            mode_start=previous.mode_.f,
        ).fit(X, y)
        evaluations["cold"] += cold.n_evaluations_
        evaluations["warm"] += warm.n_evaluations_
        assert warm.log_marginal_likelihood_value_ == pytest.approx(best, abs=1e-5)
    assert evaluations["warm"] < evaluations["cold"]


def test_mode_start_changes_the_cost_not_the_result() -> None:
    X, y = problem(30, seed=13)
    start = modality_kernel(SLICES).with_theta([0.3, -0.2, 0.4, 1.0])
    previous = BinaryGPC(start, optimize=False).fit(X[:-1], y[:-1])
    fixed = BinaryGPC(start, optimize=False).fit(X, y)
    fixed_warm = BinaryGPC(start, optimize=False, mode_start=previous.mode_.f).fit(X, y)
    np.testing.assert_allclose(fixed_warm.mode_.f, fixed.mode_.f, atol=1e-5)  # see _CONVERGED
    at_mode = BinaryGPC(start, optimize=False, mode_start=fixed.mode_.f).fit(X, y)
    assert at_mode.mode_.n_iter == 1 < fixed.mode_.n_iter
    # a curvature of the wrong shape or a mode start longer than the data are ignored
    odd = BinaryGPC(start, inverse_hessian=np.eye(9), mode_start=np.zeros(99)).fit(X, y)
    assert np.isfinite(odd.log_marginal_likelihood_value_)


def test_cold_search_on_few_points_converges_like_lbfgsb() -> None:
    # a first fit on a handful of observations has a flat start; the search must not stop
    # there on the uninformed identity curvature's prediction (it may end at another of the
    # flat landscape's local optima than L-BFGS-B, hence the 0.01 nats)
    for seed in range(4):
        X, y = problem(6, seed=20 + seed)
        kernel = modality_kernel(SLICES)
        ours = BinaryGPC(kernel, max_iter=100).fit(X, y)
        objective = BinaryGPC(kernel)._objective(ours.X_train_, ours.y_train_)
        theirs = scipy.optimize.minimize(
            objective, kernel.theta, jac=True, method="L-BFGS-B", bounds=kernel.bounds
        )
        assert ours.n_iter_ > 0
        assert ours.log_marginal_likelihood_value_ >= -theirs.fun - 0.01
