"""README result tables written from study results: idempotent, checked, with intervals."""

from __future__ import annotations

import itertools
from typing import TYPE_CHECKING

import numpy as np
import polars as pl
import pytest

from replay.errors import ReplayError
from replay.outputs.readme_tables import gain_intervals, main, rewrite
from replay.studies._stats import HEADLINES, gain_cells, paired_gains

if TYPE_CHECKING:
    from pathlib import Path

README = """# project

Prose before.

<!-- results:transfer -->
| an old table |
<!-- /results:transfer -->

Prose between.

<!-- results:fusion -->
<!-- /results:fusion -->

<!-- results:fusion-margins -->
<!-- /results:fusion-margins -->

<!-- results:real-fusion -->
<!-- /results:real-fusion -->

<!-- results:real-fusion-session-margins -->
<!-- /results:real-fusion-session-margins -->

Prose after.
"""


def _transfer(gain_per_group: list[float], seed: int = 0) -> pl.DataFrame:
    rng = np.random.default_rng(seed)
    rows = []
    for group, gain in enumerate(gain_per_group):
        for trial in range(2):
            for step in range(4):
                base = float(rng.uniform(0.4, 0.8))
                rows += [
                    {"method": "baseline", "group": group, "trial": trial, "step": step}
                    | {"accuracy": base},
                    {"method": "ATIKT", "group": group, "trial": trial, "step": step}
                    | {"accuracy": base + gain},
                ]
    return pl.DataFrame(rows)


def _fusion(scale: float = 1.0) -> pl.DataFrame:
    rows = [
        {"action": action, "group": group, "repetition": 0, "modalities": modality}
        | {"samples": samples, "accuracy": scale * accuracy}
        for action, modality, accuracy in (
            ("P1", "multi-modal", 0.9),
            ("P1", "force", 0.6),
            ("S2", "multi-modal", 0.8),
            ("S2", "texture", 0.7),
        )
        for samples in (1, 2)
        for group in (0, 1)
    ]
    return pl.DataFrame(rows)


@pytest.fixture
def project(tmp_path: Path) -> Path:
    for root, name, frame in (
        ("studies", "transfer", _transfer([0.05, 0.02, 0.08, 0.01, 0.04])),
        ("studies", "fusion", _fusion()),
        ("studies-real", "fusion", _fusion(0.5)),
        ("studies-real", "fusion-session", _fusion(0.25)),
    ):
        (tmp_path / root / name).mkdir(parents=True)
        frame.write_parquet(tmp_path / root / name / "results.parquet")
    (tmp_path / "README.md").write_text(README)
    return tmp_path


def _args(project: Path, *extra: str) -> list[str]:
    return [
        *("--readme", str(project / "README.md"), "--studies", str(project / "studies")),
        *("--real-studies", str(project / "studies-real"), *extra),
    ]


def test_tables_are_rewritten_between_the_markers_and_twice_changes_nothing(
    project: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(_args(project, "--check")) == 1
    assert "differ" in capsys.readouterr().err
    assert main(_args(project)) == 0
    once = (project / "README.md").read_text()
    assert main(_args(project)) == 0
    assert (project / "README.md").read_text() == once
    assert main(_args(project, "--check")) == 0
    for prose in ("Prose before.", "Prose between.", "Prose after."):
        assert prose in once
    assert "an old table" not in once
    assert "| ATIKT |" in once
    assert "| gain, points [95 % interval] | +" in once
    assert "4000 paired bootstrap resamples of the 5 groups" in once
    assert "| action | multi-modal | force | texture |" in once
    assert "| P1 | 90.0 % | 60.0 % | - |" in once
    assert "| P1 | 45.0 % | 30.0 % | - |" in once  # the real study's block
    assert "| action | 1 / object | 2 / object |" in once
    assert "| P1 | +30.0 [+30.0, +30.0] | +30.0 [+30.0, +30.0] |" in once
    # Any fusion study's directory makes a margins block (here a second real one).
    assert "| P1 | +7.5 [+7.5, +7.5] | +7.5 [+7.5, +7.5] |" in once


def test_a_constant_gain_has_a_degenerate_interval() -> None:
    low, high = gain_intervals(_transfer([0.05] * 6), budget=3, seed=0)
    assert low == pytest.approx([0.05] * 3)
    assert high == pytest.approx([0.05] * 3)


def test_the_interval_holds_the_paired_gain_and_depends_only_on_the_seed() -> None:
    frame = _transfer([0.05, -0.02, 0.08, 0.01, 0.04, 0.0, 0.03])
    low, high = gain_intervals(frame, budget=3, seed=1)
    assert np.all(low < 0.0271)
    assert np.all(high > 0.0271)
    assert np.all(low >= -0.02 - 1e-12)
    assert np.all(high <= 0.08 + 1e-12)
    again = gain_intervals(frame.sample(fraction=1.0, shuffle=True, seed=3), budget=3, seed=1)
    np.testing.assert_allclose(again, np.stack([low, high]))


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda p: (p / "studies" / "fusion" / "results.parquet").unlink(), "cannot read"),
        (lambda p: (p / "README.md").write_text("no markers\n"), "no '<!-- results:NAME -->'"),
        (
            lambda p: (p / "README.md").write_text("<!-- results:transfer -->\n"),
            "'<!-- results:transfer -->' is not closed",
        ),
    ],
)
def test_a_missing_marker_or_results_file_is_refused_in_one_line(
    project: Path, capsys: pytest.CaptureFixture[str], change: object, message: str
) -> None:
    change(project)  # type: ignore[operator]
    before = (project / "README.md").read_text()
    assert main(_args(project)) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert message in err
    assert (project / "README.md").read_text() == before


