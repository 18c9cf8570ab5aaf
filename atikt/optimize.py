"""A small box-constrained quasi-Newton minimiser that can carry its curvature between searches.

Active learning refits every classifier's hyperparameters after each observation, starting from
the previous optimum; one new observation moves that optimum only a little. A general-purpose
L-BFGS-B starts every such search from scratch: its first step is a steepest-descent guess and
its line search spends several objective evaluations before the curvature is known again. Here
the BFGS inverse-Hessian approximation of the previous search is the starting curvature of the
next (Nocedal & Wright, *Numerical Optimization*, 2006, Alg. 6.1 with a projected step for the
box), so a warm search usually needs one or two evaluations. Each evaluation is a Laplace mode
search and an ``O(n^3)`` gradient, so evaluations are what a search costs.

The search stops when the quadratic model predicts an improvement below ``tol`` (the same units
as the objective: nats for a log marginal likelihood) or a step gained less than that, when
the projected gradient is below
``gtol``, after ``max_iter`` iterations, or when no step along the search direction lowers the
objective. The model's prediction is trusted only with an informed curvature (one that was
passed in, or after the first BFGS update): the identity of a cold start says nothing about the
objective's scale, and a flat start would otherwise end the search before it moved. It is
deterministic: pure numpy, no randomness.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Final

import numpy as np
import numpy.typing as npt

from atikt.errors import AtiktError, NumericalError

if TYPE_CHECKING:
    from collections.abc import Callable

FloatArray = npt.NDArray[np.float64]

_ARMIJO: Final = 1e-4
"""Sufficient-decrease constant of the backtracking line search."""
_MAX_BACKTRACKS: Final = 20
_WOLFE: Final = 0.9
"""Curvature constant: a full step is lengthened while the slope keeps this much of its start."""
_EXPANSION: Final = 4.0
_MAX_EXPANSIONS: Final = 2
_CURVATURE: Final = 1e-10
"""A BFGS update needs ``s'y > _CURVATURE |s| |y|`` (it keeps the approximation positive)."""


@dataclass(frozen=True, slots=True, eq=False)
class SearchResult:
    """The end of one search.

    Attributes:
        x: The best point found (inside the box).
        fun: The objective at ``x``.
        jac: The gradient at ``x``.
        inverse_hessian: BFGS approximation of the inverse Hessian at ``x``; pass it as the
            ``inverse_hessian`` of the next search on a similar objective.
        n_iter: Accepted steps.
        n_evaluations: Objective evaluations, the start included.
        converged: The search stopped on ``tol`` or ``gtol`` (not on ``max_iter`` or a failed
            line search).
    """

    x: FloatArray
    fun: float
    jac: FloatArray
    inverse_hessian: FloatArray
    n_iter: int
    n_evaluations: int
    converged: bool


