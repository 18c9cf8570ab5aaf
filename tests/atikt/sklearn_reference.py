"""Independent reference of the atikt classifiers on scikit-learn's GaussianProcessClassifier.

The kernels are scikit-learn ``Kernel`` subclasses built on scikit-learn's own ``RBF`` and
``ConstantKernel``: a column-slice RBF, a softmax-weighted sum of kernels, and the dependent
(transfer) kernel reading the domain flag from the last column. At fixed hyperparameters the
probabilities agree with atikt's to 1e-6 (tests/atikt/test_atikt_reference.py); the benchmark
(tests/bench/bench_atikt.py) times :func:`reference_update` against atikt's own update.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt
import scipy.optimize
from sklearn.gaussian_process import GaussianProcessClassifier
from sklearn.gaussian_process.kernels import RBF, ConstantKernel, Hyperparameter
from sklearn.gaussian_process.kernels import Kernel as SkKernel

from atikt import (
    DependentKernel,
    FeatureTransformer,
    ModalityKernel,
    entropy,
    modality_kernel,
)
from atikt.active import separation
from atikt.gpc import normalise
from atikt.transfer import OLD_DOMAIN, with_domain

if TYPE_CHECKING:
    from collections.abc import Sequence

    from atikt.active import ActionState

FloatArray = npt.NDArray[np.float64]
RATIO_BOUNDS = (float(np.exp(-6.0)), float(np.exp(6.0)))


class ColumnRBF(SkKernel):  # type: ignore[misc]
    """scikit-learn's RBF applied to the columns ``[start, stop)``."""

    def __init__(
        self,
        start: int = 0,
        stop: int = 1,
        length_scale: float = 1.0,
        length_scale_bounds: Any = (0.05, 20.0),
    ) -> None:
        self.start = start
        self.stop = stop
        self.length_scale = length_scale
        self.length_scale_bounds = length_scale_bounds

    @property
    def hyperparameter_length_scale(self) -> Hyperparameter:
        return Hyperparameter("length_scale", "numeric", self.length_scale_bounds)

    def __call__(self, X: Any, Y: Any = None, eval_gradient: bool = False) -> Any:  # noqa: FBT001, FBT002
        rbf = RBF(self.length_scale, self.length_scale_bounds)
        cols = slice(self.start, self.stop)
        if Y is not None:
            return rbf(X[:, cols], Y[:, cols])
        return rbf(X[:, cols], eval_gradient=eval_gradient)

    def diag(self, X: Any) -> Any:
        return np.ones(X.shape[0])

    def is_stationary(self) -> bool:
        return True


class SoftmaxMixture(SkKernel):  # type: ignore[misc]
    """``sum_m w_m k_m``, ``w = [1, ratios] / (1 + sum ratios)``; theta: children, log ratios."""

    def __init__(
        self,
        kernels: tuple[SkKernel, ...] = (),
        ratios: Any = None,
        ratio_bounds: Any = RATIO_BOUNDS,
    ) -> None:
        self.kernels = kernels
        self.ratios = ratios
        self.ratio_bounds = ratio_bounds

    def _ratios(self) -> FloatArray:
        return np.asarray(self.ratios, dtype=np.float64).reshape(-1)

    @property
    def weights(self) -> FloatArray:
        r = np.concatenate([[1.0], self._ratios()])
        return np.asarray(r / r.sum())

    @property
    def hyperparameters(self) -> list[Hyperparameter]:
        out = [
            Hyperparameter(f"k{i}__{h.name}", h.value_type, h.bounds, h.n_elements)
            for i, k in enumerate(self.kernels)
            for h in k.hyperparameters
        ]
        n = len(self.kernels) - 1
        if n:
            out.append(Hyperparameter("ratios", "numeric", [self.ratio_bounds] * n, n))
        return out

    @property
    def theta(self) -> FloatArray:
        return np.concatenate([*(k.theta for k in self.kernels), np.log(self._ratios())])

    @theta.setter
    def theta(self, theta: FloatArray) -> None:
        start = 0
        for k in self.kernels:
            k.theta = theta[start : start + k.n_dims]
            start += k.n_dims
        self.ratios = np.exp(theta[start:])

    @property
    def bounds(self) -> FloatArray:
        n = len(self.kernels) - 1
        ratio = np.log(np.tile(np.asarray(self.ratio_bounds, float), (n, 1)))
        return np.vstack([*(k.bounds for k in self.kernels), ratio])

    def __call__(self, X: Any, Y: Any = None, eval_gradient: bool = False) -> Any:  # noqa: FBT001, FBT002
        w = self.weights
        if not eval_gradient:
            return sum(wm * k(X, Y) for wm, k in zip(w, self.kernels, strict=True))
        parts = [k(X, eval_gradient=True) for k in self.kernels]
        K = sum(wm * Km for wm, (Km, _) in zip(w, parts, strict=True))
        grads = [wm * dKm for wm, (_, dKm) in zip(w, parts, strict=True)]
        grads += [(w[j] * (parts[j][0] - K))[:, :, None] for j in range(1, len(parts))]
        return K, np.concatenate(grads, axis=2)

    def diag(self, X: Any) -> Any:
        return sum(wm * k.diag(X) for wm, k in zip(self.weights, self.kernels, strict=True))

    def is_stationary(self) -> bool:
        return True


