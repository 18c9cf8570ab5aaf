"""The most and the least similar prior groups run on the same splits (paired), and a step's
observation count is the explored object's."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import TYPE_CHECKING

import polars as pl

from replay.learning._datasets import dataset_roles
from replay.learning._features import build_features
from replay.learning._session import DEFAULT_LEARNER
from replay.studies._negative import similarity_tasks
from replay.studies._running import StudyConfig, dataset_actions

if TYPE_CHECKING:
    from types import ModuleType

ROOT = Path(__file__).resolve().parents[2]
RECORDINGS = ROOT / "recordings" / "data"


def _bench() -> ModuleType:
    path = ROOT / "tests" / "bench" / "relatedness_candidates.py"
    spec = importlib.util.spec_from_file_location("relatedness_candidates", path)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_most_and_least_similar_groups_share_their_splits(tmp_path: Path) -> None:
    cache = tmp_path / "features.parquet"
    build_features(RECORDINGS, cache=cache)
    frame = pl.read_parquet(cache)
    roles = dataset_roles(RECORDINGS, sorted(set(frame["object_id"])))
    config = StudyConfig(
        out=tmp_path,
        groups=2,
        trials=2,
        learner=DEFAULT_LEARNER,
        new=roles.new,
        old=roles.old,
        actions=dataset_actions(frame),
        group_size=1,
    )
    far, near = (
        similarity_tasks(frame, config, study, nearest=study == "related", splits_of="negative")
        for study in ("negative", "related")
    )
    assert [t.seed for t in far] == [t.seed for t in near]
    assert far[0].priors != near[0].priors
    alone = similarity_tasks(frame, config, "related", nearest=True)  # its own seeds
    assert [t.seed for t in alone] != [t.seed for t in near]


def test_observations_count_the_explored_object_and_action() -> None:
    steps = [  # one run: (step, object, action)
        (1, "a", "P1"),
        (2, "b", "P1"),
        (3, "a", "P1"),
        (4, "a", "S1"),
        (5, "a", "P1"),
    ]
    frame = pl.DataFrame(
        {
            "method": ["ATIKT"] * 6 + ["baseline"],
            "group": [0] * 7,
            "trial": [0] * 7,
            "step": [0, *(s for s, _, _ in steps), 1],
            "object": ["", *(o for _, o, _ in steps), "a"],
            "action": ["", *(a for _, _, a in steps), "P1"],
            "rho": [None, 0.0, 0.7, 0.8, 0.0, 0.9, None],
        }
    )
    counted = _bench().observations(frame)
    assert counted["n"].to_list() == [2, 2, 3, 2, 4]
