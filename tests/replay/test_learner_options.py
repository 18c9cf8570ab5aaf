"""The learner's options from the command line: the file, the flags over it, every refusal."""

from __future__ import annotations

import argparse
import json
import math
from typing import TYPE_CHECKING

import pytest

from atikt.strategies import Density, Prediction
from replay.cli._options import MAX_JSON_BYTES, learner_from_args, parse_parts
from replay.errors import ReplayError
from replay.learning._session import DEFAULT_LEARNER

if TYPE_CHECKING:
    from pathlib import Path


def _args(**given: object) -> argparse.Namespace:
    """The parsed arguments of a command given only ``given`` (absent flags are absent)."""
    return argparse.Namespace(**given)


def test_no_file_and_no_flags_is_the_default_learner() -> None:
    assert learner_from_args(_args()) == DEFAULT_LEARNER


def test_a_toml_file_with_a_learner_table_and_flags_over_it(tmp_path: Path) -> None:
    path = tmp_path / "lab.toml"
    path.write_text('[learner]\nbudget = 7\ntransfer = "density"\neps_density = 0.3\n', "utf-8")
    options = learner_from_args(_args(learner_config=path, budget=9, kernel_parts="force=matern52"))
    assert options.budget == 9
    assert options.transfer == Density(eps_density=0.3)
    assert options.kernel_parts == (("force", "matern52"),)


def test_a_study_json_repeats_its_learner(tmp_path: Path) -> None:
    learner = DEFAULT_LEARNER.replace(transfer="density", max_sources=3, hyper_sd=2.0)
    path = tmp_path / "study.json"
    path.write_text(json.dumps({"name": "transfer", "learner": learner.as_dict()}), "utf-8")
    assert learner_from_args(_args(learner_config=path)) == learner


def test_another_transfer_keeps_the_options_both_strategies_have(tmp_path: Path) -> None:
    path = tmp_path / "lab.toml"
    path.write_text('transfer = "density"\nmax_sources = 3\neps_density = 0.3\n', "utf-8")
    options = learner_from_args(_args(learner_config=path, transfer="prediction"))
    assert options.transfer == Prediction(max_sources=3)  # eps_density is density's alone
    assert learner_from_args(_args(transfer="prediction")) == DEFAULT_LEARNER


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("missing.toml", None, r"cannot read it \(.*No such file"),
        ("bad.toml", "budget = = 1", "cannot read it"),
        ("bad.json", "{not json", "cannot read it"),
        ("latin.json", b"\xff\xfe{}", "cannot read it"),
        ("list.json", "[1, 2]", r"no table of learner options \(a run.json has one\)"),
        ("big.json", " " * (MAX_JSON_BYTES + 1), f"over {MAX_JSON_BYTES} bytes; give a run.json"),
        ("unknown.toml", "eps_neg3 = 1\n", "unknown learner option"),
        ("range.toml", "eps_explore = 2.0\n", r"eps_explore=2\.0 must lie in \[0, 1\]"),
        # a string where a number goes was a TypeError traceback; "no" was a true bias
        ("type.toml", 'budget = "x"\n', r"budget='x' must be a whole number"),
        ("bool.toml", 'bias = "no"\n', r"bias='no' must be true or false"),
        ("restarts.toml", "n_restarts = -1\n", r"n_restarts=-1 must be >= 0"),
        ("strategy.toml", 'transfer = "density"\neps_density = "x"\n', "eps_density='x' must be a"),
        ("sources.toml", 'max_sources = "2"\n', r"max_sources='2' must be a whole number"),
    ],
)
def test_a_bad_learner_file_is_refused_in_one_line_naming_it(
    tmp_path: Path, name: str, content: str | bytes | None, message: str
) -> None:
    path = tmp_path / name
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif content is not None:
        path.write_text(content, "utf-8")
    with pytest.raises(ReplayError, match=message) as caught:
        learner_from_args(_args(learner_config=path))
    text = str(caught.value)
    assert text.startswith(f"--learner-config {path}: ")
    assert "\n" not in text


@pytest.mark.parametrize(
    ("given", "message"),
    [
        ({"budget": -1}, "--budget -1: give 0 or more observations"),
        ({"max_sources": 0}, r"--max-sources 0: give 1 \(the thesis\) or more"),
        ({"transfer_from": 0}, r"--transfer-from 0: give 1 \(from the first observation\)"),
        ({"hyper_sd": math.inf}, "--hyper-sd inf: give a positive standard deviation"),
        ({"metric_sd": -2.0}, "--metric-sd -2.0: give a positive standard deviation"),
        ({"kernel_parts": "texture=cubic"}, "--kernel-parts 'texture=cubic': 'texture=cubic'"),
    ],
)
def test_a_flag_out_of_range_is_refused_naming_the_flag(
    given: dict[str, object], message: str
) -> None:
    with pytest.raises(ReplayError, match=message) as caught:
        learner_from_args(_args(**given))
    assert "\n" not in str(caught.value)


def test_a_flag_the_strategy_refuses_names_the_flags_given() -> None:
    with pytest.raises(ReplayError, match=r"--transfer none --max-sources 2: .*max_sources"):
        learner_from_args(_args(transfer="none", max_sources=2))


def test_kernel_parts_are_pairs_of_a_block_and_a_kernel() -> None:
    assert parse_parts("texture=matern32, thermal=matern52", "--kernel-parts") == (
        ("texture", "matern32"),
        ("thermal", "matern52"),
    )
    assert parse_parts("", "--kernel-parts") == ()
    with pytest.raises(ReplayError, match="is not BLOCK=KERNEL with a block of"):
        parse_parts("colour=matern32", "--fusion-parts")
