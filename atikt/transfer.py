"""Instance knowledge transfer from old objects to a new object's classifier.

Feng, Kaboli & Cheng, "Active tactile instance knowledge transfer" (TUM 2017): per action and
new object, the observations of the most related old object join the new object's binary
(one-vs-all) classifier as auxiliary positives through the dependent kernel
``[[K(Xo, Xo), rho K(Xo, Xn)], [rho K(Xn, Xo), K(Xn, Xn)]]``.

*Where from and how much* is decided by one of two approaches:

- model prediction (:func:`choose_by_prediction`): the old objects' one-vs-all models predict
  the new object's observations; the old object with the largest mean probability is the
  source and ``rho`` is that mean, transferred only if ``rho >= eps_neg1`` (> 0.5, otherwise an
  old object that is merely "not rejected" would count as related);
- model optimisation (:func:`choose_by_optimization`): for every old object, ``rho`` is learned
  with the other hyperparameters by maximising the log marginal likelihood; the largest ``rho``
  wins if it is ``>= eps_neg2``.

Without a source (or with ``rho = 0``) the classifier is exactly the plain :class:`BinaryGPC` on
the new objects' observations.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Final, Self

import numpy as np
import numpy.typing as npt

from atikt.errors import AtiktError, NotFittedError
from atikt.gpc import BinaryGPC, OneVsAllGPC, RandomState, predictive_probability
from atikt.kernels import DEFAULT_RHO_BOUNDS, DependentKernel, Kernel, ModalityKernel

FloatArray = npt.NDArray[np.float64]

OLD_DOMAIN: Final = 0.0
"""Domain flag of auxiliary (old-object) observations."""
NEW_DOMAIN: Final = 1.0
"""Domain flag of the new objects' observations."""


def with_domain(X: npt.ArrayLike, flag: float) -> FloatArray:
    """Append the domain flag column to ``X`` (n, d) -> (n, d + 1)."""
    Xa = np.asarray(X, dtype=np.float64)
    return np.hstack([Xa, np.full((Xa.shape[0], 1), flag)])


def _stack_domains(X_old: FloatArray, X_new: FloatArray) -> FloatArray:
    """``[with_domain(X_old, OLD_DOMAIN); with_domain(X_new, NEW_DOMAIN)]`` in one array."""
    n_old, d = X_old.shape
    out = np.empty((n_old + X_new.shape[0], d + 1))
    out[:n_old, :d], out[:n_old, d] = X_old, OLD_DOMAIN
    out[n_old:, :d], out[n_old:, d] = X_new, NEW_DOMAIN
    return out


def _added_start(known: FloatArray, y: FloatArray) -> FloatArray:
    """Starting latent values of the observations after the ``len(known)`` earlier ones.

    Each starts at the mean of ``known`` over the earlier observations with its label (0 when
    there are none).
    """
    earlier, added = y[: known.shape[0]], y[known.shape[0] :]
    start = np.zeros(added.shape[0])
    for label in (0.0, 1.0):
        same = earlier == label
        if same.any():
            start[added == label] = known[same].mean()
    return start


