"""The action runner: one robot loop for every arm.

:class:`ArmRig` performs an exploratory action with any :class:`ArmDriver` and any live skin:
the tare (the skin's zero in free air), the approach with a speed from proximity until the
light contact, the action itself (a press to depth and a hold, or a slide at a set force),
and the retract; it presents objects (moves to their pose) and checks the limits and the
sources' silence on every state sample as it arrives, in its own loop. A slow writer or viewer
never delays a check: items go to a non-blocking sink (:class:`recorder.runner.WriterThread`).

Any end of an action other than its normal end -- a limit, a protective stop, a lost or silent
source, Ctrl-C or SIGTERM (a flag, see ``_interrupts``), a writer that failed or fell behind,
any exception -- sends the stop first, then hands over what arrived; the recorder keeps it as
``<trial>.incomplete.mcap``.
"""

from __future__ import annotations

import bisect
import contextlib
import dataclasses
import math
import os
import sys
import traceback
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn, Protocol, Self

import numpy as np

from recorder.errors import RecorderError, RigError
from recorder.live import (
    ExplainingSkin,
    RecorderClock,
    SourceLostError,
    check_rt_priority,
    readers_at,
    real_time,
    rt_refusal,
    window_samples,
)
from recorder.runner._arm import Context, StopsOtherwise
from recorder.runner._interrupts import InterruptFlag, deferred_interrupts, raise_interrupt
from recorder.runner._limits import (
    REACHED_M,
    Limits,
    Motion,
    check_action,
    check_motion,
    check_pose,
    path_problem,
)
from recorder.runner._limits import tool_axis as _tool_axis
from recorder.runner._watchdog import Watchdog, WatchedArm
from recorder.writing._stream import JointSample, PhaseEvent, PoseSample, SkinBlock

if TYPE_CHECKING:
    from collections.abc import Callable, Generator, Iterator, Mapping, Sequence
    from types import TracebackType

    from numpy.typing import NDArray

    from recorder._catalog import ActionSpec, ObjectSpec
    from recorder.live import LiveSkin, SourceStats
    from recorder.runner._arm import ArmDriver, ArmSample
    from recorder.writing._stream import StreamItem

_NS = 1_000_000_000
#: Joint speed below which the arm counts as still, rad/s.
STILL_RAD_S = 1e-3
#: Joint speed above which the arm counts as moving before an action (a person guiding it by
#: hand, another program), rad/s; far above a resting arm's readings.
MOVING_RAD_S = 0.01
#: How long an arm found moving before an action may take to come to rest, s (action time),
#: and at least how many controller cycles.
MOVING_WAIT_S = 1.0
MOVING_WAIT_CYCLES = 125
#: How long after a motion command the arm must have started moving, s (action time): a
#: controller starts a program within a few cycles.
START_S = 1.0
#: ... and at least this many cycles: a fast lab's second is a few, and a virtual lab in a
#: loaded process (its program checked and started by threads that wait for the interpreter)
#: may take a few hundred ms of them.
START_CYCLES = 50
#: How long the arm must be still (after the retract started) to end the action, s.
SETTLE_S = 0.25
#: How far from the home pose an approach may begin and still return there, m.
_HOME_M = 0.002
#: How long the skin is read in free air before each approach to find its zero, ns.
TARE_NS = 30_000_000
#: Longest wait for a state sample in one cycle, s (a cycle also ends when one arrives).
CYCLE_WAIT_S = 0.002
#: Longest pause of the approach waiting for a late skin's force samples, s.
SKIN_BEHIND_S = 2.0
#: How long one approach speed command moves the arm unless renewed (action time), s; the
#: runner renews it every half of it.
SPEED_LEASE_S = 0.5
#: What a stop between actions asks of a person unless its cause says more.
CHECK_ARM = "check the arm, then retry"
#: How long an approach's arm may stand still while its speed is sent before the controller is
#: taken to run none of the programs, controller seconds (and at least START_S of action time):
#: a virtual lab on a loaded machine starts a program a few hundred ms late, and a dead link
#: costs these seconds, not the approach's whole time limit.
STALL_S = 2.0
#: How far the TCP must move during an approach to count as progress (far above the noise of
#: its readings, far below what START_S of the slowest approach covers), m.
_PROGRESS_M = 0.0002
#: The approach stops this far (m) plus its stopping distance before the workspace's edge.
_EDGE_M = 0.0005
#: Controller cycles of reaction counted into that stopping distance (detection to stop).
_EDGE_CYCLES = 4
#: The oldest the arm's latest state may be (controller cycles since it arrived) when a motion
#: is commanded on it: an older one (a stalled stream) is waited on, and a speed is not
#: renewed on it (its lease runs out: the arm stops by itself), until the silence check ends
#: the action. At least FRESH_S: at 500 Hz ten cycles (20 ms) is a loaded machine's hiccup.
FRESH_CYCLES = 10
FRESH_S = 0.05
#: How long the arm may take to come to rest after the stop, s (action time), and at least
#: how many controller cycles: a stop at the runner's deceleration halts any of its motions in
#: a fraction of it.
REST_S = 1.0
REST_CYCLES = 125
#: Force blocks whose median span says how far the skin's samples reach beyond its blocks.
FORCE_SPANS = 32


class Watch(Protocol):
    """What else may end an action: a deferred signal, a writer in trouble."""

    def problem(self) -> str:
        """Return why the action must end now (empty: it may go on)."""
        ...


class _Never:
    def problem(self) -> str:
        return ""


class _Deferred:
    """What ends a move to an object: a signal deferred while it runs, or the caller's watch."""

    def __init__(self, flag: InterruptFlag, watch: Watch | None) -> None:
        self.flag, self.watch = flag, watch

    def problem(self) -> str:
        if self.flag.signum is not None:
            return self.flag.reason
        if self.flag.continued:
            return self.flag.stopped_meanwhile
        return self.watch.problem() if self.watch is not None else ""


@dataclass(frozen=True, slots=True)
class RunnerOptions:
    """How the runner drives an arm (rig options shared by every arm).

    Attributes:
        time_scale: Real seconds per action second; < 1 only against the virtual lab, which
            plays actions faster (the runner then holds and slides that much shorter).
        silence_s: A source silent this long ends the action, s.
        motion: How the arm moves.
        rt_priority: ``SCHED_FIFO`` priority, 1-99, of the arm's and the skin's readers and
            of the runner's loop while an action runs (0: normal scheduling; see
            ``recorder.live._realtime``).
    """

    time_scale: float = 1.0
    silence_s: float = 0.5
    motion: Motion = field(default_factory=Motion)
    rt_priority: int = 0


class Stop(Exception):  # noqa: N818 (control flow inside the runner, never escapes it)
    """A stop condition met inside the runner."""

    def __init__(
        self,
        reason: str,
        at_ns: int,
        arrived: Sequence[StreamItem] = (),
        *,
        fix: str = CHECK_ARM,
    ) -> None:
        """Keep the reason, when it was met and what arrived with its cause.

        Args:
            reason: One line.
            at_ns: When the cause was met (recorder clock, ns).
            arrived: What arrived with the cause, not yet handed over (handed over once the
                stop went out).
            fix: What to do when it stops a move between actions.
        """
        super().__init__(reason)
        self.reason = reason
        self.at_ns = at_ns
        self.arrived = arrived
        self.fix = fix
        #: What a person must know of the arm after the stop, one clause: the stop did not
        #: reach it, or it did not come to rest (empty: it was stopped).
        self.arm_left = ""


@dataclass(slots=True)
class _State:
    """The latest state of the arm."""

    sample: ArmSample | None = None
    receive_ns: int = 0
    #: State samples taken so far (the controller's cycles seen).
    taken: int = 0
    #: Of those, the ones that arrived since the last command was sent (see ArmRig._mark):
    #: samples queued before it (a loaded recorder reads them late) say nothing of it.
    since: int = 0

    @property
    def pose(self) -> NDArray[np.float64] | None:
        return None if self.sample is None else self.sample.tcp_pose

    @property
    def still(self) -> bool:
        return self.sample is None or bool(np.all(np.abs(self.sample.qd) < STILL_RAD_S))


