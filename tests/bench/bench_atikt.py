"""Benchmark of one ATIKT active-learning iteration, atikt against the scikit-learn reference.

Setting: 5 new objects, 3 old objects, 7 actions (P1, P2, S1-S4, C1), 20 prior observations per
old object and action, model prediction transfer, one initial observation per (new object,
action) and then 40 steps. Printed:

- the median latency of ``ActiveLearner.step()`` (decision + observation + update of the chosen
  action's models + record), over the first 5 steps (up to 40 collected observations) and over
  all 40 steps;
- side by side, on the same inputs (the learner's state just before each update, copied; each
  update timed in atikt and right after in scikit-learn, ``--rounds`` rounds (3), an
  update's time its fastest round): the median time of atikt's update of the chosen action
  and of the same update done with scikit-learn's GaussianProcessClassifier
  (tests/atikt/sklearn_reference.py, with its ``warm_start`` on, its fastest setting, and its
  L-BFGS-B optimiser started from the same hyperparameters with the same iteration cap), and
  their ratio. atikt searches with its own
  projected BFGS (atikt/optimize.py), which carries the curvature from the previous update
  and stops when the predicted rise of the log marginal likelihood is below ``tol``; so the
  optima differ, and the quality is printed next to the speed: the log marginal likelihood
  each classifier reached, atikt minus the reference without ``warm_start`` (exact), and
  the largest difference of the resulting UNC values;
- objective evaluations along one search path, side by side;
- how often the warm-started step searches stop at the iteration cap;
- the step latency of the baseline, of the model optimisation approach, of the open-set
  (density) approach, of the evidence-gain approach, of multi-source density transfer (at
  most 3 sources), and of the prediction approach and the baseline with the replay tool's
  default hyperprior (``hyper_sd=5``);
- with ``--accuracy``: final test accuracy of the amplitude kernel against the thesis kernel
  (no signal variance), baseline and transfer, over a few seeds.

BLAS runs single-threaded (``OPENBLAS_NUM_THREADS=1`` unless set): at these matrix sizes
threads only add contention, for both implementations; studies running learners in joblib
workers get the same setting from joblib. scikit-learn's ConvergenceWarnings are silenced.

The quality of the update's optima is checked against targets (:data:`QUALITY_MEDIAN`,
:data:`QUALITY_P10`, :data:`QUALITY_UNC`): the benchmark prints them and exits with status 1
when one is missed; the share of updates within :data:`QUALITY_UNC` is printed against
:data:`QUALITY_UNC_SHARE` (with ``--strict`` it fails the run too). scikit-learn searches
the same objective as atikt (log marginal likelihood
plus the hyperprior of metric transfer, when atikt's update used one), from the same start
with the same source and rho, to its own convergence.

Run: ``taskset -c 1 python tests/bench/bench_atikt.py [--steps 40] [--accuracy] [--quick]
[--strict]`` (``--quick``: 4 steps, one round; tests/atikt/test_atikt_bench.py runs it).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import copy
import functools
import statistics
import sys
import time
import timeit
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "atikt"))

import scipy.optimize
from atikt_synthetic import ACTIONS, NEW_OBJECTS, OLD_OBJECTS, PoolObserver, pool
from sklearn.gaussian_process import GaussianProcessClassifier
from sklearn_reference import (
    ObjectSearch,
    log_hyperprior,
    reference_kernel,
    reference_old_model,
    reference_update,
    to_reference_theta,
)

import atikt.transfer
from atikt import (
    ActiveLearner,
    BinaryGPC,
    DependentKernel,
    fit_prior_models,
    modality_kernel,
    transfer_strategy,
)
from atikt.strategies import strategy_options
from atikt.transfer import with_domain

N_NEW = len(NEW_OBJECTS)
SIZES = ((10, 0), (10, 20), (30, 20))
"""(new, auxiliary) observations of the objective-evaluation comparison."""
CONVERGED_MAX_ITER = 1000
"""The quality reference: scikit-learn's L-BFGS-B searched to its own convergence."""


@dataclass
class Snapshot:
    """The inputs of one action update: a copy of the learner just before it, and its options."""

    learner: ActiveLearner
    action: str
    n_restarts: int
    max_iter: int
    changed: int | None


