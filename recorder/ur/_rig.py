"""A Universal Robots arm with a live skin: state over RTDE, motion as URScript.

The rig reads every RTDE data package in a reader thread (bounded queue, overflow counted) and
counts it by the controller's ``timestamp``; it sends URScript programs to the secondary
interface, one per phase (see ``_script``), and decides the phases from what arrives: the
light contact from the skin's total force, the press from ``actual_TCP_pose`` within 1 mm of
its target, the hold and the slide from their durations. ``perform`` yields every item as it
arrives, so the writer flushes while the arm moves.

A protective or emergency stop (RTDE ``safety_status``), a force or a position outside the
limits, a lost RTDE or script connection, or a source silent for ``silence_s`` end the action
at once: the rig sends ``stopl`` if the controller is reachable, yields what arrived and
raises :class:`recorder.ActionStoppedError` with one line saying why.
"""

from __future__ import annotations

import contextlib
import socket
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any, Self

import numpy as np
from scipy.spatial.transform import Rotation

from recorder._rigconfig import refuse_sections, thaw
from recorder.errors import ActionStoppedError, RigError
from recorder.live import RecorderClock, SourceCounter, SourceLostError, SourceReader, open_skin
from recorder.ur._rtde import MAX_FREQUENCY, RTDE_PORT, RtdeClient, RtdeError
from recorder.ur._script import (
    REACHED_M,
    Announcement,
    Limits,
    Motion,
    approach_program,
    check_action,
    check_motion,
    check_pose,
    move_program,
    slide_program,
    stop_program,
    tool_axis,
)
from recorder.writing._stream import JointSample, PhaseEvent, PoseSample, SkinBlock

if TYPE_CHECKING:
    from collections.abc import Callable, Generator, Iterator, Mapping, Sequence
    from types import TracebackType

    from numpy.typing import NDArray

    from recorder._catalog import ActionSpec, ObjectSpec
    from recorder.live import LiveSkin, Received, SourceStats
    from recorder.writing._stream import StreamItem

#: The UR arms' joint names, in RTDE's order.
JOINT_NAMES = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
#: The RTDE outputs the rig asks for (``target_moment``: the joint torques it records).
RTDE_VARIABLES = (
    "timestamp",
    "actual_q",
    "actual_qd",
    "target_moment",
    "actual_TCP_pose",
    "actual_TCP_force",
    "robot_mode",
    "safety_status",
)
#: The secondary interface's port (URScript programs).
SCRIPT_PORT = 30002
#: RTDE ``safety_status`` values under which the arm may move (normal, reduced).
SAFE_STATUS = frozenset({1, 2})
#: Names of the other safety states, for messages.
SAFETY_NAMES = {
    3: "protective stop",
    4: "recovery",
    5: "safeguard stop",
    6: "system emergency stop",
    7: "robot emergency stop",
    8: "violation",
    9: "fault",
}
#: Joint speed below which the arm counts as still, rad/s.
STILL_RAD_S = 1e-3
#: How long the arm must be still (after the retract started) to end the action, s.
SETTLE_S = 0.25
#: RTDE samples read when connecting to estimate the controller's clock offset.
OFFSET_SAMPLES = 10
_NS = 1_000_000_000
#: How long the skin is read in free air before each approach to find its zero, ns.
TARE_NS = 30_000_000


