from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.interfaces import Nodetype

from schemas import CHANNELS, build_typestore, full_type_name
from schemas.cdr import CdrError, decode_topic, gather, message_layout

if TYPE_CHECKING:
    from collections.abc import Sequence

STORE = build_typestore()
T = STORE.types


def _flatten(msgtype: str, msg: Any, prefix: str = "") -> dict[str, Any]:
    """Flatten a rosbags message into the decoder's field paths."""
    out: dict[str, Any] = {}
    fields: Sequence[tuple[str, tuple[int, Any]]] = STORE.fielddefs[msgtype][1]
    for name, (nodetype, details) in fields:
        path, value = f"{prefix}{name}", getattr(msg, name)
        if nodetype == Nodetype.NAME:
            out |= _flatten(details, value, f"{path}.")
        elif nodetype == Nodetype.BASE:
            out[path] = value if details[0] == "string" else np.array([value])
        elif details[0][0] == Nodetype.BASE and details[0][1][0] == "string":
            out |= {f"{path}[{i}]": item for i, item in enumerate(value)}
        elif details[0][0] == Nodetype.NAME:
            for i, item in enumerate(value):
                out |= _flatten(details[0][1], item, f"{path}[{i}].")
        else:
            out[path] = np.asarray(value)
    return out


def _assert_decodes_like_rosbags(msgtype: str, payloads: list[bytes]) -> None:
    groups = decode_topic(STORE, msgtype, payloads)
    indices = np.concatenate([g.indices for g in groups])
    assert sorted(indices.tolist()) == list(range(len(payloads)))
    for group in groups:
        for row, index in enumerate(group.indices):
            expected = _flatten(msgtype, STORE.deserialize_cdr(payloads[index], msgtype))
            for path, value in expected.items():
                if isinstance(value, str):
                    assert group.strings[path] == value, path
                else:
                    np.testing.assert_array_equal(group.numeric[path][row], value, err_msg=path)
            assert set(group.numeric) | set(group.strings) == set(expected)


def _header(sec: int, nanosec: int, frame: str) -> Any:
    stamp = T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
    return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)


def _joint_state(sec: int, names: list[str], values: list[float]) -> bytes:
    array = np.array(values, dtype=np.float64)
    msg = T["sensor_msgs/msg/JointState"](
        header=_header(sec, 7, "base" if sec % 2 else ""),
        name=names,
        position=array,
        velocity=array[: len(array) // 2],
        effort=-array,
    )
    return bytes(STORE.serialize_cdr(msg, "sensor_msgs/msg/JointState"))


def _skin(name: str, n_samples: int, cells: int, seed: int) -> bytes:
    data = np.random.default_rng(seed).normal(size=n_samples * cells * 3).astype(np.float32)
    msgtype = full_type_name(name)
    msg = T[msgtype](
        header=_header(seed, 999_999_999, "skin"),
        schema_version=1,
        sample_period_ns=seed * 1000 + 1,
        n_samples=n_samples,
        n_cells=cells,
        n_channels=3,
        cell_ids=np.arange(cells, dtype=np.uint16),
        data=data,
    )
    return bytes(STORE.serialize_cdr(msg, msgtype))


names = st.lists(st.text(alphabet="abc_xyz019", max_size=9), max_size=4)
values = st.lists(st.floats(allow_nan=False, width=64), max_size=5)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 2**31 - 1), names, values), min_size=1, max_size=8))
def test_joint_states_decode_like_rosbags(
    messages: list[tuple[int, list[str], list[float]]],
) -> None:
    payloads = [_joint_state(sec, n, v) for sec, n, v in messages]
    _assert_decodes_like_rosbags("sensor_msgs/msg/JointState", payloads)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 4), st.integers(0, 8)), min_size=1, max_size=8))
def test_skin_blocks_decode_like_rosbags(shapes: list[tuple[int, int]]) -> None:
    payloads = [_skin("SkinAcceleration", n, c, i) for i, (n, c) in enumerate(shapes)]
    _assert_decodes_like_rosbags(full_type_name("SkinAcceleration"), payloads)


def test_uniform_messages_form_one_group_and_gather_keeps_order() -> None:
    payloads = [_joint_state(sec, ["a", "b"], [sec, 2.0]) for sec in (1, 3, 5, 7)]
    payloads.insert(2, _joint_state(4, ["a", "b"], [4.0, 2.0]))  # another frame_id
    groups = decode_topic(STORE, "sensor_msgs/msg/JointState", payloads)
    assert [g.indices.tolist() for g in groups] == [[0, 1, 3, 4], [2]]
    position = gather(groups, "position", len(payloads))
    np.testing.assert_array_equal(position[:, 0], [1, 3, 4, 5, 7])


@pytest.mark.parametrize("channel", CHANNELS, ids=lambda c: c.topic)
def test_every_contract_type_has_a_layout(channel: Any) -> None:
    payload = _empty_message(channel.msgtype)
    _assert_decodes_like_rosbags(channel.msgtype, [payload, payload])


def _empty_message(msgtype: str) -> bytes:
    """Return a payload of ``msgtype`` with empty strings and sequences and zero numbers."""

    def build(typename: str) -> Any:
        fields: dict[str, Any] = {}
        defs: Sequence[tuple[str, tuple[int, Any]]] = STORE.fielddefs[typename][1]
        for name, (nodetype, details) in defs:
            if nodetype == Nodetype.NAME:
                fields[name] = build(details)
            elif nodetype == Nodetype.BASE:
                fields[name] = "" if details[0] == "string" else 0
            elif details[0][1][0] == "string":
                fields[name] = []
            else:
                fields[name] = np.zeros(0, dtype=np.float64)
        return T[typename](**fields)

    return bytes(STORE.serialize_cdr(build(msgtype), msgtype))


def test_malformed_payloads_are_cdr_errors() -> None:
    good = _skin("SkinForce", 2, 7, 1)
    with pytest.raises(CdrError, match="encapsulation header"):
        message_layout(STORE, full_type_name("SkinForce"), b"\x07" + good[1:])
    with pytest.raises(CdrError, match=r"field data: count 42 at byte \d+ needs at least 168"):
        message_layout(STORE, full_type_name("SkinForce"), good[:-8])
    pose = _empty_message("geometry_msgs/msg/PoseStamped")
    with pytest.raises(CdrError, match="shorter than its layout"):
        message_layout(STORE, "geometry_msgs/msg/PoseStamped", pose[:-8])
    cut = len(good) - 7 * 2 * 3 * 4 - 4 - 2  # inside the count of ``data``
    with pytest.raises(CdrError, match="field data: the length prefix at byte"):
        message_layout(STORE, full_type_name("SkinForce"), good[:cut])
    with pytest.raises(CdrError, match="malformed"):
        decode_topic(STORE, full_type_name("SkinForce"), [good[:30]])
