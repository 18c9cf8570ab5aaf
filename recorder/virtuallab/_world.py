"""The virtual lab's world: a kinematic UR10 running URScript over the simulator's objects.

The world is a controller stepped one cycle at a time (125 Hz CB3 or 500 Hz e-Series) on its
own clock (``controller_ns``: ns since the lab started, RTDE's ``timestamp``). Each cycle the
program runner (``_runner``) advances the running URScript program and commands a TCP twist;
the arm (``_arm``) follows it by resolved rate and its TCP is the forward kinematics of its
joints; the skin (``_skinmodel``) samples the touched object's face at the arm's actual
positions. Every server reads the world's state at its own instants: the latest cycle at or
before (sample and hold; the skin on a 1 ms grid inside the cycle). A read or the world's own
ticking thread (``with world:``) computes the cycles due; the world never runs ahead of its
clock. The last seconds of cycles are kept for readers a little behind.

Time scale: with ``time_scale`` S (0 < S <= 1) the controller's clock and cycles run in real
time, and each cycle advances the world by ``period / S``: the arm moves, the skin heats and
the programs' ``t``, ``sleep`` and speeds run 1/S times faster than the clock. Speeds and
accelerations in programs, in ``actual_TCP_speed``, ``actual_qd`` and ``target_TCP_speed`` are
world units (per world second); the pose's change over RTDE's ``timestamp`` is therefore 1/S
times the reported speed. At S = 1 (a rehearsal at real time) both agree. A rig against a
lab at S < 1 sets ``time_scale = S`` so that it holds and slides for S times the durations.

A protective or emergency stop halts the arm at once and drops the program; programs are
refused until ``unlock`` (the pendant's "unlock protective stop", or the dashboard server).
What happened is recorded with both clocks (``_events``; ``events()``).
"""

from __future__ import annotations

import importlib
import logging
import math
import threading
import time
import weakref
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Self

import numpy as np

from recorder.errors import RigError
from recorder.virtuallab._arm import STILL, KinematicArm, matrix_pose, pose_matrix
from recorder.virtuallab._events import Event, EventLog
from recorder.virtuallab._runner import RUNTIME_PLAYING, RUNTIME_STOPPED, ProgramRunner
from recorder.virtuallab._skinmodel import SUB_NS, SkinModel, Surface
from recorder.virtuallab._urscript import Call, Program
from schemas import VOCABULARY

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence
    from types import TracebackType

    from numpy.typing import NDArray

    from recorder._catalog import ActionSpec, ObjectSpec
    from recorder._sim import SimulatedRig

    F64 = NDArray[np.float64]

_log = logging.getLogger("atikt.virtuallab")
#: RTDE ``robot_mode`` values the virtual arm takes (the controller's RobotMode enumeration):
#: powered off, powered on with the brakes engaged, running (brakes released).
ROBOT_MODE_POWER_OFF = 3
ROBOT_MODE_IDLE = 5
ROBOT_MODE_RUNNING = 7
#: RTDE ``safety_status`` values (the controller's SafetyStatus enumeration).
SAFETY_NORMAL = 1
SAFETY_PROTECTIVE_STOP = 3
SAFETY_EMERGENCY_STOP = 7  # SAFETY_STATUS_ROBOT_EMERGENCY_STOP
_STOPS = {"protective": SAFETY_PROTECTIVE_STOP, "emergency": SAFETY_EMERGENCY_STOP}
#: Where the virtual arm waits before anything moved it: above the simulator's workspace, the
#: tool pointing down (x, y, z in m, rotation vector in rad).
HOME_POSE = (-0.6, -0.2, 0.2, 0.0, np.pi, 0.0)
#: Seconds of cycles kept for readers.
HISTORY_S = 4
#: Newest cycles readers search without the lock.
RECENT = 32
#: Phase announcements kept for readers such as the ROS 2 publisher (each action says ~5).
ANNOUNCED = 1024
#: Lines of the controller's log kept (a ring: the oldest go first).
LOG_LINES = 1000
#: The least time between two lines saying the world fell behind its clock, s.
OVERRUN_EVERY_S = 10.0
#: Cycles the world may fall behind its clock before it computes the backlog as one cycle
#: (moving the world by one cycle only: the world slows down, it never jumps).
MAX_BACKLOG = 3


