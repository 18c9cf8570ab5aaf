"""The MCAP writer: one action execution -> one chunked, zstd-compressed ``ros2`` MCAP file.

A rig's stream items become ROS 2 CDR messages on the contract's channels
(``schemas.CHANNELS``); MCAP ``log_time`` is the receive time, ``publish_time`` the sensor
stamp. The file is written under a temporary name (``<stem>.<token>.mcap.part``) beside the
target, flushed to the operating system at least every ``flush_interval_ns`` of log time (a
killed recorder loses less than that plus one sensor block), and linked to its final name only
when complete. The link fails if the final name exists: two recorders never clobber each other
and a recording is never overwritten.

Nothing in a file depends on the wall clock: the same rig, seed and software give the same bytes.
"""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Self

import numpy as np
from mcap.writer import CompressionType

from recorder._rig import facts
from recorder.errors import OutputExistsError, RecorderError
from recorder.writing._mcap import McapWriter
from recorder.writing._stream import JointSample, PhaseEvent, PoseSample, SkinBlock
from schemas import (
    INCOMPLETE_RECORD,
    MESSAGE_VERSION,
    PART_SUFFIX,
    SCHEMA_VERSION,
    SOURCES_RECORD,
    VOCABULARY,
    RecordingMetadata,
    SourceStats,
    build_typestore,
    check_rig,
    cli,
    encode_source_stats,
    software_version,
)

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Mapping, Sequence
    from types import TracebackType

    from numpy.typing import NDArray
    from rosbags.typesys.store import Typestore

    from recorder._catalog import ActionSpec, ObjectSpec
    from recorder._rig import Rig
    from recorder.writing._stream import StreamItem

#: Name of the file-level MCAP metadata record describing the recording.
METADATA_NAME = VOCABULARY.metadata_record
#: MCAP profile of every recording.
PROFILE = "ros2"
#: Default time between flushes, in log time: a killed recorder loses less than this.
FLUSH_INTERVAL_NS = 350_000_000

_NS_PER_S = 1_000_000_000


#: Prefix of the rig description's keys that a rig learned on connecting (a controller's
#: version): recorded in every file, never compared when a dataset is resumed.
FACT_PREFIX = "fact:"


def _identity(rig: Rig) -> dict[str, object]:
    """Return the rig's configuration and, prefixed, what it learned on connecting."""
    described: dict[str, object] = dict(rig.describe())
    described.update({f"{FACT_PREFIX}{key}": value for key, value in facts(rig).items()})
    return described


@dataclass(frozen=True, slots=True)
class RecordingInfo:
    """What a recording is: its metadata record and the layout of its robot channel.

    Attributes:
        metadata: The metadata record (object, action, trial, rig, seed, source, versions).
        joint_names: The robot's joint names in the order of its joint-state arrays (empty for
            a rig without an arm: then no joint states may be written).
    """

    metadata: RecordingMetadata
    joint_names: tuple[str, ...] = ()

    @classmethod
    def create(
        cls, obj: ObjectSpec, action: ActionSpec, trial: int, rig: Rig, seed: int
    ) -> RecordingInfo:
        """Describe the execution of ``action`` on ``obj`` by ``rig`` (source: recorder).

        Returns:
            The recording's description.
        """
        metadata = RecordingMetadata(
            object_id=obj.id,
            object_name=obj.name,
            object_description=obj.description,
            action_id=action.id,
            action_kind=str(action.kind),
            action_parameters=action.parameters(),
            trial=trial,
            rig=check_rig(_identity(rig)),
            seed=seed,
            source="recorder",
            software_version=software_version(),
            schema_version=SCHEMA_VERSION,
        )
        return cls(metadata, tuple(rig.joint_names))

    def to_metadata(self) -> dict[str, str]:
        """Return the metadata record's key-value pairs (deterministic, no wall-clock time)."""
        return self.metadata.encode()


