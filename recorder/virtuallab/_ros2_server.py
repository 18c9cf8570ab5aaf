"""The virtual lab's ROS 2 side: the world's joint states, tool pose and skin over DDS.

A lab rehearses ``listen`` or a ``[skin] transport = "ros2"`` rig configuration without the
robot: :func:`serve_ros2` publishes, on the topics a topic map names, what a ROS 2 driver of
the arm and of the skin would publish (``sensor_msgs/msg/JointState``, the tool's
``geometry_msgs/msg/PoseStamped`` where the map has a ``[tool_pose]``, and one
``atikt_msgs/msg/SkinCell`` message per cell with the fields the map reads, in the map's raw
units), stamped with the wall clock, and, when the map cuts its windows from an annotation
topic, the annotations a lab's system would publish: one JSON ``std_msgs/msg/String`` per
phase the world's playing action enters (``{"object", "action", "trial", "phase",
"stamp_ns"}``), so ``listen`` is rehearsed end to end. Faults for tests: samples of a topic
not published (counted exactly by the readers), and a stall of every topic.
"""

from __future__ import annotations

import json
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from recorder._sim.ur10 import JOINT_NAMES
from recorder.bagimport._source import (
    ANNOTATION_TYPE,
    JOINT_TYPE,
    POSE_TYPE,
    SkinTopic,
    extractors,
    typestore,
)
from recorder.bagimport._topicmap import load_topic_map
from recorder.errors import RigError
from recorder.live.dds import DdsDomain
from recorder.writing._writer import _STAMP, _STAMP_OFFSET, _sentinels, _Template

if TYPE_CHECKING:
    from collections.abc import Iterator, Mapping
    from pathlib import Path

    from recorder.bagimport._topicmap import TopicMap
    from recorder.live.dds import RawWriter
    from recorder.virtuallab._world import VirtualWorld

CELL_TYPE = "atikt_msgs/msg/SkinCell"
#: The cell message's counter of the messages published on its topic (dropped ones included,
#: as a publisher counts what it sent): a topic map's ``counter = "seq"`` counts their loss.
CELL_COUNTER = "seq"
#: Field of the cell message -> (modality, values per cell).
CELL_FIELDS = {"force": 3, "acc": 3, "temp": 1, "prox": 1}
#: Where each field's values start among the cell message's eight float32.
_CELL_AT = {"force": 0, "acc": 3, "temp": 6, "prox": 7}
_CELL_VALUES = 8
_NS_PER_S = 1_000_000_000


@dataclass(frozen=True, slots=True)
class Ros2Faults:
    """Faults the virtual lab injects into its ROS 2 topics.

    Attributes:
        drop: Topic -> how many consecutive samples are not published.
        drop_after: Samples of each topic published before the drop starts.
        stall_s: Every topic pauses this long once (0: never).
        stall_after_s: When the pause starts, s after the start.
        at_action_s: Count ``drop_after`` and ``stall_after_s`` from this long after the
            first announced action began instead of from the start (negative: from the
            start), so that a fault lands inside an action however long the lab waited.
    """

    drop: Mapping[str, int] = field(default_factory=dict)
    drop_after: int = 50
    stall_s: float = 0.0
    stall_after_s: float = 0.0
    at_action_s: float = -1.0


