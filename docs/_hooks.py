"""MkDocs hook: the repository's files that the manual links to are part of the site.

The pages link to the repository's own files relative to ``docs/`` (``../schemas/contract.toml``,
``../recordings/thermal_probe``), so the links work wherever the Markdown is read as it is (a
checkout, a code host). In the built site such a file is served under ``repo/`` with its
repository path (``repo/schemas/contract.toml``); a Markdown file becomes a page whose own
relative links are followed the same way, and a directory link goes to the directory's
``README.md`` or, without one, to a generated list of its files. MkDocs then checks every link
as usual (``--strict``): a link to a file that exists nowhere still fails the build.
"""

from __future__ import annotations

import posixpath
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mkdocs.structure.files import File, InclusionLevel

if TYPE_CHECKING:
    from mkdocs.config.defaults import MkDocsConfig
    from mkdocs.structure.files import Files
    from mkdocs.structure.pages import Page

ROOT = Path(__file__).resolve().parents[1]
#: Where the repository's files are served in the site.
PREFIX = "repo"
#: A Markdown link's target (without its anchor); links written as URLs are left alone.
_LINK = re.compile(r"(?P<head>\]\()(?P<target>[^)\s#]+)(?P<tail>[^)\s]*\))")
_SCHEME = re.compile(r"^[a-z][a-z0-9+.-]*:", re.IGNORECASE)


def _nav_paths(nav: Any) -> list[str]:  # noqa: ANN401 (MkDocs' nav is nested YAML)
    """Return every page path the configuration's ``nav`` names."""
    if isinstance(nav, str):
        return [nav]
    if isinstance(nav, dict):
        return [p for value in nav.values() for p in _nav_paths(value)]
    if isinstance(nav, list):
        return [p for item in nav for p in _nav_paths(item)]
    return []


def _repo_target(base: Path, target: str) -> str | None:
    """Return ``target`` (relative to ``base``) as a repository path, or None if it is not one.

    None for URLs, absolute paths, anything under ``docs/`` (MkDocs' own files) and anything
    outside the repository.
    """
    if _SCHEME.match(target) or target.startswith("/"):
        return None
    path = Path(posixpath.normpath((base / target).as_posix()))
    if not path.is_relative_to(ROOT) or path.is_relative_to(ROOT / "docs"):
        return None
    return path.relative_to(ROOT).as_posix()


def _docs_target(base: Path, target: str, docs: Path) -> str | None:
    """Return ``target`` (relative to ``base``) as a page of the manual, or None."""
    if _SCHEME.match(target) or target.startswith("/"):
        return None
    path = Path(posixpath.normpath((base / target).as_posix()))
    return path.relative_to(docs).as_posix() if path.is_relative_to(docs) else None


def _page_of(rel: str) -> str:
    """Return the repository file a link to ``rel`` shows: the file, or a directory's page."""
    if not (ROOT / rel).is_dir():
        return rel
    return f"{rel}/README.md" if (ROOT / rel / "README.md").is_file() else f"{rel}/index.md"


def _listing(rel: str) -> str:
    """Return the generated page of a directory without a README: its files, linked."""
    names = sorted(p.name for p in (ROOT / rel).iterdir() if p.is_file())
    return f"# {rel}/\n\n" + "".join(f"- [{name}]({name})\n" for name in names)


def _links(path: Path) -> list[str]:
    """Return the repository paths a Markdown file links to."""
    text = path.read_text("utf-8")
    return [t for m in _LINK.finditer(text) if (t := _repo_target(path.parent, m["target"]))]


def _add(rel: str, files: Files, config: MkDocsConfig, in_nav: set[str]) -> list[str]:
    """Put repository path ``rel`` (a file or a directory) into the site.

    Returns:
        The repository paths that must follow it: a Markdown file's links, or the files of a
        directory whose generated page lists them.
    """
    shown = _page_of(rel)
    uri = f"{PREFIX}/{shown}"
    if files.get_file_from_path(uri) is not None:
        return []
    inclusion = InclusionLevel.UNDEFINED if uri in in_nav else InclusionLevel.NOT_IN_NAV
    if (ROOT / shown).is_file():
        source = str(ROOT / shown)
        files.append(File.generated(config, uri, abs_src_path=source, inclusion=inclusion))
        return _links(ROOT / shown) if shown.endswith(".md") else []
    if not (ROOT / rel).is_dir():
        return []  # not in the repository: MkDocs reports the link
    files.append(File.generated(config, uri, content=_listing(rel), inclusion=inclusion))
    return [f"{rel}/{p.name}" for p in sorted((ROOT / rel).iterdir()) if p.is_file()]


def on_files(files: Files, config: MkDocsConfig) -> Files:
    """Add the repository files the pages link to (and those the nav names) to the site."""
    in_nav = {p for p in _nav_paths(config.nav) if p.startswith(f"{PREFIX}/")}
    wanted = [p.removeprefix(f"{PREFIX}/") for p in sorted(in_nav)]
    for page in files.documentation_pages():
        if page.abs_src_path is not None:
            wanted += _links(Path(page.abs_src_path))
    while wanted:
        wanted += _add(wanted.pop(), files, config, in_nav)
    return files


def on_page_markdown(markdown: str, page: Page, config: MkDocsConfig, **_: object) -> str:
    """Point a page's links to repository files at their copies in the site."""
    docs = Path(config.docs_dir)
    src = page.file.src_uri
    in_repo = src.startswith(f"{PREFIX}/")
    base = ROOT / Path(src).relative_to(PREFIX).parent if in_repo else (docs / src).parent

    def _site_link(match: re.Match[str]) -> str:
        rel = _repo_target(base, match["target"])
        if rel is not None:
            uri = f"{PREFIX}/{_page_of(rel)}"
        elif in_repo and (page_uri := _docs_target(base, match["target"], docs)) is not None:
            uri = page_uri  # a repository file's link to one of the manual's pages
        else:
            return match[0]
        return f"{match['head']}{posixpath.relpath(uri, posixpath.dirname(src))}{match['tail']}"

    return _LINK.sub(_site_link, markdown)
