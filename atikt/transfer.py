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

A third, open-set estimate does not depend on how many old objects there are
(:class:`ObjectDensities`, :func:`choose_by_density`): each old object's own feature
distribution (a diagonal Gaussian, its variances shrunk towards the pooled within-object
variance) asks whether the new object's observations are typical draws of it, by the tail
probability of their squared Mahalanobis distance (chi-square); the score of an old object is
the mean tail probability (0.5 for draws of its own distribution, ~0 for a different object),
unaffected by the other old objects.

Without a source (or with ``rho = 0``) the classifier is exactly the plain :class:`BinaryGPC` on
the new objects' observations.

Old objects' observations of *another* action, or recorded by *another* rig, become priors of
an action through :func:`shared_observations`: the feature blocks both have (same feature
definition, e.g. the stiffness block of a press and of a static contact, or the thermal block
of a 7-cell skin and of a heated probe), relabelled with the action's kind. Relatedness then
decides, as for the action's own priors, whether and how much they are transferred.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Final, Self

import numpy as np
import numpy.typing as npt
from scipy.special import chdtrc  # chi2.sf itself; scipy.stats takes ~1 s to import

from atikt.errors import AtiktError, NotFittedError
from atikt.features import RawFeatures
from atikt.gpc import BinaryGPC, OneVsAllGPC, RandomState, predictive_probability
from atikt.kernels import (
    DEFAULT_RHO_BOUNDS,
    Bounds,
    DependentKernel,
    Kernel,
    ModalityKernel,
    MultiSourceKernel,
)

FloatArray = npt.NDArray[np.float64]

OLD_DOMAIN: Final = 0.0
"""Domain flag of auxiliary (old-object) observations."""
NEW_DOMAIN: Final = 1.0
"""Domain flag of the new objects' observations."""


def with_domain(X: npt.ArrayLike, flag: float) -> FloatArray:
    """Append the domain flag column to ``X`` (n, d) -> (n, d + 1)."""
    Xa = np.asarray(X, dtype=np.float64)
    return np.hstack([Xa, np.full((Xa.shape[0], 1), flag)])


def shared_observations(
    observations: Sequence[RawFeatures], kind: str, blocks: Sequence[str]
) -> tuple[RawFeatures, ...]:
    """Observations of another action or rig as observations of ``kind`` with ``blocks``.

    Cross-action and cross-rig transfer: an old object's observations of action B (or of
    another rig's action) serve as prior observations of action A through the feature blocks
    A uses, which B must have with the same definition and length (e.g. stiffness from a
    press P1 for a static contact C1, texture from slide S1 for slide S3, the thermal block
    of a 7-cell skin for a heated probe). Nothing else changes: the prior model of A is then
    fitted on them and relatedness decides whether they are transferred.

    Args:
        observations: The source observations (one action's, of any kind).
        kind: The kind of the action they are to serve (its observations' ``kind``).
        blocks: The feature blocks that action's observations have.

    Returns:
        One observation per source observation, with ``kind`` and exactly ``blocks``.

    Raises:
        AtiktError: A source observation lacks one of ``blocks``.
    """
    shared = []
    for obs in observations:
        missing = [b for b in blocks if b not in obs.blocks]
        if missing:
            msg = (
                f"a {obs.kind!r} observation has no {missing} features, the {kind!r} action "
                f"uses {list(blocks)}; borrow from an action (or rig) that has them"
            )
            raise AtiktError(msg)
        shared.append(RawFeatures(kind, MappingProxyType({b: obs.blocks[b] for b in blocks})))
    return tuple(shared)


def _stack_domains(X_old: FloatArray, X_new: FloatArray) -> FloatArray:
    """``[with_domain(X_old, OLD_DOMAIN); with_domain(X_new, NEW_DOMAIN)]`` in one array."""
    n_old, d = X_old.shape
    out = np.empty((n_old + X_new.shape[0], d + 1))
    out[:n_old, :d], out[:n_old, d] = X_old, OLD_DOMAIN
    out[n_old:, :d], out[n_old:, d] = X_new, NEW_DOMAIN
    return out


