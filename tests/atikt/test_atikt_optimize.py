"""The box-constrained quasi-Newton search: optima, bounds, carried curvature, failures."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest
import scipy.optimize
from hypothesis import given, settings
from hypothesis import strategies as st

from atikt import AtiktError, NumericalError
from atikt.optimize import minimize_box

if TYPE_CHECKING:
    from collections.abc import Callable


def quadratic(
    A: np.ndarray, centre: np.ndarray
) -> Callable[[np.ndarray], tuple[float, np.ndarray]]:
    """``(x - c)' A (x - c) / 2`` and its gradient."""

    def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
        r = x - centre
        return 0.5 * float(r @ A @ r), A @ r

    return fun


def rosenbrock(x: np.ndarray) -> tuple[float, np.ndarray]:
    value = 100.0 * (x[1] - x[0] ** 2) ** 2 + (1.0 - x[0]) ** 2
    grad = np.array(
        [-400.0 * x[0] * (x[1] - x[0] ** 2) - 2.0 * (1.0 - x[0]), 200.0 * (x[1] - x[0] ** 2)]
    )
    return value, grad


def spd(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return np.asarray((Q * np.geomspace(0.5, 20.0, n)) @ Q.T, dtype=np.float64)


BOX = np.array([[-5.0, 5.0]] * 4)


def test_interior_minimum_of_a_quadratic() -> None:
    A, centre = spd(4, 0), np.array([1.0, -2.0, 0.5, 3.0])
    result = minimize_box(quadratic(A, centre), np.zeros(4), BOX, tol=1e-14, gtol=1e-10)
    assert result.converged
    np.testing.assert_allclose(result.x, centre, atol=1e-6)
    assert result.fun == pytest.approx(0.0, abs=1e-10)


def test_minimum_on_the_bounds_agrees_with_scipy() -> None:
    A, centre = spd(4, 1), np.array([7.0, -9.0, 0.5, 3.0])  # outside the box in 2 coordinates
    ours = minimize_box(quadratic(A, centre), np.zeros(4), BOX, tol=1e-14, gtol=1e-10)
    theirs = scipy.optimize.minimize(
        quadratic(A, centre),
        np.zeros(4),
        jac=True,
        method="L-BFGS-B",
        bounds=BOX,
        options={"ftol": 1e-15, "gtol": 1e-12},
    )
    np.testing.assert_allclose(ours.x, theirs.x, atol=1e-5)
    assert ours.fun == pytest.approx(theirs.fun, rel=1e-8)


def test_rosenbrock_in_a_box() -> None:
    box = np.array([[-2.0, 2.0], [-1.0, 3.0]])
    result = minimize_box(rosenbrock, [-1.2, 1.0], box, max_iter=200, tol=1e-16, gtol=1e-8)
    np.testing.assert_allclose(result.x, [1.0, 1.0], atol=1e-4)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    start=st.lists(st.floats(-20.0, 20.0), min_size=4, max_size=4),
)
def test_every_evaluation_stays_in_the_box(seed: int, start: list[float]) -> None:
    rng = np.random.default_rng(seed)
    A, centre = spd(4, seed), rng.normal(0.0, 8.0, 4)
    visited: list[np.ndarray] = []
    inner = quadratic(A, centre)

    def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
        visited.append(x.copy())
        return inner(x)

    result = minimize_box(fun, start, BOX, max_iter=30)
    points = np.array(visited)
    assert np.all(points >= BOX[:, 0])
    assert np.all(points <= BOX[:, 1])
    assert result.fun <= fun(np.clip(np.asarray(start), -5.0, 5.0))[0] + 1e-12


def test_carried_curvature_makes_the_next_search_cheap() -> None:
    A = spd(4, 2)
    first = minimize_box(quadratic(A, np.ones(4)), np.zeros(4), BOX, tol=1e-12, max_iter=50)
    shifted = quadratic(A, np.ones(4) + 0.05)  # the optimum moved a little
    cold = minimize_box(shifted, first.x, BOX, tol=1e-8)
    warm = minimize_box(shifted, first.x, BOX, tol=1e-8, inverse_hessian=first.inverse_hessian)
    assert warm.n_evaluations <= 4
    assert 3 * warm.n_evaluations < cold.n_evaluations
    np.testing.assert_allclose(warm.x, np.ones(4) + 0.05, atol=1e-3)


