"""What ``import-bag`` prints: every sample it drops, and a bag given twice refused."""

from __future__ import annotations

import contextlib
import re
import shutil
import sqlite3
from typing import TYPE_CHECKING

import pytest
from labbags import PROBE_MAP, Session, header, probe_messages, write_bag

from recorder._cli import main as record

if TYPE_CHECKING:
    from pathlib import Path

SMALL = Session(("wood", "foam"), ("hold5",), trials=1, execute_s=5.0, gap_s=0.4)


def _humble(bag: Path, humble: Path) -> Path:
    """Rewrite a rosbags sqlite3 bag as ROS 2 Humble writes one: no message definitions."""
    humble.mkdir()
    with (
        contextlib.closing(sqlite3.connect(next(bag.glob("*.db3")))) as source,
        contextlib.closing(sqlite3.connect(humble / "bag.db3")) as target,
    ):
        target.executescript(
            "CREATE TABLE schema(schema_version INTEGER PRIMARY KEY, ros_distro TEXT NOT NULL);"
            "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,"
            " serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);"
            "CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,"
            " timestamp INTEGER NOT NULL, data BLOB NOT NULL);"
            "INSERT INTO schema VALUES (3, 'humble');"
        )
        topics = "SELECT id, name, type, serialization_format, offered_qos_profiles FROM topics"
        target.executemany("INSERT INTO topics VALUES (?, ?, ?, ?, ?)", source.execute(topics))
        rows = source.execute("SELECT id, topic_id, timestamp, data FROM messages")
        target.executemany("INSERT INTO messages VALUES (?, ?, ?, ?)", rows)
        target.commit()
    text = (bag / "metadata.yaml").read_text().replace("version: 8", "version: 5")
    text = re.sub(r"\n\s*type_description_hash:[^\n]*(\n\s*RIHS01_[0-9a-f]+)?", "", text)
    text = re.sub(r"\n\s*(custom_data: null|ros_distro: rosbags)", "", text)
    text = text.replace("version: 9", "version: 5").replace(f"{bag.name}.db3", "bag.db3")
    (humble / "metadata.yaml").write_text(text)
    return humble


@pytest.fixture
def repeated(tmp_path: Path) -> tuple[Path, Path]:
    """Return a probe bag in which 3 messages repeat their predecessor's stamp, and its map."""
    messages, store = probe_messages(ros1=True, session=SMALL)
    probe = [m for m in messages if m[1] == "/probe"]
    again = [(receive + 1_000_000, topic, msgtype, m) for receive, topic, msgtype, m in probe[:3]]
    bag = write_bag(tmp_path / "probe.bag", "ros1", messages + again, store)
    map_path = tmp_path / "map.toml"
    map_path.write_text(PROBE_MAP, encoding="utf-8")
    return bag, map_path


def test_skin_messages_dropped_for_a_repeated_stamp_are_printed(
    repeated: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag, map_path = repeated
    argv = ["import-bag", str(bag), "--topic-map", str(map_path), "--out", str(tmp_path / "o")]
    assert record(argv) == 0
    out = capsys.readouterr().out
    line = next(line for line in out.splitlines() if "stamp repeated" in line)
    assert " 3 " in line, out


def test_the_same_bag_given_twice_is_refused_naming_both(
    repeated: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag, map_path = repeated
    copy = shutil.copy(bag, tmp_path / "copy.bag")
    argv = ["import-bag", str(bag), str(copy), "--topic-map", str(map_path), "--out", "x"]
    assert record(argv) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert f"{bag} and {copy} are the same bag" in err
    assert not (tmp_path / "x").exists()


def test_a_windows_table_saved_by_excel_with_spaces_is_read(
    repeated: tuple[Path, Path], tmp_path: Path
) -> None:
    bag, map_path = repeated
    rows = [f"{start}, {stop}, {obj}, {action}" for obj, action, _, start, stop in SMALL.windows()]
    table = tmp_path / "windows.csv"
    table.write_text("\ufeffstart, stop, object, action\n" + "\n".join(rows) + "\n", "utf-8")
    windows = '[windows]\nsource = "csv"\ncsv = "windows.csv"\ntime_unit = "ns"'
    map_path.write_text(
        PROBE_MAP.replace('[windows]\nsource = "topic"\ntopic = "/annotations"', windows)
    )
    out = tmp_path / "o"
    assert record(["import-bag", str(bag), "--topic-map", str(map_path), "--out", str(out)]) == 0
    assert sorted(p.relative_to(out).as_posix() for p in out.glob("*/*/*.mcap")) == [
        "foam/hold5/001.mcap",
        "wood/hold5/001.mcap",
    ]


def test_a_humble_bag_without_definitions_lists_topics_and_names_the_missing_type(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    messages, store = probe_messages(ros1=False, session=SMALL)
    bag = _humble(write_bag(tmp_path / "v8", "sqlite3", messages, store), tmp_path / "humble")
    assert record(["import-bag", str(bag), "--topics"]) == 0
    assert "probe_msgs/msg/Probe" in capsys.readouterr().out
    err = _refused(bag, tmp_path, capsys)
    assert "topic /probe carries probe_msgs/msg/Probe, whose definition the bag does not" in err
    assert '[types] "probe_msgs/msg/Probe"' in err


def test_a_driver_that_never_stamps_its_messages_is_named_with_the_way_out(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    messages, store = probe_messages(ros1=True, session=SMALL)
    unstamped = [
        (receive, topic, msgtype, type(m)(header=header(store, 0, ros1=True), **_payload(m)))
        if topic == "/probe"
        else (receive, topic, msgtype, m)
        for receive, topic, msgtype, m in messages
    ]
    bag = write_bag(tmp_path / "probe.bag", "ros1", unstamped, store)
    err = _refused(bag, tmp_path, capsys)
    assert "stamps of /probe are all 0" in err, err
    assert 'set [time] stamps = "log" in map.toml' in err, err


def _payload(message: object) -> dict[str, object]:
    """Return a probe message's fields other than its header."""
    return {"force": message.force, "temperatures": message.temperatures}  # type: ignore[attr-defined]


def test_the_import_table_is_whole_in_a_pipe(
    repeated: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag, map_path = repeated
    out = tmp_path / ("a-directory-name-long-enough-to-overflow-eighty-columns-" * 2) / "o"
    argv = ["import-bag", str(bag), "--topic-map", str(map_path), "--out", str(out)]
    assert record(argv) == 0
    printed = capsys.readouterr().out
    assert f"recordings from probe.bag -> {out}" in printed, printed
    assert "largest stamp jitter (ms)" in printed, printed
    assert "…" not in printed, printed


def _refused(bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> str:
    """Import ``bag`` with the probe's map; return the one line it was refused with."""
    map_path = tmp_path / "map.toml"
    map_path.write_text(PROBE_MAP, encoding="utf-8")
    argv = ["import-bag", str(bag), "--topic-map", str(map_path), "--out", str(tmp_path / "o")]
    assert record(argv) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    return err
