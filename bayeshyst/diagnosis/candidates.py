"""The candidates beyond the catalogue and the gate every candidate passes or fails.

The base model's own branch shape (when the driver scan keeps the loop position), a
periodic disturbance (a spectral line) and, last, a smooth term in a feature no block
explains (time, a measured column: structure reported as *unexplained*) join the fired
effects as candidates;
:func:`judge` keeps an augmented fit or not (held-out elpd, or its documented fallback,
plausibility, ties; :mod:`bayeshyst.diagnosis.verdict`); :func:`pair_for` picks two
effects to try together when each alone lost the gate on cycles the other explains.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from bayeshyst.diagnosis.drivers import DriverRelevance
from bayeshyst.diagnosis.records import (
    UNEXPLAINED,
    DiagnosisFit,
    DiagnosisSettings,
    DiagnosisStep,
)
from bayeshyst.diagnosis.residual import EffectTest
from bayeshyst.diagnosis.verdict import (
    BRANCH_SHAPE,
    BY_RESOLUTION,
    FALLBACK_LOG_BF,
    LAG_LIKE,
    MIN_ELPD_GAIN,
    MIN_GATE_UNITS,
    NOT_CONVERGED,
    SCREEN,
    experiment_for,
    implausible,
    passes_gate,
    separates_lags,
    shape_tied,
    tied_effects,
    unresolved,
    unresolved_throughout,
)
from bayeshyst.inference.sampling_result import ParamSummary, SamplingResult
from bayeshyst.models.blocks.smooth import TIME
from bayeshyst.selection import paired_difference

__all__ = ["BRANCH_SHAPE", "DISTURBANCE", "SCAN_JUDGED", "SHAPE_DISCREPANCY", "UNEXPLAINED",
           "added_names", "added_parameters", "judge", "line_candidate", "pair_for",
           "shape_candidate", "unexplained_candidate", "unresolved_added"]


#: The discrepancy that stands for it: a smooth function of where on the loop a sample is.
SHAPE_DISCREPANCY = "hsgp"


def shape_candidate(current: DiagnosisFit, alpha: float) -> EffectTest | None:
    """The base model's branch-shape misfit as a candidate, when the driver scan finds it.

    Returned as an :class:`EffectTest` named :data:`BRANCH_SHAPE` carrying the scan's
    numbers (held-out gain, randomisation p-value); None when the loop position is not
    among the drivers the scan kept.
    """
    scan = current.analysis.drivers
    if scan is None or not scan.found:
        return None
    for d in scan.selected:
        if d.driver == "loop position":
            return _scan_test(BRANCH_SHAPE, d, alpha)
    return None


def _scan_test(name: str, d: DriverRelevance, alpha: float, variant: str = "") -> EffectTest:
    """A kept driver as a candidate: the scan's held-out gain and randomisation p-value."""
    nan = math.nan
    return EffectTest(name, "held-out gain (%)", d.conditional_percent, 0, 0, d.p_value,
                      d.p_value, nan, d.conditional_percent / 100.0, nan, nan, {},
                      {"heldout_gain_percent": d.conditional_percent},
                      bool(d.p_value < alpha), variant=variant)


#: Name of a periodic disturbance (a spectral line) among the loop's candidates.
DISTURBANCE = "disturbance"


def line_candidate(current: DiagnosisFit, alpha: float) -> EffectTest | None:
    """The strongest spectral line of the residual as a candidate (None without one).

    Lines within a frequency bin of a disturbance the model already has are skipped.
    """
    model = current.model
    have = [b.frequency_hz for b in getattr(model, "blocks", ()) if b.name == DISTURBANCE]
    tol = 1.0 / max(float(np.ptp(current.analysis.time[0])), 1e-12)  # one frequency bin
    for line in current.analysis.lines:
        if any(abs(line.frequency_hz - f) <= tol for f in have):
            continue
        nan = math.nan
        return EffectTest(DISTURBANCE, "spectral line", line.share_percent, 0, 0,
                          line.p_value, line.p_value, nan, line.share_percent / 100.0,
                          line.amplitude / math.sqrt(2.0), nan, {},
                          {"frequency_hz": line.frequency_hz, "amplitude": line.amplitude},
                          bool(line.p_value < alpha), variant=f"{line.frequency_hz:.6g}")
    return None


def unexplained_candidate(current: DiagnosisFit, alpha: float) -> EffectTest | None:
    """A smooth term in a feature the residual depends on and no block explains.

    The first driver the scan kept that is the time since the record started or a
    measured column, and that the model has no smooth term in yet, as an
    :class:`EffectTest` named :data:`UNEXPLAINED` (variant: the feature) carrying the
    scan's numbers. Loop position (the shape candidate) and the rate-like drivers
    (rate dependence, creep and their tests) have their own candidates; None when
    nothing else is left.
    """
    scan = current.analysis.drivers
    if scan is None or not scan.found:
        return None
    have = {b.feature for b in getattr(current.model, "blocks", ())
            if b.name == UNEXPLAINED}
    for d in scan.selected:
        if not (d.driver == TIME or d.kind == "external") or d.driver in have:
            continue
        return _scan_test(UNEXPLAINED, d, alpha, variant=d.driver)
    return None