@dataclass(frozen=True, slots=True)
class UROptions:
    """The UR rig's options (``[options]`` or ``--rig-option``), flat values.

    Attributes:
        host: The controller's address (the virtual lab: 127.0.0.1).
        rtde_port: RTDE port.
        script_port: Secondary interface port for URScript (30002; 30003 also works).
        frequency: RTDE packages per second: 125 (CB3) or 500 (e-Series).
        time_scale: Real seconds per action second; < 1 only against the virtual lab, which
            plays actions faster (the rig then holds and slides that much shorter).
        silence_s: A source silent this long ends the action, s.
        motion: How the arm moves (the remaining options: ``Motion``'s fields).
    """

    host: str = "127.0.0.1"
    rtde_port: int = RTDE_PORT
    script_port: int = SCRIPT_PORT
    frequency: int = 125
    time_scale: float = 1.0
    silence_s: float = 0.5
    motion: Motion = field(default_factory=Motion)

    @classmethod
    def from_options(cls, options: Mapping[str, object], where: str) -> UROptions:
        """Check and convert flat options.

        Raises:
            RigError: An unknown option or a value of the wrong type or range.
        """
        own = {f.name: f for f in fields(cls) if f.name != "motion"}
        moves = {f.name for f in fields(Motion)}
        values: dict[str, Any] = {}
        motion: dict[str, float] = {}
        for key, value in options.items():
            if key == "host":
                if not isinstance(value, str) or not value:
                    msg = f'{where}: rig option host = {value!r}: give an address, e.g. "127.0.0.1"'
                    raise RigError(msg)
                values[key] = value
            elif key in own or key in moves:
                number = _number(key, value, where)
                (motion if key in moves else values)[key] = number
            else:
                known = ", ".join([*own, *sorted(moves)])
                msg = f"{where}: rig option {key!r}: the ur rig takes {known}"
                raise RigError(msg)
        for key in ("rtde_port", "script_port", "frequency"):
            if key in values:
                values[key] = int(values[key])
        made = cls(**values, motion=Motion(**motion))
        made.check(where)
        return made

    def check(self, where: str) -> None:
        """Refuse a frequency or time scale a controller cannot have.

        Raises:
            RigError: The value and what to give instead.
        """
        if self.frequency not in {125, 500}:
            msg = (
                f"{where}: rig option frequency = {self.frequency}: "
                "give 125 (CB3) or 500 (e-Series)"
            )
            raise RigError(msg)
        if not 0 < self.time_scale <= 1:
            msg = f"{where}: rig option time_scale = {self.time_scale}: give a value in (0, 1]"
            raise RigError(msg)


def _number(key: str, value: object, where: str) -> float:
    """Return a positive option value.

    Raises:
        RigError: Not a positive number.
    """
    if isinstance(value, bool) or not isinstance(value, int | float) or value <= 0:
        msg = f"{where}: rig option {key} = {value!r}: give a positive number"
        raise RigError(msg)
    return float(value)


class _Stop(Exception):  # noqa: N818 (control flow inside perform, never escapes)
    """A stop condition met inside ``perform``."""

    def __init__(self, reason: str, at_ns: int) -> None:
        super().__init__(reason)
        self.reason = reason
        self.at_ns = at_ns


@dataclass(slots=True)
class _Arm:
    """The latest state of the arm, from the newest in-order RTDE package."""

    stamp_ns: int = -1
    pose: NDArray[np.float64] | None = None
    qd: NDArray[np.float64] = field(default_factory=lambda: np.zeros(6))
    force: NDArray[np.float64] = field(default_factory=lambda: np.zeros(6))
    safety: int = 1
    receive_ns: int = 0


