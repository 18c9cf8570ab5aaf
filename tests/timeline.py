"""Each xdist worker's tests in time: where a run of the suite spends its wall time.

Load it as a plugin, then summarise what the workers wrote::

    ATIKT_TIMELINE=/tmp/tl python -m pytest -q -p timeline
    python tests/timeline.py /tmp/tl

Each worker writes ``<worker>.tsv`` into the directory: a line per test with its start and
end, seconds from the worker's start (``ATIKT_TIMELINE_T0``, set by the main process so the
workers share one origin). The summary prints per worker its tests, its busy time and when it
finished, then the longest tests of the worker that finished last: the run's longest path.
Written by hand: pytest's ``--durations`` gives each test's length, not when and where it ran.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import pytest

#: The directory the workers write into (no directory: the plugin does nothing).
DIRECTORY = "ATIKT_TIMELINE"
#: The run's origin (time.time() of the main process), shared by its workers.
ORIGIN = "ATIKT_TIMELINE_T0"


def _origin() -> float:
    return float(os.environ.setdefault(ORIGIN, repr(time.time())))


_ORIGIN = _origin() if os.environ.get(DIRECTORY) else 0.0
_STARTS: dict[str, float] = {}
#: Whether this process writes: not the main process of an xdist run (its workers do).
_WRITING = [bool(os.environ.get(DIRECTORY))]


def pytest_sessionstart(session: pytest.Session) -> None:
    """Leave the writing to the workers when the tests run on xdist workers."""
    if session.config.pluginmanager.has_plugin("dsession"):  # pytest-xdist's main process
        _WRITING[0] = False


def _write(line: str) -> None:
    directory = Path(os.environ[DIRECTORY])
    directory.mkdir(parents=True, exist_ok=True)
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    with (directory / f"{worker}.tsv").open("a", encoding="utf-8") as out:
        out.write(line)


def pytest_runtest_logstart(nodeid: str, location: object) -> None:  # noqa: ARG001 (the hook's)
    """Note when a test starts."""
    if _WRITING[0]:
        _STARTS[nodeid] = time.time() - _ORIGIN


def pytest_runtest_logfinish(nodeid: str, location: object) -> None:  # noqa: ARG001 (the hook's)
    """Write the test's start and end."""
    if _WRITING[0] and nodeid in _STARTS:
        _write(f"{_STARTS.pop(nodeid):.2f}\t{time.time() - _ORIGIN:.2f}\t{nodeid}\n")


def summary(directory: Path, longest: int = 10) -> str:
    """Return the run's summary from the workers' files in ``directory``."""
    workers: dict[str, list[tuple[float, float, str]]] = {}
    for path in sorted(directory.glob("*.tsv")):
        rows = []
        for line in path.read_text("utf-8").splitlines():
            start, end, nodeid = line.split("\t", 2)
            rows.append((float(start), float(end), nodeid))
        workers[path.stem] = rows
    if not workers:
        return f"{directory}: no worker's timeline (run pytest with -p timeline and {DIRECTORY})"
    lines = []
    for name, rows in workers.items():
        busy = sum(end - start for start, end, _ in rows)
        finished = max(end for _, end, _ in rows)
        lines.append(f"{name}: {len(rows)} tests, busy {busy:.1f} s, finished at {finished:.1f} s")
    last = max(workers, key=lambda name: max(end for _, end, _ in workers[name]))
    lines.append(f"longest tests of {last}, the last to finish:")
    rows = sorted(workers[last], key=lambda row: row[0] - row[1])[:longest]
    lines += [
        f"  {start:7.1f}-{end:7.1f} s  {end - start:6.1f} s  {node}" for start, end, node in rows
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    print(summary(Path(sys.argv[1])))