def _check_bounds(x0: FloatArray, bounds: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Return the lower and upper ends of the box of ``x0``.

    Raises:
        AtiktError: The box does not fit ``x0`` or is empty.
    """
    box = np.asarray(bounds, dtype=np.float64)
    if box.shape != (x0.shape[0], 2) or not (box[:, 0] <= box[:, 1]).all():
        msg = f"bounds of shape {box.shape}: need ({x0.shape[0]}, 2) with low <= high"
        raise AtiktError(msg)
    return box[:, 0], box[:, 1]


def _bfgs_update(H: FloatArray, s: FloatArray, y: FloatArray, sy: float) -> FloatArray:
    """Return the BFGS update of the inverse Hessian ``H`` (Nocedal & Wright Eq. 6.17).

    ``(I - rho s y') H (I - rho y s') + rho s s'`` with ``rho = 1 / s'y``, expanded.
    """
    rho = 1.0 / sy
    Hy = H @ y
    sHy = np.multiply.outer(s, Hy)
    symmetric = sHy + sHy.T
    symmetric *= rho
    H = H - symmetric
    ss = np.multiply.outer(s, s)
    ss *= rho * rho * float(y @ Hy) + rho
    H += ss
    return H


def _capped(d: FloatArray, max_step: float) -> FloatArray:
    """``d`` shortened to at most ``max_step`` in every variable.

    A stale or uninformed curvature can propose huge steps.
    """
    longest = _largest([abs(v) for v in d.tolist()])  # at a few variables, faster than numpy
    return d * (max_step / longest) if longest > max_step else d


def _largest(values: list[float]) -> float:
    """The largest of ``values`` (0 when empty), NaN when one is NaN: numpy's ``max``."""
    return math.nan if any(math.isnan(v) for v in values) else max(values, default=0.0)


def _learn_curvature(
    H: FloatArray, s: FloatArray, y: FloatArray, *, scale_first: bool
) -> tuple[FloatArray, bool]:
    """BFGS-update ``H`` with the step ``s`` and gradient change ``y`` when ``s'y > 0``.

    The first update of an uninformed identity rescales it first (Nocedal & Wright Eq. 6.20).
    Returns the curvature and whether it is still uninformed.
    """
    sy = float(s @ y)
    if sy <= _CURVATURE * math.sqrt(float(s @ s) * float(y @ y)):
        return H, scale_first
    if scale_first:
        H = np.eye(H.shape[0]) * (sy / float(y @ y))
    return _bfgs_update(H, s, y, sy), False


def _direction(
    H: FloatArray, x: FloatArray, g: FloatArray, box: tuple[list[float], list[float]]
) -> tuple[FloatArray, FloatArray, float]:
    """The quasi-Newton direction, the projected gradient and its largest magnitude.

    Variables held at a bound (``box``: the lower and upper ends as lists) by the gradient
    stay there; the others move along ``-H g`` restricted to them. The tests run on Python
    floats: at a few variables each numpy call costs more than all of them.
    """
    gs = g.tolist()
    held = [
        (xi <= low and gi > 0.0) or (xi >= high and gi < 0.0)
        for xi, gi, low, high in zip(x.tolist(), gs, box[0], box[1], strict=True)
    ]
    largest = _largest([abs(gi) for gi, h in zip(gs, held, strict=True) if not h])
    if not any(held):
        return -(H @ g), g, largest
    mask = np.array(held)
    g_free = np.where(mask, 0.0, g)  # H g_free restricted to the free rows is H_ff g_f
    return np.where(mask, 0.0, -(H @ g_free)), g_free, largest


def minimize_box(
    fun: Callable[[FloatArray], tuple[float, FloatArray]],
    x0: npt.ArrayLike,
    bounds: npt.ArrayLike,
    *,
    inverse_hessian: FloatArray | None = None,
    max_iter: int = 50,
    tol: float = 1e-4,
    gtol: float = 1e-5,
    max_step: float = 2.0,
) -> SearchResult:
    """Minimise ``fun`` over a box with projected BFGS steps and a backtracking line search.

    Args:
        fun: ``x -> (value, gradient)``. A :class:`NumericalError` raised at a trial point of
            the line search rejects that point; raised at ``x0`` it propagates.
        x0: Starting point; clipped into the box.
        bounds: Box, shape (n, 2).
        inverse_hessian: Starting curvature, shape (n, n), symmetric positive definite (e.g.
            the ``inverse_hessian`` of a previous search). None: the identity, rescaled after
            the first step (Nocedal & Wright Eq. 6.20).
        max_iter: Maximum accepted steps.
        tol: Stop when the quadratic model predicts an improvement below ``tol``, or after a
            step that improved by less (neither is tested while the curvature is the
            uninformed identity of a cold start).
        gtol: Stop when the largest projected gradient entry is below ``gtol``.
        max_step: Largest change of any variable in one full step (a trust region; 2 in log
            space is a factor of 7.4 on a hyperparameter).

    Returns:
        The best point and the curvature there.

    Raises:
        AtiktError: Malformed box or starting curvature.
        NumericalError: The objective failed or is not finite at ``x0``.
    """
    x = np.asarray(x0, dtype=np.float64).reshape(-1).copy()
    lo, hi = _check_bounds(x, np.asarray(bounds, dtype=np.float64))
    n = x.shape[0]
    scale_first = inverse_hessian is None
    H = np.eye(n) if inverse_hessian is None else np.array(inverse_hessian, dtype=np.float64)
    if H.shape != (n, n) or not np.isfinite(H).all():
        msg = f"inverse_hessian of shape {H.shape}: need a finite ({n}, {n}) matrix"
        raise AtiktError(msg)
    x = np.minimum(np.maximum(x, lo), hi)
    f, g = fun(x)
    g = np.asarray(g, dtype=np.float64)
    if not (math.isfinite(f) and np.isfinite(g).all()):
        msg = "the objective is not finite at the starting point"
        raise NumericalError(msg)
    n_eval, n_iter, converged = 1, 0, False
    box = (lo.tolist(), hi.tolist())
    while n_iter < max_iter:
        d, g_free, largest = _direction(H, x, g, box)
        if largest < gtol:
            converged = True
            break
        slope = float(g @ d)
        if slope >= 0.0:  # not a descent direction (curvature lost): steepest descent
            H, scale_first = np.eye(n), True
            d = -g_free
            slope = float(g @ d)
        if not scale_first and -0.5 * slope < tol:  # the model's predicted improvement
            converged = True
            break
        floor = 0.0 if scale_first else tol
        step = _line_search(fun, x, f, g, _capped(d, max_step), lo=lo, hi=hi, floor=floor)
        n_eval += step.n_evaluations
        if step.x is None:
            break
        H, scale_first = _learn_curvature(H, step.x - x, step.g - g, scale_first=scale_first)
        gained = f - step.f
        x, f, g = step.x, step.f, step.g
        n_iter += 1
        if gained < tol and not scale_first:  # a step that gained less than tol: done
            converged = True
            break
    return SearchResult(x, float(f), g, H, n_iter, n_eval, converged)


@dataclass(frozen=True, slots=True)
class _Step:
    """An accepted line-search point (``x`` None: none found)."""

    x: FloatArray | None
    f: float
    g: FloatArray
    n_evaluations: int


def _line_search(
    fun: Callable[[FloatArray], tuple[float, FloatArray]],
    x: FloatArray,
    f: float,
    g: FloatArray,
    d: FloatArray,
    *,
    lo: FloatArray,
    hi: FloatArray,
    floor: float = 0.0,
) -> _Step:
    """Backtrack along the projected path ``clip(x + t d)`` from ``t = 1`` (Armijo condition).

    A rejected trial shrinks ``t`` to the minimiser of the quadratic through ``f``, the slope
    and the trial value, kept within ``[t/10, t/2]``; a failed evaluation shrinks it tenfold.
    A trial whose first-order gain ``-g'(trial - x)`` is below ``floor`` (the search's ``tol``)
    is not evaluated: the search would stop after such a step anyway (it gained less than
    ``tol``), and below the objective's own resolution (the Laplace mode's, up to about 1e-4
    nats) further backtracking only compares noise.
    """
    t, k, last = 1.0, 0, None
    for _ in range(_MAX_BACKTRACKS):
        trial = np.minimum(np.maximum(x + d if t == 1.0 else x + t * d, lo), hi)
        decrease = float(g @ (trial - x))
        if decrease >= 0.0 or (k > 0 and -decrease < floor):
            # the projection left no descent (all movement clipped away), or what is left
            # could gain less than the search's tolerance after a rejected trial
            return _Step(None, f, g, k)
        if last is not None and np.array_equal(trial, last):  # still clipped to the same point
            t *= 0.5
            continue
        k, last = k + 1, trial
        try:
            f_new, g_new = fun(trial)
        except NumericalError:
            f_new, g_new = np.inf, g
        if math.isfinite(f_new) and f_new <= f + _ARMIJO * decrease:
            step = _Step(trial, float(f_new), np.asarray(g_new, dtype=np.float64), k)
            return _extrapolate(fun, x, g, d, step, lo=lo, hi=hi) if k == 1 else step
        if math.isfinite(f_new):
            slope = decrease / t
            curvature = f_new - f - slope * t
            t_new = -slope * t * t / (2.0 * curvature) if curvature > 0.0 else 0.5 * t
            t = min(max(t_new, 0.1 * t), 0.5 * t)
        else:
            t *= 0.1
    return _Step(None, f, g, k)


def _extrapolate(
    fun: Callable[[FloatArray], tuple[float, FloatArray]],
    x: FloatArray,
    g: FloatArray,
    d: FloatArray,
    step: _Step,
    *,
    lo: FloatArray,
    hi: FloatArray,
) -> _Step:
    """Lengthen a full step while the objective still falls steeply along ``d``.

    A stale curvature (carried over from another search) can make the full step far too short
    on a flat ridge; while the slope at the accepted point is still steeper than ``_WOLFE``
    times the initial one (the curvature condition of Wolfe fails), ``t`` grows by
    ``_EXPANSION``, for at most ``_MAX_EXPANSIONS`` more evaluations, keeping the best point.
    """
    slope0, t = float(g @ d), 1.0
    for _ in range(_MAX_EXPANSIONS):
        assert step.x is not None  # noqa: S101 - only accepted steps are extended
        if float(step.g @ d) > _WOLFE * slope0:
            break
        t *= _EXPANSION
        trial = np.minimum(np.maximum(x + t * d, lo), hi)
        if np.array_equal(trial, step.x):  # held by the bounds
            break
        try:
            f_new, g_new = fun(trial)
        except NumericalError:
            return _Step(step.x, step.f, step.g, step.n_evaluations + 1)
        if not (math.isfinite(f_new) and f_new < step.f):
            return _Step(step.x, step.f, step.g, step.n_evaluations + 1)
        step = _Step(
            trial, float(f_new), np.asarray(g_new, dtype=np.float64), step.n_evaluations + 1
        )
    return step
