"""Tactile features of one exploratory action and their training-set normalisation.

Feng, Kaboli & Cheng, "Active tactile instance knowledge transfer" (TUM 2017), table "actions,
feedbacks, features", following Kaboli et al.'s robust tactile descriptors:

- stiffness: mean normal force over all force sensors and the hold samples;
- texture: Hjorth activity, mobility and complexity of the acceleration per axis, averaged over
  cells, plus the mean linear correlation of the axis pairs xy, yz, xz (``[Act, Mob, Comp,
  Lcorr]``);
- thermal: the mean temperature sequence over sensors and its gradient, ``[T, dT]``, resampled to
  a fixed number of points so that every duration yields the same length, then reduced by a PCA
  fitted on training observations only (:class:`FeatureTransformer`).

Which blocks an observation has is the caller's choice (the recording contract assigns them
to action kinds: the thesis gives pressing and static contact force + thermal, sliding texture
+ thermal); an observation carries any subset of :data:`FEATURE_BLOCKS`, and every function here
works with the blocks present. All functions take numpy arrays and never see a file.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Final, Self

import numpy as np
import numpy.typing as npt
import scipy.linalg

from atikt.errors import AtiktError, NotFittedError, NumericalError

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence

FloatArray = npt.NDArray[np.float64]

FEATURE_BLOCKS: Final = ("force", "texture", "thermal")
"""Feature blocks atikt computes (one function each), in the column order of every matrix."""

SEQUENCE_MODALITIES: Final = frozenset({"thermal"})
"""Blocks that are sequences: normalised per half and reduced by PCA (the others z-scored)."""

AXIS_PAIRS: Final = ((0, 1), (1, 2), (0, 2))
"""Axis pairs of the linear-correlation feature: xy, yz, xz."""

TEXTURE_NAMES: Final = (
    *(f"activity_{a}" for a in "xyz"),
    *(f"mobility_{a}" for a in "xyz"),
    *(f"complexity_{a}" for a in "xyz"),
    "lcorr_xy",
    "lcorr_yz",
    "lcorr_xz",
)
"""Names of the per-axis texture descriptor returned by :func:`texture`."""

_TINY: Final = 1e-300


def _as_float_array(name: str, value: npt.ArrayLike, ndim: int) -> FloatArray:
    """Convert ``value`` to a finite float64 array with ``ndim`` dimensions.

    Raises:
        AtiktError: Wrong number of dimensions, no samples, or non-finite values.
    """
    array = np.asarray(value, dtype=np.float64)
    if array.ndim != ndim:
        msg = f"{name}: expected a {ndim}-d array, got shape {array.shape}; check the slicing"
        raise AtiktError(msg)
    if array.shape[0] == 0:
        msg = f"{name}: no samples; cut the signal to a non-empty execute phase"
        raise AtiktError(msg)
    if not np.all(np.isfinite(array)):
        msg = f"{name}: contains NaN or inf; drop or interpolate invalid samples first"
        raise AtiktError(msg)
    return array


def _safe_ratio(numerator: FloatArray, denominator: FloatArray) -> FloatArray:
    """Return ``numerator / denominator`` with 0 where the denominator is 0."""
    out = np.zeros(np.broadcast(numerator, denominator).shape)
    np.divide(numerator, denominator, out=out, where=denominator > _TINY)
    return out


def stiffness(force: npt.ArrayLike) -> FloatArray:
    """Stiffness feature: mean normal force over all sensors and samples.

    Args:
        force: Normal forces in N, shape (n_samples, n_cells, n_sensors) float; the execute
            (hold) phase of a press or static action.

    Returns:
        Shape (1,) float64: the mean force in N.

    Raises:
        AtiktError: ``force`` is not 3-d, empty or not finite.
    """
    array = _as_float_array("force", force, 3)
    return np.array([array.mean()])


def hjorth(signal: npt.ArrayLike, axis: int = 0) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Hjorth parameters of signals along ``axis`` (Hjorth 1970).

    Activity is the population variance ``Var(x)``; mobility ``sqrt(Var(dx) / Var(x))`` with
    first differences ``dx``; complexity ``Mob(dx) / Mob(x)``. A constant signal has mobility 0
    and complexity 0 (the ratios are defined as 0 where a variance is 0).

    Args:
        signal: Float array; ``axis`` indexes time, every other axis is an independent signal.
        axis: The time axis.

    Returns:
        Activity, mobility and complexity, each of the signal's shape without ``axis``.
    """
    x = np.asarray(signal, dtype=np.float64)
    dx = np.diff(x, axis=axis)
    ddx = np.diff(dx, axis=axis)
    var_x = x.var(axis=axis)
    var_dx = dx.var(axis=axis) if dx.shape[axis] else np.zeros_like(var_x)
    var_ddx = ddx.var(axis=axis) if ddx.shape[axis] else np.zeros_like(var_x)
    mobility = np.sqrt(_safe_ratio(var_dx, var_x))
    mobility_dx = np.sqrt(_safe_ratio(var_ddx, var_dx))
    complexity = _safe_ratio(mobility_dx, mobility)
    return var_x, mobility, complexity


