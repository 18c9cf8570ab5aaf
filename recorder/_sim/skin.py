"""The simulated skin patch: hexagonal cells, their sensors and the sensors' imperfections.

The thesis's patch has 7 cells, a centre cell and a ring of 6 (the default); a smaller skin
(e.g. a 3-cell fingertip) keeps the first cells of that patch, or lies in a row (``SkinLayout``).

Per cell (HEX-o-SKIN style): 3 normal-force sensors, 1 temperature sensor (LM71), 1 three-axis
accelerometer (BMA250) and 1 proximity sensor (VCNL4010). The patch is flat; its frame is the
robot's tool frame: x along the sliding direction, z along the outward normal (towards the
object). Each cell's accelerometer axes are rotated about z by the cell's mounting angle.

Sensor models follow the datasheets named in CALIBRATION.md: BMA250 10 bit at +-2 g (256 LSB/g);
LM71 0.03125 C resolution with per-sensor offsets inside its +-1.5 C accuracy; force accuracy
about 0.05 N; VCNL4010 16-bit counts, up to 200 mm.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final

import numpy as np
from numpy.typing import NDArray

from schemas import VOCABULARY

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]

N_CELLS: Final = 7
"""Cells of the thesis's patch (the default layout)."""
FORCE_SENSORS: Final = 3
CELL_PITCH_M: Final = 0.015
"""Centre-to-centre distance of neighbouring cells."""
FORCE_SENSOR_RADIUS_M: Final = 0.0045
"""Distance of a cell's force sensors from its centre."""

GRAVITY_M_S2: Final = 9.81
ACC_LSB_M_S2: Final = GRAVITY_M_S2 / 256.0
"""BMA250 resolution at +-2 g: 256 LSB/g."""
ACC_MIN_LSB: Final = -512
ACC_MAX_LSB: Final = 511
ACC_NOISE_M_S2: Final = VOCABULARY.modalities["acceleration"].noise
"""Accelerometer noise, about one LSB RMS at 1 kHz bandwidth: the contract's declared noise, so
that the fusion study's noise prior and the simulated skin cannot disagree."""
ACC_BIAS_M_S2: Final = 0.2
"""Spread of the accelerometers' zero-g offsets."""

TEMP_LSB_C: Final = 0.03125
"""LM71 resolution."""
TEMP_ACCURACY_C: Final = 1.5
"""LM71 accuracy: bound of the per-sensor offsets."""
TEMP_OFFSET_C: Final = 0.4
"""Spread of the per-sensor offsets (typical, inside the accuracy bound)."""
TEMP_NOISE_C: Final = VOCABULARY.modalities["temperature"].noise
"""Temperature noise of one sample: the contract's declared noise."""
TEMP_DRIFT_C_S: Final = 0.002
"""Spread of a temperature sensor's drift rate during one execution."""
TEMP_AGEING_C: Final = 0.003
"""Spread of a temperature sensor's offset change per trial (round) of a session, C: the
heated thermistor of the real probe data (shared/data/thermal-ambiguity-toh) reads 0.0020 to
0.0032 C higher per run before contact over its 30 runs (CALIBRATION.md)."""

FORCE_LSB_N: Final = 0.001
"""Resolution of the force channel after the driver's calibration."""
FORCE_GAIN_SPREAD: Final = 0.03
"""Spread of the force sensors' gain errors (the 0.05 N accuracy at about 1.5 N per sensor)."""
FORCE_GAIN_DRIFT: Final = 0.02
"""Spread of the common gain change between executions (the sensors' temperature drift)."""
FORCE_NOISE_N: Final = VOCABULARY.modalities["force"].noise
"""Force noise of one sample: the contract's declared noise."""
FORCE_OFFSET_N: Final = 0.002
"""Spread of the residual offsets left after the driver tares the sensors."""
FORCE_DRIFT_N_S: Final = 0.0005
"""Spread of a force sensor's drift rate during one execution."""
FORCE_AGEING: Final = 0.0015
"""Spread of a force sensor's relative gain change per trial (round) of a session: over the 20
rounds of a dataset the gains age by up to 3 % (1 sd), the sensors' 0.05 N accuracy at 1.5 N
(CALIBRATION.md)."""

