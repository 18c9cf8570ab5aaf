"""Lab-shaped bags for import tests: a fingertip on a 7-joint arm and a fixed probe.

Bags are written with rosbags' own writers (ROS 1 and ROS 2), with the labs' own message
types, rates and batching; every value is seeded.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Ros2Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

if TYPE_CHECKING:
    from pathlib import Path

NS = 1_000_000_000
START = 1_700_000_000 * NS
#: (type name, definition) of the labs' own messages.
TYPES = {
    "tip_msgs/msg/Pressure": "std_msgs/Header header\nfloat32 pressure\n",
    "tip_msgs/msg/Vibration": "std_msgs/Header header\nfloat32[22] samples\n",
    "probe_msgs/msg/Probe": "std_msgs/Header header\nfloat32 force\nfloat32[2] temperatures\n",
}
Message = tuple[int, str, str, Any]


def typestore(*, ros1: bool) -> Any:
    """Return a typestore with the labs' types."""
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    for name, text in TYPES.items():
        store.register(get_types_from_msg(text, name))
    return store


def header(store: Any, stamp: int, *, ros1: bool) -> Any:
    """Return a std_msgs/Header."""
    time = store.types["builtin_interfaces/msg/Time"](sec=stamp // NS, nanosec=stamp % NS)
    extra = {"seq": 0} if ros1 else {}
    return store.types["std_msgs/msg/Header"](stamp=time, frame_id="lab", **extra)


def write_bag(path: Path, storage: str, messages: list[Message], store: Any) -> Path:
    """Write (receive, topic, type, message) tuples: ``ros1``, ``sqlite3`` or ``mcap``."""
    ros1 = storage == "ros1"
    if ros1:
        writer: Any = Ros1Writer(path)
    else:
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        writer = Ros2Writer(path, version=9, storage_plugin=plugin)
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    with writer:
        connections: dict[str, Any] = {}
        for receive, topic, msgtype, message in sorted(messages, key=lambda m: m[0]):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], receive, serialize(message, msgtype))
    return path


