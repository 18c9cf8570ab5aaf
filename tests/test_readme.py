"""The documentation's commands, typed as printed: every `atikt-record` / `atikt-replay` line of
the bash blocks of README.md and the manual's pages (docs/*.md) is accepted by the tools' own
parsers, README's set-up extras exist, and the "See your data" examples run on a copy of the
committed recordings."""

from __future__ import annotations

import re
import shlex
import shutil
import tomllib
from pathlib import Path

import pytest

from recorder._cli import build_parser as record_parser
from replay.cli._main import build_parser as replay_parser
from replay.cli._main import main as replay

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text("utf-8")
#: README first, then the manual's pages.
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
BLOCKS = re.findall(r"```bash\n(.*?)```", README, flags=re.DOTALL)
DOC_BLOCKS = [
    block
    for page in PAGES
    for block in re.findall(r"```bash\n(.*?)```", page.read_text("utf-8"), flags=re.DOTALL)
]


def _lines(block: str) -> list[str]:
    """Return a block's commands: continuations joined, comments dropped."""
    joined = re.sub(r"\\\n\s*", " ", block)
    lines = [line.split("  #")[0].split("   #")[0].strip() for line in joined.splitlines()]
    return [line for line in lines if line and not line.startswith("#")]


def _commands() -> list[str]:
    found = []
    for block in DOC_BLOCKS:
        for line in _lines(block):
            for part in line.split("&&"):
                words = part.strip()
                if words.startswith(("atikt-record ", "atikt-replay ")):
                    found.append(words)
    return found


COMMANDS = _commands()


def test_readme_has_its_two_setup_commands() -> None:
    setup = _lines(BLOCKS[0])
    assert len(setup) == 2
    assert setup[0].endswith("atikt-replay study transfer")
    assert setup[1].endswith("python -m pytest -q")
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text("utf-8"))["project"]
    for line in setup:
        wanted = re.search(r'pip install -e "\.\[(.*?)\]"', line)
        assert wanted is not None
        assert set(wanted.group(1).split(",")) <= set(extras["optional-dependencies"])


@pytest.mark.parametrize("command", COMMANDS)
def test_every_readme_command_parses(command: str) -> None:
    program, *argv = shlex.split(command)
    parser = {"atikt-record": record_parser, "atikt-replay": replay_parser}[program]()
    try:
        parser.parse_args(argv)
    except SystemExit as exit_:  # argparse's way of refusing a command line
        pytest.fail(f"documented command refused by {program} ({exit_.code}): {command}")


def test_readme_has_commands_for_every_tool() -> None:
    used = {tuple(shlex.split(c)[:2]) for c in COMMANDS}
    for wanted in ("session", "listen", "dataset", "learn", "view", "export", "check"):
        assert any(words[1] == wanted for words in used), wanted


@pytest.mark.slow(7)
def test_see_your_data_examples_run_on_small_data(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    shutil.copytree(ROOT / "recordings" / "data", tmp_path / "DATASET")
    monkeypatch.chdir(tmp_path)
    ran = 0
    for command in COMMANDS:
        program, *argv = shlex.split(command)
        writes = {"--save", "--out"} & set(argv)
        if program != "atikt-replay" or not writes or not argv[1].startswith("DATASET"):
            continue  # a viewer, a server, or data this test does not have
        assert replay(argv) == 0, capsys.readouterr().err
        ran += 1
    assert ran >= 2
    assert Path("s2.rrd").stat().st_size > 0
    assert sorted(p.name for p in Path("export").iterdir())