@dataclass(frozen=True, slots=True)
class WrittenRecording:
    """What the writer wrote.

    Attributes:
        path: Final path of the recording.
        message_counts: Messages per topic.
        start_ns: First log time, ns.
        end_ns: Last log time, ns.
        size_bytes: File size in bytes.
        incomplete: Why a stop ended the action early (empty: the recording is complete).
        sources: The live sources' accounting written into the file (empty: none).
    """

    path: Path
    message_counts: Mapping[str, int]
    start_ns: int
    end_ns: int
    size_bytes: int
    incomplete: str = ""
    sources: tuple[SourceStats, ...] = ()


def _time(store: Typestore, stamp_ns: int) -> Any:  # noqa: ANN401 (typestore message class)
    """Return a ``builtin_interfaces/msg/Time`` for an integer-nanosecond stamp."""
    sec, nanosec = divmod(stamp_ns, _NS_PER_S)
    return store.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)


@dataclass(frozen=True, slots=True)
class _Template:
    """A message whose layout never changes: serialised once, then stamp and numbers patched.

    Joint states and TCP poses (250 messages per second) have constant strings and sequence
    lengths, so their CDR bytes differ only in the header stamp and the float64 values. The
    template keeps the constant bytes between those fields; a message is the join of the
    pieces with the new stamp and values (rosbags' serialiser builds a message object per
    sample and costs ten times as much).
    """

    pieces: tuple[bytes, ...]

    @classmethod
    def create(cls, payload: bytes, runs: Sequence[NDArray[np.float64]]) -> _Template:
        """Locate each run of float64 values (distinct sentinels, in payload order)."""
        pieces, start = [payload[:_STAMP_OFFSET]], _STAMP_OFFSET + _STAMP.size
        for run in runs:
            pattern = run.astype("<f8").tobytes()
            if payload.count(pattern) != 1 or payload.index(pattern) < start:
                msg = "template sentinel values are not unique in the payload"  # pragma: no cover
                raise RecorderError(msg)  # pragma: no cover
            offset = payload.index(pattern)
            pieces.append(payload[start:offset])
            start = offset + len(pattern)
        pieces.append(payload[start:])
        return cls(tuple(pieces))

    def fill(self, stamp_ns: int, runs: Sequence[NDArray[np.float64]]) -> bytes:
        """Return the payload with ``header.stamp`` and the runs (``<f8`` arrays) replaced."""
        pieces = self.pieces
        parts = [pieces[0], _STAMP.pack(*divmod(stamp_ns, _NS_PER_S))]
        for piece, run in zip(pieces[1:-1], runs, strict=True):
            parts += (piece, run.tobytes())
        parts.append(pieces[-1])
        return b"".join(parts)


@dataclass(frozen=True, slots=True)
class _BlockTemplate:
    """A skin block message of one shape: serialised once by rosbags, then patched.

    For a given modality and (samples, cells, channels) every byte before the samples is fixed
    but the header stamp and the sample period (the cell ids are ``0..cells-1``); the samples
    are the message's last field. A block is that head, patched, and the samples' bytes: the
    same bytes as rosbags' serialiser (``tests/recorder/test_writer.py`` compares them), which
    costs ~140 us a block building the message object, against a few us here.
    """

    head: bytes
    period_offset: int

    def fill(self, stamp_ns: int, period_ns: int, data: NDArray[np.float32]) -> bytes:
        """Return the message of a block with these stamp, period and samples."""
        head = bytearray(self.head)
        _STAMP.pack_into(head, _STAMP_OFFSET, *divmod(stamp_ns, _NS_PER_S))
        _PERIOD.pack_into(head, self.period_offset, period_ns)
        return b"".join((head, data.astype("<f4", copy=False).tobytes()))


_STAMP = struct.Struct("<iI")  # builtin_interfaces/msg/Time: int32 sec, uint32 nanosec
_STAMP_OFFSET = 4  # header.stamp follows the 4-byte CDR encapsulation header
_PERIOD = struct.Struct("<Q")  # sample_period_ns: uint64
_PERIOD_SENTINEL = 0x0123_4567_89AB_CDEF  # locates sample_period_ns in a block template


