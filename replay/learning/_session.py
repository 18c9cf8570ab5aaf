"""One active-learning run: the ATIKT loop against an executor, scored after every step."""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import polars as pl
from threadpoolctl import threadpool_limits

from atikt import (
    ActiveLearner,
    AtiktError,
    LearnerOptions,
    PriorModel,
    fit_prior_models,
    shared_observations,
    strategy_names,
)
from atikt.strategies import Prediction, strategy_options
from replay.errors import ReplayError
from replay.learning._executors import FeatureLookup, PoolExecutor, Split

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence

    from atikt import RawFeatures
    from atikt.options import MetricCheck
    from replay.learning._executors import Executor, TestSet

#: Transfer modes: the registered transfer strategies (prediction, optimization, density,
#: evidence, none; ``atikt.strategy_names``).
TRANSFER_MODES = strategy_names()

#: The learners' default hyperprior: a Gaussian of this sd on every classifier's log
#: hyperparameters around the initial kernel (maximum a posteriori instead of the thesis's
#: maximum likelihood). Chosen from sd 1, 2, 3, 5, 10 on the priors and negative runs of
#: ``tests/bench/relatedness_candidates.py`` (atikt/README, *Hyperprior*): with 5 both ATIKT and
#: the baseline gain the most; ``--hyper-sd none`` is the thesis.
DEFAULT_HYPER_SD = 5.0

#: Metric transfer (``LearnerOptions.metric_sd``): the new objects' classifiers start from
#: the old objects' kernel hyperparameters, with a Gaussian prior of this sd around them.
#: Chosen from sd 1 and 5 on the negative and related runs of
#: ``tests/bench/relatedness_candidates.py`` (atikt/README, *Metric transfer*);
#: ``--metric-sd none`` is the thesis.
DEFAULT_METRIC_SD = 1.0

#: When the old objects' kernel is used (``LearnerOptions.metric_check``) and until how
#: many observations of a new object (``metric_until``): chosen on the priors, negative,
#: related and single-action runs of ``tests/bench/relatedness_candidates.py``
#: (atikt/README, *Metric transfer*).
DEFAULT_METRIC_CHECK: MetricCheck = "either"
DEFAULT_METRIC_UNTIL: int | None = 2

#: The model prediction approach borrows no old object's observations in the initial round,
#: where every new object has one observation (``Prediction.borrow_initial``): from one
#: observation the old models admit dissimilar priors as readily as related ones. Chosen on
#: the simulated dataset and the iCub grasps together (atikt/README, *Borrowing from one
#: observation*): after one observation it is never below the baseline there, where the
#: thesis's rule lost up to 4 points (single actions), and the mean over steps 1..40 holds.
DEFAULT_TRANSFER = Prediction(borrow_initial=False)

#: The project's learner: the thesis's ATIKT (model prediction, one source, 40 steps) with
#: the hyperprior, metric transfer and the initial-round rule above; every run and study
#: starts from it.
DEFAULT_LEARNER = LearnerOptions(
    transfer=DEFAULT_TRANSFER,
    hyper_sd=DEFAULT_HYPER_SD,
    metric_sd=DEFAULT_METRIC_SD,
    metric_check=DEFAULT_METRIC_CHECK,
    metric_until=DEFAULT_METRIC_UNTIL,
)

PriorData = dict[str, dict[int, list["RawFeatures"]]]


#: A fix in the learner's API syntax (``transfer='optimization'``), as atikt words it.
_API_TRANSFER = re.compile(r"\btransfer='([\w-]+)'")


def _in_cli_words(err: AtiktError) -> str:
    """Return atikt's message with a fix in API syntax named as the command line's option.

    atikt speaks to Python callers (``transfer='optimization'``); a command's user types
    ``--transfer optimization``.
    """
    return _API_TRANSFER.sub(r"--transfer \1", str(err))


def learner_options(transfer: str, *, max_sources: int = 1, **options: Any) -> LearnerOptions:  # noqa: ANN401 (any option of LearnerOptions)
    """:data:`DEFAULT_LEARNER` with a transfer strategy and options changed.

    ``max_sources`` goes to the strategies that transfer several sources at once and is
    left out for the others (``optimization``, ``none``), so one study setting serves them
    all.

    Raises:
        ReplayError: An option out of range or unknown (one line naming it).
    """
    changes = {"transfer": transfer, **options}
    if transfer in strategy_options().get("max_sources", ()):
        changes["max_sources"] = max_sources
    try:
        return DEFAULT_LEARNER.replace(**changes)
    except AtiktError as err:
        raise ReplayError(str(err)) from err