class TimedLearner(ActiveLearner):
    """An ActiveLearner that keeps a copy of its state before each step's update.

    :meth:`compare` then times both implementations on those inputs, each implementation in a
    loop of its own over all the updates (as they run in a study: back to back, not
    interleaved with the other implementation, whose memory traffic would slow either).
    """

    def __init__(self, *args: Any, reference: dict[str, Any], **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.reference = reference
        self.record = False
        self.snapshots: list[Snapshot] = []
        self.ours: list[float] = []
        self.theirs: list[float] = []
        self.unc_gap: list[float] = []
        self.lml_gap: list[float] = []
        #: Per update: the objective atikt's classifiers reached minus the reference's.
        self.lml_by_update: list[np.ndarray] = []

    def _reference(
        self,
        snapshot: Snapshot,
        state: Any,
        fits: Any,
        *,
        warm_start: bool,
        max_iter: int | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        learner = snapshot.learner
        return reference_update(
            state,
            n_new_objects=learner.n_new_objects,
            amplitude=learner.options.amplitude,
            n_thermal_components=learner.options.n_thermal_components,
            eps_neg1=learner.options.transfer.options()["eps_neg1"],
            max_iter=snapshot.max_iter if max_iter is None else max_iter,
            old_model=self.reference.get(snapshot.action),
            changed=snapshot.changed,
            warm_start=warm_start,
            fits=fits,
            metric_check=learner.options.metric_check
            if learner.options.metric_sd is not None
            else "none",
        )

    def _update(
        self, action: str, *, n_restarts: int, max_iter: int, changed: int | None = None
    ) -> None:
        if self.record:
            reference, self.reference = self.reference, {}
            self.record, snapshots, self.snapshots = False, self.snapshots, []
            mine = copy.deepcopy(self)
            self.reference, self.record, self.snapshots = reference, True, snapshots
            self.snapshots.append(Snapshot(mine, action, n_restarts, max_iter, changed))
        super()._update(action, n_restarts=n_restarts, max_iter=max_iter, changed=changed)

    def compare(self, rounds: int = 3) -> None:
        """Time every recorded update in atikt and in scikit-learn; compare the results.

        Each round times every update in atikt (on a fresh copy) and right after it the same
        update in scikit-learn, so the two meet the same moment of the machine's load (in
        loops of their own, a burst of load during one loop moved the ratio by 1.5x between
        runs); an update's time is its fastest over the rounds (noise only ever adds).
        scikit-learn searches the objective atikt's update searched (same source, rho and
        hyperprior per classifier, taken from atikt's update): the comparison is of the
        searches, not of the choices.
        """
        ours, theirs = [], []
        fits: list[list[ObjectSearch]] = []
        for _ in range(rounds):
            mine = [copy.deepcopy(s.learner) for s in self.snapshots]
            states = [copy.deepcopy(s.learner.states_[s.action]) for s in self.snapshots]
            times, their_times = [], []
            for index, (learner, s, state) in enumerate(
                zip(mine, self.snapshots, states, strict=True)
            ):
                start = time.perf_counter()
                learner._update(
                    s.action, n_restarts=s.n_restarts, max_iter=s.max_iter, changed=s.changed
                )
                times.append(time.perf_counter() - start)
                if len(fits) <= index:
                    fits.append(searched(learner.states_[s.action]))
                start = time.perf_counter()
                self._reference(s, state, fits[index], warm_start=True)
                their_times.append(time.perf_counter() - start)
            ours.append(times)
            theirs.append(their_times)
        self.ours = list(np.min(ours, axis=0))
        self.theirs = list(np.min(theirs, axis=0))
        for learner, s, fit in zip(mine, self.snapshots, fits, strict=True):
            state = copy.deepcopy(s.learner.states_[s.action])
            unc, value = self._reference(
                s, state, fit, warm_start=False, max_iter=CONVERGED_MAX_ITER
            )
            state = learner.states_[s.action]
            self.unc_gap.append(float(np.abs(unc - state.uncertainty).max()))
            self.lml_gap.extend(reached(state) - value)
            self.lml_by_update.append(reached(state) - value)


def searched(state: Any) -> list[ObjectSearch]:
    """Per new object: the source, rho and hyperprior of its classifier's search."""
    out = []
    for choice, model in zip(state.choices, state.models, strict=True):
        estimator = model.estimator_
        sd = estimator.prior_sd
        mean = None if sd is None else estimator.prior_mean
        if sd is not None and mean is None:
            mean = estimator.kernel.theta
        out.append(ObjectSearch(choice.source, float(choice.rho), sd, mean))
    return out


def reached(state: Any) -> np.ndarray:
    """Per new object: log marginal likelihood + log hyperprior density its search reached."""
    values = []
    for model, fit in zip(state.models, searched(state), strict=True):
        estimator = model.estimator_
        sd = None if fit.sd is None else np.asarray(fit.sd, dtype=np.float64)
        penalty = log_hyperprior(estimator.kernel_.theta, sd, fit.mean)
        values.append(estimator.log_marginal_likelihood_value_ + penalty)
    return np.array(values)


@functools.cache
def old_models() -> dict[str, Any]:
    """The old objects' models of every action (20 trials each), fitted once per run.

    The learners only read them (``fit_prior_models`` fits models reusable by many learners),
    so the latency, search and mode measurements share one fit.
    """
    return fit_prior_models(pool(OLD_OBJECTS, list(ACTIONS), n_trials=20, seed=2), random_state=0)


def sklearn_old_models(priors: dict[str, Any]) -> dict[str, Any]:
    """The old objects' models in scikit-learn at atikt's fitted hyperparameters."""
    out = {}
    for action, prior in priors.items():
        X = prior.transformer.transform(prior.observations)
        kernels = [e.kernel_ for e in prior.model.estimators_]
        out[action] = reference_old_model(kernels, X, prior.labels)
    return out


def latency(steps: int, rounds: int = 3, *, strict: bool = False) -> list[str]:
    """Step latency and the side-by-side update comparison; returns the quality targets missed."""
    actions = list(ACTIONS)
    train = pool(NEW_OBJECTS, actions, n_trials=steps + 1, seed=1)
    priors = old_models()
    learner = TimedLearner(
        actions,
        N_NEW,
        observe=PoolObserver(train),
        priors=priors,
        budget=steps,
        random_state=0,
        reference=sklearn_old_models(priors),
    )
    start = time.perf_counter()
    learner.initialise()
    print(f"initialise (35 observations, prior models given): {time.perf_counter() - start:.2f} s")
    step_times = []
    while not learner.done:
        start = time.perf_counter()
        learner.step()
        step_times.append(time.perf_counter() - start)
    early = statistics.median(step_times[:5]) * 1e3
    print(f"step latency, first 5 steps (<= 40 observations): median {early:.1f} ms")
    print(f"step latency, all {len(step_times)} steps: median {np.median(step_times) * 1e3:.1f} ms")
    print(
        f"                             90th percentile {np.percentile(step_times, 90) * 1e3:.1f} ms"
    )

    timed = TimedLearner(
        actions,
        N_NEW,
        observe=PoolObserver(train),
        priors=priors,
        budget=steps,
        random_state=0,
        reference=learner.reference,
    )
    timed.initialise()
    timed.record = True
    while not timed.done:
        timed.step()
    timed.compare(rounds)
    ours, theirs = np.median(timed.ours) * 1e3, np.median(timed.theirs) * 1e3
    ratios = np.array(timed.theirs) / np.array(timed.ours)
    print(
        f"action update, same inputs and warm starts ({len(timed.ours)} updates, "
        f"each the fastest of {rounds} rounds):"
    )
    print(f"  atikt        median {ours:.1f} ms")
    print(f"  scikit-learn median {theirs:.1f} ms")
    median_ratio = float(np.median(ratios))
    print(f"  speed ratio {theirs / ours:.1f}x (median per-update ratio {median_ratio:.1f}x)")
    return print_quality(timed, strict=strict)


QUALITY_MEDIAN = 1e-3
"""Largest median |objective atikt - objective reference| (nats) the benchmark accepts."""
QUALITY_P10 = -1e-2
"""Smallest 10th percentile of objective atikt - objective reference (nats) it accepts."""
QUALITY_UNC = 1e-2
"""Largest median over updates of max |UNC atikt - UNC reference| (nats) it accepts."""
QUALITY_UNC_SHARE = 0.9
"""Issue 32's target: this share of the updates within :data:`QUALITY_UNC` (its 90th
percentile at most that). Printed as met or missed; it fails the run only with ``--strict``
(the learner misses it: see docs/performance.md), so that the quick run in CI keeps checking
the targets that hold."""


def print_quality(learner: TimedLearner, *, strict: bool = False) -> list[str]:
    """Print the optima reached by atikt and by the converged reference on the same inputs.

    Args:
        learner: The learner whose updates :meth:`TimedLearner.compare` compared.
        strict: Also count :data:`QUALITY_UNC_SHARE` among the targets that fail the run.

    Returns:
        The quality targets missed (empty: all met).
    """
    gap = np.array(learner.lml_gap)
    unc = np.array(learner.unc_gap)
    print(
        f"  objective reached (log marginal likelihood + log hyperprior), atikt - scikit-learn "
        f"searched to convergence, {gap.size} classifiers: median {np.median(gap):+.4f}, "
        f"median |difference| {np.median(np.abs(gap)):.5f}, 10th percentile "
        f"{np.percentile(gap, 10):+.4f}, worst {gap.min():+.3f}, best {gap.max():+.3f} nats "
        f"(atikt higher in {np.mean(gap > 0):.0%})"
    )
    print(
        f"  |UNC atikt - UNC scikit-learn| per update (largest over the new objects), "
        f"{unc.size} updates: median {np.median(unc):.4f}, 90th percentile "
        f"{np.percentile(unc, 90):.4f}, max {unc.max():.4f} nats"
    )
    # where UNC differs, the two searches from one start ended at different optima of a
    # multi-modal objective (a classifier's objective differs by more than 0.01 nats)
    far = [k for k, u in enumerate(unc) if u > QUALITY_UNC]
    apart = [learner.lml_by_update[k] for k in far]
    split = [g[np.abs(g) > QUALITY_UNC] for g in apart]
    higher = sum(int((d > 0).any()) for d in split)
    lower = sum(int((d < 0).any()) for d in split)
    print(
        f"  updates with |UNC difference| > {QUALITY_UNC}: {len(far)} of {unc.size}; in "
        f"{sum(d.size > 0 for d in split)} of them a classifier ended at another optimum than "
        f"the reference's (objective > {QUALITY_UNC} nats apart: atikt's higher in {higher}, "
        f"lower in {lower})"
    )
    within = float(np.mean(unc <= QUALITY_UNC))
    share_met = within >= QUALITY_UNC_SHARE
    print(
        f"  updates with |UNC difference| <= {QUALITY_UNC}: {within:.0%} (90th percentile "
        f"{np.percentile(unc, 90):.4f} nats); target >= {QUALITY_UNC_SHARE:.0%}: "
        f"{'met' if share_met else 'MISSED'}"
    )
    missed = []
    if strict and not share_met:
        missed.append(f"fewer than {QUALITY_UNC_SHARE:.0%} of updates within {QUALITY_UNC}")
    if np.median(np.abs(gap)) > QUALITY_MEDIAN:
        missed.append(f"median |objective difference| > {QUALITY_MEDIAN}")
    if np.percentile(gap, 10) < QUALITY_P10:
        missed.append(f"10th percentile of the objective difference < {QUALITY_P10}")
    if np.median(unc) > QUALITY_UNC:
        missed.append(f"median UNC difference > {QUALITY_UNC}")
    return missed


def evaluation(repeats: int = 20, sizes: tuple[tuple[int, int], ...] = SIZES) -> None:
    """Objective evaluations (log marginal likelihood + gradient) along one search path.

    The path is the sequence of theta visited by an L-BFGS-B search from a perturbed optimum;
    both implementations evaluate it in order, each warm-starting Newton's method its own way
    (atikt: first-order prediction of the mode; scikit-learn: ``warm_start``, the last mode).
    """
    rng = np.random.default_rng(0)
    slices = {"force": slice(0, 1), "thermal": slice(1, 11)}
    for n_new, n_aux in sizes:
        X = rng.standard_normal((n_new, 11))
        y = (np.arange(n_new) % 5 == 0).astype(float)
        kernel: Any = modality_kernel(slices)
        if n_aux:
            kernel = DependentKernel(kernel, 0.7)
            aux = with_domain(rng.standard_normal((n_aux, 11)) * 0.5 + 1.0, 0.0)
            X = np.vstack([aux, with_domain(X, 1.0)])
            y = np.concatenate([np.ones(n_aux), y])
        fitted = BinaryGPC(kernel, max_iter=30).fit(X, y).kernel_
        start: Any = fitted.with_theta(fitted.theta + rng.normal(0, 0.2, fitted.n_params))
        path: list[np.ndarray] = []
        objective = BinaryGPC(start)._objective(X, y)

        def record(
            theta: np.ndarray, objective: Any = objective, path: list[np.ndarray] = path
        ) -> Any:
            path.append(theta.copy())
            return objective(theta)

        scipy.optimize.minimize(
            record,
            start.theta,
            jac=True,
            method="L-BFGS-B",
            bounds=start.bounds,
            options={"maxiter": 10},
        )
        reference = (
            GaussianProcessClassifier(reference_kernel(start), optimizer=None, warm_start=True)
            .fit(X, y)
            .base_estimator_
        )
        ref_path = [to_reference_theta(start.with_theta(t)) for t in path]

        def ours(path: list[np.ndarray] = path, start: Any = start, X: Any = X, y: Any = y) -> None:
            objective = BinaryGPC(start)._objective(X, y)
            for theta in path:
                objective(theta)

        def theirs(ref_path: list[np.ndarray] = ref_path, reference: Any = reference) -> None:
            for theta in ref_path:
                reference.log_marginal_likelihood(theta, eval_gradient=True, clone_kernel=False)

        t_ours = min(timeit.repeat(ours, number=repeats, repeat=3)) / repeats / len(path)
        t_theirs = min(timeit.repeat(theirs, number=repeats, repeat=3)) / repeats / len(path)
        print(
            f"objective evaluation along a {len(path)}-point search path, n = {n_new} + {n_aux} "
            f"auxiliary: atikt {t_ours * 1e6:.0f} us, scikit-learn {t_theirs * 1e6:.0f} us, "
            f"ratio {t_theirs / t_ours:.1f}x"
        )


class CountingGPC(BinaryGPC):
    """A BinaryGPC that records the search iterations and evaluations of every fit."""

    iterations: ClassVar[list[int]] = []
    evaluations: ClassVar[list[int]] = []
    lbfgsb: ClassVar[list[int]] = []

    def fit(self, X: Any, y: Any) -> Any:
        out = super().fit(X, y)
        CountingGPC.iterations.append(self.n_iter_)
        CountingGPC.evaluations.append(self.n_evaluations_)
        # the same search with scipy's L-BFGS-B: same objective, start and iteration cap
        objective = BinaryGPC(self.kernel)._objective(self.X_train_, self.y_train_)
        scipy.optimize.minimize(
            objective,
            np.clip(self.kernel.theta, self.kernel.bounds[:, 0], self.kernel.bounds[:, 1]),
            jac=True,
            method="L-BFGS-B",
            bounds=self.kernel.bounds,
            options={"maxiter": self.max_iter},
        )
        CountingGPC.lbfgsb.append(objective.n_calls)
        return out


def search_iterations(steps: int) -> None:
    """How often the warm-started step searches hit the iteration cap."""
    actions = list(ACTIONS)
    train = pool(NEW_OBJECTS, actions, n_trials=steps + 1, seed=1)
    priors = old_models()
    learner = ActiveLearner(
        actions, N_NEW, observe=PoolObserver(train), priors=priors, budget=steps, random_state=0
    )
    learner.initialise()
    namespace = vars(atikt.transfer)  # count the fits of the classifiers the learner builds
    original = namespace["BinaryGPC"]
    namespace["BinaryGPC"] = CountingGPC
    try:
        while not learner.done:
            learner.step()
    finally:
        namespace["BinaryGPC"] = original
    iterations = np.array(CountingGPC.iterations)
    capped = np.mean(iterations >= learner.options.max_iter_step)
    evaluations = np.array(CountingGPC.evaluations)
    print(
        f"step searches: {len(iterations)}, {capped:.0%} stopped at the cap of "
        f"{learner.options.max_iter_step} iterations, median {np.median(iterations):.0f}; "
        "objective "
        f"evaluations per search: mean {evaluations.mean():.2f}, median "
        f"{np.median(evaluations):.0f}; scipy's L-BFGS-B on the same searches (same start and "
        f"cap): mean {np.mean(CountingGPC.lbfgsb):.2f}, median {np.median(CountingGPC.lbfgsb):.0f}"
    )


def other_modes(steps: int) -> None:
    """Median step latency of the baseline, the model optimisation approach, the open-set
    (density) approach, the evidence-gain approach, multi-source density transfer (at most
    3 sources; atikt), and of the prediction approach and the baseline with the replay tool's
    default hyperprior."""
    actions = list(ACTIONS)
    train = pool(NEW_OBJECTS, actions, n_trials=steps + 1, seed=1)
    priors = old_models()
    modes: list[tuple[Any, int, float | None]] = [
        ("none", 1, None),
        ("optimization", 1, None),
        ("density", 1, None),
        ("evidence", 1, None),
        ("density", 3, None),
        ("prediction", 1, 5.0),  # the replay tool's default hyperprior (DEFAULT_HYPER_SD)
        ("none", 1, 5.0),
    ]
    for transfer, max_sources, hyper_sd in modes:
        # max_sources is an option of the strategies that choose several sources only
        owners = strategy_options().get("max_sources", ())
        sources = {"max_sources": max_sources} if transfer in owners else {}
        learner = ActiveLearner(
            actions,
            N_NEW,
            observe=PoolObserver(train),
            priors=priors,
            transfer=transfer_strategy(transfer, **sources),
            hyper_sd=hyper_sd,
            budget=steps,
            random_state=0,
        )
        learner.initialise()
        times = []
        while not learner.done:
            start = time.perf_counter()
            learner.step()
            times.append(time.perf_counter() - start)
        print(
            f"step latency, transfer={transfer!r}, max_sources={max_sources}, "
            f"hyper_sd={hyper_sd}: "
            f"median {np.median(times) * 1e3:.1f} ms"
        )


def accuracy(seeds: int, steps: int) -> None:
    """Final test accuracy of the amplitude and the thesis kernel (synthetic objects)."""
    actions = list(ACTIONS)
    raw_priors = pool(OLD_OBJECTS, actions, n_trials=20, seed=2)
    test = pool(NEW_OBJECTS, actions, n_trials=10, seed=3)
    test_set = {
        a: (
            [o for j in range(N_NEW) for o in test[a][j]],
            [j for j in range(N_NEW) for _ in test[a][j]],
        )
        for a in actions
    }
    for amplitude in (True, False):
        priors = fit_prior_models(raw_priors, amplitude=amplitude, random_state=0)
        for transfer in ("none", "prediction"):
            finals, initials = [], []
            for seed in range(seeds):
                train = pool(NEW_OBJECTS, actions, n_trials=steps + 1, seed=100 + seed)
                learner = ActiveLearner(
                    actions,
                    N_NEW,
                    observe=PoolObserver(train),
                    priors=priors,
                    transfer=transfer,
                    budget=steps,
                    amplitude=amplitude,
                    random_state=seed,
                )
                learner.initialise()
                initials.append(learner.score(test_set))
                while not learner.done:
                    learner.step()
                finals.append(learner.score(test_set))
            name = "amplitude" if amplitude else "thesis   "
            print(
                f"{name} transfer={transfer:10s} accuracy after init {np.mean(initials):.3f}, "
                f"after {steps} steps {np.mean(finals):.3f} +- {np.std(finals):.3f} ({seeds} seeds)"
            )


def main(argv: list[str] | None = None) -> int:
    """Parse the options and run the benchmarks.

    Returns:
        0, or 1 when the update's optima miss a quality target (printed on stderr).
    """
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--accuracy", action="store_true", help="also compare the kernels")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--rounds", type=int, default=3, help="timing rounds per update")
    parser.add_argument(
        "--quick",
        action="store_true",
        help="a few steps, one round, one accuracy seed (checks that everything runs; the "
        "quality targets still apply, the timings mean nothing)",
    )
    parser.add_argument(
        "--strict",
        action="store_true",
        help=f"also fail when fewer than {QUALITY_UNC_SHARE:.0%} of the updates' UNC values are "
        f"within {QUALITY_UNC} nats of the reference's (issue 32's target, not met yet)",
    )
    args = parser.parse_args(argv)
    if args.quick:
        args.steps, args.rounds, args.seeds = min(args.steps, 4), 1, 1
    warnings.simplefilter("ignore")
    print(f"OPENBLAS_NUM_THREADS={os.environ['OPENBLAS_NUM_THREADS']}")
    missed = latency(args.steps, args.rounds, strict=args.strict)
    evaluation(1 if args.quick else 20, SIZES[:1] if args.quick else SIZES)
    search_iterations(args.steps)
    other_modes(args.steps)
    if args.accuracy:
        accuracy(args.seeds, args.steps)
    if missed:
        print(f"QUALITY FAILED: {'; '.join(missed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
