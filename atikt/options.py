"""The active learner's options as one frozen, checked object.

:class:`LearnerOptions` holds every option of :class:`~atikt.ActiveLearner` except its data
(actions, objects, the observe callback, priors) and its seed. It is built once (from keywords,
a mapping, or a results file's ``as_dict``), checked once, and carried whole; the transfer
strategy inside it (:mod:`atikt.strategies`) owns its own options.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Final, Literal

import numpy as np

from atikt.errors import AtiktError
from atikt.kernels import PART_KERNELS
from atikt.strategies import (
    Prediction,
    TransferStrategy,
    strategy_options,
    transfer_strategy,
)

MetricCheck = Literal["evidence", "separation", "either", "none"]
METRIC_CHECKS: Final = ("evidence", "separation", "either", "none")


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


def _positive_or_none(name: str, value: float | None) -> str | None:
    """A problem when ``value`` is neither None nor a finite positive number."""
    if value is None or 0.0 < value < math.inf:
        return None
    return f"{name}={value} must be None or > 0"


@dataclass(frozen=True, slots=True, kw_only=True)
class LearnerOptions:
    """Every option of the active learner (see :class:`~atikt.ActiveLearner`).

    Attributes:
        budget: Steps (observations after the initial one per object and action), >= 0.
        eps_explore: Probability of a uniformly random (object, action), in [0, 1].
        transfer: The transfer strategy with its own options (:func:`transfer_strategy`);
            ``NoTransfer`` is the baseline.
        hyper_sd: Sd of a Gaussian prior on every new-object classifier's log
            hyperparameters around the initial kernel; None: maximum likelihood (the thesis).
        metric_sd: Metric transfer: with prior models of two or more old objects, the
            classifiers start from the old objects' kernel hyperparameters (their median) with
            a hyperprior of this sd around them. None: none (the thesis).
        metric_check: When the old objects' kernel is used: ``evidence``, ``separation``,
            ``either`` or ``none`` (always); True / False mean evidence / none.
        metric_until: The old objects' kernel centres a new object's hyperprior while it has at
            most this many observations of the action; None: always.
        transfer_from: A new object's classifier of an action borrows no old object's
            observations until the object has this many observations of the action; 1: from
            the first (the thesis). The old objects' kernel (metric transfer) follows
            ``metric_*``.
        bias: Learn a constant ``b^2`` in the kernel (a bias of the latent function).
        patience: Stop after this many steps without the mean ``UNC`` improving by
            ``min_improvement``; None: run the whole budget.
        min_improvement: See ``patience`` (nats).
        amplitude: Learn a signal variance (False: the thesis kernel, ``|w|_1 = 1`` only).
        n_thermal_components: Thermal PCA dimensions (thesis: 10).
        n_restarts: Random restarts of each hyperparameter search at initialisation.
        max_iter_initial: Search iteration limit per start at initialisation.
        max_iter_step: Iteration limit of the warm-started search of each step.
        kernel_parts: Kernel per feature block, as (block, kernel) pairs
            (``atikt.kernels.PART_KERNELS``; RBF where not named, the thesis).
    """

    budget: int = 40
    eps_explore: float = 0.3
    transfer: TransferStrategy = field(default_factory=Prediction)
    hyper_sd: float | None = None
    metric_sd: float | None = 1.0
    metric_check: MetricCheck = "either"
    metric_until: int | None = 2
    transfer_from: int = 1
    bias: bool = False
    patience: int | None = None
    min_improvement: float = 1e-3
    amplitude: bool = True
    n_thermal_components: int = 10
    n_restarts: int = 1
    max_iter_initial: int = 30
    max_iter_step: int = 10
    kernel_parts: tuple[tuple[str, str], ...] = ()

    def __post_init__(self) -> None:
        """Normalise ``metric_check`` and check every option.

        Raises:
            AtiktError: Options out of range, all named in one line.
        """
        if problems := _type_problems(self):  # before any comparison: 'x' >= 0 is a TypeError
            raise AtiktError("; ".join(problems))
        object.__setattr__(self, "metric_check", _metric_check(self.metric_check))
        object.__setattr__(self, "bias", bool(self.bias))  # numpy's bool as Python's
        transfer: object = self.transfer  # a caller may pass a name instead of a strategy
        if isinstance(transfer, str):
            object.__setattr__(self, "transfer", transfer_strategy(transfer))
        elif not isinstance(transfer, TransferStrategy):
            msg = (
                f"transfer={self.transfer!r} must be a transfer strategy; build one with "
                "atikt.transfer_strategy(name, **options) or LearnerOptions.from_dict"
            )
            raise AtiktError(msg)
        checks = (
            (self.budget >= 0, f"budget={self.budget} must be >= 0"),
            (0.0 <= self.eps_explore <= 1.0, f"eps_explore={self.eps_explore} must lie in [0, 1]"),
            (
                self.metric_until is None or self.metric_until >= 1,
                f"metric_until={self.metric_until} must be None or >= 1",
            ),
            (self.transfer_from >= 1, f"transfer_from={self.transfer_from} must be >= 1"),
            (
                self.patience is None or self.patience >= 1,
                f"patience={self.patience} must be None or >= 1",
            ),
            (
                0.0 <= self.min_improvement < math.inf,
                f"min_improvement={self.min_improvement} must be finite and >= 0",
            ),
            (
                self.n_thermal_components >= 1,
                f"n_thermal_components={self.n_thermal_components} must be >= 1",
            ),
            (self.n_restarts >= 0, f"n_restarts={self.n_restarts} must be >= 0"),
            (
                min(self.max_iter_initial, self.max_iter_step) >= 1,
                (
                    f"max_iter_initial={self.max_iter_initial} and max_iter_step="
                    f"{self.max_iter_step} must be >= 1"
                ),
            ),
            (
                all(kind in PART_KERNELS for _, kind in self.kernel_parts),
                f"kernel_parts={list(self.kernel_parts)}: kernels must be in {PART_KERNELS}",
            ),
        )
        problems = [problem for ok, problem in checks if not ok]
        problems += [
            p
            for p in (
                _positive_or_none("hyper_sd", self.hyper_sd),
                _positive_or_none("metric_sd", self.metric_sd),
            )
            if p is not None
        ]
        if problems:
            raise AtiktError("; ".join(problems))

    @property
    def parts(self) -> dict[str, str] | None:
        """``kernel_parts`` as a mapping for the kernel builders (None: all RBF)."""
        return dict(self.kernel_parts) or None

    def replace(self, **changes: Any) -> LearnerOptions:  # noqa: ANN401 (any option)
        """A copy with some options changed (strategy options route to the strategy).

        ``transfer`` may be a name or a strategy; a strategy's own option (e.g. ``eps_neg1``)
        changes the strategy. The name of the strategy in use keeps it with its options;
        another name starts that strategy from its defaults.
        """
        if changes.get("transfer") == self.transfer.name:
            changes = {k: v for k, v in changes.items() if k != "transfer"}
        return LearnerOptions.from_dict({**self.as_dict(), **changes})

    def as_dict(self) -> dict[str, Any]:
        """Every option by name, the strategy as ``{"name": ..., **its options}`` (JSON-able)."""
        values = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        values["transfer"] = self.transfer.as_dict()
        values["kernel_parts"] = [list(pair) for pair in self.kernel_parts]
        return values

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> LearnerOptions:
        """Build from a mapping: :meth:`as_dict`'s output, a TOML table, or flat options.

        ``transfer`` is a strategy, a name, or ``{"name": ..., **options}``; a strategy's
        options may also be given flat (``{"transfer": "density", "eps_density": 0.2}``).

        Raises:
            AtiktError: An unknown option, or one the chosen strategy does not have; one line
                naming it.
        """
        own = {f.name for f in dataclasses.fields(cls)}
        owned = strategy_options()
        unknown = sorted(k for k in values if k not in own and k not in owned)
        if unknown:
            msg = (
                f"unknown learner option(s) {', '.join(unknown)}; options are "
                f"{', '.join(sorted(own | set(owned)))}"
            )
            raise AtiktError(msg)
        kwargs = {k: v for k, v in values.items() if k in own}
        flat = {k: v for k, v in values.items() if k not in own}
        transfer = kwargs.pop("transfer", None)
        kwargs["transfer"] = _strategy(transfer, flat)
        if "kernel_parts" in kwargs:
            kwargs["kernel_parts"] = _pairs(kwargs["kernel_parts"])
        return cls(**kwargs)


#: The options of each type (None allowed where the name is in ``_OPTIONAL``).
_INTEGERS = (
    "budget",
    "metric_until",
    "transfer_from",
    "patience",
    "n_thermal_components",
    "n_restarts",
    "max_iter_initial",
    "max_iter_step",
)
_NUMBERS = ("eps_explore", "hyper_sd", "metric_sd", "min_improvement")
_BOOLEANS = ("bias", "amplitude")
_OPTIONAL = ("hyper_sd", "metric_sd", "metric_until", "patience")


def _type_problems(options: LearnerOptions) -> list[str]:
    """Return the options of the wrong type, one phrase each (a TOML file may hold anything)."""
    problems = []
    for name in (*_INTEGERS, *_NUMBERS, *_BOOLEANS):
        value = getattr(options, name)
        if value is None and name in _OPTIONAL:
            continue
        boolean = isinstance(value, bool | np.bool_)
        if name in _BOOLEANS:
            ok, kind = boolean, "true or false"
        elif name in _INTEGERS:  # numpy's integers too (numbers.Integral)
            ok, kind = isinstance(value, numbers.Integral) and not boolean, "a whole number"
        else:
            ok, kind = isinstance(value, numbers.Real) and not boolean, "a number"
        if not ok:
            problems.append(f"{name}={value!r} must be {kind}")
    return problems


def _strategy(transfer: object, flat: Mapping[str, Any]) -> TransferStrategy:
    """The strategy of ``transfer`` (strategy, name, mapping or None) with ``flat`` options.

    Raises:
        AtiktError: An invalid description (one line).
    """
    if transfer is None:
        transfer = Prediction()
    if isinstance(transfer, TransferStrategy):
        if not flat:
            return transfer
        return transfer_strategy(transfer.name, **{**transfer.options(), **flat})
    if isinstance(transfer, str):
        return transfer_strategy(transfer, **flat)
    if isinstance(transfer, Mapping) and isinstance(transfer.get("name"), str):
        options = {k: v for k, v in transfer.items() if k != "name"}
        return transfer_strategy(transfer["name"], **{**options, **flat})
    msg = f"transfer={transfer!r}: give a strategy name, e.g. 'prediction', or a strategy"
    raise AtiktError(msg)


def _pairs(value: object) -> tuple[tuple[str, str], ...]:
    """``kernel_parts`` from pairs or a mapping, as sorted-as-given (block, kernel) tuples.

    Raises:
        AtiktError: Not pairs of two strings.
    """
    items: Any = value.items() if isinstance(value, Mapping) else value
    try:
        pairs = tuple((str(block), str(kind)) for block, kind in items)
    except (TypeError, ValueError):
        msg = f"kernel_parts={value!r}: give (block, kernel) pairs, e.g. [['texture', 'matern32']]"
        raise AtiktError(msg) from None
    return pairs
