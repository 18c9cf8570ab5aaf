"""Numerical robustness: degenerate training data give documented results, never a crash.

- duplicate observations with different labels, or constant features: the classifier cannot
  tell the objects apart and says so with uniform probabilities;
- a single observation or a single class: AtiktError naming the problem;
- huge or tiny feature scales: the same probabilities as at unit scale (standardisation uses
  relative thresholds).
"""

import numpy as np
import pytest

from atikt import ActiveLearner, AtiktError, MultiModalGPC, RawFeatures

LABELS = [0, 0, 1, 1, 2, 2]


def _press(force: float, thermal: np.ndarray) -> RawFeatures:
    blocks = {"force": np.array([force]), "thermal": np.asarray(thermal, dtype=np.float64)}
    return RawFeatures("press", blocks)


def _observations(scale: float = 1.0) -> list[RawFeatures]:
    ramp = np.linspace(29.0, 28.0, 40)
    return [_press(scale * (1.0 + 0.1 * i), scale * (ramp + 0.01 * i)) for i in range(6)]


def _proba(observations: list[RawFeatures], labels: list[int]) -> np.ndarray:
    model = MultiModalGPC(random_state=0).fit(observations, labels)
    return np.asarray(model.predict_proba(observations))


@pytest.mark.parametrize(
    "observations",
    [
        [_observations()[0]] * 6,  # the same observation for every object
        [_press(1.0, np.full(40, 29.0)) for _ in range(6)],  # constant features
    ],
    ids=["duplicates", "constant"],
)
def test_indistinguishable_objects_get_uniform_probabilities(
    observations: list[RawFeatures],
) -> None:
    proba = _proba(observations, LABELS)
    np.testing.assert_allclose(proba, 1.0 / 3.0, atol=1e-6)


@pytest.mark.parametrize(
    ("observations", "labels"),
    [(_observations()[:1], [0]), (_observations(), [1] * 6)],
    ids=["single observation", "one class"],
)
def test_one_class_is_refused_clearly(observations: list[RawFeatures], labels: list[int]) -> None:
    with pytest.raises(AtiktError, match="at least two classes"):
        MultiModalGPC().fit(observations, labels)


@pytest.mark.parametrize("scale", [1e-12, 1e12])
def test_huge_and_tiny_feature_scales_change_nothing(scale: float) -> None:
    reference = _proba(_observations(), LABELS)
    scaled = _proba(_observations(scale), LABELS)
    assert np.isfinite(scaled).all()
    np.testing.assert_allclose(scaled, reference, atol=1e-6)


def test_learner_on_duplicate_observations_runs_its_budget() -> None:
    same = _observations()[0]
    learner = ActiveLearner(["P1"], 3, observe=lambda _obj, _action: same, budget=3, random_state=0)
    learner.initialise()
    while not learner.done:
        learner.step()
    assert len(learner.history_) == 3
    assert np.isfinite(learner.uncertainty_).all()
    proba = learner.predict_proba("P1", [same])
    np.testing.assert_allclose(proba.sum(axis=1), 1.0)
