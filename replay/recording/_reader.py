"""One recording -> an immutable, typed :class:`ActionRecording` (numpy arrays, phases, metadata).

Three layers: :mod:`replay.recording._container` reads the file and checks its CRCs,
:mod:`schemas.cdr` turns CDR payloads into arrays, and this module validates the
contract (profile, metadata, schema version, required channels, and with
:mod:`replay.recording._checks` message definitions, strictly increasing stamps, finite values,
phases and the action's duration) and assembles the typed recording. Nothing is repaired or
reordered silently: a file that breaks a rule is refused with a
:class:`replay.errors.RecordingError` naming it and the fix. Every array is read-only; time is
int64 nanoseconds of the sensor clock; ranges are half-open.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from replay.errors import RecordingError
from replay.recording._checks import (
    MAX_GAP_PERIODS,
    check_definitions,
    check_duration,
    check_finite,
    check_gaps,
    check_location,
    check_phases,
    check_stamps,
    dataset_root,
    index_row_problem,
    pauses_explained,
    read_index,
    time_scale,
)
from replay.recording._container import RawChannel, read_container
from schemas import (
    INCOMPLETE_RECORD,
    MESSAGE_VERSION,
    SOURCES_RECORD,
    VOCABULARY,
    ContractError,
    RecordingMetadata,
    SourceStats,
    build_typestore,
    parse_source_stats,
    unreadable,
)
from schemas import parse_metadata as read_metadata
from schemas.cdr import CdrError, DecodedGroup, decode_topic, gather

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from numpy.typing import NDArray

    from replay.recording._container import Container

#: Name of the file-level metadata record written by the recorder.
METADATA_NAME = VOCABULARY.metadata_record
#: Skin modalities of the contract, in contract order (a recording holds any subset).
MODALITIES = tuple(VOCABULARY.modalities)

_NS_PER_S = 1_000_000_000
_MAX_PERIOD_NS = 2**40  # about 18 minutes: a longer sample period is a damaged field
_DAMAGED = "the file is damaged: restore it from a copy or record the action again"
_ROBOT_OF_TOPIC_NAME = VOCABULARY.robot
_TYPE_OF_TOPIC = {
    **{spec.topic: spec.msgtype for spec in VOCABULARY.robot.values()},
    **{spec.topic: spec.msgtype for spec in VOCABULARY.modalities.values()},
    VOCABULARY.events.topic: VOCABULARY.events.msgtype,
}


def _frozen(array: NDArray[Any]) -> NDArray[Any]:
    """Return ``array`` marked read-only."""
    array.flags.writeable = False
    return array


def _span(stamps: NDArray[np.int64], start_ns: int, stop_ns: int) -> slice:
    """Return the slice of sorted ``stamps`` inside ``[start_ns, stop_ns)``."""
    lo, hi = np.searchsorted(stamps, [start_ns, stop_ns], side="left")
    return slice(int(lo), int(hi))


@dataclass(frozen=True, slots=True)
class SkinSeries:
    """The samples of one skin modality.

    Attributes:
        modality: One of the contract's modalities (``schemas.VOCABULARY.modalities``).
        stamps_ns: Sensor time of every sample, int64 ns, shape (n,), strictly increasing.
        data: Samples, float32, shape (n, cells, values), SI units (C for temperature); the
            number of cells and of values per cell are those of the recording's skin.
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
    """Joint states of the robot arm (joint count and names from the data).

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
        signals: The skin modalities the recording holds, by name, in contract order.
        joints: Joint states of the arm, or None (a fixed probe has no arm).
        tcp: TCP poses, or None.
        phases: Phase starts in time order (approach, contact, execute, retract, end; an
            import holds at least execute and end).
        sources: What each live source delivered (expected, received, missing...), for
            recordings of a live rig or a live listener; empty otherwise.
    """

    path: Path
    metadata: RecordingMetadata
    signals: Mapping[str, SkinSeries]
    joints: JointStates | None
    tcp: TcpPoses | None
    phases: tuple[PhaseStart, ...]
    sources: tuple[SourceStats, ...] = ()

    @property
    def modalities(self) -> tuple[str, ...]:
        """Return the skin modalities the recording holds, in contract order."""
        return tuple(self.signals)

    def skin(self, modality: str) -> SkinSeries:
        """Return the series of a modality by name.

        Raises:
            RecordingError: The recording holds no such modality; the message lists its own.
        """
        series = self.signals.get(modality)
        if series is None:
            held = ", ".join(self.signals) or "none"
            msg = f"{self.path}: the recording has no {modality!r} channel (it has: {held})"
            raise RecordingError(msg)
        return series

    @property
    def end_ns(self) -> int:
        """Return one nanosecond past the last stamp of any channel."""
        lasts = [series.stamps_ns[-1:] for series in self.signals.values()]
        lasts += [robot.stamps_ns[-1:] for robot in (self.joints, self.tcp) if robot is not None]
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


