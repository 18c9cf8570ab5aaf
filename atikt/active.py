"""Active selection of exploratory actions with instance knowledge transfer (the ATIKT loop).

Feng, Kaboli & Cheng, "Active tactile instance knowledge transfer" (TUM 2017):

1. start with one observation per (new object, action);
2. estimate ``UNC(action, object)``: the mean Shannon entropy (nats) of the posterior over the
   new objects, predicted by that action's one-vs-all models for that object's own
   observations of that action;
3. perform the (object, action) with the largest ``UNC``, or, with probability
   ``eps_explore``, a uniformly random one;
4. update the chosen action's models only: feature normalisation, relatedness to the old
   objects (where from, how much), kernel weights and GP classifiers;
5. repeat until the budget is spent or the models stop improving.

The learner receives observations through the ``observe`` callable it is given and never knows
where they come from (a rig, or a pool of recordings). Given the same observations in the same
order and the same ``random_state``, it makes the same decisions, bit for bit. The baseline is
``transfer="none"``: the same loop without prior knowledge.

Cost control (a step must take milliseconds): the hyperparameter search of every classifier
starts from that classifier's optimum, search curvature and Laplace mode of the previous
update (warm start, :mod:`atikt.optimize`), uses no random restarts after
:meth:`ActiveLearner.initialise`, and stops after ``max_iter_step`` iterations or when it
predicts less than 1e-3 nats of improvement (``tol`` of :class:`~atikt.gpc.BinaryGPC`); the
old objects' models are fitted once per learner (or once per study, see
:func:`fit_prior_models`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Final, Literal

import numpy as np
import numpy.typing as npt

from atikt.errors import AtiktError, NotFittedError
from atikt.features import FeatureTransformer, RawFeatures, StackedFeatures, stack_features
from atikt.gpc import (
    BinaryGPC,
    OneVsAllGPC,
    RandomState,
    normalise,
    predictive_probability,
    spawn_seeds,
)
from atikt.kernels import ModalityKernel, modality_kernel
from atikt.transfer import (
    ObjectDensities,
    PriorChoice,
    TransferGPC,
    check_threshold,
    choose_by_density,
    choose_by_evidence,
    choose_by_optimization,
    choose_by_relatedness,
    evidence_gains,
)

if TYPE_CHECKING:
    import builtins

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
TransferMode = Literal["prediction", "optimization", "density", "evidence", "none"]
Observe = Callable[[int, str], RawFeatures]
"""``observe(new_object_index, action) -> RawFeatures`` of one performed action."""
Available = Callable[[int, str], bool]
"""``available(new_object_index, action) -> bool``: can another observation be served?"""

TRANSFER_MODES: Final = ("prediction", "optimization", "density", "evidence", "none")
_SCORED: Final = ("prediction", "density")
"""Modes whose relatedness is a per-observation score of the fixed prior models (cached)."""
_KEPT: Final = (*_SCORED, "evidence")
"""Modes whose choice for a new object is kept while only other objects' observations change."""
MetricCheck = Literal["evidence", "separation", "either", "none"]
METRIC_CHECKS: Final = ("evidence", "separation", "either", "none")
_NO_CHOICE: Final = PriorChoice(None, 0.0, (), ())


def _metric_check(value: object) -> MetricCheck:
    """``metric_check`` as one of :data:`METRIC_CHECKS` (True: evidence; False, None: none).

    Raises:
        AtiktError: Any other value.
    """
    if value is None:
        return "none"
    if isinstance(value, bool | int | float) and value in {0, 1}:
        return "evidence" if value else "none"
    if value not in METRIC_CHECKS:
        msg = f"metric_check={value!r} must be one of {METRIC_CHECKS} (or True / False)"
        raise AtiktError(msg)
    return value


SEPARATION_REPEATS: Final = 32
"""Most observations per old object whose pairs :func:`separation` compares."""