@dataclass(frozen=True, slots=True, kw_only=True)
class RunSpec:
    """Everything that determines one learning run (with the data and the seed).

    Attributes:
        new_objects: Ids of the objects to learn, in label order.
        prior_objects: Ids of the old objects whose observations may be transferred.
        actions: Actions the learner may choose.
        learner: The learner's options (budget, transfer strategy, hyperpriors, ...).
        seed: Seed of every random choice of the run.
        test_fraction: Share of each (object, action)'s recordings held out for testing.
        features: Feature policy (``thesis`` or ``all``; see ``select_blocks``).
    """

    new_objects: tuple[str, ...]
    prior_objects: tuple[str, ...]
    actions: tuple[str, ...]
    learner: LearnerOptions = DEFAULT_LEARNER
    seed: int = 0
    test_fraction: float = 0.5
    features: str = "thesis"

    @property
    def transfers(self) -> bool:
        """True when the learner transfers from prior objects (not the baseline)."""
        return self.learner.transfer.transfers

    def baseline(self) -> RunSpec:
        """The same run without transfer (the baseline on the same split and seed)."""
        return replace(self, learner=self.learner.replace(transfer="none"))

    def __post_init__(self) -> None:
        """Check the spec; errors name the option to fix."""
        if len(self.new_objects) < 2:  # noqa: PLR2004
            msg = (
                f"--new {','.join(self.new_objects) or '(none)'}: a run needs at least two new "
                "objects; name them with --new or declare them new in the dataset's objects.toml"
            )
            raise ReplayError(msg)
        if not 0 <= self.seed < 2**32:
            msg = f"--seed {self.seed}: give an integer in 0..{2**32 - 1}"
            raise ReplayError(msg)
        if overlap := set(self.new_objects) & set(self.prior_objects):
            msg = f"{', '.join(sorted(overlap))}: an object cannot be new and prior at once"
            raise ReplayError(msg)


def prior_data(
    lookup: FeatureLookup,
    prior_objects: Sequence[str],
    actions: Sequence[str],
    *,
    source: FeatureLookup | None = None,
    borrow: Mapping[str, str] | None = None,
) -> PriorData:
    """Return every recording of the prior objects, action -> prior index -> features.

    Args:
        lookup: The features of the dataset the learner runs on (its actions' kinds and
            feature blocks).
        prior_objects: The old objects, in prior index order.
        actions: The learner's actions.
        source: Where the prior objects' recordings come from: another dataset (another rig:
            cross-rig transfer); None: ``lookup``.
        borrow: Action -> the source action whose recordings serve as its priors
            (cross-action transfer, e.g. ``{"C1": "P1"}``; cross-rig, e.g. ``{"H5": "C1"}``);
            an action it does not name borrows from the source action of the same id. The
            observations keep the feature blocks the action uses (``atikt.shared_observations``).

    Raises:
        ReplayError: A source action lacks a feature block the action uses.
    """
    source = lookup if source is None else source
    borrow = borrow or {}
    data: PriorData = {}
    for action in actions:
        origin = borrow.get(action, action)
        if origin not in source.blocks and action in borrow:
            msg = (
                f"--prior-actions {action}={origin}: the prior recordings have no action "
                f"{origin}; choose one of {', '.join(sorted(source.blocks))}"
            )
            raise ReplayError(msg)
        if origin not in source.blocks:
            continue  # the other rig has no such action: no priors for it
        groups = source.groups(prior_objects, origin)
        if origin == action and source is lookup:
            data[action] = groups
            continue
        kind, blocks = lookup.kinds[action], lookup.blocks[action]
        try:
            data[action] = {
                i: list(shared_observations(obs, kind, blocks)) for i, obs in groups.items()
            }
        except AtiktError as err:
            msg = f"priors of action {action} from action {origin}: {_in_cli_words(err)}"
            raise ReplayError(msg) from err
    return data