def parse_metadata(path: Path, records: Mapping[str, Mapping[str, str]]) -> RecordingMetadata:
    """Return the typed metadata record (:func:`schemas.parse_metadata`), checking it strictly.

    Raises:
        RecordingError: The record is missing or breaks the contract; the message names the
            file, the key and the fix.
    """
    record = records.get(METADATA_NAME)
    if record is None:
        msg = (
            f"{path}: no {METADATA_NAME!r} metadata record: not written by atikt-record or "
            "atikt-record import-bag; record or import it with them"
        )
        raise RecordingError(msg)
    try:
        return read_metadata(record)
    except ContractError as err:
        msg = f"{path}: metadata record: {err}"
        if "upgrade" not in str(err) and "release" not in str(err):
            msg += "; the file was not written by atikt-record or is damaged: record it again"
        raise RecordingError(msg) from err


def parse_sources(path: Path, records: Mapping[str, Mapping[str, str]]) -> tuple[SourceStats, ...]:
    """Return the live sources' accounting (``atikt.sources``; empty when there is none).

    Raises:
        RecordingError: The record is malformed.
    """
    record = records.get(SOURCES_RECORD)
    if record is None:
        return ()
    try:
        return parse_source_stats(record)
    except ValueError as err:
        msg = f"{path}: metadata record {SOURCES_RECORD!r}: {err}; {_DAMAGED}"
        raise RecordingError(msg) from err


def stopped_reason(records: Mapping[str, Mapping[str, str]]) -> str | None:
    """Return why a stop ended the recorded action early (None: the recording is complete)."""
    record = records.get(INCOMPLETE_RECORD)
    if record is None:
        return None
    return record.get("reason") or "unknown"


def _refuse_incomplete(path: Path, records: Mapping[str, Mapping[str, str]]) -> None:
    """Refuse a recording a stop ended early: it is kept for inspection, not for learning.

    Raises:
        RecordingError: The file carries the ``atikt.incomplete`` record.
    """
    reason = stopped_reason(records)
    if reason is not None:
        msg = (
            f"{path}: an incomplete recording (the action was stopped: {reason}); it is kept "
            f"for inspection (atikt-replay info {path}), not learned from; record the action "
            "again"
        )
        raise RecordingError(msg)


def _topics(metadata: RecordingMetadata) -> Mapping[str, str]:
    """Return the file's topic -> the contract's topic (schema 1 used other robot topics)."""
    legacy = VOCABULARY.legacy.get(metadata.schema_version)
    return legacy.topics if legacy is not None else {}


def _contract_channels(container: Container, metadata: RecordingMetadata) -> dict[str, RawChannel]:
    """Return the file's non-empty channels by contract topic, checking each one's type.

    Channels on topics outside the contract are a lab's extras: kept in the file, not read.

    Raises:
        RecordingError: The profile is not ros2, the events channel is missing, or a channel
            carries another type or encoding than the contract says.
    """
    summary = container.summary
    path = summary.path
    if summary.profile != "ros2":
        msg = (
            f"{path}: MCAP profile {summary.profile!r}, expected 'ros2': not an atikt "
            "recording; give one written by atikt-record"
        )
        raise RecordingError(msg)
    renamed = _topics(metadata)
    channels: dict[str, RawChannel] = {}
    for raw in container.topics.values():
        topic = renamed.get(raw.info.topic, raw.info.topic)
        expected = _TYPE_OF_TOPIC.get(topic)
        if expected is None or raw.info.message_count == 0:
            continue
        found = (raw.info.msgtype, raw.info.schema_encoding, raw.info.message_encoding)
        if found != (expected, "ros2msg", "cdr"):
            msg = (
                f"{path}: channel {raw.info.topic} carries {found[0]} ({found[1]}/{found[2]}), "
                f"the contract says {expected} (ros2msg/cdr): not an atikt recording; convert "
                "it with atikt-record import-bag"
            )
            raise RecordingError(msg)
        channels[topic] = raw
    events = VOCABULARY.events
    if events.topic not in channels:
        msg = (
            f"{path}: the action events channel {events.topic} ({events.msgtype}) is missing "
            "or empty: the recording is incomplete; record the action again"
        )
        raise RecordingError(msg)
    check_definitions(path, [raw.info for raw in channels.values()])
    return channels