class ArmRig:
    """An arm driver and a live skin driven by the runner (a :class:`recorder.Rig`)."""

    def __init__(
        self,
        arm: ArmDriver,
        skin: LiveSkin,
        limits: Limits,
        options: RunnerOptions,
        poses: Mapping[str, Sequence[float]],
        *,
        kind: str,
        skin_transport: str = "",
        where: str = "<rig options>",
        clock: RecorderClock | None = None,
    ) -> None:
        """Check the motion settings and the objects' poses against the limits.

        Raises:
            RigError: A setting or a pose outside the limits (one line naming the file).
        """
        self.arm, self.skin, self.limits, self.options = arm, skin, limits, options
        #: Watches the runner's calls into the drivers (a call that hangs gets the stop).
        self._dog = Watchdog(self._stop_from_watchdog, where, options.silence_s)
        #: The arm as the runner calls it: every call watched.
        self._driver: ArmDriver = WatchedArm(arm, self._dog)
        self.kind, self.where, self.skin_transport = kind, where, skin_transport
        check_motion(options.motion, limits, where)
        for object_id, pose in poses.items():
            if len(pose) != 6:  # noqa: PLR2004 (x, y, z, rx, ry, rz)
                msg = (
                    f"{where}: [objects.{object_id}] pose = {list(pose)}: "
                    "give [x, y, z, rx, ry, rz]"
                )
                raise RigError(msg)
            check_pose(object_id, pose, limits, where)
        self._poses = {k: np.asarray(v, dtype=np.float64) for k, v in poses.items()}
        self.clock = clock or RecorderClock()
        check_rt_priority(options.rt_priority, where)
        #: The real-time priority granted on connecting (0: normal scheduling).
        self._rt_priority = 0
        self._stack: contextlib.ExitStack | None = None
        self._state = _State()
        self._begun_ns = 0
        self._last_event_ns = 0
        #: Modality -> how far its skin samples taken in this action reach (last + period).
        self._skin_until: dict[str, int] = {}
        #: The spans of this action's latest force blocks, ns: a skin hands its samples over in
        #: blocks, so those of the block being filled have arrived though no block shows them.
        self._force_spans: deque[int] = deque(maxlen=FORCE_SPANS)
        #: Where the approaches begin (the object's pose once presented, else the first
        #: approach's start); retracts return there, so actions never creep toward the object.
        self._home: NDArray[np.float64] | None = None
        self._watch: Watch = _Never()
        #: Every stop sent: (when its cause was met, when the stop went to the driver, why),
        #: recorder clock (a state sample's cause: its receive time), ns; for latency
        #: measurements.
        self.stops_sent: list[tuple[int, int, str]] = []
        #: How the last stop reached the arm when not the usual way (the driver's clause).
        self.stop_note = ""
        #: The newest state sample's stamp; samples at or before it are left out, counted.
        self._newest_ns = -1
        self._repeated = self._went_back = 0
        #: When the last command that cycles are counted from was sent (recorder clock, ns).
        self._mark_ns = 0

    # -- connection -----------------------------------------------------------------------

    def __enter__(self) -> Self:
        """Connect the arm, then the skin."""
        # scipy's rotations (the recorded TCP quaternion, the tool axes) are imported here, not
        # when the module is (commands start 0.5 s sooner) and never while the arm moves: an
        # import on the first state sample would hold up the runner's loop for half a second
        from scipy.spatial.transform import Rotation  # noqa: PLC0415, F401

        self._rt_priority = self._granted_priority()
        with contextlib.ExitStack() as stack, readers_at(self._rt_priority):
            for part, what in ((self.arm, "arm"), (self.skin, "skin")):
                try:
                    stack.enter_context(part)
                except RigError:
                    raise
                except Exception as err:  # a driver's own (a vendor library's) exception
                    msg = (
                        f"{self.where}: the {what} could not connect ({_error(err)}); check "
                        f"that it is on and reachable and the configuration's {what} settings"
                    )
                    raise RigError(msg) from err
            if self.clock.real:  # a simulated clock's driver holds nothing in real time
                self._dog.allowed_s = self.options.silence_s
                stack.enter_context(self._dog)
            stack.callback(sys.setswitchinterval, sys.getswitchinterval())
            # the readers, the runner's loop and the writer share one interpreter, handed
            # over every 5 ms by default: 2.5 cycles at 500 Hz that a state sample which
            # breaks a limit could wait in its reader; within a quarter cycle instead (as
            # serve-sim's threads take turns). Restored when the rig disconnects.
            period_s = self.arm.period_ns / 1e9
            if period_s > 0:
                sys.setswitchinterval(min(sys.getswitchinterval(), period_s / 4))
            self._stack = stack.pop_all()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Disconnect the skin and the arm, whatever happened."""
        stack, self._stack = self._stack, None
        if stack is not None:
            stack.close()

    def _granted_priority(self) -> int:
        """Return the real-time priority asked for if the system grants it, else 0 (said once)."""
        asked = self.options.rt_priority
        refused = rt_refusal(asked)
        if refused is None:
            return asked
        print(  # noqa: T201 (the recorder goes on: a warning for the operator)
            f"{self.where}: rt_priority = {asked}: {refused}; recording at normal priority "
            "(allow it with an rtprio limit, e.g. '@robot - rtprio 99' in "
            "/etc/security/limits.conf, or CAP_SYS_NICE)",
            file=sys.stderr,
            flush=True,
        )
        return 0

    def _connected(self) -> None:
        if self._stack is None:
            msg = f"{self.where}: the rig is used outside its with block; use `with rig:`"
            raise RigError(msg)

    # -- what the recorder asks -----------------------------------------------------------

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Return the arm's joint names."""
        return self.arm.joint_names

    def describe(self) -> Mapping[str, str]:
        """Return the rig's configuration (its identity in a dataset), flat.

        What shapes the recorded signals is part of it: the skin's transport, and how the arm
        moves (``motion.*``: the approach, press and retract speeds, the acceleration, the
        light contact), so a dataset never mixes recordings made with other settings. The
        limits and the objects' poses are not: they bound the motion, they do not change it.
        Only what the configuration says is described: it is compared before the rig
        connects (a skin plug-in may learn its cells only on connecting).
        """
        described = {"kind": self.kind, **self.arm.describe()}
        described["skin_transport"] = self.skin_transport
        described["silence_s"] = f"{self.options.silence_s:g}"
        if self.options.time_scale != 1:
            described["time_scale"] = f"{self.options.time_scale:g}"
        described.update(self.options.motion.describe())
        return described

    def facts(self) -> Mapping[str, str]:
        """Return what the arm said on connecting and the scheduling granted (recorded only)."""
        facts = dict(self.arm.facts())
        if self.options.rt_priority:  # asked for: say whether the system granted it
            granted = self._rt_priority
            facts["scheduling"] = f"SCHED_FIFO {granted}" if granted else "normal"
        return facts

    def source_stats(self) -> list[SourceStats]:
        """Return the accounting of the last action: the arm's and the skin's sources.

        The state samples the runner left out (a stamp repeated or gone back) are added to
        the arm's first source.
        """
        arm = list(self.arm.stats())
        if arm and (self._repeated or self._went_back):
            first = arm[0]
            arm[0] = dataclasses.replace(
                first,
                duplicated=first.duplicated + self._repeated,
                out_of_order=first.out_of_order + self._went_back,
            )
        return [*arm, *self.skin.stats()]

    def can_present(self, obj: ObjectSpec) -> bool:
        """Return whether the arm can visit ``obj`` by itself (it has a pose)."""
        return obj.id in self._poses

    def present(self, obj: ObjectSpec, watch: Watch | None = None) -> bool:
        """Move the arm to ``obj``'s pose, until within 1 mm; limits checked on every sample.

        Returns:
            True when the arm is there; False when ``obj`` has no pose (a person places it).

        Raises:
            RigError: The arm stopped, a source was lost or it did not arrive in time (the
                stop was sent first).
        """
        self._connected()
        target = self._poses.get(obj.id)
        if target is None:
            return False
        # a signal while the arm moves is deferred as in an action: it never lands inside a
        # program being sent, the stop goes out first, and the line says so
        with real_time(self._rt_priority), deferred_interrupts(arm=True) as flag:
            try:
                self._present(obj, target, _Deferred(flag, watch))
            except RigError:
                if flag.signum is None:
                    raise
                _interrupted(flag, f"before moving to {obj.id}: nothing was sent to the arm")
        return True

    def _present(self, obj: ObjectSpec, target: NDArray[np.float64], watch: _Deferred) -> None:
        """Move to ``target`` (see :meth:`present`)."""
        motion = self.options.motion
        self._watch = watch
        self._begin()
        self.skin.begin()
        self._until_free(f"move to {obj.id}")  # nothing sent yet: a refusal stops nothing
        try:
            self._check("")  # a signal that came before anything is sent
            while self._state.pose is None:
                self._pump_quietly()
            distance = float(np.linalg.norm(self._state.pose[:3] - target[:3]))
            seconds = (5 + 3 * distance / motion.retract_m_s) * self.options.time_scale + 5
            limit_ns = self.clock.now_ns() + round(seconds * _NS)
            self._mark()
            self._driver.move(target, motion.retract_m_s, motion.acceleration_m_s2, None)
            self._until_reached(target, limit_ns, obj.id)
            self._home = target.copy()
        except (Stop, SourceLostError, Exception) as ended:  # noqa: BLE001 (a driver's own)
            stop: Stop | SourceLostError = (
                ended
                if isinstance(ended, Stop | SourceLostError)
                else Stop(f"an error ({_error(ended)})", self.clock.now_ns())
            )
            undelivered = self._send_stop(None, str(stop))
            said = undelivered_line(undelivered, str(stop)) if undelivered else self.stop_note
            if not undelivered:  # as after an action's stop: a moving arm unseen is said
                said = "; ".join(c for c in (said, self._until_rest_quietly()) if c)
            if watch.flag.signum is not None:  # Ctrl-C, SIGTERM, SIGHUP: the run ends
                arm = said or "the arm was stopped"
                _interrupted(watch.flag, f"while moving to {obj.id}: {arm}")
            left = f"; {said}" if said else ""
            fix = stop.fix if isinstance(stop, Stop) else CHECK_ARM
            if "check the arm at the teach pendant now" in said and fix == CHECK_ARM:
                fix = "then retry"  # the arm is a person's to check already
            msg = f"{self.where}: moving to {obj.id}: {stop}{left}; {fix}"
            raise RigError(msg) from None
        except BaseException:
            if undelivered := self._send_stop(None, "error"):
                print(f"{self.where}: {undelivered_line(undelivered)}", file=sys.stderr)  # noqa: T201
            raise
        finally:
            self._watch = _Never()

    def _until_reached(self, target: NDArray[np.float64], limit_ns: int, what: str) -> None:
        """Read the arm's state (recording nothing) until within 1 mm of ``target``.

        Raises:
            Stop: A stop condition, or the deadline passed.
        """
        # counted in the controller's cycles, not in time: a controller (or a virtual lab) held
        # up by its machine sends nothing meanwhile, and its program starts none the later
        # (and only the cycles since the move was sent: see _State.since)
        cycles = self._start_cycles()
        moved = False
        while not self._reached(target):
            self._pump_quietly()
            now = self.clock.now_ns()
            moved = moved or not self._state.still
            if not moved and self._state.since > cycles:  # a program the controller did not run
                msg = (
                    f"the arm did not start moving toward {what} in {round(cycles)} controller "
                    "cycles: the controller did not run the program (an e-Series in local "
                    "control runs none sent to it; the controller's log says why)"
                )
                raise Stop(msg, now)
            if now > limit_ns:
                msg = f"the arm did not reach the pose of {what} within 1 mm"
                raise Stop(msg, now)

    def _progress(self, pose: NDArray[np.float64]) -> _Progress:
        """Watch an approach's progress from ``pose`` (see :data:`STALL_S`)."""
        stall = max(self._start_cycles(), STALL_S * _NS / self.arm.period_ns)
        return _Progress(pose.copy(), 0, stall)

    def _start_cycles(self) -> float:
        """Return within how many controller cycles a motion sent must show (see START_S)."""
        return max(START_S * self.options.time_scale * _NS / self.arm.period_ns, START_CYCLES)

    def check_ready(self) -> None:
        """Read the arm's state afresh before an action; refuse an arm that could not start it.

        A stop on the controller, a robot mode other than running (powered off, brakes
        engaged), a limit broken where the arm stands, a silent source or an arm that keeps
        moving (guided by hand, another program) is refused here, before anything is sent and
        before the action's file exists (the action itself checks every sample again).

        Raises:
            RigError: The reason, one line (nothing was sent).
        """
        self._connected()
        self._begin()
        self.skin.begin()
        self._until_free("start an action")

    def _until_free(self, what: str) -> None:
        """Wait until the arm is at rest and the controller runs no other program.

        Counted in the controller's cycles (1 s, at least :data:`MOVING_WAIT_CYCLES`), so a
        controller held up by its machine is not taken for a moving arm. Nothing is sent.

        Raises:
            RigError: The arm kept moving, another program kept running, a stop or a silent
                source: ``the arm cannot <what>: <reason>``, one line.
        """
        before, reason, fix = self._state.sample, "", CHECK_ARM
        try:
            while self._state.sample is before:  # the silence check bounds the wait
                self._pump_quietly()
            # nothing moves before the skin has sent since begin (a skin on the wrong port or
            # address is found here, not half a second into a motion): the silence check
            # bounds this wait too
            while (self.skin.last_receive_ns() or 0) <= self._begun_ns:
                self._pump_quietly()
            # in the controller's cycles, as the start of a motion (see _until_reached)
            cycles = MOVING_WAIT_S * self.options.time_scale * _NS / self.arm.period_ns
            until = self._state.taken + max(cycles, MOVING_WAIT_CYCLES)
            waited = False
            while (speed := self._joint_speed()) > MOVING_RAD_S or self._busy():
                if (
                    self._state.taken > until
                    and self._busy()
                    and not waited
                    and speed <= MOVING_RAD_S
                ):
                    # perhaps a press of a recorder that was killed, holding the arm still and
                    # bringing it back by itself when its lease ends: waited for, once, moving
                    # nothing (an arm kept moving is refused: guided by hand, another program)
                    waited = True
                    until = self._state.taken + round(PROGRAM_WAIT_S * _NS / self.arm.period_ns)
                    print(  # noqa: T201
                        f"{self.where}: {self._busy()} on the controller: waiting up to "
                        f"{PROGRAM_WAIT_S:g} s for it to end (a recorder stopped mid-press "
                        "leaves its press to bring the arm back by itself)",
                        file=sys.stderr,
                        flush=True,
                    )
                if self._state.taken > until:
                    reason = (
                        f"the arm is moving (a joint at {speed:.3f} rad/s: guided by hand, or "
                        "another program); let it come to rest"
                        if speed > MOVING_RAD_S
                        else f"{self._busy()}: another program runs on the controller, and "
                        "one of ours would replace it; stop it (the teach pendant, or the "
                        "dashboard's stop)"
                    )
                    break
                self._pump_quietly()
        except (Stop, SourceLostError) as stop:
            reason = str(stop)
            fix = stop.fix if isinstance(stop, Stop) else fix
        if reason:
            said = f"the arm cannot {what}: {reason}; {fix}"
            msg = f"{self.where}: {said}"
            raise RigError(msg)

    def _busy(self) -> str:
        """Return what else the controller runs, from the latest state sample ('': nothing)."""
        sample = self._state.sample
        return "" if sample is None else sample.busy

    def watch(self, seconds: float) -> None:
        """Read the arm and the skin for ``seconds`` (action time), moving nothing.

        Every check of an action runs on what arrives (``session --dry-run``); the sources'
        accounting (:meth:`source_stats`) then covers this and :meth:`check_ready`.

        Raises:
            RigError: A check failed, one line (nothing was sent).
        """
        self._connected()
        end_ns = self.clock.now_ns() + round(seconds * self.options.time_scale * _NS)
        try:
            while self.clock.now_ns() < end_ns:
                self._pump_quietly()
        except (Stop, SourceLostError) as stop:
            msg = f"{self.where}: watching the arm and the skin: {stop}; check them, then retry"
            raise RigError(msg) from None

    def _joint_speed(self) -> float:
        """Return the fastest joint's speed in the latest state sample, rad/s."""
        sample = self._state.sample
        return 0.0 if sample is None else float(np.abs(sample.qd).max(initial=0.0))

    def perform(self, obj: ObjectSpec, action: ActionSpec, trial: int) -> Iterator[StreamItem]:
        """Perform ``action`` on ``obj``; yield every item as it arrives.

        The generator returns the reason of a stop (empty after a normal end); use
        :meth:`run` to hand items to a sink.

        Raises:
            RigError: The action is outside the limits (nothing moved) or the rig is not
                connected.
        """
        self.check_plan(obj, action)
        self._connected()
        return self._perform(obj, action, trial)

    def check_plan(self, obj: ObjectSpec, action: ActionSpec) -> None:
        """Check ``action`` on ``obj`` against the limits before anything moves.

        The action's speed and force, the object's pose, and the path of its execute phase
        from that pose (a press deeper or a slide longer than the workspace leaves room for).

        Raises:
            RigError: One line naming the file, the value and the limit.
        """
        check_action(action, self.limits, self.where)
        pose = self._poses.get(obj.id)
        if pose is None:  # placed by hand: the path is checked at the contact
            return
        check_pose(obj.id, pose, self.limits, self.where)
        accel = self.options.motion.acceleration_m_s2
        if problem := path_problem(action, pose, self.limits, accel):
            msg = f"{self.where}: {obj.id} (its [objects] pose): {problem}"
            raise RigError(msg)

    def run(
        self,
        obj: ObjectSpec,
        action: ActionSpec,
        trial: int,
        put: Callable[[StreamItem], None],
        watch: Watch | None = None,
    ) -> Stop | None:
        """Perform ``action`` on ``obj``, handing every item to ``put`` (never blocking).

        Returns:
            The stop that ended the action early (None: it ended normally).
        """
        actions = self.perform(obj, action, trial)
        self._watch = watch or _Never()
        try:
            with real_time(self._rt_priority):  # this thread only, while the arm moves
                while True:
                    put(next(actions))
        except StopIteration as done:
            stop: Stop | None = done.value
            return stop
        finally:
            self._watch = _Never()

    # -- the action -----------------------------------------------------------------------

    def _perform(
        self, obj: ObjectSpec, action: ActionSpec, trial: int
    ) -> Generator[StreamItem, None, Stop | None]:
        at = Context(obj.id, action.id, trial, "approach")
        self._begin()
        self.skin.begin()
        touching = False  # between the light contact and the retract's end
        try:
            yield from self._pump(0.0)
            yield self._event("approach")
            contact = yield from self._approach(at)
            touching = True
            yield from self._execute(at, action, contact)
            yield from self._retract(at, contact)
            touching = False
            yield from self._skin_catch_up(self.clock.now_ns())
        except (Stop, SourceLostError, Exception) as ended:  # noqa: BLE001 (a driver's own)
            # a driver's own exception (a command the vendor library refused) ends the action
            # as a stop does: the stop first, what arrived kept, one line naming it
            if isinstance(ended, Stop):
                stop = ended
            elif isinstance(ended, SourceLostError):
                stop = Stop(str(ended), self.clock.now_ns())
            else:
                stop = Stop(f"an error in the action ({_error(ended)})", self.clock.now_ns())
            if undelivered := self._send_stop(at, stop.reason, stop.at_ns):
                stop.arm_left = undelivered_line(undelivered, stop.reason)
            yield from stop.arrived
            if not undelivered:
                moving = yield from self._until_rest()
                # a stop holds the arm where it found it: on the object, pressed into it
                # mid-press, until something moves it
                held = "" if moving or not touching else _held_on(obj.id)
                stop.arm_left = "; ".join(c for c in (self.stop_note, moving, held) if c)
            yield from self._rest()
            return stop
        except BaseException:  # GeneratorExit, an interrupt, a bug: the arm stops first
            if undelivered := self._send_stop(at, "error"):
                # the exception on its way says nothing of the arm: a person must act now
                print(f"{self.where}: {undelivered_line(undelivered)}", file=sys.stderr)  # noqa: T201
            raise
        yield from self._rest()
        with contextlib.suppress(SourceLostError):  # the action is over: a log line at most
            self._driver.announce(_phase(at, "end"))
        yield self._event("end")
        return None

    def _until_rest_quietly(self) -> str:
        """Run :meth:`_until_rest` recording nothing (between actions); return its clause."""
        waiting = self._until_rest()
        while True:
            try:
                next(waiting)
            except StopIteration as done:
                return str(done.value)

    def _until_rest(self) -> Generator[StreamItem, None, str]:
        """Read the arm and the skin after the stop until the arm is at rest; hand them over.

        A stop the controller took halts the arm within its deceleration; one it did not (a
        program sent into a connection that was dying, a controller that ignores programs)
        leaves it moving. Counted in controller cycles (:data:`REST_S`, at least
        :data:`REST_CYCLES`), so a loaded machine is not taken for a moving arm. No limit is
        judged here: the arm may stand outside one (that was the cause).

        Returns:
            The clause to tell a person when the arm did not come to rest, or when its state
            stopped arriving while it was last seen moving (the stop cannot be confirmed);
            empty: it came to rest.
        """
        cycles = max(REST_S * self.options.time_scale * _NS / self.arm.period_ns, REST_CYCLES)
        deadline = self.clock.now_ns() + round((REST_S + self.options.silence_s) * _NS)
        # at rest is still (STILL_RAD_S), not "not moving by hand" (MOVING_RAD_S): a UR10's
        # slowest approach turns its joints at a few mrad/s, below that
        tried, otherwise = False, ""  # the driver's second way to stop (how it stopped it)
        while (speed := self._joint_speed()) > STILL_RAD_S:
            if self._state.since > cycles and not tried:  # the cycles since the stop went out
                tried, otherwise = True, self._stop_otherwise()
                deadline = self.clock.now_ns() + round((REST_S + self.options.silence_s) * _NS)
            if self._state.since > cycles:
                after = f"the stop, nor after {otherwise}" if otherwise else "the stop"
                return (
                    f"the arm did not come to rest after {after} (a joint at {speed:.3f} "
                    "rad/s); stop it at the teach pendant now"
                )
            items: list[StreamItem] = []
            try:
                samples = self._driver.poll(CYCLE_WAIT_S)
            except Exception:  # noqa: BLE001 (lost, or a driver's own error: the arm unseen)
                return _unconfirmed(speed)
            # the state stopped arriving: nothing seen (judged on an empty read: a recorder
            # held up meanwhile finds the samples queued, not a silent arm)
            if not samples and self.clock.now_ns() > deadline:
                return _unconfirmed(speed)
            try:
                blocks = self._skin_poll()
            except SourceLostError:  # the skin's loss is not the arm's: go on judging it
                blocks = []
            for sample in self._in_order(samples):
                if self._malformed(sample):  # nothing to judge the arm's rest on, nor to keep
                    continue
                self._state.sample, self._state.receive_ns = sample, sample.receive_ns
                self._state.taken += 1
                self._state.since += sample.receive_ns >= self._mark_ns
                items.extend(_items(sample))
            items.extend(blocks)
            items.sort(key=lambda item: item.receive_ns)
            yield from items
        if otherwise:  # at rest, by the second way: the line says the stop did not do it
            said = f"the arm did not come to rest after the stop: {otherwise}"
            self.stop_note = "; ".join(c for c in (self.stop_note, said) if c)
        return ""

    def _stop_otherwise(self) -> str:
        """Stop the arm the driver's second way: the stop did not bring it to rest.

        The cycles are counted afresh from now. Returns how it stopped the arm (one clause);
        empty when the driver has no second way, or it failed (then :attr:`stop_note` says so).
        """
        arm = self.arm
        if not isinstance(arm, StopsOtherwise):
            return ""
        self._mark()
        try:
            return arm.stop_otherwise()
        except Exception as err:  # noqa: BLE001 (a driver's own: the line must say so)
            failed = f"the driver's second way to stop failed ({_error(err)})"
            self.stop_note = "; ".join(c for c in (self.stop_note, failed) if c)
            return ""

    def _send_stop(self, at: Context | None, why: str, cause_ns: int | None = None) -> str:
        """Send the stop (first thing on every abnormal end); remember when it was sent.

        Returns why the arm did not take it (empty: it was sent); the driver tried what it
        can (a new connection) before it gave up.

        The time is taken as the stop goes to the driver, not when its send returns: a loaded
        machine can hold this thread after the stop's bytes left (another thread runs), and
        the controller then has the stop before the send "happened".
        """
        context = None if at is None else Context(at.object_id, at.action_id, at.trial, "stop")
        self._mark()
        sent = self.clock.now_ns()
        self.stop_note = ""
        try:
            self.stop_note = self._driver.stop(self.options.motion.acceleration_m_s2, context)
        except Exception as err:  # noqa: BLE001 - whatever failed, the line must say so
            return str(err) or type(err).__name__
        self.stops_sent.append((sent if cause_ns is None else cause_ns, sent, why))
        return ""

    def _tare(self) -> Generator[StreamItem, None, float]:
        """Return the skin's total force in free air before the approach (its zero).

        A skin's offsets drift between actions (temperature, ageing of the cover): the light
        contact is the total force rising above this zero by the threshold, as labs tare
        their skins before each touch.
        """
        readings: list[float] = []
        deadline = self.clock.now_ns() + TARE_NS
        while self.clock.now_ns() < deadline or not readings:
            yield from self._pump()
            total = self.skin.total_force()
            if total is not None:
                readings.append(total)
            if self.clock.now_ns() > deadline + 100 * TARE_NS:
                return 0.0  # no force sensing: nothing to tare
        return float(np.median(readings))

    def _approach(self, at: Context) -> Generator[StreamItem, None, NDArray[np.float64]]:
        """Approach with speed from proximity until the light contact; return the contact pose."""
        motion, scale = self.options.motion, self.options.time_scale
        while self._state.pose is None:
            yield from self._pump()
        zero = yield from self._tare()
        start = self._state.pose.copy()
        if self._home is None or np.linalg.norm(start[:3] - self._home[:3]) > _HOME_M:
            self._home = start.copy()  # the first approach, or the arm was moved by hand
        direction = _tool_axis(start, 2)
        edge_m = self._approach_edge(start, direction)
        self._check_reach(0.0, edge_m)  # no room to approach at all: nothing moves
        speed = motion.approach_speed(self.skin.nearest())
        self._mark()
        self._speed(direction, speed, at)
        sent_ns = began_ns = self.clock.now_ns()
        # an arm that stands still while the approach is sent and renewed: the controller
        # runs none of the programs (a half-dead link takes them and delivers none)
        progress = self._progress(start)
        # a speed command lasts SPEED_LEASE_S unless renewed: a recorder that stalls (a
        # loaded or hung process) lets the arm move on for that long at most, not the whole way
        renew_ns = round(SPEED_LEASE_S / 2 * scale * _NS)
        # the slowest approach over the whole distance, twice: an arm that does not move
        # (a program the controller refused) must not keep the action waiting forever
        limit_s = 2 * motion.approach_limit_m / motion.approach_min_m_s * self.options.time_scale
        give_up_ns = sent_ns + round(limit_s * _NS)
        blind = _Blind(direction, start, motion.approach_blind_m)
        while True:
            peak = yield from self._pump_force(since_ns=began_ns)
            if peak is not None and peak - zero > motion.contact_force_n:
                break
            nearest = self.skin.nearest()
            if blind.pauses(self._state.sample, self._skin_seen_ns(), nearest):
                # the skin is behind the arm: stop, wait for it, then go on
                waited, peak = yield from self._wait_for_skin(blind, at, began_ns)
                if peak is not None and peak - zero > motion.contact_force_n:
                    break
                give_up_ns += waited
                self._mark()
                self._speed(direction, speed, at)
                sent_ns = self.clock.now_ns()
                progress = self._progress(self._state.pose)
                continue
            now = self.clock.now_ns()
            if progress.stalled(self._state.pose, self._state.since):
                raise Stop(progress.reason(), now)
            if now > give_up_ns:
                reason = (
                    f"no light contact within {limit_s:.1f} s of approach: the arm did not "
                    "reach the object (check the controller's log for a refused program)"
                )
                raise Stop(reason, now)
            self._check_reach(float(np.linalg.norm(self._state.pose[:3] - start[:3])), edge_m)
            wanted = motion.approach_speed(self.skin.nearest())
            # at most every 0.1 s of action time (a lab at time_scale S runs 1/S times faster),
            # and before the last command's lease ends
            changed = abs(wanted - speed) > 0.25 * speed and now - sent_ns > _NS // 10 * scale
            if (changed or now - sent_ns > renew_ns) and self._fresh():
                speed, sent_ns = wanted, now
                self._speed(direction, speed, at)
        self._driver.stop(motion.acceleration_m_s2, _phase(at, "contact"))
        yield self._event("contact")
        yield from self._until_fresh()  # the contact's pose: a state taken now, not a stale one
        return self._state.pose.copy()

    def _approach_edge(self, start: NDArray[np.float64], direction: NDArray[np.float64]) -> float:
        """Return how far the approach may go before the workspace's edge, m.

        The approach ends before the edge by the distance the arm needs to stop from its
        fastest approach (a few cycles of reaction, then the deceleration): an object that is
        not there, or a pose too close to the edge, stops the arm inside the box, not on a
        limit after it left it.
        """
        motion = self.options.motion
        fastest = motion.approach_max_m_s
        margin = fastest**2 / (2 * motion.acceleration_m_s2) + _EDGE_M
        cycle_s = self.arm.period_ns / _NS / self.options.time_scale  # of the arm's motion
        margin += _EDGE_CYCLES * fastest * cycle_s
        return self.limits.reach(start[:3], direction) - margin

    def _check_reach(self, travelled: float, edge_m: float) -> None:
        """Stop an approach that went as far as it may without a light contact.

        Raises:
            Stop: Past the workspace's edge (less the stopping distance) or approach_limit_m.
        """
        motion = self.options.motion
        contact = f"no light contact (total skin force above {motion.contact_force_n:g} N)"
        if travelled >= edge_m and edge_m < motion.approach_limit_m:
            reason = (
                f"{contact} within {max(edge_m, 0.0):.3f} m of the pose, where the [limits] "
                "workspace ends (less the arm's stopping distance): is the object there, and "
                "its pose right?"
            )
            raise Stop(reason, self.clock.now_ns())
        if travelled > motion.approach_limit_m:
            reason = f"{contact} within approach_limit_m = {motion.approach_limit_m:g} m"
            raise Stop(reason, self.clock.now_ns())

    def _fresh(self) -> bool:
        """Return whether the arm's latest state is fresh enough to command a motion on."""
        age = self.clock.now_ns() - self._state.receive_ns
        return age <= max(FRESH_CYCLES * self.arm.period_ns, round(FRESH_S * _NS))

    def _until_fresh(self) -> Iterator[StreamItem]:
        """Read the sources until the arm's latest state is fresh (the silence check bounds it)."""
        while not self._fresh():
            yield from self._pump()

    def _wait_for_skin(
        self, blind: _Blind, at: Context, since_ns: int
    ) -> Generator[StreamItem, None, tuple[int, float | None]]:
        """Stop the approach until the skin's force samples have caught up with the arm.

        Returns:
            How long it waited (ns) and the largest total skin force since ``since_ns`` that
            came meanwhile (the late samples may hold the light contact).

        Raises:
            Stop: The skin stayed :data:`SKIN_BEHIND_S` behind.
        """
        self._driver.stop(self.options.motion.acceleration_m_s2, at)
        began = self.clock.now_ns()
        peak: float | None = None
        while blind.paused:
            force = yield from self._pump_force(since_ns=since_ns)
            if force is not None:
                peak = force if peak is None else max(peak, force)
            now = self.clock.now_ns()
            if now - began > round(SKIN_BEHIND_S * _NS):
                reason = (
                    f"the skin's force samples stayed {SKIN_BEHIND_S:g} s behind the arm "
                    "during the approach; check the skin's link and the recorder's load"
                )
                raise Stop(reason, now)
            blind.pauses(self._state.sample, self._skin_seen_ns(), self.skin.nearest())
        return self.clock.now_ns() - began, peak

    def _skin_seen_ns(self) -> int | None:
        """Return how far the skin's force samples reach (None: none yet this action).

        The reach of the blocks handed over, plus a typical block (the median of the latest;
        one large block after a stall does not count): the samples of the block being filled
        have arrived already (a skin's total force reads them).
        """
        until = self._skin_until.get("force")
        return None if until is None else until + int(np.median(self._force_spans))

    def _speed(self, direction: NDArray[np.float64], speed: float, at: Context) -> None:
        motion = self.options.motion
        velocity = np.concatenate([direction * speed, np.zeros(3)])
        seconds = min(motion.approach_limit_m / max(speed, 1e-6), SPEED_LEASE_S)
        self._driver.speed(velocity, motion.acceleration_m_s2, seconds, at)

    def _pump_force(self, *, since_ns: int) -> Generator[StreamItem, None, float | None]:
        """Pump once; return the largest total skin force since ``since_ns`` (None: none).

        Every force sample that arrived counts, not only the latest: a short touch between two
        checks (a light contact on a soft object) is not missed.
        """
        peak: float | None = None
        for item in self._pump():
            yield item
            if isinstance(item, SkinBlock) and item.modality == "force":
                most = peak_total(item, since_ns=since_ns)
                if most is not None:
                    peak = most if peak is None else max(peak, most)
        total = self.skin.total_force()
        if total is not None:
            peak = total if peak is None else max(peak, total)
        return peak

    def _execute(
        self, at: Context, action: ActionSpec, contact: NDArray[np.float64]
    ) -> Iterator[StreamItem]:
        """Press to depth and hold, or slide at force and speed, for the action's duration."""
        motion, scale = self.options.motion, self.options.time_scale
        hold_ns = round(action.duration_s * scale * _NS)
        here = _phase(at, "execute")
        # from the contact as found: the path must fit before it is sent (nothing moves now)
        if problem := path_problem(action, contact, self.limits, motion.acceleration_m_s2):
            raise Stop(problem, self.clock.now_ns())
        yield self._event("execute")
        yield from self._until_fresh()
        if action.kind == "slide":
            velocity = np.concatenate([_tool_axis(contact, 0) * action.speed_m_s, np.zeros(3)])
            self._driver.force_slide(
                action.force_n, velocity, action.duration_s, motion.acceleration_m_s2, here
            )
            # the hold counts from the first state that shows the slide running: a program
            # starts a controller cycle or more after it is sent (later on a loaded machine)
            limit = self.clock.now_ns() + round((2.0 * scale + 2.0) * _NS)
            while self._state.still:
                yield from self._pump()
                if self.clock.now_ns() > limit:
                    msg = "the slide did not begin: the arm stayed still"
                    raise Stop(msg, self.clock.now_ns())
            start = self.clock.now_ns()
        else:
            axis = _tool_axis(contact, 2)
            target = contact.copy()
            target[:3] += axis * action.depth_m
            # + 2 s: a virtual lab on a loaded machine runs behind its clock
            travel_s = max(2.0, 10 * action.depth_m / motion.press_m_s) * scale + 2.0
            # the press leaves the object by itself if nothing replaces it in time (a
            # recorder killed mid-press): after its way there, its hold and PRESS_LEASE_S more
            lease = travel_s + action.duration_s * scale + PRESS_LEASE_S
            pressing = dataclasses.replace(here, lease_s=lease, back=tuple(map(float, contact)))
            self._driver.move(target, motion.press_m_s, motion.acceleration_m_s2, pressing)
            limit = self.clock.now_ns() + round(travel_s * _NS)
            # at depth: past half the depth (a depth of REACHED_M is "reached" at the contact,
            # before the press program has begun), within REACHED_M of the target and still
            # (the press is over: the hold is at depth, not on the way there)
            while not (
                self._pressed(contact, axis, action.depth_m)
                and self._reached(target)
                and self._state.still
            ):
                yield from self._pump()
                if self.clock.now_ns() > limit:
                    pose = self._state.pose
                    past = 0.0 if pose is None else float((pose[:3] - contact[:3]) @ axis)
                    reason = (
                        f"the press did not reach its depth {action.depth_m:g} m within 1 mm "
                        f"and stay there (at {past * 1e3:.2f} mm past the contact, "
                        f"{'still' if self._state.still else 'moving'})"
                    )
                    raise Stop(reason, self.clock.now_ns())
            start = self.clock.now_ns()
        while self.clock.now_ns() - start < hold_ns:
            yield from self._pump()

    def _retract(self, at: Context, contact: NDArray[np.float64]) -> Iterator[StreamItem]:
        """Move back to where the approach began (at least ``retract_m`` from the contact).

        The action ends when the arm is there (within 1 mm) and still, or, when something
        holds it, still for :data:`SETTLE_S` after it moved.
        """
        motion = self.options.motion
        yield from self._until_fresh()
        target = self._retract_target(contact)
        retract = _phase(at, "retract")
        self._driver.move(target, motion.retract_m_s, motion.acceleration_m_s2, retract)
        yield self._event("retract")
        start = self.clock.now_ns()
        still_since: int | None = None
        moved = False  # a retract that has not begun (its program late) is not over
        settle = round(SETTLE_S * _NS)
        distance = float(np.linalg.norm(target[:3] - contact[:3]))
        limit = start + round((3 * distance / motion.retract_m_s + 2) * _NS)
        while not (moved and self._state.still and self._reached(target)):
            yield from self._pump()
            now = self.clock.now_ns()
            moved = moved or not self._state.still
            still_since = (still_since or now) if self._state.still and moved else None
            if still_since is not None and now - still_since > settle and now - start > settle:
                break
            if now > limit:
                msg = "the retract did not end within its time"
                raise Stop(msg, now)

    def _retract_target(self, contact: NDArray[np.float64]) -> NDArray[np.float64]:
        """Return where the approach began when it is behind the contact along the tool axis.

        Anchored there (not at a fixed distance from a contact detected a cycle late), every
        action on an object starts from the same pose; ``retract_m`` back from the contact is
        the fallback (an approach that began sideways of the contact, or too close to it).
        """
        motion = self.options.motion
        axis = _tool_axis(contact, 2)
        fallback = contact.copy()
        fallback[:3] -= axis * motion.retract_m
        home = self._home
        if home is None:
            return fallback
        offset = home[:3] - contact[:3]
        back = -float(offset @ axis)  # how far the home lies behind the contact
        sideways = float(np.linalg.norm(offset + back * axis))
        if back < motion.retract_m or sideways > _HOME_M:
            return fallback
        target = contact.copy()
        target[:3] = home[:3]
        return target

    # -- receiving and checking -----------------------------------------------------------

    def _begin(self) -> None:
        """Forget what queued before (between actions), keeping the arm's latest state."""
        self._repeated = self._went_back = 0
        self._dog.rearm()
        self._newest_ns = -1  # a file's stamps move forward; a driver's clock may restart between
        self._driver.begin()
        self._begun_ns = self.clock.now_ns()
        self._skin_until = {}
        self._force_spans.clear()

    def _pump(self, wait_s: float = CYCLE_WAIT_S) -> Iterator[StreamItem]:
        """Yield what arrived (state samples, skin blocks) in receive order; check for stops.

        Every state sample is checked against the limits as it is taken in. A sample that
        breaks one raises the stop at once, before the skin is read and anything is handed
        over; the samples that arrived with it are handed over after the stop went out (valid
        data, kept).
        """
        # silence is judged when the sources were read: as the read begins (a sample it
        # returns is newer; a read that waits finds none older), not when it returned (a
        # recorder held up between the two is not a silent arm), nor later (time the runner or
        # its consumer, the writer, spends after the read is not the sources' silence)
        polled_ns = self.clock.now_ns()
        try:
            samples = self._driver.poll(wait_s)
        except SourceLostError as err:
            msg = f"arm connection lost ({err.__cause__ or err})"
            raise Stop(msg, self.clock.now_ns()) from None
        except Exception as err:  # a driver's own (a vendor library's) exception  # noqa: BLE001
            msg = f"the arm driver failed reading the arm's state ({_error(err)})"
            raise Stop(msg, self.clock.now_ns()) from None
        items, violation, violation_ns, fix = self._take(samples)
        if violation:
            raise Stop(violation, violation_ns, items, fix=fix)
        try:
            blocks = self._skin_poll()
        except SourceLostError as err:
            violation, blocks = f"skin connection lost ({err})", []
        for block in blocks:  # each modality's samples cover up to their last one + a period
            until = block.stamp_ns + block.data.shape[0] * block.period_ns
            self._skin_until[block.modality] = max(self._skin_until.get(block.modality, 0), until)
            if block.modality == "force":
                self._force_spans.append(block.data.shape[0] * block.period_ns)
        items.extend(blocks)
        items.sort(key=lambda item: item.receive_ns)
        yield from items
        self._check(violation, violation_ns, polled_ns)

    def _mark(self) -> None:
        """Count the controller's cycles from now: a command is being sent."""
        self._mark_ns = self.clock.now_ns()
        self._state.since = 0

    def _skin_poll(self) -> list[SkinBlock]:
        """Return what the skin delivered (watched: a skin's driver may hang too)."""
        with self._dog.calling("the skin's poll()"):
            return self.skin.poll()

    def _stop_from_watchdog(self, why: str) -> None:
        """Send the stop from the watchdog's thread (a call holds the loop); see Watchdog."""
        sent = self.clock.now_ns()
        self.arm.stop(self.options.motion.acceleration_m_s2, None)
        self.stops_sent.append((sent, sent, why))

    def _take(self, samples: Sequence[ArmSample]) -> tuple[list[StreamItem], str, int, str]:
        """Take state samples in: the latest state, what to hand over, the first violation.

        Returns:
            The items, the violation ('' if none), when its sample arrived, and its fix.
        """
        items: list[StreamItem] = []
        violation, violation_ns, fix = "", 0, CHECK_ARM
        for sample in self._in_order(samples):
            if malformed := self._malformed(sample):  # never taken as the state, never kept
                if not violation:
                    violation, violation_ns = malformed, sample.receive_ns
                continue
            self._state.sample, self._state.receive_ns = sample, sample.receive_ns
            self._state.taken += 1
            self._state.since += sample.receive_ns >= self._mark_ns
            if not violation and (violation := self._violation(sample)):
                violation_ns = sample.receive_ns
                if not self.limits.inside(sample.tcp_pose[:3]):  # e.g. where it stood at start
                    fix = (
                        "bring the TCP inside [limits] workspace_min_m .. workspace_max_m at the "
                        "teach pendant, or widen the workspace, then retry"
                    )
            items.extend(_items(sample))
        return items, violation, violation_ns, fix

    def _in_order(self, samples: Sequence[ArmSample]) -> Iterator[ArmSample]:
        """Yield the samples whose stamps move forward; count the others, never record them.

        A driver that hands a sample twice, or one whose stamp goes back (a driver's bug, a
        transport that duplicates), would make a file ``check`` refuses; such samples are
        counted into the arm's accounting (duplicated, out of order) instead.
        """
        for sample in samples:
            if sample.stamp_ns > self._newest_ns:
                self._newest_ns = sample.stamp_ns
                yield sample
            elif sample.stamp_ns == self._newest_ns:
                self._repeated += 1
            else:
                self._went_back += 1

    def _pump_quietly(self) -> None:
        """Pump without recording (between actions); the checks still run."""
        for _ in self._pump():
            pass

    def _violation(self, sample: ArmSample) -> str:
        """Return why this state sample ends the action (empty: it does not)."""
        if sample.stopped:
            return f"{sample.stopped} from the controller"
        if sample.replaced:
            return sample.replaced
        limits = self.limits
        force = float(np.linalg.norm(sample.tcp_force[:3]))
        if force > limits.max_force_n:
            return f"TCP force {force:.2f} N above [limits] max_force_n = {limits.max_force_n:g}"
        if not limits.inside(sample.tcp_pose[:3]):
            where = [round(float(v), 4) for v in sample.tcp_pose[:3]]
            return f"TCP at {where} left the [limits] workspace"
        return ""

    def _malformed(self, sample: ArmSample) -> str:
        """Return what makes a state sample unusable for the checks (empty: nothing).

        A driver's sample of another shape than its joint names say, or with a value that is
        not finite (a NaN force passes every comparison: no force limit at all), cannot be
        judged; the action stops on it. One sum tells whether every value is finite.
        """
        joints = len(self.arm.joint_names)
        parts = (
            ("joint positions", sample.q, joints),
            ("joint velocities", sample.qd, joints),
            ("joint efforts", sample.effort, joints),
            ("TCP pose values", sample.tcp_pose, 6),
            ("TCP force and torque values", sample.tcp_force, 6),
        )
        for name, values, size in parts:
            if np.shape(values) != (size,):
                given = "x".join(map(str, np.shape(values))) or "a scalar"
                whose = f"its {joints} joint_names" if size == joints and name[0] == "j" else "6"
                return f"the arm driver gave {given} {name} for {whose}; fix the driver"
        if math.isfinite(sum(float(np.sum(values)) for _, values, _ in parts)):
            return ""
        for name, values, _ in parts:
            if not np.isfinite(values).all():
                shown = [round(float(v), 4) for v in values]
                return (
                    f"the arm driver gave {name} that are not finite ({shown}): no limit can be "
                    "checked on them; fix the driver"
                )
        return ""  # pragma: no cover (a finite sum of finite parts)

    def _check(self, violation: str, violation_ns: int = 0, polled_ns: int | None = None) -> None:
        """Raise a stop for a limit, a signal, a writer in trouble or a silent source.

        A source is silent when nothing of it had arrived for ``silence_s`` at ``polled_ns``
        (when the sources were last read; now when not given).

        Raises:
            Stop: The reason, one line, and when the cause was met.
        """
        now = self.clock.now_ns()
        if violation:
            raise Stop(violation, violation_ns or now)
        if held := self._dog.fired:  # the watchdog sent the stop while a call held the loop
            msg = f"{held} (the stop was sent then)"
            raise Stop(msg, now)
        reason = violation or self._watch.problem()
        fix = CHECK_ARM
        if not reason:
            read = now if polled_ns is None else polled_ns
            silence = round(self.options.silence_s * _NS)
            last_arm = max(self._state.receive_ns, self._begun_ns)
            last_skin = max(self.skin.last_receive_ns() or 0, self._begun_ns)
            # a busy computer delays every source; one source silent while the other kept
            # arriving is that source's link or device, whatever the machine's load
            if read - last_arm > silence:
                reason = f"arm state silent for {(read - last_arm) / _NS:.2f} s"
                reason += _busy_hint() if read - last_skin > silence // 2 else _only_arm()
            elif read - last_skin > silence:
                reason = f"skin silent for {(read - last_skin) / _NS:.2f} s"
                if isinstance(self.skin, ExplainingSkin) and (hint := self.skin.silence_hint()):
                    reason += f" ({hint})"
                reason += _busy_hint() if read - last_arm > silence // 2 else _only_skin()
                fix = (
                    "check that the skin sends (the dry run lists each source) and the rig "
                    "configuration's [skin], then retry"
                )
        if reason:
            raise Stop(reason, now, fix=fix)

    def _skin_catch_up(self, end_ns: int) -> Iterator[StreamItem]:
        """Pump until the skin's samples cover ``end_ns``, at most :data:`SKIN_DELAY_S`.

        A transport that delivers late (ROS 2 on a loaded machine: the publisher's samples
        stamped on time, sent late) still has the action's last samples on their way when
        the arm is done; without the wait they would be missing from the file.
        """
        limit = self.clock.now_ns() + round(SKIN_DELAY_S * _NS)
        while (
            self._skin_until
            and min(self._skin_until.values()) < end_ns
            and self.clock.now_ns() < limit
        ):
            yield from self._pump()

    def _rest(self) -> Iterator[StreamItem]:
        """Yield what is still queued: state samples and the skin's open blocks."""
        items: list[StreamItem] = []
        with contextlib.suppress(Exception):  # after the stop: a failing driver gives nothing
            for sample in self._in_order(self._driver.poll(0.0)):
                if not self._malformed(sample):
                    items.extend(_items(sample))
        with contextlib.suppress(SourceLostError):
            items.extend(self.skin.finish())
        items.sort(key=lambda item: item.receive_ns)
        yield from items

    def _event(self, phase: str) -> PhaseEvent:
        now = max(self.clock.now_ns(), self._last_event_ns + 1)
        self._last_event_ns = now
        return PhaseEvent(now, now, phase)

    def _reached(self, target: NDArray[np.float64]) -> bool:
        pose = self._state.pose
        return pose is not None and float(np.linalg.norm(pose[:3] - target[:3])) <= REACHED_M

    def _pressed(
        self, contact: NDArray[np.float64], axis: NDArray[np.float64], depth_m: float
    ) -> bool:
        """Whether the arm went at least half ``depth_m`` past the contact along ``axis``."""
        pose = self._state.pose
        return pose is not None and float((pose[:3] - contact[:3]) @ axis) >= depth_m / 2


