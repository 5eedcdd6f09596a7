"""When the structured moves' warm-up re-fits its independence proposal, and when it stops.

The independence proposal (:class:`~bayeshyst.inference.moves.IndependenceMove`) is
fitted to the ensemble's own draws. Fitted to an ensemble that has not yet spread over
the posterior, it is too narrow in the directions the walkers have still to reach; once
they get there the posterior outweighs the proposal and a walker holds still for
hundreds of steps. The warm-up therefore re-fits at fixed step counts
(:func:`adaptation_points`), may be extended at doubling step counts
(:func:`extension_points`), and is frozen only when :func:`keep_adapting` finds the
ensemble settled: its draws no longer move away from those the proposal was last fitted
to (:func:`window_divergence`) and the proposal moves enough walkers, or re-fitting it
stopped helping.

A frozen proposal can still miss a region the walkers reach later: a tail along a curved
ridge where the posterior outweighs the proposal, or a mode found late. A walker that
gets there holds still, or creeps about there (:func:`stuck_walkers`). At a convergence
check that fails after the warm-up, such walkers re-open it once more: the proposal is
re-fitted with a small component on each of them (an *anchor*) and the burn-in moves to
that step, so the kept chain is again a plain Metropolis-Hastings chain with one fixed
proposal.

Every decision is a fixed function of the stored chain, so a resumed run re-fits the
same proposals at the same steps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from bayeshyst.inference.convergence import integrated_time

__all__ = [
    "MAX_REOPENINGS", "MIN_MOVE_RATE", "MIN_STUCK_WINDOW", "SETTLED_KL", "STUCK_FRACTION",
    "TRAPPED_ALPHA", "WarmupDecision", "adaptation_points", "extension_points",
    "keep_adapting", "move_rate", "stuck_walkers", "window_divergence",
]

#: Below this fraction of walker-steps that move the proposed coordinates, the warm-up
#: goes on (the independence proposal is re-fitted again at the next extension point).
#: Well-fitted proposals move 0.75-0.9 of them (Bouc-Wen, 6 000 samples: 0.78); a
#: curved posterior the first fit missed moves 0.5-0.6.
MIN_MOVE_RATE = 0.65

#: The ensemble counts as settled when the Gaussian fitted to its latest warm-up window
#: is within this many nats (KL divergence) of the one fitted to the window the proposal
#: was last fitted to. Walkers carried from a smaller model's fit (a candidate effect
#: added to the 150 V piezo's Bouc-Wen with its shape correction) start narrower than
#: the new posterior and spread for 1 600-3 200 steps: consecutive windows differed by
#: 0.44, 0.34, 0.44, 0.26, 0.23 nats up to step 1 600, then by 0.065 and 0.04 (tau 200
#: steps). The estimate carries a positive sampling bias of about
#: ``p (1/n_1 + 1/n_2) / 2`` for ``p`` mean and covariance entries and ``n`` effective
#: draws, so a window too short to tell reads as not settled, never as settled.
SETTLED_KL = 0.1

#: A walker that moves the proposed coordinates in fewer than this fraction of the
#: ensemble's median walker's steps is stuck. Over :data:`MIN_STUCK_WINDOW` steps at a
#: median rate of 0.4 a walker moving freely makes 80 +- 7 moves; a quarter of that is
#: 8 sd below. Measured on the 150 V piezo's Bouc-Wen with asymmetry, change point and
#: creep (10 000 steps): one walker of 40 went into the low tail of the exponent after
#: the warm-up froze and moved in 5.5 % of 6 800 steps against a median of 43 %; its
#: ensemble's R-hat stayed at 1.07.
STUCK_FRACTION = 0.25

#: Shortest window, in steps, over which a walker can be called stuck.
MIN_STUCK_WINDOW = 200

#: How often a failed convergence check may re-open the warm-up for stuck walkers.
MAX_REOPENINGS = 2

#: Two-sided probability, per ensemble and window, that a freely mixing walker is called
#: trapped (:func:`stuck_walkers`). Small: a walker called so costs only an anchor, and a
#: re-opened warm-up only on a run whose check failed anyway.
TRAPPED_ALPHA = 1e-4


def adaptation_points(warmup: int) -> list[int]:
    """Step counts at which the independence proposal is re-fitted during the warm-up.

    A quarter, half, three quarters and all of the warm-up (none without one).
    """
    return sorted({warmup * k // 4 for k in (1, 2, 3, 4)} - {0})


def extension_points(warmup: int, max_steps: int) -> list[int]:
    """Where a warm-up whose proposal still moves too few walkers may be extended.

    Twice, four, eight ... times the warm-up, up to half the budget.
    """
    out = []
    b = 2 * warmup
    while warmup > 0 and b <= max_steps // 2:
        out.append(b)
        b *= 2
    return out


def move_rate(chain: np.ndarray, idx: np.ndarray) -> float:
    """Fraction of consecutive walker-steps in ``chain`` that changed the coordinates ``idx``.

    Parameters
    ----------
    chain : ndarray, shape (S, W, ndim)
    idx : ndarray of int
        The proposed coordinates.
    """
    if chain.shape[0] < 2 or idx.size == 0:
        return 1.0
    return float(np.mean(_moved(chain[:, :, idx])))


def _moved(x: np.ndarray) -> np.ndarray:
    """Whether each walker's step changed any coordinate of ``x`` (S, W, d): (S - 1, W)."""
    return np.any(np.diff(x, axis=0) != 0, axis=2)


