"""SHA-256 of the results a fixed set of runs and studies write, to show behaviour unchanged.

Run it before and after a change that must not change results and compare the two listings::

    python tests/bench/behaviour_hashes.py --out /tmp/before > before.txt
    python tests/bench/behaviour_hashes.py --out /tmp/after > after.txt
    diff before.txt after.txt && echo identical

The runs: ``learn`` in every transfer mode and ``study ... --quick`` of every study on the
simulated default dataset, the full transfer study (README's main job), and, when given,
studies on other datasets (``--probe DIR``: a converted heated-probe dataset; ``--rig-b DIR``:
a second rig's recordings for the cross-rig study); ``--quick``: one short ``learn`` on the
committed recordings (a check that the script runs; ``--out`` may then be left out). Hashed:
every ``*.parquet``, ``*.md`` and ``*.json`` file the runs write, except ``run.json`` /
``study.json`` (they record options and the software, which a refactor may spell
differently); a run's result table is the parquet.
"""

from __future__ import annotations

import argparse
import hashlib
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

MODES = ("prediction", "optimization", "density", "evidence", "none")
STUDIES = ("fusion", "transfer", "single-action", "priors", "negative", "cross-action")
SKIPPED = {"run.json", "study.json"}


def _run(args: list[str]) -> None:
    """Run one ``atikt-replay`` command, stopping on failure."""
    command = [sys.executable, "-m", "replay", *args]
    print("#", " ".join(args), file=sys.stderr, flush=True)
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)  # noqa: S603 (our own CLI)


def _quick_commands(out: Path) -> list[list[str]]:
    """Return ``--quick``'s one command: a short run on the committed recordings."""
    recordings = str(Path(__file__).resolve().parents[2] / "recordings" / "data")
    return [["learn", "--recordings", recordings, "--budget", "2", "--out", str(out / "quick")]]


def _commands(out: Path, probe: Path | None, rig_b: Path | None) -> list[list[str]]:
    """Return the commands whose outputs are hashed."""
    commands = [
        ["learn", "--transfer", mode, "--budget", "8", "--out", str(out / f"learn-{mode}")]
        for mode in MODES
    ]
    commands += [
        ["study", name, "--quick", "--out", str(out / f"quick-{name}")] for name in STUDIES
    ]
    commands.append(["study", "transfer", "--out", str(out / "transfer")])
    if probe is not None:
        commands += [
            [
                "study",
                "fusion",
                "--quick",
                "--recordings",
                str(probe),
                "--out",
                str(out / "probe-fusion"),
            ],
            [
                "learn",
                "--recordings",
                str(probe),
                "--transfer",
                "optimization",
                "--budget",
                "8",
                "--out",
                str(out / "probe-learn"),
            ],
        ]
    if rig_b is not None:
        commands.append(
            [
                "study",
                "cross-rig",
                "--quick",
                "--prior-recordings",
                str(rig_b),
                "--out",
                str(out / "cross-rig"),
            ]
        )
    return commands


def main() -> None:
    """Run the commands into ``--out`` and print one ``sha256  path`` line per result file."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help="output directory (required unless --quick)")
    parser.add_argument("--probe", type=Path)
    parser.add_argument("--rig-b", type=Path)
    parser.add_argument(
        "--quick", action="store_true", help="one short run on the committed recordings"
    )
    args = parser.parse_args()
    if args.out is None and not args.quick:
        parser.error("--out is required (unless --quick)")
    with tempfile.TemporaryDirectory() as scratch:
        out = Path(scratch) if args.out is None else args.out
        if out.exists():
            shutil.rmtree(out)
        out.mkdir(parents=True)
        commands = _quick_commands(out) if args.quick else _commands(out, args.probe, args.rig_b)
        for command in commands:
            _run(command)
        for path in sorted(out.rglob("*")):
            if path.suffix in {".parquet", ".md", ".json"} and path.name not in SKIPPED:
                digest = hashlib.sha256(path.read_bytes()).hexdigest()
                print(f"{digest}  {path.relative_to(out)}")


if __name__ == "__main__":
    main()