def _stack_sources(sources: Sequence[FloatArray], X_new: FloatArray) -> FloatArray:
    """Stack sources and new observations with flags ``-j`` (source j) and 1 (new object)."""
    parts = [with_domain(S, -float(j)) for j, S in enumerate(sources)]
    return np.vstack([*parts, with_domain(X_new, NEW_DOMAIN)])


def _added_start(known: FloatArray, y: FloatArray) -> FloatArray:
    """Starting latent values of the observations after the ``len(known)`` earlier ones.

    Each starts at the mean of ``known`` over the earlier observations with its label (0 when
    there are none).
    """
    earlier, added = y[: known.shape[0]], y[known.shape[0] :]
    start = np.zeros(added.shape[0])
    for label in (0.0, 1.0):
        mine = added == label
        if not mine.any():  # usually one observation is added: one label to fill
            continue
        same = earlier == label
        count = int(same.sum())
        if count:  # the mean (ndarray.mean is this sum over the count, behind a wrapper)
            start[mine] = known[same].sum() / count
    return start


class TransferGPC:
    """Binary classifier of one new object with optional auxiliary positives from an old one.

    With several sources (``X_aux`` a sequence of arrays, ``rho`` one value per source), the
    kernel is the :class:`~atikt.kernels.MultiSourceKernel`: one ``rho_j`` per old object, PSD
    by construction; with one source it is the thesis's dependent kernel.

    Args:
        kernel: The base (multi-modal) kernel; its ``theta`` is the first starting point.
        rho: Transfer coefficient in [0, 1] when it is fixed (model prediction approach);
            the starting value when ``learn_rho``. A sequence: one per source.
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
        prior_sd: Standard deviation of a Gaussian prior on every log hyperparameter (maximum
            a posteriori); None: maximum likelihood (the thesis). A learned ``rho`` gets the
            same prior around its start.
        prior_mean: The prior's centre for the base kernel's log hyperparameters; None:
            ``kernel.theta``.
        random_state: Seed of the restarts.

    Attributes:
        estimator_: The fitted :class:`BinaryGPC` (on ``[X_aux; X]`` with the domain column when
            transferring, on ``X`` alone otherwise).
        transferred_: Whether auxiliary data were used.
        rho_: The transfer coefficient used (0 when not transferring; the first source's with
            several).
        rhos_: The transfer coefficient of every source used, shape (n_sources,).
        base_kernel_: The fitted base kernel (for weights and warm starts).
        n_auxiliary_: Auxiliary observations used (0 when not transferring).
    """

    def __init__(
        self,
        kernel: ModalityKernel,
        *,
        rho: float | Sequence[float] = 0.0,
        learn_rho: bool = False,
        rho_bounds: tuple[float, float] = DEFAULT_RHO_BOUNDS,
        optimize: bool = True,
        n_restarts: int = 0,
        max_iter: int = 50,
        previous: TransferGPC | None = None,
        jitter: float = 1e-10,
        prior_sd: float | None = None,
        prior_mean: FloatArray | None = None,
        random_state: RandomState = None,
    ) -> None:
        """Store the parameters; see the class docstring."""
        self.kernel = kernel
        self.prior_sd = prior_sd
        self.prior_mean = prior_mean
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
        prior_mean = None
        if self.prior_sd is not None:  # the base kernel's centre, then a learned rho's start
            centre = self.kernel.theta if self.prior_mean is None else self.prior_mean
            prior_mean = np.concatenate([centre, kernel.theta[centre.shape[0] :]])
        return BinaryGPC(
            kernel,
            optimize=self.optimize,
            n_restarts=self.n_restarts,
            max_iter=self.max_iter,
            inverse_hessian=inverse_hessian,
            mode_start=mode_start,
            jitter=self.jitter,
            prior_sd=self.prior_sd,
            prior_mean=prior_mean,
            random_state=self.random_state,
        )

    def fit(
        self,
        X: npt.ArrayLike,
        y: npt.ArrayLike,
        X_aux: npt.ArrayLike | Sequence[npt.ArrayLike] | None = None,
    ) -> Self:
        """Fit on the new objects' observations and optional auxiliary positives.

        Args:
            X: New objects' observations of one action, shape (n, d).
            y: 1 for the new object this classifier recognises, 0 for the others, shape (n,).
            X_aux: The source old object's observations, shape (n_aux, d), all positives;
                or a sequence of such arrays, one per source (with one ``rho`` each); None
                or empty for no transfer.

        Returns:
            self.

        Raises:
            AtiktError: ``rho`` outside [0, 1], one ``rho`` per source missing, or mismatched
                widths.
        """
        Xn = np.asarray(X, dtype=np.float64)
        yn = np.asarray(y, dtype=np.float64).reshape(-1)
        sources, rhos = self._sources(X_aux, Xn.shape[1])
        self.transferred_ = bool(sources) and (self.learn_rho or bool((rhos > 0.0).any()))
        if not self.transferred_:
            self.estimator_ = self._estimator(self.kernel, 0, yn).fit(Xn, yn)
            self.rho_, self.rhos_, self.n_auxiliary_ = 0.0, np.zeros(0), 0
            self.base_kernel_ = self.estimator_.kernel_
            return self
        if self.learn_rho:
            rhos = np.clip(rhos, self.rho_bounds[0], self.rho_bounds[1])
        bounds: Bounds = self.rho_bounds if self.learn_rho else "fixed"
        kernel: DependentKernel | MultiSourceKernel
        if len(sources) == 1:
            kernel = DependentKernel(self.kernel, float(rhos[0]), bounds)
            X_all = _stack_domains(sources[0], Xn)
        else:
            kernel = MultiSourceKernel(self.kernel, rhos, bounds)
            X_all = _stack_sources(sources, Xn)
        n_aux = sum(S.shape[0] for S in sources)
        y_all = np.concatenate([np.ones(n_aux), yn])
        self.estimator_ = self._estimator(kernel, n_aux, yn).fit(X_all, y_all)
        self.n_auxiliary_ = n_aux
        fitted = self.estimator_.kernel_
        assert isinstance(fitted, DependentKernel | MultiSourceKernel)  # noqa: S101 - built above
        self.rhos_ = (
            np.array([fitted.rho]) if isinstance(fitted, DependentKernel) else fitted.rhos.copy()
        )
        self.rho_ = float(self.rhos_[0])
        self.base_kernel_ = fitted.base
        return self

    def _sources(
        self, X_aux: npt.ArrayLike | Sequence[npt.ArrayLike] | None, width: int
    ) -> tuple[list[FloatArray], FloatArray]:
        """The non-empty source arrays and their ``rho`` values (checked).

        Raises:
            AtiktError: ``rho`` outside [0, 1], a count mismatch, or a wrong width.
        """
        rhos = np.asarray(self.rho, dtype=np.float64).reshape(-1)
        if not ((rhos >= 0.0) & (rhos <= 1.0)).all():
            msg = f"rho={self.rho}; the transfer coefficient must lie in [0, 1]"
            raise AtiktError(msg)
        if X_aux is None:
            return [], np.zeros(0)
        several = isinstance(X_aux, list | tuple) and all(np.ndim(a) == 2 for a in X_aux)  # noqa: PLR2004
        arrays = [np.asarray(a, dtype=np.float64) for a in (X_aux if several else [X_aux])]  # type: ignore[union-attr]
        if not arrays:
            return [], np.zeros(0)
        if len(arrays) != rhos.shape[0] and not (rhos.shape[0] == 1 and len(arrays) == 1):
            msg = f"{len(arrays)} sources and rho={self.rho}: give one rho per source"
            raise AtiktError(msg)
        for a in arrays:
            if a.size and (a.ndim != 2 or a.shape[1] != width):  # noqa: PLR2004
                msg = f"X_aux has shape {a.shape}; it needs the {width} columns of X"
                raise AtiktError(msg)
        keep = [i for i, a in enumerate(arrays) if a.shape[0] > 0]
        return [arrays[i] for i in keep], rhos[keep]

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
        scores: Relatedness of each candidate: mean predicted probability (model prediction),
            learned rho (model optimisation) or open-set score (density).
        sources: Every chosen old object, the most related first (``source`` alone, or
            several for multi-source transfer; empty when nothing is transferred).
        rhos: Their transfer coefficients, in the order of ``sources``.
    """

    source: int | None
    rho: float
    candidates: tuple[int, ...]
    scores: tuple[float, ...]
    sources: tuple[int, ...] = ()
    rhos: tuple[float, ...] = ()


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


def held_out_threshold(
    held_out: Sequence[FloatArray], eps: float, n: int, quantile: float
) -> float:
    """The relatedness a new object needs after ``n`` observations, calibrated on the old ones.

    One observation says little about relatedness: a one-vs-all classifier can give an object
    it has never seen 0.6-0.9 (its one-vs-all probabilities are not normalised). The old
    objects show how much: each old object left out (``held_out``, see
    :class:`atikt.priors.PriorModel`) is unrelated to the others whose mean probability over
    all its observations is below ``eps``; the scores those others reach from ``n`` of its
    observations (disjoint runs of ``n``) are what an unrelated prior scores by chance. A
    prior is admitted only above their ``quantile`` (and above ``eps``): with few
    observations, only when its score is one that unrelated known objects rarely reach.

    Args:
        held_out: Per old object, its observations' probabilities under the others' models.
        eps: The threshold by all observations (``eps_neg1``).
        n: The new object's observations of the action.
        quantile: Quantile of the chance scores, in (0, 1).

    Returns:
        The threshold, in [eps, 1]; ``eps`` when no old object is unrelated to the others.
    """
    chance: list[float] = []
    for probabilities in held_out:
        m = probabilities.shape[0]
        width = max(1, min(n, m))
        unrelated = probabilities.mean(axis=0) < eps
        if m == 0 or not unrelated.any():
            continue
        for start in range(0, m - width + 1, width):
            window = probabilities[start : start + width].mean(axis=0)
            chance.append(float(window[unrelated].max()))
    if not chance:
        return eps
    return min(1.0, max(eps, float(np.quantile(chance, quantile))))


def choose_by_relatedness(
    scores: npt.ArrayLike, classes: npt.ArrayLike, eps_neg1: float = 0.6, max_sources: int = 1
) -> PriorChoice:
    """:func:`choose_by_prediction` from the :func:`relatedness` scores already computed.

    Args:
        scores: Mean probability of each old object, shape (n_old,).
        classes: The old objects' labels, in the order of ``scores``.
        eps_neg1: Minimum mean probability for a transfer, in (0.5, 1].
        max_sources: Most old objects transferred at once (the most related ones that pass
            the threshold, each with ``rho`` = its score).

    Returns:
        The choice (see :func:`choose_by_prediction`).
    """
    check_threshold("eps_neg1", eps_neg1)
    return _choose(scores, classes, eps_neg1, max_sources, lambda v: v)


def _choose(
    scores: npt.ArrayLike,
    classes: npt.ArrayLike,
    eps: float,
    max_sources: int,
    to_rho: Callable[[float], float],
) -> PriorChoice:
    """The candidates of the largest scores that reach ``eps`` (at most ``max_sources``).

    Raises:
        AtiktError: Scores and classes disagree, or ``max_sources < 1``.
    """
    values = np.asarray(scores, dtype=np.float64).reshape(-1)
    candidates = tuple(int(c) for c in np.asarray(classes).reshape(-1))
    if len(candidates) != values.shape[0] or not candidates or max_sources < 1:
        msg = (
            f"{values.shape[0]} relatedness scores for old objects {candidates}, "
            f"max_sources={max_sources}: need one score per old object and max_sources >= 1"
        )
        raise AtiktError(msg)
    listed = tuple(float(v) for v in values)
    order = np.argsort(-values, kind="stable")[:max_sources]
    chosen = [int(i) for i in order if values[i] >= eps]
    if not chosen:
        return PriorChoice(None, 0.0, candidates, listed)
    sources = tuple(candidates[i] for i in chosen)
    rhos = tuple(to_rho(float(values[i])) for i in chosen)
    return PriorChoice(sources[0], rhos[0], candidates, listed, sources, rhos)


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
    prior_sd: float | None = None,
    prior_mean: FloatArray | None = None,
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
        prior_sd: See :class:`TransferGPC` (None: maximum likelihood).
        prior_mean: See :class:`TransferGPC`.
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
            prior_sd=prior_sd,
            prior_mean=prior_mean,
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
        kernel,
        n_restarts=n_restarts,
        max_iter=max_iter,
        prior_sd=prior_sd,
        prior_mean=prior_mean,
        random_state=random_state,
    ).fit(X, y)
    return PriorChoice(None, 0.0, candidates, scores), plain


@dataclass(frozen=True, slots=True, eq=False)
class ObjectDensities:
    """Each old object's feature distribution (diagonal Gaussian) in one feature space.

    Attributes:
        classes: Old-object labels, shape (k,).
        means: Per-object mean, shape (k, d).
        variances: Per-object variance, shrunk towards the pooled within-object variance,
            shape (k, d).
        counts: Observations per object, shape (k,).
    """

    classes: npt.NDArray[np.int64]
    means: FloatArray
    variances: FloatArray
    counts: FloatArray

    @classmethod
    def fit(
        cls, X: npt.ArrayLike, labels: npt.ArrayLike, *, shrinkage: float = 2.0
    ) -> ObjectDensities:
        """Estimate every object's mean and (shrunk) variance.

        ``var_o = (n_o s_o^2 + c s_pooled^2) / (n_o + c)`` with ``c = shrinkage``: with few
        observations of an object its variances lean on the pooled within-object ones. A floor
        of 1e-6 keeps constant columns (e.g. unused PCA components) usable.

        Args:
            X: Old objects' observations, shape (n, d).
            labels: Old-object label of each row, shape (n,).
            shrinkage: Pseudo-count ``c`` of the pooled variance.

        Raises:
            AtiktError: Shapes disagree or no observations.
        """
        Xa = np.asarray(X, dtype=np.float64)
        la = np.asarray(labels).reshape(-1)
        if Xa.ndim != 2 or Xa.shape[0] != la.shape[0] or Xa.shape[0] == 0:  # noqa: PLR2004
            msg = f"X {Xa.shape} and labels {la.shape}: need X (n, d) and n labels, n >= 1"
            raise AtiktError(msg)
        classes = np.unique(la).astype(np.int64)
        groups = [Xa[la == c] for c in classes]
        means = np.array([g.mean(axis=0) for g in groups])
        counts = np.array([g.shape[0] for g in groups], dtype=np.float64)
        scatter = np.array([((g - m) ** 2).sum(axis=0) for g, m in zip(groups, means, strict=True)])
        dof = max(Xa.shape[0] - classes.shape[0], 1)
        pooled = scatter.sum(axis=0) / dof
        own = scatter / np.maximum(counts - 1.0, 1.0)[:, None]
        weight = np.where(counts > 1.0, counts, 0.0)[:, None]
        variances = (weight * own + shrinkage * pooled) / (weight + shrinkage) + 1e-6
        return cls(classes, means, variances, counts)

    def tail_probabilities(self, X: npt.ArrayLike) -> FloatArray:
        """Tail probability of each observation under each object's distribution.

        ``p = P(chi2_d >= m^2 / (1 + 1/n_o))`` with ``m^2`` the squared Mahalanobis distance
        to the object's mean (the factor accounts for the estimated mean).

        Args:
            X: Observations, shape (m, d).

        Returns:
            Shape (m, k), in [0, 1].
        """
        Xa = np.asarray(X, dtype=np.float64)
        d2 = (((Xa[:, None, :] - self.means[None]) ** 2) / self.variances[None]).sum(axis=2)
        d2 /= 1.0 + 1.0 / self.counts[None]
        return np.asarray(chdtrc(self.means.shape[1], d2), dtype=np.float64)


def choose_by_density(
    scores: npt.ArrayLike,
    classes: npt.ArrayLike,
    eps_density: float = 0.1,
    max_sources: int = 1,
    rho_scale: float = 2.0,
) -> PriorChoice:
    """Choose the source old object(s) by the open-set score (mean tail probability).

    Args:
        scores: Mean tail probability of the new object's observations under each old object's
            distribution (:meth:`ObjectDensities.tail_probabilities`, averaged), shape (n_old,).
        classes: The old objects' labels, in the order of ``scores``.
        eps_density: Minimum score for a transfer, in (0, 1].
        max_sources: Most old objects transferred at once.
        rho_scale: ``rho = min(1, rho_scale * score)``; 2 gives ``rho = 1`` for typical draws
            of the old object's distribution (mean tail probability 1/2).

    Returns:
        The old object(s) of the largest scores with their ``rho``, or no source when the
        largest score is below ``eps_density``.

    Raises:
        AtiktError: A threshold out of range or ``rho_scale <= 0``.
    """
    check_threshold("eps_density", eps_density, low=0.0)
    if not rho_scale > 0:
        msg = f"rho_scale={rho_scale}; it must be > 0"
        raise AtiktError(msg)
    return _choose(scores, classes, eps_density, max_sources, lambda v: min(1.0, rho_scale * v))


def evidence_gains(
    kernel: Kernel,
    X: npt.ArrayLike,
    y: npt.ArrayLike,
    auxiliary: Mapping[int, npt.ArrayLike],
    rho: float = 0.9,
) -> FloatArray:
    """The dependent GP's evidence gain of each old object for one new object's labels.

    ``log p(y | y_o; rho) - log p(y)``: how much more probable the new object-vs-rest labels
    ``y`` become when the old object's observations are added as positives with transfer
    coefficient ``rho``, under the Laplace approximation at the kernel's hyperparameters.
    ``log p(y | y_o) = log p(y_o, y) - log p(y_o)``, so an old object's own number of
    observations does not enter; the score of one old object does not depend on the others.

    Args:
        kernel: Base kernel with the hyperparameters to evaluate at (not optimised).
        X: New objects' observations, shape (n, d).
        y: 1 for the new object of interest, 0 otherwise, shape (n,).
        auxiliary: Old-object label -> its observations (n_o, d) in the same feature space.
        rho: Transfer coefficient of the evaluation, in (0, 1].

    Returns:
        Shape (n_old,), nats, in the order of ``auxiliary``.

    Raises:
        AtiktError: ``rho`` outside (0, 1].
    """
    if not 0.0 < rho <= 1.0:
        msg = f"rho={rho}; the evidence gain's transfer coefficient must lie in (0, 1]"
        raise AtiktError(msg)
    Xn = np.asarray(X, dtype=np.float64)
    yn = np.asarray(y, dtype=np.float64).reshape(-1)
    alone = _lml(kernel, Xn, yn)
    dependent = DependentKernel(kernel, rho)
    gains = []
    for obs in auxiliary.values():
        Xo = np.asarray(obs, dtype=np.float64)
        positives = np.ones(Xo.shape[0])
        joint = _lml(dependent, _stack_domains(Xo, Xn), np.concatenate([positives, yn]))
        gains.append(joint - _lml(kernel, Xo, positives) - alone)
    return np.asarray(gains, dtype=np.float64)


def _lml(kernel: Kernel, X: FloatArray, y: FloatArray) -> float:
    """Laplace log marginal likelihood at the kernel's own hyperparameters."""
    return float(BinaryGPC(kernel, optimize=False).fit(X, y).log_marginal_likelihood())  # type: ignore[arg-type]


def choose_by_evidence(
    gains: npt.ArrayLike,
    classes: npt.ArrayLike,
    eps_evidence: float = 0.0,
    max_sources: int = 1,
    rho: float = 0.9,
) -> PriorChoice:
    """Choose the source old object(s) by the evidence gain (:func:`evidence_gains`).

    Args:
        gains: Evidence gain of each old object, nats, shape (n_old,).
        classes: The old objects' labels, in the order of ``gains``.
        eps_evidence: Smallest gain (nats) for a transfer; 0: whenever the labels become
            more probable.
        max_sources: Most old objects transferred at once.
        rho: The transfer coefficient of every chosen source (the one the gains were
            evaluated at).

    Returns:
        The old object(s) of the largest gains above ``eps_evidence`` with ``rho``, or no
        source.
    """
    values = np.asarray(gains, dtype=np.float64)
    # _choose keeps the scores >= eps; a gain of exactly eps is no evidence either way
    return _choose(values, classes, np.nextafter(eps_evidence, np.inf), max_sources, lambda _: rho)
