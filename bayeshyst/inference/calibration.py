"""Is the predictive calibrated? Leave-cycles-out checks and the uncertainty budget.

**Calibration check.** The last whole cycle of every record is held out, the posterior
is re-sampled without them (:meth:`Posterior.holding_out`, started from the full fit's
draws) and its predictive — model, discrepancy, noise — is compared with the held-out
measurement, per excitation frequency:

* the probability integral transform ``PIT_i = P(y_rep_i <= y_i)`` (Monte Carlo over
  predictive draws, ties split), uniform on [0, 1] for a calibrated predictive, shown
  as a 10-bin histogram;
* the coverage of the central 50 % and 90 % predictive bands, ``|PIT - 1/2| <= p/2``,
  with the range a calibrated predictive gives 95 % of the time: binomial on the
  **effective** number of independent samples, ``n / (1 + 2 sum rho_k)`` of the PIT
  series' autocorrelation (a cycle of a thousand strongly correlated samples is not a
  thousand trials). Outside that range the check warns.

**Uncertainty budget.** The predictive variance of each scored sample splits into the
sensor noise ``E[sigma^2]``, the parameters' share ``Var_theta f`` and the
discrepancy's ``Var delta`` (posterior variances over draws; the covariance between
the two is left out, so the three add up to the predictive variance only up to it),
averaged per frequency.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy import stats

from bayeshyst.data.record import frequency_key, frequency_label
from bayeshyst.inference.convergence import _autocov
from bayeshyst.inference.linear import LinearStructure
from bayeshyst.inference.optimize import MAPResult
from bayeshyst.inference.posterior import NOISE, Posterior
from bayeshyst.inference.profile import profile_start
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.tables import TableRecord, frame

__all__ = [
    "Calibration",
    "FrequencyBudget",
    "FrequencyCalibration",
    "band_coverage",
    "binomial_range",
    "check_calibration",
    "effective_size",
    "pit_values",
    "predictive_draws",
    "uncertainty_budget",
]

#: Central band probabilities checked.
LEVELS = (0.5, 0.9)
#: PIT histogram bins.
PIT_BINS = 10


# ---------------------------------------------------------------------- statistics


def pit_values(y: np.ndarray, y_rep: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Randomised PIT (N,) of observations ``y`` (N,) under predictive draws ``y_rep`` (S, N).

    ``(#{y_rep < y} + U #{y_rep == y}) / S`` with ``U ~ Uniform(0, 1)``: uniform on
    [0, 1] in distribution when ``y`` is a draw of the predictive (ties split at
    random so discrete draws stay exact). Draws that are NaN (failed) are left out.
    """
    y = np.asarray(y, float)
    y_rep = np.asarray(y_rep, float)
    ok = np.isfinite(y_rep)
    below = np.sum((y_rep < y[None, :]) & ok, axis=0)
    equal = np.sum((y_rep == y[None, :]) & ok, axis=0)
    n = np.sum(ok, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return (below + rng.uniform(size=y.size) * equal) / n


def band_coverage(pit: np.ndarray, level: float) -> np.ndarray:
    """Indicators (N,) of the observations inside the central ``level`` predictive band."""
    return np.abs(np.asarray(pit, float) - 0.5) <= 0.5 * level


def effective_size(x: np.ndarray) -> float:
    """``n / (1 + 2 sum rho_k)`` of a series (N,), summing lags while ``rho_k > 0``.

    The number of independent trials a correlated series of indicators is worth; ``n``
    when it is not correlated, 1 at least.
    """
    x = np.asarray(x, float)
    n = x.size
    if n < 3 or np.var(x) == 0:
        return float(n)
    acov = _autocov(x[None, :])[0]
    acf = acov / acov[0]
    tau = 1.0
    for k in range(1, n):
        if acf[k] <= 0:
            break
        tau += 2.0 * acf[k]
    return float(max(1.0, n / tau))


def binomial_range(n_eff: float, p: float, mass: float = 0.95) -> tuple[float, float]:
    """Central ``mass`` range of the coverage fraction of ``n_eff`` Bernoulli(p) trials."""
    n = max(1, round(n_eff))
    lo = stats.binom.ppf(0.5 * (1 - mass), n, p) / n
    hi = stats.binom.ppf(0.5 * (1 + mass), n, p) / n
    return float(lo), float(hi)


# ---------------------------------------------------------------------- records


@dataclass(frozen=True)
class FrequencyCalibration(TableRecord):
    """The calibration check at one excitation frequency.

    Attributes
    ----------
    frequency_hz : float or None
    n_samples : int
        Held-out samples scored.
    n_effective : float
        Their effective number (see the module docstring).
    coverage : dict
        ``level -> observed coverage`` for the 50 % and 90 % bands.
    expected_range : dict
        ``level -> (lo, hi)``: where a calibrated predictive's coverage falls 95 % of
        the time.
    pit_histogram : tuple of float
        Share of the PIT values in each of 10 equal bins (0.1 each when calibrated).
    """

    frequency_hz: float | None
    n_samples: int
    n_effective: float
    coverage: dict[float, float]
    expected_range: dict[float, tuple[float, float]]
    pit_histogram: tuple[float, ...]

    @property
    def calibrated(self) -> bool:
        """Whether every band's coverage is inside its expected range."""
        return all(lo <= self.coverage[p] <= hi for p, (lo, hi) in self.expected_range.items())

    def __str__(self) -> str:
        parts = [f"{int(100 * p)} % band {100 * self.coverage[p]:.1f} % "
                 f"(expected {100 * lo:.0f}-{100 * hi:.0f} %)"
                 for p, (lo, hi) in self.expected_range.items()]
        verdict = "calibrated" if self.calibrated else "NOT calibrated"
        return (f"{frequency_label(self.frequency_hz):>10}: {', '.join(parts)}; "
                f"n={self.n_samples} (effective {self.n_effective:.0f}); {verdict}")

    def to_dataframe(self) -> Any:
        """One row: :meth:`to_dict` (without the PIT histogram)."""
        return frame([self.to_dict()], drop=("pit_histogram",))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields."""
        return {"frequency_hz": self.frequency_hz, "n_samples": self.n_samples,
                "n_effective": round(self.n_effective, 1), "calibrated": self.calibrated,
                **{f"coverage_{int(100 * p)}": self.coverage[p] for p in self.coverage},
                **{f"expected_{int(100 * p)}": list(r) for p, r in self.expected_range.items()},
                "pit_histogram": list(self.pit_histogram)}


@dataclass(frozen=True)
class Calibration(TableRecord):
    """Leave-cycles-out calibration check of a fit, per excitation frequency.

    Attributes
    ----------
    per_frequency : list of FrequencyCalibration
    held_out : tuple of str
        The held-out cycles, ``record#cycle``.
    refit_converged : bool
        Whether the posterior without them converged (if not, the check is indicative).
    """

    per_frequency: list[FrequencyCalibration]
    held_out: tuple[str, ...]
    refit_converged: bool
    notes: tuple[str, ...] = field(default=())

    @property
    def calibrated(self) -> bool:
        """Whether every frequency is calibrated."""
        return bool(self.per_frequency) and all(c.calibrated for c in self.per_frequency)

    @property
    def warnings(self) -> tuple[str, ...]:
        """One warning per frequency whose coverage is outside its expected range."""
        out = list(self.notes)
        for c in self.per_frequency:
            if not c.calibrated:
                out.append(f"predictive not calibrated at {frequency_label(c.frequency_hz)}: "
                           + ", ".join(f"{int(100 * p)} % band covers {100 * c.coverage[p]:.1f} %"
                                       f" of held-out samples (expected "
                                       f"{100 * lo:.0f}-{100 * hi:.0f} %)"
                                       for p, (lo, hi) in c.expected_range.items()))
        if not self.refit_converged:
            out.append("the calibration refit did not converge: the check is indicative")
        return tuple(out)

    def __str__(self) -> str:
        head = (f"calibration on {len(self.held_out)} held-out cycle(s) "
                f"({', '.join(self.held_out)}):")
        return "\n".join([head, *[str(c) for c in self.per_frequency]])

    def to_dataframe(self) -> Any:
        """One row per frequency: coverage of the 50 and 90 % bands, expected ranges."""
        return frame([c.to_dict() for c in self.per_frequency], drop=("pit_histogram",))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields (summary.json's ``calibration``)."""
        return {"held_out": list(self.held_out), "refit_converged": self.refit_converged,
                "calibrated": self.calibrated,
                "per_frequency": [c.to_dict() for c in self.per_frequency],
                "notes": list(self.notes)}


# ---------------------------------------------------------------------- computation


def predictive_draws(post: Posterior, z: np.ndarray, rng: np.random.Generator
                     ) -> list[np.ndarray]:
    """Posterior-predictive draws (S, N_record) per record: model + discrepancy + noise."""
    return [pred + post.noise_draws(z, pred.shape[1], rng) for pred in post.predict(z)]


def _by_frequency(groups: dict, freq_of: dict) -> list:
    """The group keys in ascending frequency, records without one last."""
    return sorted(groups, key=lambda k: (freq_of[k] is None, freq_of[k] or 0.0))


def _holdout_units(post: Posterior) -> list[int]:
    """The last cycle of every record that has at least two."""
    by_record: dict[str, list[int]] = {}
    for i, unit in enumerate(post.units):
        by_record.setdefault(unit.record, []).append(i)
    return [idx[-1] for idx in by_record.values() if len(idx) >= 2]


def check_calibration(post: Posterior, draws: np.ndarray, sampler: SamplerSettings, *,
                      start: MAPResult | None = None, n_draws: int = 400) -> Calibration:
    """Leave-cycles-out calibration check (see the module docstring).

    Parameters
    ----------
    post : Posterior
        The fitted posterior (all cycles scored).
    draws : ndarray, shape (S, ndim)
        Its draws: the refit's ensembles start from them.
    sampler : SamplerSettings
        Settings of the refit (its seed also seeds the predictive draws).
    start : MAPResult, optional
        The fit's start: the refit starts near it instead of searching (with a linear
        block; otherwise the refit searches its own MAP).
    n_draws : int
        Predictive draws per held-out sample.
    """
    # the refit writes no checkpoint: the fit's own file must not be taken for it
    sampler = replace(sampler, checkpoint=None, progress=False)
    units = _holdout_units(post)
    if not units:
        return Calibration([], (), True, ("no record has two whole cycles: calibration was "
                                          "not checked",))
    held = post.holding_out(units)
    begin = None
    structure = LinearStructure.of(held, reference=start.z) if start is not None else None
    if structure is not None:
        # the held-out data's mode searched from the full fit's over the coordinates
        # outside the linear block (a fresh MAP search would differentiate every
        # coefficient of a discrepancy)
        begin = profile_start(held, structure, start)
    res = sample_posterior(held, sampler, initial=draws, start=begin)
    rng = np.random.default_rng(sampler.seed)
    z = res.draws(n_draws, seed=sampler.seed)
    reps = predictive_draws(held, z, rng)
    groups: dict[Any, list[np.ndarray]] = {}
    freq_of: dict[Any, float | None] = {}
    for rec, y_rep in zip(post._records, reps, strict=True):
        s0 = rec["s0"]
        bounds = [*rec["unit_starts"], rec["y"].size]
        for j in range(len(bounds) - 1):
            if rec["unit_first"] + j not in units:
                continue
            a, b = bounds[j], bounds[j + 1]
            pit = pit_values(rec["y"][a:b], y_rep[:, s0 + a:s0 + b], rng)
            key = frequency_key(rec["frequency_hz"])
            groups.setdefault(key, []).append(pit)
            freq_of[key] = rec["frequency_hz"]
    per = []
    for key in _by_frequency(groups, freq_of):
        pits = groups[key]
        allp = np.concatenate(pits)
        ok = np.isfinite(allp)
        # the effective number of independent samples from the PIT series itself: an
        # indicator that is constant over a cycle (every sample inside) has no
        # estimable autocorrelation, the PIT values behind it do
        n_eff = sum(effective_size(p[np.isfinite(p)]) for p in pits)
        cov, rng_ = {}, {}
        for level in LEVELS:
            inds = [band_coverage(p[np.isfinite(p)], level) for p in pits]
            cov[level] = float(np.mean(np.concatenate(inds))) if ok.any() else math.nan
            rng_[level] = binomial_range(n_eff, level)
        hist, _ = np.histogram(allp[ok], bins=PIT_BINS, range=(0.0, 1.0))
        per.append(FrequencyCalibration(freq_of[key], int(ok.sum()), n_eff, cov, rng_,
                                        tuple(float(h) for h in hist / max(1, ok.sum()))))
    held_names = tuple(f"{post.units[u].record}#{post.units[u].index}" for u in units)
    return Calibration(per, held_names, bool(res.converged))


# ---------------------------------------------------------------------- budget


@dataclass(frozen=True)
class FrequencyBudget(TableRecord):
    """Predictive variance at one frequency split by source (output unit squared).

    ``noise`` = mean ``sigma^2``; ``parameters`` = mean over samples of the variance of
    the model output over draws; ``discrepancy`` = the same for ``delta``.
    """

    frequency_hz: float | None
    noise: float
    parameters: float
    discrepancy: float

    @property
    def total(self) -> float:
        """Sum of the three (output unit squared)."""
        return self.noise + self.parameters + self.discrepancy

    @property
    def shares(self) -> dict[str, float]:
        """Share of each source in the total."""
        tot = self.total or 1.0
        return {"noise": self.noise / tot, "parameters": self.parameters / tot,
                "discrepancy": self.discrepancy / tot}

    @property
    def dominant(self) -> str:
        """The largest source."""
        sh = self.shares
        return max(sh, key=sh.get)

    def __str__(self) -> str:
        sh = self.shares
        return (f"{frequency_label(self.frequency_hz):>10}: predictive sd "
                f"{math.sqrt(self.total):.4g} = noise {100 * sh['noise']:.0f} %, parameters "
                f"{100 * sh['parameters']:.0f} %, discrepancy {100 * sh['discrepancy']:.0f} % "
                f"of the variance (dominant: {self.dominant})")

    def to_dataframe(self) -> Any:
        """One row: :meth:`to_dict`."""
        return frame([self.to_dict()])

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields (variances and shares)."""
        return {"frequency_hz": self.frequency_hz, "noise_var": self.noise,
                "parameter_var": self.parameters, "discrepancy_var": self.discrepancy,
                "predictive_sd": math.sqrt(self.total), "shares": self.shares,
                "dominant": self.dominant}


def uncertainty_budget(post: Posterior, z: np.ndarray, *,
                       parts: tuple[list[np.ndarray], list[np.ndarray] | None] | None = None
                       ) -> list[FrequencyBudget]:
    """The predictive variance budget per excitation frequency over draws ``z`` (S, ndim).

    ``parts`` are ``(post.predict(z, discrepancy=False), post.discrepancy_draws(z))``
    when the caller has simulated them already.
    """
    theta = post.space.unpack(z)
    sigma = np.asarray(theta.get(f"{NOISE}.sigma", np.nan), float)
    if post.likelihood.name == "student_t" and f"{NOISE}.nu" in theta:
        nu = np.asarray(theta[f"{NOISE}.nu"], float)
        var = np.where(nu > 2, sigma**2 * nu / np.maximum(nu - 2, 1e-12), np.nan)
    else:
        var = sigma**2
    noise_var = float(np.nanmean(var))
    model, deltas = ((post.predict(z, discrepancy=False), post.discrepancy_draws(z))
                     if parts is None else parts)
    acc: dict[Any, list[tuple[float, float, int]]] = {}
    freq_of: dict[Any, float | None] = {}
    for i, (rec, f) in enumerate(zip(post._records, model, strict=True)):
        s0 = rec["s0"]
        pv = np.nanvar(f[:, s0:], axis=0)
        dv = np.zeros_like(pv) if deltas is None else np.nanvar(deltas[i][:, s0:], axis=0)
        key = frequency_key(rec["frequency_hz"])
        acc.setdefault(key, []).append((float(pv.sum()), float(dv.sum()), pv.size))
        freq_of[key] = rec["frequency_hz"]
    out = []
    for key in _by_frequency(acc, freq_of):
        n = sum(a[2] for a in acc[key])
        out.append(FrequencyBudget(freq_of[key], noise_var, sum(a[0] for a in acc[key]) / n,
                                   sum(a[1] for a in acc[key]) / n))
    return out
