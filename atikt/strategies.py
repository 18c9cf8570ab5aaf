"""Transfer strategies: where from and how much each new object's classifier borrows.

A strategy is a frozen object that owns its options and their checks; the active learner
(:class:`~atikt.ActiveLearner`) asks it, for every new object and action, to choose the old
objects to borrow from and to fit the classifier (:meth:`TransferStrategy.fit`). Strategies
are registered by name (:func:`register_strategy`) and built from a name and options
(:func:`transfer_strategy`), so a new one is one class and one registration; the learner
compares no names.

Registered here: ``prediction`` (the thesis's model prediction approach), ``optimization``
(rho by marginal likelihood, the thesis's model optimisation approach), ``density``
(open-set score of each old object's feature distribution), ``evidence`` (the dependent GP's
evidence gain) and ``none`` (the baseline without transfer).
"""

from __future__ import annotations

import dataclasses
import numbers
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Final

import numpy as np
import numpy.typing as npt

from atikt.errors import AtiktError
from atikt.kernels import ModalityKernel
from atikt.transfer import (
    PriorChoice,
    TransferGPC,
    check_threshold,
    choose_by_density,
    choose_by_evidence,
    choose_by_optimization,
    choose_by_relatedness,
    evidence_gains,
    held_out_threshold,
)

if TYPE_CHECKING:
    from atikt.priors import PriorModel

FloatArray = npt.NDArray[np.float64]
NO_CHOICE: Final = PriorChoice(None, 0.0, (), ())
"""The choice of no transfer."""
Scorer = Callable[[FloatArray], FloatArray]
"""Scores observations (in the prior's feature space) against each old object, (m, n_old)."""


@dataclass(slots=True)
class ObjectFit:
    """What one new object's classifier of one action is fitted from (one update).

    Attributes:
        kernel: Base kernel (starting hyperparameters).
        X: The new objects' observations of the action, shape (n, d).
        y: 1 for this new object, 0 for the others, shape (n,).
        prior: The old objects' model of the action (None: no priors).
        auxiliary: Old-object label -> its observations in the current feature space.
        known: The previous choice, kept when only other objects' observations changed
            (strategies with ``keeps_choice``); None: choose again.
        related: The old objects' score (:meth:`TransferStrategy.scorer`) of this object's
            observations, shape (m, n_old); None: not scored.
        rho_starts: Warm-start rho per old object (updated by strategies that learn rho).
        previous: The object's classifier of the previous update (warm start).
        search: Options of every hyperparameter search (``n_restarts``, ``max_iter``,
            ``prior_sd``, ``prior_mean``, ``random_state``).
        rivals: The same scores' mean over each other new object's observations of the
            action, shape (n_old,) each (strategies that keep a source to one new object).
    """

    kernel: ModalityKernel
    X: FloatArray
    y: FloatArray
    prior: PriorModel | None
    auxiliary: Mapping[int, FloatArray]
    known: PriorChoice | None = None
    related: FloatArray | None = None
    rho_starts: dict[int, float] = field(default_factory=dict)
    previous: TransferGPC | None = None
    search: dict[str, Any] = field(default_factory=dict)
    rivals: tuple[FloatArray, ...] = ()

    def fit_with(self, choice: PriorChoice) -> TransferGPC:
        """Fit the classifier transferring from ``choice``'s sources (plain without)."""
        aux: FloatArray | list[FloatArray] | None = None
        rho: float | tuple[float, ...] = choice.rho
        if len(choice.sources) > 1:
            aux, rho = [self.auxiliary[s] for s in choice.sources], choice.rhos
        elif choice.source is not None:
            aux = self.auxiliary[choice.source]
        return TransferGPC(self.kernel, rho=rho, previous=self.previous, **self.search).fit(
            self.X, self.y, aux
        )


