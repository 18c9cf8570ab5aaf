"""The virtual lab: the physics simulator served over a real rig's protocols, on loopback.

``atikt-record serve-sim`` lets a lab rehearse its rig configuration and a whole session
without the robot, and lets the tests exercise the real client code: the arm's RTDE state
stream and URScript port, the skin's frames, ROS 2 topics. :class:`VirtualWorld` is a
virtual UR10 controller that executes the URScript it receives, cycle by cycle, over the
simulator's objects; each server reads the world's state at its own rate, and
:meth:`VirtualWorld.events` says what happened (programs, faults, stops) on both clocks.
"""

from recorder.virtuallab._events import Event
from recorder.virtuallab._skin_server import InjectedFaults, SkinFaults, SkinServer, serve_skin
from recorder.virtuallab._stepped import PLUGIN as SIM_UR10
from recorder.virtuallab._stepped import SimUR10Rig, SteppedLab
from recorder.virtuallab._world import RobotState, VirtualWorld

__all__ = [
    "SIM_UR10",
    "Event",
    "InjectedFaults",
    "RobotState",
    "SimUR10Rig",
    "SkinFaults",
    "SkinServer",
    "SteppedLab",
    "VirtualWorld",
    "serve_skin",
]
