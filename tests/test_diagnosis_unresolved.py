"""An unconverged fit whose resonance lies above Nyquist in every ensemble is unresolved.

Oracles: summaries of draws built by hand (each ensemble's last half is known, so its
mean and the mass of its interval are computed here directly); stub intervals placed on
either side of the 100 Hz Nyquist frequency of records sampled at 50 and 200 Hz; and,
for the loop's wiring, a convergence rule imposed on the real sampler (as in
``test_diagnosis_budget``) so the test knows which runs the loop must make.
"""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace as NS

import numpy as np
import pytest

from bayeshyst.diagnosis.verdict import (
    BY_RESOLUTION,
    NOT_CONVERGED,
    refused_findings,
    unresolved_throughout,
)
from bayeshyst.errors import ParameterError
from bayeshyst.inference.convergence import ConvergenceReport
from bayeshyst.inference.optimize import MAPResult
from bayeshyst.inference.posterior import EvalCounts
from bayeshyst.inference.sampling_result import ParamSummary, SamplingResult
from bayeshyst.params import Param, ParamSpace
from bayeshyst.params.priors import LogNormal, Normal
from tests.test_diagnosis_budget import BASE, STEPS, TINY, _drifting
from tests.test_diagnosis_verdict import _resonance, _two_rates


def _result(chains: np.ndarray) -> SamplingResult:
    space = ParamSpace((Param("k", Normal(0.0, 1.0)),
                        Param("second_order.f_n", LogNormal.from_median(10.0, 1.0),
                              unit="Hz")))
    conv = ConvergenceReport(2.0, 10.0, 10.0, 1.0, chains.shape[1], 0, False)
    start = MAPResult(chains[0, -1, 0], space.unpack(chains[0, -1, 0]), 0.0,
                      np.eye(2), True, 0)
    return SamplingResult(space, chains, np.zeros(chains.shape[:3]), conv, start,
                          EvalCounts(0, 0, 0), np.full(chains.shape[2], 0.3), 1.0, "m", "gaussian",
                          0)