#: Candidates judged by the residual scan's own test when the elpd gate cannot decide.
SCAN_JUDGED = (BRANCH_SHAPE, DISTURBANCE, UNEXPLAINED)


def judge(rnd: int, test: EffectTest, current: DiagnosisFit, cand: DiagnosisFit,
           st: DiagnosisSettings) -> DiagnosisStep:
    """Keep the augmented fit or not: held-out elpd, or the fallback when it cannot decide.

    A passed gate is no finding when the added block's reading is implausible or
    unresolved (:mod:`bayeshyst.diagnosis.verdict`); an augmented fit that did not
    converge decides nothing (``decided_by`` :data:`NOT_CONVERGED`).
    """
    d, se = paired_difference(cand.pointwise_elpd, current.pointwise_elpd)
    n_units = current.posterior.n_units
    better = cand.overall.rmse < current.overall.rmse
    if n_units >= MIN_GATE_UNITS and math.isfinite(d) and math.isfinite(se):
        decided_by = "elpd"
        ok = passes_gate(d, se, st.threshold)
        if ok:
            # the se in the same form as the other outcomes': "> 2 x se 99.1" read as
            # 2 se = 99.1. 'z' prints a change that rounds to zero as 0.0, not -0.0
            reason = (f"held-out elpd improves by {d:z.1f} (se {se:.1f}), above "
                      f"{st.threshold:g} x se")
        elif d > st.threshold * se:
            reason = (f"held-out elpd improves by {d:z.1f} (se {se:.1f}), under the "
                      f"{MIN_ELPD_GAIN:g} nats below which a gain is negligible")
        else:
            reason = (f"held-out elpd changes by {d:z.1f} (se {se:.1f}), not above "
                      f"{st.threshold:g} x se")
    else:
        cannot = (f"held-out elpd cannot decide on these data ({n_units} cycles, fewer than "
                  f"{MIN_GATE_UNITS}; change {d:.3g}, se {se:.3g})")
        if test.effect in SCAN_JUDGED:
            decided_by = "residual scan"
            ok = bool(test.p_value < st.alpha and better)
            reason = (f"{cannot}; the residual scan's calibrated test ({test.statistic}, "
                      f"p = {test.p_value:.3g}) and the error "
                      f"({current.overall.rmse:.4g} -> {cand.overall.rmse:.4g}) decide")
        else:
            decided_by = "bic"
            lbf = test.log_bayes_factor
            ok = bool(math.isfinite(lbf) and lbf > FALLBACK_LOG_BF and better)
            reason = (f"{cannot}; the score test's BIC Bayes factor decides: log BF "
                      f"{lbf:.1f} {'>' if lbf > FALLBACK_LOG_BF else '<='} {FALLBACK_LOG_BF:g}"
                      f" and the error {current.overall.rmse:.4g} -> {cand.overall.rmse:.4g}")
    added = added_parameters(cand, current)
    gate = reason  # the gate's own words, before a reading overrides them
    if ok:
        means: dict[str, list[float]] = {}
        for p in added:
            means.setdefault(p.label.split("[")[0], []).append(p.mean)
        bad = implausible(means, st.plausible)
        hidden = unresolved(added, current.posterior.data) if not bad else []
        if bad:
            # each reading says why it is implausible (the ranges are the device's)
            ok, reason = False, "implausible: " + "; ".join(bad)
        elif hidden:
            ok, reason = False, "unresolved: " + "; ".join(hidden)
    if not cand.sampling.converged and not st.decide_unconverged:
        # kept or rejected, the verdict would rest on draws that are not yet the
        # posterior (MR damper 0.5 A: a delay on the shape correction, R-hat 1.018 after
        # 10 000 steps, "rejected" at -117 +- 56 nats): it is not decided -- unless the
        # block's resonance is above Nyquist in every ensemble, which no gate and no
        # longer run can make a finding
        hidden = unresolved_added(cand.sampling, [p.label.split("[")[0] for p in added],
                                  current.posterior.data)
        ok = False
        if hidden:
            decided_by = BY_RESOLUTION
            reason = ("unresolved: " + "; ".join(hidden) + f" (its gate, which decides "
                      f"nothing unconverged: {gate})")
        else:
            decided_by = NOT_CONVERGED
            reason = (f"not decided: the augmented fit did not converge within its budget, "
                      f"so its gate ({gate}) rests on an unconverged posterior; a larger "
                      f"step budget would decide")
    tied: list[str] = []
    if ok and test.effect not in SCAN_JUDGED:
        tied = tied_effects(test.effect, current.analysis.tests)
        if test.effect in LAG_LIKE and not separates_lags(current.posterior.data):
            # one sine, no hold: by design, every lag-like effect that fired is the same
            tied += [t.effect for t in current.analysis.tests if t.significant
                     and t.effect in LAG_LIKE and t.effect not in (test.effect, *tied)]
        if test.effect in LAG_LIKE and shape_tied(current.analysis.drivers):
            tied.append(BRANCH_SHAPE)
    per = tuple(zip(current.per_frequency, cand.per_frequency, strict=True))
    return DiagnosisStep(rnd, test.effect, test, current.label, cand.label, ok, reason,
                         current.overall, cand.overall, per, d, se, added,
                         cand.sampling.converged, tuple(tied),
                         experiment_for(test.effect, tied[0]) if tied else "", decided_by)