class TransferGPC:
    """Binary classifier of one new object with optional auxiliary positives from an old one.

    Args:
        kernel: The base (multi-modal) kernel; its ``theta`` is the first starting point.
        rho: Transfer coefficient in [0, 1] when it is fixed (model prediction approach);
            the starting value when ``learn_rho``.
        learn_rho: Learn ``rho`` by the marginal likelihood (model optimisation approach).
        rho_bounds: Box of a learned ``rho``.
        optimize: False keeps all hyperparameters.
        n_restarts: Additional random starts of the hyperparameter search.
        max_iter: Iteration limit of the hyperparameter search per start.
        previous: A fitted classifier of the same object whose new-object observations were
            the first ones of this fit's (the previous update of active learning): its search
            curvature and Laplace mode start this fit's search (see :class:`BinaryGPC`'s
            ``inverse_hessian`` and ``mode_start``); only the cost depends on it. Released
            by :meth:`fit`.
        jitter: Diagonal jitter.
        random_state: Seed of the restarts.

    Attributes:
        estimator_: The fitted :class:`BinaryGPC` (on ``[X_aux; X]`` with the domain column when
            transferring, on ``X`` alone otherwise).
        transferred_: Whether auxiliary data were used.
        rho_: The transfer coefficient used (0 when not transferring).
        base_kernel_: The fitted base kernel (for weights and warm starts).
        n_auxiliary_: Auxiliary observations used (0 when not transferring).
    """

    def __init__(
        self,
        kernel: ModalityKernel,
        *,
        rho: float = 0.0,
        learn_rho: bool = False,
        rho_bounds: tuple[float, float] = DEFAULT_RHO_BOUNDS,
        optimize: bool = True,
        n_restarts: int = 0,
        max_iter: int = 50,
        previous: TransferGPC | None = None,
        jitter: float = 1e-10,
        random_state: RandomState = None,
    ) -> None:
        """Store the parameters; see the class docstring."""
        self.kernel = kernel
        self.previous = previous
        self.rho = rho
        self.learn_rho = learn_rho
        self.rho_bounds = rho_bounds
        self.optimize = optimize
        self.n_restarts = n_restarts
        self.max_iter = max_iter
        self.jitter = jitter
        self.random_state = random_state

    def _estimator(self, kernel: Kernel, n_aux: int, yn: FloatArray) -> BinaryGPC:
        """Return an unfitted binary classifier with this object's settings and warm start.

        The previous fit's mode starts the Newton search at its own observations; an added
        observation starts at the mean mode of the earlier observations with its label (a
        start only: the mode found does not depend on it).
        """
        inverse_hessian, mode_start = None, None
        # the warm start is consumed here, not kept: every fit would otherwise hold the whole
        # chain of earlier fits (and their covariances) alive
        previous, self.previous = self.previous, None
        if previous is not None and hasattr(previous, "estimator_"):
            inverse_hessian = previous.estimator_.inverse_hessian_
            f = previous.estimator_.mode_.f
            n_prev_aux = previous.n_auxiliary_
            aux_start = f[:n_prev_aux] if n_prev_aux == n_aux else np.zeros(n_aux)
            known = f[n_prev_aux:]
            if known.shape[0] <= yn.shape[0]:
                known = np.concatenate([known, _added_start(known, yn)])
            mode_start = np.concatenate([aux_start, known])
        return BinaryGPC(
            kernel,
            optimize=self.optimize,
            n_restarts=self.n_restarts,
            max_iter=self.max_iter,
            inverse_hessian=inverse_hessian,
            mode_start=mode_start,
            jitter=self.jitter,
            random_state=self.random_state,
        )

    def fit(self, X: npt.ArrayLike, y: npt.ArrayLike, X_aux: npt.ArrayLike | None = None) -> Self:
        """Fit on the new objects' observations and optional auxiliary positives.

        Args:
            X: New objects' observations of one action, shape (n, d).
            y: 1 for the new object this classifier recognises, 0 for the others, shape (n,).
            X_aux: The source old object's observations, shape (n_aux, d), all positives;
                None or empty for no transfer.

        Returns:
            self.

        Raises:
            AtiktError: ``rho`` outside [0, 1] or mismatched widths.
        """
        if not 0.0 <= self.rho <= 1.0:
            msg = f"rho={self.rho}; the transfer coefficient must lie in [0, 1]"
            raise AtiktError(msg)
        Xn = np.asarray(X, dtype=np.float64)
        yn = np.asarray(y, dtype=np.float64).reshape(-1)
        aux = None if X_aux is None else np.asarray(X_aux, dtype=np.float64)
        self.transferred_ = aux is not None and aux.shape[0] > 0
        self.transferred_ &= self.learn_rho or self.rho > 0.0
        if not self.transferred_ or aux is None:
            self.estimator_ = self._estimator(self.kernel, 0, yn).fit(Xn, yn)
            self.rho_, self.n_auxiliary_ = 0.0, 0
            self.base_kernel_ = self.estimator_.kernel_
            return self
        if aux.ndim != 2 or aux.shape[1] != Xn.shape[1]:  # noqa: PLR2004
            msg = f"X_aux has shape {aux.shape}; it needs the {Xn.shape[1]} columns of X"
            raise AtiktError(msg)
        rho0 = (
            min(max(self.rho, self.rho_bounds[0]), self.rho_bounds[1])
            if self.learn_rho
            else self.rho
        )
        dependent = DependentKernel(
            self.kernel, rho0, self.rho_bounds if self.learn_rho else "fixed"
        )
        X_all = _stack_domains(aux, Xn)
        y_all = np.concatenate([np.ones(aux.shape[0]), yn])
        self.estimator_ = self._estimator(dependent, aux.shape[0], yn).fit(X_all, y_all)
        self.n_auxiliary_ = aux.shape[0]
        fitted = self.estimator_.kernel_
        assert isinstance(fitted, DependentKernel)  # noqa: S101 - built just above
        self.rho_ = fitted.rho
        self.base_kernel_ = fitted.base
        return self

    def predict_positive(self, X: npt.ArrayLike) -> FloatArray:
        """Probability that new-domain observations ``X`` (m, d) show this object, shape (m,)."""
        if not hasattr(self, "estimator_"):
            msg = "TransferGPC is not fitted; call fit(X, y, X_aux) first"
            raise NotFittedError(msg)
        Xs = with_domain(X, NEW_DOMAIN) if self.transferred_ else np.asarray(X, np.float64)
        return self.estimator_.predict_positive(Xs)

    def training_positive(self) -> FloatArray:
        """Probability of this object at its own new-object training observations, shape (n,).

        Equals ``predict_positive(X)`` of the ``X`` given to :meth:`fit`, without evaluating the
        kernel again (see :meth:`BinaryGPC.training_latent`).
        """
        return predictive_probability(*self.training_latent())

    def training_latent(self) -> tuple[FloatArray, FloatArray]:
        """Latent mean and variance at its own new-object training observations, each (n,).

        See :meth:`training_positive`.
        """
        if not hasattr(self, "estimator_"):
            msg = "TransferGPC is not fitted; call fit(X, y, X_aux) first"
            raise NotFittedError(msg)
        return self.estimator_.training_latent(slice(self.n_auxiliary_, None))

    def predict_proba(self, X: npt.ArrayLike) -> FloatArray:
        """Class probabilities ``[p(other), p(this object)]``, shape (m, 2)."""
        p = self.predict_positive(X)
        return np.column_stack([1.0 - p, p])


