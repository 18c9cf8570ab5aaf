"""The learner's benchmark runs to its end in its quick mode and meets its quality targets.

No time is asserted: a benchmark's timings mean nothing on a shared machine; what is checked is
that the script still runs (it crashed once on an option of a strategy) and that the update's
optima are still those of the reference (the script's exit status).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
BENCH = ROOT / "tests" / "bench" / "bench_atikt.py"


@pytest.mark.slow(13)
def test_bench_atikt_quick_runs_and_meets_its_quality_targets() -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1"}
    done = subprocess.run(  # noqa: S603 - this repository's own script
        [sys.executable, str(BENCH), "--quick"],
        capture_output=True,
        text=True,
        env=env,
        cwd=ROOT,
        timeout=900,
        check=False,
    )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    out = done.stdout
    for line in (
        "speed ratio",
        "objective reached",
        "|UNC atikt - UNC scikit-learn| per update",
        "updates with |UNC difference| <=",
        "objective evaluation along",
        "step searches:",
        "transfer='none'",
        "transfer='density', max_sources=3",
    ):
        assert line in out, (line, out[-2000:])