def test_rewrite_of_one_block(project: Path) -> None:
    text = "<!-- results:fusion -->\nold\n<!-- /results:fusion -->\n"
    assert rewrite(text, project / "studies", 0).startswith("<!-- results:fusion -->\n| action |")


def test_only_the_named_blocks_are_rewritten(project: Path) -> None:
    text = (
        "<!-- results:fusion -->\nold\n<!-- /results:fusion -->\n"
        "<!-- results:elsewhere -->\nkept\n<!-- /results:elsewhere -->\n"
    )
    block = rewrite(text, project / "studies", 0, only=["fusion"])
    assert block.startswith("<!-- results:fusion -->\n| action |")
    assert "<!-- results:elsewhere -->\nkept\n<!-- /results:elsewhere -->" in block
    with pytest.raises(ReplayError, match=r"--only nothing: .* has no such block"):
        rewrite(text, project / "studies", 0, only=["nothing"])


def test_a_vs_block_is_one_fusion_studys_multi_modal_minus_anothers(project: Path) -> None:
    name = "real-fusion-vs-fusion-session"
    text = f"<!-- results:{name} -->\n<!-- /results:{name} -->"
    block = rewrite(text, project / "studies", 0, real=project / "studies-real")
    # 0.5 x 0.9 - 0.25 x 0.9 on P1, 0.5 x 0.8 - 0.25 x 0.8 on S2, at both sizes
    assert "| P1 | +22.5 [+22.5, +22.5] | +22.5 [+22.5, +22.5] |" in block
    assert "| S2 | +20.0 [+20.0, +20.0] | +20.0 [+20.0, +20.0] |" in block
    assert "`fusion` minus that of `fusion-session`" in block
    with pytest.raises(ReplayError, match=r"fusion-none/results\.parquet: cannot read"):
        rewrite(
            text.replace("fusion-session", "fusion-none"),
            project / "studies",
            0,
            real=project / "studies-real",
        )


def _borrow(gains: dict[str, float], groups: int = 4) -> pl.DataFrame:
    """Results of a cross-action or cross-rig study: gains over the baseline per method."""
    rng = np.random.default_rng(5)
    rows = []
    for action, source in (("C1", "P1"), ("P2", "P1")):
        for group, trial, step in itertools.product(range(groups), range(2), range(4)):
            base = float(rng.uniform(0.4, 0.8))
            for method, gain in {"baseline": 0.0, **gains}.items():
                used = method != "baseline" and step > 0 and (action == "C1" or method == "within")
                rows.append(
                    {"actions": action, "source": source, "method": method, "group": group}
                    | {"trial": trial, "step": step, "accuracy": base + gain}
                    | {"rho": 0.6 if used else 0.0}
                    | {"metric_share": 0.0 if method == "baseline" else 1.0 if step == 0 else 0.5}
                )
    return pl.DataFrame(rows)


@pytest.mark.parametrize("borrowed", ["cross-rig", "cross-action"])
def test_a_borrow_block_gives_each_target_actions_accuracies_and_paired_differences(
    tmp_path: Path, borrowed: str
) -> None:
    frame = _borrow({"within": 0.02, borrowed: 0.05})
    (tmp_path / "studies" / borrowed).mkdir(parents=True)
    frame.write_parquet(tmp_path / "studies" / borrowed / "results.parquet")
    text = f"<!-- results:{borrowed} -->\nold\n<!-- /results:{borrowed} -->\n"
    block = rewrite(text, tmp_path / "studies", 0)
    assert "| action <- source | method | initial | mean 1..3 | final |" in block
    for action in ("C1 <- P1", "P2 <- P1"):
        for method in ("baseline", "within", borrowed):
            assert f"| {action} | {method} | " in block
        # constant gains: the paired differences and their intervals are exact
        assert f"| {action} | {borrowed} - baseline | +5.0 [+5.0, +5.0] |" in block
        assert f"| {action} | within - baseline | +2.0 [+2.0, +2.0] |" in block
        assert f"| {action} | {borrowed} - within | +3.0 [+3.0, +3.0] |" in block
    assert "4000 paired bootstrap resamples of the 4 prior groups (seed 0)" in block
    # relatedness admitted the borrowed priors at every step of C1 and never for P2
    assert f"Steps of `{borrowed}` that transferred a borrowed object's observations" in block
    assert "(rho > 0): C1 100 %, P2 0 %." in block
    # the share of classifiers under metric transfer at step 0 / over the later steps
    assert "step 0 / steps 1..budget: C1 100 / 50 %, P2 100 / 50 %." in block
    assert rewrite(block, tmp_path / "studies", 0) == block
    # results written before metric_share was recorded say so
    frame.drop("metric_share").write_parquet(tmp_path / "studies" / borrowed / "results.parquet")
    older = rewrite(text, tmp_path / "studies", 0)
    assert "do not say how often metric transfer was used" in older
    assert "Classifiers fitted under metric transfer" not in older


