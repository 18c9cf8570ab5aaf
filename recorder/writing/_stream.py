"""What a rig produces: timestamped, typed items, independent of any encoding.

A rig yields these in order of receive time (``receive_ns``, the MCAP ``log_time``); the
writer turns them into ROS 2 messages. Time is integer nanoseconds.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypeAlias

import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]


Modality: TypeAlias = str
"""A skin modality's name, one of ``schemas.VOCABULARY.modalities`` (the contract's list)."""

Phase: TypeAlias = str
"""An action phase's name, one of ``schemas.VOCABULARY.phases``, in the order they happen."""


@dataclass(frozen=True, slots=True)
class SkinBlock:
    """A block of consecutive samples of one skin modality.

    Attributes:
        modality: Which modality the block carries.
        stamp_ns: Sensor time of the first sample, ns.
        period_ns: Time between consecutive samples, ns.
        receive_ns: Time the block was received (the MCAP log time), ns.
        data: Samples, shape (samples, cells, channels), float32, SI units (C for temperature).
    """

    modality: str
    stamp_ns: int
    period_ns: int
    receive_ns: int
    data: F32


@dataclass(frozen=True, slots=True)
class JointSample:
    """One UR10 joint state (RTDE, 125 Hz).

    Attributes:
        stamp_ns: Controller time of the sample, ns.
        receive_ns: Receive time, ns.
        position: Joint angles, shape (6,), rad.
        velocity: Joint velocities, shape (6,), rad/s.
        effort: Joint torques, shape (6,), N m.
    """

    stamp_ns: int
    receive_ns: int
    position: F64
    velocity: F64
    effort: F64


@dataclass(frozen=True, slots=True)
class PoseSample:
    """One TCP pose in the robot base frame.

    Attributes:
        stamp_ns: Controller time of the sample, ns.
        receive_ns: Receive time, ns.
        position: TCP position, shape (3,), m.
        orientation: TCP orientation as a unit quaternion (x, y, z, w), shape (4,).
    """

    stamp_ns: int
    receive_ns: int
    position: F64
    orientation: F64


@dataclass(frozen=True, slots=True)
class PhaseEvent:
    """The start of an action phase.

    Attributes:
        stamp_ns: Time the phase starts, ns.
        receive_ns: Receive time, ns.
        phase: The phase that starts.
    """

    stamp_ns: int
    receive_ns: int
    phase: Phase


StreamItem: TypeAlias = SkinBlock | JointSample | PoseSample | PhaseEvent
