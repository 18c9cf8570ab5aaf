"""Joint states as arm drivers publish them: empty, short and mixed velocity and effort."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

import numpy as np
from labbags import NS, PROBE_MAP, Session, header, probe_messages, write_bag

from recorder import load_actions, load_objects
from recorder.bagimport._importer import import_bag
from recorder.bagimport._topicmap import load_topic_map
from replay import read_recording

if TYPE_CHECKING:
    from pathlib import Path

TWO = Session(("wood", "foam"), ("hold5",), trials=1, execute_s=5.0, gap_s=0.4)
JOINTS = tuple(f"fr3_joint{i}" for i in range(1, 8))
TOPIC = "/arm/joint_states"


def _joint_messages(store: Any) -> list[tuple[int, str, str, Any]]:
    """Return a 7-joint arm at 100 Hz: velocities always, efforts only in the second window.

    In the first window two messages carry 6 velocities for 7 names (a driver's bug) and one
    lacks a joint altogether; in the second window every other message carries efforts (a
    driver that fills them at times).
    """
    windows = TWO.windows()
    out = []
    for k, stamp in enumerate(range(windows[0][3] - NS // 2, TWO.stop_ns, 10_000_000)):
        velocity = np.full(7, 0.5)
        if k in {100, 101}:
            velocity = velocity[:6]
        effort = np.full(7, 2.0) if stamp >= windows[1][3] and k % 2 else np.zeros(0)
        names, position = list(JOINTS), np.arange(7, dtype=np.float64)
        if k == 150:  # a joint missing from one message (the map names no joints)
            names, position, velocity = names[:-1], position[:-1], velocity[:-1]
        message = store.types["sensor_msgs/msg/JointState"](
            header=header(store, stamp, ros1=True),
            name=names,
            position=position,
            velocity=velocity,
            effort=effort,
        )
        out.append((stamp + 1_000_000, TOPIC, "sensor_msgs/msg/JointState", message))
    return out


def test_short_or_missing_velocity_and_effort_are_never_made_up(tmp_path: Path) -> None:
    messages, store = probe_messages(ros1=True, session=TWO)
    bag = write_bag(tmp_path / "arm.bag", "ros1", messages + _joint_messages(store), store)
    map_path = tmp_path / "map.toml"
    map_path.write_text(
        PROBE_MAP.replace("[skin]", f'[joint_states]\ntopic = "{TOPIC}"\n\n[skin]'), "utf-8"
    )
    report = import_bag(
        bag,
        load_topic_map(map_path),
        tmp_path / "out",
        objects=load_objects(),
        actions=load_actions(),
    )
    assert report.malformed == {TOPIC: 3}
    first, second = (read_recording(path) for path in report.written)
    # first window: real velocities (the three malformed messages left out), no effort at all
    assert first.joints is not None
    assert json.loads(str(first.metadata.rig["joints_not_recorded"])) == ["effort"]
    assert np.all(first.joints.velocity == 0.5)
    _, _, _, start, stop = TWO.windows()[0]
    inside = [m[3] for m in _joint_messages(store) if start <= m[0] - 1_000_000 < stop]
    assert first.joints.stamps_ns.size == len(inside) - 3
    # second window: efforts in every other message: the others are dropped, not zeroed
    assert second.joints is not None
    assert json.loads(str(second.metadata.rig["joints_not_recorded"])) == []
    assert np.all(second.joints.effort == 2.0)
    assert np.all(np.diff(second.joints.stamps_ns) == 20_000_000)
    assert report.dropped_samples["joint_states"] > 0