@dataclass(frozen=True, slots=True)
class RobotState:
    """The arm's state at one controller time, in RTDE's units.

    Attributes:
        q: Joint positions, rad, shape (joints,).
        qd: Joint velocities, rad/s, shape (joints,).
        tcp_pose: TCP pose (x, y, z, rx, ry, rz): m and a rotation vector, rad; the forward
            kinematics of ``q``.
        tcp_force: Force and torque at the TCP (fx, fy, fz, tx, ty, tz), N and N m, base frame.
        robot_mode: RTDE robot mode (7: running).
        safety_status: RTDE safety status (1 normal, 3 protective stop, 7 emergency stop).
        effort: Joint torques, N m, shape (joints,) (RTDE ``target_moment``).
        tcp_speed: Actual TCP twist (m/s, rad/s, base frame) over the last cycle.
        target_tcp_speed: Commanded TCP twist.
        target_pose: The pose the joints follow.
        speed_fraction: The teach pendant's speed slider, 0..1 (RTDE ``target_speed_fraction``).
        runtime_state: The program's state (RTDE ``runtime_state``: 0 stopping, 1 stopped,
            2 playing, 4 paused).
    """

    q: F64
    qd: F64
    tcp_pose: F64
    tcp_force: F64
    robot_mode: int
    safety_status: int
    effort: F64 = field(default_factory=lambda: np.zeros(6))
    tcp_speed: F64 = field(default_factory=lambda: np.zeros(6))
    target_tcp_speed: F64 = field(default_factory=lambda: np.zeros(6))
    target_pose: F64 | None = None
    speed_fraction: float = 1.0
    runtime_state: int = RUNTIME_STOPPED


@dataclass(frozen=True, slots=True)
class _Cycle:
    """One controller cycle ``(start_ns, end_ns]``: the state at its end, the skin inside."""

    start_ns: int
    end_ns: int
    state: RobotState
    skin: Mapping[str, F64]
    phase: str | None
    action: tuple[str, str, int] | None


