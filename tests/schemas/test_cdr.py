"""One set of CDR bounds checks: the column decoder and the generated decoders share them."""

from __future__ import annotations

import struct
from typing import Any

import numpy as np
import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from schemas import build_typestore
from schemas.cdr import MAX_DEPTH, CdrError, compile_cdr, compile_ros1, message_layout
from schemas.cdr._rules import count_fits, count_fits_source, length_fits, length_fits_source

STORE = build_typestore()


def test_each_rule_and_its_inlined_source_agree() -> None:
    rng = np.random.default_rng(0)
    for _ in range(2000):
        pos, size, length = (int(v) for v in rng.integers(0, 64, size=3))
        count, width, limit = int(rng.integers(0, 40)), int(rng.integers(1, 9)), 16
        names = {"pos": pos, "size": size, "length": length, "count": count}
        inlined_length = eval(length_fits_source("length", "pos + 4"), {}, names)  # noqa: S307
        assert inlined_length == length_fits(length, pos + 4, size)
        inlined_count = eval(count_fits_source(width, limit), {}, names)  # noqa: S307
        assert inlined_count == count_fits(count, width, pos, size, limit)


def _nested_store(levels: int) -> Any:
    store = get_typestore(Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg("float64 v", "deep/msg/L0"))
    for level in range(1, levels + 1):
        store.register(get_types_from_msg(f"deep/L{level - 1} inner", f"deep/msg/L{level}"))
    return store


def test_nesting_beyond_the_limit_is_refused_by_both_decoders() -> None:
    store = _nested_store(MAX_DEPTH + 1)
    payload = b"\x00\x01\x00\x00" + struct.pack("<d", 1.5)
    deepest_allowed = f"deep/msg/L{MAX_DEPTH}"
    assert message_layout(store, deepest_allowed, payload).numeric
    assert compile_cdr(store, deepest_allowed, [], stamped=False) is not None
    too_deep = f"deep/msg/L{MAX_DEPTH + 1}"
    with pytest.raises(CdrError, match=f"nest more than {MAX_DEPTH} deep"):
        message_layout(store, too_deep, payload)
    assert compile_cdr(store, too_deep, [], stamped=False) is None
    assert compile_ros1(store, too_deep, [], stamped=False) is None


def _joint_state(names: list[str]) -> bytes:
    types = STORE.types
    stamp = types["builtin_interfaces/msg/Time"](sec=1, nanosec=9)
    header = types["std_msgs/msg/Header"](stamp=stamp, frame_id="")
    values = np.arange(len(names), dtype=np.float64)
    msg = types["sensor_msgs/msg/JointState"](
        header=header, name=names, position=values, velocity=values, effort=values
    )
    return bytes(STORE.serialize_cdr(msg, "sensor_msgs/msg/JointState"))


def test_a_count_the_rest_cannot_hold_is_refused_by_both_decoders() -> None:
    good = _joint_state(["a", "b"])
    offset = good.index(struct.pack("<I", 2))  # the count of ``name`` (the first uint32 2)
    # Each name needs at least 4 bytes (its length prefix): a count of a quarter of the
    # payload cannot fit, though it is below the payload's length in bytes.
    bad = good[:offset] + struct.pack("<I", len(good) // 4) + good[offset + 4 :]
    with pytest.raises(CdrError, match=r"field name: count \d+ at byte \d+ needs at least"):
        message_layout(STORE, "sensor_msgs/msg/JointState", bad)
    fields = ["name", "position", "velocity", "effort"]
    decoder = compile_cdr(STORE, "sensor_msgs/msg/JointState", fields, stamped=True)
    assert decoder is not None
    assert decoder.decode(good) is not None
    assert decoder.decode(bad) is None  # left to rosbags, which refuses it


def test_a_length_prefix_beyond_the_message_is_refused_by_both_decoders() -> None:
    good = _joint_state(["abc"])
    offset = good.index(struct.pack("<I", 4) + b"abc\x00")  # "abc" with its NUL
    bad = good[:offset] + struct.pack("<I", len(good)) + good[offset + 4 :]
    with pytest.raises(CdrError, match=r"field name\[0\]: length prefix \d+ at byte"):
        message_layout(STORE, "sensor_msgs/msg/JointState", bad)
    fields = ["name", "position", "velocity", "effort"]
    decoder = compile_cdr(STORE, "sensor_msgs/msg/JointState", fields, stamped=True)
    assert decoder is not None
    assert decoder.decode(bad) is None
