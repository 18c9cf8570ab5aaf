"""Covariance functions of the multi-modal and the dependent (transfer) GP classifiers.

Hyperparameters live in log space with bounds, in the scikit-learn style: ``theta`` holds the
free ones, ``bounds`` their (log) box, ``with_theta`` returns a new kernel, and
``gradient(X)`` returns ``K`` together with ``dK/dtheta`` of shape (n_params, n, n).

- :class:`SliceRBF`: ``exp(-|x_s - y_s|^2 / (2 l^2))`` on one modality's column slice ``s``.
- :class:`ModalityKernel`: ``s^2 * sum_m w_m k_m`` with weights ``w = softmax([0, logits])``
  (``w >= 0``, ``|w|_1 = 1``) and an optional signal variance ``s^2`` (None: the thesis
  variant, ``s^2 = 1``).
- :class:`DependentKernel`: the transfer kernel of Feng, Kaboli & Cheng (TUM 2017),
  ``[[K(Xo, Xo), rho K(Xo, Xn)], [rho K(Xn, Xo), K(Xn, Xn)]]`` with ``rho`` in [0, 1]; the
  domain (0 = old object, 1 = new object) is the last column of ``X``. It is the Hadamard
  product of the base kernel with the PSD matrix ``[[1, rho], [rho, 1]]`` expanded over the
  domains, hence PSD for every ``rho`` in [0, 1] (Schur product theorem).
- :class:`MultiSourceKernel`: several old objects at once, one ``rho_j`` each: the base kernel
  times the coregionalisation matrix ``C = v v' + diag(1 - v^2)`` with ``v = (1, rho_1, ..,
  rho_S)`` over the domains (new object, source 1..S): ``rho_j`` between the new object and
  source ``j``, ``rho_j rho_k`` between two sources, 1 within a domain. That is the covariance
  of ``f_new = g``, ``f_j = rho_j g + sqrt(1 - rho_j^2) h_j`` with independent GPs ``g``,
  ``h_j`` of the base kernel, so PSD by construction; with one source it is the
  :class:`DependentKernel`.
"""

from __future__ import annotations

import abc
import math
from typing import TYPE_CHECKING, Final, Literal, Self, TypeAlias

import numpy as np
import numpy.typing as npt
from scipy.spatial.distance import cdist

from atikt.errors import AtiktError

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence

FloatArray = npt.NDArray[np.float64]
Bounds = tuple[float, float] | Literal["fixed"]
Evaluator: TypeAlias = "Callable[[FloatArray], tuple[FloatArray, FloatArray]]"
"""``theta -> (K(X, X), dK/dtheta)`` for one fixed ``X`` (see :meth:`Kernel.evaluator`)."""

DEFAULT_LENGTH_SCALE_BOUNDS: Final = (0.05, 20.0)
"""Length-scale box: the feature blocks have unit total variance (see FeatureTransformer)."""
DEFAULT_LOGIT_BOUNDS: Final = (-6.0, 6.0)
"""Modality-weight logits box: weight ratios between e^-6 and e^6."""
DEFAULT_VARIANCE_BOUNDS: Final = (0.1, 100.0)
"""Signal-variance box of the amplitude variant."""
DEFAULT_RHO_BOUNDS: Final = (1e-3, 1.0)
DEFAULT_BIAS_BOUNDS: Final = (1e-3, 100.0)
MATERN_NUS: Final = (1.5, 2.5)
"""Smoothness values of :class:`SliceMatern` (closed forms, R&W eq. 4.17)."""
PART_KERNELS: Final = ("rbf", "matern32", "matern52")
"""Per-modality kernel choices of :func:`modality_kernel`."""
COMBINATIONS: Final = ("sum", "product")
"""How :func:`modality_kernel` combines the per-modality kernels."""
"""Box of a learned transfer coefficient rho (log space, so 0 itself is excluded)."""

_EMPTY_BOUNDS: Final = np.zeros((0, 2))


def _log_bounds(bounds: Bounds) -> FloatArray:
    """Return the (1, 2) log-space box of a positive hyperparameter, (0, 2) when fixed."""
    if bounds == "fixed":
        return _EMPTY_BOUNDS
    low, high = bounds
    if not 0 < low <= high:
        msg = f"bounds {bounds}: need 0 < low <= high for a positive hyperparameter"
        raise AtiktError(msg)
    return np.log([[low, high]])


