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

import functools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Final

import numpy as np
import numpy.typing as npt

from atikt.errors import AtiktError, NotFittedError
from atikt.features import FeatureTransformer, RawFeatures, StackedFeatures, stack_features
from atikt.gpc import (
    BinaryGPC,
    RandomState,
    add_to_diagonal,
    laplace_evidences,
    normalise,
    predictive_probability,
    spawn_seeds,
)
from atikt.kernels import ModalityKernel, SliceRBF, modality_kernel
from atikt.options import METRIC_CHECKS, LearnerOptions, MetricCheck
from atikt.priors import PriorModel, PriorsInput, fit_prior_model, fit_prior_models
from atikt.strategies import NO_CHOICE, ObjectFit, strategy_names

if TYPE_CHECKING:
    import builtins

    from atikt.transfer import PriorChoice, TransferGPC

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
Observe = Callable[[int, str], RawFeatures]
"""``observe(new_object_index, action) -> RawFeatures`` of one performed action."""
Capacity = Mapping[tuple[int, str], int]
"""(new object index, action) -> how many observations it can give in all."""

TRANSFER_MODES: Final = strategy_names()
"""The registered transfer strategies' names (prediction, optimization, density, evidence, none)."""
__all__ = [
    "METRIC_CHECKS",
    "TRANSFER_MODES",
    "ActionState",
    "ActiveLearner",
    "LearnerOptions",
    "MetricCheck",
    "PriorModel",
    "PriorsInput",
    "StepRecord",
    "entropy",
    "fit_prior_model",
    "fit_prior_models",
    "separation",
]


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
    pairs = SeparationPairs.of(X, labels, aux)
    return -np.inf if pairs is None else pairs.score(kernel)


@dataclass(frozen=True, slots=True)
class SeparationPairs:
    """The observation pairs :func:`separation` compares, gathered once for several kernels.

    The old objects' kept observations and the new objects' are stacked, so one kernel call
    gives every pair (one call instead of one per old object and one for the new objects: at
    these sizes the calls, not their arithmetic, are the cost); each kernel value depends on
    its two rows only, so the values are those of separate calls.

    The squared distances of those pairs are kept per column slice once a kernel of RBF
    parts has needed them, so that the next kernel on the same slices (the metric check
    scores two) only exponentiates them: the values are those of a kernel call on ``rows``.

    Attributes:
        rows: The kept observations of every old object, then ``X``.
        first: ``X``'s first row (the kernel's variance there scales its correlations).
        repeats: Row and column indices into the stacked kernel of the repeat pairs.
        between: Those of the pairs of different new objects, in row-major order.
    """

    rows: FloatArray
    first: FloatArray
    repeats: tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]
    between: tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]
    _distances: dict[tuple[int | None, ...], tuple[FloatArray, FloatArray]] = field(
        default_factory=dict, repr=False, compare=False
    )

    @classmethod
    def of(
        cls, X: FloatArray, labels: IntArray, aux: Mapping[int, FloatArray]
    ) -> SeparationPairs | None:
        """Gather the pairs.

        Returns:
            None without two observations of some old object or two new objects.
        """
        # at most SEPARATION_REPEATS evenly spaced observations per old object: the pairs grow
        # with the square of their number (20 objects x 100 observations: 10 ms a call, 1.4 ms
        # with the cap), and a few hundred pairs per object estimate a rank statistic well
        kept = [obs[_spread_rows(len(obs))] for obs in aux.values()]
        rows, columns, start = [], [], 0
        for obs in kept:
            upper = _upper_pairs(len(obs))
            rows.append(upper[0] + start)
            columns.append(upper[1] + start)
            start += len(obs)
        pairs = _upper_pairs(len(labels))  # the pairs of X in row-major order, as np.nonzero
        differ = labels[pairs[0]] != labels[pairs[1]]
        between = pairs[0][differ], pairs[1][differ]
        if not any(r.size for r in rows) or between[0].size == 0:
            return None
        return cls(
            np.vstack([*kept, X]),
            X[:1],
            (np.concatenate(rows), np.concatenate(columns)),
            (between[0] + start, between[1] + start),
        )

    def score(self, kernel: ModalityKernel) -> float:
        """:func:`separation` of ``kernel``."""
        scale = float(kernel.diag(self.first)[0])
        values = self._pair_values(kernel)
        if values is None:
            K = kernel(self.rows)
            values = K[self.repeats], K[self.between]
        pooled = np.sort(values[0] / scale)
        between = values[1] / scale
        below = np.searchsorted(pooled, between, side="left")
        above = np.searchsorted(pooled, between, side="right")
        return float(np.mean(1.0 - (below + above) / (2.0 * pooled.size)))

    def _pair_values(self, kernel: ModalityKernel) -> tuple[FloatArray, FloatArray] | None:
        """The kernel at the repeat pairs and at the between pairs, from the kept distances.

        None for another kernel than a weighted sum of RBFs on column slices.
        """
        # the type itself: callers may pass other kernels (the scikit-learn reference does)
        if kernel.__class__ is not ModalityKernel:
            return None
        if not all(type(part) is SliceRBF for part in kernel.parts):
            return None
        repeats, between = [], []
        for part in kernel.parts:
            columns = part.columns
            key = (columns.start, columns.stop, columns.step)
            if key not in self._distances:
                D = part.sq_dist(self.rows)
                self._distances[key] = D[self.repeats], D[self.between]
            repeats.append(self._distances[key][0])
            between.append(self._distances[key][1])
        at_repeats, at_between = kernel.from_sq_dists(repeats), kernel.from_sq_dists(between)
        if at_repeats is None or at_between is None:  # cannot happen: every part is an RBF
            return None
        return at_repeats, at_between


