from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import pytest

from recorder import CatalogError, RigError, SimulatedRig, load_actions, load_objects
from recorder._catalog import PROPERTIES, ObjectPhysics, check_object

if TYPE_CHECKING:
    from pathlib import Path

MINIMAL = """
[{id}]
name = "Thing"
novel = false
stiffness_n_m = 2000
effusivity = 300
texture_period_m = 1e-3
texture_amplitude_m = 5e-6
friction_static = 0.5
friction_kinetic = 0.4
"""


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "objects.toml"
    path.write_text(text, encoding="utf-8")
    return path


def test_packaged_catalog_has_ten_old_and_five_new_objects() -> None:
    objects = load_objects()
    assert len(objects) == 15
    assert sum(not obj.novel for obj in objects.values()) == 10
    assert sum(obj.novel for obj in objects.values()) == 5
    for object_id, obj in objects.items():
        assert obj.id == object_id
        assert obj.name
        assert obj.description
        assert obj.physics is not None
        assert check_object(obj.physics) is None


def test_every_new_object_is_related_to_an_old_one() -> None:
    objects = load_objects()
    for obj in objects.values():
        if obj.novel:
            assert not objects[obj.related_to].novel
            assert obj.shared
            assert set(obj.shared) <= set(PROPERTIES)
        else:
            assert obj.related_to == ""


def test_thesis_objects_are_in_the_catalog() -> None:
    names = " ".join(obj.name.lower() for obj in load_objects().values())
    for word in ("soft sponge", "rough sponge", "paper box", "hard box", "toolbox", "biscuit"):
        assert word in names
    for word in ("glass", "wood", "marble"):
        assert word in names


def test_objects_have_distinct_physical_parameters() -> None:
    physical = [
        dataclasses.replace(obj, id="", name="", description="", related_to="", shared=())
        for obj in load_objects().values()
    ]
    assert len(set(physical)) == len(physical)


def test_actions_catalog_is_unchanged() -> None:
    actions = load_actions()
    assert list(actions) == ["P1", "P2", "S1", "S2", "S3", "S4", "C1"]
    assert actions["C1"].duration_s == 15.0
    assert actions["S4"].speed_m_s == 0.05


def test_minimal_user_entry_takes_the_defaults(tmp_path: Path) -> None:
    objects = load_objects(_write(tmp_path, MINIMAL.format(id="thing")))
    thing = objects["thing"]
    default = ObjectPhysics()
    assert thing.physics is not None
    assert thing.physics.stiffness_n_m == 2000.0
    assert thing.physics.height_m == default.height_m
    assert thing.description == ""
    assert isinstance(thing.physics.texture_period_m, float)


def test_objects_without_physics_are_identities_the_simulator_refuses(tmp_path: Path) -> None:
    objects = load_objects(_write(tmp_path, '[mug]\nname = "Lab mug"\nnovel = true\n'))
    assert objects["mug"].physics is None
    assert (objects["mug"].name, objects["mug"].novel) == ("Lab mug", True)
    with (
        SimulatedRig(0) as rig,
        pytest.raises(RigError, match="'mug' has no physical parameters"),
    ):
        next(iter(rig.perform(objects["mug"], load_actions()["P1"], 0)))


def test_user_catalog_keeps_file_order(tmp_path: Path) -> None:
    text = MINIMAL.format(id="b") + MINIMAL.format(id="a")
    assert list(load_objects(_write(tmp_path, text))) == ["b", "a"]


@pytest.mark.parametrize(
    ("extra", "fragment"),
    [
        ("colour = 'red'", "unknown keys"),
        ("anisotropy = 1.5", "anisotropy must lie in [0, 1]"),
        ("height_m = -0.1", "height_m must be > 0"),
        ("fine_roughness_m = -1e-6", "fine_roughness_m must be >= 0"),
        ("yield_strain = 0.1", "need layer_thickness_m > 0"),
        ("layer_thickness_m = 0.01\nyield_strain = 0.3\ndensification_strain = 0.2", "exceed"),
        ("stiffness_n_m = nan", "must be finite"),
    ],
)
def test_malformed_entries_are_refused_with_the_file_and_entry(
    tmp_path: Path, extra: str, fragment: str
) -> None:
    text = MINIMAL.format(id="thing").replace("stiffness_n_m = 2000\n", "")
    text += "stiffness_n_m = 2000\n" if "stiffness_n_m" not in extra else ""
    path = _write(tmp_path, text + extra + "\n")
    with pytest.raises(CatalogError, match="thing") as info:
        load_objects(path)
    assert str(path) in str(info.value)
    assert fragment in str(info.value)


