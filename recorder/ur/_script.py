"""URScript programs: how the UR driver carries out the runner's commands.

The arm moves by URScript programs sent to the controller's primary interface (port 30001):
each program replaces the one running, so the rig steers an action phase by phase. As in the
thesis, the approach is ``speedl`` towards the object with a speed from the skin's proximity,
stopped with ``stopl`` at the light contact; a press is a ``movel`` to the depth (the rig waits
until RTDE's ``actual_TCP_pose`` is within 1 mm of the target, then holds); a slide is
``force_mode`` at the action's normal force with ``speedl`` along the tool's x axis, then
``end_force_mode``; the retract is a ``movel`` back along the tool's z axis.

Every program starts with ``textmsg("atikt: object=<id> action=<id> trial=<n> phase=<phase>")``:
on a real controller it only goes to its log; the virtual lab reads it to know what to play.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy as np
    from numpy.typing import NDArray

#: URScript functions the programs use (the virtual lab accepts these).
FUNCTIONS = frozenset(
    {
        "textmsg",
        "movel",
        "speedl",
        "stopl",
        "force_mode",
        "end_force_mode",
        "get_actual_tcp_pose",
        "sleep",
    }
)


def _vector(values: Sequence[float] | NDArray[np.float64]) -> str:
    return "[" + ", ".join(f"{float(v):.6f}" for v in values) + "]"


def _pose(values: Sequence[float] | NDArray[np.float64]) -> str:
    return "p" + _vector(values)


@dataclass(frozen=True, slots=True)
class Announcement:
    """What an action's programs announce in their first line.

    Attributes:
        object_id: The object.
        action_id: The action.
        trial: The trial.
    """

    object_id: str
    action_id: str
    trial: int

    def line(self, phase: str) -> str:
        """Return the ``textmsg`` line of a program of ``phase``."""
        return (
            f'textmsg("atikt: object={self.object_id} action={self.action_id} '
            f'trial={self.trial} phase={phase}")'
        )


def program(name: str, lines: Sequence[str]) -> str:
    """Return a URScript program ``def name(): ... end`` (sent whole, it replaces the running)."""
    body = "".join(f"  {line}\n" for line in lines)
    return f"def {name}():\n{body}end\n"


def speed_program(
    said: Announcement | None,
    phase: str,
    velocity: NDArray[np.float64],
    acceleration: float,
    seconds: float,
) -> str:
    """Return a ``speedl`` at ``velocity`` (vx, vy, vz, wx, wy, wz) for ``seconds`` at most."""
    head = [said.line(phase)] if said is not None else []
    line = f"speedl({_vector(velocity)}, {acceleration:g}, {seconds:.3f})"
    return program("atikt_approach" if phase == "approach" else "atikt_speed", [*head, line])


def stop_program(said: Announcement | None, phase: str, acceleration: float) -> str:
    """Return a program that stops the arm (``stopl``)."""
    head = [said.line(phase)] if said is not None else []
    return program("atikt_stop", [*head, f"stopl({acceleration:g})"])


def move_program(  # noqa: PLR0917 (the movel's own parameters, and its way back)
    said: Announcement | None,
    phase: str,
    target: NDArray[np.float64],
    speed: float,
    acceleration: float,
    back: Sequence[float] = (),
    lease_s: float = 0.0,
) -> str:
    """Return a ``movel`` to ``target`` (a pose: x, y, z, rx, ry, rz).

    With ``back`` and ``lease_s``: then ``sleep(lease_s)`` and a ``movel`` to ``back``, so the
    arm leaves a press by itself when no program replaced this one in time (a recorder that
    died mid-press); the recorder's next program replaces it before that.
    """
    head = [said.line(phase)] if said is not None else []
    lines = [*head, f"movel({_pose(target)}, a={acceleration:g}, v={speed:g})"]
    if back and lease_s > 0:
        lines += [f"sleep({lease_s:.3f})", f"movel({_pose(back)}, a={acceleration:g}, v={speed:g})"]
    return program("atikt_move", lines)


def slide_program(  # noqa: PLR0917 (the force mode's own parameters)
    said: Announcement,
    phase: str,
    force_n: float,
    velocity: NDArray[np.float64],
    seconds: float,
    acceleration: float,
) -> str:
    """Return the slide: ``force_mode`` at ``force_n`` along the tool's z, ``speedl`` along."""
    wrench = [0.0, 0.0, force_n, 0.0, 0.0, 0.0]
    # Compliant along the tool's z axis only; the other axes follow speedl. Limits of the
    # compliant axis: the largest speed it may take to keep the force (m/s, rad/s).
    limits = [0.1, 0.1, 0.01, 0.3, 0.3, 0.3]
    return program(
        "atikt_slide",
        [
            said.line(phase),
            (
                f"force_mode(get_actual_tcp_pose(), [0, 0, 1, 0, 0, 0], {_vector(wrench)}, 2, "
                f"{_vector(limits)})"
            ),
            f"speedl({_vector(velocity)}, {acceleration:g}, {seconds:g})",
            "end_force_mode()",
            f"stopl({acceleration:g})",
        ],
    )