def linear_correlation(a: npt.ArrayLike, b: npt.ArrayLike, axis: int = 0) -> FloatArray:
    """Pearson correlation of paired signals along ``axis``; 0 where either is constant.

    Args:
        a: Float array; ``axis`` indexes time.
        b: Float array of the same shape.
        axis: The time axis.

    Returns:
        Correlations in [-1, 1], the shape of ``a`` without ``axis``.
    """
    x = np.asarray(a, dtype=np.float64)
    y = np.asarray(b, dtype=np.float64)
    xc = x - x.mean(axis=axis, keepdims=True)
    yc = y - y.mean(axis=axis, keepdims=True)
    covariance = (xc * yc).mean(axis=axis)
    scale = np.sqrt(xc.var(axis=axis) * yc.var(axis=axis))
    return np.clip(_safe_ratio(covariance, scale), -1.0, 1.0)


def _axis_pairs(n_axes: int) -> tuple[tuple[int, int], ...]:
    """Return the axis pairs of the correlation feature: xy, yz, xz for 3 axes (thesis order)."""
    if n_axes == len(AXIS_PAIRS):
        return AXIS_PAIRS
    return tuple(itertools.combinations(range(n_axes), 2))


def texture(acceleration: npt.ArrayLike, *, per_axis: bool = True) -> FloatArray:
    """Texture descriptor ``[Act, Mob, Comp, Lcorr]`` of a sliding action.

    Hjorth parameters are computed for every cell and axis and averaged over cells; the linear
    correlation of every axis pair (xy, yz, xz for three axes) is computed per cell and
    averaged over cells. A single-axis vibration sensor has no pairs: ``[Act, Mob, Comp]``.

    Args:
        acceleration: Shape (n_samples, n_cells, n_axes) float, m/s^2; the execute (sliding)
            phase. Three axes x, y, z on the thesis's skin; one on a single-axis sensor.
        per_axis: True keeps the axes apart (for 3 axes 12 values, named by
            :data:`TEXTURE_NAMES`: Act x/y/z, Mob x/y/z, Comp x/y/z, Lcorr xy/yz/xz); False
            also averages over the axes and the pairs (4 values, 3 for one axis).

    Returns:
        Shape (3 * n_axes + n_pairs,) or (4,) float64 ((3,) for one axis).

    Raises:
        AtiktError: Wrong shape, fewer than 3 samples, or non-finite values.
    """
    acc = _as_float_array("acceleration", acceleration, 3)
    if acc.shape[0] < len("xyz"):
        msg = f"acceleration: expected shape (n_samples >= 3, n_cells, n_axes), got {acc.shape}"
        raise AtiktError(msg)
    activity, mobility, complexity = (p.mean(axis=0) for p in hjorth(acc, axis=0))
    pairs = _axis_pairs(acc.shape[2])
    lcorr = np.array([linear_correlation(acc[:, :, i], acc[:, :, j]).mean() for i, j in pairs])
    if per_axis:
        return np.concatenate([activity, mobility, complexity, lcorr])
    means = [activity.mean(), mobility.mean(), complexity.mean()]
    return np.array(means + ([lcorr.mean()] if pairs else []))


