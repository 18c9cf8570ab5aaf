"""The import's own reading of stamps and fields from message bytes agrees with rosbags'.

Every message the generated decoders accept must give rosbags' values; every message rosbags
refuses must be refused by them (they return None and rosbags decodes it); an import gives
the same files whether the decoders or rosbags decode the messages.
"""

from __future__ import annotations

from io import BytesIO
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from labbags import (
    FINGERTIP_MAP,
    NS,
    START,
    fingertip_messages,
    fingertip_windows_csv,
    write_bag,
)
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from recorder import load_actions, load_objects
from recorder.bagimport import _importer
from recorder.bagimport._importer import import_bag
from recorder.bagimport._ros1 import StreamingReader, _records, _records_checked
from recorder.bagimport._topicmap import load_topic_map
from schemas.cdr import compile_cdr, compile_ros1

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path

#: Layouts with every kind of field before and between the mapped ones, among them an empty
#: sequence of 8-byte values before an 8-byte value (where CDR padding has a corner case).
TYPES = {
    "fd_msgs/msg/Inner": "uint8 a\nfloat64 b\nstring c\n",
    "fd_msgs/msg/Mixed": (
        "std_msgs/Header header\nuint8 flag\nfloat64 x\nstring label\nfloat32[] values\n"
        "int16[3] small\nfloat64[] empty\nfloat64 after\nfd_msgs/Inner inner\nuint64 big\n"
        "string[] names\nint8[] tail\nstring[2] pair\n"
    ),
    "fd_msgs/msg/Batch": "std_msgs/Header header\nfloat32[66] acc\nfloat32[3] force\nfloat32 t\n",
}
FIELDS = {
    "fd_msgs/msg/Mixed": ["values", "x", "small", "after", "inner.b", "big", "names", "tail"],
    "fd_msgs/msg/Batch": ["acc", "force", "t"],
}


def _store(*, ros1: bool) -> Any:
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    for name, text in TYPES.items():
        store.register(get_types_from_msg(text, name))
    return store


def _message(store: Any, msgtype: str, rng: np.random.Generator, *, ros1: bool) -> Any:
    t = store.types
    sec, nanosec = int(rng.integers(0, 2**31)), int(rng.integers(0, 10**9))
    stamp = t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
    frame = "x" * int(rng.integers(0, 7))
    extra = {"seq": 4} if ros1 else {}
    header = t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame, **extra)
    if msgtype == "fd_msgs/msg/Batch":
        return t[msgtype](
            header=header,
            acc=rng.normal(size=66).astype(np.float32),
            force=rng.normal(size=3).astype(np.float32),
            t=float(np.float32(rng.normal())),
        )
    inner = t["fd_msgs/msg/Inner"](a=3, b=float(rng.normal()), c="é" * int(rng.integers(0, 3)))
    return t[msgtype](
        header=header,
        flag=1,
        x=float(rng.normal()),
        label="ab" * int(rng.integers(0, 4)),
        values=rng.normal(size=int(rng.integers(0, 5))).astype(np.float32),
        small=rng.integers(-300, 300, 3).astype(np.int16),
        empty=np.zeros(int(rng.integers(0, 2))),
        after=float(rng.normal()),
        inner=inner,
        big=int(rng.integers(0, 2**63)),
        names=["j" * int(k) for k in rng.integers(0, 4, int(rng.integers(0, 3)))],
        tail=rng.integers(-5, 5, int(rng.integers(0, 4))).astype(np.int8),
        pair=["p", "qq"],
    )


def _agrees(decoded: tuple[Any, ...] | None, message: Any, fields: list[str], dtypes: Any) -> None:
    assert decoded is not None
    stamp = message.header.stamp
    assert decoded[:2] == (stamp.sec, stamp.nanosec)
    for path, value, dtype in zip(fields, decoded[2:], dtypes, strict=True):
        expected = message
        for part in path.split("."):
            expected = getattr(expected, part)
        if dtype is None:
            assert value == expected
        else:
            ours, theirs = np.frombuffer(value, dtype), np.asarray(expected, dtype).reshape(-1)
            assert np.array_equal(ours, theirs, equal_nan=dtype.kind == "f")


@pytest.mark.parametrize("ros1", [True, False])
@pytest.mark.parametrize("msgtype", sorted(FIELDS))
def test_decoders_read_what_rosbags_reads_and_refuse_what_it_refuses(
    msgtype: str, *, ros1: bool
) -> None:
    store = _store(ros1=ros1)
    fields = FIELDS[msgtype]
    make = compile_ros1 if ros1 else compile_cdr
    decoder = make(store, msgtype, fields, stamped=True)
    assert decoder is not None
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    deserialize = store.deserialize_ros1 if ros1 else store.deserialize_cdr
    rng = np.random.default_rng(5)
    for _ in range(40):
        message = _message(store, msgtype, rng, ros1=ros1)
        raw = bytes(serialize(message, msgtype))
        _agrees(decoder.decode(raw), deserialize(raw, msgtype), fields, decoder.dtypes)
        damaged = [raw[:cut] for cut in range(len(raw))] + [raw + b"\0" * 4]
        for _ in range(30):
            at = int(rng.integers(0, len(raw)))
            damaged.append(raw[:at] + bytes([int(rng.integers(0, 256))]) + raw[at + 1 :])
        for bad in damaged:
            try:
                expected = deserialize(bad, msgtype)
            except SerdeError:
                assert decoder.decode(bad) is None
                continue
            decoded = decoder.decode(bad)
            if decoded is not None:  # None: rosbags decodes it instead
                _agrees(decoded, expected, fields, decoder.dtypes)