@dataclass(frozen=True, slots=True)
class PriorChoice:
    """Where from and how much to transfer for one (action, new object).

    Attributes:
        source: The chosen old object's label, None when nothing is transferred.
        rho: Transfer coefficient (0 when nothing is transferred).
        candidates: Old-object labels, in the order of ``scores``.
        scores: Relatedness of each candidate: mean predicted probability (model prediction)
            or learned rho (model optimisation).
    """

    source: int | None
    rho: float
    candidates: tuple[int, ...]
    scores: tuple[float, ...]


def relatedness(old_model: OneVsAllGPC, X: npt.ArrayLike) -> FloatArray:
    """Mean probability, per old object, that the new object's observations are that object.

    Args:
        old_model: The old objects' one-vs-all models of this action.
        X: The new object's observations in the old model's feature space, shape (m, d).

    Returns:
        Shape (n_old,): each old object's own (not normalised) one-vs-all probability,
        averaged over the observations.
    """
    return np.asarray(old_model.predict_binary(X).mean(axis=0), dtype=np.float64)


def check_threshold(name: str, eps: float, *, low: float = 0.5) -> float:
    """Validate a negative-transfer threshold: it must lie in ``(low, 1]``.

    Raises:
        AtiktError: The threshold is out of range.
    """
    if not low < eps <= 1.0:
        msg = f"{name}={eps}; this transfer threshold must lie in ({low}, 1]"
        raise AtiktError(msg)
    return eps


