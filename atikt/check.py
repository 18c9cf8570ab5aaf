"""Does transfer from the first observation help *this* dataset? Asked of the known objects.

From one observation of a new object, relatedness cannot be told from chance: a one-vs-all
model of the old objects gives a single observation of an unrelated object a probability of
0.6-0.9 as readily as one of a related object, and the borrowed observations then outweigh
the object's own. Whether borrowing helps before the new objects have shown more is a
property of the dataset (how far apart its objects lie, how repeatable each is), and the
known objects carry it: some of them, learned as if they were new from one observation each,
with the rest as their priors, show what transfer does there, with held-out observations to
score it on.

:func:`transfer_check` does that for one action: ``repeats`` random splits of the known
objects into pseudo-new objects and pseudo-priors (at least two of each), one random
observation per pseudo-new object, the learner's own initial fit with and without transfer
(the same options, the pseudo-priors' own models), accuracy on the pseudo-new objects' other
observations. The paired differences are the evidence the active learner's gate
(``LearnerOptions.transfer_from``, ``check_repeats``) admits transfer on before a new object
has ``transfer_from`` observations of the action. With fewer than four known objects there
is nothing to split, hence no evidence, and the gate stays closed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Final

import numpy as np
import numpy.typing as npt

from atikt.priors import PriorModel, fit_prior_model
from atikt.strategies import NoTransfer

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from atikt.features import RawFeatures
    from atikt.options import LearnerOptions

FloatArray = npt.NDArray[np.float64]

MIN_PSEUDO: Final = 2
"""Fewest pseudo-new objects and fewest pseudo-priors of a split."""
MAX_TEST: Final = 20
"""Most held-out observations scored per pseudo-new object and split."""


@dataclass(frozen=True, slots=True)
class CheckResult:
    """The held-out check of one action.

    Attributes:
        differences: Per split, accuracy with transfer minus without, shape (repeats,);
            empty when the known objects cannot be split.
    """

    differences: FloatArray

    @property
    def mean(self) -> float:
        """Mean paired difference (NaN without splits)."""
        return float(self.differences.mean()) if self.differences.size else float("nan")

    @property
    def standard_error(self) -> float:
        """Standard error of the mean difference (NaN with fewer than two splits)."""
        n = self.differences.size
        if n < 2:  # noqa: PLR2004
            return float("nan")
        return float(self.differences.std(ddof=1) / np.sqrt(n))

    @property
    def helps(self) -> bool:
        """True when transfer helped by more than a standard error (evidence, not chance)."""
        n = self.differences.size
        return n >= 2 and self.mean - self.standard_error > 0.0  # noqa: PLR2004


def transfer_check(
    prior: PriorModel,
    action: str,
    n_new: int,
    options: LearnerOptions,
    *,
    repeats: int,
    seed: int = 0,
) -> CheckResult:
    """Known objects learned as new from one observation each: transfer minus none.

    Args:
        prior: The action's prior model (its observations are the known objects').
        action: The action's id.
        n_new: New objects the learner learns; a split has ``min(n_new, known - 2)``
            pseudo-new objects.
        options: The learner's options (its transfer strategy, hyperpriors, metric transfer).
        repeats: Random splits.
        seed: Seed of the splits and draws (fixed: the same priors give the same result).

    Returns:
        The paired differences (empty with fewer than four known objects).
    """
    from atikt.active import ActiveLearner  # noqa: PLC0415 - the learner imports this module

    groups = prior.by_object()
    objects = sorted(groups)
    m = min(n_new, len(objects) - MIN_PSEUDO)
    if m < MIN_PSEUDO or repeats < 1:
        return CheckResult(np.zeros(0))
    rng = np.random.default_rng(seed)
    opened = options.replace(budget=0, transfer_from=1, check_repeats=0)
    plain = opened.replace(transfer=NoTransfer())
    differences = []
    for _ in range(repeats):
        chosen = sorted(int(o) for o in rng.choice(objects, m, replace=False))
        rest = {o: groups[o] for o in objects if o not in chosen}
        pseudo = fit_prior_model(
            rest,
            amplitude=options.amplitude,
            n_thermal_components=options.n_thermal_components,
            n_restarts=0,
            parts=options.parts,
            random_state=int(rng.integers(2**31)),
        )
        first = [int(rng.integers(len(groups[o]))) for o in chosen]
        train = [groups[o][i] for o, i in zip(chosen, first, strict=True)]
        test: list[RawFeatures] = []
        labels: list[int] = []
        for index, (o, i) in enumerate(zip(chosen, first, strict=True)):
            others = [obs for j, obs in enumerate(groups[o]) if j != i][:MAX_TEST]
            test += others
            labels += [index] * len(others)
        seed_r = int(rng.integers(2**31))
        scores = []
        for learner_options in (opened, plain):
            learner = ActiveLearner(
                [action],
                m,
                observe=_replay(train),
                priors={action: pseudo},
                options=learner_options,
                random_state=seed_r,
            )
            learner.initialise()
            scores.append(learner.score({action: (test, labels)}))
        differences.append(scores[0] - scores[1])
    return CheckResult(np.asarray(differences, dtype=np.float64))


def _replay(train: Sequence[RawFeatures]) -> Callable[[int, str], RawFeatures]:
    """An ``observe`` callback giving each pseudo-new object its one training observation."""

    def observe(obj: int, action: str) -> RawFeatures:
        del action
        return train[obj]

    return observe