def test_each_ensemble_is_summarised_alone_over_its_last_half():
    # ensemble 0 sat at 50 Hz for its first half and moved to 150-300 Hz; ensemble 1
    # is at 400-500 Hz throughout. Pooled, the interval would reach down to 50 Hz
    rng = np.random.default_rng(0)
    steps, walkers = 400, 8
    f0 = np.concatenate([np.full((steps // 2, walkers), 50.0),
                         rng.uniform(150.0, 300.0, (steps // 2, walkers))])
    f1 = rng.uniform(400.0, 500.0, (steps, walkers))
    k = rng.standard_normal((2, steps, walkers))
    chains = np.stack([np.stack([k[0], np.log(f0)], -1), np.stack([k[1], np.log(f1)], -1)])
    res = _result(chains)
    per = res.ensemble_summaries(["second_order.f_n"])
    assert [[p.label for p in e] for e in per] == [["second_order.f_n"]] * 2
    for (p,), f in zip(per, (f0, f1), strict=True):
        last = f[steps // 2:].ravel()
        assert p.mean == pytest.approx(last.mean(), rel=1e-12) and p.unit == "Hz"
        inside = np.mean((last >= p.hdi_lo) & (last <= p.hdi_hi))
        assert 0.9 <= inside <= 0.9 + 2.0 / last.size
    assert per[0][0].hdi_lo >= 150.0
    # the whole of ensemble 0 includes the 50 Hz half
    (whole,), _ = res.ensemble_summaries(["second_order.f_n"], last=1.0)
    assert whole.mean == pytest.approx(f0.mean(), rel=1e-12)
    with pytest.raises(ParameterError, match=r"no free parameters \['zeta'\]"):
        res.ensemble_summaries(["zeta"])
    with pytest.raises(ParameterError, match="last must be a fraction in"):
        res.ensemble_summaries(["k"], last=0.0)


@pytest.mark.parametrize("spans, flagged", [
    (((149.0, 294.0), (148.7, 293.9)), True),   # the MR damper at 1 A: both above
    (((101.0, 120.0), (300.0, 900.0)), True),   # different modes, both above
    (((149.0, 294.0), (83.0, 294.0)), False),   # one ensemble reaches below 100 Hz
    (((30.0, 50.0), (30.0, 50.0)), False),
    ((), False),                                # no ensembles: nothing to read
])
def test_a_resonance_is_unresolved_throughout_only_if_every_ensemble_is_above_nyquist(
        spans, flagged):
    other = ParamSummary("second_order.zeta", "1", 0.05, 0.01, 0.03, 0.07)
    words = unresolved_throughout([[_resonance(*s), other] for s in spans], _two_rates())
    assert bool(words) == flagged
    if flagged:
        (w,) = words
        assert w.startswith("second_order.f_n lies above") and "at most 100 Hz" in w
        assert "each of the 2 ensembles" in w and "did not converge" in w
        assert all(f"{lo:.3g}-{hi:.3g} Hz" in w for lo, hi in spans)
        assert f"faster than {2 * max(hi for _, hi in spans):.3g} Hz" in w


def _stub_fit(elpd, rmse, *, converged=True, spans=()):
    from bayeshyst.inference.fit import TrackingError

    err = TrackingError(None, rmse, 2 * rmse, 1.0, 2.0, 100)
    pooled = (_resonance(min(s[0] for s in spans), max(s[1] for s in spans)),) if spans else ()
    sampling = NS(converged=converged, summary=lambda: pooled,
                  ensemble_summaries=lambda names: [[_resonance(*s)] for s in spans
                                                    if "second_order.f_n" in names])
    return NS(pointwise_elpd=np.asarray(elpd, float), overall=err, per_frequency=(err,),
              posterior=NS(n_units=len(elpd), space=NS(names=("k",)), data=_two_rates()),
              sampling=sampling, label="m", spec="m", model=NS(name="m"),
              analysis=NS(tests=(), drivers=None))


@pytest.mark.parametrize("gain", [50.0, -50.0])
@pytest.mark.parametrize("spans, decided_by", [
    (((149.0, 294.0), (148.7, 293.9)), BY_RESOLUTION),
    (((149.0, 294.0), (83.0, 294.0)), NOT_CONVERGED),
])
def test_an_unconverged_resonance_above_nyquist_everywhere_is_refused_whatever_its_gate(
        spans, decided_by, gain):
    # oracle: 12 cycles gaining (or losing) 50 nats each; the gate's verdict, either
    # way, rests on an unconverged posterior. Only an interval above 100 Hz in both
    # ensembles is read (refused as unresolved); one reaching below leaves it undecided
    from bayeshyst.diagnosis.candidates import judge
    from bayeshyst.diagnosis.records import DiagnosisSettings
    from bayeshyst.diagnosis.residual import EffectTest

    test = EffectTest("rate_dependence", "F", 1.0, 1, 100, 0.0, 0.0, 40.0, 0.1,
                      float("nan"), float("nan"), {}, {}, True)
    jitter = 1e-3 * np.sin(np.arange(12))
    current = _stub_fit(np.full(12, -50.0), 1.0)
    cand = _stub_fit(np.full(12, -50.0 + gain) + jitter, 0.5, converged=False, spans=spans)
    step = judge(1, test, current, cand, DiagnosisSettings())
    assert not step.accepted and not step.converged
    assert step.decided_by == decided_by, step.reason
    words = refused_findings([step], current.label)
    if decided_by == BY_RESOLUTION:
        assert step.refused and step.outcome == "rejected"
        assert step.reason.startswith("unresolved: second_order.f_n lies above")
        assert "its gate, which decides nothing unconverged: held-out elpd" in step.reason
        # the verdict does not say it would explain anything: its gate decided nothing
        assert words == (f"rate_dependence is not credited: {step.reason}",)
    else:
        assert not step.refused and step.outcome == "not decided" and words == ()


# ------------------------------------------------ the loop: no second run for such a fit
def test_the_loop_does_not_sample_such_a_candidate_again(tmp_path, monkeypatch):
    # the real sampler never converges here (its flag is forced off), so every fit
    # would be run twice; the candidate's added block is declared unresolved
    # throughout (a stand-in for a resonance above Nyquist: the rule itself is tested
    # above), so only the base fit is run again
    import bayeshyst.diagnosis.candidates as candidates
    from bayeshyst.diagnosis import _fitting, diagnose

    runs, seen = [], []
    real = _fitting.sample_posterior

    def sample(post, settings, **kw):
        runs.append(settings.max_steps)
        res = real(post, settings, **kw)
        return dataclasses.replace(
            res, convergence=dataclasses.replace(res.convergence, converged=False))

    def unseen(sampling, names, data):
        seen.append(tuple(names))
        return ["drift.x lies above every record's Nyquist frequency"] if names else []

    monkeypatch.setattr(_fitting, "sample_posterior", sample)
    monkeypatch.setattr(_fitting, "unresolved_added", unseen)
    monkeypatch.setattr(candidates, "unresolved_added", unseen)
    # screen=False: what is tested is the sampled candidate's second run (a screen
    # could reject the drift from its MAP, and it would not be sampled at all)
    result = diagnose(_drifting(), BASE, effects=("drift",), max_rounds=1, max_candidates=1,
                      sampler=TINY, n_draws=20, max_refits=0, n_permutations=0,
                      checkpoint_dir=tmp_path, screen=False)
    assert runs == [STEPS, 2 * STEPS, STEPS]  # base twice, the candidate once
    (step,) = result.steps
    # the loop passed the names the candidate added, none of the base's
    assert any(seen) and all(n.startswith("drift.") for names in seen for n in names)
    assert step.decided_by == BY_RESOLUTION and step.refused, step.reason
    assert any("not sampled again, because the natural frequency it adds" in w
               for w in result.warnings), result.warnings
    assert result.effects_found == ()
