import contextlib
import errno
import math
import os
import signal
import subprocess
import sys
import time
import tomllib
from collections.abc import Callable
from pathlib import Path

import polars as pl
import pytest
from conftest import FakeRig

from recorder import ActionSpec, RecorderError, load_objects
from recorder._catalog import ObjectSpec
from recorder._claim import CLAIM_NAME
from recorder._dataset import (
    INDEX_NAME,
    OBJECTS_FILE,
    TaskResult,
    TaskStatus,
    build_index,
    generate_dataset,
    plan_dataset,
    recording_path,
    rig_factory,
    set_aside_stale_parts,
    write_index,
)

Objects = dict[str, ObjectSpec]
Actions = dict[str, ActionSpec]


def _files(root: Path) -> dict[str, bytes]:
    return {
        p.relative_to(root).as_posix(): p.read_bytes()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def test_plan_covers_every_object_action_and_trial(objects: Objects, actions: Actions) -> None:
    tasks = plan_dataset(objects, actions)
    expected = len(objects) * sum(action.trials for action in actions.values())
    assert len(tasks) == expected
    assert len({(t.obj.id, t.action.id, t.trial) for t in tasks}) == expected
    c1 = [t.trial for t in tasks if t.action.id == "C1" and t.obj.id == "wood"]
    assert c1 == list(range(1, actions["C1"].trials + 1))


def test_plan_selects_and_rejects_unknown_names(objects: Objects, actions: Actions) -> None:
    tasks = plan_dataset(objects, actions, object_ids=["sponge"], action_ids=["S1", "P2"], trials=2)
    assert [(t.obj.id, t.action.id, t.trial) for t in tasks] == [
        ("sponge", "P2", 1),
        ("sponge", "P2", 2),
        ("sponge", "S1", 1),
        ("sponge", "S1", 2),
    ]
    with pytest.raises(RecorderError, match="--objects marble: not in the objects catalog"):
        plan_dataset(objects, actions, object_ids=["marble"])
    with pytest.raises(RecorderError, match="--trials 0"):
        plan_dataset(objects, actions, trials=0)


def test_dataset_is_identical_whatever_the_worker_count(
    tmp_path: Path, objects: Objects, actions: Actions
) -> None:
    tasks = plan_dataset(objects, actions, action_ids=["P1", "S2"], trials=2)
    results: list[TaskResult] = []
    one = generate_dataset(
        tasks, tmp_path / "one", FakeRig, seed=4, workers=1, on_result=results.append
    )
    two = generate_dataset(tasks, tmp_path / "two", FakeRig, seed=4, workers=2)
    assert one.written == two.written == len(tasks) == len(results)
    assert _files(tmp_path / "one") == _files(tmp_path / "two")
    assert sorted(_files(tmp_path / "one")) == sorted(
        [recording_path(Path(), t.obj.id, t.action.id, t.trial).as_posix() for t in tasks]
        + [INDEX_NAME, OBJECTS_FILE, CLAIM_NAME]
    )


def test_simulated_dataset_is_identical_whatever_the_worker_count(
    tmp_path: Path, actions: Actions
) -> None:
    tasks = plan_dataset(
        load_objects(), actions, object_ids=["wood", "foam_block"], action_ids=["S4"], trials=2
    )
    factory = rig_factory("sim")
    generate_dataset(tasks, tmp_path / "one", factory, seed=1, workers=1)
    generate_dataset(tasks, tmp_path / "two", factory, seed=1, workers=2)
    assert _files(tmp_path / "one") == _files(tmp_path / "two")
    assert len(_files(tmp_path / "one")) == len(tasks) + 3  # index, objects.toml, claim


def test_rerun_skips_existing_recordings_and_never_overwrites(
    tmp_path: Path, objects: Objects, actions: Actions
) -> None:
    tasks = plan_dataset(objects, actions, object_ids=["wood"], action_ids=["S1"], trials=3)
    first = tasks[0].path(tmp_path)
    first.parent.mkdir(parents=True)
    first.write_bytes(b"kept")
    results: list[TaskResult] = []
    with pytest.raises(RecorderError, match=r"001\.mcap: not a readable recording"):
        generate_dataset(tasks, tmp_path, FakeRig, seed=0, workers=1, on_result=results.append)
    assert first.read_bytes() == b"kept"
    assert [r.status for r in results] == [TaskStatus.SKIPPED] + [TaskStatus.WRITTEN] * 2
    first.unlink()
    report = generate_dataset(tasks, tmp_path, FakeRig, seed=0, workers=1)
    assert (report.written, report.skipped) == (1, 2)


def test_a_dataset_made_again_from_its_seed_syncs_once_and_sets_aside_what_was_cut_short(
    tmp_path: Path, objects: Objects, actions: Actions, monkeypatch: pytest.MonkeyPatch
) -> None:
    # durable=False (the default dataset in the cache): no sync per recording, one for all
    # before the index; the same bytes; a recording a power loss cut short is kept aside
    tasks = plan_dataset(objects, actions, action_ids=["P1", "S2"], trials=2)
    synced: list[int] = []
    real_fsync = os.fsync

    def fsync(fd: int) -> None:
        synced.append(fd)
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    durable = generate_dataset(tasks, tmp_path / "durable", FakeRig, seed=4, workers=1)
    per_recording = len(synced)
    synced.clear()
    whole: list[bool] = []
    monkeypatch.setattr(os, "sync", lambda: whole.append(True))
    cached = generate_dataset(tasks, tmp_path / "cached", FakeRig, seed=4, workers=1, durable=False)
    assert per_recording >= 2 * len(tasks) > len(synced)  # the index and claim still sync
    assert whole == [True]
    assert _files(tmp_path / "durable") == _files(tmp_path / "cached")
    assert durable.written == cached.written == len(tasks)
    cut = tasks[1].path(tmp_path / "cached")
    data = cut.read_bytes()
    aside_dir = tmp_path / "cached" / ".incomplete" / cut.relative_to(tmp_path / "cached").parent
    for attempt in range(2):  # cut short twice: the first one set aside stays as it was
        cut.write_bytes(data[: len(data) // 2 + attempt])
        again = generate_dataset(
            tasks, tmp_path / "cached", FakeRig, seed=4, workers=1, durable=False
        )
        assert (again.written, again.skipped) == (1, len(tasks) - 1)
        assert cut.read_bytes() == data  # recorded again, the same bytes
    kept = sorted(aside_dir.iterdir())
    assert [p.name for p in kept] == [cut.name, f"{cut.name}.1"]
    assert [p.stat().st_size for p in kept] == [len(data) // 2, len(data) // 2 + 1]
    assert again.set_aside == (kept[1],)


def test_index_has_one_row_per_recording_and_is_rebuilt_from_files(
    tmp_path: Path, objects: Objects, actions: Actions
) -> None:
    tasks = plan_dataset(objects, actions, action_ids=["C1"], trials=1)
    report = generate_dataset(tasks, tmp_path, FakeRig, seed=9, workers=1)
    index = pl.read_parquet(report.index)
    assert index.height == 2
    assert index["path"].to_list() == ["sponge/C1/001.mcap", "wood/C1/001.mcap"]
    assert index["source"].to_list() == ["recorder", "recorder"]
    declared = tomllib.loads((tmp_path / OBJECTS_FILE).read_text("utf-8"))
    assert {k: v["novel"] for k, v in declared.items()} == {"sponge": True, "wood": False}
    assert index["seed"].to_list() == [9, 9]
    assert index["rig"].to_list() == ["fake", "fake"]
    assert (index["n_events"] == 5).all()
    per_topic = index.select(pl.sum_horizontal(pl.col("^n_.*$")).alias("total"))["total"]
    assert (index["messages"] == per_topic).all()
    sizes = [(tmp_path / p).stat().st_size for p in index["path"]]
    assert index["size_bytes"].to_list() == sizes == [report.size_bytes - sizes[1], sizes[1]]
    (tmp_path / INDEX_NAME).unlink()
    write_index(tmp_path)
    assert pl.read_parquet(tmp_path / INDEX_NAME).equals(index)
    assert build_index(tmp_path / "nothing").height == 0


def test_a_second_seed_into_one_dataset_is_refused(
    tmp_path: Path, objects: Objects, actions: Actions
) -> None:
    tasks = plan_dataset(objects, actions, object_ids=["wood"], action_ids=["P1"], trials=1)
    generate_dataset(tasks, tmp_path, FakeRig, seed=0, workers=1)
    more = plan_dataset(objects, actions, object_ids=["sponge"], action_ids=["P1"], trials=1)
    with pytest.raises(RecorderError, match=r"seed 0 .*--seed 1.*another --out, or --seed 0"):
        generate_dataset(more, tmp_path, FakeRig, seed=1, workers=1)
    assert not (tmp_path / "sponge").exists()
    report = generate_dataset(more, tmp_path, FakeRig, seed=0, workers=1)  # the same seed resumes
    assert report.written == 1


def test_another_rig_configuration_into_one_dataset_is_refused(
    tmp_path: Path, objects: Objects, actions: Actions
) -> None:
    tasks = plan_dataset(objects, actions, object_ids=["wood"], action_ids=["P1"], trials=1)
    generate_dataset(tasks, tmp_path, FakeRig, seed=0, workers=1)

    def faster(seed: int) -> FakeRig:
        return FakeRig(seed, time_scale=0.05)

    with pytest.raises(RecorderError, match=r"another rig configuration \(time_scale='0.1'"):
        generate_dataset(tasks, tmp_path, faster, seed=0, workers=1)

    class Other(FakeRig):  # another rig altogether: its kind is named, not every setting
        def describe(self) -> dict[str, str]:
            return {"kind": "other", "port": "1", "time_scale": "0.05"}

    with pytest.raises(RecorderError) as refused:
        generate_dataset(tasks, tmp_path, Other, seed=0, workers=1)
    said = str(refused.value)
    assert "another rig configuration (kind='fake'; this run: kind='other', e.g. " in said, said
    assert "time_scale" not in said


def test_a_full_disk_in_one_worker_keeps_what_it_wrote(
    tmp_path: Path, objects: Objects, actions: Actions
) -> None:
    from worker_rigs import FullDiskOnTrialOne  # noqa: PLC0415 (importable by the workers)

    tasks = plan_dataset(objects, actions, object_ids=["wood"], action_ids=["P1"], trials=4)
    results: list[TaskResult] = []
    with pytest.raises(RecorderError, match=r"001\.mcap: .*disk is full"):
        generate_dataset(
            tasks, tmp_path, FullDiskOnTrialOne, seed=0, workers=2, on_result=results.append
        )
    left = sorted(p.name for p in tmp_path.rglob("*") if p.is_file())
    assert "001.mcap" not in left  # never published as complete
    finished = {"002.mcap", "003.mcap", "004.mcap", CLAIM_NAME}  # and the directory's claim
    kept = [n for n in left if n not in finished]  # trial 1's messages: incomplete or .part
    assert all(n.startswith("001.") and n.endswith((".incomplete.mcap", ".part")) for n in kept)
    assert TaskStatus.FAILED in [r.status for r in results]


def test_a_full_disk_while_indexing_is_one_error_and_leaves_no_temporary_file(
    tmp_path: Path, objects: Objects, actions: Actions, monkeypatch: pytest.MonkeyPatch
) -> None:
    tasks = plan_dataset(objects, actions, object_ids=["wood"], action_ids=["P1"], trials=1)
    generate_dataset(tasks, tmp_path, FakeRig, seed=0, workers=1)
    before = sorted(tmp_path.rglob("*"))

    def full(*_args: object, **_kwargs: object) -> None:
        message = "parquet: underlying IO error: No space left on device (os error 28)"
        raise pl.exceptions.ComputeError(message)

    monkeypatch.setattr(pl.DataFrame, "write_parquet", full)
    with pytest.raises(RecorderError, match=r"index\.parquet: cannot write the index .*space"):
        write_index(tmp_path)
    assert sorted(tmp_path.rglob("*")) == before


def _alive(pid: int) -> bool:
    """Return True if ``pid`` runs (a zombie waiting to be reaped does not)."""
    stat = Path(f"/proc/{pid}/stat")
    if stat.exists():
        return stat.read_text().rsplit(")", 1)[1].split()[0] not in {"Z", "X"}
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def _wait(condition: Callable[[], bool], seconds: float) -> bool:
    # a hang guard (``seconds`` of 100 ms waits), not a time check
    for _ in range(math.ceil(seconds / 0.1)):
        if condition():
            return True
        time.sleep(0.1)
    return condition()


_KILLED_PARENT = """
import sys
sys.path[:0] = {paths!r}
from conftest import fake_objects
from recorder import generate_dataset, load_actions, plan_dataset
from worker_rigs import SleepingRig
tasks = plan_dataset(fake_objects(), load_actions(), action_ids=["P1"], trials=4)
generate_dataset(tasks, {root!r}, SleepingRig, seed=0, workers=2)
"""


@pytest.mark.skipif(os.name != "posix", reason="SIGKILL")
def test_workers_exit_when_the_dataset_run_is_killed(tmp_path: Path) -> None:
    pids = tmp_path / "pids"
    pids.mkdir()
    here = Path(__file__).resolve().parent
    paths = [str(here.parent), str(here), str(here.parents[1])]
    script = _KILLED_PARENT.format(paths=paths, root=str(tmp_path / "data"))
    env = os.environ | {"ATIKT_TEST_PIDS": str(pids)}
    parent = subprocess.Popen([sys.executable, "-c", script], env=env)  # noqa: S603
    try:
        assert _wait(lambda: len(list(pids.iterdir())) >= 2, 120), "workers did not start"
        workers = [int(p.name) for p in pids.iterdir()]
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        assert _wait(lambda: not any(_alive(pid) for pid in workers), 60), "workers run on"
    finally:
        parent.kill()
        for pid in [int(p.name) for p in pids.iterdir()]:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


@pytest.mark.parametrize("links", ["hard-links", "no-hard-links"])
def test_stale_parts_are_set_aside_never_over_one_set_aside_before(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, links: str
) -> None:
    if links == "no-hard-links":  # a file system without hard links (some network shares): a rename

        def no_link(_source: object, _target: object) -> None:
            raise OSError(errno.EPERM, "Operation not permitted")

        monkeypatch.setattr(os, "link", no_link)
    dead = 2**22 + 7  # above the default pid_max: no such process
    part = tmp_path / "wood" / "P1" / f"001.{dead}-ab12.mcap.part"
    part.parent.mkdir(parents=True)
    moved: list[Path] = []
    for content in (b"first", b"second"):
        part.write_bytes(content)
        moved += set_aside_stale_parts(tmp_path)
        assert not part.exists()
    assert [p.name for p in moved] == [part.name, f"{part.name}.1"]
    assert [p.read_bytes() for p in moved] == [b"first", b"second"]