def test_kinetic_friction_above_static_is_refused(tmp_path: Path) -> None:
    text = MINIMAL.format(id="thing").replace("friction_kinetic = 0.4", "friction_kinetic = 0.7")
    with pytest.raises(CatalogError, match="friction_kinetic"):
        load_objects(_write(tmp_path, text))


def test_missing_required_key_is_named(tmp_path: Path) -> None:
    text = MINIMAL.format(id="thing").replace("effusivity = 300\n", "")
    with pytest.raises(CatalogError, match="effusivity"):
        load_objects(_write(tmp_path, text))


def test_novel_must_be_a_boolean(tmp_path: Path) -> None:
    text = MINIMAL.format(id="thing").replace("novel = false", 'novel = "no"')
    with pytest.raises(CatalogError, match="novel must be true or false"):
        load_objects(_write(tmp_path, text))


@pytest.mark.parametrize(
    ("relation", "fragment"),
    [
        ('related_to = "nothing"\nshared = ["thermal"]', "must name an old object"),
        ('related_to = "old"\nshared = []', "shared must list"),
        ('related_to = "old"\nshared = ["colour"]', "shared must list"),
        ('related_to = "other_new"\nshared = ["thermal"]', "must name an old object"),
    ],
)
def test_new_objects_need_an_old_relative(tmp_path: Path, relation: str, fragment: str) -> None:
    old = MINIMAL.format(id="old")
    other = MINIMAL.format(id="other_new").replace("novel = false", "novel = true")
    other += 'related_to = "old"\nshared = ["stiffness"]\n'
    new = MINIMAL.format(id="new").replace("novel = false", "novel = true") + relation + "\n"
    with pytest.raises(CatalogError, match=r"\[new\]") as info:
        load_objects(_write(tmp_path, old + other + new))
    assert fragment in str(info.value)


def test_a_new_object_may_resemble_no_old_one(tmp_path: Path) -> None:
    old = MINIMAL.format(id="old")
    new = MINIMAL.format(id="new").replace("novel = false", "novel = true")
    objects = load_objects(_write(tmp_path, old + new))
    assert objects["new"].novel
    assert objects["new"].related_to == ""
    assert objects["new"].shared == ()
    with pytest.raises(CatalogError, match=r"\[new\]: related_to = '' must name an old object"):
        load_objects(_write(tmp_path, old + new + 'shared = ["thermal"]\n'))


def test_valid_relation_is_accepted(tmp_path: Path) -> None:
    old = MINIMAL.format(id="old")
    new = MINIMAL.format(id="new").replace("novel = false", "novel = true")
    new += 'related_to = "old"\nshared = ["texture", "thermal"]\n'
    objects = load_objects(_write(tmp_path, old + new))
    assert objects["new"].shared == ("texture", "thermal")


def test_unreadable_and_invalid_files_raise_catalog_errors(tmp_path: Path) -> None:
    with pytest.raises(CatalogError, match="cannot read"):
        load_objects(tmp_path / "missing.toml")
    with pytest.raises(CatalogError, match="not valid TOML"):
        load_objects(_write(tmp_path, "[thing\nname = 1"))


@pytest.mark.parametrize("trials", ["0", "10000000000000000", "2.5", "true", "'20'"])
def test_an_actions_trials_out_of_range_is_refused_with_the_file(
    tmp_path: Path, trials: str
) -> None:
    path = tmp_path / "actions.toml"
    path.write_text(f"[P9]\nkind = 'press'\nduration_s = 1.0\ntrials = {trials}\n", "utf-8")
    with pytest.raises(CatalogError, match=r"\[P9\].*not a number of trials 1\.\.999999") as info:
        load_actions(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize(
    ("line", "said"),
    [
        ("depth_m = -0.001", r"depth_m = -0.001: give a finite number >= 0"),
        ("depth_m = nan", r"depth_m = nan: give a finite number >= 0"),
        ("speed_m_s = inf", r"speed_m_s = inf: give a finite number >= 0"),
        ("duration_s = 0.0", r"duration_s = 0.0: give 0 < duration_s <= 3600 s"),
        ("duration_s = 1e9", r"duration_s = 1000000000.0: give 0 < duration_s <= 3600"),
    ],
)
def test_an_action_no_rig_could_perform_is_refused_before_anything_moves(
    tmp_path: Path, line: str, said: str
) -> None:
    # a press of -1 mm moved the arm, one of 1e9 s held it, until the recording was refused
    path = tmp_path / "actions.toml"
    entry = {"kind": "'press'", "duration_s": "3.0", "depth_m": "0.001"}
    key, _, value = line.partition(" = ")
    entry[key] = value
    path.write_text("[P9]\n" + "".join(f"{k} = {v}\n" for k, v in entry.items()), "utf-8")
    with pytest.raises(CatalogError, match=rf"actions.toml: action \[P9\] {said}"):
        load_actions(path)
