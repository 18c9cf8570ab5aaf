"""A scripted arm and skin for the runner's tests: a mock of hardware (tests only).

``FakeArm`` is an :class:`recorder.runner.ArmDriver` on the real clock: a state sample every
controller cycle, a TCP that follows ``speed`` and ``move`` commands, and one injected cause
(a force or workspace violation, a protective stop, silence, a lost connection) at a chosen
cycle after the contact. It records when ``stop`` was called, in cycles, so a test can say how
long the runner took from the cause to the stop.
"""

from __future__ import annotations

# ruff: noqa: ARG002 (a driver takes the interface's arguments; the fake uses few)
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Self

import numpy as np

from recorder.live import RecorderClock, SourceCounter, SourceLostError
from recorder.runner import ArmRig, ArmSample, Limits, RunnerOptions
from recorder.writing._stream import SkinBlock

if TYPE_CHECKING:
    from collections.abc import Mapping
    from types import TracebackType

    from numpy.typing import NDArray

    from recorder.runner import Context
    from schemas import SourceStats

START = np.array([-0.7, -0.2, 0.15, 0.0, np.pi, 0.0])
SURFACE_Z = 0.148  # the object's top: 2 mm below the start


@dataclass
class FakeArm:
    """An arm driver on the real clock; see the module docstring."""

    clock: RecorderClock
    period_ns: int = 8_000_000
    cause: str = ""  # force, workspace, protective, silence, lost, hang, or "" (none)
    cause_after_contact: int = 5  # cycles after the contact's stop
    pose: NDArray[np.float64] = field(default_factory=START.copy)
    velocity: NDArray[np.float64] = field(default_factory=lambda: np.zeros(6))
    target: NDArray[np.float64] | None = None
    target_speed: float = 0.0
    commands: list[tuple[int, str]] = field(default_factory=list)
    cause_cycle: int | None = None
    #: When the sample carrying the cause arrived (recorder clock, ns).
    cause_ns: int | None = None
    stop_cycle: int | None = None
    #: When the stop reached the arm (recorder clock, ns).
    stop_ns: int | None = None
    #: How long the caller's thread is held after a stop reached the arm (a loaded machine).
    hold_after_stop_s: float = 0.0
    #: Cycles from a motion command to its start (a program's way to the controller).
    latency_cycles: int = 0
    #: Why a stop cannot reach the arm (a lost connection no new one replaces; "": it can).
    stop_fails: str = ""
    #: Whether the contact's stop fails too (else only the stops after a cause).
    contact_stop_fails: bool = False
    #: Whether the arm goes on moving after a stop it took (a controller that ignored it).
    stop_ignored: bool = False
    #: The joints' speed while the arm moves, rad/s.
    moving_qd: float = 0.01
    #: The cycle from which the arm's state stops arriving (a stalled stream; None: never).
    silent_from: int | None = None
    #: Set to hang the driver (cause "hang"): its poll after the cause, or its stop when
    #: ``hang_in`` is "stop", waits on this event until the test sets it.
    released: threading.Event | None = None
    hang_in: str = "poll"
    #: The cycle at which each ``move`` reached its target, by phase.
    reached: dict[str, int] = field(default_factory=dict)
    #: The stamp of the sample at which each ``move`` reached its target, by phase (ns).
    reached_ns: dict[str, int] = field(default_factory=dict)
    _pending: list[tuple[int, str, NDArray[np.float64] | None, float]] = field(default_factory=list)
    _moving_phase: str = ""
    _queued_velocity: NDArray[np.float64] = field(default_factory=lambda: np.zeros(6))
    _next_ns: int = 0
    _cycle: int = 0
    _stamp_ns: int = 0
    _contact_cycle: int | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def __enter__(self) -> Self:
        self._next_ns = self.clock.now_ns()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        pass

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(f"j{i}" for i in range(6))

    def describe(self) -> Mapping[str, str]:
        return {"arm": "fake"}

    def facts(self) -> Mapping[str, str]:
        return {"firmware": "1.0"}

    def begin(self) -> None:
        self._cycle = 0
        self._next_ns = max(self._next_ns, self.clock.now_ns() - self.period_ns)

    def _step(self) -> None:
        dt = self.period_ns / 1e9
        while self._pending and self._pending[0][0] <= self._cycle:
            _, phase, target, value = self._pending.pop(0)
            if target is None:  # a slide or a speed: value is unused, velocity was queued
                self.target, self.velocity = None, self._queued_velocity
            else:
                self.target, self.target_speed, self._moving_phase = target, value, phase
        if self.target is not None:
            delta = self.target[:3] - self.pose[:3]
            distance = float(np.linalg.norm(delta))
            step = min(distance, self.target_speed * dt)
            if distance > 0:
                self.pose[:3] += delta / distance * step
            else:  # there: a real arm's program ends and its joints stand still
                self.target = None
                self.reached.setdefault(self._moving_phase, self._cycle)
                self.reached_ns.setdefault(self._moving_phase, self._stamp_ns)
        else:
            self.pose[:3] += self.velocity[:3] * dt
            self.pose[2] = max(self.pose[2], SURFACE_Z - 0.003)  # the object stops the arm

    def poll(self, wait_s: float) -> list[ArmSample]:
        if self.released is not None and self.hang_in == "poll" and self.cause_cycle is not None:
            self.released.wait()  # a driver stuck on a dead socket or a lock
        deadline = self.clock.now_ns() + round(wait_s * 1e9)
        samples: list[ArmSample] = []
        while True:
            now = self.clock.now_ns()
            while self._next_ns <= now:
                sample = self._sample(self._next_ns)
                self._next_ns += self.period_ns
                if sample is not None:
                    samples.append(sample)
            if samples or now >= deadline:
                return samples
            threading.Event().wait(min(0.001, (deadline - now) / 1e9))

    def _due(self) -> bool:
        return (
            self.cause != ""
            and self._contact_cycle is not None
            and self._cycle >= self._contact_cycle + self.cause_after_contact
        )

    def _sample(self, stamp_ns: int) -> ArmSample | None:
        self._cycle += 1
        self._stamp_ns = stamp_ns
        self._step()
        force = np.zeros(6)
        pose = self.pose.copy()
        stopped = ""
        if self._due():
            if self.cause_cycle is None:
                self.cause_cycle, self.cause_ns = self._cycle, stamp_ns
            if self.cause == "silence":
                return None
            if self.cause == "lost":
                msg = "fake arm: connection reset"
                raise SourceLostError(msg)
            if self.cause == "force":
                force[2] = 100.0
            elif self.cause == "workspace":
                pose[2] = -0.5
            elif self.cause == "protective":
                stopped = "protective stop (fake)"
        if self.silent_from is not None and self._cycle >= self.silent_from:
            return None
        moving = self.target is not None or bool(np.any(self.velocity))
        qd = np.full(6, self.moving_qd if moving else 0.0)
        return ArmSample(stamp_ns, stamp_ns, np.zeros(6), qd, np.zeros(6), pose, force, stopped)

    def speed(
        self, velocity: NDArray[np.float64], acceleration: float, duration_s: float, at: Context
    ) -> None:
        self.commands.append((self._cycle, f"speed {at.phase}"))
        self.target, self.velocity = None, np.asarray(velocity, dtype=np.float64).copy()

    def move(
        self, pose: NDArray[np.float64], speed: float, acceleration: float, at: Context | None
    ) -> None:
        phase = "present" if at is None else at.phase
        self.commands.append((self._cycle, f"move {phase}"))
        target = np.asarray(pose, dtype=np.float64).copy()
        if self.latency_cycles:
            self._pending.append((self._cycle + self.latency_cycles, phase, target, speed))
            return
        self.target, self.target_speed, self._moving_phase = target, speed, phase

    def force_slide(
        self,
        force_n: float,
        velocity: NDArray[np.float64],
        duration_s: float,
        acceleration: float,
        at: Context,
    ) -> None:
        self.commands.append((self._cycle, f"slide {at.phase}"))
        if self.latency_cycles:
            self._queued_velocity = np.asarray(velocity, dtype=np.float64).copy()
            self._pending.append((self._cycle + self.latency_cycles, at.phase, None, 0.0))
            return
        self.target, self.velocity = None, np.asarray(velocity, dtype=np.float64).copy()

    def announce(self, at: Context) -> None:
        self.commands.append((self._cycle, f"announce {at.phase}"))

    def stop(self, acceleration: float, at: Context | None) -> str:
        phase = "stop" if at is None else at.phase
        if self.released is not None and self.hang_in == "stop" and phase != "contact":
            self.released.wait()
        if self.stop_fails and (phase != "contact" or self.contact_stop_fails):
            self.commands.append((self._cycle, f"stop {phase} failed"))
            raise SourceLostError(self.stop_fails)
        self.commands.append((self._cycle, f"stop {phase}"))
        if not (self.stop_ignored and phase != "contact"):
            self.target, self.velocity, self._pending = None, np.zeros(6), []
        if phase == "contact":
            self._contact_cycle = self._cycle
        elif self.stop_cycle is None:
            self.stop_cycle, self.stop_ns = self._cycle, self.clock.now_ns()
            time.sleep(self.hold_after_stop_s)
        return ""

    def stats(self) -> list[SourceStats]:
        return [SourceCounter("fake-arm", period_ns=self.period_ns).stats()]


