"""The old objects' knowledge of each action: their observations, feature space and models.

Fitted once per learner, or once per study and shared by many learners
(:func:`fit_prior_models`); transfer strategies (:mod:`atikt.strategies`) score and borrow
from it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from atikt.features import FeatureTransformer, RawFeatures
from atikt.gpc import BinaryGPC, OneVsAllGPC, RandomState, spawn_seeds
from atikt.kernels import modality_kernel
from atikt.transfer import ObjectDensities

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]


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
        held_out: With three or more old objects, per old object (in :attr:`old_objects`
            order): its observations' one-vs-all probabilities under the *other* old objects'
            classifiers (fitted without it, at the hyperparameters of ``model``), shape
            (m_o, n_old - 1). Each old object, left out, is a new object whose relatedness to
            the rest is known from all its observations: what a few of them would have
            claimed is the calibration of :func:`atikt.transfer.held_out_threshold`. Empty
            with fewer old objects.
    """

    observations: tuple[RawFeatures, ...]
    labels: IntArray
    transformer: FeatureTransformer
    model: OneVsAllGPC | None
    densities: ObjectDensities | None = None
    held_out: tuple[FloatArray, ...] = ()
    # derived once (the model is fixed and read at every update of every learner given it)
    _old_objects: tuple[int, ...] = field(init=False, repr=False, compare=False)
    _median_theta: tuple[FloatArray | None] | None = field(
        init=False, repr=False, compare=False, default=None
    )

    def __post_init__(self) -> None:
        """Derive the old objects' labels once."""
        object.__setattr__(self, "_old_objects", tuple(int(v) for v in np.unique(self.labels)))

    @property
    def old_objects(self) -> tuple[int, ...]:
        """The old objects' labels, sorted."""
        return self._old_objects

    def median_theta(self) -> FloatArray | None:
        """The median over the old objects' classifiers of their log hyperparameters.

        Metric transfer's centre (:class:`~atikt.ActiveLearner`); computed once. None without
        a one-vs-all model or when the classifiers' kernels differ in their hyperparameters.

        Returns:
            A copy, shape (n_params,).
        """
        if self._median_theta is None:
            median = None
            if self.model is not None:
                thetas = [e.kernel_.theta for e in self.model.estimators_]
                if len({t.shape for t in thetas}) == 1:
                    median = np.median(thetas, axis=0)
            object.__setattr__(self, "_median_theta", (median,))
        assert self._median_theta is not None  # noqa: S101 - set just above
        median = self._median_theta[0]
        return None if median is None else median.copy()

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
    held_out = () if model is None else held_out_probabilities(X, labels, model)
    return PriorModel(tuple(observations), labels, transformer, model, densities, held_out)


def held_out_probabilities(
    X: FloatArray, labels: IntArray, model: OneVsAllGPC
) -> tuple[FloatArray, ...]:
    """Each old object's probabilities under the others' one-vs-all classifiers.

    The classifiers of the other old objects are refitted without the left-out object's
    observations at the hyperparameters ``model`` found (a Laplace fit each, no search).

    Args:
        X: The old objects' observations in the prior's feature space, shape (n, d).
        labels: Their old-object labels, shape (n,).
        model: The one-vs-all model fitted on all of them.

    Returns:
        Per old object (``model.classes_`` order), shape (m_o, n_old - 1); empty with fewer
        than three old objects (one left out leaves no one-vs-all pair).
    """
    classes = [int(c) for c in model.classes_]
    if len(classes) < 3:  # noqa: PLR2004
        return ()
    out = []
    for left in classes:
        own, rest = labels == left, labels != left
        columns = [
            BinaryGPC(estimator.kernel_, optimize=False)
            .fit(X[rest], labels[rest] == other)
            .predict_positive(X[own])
            for other, estimator in zip(classes, model.estimators_, strict=True)
            if other != left
        ]
        out.append(np.column_stack(columns))
    return tuple(out)


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