def thermal_sequence(
    temperature: npt.ArrayLike, *, n_points: int = 20, rate_hz: float = 20.0
) -> FloatArray:
    """Thermal feature ``[T, dT]`` before the PCA.

    The temperature is averaged over the sensors, resampled linearly to ``n_points`` equally
    spaced instants spanning the sequence, and its gradient (central differences, C/s) is
    appended.

    Args:
        temperature: Shape (n_samples >= 2, n_sensors) float, degrees C; the execute phase
            (every temperature sensor of every cell, e.g. two thermistors of a probe).
        n_points: Length of the resampled sequence (>= 2); fixes the feature length for every
            action duration.
        rate_hz: Sample rate of ``temperature``, Hz; scales the gradient to C/s.

    Returns:
        Shape (2 * n_points,) float64: resampled mean temperature, then its gradient.

    Raises:
        AtiktError: Wrong shape, fewer than 2 samples, or bad ``n_points``/``rate_hz``.
    """
    temp = _as_float_array("temperature", temperature, 2)
    if temp.shape[0] < 2 or n_points < 2 or not rate_hz > 0:  # noqa: PLR2004
        msg = (
            f"temperature: need >= 2 samples, n_points >= 2 and rate_hz > 0, got "
            f"{temp.shape[0]} samples, n_points={n_points}, rate_hz={rate_hz}"
        )
        raise AtiktError(msg)
    mean = temp.mean(axis=1)
    t_source = np.arange(mean.shape[0]) / rate_hz
    t_target = np.linspace(0.0, t_source[-1], n_points)
    resampled = np.interp(t_target, t_source, mean)
    gradient = np.gradient(resampled, t_target)
    return np.concatenate([resampled, gradient])


@dataclass(frozen=True, slots=True, eq=False)
class RawFeatures:
    """Raw (unstandardised, pre-PCA) feature vectors of one observation.

    Attributes:
        kind: Label of the observations that can be stacked together (the action's kind).
        blocks: Feature block name (one of :data:`FEATURE_BLOCKS`) -> vector; the blocks the
            observation has, e.g. ``force`` shape (1,), ``texture`` (12,), ``thermal``
            (2 * n_points,).
    """

    kind: str
    blocks: Mapping[str, FloatArray]

    @property
    def modalities(self) -> tuple[str, ...]:
        """Return the blocks the observation has, in :data:`FEATURE_BLOCKS` order."""
        return tuple(m for m in FEATURE_BLOCKS if m in self.blocks)

    def modality(self, name: str) -> FloatArray:
        """Return the vector of one block.

        Raises:
            AtiktError: The observation has no such block (e.g. texture of a press).
        """
        value = self.blocks.get(name)
        if value is None:
            msg = f"a {self.kind!r} observation has no {name!r} features; it has {self.modalities}"
            raise AtiktError(msg)
        return value

    def __reduce__(self) -> tuple[Any, tuple[str, dict[str, FloatArray]]]:
        """Pickle (and deep-copy) through a plain dict: a mapping proxy cannot be pickled."""
        return _raw_features, (self.kind, dict(self.blocks))


def _raw_features(kind: str, blocks: dict[str, FloatArray]) -> RawFeatures:
    """Rebuild a pickled :class:`RawFeatures` with read-only blocks."""
    return RawFeatures(kind, MappingProxyType({k: _frozen(v) for k, v in blocks.items()}))


def _frozen(array: FloatArray) -> FloatArray:
    """Return ``array`` marked read-only."""
    array.setflags(write=False)
    return array


def _force_block(data: npt.ArrayLike, _rate_hz: float, **_: Any) -> FloatArray:  # noqa: ANN401
    """The stiffness block of a force signal."""
    return stiffness(data)


def _texture_block(
    data: npt.ArrayLike,
    _rate_hz: float,
    *,
    texture_per_axis: bool,
    **_: Any,  # noqa: ANN401
) -> FloatArray:
    """The texture block of an acceleration signal."""
    return texture(data, per_axis=texture_per_axis)


def _thermal_block(
    data: npt.ArrayLike,
    rate_hz: float,
    *,
    n_thermal_points: int,
    **_: Any,  # noqa: ANN401
) -> FloatArray:
    """The thermal block of a temperature signal (cells and sensors flattened)."""
    array = np.asarray(data, dtype=np.float64)
    flat = array.reshape(array.shape[0], -1) if array.ndim == 3 else array  # noqa: PLR2004
    return thermal_sequence(flat, n_points=n_thermal_points, rate_hz=rate_hz)


