"""Exclusive temporary files and the input/output overlap rule of the command lines."""

from pathlib import Path

import pytest

from schemas import (
    ContractError,
    atomic_path,
    atomic_write,
    atomic_write_text,
    check_inside,
    recording_path,
    temporary_name,
)
from schemas._cli import CliError, refuse_overlap


def test_atomic_write_replaces_the_target_and_leaves_no_temporary(tmp_path: Path) -> None:
    target = tmp_path / "a.txt"
    target.write_text("old", "utf-8")
    atomic_write_text(target, "new")
    assert target.read_text("utf-8") == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]


def test_a_link_at_the_target_is_replaced_not_followed(tmp_path: Path) -> None:
    victim = tmp_path / "victim"
    victim.write_text("precious", "utf-8")
    target = tmp_path / "out.txt"
    target.symlink_to(victim)
    atomic_write(target, lambda stream: stream.write(b"data"))
    assert victim.read_text("utf-8") == "precious"
    assert not target.is_symlink()
    assert target.read_bytes() == b"data"


def test_without_replace_an_existing_target_is_kept(tmp_path: Path) -> None:
    target = tmp_path / "report.json"
    target.write_text("first", "utf-8")
    with pytest.raises(FileExistsError):
        atomic_write_text(target, "second", replace=False)
    assert target.read_text("utf-8") == "first"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.json"]


def test_a_failed_write_leaves_neither_target_nor_temporary(tmp_path: Path) -> None:
    def fail(_stream: object) -> None:
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError, match="No space"):
        atomic_write(tmp_path / "x.parquet", fail)
    with pytest.raises(OSError, match="No space"), atomic_path(tmp_path / "y.parquet"):
        raise OSError(28, "No space left on device")
    assert list(tmp_path.iterdir()) == []


def test_temporary_names_are_unpredictable(tmp_path: Path) -> None:
    names = {temporary_name(tmp_path / "index.parquet") for _ in range(100)}
    assert len(names) == 100
    assert all(n.name.startswith(".index.parquet.") for n in names)


@pytest.mark.parametrize(
    ("out", "how"),
    [
        ("parent/ds", "is"),
        ("parent", "contains"),
        ("parent/ds/results", "lies inside"),
        ("link", "is"),
    ],
)
def test_an_output_overlapping_an_input_is_refused(tmp_path: Path, out: str, how: str) -> None:
    dataset = tmp_path / "parent" / "ds"
    dataset.mkdir(parents=True)
    (tmp_path / "link").symlink_to(dataset)
    with pytest.raises(CliError, match=f"--out {tmp_path / out}: {how} the dataset") as err:
        refuse_overlap(tmp_path / out, [("dataset", dataset), ("--session", None)])
    assert "\n" not in str(err.value)


def test_an_output_beside_the_input_is_allowed(tmp_path: Path) -> None:
    (tmp_path / "ds").mkdir()
    refuse_overlap(tmp_path / "ds-results", [("dataset", tmp_path / "ds")])
    refuse_overlap(tmp_path / "out.rrd", [("input", tmp_path / "in.mcap")], option="--save")


@pytest.mark.parametrize("bad", ["../escape", "/abs", "a/b", "", "a\x00b", ".hidden", "x" * 65])
def test_recording_paths_refuse_names_that_are_not_ids(tmp_path: Path, bad: str) -> None:
    with pytest.raises(ContractError, match="is not an id"):
        recording_path(tmp_path, bad, "P1", 1)
    with pytest.raises(ContractError, match="is not an id"):
        recording_path(tmp_path, "wood", bad, 1)


def test_a_path_through_a_link_out_of_the_directory_is_refused(tmp_path: Path) -> None:
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    out.mkdir()
    elsewhere.mkdir()
    (out / "wood").symlink_to(elsewhere)
    with pytest.raises(ContractError, match="outside the output directory"):
        recording_path(out, "wood", "P1", 1)
    assert check_inside(out, out / "oak" / "P1") == out / "oak" / "P1"