#: How long a press may hold the arm beyond its way there and its hold before the driver brings
#: it back by itself (a recorder that died mid-press), s: the retract replaces it long before.
PRESS_LEASE_S = 5.0
#: How long an action waits, moving nothing, for a program found playing to end before it
#: refuses, controller seconds: a killed recorder's press returns the arm within its way
#: there, its hold and PRESS_LEASE_S.
PROGRAM_WAIT_S = 20.0
#: How long the end of an action waits for skin samples stamped up to it, s.
SKIN_DELAY_S = 2.0


@dataclass(slots=True)
class _Progress:
    """Where the approach last made progress, to tell an arm that stands still while driven.

    Judged on the TCP's position (an approach's slowest speed turns a UR10's joints at a few
    mrad/s, near the noise of their readings) and counted in the controller's cycles since the
    command was sent (``_State.since``): a loaded recorder reads queued samples late, and
    they say nothing of the command.
    """

    pose: NDArray[np.float64]
    since: int
    cycles: float

    def stalled(self, pose: NDArray[np.float64] | None, since: int) -> bool:
        """Note the TCP's progress; return whether it stood still for :attr:`cycles`."""
        if pose is None:
            return False
        if float(np.linalg.norm(pose[:3] - self.pose[:3])) >= _PROGRESS_M:
            self.pose, self.since = pose.copy(), since
            return False
        return since - self.since > self.cycles

    def reason(self) -> str:
        """Return the stop's reason."""
        return (
            f"the arm stood still for {round(self.cycles)} controller cycles of the approach "
            "though its speed was sent: the controller runs none of the programs (a URScript "
            "link that takes them and delivers none, a controller in local control; the "
            "controller's log says why)"
        )