def _sentinels(size: int, seed: int) -> NDArray[np.float64]:
    """Return ``size`` distinctive float64 values that locate a field in a template."""
    return np.random.default_rng(seed).uniform(1e-300, 2e-300, size)


@dataclass(slots=True)
class _Encoder:
    """Turns stream items into (topic, publish time, CDR bytes)."""

    info: RecordingInfo
    store: Typestore = field(default_factory=build_typestore)
    _joints: _Template = field(init=False)
    _poses: _Template = field(init=False)
    _templates: dict[tuple[object, ...], Any] = field(init=False)
    _dispatch: dict[type, Callable[[Any], tuple[str, bytes]]] = field(init=False)

    def __post_init__(self) -> None:
        """Build the templates of the fixed-layout messages and the dispatch table."""
        self._dispatch = {
            SkinBlock: self._skin,
            JointSample: self._joint,
            PoseSample: self._pose,
            PhaseEvent: self._event,
        }
        # the templates depend only on the message types: those of the shared typestore are
        # made once per process, not once per recording
        self._templates = _SHARED_TEMPLATES if self.store is build_typestore() else {}
        self._joints = self._template(("joints", self.info.joint_names), self._joint_template)
        self._poses = self._template(("pose",), self._pose_template)

    def _template(self, key: tuple[object, ...], make: Callable[[], Any]) -> Any:  # noqa: ANN401
        """Return the template of ``key``, made by ``make`` the first time."""
        template = self._templates.get(key)
        if template is None:
            template = self._templates[key] = make()
        return template

    def _joint_template(self) -> _Template:
        runs = [_sentinels(max(len(self.info.joint_names), 1), seed) for seed in range(3)]
        return _Template.create(self._joint_message(0, *runs), runs)

    def _pose_template(self) -> _Template:
        pose = _sentinels(7, 3)
        return _Template.create(self._pose_message(0, pose[:3], pose[3:]), [pose[:3], pose[3:]])

    def encode(self, item: StreamItem) -> tuple[str, int, bytes]:
        """Return the topic, sensor stamp and CDR payload of one stream item.

        Raises:
            RecorderError: The item is not a stream item or its arrays have the wrong shape.
        """
        encoder = self._dispatch.get(type(item))
        if encoder is None:
            msg = f"rig yielded {type(item).__name__}; a rig must yield recorder.StreamItem values"
            raise RecorderError(msg)
        topic, payload = encoder(item)
        return topic, item.stamp_ns, payload

    def _header(self, stamp_ns: int, frame_id: str) -> Any:  # noqa: ANN401
        return self.store.types["std_msgs/msg/Header"](
            stamp=_time(self.store, stamp_ns), frame_id=frame_id
        )

    def _serialize(self, msg: object, msgtype: str) -> bytes:
        return bytes(self.store.serialize_cdr(msg, msgtype))

    def _skin(self, block: SkinBlock) -> tuple[str, bytes]:
        data = np.asarray(block.data, dtype=np.float32)
        if data.ndim != 3 or data.shape[0] == 0:  # noqa: PLR2004 (samples, cells, channels)
            msg = (
                f"{block.modality} block of shape {data.shape}: a skin block needs shape "
                "(samples >= 1, cells, channels)"
            )
            raise RecorderError(msg)
        spec = VOCABULARY.modalities.get(str(block.modality))
        if spec is None:
            known = ", ".join(VOCABULARY.modalities)
            msg = f"rig yielded a block of modality {block.modality!r}; known: {known}"
            raise RecorderError(msg)
        template: _BlockTemplate = self._template(
            (spec.msgtype, *data.shape), lambda: self._block_template(spec.msgtype, data.shape)
        )
        return spec.topic, template.fill(block.stamp_ns, block.period_ns, data)

    def _block_message(
        self, msgtype: str, stamp_ns: int, period_ns: int, data: NDArray[np.float32]
    ) -> bytes:
        """Serialise a skin block with rosbags (the reference encoding)."""
        n_samples, n_cells, n_channels = data.shape
        message = self.store.types[msgtype](
            header=self._header(stamp_ns, "skin"),
            schema_version=MESSAGE_VERSION,
            sample_period_ns=period_ns,
            n_samples=n_samples,
            n_cells=n_cells,
            n_channels=n_channels,
            cell_ids=np.arange(n_cells, dtype=np.uint16),
            data=np.ascontiguousarray(data).reshape(-1),
        )
        return self._serialize(message, msgtype)

    def _block_template(self, msgtype: str, shape: tuple[int, ...]) -> _BlockTemplate:
        """Serialise a block of ``shape`` once and locate its sample period and samples."""
        samples = np.zeros(shape, dtype=np.float32)
        payload = self._block_message(msgtype, 0, _PERIOD_SENTINEL, samples)
        period = _PERIOD.pack(_PERIOD_SENTINEL)
        head = payload[: len(payload) - samples.nbytes]
        if payload.count(period) != 1 or head.count(period) != 1:  # pragma: no cover
            msg = f"{msgtype}: the sample period is not found once in its message"
            raise RecorderError(msg)
        return _BlockTemplate(head, head.index(period))

    def _joint_message(
        self,
        stamp_ns: int,
        position: NDArray[np.float64],
        velocity: NDArray[np.float64],
        effort: NDArray[np.float64],
    ) -> bytes:
        """Serialise a ``sensor_msgs/msg/JointState`` with rosbags (the reference encoding)."""
        msgtype = _JOINTS.msgtype
        message = self.store.types[msgtype](
            header=self._header(stamp_ns, _JOINTS.frame),
            name=list(self.info.joint_names) or [""],
            position=position,
            velocity=velocity,
            effort=effort,
        )
        return self._serialize(message, msgtype)

    def _joint(self, sample: JointSample) -> tuple[str, bytes]:
        size = len(self.info.joint_names)
        if size == 0:
            msg = "rig yielded a joint state but names no joints (Rig.joint_names is empty)"
            raise RecorderError(msg)
        runs = (
            _vector(sample.position, size, "joint position"),
            _vector(sample.velocity, size, "joint velocity"),
            _vector(sample.effort, size, "joint effort"),
        )
        return _JOINTS.topic, self._joints.fill(sample.stamp_ns, runs)

    def _pose_message(
        self, stamp_ns: int, position: NDArray[np.float64], orientation: NDArray[np.float64]
    ) -> bytes:
        """Serialise a ``geometry_msgs/msg/PoseStamped`` with rosbags (the reference encoding)."""
        msgtype = _POSES.msgtype
        types = self.store.types
        x, y, z = (float(v) for v in position)
        qx, qy, qz, qw = (float(v) for v in orientation)
        pose = types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=x, y=y, z=z),
            orientation=types["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
        )
        message = types[msgtype](header=self._header(stamp_ns, _POSES.frame), pose=pose)
        return self._serialize(message, msgtype)

    def _pose(self, sample: PoseSample) -> tuple[str, bytes]:
        runs = (
            _vector(sample.position, 3, "TCP position"),
            _vector(sample.orientation, 4, "TCP orientation"),
        )
        return _POSES.topic, self._poses.fill(sample.stamp_ns, runs)

    def _event(self, event: PhaseEvent) -> tuple[str, bytes]:
        if event.phase not in VOCABULARY.phases:
            known = ", ".join(VOCABULARY.phases)
            msg = f"rig yielded a phase event {event.phase!r}; known phases: {known}"
            raise RecorderError(msg)
        events = VOCABULARY.events
        meta = self.info.metadata
        parameters = meta.action_parameters
        message = self.store.types[events.msgtype](
            header=self._header(event.stamp_ns, events.frame),
            schema_version=MESSAGE_VERSION,
            object_id=meta.object_id,
            action_id=meta.action_id,
            action_kind=meta.action_kind,
            trial=meta.trial,
            phase=event.phase,
            depth_m=parameters.get("depth_m", 0.0),
            force_n=parameters.get("force_n", 0.0),
            speed_m_s=parameters.get("speed_m_s", 0.0),
            duration_s=parameters["duration_s"],
        )
        return events.topic, self._serialize(message, events.msgtype)


