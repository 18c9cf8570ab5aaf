"""The ROS 2 live skin (``[skin] transport = "ros2"``) against the virtual lab's DDS topics."""

from __future__ import annotations

import contextlib
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("cyclonedds")

from recorder import SimulatedRig, SkinBlock, load_actions, load_objects
from recorder.bagimport._source import JOINT_TYPE, POSE_TYPE, SkinTopic, extractors, typestore
from recorder.bagimport._topicmap import load_topic_map
from recorder.errors import RigError
from recorder.live import RecorderClock, open_skin
from recorder.live.dds import DdsDomain, register_atikt_types
from recorder.virtuallab import VirtualWorld
from recorder.virtuallab._ros2_server import CELL_TYPE, Ros2Faults, _header, serve_ros2

EXAMPLE = Path(__file__).parents[2] / "recorder" / "data" / "topic_map.example.toml"


def _with_cell_counter(root: Path) -> Path:
    """Write the example map with the cells' counter named (``counter = "seq"``)."""
    force = '[skin.force]\ntopic = "/skin/cell_{cell}"\n'
    text = EXAMPLE.read_text(encoding="utf-8")
    assert force in text
    path = root / "counted.toml"
    path.write_text(text.replace(force, force + 'counter = "seq"\n'), encoding="utf-8")
    return path


@pytest.mark.parametrize(("dropped", "counted"), [(5, False), (1, False), (2, True)])
def test_ros2_skin_reads_the_virtual_lab_and_counts_its_drops(
    dds_domain: int, tmp_path: Path, dropped: int, *, counted: bool
) -> None:
    # one lost message is a gap too: the lab stamps on its period's grid (a jittery
    # publisher's tolerance, 2.5 periods, would hide it). With the cells' counter mapped
    # (counter = "seq"), the lost messages are missing, exactly, and no gap
    objects, actions = load_objects(None), load_actions(None)
    topic_map = _with_cell_counter(tmp_path) if counted else EXAMPLE
    # the drop is placed once the skin reads the topics (a loaded machine may take a second
    # to discover them: a drop before that would be no gap in what the skin received)
    faults = Ros2Faults(drop={"/skin/cell_3": dropped}, drop_after=2**62)
    section = {"transport": "ros2", "topic_map": str(topic_map), "domain_id": dds_domain}
    blocks: list[SkinBlock] = []
    with SimulatedRig(0) as rig, contextlib.ExitStack() as stack:
        world = stack.enter_context(VirtualWorld(rig, objects, actions, time_scale=0.5))
        world.start_action("wood", "P1", 1)
        with serve_ros2(world, topic_map, faults, domain_id=dds_domain, rate_hz=100) as server:
            skin = open_skin(section, RecorderClock(), str(tmp_path / "lab.toml"))
            with skin:
                for _ in range(600):  # a hang guard (30 s of 50 ms waits), not a time check
                    if blocks:
                        break
                    blocks.extend(skin.poll())
                    time.sleep(0.05)
                else:
                    pytest.fail("the skin read nothing")
                after = server.sent.get("/skin/cell_3", 0) + 20
                server.faults = Ros2Faults(drop={"/skin/cell_3": dropped}, drop_after=after)
                until = time.monotonic() + 1.2  # the skin reads on at least this long
                for _ in range(600):  # a hang guard (30 s of 50 ms waits), not a time check
                    if (
                        time.monotonic() >= until
                        and server.dropped.get("/skin/cell_3", 0) >= dropped
                    ):
                        break
                    blocks.extend(skin.poll())
                    time.sleep(0.05)
                else:
                    pytest.fail("the server dropped nothing")
                time.sleep(0.3)  # samples after the drop: the gap ends
                blocks.extend(skin.poll())
                blocks.extend(skin.finish())
                stats = {s.name: s for s in skin.stats()}
                force = skin.total_force()
    assert server.dropped == {"/skin/cell_3": dropped}
    assert set(stats) == {f"skin/cell_{i}" for i in range(7)}
    if counted:  # counted by the cells' own counter: loss, exactly where it happened
        assert all(s.basis == "counter" and s.gaps == 0 for s in stats.values())
        assert stats["skin/cell_3"].missing == dropped
        assert all(s.missing == 0 for name, s in stats.items() if name != "skin/cell_3")
    else:  # a ROS 2 message has no sequence number: the publisher's pause is a gap
        assert all(s.basis == "stamps" and s.missing == 0 for s in stats.values())
        assert stats["skin/cell_3"].gaps == 1
        assert stats["skin/cell_3"].gap_ns == dropped * stats["skin/cell_3"].period_ns
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


