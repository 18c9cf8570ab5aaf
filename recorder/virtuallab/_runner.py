"""The virtual controller's program runner: URScript calls executed one controller cycle a step.

As on a UR controller, one program runs at a time and a new one replaces it at the next cycle
(the arm's commanded speed carries over: the new program's first motion starts from it).
Each cycle the runner runs the instantaneous calls it reaches (``textmsg``, ``force_mode``,
``end_force_mode``, ``get_actual_tcp_pose``) and advances the motion call it is in:

- ``speedl(xd, a, t[, aRot])``: the commanded TCP twist ramps towards ``xd`` at ``a`` (m/s^2;
  rotation at ``aRot``, default ``a``); returns after ``t`` s (none: never), the twist stays;
- ``stopl(a[, aRot])``: the twist ramps to zero at ``a``; returns when still;
- ``movel(pose, a=1.2, v=0.25)``: a straight line to ``pose`` with a trapezoidal speed
  (accelerating and braking at ``a``, at most ``v``; the orientation turns in proportion),
  returns when there;
- ``sleep(t)``: returns after ``t`` s, the twist stays.

When a program ends, the arm brakes at the last acceleration it was given (force mode ends).
``force_mode(frame, selection, wrench, type, limits)``: along each selected translation axis
of ``frame`` (``get_actual_tcp_pose()`` is read when the call runs) the controller no longer
follows the commanded twist but moves to reach the wrench's force against the touched face,
at most at that axis's speed limit; ``end_force_mode()`` ends it. Times, speeds and
accelerations are world seconds (see the time scale in ``_world``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Final, Protocol

import numpy as np

from recorder.virtuallab._arm import (
    DEFAULT_ACCELERATION,
    STILL,
    matrix_pose,
    pose_matrix,
    ramp,
    twist_between,
)
from recorder.virtuallab._urscript import ActualPose, Call, Pose, Program

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from recorder.virtuallab._arm import KinematicArm

    F64 = NDArray[np.float64]

#: Fastest rotation of a movel, rad/s.
MOVEL_ANGULAR_SPEED: Final = 0.5
#: Default speed of a movel without ``v``, m/s (URScript's).
MOVEL_SPEED: Final = 0.25
#: Calls that take no time.
INSTANT: Final = frozenset({"textmsg", "force_mode", "end_force_mode", "get_actual_tcp_pose"})
#: RTDE ``runtime_state`` values (the controller's program state).
RUNTIME_STOPPING: Final = 0
RUNTIME_STOPPED: Final = 1
RUNTIME_PLAYING: Final = 2
RUNTIME_PAUSED: Final = 4


class Hooks(Protocol):
    """What the runner asks of the world."""

    def started(self, program: Program) -> None:
        """A program's first call runs."""

    def message(self, text: str) -> None:
        """A ``textmsg``."""

    def force_speed(self, axis: F64, force_n: float, limit_m_s: float, dt_s: float) -> float:
        """Return the speed along ``axis`` that brings the contact force to ``force_n``."""
        ...


@dataclass(frozen=True, slots=True)
class ForceMode:
    """An active ``force_mode``: the task frame's rotation, selection, wrench and limits."""

    rotation: F64
    selection: tuple[float, ...]
    wrench: tuple[float, ...]
    limits: tuple[float, ...]


def _number(value: object, default: float) -> float:
    return float(value) if isinstance(value, float) else default


def _vector(value: object, size: int) -> tuple[float, ...]:
    if isinstance(value, tuple) and len(value) == size:
        return tuple(float(v) for v in value)
    return (0.0,) * size


def braking_speed(distance: float, acceleration: float, dt: float) -> float:
    """Return the fastest speed from which braking at ``a`` per cycle stops within ``distance``.

    Braking by ``a dt`` each cycle from ``v`` covers ``v^2 / 2a + v dt / 2``; solved for ``v``.
    """
    step = acceleration * dt
    return float(0.5 * (-step + np.sqrt(step * step + 8.0 * acceleration * distance)))


