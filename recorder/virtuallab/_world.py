"""What the virtual lab's servers serve: a simulated execution played out in real time.

When a program announces an action (object, action, trial), the world asks the simulated rig
for the whole execution (:meth:`recorder.SimulatedRig.perform`: the motion, the skin's signals
and the arm's states) and plays it from that moment on: every server asks for the state at its
own controller time and gets the latest sample at or before it (sample and hold). The
simulation runs ``1 / time_scale`` times faster than the real clock when ``time_scale < 1``
(tests), so the servers keep their real rates while an action takes a fraction of its time.
A protective or emergency stop freezes the arm where it is and ends the playback.

Each execution is simulated on its own, with its own force offsets and drift; a real skin's
readings go on from one action to the next. So the force readings of a new execution continue
from where the previous one left them (its first sample is moved onto the previous execution's
reading at the start, a constant shift per execution): the rig's tare in free air before an
approach, taken on the previous execution's readings, is the zero of the new one, as at a
real skin.

The motion is the simulator's plan for the announced action (approach until the skin's light
contact, the action, the retract); the URScript the rig sends is checked, not executed step by
step (see the URScript server).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial.transform import Rotation

from recorder.errors import RigError
from recorder.writing._stream import JointSample, PhaseEvent, PoseSample, SkinBlock
from schemas import VOCABULARY

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping

    from numpy.typing import NDArray

    from recorder._catalog import ActionSpec, ObjectSpec
    from recorder._sim import SimulatedRig

#: RTDE ``robot_mode`` of a running arm (ROBOT_MODE_RUNNING).
ROBOT_MODE_RUNNING = 7
#: RTDE ``safety_status`` values (the controller's SafetyStatus enumeration).
SAFETY_NORMAL = 1
SAFETY_PROTECTIVE_STOP = 3
SAFETY_EMERGENCY_STOP = 7  # SAFETY_STATUS_ROBOT_EMERGENCY_STOP
_STOPS = {"protective": SAFETY_PROTECTIVE_STOP, "emergency": SAFETY_EMERGENCY_STOP}


@dataclass(frozen=True, slots=True)
class RobotState:
    """The arm's state at one controller time, in RTDE's units.

    Attributes:
        q: Joint positions, rad, shape (joints,).
        qd: Joint velocities, rad/s, shape (joints,).
        tcp_pose: TCP pose (x, y, z, rx, ry, rz): m and a rotation vector, rad.
        tcp_force: Force and torque at the TCP (fx, fy, fz, tx, ty, tz), N and N m.
        robot_mode: RTDE robot mode (7: running).
        safety_status: RTDE safety status (1 normal, 3 protective stop, 7 emergency stop).
        effort: Joint torques, N m, shape (joints,) (RTDE ``target_moment``).
    """

    q: NDArray[np.float64]
    qd: NDArray[np.float64]
    tcp_pose: NDArray[np.float64]
    tcp_force: NDArray[np.float64]
    robot_mode: int
    safety_status: int
    effort: NDArray[np.float64] = field(default_factory=lambda: np.zeros(6))


@dataclass(frozen=True, slots=True)
class _Series:
    """One signal of an execution: sorted stamps (ns from its start) and values."""

    stamps: NDArray[np.int64]
    values: NDArray[np.float64]

    def at(self, t_ns: int) -> NDArray[np.float64]:
        """Return the latest value at or before ``t_ns`` (the first before the start)."""
        index = int(np.searchsorted(self.stamps, t_ns, side="right")) - 1
        value: NDArray[np.float64] = self.values[max(index, 0)]
        return value


def _skin_series(blocks: list[SkinBlock]) -> _Series:
    stamps = np.concatenate(
        [b.stamp_ns + b.period_ns * np.arange(b.data.shape[0], dtype=np.int64) for b in blocks]
    )
    values = np.concatenate([np.asarray(b.data, dtype=np.float64) for b in blocks])
    return _Series(stamps, values)


@dataclass(frozen=True, slots=True)
class _Execution:
    """One simulated execution, ready to be played."""

    object_id: str
    action_id: str
    trial: int
    skin: Mapping[str, _Series]
    q: _Series
    qd: _Series
    effort: _Series
    pose: _Series
    force: _Series | None
    phases: tuple[tuple[str, int], ...]
    end_ns: int

    @classmethod
    def simulate(
        cls, rig: SimulatedRig, obj: ObjectSpec, action: ActionSpec, trial: int
    ) -> _Execution:
        """Run the simulator for one execution and index its signals by time."""
        items = list(rig.perform(obj, action, trial))
        blocks: dict[str, list[SkinBlock]] = {}
        joints = [item for item in items if isinstance(item, JointSample)]
        poses = [item for item in items if isinstance(item, PoseSample)]
        events = [item for item in items if isinstance(item, PhaseEvent)]
        for item in items:
            if isinstance(item, SkinBlock):
                blocks.setdefault(item.modality, []).append(item)
        skin = {name: _skin_series(found) for name, found in blocks.items()}
        stamps = np.array([j.stamp_ns for j in joints], dtype=np.int64)
        rotation = Rotation.from_quat([p.orientation for p in poses]).as_rotvec()
        pose = np.column_stack([[p.position for p in poses], rotation])
        force = None
        if "force" in skin:
            total = skin["force"].values.reshape(len(skin["force"].stamps), -1).sum(axis=1)
            wrench = np.zeros((total.size, 6))
            wrench[:, 2] = total  # the skin presses along the tool's z axis
            force = _Series(skin["force"].stamps, wrench)
        return cls(
            obj.id,
            action.id,
            trial,
            skin,
            _Series(stamps, np.array([j.position for j in joints])),
            _Series(stamps, np.array([j.velocity for j in joints])),
            _Series(stamps, np.array([j.effort for j in joints])),
            _Series(np.array([p.stamp_ns for p in poses], dtype=np.int64), pose),
            force,
            tuple((e.phase, e.stamp_ns) for e in events),
            max(e.stamp_ns for e in events),
        )


@dataclass
class VirtualWorld:
    """The simulated rig played in real time; thread-safe (servers read it from their threads).

    Attributes:
        rig: A connected simulated rig (inside its ``with`` block).
        objects: The objects a program may announce, by id.
        actions: The actions a program may announce, by id.
        time_scale: Real seconds per simulated second (0.1: ten times faster; 1: real time).
        clock: The controller's clock, ns (monotonic).
    """

    rig: SimulatedRig
    objects: Mapping[str, ObjectSpec]
    actions: Mapping[str, ActionSpec]
    time_scale: float = 1.0
    clock: Callable[[], int] = time.monotonic_ns
    _lock: threading.Lock = field(default_factory=threading.Lock, init=False)
    _origin_ns: int = field(default=0, init=False)
    _playing: _Execution | None = field(default=None, init=False)
    _last: _Execution | None = field(default=None, init=False)
    _start_ns: int = field(default=0, init=False)
    _frozen_ns: int | None = field(default=None, init=False)
    _safety: int = field(default=SAFETY_NORMAL, init=False)
    _cache: dict[tuple[str, str, int], _Execution] = field(default_factory=dict, init=False)
    _carry: dict[str, NDArray[np.float64]] = field(default_factory=dict, init=False)

    def __post_init__(self) -> None:
        """Start the controller's clock."""
        if not 0 < self.time_scale <= 1:
            msg = f"time_scale = {self.time_scale} must be in (0, 1]; 1 is real time"
            raise RigError(msg)
        self._origin_ns = self.clock()

    def controller_ns(self) -> int:
        """Return the controller's time: ns since the virtual lab started."""
        return self.clock() - self._origin_ns

    def prepare(self, object_id: str, action_id: str, trial: int) -> None:
        """Simulate an execution ahead of time (so that starting it is instant).

        Raises:
            RigError: Unknown object or action, or the simulator cannot perform it.
        """
        key = (object_id, action_id, trial)
        if key in self._cache:
            return
        obj, action = self.objects.get(object_id), self.actions.get(action_id)
        if obj is None or action is None:
            what = f"object {object_id!r}" if obj is None else f"action {action_id!r}"
            msg = f"the virtual lab has no {what}; give it the rig's catalogs"
            raise RigError(msg)
        self._cache[key] = _Execution.simulate(self.rig, obj, action, trial)

    def start_action(self, object_id: str, action_id: str, trial: int) -> None:
        """Play the execution of ``action_id`` on ``object_id`` from now on.

        As on a controller, a new program replaces the running one: an action announced while
        the previous one still plays (its rest after the retract) starts at once.

        Raises:
            RigError: Unknown object or action, or the arm is stopped.
        """
        self.prepare(object_id, action_id, trial)
        with self._lock:
            if self._safety != SAFETY_NORMAL:
                msg = "the arm is stopped (protective or emergency stop): unlock it first"
                raise RigError(msg)
            now = self.controller_ns()
            previous, held = self._execution(), self._sim_ns(now)
            new = self._cache.pop((object_id, action_id, trial))
            carry: dict[str, NDArray[np.float64]] = {}
            if previous is not None and "force" in previous.skin and "force" in new.skin:
                reading = previous.skin["force"].at(held) + self._carry.get("force", 0.0)
                carry["force"] = reading - new.skin["force"].values[0]
            self._playing, self._carry = new, carry
            self._start_ns = now
            self._frozen_ns = None

    def busy_locked(self) -> bool:
        """Whether an action is playing (call with the lock held)."""
        playing = self._playing
        return playing is not None and self._sim_ns(self.controller_ns()) < playing.end_ns

    def playing(self) -> tuple[str, str, int] | None:
        """Return (object, action, trial) of the action playing now (None: none is)."""
        with self._lock:
            run = self._playing
            if run is None or not self.busy_locked():
                return None
            return (run.object_id, run.action_id, run.trial)

    @property
    def busy(self) -> bool:
        """Whether an action is playing."""
        with self._lock:
            return self.busy_locked()

    def stop(self, kind: str = "protective") -> None:
        """Stop the arm where it is (``protective`` or ``emergency``); the playback ends."""
        with self._lock:
            self._safety = _STOPS[kind]
            self._frozen_ns = self.controller_ns()

    def unlock(self) -> None:
        """Release a stop (the pendant's "unlock protective stop")."""
        with self._lock:
            self._safety = SAFETY_NORMAL
            if self._playing is not None:
                self._last, self._playing = self._playing, None

    def _sim_ns(self, controller_ns: int) -> int:
        """Return the simulated time of the playing execution at a controller time."""
        held = controller_ns if self._frozen_ns is None else min(controller_ns, self._frozen_ns)
        return round((held - self._start_ns) / self.time_scale)

    def _execution(self) -> _Execution | None:
        return self._playing if self._playing is not None else self._last

    def robot_at(self, controller_ns: int) -> RobotState:
        """Return the arm's state at a controller time."""
        with self._lock:
            run, sim_ns, safety = self._execution(), self._sim_ns(controller_ns), self._safety
            carry = self._carry.get("force")
        if run is None:
            home = np.zeros(6)
            return RobotState(home, home, home, home, ROBOT_MODE_RUNNING, safety)
        moving = self._frozen_ns is None and 0 <= sim_ns < run.end_ns
        wrench = run.force.at(sim_ns) if run.force is not None else np.zeros(6)
        if carry is not None:  # the skin's readings go on from the previous execution
            wrench = wrench + np.array([0.0, 0.0, float(carry.sum()), 0.0, 0.0, 0.0])
        qd = run.qd.at(sim_ns) if moving else np.zeros_like(run.qd.values[0])
        return RobotState(
            run.q.at(sim_ns),
            qd,
            run.pose.at(sim_ns),
            wrench,
            ROBOT_MODE_RUNNING,
            safety,
            run.effort.at(sim_ns),
        )

    def skin_at(self, modality: str, controller_ns: int) -> NDArray[np.float64] | None:
        """Return the skin's latest sample of ``modality`` (cells, values); None: no such."""
        with self._lock:
            run, sim_ns = self._execution(), self._sim_ns(controller_ns)
            carry = self._carry.get(modality)
        if run is None or modality not in run.skin:
            return None
        value = run.skin[modality].at(sim_ns)
        return value if carry is None else value + carry

    def phase_at(self, controller_ns: int) -> str | None:
        """Return the simulated phase at a controller time (None: no action yet)."""
        with self._lock:
            run, sim_ns = self._execution(), self._sim_ns(controller_ns)
        if run is None:
            return None
        started = [name for name, stamp in run.phases if stamp <= sim_ns]
        return started[-1] if started else run.phases[0][0]

    @staticmethod
    def modalities() -> tuple[str, ...]:
        """Return the contract's skin modalities (the simulated skin has all of them)."""
        return tuple(VOCABULARY.modalities)

    @staticmethod
    def wait(seconds: float) -> None:
        """Sleep (a seam for tests)."""
        time.sleep(seconds)