def separation(
    kernel: ModalityKernel, X: FloatArray, labels: IntArray, aux: Mapping[int, FloatArray]
) -> float:
    """How well ``kernel`` separates the new objects: do repeat touches look more alike?

    The probability (ties count half) that two observations of one object are more alike
    under the kernel (its correlation ``k(x, y) / k(x, x)``) than two observations of
    different new objects, pairs drawn at random: repeat pairs from the old objects'
    observations (``aux``: old object -> its observations in the new objects' feature space),
    because after one observation per new object there are none of theirs; different-object
    pairs from the new objects' observations (``X``, ``labels``). 1: every pair of new objects
    is less alike than repeated touches; 0.5: the kernel cannot tell them apart, whatever it
    did for the old objects. A rank statistic, so kernels of any length scale compare fairly
    (measured against the difference of mean correlations: fewer losses on single press and
    contact actions, atikt/README *Metric transfer*). The evidence cannot judge this with one
    observation per object: it always prefers the kernel that makes the few observations
    independent.

    Returns:
        The probability, in [0, 1]; ``-inf`` without two observations of some old object or
        two new objects.
    """
    scale = float(kernel.diag(X[:1])[0])
    # at most SEPARATION_REPEATS evenly spaced observations per old object: the pairs grow
    # with the square of their number (20 objects x 100 observations: 10 ms a call, 1.4 ms
    # with the cap), and a few hundred pairs per object estimate a rank statistic well
    kept = [
        obs[np.linspace(0, len(obs) - 1, min(len(obs), SEPARATION_REPEATS)).astype(int)]
        for obs in aux.values()
    ]
    repeats = [(kernel(obs) / scale)[np.triu_indices(len(obs), 1)] for obs in kept]
    pooled = np.sort(np.concatenate([np.empty(0), *repeats]))
    pairs = np.triu(labels[:, None] != labels[None, :], 1)
    if pooled.size == 0 or not pairs.any():
        return -np.inf
    between = (kernel(X) / scale)[pairs]
    below = np.searchsorted(pooled, between, side="left")
    above = np.searchsorted(pooled, between, side="right")
    return float(np.mean(1.0 - (below + above) / (2.0 * pooled.size)))


def entropy(p: FloatArray) -> FloatArray:
    """Shannon entropy in nats of each row of ``p`` (m, k); ``0 log 0 = 0``."""
    logs = np.log(np.where(p > 0, p, 1.0))
    return np.asarray(-(p * logs).sum(axis=1), dtype=np.float64)


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
    random_state: RandomState = None,
) -> PriorModel:
    """Fit the old objects' models of one action on their prior observations.

    Args:
        observations_by_object: Old-object label -> its observations of the action.
        amplitude: Learn a signal variance (False: the thesis kernel).
        n_thermal_components: Thermal PCA dimensions.
        n_restarts: Random restarts per binary classifier.
        max_iter: Iteration limit of the hyperparameter search per start.
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
        kernel = modality_kernel(transformer.slices_, amplitude=amplitude)
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
    random_state: RandomState = None,
) -> dict[str, PriorModel]:
    """Fit the old objects' models of every action (reusable by many learners of a study).

    Args:
        priors: Action -> old-object label -> observations.
        amplitude: See :func:`fit_prior_model`.
        n_thermal_components: See :func:`fit_prior_model`.
        n_restarts: See :func:`fit_prior_model`.
        max_iter: See :func:`fit_prior_model`.
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
            random_state=seed,
        )
        for action, seed in zip(actions, seeds, strict=True)
    }


@dataclass(frozen=True, slots=True)
class StepRecord:
    """One decision of the active learner and its outcome.

    Attributes:
        step: Index of the step, from 0.
        object: New object that was explored.
        action: Action that was performed.
        explored: True if the choice was random (probability ``eps_explore``).
        uncertainty: ``UNC(action, object)`` of the choice before the observation.
        entropies: ``UNC`` of every (action, object) before the decision, actions in the
            learner's order, objects by index.
        prior: Old object transferred to the explored object's classifier after the update
            (None: no transfer).
        rho: Its transfer coefficient (0 without transfer).
        relatedness: Score of every old object for the explored object (mean probability or
            learned rho), in the order of ``candidates``.
        candidates: Old-object labels.
        priors: Transferred old object of every new object's classifier of the action.
        rhos: Transfer coefficient of every new object's classifier of the action.
        modalities: Modality names, in the order of ``weights``.
        weights: Modality weights of the explored object's classifier.
        signal_variance: Its signal variance (1 for the thesis kernel).
        mean_entropy: Mean ``UNC`` over all (action, object) after the update.
        n_observations: Observations collected so far, including the initial ones.
    """

    step: int
    object: int
    action: str
    explored: bool
    uncertainty: float
    entropies: tuple[tuple[float, ...], ...]
    prior: int | None
    rho: float
    relatedness: tuple[float, ...]
    candidates: tuple[int, ...]
    priors: tuple[int | None, ...]
    rhos: tuple[float, ...]
    modalities: tuple[str, ...]
    weights: tuple[float, ...]
    signal_variance: float
    mean_entropy: float
    n_observations: int

    def as_row(self) -> dict[str, builtins.object]:
        """Flatten to one table row (lists for the tuple fields, ``-1`` for no prior)."""
        return {
            "step": self.step,
            "object": self.object,
            "action": self.action,
            "explored": self.explored,
            "uncertainty": self.uncertainty,
            "entropies": [list(row) for row in self.entropies],
            "prior": -1 if self.prior is None else self.prior,
            "rho": self.rho,
            "relatedness": list(self.relatedness),
            "candidates": list(self.candidates),
            "priors": [-1 if p is None else p for p in self.priors],
            "rhos": list(self.rhos),
            "modalities": list(self.modalities),
            "weights": list(self.weights),
            "signal_variance": self.signal_variance,
            "mean_entropy": self.mean_entropy,
            "n_observations": self.n_observations,
        }


