"""The records of a diagnosis: its settings, each fit, each step tried, the result.

:func:`~bayeshyst.diagnosis.loop.diagnose` returns a :class:`DiagnosisResult`; its
``to_dict`` is the ``summary.json`` of ``bayeshyst diagnose``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np

from bayeshyst.diagnosis.catalogue import EFFECTS
from bayeshyst.diagnosis.residual import EffectTest, ResidualAnalysis
from bayeshyst.diagnosis.verdict import (
    NOT_A_FINDING,
    NOT_CONVERGED,
    PLAUSIBLE,
    refused_findings,
)
from bayeshyst.inference.fit import FitResult, TrackingError
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling_result import ParamSummary, SamplingResult
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.models.base import HysteresisModel
from bayeshyst.tables import TableRecord, frame

__all__ = ["UNEXPLAINED", "DiagnosisFit", "DiagnosisResult", "DiagnosisSettings", "DiagnosisStep"]

#: Name of structure no block explains, given a smooth term in the feature it follows
#: (:func:`bayeshyst.diagnosis.candidates.unexplained_candidate`).
UNEXPLAINED = "unexplained"


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
    n_permutations: int = 999
    plausible: Mapping[str, tuple[float, float, str]] = field(default_factory=lambda: PLAUSIBLE)
    decide_unconverged: bool = False
    budget_doublings: int = 1
    screen: bool = False

    def __getstate__(self) -> dict[str, Any]:
        # a mappingproxy (the default ranges) does not pickle, and the settings travel to
        # the diagnosis' worker processes: the ranges go as a dict, read-only again there
        return {**self.__dict__, "plausible": dict(self.plausible)}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update({**state, "plausible": MappingProxyType(dict(state["plausible"]))})

    @property
    def seed(self) -> int:
        """The diagnosis' seed (the sampler settings')."""
        return self.sampler.seed

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready settings: every field (tuples as lists), the sampler's dict, the seed."""
        out = {k: (list(v) if isinstance(v, tuple) else v)
               for k, v in self.__dict__.items() if k not in ("sampler", "plausible")}
        out["plausible"] = {k: {"low": lo, "high": hi, "why": why}
                            for k, (lo, hi, why) in self.plausible.items()}
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
    tied_with : tuple of str
        Effects (or ``"branch shape"``) that explain the same residual within the
        evidence's resolution: the data cannot tell them from this one.
    experiment : str
        What would tell them apart (empty without a tie).
    decided_by : str
        ``"elpd"`` (held-out cycles), ``"bic"`` (the score test's Bayes factor, when
        the cycles are too few for the elpd gate), ``"residual scan"`` (the driver
        scan's or the spectral test's own calibrated p-value, for the branch shape and a
        disturbance), ``"not converged"`` (nothing decided: the augmented fit did not
        converge), ``"resolution"`` (the augmented fit did not converge, but the
        resonance it adds lies above Nyquist in every ensemble: refused as unresolved)
        or ``"screen"`` (rejected from the candidate's MAP without sampling it,
        :mod:`bayeshyst.diagnosis.screen`; ``after`` is then the MAP's error and
        ``added_parameters`` is empty).
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
    tied_with: tuple[str, ...] = ()
    experiment: str = ""
    decided_by: str = "elpd"

    @property
    def outcome(self) -> str:
        """``"accepted"``, ``"rejected"`` or ``"not decided"`` (the fit did not converge)."""
        if self.accepted:
            return "accepted"
        return "not decided" if self.decided_by == NOT_CONVERGED else "rejected"

    @property
    def refused(self) -> bool:
        """Whether the reading is no finding (implausible, unresolved) however the gate went.

        The gate passed, or (``decided_by`` ``"resolution"``) the fit did not converge
        and its resonance lies above Nyquist in every ensemble.
        """
        return not self.accepted and self.reason.startswith(NOT_A_FINDING)

    def verdict(self, accepted: str = "accepted") -> str:
        """``"<outcome> (<reason>)"``, the reason without the outcome it may start with.

        ``accepted`` is the word for an accepted step (``"ACCEPTED"`` in a report).
        """
        word = accepted if self.accepted else self.outcome
        reason = self.reason
        if reason.startswith(f"{self.outcome}: "):
            reason = reason[len(self.outcome) + 2:]
        return f"{word} ({reason})"

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
            "accepted": self.accepted, "outcome": self.outcome, "reason": self.reason,
            "round": self.index,
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
            "converged": self.converged, "tied_with": list(self.tied_with),
            "experiment": self.experiment, "decided_by": self.decided_by,
        }

    def __str__(self) -> str:
        lines = [f"round {self.index}: {self.effect} -> {self.model_after}: "
                 f"{self.verdict('ACCEPTED')}",
                 f"  test: {self.test}",
                 f"  RMSE {self.before.rmse:.4g} -> {self.after.rmse:.4g}, max "
                 f"{self.before.max_error:.4g} -> {self.after.max_error:.4g}; "
                 f"delta elpd {self.delta_elpd:.1f} +- {self.delta_elpd_se:.1f}"]
        for b, a in self.per_frequency:
            if b.frequency_hz is not None:
                lines.append(f"  {b.frequency_hz:>8g} Hz: RMSE {b.rmse:.4g} -> {a.rmse:.4g}, "
                             f"max {b.max_error:.4g} -> {a.max_error:.4g}")
        lines += [f"  {p}" for p in self.added_parameters]
        if self.tied_with:
            lines.append(f"  cannot tell {self.effect} from {', '.join(self.tied_with)} on these "
                         f"data; what would: {self.experiment}")
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
    warnings : tuple of str
    ties : tuple of str
        Effects that fired but were not tried because they explain nothing beyond the
        base model's branch shape, in words with the experiment that would separate them.
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
    ties: tuple[str, ...] = ()

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
            "verdict": self.verdict,
            "ties": list(self.ties),
            "remaining": _remaining(self.final.analysis),
            "remaining_before": _remaining(self.base.analysis),
            "warnings": list(self.warnings),
            "settings": self.settings.to_dict(),
        }

    @property
    def verdict(self) -> str:
        """What the loop found and what is left, in words (never "explained" by default).

        "The base model explains the data" only when no test fired on its residual and
        the residual depends on no observed driver and shows no line.
        """
        first, last = self.rounds[0], self.final.analysis
        if not self.effects_found:
            if not first.fired() and not first.structure_left:
                return ("the base model explains the data: no effect's test fires, the "
                        "residual depends on no observed driver and shows no spectral line")
            tried = [s.effect for s in self.steps]
            head = ("no effect was kept" + (f" (tried: {', '.join(tried)})" if tried else "")
                    + "; ")
        else:
            # a pair kept together is named "a+b" (bayeshyst.diagnosis.candidates.pair_for)
            kept = [(s, s.effect.split("+")) for s in self.steps if s.accepted]
            named = [e for _, parts in kept for e in parts if e != UNEXPLAINED]
            smooth = [f"unexplained structure depending on {s.test.variant} (the smooth term "
                      f"took {s.test.value:.1f} % of the residual's held-out variance; RMSE "
                      f"{s.before.rmse:.4g} -> {s.after.rmse:.4g})"
                      for s, parts in kept if UNEXPLAINED in parts]
            head = "; ".join(([f"effects found: {', '.join(named)}"] if named else [])
                             + smooth) + "; "
        fired = [t.effect for t in last.fired()]
        left = []
        if last.structure_left:
            left.append("unexplained structure: " + last.remaining())
        if fired:
            left.append(f"tests still firing on the final residual: {', '.join(fired)}")
        # a refused reading (implausible, unresolved) is no finding, but the structure
        # it explained is left in the residual: say how much
        left.extend(refused_findings(self.steps, self.final.label))
        ties = [f"cannot tell {s.effect} from {', '.join(s.tied_with)} ({s.experiment})"
                for s in self.steps if s.accepted and s.tied_with] + list(self.ties)
        if self.undecided:
            ties.append(f"not decided, because its fit did not converge within the step "
                        f"budget: {', '.join(s.effect for s in self.undecided)}")
        tail = "; ".join(left) if left else "nothing detectable is left in the residual"
        return head + tail + ("; " + "; ".join(ties) if ties else "")

    @property
    def undecided(self) -> tuple[DiagnosisStep, ...]:
        """The steps whose gate decided nothing (their fit did not converge).

        A step stops counting once a later step of the same effect decided (the
        micromanipulator's second-order candidate: unconverged in round 5, converged and
        refused in round 6).
        """
        out = []
        for i, s in enumerate(self.steps):
            later = self.steps[i + 1:]
            if s.decided_by == NOT_CONVERGED and not any(
                    t.effect == s.effect and t.decided_by != NOT_CONVERGED for t in later):
                out.append(s)
        return tuple(out)

    def _round_labels(self) -> list[str]:
        labels = [self.base_model]
        labels += [s.model_after for s in self.steps if s.accepted]
        return labels[:len(self.rounds)]

    def __str__(self) -> str:
        lines = [f"diagnosis of {self.base_model}: {self.verdict}",
                 f"final model: {self.final_model}",
                 f"error before: {self.base.overall}", f"error after:  {self.final.overall}"]
        for lab, r in zip(self._round_labels(), self.rounds, strict=True):
            lines += [f"-- tests on the residual of {lab} (AR({r.ar_order}) whitening)", str(r)]
        lines += [str(s) for s in self.steps]
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)


def _remaining(analysis: ResidualAnalysis) -> dict[str, Any]:
    """The driver scan and spectral lines of a residual, JSON-ready."""
    return {"drivers": None if analysis.drivers is None else analysis.drivers.to_dict(),
            "lines": [x.to_dict() for x in analysis.lines],
            "structure_left": analysis.structure_left}