def added_parameters(fit: DiagnosisFit, before: DiagnosisFit) -> tuple[ParamSummary, ...]:
    """Posterior summaries of the parameters the augmentation added."""
    summary = fit.sampling.summary()
    new = set(added_names([p.label.split("[")[0] for p in summary], before))
    return tuple(p for p in summary if p.label.split("[")[0] in new)


def added_names(names: Sequence[str], before: DiagnosisFit) -> list[str]:
    """The parameter names among ``names`` that ``before``'s posterior does not have.

    A composite carries the previous model's parameters under ``static.``.
    """
    def base(name: str) -> str:
        return name.removeprefix("static.")

    old = {base(n) for n in before.posterior.space.names}
    return [n for n in names if base(n) not in old]


def unresolved_added(sampling: SamplingResult, names: Sequence[str], data: Any) -> list[str]:
    """:func:`unresolved_throughout` for the natural frequencies among ``names``.

    ``names``: the parameters an augmentation added (:func:`added_names`); each
    ensemble's last half decides, so an unconverged fit is read as it stands.
    """
    resonances = sorted({n for n in names if n.endswith(".f_n")})
    if not resonances:
        return []
    return unresolved_throughout(sampling.ensemble_summaries(resonances), data)


def pair_for(tried: Sequence[tuple[EffectTest, DiagnosisFit, DiagnosisStep]],
             untried: Sequence[EffectTest], current: DiagnosisFit,
             pairable: Sequence[str], first: int | None = None
             ) -> tuple[int, EffectTest] | None:
    """Two effects to fit together when every candidate of a round lost the gate.

    One noise scale serves every cycle: an effect that explains the fast cycles (a
    delay) tightens it and then loses on the slow cycles whose misfit another effect
    (creep) explains, and the other way round -- each alone fails the held-out gate,
    together they may pass it (the bundled virtual actuator: +1 100 +- 750 and +207 +-
    409 nats alone, +3 420 +- 549 together). Returns the index in ``tried`` of the
    first effect and its partner's test, or None.

    The first is the rejected candidate that the gate judged on held-out cycles (its fit's
    or its screen's, :mod:`bayeshyst.diagnosis.screen`: the caller samples a screened
    first before the pair) and
    that gained most on the whole (more than :data:`MIN_ELPD_GAIN`) while *losing* on
    some cycles -- without such cycles a partner is no remedy. Its partner is the
    tried candidate that gained most on those cycles, if one gained there at all, else
    the first candidate of the round not tried yet. Both must be in ``pairable``
    (blocks of the catalogue: not the noise model, which changes the likelihood),
    plausible, resolved and, when tried, converged. The pair is then fitted and gated
    like any candidate. ``first``: only that entry of ``tried`` may be the first effect
    (a screened first chosen earlier and sampled since).
    """
    def usable(step: DiagnosisStep) -> bool:
        return (step.effect in pairable and not step.accepted and not step.refused
                and step.decided_by != NOT_CONVERGED)

    firsts = [i for i, (_, _, step) in enumerate(tried)
              if usable(step) and step.decided_by in ("elpd", SCREEN)
              and step.delta_elpd > MIN_ELPD_GAIN and first in (None, i)]
    if not firsts or current.pointwise_elpd is None:
        return None
    a = max(firsts, key=lambda i: tried[i][2].delta_elpd)
    test_a, fit_a, _ = tried[a]
    losing = (fit_a.pointwise_elpd - current.pointwise_elpd) < 0.0
    if not losing.any():
        return None
    gains = {i: float(np.sum((fit.pointwise_elpd - current.pointwise_elpd)[losing]))
             for i, (t, fit, step) in enumerate(tried)
             if i != a and usable(step) and t.effect != test_a.effect
             and fit.pointwise_elpd is not None}
    best = max(gains, key=gains.__getitem__, default=None)
    if best is not None and gains[best] > 0.0:
        return a, tried[best][0]
    for t in untried:
        if t.effect in pairable and t.effect != test_a.effect:
            return a, t
    return None
