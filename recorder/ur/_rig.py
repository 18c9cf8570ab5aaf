"""A Universal Robots arm with a live skin, driven by the action runner.

The UR driver (``_arm``: RTDE state, URScript motion) and a live skin (``[skin]``) under the
arm-agnostic runner (:class:`recorder.runner.ArmRig`: phases, limits, silence, the stop).
This module reads the rig configuration: ``[options]`` (connection and motion), ``[limits]``,
``[skin]`` and ``[objects.<id>] pose``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any

from recorder._rigconfig import refuse_sections, thaw
from recorder.errors import RigError
from recorder.live import RecorderClock, open_skin
from recorder.runner import ArmRig, Limits, Motion, RunnerOptions
from recorder.ur._arm import DASHBOARD_PORT, Connection, URArm
from recorder.ur._rtde import RTDE_PORT
from schemas import cli

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence

    from recorder.live import LiveSkin

#: The primary interface's port: URScript programs in, the controller's messages out.
SCRIPT_PORT = 30001

#: Values of an object's pose: position (m) and rotation vector (rad), base frame.
POSE_SIZE = 6


@dataclass(frozen=True, slots=True)
class UROptions:
    """The UR rig's options (``[options]`` or ``--rig-option``), flat values.

    Attributes:
        host: The controller's address (the virtual lab: 127.0.0.1).
        rtde_port: RTDE port.
        script_port: The port the programs go to: 30001, the primary interface, whose
            messages name every program that starts (another's is seen); 30002 and 30003
            take programs too but send no messages.
        dashboard_port: The dashboard server's port (29999): the stop goes there when no
            URScript connection takes it; 0: nowhere.
        frequency: RTDE packages per second: 125 (CB3) or 500 (e-Series).
        time_scale: Real seconds per action second; < 1 only against the virtual lab, which
            plays actions faster (the rig then holds and slides that much shorter).
        silence_s: A source silent this long ends the action, s.
        rt_priority: ``SCHED_FIFO`` priority, 1-99, of the arm's and the skin's readers and
            of the runner's loop during actions; 0 (the default): normal scheduling
            (``recorder.live._realtime``).
        motion: How the arm moves (the remaining options: ``Motion``'s fields).
    """

    host: str = "127.0.0.1"
    rtde_port: int = RTDE_PORT
    script_port: int = SCRIPT_PORT
    dashboard_port: int = DASHBOARD_PORT
    frequency: int = 125
    time_scale: float = 1.0
    silence_s: float = 0.5
    rt_priority: int = 0
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
                if not isinstance(value, str) or not value.strip() or value != value.strip():
                    msg = f'{where}: rig option host = {value!r}: give an address, e.g. "127.0.0.1"'
                    raise RigError(msg)
                values[key] = value
            elif key == "rt_priority":
                if isinstance(value, bool) or not isinstance(value, int):
                    msg = f"{where}: rig option rt_priority = {value!r}: give a whole number 1-99"
                    raise RigError(msg)
                values[key] = value
            elif key == "dashboard_port":  # 0 is a value here: no dashboard
                if isinstance(value, bool) or not isinstance(value, int):
                    msg = (
                        f"{where}: rig option dashboard_port = {value!r}: give the "
                        "controller's dashboard port (29999), or 0 for none"
                    )
                    raise RigError(msg)
                values[key] = value
            elif key in own or key in moves:
                number = _number(key, value, where)
                (motion if key in moves else values)[key] = number
            else:
                known = ", ".join([*own, *sorted(moves)])
                msg = f"{where}: rig option {key!r}: the ur rig takes {known}"
                raise RigError(msg)
        _whole_numbers(values, where)
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
        self._check_ports(where)

    def _check_ports(self, where: str) -> None:
        """Refuse two interfaces of one controller on one port.

        A controller serves RTDE, URScript and the dashboard each on a port of its own; a
        dashboard_port that is the script port would send the stop's second way in to the
        first one (and read its binary packages as the dashboard's greeting).

        Raises:
            RigError: Both options, their port and the usual ports.
        """
        ports = {"rtde_port": self.rtde_port, "script_port": self.script_port}
        if self.dashboard_port:  # 0: no dashboard
            ports["dashboard_port"] = self.dashboard_port
        seen: dict[int, str] = {}
        for key, port in ports.items():
            if port in seen:
                msg = (
                    f"{where}: rig option {key} = {port} is also {seen[port]}: a controller "
                    f"serves each interface on a port of its own (rtde_port {RTDE_PORT}, "
                    f"script_port {SCRIPT_PORT}, dashboard_port {DASHBOARD_PORT}); give {key} "
                    "its own port"
                )
                raise RigError(msg)
            seen[port] = key


def _whole_numbers(values: dict[str, Any], where: str) -> None:
    """Make the ports and the frequency whole numbers, the ports in 1..65535.

    Raises:
        RigError: A fraction, or a port out of range.
    """
    for key in ("rtde_port", "script_port", "dashboard_port", "frequency"):
        if key in values:
            if not float(values[key]).is_integer():
                msg = f"{where}: rig option {key} = {values[key]!r}: give a whole number"
                raise RigError(msg)
            values[key] = int(values[key])
    for key in ("rtde_port", "script_port"):
        if not 1 <= values.get(key, 1) <= cli.MAX_PORT:
            fix = f"give the controller's port 1..{cli.MAX_PORT}"
            msg = f"{where}: rig option {key} = {values[key]}: {fix}"
            raise RigError(msg)
    if not 0 <= values.get("dashboard_port", 0) <= cli.MAX_PORT:
        fix = f"give the controller's dashboard port 1..{cli.MAX_PORT}, or 0 for none"
        msg = f"{where}: rig option dashboard_port = {values['dashboard_port']}: {fix}"
        raise RigError(msg)


def _number(key: str, value: object, where: str) -> float:
    """Return a positive finite option value.

    Raises:
        RigError: Not a positive finite number (nan passes every comparison: a silence_s of
            nan would never end a silent action).
    """
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or (isinstance(value, float) and not math.isfinite(value))
        or value <= 0
    ):
        msg = f"{where}: rig option {key} = {value!r}: give a positive finite number"
        raise RigError(msg)
    return float(value)


class URRig(ArmRig):
    """A UR arm with a live skin under the runner (a :class:`recorder.Rig`; exclusive)."""

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
            RigError: A motion setting or an object's pose is outside the limits, or the skin
                table is refused (before anything connects).
        """
        self.options_ur = options
        clock = RecorderClock()
        link = Connection(
            options.host,
            options.rtde_port,
            options.script_port,
            options.frequency,
            options.dashboard_port,
        )
        runner = RunnerOptions(
            options.time_scale, options.silence_s, options.motion, options.rt_priority
        )
        super().__init__(
            URArm(link, clock, where),
            skin_factory(skin, clock, where),
            limits,
            runner,
            poses,
            kind="ur",
            skin_transport=str(skin.get("transport", "")),
            where=where,
            clock=clock,
        )


@dataclass(frozen=True, slots=True)
class URConfig:
    """A UR rig configuration, checked: what :func:`build_ur_rig` builds a rig from.

    Attributes:
        options: ``[options]``.
        limits: ``[limits]``.
        skin: ``[skin]`` (its ``transport`` and the transport's keys).
        poses: ``[objects.<id>] pose``, by object id.
        where: The configuration file, for messages.
    """

    options: UROptions
    limits: Limits
    skin: Mapping[str, Any]
    poses: Mapping[str, Sequence[float]]
    where: str


def read_ur_config(config: Any, rig: str = "ur") -> URConfig:  # noqa: ANN401 (a RigConfig)
    """Check a UR rig configuration (nothing connects).

    Args:
        config: ``.options`` (flat), ``.sections`` (``limits``, ``skin``, ``objects``) and
            ``.source`` (the file, for messages).
        rig: The rig's name, for messages.

    Raises:
        RigError: An option, a limit or an object's pose is malformed, or no ``[skin]``.
    """
    where = str(getattr(config, "source", None) or "<rig options>")
    refuse_sections(config, ("limits", "skin", "objects"))
    sections: Mapping[str, Any] = thaw(getattr(config, "sections", {}) or {})
    options = UROptions.from_options(dict(config.options), where)
    limits = Limits.from_section(sections.get("limits", {}), where)
    skin = sections.get("skin")
    if not isinstance(skin, dict) or "transport" not in skin:
        msg = (
            f"{where}: the {rig} rig needs a [skin] table with transport = "
            '"udp", "serial" or "ros2"'
        )
        raise RigError(msg)
    poses: dict[str, Sequence[float]] = {}
    for object_id, entry in (sections.get("objects", {}) or {}).items():
        pose = entry.get("pose") if isinstance(entry, dict) else None
        if (
            not isinstance(pose, list)
            or len(pose) != POSE_SIZE
            or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in pose)
            or not all(math.isfinite(v) for v in pose)  # nan passes the workspace check
        ):
            msg = (
                f"{where}: [objects.{object_id}] pose = {pose!r}: give pose = "
                "[x, y, z, rx, ry, rz], six finite numbers in m and rad"
            )
            raise RigError(msg)
        poses[object_id] = [float(v) for v in pose]
    return URConfig(options, limits, skin, poses, where)


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
    checked = read_ur_config(config)
    return URRig(checked.options, checked.limits, checked.skin, checked.poses, where=checked.where)