@dataclass(slots=True)
class ActionState:
    """Working state of one action's models (internal, mutable; exposed for inspection).

    Attributes:
        kind: Action kind.
        prior: The old objects' model of this action (None without transfer).
        observations: Collected observations of the new objects.
        labels: New-object index of each observation.
        transformer: Feature transformer of the current update.
        X: Features of ``observations``, shape (n, d).
        models: One classifier per new object.
        choices: Transfer choice per new object.
        thetas: Warm-start hyperparameters (base kernel) per new object.
        rhos: Warm-start learned rho per new object and old object (model optimisation).
        uncertainty: ``UNC`` per new object, shape (n_new,).
        prior_stacks: The prior observations of each old object, stacked on first use.
        prior_probabilities: The old objects' one-vs-all probabilities of each observation
            scored so far (model prediction approach; the old models never change, so each
            observation is scored once), shape (n_scored, n_old).
    """

    kind: str
    prior: PriorModel | None
    observations: list[RawFeatures] = field(default_factory=list)
    labels: list[int] = field(default_factory=list)
    transformer: FeatureTransformer | None = None
    X: FloatArray = field(default_factory=lambda: np.zeros((0, 0)))
    models: list[TransferGPC] = field(default_factory=list)
    choices: list[PriorChoice] = field(default_factory=list)
    thetas: list[FloatArray | None] = field(default_factory=list)
    rhos: list[dict[int, float]] = field(default_factory=list)
    uncertainty: FloatArray = field(default_factory=lambda: np.zeros(0))
    prior_stacks: dict[int, StackedFeatures] | None = None
    prior_probabilities: FloatArray | None = None