PROXIMITY_RANGE_M: Final = 0.2
PROXIMITY_FULL_SCALE: Final = 65535
PROXIMITY_NEAR_M: Final = 0.01
"""Distance scale of the inverse-square response: counts = full scale * r * (d0 / (d + d0))^2."""
PROXIMITY_NOISE_COUNTS: Final = 3.0
NOMINAL_REFLECTANCE: Final = 0.6
"""Reflectance the driver assumes when it converts counts to distance."""


LAYOUTS: Final = ("hex", "row")
"""Cell arrangements: ``hex``, the thesis's patch (centre cell, then the ring of 6
counter-clockwise from 30 degrees: its first 3 cells are a compact triangle); ``row``, cells in
a line across the sliding direction (a finger's phalanx)."""


@dataclass(frozen=True, slots=True)
class SkinLayout:
    """The shape of the skin: how many cells and where they lie.

    Attributes:
        cells: Number of cells, 1 to 7 for ``hex``, at least 1 for ``row``.
        layout: ``hex`` or ``row`` (``LAYOUTS``).
        pitch_m: Centre-to-centre distance of neighbouring cells, m.
    """

    cells: int = N_CELLS
    layout: str = "hex"
    pitch_m: float = CELL_PITCH_M

    def problem(self) -> str | None:
        """Return what is wrong with the layout and the fix, in words, or None when valid."""
        if self.layout not in LAYOUTS:
            return f"layout = {self.layout!r} is not one of {', '.join(LAYOUTS)}; give one of them"
        if self.cells < 1:
            return f"cells = {self.cells} must be >= 1; give the skin's number of cells"
        if self.layout == "hex" and self.cells > N_CELLS:
            return (
                f"cells = {self.cells} exceeds the {N_CELLS} cells of layout 'hex' (the thesis's "
                "patch); give fewer cells, or layout=row for a longer skin"
            )
        if not self.pitch_m > 2 * FORCE_SENSOR_RADIUS_M:
            return (
                f"cell_pitch_m = {self.pitch_m} must exceed {2 * FORCE_SENSOR_RADIUS_M:.4g} m "
                "(neighbouring cells' force sensors would overlap); give a larger pitch"
            )
        return None

    def centres(self) -> F64:
        """Return the cell centres in the patch frame, shape (cells, 2), m."""
        if self.layout == "row":
            across = self.pitch_m * (np.arange(self.cells) - 0.5 * (self.cells - 1))
            return np.stack([np.zeros(self.cells), across], axis=1)
        angles = np.deg2rad(30.0 + 60.0 * np.arange(N_CELLS - 1))
        ring = self.pitch_m * np.stack([np.cos(angles), np.sin(angles)], axis=1)
        patch: F64 = np.vstack([np.zeros((1, 2)), ring])
        return patch[: self.cells]


THESIS_LAYOUT: Final = SkinLayout()
"""The thesis's 7-cell hexagonal patch."""


def cell_centres(layout: SkinLayout = THESIS_LAYOUT) -> F64:
    """Return the cell centres in the patch frame, shape (cells, 2), m (centre cell first)."""
    return layout.centres()


def rotations_2d(angles: F64) -> F64:
    """Return 2-d rotation matrices for ``angles`` (n,), shape (n, 2, 2)."""
    c, s = np.cos(angles), np.sin(angles)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