@dataclass(frozen=True)
class Session:
    """Objects x actions x trials, one window after the other."""

    objects: tuple[str, ...]
    actions: tuple[str, ...]
    trials: int
    execute_s: float
    gap_s: float

    def windows(self) -> list[tuple[str, str, int, int, int]]:
        """Return (object, action, trial, execute start ns, end ns) in time order."""
        out = []
        t = START + NS // 2
        step = round((self.execute_s + self.gap_s) * NS)
        for trial in range(1, self.trials + 1):
            for obj in self.objects:
                for action in self.actions:
                    out.append((obj, action, trial, t, t + round(self.execute_s * NS) + NS // 20))
                    t += step
        return out

    @property
    def stop_ns(self) -> int:
        """Return the end of the session."""
        return self.windows()[-1][4] + NS // 2


# ------------------------------------------------------------------------- fingertip, 7 joints

TIP_OBJECTS = ("felt", "sandpaper", "foam", "cork")
TIP_ACTIONS = ("SL-slow", "SL-fast")
PANDA = tuple(f"panda_joint{i}" for i in range(1, 8))
TIP_SESSION = Session(TIP_OBJECTS, TIP_ACTIONS, trials=4, execute_s=1.0, gap_s=0.3)


def _texture(obj: str, action: str) -> tuple[float, float]:
    """Return (vibration frequency Hz, amplitude) of an object under an action."""
    index = TIP_OBJECTS.index(obj)
    speed = 1.0 if action == "SL-slow" else 3.0
    return (40.0 + 60.0 * index) * speed, 0.2 + 0.4 * index


def fingertip_messages(*, ros1: bool, seed: int = 3) -> tuple[list[Message], Any]:
    """Return a fingertip session: scalar pressure 250 Hz, vibration 22 x 100 Hz, temperature
    10 Hz (sensor_msgs/Temperature), a 7-joint arm at 100 Hz, no tool pose."""
    rng = np.random.default_rng(seed)
    store = typestore(ros1=ros1)
    types = store.types
    stop = TIP_SESSION.stop_ns
    windows = TIP_SESSION.windows()
    starts = np.array([w[3] for w in windows])

    def current(stamp: int) -> tuple[str, str] | None:
        i = int(np.searchsorted(starts, stamp, side="right")) - 1
        return (windows[i][0], windows[i][1]) if i >= 0 and stamp < windows[i][4] else None

    out: list[Message] = []
    for stamp in range(START, stop, 4_000_000):
        touch = current(stamp)
        kpa = (50.0 + 5 * TIP_OBJECTS.index(touch[0]) if touch else 0.0) + rng.normal(0, 0.5)
        msg = types["tip_msgs/msg/Pressure"](header=header(store, stamp, ros1=ros1), pressure=kpa)
        out.append((stamp + 700_000, "/tip/pressure", "tip_msgs/msg/Pressure", msg))
    for stamp in range(START, stop, 10_000_000):
        t = (stamp + (np.arange(22) * 10_000_000) // 22) / NS
        touch = current(stamp)
        freq, amp = _texture(*touch) if touch else (0.0, 0.0)
        samples = (amp * np.sin(2 * np.pi * freq * t) + rng.normal(0, 0.02, 22)).astype(np.float32)
        msg = types["tip_msgs/msg/Vibration"](
            header=header(store, stamp, ros1=ros1), samples=samples
        )
        out.append((stamp + 10_500_000, "/tip/vibration", "tip_msgs/msg/Vibration", msg))
    temperature = "sensor_msgs/msg/Temperature"
    for stamp in range(START, stop, 100_000_000):
        touch = current(stamp)
        value = 31.0 - (0.3 * TIP_OBJECTS.index(touch[0]) if touch else 0.0) + rng.normal(0, 0.01)
        msg = types[temperature](
            header=header(store, stamp, ros1=ros1), temperature=value, variance=0.0
        )
        out.append((stamp + 1_000_000, "/tip/temperature", temperature, msg))
    joint_state = "sensor_msgs/msg/JointState"
    for stamp in range(START, stop, 10_000_000):
        msg = types[joint_state](
            header=header(store, stamp, ros1=ros1),
            name=list(PANDA),
            position=rng.normal(0, 1, 7),
            velocity=rng.normal(0, 0.1, 7),
            effort=rng.normal(0, 3, 7),
        )
        out.append((stamp + 300_000, "/franka/joint_states", joint_state, msg))
    return out, store


FINGERTIP_MAP = """
[joint_states]
topic = "/franka/joint_states"

[skin]
cells = [0]

[skin.force]
topic = "/tip/pressure"
field = "pressure"
scale = 0.01                # kPa over 1 cm^2 -> N

[skin.acceleration]
topic = "/tip/vibration"
field = "samples"
samples_per_message = 22
rate_hz = 2200
scale = 9.80665             # g -> m/s^2

[skin.temperature]
topic = "/tip/temperature"
field = "temperature"

[windows]
source = "csv"
csv = "windows.csv"
time_unit = "ns"

[actions.SL-slow]
kind = "slide"
duration_s = 1.0
speed_m_s = 0.01
force_n = 0.5

[actions.SL-fast]
kind = "slide"
duration_s = 1.0
speed_m_s = 0.03
force_n = 0.5
grit = 120                  # a lab's own parameter

[objects.felt]
name = "Felt pad"
novel = true

[objects.sandpaper]
name = "Sandpaper P120"
description = "glued on a wood block"
novel = true

[objects.foam]
name = "PU foam"

[objects.cork]
name = "Cork board"
"""


def fingertip_windows_csv() -> str:
    """Return the fingertip session's windows as CSV in ns (integers)."""
    rows = ["start,stop,object,action,trial"]
    rows += [f"{s},{e},{o},{a},{t}" for o, a, t, s, e in TIP_SESSION.windows()]
    return "\n".join(rows) + "\n"


# -------------------------------------------------------------------------------- fixed probe

PROBE_OBJECTS = ("wood", "aluminium", "cold_wood", "foam")
PROBE_SESSION = Session(PROBE_OBJECTS, ("hold5",), trials=3, execute_s=5.0, gap_s=0.4)
_DROP = {"wood": 0.5, "aluminium": 2.4, "cold_wood": 2.6, "foam": 0.2}


def probe_messages(
    *, ros1: bool, seed: int = 5, session: Session = PROBE_SESSION
) -> tuple[list[Message], Any]:
    """Return a fixed probe session at 100 Hz: one scalar force, two temperatures, JSON
    annotations on /annotations (execute, end), no arm, no pose."""
    rng = np.random.default_rng(seed)
    store = typestore(ros1=ros1)
    types = store.types
    windows = session.windows()
    starts = np.array([w[3] for w in windows])
    out: list[Message] = []
    for stamp in range(START, session.stop_ns, 10_000_000):
        i = int(np.searchsorted(starts, stamp, side="right")) - 1
        inside = i >= 0 and stamp < windows[i][4]
        elapsed = (stamp - windows[i][3]) / NS if inside else 0.0
        drop = _DROP[windows[i][0]] * (1 - np.exp(-elapsed / 1.5)) if inside else 0.0
        force = (4.5 if inside else 0.0) + rng.normal(0, 0.02)
        temps = np.array([29.5 - drop, 22.0 - 0.1 * drop], dtype=np.float32) + rng.normal(
            0, 0.01, 2
        )
        msg = types["probe_msgs/msg/Probe"](
            header=header(store, stamp, ros1=ros1),
            force=force,
            temperatures=temps.astype(np.float32),
        )
        out.append((stamp + 2_000_000, "/probe", "probe_msgs/msg/Probe", msg))
    for obj, action, trial, start, end in windows:
        for phase, stamp in (("execute", start), ("end", end)):
            text = {
                "object": obj,
                "action": action,
                "trial": trial,
                "phase": phase,
                "stamp_ns": stamp,
            }
            msg = types["std_msgs/msg/String"](data=json.dumps(text))
            out.append((stamp + 5_000_000, "/annotations", "std_msgs/msg/String", msg))
    return out, store


PROBE_MAP = """
[time]
stamps = "header"

[skin]
cells = [0]

[skin.force]
topic = "/probe"
field = "force"

[skin.temperature]
topic = "/probe"
field = "temperatures"      # heated and passive thermistor

[windows]
source = "topic"
topic = "/annotations"

[actions.hold5]
kind = "static"
duration_s = 5.0
description = "hold 5 s"

[objects.wood]
name = "Wood"
[objects.aluminium]
name = "Aluminium"
[objects.cold_wood]
name = "Cooled wood"
novel = true
[objects.foam]
name = "Foam"
novel = true
"""
