"""Ids that become paths are checked where they enter; objects.toml round-trips every id."""

import tomllib
from pathlib import Path

import pytest
from conftest import fake_objects
from hypothesis import given, settings
from hypothesis import strategies as st

from recorder._catalog import ObjectSpec, load_actions, load_objects
from recorder._cli import main
from recorder._dataset import OBJECTS_FILE, declare_objects
from recorder.errors import CatalogError
from replay.learning._datasets import declared_novel

_OBJECT = 'name = "Escape"\nstiffness_n_m = 1e6\neffusivity = 450.0\ntexture_period_m = 1e-3\n'
_OBJECT += "texture_amplitude_m = 0.0\nfriction_static = 0.5\nfriction_kinetic = 0.4\n"
_ACTION = 'kind = "press"\nduration_s = 1.0\ndepth_m = 0.001\n'
_BAD = ["../escape", "../../act", "/abs/path", "a\\u0000b", "", "a/b"]


@pytest.mark.parametrize("bad", _BAD)
def test_catalog_ids_that_are_not_ids_are_refused_naming_file_id_and_rule(
    tmp_path: Path, bad: str
) -> None:
    objects = tmp_path / "objects.toml"
    objects.write_text(f'["{bad}"]\n{_OBJECT}', "utf-8")
    actions = tmp_path / "actions.toml"
    actions.write_text(f'["{bad}"]\n{_ACTION}', "utf-8")
    with pytest.raises(CatalogError, match="is not an id: use 1-64 letters") as err:
        load_objects(objects)
    assert str(objects) in str(err.value)
    assert "\n" not in str(err.value)
    with pytest.raises(CatalogError, match=f"{actions}: action .* is not an id"):
        load_actions(actions)


@pytest.mark.parametrize("bad", ["../escape", "ABSOLUTE", "a\\u0000b"])
def test_record_action_with_a_hostile_catalog_writes_nothing_anywhere(
    tmp_path: Path, bad: str, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = bad.replace("ABSOLUTE", str(tmp_path / "abs"))  # outside --out, inside the test's
    catalog = tmp_path / "catalogs" / "objects.toml"
    catalog.parent.mkdir()
    catalog.write_text(f'["{bad}"]\n{_OBJECT}', "utf-8")
    out = tmp_path / "a" / "b" / "out"
    argv = ["action", "--object", bad.replace("\\u0000", "\x00"), "--action", "P1"]
    status = main([*argv, "--out", str(out), "--objects-catalog", str(catalog)])
    err = capsys.readouterr().err
    assert status == 1
    assert len(err.strip().splitlines()) == 1
    assert "is not an id" in err
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*")) == [
        "catalogs",
        "catalogs/objects.toml",
    ]


_IDS = st.from_regex(r"[A-Za-z0-9][A-Za-z0-9_.+-]{0,63}", fullmatch=True)


@settings(max_examples=60, deadline=None)
@given(ids=st.lists(_IDS, min_size=1, max_size=4, unique=True), novel=st.booleans())
def test_objects_toml_round_trips_every_valid_id(
    tmp_path_factory: pytest.TempPathFactory, ids: list[str], *, novel: bool
) -> None:
    root = tmp_path_factory.mktemp("ds")
    first = [ObjectSpec(i, f"name of {i}", 'a "quoted" \\ description', novel=novel) for i in ids]
    declare_objects(root, first[:1])
    declare_objects(root, first)  # appended below the first declaration
    table = tomllib.loads((root / OBJECTS_FILE).read_text("utf-8"))
    assert sorted(table) == sorted(ids)
    for spec in first:
        assert table[spec.id] == {
            "name": spec.name,
            "description": spec.description,
            "novel": novel,
        }
    assert declared_novel(root) == (set(ids) if novel else set())


@pytest.mark.parametrize("object_id", ["oak+1", "oak.v2"])
def test_ids_with_toml_punctuation_keep_their_fields(tmp_path: Path, object_id: str) -> None:
    declare_objects(
        tmp_path, [ObjectSpec(object_id, "Oak", "", novel=True), *fake_objects().values()]
    )
    assert declared_novel(tmp_path) == {object_id, "sponge"}