@dataclass
class VirtualWorld:
    """A virtual UR10 controller with a skin over the simulator's objects; thread-safe.

    Attributes:
        rig: A connected simulated rig (inside its ``with`` block): its skin and objects.
        objects: The objects a program may announce, by id.
        actions: The actions a program may announce, by id.
        time_scale: Real seconds per world second (0.1: ten times faster; 1: real time).
        clock: The machine's monotonic clock, ns.
        frequency: Controller cycles per second: 125 (CB3) or 500 (e-Series).
        poses: Object id -> pose where the rig presents it (its face lies below).
        seed: Seed of the skin's noise.
        events_log: What happened, with both clocks.
        overruns: Cycles computed merged with the next because the world fell behind its
            clock by more than ``MAX_BACKLOG`` cycles (0 on a machine fast enough).
    """

    rig: SimulatedRig
    objects: Mapping[str, ObjectSpec]
    actions: Mapping[str, ActionSpec]
    time_scale: float = 1.0
    clock: Callable[[], int] = time.monotonic_ns
    frequency: int = 125
    poses: Mapping[str, Sequence[float]] = field(default_factory=dict)
    seed: int = 0
    events_log: EventLog = field(default_factory=EventLog)
    overruns: int = field(default=0, init=False)
    #: When the world last said it fell behind (``clock``, ns; -inf: never).
    _overrun_said: float = field(default=-math.inf, init=False, repr=False)
    _lock: threading.RLock = field(default_factory=threading.RLock, init=False)
    _origin_ns: int = field(default=0, init=False)
    _period_ns: int = field(default=8_000_000, init=False)
    _arm: KinematicArm = field(init=False)
    _skin: SkinModel = field(init=False)
    _runner: ProgramRunner = field(init=False)
    _pending: Program | None = field(default=None, init=False)
    _cycles: deque[_Cycle] = field(init=False)
    _surfaces: dict[str, Surface] = field(default_factory=dict, init=False)
    _action: tuple[str, str, int] | None = field(default=None, init=False)
    _phase: str | None = field(default=None, init=False)
    _safety: int = field(default=SAFETY_NORMAL, init=False)
    _mode: int = field(default=ROBOT_MODE_RUNNING, init=False)
    _slider: float = field(default=1.0, init=False)
    _moving: tuple[bool, bool] = field(default=(False, False), init=False)
    _log: deque[str] = field(default_factory=lambda: deque(maxlen=LOG_LINES), init=False)
    _listeners: list[Callable[[tuple[str, str, int]], None]] = field(
        default_factory=list, init=False
    )
    _program_listeners: list[Callable[[str], None]] = field(default_factory=list, init=False)
    _first_action_ns: int | None = field(default=None, init=False)
    _world_s: float = field(default=0.0, init=False)
    _recent: tuple[_Cycle, ...] = field(default=(), init=False)
    #: Every phase announced, as (controller ns of its cycle's end, key, phase), in order;
    #: a ring of the latest ``ANNOUNCED`` (``_said`` counts them all).
    _announced: deque[tuple[int, tuple[str, str, int], str]] = field(
        default_factory=lambda: deque(maxlen=ANNOUNCED), init=False
    )
    _said: int = field(default=0, init=False)
    _cycle_end_ns: int = field(default=0, init=False)
    _ticker: threading.Thread | None = field(default=None, init=False)
    _stopping: threading.Event = field(default_factory=threading.Event, init=False)

    def __post_init__(self) -> None:
        """Start the controller's clock with the arm at rest at its home pose.

        Raises:
            RigError: A time scale outside (0, 1] or a frequency other than 125 or 500 Hz.
        """
        if not 0 < self.time_scale <= 1:
            msg = f"time_scale = {self.time_scale} must be in (0, 1]; 1 is real time"
            raise RigError(msg)
        if self.frequency not in {125, 500}:
            msg = f"frequency = {self.frequency}: give 125 (CB3) or 500 (e-Series)"
            raise RigError(msg)
        self._period_ns = 1_000_000_000 // self.frequency
        # the skin's filters import scipy.signal on first use (~0.8 s): here, not in a cycle
        importlib.import_module("scipy.signal")
        self._origin_ns = self.clock()
        self._arm = KinematicArm.at(np.array(HOME_POSE))
        self._skin = SkinModel(self.rig, self.seed)
        self._runner = ProgramRunner(self)
        self._cycles = deque(maxlen=HISTORY_S * self.frequency)
        self._cycles.append(self._cycle(-self._period_ns, 0))
        self._recent = (self._cycles[-1],)
        self.events_log.add(
            "start",
            0,
            origin_monotonic_ns=self._origin_ns,
            frequency=self.frequency,
            time_scale=self.time_scale,
        )

    # -- the clock and the stepping -------------------------------------------------------

    def __enter__(self) -> Self:
        """Start ticking: cycles are computed on time even when nobody reads."""
        self._start_ticking()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Stop ticking."""
        self._stopping.set()
        if self._ticker is not None:
            self._ticker.join(2.0)
            self._ticker = None

    def _start_ticking(self) -> None:
        """Start the ticking thread (it ends with the world: it holds only a weak reference)."""
        if self._ticker is not None:
            return
        self._stopping.clear()
        self._ticker = threading.Thread(
            target=_tick, args=(weakref.ref(self), self._stopping), name="atikt-vlab", daemon=True
        )
        self._ticker.start()

    @property
    def period_ns(self) -> int:
        """Return the controller's cycle, ns."""
        return self._period_ns

    def controller_ns(self) -> int:
        """Return the controller's time: ns since the virtual lab started."""
        return self.clock() - self._origin_ns

    def advance_to(self, controller_ns: int, wait_s: float = -1.0) -> None:
        """Compute every cycle that ends at or before ``controller_ns`` (and not after now).

        Args:
            controller_ns: The controller time to reach.
            wait_s: How long to wait for another thread computing a cycle (negative: as long
                as it takes); past it the caller reads what is there.
        """
        limit = min(controller_ns, self.controller_ns())
        if self._cycles[-1].end_ns + self._period_ns > limit:
            return
        if not self._lock.acquire(timeout=wait_s):
            return
        try:
            while self._cycles[-1].end_ns + self._period_ns <= limit:
                self._next_cycle(limit)
        finally:
            self._lock.release()

    def _next_cycle(self, limit: int) -> None:
        """Compute the next cycle (with the lock held); a backlog is computed as one."""
        last = self._cycles[-1].end_ns
        due = (limit - last) // self._period_ns
        span = 1
        if due > MAX_BACKLOG:  # fallen behind (a loaded machine): catch up at once
            span = due
            self.overruns += due - 1
            now = self.clock()
            if now >= self._overrun_said + OVERRUN_EVERY_S * 1e9:  # again at most every 10 s
                self._overrun_said = now
                _log.warning(
                    "virtual controller behind its clock by %d cycles (%d cycles merged so "
                    "far): computed as one, the world slows down (the machine is too loaded "
                    "for the cycle rate); a recorder may see silence or late programs",
                    due,
                    self.overruns,
                )
        self._cycles.append(self._cycle(last, last + span * self._period_ns))
        self._recent = (*self._recent[-(RECENT - 1) :], self._cycles[-1])

    def _cycle(self, start_ns: int, end_ns: int) -> _Cycle:
        """Run one controller cycle (with the lock held).

        A cycle spanning more than one period (the world fell behind its clock) still moves
        the world by one period: the world slows down rather than jump (no motion larger
        than a cycle's between two states).
        """
        dt = min(end_ns - start_ns, self._period_ns) / 1e9 / self.time_scale
        self._cycle_end_ns = end_ns
        if self._pending is not None:
            self._runner.load(self._pending)
            self._pending = None
        before = self._arm.tcp()[:3, 3].copy()
        free = self._safety == SAFETY_NORMAL and self._mode == ROBOT_MODE_RUNNING
        # the speed slider slows the program and the arm's motion alike, as a controller's does:
        # the program runs `moved` s of its time in this cycle's `dt`
        moved = dt * self._slider
        twist = self._runner.step(self._arm, moved) if free else np.zeros(6)
        self._arm.step(twist, moved)
        if self._slider != 1.0:  # the speeds the arm reports: its motion over the real dt
            self._arm.qd = self._arm.qd * self._slider
            self._arm.tcp_speed = self._arm.tcp_speed * self._slider
        after = self._arm.tcp()[:3, 3]
        count = max(1, (end_ns - start_ns) // SUB_NS)
        share = np.arange(1, count + 1) / count
        positions = before + share[:, None] * (after - before)
        world_s = self._world_s + share * dt
        self._world_s += dt
        surface = self._surfaces.get(self._action[0]) if self._action else None
        skin = self._skin.sample(surface, positions, world_s, dt)
        state = self._state(surface)
        self._note_zeros(end_ns, state)
        return _Cycle(start_ns, end_ns, state, skin, self._phase, self._action)

    def _state(self, surface: Surface | None) -> RobotState:
        """Return the arm's state now (forces from the skin's true contact force)."""
        arm = self._arm
        wrench = np.zeros(6)
        if surface is not None:
            wrench[:3] = surface.normal * self._skin.total_force()
        return RobotState(
            arm.q.copy(),
            arm.qd.copy(),
            arm.pose(),
            wrench,
            self._mode,
            self._safety,
            arm.torques(wrench[:3]),
            arm.tcp_speed.copy(),
            arm.twist.copy(),
            matrix_pose(arm.target),
            self._slider,
            RUNTIME_PLAYING if self._pending is not None else self._runner.state,
        )

    def _note_zeros(self, end_ns: int, state: RobotState) -> None:
        """Record when the commanded and the actual TCP speed reach zero after moving."""
        moving = (
            bool(np.abs(state.target_tcp_speed).max() > STILL),
            bool(np.abs(state.tcp_speed).max() > STILL),
        )
        for kind, was, now in zip(
            ("commanded_zero", "actual_zero"), self._moving, moving, strict=True
        ):
            if was and not now:
                self.events_log.add(kind, end_ns, program=self._program_name())
        self._moving = moving

    def _program_name(self) -> str:
        program = self._runner.program
        return _name(program.text) if program is not None else ""

    # -- the runner's hooks ---------------------------------------------------------------

    def started(self, program: Program) -> None:
        """Record a program's first call (the runner calls this inside a cycle)."""
        self.events_log.add(
            "program",
            self._cycles[-1].end_ns + self._period_ns,
            received_monotonic_ns=program.received_ns,
            name=_name(program.text),
            calls=[call.name for call in program.calls],
            announced=dict(program.announced),
        )
        for listener in list(self._program_listeners):
            listener(_name(program.text))

    def message(self, text: str) -> None:
        """Handle a ``textmsg``: an ``atikt:`` announcement names the action and its phase."""
        if not text.startswith("atikt:"):
            return
        pairs = dict(item.partition("=")[::2] for item in text.removeprefix("atikt:").split())
        self._announce(pairs)

    def force_speed(self, axis: F64, force_n: float, limit_m_s: float, dt_s: float) -> float:
        """Return the speed along ``axis`` that brings the contact force to ``force_n``.

        The controller knows the face's force curve: it moves half the way to the depth of
        that force each cycle, at most at the limit; with nothing under the arm, at the limit.
        """
        touch = self._skin.touch
        surface = self._surfaces.get(self._action[0]) if self._action else None
        if touch is None or surface is None:
            return float(np.sign(force_n) * limit_m_s)
        into = float(axis @ -surface.normal)
        if abs(into) < 0.1:  # noqa: PLR2004 (an axis along the face: no force to servo)
            return 0.0
        depth = float(surface.depth(self._arm.tcp()[:3, 3]))
        speed = 0.5 * (touch.depth_for(abs(force_n)) - depth) / dt_s / into
        return float(np.clip(speed, -limit_m_s, limit_m_s))

    def _announce(self, pairs: Mapping[str, str]) -> None:
        """Take an announcement: a new (object, action, trial) at ``approach`` begins it."""
        phase = pairs.get("phase", "approach")
        try:
            key = (pairs["object"], pairs["action"], int(pairs["trial"]))
        except (KeyError, ValueError):
            self.note(f"textmsg announcement {dict(pairs)} not understood")
            return
        self._phase = phase
        with self._lock:  # the cycle's lock is held already; readers take it too
            self._announced.append((self._cycle_end_ns, key, phase))
            self._said += 1
        if phase != "approach" or key == self._action:
            return
        obj, action = self.objects.get(key[0]), self.actions.get(key[1])
        if obj is None or action is None:
            what = f"object {key[0]!r}" if obj is None else f"action {key[1]!r}"
            self.note(f"textmsg announcement {dict(pairs)}: the virtual lab has no {what}")
            return
        now_ns = self._cycles[-1].end_ns + self._period_ns
        try:
            self._skin.begin(obj, action, key[2], self._world_s)
        except ValueError as err:
            self.note(f"textmsg announcement {dict(pairs)}: {err}")
            return
        if key[0] not in self._surfaces:
            pose = self.poses.get(key[0])
            where = pose_matrix(np.asarray(pose, dtype=np.float64)) if pose else self._arm.tcp()
            self._surfaces[key[0]] = Surface.below(where)
        self._action = key
        if self._first_action_ns is None:
            self._first_action_ns = now_ns
        self.events_log.add("action", now_ns, object=key[0], action=key[1], trial=key[2])
        for listener in list(self._listeners):
            listener(key)

    # -- programs, stops ------------------------------------------------------------------

    def run(self, program: Program) -> bool:
        """Run ``program`` from the next cycle on (it replaces the running one).

        Returns:
            False when the arm is stopped (the program is refused, with a log line).
        """
        with self._lock:
            if self._safety != SAFETY_NORMAL:
                self.note(
                    "URScript program refused: the arm is in a protective or emergency stop; "
                    "unlock it first"
                )
                return False
            if self._mode != ROBOT_MODE_RUNNING:
                self.note(
                    "URScript program refused: the arm is not running (powered off or its "
                    "brakes engaged); power it on and release the brakes first"
                )
                return False
            self._pending = program
            return True

    def stop(self, kind: str = "protective") -> None:
        """Stop the arm where it is (``protective`` or ``emergency``); the program ends."""
        with self._lock:
            self.advance_to(self.controller_ns())
            self._safety = _STOPS[kind]
            self._runner.abort()
            self._pending = None
            self._arm.halt()
            self.events_log.add("stop", self.controller_ns(), kind=kind)

    @property
    def safety(self) -> int:
        """Return the RTDE safety status now."""
        with self._lock:
            return self._safety

    def halt_program(self) -> None:
        """End the running program (the dashboard's ``stop``): the arm brakes as at its end."""
        with self._lock:
            self.events_log.add("halt", self.controller_ns(), program=self._program_name())
            self._pending = None
            self._runner.finish()

    @property
    def robot_mode(self) -> int:
        """Return the RTDE robot mode now."""
        with self._lock:
            return self._mode

    def power(self, mode: int) -> None:
        """Take the robot mode ``mode`` (dashboard: ``power off``, ``power on``, ``brake release``).

        Leaving the running mode ends the program and holds the arm where it is.
        """
        with self._lock:
            self.advance_to(self.controller_ns())
            if mode != ROBOT_MODE_RUNNING:
                self._runner.abort()
                self._pending = None
                self._arm.halt()
            self._mode = mode
            self.events_log.add("mode", self.controller_ns(), robot_mode=mode)

    def pause(self) -> None:
        """Pause the running program (the pendant's or the dashboard's ``pause``)."""
        with self._lock:
            self.advance_to(self.controller_ns())
            self._runner.pause()
            self.events_log.add("pause", self.controller_ns())

    def play(self) -> bool:
        """Resume a paused program (the pendant's or the dashboard's ``play``).

        Returns:
            False when no program was paused (nothing to play: the lab runs the programs it
            receives as they arrive).
        """
        with self._lock:
            self.advance_to(self.controller_ns())
            if not self._runner.resume():
                return False
            self.events_log.add("play", self.controller_ns())
            return True

    def slide_speed(self, fraction: float) -> None:
        """Set the teach pendant's speed slider (0.01..1): programs run that much slower."""
        with self._lock:
            self.advance_to(self.controller_ns())
            self._slider = min(max(float(fraction), 0.01), 1.0)
            self.events_log.add("slider", self.controller_ns(), fraction=self._slider)

    def unlock(self) -> None:
        """Release a stop (the pendant's "unlock protective stop")."""
        with self._lock:
            self._safety = SAFETY_NORMAL
            self.events_log.add("unlock", self.controller_ns())

    def place(self, pose: Sequence[float] | F64) -> None:
        """Put the arm at ``pose`` at once, at rest (tests; no controller can)."""
        with self._lock:
            self.advance_to(self.controller_ns())
            self._runner.abort()
            self._arm.place(np.asarray(pose, dtype=np.float64))

    def on_program(self, listener: Callable[[str], None]) -> None:
        """Call ``listener(name)`` when a program starts (inside a cycle: it must not block)."""
        self._program_listeners.append(listener)

    def on_action(self, listener: Callable[[tuple[str, str, int]], None]) -> None:
        """Call ``listener(object, action, trial)`` when an announced action begins."""
        self._listeners.append(listener)

    @property
    def first_action_ns(self) -> int | None:
        """Return the controller time the first announced action began (None: none yet)."""
        return self._first_action_ns

    # -- what the servers read ------------------------------------------------------------

    def _catch_up(self, controller_ns: int) -> None:
        """Compute the cycles due, unless the ticking thread does (readers never wait then).

        While ticking (``with world:``) a reader gets the latest cycle computed, at most one
        cycle late; the RTDE server calls :meth:`advance_to` itself so that every package is
        the state of its own instant.
        """
        if self._ticker is not None:
            return
        if self.clock is time.monotonic_ns:  # a real clock: tick (a stopped one: tests step)
            self._start_ticking()
        self.advance_to(controller_ns)

    def _find(self, test: Callable[[_Cycle], bool]) -> _Cycle:
        """Return the newest cycle passing ``test`` (the oldest kept when none does).

        The newest cycles are searched without the lock (an immutable snapshot, replaced
        whole each cycle), so a reader never waits for a cycle being computed.
        """
        for cycle in reversed(self._recent):
            if test(cycle):
                return cycle
        with self._lock:
            for cycle in reversed(self._cycles):
                if test(cycle):
                    return cycle
            return self._cycles[0]

    def _at(self, controller_ns: int) -> _Cycle:
        """Return the latest cycle ending at or before ``controller_ns`` (the oldest kept)."""
        self._catch_up(controller_ns)
        return self._find(lambda cycle: cycle.end_ns <= controller_ns)

    def robot_at(self, controller_ns: int) -> RobotState:
        """Return the arm's state at a controller time."""
        return self._at(controller_ns).state

    state_at = robot_at

    def skin_at(self, modality: str, controller_ns: int) -> F64 | None:
        """Return the skin's latest sample of ``modality`` (cells, values); None: no such.

        Force and acceleration are sampled every ms inside a cycle (at ``start + 1 ms``, ...,
        its end), temperature and proximity once a cycle.
        """
        self._catch_up(controller_ns)
        found = self._find(lambda cycle: cycle.start_ns + SUB_NS <= controller_ns)
        values = found.skin.get(modality)
        if values is None or values.ndim == 2:  # noqa: PLR2004 (cells, values): once a cycle
            return values
        index = (controller_ns - found.start_ns) // SUB_NS - 1
        sample: F64 = values[min(max(index, 0), values.shape[0] - 1)]
        return sample

    def phase_at(self, controller_ns: int) -> str | None:
        """Return the announced phase at a controller time (None: no action yet)."""
        return self._at(controller_ns).phase

    def announcements(
        self, after: int, until_ns: int
    ) -> tuple[list[tuple[int, tuple[str, str, int], str]], int]:
        """Return the phases announced after the first ``after``, up to ``until_ns``.

        Each is (controller ns of the cycle that executed it, (object, action, trial), phase),
        in the order the programs said them, every one of them: a reader that samples the
        phase at its own times would miss a phase shorter than its period, or see two at one
        stamp. Returns them and the count to pass as ``after`` next time.
        """
        self._catch_up(until_ns)
        with self._lock:
            kept = list(self._announced)
            first = self._said - len(kept)
        found: list[tuple[int, tuple[str, str, int], str]] = []
        position = max(after, first)
        for at_ns, key, phase in kept[position - first :]:
            if at_ns > until_ns:
                break
            found.append((at_ns, key, phase))
            position += 1
        return found, position

    def action_at(self, controller_ns: int) -> tuple[str, str, int] | None:
        """Return the announced (object, action, trial) at a controller time (None: none)."""
        return self._at(controller_ns).action

    def events(self, kind: str | None = None) -> tuple[Event, ...]:
        """Return what happened so far (of one kind), with both clocks."""
        return self.events_log.events(kind)

    def note(self, line: str) -> None:
        """Add a line to the controller's log (a ring of :data:`LOG_LINES`)."""
        with self._lock:
            self._log.append(line)

    @property
    def log(self) -> tuple[str, ...]:
        """Return the controller's log lines kept."""
        with self._lock:
            return tuple(self._log)

    # -- older seams, kept for tests and tools --------------------------------------------

    def prepare(self, object_id: str, action_id: str, trial: int) -> None:
        """Check that an action can be announced (kept from the playing lab; nothing to do).

        Raises:
            RigError: Unknown object or action.
        """
        del trial
        obj, action = self.objects.get(object_id), self.actions.get(action_id)
        if obj is None or action is None:
            what = f"object {object_id!r}" if obj is None else f"action {action_id!r}"
            msg = f"the virtual lab has no {what}; give it the rig's catalogs"
            raise RigError(msg)

    def start_action(self, object_id: str, action_id: str, trial: int) -> None:
        """Announce an action as its approach program would (no motion).

        Raises:
            RigError: Unknown object or action, or the arm is stopped.
        """
        self.prepare(object_id, action_id, trial)
        said = f"atikt: object={object_id} action={action_id} trial={trial} phase=approach"
        if not self.run(Program(f'textmsg("{said}")', (Call("textmsg", (said,)),))):
            msg = "the arm is stopped (protective or emergency stop): unlock it first"
            raise RigError(msg)
        self.advance_to(self.controller_ns() + 2 * self._period_ns)
        with self._lock:
            if self._pending is not None:  # the clock stands still (tests): run it now
                last = self._cycles[-1].end_ns
                self._cycles.append(self._cycle(last, last + self._period_ns))
                self._recent = (*self._recent[-(RECENT - 1) :], self._cycles[-1])

    def playing(self) -> tuple[str, str, int] | None:
        """Return the announced (object, action, trial) (None: none yet)."""
        with self._lock:
            return self._action

    @property
    def busy(self) -> bool:
        """Whether a program runs."""
        with self._lock:
            return self._runner.running

    @staticmethod
    def modalities() -> tuple[str, ...]:
        """Return the contract's skin modalities (the simulated skin has all of them)."""
        return tuple(VOCABULARY.modalities)

    @staticmethod
    def wait(seconds: float) -> None:
        """Sleep (a seam for tests)."""
        time.sleep(seconds)


def _tick(ref: weakref.ref[VirtualWorld], stopping: threading.Event) -> None:
    """Compute each cycle at its end until stopped or the world is gone."""
    while not stopping.is_set():
        world = ref()
        if world is None:
            return
        now = world.controller_ns()
        world.advance_to(now)
        period = world.period_ns
        wait = ((now // period + 1) * period - world.controller_ns()) / 1e9
        del world
        stopping.wait(max(wait, 0.0))


def _name(text: str) -> str:
    """Return a program's ``def`` name (empty for a one-line program)."""
    first = text.lstrip().split("\n", 1)[0]
    return first[4:].split("(", 1)[0].strip() if first.startswith("def ") else ""
