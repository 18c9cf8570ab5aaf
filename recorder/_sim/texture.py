"""Vibration of the skin cells while sliding over a textured surface.

Sources, each in the patch frame (x: sliding direction, z: into the object):

- the texture's relief, followed by the cell as it slides: a grating of ridges (period P,
  seen at ``speed * cos(angle) / P`` Hz along the path, with harmonics) and an isotropic
  random relief of the same scale; acceleration ``v^2 h''(x) + a h'(x)``. The skin cover
  smooths wavelengths shorter than its contact length. Ridges also push the cell sideways,
  along their normal.
- friction noise from micro-roughness, mostly tangential, growing with friction, normal force
  and speed;
- stick-slip where static friction clearly exceeds kinetic friction at low speed: the cover
  stores tangential force until ``mu_s F`` and slips to ``mu_k F``, every
  ``(mu_s - mu_k) F / (k_t v)`` seconds; a single break-away slip starts every slide.

The relief of a soft surface is pressed flat under the cover, in proportion to the object's
share of the contact compliance. The cell rides on the cover and the object like a mass on a
spring: every source passes a second-order resonance whose frequency grows with the contact
stiffness (210 Hz on hard objects, about 120 Hz and better damped on foam). At 2 cm/s this puts
the spectral centroid of sliding on the hard and medium catalog objects at 140-225 Hz, the
range BioTac measurements on everyday materials show (foams: 100-125 Hz).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Final

import numpy as np
from numpy.typing import NDArray

from recorder._sim.contact import SKIN_STIFFNESS_N_M
from recorder._sim.motion import DT_S, RATE_HZ

if TYPE_CHECKING:
    from recorder._catalog import ObjectPhysics
    from recorder._sim.contact import ContactLaw

F64 = NDArray[np.float64]

RIGID_RESONANCE_HZ: Final = 210.0
"""Resonance of a skin cell on a hard object."""
RESONANCE_EXPONENT: Final = 0.2
"""Resonance frequency grows as (contact stiffness / cover stiffness) ** this."""
BASE_DAMPING: Final = 0.12
"""Damping ratio of the cell's resonance on a hard object."""
CONTACT_SMOOTHING_M: Final = 1e-4
"""Length over which the cover averages the relief: gain exp(-(k L)^2 / 2) at wavenumber k."""
HARMONICS: Final = (1.0, 0.15, 0.05)
"""Relative amplitudes of the ridges' harmonics."""
RIDGE_PUSH: Final = 0.4
"""Tangential over normal acceleration caused by climbing a ridge."""
FRICTION_NOISE_GAIN: Final = 6.0e4
"""Friction noise RMS = gain * mu_k * roughness * sqrt(v / 1 cm/s) * sqrt(F_cell / 0.03 N)."""
STICK_SLIP_MIN_DIFFERENCE: Final = 0.1
"""Stick-slip needs mu_s - mu_k at least this."""
STICK_SLIP_MAX_SPEED_M_S: Final = 0.03
"""Above this speed sliding is steady (no stick-slip)."""
TANGENTIAL_STIFFNESS_N_M: Final = 400.0
"""Tangential stiffness of the skin cover under the patch."""
PATCH_MASS_KG: Final = 0.05
"""Moving mass behind the cover: a slip of force dF accelerates it by dF / m."""
SLIP_JITTER: Final = 0.15
"""Relative spread of the stick-slip intervals."""
CONTACT_SCALE_N: Final = 0.003
"""Cell force at which a cell follows the relief half as well as under firm contact."""
MOVING_SPEED_M_S: Final = 1e-4
"""Slower than this, the patch counts as standing still."""
TRANSMITTED: Final = 0.25
"""Share of the patch's mean vibration that reaches cells off the object."""


@dataclass(frozen=True, slots=True)
class Resonance:
    """The cell's mechanical resonance on an object.

    Attributes:
        frequency_hz: Natural frequency.
        damping: Damping ratio.
    """

    frequency_hz: float
    damping: float

    @classmethod
    def on(cls, obj: ObjectPhysics, law: ContactLaw) -> Resonance:
        """Return the resonance on ``obj`` (stiffer contact: higher; lossier: more damped)."""
        series = 1.0 / (1.0 / SKIN_STIFFNESS_N_M + 1.0 / obj.stiffness_n_m)
        frequency = RIGID_RESONANCE_HZ * (series / SKIN_STIFFNESS_N_M) ** RESONANCE_EXPONENT
        return cls(frequency, BASE_DAMPING + 0.5 * law.relaxation)

    def filter(self, signal: F64) -> F64:
        """Pass ``signal`` (time on axis 0) through the resonance (unit gain at DC)."""
        from scipy.signal import lfilter  # noqa: PLC0415 (scipy.signal: ~0.8 s to import, on use)

        # Bilinear transform of w^2 / (s^2 + 2 zeta w s + w^2), frequency pre-warped.
        k = 2.0 * RATE_HZ
        w = k * np.tan(np.pi * self.frequency_hz / RATE_HZ)
        damp = 2.0 * self.damping * w * k
        a0 = k * k + damp + w * w
        b = np.array([w * w, 2.0 * w * w, w * w]) / a0
        a = np.array([a0, 2.0 * (w * w - k * k), k * k - damp + w * w]) / a0
        out: F64 = lfilter(b, a, signal, axis=0)
        return out

    def impulse_scale(self) -> float:
        """Input impulse that makes the filtered response peak at about 1."""
        return 1.0 / (2.0 * np.pi * self.frequency_hz * DT_S)


