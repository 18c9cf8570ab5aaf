"""Rig plug-ins for tests, importable by worker processes (no pytest needed).

The rigs stream the fake rig's signals and leave a trace per event in the directory of their
``log_dir`` option: an empty file ``<pid>-<n>-<event>`` (``perform-<object>-<action>-<trial>``,
``present-<object>``), so a test sees which process did what and in which order.
"""

from __future__ import annotations

import itertools
import os
import textwrap
from pathlib import Path
from typing import TYPE_CHECKING

from conftest import FakeRig

from recorder import RecorderError, RigConfig, RigPlugin, refuse_sections

if TYPE_CHECKING:
    from collections.abc import Iterator, Mapping

    import pytest

    from recorder import ActionSpec, ObjectSpec, StreamItem
    from schemas import RigValue

_COUNTER = itertools.count()


class TracingRig(FakeRig):
    """The fake rig, tracing every action into ``log_dir``."""

    def __init__(self, seed: int, log_dir: Path) -> None:
        super().__init__(seed, time_scale=0.01)
        self.log_dir = log_dir

    def trace(self, event: str) -> None:
        (self.log_dir / f"{os.getpid()}-{next(_COUNTER):04d}-{event}").touch()

    def perform(self, obj: ObjectSpec, action: ActionSpec, trial: int) -> Iterator[StreamItem]:
        self.trace(f"perform-{obj.id}-{action.id}-{trial}")
        yield from super().perform(obj, action, trial)


class PresentingRig(TracingRig):
    """Brings the objects that have a pose (``[poses]`` of the rig configuration) itself."""

    def __init__(self, seed: int, log_dir: Path, poses: Mapping[str, object]) -> None:
        super().__init__(seed, log_dir)
        self.poses = poses

    def can_present(self, obj: ObjectSpec) -> bool:
        return obj.id in self.poses

    def present(self, obj: ObjectSpec) -> bool:
        self.trace(f"present-{obj.id}")
        return obj.id in self.poses


def _log_dir(options: Mapping[str, RigValue]) -> Path:
    if set(options) != {"log_dir"}:
        msg = f"rig options {sorted(options)}: the tracing rig takes log_dir only"
        raise RecorderError(msg)
    return Path(str(options["log_dir"]))


def bare_builder(seed: int, options: Mapping[str, RigValue]) -> TracingRig:
    """A bare builder ``builder(seed, options)``."""
    return TracingRig(seed, _log_dir(options))


def build(seed: int, config: RigConfig) -> TracingRig:
    """A plug-in's builder: options only."""
    refuse_sections(config)
    return TracingRig(seed, _log_dir(config.options))


def build_presenting(seed: int, config: RigConfig) -> PresentingRig:
    """A plug-in's builder that reads the ``[poses]`` table."""
    refuse_sections(config, ["poses"])
    return PresentingRig(seed, _log_dir(config.options), config.sections.get("poses", {}))


PLUGIN = RigPlugin(build, description="tracing fake rig")
EXCLUSIVE = RigPlugin(build, exclusive=True, description="tracing fake rig, exclusive")
PRESENTING = RigPlugin(build_presenting, exclusive=True, description="presents objects")
NOT_A_PLUGIN = 42

ENTRY_POINTS = """\
[atikt.rigs]
fake = rig_plugins:PLUGIN
fake-exclusive = rig_plugins:EXCLUSIVE
fake-bare = rig_plugins:bare_builder
fake-presenting = rig_plugins:PRESENTING
broken = no_such_module_for_atikt_tests:PLUGIN
not-a-plugin = rig_plugins:NOT_A_PLUGIN
"""


def install_entry_points(site: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Install a distribution ``atikt-test-rigs`` declaring :data:`ENTRY_POINTS` on sys.path."""
    info = site / "atikt_test_rigs-1.0.dist-info"
    info.mkdir(parents=True)
    metadata = "Metadata-Version: 2.1\nName: atikt-test-rigs\nVersion: 1.0\n"
    (info / "METADATA").write_text(textwrap.dedent(metadata), "utf-8")
    (info / "entry_points.txt").write_text(ENTRY_POINTS, "utf-8")
    monkeypatch.syspath_prepend(str(site))


def traces(log_dir: Path) -> list[tuple[int, str]]:
    """Return (pid, event) of every trace, in order."""
    found = []
    for path in sorted(log_dir.iterdir(), key=lambda p: p.name.split("-", 2)[1]):
        pid, _, event = path.name.split("-", 2)
        found.append((int(pid), event))
    return found
