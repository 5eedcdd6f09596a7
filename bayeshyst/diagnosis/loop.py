"""The closed loop of :func:`diagnose`: fit, test the residual, augment, refit, keep or stop.

Each round goes fit → residual tests → augment with the best-supported effect → refit →
keep it only if held-out prediction improves → repeat.

Two gates stand between a residual pattern and an effect in ``effects_found``:

1. its score test fires: Holm-adjusted p-value below ``alpha`` over all effects tested
   on that residual (:mod:`bayeshyst.diagnosis.residual`);
2. the augmented model predicts held-out cycles better: the paired difference of the
   cycle-wise PSIS-LOO elpd (exact refits for Pareto k > 0.7) exceeds ``threshold``
   standard errors (default 2, Vehtari, Gelman & Gabry 2017, §5.2).

Fired effects are tried in order of support (Bayes factor; coloured noise last); the
first that passes gate 2 is kept and the loop starts again from the augmented fit.
Effects that fire but fail gate 2 are recorded as rejected steps. The loop stops when
no test fires, when every fired effect is rejected, or after ``max_rounds``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bayeshyst.data.record import Dataset, Record
from bayeshyst.diagnosis.effects import EFFECTS, get_effect
from bayeshyst.diagnosis.residual import (
    EffectTest,
    ResidualAnalysis,
    analyse_residual,
    best_point,
)
from bayeshyst.errors import DataError, ParameterError
from bayeshyst.inference.calibration import uncertainty_budget
from bayeshyst.inference.fit import FitResult, TrackingError, errors_by_frequency
from bayeshyst.inference.optimize import find_map
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling import ParamSummary, SamplingResult, sample_posterior
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.likelihoods import get_likelihood
from bayeshyst.models import get as get_model
from bayeshyst.models.base import HysteresisModel
from bayeshyst.selection import paired_difference
from bayeshyst.selection.tasks import CompareSettings, fit_sampler, loo_scores
from bayeshyst.tables import TableRecord, frame

__all__ = ["DiagnosisFit", "DiagnosisResult", "DiagnosisSettings", "DiagnosisStep", "diagnose"]

_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DiagnosisSettings:
    """Settings of a diagnosis (see :func:`diagnose`)."""

    effects: tuple[str, ...] = tuple(EFFECTS)
    alpha: float = 0.01
    threshold: float = 2.0
    max_rounds: int = 6
    max_candidates: int = 2
    max_ar_order: int = 10
    sampler: SamplerSettings = field(default_factory=SamplerSettings)
    n_draws: int = 200
    draws_per_chain: int = 30
    max_refits: int = 5

    @property
    def seed(self) -> int:
        """The diagnosis' seed (the sampler settings')."""
        return self.sampler.seed

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready settings: every field (tuples as lists), the sampler's dict, the seed."""
        out = {k: (list(v) if isinstance(v, tuple) else v)
               for k, v in self.__dict__.items() if k != "sampler"}
        out["sampler"] = self.sampler.to_dict()
        out["seed"] = self.seed
        return out