class URRig:
    """A UR arm with a live skin (a :class:`recorder.Rig`; exclusive hardware)."""

    def __init__(
        self,
        options: UROptions,
        limits: Limits,
        skin: Mapping[str, Any],
        poses: Mapping[str, Sequence[float]],
        *,
        where: str = "<rig options>",
        skin_factory: Callable[[Mapping[str, Any], RecorderClock, str], LiveSkin] = open_skin,
    ) -> None:
        """Prepare the rig (nothing is opened before ``__enter__``).

        Args:
            options: The rig's options.
            limits: The ``[limits]`` table.
            skin: The ``[skin]`` table (its ``transport`` and the transport's keys).
            poses: Object id -> pose ``[x, y, z, rx, ry, rz]`` where the arm visits it.
            where: The configuration file, for messages.
            skin_factory: Builds the live skin from the ``[skin]`` table.

        Raises:
            RigError: A motion setting or an object's pose is outside the limits.
        """
        self.options, self.limits, self.where = options, limits, where
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
        self._skin_section = dict(skin)
        self._skin_factory = skin_factory
        self._clock = RecorderClock()
        self._stack: contextlib.ExitStack | None = None
        self._rtde: RtdeClient | None = None
        self._reader: SourceReader | None = None
        self._script: socket.socket | None = None
        self._skin: LiveSkin | None = None
        self._version = ""
        self._offset_ns = 0
        self._counter = SourceCounter("rtde", period_ns=round(_NS / options.frequency))
        self._overflow_base = 0
        self._arm = _Arm()
        self._last_event_ns = 0
        self._begun_ns = 0

    # -- connection -----------------------------------------------------------------------

    def __enter__(self) -> Self:
        """Connect to RTDE, the script port and the skin.

        Raises:
            RigError: A connection failed or the controller cannot stream at the frequency.
        """
        with contextlib.ExitStack() as stack:
            opts = self.options
            rtde = RtdeClient(opts.host, opts.rtde_port, clock=self._clock.now_ns)
            rtde.connect()
            stack.callback(rtde.close)
            major, minor, bugfix, build = rtde.controller_version()
            self._version = f"{major}.{minor}.{bugfix}.{build}"
            if opts.frequency > MAX_FREQUENCY.get(major, 500.0):
                msg = (
                    f"{self.where}: rig option frequency = {opts.frequency}, but controller "
                    f"{self._version} streams RTDE at {MAX_FREQUENCY[major]:g} Hz at most; "
                    "give frequency = 125"
                )
                raise RigError(msg)
            rtde.setup_outputs(RTDE_VARIABLES, opts.frequency)
            rtde.start()
            reader = SourceReader("rtde", rtde.receive)
            reader.start()
            stack.callback(self._stop_rtde, rtde, reader)
            self._rtde, self._reader = rtde, reader
            self._script = self._open_script()
            stack.callback(self._close_script)
            skin = self._skin_factory(self._skin_section, self._clock, self.where)
            self._skin = stack.enter_context(skin)
            self._offset_ns = self._estimate_offset()
            self._stack = stack.pop_all()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Disconnect everything, whatever happened."""
        stack, self._stack = self._stack, None
        if stack is not None:
            stack.close()
        self._rtde = self._reader = self._script = self._skin = None

    @staticmethod
    def _stop_rtde(rtde: RtdeClient, reader: SourceReader) -> None:
        with contextlib.suppress(RtdeError):
            rtde.pause(timeout_s=0.2)
        reader.stop()

    def _open_script(self) -> socket.socket:
        opts = self.options
        try:
            return socket.create_connection((opts.host, opts.script_port), timeout=2.0)
        except OSError as err:
            msg = (
                f"URScript {opts.host}:{opts.script_port}: cannot connect ({err}); check the rig "
                "options host and script_port, and that the controller is in remote control"
            )
            raise RigError(msg) from err

    def _close_script(self) -> None:
        sock, self._script = self._script, None
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.close()

    def _estimate_offset(self) -> int:
        """Return recorder time minus controller time from the first packages (lowest latency)."""
        reader, rtde = self._parts()
        recipe = rtde.recipe
        assert recipe is not None  # noqa: S101 (set up in __enter__)
        warmup = SourceCounter("rtde", period_ns=self._counter_period())
        deadline = self._clock.now_ns() + 2 * _NS
        while warmup.stats().received < OFFSET_SAMPLES and self._clock.now_ns() < deadline:
            item = reader.get(0.05)
            if item is None:
                reader.check()
                continue
            stamp = round(float(recipe.parse(item.payload)["timestamp"]) * _NS)
            warmup.observe(None, stamp, item.receive_ns)
        if warmup.clock_offset_ns is None:
            msg = f"RTDE {rtde.where}: no data package within 2 s after start; check the controller"
            raise RigError(msg)
        return warmup.clock_offset_ns

    def _counter_period(self) -> int:
        return round(_NS / self.options.frequency)

    def _parts(self) -> tuple[SourceReader, RtdeClient]:
        if self._reader is None or self._rtde is None:
            msg = "URRig used outside its with block; use `with build_ur_rig(...) as rig:`"
            raise RigError(msg)
        return self._reader, self._rtde

    def _live_skin(self) -> LiveSkin:
        if self._skin is None:
            msg = "URRig used outside its with block; use `with build_ur_rig(...) as rig:`"
            raise RigError(msg)
        return self._skin

    # -- the Rig protocol ---------------------------------------------------------------

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Return the UR joint names."""
        return JOINT_NAMES

    def describe(self) -> Mapping[str, str]:
        """Return the rig's kind and configuration, flat, for the metadata."""
        skin = self._skin_section.get("transport", "")
        described = {
            "kind": "ur",
            "host": self.options.host,
            "rtde_port": str(self.options.rtde_port),
            "script_port": str(self.options.script_port),
            "rtde_frequency_hz": str(self.options.frequency),
            "controller_version": self._version,
            "skin_transport": str(skin),
            "silence_s": f"{self.options.silence_s:g}",
        }
        if self.options.time_scale != 1:
            described["time_scale"] = f"{self.options.time_scale:g}"
        return described

    def can_present(self, obj: ObjectSpec) -> bool:
        """Return whether the arm can visit ``obj`` by itself (it has a pose)."""
        return obj.id in self._poses

    def present(self, obj: ObjectSpec) -> bool:
        """Move the arm to ``obj``'s pose (``movel``, until within 1 mm).

        Returns:
            True when the arm is there; False when ``obj`` has no pose (a person must place
            the object under the arm).

        Raises:
            RigError: The arm stopped, a connection was lost or it did not arrive in time.
        """
        target = self._poses.get(obj.id)
        if target is None:
            return False
        motion = self.options.motion
        self._send(move_program(None, "present", target, motion.retract_m_s, motion))
        self._begin()
        distance = (
            1.0
            if self._arm.pose is None
            else float(np.linalg.norm(self._arm.pose[:3] - target[:3]))
        )
        limit_ns = self._clock.now_ns() + round((5 + 3 * distance / motion.retract_m_s) * _NS)
        try:
            self._wait_until_reached(target, limit_ns, obj.id)
        except _Stop as stop:
            msg = f"{self.where}: moving to {obj.id}: {stop.reason}; check the arm, then retry"
            raise RigError(msg) from None
        return True

    def _wait_until_reached(self, target: NDArray[np.float64], limit_ns: int, what: str) -> None:
        """Read the arm's state (recording nothing) until it is within 1 mm of ``target``.

        Raises:
            _Stop: A stop condition, or the deadline passed.
        """
        while not self._reached(target):
            list(self._pump())
            if self._clock.now_ns() > limit_ns:
                msg = f"the arm did not reach the pose of {what} within 1 mm"
                raise _Stop(msg, self._clock.now_ns())

    def source_stats(self) -> list[SourceStats]:
        """Return the accounting of the last action: RTDE and the skin's sources."""
        reader = self._reader
        if reader is not None:
            missed = reader.overflowed - self._overflow_base
            if missed:
                self._counter.overflow(missed)
                self._overflow_base = reader.overflowed
        skin = self._skin.stats() if self._skin is not None else []
        return [self._counter.stats(), *skin]

    def perform(self, obj: ObjectSpec, action: ActionSpec, trial: int) -> Iterator[StreamItem]:
        """Perform ``action`` on ``obj``: light contact, execute, retract; yield as it arrives.

        Raises:
            RigError: The action is outside the limits (nothing was sent) or the rig is not
                connected.
            ActionStoppedError: A stop ended the action; everything that arrived was yielded.
        """
        check_action(action, self.limits, self.where)
        if obj.id in self._poses:
            check_pose(obj.id, self._poses[obj.id], self.limits, self.where)
        self._parts()
        return self._perform(obj, action, trial)

    def _perform(self, obj: ObjectSpec, action: ActionSpec, trial: int) -> Iterator[StreamItem]:
        said = Announcement(obj.id, action.id, trial)
        self._begin()
        self._counter = SourceCounter("rtde", period_ns=self._counter_period())
        self._live_skin().begin()
        try:
            yield from self._pump(0.0)
            yield self._event("approach")
            contact = yield from self._approach(said)
            yield from self._execute(said, action, contact)
            yield from self._retract(said, contact)
        except _Stop as stop:
            with contextlib.suppress(_Stop):
                self._send(stop_program(said, "stop", self.options.motion))
            yield from self._rest()
            raise ActionStoppedError(stop.reason, stop.at_ns) from None
        yield from self._rest()
        yield self._event("end")

    # -- phases ------------------------------------------------------------------------

    def _tare(self) -> Generator[StreamItem, None, float]:
        """Return the skin's total force in free air before the approach (its zero).

        A skin's offsets drift between actions (temperature, ageing of the cover): the light
        contact is the total force rising above this zero by the threshold, as labs tare
        their skins before each touch.
        """
        skin, readings = self._live_skin(), list[float]()
        deadline = self._clock.now_ns() + TARE_NS
        while self._clock.now_ns() < deadline or not readings:
            yield from self._pump()
            total = skin.total_force()
            if total is not None:
                readings.append(total)
            if self._clock.now_ns() > deadline + 100 * TARE_NS:
                return 0.0  # no force sensing: nothing to tare
        return float(np.median(readings))

    def _approach(self, said: Announcement) -> Generator[StreamItem, None, NDArray[np.float64]]:
        """Approach with speed from proximity until the light contact; return the contact pose."""
        motion, skin = self.options.motion, self._live_skin()
        while self._arm.pose is None:
            yield from self._pump()
        zero = yield from self._tare()
        start = self._arm.pose.copy()
        direction = tool_axis(start, 2)
        speed = motion.approach_speed(skin.nearest())
        self._send(approach_program(said, direction, speed, motion))
        sent_ns = self._clock.now_ns()
        # the slowest approach over the whole distance, twice: an arm that does not move
        # (a program the controller refused) must not keep the action waiting forever
        limit_s = 2 * motion.approach_limit_m / motion.approach_min_m_s * self.options.time_scale
        give_up_ns = sent_ns + round(limit_s * _NS)
        while True:
            peak = yield from self._pump_force(since_ns=sent_ns)
            if peak is not None and peak - zero > motion.contact_force_n:
                break
            if self._clock.now_ns() > give_up_ns:
                reason = (
                    f"no light contact within {limit_s:.1f} s of approach: the arm did not "
                    "reach the object (check the controller's log for a refused program)"
                )
                raise _Stop(reason, self._clock.now_ns())
            travelled = float(np.linalg.norm(self._arm.pose[:3] - start[:3]))
            if travelled > motion.approach_limit_m:
                reason = (
                    f"no light contact (total skin force above {motion.contact_force_n:g} N) "
                    f"within approach_limit_m = {motion.approach_limit_m:g} m"
                )
                raise _Stop(reason, self._clock.now_ns())
            wanted = motion.approach_speed(skin.nearest())
            now = self._clock.now_ns()
            if abs(wanted - speed) > 0.25 * speed and now - sent_ns > _NS // 10:
                speed, sent_ns = wanted, now
                self._send(approach_program(said, direction, speed, motion))
        self._send(stop_program(said, "contact", motion))
        yield self._event("contact")
        return self._arm.pose.copy()

    def _pump_force(self, *, since_ns: int) -> Generator[StreamItem, None, float | None]:
        """Pump once; return the largest total skin force since ``since_ns`` (None: none).

        Every force sample that arrived counts, not only the latest: a short touch between two
        checks (a light contact on a soft object) is not missed.
        """
        peak: float | None = None
        for item in self._pump():
            yield item
            if isinstance(item, SkinBlock) and item.modality == "force":
                most = _peak_total(item, since_ns=since_ns)
                if most is not None:
                    peak = most if peak is None else max(peak, most)
        total = self._live_skin().total_force()
        if total is not None:
            peak = total if peak is None else max(peak, total)
        return peak

    def _execute(
        self, said: Announcement, action: ActionSpec, contact: NDArray[np.float64]
    ) -> Iterator[StreamItem]:
        """Press to depth and hold, or slide at force and speed, for the action's duration."""
        motion, scale = self.options.motion, self.options.time_scale
        hold_ns = round(action.duration_s * scale * _NS)
        yield self._event("execute")
        if action.kind == "slide":
            self._send(slide_program(said, action, tool_axis(contact, 0), motion))
            start = self._clock.now_ns()
        else:
            target = contact.copy()
            target[:3] += tool_axis(contact, 2) * action.depth_m
            self._send(move_program(said, "execute", target, motion.press_m_s, motion))
            travel_s = max(2.0, 10 * action.depth_m / motion.press_m_s) * scale + 1.0
            limit = self._clock.now_ns() + round(travel_s * _NS)
            while not self._reached(target):
                yield from self._pump()
                if self._clock.now_ns() > limit:
                    reason = f"the press did not reach its depth {action.depth_m:g} m within 1 mm"
                    raise _Stop(reason, self._clock.now_ns())
            start = self._clock.now_ns()
        while self._clock.now_ns() - start < hold_ns:
            yield from self._pump()

    def _retract(self, said: Announcement, contact: NDArray[np.float64]) -> Iterator[StreamItem]:
        """Move back from the contact until there (within 1 mm) or at rest."""
        motion = self.options.motion
        target = contact.copy()
        target[:3] -= tool_axis(contact, 2) * motion.retract_m
        self._send(move_program(said, "retract", target, motion.retract_m_s, motion))
        yield self._event("retract")
        start = self._clock.now_ns()
        still_since: int | None = None
        settle = round(SETTLE_S * _NS)
        limit = start + round((3 * motion.retract_m / motion.retract_m_s + 2) * _NS)
        while not self._reached(target):
            yield from self._pump()
            now = self._clock.now_ns()
            still = bool(np.all(np.abs(self._arm.qd) < STILL_RAD_S))
            still_since = (still_since or now) if still else None
            if still_since is not None and now - still_since > settle and now - start > settle:
                break
            if now > limit:
                msg = "the retract did not end within its time"
                raise _Stop(msg, now)

    # -- receiving ----------------------------------------------------------------------

    def _begin(self) -> None:
        """Drop what was queued before (between actions) and update the arm's state."""
        reader, _ = self._parts()
        stale = reader.drain()
        if stale:
            self._update_only(stale)
        self._overflow_base = reader.overflowed
        self._begun_ns = self._clock.now_ns()

    def _update_only(self, items: Sequence[Received]) -> None:
        recipe = self._parts()[1].recipe
        assert recipe is not None  # noqa: S101 (set up in __enter__)
        for item in items:
            values = recipe.parse(item.payload)
            stamp = round(float(values["timestamp"]) * _NS)
            if stamp > self._arm.stamp_ns:
                self._state(values, stamp, item.receive_ns)

    def _state(self, values: Mapping[str, Any], stamp: int, receive_ns: int) -> None:
        arm = self._arm
        arm.stamp_ns, arm.receive_ns = stamp, receive_ns
        arm.pose = np.asarray(values["actual_TCP_pose"], dtype=np.float64)
        arm.qd = np.asarray(values["actual_qd"], dtype=np.float64)
        arm.force = np.asarray(values["actual_TCP_force"], dtype=np.float64)
        arm.safety = int(values["safety_status"])

    def _pump(self, wait_s: float = 0.01) -> Iterator[StreamItem]:
        """Yield what arrived (RTDE samples, skin blocks) in receive order; check for stops."""
        reader, rtde = self._parts()
        skin = self._live_skin()
        first = reader.get(wait_s) if wait_s > 0 else None
        try:
            packages = ([first] if first is not None else []) + reader.drain()
        except SourceLostError as err:
            msg = f"RTDE connection lost ({err.__cause__ or err})"
            raise _Stop(msg, self._clock.now_ns()) from None
        items: list[StreamItem] = []
        recipe = rtde.recipe
        assert recipe is not None  # noqa: S101 (set up in __enter__)
        for package in packages:
            items.extend(self._sample(recipe.parse(package.payload), package.receive_ns))
        try:
            items.extend(skin.poll())
        except SourceLostError as err:
            msg = f"skin connection lost ({err})"
            raise _Stop(msg, self._clock.now_ns()) from None
        items.sort(key=lambda item: item.receive_ns)
        yield from items
        self._check()

    def _sample(self, values: Mapping[str, Any], receive_ns: int) -> list[StreamItem]:
        """Count one RTDE package; return its joint state and pose if it is new and in order.

        A duplicate or a package older than the newest one is counted, not written (the
        recording's stamps strictly increase).
        """
        stamp = round(float(values["timestamp"]) * _NS)
        if not self._counter.observe(None, stamp, receive_ns) or stamp <= self._arm.stamp_ns:
            return []
        self._state(values, stamp, receive_ns)
        at = stamp + self._offset_ns
        pose = np.asarray(values["actual_TCP_pose"], dtype=np.float64)
        quat = Rotation.from_rotvec(pose[3:6]).as_quat()
        return [
            JointSample(
                at,
                receive_ns,
                np.asarray(values["actual_q"], dtype=np.float64),
                np.asarray(values["actual_qd"], dtype=np.float64),
                np.asarray(values["target_moment"], dtype=np.float64),
            ),
            PoseSample(at, receive_ns, pose[:3].copy(), quat),
        ]

    def _check(self) -> None:
        """Raise a stop for a safety stop, a limit, or a silent source.

        Raises:
            _Stop: The reason, one line.
        """
        arm, now, limits = self._arm, self._clock.now_ns(), self.limits
        if arm.safety not in SAFE_STATUS:
            name = SAFETY_NAMES.get(arm.safety, "unsafe state")
            msg = f"{name} (RTDE safety_status {arm.safety}) from the controller"
            raise _Stop(msg, now)
        force = float(np.linalg.norm(arm.force[:3]))
        if force > limits.max_force_n:
            reason = f"TCP force {force:.2f} N above [limits] max_force_n = {limits.max_force_n:g}"
            raise _Stop(reason, now)
        if arm.pose is not None and not limits.inside(arm.pose[:3]):
            where = [round(float(v), 4) for v in arm.pose[:3]]
            msg = f"TCP at {where} left the [limits] workspace"
            raise _Stop(msg, now)
        silence = round(self.options.silence_s * _NS)
        last_rtde = max(arm.receive_ns, self._begun_ns)
        if now - last_rtde > silence:
            msg = f"RTDE silent for {(now - last_rtde) / _NS:.2f} s"
            raise _Stop(msg, now)
        last_skin = max(self._live_skin().last_receive_ns() or 0, self._begun_ns)
        if now - last_skin > silence:
            msg = f"skin silent for {(now - last_skin) / _NS:.2f} s"
            raise _Stop(msg, now)

    def _rest(self) -> Iterator[StreamItem]:
        """Yield what is still queued: RTDE packages and the skin's open blocks."""
        reader, rtde = self._parts()
        recipe = rtde.recipe
        assert recipe is not None  # noqa: S101 (set up in __enter__)
        items: list[StreamItem] = []
        with contextlib.suppress(SourceLostError):
            for package in reader.drain():
                items.extend(self._sample(recipe.parse(package.payload), package.receive_ns))
        items.extend(self._live_skin().finish())
        items.sort(key=lambda item: item.receive_ns)
        yield from items

    def _event(self, phase: str) -> PhaseEvent:
        now = max(self._clock.now_ns(), self._last_event_ns + 1)
        self._last_event_ns = now
        return PhaseEvent(now, now, phase)

    def _reached(self, target: NDArray[np.float64]) -> bool:
        pose = self._arm.pose
        return pose is not None and float(np.linalg.norm(pose[:3] - target[:3])) <= REACHED_M

    def _send(self, text: str) -> None:
        """Send a URScript program (it replaces the running one).

        Raises:
            _Stop: The script connection is lost.
        """
        sock = self._script
        where = f"{self.options.host}:{self.options.script_port}"
        if sock is None:
            msg = f"URScript connection to {where} is closed"
            raise _Stop(msg, self._clock.now_ns())
        try:
            sock.sendall(text.encode())
        except OSError as err:
            msg = f"URScript connection to {where} lost ({err})"
            raise _Stop(msg, self._clock.now_ns()) from None