@dataclass(frozen=True, slots=True)
class SlideConditions:
    """Trial-dependent conditions of one slide.

    Attributes:
        ridge_angle: Angle between the sliding direction and the ridges' normal, rad.
        phases: Phase of each harmonic of the ridges, shape (3,), rad.
    """

    ridge_angle: float
    phases: F64


def followed_relief(obj: ObjectPhysics) -> float:
    """Return the relief height the cell follows: a soft surface flattens under the cover.

    The relief is pressed flat in proportion to the object's share of the contact compliance,
    so the cell rides the full relief of a hard surface and little of a foam's.
    """
    return obj.texture_amplitude_m * obj.stiffness_n_m / (obj.stiffness_n_m + SKIN_STIFFNESS_N_M)


def _smoothing(wavenumber: NDArray[np.floating[Any]] | float) -> F64:
    """Return the cover's gain at spatial wavenumber ``wavenumber`` (rad/m)."""
    gain: F64 = np.exp(-0.5 * (np.asarray(wavenumber, dtype=np.float64) * CONTACT_SMOOTHING_M) ** 2)
    return gain


def _ridge_coordinate(obj: ObjectPhysics, slide: F64, points: F64, angle: float) -> F64:
    """Return the ridges' phase under each point over time, shape (m, *points.shape[:-1])."""
    normal = np.array([np.cos(angle), np.sin(angle)])
    along = points @ normal
    path = slide.reshape(-1, *([1] * along.ndim)) * normal[0] + along
    phase: F64 = 2.0 * np.pi * path / obj.texture_period_m
    return phase


def ridge_relief(obj: ObjectPhysics, slide: F64, points: F64, conditions: SlideConditions) -> F64:
    """Return the ridges' height under each point over time (for the force sensors).

    Args:
        obj: The object.
        slide: Distance slid, shape (m,), m.
        points: Positions in the patch frame, shape (..., 2), m.
        conditions: The slide's conditions.

    Returns:
        Heights, shape (m, *points.shape[:-1]), m.
    """
    theta = _ridge_coordinate(obj, slide, points, conditions.ridge_angle)
    height = np.zeros_like(theta)
    base_k = 2.0 * np.pi / obj.texture_period_m
    for order, (weight, phase) in enumerate(zip(HARMONICS, conditions.phases, strict=True), 1):
        gain = weight * float(_smoothing(order * base_k))
        height += gain * np.sin(order * theta + phase)
    return obj.anisotropy * followed_relief(obj) * height


def _ridge_acceleration(
    obj: ObjectPhysics, slide: F64, cells: F64, conditions: SlideConditions
) -> F64:
    """Return the normal acceleration the ridges cause at each cell, shape (m, cells)."""
    speed = np.gradient(slide, DT_S)
    accel = np.gradient(speed, DT_S)
    theta = _ridge_coordinate(obj, slide, cells, conditions.ridge_angle)
    rate = 2.0 * np.pi * np.cos(conditions.ridge_angle) / obj.texture_period_m
    base_k = 2.0 * np.pi / obj.texture_period_m
    out = np.zeros_like(theta)
    for order, (weight, phase) in enumerate(zip(HARMONICS, conditions.phases, strict=True), 1):
        gain = weight * float(_smoothing(order * base_k))
        k = order * rate
        arg = order * theta + phase
        out += gain * (
            -((k * speed[:, None]) ** 2) * np.sin(arg) + k * accel[:, None] * np.cos(arg)
        )
    return obj.anisotropy * followed_relief(obj) * out


