"""Normal contact between the skin patch and an object: force from depth, per force sensor.

Each force sensor presses through the skin's elastomer cover (a linear spring) onto its share
of the object's surface (the object's law: linear for hard objects, elastic-plateau-
densification for foams, the densification coming early for a thin foam layer on a hard base).
The two springs are in series, so on hard objects the cover takes the deflection. The elastic
force then relaxes during a hold (a standard linear solid: a fraction of the force decays with
the material's time constant).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Final

import numpy as np
from numpy.typing import NDArray

from recorder._sim.skin import FORCE_SENSORS, N_CELLS

if TYPE_CHECKING:
    from recorder._catalog import ObjectPhysics

F64 = NDArray[np.float64]

SENSORS: Final = N_CELLS * FORCE_SENSORS
"""Force sensors of the thesis's 7-cell patch. The catalog's stiffnesses and the cover's are
those under that patch; each sensor takes its share of the area, so a skin of other shape
keeps the per-sensor laws and its total force scales with its number of cells."""
SKIN_STIFFNESS_N_M: Final = 2250.0
"""Stiffness of the skin's cover under the whole patch: 2 mm on a hard object give 4.5 N."""
SKIN_RELAXATION: Final = 0.04
"""Fraction of force the silicone cover relaxes during a long hold."""
SKIN_RELAXATION_S: Final = 2.0
FORCE_CAP_N: Final = 20.0
"""Largest force per sensor the law is tabulated for."""
_TABLE_POINTS: Final = 600
_DENSIFICATION_EXPONENT: Final = 2.0


def object_force(obj: ObjectPhysics, depth: F64) -> F64:
    """Force of one sensor's share of the object's surface at a given object deflection.

    Elastic range, then (foams) a plateau of lower stiffness past ``yield_strain``, smoothly
    joined by a tanh; densification multiplies by ``(1 - strain / densification_strain)^-2``.

    Args:
        obj: The object.
        depth: Deflection of the object's surface, m (>= 0).

    Returns:
        Force, N, the shape of ``depth``.
    """
    k = obj.stiffness_n_m / SENSORS
    force = k * depth
    if obj.yield_strain > 0:
        knee = obj.yield_strain * obj.layer_thickness_m
        bent = knee * np.tanh(depth / knee)
        force = k * (bent + obj.plateau_ratio * (depth - bent))
    if obj.densification_strain > 0:
        limit = obj.densification_strain * obj.layer_thickness_m
        force = force / np.maximum(1.0 - depth / limit, 1e-6) ** _DENSIFICATION_EXPONENT
    return np.asarray(force, dtype=np.float64)


@dataclass(frozen=True, slots=True)
class ContactLaw:
    """Force of one force sensor as a function of its depth into the undeformed surface.

    Attributes:
        depth_m: Total depth (cover plus object deflection), ascending, m.
        force_n: Force at each depth, N.
        relaxation: Fraction of the force that relaxes during a hold (cover and object).
        relaxation_s: Time constant of the relaxation, s.
        object_share: Share of the deflection the object takes at light pressure.
    """

    depth_m: F64
    force_n: F64
    relaxation: float
    relaxation_s: float
    object_share: float

    def elastic(self, depth: F64) -> F64:
        """Return the elastic force at ``depth`` (any shape), 0 where out of contact."""
        force: F64 = np.interp(depth, self.depth_m, self.force_n, left=0.0)
        return force

    def relaxed(self, elastic: F64, dt_s: float) -> F64:
        """Apply the relaxation to an elastic force history along axis 0.

        Standard linear solid: ``F = F_e - r * lowpass_tau(F_e)``; a force that would pull
        (after a fast retract) means the surfaces separate, so it is clipped at 0.
        """
        from scipy.signal import lfilter  # noqa: PLC0415 (scipy.signal: ~0.8 s to import, on use)

        decay = float(np.exp(-dt_s / self.relaxation_s))
        memory = lfilter([1.0 - decay], [1.0, -decay], elastic, axis=0)
        force: F64 = np.maximum(elastic - self.relaxation * memory, 0.0)
        return force


