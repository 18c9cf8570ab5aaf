"""A scripted lab session published over DDS (loopback) and written into a ROS 2 bag.

The same rosbags messages give the DDS samples (their CDR bytes) and the bag's records, so a
``listen`` of the published session and an ``import-bag`` of the bag see the same data.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from labbags import write_bag

from recorder.live.dds import register_atikt_types

if TYPE_CHECKING:
    from pathlib import Path

    from recorder.live.dds import DdsDomain

NS = 1_000_000_000
CELL = "atikt_msgs/msg/SkinCell"
JOINTS = tuple(f"joint_{i}" for i in range(6))
#: (object, execute start s, end s) after the session's start.
WINDOWS = (("wood", 0.20, 0.50), ("foam", 0.65, 0.95), ("wood", 1.10, 1.40))
LENGTH_S = 1.6
JOINT_PERIOD_NS = 4_000_000
CELL_PERIOD_NS = 5_000_000
#: Joint states not published (index in the session), all inside the second window.
DROPPED_JOINTS = frozenset({180, 181, 190})

TOPIC_MAP = """
[time]
stamps = "header"
max_delay_s = 0.2

[joint_states]
topic = "/joint_states"

[skin]
cells = [0, 1]

[skin.force]
topic = "/skin/cell_{cell}"
field = "force"

[skin.acceleration]
topic = "/skin/cell_{cell}"
field = "acc"
scale = 9.80665

[skin.temperature]
topic = "/skin/cell_{cell}"
field = "temp"

[skin.proximity]
topic = "/skin/cell_{cell}"
field = "prox"

[windows]
source = "topic"
topic = "/annotations"

[actions.tap]
kind = "static"
duration_s = 0.25

[objects.wood]
name = "Wood"
[objects.foam]
name = "Foam"
"""


@dataclass
class Script:
    """The session's messages: (offset ns from the start, topic, type, message)."""

    store: Any
    messages: list[tuple[int, str, str, Any]] = field(default_factory=list)

    def stamped(self, start_ns: int) -> list[tuple[int, str, str, bytes, Any]]:
        """Return (stamp, topic, type, CDR bytes, message) with stamps from ``start_ns``."""
        out = []
        for offset, topic, msgtype, make in self.messages:
            message = make(start_ns + offset)
            out.append(
                (
                    start_ns + offset,
                    topic,
                    msgtype,
                    bytes(self.store.serialize_cdr(message, msgtype)),
                    message,
                )
            )
        return out


def script(store: Any, seed: int = 11) -> Script:
    """Return the scripted session (JointState 250 Hz, 2 skin cells 200 Hz, annotations)."""
    register_atikt_types(store)
    rng = np.random.default_rng(seed)
    types = store.types
    out = Script(store)

    def header(stamp: int) -> Any:
        time_msg = types["builtin_interfaces/msg/Time"](sec=stamp // NS, nanosec=stamp % NS)
        return types["std_msgs/msg/Header"](stamp=time_msg, frame_id="lab")

    for k, offset in enumerate(range(0, round(LENGTH_S * NS), JOINT_PERIOD_NS)):
        if k in DROPPED_JOINTS:
            continue
        q, qd, effort = rng.normal(0, 1, 6), rng.normal(0, 0.1, 6), rng.normal(0, 2, 6)
        out.messages.append(
            (
                offset,
                "/joint_states",
                "sensor_msgs/msg/JointState",
                lambda s, q=q, qd=qd, e=effort: types["sensor_msgs/msg/JointState"](
                    header=header(s), name=list(JOINTS), position=q, velocity=qd, effort=e
                ),
            )
        )
    for offset in range(0, round(LENGTH_S * NS), CELL_PERIOD_NS):
        for cell in (0, 1):
            force = rng.normal(1.0, 0.1, 3).astype(np.float32)
            acc = rng.normal(0, 0.2, 3).astype(np.float32)
            temp, prox = float(rng.normal(30, 0.1)), float(rng.uniform(0, 0.05))
            out.messages.append(
                (
                    offset + 300_000 * cell,
                    f"/skin/cell_{cell}",
                    CELL,
                    lambda s, f=force, a=acc, t=temp, p=prox: types[CELL](
                        header=header(s), force=f, acc=a, temp=t, prox=p, seq=0
                    ),
                )
            )
    for obj, start, end in WINDOWS:
        for phase, at in (("execute", start), ("end", end)):
            stamp_offset = round(at * NS)

            def annotation(s: int, obj: str = obj, phase: str = phase) -> Any:
                text = {"object": obj, "action": "tap", "phase": phase, "stamp_ns": s}
                return types["std_msgs/msg/String"](data=json.dumps(text))

            out.messages.append((stamp_offset, "/annotations", "std_msgs/msg/String", annotation))
    out.messages.sort(key=lambda m: m[0])
    return out


def publish(
    domain: DdsDomain, session: Script, *, match_s: float = 5.0
) -> list[tuple[int, str, str, bytes, Any]]:
    """Publish the session in real time once every writer has a reader; return what was sent."""
    writers = {}
    for _, topic, msgtype, _ in session.messages:
        if topic not in writers:
            writers[topic] = domain.writer(topic, msgtype)
    deadline = time.monotonic() + match_s
    while any(w.matched() == 0 for w in writers.values()) and time.monotonic() < deadline:
        time.sleep(0.01)
    messages = session.stamped(time.time_ns() + NS // 10)
    for stamp, topic, _, raw, _ in messages:
        delay = (stamp - time.time_ns()) / NS
        if delay > 0:
            time.sleep(delay)
        writers[topic].write(raw)
    return messages


def bag(path: Path, messages: list[tuple[int, str, str, bytes, Any]], store: Any) -> Path:
    """Write the messages into a ROS 2 MCAP bag, received 1 ms after their stamps."""
    records = [
        (stamp + 1_000_000, topic, msgtype, message)
        for stamp, topic, msgtype, _, message in messages
    ]
    return write_bag(path, "mcap", records, store)