def _random_acceleration(
    obj: ObjectPhysics, slide: F64, cells: int, rng: np.random.Generator
) -> F64:
    """Return the normal acceleration of an isotropic random relief, per cell, shape (m, cells).

    The relief is a Gaussian process along each cell's path with a log-normal band around the
    texture's wavenumber; its RMS is that of the ridges' fundamental.
    """
    amplitude = (1.0 - obj.anisotropy) * followed_relief(obj)
    if amplitude <= 0:
        return np.zeros((slide.shape[0], cells))
    step = obj.texture_period_m / 16.0
    length = float(slide.max() - slide.min()) + 4.0 * obj.texture_period_m
    n = int(2 ** np.ceil(np.log2(max(64.0, length / step))))
    k = 2.0 * np.pi * np.fft.rfftfreq(n, step)
    k0 = 2.0 * np.pi / obj.texture_period_m
    band = np.exp(-0.5 * (np.log(np.maximum(k, 1e-9) / k0) / 0.35) ** 2)
    white = np.fft.rfft(rng.standard_normal((n, cells)), axis=0) * band[:, None]
    rms = np.sqrt(2.0 * (np.abs(white[1:]) ** 2).sum(axis=0)) / n
    white *= amplitude / np.sqrt(2.0) / np.maximum(rms, 1e-30) * _smoothing(k)[:, None]
    second = np.fft.irfft(-(k**2)[:, None] * white, n, axis=0)
    first = np.fft.irfft(1j * k[:, None] * white, n, axis=0)
    grid = slide.min() - 2.0 * obj.texture_period_m + step * np.arange(n)
    speed = np.gradient(slide, DT_S)
    accel = np.gradient(speed, DT_S)
    out = np.empty((slide.shape[0], cells))
    for cell in range(cells):
        out[:, cell] = speed**2 * np.interp(slide, grid, second[:, cell]) + accel * np.interp(
            slide, grid, first[:, cell]
        )
    return out


def _slip_train(obj: ObjectPhysics, slide: F64, total_force: F64, rng: np.random.Generator) -> F64:
    """Return the stick-slip force drops over time (break-away included), shape (m,), N."""
    speed = np.gradient(slide, DT_S)
    drops = np.zeros(slide.shape[0])
    moving = np.flatnonzero(speed > MOVING_SPEED_M_S)
    if moving.size == 0:
        return drops
    start = int(moving[0])
    difference = obj.friction_static - obj.friction_kinetic
    drops[start] = obj.friction_static * float(total_force[start])
    steady = float(np.median(speed[moving]))
    if difference < STICK_SLIP_MIN_DIFFERENCE or steady > STICK_SLIP_MAX_SPEED_M_S:
        return drops
    force = float(np.median(total_force[moving]))
    interval = difference * force / (TANGENTIAL_STIFFNESS_N_M * steady)
    count = int((moving[-1] - start) * DT_S / interval) + 2
    gaps = interval * np.maximum(1.0 + SLIP_JITTER * rng.standard_normal(count), 0.2)
    times = start + np.round(np.cumsum(gaps) / DT_S).astype(np.int64)
    times = times[times <= moving[-1]]
    drops[times] += difference * total_force[times]
    return drops


def sliding_vibration(
    obj: ObjectPhysics,
    law: ContactLaw,
    slide: F64,
    *,
    cell_force: F64,
    cells: F64,
    conditions: SlideConditions,
    rng: np.random.Generator,
) -> F64:
    """Return the cells' vibration during a slide, in the patch frame.

    Args:
        obj: The object.
        law: The sensors' contact law on it.
        slide: Distance slid over the window, shape (m,), m.
        cell_force: Normal force on each cell, shape (m, c), N.
        cells: Cell centres in the patch frame, shape (c, 2), m (7 for the thesis's patch).
        conditions: The slide's conditions.
        rng: Random generator of this execution.

    Returns:
        Accelerations, shape (m, c, 3), m/s^2 (x: sliding direction, z: into the object).
    """
    m = slide.shape[0]
    resonance = Resonance.on(obj, law)
    speed = np.abs(np.gradient(slide, DT_S))
    contact = cell_force / (cell_force + CONTACT_SCALE_N)
    ridges = _ridge_acceleration(obj, slide, cells, conditions)
    normal = ridges + _random_acceleration(obj, slide, cells.shape[0], rng)
    scale = (
        FRICTION_NOISE_GAIN
        * obj.friction_kinetic
        * obj.fine_roughness_m
        * np.sqrt(speed / 0.01)[:, None]
        * np.sqrt(np.maximum(cell_force, 0.0) / 0.03)
    )
    noise = rng.standard_normal((m, cells.shape[0], 3)) * scale[..., None]
    slips = _slip_train(obj, slide, cell_force.sum(axis=1), rng) / PATCH_MASS_KG
    slips *= resonance.impulse_scale()
    source = np.empty((m, cells.shape[0], 3))
    angle = conditions.ridge_angle
    source[..., 0] = (
        RIDGE_PUSH * np.cos(angle) * ridges + obj.friction_kinetic * normal + noise[..., 0]
    )
    source[..., 0] += slips[:, None]
    source[..., 1] = RIDGE_PUSH * np.sin(angle) * ridges + 0.5 * noise[..., 1]
    source[..., 2] = normal + 0.4 * (0.5 * noise[..., 0] + 0.87 * noise[..., 2])
    source[..., 2] += 0.3 * slips[:, None]
    source *= contact[..., None]
    vibration = resonance.filter(source)
    touching = contact.mean(axis=0) > 0.5  # noqa: PLR2004 - half-contact threshold
    if touching.any() and not touching.all():
        shared = vibration[:, touching].mean(axis=1)
        vibration[:, ~touching] += TRANSMITTED * shared[:, None]
    return vibration
