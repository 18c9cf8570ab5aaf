"""One recording -> an immutable, typed :class:`ActionRecording` (numpy arrays, phases, metadata).

Three layers: :mod:`replay._container` reads the file and checks its CRCs, :mod:`replay._decode`
turns CDR payloads into arrays, and this module validates the contract (profile, metadata,
schema version, required channels) and assembles the typed recording. Every array is
read-only; time is int64 nanoseconds of the sensor clock; ranges are half-open.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from replay._container import RawChannel, read_container
from replay._decode import DecodedGroup, decode_topic, gather
from replay.errors import RecordingError
from schemas import CHANNELS, SCHEMA_VERSION, build_typestore, full_type_name

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from numpy.typing import NDArray

    from replay._container import Container

#: Name of the file-level metadata record written by the recorder.
METADATA_NAME = "atikt.recording"
#: Skin modalities, each on its own channel, in contract order.
MODALITIES = ("force", "temperature", "acceleration", "proximity")

_NS_PER_S = 1_000_000_000
_SKIN_TYPES = {
    "force": "SkinForce",
    "temperature": "SkinTemperature",
    "acceleration": "SkinAcceleration",
    "proximity": "SkinProximity",
}
_TOPICS = {channel.msgtype: channel.topic for channel in CHANNELS}
_METADATA_KEYS = (
    "object_id",
    "object_name",
    "object_novel",
    "action_id",
    "action_kind",
    "action_parameters",
    "trial",
    "rig",
    "seed",
    "software_version",
    "schema_version",
)


def _frozen(array: NDArray[Any]) -> NDArray[Any]:
    """Return ``array`` marked read-only."""
    array.flags.writeable = False
    return array


def _span(stamps: NDArray[np.int64], start_ns: int, stop_ns: int) -> slice:
    """Return the slice of sorted ``stamps`` inside ``[start_ns, stop_ns)``."""
    lo, hi = np.searchsorted(stamps, [start_ns, stop_ns], side="left")
    return slice(int(lo), int(hi))


@dataclass(frozen=True, slots=True)
class RecordingMetadata:
    """The recording's ``atikt.recording`` metadata record, typed.

    Attributes:
        object_id: Catalog id of the explored object.
        object_name: Human-readable object name.
        object_novel: True for a "new" object, False for an "old" (prior) object.
        action_id: Catalog id of the action (P1, P2, S1..S4, C1, ...).
        action_kind: press, slide or static.
        action_parameters: depth_m, force_n, speed_m_s, duration_s (SI units).
        trial: Trial number of this (object, action).
        rig: The rig's kind and configuration.
        seed: Seed the rig was created with.
        software_version: Version of the software that recorded the file.
        schema_version: Version of the message definitions and layout.
    """

    object_id: str
    object_name: str
    object_novel: bool
    action_id: str
    action_kind: str
    action_parameters: Mapping[str, float]
    trial: int
    rig: Mapping[str, str]
    seed: int
    software_version: str
    schema_version: int


@dataclass(frozen=True, slots=True)
class SkinSeries:
    """The samples of one skin modality.

    Attributes:
        modality: force, temperature, acceleration or proximity.
        stamps_ns: Sensor time of every sample, int64 ns, shape (n,), non-decreasing.
        data: Samples, float32, shape (n, cells, channels), SI units (C for temperature).
        cell_ids: Id of each cell, shape (cells,).
        period_ns: Nominal time between samples, ns.
    """

    modality: str
    stamps_ns: NDArray[np.int64]
    data: NDArray[np.float32]
    cell_ids: NDArray[np.uint16]
    period_ns: int

    def between(self, start_ns: int, stop_ns: int) -> SkinSeries:
        """Return the samples with stamps in ``[start_ns, stop_ns)`` (read-only views)."""
        span = _span(self.stamps_ns, start_ns, stop_ns)
        return SkinSeries(
            self.modality, self.stamps_ns[span], self.data[span], self.cell_ids, self.period_ns
        )


@dataclass(frozen=True, slots=True)
class JointStates:
    """UR10 joint states.

    Attributes:
        names: Joint names, in array column order.
        stamps_ns: Controller time of every sample, int64 ns, shape (n,).
        position: Joint angles, rad, float64, shape (n, joints).
        velocity: Joint velocities, rad/s, float64, shape (n, joints).
        effort: Joint torques, N m, float64, shape (n, joints).
    """

    names: tuple[str, ...]
    stamps_ns: NDArray[np.int64]
    position: NDArray[np.float64]
    velocity: NDArray[np.float64]
    effort: NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class TcpPoses:
    """TCP poses in the robot base frame.

    Attributes:
        frame_id: Frame of the poses.
        stamps_ns: Controller time of every sample, int64 ns, shape (n,).
        position: Positions, m, float64, shape (n, 3).
        orientation: Unit quaternions (x, y, z, w), float64, shape (n, 4).
    """

    frame_id: str
    stamps_ns: NDArray[np.int64]
    position: NDArray[np.float64]
    orientation: NDArray[np.float64]


class PhaseStart(NamedTuple):
    """The start of one phase of the action."""

    phase: str
    start_ns: int


@dataclass(frozen=True, slots=True)
class ActionRecording:
    """One recorded action execution, immutable.

    Attributes:
        path: The file it was read from.
        metadata: What was recorded.
        force: Normal forces, N, shape (n, cells, 3).
        temperature: Temperatures, C, shape (n, cells, 1).
        acceleration: Accelerations, m/s^2, shape (n, cells, 3).
        proximity: Distances, m, shape (n, cells, 1).
        joints: UR10 joint states.
        tcp: TCP poses.
        phases: Phase starts in time order: approach, contact, execute, retract, end.
    """

    path: Path
    metadata: RecordingMetadata
    force: SkinSeries
    temperature: SkinSeries
    acceleration: SkinSeries
    proximity: SkinSeries
    joints: JointStates
    tcp: TcpPoses
    phases: tuple[PhaseStart, ...]

    def skin(self, modality: str) -> SkinSeries:
        """Return the series of a modality by name.

        Raises:
            RecordingError: ``modality`` is not one of :data:`MODALITIES`.
        """
        if modality not in MODALITIES:
            msg = f"unknown modality {modality!r}; use one of {', '.join(MODALITIES)}"
            raise RecordingError(msg)
        series: SkinSeries = getattr(self, modality)
        return series

    @property
    def end_ns(self) -> int:
        """Return one nanosecond past the last stamp of any channel."""
        lasts = [self.skin(m).stamps_ns[-1:] for m in MODALITIES]
        lasts += [self.joints.stamps_ns[-1:], self.tcp.stamps_ns[-1:]]
        lasts += [np.array([p.start_ns for p in self.phases], dtype=np.int64)]
        return int(np.concatenate(lasts).max()) + 1

    def phase_range(self, phase: str) -> tuple[int, int]:
        """Return the half-open range ``[start_ns, stop_ns)`` of a phase.

        A phase lasts until the next phase starts; the last phase until :attr:`end_ns`.

        Raises:
            RecordingError: The recording has no such phase.
        """
        for index, mark in enumerate(self.phases):
            if mark.phase == phase:
                following = self.phases[index + 1 : index + 2]
                return mark.start_ns, following[0].start_ns if following else self.end_ns
        recorded = ", ".join(mark.phase for mark in self.phases)
        msg = f"{self.path}: no phase {phase!r} in the recording (it has: {recorded})"
        raise RecordingError(msg)

    def during(self, phase: str, modality: str) -> SkinSeries:
        """Return a modality's samples inside a phase, e.g. ``during("execute", "force")``."""
        return self.skin(modality).between(*self.phase_range(phase))


