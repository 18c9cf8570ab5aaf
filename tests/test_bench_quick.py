"""Every benchmark in tests/bench runs to its end in its ``--quick`` mode (no figure is checked).

A benchmark nobody runs rots: an option renamed or an internal moved, and it crashes the day
someone needs its figures. Each script found in tests/bench is run here as its own process with
``--quick`` (a few steps on tiny data, mostly the committed recordings); it must exit 0 and
print something. The processes are forks of a launcher (``tests/bench/_launcher.py``, one per
xdist worker) that has imported numpy, polars, scikit-learn and the project once, instead of a
fresh interpreter each that imports them again. The feature table of the committed recordings
is built once per test run, in a user cache shared by the scripts (and by the xdist workers,
under a lock).
"""

from __future__ import annotations

import fcntl
import json
import os
import select
import signal
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

if TYPE_CHECKING:
    from collections.abc import Iterator

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "tests" / "bench"
#: Scripts left out here: their quick modes have tests of their own, which also check what they
#: print (bench_atikt.py: its quality targets, tests/atikt/test_atikt_bench.py;
#: bench_listen_soak.py: every file written passes check with nothing missing,
#: tests/recorder/test_listen_live.py). Run here too, each took a second 10-20 s.
LEFT_OUT = {"bench_atikt.py", "bench_listen_soak.py"}
SCRIPTS = sorted(
    p.name for p in BENCH.glob("*.py") if not p.name.startswith("_") and p.name not in LEFT_OUT
)
#: Seconds a quick run took alone (the slowest; tests/conftest.py runs the slowest tests first).
QUICK_S = {
    "bench_stop_latency.py": 16,
    "behaviour_hashes.py": 12,
    "transfer_speed.py": 8,
    "bench_live.py": 7,
    "bench_view_export.py": 5,
    "bench_replay.py": 5,
    "bench_live_dds.py": 5,
}
#: The launcher's import of the libraries, seconds before it counts as hung.
READY_S = 120
#: Seconds one quick run may take before it counts as hung.
TIMEOUT_S = 300


@pytest.fixture(scope="session")
def quick_env(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """The scripts' environment: this checkout first, one BLAS thread, a user cache of its own.

    The cache lies in the run's shared temporary directory (the same for every xdist worker);
    the first worker to get the lock builds the committed recordings' feature table there and
    says so in a file beside it: the next workers find the table built (a fresh interpreter
    each, only to find it so, cost a few seconds of CPU).
    """
    base = tmp_path_factory.getbasetemp()
    shared = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    cache = shared / "bench-quick-cache"
    cache.mkdir(exist_ok=True)
    env = os.environ | {
        "PYTHONPATH": str(ROOT),
        "ATIKT_CACHE": str(cache),
        "OPENBLAS_NUM_THREADS": "1",
        "OMP_NUM_THREADS": "1",
        "MPLBACKEND": "Agg",
    }
    build = [sys.executable, "-c", "import _quick; _quick.quick_features()"]
    built = cache / ".built"
    with (cache / ".lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not built.exists():
            subprocess.run(build, check=True, cwd=BENCH, env=env, timeout=TIMEOUT_S)  # noqa: S603
            built.touch()
    return env


def test_scripts_found() -> None:
    assert "bench_replay.py" in SCRIPTS
    assert "behaviour_hashes.py" in SCRIPTS
    assert not LEFT_OUT & set(SCRIPTS)
    assert set(QUICK_S) <= set(SCRIPTS)


class _Launcher:
    """A running ``_launcher.py``: one script at a time, each a fork of it."""

    def __init__(self, env: dict[str, str]) -> None:
        self.process = subprocess.Popen(  # noqa: S603 (this interpreter, a script of this checkout)
            [sys.executable, str(BENCH / "_launcher.py")],
            cwd=BENCH,
            env=env,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            bufsize=0,  # unbuffered: select() sees every answer
        )
        assert self._answer(READY_S) == {"ready": 1}

    def _answer(self, timeout_s: float) -> dict[str, int] | None:
        """Return the launcher's next answer, or None when none came within ``timeout_s``."""
        assert self.process.stdout is not None
        ready, _, _ = select.select([self.process.stdout], [], [], timeout_s)
        if not ready:
            return None
        line = self.process.stdout.readline()
        assert line, f"the launcher ended (status {self.process.wait()})"
        answer: dict[str, int] = json.loads(line)
        return answer

    def run(self, script: Path, argv: list[str], cwd: Path, env: dict[str, str]) -> int | None:
        """Run ``script ARGV`` in ``cwd``; its exit status (None: killed after TIMEOUT_S).

        What it prints is in ``cwd/stdout.txt`` and ``cwd/stderr.txt``.
        """
        assert self.process.stdin is not None
        request: dict[str, Any] = {"script": str(script), "argv": argv, "cwd": str(cwd)}
        request |= {
            "env": env,
            "stdout": str(cwd / "stdout.txt"),
            "stderr": str(cwd / "stderr.txt"),
        }
        self.process.stdin.write(json.dumps(request).encode() + b"\n")
        started = self._answer(READY_S)
        assert started is not None
        assert "pid" in started
        ended = self._answer(TIMEOUT_S)
        if ended is None:  # hung: killed, and the launcher reports its end
            os.kill(started["pid"], signal.SIGKILL)
            assert self._answer(READY_S) is not None
            return None
        # a process the script started and left running (a virtual lab ticking on for the
        # rest of the run) is killed by the launcher, and the run fails
        assert not ended["left"], f"{script} left processes running (killed)"
        return ended["status"]

    def close(self) -> None:
        """End the launcher (end of its input)."""
        assert self.process.stdin is not None
        self.process.stdin.close()
        self.process.wait(timeout=30)


@pytest.fixture(scope="session")
def launcher(quick_env: dict[str, str]) -> Iterator[_Launcher]:
    """This worker's launcher of the quick runs."""
    running = _Launcher(quick_env)
    try:
        yield running
    finally:
        running.close()


@pytest.mark.parametrize(
    "script",
    [pytest.param(s, marks=pytest.mark.slow(QUICK_S[s])) if s in QUICK_S else s for s in SCRIPTS],
)
def test_quick_mode_runs(
    script: str, quick_env: dict[str, str], launcher: _Launcher, tmp_path: Path, dds_domain: int
) -> None:
    argv = ["--quick"]
    if '"--domain"' in (BENCH / script).read_text("utf-8"):  # a DDS benchmark: its own domain
        argv += ["--domain", str(dds_domain)]
    status = launcher.run(BENCH / script, argv, tmp_path, quick_env | {"TMPDIR": str(tmp_path)})
    stdout = (tmp_path / "stdout.txt").read_text("utf-8", errors="replace")
    stderr = (tmp_path / "stderr.txt").read_text("utf-8", errors="replace")
    assert status is not None, (
        f"{script} --quick still ran after {TIMEOUT_S} s:\n{stdout}\n{stderr}"
    )
    assert status == 0, f"{script} --quick failed:\n{stdout}\n{stderr}"
    assert stdout.strip(), f"{script} --quick printed nothing:\n{stderr}"
