"""A Universal Robots arm over its real interfaces: RTDE state, URScript motion, a live skin.

The UR driver (:class:`URArm`) reads every RTDE data package (port 30004; 125 Hz on CB3,
500 Hz on e-Series) and moves the arm with URScript programs (port 30001); the action runner
(:class:`recorder.runner.ArmRig`) drives it with the skin the rig configuration's ``[skin]``
table describes; limits (``[limits]``) are checked before anything moves and on every sample.
"""

from recorder._rigconfig import RigPlugin
from recorder._sim.ur10 import JOINT_NAMES
from recorder.runner import Limits, Motion
from recorder.ur._arm import RTDE_VARIABLES, Connection, URArm
from recorder.ur._rig import UROptions, URRig, build_ur_rig
from recorder.ur._rtde import Recipe, RtdeClient, RtdeError, TextMessage
from recorder.ur._script import Announcement

#: The UR rig as a plug-in: exclusive hardware (one action at a time, in the main process).
PLUGIN = RigPlugin(
    build=build_ur_rig,
    exclusive=True,
    description="a Universal Robots arm over RTDE and URScript, with a live skin",
)

__all__ = [
    "JOINT_NAMES",
    "PLUGIN",
    "RTDE_VARIABLES",
    "Announcement",
    "Connection",
    "Limits",
    "Motion",
    "Recipe",
    "RtdeClient",
    "RtdeError",
    "TextMessage",
    "URArm",
    "UROptions",
    "URRig",
    "build_ur_rig",
]