@dataclass(frozen=True, slots=True)
class SkinHardware:
    """Properties of one physical skin patch, fixed for the rig's lifetime (drawn from its seed).

    Arrays have one row per cell: ``c`` rows, 7 for the thesis's patch.

    Attributes:
        centres: Cell centres in the patch frame, shape (c, 2), m.
        cell_angle: Mounting angle of each cell about the patch normal, shape (c,), rad.
        force_gain: Gain of each force sensor, shape (c, 3).
        temp_offset: Offset of each temperature sensor, shape (c,), C.
        acc_bias: Zero-g offset of each accelerometer axis, shape (c, 3), m/s^2.
        proximity_gain: Gain of each proximity sensor, shape (c,).
        temp_ageing: Change of each temperature sensor's offset per trial, shape (c,), C.
        force_ageing: Relative change of each force sensor's gain per trial, shape (c, 3).
    """

    cell_angle: F64
    force_gain: F64
    temp_offset: F64
    acc_bias: F64
    proximity_gain: F64
    temp_ageing: F64
    force_ageing: F64
    centres: F64 = field(default_factory=cell_centres)

    @property
    def n_cells(self) -> int:
        """Return the number of cells."""
        return int(self.centres.shape[0])

    @classmethod
    def draw(cls, rng: np.random.Generator, layout: SkinLayout = THESIS_LAYOUT) -> SkinHardware:
        """Draw a patch's hardware (for the thesis's patch, the same draws in every version)."""
        n = layout.cells
        return cls(
            cell_angle=np.deg2rad(60.0 * rng.integers(0, 6, n)),
            force_gain=1.0 + FORCE_GAIN_SPREAD * rng.standard_normal((n, FORCE_SENSORS)),
            temp_offset=np.clip(
                TEMP_OFFSET_C * rng.standard_normal(n), -TEMP_ACCURACY_C, TEMP_ACCURACY_C
            ),
            acc_bias=ACC_BIAS_M_S2 * rng.standard_normal((n, 3)),
            proximity_gain=1.0 + 0.05 * rng.standard_normal(n),
            temp_ageing=TEMP_AGEING_C * rng.standard_normal(n),
            force_ageing=FORCE_AGEING * rng.standard_normal((n, FORCE_SENSORS)),
            centres=layout.centres(),
        )

    def aged(self, trial: int) -> tuple[F64, F64]:
        """Return the temperature offsets (c,) and force gains (c, 3) at trial ``trial``.

        The skin ages through a session: trial ``k`` is recorded in the ``k``-th round, after
        ``k`` rounds of drift from the calibration at trial 0. The drift is linear in the
        round and fixed by the rig's seed, so an execution still depends only on
        (seed, object, action, trial).
        """
        offset: F64 = self.temp_offset + self.temp_ageing * trial
        gain: F64 = self.force_gain * (1.0 + self.force_ageing * trial)
        return offset, gain

    def force_sensor_positions(self) -> F64:
        """Return the force sensors' positions in the patch frame, shape (c, 3, 2), m."""
        local = np.deg2rad(90.0 + 120.0 * np.arange(FORCE_SENSORS))
        angles = self.cell_angle[:, None] + local[None, :]
        offsets = FORCE_SENSOR_RADIUS_M * np.stack([np.cos(angles), np.sin(angles)], -1)
        return self.centres[:, None, :] + offsets


def quantize(values: F64, step: float) -> F64:
    """Round ``values`` to multiples of ``step`` (an ADC's least significant bit)."""
    return np.round(values / step) * step


def drift(times_s: F64, rates: F64) -> F64:
    """Return linear drifts ``rates * t``, shape (n, *rates.shape)."""
    return times_s.reshape(-1, *([1] * rates.ndim)) * rates


def measure_force(force: F64, times_s: F64, gain: F64, rng: np.random.Generator) -> F64:
    """Turn true normal forces into force-sensor readings.

    Args:
        force: True forces, shape (n, c, 3), N.
        times_s: Sample times, shape (n,), s.
        gain: Gain of each sensor during this execution, shape (c, 3).
        rng: Random generator of this execution.

    Returns:
        Readings, shape (n, c, 3), N: gain error, residual offset and drift, noise, 1 mN steps.
    """
    shape = gain.shape
    offset = FORCE_OFFSET_N * rng.standard_normal(shape)
    rate = FORCE_DRIFT_N_S * rng.standard_normal(shape)
    noise = FORCE_NOISE_N * rng.standard_normal(force.shape)
    reading = gain * force + offset + drift(times_s, rate) + noise
    return quantize(reading, FORCE_LSB_N)


