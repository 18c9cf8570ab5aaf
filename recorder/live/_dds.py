"""ROS 2 topics over DDS, without a ROS installation (Cyclone DDS's Python binding).

A ROS 2 node on Cyclone DDS (``rmw_cyclonedds``) publishes topic ``/joint_states`` of type
``sensor_msgs/msg/JointState`` as the DDS topic ``rt/joint_states`` of type
``sensor_msgs::msg::dds_::JointState_``, serialized as little-endian CDR (XCDR1, the
encapsulation rosbags reads and writes). This module speaks that mapping: the DDS types are
generated at run time from the message definitions of a rosbags typestore (the standard ROS 2
types, the virtual lab's own, a topic map's ``[types]``), and the samples are moved as their
CDR bytes, so the bytes a reader hands on are exactly the bytes ``ros2 bag record`` would have
written into a bag, and the import's decoders read them unchanged.

Quality of service follows the publishers: a reader is reliable when every publisher of its
topic is (ROS 2's default profile), else best effort (the sensor-data profile), so it matches
both; durability is volatile (matches volatile and transient-local publishers).

This is the transport only (public as :mod:`recorder.live.dds`); what reads a topic map's
topics through it (``listen``, the ``[skin] transport = "ros2"`` live skin) is
:mod:`recorder.bagimport`'s, next to the import whose conversion it shares.
"""

from __future__ import annotations

import importlib
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication
from cyclonedds.core import (
    DDSException,
    InstanceState,
    Policy,
    Qos,
    ReadCondition,
    SampleState,
    ViewState,
    WaitSet,
)
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct, make_idl_struct
from cyclonedds.idl import types as idl
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from rosbags.interfaces import Nodetype
from rosbags.typesys import get_types_from_msg

from recorder.errors import RecorderError
from recorder.live._reader import DROPS_KEPT, Drop, Received, SourceReader
from schemas.cdr import header_stamp

# DataReader.take() deserializes every sample into a Python object; the import wants the CDR
# bytes (its compiled decoders read them), so samples are taken and written as bytes with the
# binding's own C layer, which DataReader.take and DataWriter.write call themselves.
_CLAYER: Any = importlib.import_module("cyclonedds._clayer")
ddspy_take = _CLAYER.ddspy_take
ddspy_write = _CLAYER.ddspy_write

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence

    from rosbags.typesys.store import Typestore

#: The virtual lab's own message types (the skin cell of the example topic map).
ATIKT_TYPES = {
    "atikt_msgs/msg/SkinCell": (
        "std_msgs/Header header\nfloat32[3] force\nfloat32[3] acc\nfloat32 temp\nfloat32 prox\n"
        "uint32 seq\n"  # counts the cell's messages: a map's ``counter = "seq"`` counts loss
    ),
}
#: Samples a reader's DDS cache keeps before the oldest is replaced (the reader thread takes
#: them every few ms; a replaced sample is counted missing from the stamps).
READER_DEPTH = 4096
#: Samples a writer keeps for late retransmission (reliable writers).
WRITER_DEPTH = 1000
#: cyclonedds.idl.types, untyped: its generic annotations are built at run time here.
_IDL: Any = idl
_ANY = SampleState.Any | ViewState.Any | InstanceState.Any
#: How long a reader lets samples gather after the first one woke it, s.
BATCH_S = 0.004
_POLL_NS = 20_000_000
_BASE: dict[str, Any] = {
    "bool": bool,
    "byte": idl.uint8,
    "char": idl.uint8,
    "int8": idl.int8,
    "uint8": idl.uint8,
    "int16": idl.int16,
    "uint16": idl.uint16,
    "int32": idl.int32,
    "uint32": idl.uint32,
    "int64": idl.int64,
    "uint64": idl.uint64,
    "float32": idl.float32,
    "float64": idl.float64,
    "string": str,
}


class DdsError(RecorderError):
    """DDS refused something (a domain id, a type, a topic)."""


#: Cyclone DDS configuration that keeps a participant on the loopback interface: discovery and
#: data over ``lo`` only, no multicast, the one peer 127.0.0.1. Cyclone DDS (0.11) still binds
#: its two unicast *receive* sockets to 0.0.0.0 (its UDP transport always does, whatever the
#: configuration), but advertises only 127.0.0.1 and sends from 127.0.0.1 only.
LOOPBACK_CONFIG = (
    '<CycloneDDS><Domain id="any"><General><Interfaces><NetworkInterface name="lo"/>'
    "</Interfaces><AllowMulticast>false</AllowMulticast></General><Discovery><Peers>"
    '<Peer address="127.0.0.1"/></Peers><ParticipantIndex>auto</ParticipantIndex>'
    "</Discovery></Domain></CycloneDDS>"
)


