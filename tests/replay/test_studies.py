import json
from dataclasses import replace
from pathlib import Path

import polars as pl
import pytest
from conftest import ACTIONS, NEW, OLD, copy_dataset

from replay.errors import ReplayError
from replay.learning._features import build_features
from replay.learning._session import DEFAULT_LEARNER
from replay.outputs._study_report import StudyOutput, run_study, write_report
from replay.studies._fusion import FUSION, fusion_tasks
from replay.studies._fusion_prior import (
    HYPERPARAMETERS,
    action_parameter_names,
    controlled_blocks,
    declared_noise,
)
from replay.studies._negative import negative_tasks, similarity_tasks
from replay.studies._registry import STUDIES
from replay.studies._report import Gains, Headlines, Report, Text, summary
from replay.studies._running import Study, StudyConfig, prior_groups, study_results
from replay.studies._transfer import transfer_tasks


@pytest.fixture(scope="module")
def features(small_dataset: Path) -> pl.DataFrame:
    return build_features(small_dataset).frame


def _config(out: Path, **changes: object) -> StudyConfig:
    base = StudyConfig(
        out=out,
        groups=1,
        trials=1,
        learner=DEFAULT_LEARNER.replace(budget=4),
        fusion_groups=1,
        fusion_repetitions=1,
        new=NEW,
        old=OLD,
        actions=ACTIONS,
    )
    return replace(base, **changes)  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def whole_fusion(features: pl.DataFrame, tmp_path_factory: pytest.TempPathFactory) -> StudyOutput:
    """The fusion study with every object in its group (no other objects), run once: read only."""
    objects = len({*NEW, *OLD})
    out = tmp_path_factory.mktemp("fusion") / "whole"
    return run_study("fusion", features, _config(out, fusion_objects=objects))


@pytest.mark.parametrize("name", [n for n in STUDIES if not n.startswith("cross-")])
def test_every_study_writes_results_plot_and_summary(
    name: str, features: pl.DataFrame, tmp_path: Path
) -> None:
    output = run_study(name, features, _config(tmp_path / name))
    results = pl.read_parquet(output.results)
    assert results.height > 0
    assert results["accuracy"].is_between(0.0, 1.0).all()
    assert output.plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert output.summary.read_text().startswith("# ")


def test_transfer_study_pairs_atikt_with_the_baseline(
    features: pl.DataFrame, tmp_path: Path
) -> None:
    output = run_study(
        "transfer", features, _config(tmp_path, learner=DEFAULT_LEARNER.replace(budget=6))
    )
    results = pl.read_parquet(output.results)
    assert set(results["method"]) == {"ATIKT", "baseline"}
    per_method = results.group_by("method").agg(pl.col("step").max())
    assert per_method["step"].to_list() == [6, 6]
    assert "| ATIKT |" in output.text
    assert "| baseline |" in output.text


def test_results_are_the_same_bytes_for_one_and_two_workers(
    features: pl.DataFrame, tmp_path: Path
) -> None:
    one = run_study("single-action", features, _config(tmp_path / "one", workers=1))
    two = run_study("single-action", features, _config(tmp_path / "two", workers=2))
    assert one.results.read_bytes() == two.results.read_bytes()
    assert one.summary.read_bytes() == two.summary.read_bytes()


@pytest.mark.slow
def test_results_are_the_same_bytes_on_a_dask_cluster(
    features: pl.DataFrame, tmp_path: Path
) -> None:
    distributed = pytest.importorskip("dask.distributed")
    one = run_study("transfer", features, _config(tmp_path / "one", groups=2, trials=2))
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        config = _config(tmp_path / "dask", groups=2, trials=2, scheduler=cluster.scheduler_address)
        dask = run_study("transfer", features, config)
    assert one.results.read_bytes() == dask.results.read_bytes()


