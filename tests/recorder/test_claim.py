"""Two recorders, one directory: an atomic claim lets exactly one seed in."""

from __future__ import annotations

import errno
import os
import shutil
import subprocess
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING

import forked
import pytest
from conftest import FakeRig

from recorder import ActionSpec, StreamItem, generate_dataset, plan_dataset
from recorder._claim import CLAIM_NAME, claim_dataset, differing_settings
from recorder._cli import main as record
from recorder._session import check_session, run_session
from recorder.errors import RecorderError
from replay.cli._main import main as replay_main
from schemas import recorder_at_work, recording_into

if TYPE_CHECKING:
    from collections.abc import Iterator

    from recorder._catalog import ObjectSpec

ROOT = Path(__file__).parents[2]


def _race(root: Path, runs: int) -> tuple[list[int], list[str]]:
    """Claim ``root`` from ``runs`` threads at once, each with its own seed."""
    barrier = threading.Barrier(runs)
    won: list[int] = []
    refused: list[str] = []

    def run(seed: int) -> None:
        barrier.wait()
        try:
            claim_dataset(root, seed, {"rig": "sim"})
            won.append(seed)
        except RecorderError as err:
            refused.append(str(err))

    threads = [threading.Thread(target=run, args=(seed,)) for seed in range(runs)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return won, refused


def test_one_of_many_runs_started_together_claims_the_directory(tmp_path: Path) -> None:
    for round_ in range(20):
        root = tmp_path / f"d{round_}"
        won, refused = _race(root, 8)
        assert len(won) == 1
        assert len(refused) == 7
        assert all(f"is claimed by a run with seed {won[0]}" in line for line in refused)
        assert sorted(p.name for p in root.iterdir()) == [CLAIM_NAME]


def test_the_same_seed_and_configuration_resume(tmp_path: Path) -> None:
    claim_dataset(tmp_path, 3, {"rig": "ur", "host": "10.0.0.2"})
    claim_dataset(tmp_path, 3, {"rig": "ur", "host": "10.0.0.2"})
    with pytest.raises(RecorderError, match=r"another rig configuration \(host='10.0.0.2'"):
        claim_dataset(tmp_path, 3, {"rig": "ur", "host": "10.0.0.9"})
    (tmp_path / CLAIM_NAME).write_text("{", encoding="utf-8")
    with pytest.raises(RecorderError, match="the dataset's claim cannot be read"):
        claim_dataset(tmp_path, 3, {"rig": "ur", "host": "10.0.0.2"})


def test_a_dataset_claimed_before_the_motion_was_recorded_resumes(tmp_path: Path) -> None:
    earlier = {"kind": "ur", "host": "10.0.0.2"}  # recorded before motion.*
    claim_dataset(tmp_path, 3, earlier)
    claim_dataset(tmp_path, 3, {**earlier, "motion.press_m_s": "0.005"})
    assert differing_settings(earlier, {**earlier, "motion.press_m_s": "0.005"}) == []
    # once recorded, they are compared: also when this run lacks one
    now = {**earlier, "motion.press_m_s": "0.005", "motion.retract_m": "0.02"}
    assert differing_settings(now, {**now, "motion.press_m_s": "0.004"}) == ["motion.press_m_s"]
    assert differing_settings(now, earlier) == ["motion.press_m_s", "motion.retract_m"]


def test_a_claim_without_a_recording_says_how_to_take_the_directory(tmp_path: Path) -> None:
    # a run refused before its first recording (a skin on the wrong port) leaves its claim;
    # the corrected run is told it may delete the claim, until a recording is in it
    claim_dataset(tmp_path, 3, {"rig": "ur", "silence_s": "0.5"})
    kept = tmp_path / "wood" / "P1" / "001.incomplete.mcap"  # not a recording of the dataset
    kept.parent.mkdir(parents=True)
    kept.write_bytes(b"")
    hint = f"or delete {tmp_path / CLAIM_NAME}: the directory holds no recording yet"
    for seed, configuration in ((3, {"rig": "ur", "silence_s": "1"}), (4, {"rig": "ur"})):
        with pytest.raises(RecorderError) as refused:
            claim_dataset(tmp_path, seed, configuration)
        assert hint in str(refused.value)
    (kept.parent / "001.mcap").write_bytes(b"")
    with pytest.raises(RecorderError) as refused:
        claim_dataset(tmp_path, 3, {"rig": "ur", "silence_s": "1"})
    assert str(refused.value).endswith("give another --out")


def test_a_claim_held_by_a_running_recorder_is_never_advised_deleted(tmp_path: Path) -> None:
    # a session records into the directory (it holds its claim) and has written nothing yet:
    # a second run of another configuration must not be told to delete the claim
    claim_dataset(tmp_path, 3, {"rig": "ur", "silence_s": "0.5"})
    with recording_into(tmp_path):
        for seed, configuration in ((3, {"rig": "ur", "silence_s": "1"}), (4, {"rig": "ur"})):
            with pytest.raises(RecorderError) as refused:
                claim_dataset(tmp_path, seed, configuration)
            said = str(refused.value)
            assert "delete" not in said
            assert said.endswith(f": a recorder is writing into {tmp_path} now")
    with pytest.raises(RecorderError) as refused:  # the recorder gone: the way in again
        claim_dataset(tmp_path, 4, {"rig": "ur"})
    assert str(refused.value).endswith("the directory holds no recording yet")


@pytest.mark.parametrize("existing", [True, False])
def test_a_dry_run_into_a_directory_it_cannot_write_is_refused_as_the_run_is(
    tmp_path: Path,
    objects: dict[str, ObjectSpec],
    actions: dict[str, ActionSpec],
    monkeypatch: pytest.MonkeyPatch,
    existing: bool,  # noqa: FBT001 (a parameter)
) -> None:
    # a read-only file system (root writes anywhere else, so the file system's answer is
    # given here): the dry run says what the run would, where the run would be refused
    root = tmp_path / "ro" / "lab"
    if existing:
        root.mkdir(parents=True)
    tasks = plan_dataset(objects, actions, object_ids=["wood"], action_ids=["P1"], trials=1)

    def read_only(*_args: object, **_kwargs: object) -> tuple[int, str]:
        raise OSError(errno.EROFS, os.strerror(errno.EROFS))

    monkeypatch.setattr("recorder._claim.tempfile.mkstemp", read_only)
    said = f"{root / CLAIM_NAME}: cannot claim the dataset directory (Read-only file system); "
    said += "check --out"
    with pytest.raises(RecorderError) as dry:
        check_session(tasks, root, FakeRig, seed=0, unattended=True)
    assert str(dry.value) == said
    made = sorted(p.name for p in tmp_path.rglob("*"))
    assert made == (["lab", "ro"] if existing else [])  # the dry run wrote nothing
    with pytest.raises(RecorderError) as run:
        run_session(tasks, root, FakeRig, seed=0, unattended=True)
    assert str(run.value) == said
    monkeypatch.undo()
    check_session(tasks, root, FakeRig, seed=0, unattended=True)  # writable: ready
    assert not [p for p in tmp_path.rglob("*") if p.is_file()]  # its probe removed


def _dataset_argv(out: Path, seed: int) -> list[str]:
    argv = ["dataset", "--out", str(out)]
    argv += ["--objects", "wood", "--actions", "P1", "--trials", "1", "--seed", str(seed)]
    return [*argv, "--workers", "1"]


def _dataset(out: Path, seed: int) -> subprocess.Popen[str]:
    command = [sys.executable, "-m", "recorder", *_dataset_argv(out, seed)]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return forked.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_an_out_that_is_a_file_is_named_so(tmp_path: Path) -> None:
    (tmp_path / "notes").write_text("a file", encoding="utf-8")
    with pytest.raises(RecorderError, match=r"notes: is a file, not a directory; give a dir"):
        claim_dataset(tmp_path / "notes", 3, {"rig": "sim"})  # was "(File exists)"
    assert (tmp_path / "notes").read_text(encoding="utf-8") == "a file"


def test_two_dataset_runs_started_together_never_mix(tmp_path: Path) -> None:
    out = tmp_path / "data"
    runs = [_dataset(out, 1), _dataset(out, 2)]
    results = [(run.wait(300), *run.communicate()) for run in runs]
    codes = sorted(code for code, _, _ in results)
    assert codes == [0, 1], results
    refused = next(err for code, _, err in results if code == 1)
    # refused by the other run's claim, or (when that run was already done) by its recordings
    assert "is claimed by a run with seed" in refused or "holds recordings of seed" in refused
    assert len([line for line in refused.splitlines() if "error" in line]) == 1
    assert replay_main(["check", str(out), "--workers", "1"]) == 0


def test_check_reports_a_directory_of_two_seeds(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    one, two = tmp_path / "one", tmp_path / "two"
    for out, seed in ((one, 1), (two, 2)):  # one run after the other: in this process
        assert record(_dataset_argv(out, seed)) == 0, capsys.readouterr().err
    moved = one / "wood" / "P1" / "002.mcap"
    shutil.copy(two / "wood" / "P1" / "001.mcap", moved)
    (one / "index.parquet").unlink()
    capsys.readouterr()
    assert replay_main(["check", str(one), "--workers", "1"]) == 1
    captured = capsys.readouterr()
    assert "the recordings hold 2 seeds (seed 1 (e.g." in captured.err
    assert "2 of 2 recordings valid" in captured.out


def test_a_run_holds_its_dataset_while_it_records_and_lets_go_however_it_ends(
    tmp_path: Path, objects: dict[str, ObjectSpec], actions: dict[str, ActionSpec]
) -> None:
    # `atikt-replay check` beside a running session tells its files from a dead recorder's
    seen: list[bool] = []
    roots = [tmp_path / "session", tmp_path / "dataset"]

    class Watching(FakeRig):
        def perform(self, obj: ObjectSpec, action: ActionSpec, trial: int) -> Iterator[StreamItem]:
            seen.append(recorder_at_work(roots[0]))
            return super().perform(obj, action, trial)

    tasks = plan_dataset(objects, actions, object_ids=["wood"], action_ids=["P1"], trials=2)
    run_session(tasks, roots[0], Watching, seed=0, unattended=True)
    assert seen == [True, True]
    assert not recorder_at_work(roots[0])  # done: nobody records into it
    roots.pop(0)
    generate_dataset(tasks, roots[0], Watching, seed=0, workers=1)
    assert seen[2:] == [True, True]
    assert not recorder_at_work(roots[0])
    failing = [*tasks, plan_dataset(objects, actions, object_ids=["wood"], trials=1)[0]]
    Failing.calls = 0
    with pytest.raises(RecorderError):  # a run that fails lets go too
        run_session(failing, tmp_path / "failing", Failing, seed=0, unattended=True)
    assert not recorder_at_work(tmp_path / "failing")


class Failing(FakeRig):
    """A rig whose third action fails."""

    calls = 0

    def perform(self, obj: ObjectSpec, action: ActionSpec, trial: int) -> Iterator[StreamItem]:
        Failing.calls += 1
        if Failing.calls == 3:
            msg = "the rig failed"
            raise RecorderError(msg)
        return super().perform(obj, action, trial)
