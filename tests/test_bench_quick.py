"""Every benchmark in tests/bench runs to its end in its ``--quick`` mode (no figure is checked).

A benchmark nobody runs rots: an option renamed or an internal moved, and it crashes the day
someone needs its figures. Each script found in tests/bench is run here as its own process with
``--quick`` (a few steps on tiny data, mostly the committed recordings); it must exit 0 and
print something. The feature table of the committed recordings is built once per test run, in
a user cache shared by the scripts (and by the xdist workers, under a lock).
"""

from __future__ import annotations

import fcntl
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "tests" / "bench"
#: Scripts left out here: bench_atikt.py's quick mode has its own test, which also holds its
#: quality targets (tests/atikt/test_atikt_bench.py).
LEFT_OUT = {"bench_atikt.py"}
SCRIPTS = sorted(
    p.name for p in BENCH.glob("*.py") if not p.name.startswith("_") and p.name not in LEFT_OUT
)
#: Seconds one quick run may take before it counts as hung.
TIMEOUT_S = 300


@pytest.fixture(scope="session")
def quick_env(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """The scripts' environment: this checkout first, one BLAS thread, a user cache of its own.

    The cache lies in the run's shared temporary directory (the same for every xdist worker);
    the first worker to get the lock builds the committed recordings' feature table there.
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
    with (cache / ".lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        subprocess.run(build, check=True, cwd=BENCH, env=env, timeout=TIMEOUT_S)  # noqa: S603
    return env


def test_scripts_found() -> None:
    assert "bench_replay.py" in SCRIPTS
    assert "behaviour_hashes.py" in SCRIPTS
    assert not LEFT_OUT & set(SCRIPTS)


@pytest.mark.parametrize("script", SCRIPTS)
def test_quick_mode_runs(script: str, quick_env: dict[str, str], tmp_path: Path) -> None:
    command = [sys.executable, str(BENCH / script), "--quick"]
    done = subprocess.run(  # noqa: S603 (this interpreter, a script of this checkout)
        command,
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env=quick_env | {"TMPDIR": str(tmp_path)},
        timeout=TIMEOUT_S,
        check=False,
    )
    assert done.returncode == 0, f"{script} --quick failed:\n{done.stdout}\n{done.stderr}"
    assert done.stdout.strip(), f"{script} --quick printed nothing:\n{done.stderr}"