def _deflection_limit(obj: ObjectPhysics) -> float:
    """Return an object deflection at which a sensor's force exceeds the cap."""
    limit = FORCE_CAP_N * SENSORS / obj.stiffness_n_m
    if obj.densification_strain > 0:
        return min(limit, 0.999 * obj.densification_strain * obj.layer_thickness_m)
    while float(object_force(obj, np.array(limit))) < FORCE_CAP_N:
        limit *= 2.0
    return limit


def contact_law(obj: ObjectPhysics) -> ContactLaw:
    """Tabulate the series law (cover + object) of one force sensor on ``obj``.

    Args:
        obj: The object.

    Returns:
        The sensor's contact law.
    """
    k_cover = SKIN_STIFFNESS_N_M / SENSORS
    deflection = _deflection_limit(obj) * np.linspace(0.0, 1.0, _TABLE_POINTS) ** 2
    force = object_force(obj, deflection)
    depth = deflection + force / k_cover
    light = np.interp(0.02, force, deflection)  # object deflection at 0.02 N per sensor
    share = float(light / (light + 0.02 / k_cover))
    return ContactLaw(
        depth_m=depth,
        force_n=force,
        relaxation=share * obj.relaxation + (1.0 - share) * SKIN_RELAXATION,
        relaxation_s=share * obj.relaxation_time_s + (1.0 - share) * SKIN_RELAXATION_S,
        object_share=share,
    )


def total_force_curve(law: ContactLaw, offsets: F64, gain: F64, depths: F64) -> F64:
    """Return the total elastic force the skin reports at each patch-centre depth.

    Args:
        law: Contact law of one sensor.
        offsets: Extra depth of each force sensor over the patch centre, shape (c, 3), m;
            NaN where the sensor is off the object.
        gain: Gain of each force sensor, shape (c, 3).
        depths: Patch-centre depths to evaluate, shape (n,), m.

    Returns:
        Total force at each depth, shape (n,), N.
    """
    local = depths[:, None, None] + np.nan_to_num(offsets, nan=-1.0)
    total: F64 = (law.elastic(local) * gain).sum(axis=(1, 2))
    return total


def depth_for_force(law: ContactLaw, offsets: F64, gain: F64, target_n: float) -> float:
    """Return the smallest patch-centre depth at which the skin reports ``target_n`` in total.

    Args:
        law: Contact law of one sensor.
        offsets: Extra depth of each force sensor, shape (c, 3), m; NaN off the object.
        gain: Gain of each force sensor, shape (c, 3).
        target_n: Total force, N.

    Returns:
        Depth of the patch centre, m (negative if a sensor below the centre touches first).
    """
    finite = offsets[np.isfinite(offsets)]
    first = -float(finite.max())
    step = 1e-5
    depths = (first + step * np.arange(int(0.015 / step))).astype(np.float64)
    curve = total_force_curve(law, offsets, gain, depths)
    index = int(np.searchsorted(curve, target_n))
    if index >= depths.shape[0]:
        return float(depths[-1])
    if index == 0:
        return float(depths[0])
    lo, hi = curve[index - 1], curve[index]
    return float(depths[index - 1] + step * (target_n - lo) / (hi - lo))


def sensor_forces(
    law: ContactLaw, depth: F64, offsets: F64, dt_s: float, relief: F64 | None = None
) -> F64:
    """Return the true normal force of every force sensor over time.

    Args:
        law: Contact law of one sensor.
        depth: Patch-centre depth over time, shape (n,), m (negative: gap).
        offsets: Extra depth of each force sensor, shape (c, 3), m; NaN off the object.
        dt_s: Sample period, s.
        relief: Optional surface height under each sensor over time (texture while
            sliding), shape (n, c, 3), m.

    Returns:
        Forces, shape (n, c, 3), N.
    """
    local = depth[:, None, None] + np.nan_to_num(offsets, nan=-1.0)
    if relief is not None:
        local = local + relief
    return law.relaxed(law.elastic(local), dt_s)
