"""README "Bring your own rig": its commands, typed as printed, run."""

import shlex
from pathlib import Path

import pytest

from recorder._cli import main as record
from replay.cli._main import main as replay

LAB_RIG_TOML = """\
rig = "sim"                       # a rig found by name: the simulated one takes SimConfig's fields
[options]
room_c = 21.0
location_spread_m = 0.005
"""
COMMANDS = """\
atikt-record dataset --out data/lab --rig-config lab_rig.toml --rig-option room_c=22.0 \
--objects wood,soft_sponge,metal_toolbox,foam_block,pine_board --actions P1 --trials 2
atikt-replay learn --recordings data/lab --rig-config lab_rig.toml --new foam_block,pine_board \
--actions P1 --budget 3 --test-trials 2
"""


def test_the_readme_commands_run_as_printed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    Path("lab_rig.toml").write_text(LAB_RIG_TOML, "utf-8")
    programs = {"atikt-record": record, "atikt-replay": replay}
    for line in COMMANDS.splitlines():
        program, *argv = shlex.split(line)
        assert programs[program](argv) == 0, capsys.readouterr().err
    assert len(list(Path("data/lab").rglob("*.mcap"))) == 5 * 2
    (run,) = Path("runs").iterdir()
    assert (run / "history.parquet").is_file()
    assert (run / "session" / "session.parquet").is_file()
    assert "step  3" in capsys.readouterr().out