def measure_temperature(
    temperature: F64, times_s: F64, offset: F64, rng: np.random.Generator
) -> F64:
    """Turn true sensor temperatures into LM71 readings.

    Args:
        temperature: True temperatures of the sensors, shape (n, c), C.
        times_s: Sample times, shape (n,), s.
        offset: Offset of each sensor during this execution (aged), shape (c,), C.
        rng: Random generator of this execution.

    Returns:
        Readings, shape (n, c), C: offset, drift, noise, 0.03125 C steps.
    """
    rate = TEMP_DRIFT_C_S * rng.standard_normal(offset.shape)
    noise = TEMP_NOISE_C * rng.standard_normal(temperature.shape)
    reading = temperature + offset + drift(times_s, rate) + noise
    return quantize(reading, TEMP_LSB_C)


def measure_acceleration(
    specific_force: F64, hardware: SkinHardware, rng: np.random.Generator
) -> F32:
    """Turn the cells' specific force (in the patch frame) into BMA250 readings.

    Args:
        specific_force: Acceleration minus gravity, patch frame, shape (n, c, 3), m/s^2.
        hardware: The patch.
        rng: Random generator of this execution.

    Returns:
        Readings in each cell's own axes, shape (n, c, 3), m/s^2: bias, noise, 10-bit
        quantization and clipping at +-2 g.
    """
    c, s = np.cos(hardware.cell_angle), np.sin(hardware.cell_angle)
    x, y = specific_force[..., 0], specific_force[..., 1]
    cell = np.empty(specific_force.shape, dtype=np.float32)
    cell[..., 0] = c * x + s * y  # patch axes -> the cell's rotated axes
    cell[..., 1] = c * y - s * x
    cell[..., 2] = specific_force[..., 2]
    cell += hardware.acc_bias
    cell += np.float32(ACC_NOISE_M_S2) * rng.standard_normal(cell.shape, dtype=np.float32)
    cell /= ACC_LSB_M_S2
    np.round(cell, out=cell)
    np.clip(cell, ACC_MIN_LSB, ACC_MAX_LSB, out=cell)
    cell *= ACC_LSB_M_S2
    return cell


def measure_proximity(
    distance: F64, reflectance: float, hardware: SkinHardware, rng: np.random.Generator
) -> F64:
    """Turn true distances into VCNL4010 readings converted to metres.

    The sensor counts reflected infrared light, ``r (d0 / (d + d0))^2`` of full scale; the
    driver converts counts back to distance assuming a nominal reflectance, so darker
    surfaces read farther. Readings beyond the range report the range.

    Args:
        distance: True distances from each cell to the surface below it, shape (n, c), m.
        reflectance: Reflectance of the surface.
        hardware: The patch.
        rng: Random generator of this execution.

    Returns:
        Distances, shape (n, c), m, in [0, 0.2].
    """
    d = np.maximum(distance, 0.0)
    scale = PROXIMITY_FULL_SCALE * reflectance * hardware.proximity_gain
    counts = scale * (PROXIMITY_NEAR_M / (d + PROXIMITY_NEAR_M)) ** 2
    counts = np.round(counts + PROXIMITY_NOISE_COUNTS * rng.standard_normal(d.shape))
    counts = np.clip(counts, 1.0, PROXIMITY_FULL_SCALE)
    nominal = PROXIMITY_FULL_SCALE * NOMINAL_REFLECTANCE
    reading = PROXIMITY_NEAR_M * (np.sqrt(nominal / counts) - 1.0)
    reading = np.where(distance >= PROXIMITY_RANGE_M, PROXIMITY_RANGE_M, reading)
    return np.clip(reading, 0.0, PROXIMITY_RANGE_M)


def reading_bias(reflectance: float) -> tuple[float, float]:
    """Return (slope, offset) of the noise-free proximity reading: ``slope * d + offset``.

    The approach controller slows down on this reading, so darker objects are approached
    faster.
    """
    slope = float(np.sqrt(NOMINAL_REFLECTANCE / reflectance))
    return slope, PROXIMITY_NEAR_M * (slope - 1.0)