@dataclass(frozen=True, slots=True)
class TransferStrategy:
    """Base of the transfer strategies: no transfer unless a subclass chooses sources.

    Class attributes (not options):
        name: The registered name.
        transfers: False: the learner fits no prior models (the baseline).
        keeps_choice: A new object's choice depends only on its own observations and the
            fixed prior models, so it is kept while only other objects' observations change.
        min_old_objects: Old objects the strategy needs in an action's priors.
    """

    name: ClassVar[str] = ""
    transfers: ClassVar[bool] = True
    keeps_choice: ClassVar[bool] = False
    min_old_objects: ClassVar[int] = 1

    def keeps(self) -> bool:
        """Whether a new object's choice is kept while only other objects' observations change.

        ``keeps_choice``, unless the strategy's options make a choice depend on the others.
        """
        return self.keeps_choice

    def borrows_initial(self) -> bool:
        """Whether the initial round (every new object seen once) may borrow observations."""
        return True

    def options(self) -> dict[str, Any]:
        """The strategy's own options by name (as given to :func:`transfer_strategy`)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def as_dict(self) -> dict[str, Any]:
        """Name and options, for results files (:func:`transfer_strategy` reads it back)."""
        return {"name": self.name, **self.options()}

    def check_prior(self, action: str, prior: PriorModel) -> None:
        """Refuse a prior model the strategy cannot use.

        Raises:
            AtiktError: Never here; subclasses name the action and the fix.
        """
        del action, prior

    def scorer(self, prior: PriorModel) -> Scorer | None:
        """Per-observation relatedness of the fixed prior models (cached by the learner).

        Returns:
            None: the strategy scores nothing per observation.
        """
        del prior
        return None

    def choose(self, fit: ObjectFit) -> PriorChoice:
        """Choose the sources of one new object's classifier (no transfer here)."""
        del fit
        return NO_CHOICE

    def fit(self, fit: ObjectFit) -> tuple[PriorChoice, TransferGPC]:
        """Choose (or keep) the sources and fit one new object's classifier.

        Returns:
            The choice and the fitted classifier.
        """
        choice = NO_CHOICE
        if fit.known is not None:
            choice = fit.known
        elif fit.prior is not None:
            choice = self.choose(fit)
        return choice, fit.fit_with(choice)


def _check_sources(max_sources: int) -> None:
    """Refuse fewer than one source at once.

    Raises:
        AtiktError: ``max_sources < 1``.
    """
    if max_sources < 1:
        msg = f"max_sources={max_sources} must be >= 1"
        raise AtiktError(msg)


@dataclass(frozen=True, slots=True)
class NoTransfer(TransferStrategy):
    """The baseline: the same loop without prior knowledge."""

    name: ClassVar[str] = "none"
    transfers: ClassVar[bool] = False