def borrow_pairs(
    lookup: FeatureLookup, source: FeatureLookup, named: Mapping[str, str] | None = None
) -> dict[str, str]:
    """Return which source action serves as priors of each of the learner's actions.

    Named pairs first; then the action of the same id when the source has it with every
    feature block the action uses; else the first source action (by id) of the same kind with
    those blocks (e.g. a heated probe's static ``H5`` takes a skin's static ``C1``). Actions
    with no such source action are left out (they get no priors).

    Raises:
        ReplayError: A named action is in neither dataset.
    """
    pairs = dict(named or {})
    for target, origin in pairs.items():
        if target not in lookup.blocks or origin not in source.blocks:
            msg = (
                f"--prior-actions {target}={origin}: {target} must be an action of the "
                f"recordings ({', '.join(sorted(lookup.blocks))}) and {origin} one of the "
                f"prior recordings ({', '.join(sorted(source.blocks))})"
            )
            raise ReplayError(msg)

    def fits(target: str, origin: str) -> bool:
        return set(lookup.blocks[target]) <= set(source.blocks[origin])

    for target in sorted(lookup.blocks):
        if target in pairs:
            continue
        if target in source.blocks and fits(target, target):
            pairs[target] = target
            continue
        kind = lookup.kinds[target]
        same = [a for a in sorted(source.blocks) if source.kinds[a] == kind and fits(target, a)]
        if same:
            pairs[target] = same[0]
    return pairs


def fit_priors(
    data: PriorData, seed: int, learner: LearnerOptions = DEFAULT_LEARNER
) -> dict[str, PriorModel]:
    """Fit the prior objects' models once, to share them between runs.

    Args:
        data: Action -> old-object index -> observations.
        seed: Seed of the fits.
        learner: The learners' options (their kernels and feature space).

    Raises:
        ReplayError: The prior data cannot be fitted.
    """
    try:
        with threadpool_limits(limits=1):  # small matrices: see run_learning
            return fit_prior_models(
                data,
                amplitude=learner.amplitude,
                n_thermal_components=learner.n_thermal_components,
                n_restarts=learner.n_restarts,
                parts=learner.parts,
                random_state=seed,
            )
    except AtiktError as err:
        msg = f"prior objects: cannot fit their models ({_in_cli_words(err)})"
        raise ReplayError(msg) from err


@dataclass(slots=True)
class RunResult:
    """The outcome of one run: one row per step (step 0 is the state after initialisation)."""

    spec: RunSpec
    rows: list[dict[str, Any]] = field(default_factory=list)

    def frame(self) -> pl.DataFrame:
        """Return the rows as a table."""
        return pl.DataFrame(self.rows, infer_schema_length=None)


def _named(spec: RunSpec, row: dict[str, Any]) -> dict[str, Any]:
    """Replace object and prior indices of a step row by catalog ids."""
    objects, priors = spec.new_objects, spec.prior_objects
    row["object"] = objects[row["object"]]
    row["prior"] = "" if row["prior"] < 0 else priors[row["prior"]]
    row["priors"] = ["" if p < 0 else priors[p] for p in row["priors"]]
    row["candidates"] = [priors[c] for c in row["candidates"]]
    return row


@dataclass(slots=True)
class _ActionScores:
    """Test accuracy per action, computed again only for an action whose classifiers changed.

    A step refits one action: ``ActiveLearner._update`` gives that action a new feature
    transformer and a new list of classifiers and changes no other action, and predicting has
    no side effects. So an action's accuracy is kept with the transformer and classifier list
    it was computed with (held here: their identities cannot pass to new objects) and used
    while they are still the action's own. Scoring every action after every step was a
    quarter of a study's time; the accuracies are the same numbers.
    """

    test: TestSet
    _known: dict[str, tuple[object, object, float]] = field(default_factory=dict)

    def __call__(self, learner: ActiveLearner) -> dict[str, float]:
        """Return the accuracy of each action of the test set, in its order."""
        scores = {}
        for action, observations in self.test.items():
            state = learner.states_.get(action)
            known = self._known.get(action)
            if (
                state is None
                or known is None
                or known[0] is not state.transformer
                or known[1] is not state.models
            ):
                value = learner.score_per_action({action: observations})[action]
                if state is not None:
                    self._known[action] = (state.transformer, state.models, value)
                scores[action] = value
            else:
                scores[action] = known[2]
        return scores