@dataclass
class Ros2Server:
    """The publishing thread of :func:`serve_ros2`; ``sent`` counts what went out per topic."""

    world: VirtualWorld
    topic_map: TopicMap
    faults: Ros2Faults
    domain: DdsDomain
    rate_hz: float
    joint_rate_hz: float
    sent: dict[str, int] = field(default_factory=dict)
    dropped: dict[str, int] = field(default_factory=dict)
    #: Topic -> controller time of its first dropped sample, ns.
    dropped_at: dict[str, int] = field(default_factory=dict)
    #: Topic -> samples published or dropped since the faults' origin.
    _counted: dict[str, int] = field(default_factory=dict)
    #: Controller time publishing began, ns.
    _start_ns: int = 0
    _stop: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None
    _writers: dict[str, RawWriter] = field(default_factory=dict)
    _cells: dict[str, SkinTopic] = field(default_factory=dict)
    #: Per cell topic: the number of its next message (``seq``; dropped ones count too).
    _sequence: dict[str, int] = field(default_factory=dict)
    _annotations: str | None = None
    _announced: tuple[tuple[str, str, int], str] | None = None
    _said: int = 0
    _last_stamp: int = 0
    _modalities: tuple[str, ...] = ()
    _cell_head: bytes | None = None
    _joint_template: _Template | None = None
    _pose_template: _Template | None = None
    #: The annotations published, as (stamp ns, JSON text).
    annotated: list[tuple[int, str]] = field(default_factory=list)

    def start(self) -> None:
        """Create the writers and start publishing.

        Raises:
            RigError: A mapped skin field is not a field of the cell message.
        """
        for topic, extractor in extractors(self.topic_map).items():
            if not isinstance(extractor, SkinTopic):
                continue
            if bad := [s.field for s in extractor.fields if s.field not in CELL_FIELDS]:
                msg = (
                    f"{self.topic_map.path}: the virtual lab publishes {CELL_TYPE} "
                    f"({', '.join(CELL_FIELDS)}), not field {bad[0]!r} of {topic}"
                )
                raise RigError(msg)
            if bad := [s.counter for s in extractor.fields if s.counter not in {"", CELL_COUNTER}]:
                msg = (
                    f"{self.topic_map.path}: the virtual lab's {CELL_TYPE} counts its messages in "
                    f"{CELL_COUNTER!r}, not {bad[0]!r} of {topic}; set counter = "
                    f'"{CELL_COUNTER}" or leave it out'
                )
                raise RigError(msg)
            self._cells[topic] = extractor
            self._modalities += tuple(
                f.modality for f in extractor.fields if f.modality not in self._modalities
            )
            self._writers[topic] = self.domain.writer(topic, CELL_TYPE)
        if self.topic_map.joints is not None:
            topic = self.topic_map.joints.topic
            self._writers[topic] = self.domain.writer(topic, JOINT_TYPE)
        if self.topic_map.pose is not None:
            topic = self.topic_map.pose.topic
            self._writers[topic] = self.domain.writer(topic, POSE_TYPE)
        windows = self.topic_map.windows
        if windows.source == "topic" and windows.topic:
            self._annotations = windows.topic
            self._writers[windows.topic] = self.domain.writer(windows.topic, ANNOTATION_TYPE)
        self._thread = threading.Thread(target=self._run, name="atikt-ros2-server", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop publishing."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)

    def _origin(self, controller_ns: int) -> int | None:
        """Return the controller time the faults count from (None: not reached yet)."""
        if self.faults.at_action_s < 0:
            return self._start_ns
        began = self.world.first_action_ns
        if began is None:
            return None
        origin = began + round(self.faults.at_action_s * _NS_PER_S)
        return origin if controller_ns >= origin else None

    def _publish(self, topic: str, raw: bytes, controller_ns: int) -> None:
        """Publish one sample unless a fault drops it (its time: ``controller_ns``)."""
        if self._origin(controller_ns) is not None:
            count = self._counted.get(topic, 0)
            self._counted[topic] = count + 1
            drop = self.faults.drop.get(topic, 0)
            if self.faults.drop_after <= count < self.faults.drop_after + drop:
                self.dropped[topic] = self.dropped.get(topic, 0) + 1
                self.dropped_at.setdefault(topic, controller_ns)
                return
        self._writers[topic].write(raw)
        self.sent[topic] = self.sent.get(topic, 0) + 1

    def _run(self) -> None:
        """Publish at the rates until stopped (sample times on an exact grid)."""
        store = self.domain.store
        start = time.time_ns()
        offset = start - self.world.controller_ns()  # wall clock minus controller time
        self._start_ns = start - offset
        cell_period = round(_NS_PER_S / self.rate_hz)
        joint_period = round(_NS_PER_S / self.joint_rate_hz)
        stalled = self.faults.stall_s <= 0
        next_cell, next_joint = start, start
        while not self._stop.is_set():
            due = min(next_cell, next_joint)
            delay = (due - time.time_ns()) / _NS_PER_S
            if delay > 0:
                time.sleep(delay)
            # a sample's values are the world's at its stamp, as a driver stamps what it
            # acquired: a publisher running late sends old samples late, never new values
            # under an old stamp
            controller = due - offset
            origin = self._origin(controller)
            if (
                not stalled
                and origin is not None
                and controller - origin >= self.faults.stall_after_s * _NS_PER_S
            ):
                stalled = True
                time.sleep(self.faults.stall_s)
            if due == next_cell:  # the phases announced up to the sample time
                self._annotate(store, offset, controller)
            if due == next_joint:
                self._robot(store, due, controller)
                next_joint += joint_period
            if due == next_cell:
                skin = {m: self.world.skin_at(m, controller) for m in self._modalities}
                for topic, extractor in self._cells.items():
                    sequence = self._sequence.get(topic, 0)
                    self._sequence[topic] = sequence + 1
                    raw = self._cell(store, extractor, due, skin, sequence)
                    self._publish(topic, raw, controller)
                next_cell += cell_period

    def _annotate(self, store: Any, offset_ns: int, controller_ns: int) -> None:  # noqa: ANN401
        """Publish the phases the world's programs announced up to ``controller_ns``.

        Each annotation is stamped with the time of the cycle that executed its ``textmsg``
        (controller time + ``offset_ns``: the wall clock), so a loop running late delays the
        annotations but never drops, merges or reorders them. An action that gives way to
        another without saying ``end`` is ended where the next one begins.
        """
        if self._annotations is None:
            return
        said, self._said = self.world.announcements(self._said, controller_ns)
        for at_ns, key, phase in said:
            stamp = max(at_ns + offset_ns, self._last_stamp + 1)  # increasing, as a bag's
            announced = self._announced
            if announced is not None and announced[0] != key and announced[1] != "end":
                self._say(store, announced[0], "end", stamp)
                stamp += 1
                announced = None
            if announced is not None and announced == (key, phase):
                continue  # said again (a program re-announcing its phase)
            if announced is None and phase == "end":
                continue  # the end of an action never begun here
            self._say(store, key, phase, stamp)
            self._announced = None if phase == "end" else (key, phase)

    def _say(self, store: Any, key: tuple[str, str, int], phase: str, stamp: int) -> None:  # noqa: ANN401
        """Publish one annotation."""
        assert self._annotations is not None  # noqa: S101 (checked by the caller)
        text = json.dumps(
            {"object": key[0], "action": key[1], "trial": key[2], "phase": phase, "stamp_ns": stamp}
        )
        message = store.types[ANNOTATION_TYPE](data=text)
        self._writers[self._annotations].write(bytes(store.serialize_cdr(message, ANNOTATION_TYPE)))
        self.annotated.append((stamp, text))
        self._last_stamp = stamp

    def _robot(self, store: Any, stamp: int, controller_ns: int) -> None:  # noqa: ANN401
        """Publish the arm's joint state and tool pose, where the map has their topics."""
        mapped = self.topic_map
        if mapped.joints is not None:
            self._publish(
                mapped.joints.topic, self._joint(store, stamp, controller_ns), controller_ns
            )
        if mapped.pose is not None:
            pose = self._pose(store, stamp, controller_ns, mapped.pose.position_scale)
            self._publish(mapped.pose.topic, pose, controller_ns)

    def _pose(self, store: Any, stamp: int, controller_ns: int, scale: float) -> bytes:  # noqa: ANN401
        """Return a PoseStamped of the world's TCP (position in the map's raw units)."""
        tcp = self.world.robot_at(controller_ns).tcp_pose
        pose = np.empty(7)
        pose[:3] = np.asarray(tcp[:3], dtype=np.float64) / scale
        pose[3:] = _quaternion(np.asarray(tcp[3:6], dtype=np.float64))
        if self._pose_template is None:
            sentinel = _sentinels(7, 3)
            self._pose_template = _Template.create(_pose_message(store, sentinel), [sentinel])
        return self._pose_template.fill(stamp, [pose])

    def _joint(self, store: Any, stamp: int, controller_ns: int) -> bytes:  # noqa: ANN401
        """Return a JointState of the world's arm, serialized."""
        state = self.world.robot_at(controller_ns)
        if self._joint_template is None:
            runs = [_sentinels(len(JOINT_NAMES), seed) for seed in range(3)]
            self._joint_template = _Template.create(_joint_message(store, runs), runs)
        runs = [
            np.asarray(state.q, dtype=np.float64),
            np.asarray(state.qd, dtype=np.float64),
            np.zeros(len(JOINT_NAMES)),
        ]
        return self._joint_template.fill(stamp, runs)

    def _cell(
        self,
        store: Any,  # noqa: ANN401
        extractor: SkinTopic,
        stamp: int,
        skin: Mapping[str, Any],
        sequence: int,
    ) -> bytes:
        """Return one cell's message, its fields in the map's raw units, serialized.

        ``skin``: the world's sample of each modality at the stamp (cells, values);
        ``sequence``: the message's number on its topic (``seq``, wrapping at 2^32).
        """
        values = np.zeros(_CELL_VALUES, dtype=np.float32)  # force[3], acc[3], temp, prox
        for spec in extractor.fields:
            sample = skin.get(spec.modality)
            if sample is None:
                continue
            si = np.asarray(sample[extractor.cell], dtype=np.float64).reshape(-1)
            raw = (si - spec.offset) / spec.scale
            at = _CELL_AT[spec.field]
            values[at : at + CELL_FIELDS[spec.field]] = raw[: CELL_FIELDS[spec.field]]
        if self._cell_head is None:
            self._cell_head = _cell_head(store)
        head = bytearray(self._cell_head)
        _STAMP.pack_into(head, _STAMP_OFFSET, *divmod(stamp, _NS_PER_S))
        counter = (sequence % 2**32).to_bytes(4, "little")
        return bytes(head) + values.astype("<f4").tobytes() + counter


def _cell_head(store: Any) -> bytes:  # noqa: ANN401
    """Return a cell message's bytes before its values (rosbags' serialisation, once).

    The values (eight float32) and the counter (a uint32) are the message's last bytes; the
    stamp is patched per sample (rosbags builds a message object per call: ten times the cost,
    1,750 cells a second).
    """
    message = store.types[CELL_TYPE](
        header=_header(store, 0),
        force=np.zeros(3, dtype=np.float32),
        acc=np.zeros(3, dtype=np.float32),
        temp=0.0,
        prox=0.0,
        seq=0,
    )
    raw = bytes(store.serialize_cdr(message, CELL_TYPE))
    return raw[: len(raw) - 4 * _CELL_VALUES - 4]


def _joint_message(store: Any, runs: list[np.ndarray[Any, Any]]) -> bytes:  # noqa: ANN401
    """Return a JointState with positions, velocities and efforts ``runs`` (a template)."""
    message = store.types[JOINT_TYPE](
        header=_header(store, 0),
        name=list(JOINT_NAMES),
        position=runs[0],
        velocity=runs[1],
        effort=runs[2],
    )
    return bytes(store.serialize_cdr(message, JOINT_TYPE))


def _pose_message(store: Any, pose: np.ndarray[Any, Any]) -> bytes:  # noqa: ANN401
    """Return a PoseStamped of position and quaternion ``pose`` (seven values, a template)."""
    types = store.types
    x, y, z, qx, qy, qz, qw = (float(v) for v in pose)
    message = types[POSE_TYPE](
        header=_header(store, 0),
        pose=types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=x, y=y, z=z),
            orientation=types["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
        ),
    )
    return bytes(store.serialize_cdr(message, POSE_TYPE))


