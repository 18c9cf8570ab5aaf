"""The small interface an arm implements for the action runner, and what it reports.

An arm driver moves the arm and streams its state; it decides nothing. The runner
(:class:`recorder.runner.ArmRig`) owns an action's phases, the limits, silence detection and
the stop, so a new arm (a Franka through its own package, a simulated UR10, a UR over RTDE) is
a driver and an entry point with no phase logic of its own.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, Self, runtime_checkable

if TYPE_CHECKING:
    from collections.abc import Mapping
    from types import TracebackType

    import numpy as np
    from numpy.typing import NDArray

    from schemas import SourceStats


@dataclass(frozen=True, slots=True)
class ArmSample:
    """One state sample of the arm, as it arrived.

    Attributes:
        stamp_ns: The arm's own stamp on the recorder's clock (controller time + offset), ns.
        receive_ns: Receive time on the recorder's clock, ns.
        q: Joint positions, rad, shape (joints,).
        qd: Joint velocities, rad/s, shape (joints,).
        effort: Joint torques, N m, shape (joints,).
        tcp_pose: TCP pose (x, y, z, rx, ry, rz): m and a rotation vector, base frame.
        tcp_force: Force and torque at the TCP (fx, fy, fz, tx, ty, tz), N and N m.
        stopped: Empty while the arm may move; else why the controller stopped it, one line
            (e.g. ``protective stop (RTDE safety_status 3)``).
        busy: Empty when the controller runs no program of another's; else what it runs,
            one line (``a program is playing (RTDE runtime_state 2)``). Read only before an
            action, when nothing of the runner's runs: a program sent then would replace it.
        replaced: Empty while no program of another started since :meth:`ArmDriver.begin`;
            else which one, one line (it replaced the runner's: the action cannot go on).
    """

    stamp_ns: int
    receive_ns: int
    q: NDArray[np.float64]
    qd: NDArray[np.float64]
    effort: NDArray[np.float64]
    tcp_pose: NDArray[np.float64]
    tcp_force: NDArray[np.float64]
    stopped: str = ""
    busy: str = ""
    replaced: str = ""


@dataclass(frozen=True, slots=True)
class Context:
    """What a motion command belongs to: the action (None between actions) and its phase.

    A driver may show it (a UR writes it into its log with ``textmsg``); it never decides on it.

    Attributes:
        object_id: The object.
        action_id: The action.
        trial: The trial.
        phase: The phase the command starts or serves (approach, contact, execute, ...).
        lease_s: For a move that leaves the arm pressed into an object (a press): how long
            it may hold the arm there, s; a driver that can (a UR: ``sleep`` and a second
            ``movel`` in the same program) then moves it back to :attr:`back` by itself, so
            a recorder killed mid-press (SIGKILL, a power cut) does not leave the arm pressed
            until someone comes (0: no lease). The runner's next command replaces it first.
        back: Where such a move returns the arm (x, y, z, rx, ry, rz; empty: nowhere).
    """

    object_id: str
    action_id: str
    trial: int
    phase: str
    lease_s: float = 0.0
    back: tuple[float, ...] = ()


class ArmDriver(Protocol):
    """An arm the runner can drive: a state stream, move, speed, force mode, stop.

    Every command replaces the one running (as a UR's programs do); none blocks until the
    motion ends: the runner watches the state stream. ``stop`` must be safe to call at any
    time, also twice, also after the connection was lost (then it does what it can), and
    also from another thread while another call hangs: the runner's watchdog sends the stop
    when a call holds its loop longer than a source may be silent (``silence_s``).
    """

    def __enter__(self) -> Self:
        """Connect; raise :class:`recorder.RigError` in one line when it cannot."""
        ...

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Disconnect, whatever happened."""
        ...

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Return the joint names in the order of the state's arrays."""
        ...

    @property
    def period_ns(self) -> int:
        """Return the time between two state samples (one controller cycle), ns."""
        ...

    def describe(self) -> Mapping[str, str]:
        """Return the driver's configuration (what identifies the rig; nothing learned)."""
        ...

    def facts(self) -> Mapping[str, str]:
        """Return what was learned on connecting (e.g. the controller's version)."""
        ...

    def begin(self) -> None:
        """Start a new action: forget what queued before, start counting afresh."""
        ...

    def poll(self, wait_s: float) -> list[ArmSample]:
        """Return the new state samples in order, waiting up to ``wait_s`` for the first.

        Raises:
            recorder.live.SourceLostError: The state stream was lost.
        """
        ...

    def speed(
        self, velocity: NDArray[np.float64], acceleration: float, duration_s: float, at: Context
    ) -> None:
        """Move the TCP at ``velocity`` (vx, vy, vz, wx, wy, wz; m/s, rad/s) for a while."""
        ...

    def move(
        self, pose: NDArray[np.float64], speed: float, acceleration: float, at: Context | None
    ) -> None:
        """Move the TCP in a line to ``pose`` (x, y, z, rx, ry, rz)."""
        ...

    def force_slide(
        self,
        force_n: float,
        velocity: NDArray[np.float64],
        duration_s: float,
        acceleration: float,
        at: Context,
    ) -> None:
        """Press along the tool's z axis with ``force_n`` while moving at ``velocity``."""
        ...

    def announce(self, at: Context) -> None:
        """Mark a phase without motion (a UR writes it into its log; a lab reads it)."""
        ...

    def stop(self, acceleration: float, at: Context | None) -> str:
        """Stop the arm now, decelerating at ``acceleration`` (m/s^2).

        A driver tries what it can (a new connection for a lost one, another way in) before
        it raises; the runner then says in its line that the stop did not reach the arm.

        Returns:
            How the arm was stopped when not the usual way, one clause for the action's
            line (empty: the usual way).

        Raises:
            SourceLostError: The stop could not be sent.
        """
        ...

    def stats(self) -> list[SourceStats]:
        """Return the accounting of the state stream since :meth:`begin`."""
        ...


@runtime_checkable
class StopsOtherwise(Protocol):
    """An arm driver with a second way to stop the arm, sharing nothing with its commands.

    The runner uses it when the arm did not come to rest after :meth:`ArmDriver.stop`: a
    command link that takes the bytes but delivers none (a half-dead connection), a controller
    that ignores the program. A UR's is its dashboard server (``stop`` on port 29999).
    """

    def stop_otherwise(self) -> str:
        """Stop the arm the second way; return how, one clause for the action's line.

        Raises:
            recorder.live.SourceLostError: It could not (the message says why).
        """
        ...