def _metadata_error(path: Path, detail: str) -> RecordingError:
    return RecordingError(
        f"{path}: {detail}; the file was not written by atikt-record or is damaged: "
        "record it again with atikt-record"
    )


def _check_schema_version(path: Path, version: int) -> None:
    """Reject recordings whose schema this software cannot read, with migration advice."""
    if version > SCHEMA_VERSION:
        msg = (
            f"{path}: recorded with schema version {version}, newer than this software reads "
            f"({SCHEMA_VERSION}); upgrade atikt ('pip install -U atikt') to read it"
        )
        raise RecordingError(msg)
    if version != SCHEMA_VERSION:
        msg = (
            f"{path}: schema version {version} is not supported (this software reads version "
            f"{SCHEMA_VERSION}, and no migration from {version} exists); record it again "
            "or read it with the atikt release that wrote it (see schemas/README.md)"
        )
        raise RecordingError(msg)


def parse_metadata(path: Path, records: Mapping[str, Mapping[str, str]]) -> RecordingMetadata:
    """Return the typed ``atikt.recording`` metadata record, checking the schema version.

    Raises:
        RecordingError: The record is missing or malformed, or its schema version unsupported.
    """
    record = records.get(METADATA_NAME)
    if record is None:
        raise _metadata_error(path, f"no {METADATA_NAME!r} metadata record")
    if missing := [key for key in _METADATA_KEYS if key not in record]:
        raise _metadata_error(path, f"metadata record lacks {', '.join(missing)}")
    try:
        version = int(record["schema_version"])
        _check_schema_version(path, version)
        return RecordingMetadata(
            object_id=record["object_id"],
            object_name=record["object_name"],
            object_novel=bool(json.loads(record["object_novel"])),
            action_id=record["action_id"],
            action_kind=record["action_kind"],
            action_parameters=MappingProxyType(
                {k: float(v) for k, v in json.loads(record["action_parameters"]).items()}
            ),
            trial=int(record["trial"]),
            rig=MappingProxyType({k: str(v) for k, v in json.loads(record["rig"]).items()}),
            seed=int(record["seed"]),
            software_version=record["software_version"],
            schema_version=version,
        )
    except (ValueError, TypeError, AttributeError) as err:
        raise _metadata_error(path, f"malformed metadata record ({err})") from err


