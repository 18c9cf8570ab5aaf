"""The arm's motion during one action execution, on the 1 kHz simulation clock.

The motion is planned in the object's surface coordinates: the depth of the skin patch's
centre below the undeformed surface (negative: a gap) and the distance slid along the patch's
x axis. Phases: approach (accelerate, cruise, slow down in proportion to the proximity reading,
creep, at most a guard speed near the believed surface) until the skin reports light contact,
then brake; a short settle; the action (press and hold, or set the normal force and slide);
the retract; a short rest up to the next 0.1 s boundary.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Final

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from recorder._catalog import ActionSpec
    from recorder._sim.config import SimConfig

F64 = NDArray[np.float64]

RATE_HZ: Final = 1000
"""Simulation clock, the fastest sensor's rate."""
DT_S: Final = 1.0 / RATE_HZ
FORCE_DECIMATION: Final = 4
"""The controller sees the force at 250 Hz."""
STOP_SAMPLES: Final = 8
"""The arm starts braking one RTDE cycle (8 ms) after the force crossed the threshold."""
BLOCK_SAMPLES: Final = 100
"""Recordings end on a 0.1 s boundary, so that every channel has whole blocks."""
ACCELERATION_M_S2: Final = 0.3
"""Largest acceleration and deceleration of the arm during the approach."""
STOP_DECELERATION_M_S2: Final = 1.0
"""Deceleration of the guarded stop after light contact."""
SLIDE_RAMP_S: Final = 0.05
"""Time the arm takes to reach (or leave) the sliding speed."""
REST_S: Final = 0.1
"""Rest after the retract before the recording ends (then up to the next 0.1 s boundary)."""


@dataclass(frozen=True, slots=True)
class Plan:
    """Planned motion of one execution on the 1 kHz clock (sample i at i ms).

    Attributes:
        depth: Patch-centre depth below the undeformed surface, shape (n,), m (negative: gap).
        slide: Distance slid along the patch's x axis, shape (n,), m.
        contact: Sample at which light contact was detected.
        execute: First sample of the action itself.
        retract: First sample of the retract.
    """

    depth: F64
    slide: F64
    contact: int
    execute: int
    retract: int

    @property
    def n(self) -> int:
        """Number of samples; the recording ends at ``n`` ms."""
        return int(self.depth.shape[0])


def _cosine(start: float, stop: float, samples: int) -> F64:
    """Return a smooth (cosine) move from ``start`` to ``stop`` over ``samples`` samples."""
    k = np.arange(1, samples + 1) / samples
    return start + (stop - start) * 0.5 * (1.0 - np.cos(np.pi * k))


def _move(start: float, stop: float, peak_speed: float) -> F64:
    """Return a cosine move whose peak speed is ``peak_speed``."""
    seconds = max(0.05, np.pi * abs(stop - start) / (2.0 * peak_speed))
    return _cosine(start, stop, round(seconds * RATE_HZ))


def approach_speed(config: SimConfig, gap: F64, bias: tuple[float, float], believed: F64) -> F64:
    """Return the commanded approach speed at each true gap.

    The speed is the proximity reading over ``slowdown_s``, clipped to ``[creep, cruise]``;
    within ``guard_gap_m`` of where the robot believes the surface is it is at most
    ``guard_speed_m_s`` (a guarded move: a dark surface reads farther than it is).

    Args:
        config: Controller settings.
        gap: True gaps, m.
        bias: Slope and offset of the proximity reading over the true gap.
        believed: The gaps the robot believes in (true gap plus the height error), m.

    Returns:
        Speeds, m/s, the shape of ``gap``.
    """
    slope, offset = bias
    reading = slope * gap + offset
    speed = np.clip(reading / config.slowdown_s, config.creep_speed_m_s, config.approach_speed_m_s)
    guarded: F64 = np.where(believed < config.guard_gap_m, config.guard_speed_m_s, speed)
    return np.minimum(speed, guarded)


def approach_gap(
    config: SimConfig, bias: tuple[float, float], height_error: float, end_gap: float
) -> F64:
    """Return the true gap during the approach on the 1 kHz clock, until ``end_gap``.

    The speed depends on the gap alone: the proximity law and the guard, limited so that the
    arm accelerates (from rest) and decelerates at most at ``ACCELERATION_M_S2``
    (``v^2`` changes by at most ``2 a`` per metre travelled). The time to reach each gap is
    then the integral of ``1 / v`` over the gap, evaluated on a 1 um grid and inverted.

    Args:
        config: Controller settings.
        bias: Slope and offset of the proximity reading over the true gap.
        height_error: How much taller the object is than the robot believes, m.
        end_gap: Gap (negative: depth) at which the profile ends, m.

    Returns:
        Gap at 0, 1, 2, ... ms, m.
    """
    start = config.start_gap_m - height_error
    step = 1e-6
    gaps = start - step * np.arange(int((start - end_gap) / step) + 1, dtype=np.float64)
    middle: F64 = gaps[:-1] - step / 2
    target = approach_speed(config, middle, bias, middle + height_error) ** 2
    travelled = 2.0 * ACCELERATION_M_S2 * (start - middle)
    braking = np.minimum.accumulate((target + travelled)[::-1])[::-1] - travelled
    speeding = np.minimum.accumulate(np.minimum(target - travelled, 0.0)) + travelled
    speed = np.sqrt(np.maximum(np.minimum(braking, speeding), 1e-12))
    reached = np.concatenate([[0.0], np.cumsum(step / speed)])
    times = np.arange(0.0, reached[-1], DT_S)
    gap: F64 = np.interp(times, reached, gaps)
    return gap