def _only_arm() -> str:
    """Return what an arm's silence says when the skin's frames kept arriving meanwhile.

    This computer read the skin, so the arm's link or controller comes first; a controller on
    this computer (a virtual lab) is slowed by its load too, which is then said as well.
    """
    load = _load()
    busy = (
        f"; this computer is busy too: load average {load[0]:.1f} on {load[1]} cores"
        if load
        else ""
    )
    return f" (the skin kept sending meanwhile: look at the arm's link and controller first{busy})"


def _only_skin() -> str:
    """Return what a skin's silence adds while the arm's state kept arriving: the load.

    The skin's link or device comes first (the fix says so); a skin sent from this computer
    (a virtual lab, a replay) is slowed by its load too, which is then said (empty: not busy).
    """
    load = _load()
    if load is None:
        return ""
    return f" (this computer is busy too: load average {load[0]:.1f} on {load[1]} cores)"


def _load() -> tuple[float, int] | None:
    """Return this computer's load average and cores when it is overloaded (None: it is not)."""
    try:
        load = os.getloadavg()[0]
    except (AttributeError, OSError):  # not on this system
        return None
    cores = os.cpu_count() or 1
    return (load, cores) if load > 1.5 * cores else None


def _busy_hint() -> str:
    """Return a clause saying this computer is overloaded (empty: it is not, or unknown).

    A source is silent also when the computer running the recorder (or a virtual lab beside
    it) is too busy to read it: the line then says so, not only the source and its settings.
    """
    if (load := _load()) is None:
        return ""
    return (
        f" (this computer is busy: load average {load[0]:.1f} on {load[1]} cores, which delays "
        "what arrives; stop other work, or raise silence_s)"
    )


