"""Write a small ROS 1 lab session laid out as recorder/data/topic_map.example.toml expects.

Run by ``.ci/wheel_check.py`` with the Python of the virtualenv that holds the wheel (rosbags
and numpy are its dependencies)::

    python lab_bag.py session.bag

6 s of a UR10 (``/joint_states`` and ``/tool_pose`` at 125 Hz) with a 7-cell skin (one
``lab_skin/msg/CellData`` message per cell on ``/skin/cell_<n>`` at 250 Hz: force, acceleration,
temperature, proximity) and one action annotated on ``/annotations``: P1 on wood, trial 1.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

NS = 1_000_000_000
START = 1_700_000_000 * NS
SECONDS = 6
CELL = "lab_skin/msg/CellData"
CELL_MSG = "std_msgs/Header header\nfloat32 prox\nfloat32[3] force\nfloat32[3] acc\nfloat32 temp\n"
JOINTS = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
#: The annotated action's phases, s from the start (P1: a 3 s press).
PHASES = (("approach", 0.5), ("contact", 1.0), ("execute", 1.5), ("retract", 4.5), ("end", 5.5))

Message = tuple[int, str, str, Any]


def _header(types: dict[str, Any], stamp: int) -> Any:  # noqa: ANN401 (a rosbags message)
    """Return a ROS 1 header stamped ``stamp`` (ns)."""
    time = types["builtin_interfaces/msg/Time"](sec=stamp // NS, nanosec=stamp % NS)
    return types["std_msgs/msg/Header"](seq=0, stamp=time, frame_id="lab")


def _skin(types: dict[str, Any], rng: np.random.Generator) -> list[Message]:
    """Return the skin's messages: 7 cells at 250 Hz."""
    messages = []
    for k in range(SECONDS * 250):
        stamp = START + k * 4_000_000
        for cell in range(7):
            message = types[CELL](
                header=_header(types, stamp),
                prox=0.01,
                force=rng.normal(1.0, 0.1, 3).astype(np.float32),
                acc=rng.normal(0.0, 0.1, 3).astype(np.float32),
                temp=30.0,
            )
            messages.append((stamp + 300_000, f"/skin/cell_{cell}", CELL, message))
    return messages


def _robot(types: dict[str, Any], rng: np.random.Generator) -> list[Message]:
    """Return the arm's joint states and tool poses at 125 Hz."""
    messages = []
    for k in range(SECONDS * 125):
        stamp = START + k * 8_000_000
        joints = types["sensor_msgs/msg/JointState"](
            header=_header(types, stamp),
            name=list(JOINTS),
            position=rng.normal(0.0, 1.0, 6),
            velocity=np.zeros(6),
            effort=np.zeros(6),
        )
        messages.append((stamp + 200_000, "/joint_states", "sensor_msgs/msg/JointState", joints))
        pose = types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=-0.7, y=-0.2, z=0.15),
            orientation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=1.0, z=0.0, w=0.0),
        )
        tool = types["geometry_msgs/msg/PoseStamped"](header=_header(types, stamp), pose=pose)
        messages.append((stamp + 200_000, "/tool_pose", "geometry_msgs/msg/PoseStamped", tool))
    return messages


def _annotations(types: dict[str, Any]) -> list[Message]:
    """Return the phase annotations of the one action."""
    messages = []
    for phase, seconds in PHASES:
        text = json.dumps({"object": "wood", "action": "P1", "trial": 1, "phase": phase})
        message = types["std_msgs/msg/String"](data=text)
        messages.append(
            (START + round(seconds * NS), "/annotations", "std_msgs/msg/String", message)
        )
    return messages


def write(path: Path) -> None:
    """Write the session bag to ``path``."""
    store = get_typestore(Stores.ROS1_NOETIC)
    store.register(get_types_from_msg(CELL_MSG, CELL))
    rng = np.random.default_rng(0)
    messages = _skin(store.types, rng) + _robot(store.types, rng) + _annotations(store.types)
    messages.sort(key=lambda message: message[0])
    with Writer(path) as writer:
        connections: dict[str, Any] = {}
        for receive, topic, msgtype, message in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], receive, store.serialize_ros1(message, msgtype))


if __name__ == "__main__":
    write(Path(sys.argv[1]))
