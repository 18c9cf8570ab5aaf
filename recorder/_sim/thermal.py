"""Heat flow from the heated skin into a touched object, as the skin's temperature sensors see it.

Two semi-infinite bodies in contact settle at the interface temperature
``T_i = (e_s T_s + e_o T_o) / (e_s + e_o)`` with effusivities ``e = sqrt(k rho c)``. The skin is
heated to ``T_s`` (29.5 C); the object is at room temperature. A thin surface layer (paper
over glass, sponge over marble, a tin's thin sheet) shows its own effusivity first and the base's
later, once heat has crossed it (``t ~ d^2 / alpha``). Contact at light pressure conducts less:
the cell's contact conductance grows with its force. The sensor sits under the cover and
lags: two first-order stages (cover, then sensor and heater) between the surface and the
reading.

Calibration (CALIBRATION.md): 4.5 N static contact of a skin at 29.5 C on room-temperature
(22.5 C) wood drops the reading by 0.48 +- 0.10 C after 5 s, on aluminium by 2.40 +- 0.16 C,
with about 1 s lag. ``SKIN_EFFUSIVITY`` sets the ratio of the two drops, ``SENSOR_LAG_S``
their size; ``COVER_LAG_S`` is the 1 s lag. The two were fitted on whole simulated C1
executions (light contact, press-in, conductance and sensor model included): mean drops of
0.48 C (wood) and 2.43 C (aluminium plate) 5 s after light contact, seed 0.

Trial-to-trial spread (CALIBRATION.md): the skin starts each action with residual heat of
earlier touches, a deficit below the set point and a recovery still under way
(``SkinState.recovery_c_s``, decaying with ``RECOVERY_S``); with the contact conductance and
the ambient they make the 5 s drop vary by 0.09 C on wood and 0.16 C on aluminium (real
probe: 0.10 and 0.16 C).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Final

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from recorder._catalog import ObjectPhysics

F64 = NDArray[np.float64]

SKIN_EFFUSIVITY: Final = 1900.0
"""Effective effusivity of the skin (cover, heater and sensor), W s^0.5 m^-2 K^-1."""
COVER_LAG_S: Final = 1.0
"""Time constant of heat crossing the skin's cover to the sensor."""
SENSOR_LAG_S: Final = 7.0
"""Time constant of the sensor and heater node."""
HALF_CONDUCTANCE_FORCE_N: Final = 0.03
"""Cell force at which the contact conducts half as well as under firm pressure."""
CONTACT_FORCE_N: Final = 1e-3
"""Cell force above which a cell counts as touching."""
RECOVERY_S: Final = SENSOR_LAG_S
"""Time constant of the skin's recovery from residual heat: that of its slow sensor and heater
node."""


@dataclass(frozen=True, slots=True)
class SkinState:
    """The skin's thermal state when an execution starts.

    Attributes:
        set_point_c: Temperature the heater holds out of contact, C.
        deficit_c: How far below the set point the skin still is (it has not fully
            recovered from the previous touch), C.
        conductance: Factor on the contact conductance (surface condition: dust, moisture).
        recovery_c_s: Rate at which the skin's temperature is still changing when the action
            starts (residual heat of earlier touches: > 0 still rising back, < 0 falling after
            the heater overshot), C/s; the change decays with ``RECOVERY_S``.
    """

    set_point_c: float
    deficit_c: float = 0.0
    conductance: float = 1.0
    recovery_c_s: float = 0.0


def effusivity_over_time(obj: ObjectPhysics, since_contact_s: F64) -> F64:
    """Return the effusivity the skin feels, a time after contact began.

    A layer of crossing time ``tau = d^2 / alpha`` hides the base until heat has penetrated it:
    the weight of the base is ``erfc(sqrt(tau / 4 t))`` (the fraction of a diffusion front past
    depth d), blended geometrically.

    Args:
        obj: The object.
        since_contact_s: Time since the cell touched, s (any shape, >= 0).

    Returns:
        Effusivity, the shape of ``since_contact_s``.
    """
    top = np.full_like(since_contact_s, obj.effusivity)
    if obj.thermal_layer_s <= 0 or obj.base_effusivity <= 0:
        return top
    t = np.maximum(since_contact_s, 1e-9)
    # scipy.special on first use: at module level it costs every command 0.4 s of start (the
    # UR driver and the virtual lab import the simulator's kinematics).
    from scipy.special import erfc  # noqa: PLC0415

    weight = erfc(np.sqrt(obj.thermal_layer_s / (4.0 * t)))
    blended: F64 = np.exp(
        (1.0 - weight) * np.log(obj.effusivity) + weight * np.log(obj.base_effusivity)
    )
    return blended


def _lag(signal: F64, tau_s: float, dt_s: float, start: float) -> F64:
    """First-order lag along axis 0, exactly discretised, starting at rest at ``start``."""
    from scipy.signal import lfilter, lfilter_zi  # noqa: PLC0415 (scipy.signal: ~0.8 s to import, on use)

    decay = float(np.exp(-dt_s / tau_s))
    b, a = [1.0 - decay], [1.0, -decay]
    zi = lfilter_zi(b, a) * start
    state = np.broadcast_to(zi.reshape(1, *([1] * (signal.ndim - 1))), (1, *signal.shape[1:]))
    out, _ = lfilter(b, a, signal, axis=0, zi=state)
    lagged: F64 = out
    return lagged


def sensor_temperature(
    cell_force: F64,
    dt_s: float,
    obj: ObjectPhysics,
    room_c: float,
    skin: SkinState,
) -> F64:
    """Return the true temperature of each cell's sensor over time.

    Args:
        cell_force: Normal force on each cell over time, shape (n, 7), N.
        dt_s: Sample period, s.
        obj: The touched object.
        room_c: Temperature of the object (the room), C.
        skin: The skin's heater set point and state at the start.

    Returns:
        Temperatures, shape (n, 7), C.
    """
    skin_c = skin.set_point_c
    touching = cell_force > CONTACT_FORCE_N
    n = cell_force.shape[0]
    first = np.where(touching.any(axis=0), touching.argmax(axis=0), n)
    since = np.maximum(np.arange(n)[:, None] - first[None, :], 0) * dt_s
    effusivity = effusivity_over_time(obj, since)
    interface = (SKIN_EFFUSIVITY * skin_c + effusivity * room_c) / (SKIN_EFFUSIVITY + effusivity)
    force = np.maximum(cell_force, 0.0)
    conductance = np.where(touching, force / (force + HALF_CONDUCTANCE_FORCE_N), 0.0)
    conductance = np.minimum(conductance * skin.conductance, 1.0)
    surface = skin_c - conductance * (skin_c - interface)
    start = skin_c - skin.deficit_c
    cover = _lag(surface, COVER_LAG_S, dt_s, start)
    sensor = _lag(cover, SENSOR_LAG_S, dt_s, start)
    if skin.recovery_c_s != 0.0:
        elapsed = np.arange(n) * dt_s
        recovery = skin.recovery_c_s * RECOVERY_S * -np.expm1(-elapsed / RECOVERY_S)
        sensor += recovery[:, None]
    return sensor