def _error(err: BaseException) -> str:
    """Return an exception as one clause: its type, its message and where it was raised.

    The project's own errors are lines already: said as they are.
    """
    if isinstance(err, RecorderError):
        return " ".join(str(err).split())
    frames = traceback.extract_tb(err.__traceback__)
    where = f" at {Path(frames[-1].filename).name}:{frames[-1].lineno}" if frames else ""
    text = " ".join(str(err).split()) or "no message"
    return f"{type(err).__name__}: {text}{where}"


def _held_on(object_id: str) -> str:
    """Return what to say of an arm stopped while it touched the object."""
    return (
        f"the arm was stopped touching {object_id} (pressing on it, as the stop found it): the "
        "next action's move lifts it off first; to free the object now, jog the arm up at the "
        "teach pendant"
    )


def _unconfirmed(speed: float) -> str:
    """Return what to say when the arm's state stopped arriving while it was moving."""
    return (
        "the arm's state stopped arriving, so the stop cannot be confirmed (last seen moving, "
        f"a joint at {speed:.3f} rad/s); check the arm at the teach pendant now"
    )


def undelivered_line(reason: str, said: str = "") -> str:
    """Return what to say when the stop could not be sent to the arm (``reason``: why).

    When the line says ``reason`` already (``said``: the stop's own cause, e.g. the contact's
    stop that failed the same way), it is not said twice.
    """
    if reason and reason in said:
        return "the stop did not reach the arm either; stop it at the teach pendant now"
    return f"the stop did not reach the arm ({reason}); stop it at the teach pendant now"