@dataclass(frozen=True)
class DiagnosisFit:
    """One fitted model of the loop: the fit record and its residual analysis.

    Attributes
    ----------
    label : str
        Spec string (``"pi_play+creep"``) and likelihood (``" with likelihood ar1"``).
    fit : FitResult
        The fit, as :func:`~bayeshyst.inference.fit.fit_model` returns one, with its
        cycle-wise elpd, warnings and InferenceData; the compensation and the writers
        take it as it is.
    analysis : ResidualAnalysis
        Residual and every effect's test on it.

    The fit's fields read through (``posterior``, ``sampling``, ``model``,
    ``likelihood``, ``overall``, ``per_frequency``, ``pointwise_elpd``, ``warnings``,
    ``idata``, ``elpd``, ``converged``).
    """

    label: str
    fit: FitResult
    analysis: ResidualAnalysis

    @property
    def model(self) -> HysteresisModel:
        """The fitted model."""
        return self.fit.model

    @property
    def likelihood(self) -> str:
        """The likelihood's name."""
        return self.fit.likelihood

    @property
    def posterior(self) -> Posterior:
        """The fitted posterior."""
        return self.fit.posterior

    @property
    def sampling(self) -> SamplingResult:
        """Its samples."""
        return self.fit.sampling

    @property
    def overall(self) -> TrackingError:
        """Tracking error of the posterior-mean prediction over all scored samples."""
        return self.fit.overall

    @property
    def per_frequency(self) -> list[TrackingError]:
        """The same per excitation frequency."""
        return self.fit.per_frequency

    @property
    def pointwise_elpd(self) -> np.ndarray | None:
        """Cycle-wise PSIS-LOO elpd (exact where refitted), shape (n_cycles,).

        A diagnosis always scores its fits.
        """
        return self.fit.pointwise_elpd

    @property
    def warnings(self) -> tuple[str, ...]:
        """What the fit noticed."""
        return self.fit.warnings

    @property
    def idata(self) -> Any:
        """The thinned posterior (arviz.InferenceData) behind the elpd."""
        return self.fit.idata

    @property
    def elpd(self) -> float:
        """Summed cycle-wise elpd."""
        return self.fit.elpd

    @property
    def converged(self) -> bool:
        """Whether the sampler converged."""
        return self.fit.converged


def _te(e: TrackingError | None) -> dict[str, Any] | None:
    if e is None:
        return None
    return {"frequency_hz": e.frequency_hz, "rmse": e.rmse, "max_error": e.max_error,
            "nrmse_percent": e.nrmse_percent, "max_error_percent": e.max_error_percent}


@dataclass(frozen=True)
class DiagnosisStep(TableRecord):
    """One augmentation tried.

    Attributes
    ----------
    index : int
        Round of the loop (1-based).
    effect : str
    test : EffectTest
        The test that proposed it, on the residual of ``model_before``.
    model_before, model_after : str
        Labels of the fit before and the augmented fit.
    accepted : bool
    reason : str
        Plain words: why it was kept or not.
    before, after : TrackingError
        Overall error of the posterior-mean prediction.
    per_frequency : tuple of (TrackingError, TrackingError)
        Before and after at each excitation frequency.
    delta_elpd, delta_elpd_se : float
        Paired cycle-wise elpd difference (after − before) and its standard error.
    added_parameters : tuple of ParamSummary
        Posterior of the added block's (or noise model's) parameters.
    converged : bool
        Whether the augmented fit's sampler converged.
    """

    index: int
    effect: str
    test: EffectTest
    model_before: str
    model_after: str
    accepted: bool
    reason: str
    before: TrackingError
    after: TrackingError
    per_frequency: tuple[tuple[TrackingError, TrackingError], ...]
    delta_elpd: float
    delta_elpd_se: float
    added_parameters: tuple[ParamSummary, ...]
    converged: bool

    def to_dataframe(self) -> Any:
        """One row: :meth:`to_dict` without the per-frequency and parameter lists."""
        return frame([self.to_dict()], drop=("per_frequency", "added_parameters"))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready; the keys of the issue's ``steps`` entries come first."""
        return {
            "effect": self.effect, "statistic": self.test.statistic,
            "statistic_value": self.test.value, "p_value": self.test.p_value,
            "p_adjusted": self.test.p_adjusted,
            "bayes_factor_log": self.test.log_bayes_factor,
            "rmse_before": self.before.rmse, "rmse_after": self.after.rmse,
            "max_error_before": self.before.max_error, "max_error_after": self.after.max_error,
            "delta_elpd": self.delta_elpd, "delta_elpd_se": self.delta_elpd_se,
            "accepted": self.accepted, "reason": self.reason, "round": self.index,
            "model_before": self.model_before, "model_after": self.model_after,
            "nrmse_percent_before": self.before.nrmse_percent,
            "nrmse_percent_after": self.after.nrmse_percent,
            "per_frequency": [{"frequency_hz": b.frequency_hz, "rmse_before": b.rmse,
                               "rmse_after": a.rmse, "max_error_before": b.max_error,
                               "max_error_after": a.max_error} for b, a in self.per_frequency],
            "test": self.test.to_dict(),
            "added_parameters": [{"name": p.label, "unit": p.unit, "mean": p.mean, "sd": p.sd,
                                  "hdi_low": p.hdi_lo, "hdi_high": p.hdi_hi, "hdi_prob": p.prob}
                                 for p in self.added_parameters],
            "converged": self.converged,
        }

    def __str__(self) -> str:
        verdict = "ACCEPTED" if self.accepted else "rejected"
        lines = [f"round {self.index}: {self.effect} -> {self.model_after}: {verdict} "
                 f"({self.reason})",
                 f"  test: {self.test}",
                 f"  RMSE {self.before.rmse:.4g} -> {self.after.rmse:.4g}, max "
                 f"{self.before.max_error:.4g} -> {self.after.max_error:.4g}; "
                 f"delta elpd {self.delta_elpd:.1f} +- {self.delta_elpd_se:.1f}"]
        for b, a in self.per_frequency:
            if b.frequency_hz is not None:
                lines.append(f"  {b.frequency_hz:>8g} Hz: RMSE {b.rmse:.4g} -> {a.rmse:.4g}, "
                             f"max {b.max_error:.4g} -> {a.max_error:.4g}")
        lines += [f"  {p}" for p in self.added_parameters]
        return "\n".join(lines)