#: Feature block -> its extractor ``(samples, rate_hz, **options) -> vector``.
_EXTRACTORS: Final[Mapping[str, Callable[..., FloatArray]]] = MappingProxyType(
    {"force": _force_block, "texture": _texture_block, "thermal": _thermal_block}
)


def extract_features(
    kind: str,
    signals: Mapping[str, tuple[npt.ArrayLike, float]],
    *,
    n_thermal_points: int = 20,
    texture_per_axis: bool = True,
) -> RawFeatures:
    """Extract the raw features of one observation (one action's execute phase).

    Args:
        kind: Label of the observation (the action's kind).
        signals: Feature block -> (samples, rate in Hz) of the sensor that feeds it:
            ``force``: (n, n_cells, n_sensors) N; ``texture``: (n, n_cells, n_axes) m/s^2;
            ``thermal``: (n, n_cells, n_sensors) or (n, n_sensors) degrees C.
        n_thermal_points: Resampled length of the thermal sequence (same for all actions that
            are compared).
        texture_per_axis: See :func:`texture`.

    Returns:
        The raw vector of every block given, read-only.

    Raises:
        AtiktError: No signals, an unknown block, or a malformed array.
    """
    if not signals or set(signals) - set(FEATURE_BLOCKS):
        msg = f"signals {sorted(signals)}: give a non-empty subset of {FEATURE_BLOCKS}"
        raise AtiktError(msg)
    options = {"texture_per_axis": texture_per_axis, "n_thermal_points": n_thermal_points}
    blocks = {
        name: _frozen(_EXTRACTORS[name](*signals[name], **options))
        for name in FEATURE_BLOCKS
        if name in signals
    }
    return RawFeatures(kind, MappingProxyType(blocks))


def _check_observations(observations: Sequence[RawFeatures]) -> str:
    """Return the common kind of ``observations``.

    Raises:
        AtiktError: No observations, or observations of different kinds.
    """
    if len(observations) == 0:
        msg = "no observations; pass at least one RawFeatures"
        raise AtiktError(msg)
    kinds = {obs.kind for obs in observations}
    if len(kinds) != 1:
        msg = f"observations of different kinds {sorted(kinds)}; pass one action's observations"
        raise AtiktError(msg)
    held = {obs.modalities for obs in observations}
    if len(held) != 1:
        msg = f"observations with different feature blocks {sorted(held)}; give every one the same"
        raise AtiktError(msg)
    return kinds.pop()


@dataclass(frozen=True, slots=True, eq=False)
class StackedFeatures:
    """Observations of one action stacked per modality, for repeated transforms.

    A learner maps the same prior observations into a new feature space at every update;
    stacking them once (:func:`stack_features`) saves the per-observation work.

    Attributes:
        kind: Action kind of every observation.
        blocks: Modality name -> matrix (n, d) of that modality's vectors.
    """

    kind: str
    blocks: Mapping[str, FloatArray]

    def __len__(self) -> int:
        """Number of observations."""
        return int(next(iter(self.blocks.values())).shape[0])


def stack_features(observations: Sequence[RawFeatures]) -> StackedFeatures:
    """Stack every modality of one action's observations.

    Raises:
        AtiktError: No observations, mixed kinds or vectors of different lengths.
    """
    kind = _check_observations(observations)
    return StackedFeatures(kind, {m: _stack(observations, m) for m in observations[0].modalities})


def _stack(observations: Sequence[RawFeatures], modality: str) -> FloatArray:
    """Stack one modality of all observations into shape (n, d).

    Raises:
        AtiktError: Vectors of different lengths (e.g. different ``n_thermal_points``).
    """
    vectors = [obs.modality(modality) for obs in observations]
    lengths = {v.shape[0] for v in vectors}
    if len(lengths) != 1:
        msg = (
            f"{modality} vectors of different lengths {sorted(lengths)}; extract every "
            "observation with the same parameters"
        )
        raise AtiktError(msg)
    return np.vstack(vectors)