def _publish_cells(domain: DdsDomain, stamps: list[int], lag_ns: list[int]) -> None:
    """Publish the example map's seven cells at ``stamps``, each sent ``lag_ns`` after it."""
    store = domain.store
    writers = {f"/skin/cell_{c}": domain.writer(f"/skin/cell_{c}", CELL_TYPE) for c in range(7)}
    deadline = time.monotonic() + 10
    while any(w.matched() == 0 for w in writers.values()) and time.monotonic() < deadline:
        time.sleep(0.01)
    for stamp, lag in sorted(zip(stamps, lag_ns, strict=True), key=sum):
        delay = (stamp + lag - time.time_ns()) / 1e9
        if delay > 0:
            time.sleep(delay)
        message = store.types[CELL_TYPE](
            header=_header(store, stamp),
            force=np.ones(3, dtype=np.float32),
            acc=np.zeros(3, dtype=np.float32),
            temp=30.0,
            prox=0.05,
            seq=0,
        )
        raw = bytes(store.serialize_cdr(message, CELL_TYPE))
        for writer in writers.values():
            writer.write(raw)


@pytest.mark.slow(7)
def test_a_recording_whose_first_second_arrives_late_keeps_the_sources_clock_offset(
    dds_domain: int, tmp_path: Path
) -> None:
    # the skin's clock is this computer's: its offset is ~0 whatever the latency. The second
    # recording's first second is sent 0.6 s late (a publisher catching up), which alone
    # would take the 0.6 s latency for the clock offset and place its samples 0.6 s late
    period, lag = 4_000_000, 600_000_000
    section = {"transport": "ros2", "topic_map": str(EXAMPLE), "domain_id": dds_domain}
    publisher = DdsDomain(dds_domain, typestore(load_topic_map(EXAMPLE)), loopback=True)
    skin = open_skin(section, RecorderClock(), str(tmp_path / "lab.toml"))
    start = time.time_ns() + 300_000_000
    thread = threading.Thread(
        target=_publish_cells,
        args=(publisher, [start + i * period for i in range(1000)], [0] * 1000),
        daemon=True,
    )
    thread.start()
    with skin:
        thread.join()
        skin.poll()
        skin.begin()
        second = time.time_ns() + 100_000_000
        stamps = [second + i * period for i in range(500)]
        lags = [lag if i < 250 else 0 for i in range(500)]  # 1 s late, then on time
        _publish_cells(publisher, stamps, lags)
        blocks = skin.poll()
        time.sleep(0.3)
        blocks += skin.finish()
    force = [b for b in blocks if b.modality == "force"]
    assert force
    for block in force:  # a sample is never stamped after it arrived (same clock)
        last = block.stamp_ns + (len(block.data) - 1) * block.period_ns
        assert last <= block.receive_ns + 50_000_000, (last - block.receive_ns) / 1e6


