from pathlib import Path
from typing import Any

import numpy as np
import pytest

from schemas import (
    CHANNELS,
    CUSTOM_TYPES,
    SCHEMA_VERSION,
    build_typestore,
    channel_for_topic,
    full_type_name,
    msg_definition,
)


@pytest.mark.parametrize("name", CUSTOM_TYPES)
def test_custom_types_are_registered(name: str) -> None:
    store = build_typestore()
    assert full_type_name(name) in store.fielddefs
    assert "schema_version" in msg_definition(name)


def test_every_channel_type_is_known() -> None:
    store = build_typestore()
    for channel in CHANNELS:
        assert channel.msgtype in store.fielddefs, channel.topic
        assert channel_for_topic(channel.topic) is channel
    assert channel_for_topic("/not/a/topic") is None


def test_skin_block_round_trips_through_cdr() -> None:
    store = build_typestore()
    msgtype = full_type_name("SkinAcceleration")
    cls = store.types[msgtype]
    header = store.types["std_msgs/msg/Header"]
    stamp = store.types["builtin_interfaces/msg/Time"]
    data = np.arange(2 * 7 * 3, dtype=np.float32) / 7
    msg = cls(
        header=header(stamp=stamp(sec=3, nanosec=5), frame_id="skin"),
        schema_version=SCHEMA_VERSION,
        sample_period_ns=1_000_000,
        n_samples=2,
        n_cells=7,
        n_channels=3,
        cell_ids=np.arange(7, dtype=np.uint16),
        data=data,
    )
    back: Any = store.deserialize_cdr(store.serialize_cdr(msg, msgtype), msgtype)
    assert back.sample_period_ns == 1_000_000
    np.testing.assert_array_equal(back.data, data)
    assert back.header.stamp.nanosec == 5


def test_the_contract_tables_of_the_readme_come_from_the_contract() -> None:
    from schemas import contract_table  # noqa: PLC0415

    assert contract_table.main(["--check"]) == 0


def test_the_vocabulary_is_consistent_and_refuses_a_bad_edit() -> None:
    from schemas import VOCABULARY, ContractError, parse_vocabulary  # noqa: PLC0415
    from schemas._vocabulary import CONTRACT_FILE  # noqa: PLC0415

    assert set(VOCABULARY.kinds) >= {"press", "slide", "static"}
    assert VOCABULARY.modality_of_feature("texture").name == "acceleration"
    text = (Path(__file__).resolve().parents[2] / "schemas" / CONTRACT_FILE).read_text()
    broken = text.replace('needs = ["acceleration"]', 'needs = ["smell"]')
    with pytest.raises(ContractError, match=r"\[kinds.slide\] needs unknown modality 'smell'"):
        parse_vocabulary(broken, "tactile_msgs")