def _svd(z: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Thin SVD of ``z``; LAPACK's divide and conquer (gesdd) first, then the QR method.

    gesdd occasionally fails to converge on finite, well-scaled matrices (a known LAPACK
    behaviour); gesvd is slower but robust.

    Raises:
        NumericalError: Both drivers failed (e.g. non-finite values).
    """
    try:
        u, singular, vt = np.linalg.svd(z, full_matrices=False)
    except np.linalg.LinAlgError:
        try:
            u, singular, vt = scipy.linalg.svd(z, full_matrices=False, lapack_driver="gesvd")
        except (np.linalg.LinAlgError, ValueError) as err:
            msg = f"thermal PCA: SVD of a {z.shape} matrix failed ({err}); check for NaN features"
            raise NumericalError(msg) from err
    return u, singular, vt


class FeatureTransformer:
    """Standardise raw features and reduce the thermal sequence by PCA, fitted on training data.

    Every statistic (means, scales, principal axes) comes from the observations given to
    :meth:`fit`; :meth:`transform` applies them unchanged to any other observation. Each
    modality block of the output has unit total variance on the training set, so one RBF length
    scale near 1 is a sensible start for every modality:

    - force / texture: every column z-scored, the block divided by ``sqrt(n_columns)``;
    - thermal: the ``T`` half and the ``dT`` half of the sequence are centred per column and
      divided by their own pooled standard deviation (keeping the shape of the sequences), then
      projected on the first ``n_thermal_components`` principal axes; the scores are divided by
      the square root of their total variance. With fewer training observations than
      components, the missing components are zero columns, so the output width never changes.

    Args:
        modalities: Modalities to keep, in any order (output order follows
            :data:`FEATURE_BLOCKS`); None keeps every block the training observations have.
        n_thermal_components: Principal components of the thermal sequence (thesis: 10).
        min_std: A standard deviation below ``min_std`` times the magnitude of the column's
            mean counts as zero: the column is constant and is only centred. Relative, so that
            features in tiny or huge units are treated alike.

    Attributes:
        kind_: Action kind of the training observations.
        modalities_: Modalities in output order.
        slices_: Column slice of each modality in the output matrix.
        n_features_out_: Output width.
        means_: Per-modality column means (raw space).
        scales_: Per-modality column divisors (raw space).
        components_: Thermal principal axes, shape (n_thermal_components, 2 * n_points).
        thermal_scale_: Divisor of the thermal scores.
        explained_variance_: Variance of each thermal score on the training set.
    """

    def __init__(
        self,
        modalities: Sequence[str] | None = None,
        n_thermal_components: int = 10,
        min_std: float = 1e-8,
    ) -> None:
        """Store the parameters; see the class docstring."""
        self.modalities = modalities
        self.n_thermal_components = n_thermal_components
        self.min_std = min_std

    def _resolve_modalities(self, kind: str, available: tuple[str, ...]) -> tuple[str, ...]:
        """Return the modalities to use, in output order.

        Raises:
            AtiktError: A requested modality is not among the observations' blocks.
        """
        if self.modalities is None:
            return available
        unknown = set(self.modalities) - set(available)
        if unknown or not self.modalities:
            msg = (
                f"modalities {list(self.modalities)} not available for {kind!r} actions; "
                f"choose a non-empty subset of {available}"
            )
            raise AtiktError(msg)
        return tuple(m for m in FEATURE_BLOCKS if m in self.modalities)

    def fit(self, observations: Sequence[RawFeatures]) -> Self:
        """Learn the statistics from training observations of one action.

        Args:
            observations: Training observations, all of the same kind.

        Returns:
            self.

        Raises:
            AtiktError: No observations, mixed kinds, or a bad ``n_thermal_components``.
        """
        return self._fit_stacked(stack_features(observations))

    def _fit_stacked(self, stacked: StackedFeatures) -> Self:
        """Fit on stacked training observations (see :meth:`fit`)."""
        if self.n_thermal_components < 1:
            msg = f"n_thermal_components={self.n_thermal_components}; use at least 1"
            raise AtiktError(msg)
        self.kind_ = stacked.kind
        held = tuple(m for m in FEATURE_BLOCKS if m in stacked.blocks)
        self.modalities_ = self._resolve_modalities(self.kind_, held)
        self.means_: dict[str, FloatArray] = {}
        self.scales_: dict[str, FloatArray] = {}
        self.slices_: dict[str, slice] = {}
        start = 0
        for modality in self.modalities_:
            width = self._fit_modality(modality, stacked.blocks[modality])
            self.slices_[modality] = slice(start, start + width)
            start += width
        self.n_features_out_ = start
        return self

    def _fit_modality(self, modality: str, raw: FloatArray) -> int:
        """Fit the statistics of one modality block and return its output width."""
        mean = raw.mean(axis=0)
        centred = raw - mean
        if modality not in SEQUENCE_MODALITIES:
            std = centred.std(axis=0)
            informative = std > self.min_std * np.maximum(np.abs(mean), _TINY)
            scale = np.where(informative, std, 1.0) * np.sqrt(raw.shape[1])
            self.means_[modality], self.scales_[modality] = mean, scale
            return int(raw.shape[1])
        half = raw.shape[1] // 2
        parts = (slice(0, half), slice(half, None))
        pooled = [float(np.sqrt(np.mean(centred[:, part] ** 2))) for part in parts]
        size = [max(float(np.abs(mean[part]).max()), _TINY) for part in parts]
        pooled = [p if p > self.min_std * m else 1.0 for p, m in zip(pooled, size, strict=True)]
        scale = np.concatenate([np.full(half, pooled[0]), np.full(raw.shape[1] - half, pooled[1])])
        self.means_[modality], self.scales_[modality] = mean, scale
        self._fit_pca(centred / scale)
        return self.n_thermal_components

    def _fit_pca(self, z: FloatArray) -> None:
        """Fit the principal axes of the centred, scaled thermal block ``z`` (n, d)."""
        n, d = z.shape
        _, singular, vt = _svd(z)
        keep = singular > max(singular.max(initial=0.0), _TINY) * 1e-10
        signs = np.sign(vt[np.arange(vt.shape[0]), np.argmax(np.abs(vt), axis=1)])
        vt = vt * np.where(signs == 0, 1.0, signs)[:, None]
        components = np.zeros((self.n_thermal_components, d))
        variance = np.zeros(self.n_thermal_components)
        k = min(self.n_thermal_components, int(keep.sum()))
        components[:k] = vt[:k]
        variance[:k] = singular[:k] ** 2 / n
        total = variance.sum()
        self.components_ = components
        self.explained_variance_ = variance
        self.thermal_scale_ = float(np.sqrt(total)) if total > self.min_std**2 else 1.0

    def transform(self, observations: Sequence[RawFeatures] | StackedFeatures) -> FloatArray:
        """Map observations to the standardised feature matrix.

        Args:
            observations: Observations of the kind the transformer was fitted on, or such
                observations stacked by :func:`stack_features`.

        Returns:
            Shape (n, n_features_out_) float64; columns per modality as in ``slices_``.

        Raises:
            NotFittedError: ``fit`` was not called.
            AtiktError: Observations of another kind or of other vector lengths.
        """
        if not hasattr(self, "slices_"):
            msg = "FeatureTransformer is not fitted; call fit(training observations) first"
            raise NotFittedError(msg)
        if isinstance(observations, StackedFeatures):
            stacked = observations
        else:
            kind = _check_observations(observations)
            self._check_kind(kind)
            stacked = StackedFeatures(kind, {m: _stack(observations, m) for m in self.modalities_})
        self._check_kind(stacked.kind)
        columns = [self._transform_modality(m, stacked.blocks[m]) for m in self.modalities_]
        return np.asarray(np.hstack(columns), dtype=np.float64)

    def _check_kind(self, kind: str) -> None:
        """Raise AtiktError for observations of another kind than the training ones."""
        if kind != self.kind_:
            msg = f"transformer fitted on {self.kind_!r} observations, got {kind!r} ones"
            raise AtiktError(msg)

    def _transform_modality(self, modality: str, raw: FloatArray) -> FloatArray:
        """Standardise (and for thermal, project) one modality block.

        Raises:
            AtiktError: The block's width differs from the training data.
        """
        mean = self.means_[modality]
        if raw.shape[1] != mean.shape[0]:
            msg = (
                f"{modality} vectors have {raw.shape[1]} values, the training data had "
                f"{mean.shape[0]}; extract with the same parameters"
            )
            raise AtiktError(msg)
        z = (raw - mean) / self.scales_[modality]
        if modality not in SEQUENCE_MODALITIES:
            return z
        return (z @ self.components_.T) / self.thermal_scale_

    def fit_transform(self, observations: Sequence[RawFeatures]) -> FloatArray:
        """Fit on ``observations`` and return their feature matrix."""
        stacked = stack_features(observations)
        return self._fit_stacked(stacked).transform(stacked)