@dataclass(frozen=True)
class DiagnosisResult(TableRecord):
    """What the closed loop found.

    Attributes
    ----------
    base_model, final_model : str
        Labels (spec and likelihood).
    effects_found : tuple of str
        Accepted effects in the order added; empty when the base model explains the data.
    steps : tuple of DiagnosisStep
        Every augmentation tried (accepted or not).
    base, final : DiagnosisFit
    rounds : tuple of ResidualAnalysis
        The tests of every round (the last one is the final model's).
    settings : DiagnosisSettings
    """

    base_model: str
    final_model: str
    effects_found: tuple[str, ...]
    steps: tuple[DiagnosisStep, ...]
    base: DiagnosisFit
    final: DiagnosisFit
    rounds: tuple[ResidualAnalysis, ...]
    settings: DiagnosisSettings
    warnings: tuple[str, ...] = ()

    def to_dataframe(self) -> Any:
        """One row per step (effect tried): tests, errors before/after, held-out elpd."""
        return frame([s.to_dict() for s in self.steps],
                     drop=("per_frequency", "added_parameters"))

    def to_dict(self) -> dict[str, Any]:
        """The ``summary.json`` content."""
        return {
            "base_model": self.base_model,
            "final_model": self.final_model,
            "effects_found": list(self.effects_found),
            "steps": [s.to_dict() for s in self.steps],
            "before": _te(self.base.overall), "after": _te(self.final.overall),
            "per_frequency": [{"frequency_hz": b.frequency_hz, "before": _te(b),
                               "after": _te(a)}
                              for b, a in zip(self.base.per_frequency,
                                              self.final.per_frequency, strict=True)],
            "rounds": [{"model": lab, "ar_order": r.ar_order,
                        "tests": [t.to_dict() for t in r.tests]}
                       for lab, r in zip(self._round_labels(), self.rounds, strict=True)],
            "cycles": [{"record": c.record, "cycle": c.cycle, "frequency_hz": c.frequency_hz,
                        "rms_before": c.rms, "max_before": c.max_abs,
                        "rms_after": d.rms, "max_after": d.max_abs}
                       for c, d in zip(self.base.analysis.cycles, self.final.analysis.cycles,
                                       strict=True)],
            "converged": bool(self.base.sampling.converged and self.final.sampling.converged),
            "warnings": list(self.warnings),
            "settings": self.settings.to_dict(),
        }

    def _round_labels(self) -> list[str]:
        labels = [self.base_model]
        labels += [s.model_after for s in self.steps if s.accepted]
        return labels[:len(self.rounds)]

    def __str__(self) -> str:
        found = ", ".join(self.effects_found) or "none (the base model explains the data)"
        lines = [f"diagnosis of {self.base_model}: effects found: {found}",
                 f"final model: {self.final_model}",
                 f"error before: {self.base.overall}", f"error after:  {self.final.overall}"]
        for lab, r in zip(self._round_labels(), self.rounds, strict=True):
            lines += [f"-- tests on the residual of {lab} (AR({r.ar_order}) whitening)", str(r)]
        lines += [str(s) for s in self.steps]
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)