def choose_by_prediction(
    old_model: OneVsAllGPC, X: npt.ArrayLike, eps_neg1: float = 0.6
) -> PriorChoice:
    """Choose the source old object by the old models' predictions (model prediction approach).

    Args:
        old_model: The old objects' one-vs-all models of this action.
        X: The new object's observations in the old model's feature space, shape (m, d).
        eps_neg1: Minimum mean probability for a transfer, in (0.5, 1].

    Returns:
        The most related old object and ``rho`` = its mean probability, or no source when that
        probability is below ``eps_neg1``.
    """
    return choose_by_relatedness(relatedness(old_model, X), old_model.classes_, eps_neg1)


def choose_by_relatedness(
    scores: npt.ArrayLike, classes: npt.ArrayLike, eps_neg1: float = 0.6
) -> PriorChoice:
    """:func:`choose_by_prediction` from the :func:`relatedness` scores already computed.

    Args:
        scores: Mean probability of each old object, shape (n_old,).
        classes: The old objects' labels, in the order of ``scores``.
        eps_neg1: Minimum mean probability for a transfer, in (0.5, 1].

    Returns:
        The choice (see :func:`choose_by_prediction`).
    """
    check_threshold("eps_neg1", eps_neg1)
    scores = np.asarray(scores, dtype=np.float64).reshape(-1)
    candidates = tuple(int(c) for c in np.asarray(classes).reshape(-1))
    if len(candidates) != scores.shape[0] or not candidates:
        msg = f"{scores.shape[0]} relatedness scores for old objects {candidates}"
        raise AtiktError(msg)
    best = int(np.argmax(scores))
    rho = float(scores[best])
    if rho < eps_neg1:
        return PriorChoice(None, 0.0, candidates, tuple(float(s) for s in scores))
    return PriorChoice(candidates[best], rho, candidates, tuple(float(s) for s in scores))


def choose_by_optimization(
    kernel: ModalityKernel,
    X: npt.ArrayLike,
    y: npt.ArrayLike,
    auxiliary: Mapping[int, npt.ArrayLike],
    *,
    eps_neg2: float = 0.6,
    rho0: float | Mapping[int, float] = 0.5,
    n_restarts: int = 0,
    max_iter: int = 50,
    random_state: RandomState = None,
) -> tuple[PriorChoice, TransferGPC]:
    """Choose the source old object by learned ``rho`` (model optimisation approach).

    For every old object, a :class:`TransferGPC` with ``learn_rho`` is fitted; the largest
    learned ``rho`` wins if it is ``>= eps_neg2``, otherwise the plain classifier is returned.

    Args:
        kernel: Base kernel (starting hyperparameters).
        X: New objects' observations of the action, shape (n, d).
        y: 1 for the new object of interest, 0 otherwise, shape (n,).
        auxiliary: Old-object label -> its observations (n_aux, d) in the same feature space.
        eps_neg2: Minimum learned ``rho`` for a transfer, in (0, 1].
        rho0: Starting ``rho`` of every search, or per old object (warm start; 0.5 for the
            old objects it does not name).
        n_restarts: Additional random starts per search.
        max_iter: Iteration limit of each hyperparameter search per start.
        random_state: Seed of the restarts.

    Returns:
        The choice and the classifier to use (with transfer, or plain).
    """
    check_threshold("eps_neg2", eps_neg2, low=0.0)
    starts = rho0 if isinstance(rho0, Mapping) else dict.fromkeys(auxiliary, rho0)
    fitted = {
        label: TransferGPC(
            kernel,
            rho=starts.get(label, 0.5),
            learn_rho=True,
            n_restarts=n_restarts,
            max_iter=max_iter,
            random_state=random_state,
        ).fit(X, y, aux)
        for label, aux in auxiliary.items()
    }
    candidates = tuple(fitted)
    scores = tuple(fitted[c].rho_ for c in candidates)
    if candidates and max(scores) >= eps_neg2:
        best = candidates[int(np.argmax(scores))]
        return PriorChoice(best, fitted[best].rho_, candidates, scores), fitted[best]
    plain = TransferGPC(
        kernel, n_restarts=n_restarts, max_iter=max_iter, random_state=random_state
    ).fit(X, y)
    return PriorChoice(None, 0.0, candidates, scores), plain