def _quaternion(rotvec: np.ndarray[Any, Any]) -> tuple[float, float, float, float]:
    """Return the unit quaternion (x, y, z, w) of a rotation vector.

    By hand, as the virtual arm converts its rotations (scipy's Rotation costs more than the
    message at 500 Hz).
    """
    angle = float(np.sqrt(rotvec @ rotvec))
    if angle < 1e-12:  # noqa: PLR2004 (no rotation)
        return 0.0, 0.0, 0.0, 1.0
    x, y, z = (float(v) for v in rotvec / angle * np.sin(angle / 2))
    return x, y, z, float(np.cos(angle / 2))


def _header(store: Any, stamp: int) -> Any:  # noqa: ANN401
    """Return a std_msgs/Header at ``stamp``."""
    time_msg = store.types["builtin_interfaces/msg/Time"](
        sec=stamp // _NS_PER_S, nanosec=stamp % _NS_PER_S
    )
    return store.types["std_msgs/msg/Header"](stamp=time_msg, frame_id="virtual_lab")


@contextmanager
def serve_ros2(
    world: VirtualWorld,
    topic_map_path: Path,
    faults: Ros2Faults | None = None,
    *,
    domain_id: int = 0,
    rate_hz: float = 250.0,
    joint_rate_hz: float = 500.0,
    loopback: bool = True,
) -> Iterator[Ros2Server]:
    """Publish the world's joint states, tool pose and skin on a topic map's topics while inside.

    Args:
        world: The simulated execution being played.
        topic_map_path: The map whose ``[joint_states]``, ``[tool_pose]`` and ``[skin]`` topics
            are published.
        faults: Faults to inject (default: none).
        domain_id: The DDS domain (``ROS_DOMAIN_ID``).
        rate_hz: Messages per second of each skin cell topic.
        joint_rate_hz: Messages per second of the joint states (and of the tool pose).
        loopback: Confine the publisher to the loopback interface by its own configuration
            (the default: a rehearsal stays on this computer, whatever ``CYCLONEDDS_URI``
            says); False joins the interfaces ``CYCLONEDDS_URI`` names.

    Yields:
        The running server (its ``sent`` and ``dropped`` counts per topic).

    Raises:
        RigError: The map maps a skin field the cell message does not have.
    """
    topic_map = load_topic_map(topic_map_path)
    domain = DdsDomain(domain_id, typestore(topic_map), loopback=loopback)
    server = Ros2Server(world, topic_map, faults or Ros2Faults(), domain, rate_hz, joint_rate_hz)
    server.start()
    try:
        yield server
    finally:
        server.stop()
