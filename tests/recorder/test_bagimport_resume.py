"""Bag import stopped and run again: it resumes, and the dataset ends as if never stopped."""

from __future__ import annotations

import signal
from typing import TYPE_CHECKING, Any

import pytest
from labbags import PROBE_MAP, Session, probe_messages, write_bag

from recorder import load_actions, load_objects
from recorder.bagimport import _importer
from recorder.bagimport._importer import import_bag
from recorder.bagimport._topicmap import load_topic_map
from recorder.writing._writer import RecordingWriter

if TYPE_CHECKING:
    from pathlib import Path
    from types import TracebackType

    from recorder.bagimport._report import ImportReport

FOUR = Session(("wood", "foam"), ("hold5",), trials=2, execute_s=5.0, gap_s=0.4)


@pytest.fixture(scope="module")
def probe(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """Return a probe bag of four windows and its map."""
    directory = tmp_path_factory.mktemp("probe")
    messages, store = probe_messages(ros1=True, session=FOUR)
    bag = write_bag(directory / "probe.bag", "ros1", messages, store)
    map_path = directory / "map.toml"
    map_path.write_text(PROBE_MAP, encoding="utf-8")
    return bag, map_path


def _import(bag: Path, map_path: Path, out: Path, **hooks: Any) -> ImportReport:
    topic_map = load_topic_map(map_path)
    return import_bag(bag, topic_map, out, objects=load_objects(), actions=load_actions(), **hooks)


def _files(root: Path) -> dict[str, bytes]:
    """Return every file of a dataset (recordings, index, objects, report) by relative path."""
    return {
        p.relative_to(root).as_posix(): p.read_bytes()
        for p in sorted(root.rglob("*"))
        if p.is_file() and ".incomplete" not in p.parts
    }


class _SignalOnSecondFile(RecordingWriter):
    """A writer that receives Ctrl-C while it finishes the second recording."""

    finished = 0

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        type(self).finished += 1
        if type(self).finished == 2:
            signal.raise_signal(signal.SIGINT)
        super().__exit__(exc_type, exc, tb)


def test_an_import_stopped_by_ctrl_c_resumes_to_the_same_bytes(
    probe: tuple[Path, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    bag, map_path = probe
    whole = _import(bag, map_path, tmp_path / "whole")
    assert len(whole.written) == 4
    out = tmp_path / "out"
    # a killed import's unfinished file (its process, 0, is no process)
    stale = out / "wood" / "hold5" / "003.0-0badf00d.mcap.part"
    stale.parent.mkdir(parents=True)
    stale.write_bytes(b"cut off")
    monkeypatch.setattr(_importer, "RecordingWriter", _SignalOnSecondFile)
    said: list[Path] = []
    written: list[Path] = []
    with pytest.raises(KeyboardInterrupt):
        _import(bag, map_path, out, on_set_aside=said.append, on_written=written.append)
    # the signal waited for the file and its note: two whole recordings, nothing half
    assert sorted(p.relative_to(out).as_posix() for p in out.glob("*/*/*.mcap*")) == [
        "foam/hold5/001.mcap",
        "wood/hold5/001.mcap",
    ]
    assert said == [out / ".incomplete" / "wood" / "hold5" / stale.name]
    assert (out / ".incomplete" / "wood" / "hold5" / stale.name).read_bytes() == b"cut off"
    monkeypatch.undo()
    written.clear()
    report = _import(bag, map_path, out, on_written=written.append)
    assert [p.relative_to(out).as_posix() for p in written] == [
        "wood/hold5/002.mcap",
        "foam/hold5/002.mcap",
    ]
    assert len(report.resumed) == 2
    assert _files(out) == _files(tmp_path / "whole")
    # run once more: every window is there, nothing is added or rewritten
    again = _import(bag, map_path, out)
    assert again.written == []
    assert list(again.already_imported) == ["probe.bag"]
    assert _files(out) == _files(tmp_path / "whole")