def test_the_virtual_labs_messages_are_rosbags_own_bytes() -> None:
    from recorder._sim.ur10 import JOINT_NAMES  # noqa: PLC0415
    from recorder.virtuallab import _ros2_server as lab  # noqa: PLC0415

    topic_map = load_topic_map(EXAMPLE)
    store = register_atikt_types(typestore(topic_map))
    cells = [e for e in extractors(topic_map).values() if isinstance(e, SkinTopic)]
    rng = np.random.default_rng(5)
    skin = {"force": rng.normal(size=(7, 3)), "acceleration": rng.normal(size=(7, 3))}
    skin |= {"temperature": rng.normal(30, 1, size=(7, 1)), "proximity": rng.random((7, 1))}
    with SimulatedRig(0) as rig, VirtualWorld(rig, load_objects(None), load_actions(None)) as world:
        server = lab.Ros2Server(world, topic_map, Ros2Faults(), None, 250.0, 500.0)  # type: ignore[arg-type]
        stamp, controller = 1_795_784_566_528_339_486, world.controller_ns()
        for extractor in cells:
            raw: dict[str, Any] = {
                "force": np.zeros(3),
                "acc": np.zeros(3),
                "temp": 0.0,
                "prox": 0.0,
            }
            for spec in extractor.fields:
                values = (skin[spec.modality][extractor.cell] - spec.offset) / spec.scale
                raw[spec.field] = values if values.size > 1 else float(values[0])
            message = store.types[CELL_TYPE](
                header=_header(store, stamp),
                force=np.asarray(raw["force"], dtype=np.float32),
                acc=np.asarray(raw["acc"], dtype=np.float32),
                temp=float(raw["temp"]),
                prox=float(raw["prox"]),
                seq=2**32 - 1,  # the counter of the message, last before it wraps
            )
            expected = bytes(store.serialize_cdr(message, CELL_TYPE))
            made = server._cell(store, extractor, stamp, skin, 2**33 - 1)
            assert made == expected, extractor.topic
        state = world.robot_at(controller)
        joints = store.types[JOINT_TYPE](
            header=_header(store, stamp),
            name=list(JOINT_NAMES),
            position=np.asarray(state.q, dtype=np.float64),
            velocity=np.asarray(state.qd, dtype=np.float64),
            effort=np.zeros(len(JOINT_NAMES)),
        )
        expected = bytes(store.serialize_cdr(joints, JOINT_TYPE))
        assert server._joint(store, stamp, controller) == expected
        decoded: Any = store.deserialize_cdr(
            server._pose(store, stamp, controller, 0.001), POSE_TYPE
        )
        assert decoded.header.stamp.sec * 10**9 + decoded.header.stamp.nanosec == stamp
        position = [decoded.pose.position.x, decoded.pose.position.y, decoded.pose.position.z]
        np.testing.assert_allclose(position, np.asarray(state.tcp_pose[:3]) / 0.001)


def test_a_ros2_drop_placed_after_the_first_action_lands_there(dds_domain: int) -> None:
    # ros2.at_action=S: the samples before the drop are counted from S s after the first
    # action began, however long the lab ran before it
    objects, actions = load_objects(None), load_actions(None)
    faults = Ros2Faults(drop={"/skin/cell_3": 1}, drop_after=0, at_action_s=0.3)
    with contextlib.ExitStack() as stack:
        rig = stack.enter_context(SimulatedRig(0))
        world = stack.enter_context(VirtualWorld(rig, objects, actions, time_scale=0.5))
        server = stack.enter_context(
            serve_ros2(world, EXAMPLE, faults, domain_id=dds_domain, rate_hz=100)
        )
        time.sleep(0.5)  # the lab runs a while before any action
        assert server.dropped == {}
        world.start_action("wood", "P1", 1)
        for _ in range(500):  # a hang guard (10 s of 20 ms waits), not a time check
            if server.dropped:
                break
            time.sleep(0.02)
        else:
            pytest.fail("the server dropped nothing")
    began = world.first_action_ns
    assert began is not None
    assert server.dropped == {"/skin/cell_3": 1}
    late = server.dropped_at["/skin/cell_3"] - began
    assert 0.3e9 <= late < 0.3e9 + 0.05e9  # the first sample at or after the origin (100 Hz)


#: A lab's skin cell that counts its messages (the example map's fields and a uint16 counter).
COUNTED = "lab_msgs/msg/CountedCell"