def _check_needs(path: Path, metadata: RecordingMetadata, held: Sequence[str]) -> None:
    """Check that the recording holds every modality its action's kind needs.

    Raises:
        RecordingError: A needed modality is missing; names the kind, the modality and the fix.
    """
    kind = VOCABULARY.kind(metadata.action_kind)
    if missing := kind.missing(held):
        msg = (
            f"{path}: a {kind.name!r} action ({metadata.action_id}) needs the skin modality "
            f"{', '.join(missing)}, the recording has {', '.join(held) or 'none'}; record it "
            "with a skin that has it, or declare the action with a kind it fits"
        )
        raise RecordingError(msg)


def _groups(path: Path, raw: RawChannel, msgtype: str) -> list[DecodedGroup]:
    """Decode a channel's payloads (see :func:`schemas.cdr.decode_topic`).

    Raises:
        RecordingError: A payload is malformed; the message names the file and the channel.
    """
    try:
        return decode_topic(build_typestore(), msgtype, raw.payloads)
    except CdrError as err:  # the schemas' error, translated here with the file and the fix
        msg = f"{path}: {raw.info.topic}: {err}; {_DAMAGED}"
        raise RecordingError(msg) from err


def _gather(path: Path, topic: str, groups: Sequence[DecodedGroup], name: str) -> NDArray[Any]:
    """Return field ``name`` of every message (see :func:`schemas.cdr.gather`).

    Raises:
        RecordingError: The field's length differs between messages.
    """
    total = sum(group.indices.size for group in groups)
    try:
        return gather(groups, name, total)
    except CdrError as err:
        msg = f"{path}: {topic}: {err}; {_DAMAGED}"
        raise RecordingError(msg) from err


def _to_ns(path: Path, topic: str, sec: NDArray[Any], nanosec: NDArray[Any]) -> NDArray[np.int64]:
    """Return ``builtin_interfaces/Time`` fields as int64 ns.

    Raises:
        RecordingError: A nanosecond field is not below one second.
    """
    if nanosec.size and int(nanosec.max()) >= _NS_PER_S:
        msg = f"{path}: {topic}: a stamp has {int(nanosec.max())} nanoseconds; {_DAMAGED}"
        raise RecordingError(msg)
    return sec.astype(np.int64) * _NS_PER_S + nanosec.astype(np.int64)


def _stamps(path: Path, topic: str, groups: Sequence[DecodedGroup]) -> NDArray[np.int64]:
    """Return ``header.stamp`` of every message as int64 ns."""
    sec = _gather(path, topic, groups, "header.stamp.sec")[:, 0]
    return _to_ns(path, topic, sec, _gather(path, topic, groups, "header.stamp.nanosec")[:, 0])


def _checked(
    path: Path, topic: str, stamps: NDArray[np.int64], **signals: NDArray[Any]
) -> list[NDArray[Any]]:
    """Check stamps (strictly increasing) and signals (finite); return them read-only.

    Raises:
        RecordingError: A stamp repeats or goes back, or a value is not finite.
    """
    check_stamps(path, topic, stamps)
    for what, values in signals.items():
        check_finite(path, topic, stamps, values, what)
    return [_frozen(np.ascontiguousarray(a)) for a in (stamps, *signals.values())]


@dataclass(frozen=True, slots=True)
class _SkinPart:
    """The samples of one group of skin blocks sharing a layout."""

    message: NDArray[np.intp]  # message index of every sample
    stamps: NDArray[np.int64]  # sensor time of every sample
    periods: NDArray[np.int64]  # sample period of every message
    data: NDArray[np.float32]  # (samples, cells, channels)
    cells: NDArray[np.uint16]


