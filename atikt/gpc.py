"""Gaussian-process classifiers with the Laplace approximation.

Rasmussen & Williams, *Gaussian Processes for Machine Learning* (2006): Alg. 3.1 (posterior
mode by Newton's method), Alg. 3.2 (predictions), Alg. 5.1 (gradient of the approximate log
marginal likelihood). The likelihood is the logistic sigmoid; the predictive integral
``int sigmoid(f) N(f | mu, var) df`` uses the five-error-function approximation of Williams &
Barber (1998, appendix A), the same as scikit-learn, so that both implementations agree.

- :class:`BinaryGPC`: one binary classifier, hyperparameters by maximising the log marginal
  likelihood (projected BFGS of :mod:`atikt.optimize`, analytic gradient, seeded restarts,
  curvature carried over from a previous fit).
- :class:`OneVsAllGPC`: one binary classifier per class (object), probabilities normalised
  over the classes.
- :class:`MultiModalGPC`: feature normalisation + one-vs-all GPC over a chosen subset of
  modalities, for the modality-fusion study.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Final, Literal, Self

import numpy as np
import numpy.typing as npt
from scipy.linalg import lapack
from scipy.special import erf, expit

from atikt.errors import AtiktError, NotFittedError, NumericalError
from atikt.features import FeatureTransformer, RawFeatures, stack_features
from atikt.kernels import (
    DEFAULT_LOGIT_BOUNDS,
    Kernel,
    ModalityKernel,
    ProductKernel,
    fusion_kernel,
    modality_kernel,
)
from atikt.noise import feature_noise, noise_length_scales, noise_logits
from atikt.optimize import SearchResult, minimize_box

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
RandomState = int | np.random.Generator | None
Selection = Literal["fused", "evidence", "evidence-all"]
SELECTIONS: Final = ("fused", "evidence", "evidence-all")
"""Ways :class:`MultiModalGPC` combines modalities (see its docstring)."""

# Williams & Barber (1998), appendix A: sigmoid(x) ~ sum_i c_i (1 + erf(lambda_i x)) / 2.
LAMBDAS: Final = np.array([0.41, 0.4, 0.37, 0.44, 0.39])
COEFS: Final = np.array([-1854.8214151, 3516.89893646, 221.29346712, 128.12323805, -2010.49422654])
_LAMBDAS: Final = LAMBDAS[:, None]
_TWO_LAMBDAS_SQ: Final = 2.0 * LAMBDAS[:, None] ** 2
_HALF_COEFS: Final = 0.5 * COEFS
_HALF_COEFS_SUM: Final = 0.5 * float(COEFS.sum())
_MAX_HALVINGS: Final = 20
_SHORT_STEP: Final = 1e-5
_CONVERGED: Final = 1e-6
"""Predicted length of the next Newton step below which the current iterate is the mode."""
COLD_TOL: Final = 1e-8
"""Stopping tolerance (nats) of a search without a carried curvature: searched to convergence."""


def _rng(random_state: RandomState) -> np.random.Generator:
    """Return a generator for ``random_state`` (an int seed, a generator, or None)."""
    if isinstance(random_state, np.random.Generator):
        return random_state
    return np.random.default_rng(random_state)


def spawn_seeds(random_state: RandomState, n: int) -> list[int]:
    """Draw ``n`` integer seeds from ``random_state``, for sub-estimators."""
    return [int(s) for s in _rng(random_state).integers(0, 2**31 - 1, size=n)]


@dataclass(frozen=True, slots=True, eq=False)
class LaplaceMode:
    """The Laplace approximation of one binary GP classifier at fixed hyperparameters.

    Attributes:
        f: Posterior mode of the latent function at the training points, shape (n,).
        a: ``K^-1 f`` (equal to ``y - pi`` at the mode), shape (n,).
        pi: ``sigmoid(f)``, shape (n,).
        sqrt_w: ``W^1/2`` with ``W = pi (1 - pi)``, shape (n,).
        L: Lower Cholesky factor of ``B = I + W^1/2 K W^1/2`` in the lower triangle, shape
            (n, n); the strict upper triangle is not part of it (read it with ``lower=1``).
        log_marginal_likelihood: Approximate ``log q(y | X, theta)`` (R&W Eq. 3.32).
        n_iter: Newton iterations used.
        K: The prior covariance the mode was found for (jitter included), shape (n, n).
    """

    f: FloatArray
    a: FloatArray
    pi: FloatArray
    sqrt_w: FloatArray
    L: FloatArray
    log_marginal_likelihood: float
    n_iter: int
    K: FloatArray


def _log_likelihood(minus_sign: FloatArray, f: FloatArray) -> float:
    """Return ``log p(y | f) = -sum log(1 + exp(-s f))`` with ``s = 2y - 1`` in {-1, 1}.

    ``minus_sign`` is ``-s``, negated once per mode search instead of once per call.
    """
    return -float(np.logaddexp(0.0, minus_sign * f).sum())


def add_to_diagonal(A: FloatArray, value: float) -> FloatArray:
    """Add ``value`` to the diagonal of the square, C-contiguous ``A`` in place; return ``A``."""
    A.ravel()[:: A.shape[0] + 1] += value
    return A


def _cholesky_b(K: FloatArray, sqrt_w: FloatArray) -> FloatArray:
    """Return the lower Cholesky factor of ``B = I + W^1/2 K W^1/2`` (Alg. 3.1, line 5).

    LAPACK is called directly: at the sizes of active learning (tens of observations) the
    checks of the generic wrappers cost more than the factorisation.

    Raises:
        NumericalError: ``B`` is not positive definite (non-finite or asymmetric ``K``).
    """
    B = add_to_diagonal(K * (sqrt_w[:, None] * sqrt_w), 1.0)
    # B is symmetric: its transpose is the Fortran-ordered array LAPACK factorises in place.
    # The strict upper triangle of the result keeps B's entries (every user reads the lower).
    L, info = lapack.dpotrf(B.T, lower=1, clean=0, overwrite_a=1)
    _check_cholesky(L, info)
    return L  # type: ignore[no-any-return]  # LAPACK returns float64 for float64 input


def _check_cholesky(L: FloatArray, info: int) -> None:
    """Raise NumericalError when LAPACK's Cholesky factorisation of ``B`` failed."""
    if info != 0 or not math.isfinite(L[-1, -1]):
        raise NumericalError(_CHOLESKY_FAILED.format(info=f"LAPACK info {info}"))


_CHOLESKY_FAILED: Final = (
    "Cholesky of B = I + W^1/2 K W^1/2 failed ({info}): the kernel matrix is not a valid "
    "covariance (NaN/inf features or hyperparameters?); check the training features"
)


def _tri_solve(L: FloatArray, b: FloatArray) -> FloatArray:
    """Solve ``L x = b`` for lower-triangular ``L``."""
    x, _ = lapack.dtrtrs(L, b, lower=1)
    return np.asarray(x, dtype=np.float64)


