import json
import shutil
from pathlib import Path
from typing import Any, Self

import polars as pl
import pytest
from conftest import NEW, FakeRig

from recorder import _rigconfig as rigconfig
from recorder.errors import RigError
from replay.cli._main import main
from replay.learning._run_history import HISTORY_NAME, SETTINGS_NAME, load_run
from replay.learning._session import DEFAULT_HYPER_SD, DEFAULT_METRIC_CHECK, DEFAULT_METRIC_UNTIL


def test_learn_prints_a_line_per_step_and_writes_history_and_plot(
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    argv = ["learn", "--recordings", str(small_dataset), "--budget", "3", "--out", str(out)]
    assert main([*argv, "--workers", "1"]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("step")]
    assert len(lines) == 4
    assert "initial observations" in lines[0]
    assert all("accuracy" in line for line in lines)
    history = pl.read_parquet(out / "history.parquet")
    assert history["step"].to_list() == [0, 1, 2, 3]
    assert set(history["object"][1:]) <= set(NEW)
    assert (out / "learning_curve.png").read_bytes()[:4] == b"\x89PNG"
    run = load_run(out)
    assert run.objects == NEW
    assert run.actions == ("P1", "S2")


def test_live_learn_then_offline_replay_of_the_session_print_the_same_steps(
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    common = ["--recordings", str(small_dataset), "--budget", "2", "--actions", "P1,S2"]
    common += ["--workers", "1", "--seed", "4"]
    live_out, replay_out = tmp_path / "live", tmp_path / "replay"
    extra = ["--test-trials", "1"]
    assert main(["learn", "--rig", "sim", *common, *extra, "--out", str(live_out)]) == 0
    live = capsys.readouterr().out.splitlines()
    session = str(live_out / "session")
    assert main(["learn", "--session", session, *common, "--out", str(replay_out)]) == 0
    replay = capsys.readouterr().out.splitlines()
    assert [x for x in live if x.startswith("step")] == [x for x in replay if x.startswith("step")]
    assert (live_out / "session" / "session.parquet").exists()


def test_quick_study_prints_its_summary(
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["study", "negative", "--recordings", str(small_dataset), "--quick"]
    assert main([*argv, "--out", str(tmp_path), "--workers", "1"]) == 0
    printed = capsys.readouterr().out
    assert "| ATIKT |" in printed
    assert (tmp_path / "summary.md").read_text() in printed


def test_learn_refuses_a_missing_dataset(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    missing = tmp_path / "nowhere"
    assert main(["learn", "--recordings", str(missing)]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert str(missing) in err[0]


def _learn(data: Path, *extra: str) -> list[str]:
    """Return a short learn command line (no transfer: no prior models to fit)."""
    argv = ["learn", "--recordings", str(data), "--budget", "1", "--transfer", "none"]
    return [*argv, "--workers", "1", *extra]


def test_learn_without_out_never_overwrites_an_earlier_run(
    small_dataset: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(_learn(small_dataset)) == 0
    first = (tmp_path / "runs" / "learn-0" / "history.parquet").read_bytes()
    assert main(_learn(small_dataset)) == 0
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == ["learn-0", "learn-0-2"]
    assert (tmp_path / "runs" / "learn-0" / "history.parquet").read_bytes() == first
    assert (tmp_path / "runs" / "learn-0-2" / "history.parquet").exists()


def test_learn_force_replaces_the_named_out_whole(
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    (out / "figures").mkdir(parents=True)
    (out / "figures" / "accuracy.png").write_bytes(b"a figure of an earlier run")
    assert main(_learn(small_dataset, "--out", str(out))) == 1
    assert "--force" in capsys.readouterr().err
    assert main(_learn(small_dataset, "--out", str(out), "--force")) == 0
    assert sorted(p.name for p in out.iterdir()) == [
        "history.parquet",
        "learning_curve.png",
        SETTINGS_NAME,
    ]
    assert [p.name for p in tmp_path.iterdir()] == ["run"]  # no temporary directory left


def test_study_without_out_takes_a_new_numbered_directory(
    small_dataset: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    earlier = tmp_path / "studies" / "negative"
    earlier.mkdir(parents=True)
    (earlier / "summary.md").write_text("an earlier study\n")
    argv = ["study", "negative", "--recordings", str(small_dataset), "--quick", "--workers", "1"]
    assert main(argv) == 0
    assert (earlier / "summary.md").read_text() == "an earlier study\n"
    made = tmp_path / "studies" / "negative-2"
    assert sorted(p.name for p in made.iterdir()) == [
        "learning_curves.png",
        "results.parquet",
        "study.json",
        "summary.md",
    ]
    options = json.loads((made / "study.json").read_text("utf-8"))
    assert (options["study"], options["learner"]["budget"]) == ("negative", 10)  # --quick


def test_a_complete_default_dataset_prints_no_recording_progress(
    small_dataset: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import replay.live  # noqa: PLC0415
    from replay.cli import _learn  # noqa: PLC0415

    shown: list[str] = []
    progress = _learn._progress

    def spy(description: str, unit: str = "") -> Any:
        shown.append(description)
        return progress(description, unit)

    monkeypatch.setattr(_learn, "_progress", spy)
    monkeypatch.setattr(replay.live, "default_dataset_ready", lambda: True)
    monkeypatch.setattr(replay.live, "ensure_default_dataset", lambda **_: small_dataset)
    argv = ["learn", "--budget", "0", "--transfer", "none", "--workers", "1"]
    assert main([*argv, "--out", str(tmp_path / "r")]) == 0
    assert not [text for text in shown if "recording" in text]


def test_a_full_disk_while_writing_the_run_is_one_line_and_leaves_nothing(
    small_dataset: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    original = pl.DataFrame.write_parquet

    def full_for_history(frame: pl.DataFrame, file: Any, *args: Any, **kwargs: Any) -> None:
        if "history.parquet" in str(getattr(file, "name", file)):  # a temporary file
            message = "parquet: underlying IO error: No space left on device (os error 28)"
            raise pl.exceptions.ComputeError(message)
        original(frame, file, *args, **kwargs)

    monkeypatch.setattr(pl.DataFrame, "write_parquet", full_for_history)
    out = tmp_path / "run"
    assert main(_learn(small_dataset, "--out", str(out))) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "No space left on device" in err
    assert list(tmp_path.iterdir()) == []  # neither the run nor its temporary directory


class _Unplugged(FakeRig):
    def __enter__(self) -> Self:
        msg = "the fake rig does not answer; check its cable"
        raise RigError(msg)


def test_a_failing_rig_in_a_live_run_is_one_line(
    small_dataset: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.setitem(rigconfig._BUILDERS, "unplugged", lambda seed, _options: _Unplugged(seed))
    argv = _learn(small_dataset, "--rig", "unplugged", "--out", str(tmp_path / "live"))
    assert main([*argv, "--actions", "P1", "--test-trials", "1"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "--rig unplugged: the fake rig does not answer; check its cable" in err
    # nothing was recorded: the run's claim is taken back, so that a corrected command (another
    # rig configuration) starts afresh instead of being refused as another run's directory
    assert list((tmp_path / "live").iterdir()) == []
    monkeypatch.setitem(rigconfig._BUILDERS, "unplugged", lambda seed, _options: _Unplugged(seed))
    assert main([*argv, "--actions", "P1", "--test-trials", "1"]) == 1
    assert "is not a live run" not in capsys.readouterr().err


def test_learn_takes_the_open_set_and_multi_source_modes(
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = _learn(small_dataset, "--transfer", "density", "--max-sources", "2")
    assert main([*argv, "--actions", "P1", "--budget", "3", "--out", str(tmp_path / "d")]) == 0
    assert main([*argv, "--max-sources", "0", "--out", str(tmp_path / "z")]) == 1
    assert "--max-sources 0" in capsys.readouterr().err


def test_learn_records_its_hyperprior_and_none_is_the_thesis(
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = _learn(small_dataset, "--actions", "P1", "--budget", "2")
    assert main([*argv, "--out", str(tmp_path / "map")]) == 0
    assert main([*argv, "--hyper-sd", "none", "--out", str(tmp_path / "ml")]) == 0
    capsys.readouterr()
    settings = {
        name: json.loads((tmp_path / name / SETTINGS_NAME).read_text("utf-8"))
        for name in ("map", "ml")
    }
    assert settings["map"]["learner"]["hyper_sd"] == DEFAULT_HYPER_SD
    assert settings["ml"]["learner"]["hyper_sd"] is None


def test_learn_records_its_metric_transfer_settings(
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = _learn(small_dataset, "--actions", "P1", "--budget", "2")
    assert main([*argv, "--out", str(tmp_path / "default")]) == 0
    chosen = ["--metric-check", "separation", "--metric-until", "none"]
    assert main([*argv, *chosen, "--out", str(tmp_path / "chosen")]) == 0
    capsys.readouterr()
    settings = {
        name: json.loads((tmp_path / name / SETTINGS_NAME).read_text("utf-8"))
        for name in ("default", "chosen")
    }
    default, chosen = settings["default"]["learner"], settings["chosen"]["learner"]
    assert default["metric_check"] == DEFAULT_METRIC_CHECK
    assert default["metric_until"] == DEFAULT_METRIC_UNTIL
    assert (chosen["metric_check"], chosen["metric_until"]) == ("separation", None)


def test_the_history_says_how_many_classifiers_used_the_old_objects_kernel(
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = _learn(small_dataset, "--actions", "P1", "--budget", "2")
    always = ["--metric-check", "none", "--metric-until", "none"]
    transfer = [*argv, "--transfer", "prediction"]
    assert main([*transfer, *always, "--out", str(tmp_path / "always")]) == 0
    assert main([*transfer, "--metric-sd", "none", "--out", str(tmp_path / "thesis")]) == 0
    assert main([*argv, *always, "--out", str(tmp_path / "none")]) == 0
    capsys.readouterr()
    shares = {
        name: pl.read_parquet(tmp_path / name / HISTORY_NAME)["metric_share"].to_list()
        for name in ("always", "thesis", "none")
    }
    assert shares == {"always": [1.0] * 3, "thesis": [0.0] * 3, "none": [0.0] * 3}
    metrics = pl.read_parquet(tmp_path / "always" / HISTORY_NAME)["metrics"].to_list()
    assert metrics[1:] == [[True] * len(NEW)] * 2


def test_a_run_repeats_from_its_run_json(
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["learn", "--recordings", str(small_dataset), "--workers", "1", "--actions", "P1"]
    options = ["--budget", "2", "--transfer", "density", "--max-sources", "2", "--hyper-sd", "3"]
    assert main([*argv, *options, "--out", str(tmp_path / "first")]) == 0
    again = ["--learner-config", str(tmp_path / "first" / SETTINGS_NAME)]
    assert main([*argv, *again, "--out", str(tmp_path / "again")]) == 0
    capsys.readouterr()
    first, repeated = (
        json.loads((tmp_path / name / SETTINGS_NAME).read_text("utf-8"))["learner"]
        for name in ("first", "again")
    )
    assert first == repeated
    assert first["transfer"] == {
        "name": "density",
        "eps_density": 0.1,
        "density_rho_scale": 2.0,
        "max_sources": 2,
    }
    history = [(tmp_path / name / HISTORY_NAME).read_bytes() for name in ("first", "again")]
    assert history[0] == history[1]


def test_learner_options_from_a_toml_file_and_flags_over_it(
    small_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = tmp_path / "learner.toml"
    config.write_text('budget = 1\ntransfer = "evidence"\nevidence_rho = 0.5\n', "utf-8")
    argv = ["learn", "--recordings", str(small_dataset), "--workers", "1", "--actions", "P1"]
    argv += ["--learner-config", str(config)]
    assert main([*argv, "--budget", "2", "--out", str(tmp_path / "run")]) == 0
    capsys.readouterr()
    learner = json.loads((tmp_path / "run" / SETTINGS_NAME).read_text("utf-8"))["learner"]
    assert (learner["budget"], learner["transfer"]["evidence_rho"]) == (2, 0.5)
    config.write_text('transfer = "prediction"\neps_density = 0.5\n', "utf-8")
    assert main([*argv, "--out", str(tmp_path / "bad")]) == 1
    error = capsys.readouterr().err
    assert "learner.toml" in error
    assert "transfer 'prediction' has no option eps_density" in error
    assert not (tmp_path / "bad").exists()


def _one_action_dataset(small_dataset: Path, root: Path) -> Path:
    """Copy two trials of P1 of every object of the small dataset (one action: no pair)."""
    for path in small_dataset.glob("*/P1/00[12].mcap"):
        target = root / path.relative_to(small_dataset)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(path.read_bytes())
    return root


def test_study_all_skips_what_does_not_apply_and_resumes_what_is_finished(
    small_dataset: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Which studies run is decided before any runs; a rerun keeps the finished ones."""
    from replay.outputs import _study_report  # noqa: PLC0415 (matplotlib on use)
    from replay.studies._registry import STUDIES  # noqa: PLC0415

    ran: list[str] = []

    def run_study(name: str, _frame: pl.DataFrame, config: Any, **_: Any) -> Any:
        """Stand in for a study: its options file, as a finished study leaves it."""
        ran.append(name)
        study = STUDIES[name]
        options = _study_report.study_options(study, config)
        (config.out / _study_report.OPTIONS).write_text(json.dumps(options, indent=1) + "\n")
        results, plot, text = (config.out / n for n in ("results.parquet", "plot.png", "s.md"))
        return _study_report.StudyOutput(name, results, plot, text, f"{name} done")

    monkeypatch.setattr(_study_report, "run_study", run_study)
    data = _one_action_dataset(small_dataset, tmp_path / "data")
    out = tmp_path / "all"
    argv = ["study", "all", "--recordings", str(data), "--new", ",".join(NEW), "--quick"]
    argv += ["--out", str(out), "--workers", "1"]
    assert main(argv) == 0
    err = capsys.readouterr().err
    skipped = [line for line in err.splitlines() if line.startswith("skipped")]
    assert skipped == [
        (
            "skipped study cross-rig: it learns from another rig's priors; give them with "
            "--prior-recordings DIR (and --prior-actions)"
        ),
        (
            "skipped study cross-action: the dataset has actions P1; the study needs a target "
            "and a source action with the same feature blocks (--prior-actions T=S) (choose "
            "roles with --new/--priors, or record more)"
        ),
    ]
    assert "cross-action" not in ran
    assert len(ran) == 6
    last = ran[-1]
    shutil.rmtree(out / last)  # stopped before its last study: the rerun resumes
    first = sorted((out / ran[0]).iterdir())
    ran.clear()
    assert main(argv) == 0
    assert ran == [last]
    kept = f"study fusion: finished before with the same settings in {out / 'fusion'}; kept"
    assert kept in capsys.readouterr().err
    assert sorted((out / "fusion").iterdir()) == first
    ran.clear()  # another seed: the finished studies are not this run's, never replaced
    assert main([*argv, "--seed", "1"]) == 1
    assert "holds a fusion study of other settings" in capsys.readouterr().err
    assert ran == []