class ProgramRunner:
    """Runs one program at a time on a :class:`KinematicArm` (not thread-safe: the world locks)."""

    def __init__(self, hooks: Hooks) -> None:
        """Start idle."""
        self._hooks = hooks
        self.program: Program | None = None
        self.force_mode: ForceMode | None = None
        self._pc = 0
        self._elapsed = 0.0
        self._began = False
        self._braking = False
        self._paused = False
        self._acceleration = DEFAULT_ACCELERATION

    @property
    def running(self) -> bool:
        """Whether a program runs (or the arm still brakes after its end)."""
        return self.program is not None or self._braking

    @property
    def state(self) -> int:
        """The program's state as RTDE's ``runtime_state`` says it.

        0 stopping (the arm brakes after the program's end), 1 stopped, 2 playing, 4 paused.
        """
        if self.program is not None:
            return RUNTIME_PAUSED if self._paused else RUNTIME_PLAYING
        return RUNTIME_STOPPING if self._braking else RUNTIME_STOPPED

    def pause(self) -> None:
        """Pause the program (the pendant's pause): the arm brakes, the program waits."""
        if self.program is not None:
            self._paused = True

    def resume(self) -> bool:
        """Resume a paused program where it was (the pendant's play); False: none paused."""
        paused, self._paused = self._paused, False
        return paused

    def load(self, program: Program) -> None:
        """Replace the running program (at the next cycle)."""
        self.program, self.force_mode = program, None
        self._pc, self._elapsed, self._began, self._braking = 0, 0.0, False, False
        self._paused = False

    def finish(self) -> None:
        """End the program now: force mode ends, the arm brakes at the last acceleration."""
        if self.program is not None:
            self.program, self.force_mode, self._braking = None, None, True
        self._paused = False

    def abort(self) -> None:
        """Drop the program (a protective stop): nothing runs until the next program."""
        self.program, self.force_mode, self._braking = None, None, False
        self._paused = False

    def step(self, arm: KinematicArm, dt: float) -> F64:
        """Run one cycle; return the commanded TCP twist for it."""
        twist: F64 = arm.twist.copy()
        if self._paused:  # the arm brakes; the program goes on from here when resumed
            return ramp(twist, np.zeros(6), self._acceleration, dt)
        while self.program is not None:
            calls = self.program.calls
            if self._pc >= len(calls):
                self.program, self.force_mode, self._braking = None, None, True
                break
            if not self._began:
                self._began = True
                self._hooks.started(self.program)
            call = calls[self._pc]
            if call.name in INSTANT:
                self._instant(call, arm)
                self._next()
                continue
            twist, done = self._motion(call, arm, twist, dt)
            if done:
                self._next()
            return self._comply(twist, dt)
        if self._braking:
            twist = ramp(twist, np.zeros(6), self._acceleration, dt)
            self._braking = bool(np.abs(twist).max() > STILL)
        return twist

    def _next(self) -> None:
        self._pc += 1
        self._elapsed = 0.0

    def _instant(self, call: Call, arm: KinematicArm) -> None:
        """Run a call that takes no time."""
        if call.name == "textmsg":
            self._hooks.message(str(call.arg(0, "s", "")))
        elif call.name == "force_mode":
            frame = call.arg(0, "task_frame")
            pose = frame.values if isinstance(frame, Pose) else None
            if isinstance(frame, ActualPose) or pose is None:
                pose = tuple(matrix_pose(arm.tcp()))
            self.force_mode = ForceMode(
                pose_matrix(np.asarray(pose, dtype=np.float64))[:3, :3],
                _vector(call.arg(1, "selection_vector"), 6),
                _vector(call.arg(2, "wrench"), 6),
                _vector(call.arg(4, "limits"), 6),
            )
        elif call.name == "end_force_mode":
            self.force_mode = None

    def _motion(self, call: Call, arm: KinematicArm, twist: F64, dt: float) -> tuple[F64, bool]:
        """Advance a motion call by one cycle; return the twist and whether it returned."""
        self._elapsed += dt
        if call.name == "speedl":
            wanted = np.asarray(_vector(call.arg(0, "xd"), 6))
            a = self._accelerate(call.arg(1, "a"))
            spin = _number(call.arg(3, "aRot"), a)
            limit = call.arg(2, "t")
            moved = np.concatenate(
                [ramp(twist[:3], wanted[:3], a, dt), ramp(twist[3:], wanted[3:], spin, dt)]
            )
            return moved, isinstance(limit, float) and self._elapsed >= limit
        if call.name == "stopl":
            a = self._accelerate(call.arg(0, "a"))
            spin = _number(call.arg(1, "aRot"), a)
            moved = np.concatenate(
                [ramp(twist[:3], np.zeros(3), a, dt), ramp(twist[3:], np.zeros(3), spin, dt)]
            )
            return moved, bool(np.abs(moved).max() <= STILL)
        if call.name == "movel":
            return self._movel(call, arm, twist, dt)
        limit = call.arg(0, "t", 0.0)  # sleep
        return twist, self._elapsed >= (limit if isinstance(limit, float) else 0.0)

    def _accelerate(self, value: object) -> float:
        """Return a call's acceleration (and remember it for the program's end)."""
        a = _number(value, DEFAULT_ACCELERATION)
        self._acceleration = a if a > 0 else DEFAULT_ACCELERATION
        return self._acceleration

    def _movel(self, call: Call, arm: KinematicArm, twist: F64, dt: float) -> tuple[F64, bool]:
        """Advance a ``movel`` by one cycle (trapezoidal speed along the line)."""
        goal_value = call.arg(0, "pose")
        if not isinstance(goal_value, Pose | tuple) or len(_goal(goal_value)) != 6:  # noqa: PLR2004
            return np.zeros(6), True
        goal = pose_matrix(np.asarray(_goal(goal_value), dtype=np.float64))
        a = self._accelerate(call.arg(1, "a"))
        v = _number(call.arg(2, "v"), MOVEL_SPEED)
        error = twist_between(arm.target, goal)
        distance, turn = float(np.linalg.norm(error[:3])), float(np.linalg.norm(error[3:]))
        speed = min(v, braking_speed(distance, a, dt))
        direction = error[:3] / distance if distance > 0 else np.zeros(3)
        linear = ramp(twist[:3], direction * speed, a, dt)
        pace = float(np.linalg.norm(linear))
        left_s = distance / pace if pace > STILL else turn / MOVEL_ANGULAR_SPEED
        spin = error[3:] / max(left_s, dt)
        spin_speed = float(np.linalg.norm(spin))
        if spin_speed > MOVEL_ANGULAR_SPEED:
            spin *= MOVEL_ANGULAR_SPEED / spin_speed
        if distance <= pace * dt + 1e-9 and turn <= MOVEL_ANGULAR_SPEED * dt + 1e-9:
            arm.aim(goal)  # the rest of the line within this cycle: there
            return np.zeros(6), True
        return np.concatenate([linear, spin]), False

    def _comply(self, twist: F64, dt: float) -> F64:
        """Replace the selected axes' motion by the force controller's (force mode)."""
        mode = self.force_mode
        if mode is None:
            return twist
        out = twist.copy()
        for axis_index in range(3):
            if not mode.selection[axis_index]:
                continue
            axis = mode.rotation[:, axis_index]
            out[:3] -= axis * float(out[:3] @ axis)
            force = mode.wrench[axis_index]
            if force != 0:
                limit = abs(mode.limits[axis_index])
                out[:3] += axis * self._hooks.force_speed(axis, force, limit, dt)
        return out


def _goal(value: Pose | tuple[float, ...]) -> tuple[float, ...]:
    return value.values if isinstance(value, Pose) else value
