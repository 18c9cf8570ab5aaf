"""The old objects' knowledge of each action: their observations, feature space and models.

Fitted once per learner, or once per study and shared by many learners
(:func:`fit_prior_models`); transfer strategies (:mod:`atikt.strategies`) score and borrow
from it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from atikt.features import FeatureTransformer, RawFeatures
from atikt.gpc import OneVsAllGPC, RandomState, spawn_seeds
from atikt.kernels import modality_kernel
from atikt.transfer import ObjectDensities

IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True, slots=True, eq=False)
class PriorModel:
    """The old objects' knowledge of one action.

    Attributes:
        observations: Prior observations of all old objects.
        labels: Old-object label of each observation, shape (n,).
        transformer: Feature transformer fitted on ``observations``.
        model: One-vs-all GPC over the old objects in the transformer's space (None with a
            single old object: the model prediction approach then cannot be used).
        densities: Each old object's feature distribution in the transformer's space (the
            open-set relatedness of ``transfer="density"``).
    """

    observations: tuple[RawFeatures, ...]
    labels: IntArray
    transformer: FeatureTransformer
    model: OneVsAllGPC | None
    densities: ObjectDensities | None = None

    @property
    def old_objects(self) -> tuple[int, ...]:
        """The old objects' labels, sorted."""
        return tuple(int(v) for v in np.unique(self.labels))

    def by_object(self) -> dict[int, list[RawFeatures]]:
        """Prior observations grouped by old object."""
        groups: dict[int, list[RawFeatures]] = {o: [] for o in self.old_objects}
        for obs, label in zip(self.observations, self.labels, strict=True):
            groups[int(label)].append(obs)
        return groups


PriorsInput = Mapping[str, Mapping[int, Sequence[RawFeatures]] | PriorModel]


def fit_prior_model(
    observations_by_object: Mapping[int, Sequence[RawFeatures]],
    *,
    amplitude: bool = True,
    n_thermal_components: int = 10,
    n_restarts: int = 1,
    max_iter: int = 50,
    parts: Mapping[str, str] | None = None,
    random_state: RandomState = None,
) -> PriorModel:
    """Fit the old objects' models of one action on their prior observations.

    Args:
        observations_by_object: Old-object label -> its observations of the action.
        amplitude: Learn a signal variance (False: the thesis kernel).
        n_thermal_components: Thermal PCA dimensions.
        n_restarts: Random restarts per binary classifier.
        max_iter: Iteration limit of the hyperparameter search per start.
        parts: Kernel of each modality (``atikt.kernels.PART_KERNELS``; RBF where not named).
        random_state: Seed of the restarts.

    Returns:
        The fitted prior model.

    Raises:
        AtiktError: No observations.
    """
    observations = [o for obs in observations_by_object.values() for o in obs]
    labels = np.array([k for k, obs in observations_by_object.items() for _ in obs], dtype=np.int64)
    transformer = FeatureTransformer(n_thermal_components=n_thermal_components)
    X = transformer.fit_transform(observations)
    model = None
    if np.unique(labels).shape[0] >= 2:  # noqa: PLR2004
        kernel = modality_kernel(transformer.slices_, amplitude=amplitude, parts=parts)
        model = OneVsAllGPC(
            kernel, n_restarts=n_restarts, max_iter=max_iter, random_state=random_state
        ).fit(X, labels)
    densities = ObjectDensities.fit(X, labels)
    return PriorModel(tuple(observations), labels, transformer, model, densities)


def fit_prior_models(
    priors: Mapping[str, Mapping[int, Sequence[RawFeatures]]],
    *,
    amplitude: bool = True,
    n_thermal_components: int = 10,
    n_restarts: int = 1,
    max_iter: int = 50,
    parts: Mapping[str, str] | None = None,
    random_state: RandomState = None,
) -> dict[str, PriorModel]:
    """Fit the old objects' models of every action (reusable by many learners of a study).

    Args:
        priors: Action -> old-object label -> observations.
        amplitude: See :func:`fit_prior_model`.
        n_thermal_components: See :func:`fit_prior_model`.
        n_restarts: See :func:`fit_prior_model`.
        max_iter: See :func:`fit_prior_model`.
        parts: See :func:`fit_prior_model`.
        random_state: Seed; each action gets its own derived seed.

    Returns:
        Action -> fitted prior model (actions without observations are left out).
    """
    actions = [a for a, groups in priors.items() if any(len(o) for o in groups.values())]
    seeds = spawn_seeds(random_state, len(actions))
    return {
        action: fit_prior_model(
            {k: v for k, v in priors[action].items() if len(v)},
            amplitude=amplitude,
            n_thermal_components=n_thermal_components,
            n_restarts=n_restarts,
            max_iter=max_iter,
            parts=parts,
            random_state=seed,
        )
        for action, seed in zip(actions, seeds, strict=True)
    }
