"""Skin transports are plug-ins found by name, like rigs: a lab's package adds its own skin."""

from __future__ import annotations

import textwrap
from typing import TYPE_CHECKING, Any

import pytest

from recorder.errors import RigError
from recorder.live import RecorderClock, open_skin, skin_transports

if TYPE_CHECKING:
    from collections.abc import Mapping
    from pathlib import Path

BUILT: list[Mapping[str, Any]] = []


def build_lab_skin(section: Mapping[str, Any], clock: RecorderClock, where: str) -> object:
    """A lab's skin builder (the entry point's target)."""
    del clock, where
    BUILT.append(section)
    return "a lab skin"


def _install(site: Path, monkeypatch: pytest.MonkeyPatch, target: str) -> None:
    info = site / "lab_skin-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: lab-skin\nVersion: 1.0\n")
    points = f"[atikt.skins]\nlabskin = {target}\n"
    (info / "entry_points.txt").write_text(textwrap.dedent(points), "utf-8")
    monkeypatch.syspath_prepend(str(site))


def test_an_installed_skin_is_found_by_name(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _install(tmp_path / "site", monkeypatch, "test_skin_plugins:build_lab_skin")
    assert {"udp", "serial", "ros2", "labskin"} <= set(skin_transports())
    section = {"transport": "labskin", "port": 7}
    built: object = open_skin(section, RecorderClock(), "lab.toml")
    assert built == "a lab skin"
    assert BUILT[-1] == section


def test_a_broken_skin_plugin_is_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _install(tmp_path / "site", monkeypatch, "no_such_module:build")
    with pytest.raises(RigError, match=r"the labskin skin transport is not available .*reinstall"):
        open_skin({"transport": "labskin"}, RecorderClock(), "lab.toml")
    with pytest.raises(RigError, match=r"transport = 'nope': give one of udp, serial, ros2"):
        open_skin({"transport": "nope"}, RecorderClock(), "lab.toml")
