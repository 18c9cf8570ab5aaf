"""Run one study with chosen numbers of groups, trials and budget (the CLI has full or --quick).

``atikt-replay study NAME`` runs the full design (10 groups x 5 trials, budget 40) or a reduced
one (``--quick``); this script runs ``replay.outputs._study_report.run_study`` with the numbers
given, on any dataset, and writes the same results.parquet, learning_curves.png and
summary.md. Used for the cross-action, cross-rig and real-data transfer numbers of
atikt/README.

Run: ``python tests/bench/run_study.py NAME --recordings DIR --out OUT [--prior-recordings
DIR2] [--new a,b] [--priors c,d] [--actions C1,P1] [--groups 10] [--trials 2] [--budget 40]
[--group-size 3] [--transfer prediction] [--metric-sd 1|none] [--kernel-parts BLOCK=KERNEL,..]
[--option NAME=VALUE ...]
[--workers 2]``; ``--quick``: one run of budget 2 of ``transfer`` (or NAME) on the committed
recordings into a temporary directory (a check that the script runs).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's packages

from replay.cli._options import parse_parts
from replay.learning._datasets import dataset_roles
from replay.learning._features import build_features
from replay.learning._session import DEFAULT_LEARNER
from replay.outputs._study_report import run_study
from replay.studies._running import StudyConfig, dataset_actions

RECORDINGS = Path(__file__).resolve().parents[2] / "recordings" / "data"


def _optional(text: str) -> float | None:
    """``none`` or a number."""
    return None if text.lower() == "none" else float(text)


def _number(text: str) -> int | float:
    """An option's value: an integer, else a float."""
    try:
        return int(text)
    except ValueError:
        return float(text)


def _split(text: str | None) -> list[str] | None:
    """A comma-separated list, or None."""
    return None if text is None else [p for p in text.split(",") if p]


def main() -> int:
    """Run the study and print its summary."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("name", nargs="?", help="the study (--quick: transfer)")
    parser.add_argument("--recordings", type=Path, help="the dataset (required unless --quick)")
    parser.add_argument("--out", type=Path, help="output directory (required unless --quick)")
    parser.add_argument("--prior-recordings", type=Path, default=None)
    parser.add_argument("--prior-actions", default=None, help="T=S,... pairs")
    parser.add_argument("--new", default=None)
    parser.add_argument("--priors", default=None)
    parser.add_argument("--actions", default=None)
    parser.add_argument("--groups", type=int, default=10)
    parser.add_argument("--trials", type=int, default=2)
    parser.add_argument("--budget", type=int, default=40)
    parser.add_argument("--group-size", type=int, default=3)
    parser.add_argument("--transfer", default="prediction")
    parser.add_argument("--metric-sd", type=_optional, default=1.0)
    parser.add_argument("--kernel-parts", default="", help="BLOCK=KERNEL,.. of the learners")
    parser.add_argument(
        "--option",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="another learner option (a number), e.g. transfer_from=2; repeatable",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument(
        "--quick",
        action="store_true",
        help="one run of budget 2 on the committed recordings into a temporary directory",
    )
    args = parser.parse_args()
    if args.quick:
        with tempfile.TemporaryDirectory() as scratch:
            args.name, args.recordings = args.name or "transfer", args.recordings or RECORDINGS
            args.out = args.out or Path(scratch) / "study"
            args.groups, args.trials, args.budget, args.workers = 1, 1, 2, 1
            return _run(args)
    if args.name is None or args.recordings is None or args.out is None:
        parser.error("NAME, --recordings and --out are required (unless --quick)")
    return _run(args)


def _run(args: argparse.Namespace) -> int:
    """Run the study the options describe and print its summary."""
    frame = build_features(args.recordings, workers=args.workers).frame
    roles = dataset_roles(
        args.recordings, frame["object_id"].to_list(), _split(args.new), _split(args.priors)
    )
    other = None
    if args.prior_recordings is not None:
        other = build_features(args.prior_recordings, workers=args.workers).frame
    pairs = tuple(tuple(p.split("=", 1)) for p in _split(args.prior_actions) or [])
    config = StudyConfig(
        out=args.out,
        seed=args.seed,
        groups=args.groups,
        trials=args.trials,
        workers=args.workers,
        learner=DEFAULT_LEARNER.replace(
            budget=args.budget,
            transfer=args.transfer,
            metric_sd=args.metric_sd,
            kernel_parts=parse_parts(args.kernel_parts, "--kernel-parts"),
            **{k: _number(v) for k, v in (o.split("=", 1) for o in args.option)},
        ),
        new=roles.new,
        old=roles.old,
        actions=tuple(_split(args.actions) or dataset_actions(frame)),
        group_size=args.group_size,
        prior_frame=other,
        prior_actions=pairs,  # type: ignore[arg-type]
    )
    output = run_study(args.name, frame, config)
    print(output.text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