class DomainKernel(SkKernel):  # type: ignore[misc]
    """Dependent kernel: ``rho`` times the base kernel across domains (flag = last column)."""

    def __init__(self, base: SkKernel = None, rho: float = 0.5, rho_bounds: Any = "fixed") -> None:
        self.base = base
        self.rho = rho
        self.rho_bounds = rho_bounds

    @property
    def _learn(self) -> bool:
        return not (isinstance(self.rho_bounds, str) and self.rho_bounds == "fixed")

    @property
    def hyperparameters(self) -> list[Hyperparameter]:
        out = [
            Hyperparameter(f"base__{h.name}", h.value_type, h.bounds, h.n_elements)
            for h in self.base.hyperparameters
        ]
        if self._learn:
            out.append(Hyperparameter("rho", "numeric", self.rho_bounds))
        return out

    @property
    def theta(self) -> FloatArray:
        tail = [np.log(self.rho)] if self._learn else []
        return np.concatenate([self.base.theta, tail])

    @theta.setter
    def theta(self, theta: FloatArray) -> None:
        n = self.base.n_dims
        self.base.theta = theta[:n]
        if self._learn:
            self.rho = float(np.exp(theta[n]))

    @property
    def bounds(self) -> FloatArray:
        tail = [np.log(np.asarray(self.rho_bounds, float))] if self._learn else []
        return np.vstack([self.base.bounds, *tail])

    def _cross(self, X: Any, Y: Any) -> Any:
        fy = X[:, -1] if Y is None else Y[:, -1]
        return X[:, -1][:, None] != fy[None, :]

    def __call__(self, X: Any, Y: Any = None, eval_gradient: bool = False) -> Any:  # noqa: FBT001, FBT002
        cross = self._cross(X, Y)
        mask = np.where(cross, self.rho, 1.0)
        if not eval_gradient:
            return self.base(X, Y) * mask
        K, dK = self.base(X, eval_gradient=True)
        grads = [dK * mask[:, :, None]]
        if self._learn:
            grads.append((np.where(cross, self.rho, 0.0) * K)[:, :, None])
        return K * mask, np.concatenate(grads, axis=2)

    def diag(self, X: Any) -> Any:
        return self.base.diag(X)

    def is_stationary(self) -> bool:
        return False


def reference_kernel(ours: ModalityKernel | DependentKernel) -> SkKernel:
    """The scikit-learn kernel with the same hyperparameter values as an atikt kernel."""
    if isinstance(ours, DependentKernel):
        assert isinstance(ours.base, ModalityKernel)
        bounds = ours.rho_bounds
        return DomainKernel(reference_kernel(ours.base), ours.rho, bounds)
    parts = tuple(
        ColumnRBF(p.columns.start, p.columns.stop, p.length_scale, p.length_scale_bounds)
        for p in ours.parts
    )
    lo, hi = ours.logit_bounds
    mixture = SoftmaxMixture(parts, np.exp(ours.logits), (np.exp(lo), np.exp(hi)))
    if ours.variance is None:
        return mixture
    return ConstantKernel(ours.variance, ours.variance_bounds) * mixture


def to_reference_theta(ours: ModalityKernel | DependentKernel) -> FloatArray:
    """Reorder atikt's theta into the reference kernel's order (signal variance first)."""
    base = ours.base if isinstance(ours, DependentKernel) else ours
    assert isinstance(base, ModalityKernel)
    theta = base.theta
    if base.variance is not None:
        theta = np.concatenate([theta[-1:], theta[:-1]])
    if isinstance(ours, DependentKernel) and ours.learn_rho:
        theta = np.concatenate([theta, [np.log(ours.rho)]])
    return theta


def reference_order(ours: ModalityKernel | DependentKernel, values: FloatArray) -> FloatArray:
    """``values`` given per atikt hyperparameter (theta order) in the reference kernel's order."""
    base = ours.base if isinstance(ours, DependentKernel) else ours
    assert isinstance(base, ModalityKernel)
    values = np.broadcast_to(np.asarray(values, dtype=np.float64), ours.theta.shape)
    n = base.theta.shape[0]
    head = values[:n]
    if base.variance is not None:
        head = np.concatenate([head[-1:], head[:-1]])
    return np.concatenate([head, values[n:]])


