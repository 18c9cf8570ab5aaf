"""Live recordings as the reader, info and check see them: sources' accounting, stopped actions."""

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import FakeRig

from recorder import ActionSpec, ActionStoppedError, StreamItem
from recorder._catalog import ObjectSpec
from recorder.runner._record import record_action
from replay import RecordingError, read_recording
from replay.cli._main import main
from schemas import SourceStats

LOSSY = SourceStats("skin", "counter", expected=100, received=99, missing=2, duplicated=1)


class _LiveRig(FakeRig):
    """A fake rig that reports its sources' accounting, like a live rig."""

    def __init__(
        self,
        stats: SourceStats,
        stop_at: float | None = None,
        reason: str = "protective stop (safety status 3)",
    ) -> None:
        super().__init__(seed=0)
        self._stats = stats
        self._stop_at = stop_at
        self._reason = reason

    def perform(self, obj: ObjectSpec, action: ActionSpec, trial: int) -> Iterator[StreamItem]:
        items = list(super().perform(obj, action, trial))
        if self._stop_at is None:
            yield from items
            return
        cut = int(len(items) * self._stop_at)
        yield from items[:cut]
        raise ActionStoppedError(self._reason, items[cut].receive_ns)

    def source_stats(self) -> list[SourceStats]:
        return [self._stats]


def _record(rig: FakeRig, root: Path, obj: ObjectSpec, action: ActionSpec) -> Path:
    path = root / obj.id / action.id / "001.mcap"
    with rig:
        return record_action(rig, obj, action, 1, path, seed=0).path


def test_sources_are_read_and_losses_refused(
    tmp_path: Path,
    objects: dict[str, ObjectSpec],
    actions: dict[str, ActionSpec],
    capsys: pytest.CaptureFixture[str],
) -> None:
    path = _record(_LiveRig(LOSSY), tmp_path, objects["wood"], actions["P1"])
    assert read_recording(path).sources == (LOSSY,)
    assert main(["info", str(path)]) == 0
    shown = capsys.readouterr().out
    assert "live sources" in shown
    assert "skin" in shown
    assert main(["check", str(tmp_path), "--workers", "1"]) != 0  # counted loss fails
    captured = capsys.readouterr()
    assert "0 of 1 recordings valid" in captured.out + captured.err
    assert "live sources lost samples (skin: 2 of 100 missing)" in captured.out + captured.err


def test_counted_without_loss_is_a_warning(
    tmp_path: Path,
    objects: dict[str, ObjectSpec],
    actions: dict[str, ActionSpec],
    capsys: pytest.CaptureFixture[str],
) -> None:
    counted = SourceStats(
        "skin", "counter", expected=100, received=103, duplicated=1, malformed=2, gaps=1
    )
    _record(_LiveRig(counted), tmp_path, objects["wood"], actions["P1"])
    assert main(["check", str(tmp_path), "--workers", "1"]) == 0
    captured = capsys.readouterr()
    assert "1 of 1 recordings valid" in captured.out
    assert "WARN" in captured.err
    assert "1 duplicated, 2 malformed, 1 gap (" in captured.err
    said = " ".join(captured.err.split())  # the console wraps long lines
    assert "no valid sample lost: the recording is usable; malformed: check the source's" in said
    assert "duplicated or out of order: the transport repeats or reorders; gaps: the" in said


def test_complete_sources_give_no_warning(
    tmp_path: Path,
    objects: dict[str, ObjectSpec],
    actions: dict[str, ActionSpec],
    capsys: pytest.CaptureFixture[str],
) -> None:
    whole = SourceStats("skin", "counter", expected=100, received=100)
    _record(_LiveRig(whole), tmp_path, objects["wood"], actions["P1"])
    assert main(["check", str(tmp_path), "--workers", "1"]) == 0
    assert "WARN" not in capsys.readouterr().err


