"""Every channel's message definition is compared with this software's, standard types too."""

from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from replay.errors import RecordingError
from replay.recording._checks import _normalized, check_definitions
from replay.recording._container import ChannelInfo
from schemas import VOCABULARY, build_typestore

TYPES = sorted(
    {c.msgtype for c in VOCABULARY.robot.values()}
    | {m.msgtype for m in VOCABULARY.modalities.values()}
    | {VOCABULARY.events.msgtype}
)
PATH = Path("x.mcap")


def _info(msgtype: str, text: str) -> ChannelInfo:
    return ChannelInfo("/t", msgtype, "ros2msg", "cdr", 1, text)


def _own(msgtype: str) -> str:
    return build_typestore().generate_msgdef(msgtype, ros_version=2)[0]


@pytest.mark.parametrize("msgtype", TYPES)
def test_the_own_definition_passes(msgtype: str) -> None:
    check_definitions(PATH, [_info(msgtype, _own(msgtype))])


@given(st.sampled_from(TYPES), st.data())
def test_any_reordered_or_missing_field_is_refused(msgtype: str, data: st.DataObject) -> None:
    text = _own(msgtype)
    main, _, rest = text.partition("=" * 80)
    fields = [line for line in main.splitlines() if line.split("#")[0].strip()]
    assert len(_normalized(text)) == len(fields)
    changed = data.draw(
        st.one_of(
            st.permutations(fields).filter(lambda order: order != fields),
            st.integers(0, len(fields) - 1).map(lambda i: fields[:i] + fields[i + 1 :]),
        )
    )
    if [_normalized(line) for line in changed] == [_normalized(line) for line in fields]:
        return  # two identical lines swapped: the same definition
    mutated = "\n".join(changed) + "\n" + ("=" * 80 + rest if rest else "")
    with pytest.raises(RecordingError, match=f"defines {msgtype} differently"):
        check_definitions(PATH, [_info(msgtype, mutated)])


def test_an_empty_definition_is_refused() -> None:
    with pytest.raises(RecordingError, match="0 fields where this software has"):
        check_definitions(PATH, [_info(VOCABULARY.events.msgtype, "")])
