"""Cross-action and cross-rig transfer: priors from another action or another dataset."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from conftest import NEW, OLD

from replay.errors import ReplayError
from replay.learning._executors import FeatureLookup
from replay.learning._features import build_features
from replay.learning._session import DEFAULT_LEARNER, borrow_pairs, prior_data
from replay.outputs._study_report import run_study
from replay.outputs.readme_tables import study_block
from replay.studies._running import StudyConfig


@pytest.fixture(scope="module")
def features(small_dataset: Path) -> pl.DataFrame:
    return build_features(small_dataset).frame


@pytest.fixture(scope="module")
def with_copy(features: pl.DataFrame) -> pl.DataFrame:
    """The dataset plus its P1 recordings again as a second press action P9."""
    copy = features.filter(pl.col("action_id") == "P1").with_columns(
        pl.lit("P9").alias("action_id"), pl.col("path").str.replace("/P1/", "/P9/")
    )
    return pl.concat([features, copy])


def _config(out: Path, **changes: object) -> StudyConfig:
    learner = DEFAULT_LEARNER.replace(budget=3)
    base = StudyConfig(out=out, groups=2, trials=1, learner=learner, new=NEW, old=OLD, group_size=2)
    return replace(base, **changes)  # type: ignore[arg-type]


def test_borrowed_priors_are_the_source_actions_recordings_relabelled(
    with_copy: pl.DataFrame,
) -> None:
    lookup = FeatureLookup(with_copy)
    own = prior_data(lookup, OLD[:2], ["P1"])
    borrowed = prior_data(lookup, OLD[:2], ["P1"], borrow={"P1": "P9"})
    assert len(borrowed["P1"][0]) == len(own["P1"][0]) > 0
    for a, b in zip(own["P1"][0], borrowed["P1"][0], strict=True):
        assert a.kind == b.kind
        assert a.modalities == b.modalities
        assert all(np.array_equal(a.blocks[m], b.blocks[m]) for m in a.modalities)


def test_a_source_action_without_the_targets_blocks_is_refused(features: pl.DataFrame) -> None:
    lookup = FeatureLookup(features)  # P1: force + thermal, S2: texture + thermal
    with pytest.raises(ReplayError, match=r"priors of action P1 from action S2: .*'force'"):
        prior_data(lookup, OLD[:2], ["P1"], borrow={"P1": "S2"})
    with pytest.raises(ReplayError, match="no action Z9"):
        prior_data(lookup, OLD[:2], ["P1"], borrow={"P1": "Z9"})


def test_another_rigs_action_pairs_by_id_then_by_kind(
    features: pl.DataFrame, with_copy: pl.DataFrame
) -> None:
    other = FeatureLookup(
        features.with_columns(
            pl.col("action_id").replace({"P1": "Q1"}), pl.col("path").str.replace("/P1/", "/Q1/")
        )
    )
    assert borrow_pairs(FeatureLookup(with_copy), other) == {"P1": "Q1", "P9": "Q1", "S2": "S2"}
    assert borrow_pairs(FeatureLookup(features), other, {"P1": "Q1"})["S2"] == "S2"
    with pytest.raises(ReplayError, match="--prior-actions P1=Z1"):
        borrow_pairs(FeatureLookup(features), other, {"P1": "Z1"})


def test_cross_action_study_runs_three_learners_on_the_same_splits(
    with_copy: pl.DataFrame, tmp_path: Path
) -> None:
    config = _config(tmp_path, actions=("P1", "S2", "P9"), prior_actions=(("P1", "P9"),))
    output = run_study("cross-action", with_copy, config)
    results = pl.read_parquet(output.results)
    assert set(results["method"]) == {"baseline", "within", "cross-action"}
    assert set(results["actions"]) == {"P1"}
    # P9 holds exactly P1's recordings: borrowing them is the within-action transfer
    steps = results.sort("group", "trial", "step")
    within = steps.filter(pl.col("method") == "within")["accuracy"].to_list()
    assert steps.filter(pl.col("method") == "cross-action")["accuracy"].to_list() == within
    assert "cross-action - baseline" in output.text
    # the README table prints the summary's paired differences
    table = study_block(tmp_path.name, tmp_path.parent, config.seed)
    line = next(r for r in table.splitlines() if "| within - baseline |" in r)
    cells = line.strip("| ").split(" | ")[2:]
    assert len(cells) == 3
    summary = output.text.replace(" pts", "")
    assert all(f" {c} |" in summary for c in cells)
    assert output.plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cross_rig_study_needs_the_other_dataset_and_labels_its_priors(
    features: pl.DataFrame, tmp_path: Path
) -> None:
    with pytest.raises(ReplayError, match="--prior-recordings"):
        run_study("cross-rig", features, _config(tmp_path / "none", actions=("P1",)))
    config = _config(tmp_path / "rig", actions=("P1",), prior_frame=features)
    output = run_study("cross-rig", features, config)
    results = pl.read_parquet(output.results)
    assert set(results["method"]) == {"baseline", "within", "cross-rig"}
    rig = results.filter(pl.col("method") == "cross-rig")["priors"].unique().to_list()
    assert all(p.startswith("rig:") for names in rig for p in names.split(","))