@functools.cache
def _spread_rows(n: int) -> npt.NDArray[np.intp]:
    """Return at most SEPARATION_REPEATS evenly spaced row indices of ``n`` rows (read only)."""
    rows = np.linspace(0, n - 1, min(n, SEPARATION_REPEATS)).astype(int)
    rows.flags.writeable = False
    return rows


@functools.cache
def _upper_pairs(n: int) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    """Return the indices of the strict upper triangle of an (n, n) matrix (read only).

    Cached: :func:`separation` needs them for every old object at every update, and numpy
    builds them through an (n, n) mask each time (a tenth of a millisecond apiece).
    """
    rows, columns = np.triu_indices(n, 1)
    rows.flags.writeable = columns.flags.writeable = False
    return rows, columns


def entropy(p: FloatArray) -> FloatArray:
    """Shannon entropy in nats of each row of ``p`` (m, k); ``0 log 0 = 0``."""
    logs = np.log(np.where(p > 0, p, 1.0))
    return np.asarray(-(p * logs).sum(axis=1), dtype=np.float64)


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
        metrics: Whether every new object's classifier of the action was fitted under a
            hyperprior centred on the old objects' kernel (metric transfer).
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
    metrics: tuple[bool, ...]
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
            "metrics": list(self.metrics),
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
        metrics: Per new object, whether its classifier's hyperprior is centred on the old
            objects' kernel (metric transfer) in the current update.
        gated: Per new object, whether the transfer gate (``transfer_from``, the strategy's
            ``borrows_initial``) kept its classifier from borrowing in the current update.
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
    metrics: list[bool] = field(default_factory=list)
    gated: list[bool] = field(default_factory=list)
    uncertainty: FloatArray = field(default_factory=lambda: np.zeros(0))
    prior_stacks: dict[int, StackedFeatures] | None = None
    prior_probabilities: FloatArray | None = None


def _group_means(probabilities: FloatArray | None, labels: IntArray) -> dict[int, FloatArray]:
    """The old models' mean score of each new object's observations, by object."""
    if probabilities is None:
        return {}
    means = {}
    for o in np.unique(labels).tolist():  # each mean as ndarray.mean computes it (sum / count)
        rows = probabilities[labels == o]
        means[o] = rows.sum(axis=0) / rows.shape[0]
    return means


def _rivals(means: Mapping[int, FloatArray], obj: int) -> tuple[FloatArray, ...]:
    """The old models' mean score of each other new object's observations (object order)."""
    return tuple(mean for o, mean in means.items() if o != obj)