def test_study_over_bad_files_equals_the_study_without_them(
    small_dataset: Path, tmp_path: Path
) -> None:
    damaged, pruned = tmp_path / "damaged", tmp_path / "pruned"
    for copy in (damaged, pruned):
        copy_dataset(small_dataset, copy)
        (copy / "features.parquet").unlink(missing_ok=True)
    bad = [f"{NEW[0]}/{ACTIONS[0]}/002.mcap", f"{OLD[1]}/{ACTIONS[1]}/004.mcap"]
    (damaged / bad[0]).write_bytes(b"not an mcap file")
    data = (damaged / bad[1]).read_bytes()
    (damaged / bad[1]).write_bytes(data[: len(data) * 9 // 10])
    for name in bad:
        (pruned / name).unlink()

    with_bad = build_features(damaged)
    without = build_features(pruned)
    assert sorted(with_bad.quarantined["path"]) == sorted(bad)
    out_bad = run_study(
        "transfer", with_bad.frame, _config(tmp_path / "a"), quarantined=with_bad.quarantined
    )
    out_clean = run_study("transfer", without.frame, _config(tmp_path / "b"))
    assert out_bad.results.read_bytes() == out_clean.results.read_bytes()
    assert "Quarantined recordings (2)" in out_bad.text
    assert all(name in out_bad.text for name in bad)


def test_negative_and_related_runs_take_the_least_and_most_similar_priors(
    features: pl.DataFrame,
) -> None:
    config = _config(
        Path(), group_size=1, trials=2, learner=DEFAULT_LEARNER.replace(transfer="optimization")
    )
    least = similarity_tasks(features, config, "negative", nearest=False)
    most = similarity_tasks(features, config, "related", nearest=True)
    assert [t.priors for t in negative_tasks(features, config)] == [t.priors for t in least]
    assert len(least) == len(most) == 2  # groups * trials runs of one group
    assert least[0].priors == least[1].priors
    assert least[0].priors != most[0].priors
    assert {*least[0].priors, *most[0].priors} <= set(OLD)
    assert least[0].seed != least[1].seed


def test_prior_groups_are_distinct_and_seeded() -> None:
    old = [f"o{i}" for i in range(10)]
    groups = prior_groups(old, 3, 10, seed=1)
    assert len(set(groups)) == 10
    assert all(len(set(g)) == 3 for g in groups)
    assert groups == prior_groups(old, 3, 10, seed=1)
    assert groups != prior_groups(old, 3, 10, seed=2)
    assert prior_groups(old, 10, 10, seed=1) == [tuple(sorted(old))]


def test_unknown_study_is_a_clear_error(features: pl.DataFrame, tmp_path: Path) -> None:
    with pytest.raises(ReplayError, match="unknown study"):
        run_study("nope", features, _config(tmp_path))


def test_prediction_transfer_needs_two_old_objects_the_others_one(
    features: pl.DataFrame, tmp_path: Path
) -> None:
    one_old = _config(tmp_path, old=OLD[:1])
    with pytest.raises(ReplayError, match=r">= 2 old objects .*--transfer optimization"):
        transfer_tasks(features, one_old)
    for mode in ("optimization", "density"):
        learner = one_old.learner.replace(transfer=mode)
        tasks = transfer_tasks(features, replace(one_old, learner=learner))
        assert [task.priors for task in tasks] == [OLD[:1]]


@pytest.mark.slow(6)
def test_fusion_prior_from_the_other_objects_and_the_margin_table(
    features: pl.DataFrame, whole_fusion: StudyOutput, tmp_path: Path
) -> None:
    objects = len({*NEW, *OLD})
    config = _config(tmp_path / "others", fusion_objects=objects - 2)
    output = run_study("fusion", features, config)
    results = pl.read_parquet(output.results)
    assert set(results["fusion_prior"]) == {"others"}
    assert "centred on those fitted on the objects outside the group" in output.text
    assert "Multi-modal minus the best single modality" in output.text
    alone = run_study(
        "fusion", features, replace(config, out=tmp_path / "none", fusion_prior="none")
    )
    assert set(pl.read_parquet(alone.results)["fusion_prior"]) == {"none"}
    assert "maximum likelihood on the group's samples" in alone.text
    assert f"groups of {objects - 2} objects" in output.text
    whole = whole_fusion
    # no other objects: the modality weights come from the sensors' declared noise
    assert set(pl.read_parquet(whole.results)["fusion_prior"]) == {"noise"}
    assert "relative to its sensor's declared noise" in whole.text
    assert f"groups of {objects} objects" in whole.text
    noise = run_study(
        "fusion", features, replace(config, out=tmp_path / "noise", fusion_prior="noise")
    )
    assert set(pl.read_parquet(noise.results)["fusion_prior"]) == {"noise"}


def test_an_action_that_sets_the_force_makes_it_a_controlled_block(
    features: pl.DataFrame, tmp_path: Path
) -> None:
    assert controlled_blocks(("duration_s", "force_n")) == ("force",)
    assert controlled_blocks(("duration_s", "depth_m")) == ()
    assert declared_noise() == {"force": 0.002, "thermal": 0.012, "texture": 0.04}
    parameters = tuple((a, ("duration_s", "force_n")) for a in ACTIONS)
    config = _config(tmp_path, action_parameters=parameters)
    assert {task.controlled for task in fusion_tasks(features, config)} == {("force",)}
    assert {task.controlled for task in fusion_tasks(features, _config(tmp_path))} == {()}


def test_fusion_study_saves_hyperparameters_that_centre_a_later_studys_prior(
    features: pl.DataFrame, whole_fusion: StudyOutput, tmp_path: Path
) -> None:
    objects = len({*NEW, *OLD})
    whole = _config(tmp_path / "first", fusion_objects=objects)
    first = whole_fusion
    saved = first.summary.parent / HYPERPARAMETERS
    document = json.loads(saved.read_text())
    assert set(document["actions"]) == set(ACTIONS)
    assert document["kernel"] == {"combination": "sum", "parts": {}}
    for entry in document["actions"].values():
        assert len(entry["names"]) == len(entry["theta"]) > 0
        assert sorted(entry["objects"]) == sorted({*NEW, *OLD})
    again = run_study("fusion", features, replace(whole, out=tmp_path / "again"))
    assert (again.summary.parent / HYPERPARAMETERS).read_bytes() == saved.read_bytes()
    assert HYPERPARAMETERS in first.text
    # With no object outside the group there is no "others" prior; the saved file gives one.
    later = run_study(
        "fusion", features, replace(whole, out=tmp_path / "later", fusion_prior=str(saved))
    )
    results = pl.read_parquet(later.results)
    assert set(results["fusion_prior"]) == {"saved"}
    assert "a prior centred on the saved hyperparameters" in later.text
    plain = pl.read_parquet(first.results)
    assert set(plain["fusion_prior"]) == {"noise"}
    assert not results["accuracy"].equals(plain["accuracy"])  # the prior changed the fits


_HEAD = '{"format": "atikt fusion hyperparameters", "actions": '
_OTHER_KERNEL = (
    r"fitted with --fusion-kernel sum \(thermal=matern32\), this study uses "
    r"--fusion-kernel sum \(RBF parts\); run both with the same --fusion-kernel"
)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, r"cannot read it \(No such file"),
        ("{not json", r"cannot read it \(Expecting"),
        ('{"format": "other"}', "not a fusion study's hyperparameters file"),
        (
            _HEAD + '{"X": {"names": ["a"], "theta": [NaN]}}}',
            "action 'X' needs equally long 'names' and finite 'theta'",
        ),
        ('{"format": "atikt fusion hyperparameters", "actions": {}}', "holds no action"),
        (
            _HEAD + '{"X": {"names": ["a"], "theta": [1.0]}}}',
            r"no hyperparameters for action '\w+' \(it has X\); choose --actions",
        ),
        (
            '{"format": "atikt fusion hyperparameters", "actions": {ACTIONS}}',
            "was saved for the kernel a, this dataset's is",
        ),
        (
            _HEAD.replace(
                '"actions"',
                '"kernel": {"combination": "sum", "parts": {"thermal": "matern32"}}, "actions"',
            )
            + "{ACTIONS}}",
            _OTHER_KERNEL,
        ),
    ],
)
def test_a_bad_saved_prior_is_refused_in_one_line_naming_the_file(
    content: str | None, message: str, features: pl.DataFrame, tmp_path: Path
) -> None:
    path = tmp_path / "hyperparameters.json"
    if content is not None:
        entries = ", ".join(f'"{a}": {{"names": ["a"], "theta": [1.0]}}' for a in ACTIONS)
        path.write_text(content.replace("{ACTIONS}", "{" + entries + "}"))
    config = _config(tmp_path / "out", fusion_prior=str(path))
    with pytest.raises(ReplayError, match=message) as caught:
        fusion_tasks(features, config)
    assert str(caught.value).startswith(f"--fusion-prior {path}: ")
    assert "\n" not in str(caught.value)