@dataclass(frozen=True, slots=True)
class Prediction(TransferStrategy):
    """The model prediction approach: the old objects' one-vs-all models score the new object.

    Attributes:
        eps_neg1: Smallest mean probability for a transfer, in (0.5, 1].
        max_sources: Most old objects transferred to one classifier at once (the most related
            ones passing the threshold, one ``rho`` each); 1 is the thesis's single source.
        held_out_quantile: With three or more old objects, the threshold after ``n``
            observations is raised to this quantile of the scores the old objects, each left
            out, give the others they are unrelated to from ``n`` of their observations
            (:func:`atikt.transfer.held_out_threshold`); None: ``eps_neg1`` always (the
            thesis).
        exclusive: An old object chosen by several new objects of an action is the source of
            the one it is most related to only (ties: each keeps it); the others do without it.
            Its observations, borrowed as positives by several new objects' classifiers,
            would make each claim the others' observations. False: each new object chooses
            alone (the thesis).
        min_tail: Open-set gate: an old object is admitted only where the new object's
            observations lie within its feature distribution, their mean tail probability
            under it (``transfer="density"``'s score) at least ``min_tail``. A one-vs-all
            classifier extrapolates: an observation far from every old object can score 0.9
            for the one it is least far from. None: no gate (the thesis).
        borrow_initial: Whether the initial round (one observation of every new object of the
            action) borrows. The old models' probability of one observation does not tell a
            related old object from chance (a dissimilar one scores 0.6-0.9 as readily), and
            with every object seen once nothing else offsets a wrong borrowing; from the first
            step on, objects seen more often than others are what the borrowed observations
            balance. False: the initial fits borrow no observations (the old objects' kernel
            as metric transfer decides); True: the thesis.
    """

    name: ClassVar[str] = "prediction"
    keeps_choice: ClassVar[bool] = True
    min_old_objects: ClassVar[int] = 2  # one-vs-all models of the old objects
    eps_neg1: float = 0.6
    max_sources: int = 1
    held_out_quantile: float | None = None
    exclusive: bool = False
    min_tail: float | None = None
    borrow_initial: bool = True

    def borrows_initial(self) -> bool:
        """``borrow_initial``."""
        return self.borrow_initial

    def keeps(self) -> bool:
        """Exclusive sources depend on the other new objects' observations: chosen again."""
        return not self.exclusive

    def __post_init__(self) -> None:
        """Check the options (one error naming the option)."""
        check_threshold("eps_neg1", self.eps_neg1)
        _check_sources(self.max_sources)
        q = self.held_out_quantile
        if q is not None and not 0.0 < q < 1.0:
            msg = f"held_out_quantile={q} must be None or lie in (0, 1)"
            raise AtiktError(msg)
        if self.min_tail is not None and not 0.0 <= self.min_tail < 1.0:
            msg = f"min_tail={self.min_tail} must be None or lie in [0, 1)"
            raise AtiktError(msg)

    def check_prior(self, action: str, prior: PriorModel) -> None:
        """Refuse a prior of a single old object (no one-vs-all model).

        Raises:
            AtiktError: The action's prior has one old object; names the fix.
        """
        if prior.model is None:
            msg = (
                f"action {action!r} has prior data of one old object only; the model "
                "prediction approach needs >= 2 old objects (use transfer='optimization')"
            )
            raise AtiktError(msg)

    def scorer(self, prior: PriorModel) -> Scorer | None:
        """The old models' one-vs-all probabilities (then, with ``min_tail``, the tails)."""
        model, densities = prior.model, prior.densities
        if model is None:
            return None
        if self.min_tail is None or densities is None:
            return model.predict_binary
        return lambda X: np.hstack([model.predict_binary(X), densities.tail_probabilities(X)])

    def choose(self, fit: ObjectFit) -> PriorChoice:
        """The old objects of the largest mean probability of the object's observations."""
        prior = fit.prior
        if fit.related is None or fit.related.shape[0] == 0 or prior is None:
            return NO_CHOICE
        if prior.model is None:
            return NO_CHOICE
        k = len(prior.old_objects)
        means = fit.related.sum(axis=0) / fit.related.shape[0]  # the mean, without its wrapper
        scores = means[:k]
        if means.shape[0] == 2 * k and self.min_tail is not None:  # the open-set gate
            scores = np.where(means[k:] >= self.min_tail, scores, 0.0)
        eps = self.eps_neg1
        if self.held_out_quantile is not None and prior.held_out:
            n = fit.related.shape[0]
            eps = held_out_threshold(prior.held_out, eps, n, self.held_out_quantile)
        choice = choose_by_relatedness(scores, prior.model.classes_, eps, self.max_sources)
        if self.exclusive and choice.source is not None:
            column = prior.model.classes_.tolist().index(choice.source)
            mine = float(scores[column])
            for rival in fit.rivals:
                if int(np.argmax(rival[:k])) == column and rival[column] > mine:
                    return PriorChoice(None, 0.0, choice.candidates, choice.scores)
        return choice