def check_contract(container: Container) -> None:
    """Check the profile and that every required channel is present, typed and non-empty.

    Raises:
        RecordingError: The first violation found, naming the file and the fix.
    """
    summary = container.summary
    path = summary.path
    if summary.profile != "ros2":
        msg = f"{path}: MCAP profile {summary.profile!r}, expected 'ros2'; not an atikt recording"
        raise RecordingError(msg)
    for channel in CHANNELS:
        found = summary.channels.get(channel.topic)
        fix = "the recording is incomplete: record the action again"
        if found is None or (channel.required and found.message_count == 0):
            state = "missing" if found is None else "empty"
            msg = f"{path}: required channel {channel.topic} ({channel.msgtype}) is {state}; {fix}"
            raise RecordingError(msg)
        if (found.msgtype, found.schema_encoding, found.message_encoding) != (
            channel.msgtype,
            "ros2msg",
            "cdr",
        ):
            msg = (
                f"{path}: channel {channel.topic} carries {found.msgtype} "
                f"({found.schema_encoding}/{found.message_encoding}), expected "
                f"{channel.msgtype} (ros2msg/cdr); not an atikt recording"
            )
            raise RecordingError(msg)


def _stamps(groups: Sequence[DecodedGroup], total: int) -> NDArray[np.int64]:
    """Return ``header.stamp`` of every message as int64 ns."""
    sec = gather(groups, "header.stamp.sec", total)[:, 0].astype(np.int64)
    nanosec = gather(groups, "header.stamp.nanosec", total)[:, 0].astype(np.int64)
    return sec * _NS_PER_S + nanosec


def _ordered(stamps: NDArray[np.int64], *arrays: NDArray[Any]) -> list[NDArray[Any]]:
    """Return stamps and arrays sorted by stamp (stable), all read-only."""
    if stamps.size > 1 and bool(np.any(np.diff(stamps) < 0)):
        order = np.argsort(stamps, kind="stable")
        stamps, arrays = stamps[order], tuple(a[order] for a in arrays)
    return [_frozen(np.ascontiguousarray(a)) for a in (stamps, *arrays)]


@dataclass(frozen=True, slots=True)
class _SkinPart:
    """The samples of one group of skin blocks sharing a layout."""

    message: NDArray[np.intp]  # message index of every sample
    stamps: NDArray[np.int64]  # sensor time of every sample
    periods: NDArray[np.int64]  # sample period of every message
    data: NDArray[np.float32]  # (samples, cells, channels)
    cells: NDArray[np.uint16]


def _skin_part(path: Path, topic: str, group: DecodedGroup) -> _SkinPart:
    """Unpack one group of skin blocks into per-sample stamps and data, vectorised.

    Raises:
        RecordingError: A block's shape fields disagree with its data.
    """
    numeric = group.numeric
    shape = np.concatenate([numeric[f] for f in ("n_samples", "n_cells", "n_channels")], axis=1)
    data = numeric["data"]
    if not (bool(np.all(shape == shape[0])) and int(shape[0].prod()) == data.shape[1]):
        msg = f"{path}: {topic}: n_samples * n_cells * n_channels does not match len(data)"
        raise RecordingError(msg)
    n_samples, n_cells, n_channels = (int(v) for v in shape[0])
    n_blocks = group.indices.size
    firsts = numeric["header.stamp.sec"][:, 0].astype(np.int64) * _NS_PER_S
    firsts += numeric["header.stamp.nanosec"][:, 0]
    periods = numeric["sample_period_ns"][:, 0].astype(np.int64)
    within = np.tile(np.arange(n_samples, dtype=np.int64), n_blocks)
    return _SkinPart(
        message=np.repeat(group.indices, n_samples),
        stamps=np.repeat(firsts, n_samples) + within * np.repeat(periods, n_samples),
        periods=periods,
        data=data.reshape(n_blocks * n_samples, n_cells, n_channels),
        cells=numeric["cell_ids"][0].astype(np.uint16),
    )