@pytest.mark.parametrize("ros1", [True, False])
def test_repeated_names_reuse_their_decode_only_for_the_same_bytes_and_alignment(
    *, ros1: bool
) -> None:
    msgtype = "fd_msgs/msg/Mixed"
    store = _store(ros1=ros1)
    fields = FIELDS[msgtype]
    decoder = (compile_ros1 if ros1 else compile_cdr)(store, msgtype, fields, stamped=True)
    assert decoder is not None
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    deserialize = store.deserialize_ros1 if ros1 else store.deserialize_cdr
    rng = np.random.default_rng(11)
    previous = None
    hits = 0
    for number in range(80):
        message = _message(store, msgtype, rng, ros1=ros1)
        message.names = ["shoulder", "elbow"] if number % 7 else ["shoulder", "elbow", "w"]
        raw = bytes(serialize(message, msgtype))  # the frame and values shift the names
        decoded = decoder.decode(raw)
        _agrees(decoded, deserialize(raw, msgtype), fields, decoder.dtypes)
        assert decoded is not None
        names = decoded[2 + fields.index("names")]
        hits += names is previous
        previous = names
        for cut in range(len(raw) - 12, len(raw)):  # cut after the names: still refused
            try:
                deserialize(raw[:cut], msgtype)
            except SerdeError:
                assert decoder.decode(raw[:cut]) is None
    assert hits > 0  # the cache is used


def test_layouts_the_decoders_do_not_read_are_left_to_rosbags() -> None:
    store = get_typestore(Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg("std_msgs/Header header\nbool[4] on\n", "fd_msgs/msg/B"))
    for make in (compile_ros1, compile_cdr):
        assert make(store, "fd_msgs/msg/B", ["on"], stamped=True) is None  # bool values
        assert make(store, "fd_msgs/msg/B", ["missing"], stamped=True) is None
        # a sequence of messages
        assert make(store, "tf2_msgs/msg/TFMessage", [], stamped=False) is None
        assert make(store, "std_msgs/msg/String", [], stamped=True) is None  # no header


@pytest.mark.parametrize("storage", ["ros1", "sqlite3"])
def test_an_import_writes_the_same_files_with_rosbags_decoding(
    storage: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    messages, store = fingertip_messages(ros1=storage == "ros1")
    name = "tip.bag" if storage == "ros1" else "tip"
    bag = write_bag(tmp_path / name, storage, messages, store)
    (tmp_path / "windows.csv").write_text(fingertip_windows_csv(), encoding="utf-8")
    (tmp_path / "map.toml").write_text(FINGERTIP_MAP, encoding="utf-8")
    topic_map = load_topic_map(tmp_path / "map.toml")
    trees = []
    for name in ("generated", "rosbags"):
        if name == "rosbags":
            monkeypatch.setattr(_importer, "compile_ros1", lambda *_, **__: None)
            monkeypatch.setattr(_importer, "compile_cdr", lambda *_, **__: None)
        out = tmp_path / name
        import_bag(bag, topic_map, out, objects=load_objects(), actions=load_actions())
        files = sorted(p for p in out.rglob("*") if p.is_file())
        trees.append({p.relative_to(out).as_posix(): p.read_bytes() for p in files})
    assert len(trees[0]) > 3
    assert trees[0] == trees[1]


def _walk(records: Iterator[tuple[Any, int, bytes]]) -> list[Any]:
    out: list[Any] = []
    try:
        out.extend((c.id, t, raw) for c, t, raw in records)
    except Exception as err:  # noqa: BLE001 (the error itself is compared)
        out.append(repr(err))
    return out


def test_chunk_records_are_read_as_rosbags_reads_them(tmp_path: Path) -> None:
    messages, store = fingertip_messages(ros1=True)
    bag = write_bag(tmp_path / "tip.bag", "ros1", messages, store)
    with StreamingReader(bag) as reader:
        wanted = {c.id: c for c in reader.connections[1:]}
        chunk = reader._chunk(reader.chunk_infos[0].pos)
    rng = np.random.default_rng(2)
    variants = [chunk, chunk[: len(chunk) // 2], chunk[:-3]]
    head = chunk[:6000]  # damaged copies of the first records (and a cut one at the end)
    for _ in range(300):
        at = int(rng.integers(0, len(head)))
        variants.append(head[:at] + bytes([int(rng.integers(0, 256))]) + head[at + 1 :])
    for data in variants:
        for start, stop in ((None, None), (START + NS // 2, START + NS)):
            fast = _walk(_records(data, wanted, start, stop))
            checked = _walk(_records_checked(BytesIO(data), len(data), wanted, start, stop))
            assert fast == checked
    assert len(_walk(_records(chunk, wanted, None, None))) > 100