#: Templates of the shared typestore's messages, by message and layout (see ``_Encoder``).
_SHARED_TEMPLATES: dict[tuple[object, ...], Any] = {}
_JOINTS = VOCABULARY.robot["joint_states"]
_POSES = VOCABULARY.robot["tcp_pose"]
TYPE_OF_TOPIC = {
    **{spec.topic: spec.msgtype for spec in VOCABULARY.robot.values()},
    **{spec.topic: spec.msgtype for spec in VOCABULARY.modalities.values()},
    VOCABULARY.events.topic: VOCABULARY.events.msgtype,
}


def _vector(values: Iterable[float], size: int, what: str) -> NDArray[np.float64]:
    """Return ``values`` as a float64 vector of length ``size``.

    Raises:
        RecorderError: The length is wrong.
    """
    if type(values) is np.ndarray and values.dtype == _F8 and values.shape == (size,):
        return values  # the rigs' usual case, checked without a conversion
    array = np.asarray(values, dtype=_F8).reshape(-1)
    if array.shape != (size,):
        msg = f"{what} has {array.size} values; the rig must give {size}"
        raise RecorderError(msg)
    return array


_F8 = np.dtype("<f8")


def _temporary_path(final: Path) -> Path:
    """Return a fresh temporary name beside ``final`` (``<stem>.<token>.mcap.part``)."""
    stem = final.name.removesuffix(".mcap")
    return final.with_name(f"{stem}.{os.getpid()}-{secrets.token_hex(4)}{PART_SUFFIX}")


