"""A DDS participant the project closes leaves its peers at once (no lingering, no lease)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

pytest.importorskip("cyclonedds")

from recorder.bagimport._source import ANNOTATION_TYPE, typestore
from recorder.bagimport._topicmap import load_topic_map
from recorder.live.dds import DdsDomain

EXAMPLE = Path(__file__).parents[2] / "recorder" / "data" / "topic_map.example.toml"


def _matched_after(writer: object, seconds: float) -> int:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if writer.matched() == 0:  # type: ignore[attr-defined]
            return 0
        time.sleep(0.02)
    return int(writer.matched())  # type: ignore[attr-defined]


def test_a_closed_domain_leaves_its_peers_at_once(dds_domain: int) -> None:
    # listen's participant, closed when it stops: a lab's reliable writer sees its reader go
    # at once (else it stays matched until the lease ends, ~10 s, and lingers at its end)
    store = typestore(load_topic_map(EXAMPLE))
    lab = DdsDomain(dds_domain, store, loopback=True)
    listener = DdsDomain(dds_domain, store, loopback=True)
    writer = lab.writer("/annotations", ANNOTATION_TYPE)
    reader = listener.reader("/annotations", ANNOTATION_TYPE, reliable=True)
    deadline = time.monotonic() + 10
    while writer.matched() == 0 and time.monotonic() < deadline:
        time.sleep(0.02)
    assert writer.matched() == 1
    assert reader.take() == []
    listener.close()
    listener.close()  # twice: nothing happens
    assert _matched_after(writer, 2.0) == 0
    lab.close()