def _scores(learner: ActiveLearner, per_action_scores: _ActionScores) -> dict[str, float]:
    """Return the accuracy of all actions together and of each action, and the metric share.

    ``metric_share``: the share of the new objects' classifiers fitted under metric transfer
    (``ActiveLearner.metric_share``), which transfers the old objects' kernel, not their
    observations (``rho`` says when observations are transferred).
    """
    per_action = per_action_scores(learner)
    overall = sum(per_action.values()) / len(per_action)
    accuracies = {"accuracy": overall} | {f"accuracy_{a}": v for a, v in per_action.items()}
    return accuracies | {"metric_share": learner.metric_share()}


def run_learning(
    spec: RunSpec,
    executor: Executor,
    test: TestSet,
    priors: Mapping[str, PriorModel] | PriorData | None,
    *,
    on_step: Callable[[dict[str, Any]], Any] | None = None,
) -> RunResult:
    """Run the ATIKT loop (or the baseline) and score it on ``test`` after every step.

    Args:
        spec: What to run.
        executor: Serves observations (offline pool or live rig).
        test: Held-out observations per action, labelled by new-object index.
        priors: Fitted prior models or raw prior data (ignored without transfer).
        on_step: Called with every row as soon as it is known (for live printing).

    Returns:
        The rows of the run.

    Raises:
        ReplayError: The learner refused its input; the message says why.
    """
    learner = ActiveLearner(
        spec.actions,
        len(spec.new_objects),
        observe=executor,
        capacity=executor.capacity,
        priors=dict(priors or {}) if spec.transfers else None,
        options=spec.learner,
        random_state=spec.seed,
    )
    result = RunResult(spec)
    # One BLAS thread: the learner's matrices are small (tens to a few hundred rows), and
    # OpenBLAS's threads cost more than they save there (the heated-probe run of
    # tests/bench/transfer_speed.py: --transfer optimization 11.5 s with the default threads,
    # 1.2 s with one); the studies' tasks already run with one (replay.learning._parallel).
    with threadpool_limits(limits=1):
        _learn(learner, spec, test, result, on_step)
    return result


def _learn(
    learner: ActiveLearner,
    spec: RunSpec,
    test: TestSet,
    result: RunResult,
    on_step: Callable[[dict[str, Any]], Any] | None,
) -> None:
    """Initialise the learner and step it to the end, appending one scored row per step.

    Raises:
        ReplayError: The learner refused its input; the message says why.
    """
    scores = _ActionScores(test)
    try:
        learner.initialise()
        initial = {"step": 0, "object": "", "action": "", "explored": False, "prior": ""}
        result.rows.append(initial | {"n_observations": learner.n_observations_})
        result.rows[-1] |= _scores(learner, scores)
        if on_step is not None:
            on_step(result.rows[-1])
        while not learner.done:
            record = learner.step()
            row = _named(spec, record.as_row()) | {"step": record.step + 1}
            result.rows.append(row | _scores(learner, scores))
            if on_step is not None:
                on_step(result.rows[-1])
    except AtiktError as err:
        msg = f"learning run (seed {spec.seed}): {_in_cli_words(err)}"
        raise ReplayError(msg) from err


def run_offline(
    frame: pl.DataFrame,
    spec: RunSpec,
    *,
    priors: Mapping[str, PriorModel] | None = None,
    on_step: Callable[[dict[str, Any]], Any] | None = None,
    lookup: FeatureLookup | None = None,
) -> RunResult:
    """Run one learning session over a dataset's feature table (random split by the seed).

    Args:
        frame: The feature table of the dataset.
        spec: What to run; its seed also draws the test/pool split.
        priors: Prior models fitted beforehand (fitted here from ``frame`` when None).
        on_step: Called with every row as soon as it is known.
        lookup: The table's features already converted (``FeatureLookup(frame, spec.features)``,
            shared by the runs of a study task); None: converted here.

    Returns:
        The rows of the run.
    """
    lookup = FeatureLookup(frame, spec.features) if lookup is None else lookup
    if priors is None and spec.transfers:
        data = prior_data(lookup, spec.prior_objects, spec.actions)
        priors = fit_priors(data, spec.seed, spec.learner)
    split = Split.random(
        frame, spec.new_objects, spec.actions, seed=spec.seed, test_fraction=spec.test_fraction
    )
    executor = PoolExecutor(lookup, spec.new_objects, split)
    return run_learning(spec, executor, executor.test_set(spec.actions), priors, on_step=on_step)