def _decode_skin(path: Path, modality: str, raw: RawChannel) -> SkinSeries:
    """Decode a skin channel into per-sample stamps and a (n, cells, channels) array."""
    msgtype = full_type_name(_SKIN_TYPES[modality])
    groups = decode_topic(build_typestore(), msgtype, raw.payloads)
    parts = [_skin_part(path, raw.info.topic, group) for group in groups]
    shapes = {part.data.shape[1:] for part in parts}
    if len(shapes) != 1:
        msg = f"{path}: {raw.info.topic}: blocks differ in cells x channels {sorted(shapes)}"
        raise RecordingError(msg)
    stamps = np.concatenate([part.stamps for part in parts])
    data = np.concatenate([part.data for part in parts]).astype(np.float32, copy=False)
    if len(parts) > 1:  # restore file order: by message, then sample (stable)
        order = np.argsort(np.concatenate([part.message for part in parts]), kind="stable")
        stamps, data = stamps[order], data[order]
    stamps, data = _ordered(stamps, data)
    return SkinSeries(
        modality=modality,
        stamps_ns=stamps,
        data=data,
        cell_ids=_frozen(parts[0].cells),
        period_ns=int(np.median(np.concatenate([part.periods for part in parts]))),
    )


def _decode_joints(raw: RawChannel) -> JointStates:
    """Decode ``sensor_msgs/msg/JointState`` messages."""
    msgtype = raw.info.msgtype
    groups = decode_topic(build_typestore(), msgtype, raw.payloads)
    total = len(raw.payloads)
    strings = groups[0].strings
    count = sum(1 for key in strings if key.startswith("name["))
    names = tuple(strings[f"name[{i}]"] for i in range(count))
    stamps, position, velocity, effort = _ordered(
        _stamps(groups, total),
        *(gather(groups, field, total) for field in ("position", "velocity", "effort")),
    )
    return JointStates(names, stamps, position, velocity, effort)


def _decode_poses(raw: RawChannel) -> TcpPoses:
    """Decode ``geometry_msgs/msg/PoseStamped`` messages."""
    groups = decode_topic(build_typestore(), raw.info.msgtype, raw.payloads)
    total = len(raw.payloads)

    def columns(prefix: str, axes: str) -> NDArray[np.float64]:
        return np.concatenate([gather(groups, f"{prefix}.{a}", total) for a in axes], axis=1)

    stamps, position, orientation = _ordered(
        _stamps(groups, total), columns("pose.position", "xyz"), columns("pose.orientation", "xyzw")
    )
    return TcpPoses(groups[0].strings["header.frame_id"], stamps, position, orientation)


def _decode_phases(raw: RawChannel) -> tuple[PhaseStart, ...]:
    """Decode the action events into phase starts, in time order."""
    store = build_typestore()
    marks = []
    for payload in raw.payloads:
        event: Any = store.deserialize_cdr(payload, raw.info.msgtype)
        stamp = int(event.header.stamp.sec) * _NS_PER_S + int(event.header.stamp.nanosec)
        marks.append(PhaseStart(str(event.phase), stamp))
    return tuple(sorted(marks, key=lambda mark: mark.start_ns))


def decode_recording(container: Container) -> ActionRecording:
    """Validate a container against the contract and decode it into an :class:`ActionRecording`.

    Raises:
        RecordingError: The recording violates the contract or a message is malformed.
    """
    path = container.summary.path
    metadata = parse_metadata(path, container.summary.metadata)
    check_contract(container)
    topics = container.topics
    skins = {
        modality: _decode_skin(path, modality, topics[_TOPICS[full_type_name(name)]])
        for modality, name in _SKIN_TYPES.items()
    }
    try:
        phases = _decode_phases(topics[_TOPICS[full_type_name("ActionEvent")]])
    except Exception as err:  # rosbags raises SerdeError, struct.error, ...
        msg = f"{path}: malformed action event ({err}); record the action again"
        raise RecordingError(msg) from err
    return ActionRecording(
        path=path,
        metadata=metadata,
        force=skins["force"],
        temperature=skins["temperature"],
        acceleration=skins["acceleration"],
        proximity=skins["proximity"],
        joints=_decode_joints(topics[_TOPICS["sensor_msgs/msg/JointState"]]),
        tcp=_decode_poses(topics[_TOPICS["geometry_msgs/msg/PoseStamped"]]),
        phases=phases,
    )


def read_recording(path: Path | str) -> ActionRecording:
    """Read one recording: check its CRCs, schema version and channels, decode it.

    Args:
        path: An ``.mcap`` file written by the recorder.

    Returns:
        The immutable recording.

    Raises:
        RecordingError: The file is unreadable, corrupt, or violates the contract; the message
            names the file and the fix.
    """
    return decode_recording(read_container(Path(path)))
