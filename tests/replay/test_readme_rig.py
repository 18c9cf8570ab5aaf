"""The manual's "Bring your own rig" (docs/your-rig.md): its commands, typed as printed, run."""

import shlex
from pathlib import Path

import pytest

from recorder._cli import main as record
from replay.cli._main import main as replay

PAGE = Path(__file__).resolve().parents[2] / "docs" / "your-rig.md"


def _blocks(after: str) -> tuple[str, str]:
    """Return the bash and the TOML block that follow ``after`` in the page."""
    text = PAGE.read_text("utf-8")
    rest = text[text.index(after) :]
    bash = rest[rest.index("```bash\n") + 8 :]
    toml = rest[rest.index("```toml\n") + 8 :]
    return bash[: bash.index("```")], toml[: toml.index("```")]


COMMANDS, LAB_RIG_TOML = _blocks("**Its rig, live**")


def test_the_readme_commands_run_as_printed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    Path("lab_rig.toml").write_text(LAB_RIG_TOML, "utf-8")
    programs = {"atikt-record": record, "atikt-replay": replay}
    for line in COMMANDS.replace("\\\n", " ").splitlines():
        program, *argv = shlex.split(line)
        assert programs[program](argv) == 0, capsys.readouterr().err
    assert len(list(Path("data/lab").rglob("*.mcap"))) == 5 * 2
    (run,) = Path("runs").iterdir()
    assert (run / "history.parquet").is_file()
    assert (run / "session" / "session.parquet").is_file()
    assert "step  3" in capsys.readouterr().out
