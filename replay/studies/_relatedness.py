"""Which prior objects resemble which new objects: per-action confusion of a Gaussian mixture.

The thesis builds its "negative transfer" experiment from priors that are dissimilar to the new
objects. Dissimilarity comes from confusion matrices: a Gaussian mixture model with one component
per object is fitted, unsupervised, to the standardised features of every object's observations
of one action; two objects are confused when their observations fall into the same components.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from sklearn.mixture import GaussianMixture

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from numpy.typing import NDArray


def confusion_matrix(
    features: NDArray[np.float64], labels: NDArray[np.int64], n_objects: int, seed: int
) -> NDArray[np.float64]:
    """Return the objects' confusion under an unsupervised Gaussian mixture.

    Args:
        features: Observations of one action, shape (n, d).
        labels: Object index of each observation, shape (n,), values in [0, n_objects).
        n_objects: Number of objects (and mixture components).
        seed: Seed of the mixture's initialisation.

    Returns:
        Matrix (n_objects, n_objects): entry (i, j) is the probability that an observation of
        object i and one of object j fall into the same mixture component.
    """
    scale = features.std(axis=0)
    standard = (features - features.mean(axis=0)) / np.where(scale > 0, scale, 1.0)
    mixture = GaussianMixture(
        n_components=n_objects, covariance_type="diag", reg_covar=1e-4, random_state=seed
    )
    components: NDArray[np.int64] = mixture.fit(standard).predict(standard)
    counts = np.zeros((n_objects, n_objects))
    np.add.at(counts, (labels, components), 1.0)
    shares = counts / counts.sum(axis=1, keepdims=True)
    confusion: NDArray[np.float64] = shares @ shares.T
    return confusion


def similarity_to_new(
    per_action: Mapping[str, tuple[NDArray[np.float64], NDArray[np.int64]]],
    n_objects: int,
    new: Sequence[int],
    seed: int,
) -> NDArray[np.float64]:
    """Return every object's confusion with the new objects, summed over actions.

    Args:
        per_action: For each action, the observations (n, d) and their object indices (n,).
        n_objects: Number of objects.
        new: Indices of the new objects.
        seed: Seed of the mixtures.

    Returns:
        Array (n_objects,): mean over actions of the largest confusion with any new object.
    """
    total = np.zeros(n_objects)
    for features, labels in per_action.values():
        confusion = confusion_matrix(features, labels, n_objects, seed)
        total += confusion[:, list(new)].max(axis=1)
    return total / max(len(per_action), 1)


def least_similar(similarity: NDArray[np.float64], candidates: Sequence[int], k: int) -> list[int]:
    """Return the ``k`` candidates with the smallest similarity, ties broken by index."""
    order = sorted(candidates, key=lambda index: (float(similarity[index]), index))
    return sorted(order[:k])