def _confine(domain_id: int) -> Any:  # noqa: ANN401 (a cyclonedds Domain)
    """Create the domain with :data:`LOOPBACK_CONFIG` (before any participant joins it).

    Returns:
        The domain, or None when this process has joined it already (a command line
        process has not: its participant is the first; a program that publishes and
        listens in one process shares the configuration of its first participant).
    """
    from cyclonedds.domain import Domain  # noqa: PLC0415

    try:
        return Domain(domain_id, LOOPBACK_CONFIG)
    except DDSException:  # the domain exists in this process: join it as it is
        return None


def dds_topic(topic: str) -> str:
    """Return the DDS topic of a ROS 2 topic (``/joint_states`` -> ``rt/joint_states``)."""
    return "rt/" + topic.lstrip("/")


def dds_type(msgtype: str) -> str:
    """Return the DDS type name of a ROS 2 type (``a/msg/B`` -> ``a::msg::dds_::B_``)."""
    package, kind, name = msgtype.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def ros_type(type_name: str) -> str:
    """Return the ROS 2 type of a DDS type name (the inverse of :func:`dds_type`)."""
    parts = type_name.split("::")
    if len(parts) != 4 or parts[2] != "dds_" or not parts[3].endswith("_"):  # noqa: PLR2004
        return type_name
    return f"{parts[0]}/{parts[1]}/{parts[3][:-1]}"


def leads_with_header(store: Typestore, msgtype: str) -> bool:
    """Whether a type's first field is a std_msgs/Header (its stamp at CDR offset 4)."""
    if msgtype not in store.fielddefs:
        return False
    fields = store.fielddefs[msgtype][1]
    return bool(fields) and fields[0][0] == "header" and fields[0][1][1] == "std_msgs/msg/Header"


def register_atikt_types(store: Typestore) -> Typestore:
    """Add the virtual lab's message types to a typestore (those it lacks) and return it."""
    for name, text in ATIKT_TYPES.items():
        if name not in store.fielddefs:
            store.register(get_types_from_msg(text, name))
    return store


class IdlTypes:
    """DDS types generated from a typestore's message definitions, cached by ROS 2 name."""

    def __init__(self, store: Typestore) -> None:
        """Keep the typestore."""
        self._store = store
        self._made: dict[str, type[IdlStruct]] = {}

    def get(self, msgtype: str) -> type[IdlStruct]:
        """Return the DDS type of ``msgtype`` (``pkg/msg/Name``).

        Raises:
            DdsError: The typestore does not know the type.
        """
        if msgtype not in self._made:
            if msgtype not in self._store.fielddefs:
                msg = (
                    f"message type {msgtype} is unknown; give its definition under [types] "
                    "of the topic map"
                )
                raise DdsError(msg)
            fields = {name: self._node(desc) for name, desc in self._store.fielddefs[msgtype][1]}
            name = msgtype.rsplit("/", 1)[-1]
            self._made[msgtype] = make_idl_struct(name, dds_type(msgtype), fields)
        return self._made[msgtype]

    def _node(self, desc: tuple[Any, ...]) -> Any:  # noqa: ANN401 (an IDL type annotation)
        """Return the IDL annotation of one field's type node."""
        kind, rest = desc
        if kind == Nodetype.BASE:
            name, bound = rest
            if name == "string" and bound:
                return _IDL.bounded_str[bound]
            return _BASE[name]
        if kind == Nodetype.NAME:
            return self.get(rest)
        sub = self._node(rest[0])
        if kind == Nodetype.ARRAY:
            return _IDL.array[sub, rest[1]]
        return _IDL.sequence[sub, rest[1]] if rest[1] else _IDL.sequence[sub]


def ros_qos(*, reliable: bool, depth: int) -> Qos:
    """Return the QoS of a ROS 2 endpoint (reliable: default profile, else sensor data)."""
    reliability = Policy.Reliability.Reliable(0) if reliable else Policy.Reliability.BestEffort
    return Qos(
        reliability,
        Policy.Durability.Volatile,
        Policy.History.KeepLast(depth),
        Policy.DataRepresentation(use_cdrv0_representation=True),
    )


@dataclass(frozen=True, slots=True)
class Publication:
    """A publisher seen on the domain: its ROS 2 topic and type, and whether it is reliable."""

    topic: str
    msgtype: str
    reliable: bool


def _publication(sample: Any) -> Publication | None:  # noqa: ANN401 (a DcpsEndpoint)
    """Return a discovered publication of a ROS 2 topic (None: another DDS topic)."""
    name = str(sample.topic_name)
    if not name.startswith("rt/"):
        return None
    reliability = sample.qos[Policy.Reliability] if sample.qos is not None else None
    reliable = isinstance(reliability, Policy.Reliability.Reliable)
    return Publication("/" + name[3:], ros_type(str(sample.type_name)), reliable)


