"""``atikt-record listen`` against a DDS publisher on loopback, compared with ``import-bag``.

One scripted session (joint states, two skin cells, JSON annotations) is published over DDS
while ``listen`` records it; the same messages are written into a ROS 2 bag and imported.
The files must hold the same messages and metadata; the live ones also count every sample.
"""

from __future__ import annotations

import json
import threading
from typing import TYPE_CHECKING, Any

import pytest

pytest.importorskip("cyclonedds")

import ddsdata
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader

from recorder import load_actions, load_objects
from recorder._cli import main as record_main
from recorder.bagimport._importer import import_bag
from recorder.bagimport._listen import listen
from recorder.bagimport._source import typestore
from recorder.bagimport._topicmap import load_topic_map
from recorder.live import SOURCES_RECORD, parse_source_stats
from recorder.live.dds import DdsDomain
from replay.cli._main import main as replay_main

if TYPE_CHECKING:
    from pathlib import Path

    from recorder.bagimport._report import ImportReport

_SOURCE_FIELDS = {"source", "bag_sha256"}


def _contents(path: Path) -> tuple[dict[str, list[bytes]], dict[str, dict[str, str]]]:
    """Return a recording's messages per topic and its metadata records."""
    messages: dict[str, list[bytes]] = {}
    metadata: dict[str, dict[str, str]] = {}
    with path.open("rb") as handle:
        reader = make_reader(handle)
        for _, channel, message in reader.iter_messages(log_time_order=False):
            messages.setdefault(channel.topic, []).append(message.data)
        for record in reader.iter_metadata():
            metadata[record.name] = dict(record.metadata)
    return messages, metadata


def _without_source(record: dict[str, str]) -> dict[str, str]:
    """Return a metadata record without the fields that name the source (bag or DDS)."""
    out = {k: v for k, v in record.items() if k not in _SOURCE_FIELDS}
    if "rig" in out:
        rig = {k: v for k, v in json.loads(out["rig"]).items() if k not in _SOURCE_FIELDS}
        out["rig"] = json.dumps(rig, sort_keys=True)
    return out


@pytest.fixture(scope="module")
def recorded(
    module_dds_domain: int, tmp_path_factory: pytest.TempPathFactory
) -> tuple[ImportReport, ImportReport, list[str]]:
    """Publish the session while listen records it; import the same messages from a bag."""
    root = tmp_path_factory.mktemp("dds")
    map_path = root / "map.toml"
    map_path.write_text(ddsdata.TOPIC_MAP, encoding="utf-8")
    topic_map = load_topic_map(map_path)
    objects, actions = load_objects(None), load_actions(None)
    store = typestore(topic_map)
    session = ddsdata.script(store)
    publisher = DdsDomain(module_dds_domain, store)
    notes: list[str] = []
    stop = threading.Event()
    result: dict[str, Any] = {}

    def run() -> None:
        result["live"] = listen(
            topic_map,
            root / "live",
            objects=objects,
            actions=actions,
            domain_id=module_dds_domain,
            stop=stop,
            discovery_s=5.0,
            on_note=notes.append,
        )

    thread = threading.Thread(target=run)
    thread.start()
    sent = ddsdata.publish(publisher, session)
    stop.set()
    thread.join(20)
    bag = ddsdata.bag(root / "session", sent, store)
    offline = import_bag(bag, topic_map, root / "bag", objects=objects, actions=actions)
    return result["live"], offline, notes


def test_listen_writes_what_import_bag_writes(
    recorded: tuple[ImportReport, ImportReport, list[str]],
) -> None:
    live, offline, _ = recorded
    assert len(offline.written) == len(ddsdata.WINDOWS)
    assert [p.relative_to(live.out) for p in live.written] == [
        p.relative_to(offline.out) for p in offline.written
    ]
    for mine, theirs in zip(live.written, offline.written, strict=True):
        live_messages, live_meta = _contents(mine)
        bag_messages, bag_meta = _contents(theirs)
        assert live_messages == bag_messages
        assert live_meta.keys() - {SOURCES_RECORD} == bag_meta.keys()
        for name, record in bag_meta.items():
            assert _without_source(live_meta[name]) == _without_source(record), name


def test_publisher_pauses_are_gaps_not_loss(
    recorded: tuple[ImportReport, ImportReport, list[str]],
) -> None:
    live, _, _ = recorded
    gaps = []
    for path in live.written:
        _, meta = _contents(path)
        stats = {s.name: s for s in parse_source_stats(meta[SOURCES_RECORD])}
        assert set(stats) == {"/joint_states", "/skin/cell_0", "/skin/cell_1"}
        assert all(s.basis == "stamps" and s.lost == 0 for s in stats.values())
        assert stats["/skin/cell_0"].gaps == stats["/skin/cell_1"].gaps == 0
        assert stats["/joint_states"].received > 0
        gaps.append((stats["/joint_states"].gaps, stats["/joint_states"].gap_ns))
    # joint states 180 and 181 not published: a pause of 3 periods; 190 not published: a
    # pause of 2 periods, a gap too as the publisher stamps on its period's grid (for a
    # jittery one it would be within the tolerance: test_hostile_live.py)
    assert gaps == [(0, 0), (2, 3 * ddsdata.JOINT_PERIOD_NS), (0, 0)]


def test_live_files_pass_check_and_open_in_rosbags(
    recorded: tuple[ImportReport, ImportReport, list[str]],
) -> None:
    live, _, _ = recorded
    for path in live.written:
        assert replay_main(["check", str(path)]) == 0
    with AnyReader(list(live.written)) as reader:
        assert sum(1 for _ in reader.messages()) > 0
    assert live.index is not None
    assert live.index.exists()
    assert live.json_path is not None
    assert live.json_path.exists()


def test_cli_without_publishers_says_so_in_one_line(
    dds_domain: int, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    map_path = tmp_path / "map.toml"
    map_path.write_text(ddsdata.TOPIC_MAP, encoding="utf-8")
    argv = ["listen", "--topic-map", str(map_path), "--out", str(tmp_path / "out")]
    argv += ["--duration", "0.3", "--domain-id", str(dds_domain + 1)]
    assert record_main(argv) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "/skin/cell_0" in err
    assert "no publisher" in err
    assert not (tmp_path / "out").exists()
