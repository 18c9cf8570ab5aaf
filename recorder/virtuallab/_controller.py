"""The virtual lab's controller as its servers see it: the world's arm, programs and log.

The RTDE, URScript and dashboard servers talk to this object; the world (``_world``) runs the
programs on the kinematic arm. The controller's log (what a real controller shows on its
pendant: program errors, refusals, stops) is a ring of the last ``LOG_LINES`` lines, and every
line also goes to the ``atikt.virtuallab`` logger.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np

from recorder.virtuallab._world import HOME_POSE

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from recorder.virtuallab._urscript import Program
    from recorder.virtuallab._world import RobotState, VirtualWorld

_log = logging.getLogger("atikt.virtuallab")

__all__ = ["HOME_POSE", "VirtualController"]


class VirtualController:
    """The arm as the servers see it (thread-safe: the world locks)."""

    def __init__(self, world: VirtualWorld) -> None:
        """Wrap a world."""
        self.world = world

    def controller_ns(self) -> int:
        """Return the controller's time, ns."""
        return self.world.controller_ns()

    def state_at(self, controller_ns: int) -> RobotState:
        """Return the arm's state at a controller time (computing the cycles due first).

        The server waits at most 2 ms for a cycle another thread computes (then sends the
        state of the cycle before): its stream keeps its rate on a loaded machine.
        """
        self.world.advance_to(controller_ns, wait_s=0.002)
        return self.world.robot_at(controller_ns)

    def execute(self, program: Program) -> bool:
        """Run a checked program from the next cycle on (it replaces the running one).

        Returns:
            False when the controller refused it (a stop is active; logged).
        """
        return self.world.run(program)

    def park(self, pose: NDArray[np.float64]) -> None:
        """Put the arm at ``pose`` at once, at rest (tests; a real arm gets there by movel)."""
        self.world.place(np.asarray(pose, dtype=np.float64))

    def note(self, line: str) -> None:
        """Add a line to the controller's log."""
        self.world.note(line)
        _log.warning("%s", line)

    @property
    def log(self) -> tuple[str, ...]:
        """Return the controller's log lines kept."""
        return self.world.log