@dataclass(frozen=True, slots=True)
class Density(TransferStrategy):
    """Open-set relatedness: the tail probability under each old object's distribution.

    Attributes:
        eps_density: Smallest open-set score for a transfer, in (0, 1].
        density_rho_scale: ``rho = min(1, density_rho_scale * score)``, > 0.
        max_sources: Most old objects transferred at once.
    """

    name: ClassVar[str] = "density"
    keeps_choice: ClassVar[bool] = True
    eps_density: float = 0.1
    density_rho_scale: float = 2.0
    max_sources: int = 1

    def __post_init__(self) -> None:
        """Check the options (one error naming the option)."""
        check_threshold("eps_density", self.eps_density, low=0.0)
        if not self.density_rho_scale > 0:
            msg = f"density_rho_scale={self.density_rho_scale} must be > 0"
            raise AtiktError(msg)
        _check_sources(self.max_sources)

    def scorer(self, prior: PriorModel) -> Scorer | None:
        """Each old object's tail probabilities."""
        return None if prior.densities is None else prior.densities.tail_probabilities

    def choose(self, fit: ObjectFit) -> PriorChoice:
        """The old objects of the largest mean open-set score."""
        prior = fit.prior
        if fit.related is None or fit.related.shape[0] == 0 or prior is None:
            return NO_CHOICE
        if prior.densities is None:
            return NO_CHOICE
        scores = fit.related.mean(axis=0)
        classes = prior.densities.classes
        return choose_by_density(
            scores, classes, self.eps_density, self.max_sources, self.density_rho_scale
        )


@dataclass(frozen=True, slots=True)
class Evidence(TransferStrategy):
    """The dependent GP's evidence gain of each old object for the new object's labels.

    Attributes:
        eps_evidence: Smallest evidence gain (nats) for a transfer, finite.
        evidence_rho: The transfer coefficient the gain is evaluated at and transferred with,
            in (0, 1].
        max_sources: Most old objects transferred at once.
    """

    name: ClassVar[str] = "evidence"
    keeps_choice: ClassVar[bool] = True
    eps_evidence: float = 0.0
    evidence_rho: float = 0.9
    max_sources: int = 1

    def __post_init__(self) -> None:
        """Check the options (one error naming the option)."""
        if not 0.0 < self.evidence_rho <= 1.0:
            msg = f"evidence_rho={self.evidence_rho} must lie in (0, 1]"
            raise AtiktError(msg)
        if not np.isfinite(self.eps_evidence):
            msg = f"eps_evidence={self.eps_evidence} must be finite"
            raise AtiktError(msg)
        _check_sources(self.max_sources)

    def fit(self, fit: ObjectFit) -> tuple[PriorChoice, TransferGPC]:
        """Evaluate the gains at the hyperparameters the labels give alone, then transfer."""
        if fit.known is not None or fit.prior is None or not fit.auxiliary:
            return TransferStrategy.fit(self, fit)
        plain = TransferGPC(fit.kernel, previous=fit.previous, **fit.search).fit(fit.X, fit.y)
        rho = self.evidence_rho
        gains = evidence_gains(plain.base_kernel_, fit.X, fit.y, fit.auxiliary, rho)
        choice = choose_by_evidence(
            gains, tuple(fit.auxiliary), self.eps_evidence, self.max_sources, rho
        )
        if choice.source is None:
            return choice, plain
        fitted = plain.base_kernel_
        assert isinstance(fitted, ModalityKernel)  # noqa: S101 - the plain fit of kernel
        fit.kernel, fit.previous = fitted, plain
        return choice, fit.fit_with(choice)


