"""The metadata record: one type, one encoder, one strict parser (property-based)."""

import contextlib
import json
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from schemas import ContractError, RecordingMetadata, parse_metadata

IDS = st.from_regex(r"[A-Za-z0-9][A-Za-z0-9_.+-]{0,20}", fullmatch=True)
TEXT = st.text(st.characters(min_codepoint=32, max_codepoint=0x2FFF), min_size=1, max_size=30)
FINITE = st.floats(allow_nan=False, allow_infinity=False, min_value=-1e9, max_value=1e9)
RIG = st.dictionaries(
    st.text(min_size=1, max_size=8),
    st.one_of(st.text(max_size=8), st.integers(-(2**62), 2**62), FINITE, st.booleans()),
    max_size=4,
)


@st.composite
def records(draw: st.DrawFn) -> RecordingMetadata:
    kind = draw(st.sampled_from(["press", "slide", "static"]))
    parameters = draw(st.dictionaries(st.sampled_from(["depth_m", "force_n", "x"]), FINITE))
    parameters["duration_s"] = draw(st.floats(min_value=1e-3, max_value=1e3))
    return RecordingMetadata(
        object_id=draw(IDS),
        object_name=draw(TEXT),
        object_description=draw(st.text(st.characters(min_codepoint=32), max_size=30)),
        action_id=draw(IDS),
        action_kind=kind,
        action_parameters=dict(sorted(parameters.items())),
        trial=draw(st.integers(1, 999_999)),
        rig=dict(sorted(draw(RIG).items())),
        seed=draw(st.integers(0, 2**63 - 1)),
        source=draw(st.sampled_from(["recorder", "import", "salvage"])),
        software_version=draw(TEXT),
        schema_version=2,
    )


@given(records())
def test_encode_then_parse_is_the_identity(meta: RecordingMetadata) -> None:
    assert parse_metadata(meta.encode()) == meta


BAD = {
    "object_novel": ("object_novel", "yes"),
    "nested rig": ("rig", json.dumps({"arm": {"joints": 7}})),
    "huge seed": ("seed", str(10**30)),
    "negative trial": ("trial", "-2"),
    "trial as float": ("trial", "3.0"),
    "no duration": ("action_parameters", json.dumps({"depth_m": 0.001})),
    "NaN parameter": ("action_parameters", json.dumps({"duration_s": math.nan})),
    "unknown kind": ("action_kind", "squeeze"),
    "unknown source": ("source", "camera"),
    "bad id": ("object_id", "../etc"),
    "control character": ("object_name", "a\nb"),
}


@pytest.mark.parametrize(("key", "value"), list(BAD.values()), ids=list(BAD))
def test_every_field_is_typed_and_ranged(key: str, value: str) -> None:
    good = RecordingMetadata(
        "wood",
        "Wood",
        "P1",
        "press",
        {"duration_s": 3.0},
        1,
        {"kind": "sim"},
        0,
        "recorder",
        "0.1",
        2,
    ).encode()
    parse_metadata(good)
    with pytest.raises(ContractError, match=key.split("_", maxsplit=1)[0]):
        parse_metadata(good | {key: value})


@given(st.dictionaries(st.text(max_size=12), st.text(max_size=12), max_size=14))
def test_arbitrary_records_are_refused_with_a_contract_error_or_parsed(
    record: dict[str, str],
) -> None:
    with contextlib.suppress(ContractError):  # anything else escaping is a bug
        parse_metadata(record)
