"""What an arm may do and how the runner moves it: limits and motion settings, checked early.

Limits (``[limits]`` of the rig configuration) are checked before anything moves and on every
state sample; a value outside them is refused in one line naming the file, the value and the
limit. Arm-agnostic: every driver's arm is held to the same limits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

import numpy as np

from recorder.errors import RigError

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from numpy.typing import NDArray

    from recorder._catalog import ActionSpec

#: Light contact of the catalog (recorder/data/actions.toml): total normal force, N.
LIGHT_CONTACT_N = 0.05
#: How close a ``movel`` target counts as reached (the thesis: 1 mm).
REACHED_M = 0.001
#: Prefix of the motion settings in a rig's description (its identity in a dataset).
MOTION_PREFIX = "motion."


@dataclass(frozen=True, slots=True)
class Limits:
    """What the arm may do, from the rig configuration's ``[limits]`` table.

    Attributes:
        max_tcp_speed_m_s: Fastest TCP speed of any motion, m/s.
        max_force_n: Largest normal force the arm may press or slide with, N.
        max_acceleration_m_s2: Largest TCP acceleration, m/s^2.
        workspace_min_m: Lowest corner (x, y, z) of the box the TCP stays in, base frame, m.
        workspace_max_m: Highest corner (x, y, z) of that box, m.
    """

    max_tcp_speed_m_s: float = 0.1
    max_force_n: float = 20.0
    max_acceleration_m_s2: float = 1.0
    workspace_min_m: tuple[float, float, float] = (-1.0, -1.0, 0.0)
    workspace_max_m: tuple[float, float, float] = (1.0, 1.0, 1.0)

    @classmethod
    def from_section(cls, section: Mapping[str, Any], where: str) -> Limits:
        """Read a ``[limits]`` table (missing keys keep their defaults).

        Raises:
            RigError: An unknown key, a value that is not a positive number, or a box
                whose corners are not 3 numbers with min < max.
        """
        known = {f.name for f in fields(cls)}
        values: dict[str, Any] = {}
        for key, value in section.items():
            if key not in known:
                msg = f"{where}: [limits] {key}: unknown; the limits are {', '.join(sorted(known))}"
                raise RigError(msg)
            if key.startswith("workspace"):
                values[key] = _corner(value, f"{where}: [limits] {key}")
            elif (
                isinstance(value, bool)
                or not isinstance(value, int | float)
                or not math.isfinite(value)  # nan passes every comparison: no limit at all
                or value <= 0
            ):
                msg = f"{where}: [limits] {key} = {value!r}: give a positive finite number"
                raise RigError(msg)
            else:
                values[key] = float(value)
        limits = cls(**values)
        if not all(
            lo < hi for lo, hi in zip(limits.workspace_min_m, limits.workspace_max_m, strict=False)
        ):
            msg = (
                f"{where}: [limits] workspace_min_m {list(limits.workspace_min_m)} must be "
                f"below workspace_max_m {list(limits.workspace_max_m)} on every axis"
            )
            raise RigError(msg)
        return limits

    def inside(self, position: Sequence[float] | NDArray[np.float64]) -> bool:
        """Return whether a TCP position (x, y, z) lies in the workspace box."""
        return all(
            lo <= float(v) <= hi
            for v, lo, hi in zip(position, self.workspace_min_m, self.workspace_max_m, strict=True)
        )

    def reach(
        self, position: Sequence[float] | NDArray[np.float64], direction: NDArray[np.float64]
    ) -> float:
        """Return how far the TCP may go from ``position`` along unit ``direction`` in the box, m.

        0 for a position outside the box; infinity for a direction of zeros.
        """
        if not self.inside(position):
            return 0.0
        out = math.inf
        for v, d, lo, hi in zip(
            position, direction, self.workspace_min_m, self.workspace_max_m, strict=True
        ):
            if d > 0:
                out = min(out, (hi - float(v)) / float(d))
            elif d < 0:
                out = min(out, (lo - float(v)) / float(d))
        return out


def _corner(value: object, what: str) -> tuple[float, float, float]:
    """Return a workspace corner (3 finite numbers).

    Raises:
        RigError: Not a list of 3 numbers.
    """
    if (
        not isinstance(value, list | tuple)
        or len(value) != 3  # noqa: PLR2004 (x, y, z)
        or not all(isinstance(v, int | float) and math.isfinite(v) for v in value)
    ):
        msg = f"{what} = {value!r}: give [x, y, z] in metres"
        raise RigError(msg)
    x, y, z = (float(v) for v in value)
    return x, y, z


@dataclass(frozen=True, slots=True)
class Motion:
    """How the rig moves the arm (rig options).

    Attributes:
        approach_max_m_s: Approach speed far from the object, m/s.
        approach_min_m_s: Approach speed at the object (and without proximity sensing), m/s.
        approach_gain_1_s: Approach speed per metre of proximity distance, 1/s.
        approach_limit_m: Longest approach before the rig gives up, m.
        press_m_s: Speed of the press ``movel``, m/s.
        retract_m: How far the retract moves back from the contact, m.
        retract_m_s: Speed of the retract and of ``movel`` between objects, m/s.
        acceleration_m_s2: TCP acceleration of every motion, m/s^2.
        contact_force_n: Total skin force that counts as the light contact, N.
        approach_blind_m: How far the approach may move toward the object beyond what the
            skin's force samples have seen, m: a skin whose samples come late (a delayed
            transport, a loaded recorder) pauses the approach until they catch up, so the
            light contact is never overrun by more than this.
    """

    approach_max_m_s: float = 0.02
    approach_min_m_s: float = 0.002
    approach_gain_1_s: float = 0.5
    approach_limit_m: float = 0.2
    press_m_s: float = 0.005
    retract_m: float = 0.02
    retract_m_s: float = 0.02
    acceleration_m_s2: float = 0.5
    contact_force_n: float = LIGHT_CONTACT_N
    approach_blind_m: float = 0.0005

    def describe(self) -> dict[str, str]:
        """Return the settings that shape the recorded signals, as ``motion.<name>`` text.

        ``approach_limit_m`` is left out: it bounds the approach (when the rig gives up), as
        the limits bound every motion; raising it changes no recording.
        """
        return {
            f"{MOTION_PREFIX}{item.name}": repr(getattr(self, item.name))
            for item in fields(self)
            if item.name != "approach_limit_m"
        }

    def approach_speed(self, distance_m: float | None) -> float:
        """Return the approach speed at a proximity distance (None: no proximity, slowest)."""
        if distance_m is None or not math.isfinite(distance_m):
            return self.approach_min_m_s
        speed = self.approach_gain_1_s * max(distance_m, 0.0)
        return min(max(speed, self.approach_min_m_s), self.approach_max_m_s)


def _refuse(  # noqa: PLR0917 (one message from its six parts)
    where: str, what: str, value: float, limit: str, bound: float, fix: str
) -> RigError:
    return RigError(f"{where}: {what} = {value:g} exceeds [limits] {limit} = {bound:g}; {fix}")


def check_motion(motion: Motion, limits: Limits, where: str) -> None:
    """Check the rig's own motion settings against the limits.

    Raises:
        RigError: A speed, acceleration or force (the light contact's) above its limit.
    """
    if motion.approach_min_m_s > motion.approach_max_m_s:
        # the slowest approach would be the fastest: an approach without proximity (or near
        # the object) would run faster than the one the margins are computed for
        msg = (
            f"{where}: approach_min_m_s = {motion.approach_min_m_s:g} exceeds approach_max_m_s "
            f"= {motion.approach_max_m_s:g}; give approach_min_m_s <= approach_max_m_s"
        )
        raise RigError(msg)
    speeds = {
        "approach_max_m_s": motion.approach_max_m_s,
        "press_m_s": motion.press_m_s,
        "retract_m_s": motion.retract_m_s,
    }
    for name, speed in speeds.items():
        if speed > limits.max_tcp_speed_m_s:
            fix = f"lower the rig option {name} or raise the limit"
            raise _refuse(where, name, speed, "max_tcp_speed_m_s", limits.max_tcp_speed_m_s, fix)
    if motion.contact_force_n > limits.max_force_n:
        # the light contact would be found only past the force limit: every approach stops
        fix = "lower the rig option contact_force_n or raise the limit"
        raise _refuse(
            where, "contact_force_n", motion.contact_force_n, "max_force_n", limits.max_force_n, fix
        )
    if motion.acceleration_m_s2 > limits.max_acceleration_m_s2:
        fix = "lower the rig option acceleration_m_s2 or raise the limit"
        raise _refuse(
            where,
            "acceleration_m_s2",
            motion.acceleration_m_s2,
            "max_acceleration_m_s2",
            limits.max_acceleration_m_s2,
            fix,
        )


def check_action(action: ActionSpec, limits: Limits, where: str) -> None:
    """Check an action's parameters against the limits (before anything moves).

    Raises:
        RigError: The action's speed or force is above its limit; names the file and value.
    """
    fix = f"change action {action.id} in the action catalog or raise the limit"
    if action.speed_m_s > limits.max_tcp_speed_m_s:
        raise _refuse(
            where,
            f"action {action.id} speed_m_s",
            action.speed_m_s,
            "max_tcp_speed_m_s",
            limits.max_tcp_speed_m_s,
            fix,
        )
    if action.force_n > limits.max_force_n:
        raise _refuse(
            where,
            f"action {action.id} force_n",
            action.force_n,
            "max_force_n",
            limits.max_force_n,
            fix,
        )


def execute_path(
    action: ActionSpec, start: NDArray[np.float64], acceleration_m_s2: float
) -> tuple[NDArray[np.float64], float]:
    """Return where an action's execute phase takes the TCP from ``start``, and how far, m.

    A press (or a static contact) moves ``depth_m`` along the tool's z axis and ends there; a
    slide moves along the tool's x axis at ``speed_m_s`` for ``duration_s``, then decelerates
    (at ``acceleration_m_s2``) beyond that.
    """
    if action.kind == "slide":
        length = action.speed_m_s * action.duration_s
        length += action.speed_m_s**2 / (2 * acceleration_m_s2)
        direction = tool_axis(start, 0)
    else:
        length, direction = action.depth_m, tool_axis(start, 2)
    end: NDArray[np.float64] = np.asarray(start[:3], dtype=np.float64) + direction * length
    return end, length


def path_problem(
    action: ActionSpec,
    start: NDArray[np.float64],
    limits: Limits,
    acceleration_m_s2: float,
) -> str:
    """Return why the action's execute phase from ``start`` would leave the workspace ('': fits).

    Used twice: from the object's pose before anything moves (the approach finds the contact
    at the pose or beyond it along the tool's z axis; a press that leaves the box from the
    pose leaves it from every contact), and from the contact before the execute phase is
    sent.
    """
    end, length = execute_path(action, start, acceleration_m_s2)
    if limits.inside(end):
        return ""
    what = "press" if action.kind != "slide" else "slide"
    return (
        f"the {what} of action {action.id} ({length:.3f} m from {_rounded(start[:3])}, to "
        f"{_rounded(end)}) would leave the [limits] workspace {list(limits.workspace_min_m)} .. "
        f"{list(limits.workspace_max_m)}; shorten the action (depth_m, or speed_m_s "
        "x duration_s) in the action catalog, or move the object or the workspace"
    )


def _rounded(position: Sequence[float] | NDArray[np.float64]) -> list[float]:
    return [round(float(v), 4) for v in position]


def check_pose(
    object_id: str, pose: Sequence[float] | NDArray[np.float64], limits: Limits, where: str
) -> None:
    """Check an object's pose (where the arm visits it) against the workspace box.

    Raises:
        RigError: The position is outside the box; names the object, the value and the box.
    """
    if not limits.inside(pose[:3]):
        msg = (
            f"{where}: [objects.{object_id}] pose position {[float(v) for v in pose[:3]]} lies "
            f"outside [limits] workspace_min_m {list(limits.workspace_min_m)} .. "
            f"workspace_max_m {list(limits.workspace_max_m)}; fix the pose or the workspace"
        )
        raise RigError(msg)


def tool_axis(pose: NDArray[np.float64], axis: int) -> NDArray[np.float64]:
    """Return a TCP axis (0: x, 1: y, 2: z) in the base frame from a pose's rotation vector."""
    # scipy is imported on first use: at module level it costs every command 0.5 s of start.
    from scipy.spatial.transform import Rotation  # noqa: PLC0415

    matrix = Rotation.from_rotvec(np.asarray(pose[3:6], dtype=np.float64)).as_matrix()
    column: NDArray[np.float64] = matrix[:, axis]
    return column
