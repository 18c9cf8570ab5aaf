import numpy as np

from replay.studies._relatedness import confusion_matrix, least_similar, similarity_to_new


def _clusters(centres: list[float], n: int = 30, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    features = np.concatenate([rng.normal(c, 0.1, size=(n, 2)) for c in centres])
    labels = np.repeat(np.arange(len(centres)), n)
    return features, labels


def test_confusion_separates_distant_objects_and_merges_identical_ones() -> None:
    # objects 0 and 1 are the same distribution; 2 is far away
    features, labels = _clusters([0.0, 0.0, 10.0])
    confusion = confusion_matrix(features, labels, 3, seed=0)
    assert confusion.shape == (3, 3)
    assert confusion[0, 2] < 0.05
    assert confusion[0, 1] > 0.2
    np.testing.assert_allclose(confusion, confusion.T)


def test_least_similar_picks_the_priors_far_from_the_new_objects() -> None:
    # object 3 is new; 0 sits on it, 1 and 2 are far
    features, labels = _clusters([5.0, -10.0, 20.0, 5.0], seed=1)
    similarity = similarity_to_new({"P1": (features, labels)}, 4, new=[3], seed=0)
    assert similarity[0] > similarity[1]
    assert similarity[0] > similarity[2]
    assert least_similar(similarity, [0, 1, 2], k=2) == [1, 2]


def test_confusion_is_deterministic_by_seed() -> None:
    features, labels = _clusters([0.0, 1.0, 2.0], seed=2)
    first = confusion_matrix(features, labels, 3, seed=7)
    np.testing.assert_array_equal(first, confusion_matrix(features, labels, 3, seed=7))