class ActiveLearner:
    """ATIKT active learner of new objects, optionally transferring old objects' observations.

    Args:
        actions: Action ids, e.g. ``["P1", "P2", "S1", "S2", "S3", "S4", "C1"]``.
        n_new_objects: Number of new objects (indices ``0 .. n_new_objects - 1``).
        observe: ``observe(object_index, action) -> RawFeatures``: performs (or replays) an
            action and returns its raw features.
        capacity: (object index, action) -> how many observations the pair can give in all,
            the initial one included (e.g. a finite pool of recordings; a pair not named gives
            only the initial one); decisions only consider pairs below it, and the learner is
            done when none is left. None: every pair can always give another (a rig).
        priors: Action -> old-object label -> raw observations, or action -> a
            :class:`PriorModel` from :func:`fit_prior_models` (fitted once for many
            learners). Ignored by a strategy that does not transfer (the baseline).
        options: Every other option (:class:`~atikt.options.LearnerOptions`: budget,
            exploration, the transfer strategy with its own thresholds, hyperpriors, metric
            transfer, kernels, search limits). None: the defaults.
        random_state: Seed of every random choice (exploration, restarts).
        **overrides: Options changed from ``options`` by name, a convenience for
            ``options.replace(...)``: ``ActiveLearner(..., transfer="none", budget=10)``.

    Attributes:
        options: The options in use.
        strategy: ``options.transfer``, the transfer strategy.
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
        capacity: Capacity | None = None,
        priors: PriorsInput | None = None,
        options: LearnerOptions | None = None,
        random_state: RandomState = None,
        **overrides: Any,  # noqa: ANN401 (any option of LearnerOptions)
    ) -> None:
        """Store and validate the parameters; see the class docstring.

        Raises:
            AtiktError: A parameter is out of range or unknown; the message names it.
        """
        self.actions = tuple(actions)
        self.n_new_objects = n_new_objects
        self.observe = observe
        self.capacity = capacity
        self.priors = priors
        base = LearnerOptions() if options is None else options
        self.options = base.replace(**overrides) if overrides else base
        self.strategy = self.options.transfer
        self.random_state = random_state
        problems = []
        if len(set(self.actions)) != len(self.actions) or not self.actions:
            problems.append(f"actions={list(self.actions)} must be non-empty and distinct")
        if self.n_new_objects < 2:  # noqa: PLR2004
            problems.append(f"n_new_objects={self.n_new_objects} must be >= 2")
        if problems:
            raise AtiktError("; ".join(problems))

    # ----------------------------------------------------------------------------- state

    @property
    def done(self) -> bool:
        """True when the budget is spent or the models stopped improving."""
        if not hasattr(self, "history_"):
            return False
        return (
            len(self.history_) >= self.options.budget or self._stalled() or not self._candidates()
        )

    def _candidates(self) -> list[int]:
        """Flat indices (action-major) of the (action, object) pairs that can be observed."""
        pairs = range(len(self.actions) * self.n_new_objects)
        if self.capacity is None:
            return list(pairs)
        n, capacity, served = self.n_new_objects, self.capacity, self._served
        return [
            i
            for i in pairs
            if served.get(key := (i % n, self.actions[i // n]), 0) < capacity.get(key, 1)
        ]

    def _stalled(self) -> bool:
        """True after ``patience`` steps without the mean UNC improving by ``min_improvement``."""
        patience = self.options.patience
        if patience is None or len(self.history_) < patience:
            return False
        means = [self._initial_mean_entropy, *(r.mean_entropy for r in self.history_)]
        best_before = min(means[:-patience])
        return min(means[-patience:]) > best_before - self.options.min_improvement

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
        self._served: dict[tuple[int, str], int] = {}
        priors = self._prior_models()
        self.states_: dict[str, ActionState] = {}
        for action in self.actions:
            for obj in range(self.n_new_objects):
                self._record(action, obj, self._observe(obj, action), priors)
        for action in self.actions:
            self._update(
                action, n_restarts=self.options.n_restarts, max_iter=self.options.max_iter_initial
            )
        self.uncertainty_ = np.vstack([self.states_[a].uncertainty for a in self.actions])
        self._initial_mean_entropy = float(self.uncertainty_.mean())

    def _prior_models(self) -> dict[str, PriorModel]:
        """Fit (or take) the prior models of the actions; none for the baseline."""
        if not self.strategy.transfers or not self.priors:
            return {}
        given = {a: p for a, p in self.priors.items() if isinstance(p, PriorModel)}
        raw = {a: p for a, p in self.priors.items() if not isinstance(p, PriorModel)}
        fitted = fit_prior_models(
            raw,
            amplitude=self.options.amplitude,
            n_thermal_components=self.options.n_thermal_components,
            n_restarts=self.options.n_restarts,
            parts=self.options.parts,
            random_state=self._rng.spawn(1)[0],  # leaves the decisions' stream untouched
        )
        models = {**given, **fitted}
        for action, prior in models.items():
            self.strategy.check_prior(action, prior)
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
        self._served[obj, action] = self._served.get((obj, action), 0) + 1
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
            prior = priors.get(action)
            state = ActionState(kind=observation.kind, prior=prior)
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
        explored = bool(self._rng.random() < self.options.eps_explore)
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
        self._update(action, n_restarts=0, max_iter=self.options.max_iter_step, changed=obj)
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
            metrics=tuple(state.metrics),
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
        transformer = FeatureTransformer(n_thermal_components=self.options.n_thermal_components)
        X = transformer.fit_transform(state.observations)
        labels = np.asarray(state.labels)
        auxiliary = self._auxiliary(state, transformer)
        if not state.models:
            n = self.n_new_objects
            state.models, state.choices = [], [NO_CHOICE] * n
            state.thetas, state.rhos = [None] * n, [{} for _ in range(n)]
            state.metrics = [False] * n
            state.gated = [False] * n
        seeds = spawn_seeds(self._rng, self.n_new_objects)
        probabilities = self._prior_probabilities(state)
        means = _group_means(probabilities, labels)  # every object's rivals come from these
        models = []
        options = self.options
        initial = modality_kernel(
            transformer.slices_,
            amplitude=options.amplitude,
            bias=1.0 if options.bias else None,
            parts=options.parts,
        )
        base, base_sd = initial, options.hyper_sd
        counts = np.bincount(labels, minlength=self.n_new_objects)
        prior_sd = base_sd
        if options.metric_until is None or counts.min() <= options.metric_until:  # someone uses it
            initial, prior_sd = self._metric(prior, initial, X, labels, auxiliary)
        for obj, seed in enumerate(seeds):
            centre, sd = initial, prior_sd
            if options.metric_until is not None and counts[obj] > options.metric_until:
                centre, sd = base, base_sd  # enough own observations: the data decide
            # too few of its own observations to tell what is related; or the initial round,
            # every object seen once, where the strategy does not borrow on it
            closed = counts[obj] < options.transfer_from or (
                counts.max() <= 1 and not self.strategy.borrows_initial()
            )
            kernel = centre  # kernels are immutable: with_theta returns a new one
            theta = state.thetas[obj]
            if theta is not None and theta.shape == (kernel.n_params,):
                kernel = kernel.with_theta(theta)
            y = (labels == obj).astype(np.float64)
            keep = changed is not None and obj != changed and self.strategy.keeps()
            keep = keep and not state.gated[obj]  # a choice the gate made is made again
            choice, model = self._fit_object(
                kernel,
                X,
                y,
                known=state.choices[obj] if keep and not closed else None,
                related=None if probabilities is None else probabilities[labels == obj],
                rivals=_rivals(means, obj),
                prior=None if closed else prior,
                auxiliary={} if closed else auxiliary,
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
            state.metrics[obj] = centre is not base
            state.gated[obj] = closed
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
        options = self.options
        if options.metric_sd is None or prior is None or prior.model is None:
            return initial, options.hyper_sd
        centre = prior.median_theta()
        if centre is None or centre.shape != initial.theta.shape:  # e.g. bias in one only
            return initial, options.hyper_sd
        metric = initial.with_theta(centre)
        check = options.metric_check
        passed = check == "none"
        if not passed and check in {"separation", "either"}:
            pairs = SeparationPairs.of(X, labels, aux)  # gathered once for both kernels
            passed = pairs is None or pairs.score(metric) >= pairs.score(initial)
        if not passed and check in {"evidence", "either"}:
            # both kernels have the same column slices: their squared distances are shared
            rbf = all(type(part) is SliceRBF for part in initial.parts)
            distances = [part.sq_dist(X) for part in initial.parts] if rbf else []
            passed = self._evidence(metric, X, labels, distances) >= self._evidence(
                initial, X, labels, distances
            )
        return (metric, options.metric_sd) if passed else (initial, options.hyper_sd)

    def _evidence(
        self,
        kernel: ModalityKernel,
        X: FloatArray,
        labels: IntArray,
        distances: Sequence[FloatArray] = (),
    ) -> float:
        """Sum over the new objects of their one-vs-all log evidence at ``kernel``.

        The covariance is the same for every object (only the labels differ): computed once,
        as :class:`BinaryGPC` with ``optimize=False`` would compute it for each, and the
        objects' Laplace approximations found together (:func:`~atikt.gpc.laplace_evidences`).
        ``distances``: each part's squared distances of ``X`` (:meth:`SliceRBF.sq_dist`),
        shared by the kernels of one check; empty: computed here.
        """
        gpc = BinaryGPC(kernel, optimize=False)
        shared = kernel.from_sq_dists(distances) if distances else None
        K = add_to_diagonal(kernel(X) if shared is None else shared, gpc.jitter)
        Y = (labels == np.arange(self.n_new_objects)[:, None]).astype(np.float64)
        evidences = laplace_evidences(K, Y, max_iter=gpc.newton_max_iter, tol=gpc.newton_tol)
        return float(sum(evidences.tolist()))  # summed in order, as one by one

    def _prior_probabilities(self, state: ActionState) -> FloatArray | None:
        """The old models' score of every observation (model prediction or density approach).

        The old objects' one-vs-all probabilities (prediction) or the tail probabilities under
        their feature distributions (density); only the observations not scored before are
        scored.
        """
        prior = state.prior
        if prior is None:
            return None
        scorer = self.strategy.scorer(prior)
        if scorer is None:
            return None
        done = 0 if state.prior_probabilities is None else state.prior_probabilities.shape[0]
        if done < len(state.observations):
            features = prior.transformer.transform(state.observations[done:])
            new = scorer(features)
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
        rivals: tuple[FloatArray, ...],
        previous: TransferGPC | None,
        centre: FloatArray,
        prior_sd: float | None,
        n_restarts: int,
        max_iter: int,
        seed: int,
    ) -> tuple[PriorChoice, TransferGPC]:
        """Let the strategy choose where from / how much to transfer and fit one classifier."""
        # every classifier fitted here searches its hyperparameters the same way
        search: dict[str, Any] = {
            "n_restarts": n_restarts,
            "max_iter": max_iter,
            "prior_sd": prior_sd,
            "prior_mean": centre,
            "random_state": seed,
        }
        fit = ObjectFit(
            kernel, X, y, prior, auxiliary, known, related, rho_starts, previous, search, rivals
        )
        return self.strategy.fit(fit)

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

    def metric_share(self) -> float:
        """Share of the new objects' classifiers (all actions) fitted under metric transfer.

        The classifiers whose hyperprior is centred on the old objects' kernel in the latest
        update of their action, in [0, 1]; 0 without priors or with ``metric_sd=None``.
        """
        self._check_initialised()
        used = [m for state in self.states_.values() for m in state.metrics]
        return sum(used) / len(used) if used else 0.0

    def score(self, test: Mapping[str, tuple[Sequence[RawFeatures], npt.ArrayLike]]) -> float:
        """Accuracy of all actions together: the mean over actions of per-action accuracy."""
        scores = self.score_per_action(test)
        if not scores:
            msg = "no test data; pass {action: (observations, labels)}"
            raise AtiktError(msg)
        return float(np.mean(list(scores.values())))
