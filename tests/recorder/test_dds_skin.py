"""The ROS 2 live skin (``[skin] transport = "ros2"``) against the virtual lab's DDS topics."""

from __future__ import annotations

import contextlib
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cyclonedds")

from recorder import SimulatedRig, load_actions, load_objects
from recorder.errors import RigError
from recorder.live import RecorderClock, open_skin
from recorder.virtuallab import VirtualWorld
from recorder.virtuallab._ros2_server import Ros2Faults, serve_ros2

EXAMPLE = Path(__file__).parents[2] / "recorder" / "data" / "topic_map.example.toml"
DROPPED = 5


def test_ros2_skin_reads_the_virtual_lab_and_counts_its_drops(
    dds_domain: int, tmp_path: Path
) -> None:
    objects, actions = load_objects(None), load_actions(None)
    faults = Ros2Faults(drop={"/skin/cell_3": DROPPED}, drop_after=60)
    section = {"transport": "ros2", "topic_map": str(EXAMPLE), "domain_id": dds_domain}
    blocks = []
    with SimulatedRig(0) as rig, contextlib.ExitStack() as stack:
        world = stack.enter_context(VirtualWorld(rig, objects, actions, time_scale=0.5))
        world.start_action("wood", "P1", 1)
        with serve_ros2(world, EXAMPLE, faults, domain_id=dds_domain, rate_hz=100) as server:
            skin = open_skin(section, RecorderClock(), str(tmp_path / "lab.toml"))
            with skin:
                deadline = time.monotonic() + 1.2
                while time.monotonic() < deadline:
                    blocks.extend(skin.poll())
                    time.sleep(0.05)
                blocks.extend(skin.finish())
                stats = {s.name: s for s in skin.stats()}
                force = skin.total_force()
    assert server.dropped == {"/skin/cell_3": DROPPED}
    assert set(stats) == {f"skin/cell_{i}" for i in range(7)}
    # a ROS 2 message has no sequence number: the publisher's pause is a gap, not loss
    assert all(s.basis == "stamps" and s.missing == 0 for s in stats.values())
    assert stats["skin/cell_3"].gaps == 1
    assert stats["skin/cell_3"].gap_ns == DROPPED * stats["skin/cell_3"].period_ns
    assert all(s.gaps == 0 for name, s in stats.items() if name != "skin/cell_3")
    assert all(s.received > 50 for s in stats.values())
    assert {b.modality for b in blocks} == {"force", "acceleration", "temperature", "proximity"}
    widths = {b.modality: b.data.shape[1:] for b in blocks}
    assert widths == {
        "force": (7, 3),
        "acceleration": (7, 3),
        "temperature": (7, 1),
        "proximity": (7, 1),
    }
    assert all(np.isfinite(b.data).all() for b in blocks)
    for modality in widths:  # one time base per recording: no sample before an earlier one's
        mine = [b for b in blocks if b.modality == modality]
        stamps = np.concatenate([b.stamp_ns + np.arange(len(b.data)) * b.period_ns for b in mine])
        assert np.all(np.diff(stamps) > 0), modality
    assert force is not None


def test_ros2_skin_refuses_a_bad_section(tmp_path: Path) -> None:
    clock = RecorderClock()
    with pytest.raises(RigError, match="topic_map"):
        open_skin({"transport": "ros2"}, clock, str(tmp_path / "lab.toml"))
    with pytest.raises(RigError, match="domain_id"):
        open_skin({"transport": "ros2", "topic_map": str(EXAMPLE), "domain_id": 999}, clock, "x")
    with pytest.raises(RigError, match="unknown"):
        open_skin({"transport": "ros2", "topic_map": str(EXAMPLE), "port": 1}, clock, "x")
