"""A prior on the modality weights from the sensors' declared noise (no labels needed).

With one training sample per object the evidence cannot tell which modality separates the
objects (every one-vs-all problem has a single positive). What the rig knows without labels is
how large each feature's spread over the group is *relative to the noise its sensor is declared
to have*: a feature whose values differ by a few noise widths can separate little, one whose
values differ by hundreds of noise widths may. The declared noise is a lower bound on the
repeat-to-repeat spread of an object (the rig adds its own), so the ratio is an upper bound on
a modality's separating power, which is what a prior can use.

- :func:`feature_noise`: the declared noise of each column of a raw feature block (standard
  deviation in the feature's units), derived from the sensor's declared noise of one sample;
  NaN where the feature's noise is not derived (ratios such as Hjorth mobility, the thermal
  gradient, whose noise depends on the sample spacing).
- :func:`noise_logits`: modality-weight logits ``log(SNR_m^2 / SNR_1^2)`` (weights proportional
  to each block's signal-to-noise power ratio), where ``SNR_m^2`` is the mean over the block's
  declared columns of ``Var_j / noise_j^2`` on the training observations.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from atikt.errors import AtiktError

if TYPE_CHECKING:
    from collections.abc import Collection, Mapping, Sequence

FloatArray = npt.NDArray[np.float64]


def _texture_axes(width: int) -> int:
    """Return the number of Hjorth activity columns of a texture block of ``width`` values.

    Per axis: ``3 a + a (a - 1) / 2`` values for ``a`` axes (12 for 3); averaged over axes: 4
    (3 for one axis); the activities come first either way.

    Raises:
        AtiktError: No texture layout has that width.
    """
    if width in {3, 4}:
        return 1
    for axes in range(2, 16):
        if 3 * axes + axes * (axes - 1) // 2 == width:
            return axes
    msg = f"texture block of {width} values: not a layout of atikt.texture; recompute features"
    raise AtiktError(msg)


def feature_noise(block: str, width: int, sensor_noise: float) -> FloatArray:
    """Return the declared noise (sd) of each column of a raw feature block.

    Args:
        block: Feature block name (``force``, ``texture``, ``thermal``).
        width: Number of columns of the block.
        sensor_noise: Declared noise (sd) of one sample of the sensor the block comes from,
            in the sensor's units (N, m/s^2, C); 0 or less: not declared.

    Returns:
        Shape (width,) float64; NaN where not derived:

        - force (mean normal force): the sensor's noise (an accuracy does not average out);
        - texture: the Hjorth activities (variances of the acceleration) ``noise^2``, the
          variance the noise alone has; mobility, complexity and correlations NaN;
        - thermal ``[T, dT]``: ``noise`` for the temperatures, NaN for the gradient.

    Raises:
        AtiktError: Unknown block or a texture width of no known layout.
    """
    out = np.full(width, np.nan)
    if not sensor_noise > 0:
        return out
    if block == "force":
        out[:] = sensor_noise
    elif block == "texture":
        out[: _texture_axes(width)] = sensor_noise**2
    elif block == "thermal":
        out[: width // 2] = sensor_noise
    else:
        msg = f"feature block {block!r}: no noise model; use force, texture or thermal"
        raise AtiktError(msg)
    return out


def signal_to_noise(raw: FloatArray, noise: FloatArray) -> float:
    """Return a block's mean signal-to-noise power ratio ``mean_j Var_j / noise_j^2``.

    Args:
        raw: Training observations of the block, shape (n, d).
        noise: Declared noise per column, shape (d,), NaN where undeclared.

    Returns:
        The ratio over the declared columns; NaN when none is declared.
    """
    declared = np.isfinite(noise) & (noise > 0)
    if not np.any(declared):
        return float("nan")
    variance = raw[:, declared].var(axis=0)
    return float(np.mean(variance / noise[declared] ** 2))


def noise_logits(
    blocks: Mapping[str, FloatArray],
    noise: Mapping[str, FloatArray],
    modalities: Sequence[str],
    bounds: tuple[float, float],
    controlled: Collection[str] = (),
) -> FloatArray | None:
    """Return modality-weight logits ``log(SNR_m^2 / SNR_1^2)`` relative to the first modality.

    A modality without declared noise gets the geometric mean of the declared ones (a neutral
    weight); a declared one whose training spread is zero gets the lower bound. A block the
    action itself sets (``controlled``: e.g. the force of a force-controlled press) has
    ``SNR^2 = 1``: its whole spread is the controller's, none of it the objects'.

    Args:
        blocks: Raw training observations per block, shape (n, d_m) each.
        noise: Declared noise per column of each block (:func:`feature_noise`).
        modalities: The kernel's modalities in order (the first is the reference).
        bounds: Box of the logits; the result is clipped to it.
        controlled: Blocks whose values the action sets.

    Returns:
        Shape (len(modalities) - 1,), or None when no modality declares its noise.
    """
    ratios = np.array(
        [
            1.0
            if m in controlled
            else signal_to_noise(blocks[m], noise[m])
            if m in noise
            else float("nan")
            for m in modalities
        ]
    )
    declared = np.isfinite(ratios)
    if not np.any(declared):
        return None
    floor = np.exp(bounds[0])  # a zero spread: as little weight as the box allows
    logs = np.log(np.maximum(ratios[declared], floor * ratios[declared].max() + 1e-300))
    filled = np.full(ratios.shape, float(np.mean(logs)))
    filled[declared] = logs
    return np.asarray(np.clip(filled[1:] - filled[0], bounds[0], bounds[1]), dtype=np.float64)


def noise_length_scales(logits: FloatArray, bounds: FloatArray) -> FloatArray:
    """Return log length scales of a product kernel's parts from :func:`noise_logits`.

    The product has no weights: a modality is muted by a long length scale (its factor tends
    to 1). The modality of the largest signal-to-noise ratio keeps the unit length scale; one
    whose ``SNR^2`` is ``r`` times smaller gets ``l = sqrt(r)`` (distances in its normalised
    block count ``sqrt(r)`` times less), clipped to the box.

    Args:
        logits: ``log(SNR_m^2 / SNR_1^2)`` of modalities 2..M (shape (M - 1,)).
        bounds: Box of the log length scales, shape (M, 2).

    Returns:
        Shape (M,) log length scales.
    """
    logs = np.concatenate([[0.0], logits])
    return np.asarray(np.clip(0.5 * (logs.max() - logs), bounds[:, 0], bounds[:, 1]))