class FakeSkin:
    """A live skin whose force rises when the fake arm's TCP is below the surface."""

    def __init__(self, arm: FakeArm, clock: RecorderClock) -> None:
        self.arm, self.clock = arm, clock
        self._next_ns = 0
        self.fail = False
        #: How long a poll takes once the arm met its cause (a skin slow to read), s.
        self.slow_after_cause_s = 0.0
        #: How late the skin's samples arrive (a transport that delivers late), ns.
        self.delay_ns = 0
        #: A skin that sends nothing (unplugged, or its sender not started).
        self.mute = False

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *_: object) -> None:
        pass

    @property
    def cells(self) -> int:
        return 1

    def begin(self) -> None:
        self._next_ns = self.clock.now_ns()

    def _force(self) -> float:
        return max(0.0, (SURFACE_Z - float(self.arm.pose[2])) * 200.0)

    def poll(self) -> list[SkinBlock]:
        if self.fail:
            msg = "fake skin: a bug"
            raise RuntimeError(msg)
        if self.arm.cause_cycle is not None:
            time.sleep(self.slow_after_cause_s)
        now = self.clock.now_ns()
        if self.mute or now - self.delay_ns - self._next_ns < 4_000_000:
            return []
        count = (now - self.delay_ns - self._next_ns) // 4_000_000
        data = np.full((int(count), 1, 3), self._force() / 3, dtype=np.float32)
        block = SkinBlock("force", self._next_ns, 4_000_000, now, data)
        self._next_ns += int(count) * 4_000_000
        return [block]

    def finish(self) -> list[SkinBlock]:
        return []

    def total_force(self) -> float | None:
        return self._force()

    def nearest(self) -> float | None:
        return float(self.arm.pose[2] - SURFACE_Z)

    def last_receive_ns(self) -> int | None:
        return None if self.mute else self.clock.now_ns()

    def stats(self) -> list[SourceStats]:
        return []


def fake_rig(cause: str = "", *, period_ns: int = 8_000_000, latency_cycles: int = 0) -> ArmRig:
    """Return a runner over a fake arm and skin (time scale 0.05: actions are short)."""
    clock = RecorderClock()
    arm = FakeArm(clock, period_ns=period_ns, cause=cause, latency_cycles=latency_cycles)
    options = RunnerOptions(time_scale=0.05, silence_s=0.1)
    return ArmRig(
        arm,
        FakeSkin(arm, clock),
        Limits(),
        options,
        {"wood": START.tolist()},
        kind="fake",
        where="fake.toml",
        clock=clock,
    )