def stuck_walkers(chains: list[np.ndarray], idx: np.ndarray, start: int, stop: int
                  ) -> list[np.ndarray]:
    """The draws of every walker held in one place between steps ``start`` and ``stop``.

    A walker is held there in either of two ways:

    * *still*: it moved the coordinates ``idx`` in fewer than :data:`STUCK_FRACTION`
      times as many steps as its ensemble's median walker (an ensemble whose median
      walker never moves has none by this rule: the warm-up's move rate catches that);
    * *trapped*: it moves, but locally, and its time average of some coordinate lies
      farther from the ensemble's than a freely mixing walker's could. That average has
      standard error ``s sqrt(tau / L)`` over ``L`` steps (``s`` the ensemble's sd,
      ``tau`` its integrated autocorrelation time); the walker is trapped beyond the
      two-sided :data:`TRAPPED_ALPHA` quantile, Bonferroni-corrected over walkers and
      coordinates. Measured on the 150 V piezo's asymmetry candidate: with the still
      walker anchored, another crept along the low tail of the exponent for 2 000 of
      6 000 steps at 23 % moves (median 38 %): z = -15.5 against a threshold of 5.2.

    Windows shorter than :data:`MIN_STUCK_WINDOW` steps cannot tell and give none.

    Parameters
    ----------
    chains : list of ndarray, shape (S, W, ndim) each
        The stored chain of every ensemble, at least ``stop`` steps.
    idx : ndarray of int
        The proposed coordinates.
    start, stop : int
        The window.

    Returns
    -------
    list of ndarray, shape (stop - start, ndim) each
        The held walkers' draws in the window, every coordinate: the still ones first
        (slowest first), then the trapped ones (farthest first).
    """
    if stop - start < MIN_STUCK_WINDOW or idx.size == 0:
        return []
    found = []
    for c in chains:
        window = c[start:stop]
        x = window[:, :, idx]
        rates = np.mean(_moved(x), axis=0)
        still = rates < STUCK_FRACTION * float(np.median(rates))
        z = _walker_offsets(x)
        crit = float(stats.norm.isf(TRAPPED_ALPHA / (2 * z.size)))
        far = np.max(np.abs(z), axis=1)
        for w in range(x.shape[1]):
            if still[w]:
                found.append(((0, float(rates[w])), window[:, w, :]))
            elif far[w] > crit:
                found.append(((1, -float(far[w])), window[:, w, :]))
    found.sort(key=lambda pair: pair[0])
    return [draws for _, draws in found]


def _walker_offsets(x: np.ndarray) -> np.ndarray:
    """Each walker's time average, in standard errors from the ensemble's (W, d).

    ``x`` (L, W, d); 0 for a coordinate whose standard error is not defined.
    """
    n_steps, _, d = x.shape
    tau = integrated_time(x)
    sd = x.reshape(-1, d).std(axis=0)
    se = sd * np.sqrt(tau / n_steps)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = (x.mean(axis=0) - x.mean(axis=(0, 1))) / se
    return np.where(np.isfinite(z), z, 0.0)