def log_hyperprior(theta: FloatArray, sd: FloatArray | None, mean: FloatArray | None) -> float:
    """``-sum((theta - mean)^2 / (2 sd^2))`` (constants dropped; 0 without a prior)."""
    if sd is None or mean is None:
        return 0.0
    return float(-0.5 * np.sum(((theta - mean) / sd) ** 2))


def lbfgs(max_iter: int, sd: FloatArray | None = None, mean: FloatArray | None = None) -> Any:
    """A scikit-learn ``optimizer`` callable: L-BFGS-B with an iteration limit.

    With ``sd`` and ``mean`` (reference order) it maximises the log marginal likelihood plus
    the log density of a Gaussian hyperprior, the objective atikt's searches maximise.
    """

    def penalised(obj_func: Any) -> Any:
        if sd is None or mean is None:
            return obj_func

        def objective(theta: FloatArray) -> tuple[float, FloatArray]:
            value, grad = obj_func(theta)
            z = (theta - mean) / sd
            return value + 0.5 * float(z @ z), grad + z / sd

        return objective

    def optimizer(obj_func: Any, initial_theta: FloatArray, bounds: FloatArray) -> Any:
        result = scipy.optimize.minimize(
            penalised(obj_func),
            initial_theta,
            method="L-BFGS-B",
            jac=True,
            bounds=bounds,
            options={"maxiter": max_iter},
        )
        return result.x, result.fun

    return optimizer


def fixed_gpc(kernel: SkKernel, X: FloatArray, y: npt.ArrayLike) -> GaussianProcessClassifier:
    """scikit-learn's classifier at fixed hyperparameters."""
    return GaussianProcessClassifier(kernel=kernel, optimizer=None).fit(X, y)


@dataclass(frozen=True)
class ObjectSearch:
    """What one new object's classifier was searched with: source, rho, hyperprior (atikt order).

    ``sd`` None: no hyperprior (maximum likelihood).
    """

    source: int | None
    rho: float
    sd: float | FloatArray | None
    mean: FloatArray | None


def reference_update(
    state: ActionState,
    *,
    n_new_objects: int,
    amplitude: bool,
    n_thermal_components: int,
    eps_neg1: float,
    max_iter: int,
    old_model: Sequence[GaussianProcessClassifier] | None,
    changed: int | None = None,
    warm_start: bool = True,
    fits: Sequence[ObjectSearch] | None = None,
    metric_check: str = "none",
) -> tuple[FloatArray, FloatArray]:
    """One action update of the model prediction approach with scikit-learn.

    Returns UNC per new object and the objective each new object's classifier reached: its
    log marginal likelihood plus the log density of its hyperprior (0 without one).

    Mirrors :meth:`atikt.ActiveLearner._update`: features fitted on the collected observations
    (prior observations mapped into that space), relatedness by the old objects' binary
    classifiers, one classifier per new object (dependent kernel with the chosen old object's
    observations as auxiliary positives),
    each warm-started from the state's previous hyperparameters (and, with ``warm_start``,
    scikit-learn's reuse of the last Newton mode within a search: faster, but its objective is
    then only accurate to the Newton tolerance, which moves capped searches elsewhere), then
    the mean entropy of each
    object's own observations. As in atikt, only the ``changed`` object's relatedness is
    recomputed (the others' depends on unchanged observations and fixed prior models).
    ``fits``: per new object, the source, rho and hyperprior atikt's update used; given, the
    reference searches the same objective from the same choices (a comparison of the searches
    alone). ``metric_check``: the learner's check of metric transfer (``separation``,
    ``evidence``, ``either``), done here with scikit-learn's kernels and classifiers so that
    the update does the learner's work; its outcome is atikt's (in ``fits``).
    """
    prior = state.prior
    transformer = FeatureTransformer(n_thermal_components=n_thermal_components)
    X = transformer.fit_transform(state.observations)
    labels = np.asarray(state.labels)
    groups = prior.by_object() if prior is not None else {}
    auxiliary = {old: transformer.transform(obs) for old, obs in groups.items()}
    _metric_work(
        state,
        transformer,
        X,
        auxiliary,
        amplitude=amplitude,
        n_new=n_new_objects,
        check=metric_check,
    )
    models: list[tuple[GaussianProcessClassifier, bool]] = []
    values: list[float] = []
    for obj in range(n_new_objects):
        kernel = modality_kernel(transformer.slices_, amplitude=amplitude)
        theta = state.thetas[obj]
        if theta is not None:
            kernel = kernel.with_theta(theta)
        y = (labels == obj).astype(np.float64)
        source, rho = None, 0.0
        sd, mean = None, None
        if fits is not None:
            source, rho = fits[obj].source, fits[obj].rho
            if fits[obj].sd is not None and fits[obj].mean is not None:
                sd = reference_order(kernel, np.asarray(fits[obj].sd, dtype=np.float64))
                mean = reference_order(kernel, np.asarray(fits[obj].mean, dtype=np.float64))
        elif changed is not None and obj != changed:
            source, rho = state.choices[obj].source, state.choices[obj].rho
        elif prior is not None and old_model is not None:
            mine = [
                o for o, lab in zip(state.observations, state.labels, strict=True) if lab == obj
            ]
            Xp = prior.transformer.transform(mine)
            scores = [m.predict_proba(Xp)[:, 1].mean() for m in old_model]
            best = int(np.argmax(scores))
            if scores[best] >= eps_neg1:
                source, rho = prior.old_objects[best], float(scores[best])
        sk_kernel = reference_kernel(kernel)
        if source is not None:
            sk_kernel = DomainKernel(sk_kernel, rho, "fixed")
        gpc = GaussianProcessClassifier(
            kernel=sk_kernel, optimizer=lbfgs(max_iter, sd, mean), warm_start=warm_start
        )
        if source is None:
            models.append((gpc.fit(X, y), False))
        else:
            aux = with_domain(auxiliary[source], OLD_DOMAIN)
            X_all = np.vstack([aux, with_domain(X, 1.0)])
            y_all = np.concatenate([np.ones(aux.shape[0]), y])
            models.append((gpc.fit(X_all, y_all), True))
        # scikit-learn keeps the optimiser's best value: with a hyperprior, the log marginal
        # likelihood plus the log hyperprior density already
        values.append(models[-1][0].log_marginal_likelihood_value_)
    columns = [
        m.predict_proba(with_domain(X, 1.0) if flagged else X)[:, 1] for m, flagged in models
    ]
    entropies = entropy(normalise(np.column_stack(columns)))
    unc = np.array([entropies[labels == obj].mean() for obj in range(n_new_objects)])
    return unc, np.array(values)