class Kernel(abc.ABC):
    """A covariance function with log-space hyperparameters and analytic gradients."""

    @property
    @abc.abstractmethod
    def theta(self) -> FloatArray:
        """Free hyperparameters in log space, shape (n_params,)."""

    @property
    @abc.abstractmethod
    def bounds(self) -> FloatArray:
        """Box of ``theta``, shape (n_params, 2), log space."""

    @property
    @abc.abstractmethod
    def names(self) -> tuple[str, ...]:
        """One name per entry of ``theta``."""

    def with_theta(self, theta: npt.ArrayLike) -> Self:
        """Return a copy with the free hyperparameters set to ``theta`` (log space).

        Raises:
            AtiktError: Wrong length or non-finite values.
        """
        return self._with_values(self._check_theta(theta))

    @abc.abstractmethod
    def _with_values(self, values: FloatArray) -> Self:
        """:meth:`with_theta` of an already checked float array.

        Composite kernels pass their parts slices of it without checking each again.
        """

    @abc.abstractmethod
    def __call__(self, X: FloatArray, Y: FloatArray | None = None) -> FloatArray:
        """Return ``K(X, Y)``, shape (n_X, n_Y); ``Y = X`` when None."""

    @abc.abstractmethod
    def gradient(self, X: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Return ``K(X, X)`` (n, n) and ``dK/dtheta`` (n_params, n, n)."""

    @abc.abstractmethod
    def diag(self, X: FloatArray) -> FloatArray:
        """Return the diagonal of ``K(X, X)``, shape (n,)."""

    def evaluator(self, X: FloatArray, scale: FloatArray | None = None) -> Evaluator:
        """Return ``theta -> (K(X, X), dK/dtheta)`` for this ``X``.

        The hyperparameter search evaluates the kernel of one training set at many ``theta``;
        subclasses precompute what does not depend on ``theta`` (squared distances, domain
        masks) and build no kernel objects per call. The result equals
        ``self.with_theta(theta).gradient(X)``, multiplied elementwise by ``scale`` (n, n)
        when given (a fixed factor such as the dependent kernel's domain mask, which
        subclasses fold into their parts instead of multiplying every output).
        """
        if scale is None:
            return lambda theta: self.with_theta(theta).gradient(X)

        def evaluate(theta: FloatArray) -> tuple[FloatArray, FloatArray]:
            K, dK = self.with_theta(theta).gradient(X)
            return K * scale, dK * scale

        return evaluate

    def _copy(self) -> Self:
        """A shallow copy (``with_theta`` then replaces the values that change)."""
        new = object.__new__(type(self))
        new.__dict__.update(self.__dict__)
        return new

    @property
    def n_params(self) -> int:
        """Number of free hyperparameters."""
        return int(self.bounds.shape[0])

    def _check_theta(self, theta: npt.ArrayLike) -> FloatArray:
        """Return ``theta`` as a float array of the right length.

        Raises:
            AtiktError: Wrong length or non-finite values.
        """
        array = np.asarray(theta, dtype=np.float64).reshape(-1)
        if array.shape[0] != self.n_params or not np.isfinite(array).all():
            msg = f"theta {array}: need {self.n_params} finite values for {self.names}"
            raise AtiktError(msg)
        return array


class SliceRBF(Kernel):
    """Squared-exponential kernel on one modality's column slice.

    Args:
        columns: The columns of the modality in the feature matrix.
        length_scale: Length scale ``l > 0``.
        length_scale_bounds: Box of ``l`` or ``"fixed"``.
        name: Modality name, used in ``names``.
    """

    def __init__(
        self,
        columns: slice,
        length_scale: float = 1.0,
        length_scale_bounds: Bounds = DEFAULT_LENGTH_SCALE_BOUNDS,
        name: str = "rbf",
    ) -> None:
        """Store the parameters; see the class docstring."""
        if not length_scale > 0:
            msg = f"length_scale={length_scale}; it must be > 0"
            raise AtiktError(msg)
        self.columns = columns
        self.length_scale = float(length_scale)
        self.length_scale_bounds = length_scale_bounds
        self.name = name
        self._bounds = _log_bounds(length_scale_bounds)

    @property
    def theta(self) -> FloatArray:
        """``[log l]``, or empty when fixed."""
        if self.length_scale_bounds == "fixed":
            return np.zeros(0)
        return np.array([np.log(self.length_scale)])

    @property
    def bounds(self) -> FloatArray:
        """Log-space box of ``theta``."""
        return self._bounds

    @property
    def names(self) -> tuple[str, ...]:
        """``(f"{name}.length_scale",)`` or empty."""
        return () if self.length_scale_bounds == "fixed" else (f"{self.name}.length_scale",)

    def _with_values(self, values: FloatArray) -> Self:
        """Return a copy with ``log l = values[0]``."""
        new = self._copy()  # the bounds stay: only the value changes
        if values.shape[0]:
            new.length_scale = math.exp(values[0])
        return new

    def sq_dist(self, X: FloatArray, Y: FloatArray | None = None) -> FloatArray:
        """Squared Euclidean distances of the slice, shape (n_X, n_Y)."""
        xs = X[:, self.columns]
        ys = xs if Y is None else Y[:, self.columns]
        return np.asarray(cdist(xs, ys, "sqeuclidean"), dtype=np.float64)

    def __call__(self, X: FloatArray, Y: FloatArray | None = None) -> FloatArray:
        """Return ``exp(-d^2 / (2 l^2))``."""
        return self.from_sq_dist(self.sq_dist(X, Y))

    def from_sq_dist(self, D: FloatArray) -> FloatArray:
        """The kernel's values at squared distances ``D`` of the slice (any shape)."""
        return np.exp(D / (-2.0 * self.length_scale**2))

    def gradient(self, X: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Return ``K`` and ``dK/dlog l = K * d^2 / l^2``."""
        scaled = self.sq_dist(X) / self.length_scale**2
        K = np.exp(-0.5 * scaled)
        if self.length_scale_bounds == "fixed":
            return K, np.zeros((0, *K.shape))
        return K, (K * scaled)[None]

    def diag(self, X: FloatArray) -> FloatArray:
        """Return ones: the RBF has unit variance."""
        return np.ones(X.shape[0])

    def evaluator(self, X: FloatArray, scale: FloatArray | None = None) -> Evaluator:
        """Return ``theta -> (K, dK)`` with the squared distances computed once."""
        D = self.sq_dist(X)
        if self.length_scale_bounds == "fixed":
            K = np.exp(D / (-2.0 * self.length_scale**2))
            if scale is not None:
                K *= scale
            empty = np.zeros((0, *D.shape))
            return lambda _theta: (K.copy(), empty)

        def evaluate(theta: FloatArray) -> tuple[FloatArray, FloatArray]:
            scaled = D * math.exp(-2.0 * theta[0])  # d^2 / l^2
            K = np.exp(-0.5 * scaled)
            if scale is not None:
                K *= scale
            return K, (K * scaled)[None]

        return evaluate


class SliceMatern(SliceRBF):
    """Matern kernel of smoothness ``nu`` (3/2 or 5/2) on one modality's column slice.

    ``k = (1 + a) e^-a`` (``nu = 3/2``, ``a = sqrt(3) d / l``) or ``(1 + a + a^2 / 3) e^-a``
    (``nu = 5/2``, ``a = sqrt(5) d / l``), Rasmussen & Williams eq. 4.17; unit variance like the
    RBF, rougher functions of the features (the RBF is the limit ``nu -> inf``).

    Args:
        columns: The columns of the modality in the feature matrix.
        length_scale: Length scale ``l > 0``.
        length_scale_bounds: Box of ``l`` or ``"fixed"``.
        name: Modality name, used in ``names``.
        nu: 1.5 or 2.5.
    """

    def __init__(
        self,
        columns: slice,
        length_scale: float = 1.0,
        length_scale_bounds: Bounds = DEFAULT_LENGTH_SCALE_BOUNDS,
        name: str = "matern",
        nu: float = 2.5,
    ) -> None:
        """Store the parameters; see the class docstring."""
        if nu not in MATERN_NUS:
            msg = f"nu={nu}; use one of {MATERN_NUS}"
            raise AtiktError(msg)
        super().__init__(columns, length_scale, length_scale_bounds, name)
        self.nu = float(nu)

    def _values(self, D: FloatArray, log_l: float) -> tuple[FloatArray, FloatArray]:
        """Return ``k`` and ``dk/dlog l`` from squared distances ``D`` (eq. 4.17)."""
        a = np.sqrt(D) * (math.sqrt(2.0 * self.nu) * math.exp(-log_l))
        e = np.exp(-a)
        if self.nu == MATERN_NUS[0]:
            return (1.0 + a) * e, a * a * e  # dk/da = -a e^-a, da/dlog l = -a
        return (1.0 + a + a * a / 3.0) * e, a * a * (1.0 + a) / 3.0 * e

    def __call__(self, X: FloatArray, Y: FloatArray | None = None) -> FloatArray:
        """Return the Matern kernel of the slice."""
        return self._values(self.sq_dist(X, Y), math.log(self.length_scale))[0]

    def gradient(self, X: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Return ``K`` and ``dK/dlog l``."""
        K, dK = self._values(self.sq_dist(X), math.log(self.length_scale))
        if self.length_scale_bounds == "fixed":
            return K, np.zeros((0, *K.shape))
        return K, dK[None]

    def evaluator(self, X: FloatArray, scale: FloatArray | None = None) -> Evaluator:
        """Return ``theta -> (K, dK)`` with the squared distances computed once."""
        D = self.sq_dist(X)
        fixed = self.length_scale_bounds == "fixed"
        log_l = math.log(self.length_scale)

        def evaluate(theta: FloatArray) -> tuple[FloatArray, FloatArray]:
            K, dK = self._values(D, log_l if fixed else float(theta[0]))
            if scale is not None:
                K *= scale
                dK *= scale
            return K, np.zeros((0, *K.shape)) if fixed else dK[None]

        return evaluate


class ProductKernel(Kernel):
    """Product of per-modality kernels times a signal variance: ``s^2 prod_m k_m(x, y)``.

    A non-additive combination: two observations are alike only if they are alike in every
    modality. A modality is switched off by a long length scale instead of a small weight (its
    factor tends to 1), so there are no weights. With RBF parts it is one RBF with a length
    scale per modality (automatic relevance determination over the modalities). ``theta`` is
    ``[parts' log length scales..., log s^2]``; PSD as a product of PSD kernels (Schur).

    Args:
        parts: One unit-variance kernel per modality (:class:`SliceRBF`, :class:`SliceMatern`).
        variance: Signal variance ``s^2``; None: ``s^2 = 1``, not learned.
        variance_bounds: Box of ``s^2`` or ``"fixed"``.
    """

    def __init__(
        self,
        parts: Sequence[SliceRBF],
        variance: float | None = 1.0,
        variance_bounds: Bounds = DEFAULT_VARIANCE_BOUNDS,
    ) -> None:
        """Store the parameters; see the class docstring."""
        if not parts:
            msg = "ProductKernel needs at least one modality kernel"
            raise AtiktError(msg)
        if variance is not None and not variance > 0:
            msg = f"variance={variance}; it must be > 0 (or None for s^2 = 1)"
            raise AtiktError(msg)
        self.parts = tuple(parts)
        self.variance = variance
        self.variance_bounds = variance_bounds
        self._learn_variance = variance is not None and variance_bounds != "fixed"
        self._bounds = np.vstack(
            [
                *(p.bounds for p in self.parts),
                _log_bounds(variance_bounds) if self._learn_variance else _EMPTY_BOUNDS,
            ]
        )

    @property
    def modalities(self) -> tuple[str, ...]:
        """Names of the modality kernels, in order."""
        return tuple(p.name for p in self.parts)

    @property
    def signal_variance(self) -> float:
        """``s^2``."""
        return 1.0 if self.variance is None else self.variance

    @property
    def theta(self) -> FloatArray:
        """``[log l_m..., log s^2]``."""
        tail = [np.log(self.signal_variance)] if self._learn_variance else []
        return np.concatenate([*(p.theta for p in self.parts), tail])

    @property
    def bounds(self) -> FloatArray:
        """Log-space box of ``theta``."""
        return self._bounds

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the ``theta`` entries."""
        tail = ["signal_variance"] if self._learn_variance else []
        return (*(n for p in self.parts for n in p.names), *tail)

    def _with_values(self, values: FloatArray) -> Self:
        """Return a copy with the free hyperparameters set from ``values``."""
        parts, start = [], 0
        for part in self.parts:
            parts.append(part._with_values(values[start : start + part.n_params]))  # noqa: SLF001
            start += part.n_params
        new = self._copy()
        new.parts = tuple(parts)
        if self._learn_variance:
            new.variance = math.exp(values[start])
        return new

    def __call__(self, X: FloatArray, Y: FloatArray | None = None) -> FloatArray:
        """Return ``s^2 prod_m K_m(X, Y)``."""
        K = self.signal_variance * self.parts[0](X, Y)
        for part in self.parts[1:]:
            K *= part(X, Y)
        return K

    def _combine(
        self, pieces: Sequence[tuple[FloatArray, FloatArray]], s2: float
    ) -> tuple[FloatArray, FloatArray]:
        """Return ``K`` and ``dK`` from the parts' ``(K_m, dK_m)`` (product rule)."""
        n = pieces[0][0].shape[0]
        dK = np.empty((self.n_params, n, n))
        start = 0
        for m, (_, dKm) in enumerate(pieces):
            others = np.full((n, n), s2)
            for o, (Ko, _) in enumerate(pieces):
                if o != m:
                    others *= Ko
            k = dKm.shape[0]
            np.multiply(dKm, others, out=dK[start : start + k])
            start += k
        K = np.full((n, n), s2)
        for Km, _ in pieces:
            K *= Km
        if self._learn_variance:
            dK[start] = K
        return K, dK

    def gradient(self, X: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Return ``K`` and ``dK/dtheta``: ``dK/dtheta_m = s^2 dK_m prod_(o != m) K_o``."""
        return self._combine([p.gradient(X) for p in self.parts], self.signal_variance)

    def diag(self, X: FloatArray) -> FloatArray:
        """Return ``s^2`` for every row (unit-variance parts)."""
        return np.full(X.shape[0], self.signal_variance)

    def evaluator(self, X: FloatArray, scale: FloatArray | None = None) -> Evaluator:
        """Return ``theta -> (K, dK)`` on the parts' evaluators (``scale`` goes into the first)."""
        parts = [
            (p.evaluator(X, scale if m == 0 else None), p.n_params)
            for m, p in enumerate(self.parts)
        ]
        learn, fixed = self._learn_variance, self.signal_variance

        def evaluate(theta: FloatArray) -> tuple[FloatArray, FloatArray]:
            pieces, start = [], 0
            for evaluate_part, k in parts:
                pieces.append(evaluate_part(theta[start : start + k]))
                start += k
            return self._combine(pieces, math.exp(theta[start]) if learn else fixed)

        return evaluate


class ModalityKernel(Kernel):
    """Weighted sum of per-modality RBFs, optionally scaled by a signal variance.

    ``k(x, y) = s^2 * sum_m w_m k_m(x, y)`` with ``w = softmax([0, *logits])``: the first
    modality is the reference, so ``M`` modalities have ``M - 1`` free logits and the weights
    are non-negative with L1 norm 1. ``theta`` is
    ``[log l_1..log l_M, logits, log s^2, log b^2]`` (``s^2`` only when ``variance`` is not
    None, ``b^2`` only with a ``bias``).

    Args:
        parts: One :class:`SliceRBF` per modality.
        logits: ``M - 1`` weight logits relative to the first modality; None = equal weights.
        variance: Signal variance ``s^2``; None is the thesis variant (no amplitude, ``s^2=1``).
        logit_bounds: Box of each logit (not logged: logits are already log ratios).
        variance_bounds: Box of ``s^2`` or ``"fixed"``.
        bias: Variance ``b^2`` of a constant part of the latent function, added to every
            entry (``k + b^2``, learned in log space after ``s^2``); None: none (the thesis).
        bias_bounds: Box of ``b^2`` or ``"fixed"``.
    """

    def __init__(
        self,
        parts: Sequence[SliceRBF],
        logits: npt.ArrayLike | None = None,
        variance: float | None = None,
        logit_bounds: tuple[float, float] = DEFAULT_LOGIT_BOUNDS,
        variance_bounds: Bounds = DEFAULT_VARIANCE_BOUNDS,
        *,
        bias: float | None = None,
        bias_bounds: Bounds = DEFAULT_BIAS_BOUNDS,
    ) -> None:
        """Store the parameters; see the class docstring."""
        if not parts:
            msg = "ModalityKernel needs at least one modality kernel"
            raise AtiktError(msg)
        self.parts = tuple(parts)
        values = np.zeros(len(parts) - 1) if logits is None else np.asarray(logits, float)
        if values.shape != (len(parts) - 1,):
            msg = f"logits {values}: need {len(parts) - 1} values for {len(parts)} modalities"
            raise AtiktError(msg)
        if variance is not None and not variance > 0:
            msg = f"variance={variance}; it must be > 0 (or None for the thesis variant)"
            raise AtiktError(msg)
        self.logits = values
        self._weights = self._softmax(values)
        self._theta: FloatArray | None = None  # theta, computed once (see the property)
        self.variance = variance
        self.logit_bounds = logit_bounds
        self.variance_bounds = variance_bounds
        self._learn_variance = variance is not None and variance_bounds != "fixed"
        if bias is not None and not bias > 0:
            msg = f"bias={bias}; it must be > 0 (or None for no constant term)"
            raise AtiktError(msg)
        self.bias = bias
        self.bias_bounds = bias_bounds
        self._learn_bias = bias is not None and bias_bounds != "fixed"
        self._bounds = np.vstack(
            [
                *(p.bounds for p in self.parts),
                np.tile(np.asarray(logit_bounds, float), (len(parts) - 1, 1)),
                _log_bounds(variance_bounds) if self._learn_variance else _EMPTY_BOUNDS,
                _log_bounds(bias_bounds) if self._learn_bias else _EMPTY_BOUNDS,
            ]
        )

    @property
    def weights(self) -> FloatArray:
        """Modality weights, shape (M,), non-negative, summing to 1."""
        return self._weights.copy()

    @staticmethod
    def _softmax(logits: FloatArray) -> FloatArray:
        """``softmax([0, *logits])``."""
        z = np.concatenate([[0.0], logits])
        e = np.exp(z - z.max())
        return np.asarray(e / e.sum(), dtype=np.float64)

    @property
    def modalities(self) -> tuple[str, ...]:
        """Names of the modality kernels, in order."""
        return tuple(p.name for p in self.parts)

    @property
    def signal_variance(self) -> float:
        """``s^2`` (1 for the thesis variant)."""
        return 1.0 if self.variance is None else self.variance

    @property
    def constant(self) -> float:
        """``b^2``, the variance of the latent function's constant part (0 without)."""
        return 0.0 if self.bias is None else self.bias

    @property
    def theta(self) -> FloatArray:
        """``[log l_m..., logits..., log s^2, log b^2]`` (a copy: the caller may change it)."""
        # the kernel is immutable (with_theta makes a new one): theta is put together once;
        # the learner reads it several times per object and update
        if self._theta is None:
            tail = [np.log(self.signal_variance)] if self._learn_variance else []
            tail += [np.log(self.constant)] if self._learn_bias else []
            self._theta = np.concatenate([*(p.theta for p in self.parts), self.logits, tail])
        return self._theta.copy()

    @property
    def bounds(self) -> FloatArray:
        """Log-space box of ``theta``."""
        return self._bounds

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the ``theta`` entries."""
        part_names = [n for p in self.parts for n in p.names]
        logit_names = [f"{p.name}.weight_logit" for p in self.parts[1:]]
        tail = ["signal_variance"] if self._learn_variance else []
        return (*part_names, *logit_names, *tail, *(["bias"] if self._learn_bias else []))

    def _with_values(self, values: FloatArray) -> Self:
        """Return a copy with the free hyperparameters set from ``values``."""
        parts, start = [], 0
        for part in self.parts:
            n = part.n_params
            parts.append(part._with_values(values[start : start + n]))  # noqa: SLF001
            start += n
        new = self._copy()  # the bounds stay: only the values change
        new._theta = None  # noqa: SLF001 - a copy of this class
        new.parts = tuple(parts)
        new.logits = values[start : start + len(self.parts) - 1].copy()
        new._weights = self._softmax(new.logits)  # noqa: SLF001 - a copy of this class
        start += len(self.parts) - 1
        if self._learn_variance:
            new.variance = math.exp(values[start])
            start += 1
        if self._learn_bias:
            new.bias = math.exp(values[start])
        return new

    def __call__(self, X: FloatArray, Y: FloatArray | None = None) -> FloatArray:
        """Return ``s^2 * sum_m w_m K_m(X, Y)``."""
        weights = self._weights * self.signal_variance
        K: FloatArray = weights[0] * self.parts[0](X, Y)
        for w, part in zip(weights[1:], self.parts[1:], strict=True):
            K += w * part(X, Y)
        if self.bias is not None:
            K += self.bias
        return K

    def from_sq_dists(self, distances: Sequence[FloatArray]) -> FloatArray | None:
        """The kernel's values at each part's squared distances (one array per part).

        The same arithmetic as :meth:`__call__` on the entries given (e.g. only some pairs of
        rows, or distances shared by several kernels on the same rows); None when a part is
        not a :class:`SliceRBF`, whose values are a function of the distance alone.
        """
        parts = self.parts
        if not all(type(part) is SliceRBF for part in parts):
            return None
        weights = self._weights * self.signal_variance
        K: FloatArray = weights[0] * parts[0].from_sq_dist(distances[0])
        for w, part, D in zip(weights[1:], parts[1:], distances[1:], strict=True):
            K += w * part.from_sq_dist(D)
        if self.bias is not None:
            K += self.bias
        return K

    def gradient(self, X: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Return ``K`` and ``dK/dtheta`` (chain rule through the softmax and ``log s^2``)."""
        w, s2 = self.weights, self.signal_variance
        parts = [part.gradient(X) for part in self.parts]
        mixture = w[0] * parts[0][0]
        for wm, (Km, _) in zip(w[1:], parts[1:], strict=True):
            mixture = mixture + wm * Km
        blocks = [s2 * wm * dKm for wm, (_, dKm) in zip(w, parts, strict=True)]
        # d w_m / d logit_j = w_m (delta_mj - w_j)  =>  dK / d logit_j = s2 w_j (K_j - mixture)
        blocks += [(s2 * w[j] * (parts[j][0] - mixture))[None] for j in range(1, len(parts))]
        if self._learn_variance:
            blocks.append((s2 * mixture)[None])
        if self._learn_bias:
            blocks.append(np.full((1, *mixture.shape), self.constant))
        return s2 * mixture + self.constant, np.concatenate(blocks, axis=0)

    def diag(self, X: FloatArray) -> FloatArray:
        """Return ``s^2 + b^2`` for every row (each RBF has unit variance, ``|w|_1 = 1``)."""
        return np.full(X.shape[0], self.signal_variance + self.constant)

    def evaluator(self, X: FloatArray, scale: FloatArray | None = None) -> Evaluator:
        """Return ``theta -> (K, dK)`` built on the parts' evaluators (same maths as gradient).

        ``scale`` goes into every part's ``K_m``: all outputs are linear in them.
        """
        if all(type(p) is SliceRBF and p.n_params == 1 for p in self.parts):
            return self._rbf_evaluator(X, scale)
        parts = [(part.evaluator(X, scale), part.n_params) for part in self.parts]
        n_part = sum(k for _, k in parts)
        n_logits = len(self.parts) - 1
        n, n_params = X.shape[0], self.n_params
        learn_variance, fixed_variance = self._learn_variance, self.signal_variance
        at_variance = n_part + n_logits
        constant = self._constant_term(scale)

        def evaluate(theta: FloatArray) -> tuple[FloatArray, FloatArray]:
            z = np.zeros(n_logits + 1)
            z[1:] = theta[n_part : n_part + n_logits]
            w = np.exp(z - z.max())
            w /= w.sum()
            s2 = math.exp(theta[at_variance]) if learn_variance else fixed_variance
            dK = np.empty((n_params, n, n))
            kernels, start = [], 0
            for (evaluate_part, k), wm in zip(parts, w, strict=True):
                Km, dKm = evaluate_part(theta[start : start + k])
                np.multiply(dKm, s2 * wm, out=dK[start : start + k])
                kernels.append(Km)
                start += k
            mixture = w[0] * kernels[0]
            for wm, Km in zip(w[1:], kernels[1:], strict=True):
                mixture += wm * Km
            for j in range(1, len(parts)):  # dK / d logit_j = s2 w_j (K_j - mixture)
                np.subtract(kernels[j], mixture, out=dK[n_part + j - 1])
                dK[n_part + j - 1] *= s2 * w[j]
            K = s2 * mixture
            if learn_variance:
                dK[at_variance] = K
            return constant(theta, K, dK), dK

        return evaluate

    def _rbf_evaluator(self, X: FloatArray, scale: FloatArray | None) -> Evaluator:
        """:meth:`evaluator` of learned-length-scale RBF parts, the parts' work inlined.

        ``dK_m = s2 w_m K_m d_m^2 / l_m^2`` is written straight into its slot of ``dK``; at the
        sizes of active learning the number of numpy calls, not their arithmetic, is the cost.
        """
        half_d2 = [-0.5 * part.sq_dist(X) for part in self.parts]  # -d^2 / 2 per modality
        n_parts, n, n_params = len(self.parts), X.shape[0], self.n_params
        learn_variance, fixed_variance = self._learn_variance, self.signal_variance
        at_variance = 2 * n_parts - 1
        constant = self._constant_term(scale)

        def evaluate(theta: FloatArray) -> tuple[FloatArray, FloatArray]:
            if n_parts == 2:  # noqa: PLR2004 - softmax([0, z]) of two modalities
                w1 = 1.0 / (1.0 + math.exp(-theta[n_parts]))
                w = (1.0 - w1, w1)
            else:
                z = np.zeros(n_parts)
                z[1:] = theta[n_parts : 2 * n_parts - 1]
                e = np.exp(z - z.max())
                w = tuple(e / e.sum())
            s2 = math.exp(theta[at_variance]) if learn_variance else fixed_variance
            dK = np.empty((n_params, n, n))
            kernels = []
            for m, H in enumerate(half_d2):
                inv_l2 = math.exp(-2.0 * theta[m])  # 1 / l^2
                Km = np.multiply(H, inv_l2)
                np.exp(Km, out=Km)
                if scale is not None:
                    Km *= scale
                np.multiply(Km, H, out=dK[m])  # K_m (-d^2 / 2)
                dK[m] *= -2.0 * inv_l2 * s2 * w[m]  # s2 w_m K_m d^2 / l^2
                kernels.append(Km)
            mixture = kernels[0] * w[0]
            for m in range(1, n_parts):
                mixture += kernels[m] * w[m]
            for m in range(1, n_parts):  # dK / d logit_m = s2 w_m (K_m - mixture)
                slot = dK[n_parts + m - 1]
                np.subtract(kernels[m], mixture, out=slot)
                slot *= s2 * w[m]
            mixture *= s2
            if learn_variance:
                dK[at_variance] = mixture
            return constant(theta, mixture, dK), dK

        return evaluate

    def _constant_term(
        self, scale: FloatArray | None
    ) -> Callable[[FloatArray, FloatArray, FloatArray], FloatArray]:
        """``(theta, K, dK) -> K + b^2 scale``, writing ``dK/d log b^2`` into the last slot."""
        if self.bias is None:
            return lambda _theta, K, _dK: K
        learn, fixed = self._learn_bias, self.constant
        ones = np.ones(1) if scale is None else scale

        def add(theta: FloatArray, K: FloatArray, dK: FloatArray) -> FloatArray:
            b2 = math.exp(theta[-1]) if learn else fixed
            K += b2 * ones
            if learn:
                dK[-1] = b2 * ones
            return K

        return add


class DependentKernel(Kernel):
    """The dependent-GP transfer kernel over old-object and new-object observations.

    ``K_ij = k(x_i, x_j) * (1 if d_i == d_j else rho)`` where ``d`` is the domain flag in
    column ``flag_column`` of ``X`` (0 = old object, 1 = new object) and ``k`` is the base
    kernel, which must ignore that column (the modality slices never cover it).

    Args:
        base: The multi-modal kernel shared by both domains.
        rho: Transfer coefficient in [0, 1].
        rho_bounds: Box of a learned ``rho`` or ``"fixed"`` (fixed ``rho`` may be 0).
        flag_column: Column of ``X`` holding the domain flag.
    """

    def __init__(
        self,
        base: Kernel,
        rho: float,
        rho_bounds: Bounds = "fixed",
        flag_column: int = -1,
    ) -> None:
        """Store the parameters; see the class docstring."""
        if not 0.0 <= rho <= 1.0 or (rho_bounds != "fixed" and rho <= 0.0):
            msg = f"rho={rho}; it must lie in [0, 1] (and be > 0 when it is learned)"
            raise AtiktError(msg)
        self.base = base
        self.rho = float(rho)
        self.rho_bounds = rho_bounds
        self.flag_column = flag_column
        self._bounds = np.concatenate([base.bounds, _log_bounds(rho_bounds)])  # both (k, 2)
        self._theta: FloatArray | None = None  # theta, computed once (see the property)

    @property
    def learn_rho(self) -> bool:
        """Whether ``rho`` is a free hyperparameter."""
        return self.rho_bounds != "fixed"

    @property
    def theta(self) -> FloatArray:
        """``[base theta..., log rho]`` (the last only when ``rho`` is learned; a copy)."""
        theta = getattr(self, "_theta", None)  # absent from a kernel pickled before the cache
        if theta is None:  # immutable (with_theta makes a new kernel): put together once
            tail = [np.log(self.rho)] if self.learn_rho else []
            theta = self._theta = np.concatenate([self.base.theta, tail])
        return theta.copy()

    @property
    def bounds(self) -> FloatArray:
        """Log-space box of ``theta``."""
        return self._bounds

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the ``theta`` entries."""
        return (*self.base.names, *(["rho"] if self.learn_rho else []))

    def _with_values(self, values: FloatArray) -> Self:
        """Return a copy with the free hyperparameters set from ``values``."""
        n_base = self.base.n_params
        new = self._copy()  # the bounds stay: only the values change
        new._theta = None  # noqa: SLF001 - a copy of this class
        new.base = self.base._with_values(values[:n_base])  # noqa: SLF001
        if self.learn_rho:
            new.rho = min(math.exp(values[n_base]), 1.0)
        return new

    def _cross(self, X: FloatArray, Y: FloatArray | None) -> npt.NDArray[np.bool_]:
        """Return True where the two observations come from different domains."""
        fx = X[:, self.flag_column]
        fy = fx if Y is None else Y[:, self.flag_column]
        return np.asarray(fx[:, None] != fy[None, :])

    def __call__(self, X: FloatArray, Y: FloatArray | None = None) -> FloatArray:
        """Return the block matrix with ``rho`` on the cross-domain entries."""
        return np.where(self._cross(X, Y), self.rho, 1.0) * self.base(X, Y)

    def gradient(self, X: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Return ``K`` and ``dK/dtheta``; ``dK/dlog rho = rho * k`` on cross-domain entries."""
        cross = self._cross(X, None)
        mask = np.where(cross, self.rho, 1.0)
        K_base, dK_base = self.base.gradient(X)
        dK = dK_base * mask
        if self.learn_rho:
            dK = np.concatenate([dK, (np.where(cross, self.rho, 0.0) * K_base)[None]], axis=0)
        return K_base * mask, dK

    def diag(self, X: FloatArray) -> FloatArray:
        """Return the base kernel's diagonal (each point shares its own domain)."""
        return self.base.diag(X)

    def evaluator(self, X: FloatArray, scale: FloatArray | None = None) -> Evaluator:
        """Return ``theta -> (K, dK)`` with the domain mask computed once.

        A fixed ``rho``'s mask is folded into the base kernel's evaluator (``scale``).
        """
        cross = self._cross(X, None)
        n_base = self.base.n_params
        if not self.learn_rho:
            mask = np.where(cross, self.rho, 1.0)
            return self.base.evaluator(X, mask if scale is None else mask * scale)
        evaluate_base = self.base.evaluator(X, scale)

        def evaluate(theta: FloatArray) -> tuple[FloatArray, FloatArray]:
            K_base, dK_base = evaluate_base(theta[:n_base])
            rho = math.exp(theta[n_base])
            K = K_base * np.where(cross, rho, 1.0)
            dK = np.empty((n_base + 1, *K.shape))
            dK[:n_base] = dK_base * np.where(cross, rho, 1.0)
            dK[n_base] = np.where(cross, K, 0.0)  # dK / dlog rho = rho k on cross entries
            return K, dK

        return evaluate


class MultiSourceKernel(Kernel):
    """Dependent-GP kernel over a new object's and several source objects' observations.

    ``K_ab = k(x_a, x_b) * C[d_a, d_b]`` with ``C[d, d] = 1``, ``C[new, j] = rho_j`` and
    ``C[i, j] = rho_i rho_j`` (see the module docstring). The domain flag in ``flag_column``
    is 1 for the new object's observations and ``-j`` for source ``j`` (0, -1, -2, ...), so
    that source 0 carries the :class:`DependentKernel`'s old-object flag 0.

    Args:
        base: The multi-modal kernel shared by all domains (it must ignore the flag column).
        rhos: One transfer coefficient per source, each in [0, 1].
        rho_bounds: Box of every learned ``rho_j`` or ``"fixed"``.
        flag_column: Column of ``X`` holding the domain flag.
    """

    def __init__(
        self,
        base: Kernel,
        rhos: npt.ArrayLike,
        rho_bounds: Bounds = "fixed",
        flag_column: int = -1,
    ) -> None:
        """Store the parameters; see the class docstring."""
        values = np.asarray(rhos, dtype=np.float64).reshape(-1)
        low = 0.0 if rho_bounds == "fixed" else np.nextafter(0.0, 1.0)
        if values.shape[0] == 0 or not np.all((values >= low) & (values <= 1.0)):
            msg = f"rhos={list(values)}: need at least one, each in [0, 1] (> 0 when learned)"
            raise AtiktError(msg)
        self.base = base
        self.rhos = values
        self.rho_bounds = rho_bounds
        self.flag_column = flag_column
        self._bounds = np.vstack(
            [base.bounds, *([_log_bounds(rho_bounds)] * values.shape[0])]
            if rho_bounds != "fixed"
            else [base.bounds]
        )

    @property
    def learn_rho(self) -> bool:
        """Whether the ``rho_j`` are free hyperparameters."""
        return self.rho_bounds != "fixed"

    @property
    def theta(self) -> FloatArray:
        """``[base theta..., log rho_1..log rho_S]`` (the tail only when learned)."""
        tail = np.log(self.rhos) if self.learn_rho else np.zeros(0)
        return np.concatenate([self.base.theta, tail])

    @property
    def bounds(self) -> FloatArray:
        """Log-space box of ``theta``."""
        return self._bounds

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the ``theta`` entries."""
        tail = [f"rho_{j}" for j in range(self.rhos.shape[0])] if self.learn_rho else []
        return (*self.base.names, *tail)

    def _with_values(self, values: FloatArray) -> Self:
        """Return a copy with the free hyperparameters set from ``values``."""
        n_base = self.base.n_params
        new = self._copy()
        new.base = self.base._with_values(values[:n_base])  # noqa: SLF001
        if self.learn_rho:
            new.rhos = np.minimum(np.exp(values[n_base:]), 1.0)
        return new

    def _loadings(self, X: FloatArray) -> tuple[FloatArray, npt.NDArray[np.int64]]:
        """Per row: ``v`` of its domain (1 for the new object) and its source index (-1: new)."""
        flags = X[:, self.flag_column]
        source = np.where(flags == 1.0, -1, np.rint(-flags)).astype(np.int64)
        if np.any(source >= self.rhos.shape[0]) or np.any(source < -1):
            msg = (
                f"domain flags {sorted(set(flags.tolist()))}: need 1 (new object) or 0, -1, .. "
                f"for the {self.rhos.shape[0]} sources"
            )
            raise AtiktError(msg)
        return np.where(source < 0, 1.0, self.rhos[np.maximum(source, 0)]), source

    def mask(self, X: FloatArray, Y: FloatArray | None = None) -> FloatArray:
        """Return ``C[d_a, d_b]`` for the rows of ``X`` and ``Y``, shape (n_X, n_Y)."""
        vx, sx = self._loadings(X)
        vy, sy = (vx, sx) if Y is None else self._loadings(Y)
        return np.where(sx[:, None] == sy[None, :], 1.0, vx[:, None] * vy[None, :])

    def __call__(self, X: FloatArray, Y: FloatArray | None = None) -> FloatArray:
        """Return ``k(X, Y) * C``."""
        return self.mask(X, Y) * self.base(X, Y)

    def _rho_gradients(self, X: FloatArray, K: FloatArray) -> FloatArray:
        """``dK/dlog rho_j = K`` where exactly one of the two rows is of source ``j``."""
        _, source = self._loadings(X)
        dK = np.empty((self.rhos.shape[0], *K.shape))
        for j in range(self.rhos.shape[0]):
            member = source == j
            dK[j] = np.where(member[:, None] != member[None, :], K, 0.0)
        return dK

    def gradient(self, X: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Return ``K`` and ``dK/dtheta``."""
        mask = self.mask(X)
        K_base, dK_base = self.base.gradient(X)
        K = K_base * mask
        dK = dK_base * mask
        if self.learn_rho:
            dK = np.concatenate([dK, self._rho_gradients(X, K)], axis=0)
        return K, dK

    def diag(self, X: FloatArray) -> FloatArray:
        """Return the base kernel's diagonal (``C`` has a unit diagonal)."""
        return self.base.diag(X)

    def evaluator(self, X: FloatArray, scale: FloatArray | None = None) -> Evaluator:
        """Return ``theta -> (K, dK)``; fixed ``rho``s fold their mask into the base's."""
        if not self.learn_rho:
            mask = self.mask(X)
            return self.base.evaluator(X, mask if scale is None else mask * scale)
        return super().evaluator(X, scale)


def _parts(
    slices: Mapping[str, slice], parts: Mapping[str, str] | None, length_scale: float
) -> list[SliceRBF]:
    """Return one unit-variance kernel per modality, of the kind ``parts`` names (RBF default).

    Raises:
        AtiktError: An unknown part kernel.
    """
    chosen = dict(parts or {})
    unknown = sorted({k for k in chosen.values() if k not in PART_KERNELS})
    if unknown:
        msg = f"modality kernels {unknown}: use {PART_KERNELS}"
        raise AtiktError(msg)
    built: list[SliceRBF] = []
    for name, cols in slices.items():
        kind = chosen.get(name, "rbf")
        if kind == "rbf":
            built.append(SliceRBF(cols, length_scale, name=name))
        else:
            nu = MATERN_NUS[0] if kind == "matern32" else MATERN_NUS[1]
            built.append(SliceMatern(cols, length_scale, name=name, nu=nu))
    return built


def modality_kernel(
    slices: Mapping[str, slice],
    *,
    amplitude: bool = True,
    length_scale: float = 1.0,
    variance: float = 1.0,
    bias: float | None = None,
    parts: Mapping[str, str] | None = None,
) -> ModalityKernel:
    """Build the multi-modal kernel for a feature matrix with the given modality slices.

    Args:
        slices: Column slice of each modality (e.g. ``FeatureTransformer.slices_``).
        amplitude: True learns a signal variance ``s^2``; False is the thesis variant.
        length_scale: Initial length scale of every modality.
        variance: Initial signal variance (with ``amplitude``).
        bias: Initial variance ``b^2`` of a learned constant part of the latent function
            (a bias); None: none (the thesis).
        parts: Kernel of each modality (``PART_KERNELS``); a modality not named gets the RBF
            (the thesis).

    Returns:
        The kernel with equal initial weights.
    """
    built = _parts(slices, parts, length_scale)
    return ModalityKernel(built, variance=variance if amplitude else None, bias=bias)


def fusion_kernel(
    slices: Mapping[str, slice],
    *,
    combination: str = "sum",
    parts: Mapping[str, str] | None = None,
    amplitude: bool = True,
) -> ModalityKernel | ProductKernel:
    """Build the multi-modal kernel of a combination: ``sum`` (weighted) or ``product``.

    Args:
        slices: Column slice of each modality.
        combination: ``COMBINATIONS``: ``sum`` (:func:`modality_kernel`) or ``product``
            (:class:`ProductKernel`).
        parts: Kernel of each modality (``PART_KERNELS``; RBF where not named).
        amplitude: Learn a signal variance.

    Raises:
        AtiktError: An unknown combination or part kernel.
    """
    if combination not in COMBINATIONS:
        msg = f"combination={combination!r}; use one of {COMBINATIONS}"
        raise AtiktError(msg)
    if combination == "product":
        return ProductKernel(_parts(slices, parts, 1.0), variance=1.0 if amplitude else None)
    return modality_kernel(slices, amplitude=amplitude, parts=parts)