def test_tol_is_the_predicted_improvement() -> None:
    A, centre = np.eye(2), np.array([0.1, 0.0])  # from 0: predicted improvement 0.005
    fun = quadratic(A, centre)
    lazy = minimize_box(fun, np.zeros(2), BOX[:2], inverse_hessian=np.eye(2), tol=0.01)
    assert (lazy.n_evaluations, lazy.n_iter) == (1, 0)
    assert lazy.converged
    eager = minimize_box(fun, np.zeros(2), BOX[:2], inverse_hessian=np.eye(2), tol=0.001)
    np.testing.assert_allclose(eager.x, centre, atol=1e-12)


def test_flat_ridge_steps_are_lengthened() -> None:
    # a nearly linear valley: an identity curvature makes tiny steps; lengthening catches up
    def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
        return float(-0.1 * x[0] + 0.5 * x[1] ** 2), np.array([-0.1, x[1]])

    box = np.array([[0.0, 4.0], [-1.0, 1.0]])
    result = minimize_box(fun, [0.0, 0.5], box, inverse_hessian=np.eye(2), max_iter=10)
    assert result.x[0] == pytest.approx(4.0)


def test_failed_trial_points_are_rejected() -> None:
    inner = quadratic(np.eye(2), np.array([3.0, 0.0]))

    def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
        if x[0] > 2.0:  # e.g. a kernel matrix that cannot be factorised
            msg = "no"
            raise NumericalError(msg)
        return inner(x)

    result = minimize_box(fun, [0.0, 0.0], BOX[:2], max_iter=50)
    assert result.x[0] <= 2.0
    assert result.fun < inner(np.zeros(2))[0]


def test_failure_at_the_start_propagates() -> None:
    def fun(_x: np.ndarray) -> tuple[float, np.ndarray]:
        msg = "no"
        raise NumericalError(msg)

    with pytest.raises(NumericalError):
        minimize_box(fun, [0.0], [[-1.0, 1.0]])
    with pytest.raises(NumericalError, match="not finite"):
        minimize_box(lambda x: (float("nan"), x), [0.0], [[-1.0, 1.0]])


def test_malformed_inputs() -> None:
    fun = quadratic(np.eye(2), np.zeros(2))
    with pytest.raises(AtiktError, match="bounds"):
        minimize_box(fun, [0.0, 0.0], [[-1.0, 1.0]])
    with pytest.raises(AtiktError, match="bounds"):
        minimize_box(fun, [0.0, 0.0], [[1.0, -1.0], [0.0, 1.0]])
    with pytest.raises(AtiktError, match="inverse_hessian"):
        minimize_box(fun, [0.0, 0.0], BOX[:2], inverse_hessian=np.eye(3))


def test_deterministic() -> None:
    A, centre = spd(4, 3), np.array([1.0, 9.0, -2.0, 0.0])
    runs = [minimize_box(quadratic(A, centre), np.ones(4), BOX, max_iter=5) for _ in range(2)]
    assert np.array_equal(runs[0].x, runs[1].x)
    assert np.array_equal(runs[0].inverse_hessian, runs[1].inverse_hessian)


def test_a_full_step_is_at_most_max_step() -> None:
    # an inflated curvature proposes a step of 400; the first trial stays within max_step
    visited: list[np.ndarray] = []
    inner = quadratic(np.eye(2), np.array([4.0, 0.0]))

    def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
        visited.append(x.copy())
        return inner(x)

    box = np.array([[-500.0, 500.0]] * 2)
    minimize_box(fun, [0.0, 0.0], box, inverse_hessian=100.0 * np.eye(2), max_step=2.0)
    assert np.abs(visited[1] - visited[0]).max() == pytest.approx(2.0)


def test_backtracking_stops_where_a_step_could_gain_less_than_tol() -> None:
    # the start sits in a dip of the objective's noise (as a Laplace mode's inexact search
    # leaves one): no trial along the direction is lower; backtracking below what tol could
    # still gain is futile and stops, at the start
    start = np.zeros(2)
    inner = quadratic(np.eye(2), np.array([4e-4, 3e-4]))  # predicted improvement 1.25e-7
    counted: list[np.ndarray] = []

    def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
        counted.append(x.copy())
        value, grad = inner(x)
        return value - (1e-6 if np.array_equal(x, start) else 0.0), grad

    result = minimize_box(fun, start, BOX[:2], inverse_hessian=np.eye(2), tol=1e-8)
    assert np.array_equal(result.x, start)
    assert 2 <= len(counted) <= 5  # the start, then trials down to a gain of 1e-8
    # the same search with tol = 0 backtracks to the limit before giving up
    counted.clear()
    minimize_box(fun, start, BOX[:2], inverse_hessian=np.eye(2), tol=0.0)
    assert len(counted) == 21