def _phase(at: Context, phase: str) -> Context:
    return Context(at.object_id, at.action_id, at.trial, phase)


@dataclass(slots=True)
class _Blind:
    """How far the approach moved beyond what the skin's force samples have seen.

    The arm's positions along the approach, by state stamp, and the skin's reach (its newest
    sample's stamp, on the same time base) give the distance moved since the skin last saw
    the arm: a late skin (a delayed transport, a loaded recorder) lets the arm press on past a
    light contact it has not reported yet. Past ``limit_m`` the approach pauses; it goes on
    once the skin has caught up with the arm (within half the limit).
    """

    direction: NDArray[np.float64]
    start: NDArray[np.float64]
    limit_m: float
    paused: bool = False
    _track: list[tuple[int, float]] = field(default_factory=list)

    def pauses(
        self, sample: ArmSample | None, skin_ns: int | None, nearest_m: float | None = None
    ) -> bool:
        """Take the arm's latest state; return True when the approach must pause now.

        ``nearest_m`` is the skin's latest proximity reading: far from the object the arm may
        move blind up to half of it (a skin's usual latency at the far approach speed).
        While paused, :attr:`paused` turns False once the skin has caught up.
        """
        if sample is None:
            return False
        along = float(np.dot(sample.tcp_pose[:3] - self.start[:3], self.direction))
        if not self._track or sample.stamp_ns > self._track[-1][0]:
            self._track.append((sample.stamp_ns, along))
        seen = 0.0  # where the arm was when the skin's newest sample was taken
        if skin_ns is not None:
            index = bisect.bisect_right(self._track, (skin_ns, math.inf)) - 1
            if index >= 0:
                seen = self._track[index][1]
                del self._track[:index]  # older positions are never needed again
        ahead = along - seen
        limit = max(self.limit_m, 0.5 * nearest_m) if nearest_m is not None else self.limit_m
        if self.paused:
            self.paused = ahead > limit / 2
            return False
        self.paused = ahead > limit
        return self.paused


