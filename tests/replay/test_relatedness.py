import numpy as np
import pytest

from replay.studies._relatedness import closeness, least_similar, most_similar, similarity_to_new


def _clusters(
    centres: list[float], n: int = 30, seed: int = 0, spread: float = 0.1
) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    features = np.concatenate([rng.normal(c, spread, size=(n, 2)) for c in centres])
    labels = np.repeat(np.arange(len(centres)), n)
    return features, labels


def test_closeness_is_largest_for_the_old_object_on_top_of_the_new_one() -> None:
    # old 0 sits on new 3; old 1 is near; old 2 is far
    features, labels = _clusters([5.0, 6.0, 20.0, 5.0])
    matrix = closeness(features, labels, old=[0, 1, 2], new=[3])
    assert matrix.shape == (3, 1)
    assert matrix[0, 0] > matrix[1, 0] > matrix[2, 0]


def test_closeness_of_an_object_without_observations_is_minus_infinity() -> None:
    features, labels = _clusters([0.0, 1.0])
    matrix = closeness(features, labels, old=[0, 5], new=[1])
    assert np.isfinite(matrix[0, 0])
    assert matrix[1, 0] == -np.inf


def test_least_and_most_similar_pick_far_and_near_priors() -> None:
    # object 4 is new; 0 sits on it, 1 is near, 2 and 3 are far
    features, labels = _clusters([5.0, 7.0, -10.0, 20.0, 5.0], seed=1)
    similarity = similarity_to_new({"P1": (features, labels)}, 5, new=[4])
    assert similarity[0] == pytest.approx(1.0)  # nearest in the only action
    assert similarity[0] > similarity[1] > max(similarity[2], similarity[3])
    assert similarity[4] == 0.0  # the new object is no candidate
    assert least_similar(similarity, [0, 1, 2, 3], k=2) == [2, 3]
    assert most_similar(similarity, [0, 1, 2, 3], k=2) == [0, 1]


def test_ranks_not_log_densities_are_averaged_over_actions() -> None:
    # action A: old 0 nearest, 2 second, 1 very far; action B: old 1 nearest, 2 second, 0 a
    # little behind. Every old object averages the same rank, although its mean log density
    # over the two actions differs a lot.
    a_features, labels = _clusters([0.0, 1000.0, 3.0, 0.0], seed=2, spread=1.0)
    b_features, _ = _clusters([6.0, 0.0, 3.0, 0.0], seed=3, spread=1.0)
    per_action = {"A": (a_features, labels), "B": (b_features, labels)}
    similarity = similarity_to_new(per_action, 4, [3])
    np.testing.assert_allclose(similarity[:3], 0.5)
    density = np.sum([closeness(f, lab, [0, 1, 2], [3])[:, 0] for f, lab in per_action.values()], 0)
    assert density[0] - density[1] > 10.0


def test_similarity_is_the_same_whatever_the_order_of_the_actions() -> None:
    a = _clusters([0.0, 1.0, 2.0, 0.5], seed=4)
    b = _clusters([2.0, 1.0, 0.0, 0.5], seed=5)
    first = similarity_to_new({"A": a, "B": b}, 4, [3])
    np.testing.assert_array_equal(first, similarity_to_new({"B": b, "A": a}, 4, [3]))