def window_divergence(new: np.ndarray, old: np.ndarray) -> float:
    """KL divergence ``KL(N_new || N_old)`` (nats) of Gaussians fitted to two sets of draws.

    It is the expected log density ratio, under the newer draws, of the two fits: large
    when the newer draws reach where the older fit puts little mass (the older fit is
    too narrow or off-centre), small when they agree.

    Parameters
    ----------
    new, old : ndarray, shape (M, d)
        Draws of the proposed coordinates (``M > d``).

    Returns
    -------
    float
        ``inf`` when either covariance is singular or not finite (the draws cannot say
        the ensemble has settled).
    """
    new = np.asarray(new, dtype=float)
    old = np.asarray(old, dtype=float)
    d = new.shape[1]
    if d == 0:
        return 0.0
    if min(new.shape[0], old.shape[0]) <= d:
        return math.inf
    m1, m0 = new.mean(axis=0), old.mean(axis=0)
    s1 = np.cov(new.T).reshape(d, d)
    s0 = np.cov(old.T).reshape(d, d)
    if not (np.all(np.isfinite(s1)) and np.all(np.isfinite(s0))):
        return math.inf
    try:
        c0 = np.linalg.cholesky(s0)
        c1 = np.linalg.cholesky(s1)
    except np.linalg.LinAlgError:
        return math.inf
    a = np.linalg.solve(c0, c1)  # tr(S0^-1 S1) = ||C0^-1 C1||_F^2
    r = np.linalg.solve(c0, m1 - m0)
    logdet = 2.0 * (np.sum(np.log(np.diag(c0))) - np.sum(np.log(np.diag(c1))))
    kl = 0.5 * (float(np.sum(a * a)) - d + float(r @ r) + float(logdet))
    return max(kl, 0.0) if math.isfinite(kl) else math.inf


@dataclass(frozen=True)
class WarmupDecision:
    """What the warm-up does at an extension point, and the measurements behind it.

    Attributes
    ----------
    refit : bool
        Re-fit the proposal and go on warming up (False: freeze it).
    move_rate : float
        Fraction of walker-steps since the last re-fit that moved the proposed
        coordinates (the least over ensembles).
    divergence : float
        :func:`window_divergence` of the latest window from the one last fitted (nats).
    """

    refit: bool
    move_rate: float
    divergence: float

    def __str__(self) -> str:
        kl = (f"{self.divergence:.3g} nats" if math.isfinite(self.divergence)
              else "not measurable (a singular covariance)")
        return (f"{'re-fit' if self.refit else 'freeze'}: move rate {self.move_rate:.2f}, "
                f"window divergence {kl}")


def keep_adapting(chains: list[np.ndarray], idx: np.ndarray, last_fit: int, boundary: int,
                  last_rate: float) -> WarmupDecision:
    """Whether the warm-up re-fits the proposal at the extension point ``boundary``.

    It goes on while the ensemble still spreads (the draws of ``boundary // 2`` to
    ``boundary`` differ from those of ``last_fit // 2`` to ``last_fit``, which the
    proposal was fitted to, by :data:`SETTLED_KL` nats or more), or while its proposal
    moves fewer than :data:`MIN_MOVE_RATE` of the walker-steps and the last re-fit
    raised that by at least 0.05 (a curved posterior no mixture fits well stops there).

    Parameters
    ----------
    chains : list of ndarray, shape (S, W, ndim) each
        The stored chain of every ensemble, at least ``boundary`` steps.
    idx : ndarray of int
        The proposed coordinates.
    last_fit, boundary : int
        Step of the last re-fit, and this extension point.
    last_rate : float
        The move rate measured at the previous extension point (``-inf`` at the first).
    """
    rate = min(move_rate(c[last_fit:boundary], idx) for c in chains)
    new = np.concatenate([c[boundary // 2:boundary][:, :, idx].reshape(-1, idx.size)
                          for c in chains])
    old = np.concatenate([c[last_fit // 2:last_fit][:, :, idx].reshape(-1, idx.size)
                          for c in chains])
    kl = window_divergence(new, old)
    spreading = not kl < SETTLED_KL
    improving = rate < MIN_MOVE_RATE and rate >= last_rate + 0.05
    return WarmupDecision(spreading or improving, rate, kl)