def _block_shape(path: Path, topic: str, group: DecodedGroup) -> tuple[int, int, int]:
    """Return (samples, cells, channels) shared by a group of skin blocks.

    Raises:
        RecordingError: The blocks' shape fields differ or disagree with their data.
    """
    fields = ("n_samples", "n_cells", "n_channels")
    shape = np.concatenate([group.numeric[f].astype(np.int64) for f in fields], axis=1)
    n_samples, n_cells, n_channels = (int(v) for v in shape[0])  # Python ints: no overflow
    size = group.numeric["data"].shape[1]
    if not (bool(np.all(shape == shape[0])) and n_samples * n_cells * n_channels == size):
        msg = f"{path}: {topic}: n_samples * n_cells * n_channels does not match len(data); "
        raise RecordingError(msg + _DAMAGED)
    return n_samples, n_cells, n_channels


def _periods(path: Path, topic: str, group: DecodedGroup) -> NDArray[np.int64]:
    """Return the blocks' sample periods, ns.

    Raises:
        RecordingError: A period is not positive or absurdly long.
    """
    periods = group.numeric["sample_period_ns"][:, 0]
    low, high = int(periods.min()), int(periods.max())
    if not 0 < low <= high < _MAX_PERIOD_NS:
        msg = f"{path}: {topic}: sample_period_ns {low}..{high} is not a positive period; "
        raise RecordingError(msg + _DAMAGED)
    return periods.astype(np.int64)


def _skin_part(path: Path, topic: str, group: DecodedGroup) -> _SkinPart:
    """Unpack one group of skin blocks into per-sample stamps and data, vectorised.

    Raises:
        RecordingError: A block's fields are inconsistent or of another schema version.
    """
    numeric = group.numeric
    n_samples, n_cells, n_channels = _block_shape(path, topic, group)
    _check_versions(path, topic, numeric["schema_version"])
    stamp = numeric["header.stamp.sec"][:, 0], numeric["header.stamp.nanosec"][:, 0]
    firsts = _to_ns(path, topic, *stamp)
    periods = _periods(path, topic, group)
    n_blocks = group.indices.size
    within = np.tile(np.arange(n_samples, dtype=np.int64), n_blocks)
    return _SkinPart(
        message=np.repeat(group.indices, n_samples),
        stamps=np.repeat(firsts, n_samples) + within * np.repeat(periods, n_samples),
        periods=periods,
        data=numeric["data"].reshape(n_blocks * n_samples, n_cells, n_channels),
        cells=numeric["cell_ids"][0].astype(np.uint16),
    )


def _decode_skin(path: Path, modality: str, raw: RawChannel) -> SkinSeries:
    """Decode a skin channel into per-sample stamps and a (n, cells, channels) array."""
    groups = _groups(path, raw, VOCABULARY.modalities[modality].msgtype)
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
    stamps, data = _checked(path, raw.info.topic, stamps, **{modality: data})
    return SkinSeries(
        modality=modality,
        stamps_ns=stamps,
        data=data,
        cell_ids=_frozen(parts[0].cells),
        period_ns=int(np.median(np.concatenate([part.periods for part in parts]))),
    )


def _joint_names(path: Path, topic: str, groups: Sequence[DecodedGroup]) -> tuple[str, ...]:
    """Return the joint names, the same in every message.

    Raises:
        RecordingError: Messages name different joints.
    """
    named = set()
    for group in groups:
        count = sum(1 for key in group.strings if key.startswith("name["))
        named.add(tuple(group.strings[f"name[{i}]"] for i in range(count)))
    if len(named) != 1:
        msg = f"{path}: {topic}: messages name different joints {sorted(named)}; {_DAMAGED}"
        raise RecordingError(msg)
    return named.pop()


def _decode_joints(path: Path, raw: RawChannel) -> JointStates:
    """Decode ``sensor_msgs/msg/JointState`` messages."""
    topic = raw.info.topic
    groups = _groups(path, raw, raw.info.msgtype)
    names = _joint_names(path, topic, groups)
    columns = {
        field: _gather(path, topic, groups, field) for field in ("position", "velocity", "effort")
    }
    if any(values.shape[1] != len(names) for values in columns.values()):
        widths = {field: values.shape[1] for field, values in columns.items()}
        msg = f"{path}: {topic}: {len(names)} joint names but {widths} values; {_DAMAGED}"
        raise RecordingError(msg)
    stamps, position, velocity, effort = _checked(
        path, topic, _stamps(path, topic, groups), **columns
    )
    return JointStates(names, stamps, position, velocity, effort)