class DdsDomain:
    """One DDS participant on a domain: discovery, raw readers and raw writers."""

    #: Domains this process confined to loopback (kept alive: deleting one ends it).
    _confined: dict[int, Any] = {}  # noqa: RUF012 (one registry per process)

    def __init__(self, domain_id: int, store: Typestore, *, loopback: bool = False) -> None:
        """Join the domain (on the loopback interface only, with ``loopback``).

        Without ``loopback`` the participant joins the interfaces Cyclone DDS picks, or those
        ``CYCLONEDDS_URI`` names; with it, this process's configuration confines it to ``lo``
        whatever ``CYCLONEDDS_URI`` says.

        Raises:
            DdsError: DDS refuses the domain id (0..232) or its configuration.
        """
        if loopback and DdsDomain._confined.get(domain_id) is None:
            DdsDomain._confined[domain_id] = _confine(domain_id)
        #: Whether this process confined the domain to loopback by its own configuration.
        self.confined = DdsDomain._confined.get(domain_id) is not None
        try:
            self.participant = DomainParticipant(domain_id)
        except DDSException as err:
            msg = (
                f"DDS domain {domain_id}: cannot join ({err}); give a domain id 0..232 and "
                "check CYCLONEDDS_URI"
            )
            raise DdsError(msg) from err
        self.domain_id = domain_id
        self.store = register_atikt_types(store)
        self.types = IdlTypes(self.store)
        self._topics: dict[str, Topic[Any]] = {}
        self._discovery = BuiltinDataReader(self.participant, BuiltinTopicDcpsPublication)
        self.seen: dict[str, list[Publication]] = {}

    def topic(self, topic: str, msgtype: str) -> Topic[Any]:
        """Return the DDS topic of a ROS 2 topic and type (created once).

        Raises:
            DdsError: The type is unknown, or the topic exists with another type.
        """
        if topic not in self._topics:
            self._topics[topic] = Topic(self.participant, dds_topic(topic), self.types.get(msgtype))
        made = self._topics[topic]
        if made.data_type.__idl_typename__.replace(".", "::") != dds_type(msgtype):
            msg = f"topic {topic}: used with two types here ({msgtype}); map each topic once"
            raise DdsError(msg)
        return made

    def discover(self) -> dict[str, list[Publication]]:
        """Return the ROS 2 publications seen so far, by topic."""
        for sample in self._discovery.take(256):
            if getattr(sample, "sample_info", None) is None or not sample.sample_info.valid_data:
                continue
            found = _publication(sample)
            if found is not None:
                self.seen.setdefault(found.topic, []).append(found)
        return self.seen

    def wait_for(self, topics: Iterable[str], timeout_s: float) -> dict[str, list[Publication]]:
        """Return the publications of ``topics`` seen within ``timeout_s`` (some may lack)."""
        wanted = set(topics)
        deadline = time.monotonic() + timeout_s
        while True:
            seen = self.discover()
            if wanted <= set(seen) or time.monotonic() >= deadline:
                return {t: seen[t] for t in wanted if t in seen}
            time.sleep(0.02)

    def reader(self, topic: str, msgtype: str, *, reliable: bool) -> RawReader:
        """Return a reader of a topic's CDR bytes."""
        return RawReader(self, topic, msgtype, reliable=reliable)

    def close(self) -> None:
        """Leave the domain now: delete the participant, its readers, writers and topics.

        The binding deletes an entity when Python collects it, which an exiting interpreter
        may never do; a peer then keeps this participant's readers matched until their lease
        ends, and each of its reliable writers lingers at its end for acknowledgements that
        never come (Cyclone DDS's default 1 s: a virtual lab's 8 topics took 8 s to stop).
        Safe to call twice; the binding's own deletion (``Entity.__del__``) is what runs.
        """
        self.participant.__del__()

    def writer(self, topic: str, msgtype: str, *, reliable: bool = True) -> RawWriter:
        """Return a writer of a topic's CDR bytes (for the virtual lab and the tests)."""
        made = DataWriter(
            self.participant,
            self.topic(topic, msgtype),
            qos=ros_qos(reliable=reliable, depth=WRITER_DEPTH),
        )
        return RawWriter(topic, made)


@dataclass(slots=True)
class RawWriter:
    """Publishes CDR bytes (with their encapsulation header) on one topic."""

    topic: str
    writer: DataWriter[Any]

    def write(self, raw: bytes) -> None:
        """Publish one message.

        Raises:
            DdsError: DDS refused it.
        """
        code = ddspy_write(self.writer._ref, raw)  # noqa: SLF001 (the binding's own handle)
        if code < 0:
            msg = f"topic {self.topic}: DDS refused a message (code {code})"
            raise DdsError(msg)

    def matched(self) -> int:
        """Return the number of readers matched."""
        status: Any = self.writer.get_publication_matched_status()  # type: ignore[no-untyped-call]
        return int(status.current_count)