def _metric_work(
    state: ActionState,
    transformer: FeatureTransformer,
    X: FloatArray,
    auxiliary: dict[int, FloatArray],
    *,
    amplitude: bool,
    n_new: int,
    check: str,
) -> bool | None:
    """The learner's check of metric transfer (None: none asked, or no old objects' kernel)."""
    prior = state.prior
    if check == "none" or prior is None or prior.model is None:
        return None
    initial = modality_kernel(transformer.slices_, amplitude=amplitude)
    thetas = [e.kernel_.theta for e in prior.model.estimators_]
    metric = initial.with_theta(np.median(thetas, axis=0))
    kernels = (reference_kernel(metric), reference_kernel(initial))
    labels = np.asarray(state.labels)
    return check_metric(kernels, X, labels, auxiliary, n_new_objects=n_new, check=check)


def check_metric(
    kernels: tuple[SkKernel, SkKernel],
    X: FloatArray,
    labels: npt.NDArray[np.int64],
    auxiliary: dict[int, FloatArray],
    *,
    n_new_objects: int,
    check: str,
) -> bool:
    """Whether the old objects' kernel passes the learner's check, in scikit-learn.

    ``separation`` ranks kernel correlations (atikt's function, given scikit-learn's kernels:
    the kernel evaluations are scikit-learn's); ``evidence`` sums the new objects'
    one-vs-all log evidence, each a scikit-learn classifier fitted without optimisation.
    """
    metric, initial = kernels
    passed = False
    if check in {"separation", "either"}:
        passed = separation(metric, X, labels, auxiliary) >= separation(
            initial, X, labels, auxiliary
        )
    if not passed and check in {"evidence", "either"}:
        evidence = [
            sum(
                GaussianProcessClassifier(kernel=kernel, optimizer=None)
                .fit(X, (labels == obj).astype(np.float64))
                .log_marginal_likelihood_value_
                for obj in range(n_new_objects)
            )
            for kernel in (metric, initial)
        ]
        passed = evidence[0] >= evidence[1]
    return passed


def reference_old_model(
    kernels: Sequence[ModalityKernel], X: FloatArray, labels: npt.ArrayLike
) -> list[GaussianProcessClassifier]:
    """The old objects' binary classifiers in scikit-learn at atikt's fitted hyperparameters."""
    classes = np.unique(np.asarray(labels))
    return [
        fixed_gpc(reference_kernel(k), X, (np.asarray(labels) == c).astype(float))
        for k, c in zip(kernels, classes, strict=True)
    ]