def _decode_poses(path: Path, raw: RawChannel) -> TcpPoses:
    """Decode ``geometry_msgs/msg/PoseStamped`` messages."""
    topic = raw.info.topic
    groups = _groups(path, raw, raw.info.msgtype)

    def columns(prefix: str, axes: str) -> NDArray[np.float64]:
        fields = [_gather(path, topic, groups, f"{prefix}.{a}") for a in axes]
        return np.concatenate(fields, axis=1)

    stamps, position, orientation = _checked(
        path,
        topic,
        _stamps(path, topic, groups),
        position=columns("pose.position", "xyz"),
        orientation=columns("pose.orientation", "xyzw"),
    )
    return TcpPoses(groups[0].strings["header.frame_id"], stamps, position, orientation)


def _check_versions(path: Path, topic: str, versions: NDArray[Any]) -> None:
    """Check the ``schema_version`` field of a channel's messages.

    Raises:
        RecordingError: A message has another version than this software reads.
    """
    found = sorted({int(v) for v in np.unique(versions)} - {MESSAGE_VERSION})
    if found:
        msg = (
            f"{path}: {topic}: messages of schema version {found[0]}, this software reads "
            f"version {MESSAGE_VERSION}; read the file with the atikt release that wrote it "
            "(or upgrade atikt: 'pip install -U atikt')"
        )
        raise RecordingError(msg)


def _check_event_subject(path: Path, group: DecodedGroup, metadata: RecordingMetadata) -> None:
    """Check that action events name the object and action of the metadata record.

    Raises:
        RecordingError: They name another object, action or trial.
    """
    said = {
        "object_id": metadata.object_id,
        "action_id": metadata.action_id,
        "action_kind": metadata.action_kind,
    }
    events = {key: group.strings[key] for key in said}
    trials = {int(v) for v in np.unique(group.numeric["trial"])}
    if events != said or trials != {metadata.trial}:
        msg = (
            f"{path}: the action events are about {events['object_id']} "
            f"{events['action_id']} ({events['action_kind']}) trial {sorted(trials)}, the "
            f"metadata record about {metadata.object_id} {metadata.action_id} "
            f"({metadata.action_kind}) trial {metadata.trial}; {_DAMAGED}"
        )
        raise RecordingError(msg)


def _decode_phases(
    path: Path, raw: RawChannel, metadata: RecordingMetadata
) -> tuple[PhaseStart, ...]:
    """Decode the action events into phase starts, in file order, and check them."""
    topic = raw.info.topic
    groups = _groups(path, raw, raw.info.msgtype)
    stamps = _stamps(path, topic, groups)
    names = [""] * stamps.size
    for group in groups:
        _check_versions(path, topic, group.numeric["schema_version"])
        _check_event_subject(path, group, metadata)
        for index in group.indices:
            names[int(index)] = group.strings["phase"]
    return tuple(PhaseStart(name, int(stamp)) for name, stamp in zip(names, stamps, strict=True))


def _check_duration(recording: ActionRecording) -> None:
    """Check the execute phase and the skin channels against the action's duration.

    Raises:
        RecordingError: The action is shorter than its parameters say.
    """
    path, meta = recording.path, recording.metadata
    duration_s = meta.action_parameters["duration_s"] * time_scale(path, meta.rig)
    explained = pauses_explained(recording.sources)
    coverage = {}
    for modality, series in recording.signals.items():
        first = int(series.stamps_ns[0]) if series.stamps_ns.size else recording.end_ns
        last = int(series.stamps_ns[-1]) + series.period_ns if series.stamps_ns.size else 0
        if explained and series.stamps_ns.size:  # a counted pause at an edge is no loss
            slack = MAX_GAP_PERIODS * series.period_ns
            first, last = first - slack, last + slack
        coverage[VOCABULARY.modalities[modality].topic] = (first, last)
    execute = recording.phase_range("execute")
    check_duration(path, (meta.action_id, duration_s), execute, coverage)
    check_gaps(path, execute, recording.signals, explained)