# --------------------------------------------------------------------------- the loop
def _carried(post: Posterior, previous: DiagnosisFit, added: dict[str, Any],
             z_old: np.ndarray, seed: int) -> np.ndarray:
    """Points of the augmented posterior made from the previous fit's points ``z_old``.

    ``z_old`` is (M, ndim_old): its names are carried into the composite's ``static.``
    namespace, the added parameters set at the test's estimate, anything else taken from
    prior draws. Points that cannot be written in the new space are left out.
    """
    old = previous.posterior.space.unpack(np.atleast_2d(z_old))
    space = post.space
    fill = space.unpack(space.sample_prior(np.random.default_rng(seed), z_old.shape[0]))
    out = []
    for i in range(z_old.shape[0]):
        theta = {n: np.asarray(fill[n])[i] for n in space.names}
        for name in space.names:
            for src in (name, name.removeprefix("static.")):
                if src in old and np.shape(old[src])[1:] == np.shape(theta[name]):
                    theta[name] = np.asarray(old[src])[i]
                    break
            if name in added and np.shape(added[name]) == np.shape(theta[name]):
                theta[name] = added[name]
        try:
            out.append(space.pack(theta))
        except (ValueError, FloatingPointError):
            continue
    return np.array(out).reshape(-1, space.ndim)


