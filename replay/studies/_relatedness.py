"""Which prior objects resemble which new objects: per-action nearness in likelihood.

The thesis builds its "negative transfer" experiment from priors that are dissimilar to the new
objects, judged from the confusion matrices of an unsupervised Gaussian mixture (one component
per object) fitted to every object's observations of one action. Where most objects are
separable that confusion is near zero for most pairs, and which objects come out "least
similar" is decided by the mixture's initialisation: on the simulated dataset, 20 mixture
seeds gave three different groups of three, 8 of them with the paper box (the book's designed
counterpart), 6 with the rough sponge, 6 with the biscuit tin. The objects are labelled, so
this module uses the labels instead (deterministic; it picks the biscuit tin, hard box and
rubber mat there, and the glass plate, soft sponge and wood as the most similar):

- per action, every object's observations are standardised (over all objects) and summarised by
  a diagonal Gaussian;
- an old object's *closeness* to a new object is the mean log density, per feature, of the new
  object's observations under the old object's Gaussian; its closeness to the new objects is
  the largest over them;
- per action the old objects are ranked by closeness, and an old object's *similarity* is its
  mean over actions of ``1 - (rank - 1) / (n_old - 1)``: 1 for the nearest old object of some
  new object in every action, 0 for the farthest in every action.

Ranks rather than log densities are averaged so that one action where an object is far away in
some feature (a log density of -9 per feature) does not outweigh the others.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from numpy.typing import NDArray

#: Smallest per-feature variance of an object's Gaussian, in standardised units: a feature that
#: is constant over one object's observations (or an object with one observation) would
#: otherwise give an infinite density.
VARIANCE_FLOOR = 1e-2


def closeness(
    features: NDArray[np.float64], labels: NDArray[np.int64], old: Sequence[int], new: Sequence[int]
) -> NDArray[np.float64]:
    """Return every old object's closeness to every new object in one action.

    Args:
        features: Observations of one action, shape (n, d).
        labels: Object index of each observation, shape (n,).
        old: Indices of the old objects (rows of the result).
        new: Indices of the new objects (columns of the result).

    Returns:
        Matrix (len(old), len(new)): mean log density per feature of the new object's
        observations under the old object's diagonal Gaussian (standardised features);
        ``-inf`` where either object has no observation.
    """
    scale = features.std(axis=0)
    standard = (features - features.mean(axis=0)) / np.where(scale > 0, scale, 1.0)
    d = standard.shape[1]
    result = np.full((len(old), len(new)), -np.inf)
    for i, o in enumerate(old):
        own = standard[labels == o]
        if own.shape[0] == 0:
            continue
        mean, var = own.mean(axis=0), own.var(axis=0) + VARIANCE_FLOOR
        norm = np.log(2.0 * np.pi * var).sum()
        for j, n in enumerate(new):
            x = standard[labels == n]
            if x.shape[0]:
                log_density = -0.5 * (((x - mean) ** 2) / var).sum(axis=1) - 0.5 * norm
                result[i, j] = float(log_density.mean()) / d
    return result


def similarity_to_new(
    per_action: Mapping[str, tuple[NDArray[np.float64], NDArray[np.int64]]],
    n_objects: int,
    new: Sequence[int],
) -> NDArray[np.float64]:
    """Return every object's similarity to the new objects, from its per-action ranks.

    Args:
        per_action: For each action, the observations (n, d) and their object indices (n,).
        n_objects: Number of objects.
        new: Indices of the new objects.

    Returns:
        Array (n_objects,): for an old object, the mean over actions of its rank score
        ``1 - (rank - 1) / (n_old - 1)`` by closeness to its nearest new object (ties share
        the better rank's order by index); 0 for the new objects themselves.
    """
    old = [i for i in range(n_objects) if i not in set(new)]
    total = np.zeros(n_objects)
    if not old or not per_action:
        return total
    for features, labels in per_action.values():
        nearest = closeness(features, labels, old, list(new)).max(axis=1)
        order = sorted(range(len(old)), key=lambda i: (-nearest[i], old[i]))
        for rank, i in enumerate(order):
            total[old[i]] += 1.0 - rank / max(len(old) - 1, 1)
    return total / len(per_action)


def least_similar(similarity: NDArray[np.float64], candidates: Sequence[int], k: int) -> list[int]:
    """Return the ``k`` candidates with the smallest similarity, ties broken by index."""
    order = sorted(candidates, key=lambda index: (float(similarity[index]), index))
    return sorted(order[:k])


def most_similar(similarity: NDArray[np.float64], candidates: Sequence[int], k: int) -> list[int]:
    """Return the ``k`` candidates with the largest similarity, ties broken by index."""
    order = sorted(candidates, key=lambda index: (-float(similarity[index]), index))
    return sorted(order[:k])
