"""A link planted at a temporary name a writer used to choose predictably is never followed."""

import os
from pathlib import Path

import pytest
from conftest import copy_dataset, fake_objects

from recorder._dataset import declare_objects, write_index
from replay.learning._features import build_features
from replay.outputs._export import export
from schemas import dataset_recordings


@pytest.fixture
def dataset(small_dataset: Path, tmp_path: Path) -> Path:
    """A copy of the small dataset without its feature cache."""
    copy = tmp_path / "ds"
    copy_dataset(small_dataset, copy)
    (copy / "features.parquet").unlink(missing_ok=True)
    return copy


@pytest.fixture
def victim(tmp_path: Path) -> Path:
    """A file an attacker would like overwritten."""
    path = tmp_path / "victim.txt"
    path.write_text("precious\n", "utf-8")
    return path


def _plant(link: Path, target: Path) -> None:
    link.parent.mkdir(parents=True, exist_ok=True)
    link.symlink_to(target)


def test_the_feature_cache_never_follows_a_planted_link(dataset: Path, victim: Path) -> None:
    _plant(dataset / f".features.parquet.{os.getpid()}.tmp", victim)
    build_features(dataset, workers=1)
    assert victim.read_text("utf-8") == "precious\n"
    assert (dataset / "features.parquet").is_file()


def test_objects_toml_never_follows_a_planted_link(tmp_path: Path, victim: Path) -> None:
    root = tmp_path / "new"
    _plant(root / f".objects.toml.{os.getpid()}.tmp", victim)
    declare_objects(root, fake_objects().values())
    assert victim.read_text("utf-8") == "precious\n"
    assert "sponge" in (root / "objects.toml").read_text("utf-8")


def test_the_index_never_follows_a_planted_link(dataset: Path, victim: Path) -> None:
    _plant(dataset / f".index.parquet.{os.getpid()}.tmp", victim)
    write_index(dataset)
    assert victim.read_text("utf-8") == "precious\n"


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_exports_never_follow_planted_links(
    dataset: Path, tmp_path: Path, victim: Path, fmt: str
) -> None:
    out = tmp_path / "export"
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    for name in ("recordings", "phases", "force", "temperature"):
        _plant(out / f"{name}.{fmt}.part", victim)
    _plant(out / f".export-parts-{fmt}", elsewhere)
    report = export(dataset_recordings(dataset)[:2], out, fmt=fmt)
    assert victim.read_text("utf-8") == "precious\n"
    assert list(elsewhere.iterdir()) == []
    assert all(path.is_file() and not path.is_symlink() for path in report.files)