def test_action_parameter_names_come_from_the_recordings(
    small_dataset: Path, features: pl.DataFrame
) -> None:
    names = dict(action_parameter_names(small_dataset, features))
    kinds = dict(features.select("action_id", "action_kind").unique().iter_rows())
    assert set(names) == set(kinds)
    for action, parameters in names.items():
        assert "duration_s" in parameters
        assert ("force_n" in parameters) == (kinds[action] == "slide")  # slides set the force


def _toy_rows(group: int) -> pl.DataFrame:
    """One toy task: ATIKT gains 0.1 per step over the baseline, more in group 1."""
    return pl.DataFrame(
        {"method": method, "group": group, "trial": 0, "step": step}
        | {"accuracy": 0.5 + step * (0.1 + 0.1 * group if method == "ATIKT" else 0.0)}
        for method in ("baseline", "ATIKT")
        for step in range(3)
    )


def test_a_study_declared_outside_the_package_is_reported_by_the_one_writer(
    tmp_path: Path,
) -> None:
    toy = Study(
        name="toy",
        title="Toy study",
        tasks=lambda frame, config: [1, 0],  # noqa: ARG005
        run=_toy_rows,
        labels=("method", "group", "trial", "step"),
        report=Report((Text("Two toy groups."), Headlines(("method",)), Gains(()))),
    )
    learner = DEFAULT_LEARNER.replace(budget=2, hyper_sd=None, metric_sd=None)
    config = StudyConfig(out=tmp_path / "toy", learner=learner)
    results = study_results(toy, pl.DataFrame(), config)
    assert results["group"].to_list()[:3] == [0, 0, 0]  # sorted by its labels
    output = write_report(toy, results, pl.DataFrame(), config)
    assert output.plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert output.summary.read_text() == output.text
    assert output.text.startswith("# Toy study\n\nLearners: maximum likelihood")
    assert "\nTwo toy groups.\n\n| method | initial | mean | final |\n" in output.text
    assert "| ATIKT | 50.0 % | 72.5 % | 80.0 % |" in output.text
    assert (
        "| 2 | +0.0 pts [+0.0, +0.0] | +22.5 pts [+15.0, +30.0] | +30.0 pts [+20.0, +40.0] |"
        in (output.text)
    )


def test_the_fusion_summary_is_the_same_text_for_rows_in_any_order(tmp_path: Path) -> None:
    rows = pl.DataFrame(
        {"action": action, "group": 0, "repetition": 0, "modalities": name}
        | {"samples": samples, "accuracy": 0.1 * len(name) + 0.01 * samples}
        for action in ("C1", "S1")
        for name in ("multi-modal", "force", "thermal", "texture")
        for samples in (1, 2)
        if action == "S1" or name != "texture"
    )
    config = StudyConfig(out=tmp_path)
    texts = {
        summary(FUSION, rows.sample(fraction=1.0, shuffle=True, seed=seed), config)
        for seed in range(10)
    }
    assert len(texts) == 1
    assert "| action | samples | force | multi-modal | thermal | texture |" in texts.pop()