def build_ur_rig(seed: int, config: Any) -> URRig:  # noqa: ANN401 (a RigConfig)
    """Build the UR rig from a rig configuration (not yet connected).

    Args:
        seed: Unused (a real arm draws nothing); part of the builder's signature.
        config: ``.options`` (flat), ``.sections`` (``limits``, ``skin``, ``objects``) and
            ``.source`` (the file, for messages).

    Raises:
        RigError: An option, a limit or an object's pose is malformed or outside the limits.
    """
    del seed
    where = str(getattr(config, "source", None) or "<rig options>")
    refuse_sections(config, ("limits", "skin", "objects"))
    sections: Mapping[str, Any] = thaw(getattr(config, "sections", {}) or {})
    options = UROptions.from_options(dict(config.options), where)
    limits = Limits.from_section(sections.get("limits", {}), where)
    skin = sections.get("skin")
    if not isinstance(skin, dict) or "transport" not in skin:
        msg = f'{where}: the ur rig needs a [skin] table with transport = "udp", "serial" or "ros2"'
        raise RigError(msg)
    poses: dict[str, Sequence[float]] = {}
    for object_id, entry in (sections.get("objects", {}) or {}).items():
        pose = entry.get("pose") if isinstance(entry, dict) else None
        if not isinstance(pose, list) or not all(isinstance(v, int | float) for v in pose):
            msg = f"{where}: [objects.{object_id}] needs pose = [x, y, z, rx, ry, rz] in m and rad"
            raise RigError(msg)
        poses[object_id] = [float(v) for v in pose]
    return URRig(options, limits, skin, poses, where=where)


def _peak_total(block: SkinBlock, *, since_ns: int) -> float | None:
    """Return the largest total force of a force block's samples taken at or after ``since_ns``.

    Samples from before (a block may begin before the approach, in the tare) are not counted:
    a jolt while the arm moved to the object must not read as its contact.
    """
    totals = block.data.reshape(len(block.data), -1).sum(axis=1)
    stamps = block.stamp_ns + block.period_ns * np.arange(len(totals))
    after = totals[stamps >= since_ns]
    return float(after.max()) if after.size else None