def _counted_map(root: Path) -> Path:
    """Write the example map with the cells' type counting its messages (``seq``)."""
    (root / "CountedCell.msg").write_text(
        "std_msgs/Header header\nuint16 seq\nfloat32[3] force\nfloat32[3] acc\n"
        "float32 temp\nfloat32 prox\n",
        encoding="utf-8",
    )
    path = _with_cell_counter(root)
    text = path.read_text(encoding="utf-8").replace(
        'counter = "seq"\n', 'counter = "seq"\ncounter_modulo = 65536\n'
    )
    path.write_text(text + f'\n[types]\n"{COUNTED}" = "CountedCell.msg"\n', encoding="utf-8")
    return path


def test_a_ros2_skin_counts_a_jittery_publishers_lost_messages_by_their_counter(
    dds_domain: int, tmp_path: Path
) -> None:
    # 250 Hz, each message stamped up to 0.4 periods off its tick (a jittery publisher: its
    # stamps alone could not tell a lost message from jitter). Cell 2 loses 3 single
    # messages; its counter says so exactly: 3 missing, no gap; the other cells lose none
    path = _counted_map(tmp_path)
    section = {"transport": "ros2", "topic_map": str(path), "domain_id": dds_domain}
    publisher = DdsDomain(dds_domain, typestore(load_topic_map(path)), loopback=True)
    store = publisher.store
    writers = {c: publisher.writer(f"/skin/cell_{c}", COUNTED) for c in range(7)}
    period, count, lost = 4_000_000, 600, {200, 301, 402}
    rng = np.random.default_rng(3)
    jitter = rng.uniform(-0.4, 0.4, count) * period
    skin = open_skin(section, RecorderClock(), str(tmp_path / "lab.toml"))
    blocks: list[SkinBlock] = []
    with skin:
        for _ in range(1000):  # a hang guard (10 s of 10 ms waits), not a time check
            if all(w.matched() != 0 for w in writers.values()):
                break
            time.sleep(0.01)
        else:
            pytest.fail("no reader matched")
        skin.begin()
        start = time.time_ns() + 100_000_000
        for i in range(count):
            stamp = start + i * period + round(jitter[i])
            delay = (stamp - time.time_ns()) / 1e9
            if delay > 0:
                time.sleep(delay)
            message = store.types[COUNTED](
                header=_header(store, stamp),
                seq=i,
                force=np.ones(3, dtype=np.float32),
                acc=np.zeros(3, dtype=np.float32),
                temp=30.0,
                prox=0.05,
            )
            raw = bytes(store.serialize_cdr(message, COUNTED))
            for cell, writer in writers.items():
                if cell != 2 or i not in lost:
                    writer.write(raw)
            if i % 50 == 0:
                blocks.extend(skin.poll())
        time.sleep(0.3)
        blocks.extend(skin.poll())
        blocks.extend(skin.finish())
        stats = {s.name: s for s in skin.stats()}
    assert all(s.basis == "counter" for s in stats.values())
    assert stats["skin/cell_2"].missing == 3
    assert all(s.missing == 0 for name, s in stats.items() if name != "skin/cell_2")
    assert all(s.gaps == 0 and s.counter_resets == 0 for s in stats.values())
    assert all(
        s.received == count - (3 if name == "skin/cell_2" else 0) for name, s in stats.items()
    )
    assert {b.modality for b in blocks} == {"force", "acceleration", "temperature", "proximity"}


def test_the_virtual_lab_refuses_a_cell_counter_it_does_not_fill(
    dds_domain: int, tmp_path: Path
) -> None:
    path = _with_cell_counter(tmp_path)
    path.write_text(path.read_text("utf-8").replace('counter = "seq"', 'counter = "frame"'))
    with (
        SimulatedRig(0) as rig,
        VirtualWorld(rig, load_objects(None), load_actions(None)) as world,
        pytest.raises(RigError, match=r"counts its messages in 'seq', not 'frame' of /skin/cell_0"),
        serve_ros2(world, path, domain_id=dds_domain),
    ):
        pass
