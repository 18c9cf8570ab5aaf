"""What the benchmarks' ``--quick`` modes share: tiny data from the committed recordings.

A quick mode runs a benchmark's whole code path on a few steps of small data, so that a test
(``tests/test_bench_quick.py``) notices when a benchmark no longer runs; its figures mean
nothing and nothing is timed against a target. The data is ``recordings/data`` (96 recordings
of the simulated rig, 6 objects with declared roles, 7 actions, 2 trials each), whose feature
table is built once and kept in the user cache (``$ATIKT_CACHE``), where the replay tool keeps
the cache of a dataset inside a checkout; it is rebuilt when a recording's bytes change.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
#: The committed regression recordings (recordings/README.md).
RECORDINGS = ROOT / "recordings" / "data"


def quick_features() -> Path:
    """Return a feature table of the committed recordings, with their ``objects.toml`` beside.

    The scripts that take ``--features FILE`` read the dataset's declared roles from the
    file's directory, so the roles are copied next to the table (atomically: several quick
    runs may start at once).
    """
    from replay.learning._cachedir import feature_cache_path  # noqa: PLC0415 (the checkout's)
    from replay.learning._features import build_features  # noqa: PLC0415

    path = feature_cache_path(RECORDINGS)
    build_features(RECORDINGS, cache=path)
    roles = path.parent / "objects.toml"
    if not roles.exists():
        with tempfile.NamedTemporaryFile(dir=path.parent, delete=False) as scratch:
            scratch.write((RECORDINGS / "objects.toml").read_bytes())
        Path(scratch.name).replace(roles)
    return path


def quick_study(name: str, out: Path, **options: Any) -> Path:
    """Run study ``name`` on the committed recordings, one group, one trial, budget 2.

    Args:
        name: The study (``atikt-replay study NAME``).
        out: Its output directory (results.parquet, study.json, summary.md).
        options: Further ``StudyConfig`` fields (e.g. ``prior_counts=(3,)``).

    Returns:
        ``out``.
    """
    import polars as pl  # noqa: PLC0415

    from replay.learning._datasets import dataset_roles  # noqa: PLC0415
    from replay.learning._session import DEFAULT_LEARNER  # noqa: PLC0415
    from replay.outputs._study_report import run_study  # noqa: PLC0415
    from replay.studies._running import StudyConfig, dataset_actions  # noqa: PLC0415

    frame = pl.read_parquet(quick_features())
    roles = dataset_roles(RECORDINGS, frame["object_id"].to_list())
    config = StudyConfig(
        out=out,
        groups=1,
        trials=1,
        learner=DEFAULT_LEARNER.replace(budget=2),
        new=roles.new,
        old=roles.old,
        actions=dataset_actions(frame),
        **options,
    )
    run_study(name, frame, config)
    return out


def small_dataset(directory: Path, objects: int = 2, actions: int = 1) -> Path:
    """Return a dataset of the first recordings of the committed data, linked into ``directory``.

    It holds every trial of the first ``actions`` actions of the first ``objects`` objects (in
    name order), e.g. for a feature extraction that only has to run.
    """
    for obj in sorted(p for p in RECORDINGS.iterdir() if p.is_dir())[:objects]:
        for action in sorted(obj.iterdir())[:actions]:
            target = directory / obj.name / action.name
            target.mkdir(parents=True)
            for recording in action.glob("*.mcap"):
                (target / recording.name).symlink_to(recording)
    return directory