class RawReader:
    """Takes one topic's samples as CDR bytes; ``receive`` is a :class:`SourceReader` source.

    A message larger than :attr:`max_bytes` is dropped and counted (:attr:`oversize`); its
    receive time and its header stamp (:func:`header_stamp`, when its type begins with a
    header) are kept for :meth:`dropped`, so that it is counted where it was stamped.
    :meth:`place` reads the same stamp for a :class:`SourceReader`'s full queue.
    """

    def __init__(self, domain: DdsDomain, topic: str, msgtype: str, *, reliable: bool) -> None:
        """Create the DDS reader (matching starts now)."""
        self.topic = topic
        self.msgtype = msgtype
        self.reader = DataReader(
            domain.participant,
            domain.topic(topic, msgtype),
            qos=ros_qos(reliable=reliable, depth=READER_DEPTH),
        )
        self._waitset = WaitSet(domain.participant)
        self._waitset.attach(ReadCondition(self.reader, _ANY))
        self._pending: deque[tuple[int, bytes]] = deque()
        self.clock = time.time_ns
        #: Largest message taken, bytes (0: no limit); a larger one is counted and dropped.
        self.max_bytes = 0
        #: Messages dropped for their size since the start (read by the consumer).
        self.oversize = 0
        #: Size of the latest message dropped for its size, bytes.
        self.oversize_bytes = 0
        #: Whether the type begins with a std_msgs/Header (a dropped message's stamp is read).
        self.stamped = leads_with_header(domain.store, msgtype)
        self._dropped: deque[Drop] = deque(maxlen=DROPS_KEPT)
        self._lock = threading.Lock()

    def take(self, receive_ns: int | None = None) -> list[bytes]:
        """Return the valid samples waiting now, as bytes (too large ones counted, dropped).

        ``receive_ns``: the take's time (None: now), kept with every message dropped.
        """
        taken = ddspy_take(self.reader._ref, _ANY, 256)  # noqa: SLF001 (the binding's handle)
        if isinstance(taken, int):
            msg = f"topic {self.topic}: DDS read failed (code {taken})"
            raise DdsError(msg)
        out = []
        limit = self.max_bytes
        for data, info in taken:
            if not info.valid_data:
                continue
            if limit and len(data) > limit:
                self._oversized(data, self.clock() if receive_ns is None else receive_ns)
                continue
            out.append(bytes(data))
        return out

    def _oversized(self, data: bytes, receive_ns: int) -> None:
        """Count a message dropped for its size and keep where it belongs (12 bytes read)."""
        stamp = header_stamp(data) if self.stamped else None
        with self._lock:
            self.oversize += 1
            self.oversize_bytes = len(data)
            self._dropped.append((receive_ns, stamp))

    def dropped(self) -> tuple[int, int, list[Drop]]:
        """Return the oversize count, the latest's size, and take the drops kept since.

        Each drop is ``(receive ns, header stamp or None)``; taken with the count, so every
        drop taken is in it.
        """
        with self._lock:
            taken = list(self._dropped)
            self._dropped.clear()
            return self.oversize, self.oversize_bytes, taken

    def place(self, item: Received) -> int | None:
        """Return the header stamp of a received sample (a :class:`SourceReader`'s ``place``).

        None: its type has no leading header, or its bytes are too short to hold one.
        """
        return header_stamp(item.payload[1]) if self.stamped else None

    def receive(self) -> Received | None:
        """Return one sample ``(topic, bytes)`` with its receive time, waiting 20 ms at most.

        After the first sample wakes the thread, it waits :data:`BATCH_S` more and takes
        everything then waiting: a topic at 1 kHz wakes its thread 1000 times a second
        otherwise, and with tens of topics the wake-ups, not the samples, cost the CPU. The
        receive time is the take's (at most ``BATCH_S`` after the arrival).
        """
        if not self._pending:
            if self._waitset.wait(_POLL_NS) > 0:
                time.sleep(BATCH_S)
            now = self.clock()
            self._pending.extend((now, raw) for raw in self.take(now))
            if not self._pending:
                return None
        receive_ns, raw = self._pending.popleft()
        return Received(receive_ns, (self.topic, raw))


def merge_received(readers: Sequence[SourceReader]) -> list[Received]:
    """Return what every reader has queued now, in receive order."""
    items = [item for reader in readers for item in reader.drain()]
    items.sort(key=lambda item: item.receive_ns)
    return items
