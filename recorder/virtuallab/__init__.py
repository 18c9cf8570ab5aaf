"""The virtual lab: the physics simulator served over a real rig's protocols, on loopback.

``atikt-record serve-sim`` lets a lab rehearse its rig configuration and a whole session
without the robot, and lets the tests exercise the real client code: the arm's RTDE state
stream and URScript port, the skin's frames, ROS 2 topics. :class:`VirtualWorld` holds the
simulated execution being played; each server reads the world's state at its own rate.
"""

from recorder.virtuallab._skin_server import InjectedFaults, SkinFaults, SkinServer, serve_skin
from recorder.virtuallab._world import RobotState, VirtualWorld

__all__ = [
    "InjectedFaults",
    "RobotState",
    "SkinFaults",
    "SkinServer",
    "VirtualWorld",
    "serve_skin",
]