def _detect_contact(depth: F64, light_depth: float) -> int:
    """Return the first 250 Hz force sample at which the depth reaches ``light_depth``."""
    checked = depth[::FORCE_DECIMATION]
    index = int(np.argmax(checked >= light_depth))
    return index * FORCE_DECIMATION


def _stop(depth: F64, stop: int) -> F64:
    """Return the depth profile up to ``stop``, then braking to rest at constant deceleration."""
    speed = float(depth[stop] - depth[stop - 1]) / DT_S
    samples = max(1, int(np.ceil(speed / STOP_DECELERATION_M_S2 / DT_S)))
    braking = np.arange(1, samples + 1) * DT_S
    braking = np.minimum(braking, speed / STOP_DECELERATION_M_S2)
    tail = depth[stop] + speed * braking - 0.5 * STOP_DECELERATION_M_S2 * braking**2
    return np.concatenate([depth[: stop + 1], tail])


def plan_approach(
    config: SimConfig, bias: tuple[float, float], height_error: float, light_depth: float
) -> tuple[F64, int]:
    """Plan the approach up to the arm's rest after light contact.

    Args:
        config: Controller settings.
        bias: Slope and offset of the proximity reading over the true gap.
        height_error: How much taller the object is than the robot believes, m.
        light_depth: Patch-centre depth at which the skin reports light contact, m.

    Returns:
        The depth profile up to the rest, and the sample at which contact was detected.
    """
    depth = -approach_gap(config, bias, height_error, -(light_depth + 1e-3))
    contact = _detect_contact(depth, light_depth)
    return _stop(depth, contact + STOP_SAMPLES), contact


def _press(depth: float, action: ActionSpec, config: SimConfig) -> F64:
    """Press ``depth_m`` deeper, then hold for the action's duration."""
    move = _move(depth, depth + action.depth_m, config.press_speed_m_s)
    hold = np.full(round(action.duration_s * RATE_HZ), move[-1])
    return np.concatenate([move, hold])


def _slide(action: ActionSpec) -> F64:
    """Return the distance slid: smooth start, constant speed, smooth stop."""
    samples = round((action.duration_s + SLIDE_RAMP_S) * RATE_HZ)
    ramp = round(SLIDE_RAMP_S * RATE_HZ)
    speed = np.ones(samples)
    rise = 0.5 * (1.0 - np.cos(np.pi * np.arange(1, ramp + 1) / ramp))
    speed[:ramp] = rise
    speed[-ramp:] = rise[::-1]
    distance: F64 = np.cumsum(speed) * action.speed_m_s * DT_S
    return distance


def plan_execution(
    action: ActionSpec,
    config: SimConfig,
    approach: tuple[F64, int],
    slide_depth: float,
) -> Plan:
    """Plan a whole execution after the approach.

    Args:
        action: The action.
        config: Controller settings.
        approach: Depth profile up to the stop and the contact sample (:func:`plan_approach`).
        slide_depth: Patch-centre depth that gives the sliding force (slides only), m.

    Returns:
        The plan.
    """
    approach_depth, contact = approach
    stopped = float(approach_depth[-1])
    settle = np.full(round(config.settle_s * RATE_HZ), stopped)
    if action.kind == "slide":
        set_force = _move(stopped, slide_depth, config.press_speed_m_s)
        distance = _slide(action)
        act_depth = np.concatenate([set_force, np.full(distance.shape[0], set_force[-1])])
        act_slide = np.concatenate([np.zeros(set_force.shape[0]), distance])
    else:
        act_depth = _press(stopped, action, config)
        act_slide = np.zeros(act_depth.shape[0])
    retract = _move(float(act_depth[-1]), -config.retract_gap_m, config.retract_speed_m_s)
    depth = np.concatenate([approach_depth, settle, act_depth, retract])
    total = depth.shape[0] + round(REST_S * RATE_HZ)
    total = -(-total // BLOCK_SAMPLES) * BLOCK_SAMPLES
    depth = np.concatenate([depth, np.full(total - depth.shape[0], depth[-1])])
    slid = float(act_slide[-1])
    pre = approach_depth.shape[0] + settle.shape[0]
    slide = np.concatenate(
        [np.zeros(pre), act_slide, np.full(total - pre - act_slide.shape[0], slid)]
    )
    return Plan(
        depth=depth,
        slide=slide,
        contact=contact,
        execute=pre,
        retract=pre + act_depth.shape[0],
    )
