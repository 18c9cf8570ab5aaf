"""The manual: the site builds with warnings as errors, and README's links lead to its pages.

The build is CI's (`mkdocs build --strict`, .ci/run): a broken link or anchor, a page missing
from the navigation or a docstring the API reference cannot read fails it.
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from replay.outputs.readme_tables import marked_files

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text("utf-8")
PAGES = sorted((ROOT / "docs").glob("*.md"))


@pytest.mark.slow(9)
def test_the_site_builds_strictly(tmp_path: Path) -> None:
    if importlib.util.find_spec("mkdocs") is None:
        pytest.skip("mkdocs is not installed: pip install -e '.[docs]' (part of '.[dev]')")
    env = os.environ | {"NO_MKDOCS_2_WARNING": "1"}
    site = tmp_path / "site"
    done = subprocess.run(  # noqa: S603 (the documentation's own build)
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    for page in PAGES:
        assert (site / page.stem / "index.html").is_file() or page.stem == "index", page
    reference = (site / "api" / "atikt" / "index.html").read_text("utf-8")
    assert 'id="atikt.ActiveLearner"' in reference  # a name of atikt.__all__
    assert 'id="atikt.active"' not in reference  # its modules are not the public API
    getting_started = (site / "getting-started" / "index.html").read_text("utf-8")
    assert "python -m pytest -q" in re.sub(r"<[^>]+>", "", getting_started)  # README's set-up
    # a repository file the pages link to is served with the site, a README as a page whose
    # links lead back into the manual
    assert (site / "repo" / "recorder" / "data" / "ur_rig.example.toml").is_file()
    contract = (site / "repo" / "schemas" / "index.html").read_text("utf-8")
    assert 'href="../../your-rig/"' in contract
    assert 'href="contract.toml"' in contract


def test_readme_is_short_and_its_links_resolve() -> None:
    assert README.count("\n") <= 200
    targets = re.findall(r"\]\((?!https?:)([^)#\s]+)", README)
    assert any(t.startswith("docs/") for t in targets)
    for target in targets:
        assert (ROOT / target).exists(), target


def test_every_page_of_the_manual_is_linked_from_readme() -> None:
    linked = set(re.findall(r"\]\((docs/[^)#\s]+\.md)", README))
    wanted = {f"docs/{p.name}" for p in PAGES if p.name != "index.md"}
    assert wanted <= linked


def test_readmes_headline_table_is_one_of_the_results_pages() -> None:
    files = marked_files(ROOT / "README.md", ROOT / "docs")
    assert files == [ROOT / "README.md", ROOT / "docs" / "results.md"]
    block = re.compile(r"<!-- results:(\S+) -->\n(.*?)<!-- /results:", re.DOTALL)
    blocks = [dict(block.findall(p.read_text("utf-8"))) for p in files]
    assert blocks[0]
    for name, table in blocks[0].items():
        assert blocks[1][name] == table, name