def test_a_stopped_action_is_shown_warned_and_never_learned_from(
    tmp_path: Path,
    objects: dict[str, ObjectSpec],
    actions: dict[str, ActionSpec],
    capsys: pytest.CaptureFixture[str],
) -> None:
    whole = SourceStats("skin", "counter", expected=100, received=100)
    _record(_LiveRig(whole), tmp_path, objects["wood"], actions["P1"])
    with pytest.raises(ActionStoppedError) as stopped:
        _record(_LiveRig(LOSSY, stop_at=0.5), tmp_path, objects["wood"], actions["S1"])
    incomplete = stopped.value.path
    assert incomplete is not None
    assert incomplete.name == "001.incomplete.mcap"
    with pytest.raises(RecordingError, match=r"incomplete recording.*protective stop"):
        read_recording(incomplete)
    assert main(["info", str(incomplete)]) == 0
    shown = capsys.readouterr().out
    assert "incomplete: the action was stopped (protective stop" in shown
    assert main(["check", str(tmp_path), "--workers", "1"]) == 0
    captured = capsys.readouterr()
    assert "1 of 1 recordings valid" in captured.out
    assert "incomplete, kept for inspection" in captured.err


def test_a_directory_holding_only_stopped_actions_lists_them(
    tmp_path: Path,
    objects: dict[str, ObjectSpec],
    actions: dict[str, ActionSpec],
    capsys: pytest.CaptureFixture[str],
) -> None:
    # a session stopped in its first action: what it kept is listed, never "no recordings"
    with pytest.raises(ActionStoppedError) as stopped:
        _record(_LiveRig(LOSSY, stop_at=0.5), tmp_path, objects["wood"], actions["S1"])
    incomplete = stopped.value.path
    assert incomplete is not None
    assert main(["check", str(tmp_path), "--workers", "1"]) == 1  # no recording of a dataset
    captured = capsys.readouterr()
    err = captured.err.replace("\n", "")
    assert f"{incomplete}: incomplete, kept for inspection (the action was stopped: " in err
    assert (
        f"{tmp_path}: no recordings (*.mcap) found, only 1 incomplete (*.incomplete.mcap, each "
        "listed) kept from actions a stop ended early; see what one holds with atikt-replay info "
        "FILE, and record those actions again" in err
    )
    assert captured.out.splitlines() == ["0 of 0 recordings valid"]  # no unfinished ones
    assert main(["check", str(tmp_path), "--workers", "1", "--json"]) == 1
    said = json.loads(capsys.readouterr().out)
    assert said["ok"] is False
    assert [line.split(":")[0] for line in said["warnings"]] == [str(incomplete)]


def test_brackets_in_a_reason_or_a_path_are_printed_as_they_are(
    tmp_path: Path,
    objects: dict[str, ObjectSpec],
    actions: dict[str, ActionSpec],
    capsys: pytest.CaptureFixture[str],
) -> None:
    # rich reads "[limits]" as a style and drops it: every value a command prints is text
    reason = "TCP at [-0.7, -0.2, -0.0007] left the [limits] workspace"
    root = tmp_path / "[lab]"
    whole = SourceStats("skin", "counter", expected=100, received=100)
    _record(_LiveRig(whole), root, objects["wood"], actions["P1"])
    with pytest.raises(ActionStoppedError) as stopped:
        _record(_LiveRig(whole, stop_at=0.5, reason=reason), root, objects["wood"], actions["S1"])
    assert main(["info", str(stopped.value.path)]) == 0
    shown = capsys.readouterr().out
    assert f"incomplete: the action was stopped ({reason})" in shown
    assert "[lab]" in shown
    assert main(["info", str(root)]) == 0
    assert str(root) in capsys.readouterr().out.replace("\n", "")
    assert main(["check", str(root), "--workers", "1"]) == 0
    assert f"(the action was stopped: {reason})" in capsys.readouterr().err.replace("\n", "")