def incomplete_path(final: Path, attempt: int = 1) -> Path:
    """Return the name of an incomplete recording of ``final``.

    ``001.incomplete.mcap``, then ``001.incomplete-2.mcap``, ... when the trial stopped again.
    """
    stem = final.name.removesuffix(".mcap")
    suffix = "" if attempt == 1 else f"-{attempt}"
    return final.with_name(f"{stem}.incomplete{suffix}.mcap")


#: Most incomplete recordings kept of one trial (a rig that stops every time needs fixing).
MAX_INCOMPLETE = 999


def _open_exclusive(path: Path) -> IO[bytes]:
    """Create ``path`` for writing; fail if it exists (two recorders never share a file)."""
    return path.open("xb")


def _exists_error(final: Path) -> OutputExistsError:
    msg = (
        f"{final}: a recording with this name exists and is never overwritten; "
        "choose another --out directory or trial number"
    )
    return OutputExistsError(msg)


_FIXES = {
    errno.ENOSPC: "the disk is full: free space, then record the action again",
    errno.EDQUOT: "the disk quota is exhausted: free space, then record the action again",
    errno.EACCES: "the directory is not writable: fix its permissions or choose another --out",
    errno.EPERM: "the directory is not writable: fix its permissions or choose another --out",
    errno.EROFS: "the file system is read-only: choose another --out",
}


def _fix(err: OSError) -> str:
    """Return what to do about a failed file operation."""
    return _FIXES.get(
        err.errno or 0, "check free space and the directory, then record the action again"
    )


def _write_error(final: Path, err: OSError) -> RecorderError:
    """Return the error for a failed write (disk full, file system gone, ...)."""
    return RecorderError(
        f"{final}: writing the recording failed ({err.strerror or err}); {_fix(err)}"
    )


