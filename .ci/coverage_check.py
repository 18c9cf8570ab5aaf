"""Print each package's branch coverage and fail if one fell below its committed baseline.

Run after the test command of README.md with coverage measured, as CI does
(``PYTEST_ADDOPTS="--cov --cov-report=" python -m pytest -q``; ``[tool.coverage]`` in
pyproject.toml), which writes ``.coverage``:

    python .ci/coverage_check.py            # the table; exit 1 if a package fell > 0.5 points
    python .ci/coverage_check.py --update   # write the current figures as the new baseline

Branch coverage of a package is its covered branches over its branches (coverage's arcs from
``branch = true``); lines are printed beside it. Code reached only in subprocesses the tests
start (CLI commands, serve-sim) is not measured and counts as missed.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import coverage

ROOT = Path(__file__).resolve().parents[1]
BASELINE = ROOT / ".ci" / "coverage_baseline.json"
PACKAGES = ("schemas", "recorder", "replay", "atikt")
#: Points a package's branch coverage may fall before CI fails (noise of timing-dependent paths).
TOLERANCE = 0.5


@dataclass
class Figures:
    """Counts of one package, summed over its files."""

    lines: int = 0
    lines_covered: int = 0
    branches: int = 0
    branches_covered: int = 0

    @property
    def branch_percent(self) -> float:
        """Covered branches in percent (100 without branches)."""
        return 100.0 * self.branches_covered / self.branches if self.branches else 100.0

    @property
    def line_percent(self) -> float:
        """Covered lines in percent (100 without lines)."""
        return 100.0 * self.lines_covered / self.lines if self.lines else 100.0


def measure(data_file: Path) -> dict[str, Figures]:
    """Return each package's figures from the coverage data file."""
    cov = coverage.Coverage(data_file=str(data_file), config_file=str(ROOT / "pyproject.toml"))
    cov.load()
    with tempfile.TemporaryDirectory() as scratch:
        out = Path(scratch) / "coverage.json"
        cov.json_report(outfile=str(out), ignore_errors=True)
        report = json.loads(out.read_text(encoding="utf-8"))
    figures = {package: Figures() for package in PACKAGES}
    for name, entry in report["files"].items():
        path = Path(name).resolve()
        package = path.relative_to(ROOT).parts[0] if path.is_relative_to(ROOT) else ""
        if package not in figures:
            continue
        summary, total = entry["summary"], figures[package]
        total.lines += summary["num_statements"]
        total.lines_covered += summary["covered_lines"]
        total.branches += summary["num_branches"]
        total.branches_covered += summary["covered_branches"]
    return figures


def main() -> int:
    """Print the table, compare with the baseline; return the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-file", type=Path, default=ROOT / ".coverage")
    parser.add_argument("--update", action="store_true", help="write the baseline")
    args = parser.parse_args()
    if not args.data_file.is_file():
        print(f"coverage_check: no {args.data_file}; run `python -m pytest -q --cov` first")
        return 1
    figures = measure(args.data_file)
    baseline = json.loads(BASELINE.read_text(encoding="utf-8")) if BASELINE.is_file() else {}
    print(
        f"{'package':10}{'lines':>8}{'line %':>8}{'branches':>10}{'branch %':>10}{'baseline':>10}"
    )
    fell = []
    for package, f in figures.items():
        base = baseline.get(package)
        shown = f"{base:10.1f}" if base is not None else f"{'-':>10}"
        print(
            f"{package:10}{f.lines:8d}{f.line_percent:8.1f}{f.branches:10d}"
            f"{f.branch_percent:10.1f}{shown}"
        )
        if base is not None and f.branch_percent < base - TOLERANCE:
            fell.append(f"{package} {f.branch_percent:.1f} < {base:.1f}")
    if args.update:
        current = {p: round(f.branch_percent, 1) for p, f in figures.items()}
        BASELINE.write_text(json.dumps(current, indent=2) + "\n", encoding="utf-8")
        print(f"baseline written: {BASELINE.relative_to(ROOT)}")
        return 0
    if fell:
        print(
            f"coverage_check: branch coverage fell more than {TOLERANCE} points: "
            f"{'; '.join(fell)}; add tests for the new branches (or, if a fall is intended, "
            "run `python .ci/coverage_check.py --update` and commit the baseline)"
        )
        return 1
    print(f"coverage_check: no package fell more than {TOLERANCE} points below its baseline")
    return 0


if __name__ == "__main__":
    sys.exit(main())
