from pathlib import Path

import pytest

from recorder import RecorderError, RigConfig, load_rig_config, rig_factory
from recorder._sim import SimulatedRig


def test_a_rig_is_configured_from_a_file_and_the_command_line(tmp_path: Path) -> None:
    path = tmp_path / "rig.toml"
    path.write_text('rig = "sim"\n[options]\nroom_c = 21.0\nlocation_spread_m = 0.005\n')
    config = load_rig_config(path, options=["room_c=20.5", "tilt_deg=0"])
    options = {"location_spread_m": 0.005, "room_c": 20.5, "tilt_deg": 0}
    assert config == RigConfig("sim", options, source=str(path))
    rig = rig_factory(config)(3)
    assert isinstance(rig, SimulatedRig)
    assert rig.config.room_c == 20.5
    assert rig.describe()["room_c"] == "20.5"


@pytest.mark.parametrize(
    ("text", "options", "match"),
    [
        ('rig = "sim"\n[options]\nroom = 21.0\n', [], "rig option 'room': the sim rig takes"),
        ('rig = "sim"\n[options]\nroom_c = "warm"\n', [], "room_c='warm': give a number"),
        ('rig = "ur10-lab"\n', [], "--rig ur10-lab: unknown rig; known rigs: sim, ur"),
        ('rig = "sim"\n[options.nested]\nx = 1\n', [], "no nesting"),
        ('rig = "sim"\n[options]\nroom_c = nan\n', [], "room_c=nan is not a finite number"),
        ('rig = "sim"\n', ["room_c=inf"], "room_c=inf is not a finite number; give a finite"),
        ("rig = ", [], "cannot read the rig configuration"),
        ('rig = "sim"\nhost = "x"\n', [], r"unknown keys \['host'\]"),
        ('rig = "sim"\n[limits]\nspeed_m_s = 0.1\n', [], r"unknown tables \[limits\]; rig 'sim'"),
        ('rig = "sim"\n', ["room_c"], "give key=value"),
    ],
)
def test_bad_rig_configurations_are_one_line_errors(
    tmp_path: Path, text: str, options: list[str], match: str
) -> None:
    path = tmp_path / "rig.toml"
    path.write_text(text)
    with pytest.raises(RecorderError, match=match):
        rig_factory(load_rig_config(path, options=options))(0)


def test_rig_factories_pickle_into_worker_processes() -> None:
    import pickle  # noqa: PLC0415

    factory = rig_factory(load_rig_config(options=["room_c=21"]))
    assert pickle.loads(pickle.dumps(factory))(1).config.room_c == 21.0  # noqa: S301


def test_the_recorder_cli_records_with_a_configured_rig(tmp_path: Path) -> None:
    from recorder._cli import main  # noqa: PLC0415
    from replay import read_recording  # noqa: PLC0415

    config = tmp_path / "rig.toml"
    config.write_text('rig = "sim"\n[options]\nroom_c = 19.0\n')
    argv = ["action", "--object", "wood", "--action", "S1", "--out", str(tmp_path / "d")]
    assert main([*argv, "--rig-config", str(config), "--rig-option", "room_spread_c=0"]) == 0
    rig = read_recording(tmp_path / "d" / "wood" / "S1" / "001.mcap").metadata.rig
    assert (rig["room_c"], rig["room_spread_c"]) == ("19.0", "0.0")
    assert main([*argv, "--trial", "2", "--rig-option", "room=1"]) != 0