def _create_error(final: Path, err: OSError) -> RecorderError:
    """Return the error for a recording that cannot be created (directory missing, read-only)."""
    return RecorderError(
        f"{final}: cannot create the recording ({err.strerror or err}); {_fix(err)}"
    )


def _sync_directory(directory: Path) -> None:
    """Make a new name in ``directory`` durable (best effort: not every system allows it)."""
    try:
        descriptor = os.open(directory, os.O_RDONLY)
    except OSError:  # pragma: no cover (Windows cannot open directories)
        return
    try:
        os.fsync(descriptor)
    except OSError:  # pragma: no cover (some file systems refuse to sync a directory)
        pass
    finally:
        os.close(descriptor)


def _link_no_replace(temporary: Path, final: Path) -> None:
    """Give the complete file ``temporary`` the name ``final``, never replacing a file.

    Hard-linking is atomic and fails if ``final`` exists. Where the file system has no hard
    links, the final name is reserved by exclusive creation before the rename.

    Raises:
        OutputExistsError: ``final`` exists.
        RecorderError: The file system refused both ways.
    """
    try:
        os.link(temporary, final)
    except FileExistsError as err:
        raise _exists_error(final) from err
    except OSError:
        _reserve_and_replace(temporary, final)
    else:
        temporary.unlink()


