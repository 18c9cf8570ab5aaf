"""The virtual lab's controller: the world's arm plus what URScript told it outside actions.

The world plays whole simulated executions; between them, a program's ``movel`` (visiting an
object) parks the arm at the target, so the state served over RTDE says the arm arrived. An
action is played from wherever the arm is (parked, or where the last action left it): its TCP
positions are shifted by that pose minus the simulator's start, so the arm never jumps.
Every server reads the arm through this object; it also keeps the controller's log (what a
real controller shows on its pendant: program errors, stops).
"""

from __future__ import annotations

import dataclasses
import logging
import threading
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from recorder.virtuallab._world import RobotState, VirtualWorld

_log = logging.getLogger("atikt.virtuallab")
#: Where the virtual arm waits before anything moved it: above the simulator's workspace, the
#: tool pointing down (x, y, z in m, rotation vector in rad).
HOME_POSE = (-0.6, -0.2, 0.2, 0.0, np.pi, 0.0)


class VirtualController:
    """The arm as the servers see it (thread-safe)."""

    def __init__(self, world: VirtualWorld) -> None:
        """Wrap a world."""
        self.world = world
        self._lock = threading.Lock()
        self._parked: NDArray[np.float64] | None = np.array(HOME_POSE)
        self._shift = np.zeros(3)
        self._log: list[str] = []

    def controller_ns(self) -> int:
        """Return the controller's time, ns."""
        return self.world.controller_ns()

    def state_at(self, controller_ns: int) -> RobotState:
        """Return the arm's state (parked at a ``movel`` target when one came last)."""
        state = self.world.robot_at(controller_ns)
        with self._lock:
            parked, shift = self._parked, self._shift
        if parked is None:
            pose = state.tcp_pose.copy()
            pose[:3] += shift
            return dataclasses.replace(state, tcp_pose=pose)
        return dataclasses.replace(state, tcp_pose=parked.copy(), qd=np.zeros_like(state.qd))

    def park(self, pose: NDArray[np.float64]) -> None:
        """Put the arm at ``pose`` (a ``movel`` outside an action; it arrives at once)."""
        with self._lock:
            self._parked = np.asarray(pose, dtype=np.float64)

    def start_action(self, object_id: str, action_id: str, trial: int) -> None:
        """Start playing an action (the arm leaves its parked pose).

        Raises:
            RigError: The world refuses (unknown object or action, stopped, busy).
        """
        here = self.state_at(self.world.controller_ns()).tcp_pose
        self.world.start_action(object_id, action_id, trial)
        start = self.world.robot_at(self.world.controller_ns()).tcp_pose
        with self._lock:
            self._parked = None
            self._shift = here[:3] - start[:3]

    def note(self, line: str) -> None:
        """Add a line to the controller's log."""
        with self._lock:
            self._log.append(line)
        _log.warning("%s", line)

    @property
    def log(self) -> tuple[str, ...]:
        """Return the controller's log lines so far."""
        with self._lock:
            return tuple(self._log)