def _items(sample: ArmSample) -> list[StreamItem]:
    """Return the joint state and the TCP pose of one state sample."""
    from scipy.spatial.transform import Rotation  # noqa: PLC0415 (0.5 s: on first use)

    quat = Rotation.from_rotvec(sample.tcp_pose[3:6]).as_quat()
    return [
        JointSample(sample.stamp_ns, sample.receive_ns, sample.q, sample.qd, sample.effort),
        PoseSample(sample.stamp_ns, sample.receive_ns, sample.tcp_pose[:3].copy(), quat),
    ]


def peak_total(block: SkinBlock, *, since_ns: int) -> float | None:
    """Return the largest windowed total force of a block's samples at or after ``since_ns``.

    The total over every sensor, averaged over a sliding window of
    ``recorder.live.FORCE_WINDOW_NS`` (the mean the skin's ``total_force`` gives): a single
    sample's sum is too noisy for a light contact, the window's mean is not and still sees a
    short touch. Samples from before ``since_ns`` (a block may begin in the tare) do not count:
    a jolt while the arm moved to the object must not read as its contact.
    """
    totals = block.data.reshape(len(block.data), -1).sum(axis=1).astype(np.float64)
    stamps = block.stamp_ns + block.period_ns * np.arange(len(totals))
    after = totals[stamps >= since_ns]
    if not after.size:
        return None
    width = min(window_samples(block.period_ns), after.size)
    means = np.convolve(after, np.full(width, 1.0 / width), mode="valid")
    return float(means.max())


def _interrupted(flag: InterruptFlag, what: str) -> NoReturn:
    """End the run for the deferred signal of ``flag``; the line says ``what`` of the arm."""
    assert flag.signum is not None  # noqa: S101 - only called once a signal came
    try:
        raise_interrupt(flag.signum)
    except KeyboardInterrupt as err:
        err.args = (f"{flag.reason} {what}",)
        raise