class ActiveLearner:
    """ATIKT active learner of new objects, optionally transferring old objects' observations.

    Args:
        actions: Action ids, e.g. ``["P1", "P2", "S1", "S2", "S3", "S4", "C1"]``.
        n_new_objects: Number of new objects (indices ``0 .. n_new_objects - 1``).
        observe: ``observe(object_index, action) -> RawFeatures``: performs (or replays) an
            action and returns its raw features.
        available: ``available(object_index, action) -> bool``; decisions only consider
            pairs for which it is True (e.g. a finite pool of recordings), and the learner is
            done when no pair is left. None: every pair is always available.
        priors: Action -> old-object label -> raw observations, or action -> a
            :class:`PriorModel` from :func:`fit_prior_models` (fitted once for many
            learners). Ignored with ``transfer="none"``.
        budget: Number of steps (observations after the initial one per object and action).
        eps_explore: Probability of a uniformly random (object, action).
        transfer: ``"prediction"`` (model prediction approach), ``"optimization"`` (rho by
            marginal likelihood), ``"density"`` (open-set score of each old object's own
            feature distribution, :func:`~atikt.transfer.choose_by_density`), ``"evidence"``
            (the dependent GP's evidence gain of each old object,
            :func:`~atikt.transfer.choose_by_evidence`) or ``"none"`` (baseline).
        eps_neg1: Threshold of the model prediction approach, in (0.5, 1].
        eps_neg2: Threshold of the model optimisation approach, in (0, 1].
        eps_density: Threshold of the open-set score, in (0, 1].
        density_rho_scale: ``rho = min(1, density_rho_scale * score)`` of the open-set score.
        eps_evidence: Smallest evidence gain (nats) for a transfer (``transfer="evidence"``).
        evidence_rho: ``rho`` at which the evidence gain is evaluated and transferred, (0, 1].
        max_sources: Most old objects transferred to one new object's classifier at once (the
            most related ones passing the threshold, one ``rho`` each, through the
            multi-source kernel); 1 is the thesis's single source. Prediction, density and
            evidence approaches only.
        hyper_sd: Standard deviation of a Gaussian prior on every new-object classifier's log
            hyperparameters, centred on the initial kernel (unit length scales, equal weights,
            unit variance): maximum a posteriori instead of the thesis's maximum likelihood,
            for baseline and transfer alike; None: maximum likelihood.
        metric_sd: Metric transfer: with prior models of two or more old objects, every
            new-object classifier starts from the old objects' kernel hyperparameters (their
            median) and its hyperprior, of this sd, is centred there instead of on the
            initial kernel (``hyper_sd``). None: no metric transfer (the thesis). Ignored
            without priors (the baseline).
        metric_check: When to use the old objects' kernel, checked at every update:
            ``"evidence"`` (or True) when the new objects' summed one-vs-all log evidence is
            at least as large there as at the initial kernel; ``"separation"`` when it
            separates the new objects at least as well (:func:`separation`: the old objects'
            repeat observations against the new objects' pairs); ``"either"`` when one of
            the two holds (the default: separation decides after one observation per
            object, where the evidence always prefers the kernel that makes the few
            observations independent); ``"none"`` (or False): whenever there is one.
        metric_until: The old objects' kernel centres a new object's hyperprior only while the
            object has at most this many observations of the action; with more, its own
            observations decide (the initial kernel's centre and ``hyper_sd``). None: always
            (the old kernel's pull then costs up to 10 points once an action has many
            observations, atikt/README *Metric transfer*).
        bias: Add a learned constant ``b^2`` to the kernel (a bias of the latent function).
        patience: Stop early after this many steps without the mean ``UNC`` improving by
            ``min_improvement``; None runs the whole budget.
        min_improvement: See ``patience`` (nats).
        amplitude: Learn a signal variance (False: the thesis kernel, ``|w|_1 = 1`` only).
        n_thermal_components: Thermal PCA dimensions (thesis: 10).
        n_restarts: Random restarts of each hyperparameter search in :meth:`initialise`.
        max_iter_initial: Search iteration limit per start in :meth:`initialise`.
        max_iter_step: Iteration limit of the warm-started search of each step.
        random_state: Seed of every random choice (exploration, restarts).

    Attributes:
        history_: One :class:`StepRecord` per step.
        uncertainty_: ``UNC``, shape (n_actions, n_new_objects).
        states_: Action -> its :class:`ActionState`.
        n_observations_: Observations collected so far.
    """

    def __init__(
        self,
        actions: Sequence[str],
        n_new_objects: int,
        *,
        observe: Observe,
        available: Available | None = None,
        priors: PriorsInput | None = None,
        budget: int = 40,
        eps_explore: float = 0.3,
        transfer: TransferMode = "prediction",
        eps_neg1: float = 0.6,
        eps_neg2: float = 0.6,
        eps_density: float = 0.1,
        density_rho_scale: float = 2.0,
        eps_evidence: float = 0.0,
        evidence_rho: float = 0.9,
        max_sources: int = 1,
        hyper_sd: float | None = None,
        metric_sd: float | None = 1.0,
        bias: bool = False,
        metric_check: MetricCheck | bool = "either",
        metric_until: int | None = 2,
        patience: int | None = None,
        min_improvement: float = 1e-3,
        amplitude: bool = True,
        n_thermal_components: int = 10,
        n_restarts: int = 1,
        max_iter_initial: int = 30,
        max_iter_step: int = 10,
        random_state: RandomState = None,
    ) -> None:
        """Store and validate the parameters; see the class docstring."""
        self.actions = tuple(actions)
        self.n_new_objects = n_new_objects
        self.observe = observe
        self.available = available
        self.priors = priors
        self.budget = budget
        self.eps_explore = eps_explore
        self.transfer = transfer
        self.eps_neg1 = eps_neg1
        self.eps_neg2 = eps_neg2
        self.eps_density = eps_density
        self.density_rho_scale = density_rho_scale
        self.eps_evidence = eps_evidence
        self.evidence_rho = evidence_rho
        self.max_sources = max_sources
        self.hyper_sd = hyper_sd
        self.metric_sd = metric_sd
        self.bias = bool(bias)
        self.metric_check = _metric_check(metric_check)
        self.metric_until = None if metric_until is None else int(metric_until)
        self.patience = patience
        self.min_improvement = min_improvement
        self.amplitude = amplitude
        self.n_thermal_components = n_thermal_components
        self.n_restarts = n_restarts
        self.max_iter_initial = max_iter_initial
        self.max_iter_step = max_iter_step
        self.random_state = random_state
        self._validate()

    def _validate(self) -> None:
        """Check the parameters.

        Raises:
            AtiktError: A parameter is out of range; the message names it.
        """
        problems = []
        if len(set(self.actions)) != len(self.actions) or not self.actions:
            problems.append(f"actions={list(self.actions)} must be non-empty and distinct")
        if self.n_new_objects < 2:  # noqa: PLR2004
            problems.append(f"n_new_objects={self.n_new_objects} must be >= 2")
        if self.transfer not in TRANSFER_MODES:
            problems.append(f"transfer={self.transfer!r} must be one of {TRANSFER_MODES}")
        if not 0.0 <= self.eps_explore <= 1.0:
            problems.append(f"eps_explore={self.eps_explore} must lie in [0, 1]")
        if not self.density_rho_scale > 0:
            problems.append(f"density_rho_scale={self.density_rho_scale} must be > 0")
        ranges = (
            (
                0.0 < self.evidence_rho <= 1.0,
                f"evidence_rho={self.evidence_rho} must lie in (0, 1]",
            ),
            (
                bool(np.isfinite(self.eps_evidence)),
                f"eps_evidence={self.eps_evidence} must be finite",
            ),
            (self.max_sources >= 1, f"max_sources={self.max_sources} must be >= 1"),
            (
                self.metric_until is None or self.metric_until >= 1,
                f"metric_until={self.metric_until} must be None or >= 1",
            ),
            (
                self.hyper_sd is None or 0.0 < self.hyper_sd < np.inf,
                f"hyper_sd={self.hyper_sd} must be None or > 0",
            ),
            (
                self.metric_sd is None or 0.0 < self.metric_sd < np.inf,
                f"metric_sd={self.metric_sd} must be None or > 0",
            ),
        )
        problems += [problem for ok, problem in ranges if not ok]
        if self.budget < 0:
            problems.append(f"budget={self.budget} must be >= 0")
        if problems:
            raise AtiktError("; ".join(problems))
        check_threshold("eps_neg1", self.eps_neg1)
        check_threshold("eps_neg2", self.eps_neg2, low=0.0)
        check_threshold("eps_density", self.eps_density, low=0.0)

    # ----------------------------------------------------------------------------- state

    @property
    def done(self) -> bool:
        """True when the budget is spent or the models stopped improving."""
        if not hasattr(self, "history_"):
            return False
        return len(self.history_) >= self.budget or self._stalled() or not self._candidates()

    def _candidates(self) -> list[int]:
        """Flat indices (action-major) of the (action, object) pairs that can be observed."""
        pairs = range(len(self.actions) * self.n_new_objects)
        if self.available is None:
            return list(pairs)
        n = self.n_new_objects
        return [i for i in pairs if self.available(i % n, self.actions[i // n])]

    def _stalled(self) -> bool:
        """True after ``patience`` steps without the mean UNC improving by ``min_improvement``."""
        if self.patience is None or len(self.history_) < self.patience:
            return False
        means = [self._initial_mean_entropy, *(r.mean_entropy for r in self.history_)]
        best_before = min(means[: -self.patience])
        return min(means[-self.patience :]) > best_before - self.min_improvement

    def _check_initialised(self) -> None:
        """Raise NotFittedError before :meth:`initialise`."""
        if not hasattr(self, "history_"):
            msg = "ActiveLearner is not initialised; call initialise() first"
            raise NotFittedError(msg)

    # ------------------------------------------------------------------------ the loop

    def initialise(self) -> None:
        """Reset, fit the prior models, and observe each (new object, action) once.

        Observations are requested action by action, objects in index order.
        """
        self._rng = np.random.default_rng(self.random_state)
        self.history_: list[StepRecord] = []
        self.n_observations_ = 0
        priors = self._prior_models()
        self.states_: dict[str, ActionState] = {}
        for action in self.actions:
            for obj in range(self.n_new_objects):
                self._record(action, obj, self._observe(obj, action), priors)
        for action in self.actions:
            self._update(action, n_restarts=self.n_restarts, max_iter=self.max_iter_initial)
        self.uncertainty_ = np.vstack([self.states_[a].uncertainty for a in self.actions])
        self._initial_mean_entropy = float(self.uncertainty_.mean())

    def _prior_models(self) -> dict[str, PriorModel]:
        """Fit (or take) the prior models of the actions; none for the baseline."""
        if self.transfer == "none" or not self.priors:
            return {}
        given = {a: p for a, p in self.priors.items() if isinstance(p, PriorModel)}
        raw = {a: p for a, p in self.priors.items() if not isinstance(p, PriorModel)}
        fitted = fit_prior_models(
            raw,
            amplitude=self.amplitude,
            n_thermal_components=self.n_thermal_components,
            n_restarts=self.n_restarts,
            random_state=self._rng.spawn(1)[0],  # leaves the decisions' stream untouched
        )
        models = {**given, **fitted}
        for action, prior in models.items():
            if self.transfer == "prediction" and prior.model is None:
                msg = (
                    f"action {action!r} has prior data of one old object only; the model "
                    "prediction approach needs >= 2 old objects (use transfer='optimization')"
                )
                raise AtiktError(msg)
        return models

    def _observe(self, obj: int, action: str) -> RawFeatures:
        """Call ``observe`` and check what it returns.

        Raises:
            AtiktError: The callback returned something other than RawFeatures.
        """
        observation: object = self.observe(obj, action)
        if not isinstance(observation, RawFeatures):
            msg = (
                f"observe({obj}, {action!r}) returned {type(observation).__name__}; it must "
                "return RawFeatures (see atikt.extract_features)"
            )
            raise AtiktError(msg)
        self.n_observations_ += 1
        return observation

    def _record(
        self, action: str, obj: int, observation: RawFeatures, priors: Mapping[str, PriorModel]
    ) -> None:
        """Store a new observation of ``action``.

        Raises:
            AtiktError: Its kind differs from the action's earlier observations or priors.
        """
        state = self.states_.get(action)
        if state is None:
            state = ActionState(kind=observation.kind, prior=priors.get(action))
            self.states_[action] = state
        expected = state.kind if state.prior is None else state.prior.transformer.kind_
        if observation.kind != state.kind or state.kind != expected:
            msg = (
                f"action {action!r}: observation of kind {observation.kind!r}, expected "
                f"{state.kind!r} (priors: {expected!r}); check the action ids"
            )
            raise AtiktError(msg)
        state.observations.append(observation)
        state.labels.append(obj)

    def step(self) -> StepRecord:
        """Take one decision, observe, update the chosen action's models, and record it.

        Returns:
            The step's record (also appended to ``history_``).

        Raises:
            NotFittedError: :meth:`initialise` was not called.
            AtiktError: The learner is done (budget spent, stalled, or nothing available).
        """
        self._check_initialised()
        if self.done:
            msg = f"the learner is done after {len(self.history_)} steps; check `done` first"
            raise AtiktError(msg)
        entropies = self.uncertainty_.copy()
        candidates = self._candidates()
        explored = bool(self._rng.random() < self.eps_explore)
        # Exploration: a uniformly random available (action, object); exploitation: the largest
        # UNC among the available pairs, ties to the first in (action, object) order.
        if explored:
            index = candidates[int(self._rng.integers(len(candidates)))]
        else:
            index = candidates[int(np.argmax(entropies.ravel()[candidates]))]
        action_index, obj = divmod(index, self.n_new_objects)
        action = self.actions[action_index]
        observation = self._observe(obj, action)
        self._record(action, obj, observation, {})
        self._update(action, n_restarts=0, max_iter=self.max_iter_step, changed=obj)
        self.uncertainty_[action_index] = self.states_[action].uncertainty
        record = self._step_record(obj, action, entropies, explored=explored)
        self.history_.append(record)
        return record

    def _step_record(
        self, obj: int, action: str, entropies: FloatArray, *, explored: bool
    ) -> StepRecord:
        """Build the record of a step from the updated state."""
        state = self.states_[action]
        choice = state.choices[obj]
        kernel = state.models[obj].base_kernel_
        assert isinstance(kernel, ModalityKernel)  # noqa: S101 - built by _update
        return StepRecord(
            step=len(self.history_),
            object=obj,
            action=action,
            explored=explored,
            uncertainty=float(entropies[self.actions.index(action), obj]),
            entropies=tuple(tuple(float(v) for v in row) for row in entropies),
            prior=choice.source,
            rho=choice.rho,
            relatedness=choice.scores,
            candidates=choice.candidates,
            priors=tuple(c.source for c in state.choices),
            rhos=tuple(c.rho for c in state.choices),
            modalities=kernel.modalities,
            weights=tuple(float(w) for w in kernel.weights),
            signal_variance=kernel.signal_variance,
            mean_entropy=float(self.uncertainty_.mean()),
            n_observations=self.n_observations_,
        )

    # ---------------------------------------------------------------------- the update

    def _update(
        self, action: str, *, n_restarts: int, max_iter: int, changed: int | None = None
    ) -> None:
        """Refit one action's features, transfer choices and classifiers; recompute its UNC.

        ``changed`` names the only new object whose observations changed: the relatedness of
        the others (model prediction approach) depends on their own observations and the fixed
        prior models only, so their previous choices are kept (None: recompute all).
        """
        state = self.states_[action]
        prior = state.prior
        # The new objects' feature space comes from their own observations (the learning task's
        # training set), exactly as without priors; auxiliary observations are mapped into it.
        transformer = FeatureTransformer(n_thermal_components=self.n_thermal_components)
        X = transformer.fit_transform(state.observations)
        labels = np.asarray(state.labels)
        auxiliary = self._auxiliary(state, transformer)
        if not state.models:
            n = self.n_new_objects
            state.models, state.choices = [], [_NO_CHOICE] * n
            state.thetas, state.rhos = [None] * n, [{} for _ in range(n)]
        seeds = spawn_seeds(self._rng, self.n_new_objects)
        probabilities = self._prior_probabilities(state)
        models = []
        initial = modality_kernel(
            transformer.slices_, amplitude=self.amplitude, bias=1.0 if self.bias else None
        )
        base, base_sd = initial, self.hyper_sd
        counts = np.bincount(labels, minlength=self.n_new_objects)
        prior_sd = base_sd
        if self.metric_until is None or counts.min() <= self.metric_until:  # someone uses it
            initial, prior_sd = self._metric(prior, initial, X, labels, auxiliary)
        for obj, seed in enumerate(seeds):
            centre, sd = initial, prior_sd
            if self.metric_until is not None and counts[obj] > self.metric_until:
                centre, sd = base, base_sd  # enough own observations: the data decide
            kernel = centre  # kernels are immutable: with_theta returns a new one
            theta = state.thetas[obj]
            if theta is not None and theta.shape == kernel.theta.shape:
                kernel = kernel.with_theta(theta)
            y = (labels == obj).astype(np.float64)
            keep = changed is not None and obj != changed and self.transfer in _KEPT
            choice, model = self._fit_object(
                kernel,
                X,
                y,
                known=state.choices[obj] if keep else None,
                related=None if probabilities is None else probabilities[labels == obj],
                prior=prior,
                auxiliary=auxiliary,
                rho_starts=state.rhos[obj],
                previous=state.models[obj] if state.models else None,
                centre=centre.theta,
                prior_sd=sd,
                n_restarts=n_restarts,
                max_iter=max_iter,
                seed=seed,
            )
            state.choices[obj] = choice
            state.thetas[obj] = model.base_kernel_.theta
            models.append(model)
        state.transformer, state.X, state.models = transformer, X, models
        state.uncertainty = self._uncertainty(state)

    def _metric(
        self,
        prior: PriorModel | None,
        initial: ModalityKernel,
        X: FloatArray,
        labels: IntArray,
        aux: Mapping[int, FloatArray],
    ) -> tuple[ModalityKernel, float | None]:
        """The new objects' starting kernel and hyperprior sd: the old objects' metric if known.

        Metric transfer: the old objects' classifiers, fitted on many observations per object,
        know which modalities and length scales separate objects of this action; one
        observation per new object does not. Their hyperparameters (the median over the old
        objects' one-vs-all classifiers, log space) start every new object's search and centre
        its hyperprior, of sd ``metric_sd``. Without priors, with a single old object (no
        one-vs-all model), with ``metric_sd=None`` or when ``metric_check`` refuses it: the
        initial kernel and ``hyper_sd``.
        """
        if self.metric_sd is None or prior is None or prior.model is None:
            return initial, self.hyper_sd
        thetas = [e.kernel_.theta for e in prior.model.estimators_]
        if any(t.shape != initial.theta.shape for t in thetas):  # e.g. bias in one only
            return initial, self.hyper_sd
        metric = initial.with_theta(np.median(thetas, axis=0))
        check = self.metric_check
        passed = check == "none"
        if not passed and check in {"separation", "either"}:
            passed = separation(metric, X, labels, aux) >= separation(initial, X, labels, aux)
        if not passed and check in {"evidence", "either"}:
            passed = self._evidence(metric, X, labels) >= self._evidence(initial, X, labels)
        return (metric, self.metric_sd) if passed else (initial, self.hyper_sd)

    def _evidence(self, kernel: ModalityKernel, X: FloatArray, labels: IntArray) -> float:
        """Sum over the new objects of their one-vs-all log evidence at ``kernel``."""
        return sum(
            BinaryGPC(kernel, optimize=False).fit(X, labels == obj).log_marginal_likelihood_value_
            for obj in range(self.n_new_objects)
        )

    def _prior_probabilities(self, state: ActionState) -> FloatArray | None:
        """The old models' score of every observation (model prediction or density approach).

        The old objects' one-vs-all probabilities (prediction) or the tail probabilities under
        their feature distributions (density); only the observations not scored before are
        scored.
        """
        prior = state.prior
        if prior is None or self.transfer not in _SCORED:
            return None
        scorer = prior.model if self.transfer == "prediction" else prior.densities
        if scorer is None:
            return None
        done = 0 if state.prior_probabilities is None else state.prior_probabilities.shape[0]
        if done < len(state.observations):
            features = prior.transformer.transform(state.observations[done:])
            new = (
                scorer.predict_binary(features)
                if isinstance(scorer, OneVsAllGPC)
                else scorer.tail_probabilities(features)
            )
            old = state.prior_probabilities
            state.prior_probabilities = new if old is None else np.vstack([old, new])
        assert state.prior_probabilities is not None  # noqa: S101 - set just above
        return state.prior_probabilities

    def _auxiliary(
        self, state: ActionState, transformer: FeatureTransformer
    ) -> dict[int, FloatArray]:
        """Each old object's prior observations in the current feature space."""
        if state.prior is None:
            return {}
        if state.prior_stacks is None:  # stacked once: the prior observations never change
            groups = state.prior.by_object().items()
            state.prior_stacks = {old: stack_features(obs) for old, obs in groups}
        return {old: transformer.transform(obs) for old, obs in state.prior_stacks.items()}

    def _fit_object(
        self,
        kernel: ModalityKernel,
        X: FloatArray,
        y: FloatArray,
        *,
        known: PriorChoice | None,
        related: FloatArray | None,
        prior: PriorModel | None,
        auxiliary: Mapping[int, FloatArray],
        rho_starts: dict[int, float],
        previous: TransferGPC | None,
        centre: FloatArray,
        prior_sd: float | None,
        n_restarts: int,
        max_iter: int,
        seed: int,
    ) -> tuple[PriorChoice, TransferGPC]:
        """Choose where from / how much to transfer and fit one new object's classifier."""
        # every classifier fitted here searches its hyperparameters the same way
        search: dict[str, Any] = {
            "n_restarts": n_restarts,
            "max_iter": max_iter,
            "prior_sd": prior_sd,
            "prior_mean": centre,
            "random_state": seed,
        }
        if prior is not None and self.transfer == "optimization":
            choice, model = choose_by_optimization(
                kernel, X, y, auxiliary, eps_neg2=self.eps_neg2, rho0=rho_starts, **search
            )
            rho_starts.update(zip(choice.candidates, choice.scores, strict=True))
            return choice, model
        choice = _NO_CHOICE if known is None else known
        if known is None and prior is not None and self.transfer == "evidence" and auxiliary:
            # the gains are evaluated at the hyperparameters the labels give without transfer
            plain = TransferGPC(kernel, previous=previous, **search).fit(X, y)
            gains = evidence_gains(plain.base_kernel_, X, y, auxiliary, self.evidence_rho)
            choice = choose_by_evidence(
                gains, tuple(auxiliary), self.eps_evidence, self.max_sources, self.evidence_rho
            )
            if choice.source is None:
                return choice, plain
            fitted = plain.base_kernel_
            assert isinstance(fitted, ModalityKernel)  # noqa: S101 - the plain fit of kernel
            kernel, previous = fitted, plain
        scored = related is not None and related.shape[0] > 0
        if known is None and prior is not None and scored:
            assert related is not None  # noqa: S101 - scored
            # relatedness: the mean of the old models' scores of this object's observations
            scores = related.mean(axis=0)
            if self.transfer == "density" and prior.densities is not None:
                classes = prior.densities.classes
                choice = choose_by_density(
                    scores, classes, self.eps_density, self.max_sources, self.density_rho_scale
                )
            elif prior.model is not None:
                classes = prior.model.classes_
                choice = choose_by_relatedness(scores, classes, self.eps_neg1, self.max_sources)
        aux: FloatArray | list[FloatArray] | None = None
        rho: float | tuple[float, ...] = choice.rho
        if len(choice.sources) > 1:
            aux, rho = [auxiliary[s] for s in choice.sources], choice.rhos
        elif choice.source is not None:
            aux = auxiliary[choice.source]
        model = TransferGPC(kernel, rho=rho, previous=previous, **search).fit(X, y, aux)
        return choice, model

    def _uncertainty(self, state: ActionState) -> FloatArray:
        """``UNC`` of each new object: mean entropy of its own observations' posteriors."""
        latents = [m.training_latent() for m in state.models]  # one probability call for all
        mean = np.concatenate([m for m, _ in latents])
        var = np.concatenate([v for _, v in latents])
        positive = predictive_probability(mean, var).reshape(len(latents), -1).T
        entropies = entropy(normalise(positive))
        labels = np.asarray(state.labels)
        n = self.n_new_objects
        return np.bincount(labels, entropies, n) / np.bincount(labels, minlength=n)

    @staticmethod
    def _posterior(state: ActionState, X: FloatArray) -> FloatArray:
        """Posterior over the new objects (one-vs-all, normalised), shape (m, n_new)."""
        return normalise(np.column_stack([m.predict_positive(X) for m in state.models]))

    # ------------------------------------------------------------------------ evaluation

    def predict_proba(self, action: str, observations: Sequence[RawFeatures]) -> FloatArray:
        """Posterior over the new objects of test observations of one action.

        Args:
            action: The action the observations come from.
            observations: Raw test observations.

        Returns:
            Shape (m, n_new_objects), rows sum to 1.

        Raises:
            NotFittedError: :meth:`initialise` was not called.
            AtiktError: Unknown action.
        """
        self._check_initialised()
        if action not in self.states_:
            msg = f"unknown action {action!r}; the learner knows {list(self.actions)}"
            raise AtiktError(msg)
        state = self.states_[action]
        assert state.transformer is not None  # noqa: S101 - set by initialise
        return self._posterior(state, state.transformer.transform(observations))

    def predict(self, action: str, observations: Sequence[RawFeatures]) -> IntArray:
        """Most probable new object of each test observation, shape (m,)."""
        return np.asarray(np.argmax(self.predict_proba(action, observations), axis=1), np.int64)

    def score_per_action(
        self, test: Mapping[str, tuple[Sequence[RawFeatures], npt.ArrayLike]]
    ) -> dict[str, float]:
        """Accuracy per action on test observations.

        Args:
            test: Action -> (raw test observations, their new-object indices).

        Returns:
            Action -> accuracy in [0, 1].
        """
        self._check_initialised()
        scores = {}
        for action, (observations, labels) in test.items():
            predicted = self.predict(action, observations)
            scores[action] = float(np.mean(predicted == np.asarray(labels).reshape(-1)))
        return scores

    def score(self, test: Mapping[str, tuple[Sequence[RawFeatures], npt.ArrayLike]]) -> float:
        """Accuracy of all actions together: the mean over actions of per-action accuracy."""
        scores = self.score_per_action(test)
        if not scores:
            msg = "no test data; pass {action: (observations, labels)}"
            raise AtiktError(msg)
        return float(np.mean(list(scores.values())))
