"""The arm's motion during one action execution, on the 1 kHz simulation clock.

The motion is planned in the object's surface coordinates: the depth of the skin patch's
centre below the undeformed surface (negative: a gap) and the distance slid along the patch's
x axis. Phases: approach (cruise, then slowed in proportion to the proximity reading, then a
creep speed) until the skin reports light contact; a short settle; the action (press and hold,
or set the normal force and slide); the retract; a short rest up to the next 0.1 s boundary.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Final

import numpy as np
from numpy.typing import NDArray

from recorder._catalog import ActionKind

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
"""The arm stops one RTDE cycle (8 ms) after the force crossed the threshold."""
BLOCK_SAMPLES: Final = 100
"""Recordings end on a 0.1 s boundary, so that every channel has whole blocks."""
START_RAMP_S: Final = 0.1
"""Time the arm takes to reach cruise speed."""
SLIDE_RAMP_S: Final = 0.05
"""Time the arm takes to reach (or leave) the sliding speed."""
REST_S: Final = 0.1


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


def approach_gap(config: SimConfig, slope: float, offset: float, seconds: float) -> F64:
    """Return the true gap during the approach, sampled from 0 for ``seconds``.

    The controller commands ``v = clip(reading / slowdown_s, creep, cruise)`` where the
    proximity reading is ``slope * gap + offset`` (reflectance bias); in terms of the reading
    this is a cruise (after a linear start ramp), an exponential slowdown and a creep.

    Args:
        config: Controller settings.
        slope: Slope of the reading over the true gap.
        offset: Offset of the reading at zero gap, m.
        seconds: Length of the profile, s.

    Returns:
        Gap, shape (round(seconds * 1000),), m; it goes negative past the surface.
    """
    tau, v_max, v_min = config.slowdown_s, config.approach_speed_m_s, config.creep_speed_m_s
    t = np.arange(round(seconds * RATE_HZ)) * DT_S
    reading0 = slope * config.start_gap_m + offset
    cruise_end = tau * v_max
    t_cruise = START_RAMP_S / 2 + (reading0 - cruise_end) / (slope * v_max)
    t_creep = t_cruise + tau / slope * np.log(cruise_end / (tau * v_min))
    ramp = reading0 - slope * v_max * t**2 / (2 * START_RAMP_S)
    cruise = reading0 - slope * v_max * (t - START_RAMP_S / 2)
    slow = cruise_end * np.exp(-slope * (t - t_cruise) / tau)
    creep = tau * v_min - slope * v_min * (t - t_creep)
    reading = np.select(
        [t < START_RAMP_S, t < t_cruise, t < t_creep], [ramp, cruise, slow], default=creep
    )
    gap: F64 = (reading - offset) / slope
    return gap


def _detect_contact(depth: F64, light_depth: float) -> int:
    """Return the first 250 Hz force sample at which the depth reaches ``light_depth``."""
    checked = depth[::FORCE_DECIMATION]
    index = int(np.argmax(checked >= light_depth))
    return index * FORCE_DECIMATION


def plan_approach(
    config: SimConfig, slope: float, offset: float, light_depth: float
) -> tuple[F64, int]:
    """Plan the approach up to the stop after light contact.

    Args:
        config: Controller settings.
        slope: Slope of the proximity reading over the true gap.
        offset: Offset of the proximity reading at zero gap, m.
        light_depth: Patch-centre depth at which the skin reports light contact, m.

    Returns:
        The depth profile up to and including the stop, and the contact sample.
    """
    worst = config.start_gap_m + light_depth + 1e-3
    seconds = 1.0 + config.slowdown_s * 8.0 + worst / config.creep_speed_m_s
    seconds = min(seconds, 60.0)
    depth = -approach_gap(config, slope, offset, seconds)
    contact = _detect_contact(depth, light_depth)
    stop = contact + STOP_SAMPLES
    return depth[: stop + 1], contact


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
    if action.kind is ActionKind.SLIDE:
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
