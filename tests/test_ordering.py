"""The suite's order: the slow tests at the front of two workers' first shares (conftest)."""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import timeline
from conftest import deal_slow_tests, first_shares


@dataclass
class _Item:
    name: str
    seconds: float = 0.0

    def get_closest_marker(self, name: str) -> Any:
        assert name == "slow"
        return pytest.mark.slow(self.seconds).mark if self.seconds else None


def test_first_shares_are_cut_as_worksteal_cuts_them() -> None:
    assert first_shares(10, 4) == [2, 2, 3, 3]
    assert first_shares(1776, 5) == [355, 355, 355, 355, 356]
    assert sum(first_shares(7, 3)) == 7


def test_slow_tests_are_dealt_longest_first_to_two_shares() -> None:
    slow = [_Item(f"s{s}", s) for s in (50, 20, 20, 10, 5, 4)]
    items: list[Any] = [
        *[_Item(f"n{i}") for i in range(7)],
        *slow,
        *[_Item(f"m{i}") for i in range(7)],
    ]
    order = [item.name for item in deal_slow_tests(items, workers=4)]
    assert sorted(order) == sorted(item.name for item in items)  # every test, once
    # shares of 5: the chains take 50+5 and 20+20+10+4 seconds, each at the front of its share
    assert order[:5] == ["s50", "s5", "n0", "n1", "n2"]
    assert order[5:10] == ["s20", "s20", "s10", "s4", "n3"]
    assert "s" not in "".join(name[0] for name in order[10:])


def test_one_worker_runs_the_slow_tests_first() -> None:
    items: list[Any] = [_Item("a"), _Item("b", 3), _Item("c", 9)]
    assert [item.name for item in deal_slow_tests(items, workers=1)] == ["c", "b", "a"]


def test_the_timeline_plugin_says_when_and_where_each_test_ran(tmp_path: Path) -> None:
    (tmp_path / "pytest.ini").write_text("[pytest]\n", "utf-8")
    (tmp_path / "test_two.py").write_text(
        "import time\n\ndef test_a():\n    time.sleep(0.2)\n\ndef test_b():\n    pass\n", "utf-8"
    )
    out = tmp_path / "timeline"
    env = os.environ | {"PYTHONPATH": str(Path(__file__).parent), timeline.DIRECTORY: str(out)}
    for name in (timeline.ORIGIN, "PYTEST_XDIST_WORKER", "PYTEST_ADDOPTS"):  # a run of its own
        env.pop(name, None)
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "timeline", "-p", "no:cacheprovider"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    said = timeline.summary(out)
    assert said.startswith("main: 2 tests, busy 0.")
    assert "longest tests of main, the last to finish:" in said
    first = said.splitlines()[2]
    assert first.endswith("test_two.py::test_a"), said