def test_a_borrow_blocks_interval_is_the_summarys(tmp_path: Path) -> None:
    frame = _borrow({"within": 0.0, "cross-rig": 0.0}, groups=6)
    noisy = frame.with_columns(
        pl.when(pl.col("method") == "cross-rig")
        .then(pl.col("accuracy") + 0.01 * pl.col("group") - 0.02)
        .otherwise(pl.col("accuracy"))
    )
    (tmp_path / "cross-rig").mkdir()
    noisy.write_parquet(tmp_path / "cross-rig" / "results.parquet")
    block = rewrite("<!-- results:cross-rig -->\n<!-- /results:cross-rig -->", tmp_path, 7)
    # the study's summary: all target actions in one call (``report_borrow``)
    summary = paired_gains(
        noisy, ["actions"], "group", 3, methods=("cross-rig", "baseline"), seed=7
    )
    gains = summary.filter(pl.col("actions") == "C1").row(0, named=True)
    cells = " | ".join(gain_cells(gains, h).replace(" pts", "") for h in HEADLINES)
    assert f"| C1 <- P1 | cross-rig - baseline | {cells} |" in block
    assert gains["low_mean"] < gains["gain_mean"] < gains["high_mean"]


def test_borrow_results_without_their_columns_are_refused_in_one_line(tmp_path: Path) -> None:
    (tmp_path / "cross-rig").mkdir()
    _borrow({"cross-rig": 0.1}).drop("group").write_parquet(
        tmp_path / "cross-rig" / "results.parquet"
    )
    # without ``group`` the results look like no study's; with ``source`` they are a borrow's
    with pytest.raises(ReplayError, match=r"lack group; run 'atikt-replay study cross-action'"):
        rewrite("<!-- results:cross-rig -->\n<!-- /results:cross-rig -->", tmp_path, 0)


def test_without_readme_every_marked_file_of_readme_and_the_manual_is_written(
    project: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    docs = project / "docs"
    (docs / "guide").mkdir(parents=True)
    (docs / "results.md").write_text("# Results\n\n" + README)
    (docs / "guide" / "deep.md").write_text("<!-- results:fusion -->\n<!-- /results:fusion -->\n")
    (docs / "plain.md").write_text("# No tables here\n")
    head = "<!-- results:transfer -->\n<!-- /results:transfer -->\n"
    (project / "README.md").write_text(head)
    monkeypatch.chdir(project)
    args = ["--real-studies", "studies-real"]
    assert main([*args, "--check"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    for name in ("README.md", "docs/results.md", "docs/guide/deep.md"):
        assert name in err
    assert "plain.md" not in err
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "docs/guide/deep.md: result tables rewritten" in out
    assert (docs / "plain.md").read_text() == "# No tables here\n"
    readme = (project / "README.md").read_text()
    page = (docs / "results.md").read_text()
    transfer = readme.split("<!-- results:transfer -->")[1].split("<!-- /results")[0]
    assert "| ATIKT |" in transfer
    assert transfer in page  # one study, one table, wherever it is shown
    assert "| P1 | 90.0 % | 60.0 % | - |" in (docs / "guide" / "deep.md").read_text()
    assert main([*args, "--check"]) == 0
    # a hand edit in any of the files is found
    (docs / "guide" / "deep.md").write_text((docs / "guide" / "deep.md").read_text() + "x\n")
    (docs / "results.md").write_text(page.replace("90.0 %", "91.0 %"))
    assert main([*args, "--check"]) == 1
    assert "docs/results.md" in capsys.readouterr().err


def test_only_rewrites_the_files_that_hold_the_named_blocks(
    project: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    (project / "docs").mkdir()
    (project / "docs" / "fusion.md").write_text(
        "<!-- results:fusion -->\nold\n<!-- /results:fusion -->\n"
    )
    monkeypatch.chdir(project)
    readme = (project / "README.md").read_text()
    assert main(["--real-studies", "studies-real", "--only", "fusion"]) == 0
    assert (project / "docs" / "fusion.md").read_text().startswith("<!-- results:fusion -->\n| ")
    fusion_only = (project / "README.md").read_text()
    assert "an old table" in fusion_only  # transfer, not named, is kept
    assert fusion_only != readme
    assert main(["--only", "nothing"]) == 1
    assert "--only nothing: " in capsys.readouterr().err


def test_no_marked_file_is_refused_in_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "README.md").write_text("no tables\n")
    monkeypatch.chdir(tmp_path)
    assert main([]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "no '<!-- results:NAME -->' markers" in err