def _newton_step(
    K: FloatArray, y: FloatArray, f: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """One Newton step from ``f`` (R&W Alg. 3.1, lines 4-7): ``a_new``, ``pi``, ``W^1/2``, ``L``.

    LAPACK's ``dposv`` factorises ``B`` and solves with it in one call; written with in-place
    operations, as at these sizes each numpy call costs more than its arithmetic.

    Raises:
        NumericalError: ``B`` is not positive definite (non-finite or asymmetric ``K``).
    """
    pi = expit(f)  # line 4: W = -grad grad log p(y|f)
    W = pi * (1.0 - pi)
    sqrt_w = np.sqrt(W)
    B = sqrt_w[:, None] * K  # line 5: B = I + W^1/2 K W^1/2
    B *= sqrt_w
    add_to_diagonal(B, 1.0)
    b = W * f  # line 6: b = W f + grad log p(y|f)
    b += y
    b -= pi
    rhs = K @ b  # line 7: a = b - W^1/2 L' \\ (L \\ (W^1/2 K b))
    rhs *= sqrt_w
    # B (symmetric) transposed is the Fortran-ordered array LAPACK factorises in place
    L, z, info = lapack.dposv(B.T, rhs, lower=1, overwrite_a=1, overwrite_b=1)
    _check_cholesky(L, info)
    z *= sqrt_w
    b -= z
    return b, pi, sqrt_w, L


def _damped(
    K: FloatArray, minus_sign: FloatArray, a: FloatArray, a_new: FloatArray, psi: float
) -> tuple[FloatArray, FloatArray, float]:
    """Halve a Newton step that lowered ``Psi`` until it does not (rarely needed)."""
    for _ in range(_MAX_HALVINGS):
        a_new = 0.5 * (a + a_new)
        f_new = K @ a_new
        psi_new = -0.5 * float(a_new @ f_new) + _log_likelihood(minus_sign, f_new)
        if psi_new >= psi:
            break
    return a_new, f_new, psi_new


def _check_newton(K: FloatArray, max_iter: int) -> None:
    """Raise for an iteration limit below 1 or a non-finite covariance."""
    if max_iter < 1:
        msg = f"max_iter={max_iter}; Newton's method needs at least one iteration"
        raise AtiktError(msg)
    if not np.isfinite(K).all():
        msg = "the kernel matrix has NaN or inf entries; check the features and hyperparameters"
        raise NumericalError(msg)


def laplace_mode(
    K: FloatArray,
    y: FloatArray,
    f0: FloatArray | None = None,
    *,
    max_iter: int = 100,
    tol: float = 1e-10,
) -> LaplaceMode:
    """Find the posterior mode of a binary GP classifier by Newton's method (R&W Alg. 3.1).

    Newton's method stops when a step raises the objective ``Psi(f) = -a'f/2 + log p(y|f)`` by
    less than ``tol``, or when an undamped step moved no latent value by more than
    ``_SHORT_STEP`` (Newton's method converges quadratically: the error left is of the order
    of that step squared), or when the quadratic convergence of the last two steps predicts
    the next one to be shorter than ``_CONVERGED`` (``step^3 / last_step^2``; ``W`` and ``L``
    are then computed at the returned ``f``, which is the mode up to about that length,
    instead of taking that step). When the last step moved no latent value by more than
    ``_SHORT_STEP``, ``W`` and ``L`` (hence the log determinant, the predictions and the
    gradient) are those of the last linearisation point, at most that far from the returned
    mode (the log determinant moves by ``O(n * _SHORT_STEP * max W')``, ``|W'| < 0.1``: below
    1e-4 nats here, far below the hyperparameter search's tolerance); after a longer last step
    they are recomputed at the returned mode.

    Args:
        K: Prior covariance of the training points, shape (n, n).
        y: Labels in {0, 1}, shape (n,) float.
        f0: Starting latent values, e.g. a previous mode or a prediction of it; zeros when None.
        max_iter: Maximum Newton iterations.
        tol: Stopping tolerance on the rise of ``Psi``.

    Returns:
        The mode and the quantities Alg. 3.2 and Alg. 5.1 reuse.

    Raises:
        NumericalError: ``K`` is not finite, ``B`` could not be factorised, or the objective
            is not finite.
    """
    _check_newton(K, max_iter)
    minus_sign = -(2.0 * y - 1.0)  # -s of the likelihood, s = 2y - 1
    a: FloatArray | None = None
    if f0 is None:  # f = K a with a = 0: Psi(0) = log p(y | 0)
        f, a = np.zeros(y.shape[0]), np.zeros(y.shape[0])
        psi = _log_likelihood(minus_sign, f)
    else:  # no a with K a = f0: the first Newton step is always taken
        f, psi = f0, -np.inf
    n_iter, last_step = 0, math.inf
    for n_iter in range(1, max_iter + 1):
        a_new, pi, sqrt_w, L = _newton_step(K, y, f)
        f_new = K @ a_new  # line 8
        psi_new = -0.5 * float(a_new @ f_new) + _log_likelihood(minus_sign, f_new)
        damped = False
        if a is not None and psi_new < psi - tol:
            a_new, f_new, psi_new = _damped(K, minus_sign, a, a_new, psi)
            damped = True
        if not math.isfinite(psi_new):
            msg = "the Laplace objective is not finite; check the features and hyperparameters"
            raise NumericalError(msg)
        step = float(np.abs(f_new - f).max())
        # line 10; a full Newton step this short leaves an error of its square
        if psi_new - psi < tol or (step <= _SHORT_STEP and not damped):
            if step <= _SHORT_STEP:  # W and L of f are those of the mode, up to the step
                lml = psi_new - float(np.log(L.diagonal()).sum())
                return LaplaceMode(f_new, a_new, pi, sqrt_w, L, lml, n_iter, K)
            a, f, psi = a_new, f_new, psi_new
            break
        a, f, psi = a_new, f_new, psi_new
        # quadratic convergence: the next step would be about step^3 / last_step^2 long; if that
        # is short, f is the mode up to it and only W and L are still needed there
        if not damped and step < last_step < math.inf and step**3 <= _CONVERGED * last_step**2:
            break
        last_step = math.inf if damped else step
    pi = expit(f)  # W and L at the returned mode
    sqrt_w = np.sqrt(pi * (1.0 - pi))
    L = _cholesky_b(K, sqrt_w)
    if a is None:  # cannot happen: every iteration that does not return sets a
        msg = "Newton's method produced no iterate; report this with the inputs"
        raise NumericalError(msg)
    lml = psi - float(np.log(L.diagonal()).sum())
    return LaplaceMode(f, a, pi, sqrt_w, L, lml, n_iter, K)


def laplace_evidences(
    K: FloatArray, Y: FloatArray, *, max_iter: int = 100, tol: float = 1e-10
) -> FloatArray:
    """Return :func:`laplace_mode`'s log marginal likelihood for each row of labels ``Y``.

    The labels share one covariance ``K`` (e.g. the one-vs-all classifiers of several objects
    at one kernel), so Newton's method runs on all of them at once: each array operation works
    on every label vector still iterating, with the same steps and the same stopping rules per
    vector as :func:`laplace_mode`. The results equal :func:`laplace_mode`'s up to rounding
    (about 1e-13 nats). A vector whose Newton step lowers the objective (the rare damped
    step) is handed to :func:`laplace_mode` itself, and so is every vector when ``K`` is not
    positive definite (not a covariance, or singular without jitter). Written by hand because
    no library fits many small Laplace approximations at once; at tens of observations each
    numpy call costs more than its arithmetic, so one call for all vectors instead of one per
    vector is what makes it faster.

    Args:
        K: Prior covariance of the training points, shape (n, n).
        Y: Labels in {0, 1}, shape (m, n) float: one row per classifier.
        max_iter: Maximum Newton iterations.
        tol: Stopping tolerance on the rise of ``Psi``.

    Returns:
        The log marginal likelihoods, shape (m,).

    Raises:
        NumericalError: ``K`` is not finite, a ``B`` could not be factorised, or an objective
            is not finite.
    """
    _check_newton(K, max_iter)
    try:  # K positive definite: every B = I + W^1/2 K W^1/2 is, as laplace_mode's Cholesky needs
        np.linalg.cholesky(K)
    except np.linalg.LinAlgError:  # not a covariance: each vector as laplace_mode decides
        return np.array(
            [laplace_mode(K, y, max_iter=max_iter, tol=tol).log_marginal_likelihood for y in Y]
        )
    m, n = Y.shape
    result = [math.nan] * m
    sign = 2.0 * Y - 1.0
    F = np.zeros((m, n))
    psi = [-n * math.log(2.0)] * m  # Psi(0) = log p(y | 0)
    last_step = [math.inf] * m
    active, ended = list(range(m)), []
    eye = np.eye(n)
    for _ in range(max_iter):
        if not active:
            break
        rows = np.asarray(active)
        f = F[rows]
        pi = expit(f)
        W = pi * (1.0 - pi)
        sqrt_w = np.sqrt(W)
        B = sqrt_w[:, :, None] * K  # each I + W^1/2 K W^1/2, in place
        B *= sqrt_w[:, None, :]
        B += eye
        b = W * f + Y[rows] - pi
        rhs = (b @ K) * sqrt_w  # K b per row (K symmetric)
        a_new = b - np.linalg.solve(B, rhs[:, :, None])[:, :, 0] * sqrt_w
        f_new = a_new @ K
        psi_new = -0.5 * np.einsum("ij,ij->i", a_new, f_new)
        psi_new -= np.logaddexp(0.0, -sign[rows] * f_new).sum(axis=1)
        steps = np.abs(f_new - f).max(axis=1).tolist()
        F[rows] = f_new
        still, short = [], []
        for k, (row, new) in enumerate(zip(active, psi_new.tolist(), strict=True)):
            step, old = steps[k], psi[row]
            psi[row] = new
            if new < old - tol or not math.isfinite(new):  # a damped step: rare
                mode = laplace_mode(K, Y[row], max_iter=max_iter, tol=tol)
                result[row] = mode.log_marginal_likelihood
            elif step <= _SHORT_STEP:  # W and L of f are those of the mode, up to the step
                short.append(k)
            elif new - old < tol or (
                step < last_step[row] < math.inf and step**3 <= _CONVERGED * last_step[row] ** 2
            ):
                ended.append(row)  # W and L at the returned mode: below
            else:
                last_step[row] = step
                still.append(row)
        _subtract_half_log_det(result, psi, [active[k] for k in short], B[short])
        active = still
    ended += active  # at max_iter: W and L at the last iterate, as laplace_mode
    pi = expit(F[ended])
    sqrt_w = np.sqrt(pi * (1.0 - pi))
    _subtract_half_log_det(result, psi, ended, sqrt_w[:, :, None] * K * sqrt_w[:, None, :] + eye)
    return np.asarray(result)


def _subtract_half_log_det(
    result: list[float], psi: list[float], rows: list[int], B: FloatArray
) -> None:
    """Set ``result[row] = psi[row] - log |B_k| / 2`` for the ``k``-th of ``rows``."""
    if rows:
        for row, value in zip(rows, _half_log_det(B).tolist(), strict=True):
            result[row] = psi[row] - value


def _half_log_det(B: FloatArray) -> FloatArray:
    """``log |B| / 2`` of each of a stack of ``B`` (the sum of its Cholesky factor's log diagonal).

    Raises:
        NumericalError: a ``B`` is not positive definite.
    """
    try:
        L = np.linalg.cholesky(B)
    except np.linalg.LinAlgError as error:
        raise NumericalError(_CHOLESKY_FAILED.format(info="not positive definite")) from error
    return np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1)  # type: ignore[no-any-return]