@dataclass(frozen=True, slots=True)
class Optimization(TransferStrategy):
    """The model optimisation approach: rho learned by marginal likelihood per old object.

    Attributes:
        eps_neg2: Smallest learned ``rho`` for a transfer, in (0, 1].
    """

    name: ClassVar[str] = "optimization"
    eps_neg2: float = 0.6

    def __post_init__(self) -> None:
        """Check the options (one error naming the option)."""
        check_threshold("eps_neg2", self.eps_neg2, low=0.0)

    def fit(self, fit: ObjectFit) -> tuple[PriorChoice, TransferGPC]:
        """Fit one classifier per old object with learned rho; keep the largest rho's."""
        if fit.prior is None:
            return TransferStrategy.fit(self, fit)
        choice, model = choose_by_optimization(
            fit.kernel, fit.X, fit.y, fit.auxiliary, eps_neg2=self.eps_neg2,
            rho0=fit.rho_starts, **fit.search,
        )  # fmt: skip
        fit.rho_starts.update(zip(choice.candidates, choice.scores, strict=True))
        return choice, model


_REGISTRY: dict[str, type[TransferStrategy]] = {}


def register_strategy(strategy: type[TransferStrategy]) -> type[TransferStrategy]:
    """Register a strategy class under its ``name`` (usable as a class decorator).

    Raises:
        AtiktError: No name, or the name is taken by another class.
    """
    taken = _REGISTRY.get(strategy.name)
    if not strategy.name or (taken is not None and taken is not strategy):
        msg = f"transfer strategy {strategy.__name__}: name {strategy.name!r} is empty or taken"
        raise AtiktError(msg)
    _REGISTRY[strategy.name] = strategy
    return strategy


for _strategy in (Prediction, Optimization, Density, Evidence, NoTransfer):
    register_strategy(_strategy)


def strategy_names() -> tuple[str, ...]:
    """The registered strategies' names, in registration order."""
    return tuple(_REGISTRY)


def strategy_options() -> dict[str, tuple[str, ...]]:
    """Each option name and the strategies that own it."""
    owners: dict[str, list[str]] = {}
    for name, cls in _REGISTRY.items():
        for f in dataclasses.fields(cls):
            owners.setdefault(f.name, []).append(name)
    return {option: tuple(names) for option, names in owners.items()}


def transfer_strategy(name: str, **options: Any) -> TransferStrategy:  # noqa: ANN401 (per strategy)
    """Build the strategy registered as ``name`` with its options.

    Args:
        name: A registered name (:func:`strategy_names`).
        **options: The strategy's own options (e.g. ``eps_neg1`` of ``prediction``).

    Returns:
        The strategy; its options are checked.

    Raises:
        AtiktError: An unknown name, or an option the strategy does not have (the message
            names the strategies that have it).
    """
    cls = _REGISTRY.get(name)
    if cls is None:
        msg = f"transfer={name!r} must be one of {strategy_names()}"
        raise AtiktError(msg)
    own = {f.name for f in dataclasses.fields(cls)}
    foreign = sorted(set(options) - own)
    if foreign:
        owners = strategy_options()
        where = "; ".join(f"{o}: {', '.join(owners.get(o, ())) or 'no strategy'}" for o in foreign)
        msg = f"transfer {name!r} has no option {', '.join(foreign)} (owned by {where})"
        raise AtiktError(msg)
    if problems := [
        p
        for f in dataclasses.fields(cls)
        if f.name in options
        if (p := _type_problem(f.name, options[f.name], f.default))
    ]:
        raise AtiktError("; ".join(problems))  # before the ranges: 'x' < 0.5 is a TypeError
    return cls(**options)


def _type_problem(name: str, value: object, default: object) -> str:
    """Return why ``value`` is not of its option's type (the default's), or empty."""
    boolean = isinstance(value, bool | np.bool_)
    if isinstance(default, bool):
        ok, kind = boolean, "true or false"
    elif isinstance(default, int):  # numpy's integers too (numbers.Integral)
        ok, kind = isinstance(value, numbers.Integral) and not boolean, "a whole number"
    elif isinstance(default, float) or default is None:
        number = isinstance(value, numbers.Real) and not boolean
        ok = number or (default is None and value is None)
        kind = "a number" if default is not None else "a number or None"
    else:
        return ""
    return "" if ok else f"{name}={value!r} must be {kind}"
