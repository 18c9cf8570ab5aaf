"""Skin frame layouts: the [skin] table's checks, parsing and building frames, the byte framer."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from skinframes import example, serial_example

from recorder.errors import RigError
from recorder.live import RecorderClock, SourceStats, open_skin, parse_source_stats
from recorder.live._accounting import encode_source_stats
from recorder.live._framelayout import FIELD_TYPES, parse_layout
from recorder.live._frames import ByteFramer, SerialSkin, UdpSkin, Unwrap
from recorder.virtuallab._skin_server import _Encoder

WHERE = "lab.toml"


def test_example_layout() -> None:
    layout = parse_layout(example(), WHERE)
    assert [(f.name, f.id, f.size, f.period_ns) for f in layout.frames] == [
        ("fast", 1, 93, 1_000_000),
        ("proximity", 2, 23, 20_000_000),
        ("temperature", 3, 23, 50_000_000),
    ]
    assert layout.magic == b"\xaa\x55"
    assert [layout.source(f) for f in layout.frames] == [
        "skin-fast",
        "skin-proximity",
        "skin-temperature",
    ]
    fast = layout.frames[0]
    assert fast.dtype("little", 7).itemsize == 93
    assert [item.count for item in fast.modalities] == [3, 3]


def test_open_skin_picks_the_transport() -> None:
    assert isinstance(open_skin(example(), RecorderClock(), WHERE), UdpSkin)
    serial = serial_example("/dev/null")
    assert isinstance(open_skin(serial, RecorderClock(), WHERE), SerialSkin)


def _frames(section: dict[str, Any]) -> dict[str, Any]:
    return section["frames"]  # type: ignore[no-any-return]


def _change(path: str, value: object) -> dict[str, Any]:
    """Return the example with the key at a dotted path set (None: removed)."""
    section = example()
    keys = path.split(".")
    table: dict[str, Any] = section
    for key in keys[:-1]:
        table[key] = dict(table[key])
        table = table[key]
    if value is None:
        del table[keys[-1]]
    else:
        table[keys[-1]] = value
    return section


REFUSALS = [
    (_change("transport", "tcp"), "[skin] transport = 'tcp': give one of udp, serial"),
    (_change("colour", "red"), "[skin] colour = 'red': unknown key"),
    (_change("bind", "localhost"), 'give "host:port"'),
    (_change("cells", 0), "[skin] cells = 0: give an integer >= 1"),
    (_change("cells", 100_000_000), "[skin] cells = 100000000: give an integer 1..65535"),
    (_change("byte_order", "middle"), "give one of little, big"),
    (_change("frames.fast.force.type", "i17"), "[skin.frames.fast.force] type = 'i17'"),
    (_change("frames.fast.force.scale", 0), "give a non-zero scale"),
    (_change("frames.fast.acceleration.at", 10), "overlaps"),
    (_change("frames.fast.force.at", 0), "force.at = 0: overlaps the header"),
    (_change("frames.fast.size", 50), "[skin.frames.fast] size = 50: give at least 93"),
    (_change("frames.proximity.id", 1), "give every frame type its own id"),
    (_change("frames.fast.id", None), "[skin.frames.fast] id = None"),
    (_change("frames.fast.rate_hz", -5), "give a finite number > 0"),
    (_change("frames.fast.sequence.type", "f32"), "[skin.frames.fast.sequence] type = 'f32'"),
    (_change("frames.fast.sequence.modulo", 70000), "give 2..65536"),
    (_change("frames.fast.stamp.unit_ns", None), "unit_ns = 'missing'"),
    (_change("frames.fast.cell_stride", None), "cell_stride = None"),
    (_change("frames.fast.cell_stride", 4), "cell_stride = 4: give at least 6"),
    (_change("frames.fast.cell_stride", 8), "x cell_stride = 17: overlaps acceleration.at"),
    (
        _change("frames.proximity.temperature", {"at": 23, "type": "i16", "cell_stride": 2}),
        "temperature.temperature = {...}: already sent in frames.proximity",
    ),
    (_change("frames.fast.force.colour", 1), "[skin.frames.fast.force] colour = 1"),
    (_change("frames.fast.force", "no"), "give a table"),
    (_change("header.id", None), "give [skin.header] id"),
    (_change("header.magic", [300]), "give the sync bytes"),
    (_change("frames", {}), "give at least one [skin.frames.<name>]"),
    (_change("frames", None), "[skin] frames = 'missing'"),
]


@pytest.mark.parametrize(("section", "message"), REFUSALS)
def test_layout_refusals(section: dict[str, Any], message: str) -> None:
    with pytest.raises(RigError) as refused:
        parse_layout(section, WHERE)
    text = str(refused.value)
    assert message in text
    assert text.startswith(f"{WHERE}: ")
    assert "\n" not in text


def test_refusals_without_sequence_and_on_serial() -> None:
    no_count = _change("frames.fast.sequence", None)
    no_count = _change("frames.fast.sequence", None) | {"frames": _frames(no_count)}
    fast = dict(_frames(no_count)["fast"])
    del fast["stamp"]
    no_count["frames"] = {**_frames(no_count), "fast": fast}
    with pytest.raises(RigError, match="so every frame is counted"):
        parse_layout(no_count, WHERE)
    serial = serial_example("/dev/ttyUSB0")
    del serial["header"]
    with pytest.raises(RigError, match=r"lab.toml: \[skin.header\] = missing: give magic"):
        parse_layout(serial, WHERE)
    per_cell = _change("frames.fast.cell", {"at": 2, "type": "u8"})
    with pytest.raises(RigError, match="overlaps"):
        parse_layout(per_cell, WHERE)


def test_unwrap_counts_across_the_wrap() -> None:
    unwrap = Unwrap(65536)
    raw = [65534, 65535, 0, 1, 65535, 2]
    assert [unwrap(r) for r in raw] == [65534, 65535, 65536, 65537, 65535, 65538]


_SCALES = {"f32": 1.0, "f64": 1.0}


@st.composite
def _layouts(draw: st.DrawFn) -> tuple[dict[str, Any], int]:
    cells = draw(st.integers(1, 8))
    kinds = [draw(st.sampled_from(list(FIELD_TYPES))) for _ in range(2)]
    counts = [draw(st.integers(1, 3)) for _ in range(2)]
    sizes = [np.dtype(FIELD_TYPES[k]).itemsize * c for k, c in zip(kinds, counts, strict=True)]
    scales = [draw(st.sampled_from([0.5, 0.001, 2.0, -0.25])) for _ in range(2)]
    stride = sizes[0] + sizes[1] + draw(st.integers(0, 3))
    frame: dict[str, Any] = {
        "rate_hz": draw(st.sampled_from([1000, 333, 20])),
        "sequence": {"at": 1, "type": draw(st.sampled_from(["u8", "u16", "i32"]))},
        "cell_stride": stride,
        "force": {"at": 8, "type": kinds[0], "count": counts[0], "scale": scales[0]},
        "acceleration": {
            "at": 8 + sizes[0],
            "type": kinds[1],
            "count": counts[1],
            "scale": scales[1],
            "offset": 0.5,
        },
    }
    section = {
        "transport": "udp",
        "byte_order": draw(st.sampled_from(["little", "big"])),
        "cells": cells,
        "header": {"magic": [0x7E]},
        "frames": {"only": frame},
    }
    return section, draw(st.integers(0, 2**32 - 1))


@settings(max_examples=60, deadline=None)
@given(_layouts(), st.integers(1, 20))
def test_frames_round_trip(drawn: tuple[dict[str, Any], int], samples: int) -> None:
    section, seed = drawn
    layout = parse_layout(section, WHERE)
    frame = layout.frames[0]
    rng = np.random.default_rng(seed)
    values: dict[str, Any] = {}
    for item in frame.modalities:
        kind = np.dtype(FIELD_TYPES[item.type])
        low, high = (-100, 100) if kind.kind == "f" else (np.iinfo(kind).min, np.iinfo(kind).max)
        raw = rng.integers(max(low, -1000), min(high, 1000), (samples, layout.cells, item.count))
        values[item.modality] = raw * item.scale + item.offset
    data = _Encoder(layout, frame).encode(range(samples), values)
    assert len(data) == samples * frame.size
    parsed = np.frombuffer(data, dtype=frame.dtype(layout.byte_order, layout.cells))
    decoded = frame.decode(parsed, layout.cells)
    for name, expected in values.items():
        np.testing.assert_allclose(decoded[name], expected.astype(np.float32), rtol=1e-6)
    modulo = frame.sequence.modulo if frame.sequence else 0
    assert parsed["sequence"].tolist() == [n % modulo for n in range(samples)]
    assert data[:: frame.size] == b"\x7e" * samples


def _stream_frames(count: int) -> tuple[ByteFramer, list[bytes]]:
    layout = parse_layout(serial_example("/dev/null"), WHERE)
    frame = layout.frames[0]
    samples = {name: np.ones((count, 7, 3)) for name in ("force", "acceleration")}
    data = _Encoder(layout, frame).encode(range(count), samples)
    frames = [data[i : i + frame.size] for i in range(0, len(data), frame.size)]
    return ByteFramer(layout), frames


@settings(max_examples=40, deadline=None)
@given(st.lists(st.integers(1, 200), min_size=1, max_size=60), st.sets(st.integers(1, 18)))
def test_framer_resyncs_after_garbage(chunks: list[int], broken: set[int]) -> None:
    framer, frames = _stream_frames(20)
    stream = b""
    for i, frame in enumerate(frames):
        # a sync loss: half a frame (the skin reset mid-frame), then the next frame
        stream += frame[: len(frame) // 2] if i in broken else frame
    got: list[bytes] = []
    position = 0
    for size in [*chunks, len(stream)]:
        got += framer.feed(stream[position : position + size])
        position += size
    got += framer.flush()
    assert got == [frame for i, frame in enumerate(frames) if i not in broken]
    assert framer.malformed == len(broken)


def test_framer_skips_leading_noise_and_unknown_types() -> None:
    framer, frames = _stream_frames(3)
    unknown = bytearray(frames[0])
    unknown[2] = 9  # no frame type has id 9
    got = framer.feed(b"\x01\x02\x03" + frames[0] + bytes(unknown) + frames[1] + frames[2])
    got += framer.flush()
    assert got == [frames[0], frames[1], frames[2]]
    assert framer.malformed == 2


def test_sources_record_carries_malformed_frames() -> None:
    stats = SourceStats("skin", expected=10, received=9, missing=1, malformed=2)
    record = encode_source_stats([stats])
    assert parse_source_stats(record) == (stats,)
    assert "2 malformed" in stats.problems()
    assert not stats.complete
    del record["skin.malformed"]
    with pytest.raises(ValueError, match="lacks fields"):
        parse_source_stats(record)