def lml_gradient(K: FloatArray, dK: FloatArray, y: FloatArray, mode: LaplaceMode) -> FloatArray:
    """Gradient of the approximate log marginal likelihood (R&W Alg. 5.1, lines 7-15).

    Args:
        K: Prior covariance, shape (n, n).
        dK: ``dK/dtheta``, shape (n_params, n, n).
        y: Labels in {0, 1}, shape (n,).
        mode: :func:`laplace_mode` of ``K`` and ``y``.

    Returns:
        ``d log q(y | X, theta) / d theta``, shape (n_params,).
    """
    return _gradient_terms(K, dK, y, mode)[0]


def _gradient_terms(
    K: FloatArray, dK: FloatArray, y: FloatArray, mode: LaplaceMode
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Alg. 5.1 lines 7-15.

    Also returns ``d f_hat / d theta`` (R&W Eq. 5.25), shape (n_params, n), and the latent
    predictive variance at the training inputs, ``diag(K - C'C)`` (line 9's ``diag(Sigma)``,
    equal to Alg. 3.2 line 6 at the training inputs), shape (n,).
    """
    sqrt_w, L, pi = mode.sqrt_w, mode.L, mode.pi
    V = _tri_solve(L, np.diag(sqrt_w))  # L \\ W^1/2, so that R = V'V and C = V K
    R = V.T @ V  # line 7: R = W^1/2 L' \\ (L \\ W^1/2)
    C = V @ K  # line 8: C = L \\ (W^1/2 K)
    variance = K.diagonal() - np.einsum("ij,ij->j", C, C)
    # line 9: d^3 log p / df^3 = -pi (1 - pi) (1 - 2 pi) for the logistic likelihood, so
    # s2 = -diag(Sigma) / 2 * d^3 log p / df^3 = diag(Sigma) W (pi - 1/2)
    s2 = variance * (sqrt_w * sqrt_w)
    s2 *= pi - 0.5
    # line 12, all hyperparameters at once: a' dK_j a / 2 - tr(R dK_j) / 2
    M = mode.a[:, None] * mode.a
    M -= R
    s1 = dK.reshape(dK.shape[0], -1) @ M.ravel()
    s1 *= 0.5
    b = dK @ (y - pi)  # line 13, one row per hyperparameter
    s3 = b - (b @ R) @ K  # line 14 (K and R are symmetric): s3_j = d f_hat / d theta_j
    return np.asarray(s1 + s3 @ s2, dtype=np.float64), s3, variance  # line 15


def predictive_probability(mean: FloatArray, var: FloatArray) -> FloatArray:
    """Return ``int sigmoid(f) N(f | mean, var) df`` (R&W Alg. 3.2 line 7; Williams & Barber).

    Args:
        mean: Latent predictive means, shape (n,).
        var: Latent predictive variances, shape (n,) (negative round-off is clipped to 0).

    Returns:
        Probabilities of the positive class in [0, 1], shape (n,).
    """
    z = _LAMBDAS * mean / np.sqrt(1.0 + _TWO_LAMBDAS_SQ * np.maximum(var, 0.0))
    p = _HALF_COEFS_SUM + _HALF_COEFS @ erf(z)
    return np.asarray(np.minimum(np.maximum(p, 0.0), 1.0), dtype=np.float64)


def _check_xy(X: npt.ArrayLike, y: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Validate a training set with binary labels.

    Raises:
        AtiktError: Shapes disagree, values are not finite, or labels are not 0/1.
    """
    Xa = np.asarray(X, dtype=np.float64)
    ya = np.asarray(y, dtype=np.float64).reshape(-1)
    if Xa.ndim != 2 or Xa.shape[0] != ya.shape[0] or Xa.shape[0] == 0:  # noqa: PLR2004
        msg = f"X has shape {Xa.shape} and y {ya.shape}; need X (n, d), y (n,) with n >= 1"
        raise AtiktError(msg)
    if not (np.isfinite(Xa).all() and ((ya == 0) | (ya == 1)).all()):
        msg = "X must be finite and y binary (0 = negative, 1 = positive); check the features"
        raise AtiktError(msg)
    return Xa, ya


class BinaryGPC:
    """Binary GP classifier with the Laplace approximation (R&W Alg. 3.1, 3.2, 5.1).

    Hyperparameters maximise the approximate log marginal likelihood with the analytic
    gradient (:func:`atikt.optimize.minimize_box`, a projected BFGS), starting from the
    kernel's own ``theta`` with the curvature ``inverse_hessian`` (so passing the previous
    optimum and its ``inverse_hessian_`` warm-starts the search) and from ``n_restarts`` points
    drawn uniformly in the bounds with ``random_state``. Within one search, Newton's method
    starts from a prediction of the mode, which typically halves the Newton iterations. A class
    may be absent from ``y`` (e.g. only positives); the classifier is then simply confident.

    Args:
        kernel: Covariance function; its ``theta`` is the first starting point.
        optimize: False keeps the kernel's hyperparameters.
        n_restarts: Additional random starting points.
        max_iter: Iteration limit per start (small values are deliberate: warm starts from the
            previous optimum only need a few).
        tol: A search that starts with a carried ``inverse_hessian`` stops when its quadratic
            model predicts a rise of the log marginal likelihood below ``tol`` nats; a cold
            search (random restarts, or no curvature given) runs to convergence
            (``COLD_TOL``), as the first fit on a few observations has a flat, uninformative
            start.
        inverse_hessian: Starting curvature of the search from the kernel's ``theta`` (the
            ``inverse_hessian_`` of a previous fit); None starts from the identity. Ignored
            when its shape does not match the kernel's hyperparameters.
        mode_start: Latent values to start the first Newton search from, for the first
            ``len(mode_start)`` training points (the others start at 0): the ``mode_.f`` of a
            previous fit whose training points were the first ones of this fit. None, or longer
            than the training set: start from 0. Only the cost depends on it, not the mode.
        newton_max_iter: Newton iteration limit of the mode search.
        newton_tol: Newton stopping tolerance on the Laplace objective.
        jitter: Added to the diagonal of ``K``; it keeps predictive variances non-negative.
        prior_sd: Standard deviation of an independent Gaussian prior on every log
            hyperparameter (the search then maximises the log marginal likelihood plus the log
            prior: maximum a posteriori); None: no prior (maximum likelihood).
        prior_mean: Centre of that prior, shape (n_params,), log space; None: the kernel's
            own ``theta``.
        random_state: Seed or generator of the restarts.

    Attributes:
        kernel_: Kernel with the fitted hyperparameters.
        X_train_: Training inputs, shape (n, d).
        y_train_: Training labels in {0, 1}, shape (n,).
        mode_: The Laplace approximation at ``kernel_``.
        log_marginal_likelihood_value_: ``log q(y | X, theta)`` at ``kernel_``.
        inverse_hessian_: The search's curvature at ``kernel_`` (None without a search).
        n_evaluations_: Objective evaluations spent on the hyperparameter search.
        n_iter_: Iterations of the start that won (0 without a search).
    """

    def __init__(
        self,
        kernel: Kernel,
        *,
        optimize: bool = True,
        n_restarts: int = 0,
        max_iter: int = 50,
        tol: float = 1e-3,
        inverse_hessian: FloatArray | None = None,
        mode_start: FloatArray | None = None,
        newton_max_iter: int = 100,
        newton_tol: float = 1e-10,
        jitter: float = 1e-10,
        prior_sd: float | FloatArray | None = None,
        prior_mean: FloatArray | None = None,
        random_state: RandomState = None,
    ) -> None:
        """Store the parameters; see the class docstring."""
        self.kernel = kernel
        self.optimize = optimize
        self.n_restarts = n_restarts
        self.max_iter = max_iter
        self.prior_sd = prior_sd
        self.prior_mean = prior_mean
        self.tol = tol
        self.inverse_hessian = inverse_hessian
        self.mode_start = mode_start
        self.newton_max_iter = newton_max_iter
        self.newton_tol = newton_tol
        self.jitter = jitter
        self.random_state = random_state

    def _covariance(self, kernel: Kernel, X: FloatArray) -> FloatArray:
        """Return ``K(X, X)`` plus jitter."""
        return add_to_diagonal(kernel(X), self.jitter)

    def _mode_start(self, n: int) -> FloatArray | None:
        """``mode_start`` padded with zeros to ``n`` points (None: no usable start)."""
        start = self.mode_start
        if start is None or not 0 < len(start) <= n:
            return None
        f_start = np.zeros(n)
        f_start[: len(start)] = start
        return f_start

    def _objective(self, X: FloatArray, y: FloatArray) -> _NegativeLml:
        """Return the negative log marginal likelihood of ``(X, y)`` as a function of theta."""
        return _NegativeLml(
            self.kernel,
            X,
            y,
            jitter=self.jitter,
            newton_max_iter=self.newton_max_iter,
            newton_tol=self.newton_tol,
            f_start=self._mode_start(y.shape[0]),
        )

    def fit(self, X: npt.ArrayLike, y: npt.ArrayLike) -> Self:
        """Fit hyperparameters (if ``optimize``) and the Laplace approximation.

        Args:
            X: Training inputs, shape (n, d).
            y: Labels in {0, 1} (or bool), shape (n,).

        Returns:
            self.

        Raises:
            AtiktError: Malformed training data.
            NumericalError: Every start of the hyperparameter search failed numerically.
        """
        self.X_train_, self.y_train_ = _check_xy(X, y)
        kernel, mode, f0 = self.kernel, None, self._mode_start(self.y_train_.shape[0])
        self.n_evaluations_, self.n_iter_ = 0, 0
        self.inverse_hessian_: FloatArray | None = None
        self._training_variance: FloatArray | None = None
        if self.optimize and kernel.n_params > 0:
            objective = self._objective(self.X_train_, self.y_train_)
            theta = self._search(objective)
            kernel, last = kernel.with_theta(theta), objective.mode_at(theta)
            if last is not None:
                mode, self._training_variance = last
            else:  # the search ended before its last evaluation: start from a prediction
                f0 = objective.start(theta)
            self.n_evaluations_ = objective.n_calls
        self.kernel_ = kernel
        if mode is None:  # the search ended elsewhere than its last evaluation, or no search
            K = self._covariance(kernel, self.X_train_)
            mode = laplace_mode(
                K, self.y_train_, f0, max_iter=self.newton_max_iter, tol=self.newton_tol
            )
        self.mode_ = mode
        self.log_marginal_likelihood_value_ = mode.log_marginal_likelihood
        return self

    def _search(self, objective: _NegativeLml) -> FloatArray:
        """Search from the kernel's theta and the random restarts; return the best theta.

        Raises:
            NumericalError: No start produced a finite optimum.
        """
        bounds = self.kernel.bounds
        n = bounds.shape[0]
        curvature = self.inverse_hessian
        if curvature is not None and np.shape(curvature) != (n, n):
            curvature = None
        # into the box (np.clip's values, without its Python-level wrapper)
        start = np.minimum(np.maximum(self.kernel.theta, bounds[:, 0]), bounds[:, 1])
        starts = [(start, curvature)]
        if self.n_restarts > 0:
            rng = _rng(self.random_state)
            starts += [
                (rng.uniform(bounds[:, 0], bounds[:, 1]), None) for _ in range(self.n_restarts)
            ]
        function = with_prior(objective, self.kernel, self.prior_sd, self.prior_mean)
        best = best_search(
            function,
            starts,
            bounds,
            max_iter=self.max_iter,
            tol=self.tol,
            failure="the hyperparameter search failed from every start; check the training data",
        )
        self.n_iter_, self.inverse_hessian_ = best.n_iter, best.inverse_hessian
        return best.x

    def log_marginal_likelihood(
        self, theta: npt.ArrayLike | None = None, *, eval_gradient: bool = False
    ) -> float | tuple[float, FloatArray]:
        """Approximate log marginal likelihood of the training data (and its gradient).

        Args:
            theta: Hyperparameters (log space); the fitted ones when None.
            eval_gradient: Also return ``d/dtheta`` (R&W Alg. 5.1).

        Returns:
            The value, or ``(value, gradient)`` with gradient shape (n_params,).

        Raises:
            NotFittedError: ``fit`` was not called.
        """
        self._check_fitted()
        kernel = self.kernel_ if theta is None else self.kernel_.with_theta(theta)
        objective = _NegativeLml(
            kernel,
            self.X_train_,
            self.y_train_,
            jitter=self.jitter,
            newton_max_iter=self.newton_max_iter,
            newton_tol=self.newton_tol,
        )
        value, gradient = objective(kernel.theta)
        return (-value, -gradient) if eval_gradient else -value

    def _check_fitted(self) -> None:
        """Raise NotFittedError before ``fit``."""
        if not hasattr(self, "mode_"):
            msg = f"{type(self).__name__} is not fitted; call fit(X, y) first"
            raise NotFittedError(msg)

    def latent(self, X: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Latent predictive mean and variance at ``X`` (R&W Alg. 3.2, lines 4-6).

        Args:
            X: Test inputs, shape (m, d).

        Returns:
            Mean and variance, each shape (m,).
        """
        self._check_fitted()
        Xs = np.asarray(X, dtype=np.float64)
        K_star = self.kernel_(self.X_train_, Xs)
        mean = K_star.T @ self.mode_.a  # line 4, a = K^-1 f = y - pi at the mode
        v = _tri_solve(self.mode_.L, self.mode_.sqrt_w[:, None] * K_star)  # line 5
        var = self.kernel_.diag(Xs) - np.einsum("ij,ij->j", v, v)  # line 6
        return mean, var

    def latent_mean(self, X: npt.ArrayLike) -> FloatArray:
        """Latent predictive mean at ``X`` only (R&W Alg. 3.2, line 4), shape (m,)."""
        self._check_fitted()
        K_star = self.kernel_(self.X_train_, np.asarray(X, dtype=np.float64))
        return np.asarray(K_star.T @ self.mode_.a, dtype=np.float64)

    def predict_positive(self, X: npt.ArrayLike) -> FloatArray:
        """Probability of the positive class at ``X``, shape (m,) (Alg. 3.2, line 7)."""
        return predictive_probability(*self.latent(X))

    def training_latent(self, rows: slice = slice(None)) -> tuple[FloatArray, FloatArray]:
        r"""Latent predictive mean and variance at training inputs, without a kernel call.

        At a training input the predictive mean ``k(x_i)' (y - pi) = (K K^-1 f)_i`` is the
        mode itself, and the variance ``diag(K - v'v)`` with ``v = L \ W^1/2 K`` reuses the
        covariance of the fit (and is the one the search's last gradient evaluation already
        computed, Alg. 5.1 line 9, when the fit ended there); this equals :meth:`latent` of
        ``X_train_[rows]`` up to the jitter (1e-10 by default).

        Args:
            rows: The training rows, e.g. ``slice(n_aux, None)``.

        Returns:
            Mean and variance, each of the rows' length.
        """
        self._check_fitted()
        mode = self.mode_
        if self._training_variance is None:  # not left by the search: one solve, kept
            v = _tri_solve(mode.L, mode.sqrt_w[:, None] * mode.K)
            self._training_variance = mode.K.diagonal() - np.einsum("ij,ij->j", v, v)
        return mode.f[rows], self._training_variance[rows]

    def predict_proba(self, X: npt.ArrayLike) -> FloatArray:
        """Class probabilities ``[p(y=0), p(y=1)]`` at ``X``, shape (m, 2)."""
        p = self.predict_positive(X)
        return np.column_stack([1.0 - p, p])

    def predict(self, X: npt.ArrayLike) -> IntArray:
        """Most probable label (0 or 1) at ``X``, shape (m,)."""
        return (self.predict_positive(X) > 0.5).astype(np.int64)  # noqa: PLR2004


def best_search(
    function: Callable[[FloatArray], tuple[float, FloatArray]],
    starts: Sequence[tuple[FloatArray, FloatArray | None]],
    bounds: FloatArray,
    *,
    max_iter: int,
    tol: float,
    failure: str,
) -> SearchResult:
    """Minimise ``function`` from every start; return the lowest result.

    Args:
        function: ``theta -> (value, gradient)`` to minimise.
        starts: ``(theta, inverse Hessian or None)`` per start; a start without a carried
            curvature is a cold search and runs to ``min(tol, COLD_TOL)``.
        bounds: The box, shape (n_params, 2).
        max_iter: Iteration limit per start.
        tol: Stopping tolerance of a warm search.
        failure: The message when every start fails.

    Raises:
        NumericalError: No start produced a finite optimum.
    """
    best, error = None, None
    for start, inverse_hessian in starts:
        try:
            result = minimize_box(
                function,
                start,
                bounds,
                inverse_hessian=inverse_hessian,
                max_iter=max_iter,
                tol=tol if inverse_hessian is not None else min(tol, COLD_TOL),
            )
        except NumericalError as err:
            error = err
            continue
        if best is None or result.fun < best.fun:
            best = result
    if best is None:
        raise NumericalError(failure) from error
    return best


def with_prior(
    objective: Callable[[FloatArray], tuple[float, FloatArray]],
    kernel: Kernel,
    sd: float | npt.ArrayLike | None,
    mean: FloatArray | None = None,
) -> Callable[[FloatArray], tuple[float, FloatArray]]:
    """Add the negative log density of a Gaussian prior on log hyperparameters to an objective.

    Args:
        objective: ``theta -> (value, gradient)`` to minimise (negative log evidence).
        kernel: The kernel (its ``theta`` is the prior's centre when ``mean`` is None).
        sd: Prior standard deviation of every log hyperparameter, or one per hyperparameter
            (shape (n_params,); ``inf`` leaves that one without a prior); None: no prior.
        mean: Prior centre, shape (n_params,).

    Returns:
        ``theta -> (value + |theta - mean|^2 / (2 sd^2), gradient + (theta - mean) / sd^2)``
        (constants dropped), or ``objective`` itself without a prior.

    Raises:
        AtiktError: ``sd`` is not positive or ``mean`` has the wrong shape.
    """
    if sd is None:
        return objective
    start = kernel.theta
    shape = start.shape
    centre = start if mean is None else np.asarray(mean, dtype=np.float64)
    scalar_sd = np.ndim(sd) == 0  # then no broadcast: numpy's broadcast_to is Python-level
    sds = np.asarray(sd, dtype=np.float64)
    if not scalar_sd:
        sds = np.broadcast_to(sds, shape)
    if not (sds > 0).all() or centre.shape != shape:
        msg = f"prior_sd={sd}, prior_mean shape {centre.shape}: need sd > 0 and {shape}"
        raise AtiktError(msg)
    if scalar_sd:  # one sd for all: the arithmetic of the learners' goldens
        scalar = 1.0 / float(sd) ** 2  # type: ignore[arg-type]

        def penalised_scalar(theta: FloatArray) -> tuple[float, FloatArray]:
            value, gradient = objective(theta)
            offset = theta - centre
            return value + 0.5 * scalar * float(offset @ offset), gradient + scalar * offset

        return penalised_scalar
    precision = 1.0 / sds**2  # inf -> 0: no prior on that hyperparameter

    def penalised(theta: FloatArray) -> tuple[float, FloatArray]:
        value, gradient = objective(theta)
        offset = theta - centre
        weighted = precision * offset
        return value + 0.5 * float(offset @ weighted), gradient + weighted

    return penalised


class _NegativeLml:
    """``theta -> (-log q, -d log q / d theta)`` with a warm-started Newton search.

    Newton's method starts from a first-order prediction of the new mode,
    ``f_hat(theta) ~ f_hat(theta') + (theta - theta') d f_hat / d theta`` (R&W Eq. 5.25, a
    by-product of the gradient), which usually leaves two Newton iterations per evaluation. The
    last evaluation (theta, mode) is kept, so the fit after the search does not redo it.
    """

    max_prediction: Final = 3.0
    """Largest predicted change of a latent value; farther jumps start from the last mode."""

    def __init__(
        self,
        kernel: Kernel,
        X: FloatArray,
        y: FloatArray,
        *,
        jitter: float,
        newton_max_iter: int,
        newton_tol: float,
        f_start: FloatArray | None = None,
    ) -> None:
        self.evaluate = kernel.evaluator(X)
        self.f_start = f_start
        self.y = y
        self.jitter, self.newton_max_iter, self.newton_tol = jitter, newton_max_iter, newton_tol
        self.last_theta: FloatArray | None = None
        self.last_mode: LaplaceMode | None = None
        self.last_slope: FloatArray | None = None
        self.last_variance = np.zeros(0)
        self.n_calls = 0

    def start(self, theta: FloatArray) -> FloatArray | None:
        """Predicted mode at ``theta`` from the last evaluation (None: start from zero)."""
        if self.last_mode is None or self.last_theta is None or self.last_slope is None:
            return self.f_start
        change = (theta - self.last_theta) @ self.last_slope
        if np.abs(change).max(initial=0.0) > self.max_prediction:
            return self.last_mode.f
        return np.asarray(self.last_mode.f + change, dtype=np.float64)

    def __call__(self, theta: FloatArray) -> tuple[float, FloatArray]:
        """Evaluate at ``theta`` (log space)."""
        self.n_calls += 1
        K, dK = self.evaluate(theta)
        add_to_diagonal(K, self.jitter)
        f0 = self.start(theta)
        mode = laplace_mode(K, self.y, f0, max_iter=self.newton_max_iter, tol=self.newton_tol)
        gradient, slope, variance = _gradient_terms(K, dK, self.y, mode)
        self.last_theta = np.array(theta, dtype=np.float64)
        self.last_mode, self.last_slope, self.last_variance = mode, slope, variance
        return -mode.log_marginal_likelihood, -gradient

    def mode_at(self, theta: FloatArray) -> tuple[LaplaceMode, FloatArray] | None:
        """The last evaluation's Laplace mode and training variance if it was at ``theta``."""
        if self.last_theta is not None and np.array_equal(self.last_theta, theta):
            assert self.last_mode is not None  # noqa: S101 - set with last_theta
            return self.last_mode, self.last_variance
        return None


def _check_labels(y: npt.ArrayLike, n: int) -> IntArray:
    """Return integer class labels of length ``n``.

    Raises:
        AtiktError: Wrong length, or fewer than two classes.
    """
    labels = np.asarray(y).reshape(-1)
    if labels.shape[0] != n or not np.issubdtype(labels.dtype, np.integer):
        msg = f"labels: need {n} integer class labels, got shape {labels.shape} {labels.dtype}"
        raise AtiktError(msg)
    if np.unique(labels).shape[0] < 2:  # noqa: PLR2004
        msg = "labels: one-vs-all classification needs at least two classes"
        raise AtiktError(msg)
    return labels.astype(np.int64)


class OneVsAllGPC:
    """One binary Laplace GPC per class; probabilities normalised over the classes.

    Args:
        kernel: Starting kernel of every binary classifier.
        optimize: False keeps the kernel's hyperparameters.
        n_restarts: Additional random starts per binary classifier.
        max_iter: Iteration limit of the hyperparameter search per start.
        jitter: Diagonal jitter.
        shared: One set of hyperparameters for all classes, maximising the sum of the binary
            classifiers' log marginal likelihoods (the evidence of all classes decides, e.g.,
            the modality weights); False fits each class's own.
        random_state: Seed or generator; each binary classifier gets its own derived seed
            (with ``shared``, the one search uses the first).
        prior_sd: Gaussian prior on the log hyperparameters, centred at the kernel's
            ``theta`` (see :class:`BinaryGPC`); None: maximum likelihood.

    Attributes:
        classes_: Sorted class labels, shape (k,).
        estimators_: One fitted :class:`BinaryGPC` per class (class vs rest).
    """

    def __init__(
        self,
        kernel: Kernel,
        *,
        optimize: bool = True,
        n_restarts: int = 0,
        max_iter: int = 50,
        jitter: float = 1e-10,
        shared: bool = False,
        prior_sd: float | FloatArray | None = None,
        random_state: RandomState = None,
    ) -> None:
        """Store the parameters; see the class docstring."""
        self.kernel = kernel
        self.optimize = optimize
        self.n_restarts = n_restarts
        self.max_iter = max_iter
        self.jitter = jitter
        self.shared = shared
        self.prior_sd = prior_sd
        self.random_state = random_state

    def fit(self, X: npt.ArrayLike, y: npt.ArrayLike) -> Self:
        """Fit one binary classifier per class.

        Args:
            X: Training inputs, shape (n, d).
            y: Integer class labels, shape (n,), at least two classes.

        Returns:
            self.
        """
        Xa = np.asarray(X, dtype=np.float64)
        labels = _check_labels(y, Xa.shape[0] if Xa.ndim == 2 else -1)  # noqa: PLR2004
        self.classes_ = np.unique(labels)
        seeds = spawn_seeds(self.random_state, self.classes_.shape[0])
        kernel, optimize = self.kernel, self.optimize
        if self.shared and self.optimize and kernel.n_params > 0:
            kernel, optimize = self._shared_search(Xa, labels, seeds[0]), False
        self.estimators_ = [
            BinaryGPC(
                kernel,
                optimize=optimize,
                n_restarts=self.n_restarts,
                max_iter=self.max_iter,
                jitter=self.jitter,
                prior_sd=self.prior_sd,
                random_state=seed,
            ).fit(Xa, labels == c)
            for c, seed in zip(self.classes_, seeds, strict=True)
        ]
        return self

    def _shared_search(self, X: FloatArray, labels: IntArray, seed: int) -> Kernel:
        """Return the kernel maximising the sum over classes of the binary evidences.

        Raises:
            NumericalError: The search failed from every start.
        """
        binary = BinaryGPC(self.kernel, jitter=self.jitter)
        parts = [
            binary._objective(X, (labels == c).astype(np.float64))  # noqa: SLF001
            for c in self.classes_
        ]

        def evidence(theta: FloatArray) -> tuple[float, FloatArray]:
            values = [part(theta) for part in parts]
            return sum(v for v, _ in values), np.sum([g for _, g in values], axis=0)

        total = with_prior(evidence, self.kernel, self.prior_sd)

        bounds = self.kernel.bounds
        starts = [np.clip(self.kernel.theta, bounds[:, 0], bounds[:, 1])]
        rng = _rng(seed)
        starts += [rng.uniform(bounds[:, 0], bounds[:, 1]) for _ in range(self.n_restarts)]
        best = best_search(
            total,
            [(start, None) for start in starts],
            bounds,
            max_iter=self.max_iter,
            tol=COLD_TOL,
            failure="the shared hyperparameter search failed from every start; check the data",
        )
        return self.kernel.with_theta(best.x)

    def _check_fitted(self) -> None:
        """Raise NotFittedError before ``fit``."""
        if not hasattr(self, "estimators_"):
            msg = "OneVsAllGPC is not fitted; call fit(X, y) first"
            raise NotFittedError(msg)

    def predict_binary(self, X: npt.ArrayLike) -> FloatArray:
        """Each class's own one-vs-all probability (not normalised), shape (m, k)."""
        self._check_fitted()
        Xs = np.asarray(X, dtype=np.float64)
        latents = [e.latent(Xs) for e in self.estimators_]  # one probability call for all
        mean = np.concatenate([m for m, _ in latents])
        var = np.concatenate([v for _, v in latents])
        return predictive_probability(mean, var).reshape(len(latents), -1).T

    def predict_proba(self, X: npt.ArrayLike) -> FloatArray:
        """Probabilities normalised over the classes, shape (m, k), rows sum to 1."""
        return normalise(self.predict_binary(X))

    def predict(self, X: npt.ArrayLike) -> IntArray:
        """Most probable class label, shape (m,)."""
        return np.asarray(self.classes_[np.argmax(self.predict_binary(X), axis=1)])

    def score(self, X: npt.ArrayLike, y: npt.ArrayLike) -> float:
        """Accuracy on ``(X, y)``."""
        return float(np.mean(self.predict(X) == np.asarray(y).reshape(-1)))


def normalise(p: FloatArray) -> FloatArray:
    """Normalise one-vs-all probabilities over the classes (rows sum to 1).

    Args:
        p: Shape (m, k) probabilities in [0, 1].

    Returns:
        Shape (m, k); a row of zeros becomes uniform.
    """
    total = p.sum(axis=1, keepdims=True)
    uniform = np.full_like(p, 1.0 / p.shape[1])
    return np.asarray(np.divide(p, total, out=uniform, where=total > 0), dtype=np.float64)


NOISE_PRIOR_SD: Final = 0.5
"""Prior sd of the modality-weight logits around the declared-noise centre (MultiModalGPC)."""


class MultiModalGPC:
    """One action's object classifier over a chosen subset of modalities (fusion study).

    Fits a :class:`FeatureTransformer` and a :class:`OneVsAllGPC` with the multi-modal kernel
    on the training observations; test observations go through the same fitted transformer.

    ``selection`` decides how the modalities are combined:

    - ``"fused"``: the weighted-sum kernel of all modalities (the thesis's multi-modal kernel;
      weights learned by the marginal likelihood);
    - ``"evidence"``: the fused model and one model per single modality are fitted, and each
      class's binary classifier is the one with the largest approximate log marginal
      likelihood among them (Bayesian model selection between the fused and the
      single-modality models, per one-vs-all classifier);
    - ``"evidence-all"``: the same, one choice for all classes (the sum of their log marginal
      likelihoods).

    Args:
        modalities: Modalities to use (e.g. ``["force"]``, ``["thermal"]``); None = all of
            the action kind.
        n_thermal_components: Thermal PCA dimensions.
        amplitude: Learn a signal variance (False: the thesis kernel).
        selection: ``"fused"``, ``"evidence"`` or ``"evidence-all"`` (see above); without a
            second modality every choice is the fused model.
        shared: One set of hyperparameters for all classes (see :class:`OneVsAllGPC`); False
            fits each class's own (the earlier behaviour).
        prior_sd: Gaussian prior on the log hyperparameters around the initial kernel (see
            :class:`BinaryGPC`); None: maximum likelihood.
        initial_theta: Log hyperparameters of the fused kernel to start from (and, with
            ``prior_sd``, the prior's centre), e.g. ``theta_`` of a model fitted on other
            objects of the same action: an empirical-Bayes prior over the modality weights
            and length scales. None: the default kernel (equal weights, unit length scales).
        sensor_noise: Declared noise (sd of one sample, the sensor's units) of the sensor
            each feature block comes from, e.g. ``{"force": 0.05, "thermal": 0.03125}``. Used
            when ``initial_theta`` is None and the kernel is a weighted sum: the modality
            weights start from, and get a Gaussian prior of sd ``noise_sd`` around, the
            logits of :func:`atikt.noise.noise_logits` (weights proportional to each block's
            spread over the training observations relative to its declared noise); the
            other hyperparameters keep no prior (or ``prior_sd`` around the default). None:
            no such prior.
        noise_sd: Prior sd of the logits around the declared-noise centre.
        controlled: Feature blocks the action itself sets (e.g. ``("force",)`` for a
            force-controlled press): their spread counts as the controller's, signal-to-noise
            1 (see :func:`atikt.noise.noise_logits`); used with ``sensor_noise``.
        combination: ``"sum"`` (the weighted sum, the thesis) or ``"product"`` of the
            per-modality kernels (``atikt.kernels.COMBINATIONS``).
        parts: Kernel of each modality (``atikt.kernels.PART_KERNELS``; RBF where not named).
        n_restarts: Random restarts per binary classifier.
        max_iter: Iteration limit of the hyperparameter search per start.
        random_state: Seed of the restarts.

    Attributes:
        theta_: Fitted log hyperparameters of the fused kernel (shared over classes; with
            ``shared=False`` those of the first class).
        transformer_: The fitted feature transformer.
        model_: The fitted one-vs-all classifier (its binary classifiers may use different
            kernels with ``selection="evidence"``).
        classes_: Class labels.
        selected_: Per class, the modalities of the chosen kernel (all of them: fused).
    """

    def __init__(
        self,
        modalities: Sequence[str] | None = None,
        *,
        n_thermal_components: int = 10,
        amplitude: bool = True,
        selection: Selection = "fused",
        shared: bool = True,
        prior_sd: float | None = None,
        initial_theta: npt.ArrayLike | None = None,
        sensor_noise: Mapping[str, float] | None = None,
        noise_sd: float = NOISE_PRIOR_SD,
        controlled: Sequence[str] = (),
        combination: str = "sum",
        parts: Mapping[str, str] | None = None,
        n_restarts: int = 1,
        max_iter: int = 50,
        random_state: RandomState = None,
    ) -> None:
        """Store the parameters; see the class docstring."""
        self.sensor_noise = sensor_noise
        self.noise_sd = noise_sd
        self.controlled = controlled
        self.combination = combination
        self.parts = parts
        self.modalities = modalities
        self.n_thermal_components = n_thermal_components
        self.amplitude = amplitude
        self.selection = selection
        self.shared = shared
        self.prior_sd = prior_sd
        self.initial_theta = initial_theta
        self.n_restarts = n_restarts
        self.max_iter = max_iter
        self.random_state = random_state

    def fit(self, observations: Sequence[RawFeatures], labels: npt.ArrayLike) -> Self:
        """Fit on training observations of one action and their object labels.

        Returns:
            self.

        Raises:
            AtiktError: Unknown ``selection``, or malformed observations or labels.
        """
        if self.selection not in SELECTIONS:
            msg = f"selection={self.selection!r}; use one of {SELECTIONS}"
            raise AtiktError(msg)
        self.transformer_ = FeatureTransformer(self.modalities, self.n_thermal_components)
        X = self.transformer_.fit_transform(observations)
        slices = self.transformer_.slices_
        fused: Kernel = fusion_kernel(
            slices, combination=self.combination, parts=self.parts, amplitude=self.amplitude
        )
        prior_sd: float | FloatArray | None = self.prior_sd
        if self.initial_theta is None and self.sensor_noise is not None:
            fused, prior_sd = self._noise_prior(fused, observations)
        if self.initial_theta is not None:
            theta = np.asarray(self.initial_theta, dtype=np.float64)
            if theta.shape != fused.theta.shape or not np.all(np.isfinite(theta)):
                msg = (
                    f"initial_theta of shape {theta.shape}: the kernel of {list(slices)} has "
                    f"{fused.theta.shape[0]} finite log hyperparameters"
                )
                raise AtiktError(msg)
            fused = fused.with_theta(np.clip(theta, fused.bounds[:, 0], fused.bounds[:, 1]))
        candidates: dict[tuple[str, ...], tuple[Kernel, float | FloatArray | None]] = {
            tuple(slices): (fused, prior_sd)
        }
        if self.selection != "fused" and len(slices) > 1:
            candidates |= {
                (name,): (modality_kernel({name: cols}, amplitude=self.amplitude), self.prior_sd)
                for name, cols in slices.items()
            }
        fitted = {
            names: OneVsAllGPC(
                kernel,
                n_restarts=self.n_restarts,
                max_iter=self.max_iter,
                shared=self.shared,
                prior_sd=sd,
                random_state=self.random_state,
            ).fit(X, labels)
            for names, (kernel, sd) in candidates.items()
        }
        self.theta_ = fitted[tuple(slices)].estimators_[0].kernel_.theta.copy()
        self.model_, self.selected_ = _select_by_evidence(
            fitted, per_class=self.selection != "evidence-all"
        )
        self.classes_ = self.model_.classes_
        return self

    def _noise_prior(
        self, kernel: Kernel, observations: Sequence[RawFeatures]
    ) -> tuple[Kernel, float | FloatArray | None]:
        """Return the kernel with its logits at the declared-noise centre, and the prior sds.

        A weighted sum gets its logits there; a product its parts' length scales
        (:func:`atikt.noise.noise_length_scales`); any other kernel, or no declared noise, is
        returned unchanged with ``prior_sd``.
        """
        noise = self.sensor_noise or {}
        product = isinstance(kernel, ProductKernel)
        if not isinstance(kernel, ModalityKernel | ProductKernel) or len(kernel.parts) < 2:  # noqa: PLR2004
            return kernel, self.prior_sd
        blocks = stack_features(observations).blocks
        modalities = kernel.modalities
        declared = {
            m: feature_noise(m, blocks[m].shape[1], noise[m]) for m in modalities if m in noise
        }
        box = kernel.logit_bounds if isinstance(kernel, ModalityKernel) else DEFAULT_LOGIT_BOUNDS
        logits = noise_logits(blocks, declared, modalities, box, controlled=self.controlled)
        if logits is None:
            return kernel, self.prior_sd
        theta = kernel.theta
        default = np.inf if self.prior_sd is None else self.prior_sd
        sds = np.full(theta.shape, default)
        if product:  # the parts' length scales, one each, lead theta
            n = len(kernel.parts)
            theta[:n] = noise_length_scales(logits, kernel.bounds[:n])
            sds[:n] = self.noise_sd
            return kernel.with_theta(theta), sds
        n_part = sum(p.n_params for p in kernel.parts)
        theta[n_part : n_part + logits.shape[0]] = logits
        sds[n_part : n_part + logits.shape[0]] = self.noise_sd
        return kernel.with_theta(theta), sds

    def _features(self, observations: Sequence[RawFeatures]) -> FloatArray:
        """Transform test observations with the training statistics."""
        if not hasattr(self, "model_"):
            msg = "MultiModalGPC is not fitted; call fit(observations, labels) first"
            raise NotFittedError(msg)
        return self.transformer_.transform(observations)

    def predict_proba(self, observations: Sequence[RawFeatures]) -> FloatArray:
        """Probabilities over the classes, shape (m, k)."""
        X = self._features(observations)
        return self.model_.predict_proba(X)

    def predict(self, observations: Sequence[RawFeatures]) -> IntArray:
        """Most probable class label, shape (m,)."""
        X = self._features(observations)
        return self.model_.predict(X)

    def score(self, observations: Sequence[RawFeatures], labels: npt.ArrayLike) -> float:
        """Accuracy on test observations."""
        X = self._features(observations)
        return self.model_.score(X, labels)


def _select_by_evidence(
    fitted: Mapping[tuple[str, ...], OneVsAllGPC], *, per_class: bool
) -> tuple[OneVsAllGPC, tuple[tuple[str, ...], ...]]:
    """Return the one-vs-all model of the largest log marginal likelihood, and its kernels.

    Args:
        fitted: Modalities of a kernel -> the one-vs-all model fitted with it (same data).
        per_class: Choose each class's binary classifier separately (else one choice for all,
            by the sum over classes).

    Returns:
        The chosen model and, per class, the modalities of its kernel.
    """
    names = list(fitted)
    lml = np.array(
        [[e.log_marginal_likelihood_value_ for e in fitted[n].estimators_] for n in names]
    )  # (n_candidates, n_classes)
    if per_class:
        best = np.argmax(lml, axis=0)
    else:
        best = np.full(lml.shape[1], int(np.argmax(lml.sum(axis=1))))
    first = fitted[names[0]]
    model = copy.copy(first)
    model.estimators_ = [fitted[names[b]].estimators_[c] for c, b in enumerate(best)]
    return model, tuple(names[b] for b in best)
