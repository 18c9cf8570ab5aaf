"""Windows the bag's data does not cover, pauses inside a window, and corrected windows."""

from __future__ import annotations

from typing import TYPE_CHECKING

from labbags import NS, PROBE_MAP, START, Session, probe_messages, write_bag

from recorder import load_actions, load_objects
from recorder.bagimport._importer import import_bag
from recorder.bagimport._topicmap import load_topic_map
from replay.cli._main import _check_one

if TYPE_CHECKING:
    from pathlib import Path

    from recorder.bagimport._report import ImportReport

THREE = Session(("wood", "foam", "aluminium"), ("hold5",), trials=1, execute_s=5.0, gap_s=0.4)
STOP = THREE.stop_ns
#: 0.5 s of the probe lost inside the foam window.
LOST = (START + 8 * NS, START + 8 * NS + NS // 2)


def _import(directory: Path, rows: list[tuple[int, int, str]]) -> ImportReport:
    """Import the probe bag with a CSV of (start, stop, object) windows of hold5."""
    (directory / "windows.csv").write_text(
        "start,stop,object,action\n" + "".join(f"{a},{b},{o},hold5\n" for a, b, o in rows)
    )
    map_path = directory / "map.toml"
    windows = '[windows]\nsource = "csv"\ncsv = "windows.csv"\ntime_unit = "ns"'
    map_path.write_text(
        PROBE_MAP.replace('[windows]\nsource = "topic"\ntopic = "/annotations"', windows)
    )
    return import_bag(
        directory / "probe.bag",
        load_topic_map(map_path),
        directory / "out",
        objects=load_objects(),
        actions=load_actions(),
    )


def test_windows_the_data_does_not_cover_are_skipped_and_pauses_counted(tmp_path: Path) -> None:
    messages, store = probe_messages(ros1=True, session=THREE)
    kept = [m for m in messages if m[1] != "/probe" or not LOST[0] <= m[0] < LOST[1]]
    write_bag(tmp_path / "probe.bag", "ros1", kept, store)
    foam = (START + 59 * NS // 10, START + 11 * NS, "foam")
    report = _import(
        tmp_path,
        [
            (START - 3 * NS // 2, START + 36 * NS // 10, "wood"),  # 1.5 s before the data
            foam,
            (STOP - 435 * NS // 100, STOP + 3 * NS // 4, "aluminium"),  # 0.75 s after it
        ],
    )
    assert [p.relative_to(tmp_path / "out").as_posix() for p in report.written] == [
        "foam/hold5/001.mcap"
    ]
    (row2, why2), (row4, why4) = report.skipped
    assert "row 2" in row2
    assert "begins 1.500 s after its execute phase began" in why2
    assert "row 4" in row4
    assert "ends 0.750 s before its execute phase ends (hold5 lasts 5 s)" in why4
    assert report.gaps == {"force": 1, "temperature": 1}
    problem, warning, _ = _check_one(report.written[0])
    assert problem is None
    assert warning is not None
    assert "pauses" in warning
    # the windows corrected: the new ones are imported, numbered on; foam is not again
    again = _import(
        tmp_path,
        [
            (START + NS // 2, START + 56 * NS // 10, "wood"),
            foam,
            (STOP - 56 * NS // 10, STOP - NS // 2, "aluminium"),
        ],
    )
    assert [p.relative_to(tmp_path / "out").as_posix() for p in again.written] == [
        "wood/hold5/001.mcap",
        "foam/hold5/001.mcap",
        "aluminium/hold5/001.mcap",
    ]
    assert again.resumed == [tmp_path / "out" / "foam/hold5/001.mcap"]
    assert not again.skipped
    for path in again.written:
        assert _check_one(path)[0] is None