def check_not_partial(recording: ActionRecording) -> None:
    """Refuse a salvaged recording that lost its end as a recording of a dataset.

    Raises:
        RecordingError: The recording is a salvage without its end phase.
    """
    meta = recording.metadata
    if meta.source == "salvage" and "end" not in {mark.phase for mark in recording.phases}:
        msg = (
            f"{recording.path}: a salvaged recording that lost its end phase is not a recording "
            "of the dataset; keep it out of the dataset and record the action again"
        )
        raise RecordingError(msg)


def location_facts(recording: ActionRecording) -> dict[str, Any]:
    """Check a recording against its place in a dataset and return what its index row holds.

    The path part of :func:`check_dataset_location`: a salvage without its end is refused, and
    inside a dataset the metadata must say the object, action and trial its path says. The
    comparison with the dataset's index is left to the caller, which reads the index once
    (``atikt-replay check`` of a dataset).

    Returns:
        ``object_id``, ``action_id``, ``trial``, ``seed`` and ``size_bytes`` of the file.

    Raises:
        RecordingError: A salvage without its end, or the metadata contradicts the path.
    """
    check_not_partial(recording)
    path, meta = recording.path, recording.metadata
    said = {key: getattr(meta, key) for key in ("object_id", "action_id", "trial", "seed")}
    try:
        size = Path(path).stat().st_size
    except OSError as err:
        raise RecordingError(unreadable(path, err, "check the path", "the recording")) from err
    check_location(path, said)
    return {**said, "size_bytes": size}


def check_dataset_location(recording: ActionRecording) -> None:
    """Check a recording inside a dataset against its path and its row of the dataset index.

    :func:`read_recording` checks a file on its own; this adds the dataset's view
    (``atikt-replay check`` does the same, reading a dataset's index once for all its files).
    Outside a dataset (no ``index.parquet`` three levels up) nothing
    is checked.

    Raises:
        RecordingError: The metadata says another object, action or trial than the path, the
            index cannot be read, or it says another object, action, trial, seed or size.
    """
    facts = location_facts(recording)
    root = dataset_root(recording.path)
    rows = None if root is None else read_index(root)
    if root is not None and rows is not None:
        problem = index_row_problem(recording.path, root, rows, facts)
        if problem is not None:
            raise RecordingError(problem)


def decode_recording(container: Container) -> ActionRecording:
    """Validate a container against the contract and decode it into an :class:`ActionRecording`.

    One pass per layer: the metadata record, then each channel's type and definition, then
    each channel's payloads into arrays (stamps and values checked as they are decoded), then
    the recording as a whole (the kind's modalities, phases, duration, gaps).

    Raises:
        RecordingError: The recording violates the contract or a message is malformed.
    """
    path = container.summary.path
    metadata = parse_metadata(path, container.summary.metadata)
    _refuse_incomplete(path, container.summary.metadata)
    sources = parse_sources(path, container.summary.metadata)
    channels = _contract_channels(container, metadata)
    signals = {
        name: _decode_skin(path, name, channels[spec.topic])
        for name, spec in VOCABULARY.modalities.items()
        if spec.topic in channels
    }
    _check_needs(path, metadata, tuple(signals))
    joints, poses = (_ROBOT_OF_TOPIC_NAME[name].topic for name in ("joint_states", "tcp_pose"))
    events = _decode_phases(path, channels[VOCABULARY.events.topic], metadata)
    check_phases(path, events, VOCABULARY.sources[metadata.source].phases)
    recording = ActionRecording(
        path=path,
        metadata=metadata,
        signals=MappingProxyType(signals),
        joints=_decode_joints(path, channels[joints]) if joints in channels else None,
        tcp=_decode_poses(path, channels[poses]) if poses in channels else None,
        phases=events,
        sources=sources,
    )
    _check_duration(recording)
    return recording


def read_recording(path: Path | str) -> ActionRecording:
    """Read one recording: check its CRCs, schema version and channels, decode and check it.

    An unfinished (``*.mcap.part``) or truncated file is refused with the command that
    salvages it (``atikt-replay check FILE --recover``). The dataset's view of the file
    (path and index) is :func:`check_dataset_location`.

    Args:
        path: An ``.mcap`` file written by the recorder.

    Returns:
        The immutable recording.

    Raises:
        RecordingError: The file is unreadable, corrupt, or violates the contract; the message
            names the file and the fix.
    """
    return decode_recording(read_container(Path(path)))
