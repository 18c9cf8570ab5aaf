"""The learner's options object: the forms it is built from and every refusal, in one line."""

from __future__ import annotations

import numpy as np
import pytest

from atikt import AtiktError, LearnerOptions
from atikt.kernels import modality_kernel
from atikt.strategies import (
    NO_CHOICE,
    Density,
    Evidence,
    NoTransfer,
    ObjectFit,
    Optimization,
    Prediction,
    transfer_strategy,
)


@pytest.mark.parametrize(
    ("given", "expected"),
    [(None, "none"), (False, "none"), (True, "evidence"), (1, "evidence"), (0, "none")]
    + [(name, name) for name in ("evidence", "separation", "either", "none")],
)
def test_metric_check_takes_names_and_the_old_booleans(given: object, expected: str) -> None:
    assert LearnerOptions(metric_check=given).metric_check == expected  # type: ignore[arg-type]


def test_an_unknown_metric_check_is_refused_naming_the_choices() -> None:
    with pytest.raises(AtiktError, match=r"metric_check='sometimes' must be one of"):
        LearnerOptions(metric_check="sometimes")  # type: ignore[arg-type]


def test_transfer_is_a_strategy_a_name_or_a_table() -> None:
    by_name = LearnerOptions(transfer="density")  # type: ignore[arg-type]
    assert by_name.transfer == Density()
    table = LearnerOptions.from_dict({"transfer": {"name": "optimization", "eps_neg2": 0.3}})
    assert table.transfer == Optimization(eps_neg2=0.3)
    # A table's options and flat options together; flat ones win.
    both = LearnerOptions.from_dict(
        {"transfer": {"name": "evidence", "evidence_rho": 0.5}, "eps_evidence": 2.0}
    )
    assert both.transfer == Evidence(evidence_rho=0.5, eps_evidence=2.0)
    # A strategy object as it is, or with flat options applied over its own.
    strategy = Prediction(eps_neg1=0.7, max_sources=2)
    assert LearnerOptions.from_dict({"transfer": strategy}).transfer is strategy
    changed = LearnerOptions.from_dict({"transfer": strategy, "eps_neg1": 0.9}).transfer
    assert changed == Prediction(eps_neg1=0.9, max_sources=2)
    assert LearnerOptions.from_dict({}).transfer == Prediction()


@pytest.mark.parametrize("transfer", [3, {"eps_neg1": 0.7}, ["prediction"]])
def test_a_transfer_that_is_no_strategy_is_refused(transfer: object) -> None:
    with pytest.raises(AtiktError, match=r"give a strategy name, e\.g\. 'prediction'"):
        LearnerOptions.from_dict({"transfer": transfer})
    with pytest.raises(AtiktError, match="must be a transfer strategy; build one with"):
        LearnerOptions(transfer=transfer)  # type: ignore[arg-type]


def test_kernel_parts_from_pairs_or_a_table() -> None:
    pairs = LearnerOptions.from_dict({"kernel_parts": [["texture", "matern32"]]})
    table = LearnerOptions.from_dict({"kernel_parts": {"texture": "matern32"}})
    assert pairs == table
    assert pairs.parts == {"texture": "matern32"}
    assert LearnerOptions().parts is None


@pytest.mark.parametrize("parts", [["texture"], 5, [["texture", "matern32", "x"]]])
def test_kernel_parts_that_are_not_pairs_are_refused(parts: object) -> None:
    with pytest.raises(AtiktError, match=r"kernel_parts=.*give \(block, kernel\) pairs"):
        LearnerOptions.from_dict({"kernel_parts": parts})


def test_every_problem_is_named_in_one_line() -> None:
    with pytest.raises(AtiktError) as caught:
        LearnerOptions.from_dict(
            {
                "budget": -1,
                "eps_explore": 1.5,
                "metric_until": 0,
                "kernel_parts": {"texture": "cubic"},
                "hyper_sd": 0.0,
            }
        )
    text = str(caught.value)
    assert "\n" not in text
    for problem in (
        "budget=-1 must be >= 0",
        "eps_explore=1.5 must lie in [0, 1]",
        "metric_until=0 must be None or >= 1",
        "kernels must be in",
        "hyper_sd=0.0 must be None or > 0",
    ):
        assert problem in text


def _fit(*, related: np.ndarray | None, with_prior: bool) -> ObjectFit:
    """One object's fit with an (unfitted) prior whose models are absent."""

    class EmptyPrior:
        model = None
        densities = None

    kernel = modality_kernel({"force": slice(0, 2)})
    rng = np.random.default_rng(0)
    return ObjectFit(
        kernel=kernel,
        X=rng.normal(size=(4, 2)),
        y=np.array([1.0, 0.0, 1.0, 0.0]),
        prior=EmptyPrior() if with_prior else None,  # type: ignore[arg-type]
        auxiliary={},
        related=related,
    )


@pytest.mark.parametrize("name", ["prediction", "density"])
@pytest.mark.parametrize(
    ("related", "with_prior"),
    [
        (None, True),
        (np.empty((0, 2)), True),
        (np.full((2, 2), 0.9), False),
        (np.full((2, 2), 0.9), True),
    ],
)
def test_relatedness_strategies_choose_nothing_without_scores_or_models(
    name: str, related: np.ndarray | None, *, with_prior: bool
) -> None:
    strategy = transfer_strategy(name)
    assert strategy.choose(_fit(related=related, with_prior=with_prior)) == NO_CHOICE


def test_the_baseline_chooses_nothing_and_scores_nothing() -> None:
    fit = _fit(related=None, with_prior=True)
    assert NoTransfer().choose(fit) == NO_CHOICE
    assert NoTransfer().scorer(fit.prior) is None  # type: ignore[arg-type]
    choice, model = NoTransfer().fit(fit)
    assert choice == NO_CHOICE
    assert model.predict_proba(fit.X).shape == (4, 2)