def _reserve_and_replace(temporary: Path, final: Path) -> None:
    """Fallback of :func:`_link_no_replace` for file systems without hard links."""
    try:
        os.close(os.open(final, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError as err:
        raise _exists_error(final) from err
    except OSError as err:
        raise _create_error(final, err) from err
    temporary.replace(final)


class RecordingWriter:
    """Write one action execution to ``path`` (a context manager).

    On a clean exit the file is finished, synced and given its final name; on an error the
    temporary file is removed and the final name is never created.

    Example:
        >>> with RecordingWriter(path, info) as writer:  # doctest: +SKIP
        ...     for item in rig.perform(obj, action, trial):
        ...         writer.write(item)
    """

    def __init__(
        self,
        path: Path,
        info: RecordingInfo,
        *,
        flush_interval_ns: int = FLUSH_INTERVAL_NS,
        chunk_size: int = 4 * 1024 * 1024,
        compression: CompressionType = CompressionType.ZSTD,
        durable: bool = True,
    ) -> None:
        """Prepare to write ``path``; nothing is created before ``__enter__``.

        Args:
            path: Final path of the recording (``.mcap``).
            info: What is recorded, for the metadata record and the annotations.
            flush_interval_ns: Flush at least this often in log time, ns.
            chunk_size: Largest uncompressed chunk, bytes (flushes usually end chunks first).
            compression: Chunk compression (zstd; NONE for debugging).
            durable: Sync the file and its name to the disk before it gets its final name
                (the default: a recording counts as written once it is on the disk). False
                only for files that can be made again and whose writer syncs them later
                (a dataset recorded from a seed, synced once before its index).
        """
        self.path = Path(path)
        self.info = info
        self._flush_interval_ns = flush_interval_ns
        self._chunk_size = chunk_size
        self._compression = compression
        self._durable = durable
        self._encoder = _Encoder(info)
        self._temporary: Path | None = None
        self._stream: IO[bytes] | None = None
        self._writer: McapWriter | None = None
        self._channel_ids: dict[str, int] = {}
        self._sequences: dict[str, int] = {}
        self._last_flush_ns: int | None = None
        self._start_ns: int | None = None
        self._end_ns = 0
        self._incomplete: tuple[str, int] | None = None
        self._sources: tuple[SourceStats, ...] = ()
        self.result: WrittenRecording | None = None

    def mark_incomplete(self, reason: str, at_ns: int = 0) -> None:
        """Keep the file on a clean exit, but as incomplete: a stop ended the action early.

        The file gets a metadata record ``atikt.incomplete`` (reason, time of the stop) and
        the name ``<trial>.incomplete.mcap`` beside the final name, which stays free for the
        action recorded again.
        """
        self._incomplete = (reason, at_ns)

    def add_sources(self, stats: Sequence[SourceStats]) -> None:
        """Write the live sources' accounting into the file (metadata record ``atikt.sources``).

        Raises:
            RecorderError: The writer is not open, a source name is invalid, or it failed.
        """
        if self._writer is None:
            msg = f"{self.path}: add_sources() outside the writer's 'with' block"
            raise RecorderError(msg)
        try:
            record = encode_source_stats(stats)
        except ValueError as err:
            msg = f"{self.path}: {err}"
            raise RecorderError(msg) from err
        try:
            self._writer.add_metadata(SOURCES_RECORD, record)
        except OSError as err:
            raise _write_error(self.path, err) from err
        self._sources = tuple(stats)

    def __enter__(self) -> Self:
        """Create the temporary file and write the header, schemas, channels and metadata.

        Raises:
            OutputExistsError: The final file exists already.
            RecorderError: The directory or file cannot be created.
        """
        if self.path.exists():
            raise _exists_error(self.path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._temporary = _temporary_path(self.path)
            self._stream = _open_exclusive(self._temporary)
        except OSError as err:
            raise _create_error(self.path, err) from err
        try:
            self._writer = self._start(self._stream)
        except BaseException as err:
            self._discard()
            if isinstance(err, OSError):
                raise _write_error(self.path, err) from err
            raise
        return self

    def _start(self, stream: IO[bytes]) -> McapWriter:
        """Start the MCAP file: header, metadata record, schemas and channels."""
        writer = McapWriter(
            stream,
            chunk_size=self._chunk_size,
            compression=self._compression,
            enable_data_crcs=True,
        )
        writer.start(profile=PROFILE, library=f"atikt/{software_version()}")
        writer.add_metadata(METADATA_NAME, self.info.to_metadata())
        self._register(writer, VOCABULARY.events.topic)
        return writer

    def _register(self, writer: McapWriter, topic: str) -> int:
        """Register a topic's schema and channel (on its first message: absent ones stay out)."""
        msgtype = TYPE_OF_TOPIC[topic]
        text, _ = self._encoder.store.generate_msgdef(msgtype, ros_version=2)
        schema_id = writer.register_schema(msgtype, "ros2msg", text.encode())
        channel_id = writer.register_channel(topic, "cdr", schema_id)
        self._channel_ids[topic] = channel_id
        self._sequences[topic] = 0
        return channel_id

    def write(self, item: StreamItem) -> None:
        """Encode and write one stream item; flush when the flush interval has passed.

        Raises:
            RecorderError: The writer is not open or the item is malformed.
        """
        if self._writer is None:
            msg = f"{self.path}: write() outside the writer's 'with' block"
            raise RecorderError(msg)
        topic, stamp_ns, payload = self._encoder.encode(item)
        log_ns = item.receive_ns
        try:
            channel_id = self._channel_ids.get(topic)
            if channel_id is None:
                channel_id = self._register(self._writer, topic)
            sequence = self._sequences[topic]
            self._sequences[topic] = sequence + 1
            self._writer.add_message(channel_id, log_ns, payload, stamp_ns, sequence)
            self._track_time(log_ns)
        except OSError as err:
            raise _write_error(self.path, err) from err

    def _track_time(self, log_ns: int) -> None:
        """Remember the time range and flush when ``flush_interval_ns`` of log time passed."""
        if self._start_ns is None or self._last_flush_ns is None:
            self._start_ns = self._last_flush_ns = log_ns
        self._start_ns = min(self._start_ns, log_ns)
        self._end_ns = max(self._end_ns, log_ns)
        if log_ns - self._last_flush_ns >= self._flush_interval_ns:
            self.flush()
            self._last_flush_ns = log_ns

    def flush(self) -> None:
        """End the open chunk and hand everything written so far to the operating system."""
        if self._writer is not None:
            self._writer.flush()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Finish and publish the file; after an error, keep what was written as incomplete.

        A file that holds messages is never deleted: it is finished as incomplete with the
        error as its reason, or, when even that fails (a full disk), left as its ``.part``
        for ``atikt-replay check FILE --recover``. A file without messages is removed.
        """
        if exc_type is None:
            self._finish()
        elif not self.written or issubclass(exc_type, OutputExistsError):
            self._discard()
        else:
            if self._incomplete is None:
                reason = (
                    cli.one_line(str(exc)) if exc is not None and str(exc) else exc_type.__name__
                )
                self._incomplete = (reason, 0)
            with contextlib.suppress(RecorderError):  # the first error is the one to report
                self._finish()

    @property
    def kept(self) -> Path | None:
        """Where what was written is, once the writer has exited.

        The (incomplete) recording, or the ``.part`` left when even finishing it failed (a
        full disk); None: nothing was kept.
        """
        if self.result is not None:
            return self.result.path
        if self._temporary is not None and self._temporary.exists():
            return self._temporary
        return None

    @property
    def written(self) -> int:
        """Return how many messages were written so far."""
        return sum(self._sequences.values())

    def _finish(self) -> None:
        """Write the summary, sync, close and link the file to its final name."""
        if self._writer is None or self._stream is None or self._temporary is None:
            return
        try:
            if self._incomplete is not None:
                reason, at_ns = self._incomplete
                record = {"reason": reason, "stopped_ns": str(at_ns)}
                self._writer.add_metadata(INCOMPLETE_RECORD, record)
            self._writer.finish()
            self._stream.flush()
            if self._durable:
                os.fsync(self._stream.fileno())
            self._stream.close()
            final = self._publish(self._temporary)
            if self._durable:
                _sync_directory(self.path.parent)
        except BaseException as err:
            if self.written and not isinstance(err, OutputExistsError):
                kept = self._keep_part(err)
                if isinstance(err, OSError):
                    raise kept from err
                raise
            self._discard()
            if isinstance(err, OSError):
                raise _write_error(self.path, err) from err
            raise
        self.result = WrittenRecording(
            path=final,
            message_counts=dict(self._sequences),
            start_ns=self._start_ns or 0,
            end_ns=self._end_ns,
            size_bytes=final.stat().st_size,
            incomplete=self._incomplete[0] if self._incomplete else "",
            sources=self._sources,
        )
        self._writer = None

    def _publish(self, temporary: Path) -> Path:
        """Link the finished file to its final name (an incomplete one to a free variant)."""
        if self._incomplete is None:
            _link_no_replace(temporary, self.path)
            return self.path
        for attempt in range(1, MAX_INCOMPLETE + 1):
            target = incomplete_path(self.path, attempt)
            try:
                _link_no_replace(temporary, target)
            except OutputExistsError:
                continue
            return target
        raise _exists_error(incomplete_path(self.path, MAX_INCOMPLETE))

    def _keep_part(self, err: BaseException) -> RecorderError:
        """Close the temporary file and keep it (it holds recorded messages); say where."""
        self._writer = None
        with contextlib.suppress(OSError):
            if self._stream is not None:
                self._stream.close()
        part = self._temporary
        why = f"{err.strerror or err}); {_fix(err)}" if isinstance(err, OSError) else f"{err})"
        return RecorderError(
            f"{self.path}: writing the recording failed ({cli.one_line(why)}; what was written "
            f"is kept in {part}: salvage it with 'atikt-replay check {part} --recover'"
        )

    def _discard(self) -> None:
        """Close and delete the temporary file (whatever closing it says: the disk may be full)."""
        self._writer = None
        try:
            if self._stream is not None:
                self._stream.close()
        except OSError:
            pass  # the buffered rest could not be written; the file is deleted anyway
        finally:
            if self._temporary is not None:
                with contextlib.suppress(OSError):  # a leftover .part is never read as complete
                    self._temporary.unlink(missing_ok=True)