def _warm_start(post: Posterior, previous: DiagnosisFit, added: dict[str, Any],
                seed: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """A start for the augmented fit, carried over from the previous fit.

    The previous fit's best point becomes an extra MAP start and its final ensembles the
    sampler's starting walkers, so the augmented posterior is not sampled from scratch.
    None where nothing has finite density (the MAP search and the sampler then start
    alone).
    """
    best = _carried(post, previous, added, best_point(previous.sampling)[None, :], seed)
    x0 = best[0] if best.shape[0] and np.isfinite(post.log_prob(best[0])) else None
    last = previous.sampling.chains[:, -1].reshape(-1, previous.posterior.ndim)
    walkers = _carried(post, previous, added, last, seed + 1)
    if walkers.shape[0]:
        walkers = walkers[np.isfinite(post.log_prob_batch(walkers))]
    return x0, (walkers if walkers.shape[0] else None)


def _fit(data: Dataset, model: HysteresisModel, likelihood: str, label: str,
         st: DiagnosisSettings, checkpoint_dir: Path | None,
         warm: tuple[DiagnosisFit, dict[str, Any]] | None = None) -> DiagnosisFit:
    post = Posterior(data, model, likelihood)
    # the seed, checkpoint and walkers follow from what is fitted: the base fit of a report
    # is the comparison's joint fit (same posterior, same settings, same checkpoint folder)
    sampler = fit_sampler(post, st.sampler, st.seed, checkpoint_dir)
    seed = sampler.seed
    start = initial = None
    if warm is not None:
        x0, initial = _warm_start(post, warm[0], warm[1], seed)
        if x0 is not None:  # an extra start of the MAP search, not a replacement
            start = find_map(post, seed=np.random.default_rng(seed), x0=x0)
    res = sample_posterior(post, sampler, start=start, initial=initial)
    notes = [] if res.converged else [f"{label}: the sampler did not converge within its "
                                      f"budget ({sampler.max_steps} steps)"]
    draws = res.draws(st.n_draws, seed=seed)
    settings = CompareSettings(likelihood=likelihood, sampler=sampler,
                               draws_per_chain=st.draws_per_chain, max_refits=st.max_refits)
    loo_notes: list[str] = []
    scores = loo_scores(post, res, settings, seed, loo_notes)
    notes += [f"{label}: {n}" for n in loo_notes]
    if res.counts.failed:
        notes.append(f"{label}: {res.counts.failed} simulations failed during sampling "
                     f"(log-probability -inf)")
    analysis = analyse_residual(post, res, draws, effects=st.effects, alpha=st.alpha,
                                max_ar_order=st.max_ar_order)
    overall, per = errors_by_frequency(data, analysis.mean_prediction)
    fit = FitResult(post, res, overall, list(per), list(analysis.mean_prediction),
                    pointwise_elpd=scores.pointwise, warnings=tuple(notes), idata=scores.idata,
                    budget=tuple(uncertainty_budget(post, draws)))
    return DiagnosisFit(label, fit, analysis)


def _added(fit: DiagnosisFit, before: DiagnosisFit) -> tuple[ParamSummary, ...]:
    """Posterior summaries of the parameters the augmentation added.

    A composite carries the previous model's parameters under ``static.``.
    """
    def base(name: str) -> str:
        return name.removeprefix("static.")

    old = {base(n) for n in before.posterior.space.names}
    return tuple(p for p in fit.sampling.summary() if base(p.label.split("[")[0]) not in old)


def _check_settings(st: DiagnosisSettings) -> None:
    bad = [e for e in st.effects if e not in EFFECTS]
    if bad:
        raise ParameterError(f"effects: unknown {bad}; valid: {', '.join(EFFECTS)}")
    if not (0.0 < st.alpha < 1.0):
        raise ParameterError(f"alpha must be in (0, 1), got {st.alpha}")
    if not (math.isfinite(st.threshold) and st.threshold >= 0):
        raise ParameterError(f"threshold (standard errors) must be >= 0, got {st.threshold}")
    for name in ("max_rounds", "max_candidates", "n_draws"):
        if int(getattr(st, name)) < 1:
            raise ParameterError(f"{name} must be >= 1, got {getattr(st, name)}")


def diagnose(
    data: Dataset | Record,
    model: HysteresisModel | str,
    likelihood: str = "gaussian",
    *,
    effects: Sequence[str] | None = None,
    alpha: float = 0.01,
    threshold: float = 2.0,
    max_rounds: int = 6,
    max_candidates: int = 2,
    sampler: SamplerSettings | None = None,
    n_draws: int = 200,
    max_refits: int = 5,
    checkpoint_dir: str | Path | None = None,
    on_fit: Callable[[DiagnosisFit], None] | None = None,
) -> DiagnosisResult:
    """Find what a fitted model misses, add it, refit, and report the error before and after.

    Parameters
    ----------
    data : Dataset or Record
        Measured records (frequencies in the metadata make the per-frequency report).
    model : HysteresisModel or str
        Base model or spec string (``"bouc_wen"``, ``"pi_play(n_operators=8)"``).
    likelihood : str
        Base likelihood; ``colored_noise`` switches it to ``"ar1"``.
    effects : sequence of str, optional
        Candidate effects (default all: creep, rate_dependence, asymmetry, drift, delay,
        colored_noise).
    alpha : float
        Family-wise level of the residual tests (Holm over the effects of a round).
    threshold : float
        Standard errors by which the augmented model's cycle-wise elpd must exceed the
        current one's for the effect to be kept.
    max_rounds : int
        Most effects added.
    max_candidates : int
        Fired effects refitted per round before giving up on the round.
    sampler : SamplerSettings, optional
        How every fit is sampled (:func:`~bayeshyst.inference.sampling.sample_posterior`);
        each fit's seed derives from ``sampler.seed`` and what the fit is
        (:func:`~bayeshyst.selection.tasks.fit_sampler`): same seed, same result.
    n_draws : int
        Posterior draws averaged for predictions and residuals.
    max_refits : int
        Cycles per fit whose PSIS-LOO is unreliable (Pareto k > 0.7) that are refitted
        exactly, worst first (each refit costs a fit).
    checkpoint_dir : path, optional
        Each fit checkpoints here (``<identity>.h5``); a rerun resumes finished fits,
        and a fit another command made with the same data and settings into the same
        folder (the comparison's joint fit) is reused, not sampled again.
    on_fit : callable, optional
        Called with every :class:`DiagnosisFit` as it completes (progress reports).

    Returns
    -------
    DiagnosisResult
    """
    if isinstance(data, Record):
        data = Dataset((data,), name=data.name)
    if not isinstance(data, Dataset):
        raise DataError(f"data must be a Dataset or Record, got {type(data).__name__}")
    st = DiagnosisSettings(
        effects=tuple(EFFECTS) if effects is None else tuple(effects), alpha=float(alpha),
        threshold=float(threshold), max_rounds=int(max_rounds),
        max_candidates=int(max_candidates),
        sampler=SamplerSettings() if sampler is None else sampler, n_draws=int(n_draws),
        max_refits=int(max_refits))
    _check_settings(st)
    base_label = model if isinstance(model, str) else model.name
    base_model = get_model(model) if isinstance(model, str) else model
    likelihood = get_likelihood(likelihood).name
    ckdir = None if checkpoint_dir is None else Path(checkpoint_dir)
    if ckdir is not None:
        ckdir.mkdir(parents=True, exist_ok=True)

    def fit(m: HysteresisModel, lik: str, label: str,
            warm: tuple[DiagnosisFit, dict[str, Any]] | None = None) -> DiagnosisFit:
        f = _fit(data, m, lik, label, st, ckdir, warm)
        if on_fit is not None:
            on_fit(f)
        return f

    def lab(spec: str, lik: str) -> str:
        return spec if lik == "gaussian" else f"{spec} with likelihood {lik}"

    current = fit(base_model, likelihood, lab(base_label, likelihood))
    base, spec = current, base_label
    rounds, steps, found = [current.analysis], [], []
    warnings = list(current.warnings)
    for rnd in range(1, st.max_rounds + 1):
        fired = current.analysis.fired()
        if not fired:
            break
        accepted = None
        for test in fired[:st.max_candidates]:
            eff = get_effect(test.effect)
            new_model, new_lik, suffix = eff.augment(current.model, current.likelihood,
                                                     test.coef, data)
            new_spec = spec if suffix.startswith(" ") else spec + suffix
            cand = fit(new_model, new_lik, lab(new_spec, new_lik),
                       (current, eff.initial(test.coef, test.estimates)))
            warnings += [w for w in cand.warnings if w not in warnings]
            d, se = paired_difference(cand.pointwise_elpd, current.pointwise_elpd)
            ok = bool(math.isfinite(d) and math.isfinite(se) and d > st.threshold * se
                      and d > 0)
            reason = (f"held-out elpd improves by {d:.1f} > {st.threshold:g} x se {se:.1f}"
                      if ok else f"held-out elpd changes by {d:.1f} (se {se:.1f}), not above "
                      f"{st.threshold:g} x se")
            _log.info("round %d: %s %s (%s)", rnd, test.effect,
                      "accepted" if ok else "rejected", reason)
            per = tuple(zip(current.per_frequency, cand.per_frequency, strict=True))
            steps.append(DiagnosisStep(rnd, test.effect, test, current.label, cand.label, ok,
                                       reason, current.overall, cand.overall, per, d, se,
                                       _added(cand, current), cand.sampling.converged))
            if ok:
                accepted = (cand, new_spec)
                break
        if accepted is None:
            break
        current, spec = accepted
        found.append(steps[-1].effect)
        rounds.append(current.analysis)
    return DiagnosisResult(base.label, current.label, tuple(found), tuple(steps), base,
                           current, tuple(rounds), st, tuple(warnings))
