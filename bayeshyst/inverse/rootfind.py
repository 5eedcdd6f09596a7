"""Batched, bracketed root finding for increasing one-step maps (numerical inversion).

Every problem in the batch is a scalar equation ``g(x) = 0`` with ``g`` non-decreasing
(a hysteresis model's output against its present input, from a fixed state). The
solver brackets the root by expanding from a guess, then refines it by the Illinois
variant of false position, falling back to bisection whenever an interpolated point
would not shrink the bracket enough: superlinear on the piecewise-smooth maps of
hysteresis models, never slower than bisection, and no derivative needed (operator
models have kinks at every threshold). Monotonicity is *checked*, not assumed: a
point whose residual is out of order with the bracket ends flags the problem.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["RootResult", "solve_increasing", "solve_scalar"]

#: Bracket expansions (doublings of the step) before a root is declared out of reach.
MAX_EXPANSIONS = 60
#: Refinement iterations; bisection alone halves the bracket 200 times.
MAX_REFINE = 200


@dataclass(frozen=True)
class RootResult:
    """Solutions of a batch of increasing scalar equations.

    Attributes
    ----------
    x : ndarray, shape (B,)
        Roots; for an unreachable target the limit it was pushed to.
    residual : ndarray, shape (B,)
        ``g(x)``.
    saturated : ndarray of bool, shape (B,)
        The root lies beyond ``lo``/``hi`` (or beyond reach of the expansion).
    nonmonotone : ndarray of bool, shape (B,)
        ``g`` was seen decreasing somewhere by more than the tolerance.
    n_evaluations : int
        Calls of ``g`` (each evaluates the whole batch).
    """

    x: np.ndarray
    residual: np.ndarray
    saturated: np.ndarray
    nonmonotone: np.ndarray
    n_evaluations: int


def solve_increasing(fun: Callable[[np.ndarray], np.ndarray], x0: np.ndarray,
                     step: np.ndarray, *, lo: float = -np.inf, hi: float = np.inf,
                     ftol: float, xtol: float) -> RootResult:
    """Solve ``fun(x) = 0`` elementwise for a batch of non-decreasing functions.

    Parameters
    ----------
    fun : callable
        ``x (B,) -> g (B,)``; element ``i`` of the result depends on ``x[i]`` only.
        Non-finite values are treated as failures of that element (it stops where it is).
    x0 : ndarray, shape (B,)
        Starting guesses.
    step : ndarray, shape (B,)
        First expansion step (> 0), e.g. the expected distance to the root.
    lo, hi : float
        Admissible range of ``x``; a root outside it saturates at the limit.
    ftol : float
        Residual accepted as zero (unit of ``g``).
    xtol : float
        Bracket width at which refinement stops (unit of ``x``).

    Returns
    -------
    RootResult
    """
    x = np.clip(np.asarray(x0, dtype=float).copy(), lo, hi)
    step = np.maximum(np.asarray(step, dtype=float), xtol)
    if x.size == 1:
        # one problem (the shared command of the first stage, every sample): the same
        # algorithm on Python floats, without the ~40 array operations per iteration
        # that cost more than a one-sample model evaluation
        def one(z: float) -> float:
            return float(fun(np.array([z]))[0])

        return solve_scalar(one, float(x[0]), float(step[0]), lo=lo, hi=hi, ftol=ftol,
                            xtol=xtol)
    g = fun(x)
    n_eval = 1
    size = x.size
    done = ~np.isfinite(g) | (np.abs(g) <= ftol)
    saturated = np.zeros(size, dtype=bool)
    nonmono = np.zeros(size, dtype=bool)
    tol_mono = 10.0 * ftol
    # ---- bracket: walk from x0 against the sign of g with doubling steps
    a, ga = x.copy(), g.copy()  # the end with g < 0
    b, gb = x.copy(), g.copy()  # the end with g > 0
    direction = np.where(g < 0, 1.0, -1.0)
    open_ = ~done
    prev_x, prev_g = x.copy(), g.copy()
    for j in range(MAX_EXPANSIONS):
        if not open_.any():
            break
        trial = np.where(open_, np.clip(x + direction * step * 2.0 ** j, lo, hi), prev_x)
        gt = fun(trial)
        n_eval += 1
        bad = open_ & ~np.isfinite(gt)
        done |= bad
        open_ &= ~bad
        # moving up must not lower g (and down must not raise it)
        nonmono |= open_ & (direction * (gt - prev_g) < -tol_mono)
        hit = open_ & (np.abs(gt) <= ftol)
        x = np.where(hit, trial, x)
        g = np.where(hit, gt, g)
        done |= hit
        open_ &= ~hit
        crossed = open_ & (np.sign(gt) == direction)
        up = crossed & (direction > 0)
        down = crossed & (direction < 0)
        a = np.where(up, prev_x, np.where(down, trial, a))
        ga = np.where(up, prev_g, np.where(down, gt, ga))
        b = np.where(up, trial, np.where(down, prev_x, b))
        gb = np.where(up, gt, np.where(down, prev_g, gb))
        at_limit = open_ & ~crossed & ((trial >= hi) | (trial <= lo))
        x = np.where(at_limit, trial, x)
        g = np.where(at_limit, gt, g)
        saturated |= at_limit
        done |= at_limit
        open_ &= ~(crossed | at_limit)
        prev_x = np.where(open_, trial, prev_x)
        prev_g = np.where(open_, gt, prev_g)
    # never bracketed within the expansions: out of reach
    saturated |= open_
    x = np.where(open_, prev_x, x)
    g = np.where(open_, prev_g, g)
    done |= open_
    # ---- refine: Illinois false position with bisection safeguard
    active = ~done
    fa, fb = ga.copy(), gb.copy()  # true residuals at the ends (ga, gb get Illinois-halved)
    side = np.zeros(size)  # +1: b was kept last time, -1: a was kept
    for _ in range(MAX_REFINE):
        if not active.any():
            break
        width = b - a
        secant = b - gb * width / np.where(gb - ga != 0, gb - ga, 1.0)
        # interpolated points too close to an end make no progress: bisect instead
        safe = (secant > a + 0.01 * width) & (secant < b - 0.01 * width) & (gb - ga > 0)
        trial = np.where(safe, secant, 0.5 * (a + b))
        trial = np.where(active, trial, x)
        gt = fun(trial)
        n_eval += 1
        bad = active & ~np.isfinite(gt)
        active &= ~bad
        nonmono |= active & ((gt < fa - tol_mono) | (gt > fb + tol_mono))
        x = np.where(active, trial, x)
        g = np.where(active, gt, g)
        hit = active & (np.abs(gt) <= ftol)
        active &= ~hit
        low = active & (gt < 0)
        high = active & (gt > 0)
        # Illinois: halve the residual of an end kept twice in a row
        ga = np.where(high & (side < 0), 0.5 * ga, ga)
        gb = np.where(low & (side > 0), 0.5 * gb, gb)
        a = np.where(low, trial, a)
        ga = np.where(low, gt, ga)
        fa = np.where(low, gt, fa)
        b = np.where(high, trial, b)
        gb = np.where(high, gt, gb)
        fb = np.where(high, gt, fb)
        side = np.where(low, 1.0, np.where(high, -1.0, side))
        active &= (b - a) > xtol
    # a bracket shrunk onto a jump (a staircase model): keep the closer of its two ends
    use_a = ~done & (np.abs(g) > ftol) & (np.abs(fa) < np.abs(g)) & (np.abs(fa) <= np.abs(fb))
    use_b = ~done & (np.abs(g) > ftol) & (np.abs(fb) < np.abs(g)) & ~use_a
    x = np.where(use_a, a, np.where(use_b, b, x))
    g = np.where(use_a, fa, np.where(use_b, fb, g))
    return RootResult(x, g, saturated, nonmono, n_eval)


def solve_scalar(f: Callable[[float], float], x: float, step: float, *,
                 lo: float = -math.inf, hi: float = math.inf, ftol: float,
                 xtol: float) -> RootResult:
    """:func:`solve_increasing` for one problem given as a function of a float.

    The same steps on Python floats: the shared command of numerical inversion is one
    scalar per sample, and wrapping it in arrays costs more than evaluating the model.

    Parameters
    ----------
    f : callable
        ``x (float) -> g (float)``, non-decreasing; a non-finite value stops the search
        where it is.
    x : float
        Starting guess (clipped to ``[lo, hi]``).
    step : float
        First expansion step (floored at ``xtol``).
    lo, hi : float
        Admissible range of ``x``.
    ftol, xtol : float
        As :func:`solve_increasing`.

    Returns
    -------
    RootResult
        With arrays of one element.
    """
    x = min(max(float(x), lo), hi)
    step = max(float(step), xtol)

    def result(x: float, g: float, sat: bool, mono: bool, n: int) -> RootResult:
        return RootResult(np.array([x]), np.array([g]), np.array([sat]), np.array([mono]), n)

    g = f(x)
    n_eval = 1
    tol_mono = 10.0 * ftol
    if not math.isfinite(g) or abs(g) <= ftol:
        return result(x, g, False, False, n_eval)
    direction = 1.0 if g < 0 else -1.0
    mono = False
    prev_x, prev_g = x, g
    for j in range(MAX_EXPANSIONS):
        trial = min(max(x + direction * step * 2.0 ** j, lo), hi)
        gt = f(trial)
        n_eval += 1
        if not math.isfinite(gt):
            return result(prev_x, prev_g, False, mono, n_eval)
        mono |= direction * (gt - prev_g) < -tol_mono
        if abs(gt) <= ftol:
            return result(trial, gt, False, mono, n_eval)
        if (gt > 0) == (direction > 0):
            a, fa, b, fb = (prev_x, prev_g, trial, gt) if direction > 0 else \
                (trial, gt, prev_x, prev_g)
            break
        if trial >= hi or trial <= lo:
            return result(trial, gt, True, mono, n_eval)
        prev_x, prev_g = trial, gt
    else:
        return result(prev_x, prev_g, True, mono, n_eval)
    ga, gb = fa, fb
    side = 0.0
    x, g = prev_x, prev_g
    for _ in range(MAX_REFINE):
        width = b - a
        secant = b - gb * width / (gb - ga) if gb - ga > 0 else a - 1.0
        trial = secant if a + 0.01 * width < secant < b - 0.01 * width else 0.5 * (a + b)
        gt = f(trial)
        n_eval += 1
        if not math.isfinite(gt):
            break
        mono |= gt < fa - tol_mono or gt > fb + tol_mono
        x, g = trial, gt
        if abs(gt) <= ftol:
            return result(x, g, False, mono, n_eval)
        if gt < 0:
            if side > 0:
                gb *= 0.5
            a, ga, fa, side = trial, gt, gt, 1.0
        else:
            if side < 0:
                ga *= 0.5
            b, gb, fb, side = trial, gt, gt, -1.0
        if b - a <= xtol:
            break
    # a bracket shrunk onto a jump (a staircase model): keep the closer of its two ends
    if abs(fa) < abs(g) and abs(fa) <= abs(fb):
        x, g = a, fa
    elif abs(fb) < abs(g):
        x, g = b, fb
    return result(x, g, False, mono, n_eval)
