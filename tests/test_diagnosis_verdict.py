"""The verdict rules on constructed cases: ties within 3 nats, the loop position tied with
a time since reversal, plausibility ranges, the experiment that separates two effects."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from bayeshyst.diagnosis.drivers import DriverRelevance, DriverScan
from bayeshyst.diagnosis.residual import EffectTest
from bayeshyst.diagnosis.verdict import (
    PLAUSIBLE,
    TIE_NATS,
    experiment_for,
    implausible,
    shape_tied,
    tied_effects,
)


def _test(effect: str, log_bf: float, significant: bool = True) -> EffectTest:
    nan = math.nan
    return EffectTest(effect, "F", 1.0, 1, 100, 0.0, 0.0, log_bf, 0.1, nan, nan, {}, {},
                      significant)


def test_lag_like_effects_within_three_nats_are_tied_and_others_are_not():
    tests = [_test("creep", 40.0), _test("delay", 40.0 - 0.9 * TIE_NATS),
             _test("rate_dependence", 40.0 - 1.1 * TIE_NATS), _test("asymmetry", 40.0),
             _test("drift", 39.5, significant=False)]
    assert tied_effects("creep", tests) == ["delay"]
    assert tied_effects("delay", tests) == ["creep", "rate_dependence"]
    # asymmetry is no phase lag: never tied by this rule
    assert tied_effects("asymmetry", tests) == []


def _scan(*drivers: DriverRelevance) -> DriverScan:
    return DriverScan(drivers, 50.0, 24, 999, False, 0.0025)


def test_the_loop_position_tied_with_time_since_reversal_is_a_shape_tie():
    loop = DriverRelevance("loop position", "loop", 40, 0.001, 40, True,
                           ("time since reversal or hold",))
    other = DriverRelevance("time since reversal or hold", "time", 41, 0.9, -0.5, False,
                            ("loop position",))
    assert shape_tied(_scan(loop, other))
    plain = DriverRelevance("loop position", "loop", 40, 0.001, 40, True)
    assert not shape_tied(_scan(plain))
    assert not shape_tied(None)


def test_implausible_readings_are_named_with_their_range():
    assert implausible({"delay.d": [0.011]}, PLAUSIBLE) and "2 ms" in implausible(
        {"delay.d": [0.011]}, PLAUSIBLE)[0]
    assert implausible({"delay.d": [0.0004], "creep.c": [0.01, 0.02]}, PLAUSIBLE) == []
    assert "creep.c" in implausible({"creep.c": [0.01, 0.9]}, PLAUSIBLE)[0]


def test_the_experiment_named_separates_the_pair():
    assert "holds" in experiment_for("creep", "delay")
    assert "frequencies" in experiment_for("delay", "rate_dependence")
    assert "holds" in experiment_for("branch shape", "creep")


def test_one_sine_without_holds_cannot_separate_lags_and_more_frequencies_or_holds_can():
    from bayeshyst.data import excitation
    from bayeshyst.data.dataset import Dataset
    from bayeshyst.data.record import Record
    from bayeshyst.diagnosis.verdict import separates_lags

    def sine(f):
        t, u = excitation.sine(f, 2000.0, cycles=4)
        return Record(t, u, u.copy(), metadata={"frequency_hz": f}, name=f"s{f:g}")

    assert not separates_lags(Dataset((sine(5.0),)))
    assert separates_lags(Dataset((sine(5.0), sine(50.0))))
    t = np.arange(2000) / 1000.0
    u = np.where(t < 1.0, 0.0, 100.0)  # a step, then a hold of a second
    assert separates_lags(Dataset((Record(t, u, u.copy(), name="step"),)))


# ------------------------------------------------------- the tie, end to end (diagnose)
_BASE = "pi_play(n_operators=3)"


def _lagged_record(t, u, frequency_hz, seed, name, warmup):
    """A 3-operator play PI behind a well-damped second-order lag (40 Hz, zeta 0.9: a
    phase lag without a resonance peak) with white noise 0.3 % of the stroke."""
    from bayeshyst.data.record import Record
    from bayeshyst.models import get as get_model

    plant = get_model(_BASE + "+second_order")
    meta = {"frequency_hz": frequency_hz} if frequency_hz else {}
    proto = Record(t=t, u=u, y=u.copy(), warmup=warmup, metadata=meta)
    theta = dict(plant.param_space(proto).fixed)
    theta.update({"static.p0": 0.12, "static.w": np.array([0.05, 0.03, 0.02]),
                  "second_order.f_n": 40.0, "second_order.zeta": 0.9})
    y = plant.simulate(u, t, theta)
    y = y + 0.003 * np.ptp(y) * np.random.default_rng(seed).standard_normal(y.size)
    return Record(t=t, u=u, y=y, warmup=warmup, metadata=meta, name=name)


def _diagnose_lag(records, seed):
    from bayeshyst.data.dataset import Dataset
    from bayeshyst.diagnosis import diagnose
    from bayeshyst.inference.settings import SamplerSettings

    # screen=False: the naming and tie rules of sampled candidates are under test; the
    # screens of five candidates doubled this case's time (77 s against 25 s)
    return diagnose(Dataset(tuple(records), name="lag"), _BASE, max_rounds=1,
                    sampler=SamplerSettings(n_walkers=24, max_steps=400, first_chunk=200,
                                            seed=seed),
                    n_draws=100, max_refits=0, max_candidates=1, screen=False)


_SEEDS = [0, pytest.param(1, marks=pytest.mark.slow), pytest.param(2, marks=pytest.mark.slow)]


@pytest.mark.parametrize("seed", _SEEDS)
def test_a_lag_under_one_sine_is_reported_tied_with_the_other_lags(seed):
    # one 4 Hz sine, no hold: a lag, a delay, creep and a branch shape are one phase lag
    from bayeshyst.data import excitation
    from bayeshyst.diagnosis.verdict import LAG_LIKE

    t, u = excitation.sine(4.0, 1000.0, cycles=9)
    result = _diagnose_lag([_lagged_record(t, u, 4.0, seed, "sine_4Hz", 250)], seed)
    (step,) = [s for s in result.steps if s.accepted]
    named = {step.effect, *step.tied_with}
    named |= {e for note in result.ties for e in LAG_LIKE if e in note}
    # whatever is credited first, the others that fired are reported as tied with it
    assert step.effect in (*LAG_LIKE, "branch shape"), str(result)
    assert len(named & set(LAG_LIKE)) >= 2, result.verdict
    assert "cannot tell" in result.verdict and "several excitation frequencies" in \
        result.verdict


@pytest.mark.parametrize("seed", _SEEDS)
def test_the_same_lag_under_steps_with_holds_and_two_frequencies_is_named(seed):
    from bayeshyst.data import excitation

    recs = []
    for i, f in enumerate((2.0, 20.0)):
        t, u = excitation.sine(f, 1000.0, cycles=9 if f < 10 else 30)
        recs.append(_lagged_record(t, u, f, 10 * seed + i, f"sine_{f:g}Hz", int(1000 / f)))
    t, u = excitation.steps([0, 0.6, 0.2, 0.9, 0.4, 0.0], 0.25, 1000.0)
    recs.append(_lagged_record(t, u, None, 10 * seed + 5, "steps", 10))
    result = _diagnose_lag(recs, seed)
    # the delay fires too (the lag's first-order term) and reads several ms: implausible,
    # a warning, and the round goes on to the lag itself
    assert result.effects_found == ("rate_dependence",), str(result)
    (step,) = [s for s in result.steps if s.accepted]
    assert step.tied_with == () and not result.ties, result.verdict
    assert step.after.rmse < 0.1 * step.before.rmse


def _stub_fit(elpd, rmse, names=("k",)):
    from types import SimpleNamespace as NS

    from bayeshyst.inference.fit import TrackingError

    err = TrackingError(None, rmse, 2 * rmse, 1.0, 2.0, 100)
    return NS(pointwise_elpd=np.asarray(elpd, float), overall=err, per_frequency=(err,),
              posterior=NS(n_units=len(elpd), space=NS(names=names), data=None),
              sampling=NS(converged=True, summary=lambda: ()), label="m", spec="m",
              model=NS(name="m"), analysis=NS(tests=(), drivers=None))


@pytest.mark.parametrize("gain, kept", [(0.05, False), (0.5, True)])
def test_a_gain_under_four_nats_is_not_kept_however_small_its_error(gain, kept):
    # oracle: the paired difference over 12 cycles is 12 * gain with a tiny se (every
    # cycle gains the same, up to 1e-3): 0.6 nats is precise but negligible (Sivula et
    # al. 2020), 6 nats is kept
    from bayeshyst.diagnosis.candidates import judge
    from bayeshyst.diagnosis.records import DiagnosisSettings
    from bayeshyst.diagnosis.verdict import MIN_ELPD_GAIN

    jitter = 1e-3 * np.sin(np.arange(12))
    current = _stub_fit(np.full(12, -50.0), 1.0)
    cand = _stub_fit(np.full(12, -50.0) + gain + jitter, 0.99)
    test = EffectTest("drift", "F", 10.0, 2, 100, 1e-6, 1e-5, 20.0, 0.1, 0.01, 0.1, {}, {},
                      True)
    step = judge(1, test, current, cand, DiagnosisSettings())
    assert step.accepted == kept and (12 * gain > MIN_ELPD_GAIN) == kept
    if not kept:
        assert "negligible" in step.reason, step.reason


def test_a_change_that_rounds_to_zero_prints_as_zero_not_minus_zero():
    # oracle: the paired difference over 12 cycles is 12 * (-0.003) = -0.036 nats, which
    # rounds to 0.0 at one decimal; the sign of a rounded zero carries no information
    from bayeshyst.diagnosis.candidates import judge
    from bayeshyst.diagnosis.records import DiagnosisSettings

    current = _stub_fit(np.full(12, -50.0), 1.0)
    cand = _stub_fit(np.full(12, -50.0) - 0.003 + 1e-3 * np.sin(np.arange(12)), 1.0)
    test = EffectTest("drift", "F", 10.0, 2, 100, 1e-6, 1e-5, 20.0, 0.1, 0.01, 0.1, {}, {},
                      True)
    step = judge(1, test, current, cand, DiagnosisSettings())
    assert not step.accepted
    assert "changes by 0.0 (se" in step.reason and "-0.0" not in step.reason, step.reason


# ------------------------------------------------ effects fitted together (pair_for)
# per-cycle held-out elpd on the bundled virtual actuator (10 cycles: two per frequency,
# 1-200 Hz) of pi_play(8)+asym_output, and the gains of adding a delay, second-order
# dynamics or creep to it (measured 2026-11-27): the delay and the dynamics gain on the
# fast cycles and lose on the second 1 Hz cycle, which creep explains
_PAIR_BASE = np.array([-186.7, -516.5, -109.9, -251.4, -97.2, -186.1, -110.3, -192.1, -330.6,
                  -803.6])
_GAIN = {"delay": [19.8, -366.8, 105.6, 193.6, 57.6, 138.2, 39.1, 113.4, 191.6, 607.7],
         "rate_dependence": [4.4, -504.0, 110.7, 202.0, 64.4, 154.0, 39.9, 117.4, 207.5,
                             642.5],
         "creep": [54.4, 247.1, 3.0, -2.7, 35.5, 57.6, 46.5, 67.4, -21.1, -280.5]}


def _tried(*effects, gains=_GAIN, base=_PAIR_BASE, log_bf=400.0):
    from bayeshyst.diagnosis.candidates import judge
    from bayeshyst.diagnosis.records import DiagnosisSettings

    current = _stub_fit(base, 0.54)
    out = []
    for e in effects:
        fit = _stub_fit(base + np.asarray(gains[e]), 0.36)
        out.append((_test(e, log_bf), fit, judge(2, _test(e, log_bf), current, fit,
                                                DiagnosisSettings())))
    return current, out


_PAIRABLE = ("creep", "rate_dependence", "asymmetry", "drift", "delay")


def test_a_rejected_effect_that_lost_cycles_is_paired_with_the_next_untried_one():
    # oracle: the rule as documented -- every single lost the 2-se gate (1 100 +- 750,
    # 1 039 +- 881), the delay gained most and lost on cycle 1, the dynamics lost there
    # too (no tried partner), so the partner is the round's first untried pairable
    # candidate; coloured noise, before it in this list, is not pairable
    from bayeshyst.diagnosis.candidates import pair_for

    current, tried = _tried("delay", "rate_dependence")
    assert not any(step.accepted for _, _, step in tried)
    untried = [_test("colored_noise", 300.0), _test("creep", 200.0), _test("drift", 100.0)]
    a, partner = pair_for(tried, untried, current, _PAIRABLE)
    assert tried[a][0].effect == "delay" and partner.effect == "creep"


def test_a_tried_effect_that_gained_where_the_first_lost_is_its_partner():
    from bayeshyst.diagnosis.candidates import pair_for

    current, tried = _tried("delay", "rate_dependence", "creep")
    a, partner = pair_for(tried, [_test("drift", 100.0)], current, _PAIRABLE)
    assert tried[a][0].effect == "delay" and partner is tried[2][0]


@pytest.mark.parametrize("case", ["no cycle lost", "gain under four nats", "bic gate",
                                  "implausible", "no partner"])
def test_no_pair_without_the_pattern_that_calls_for_one(case):
    from bayeshyst.diagnosis.candidates import pair_for

    gains = dict(_GAIN)
    base, untried = _PAIR_BASE, [_test("creep", 200.0)]
    if case == "no cycle lost":  # gains everywhere, only too noisy to pass: no remedy
        gains["delay"] = [1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 90.0]
    elif case == "gain under four nats":
        gains["delay"] = [1.0, -3.0, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5]
    elif case == "bic gate":  # 6 cycles: the elpd gate did not decide (and BIC rejected)
        base = _PAIR_BASE[:6]
        gains = {k: v[:6] for k, v in _GAIN.items()}
    elif case == "no partner":
        untried = [_test("colored_noise", 300.0)]
    current, tried = _tried("delay", gains=gains, base=base,
                            log_bf=2.0 if case == "bic gate" else 400.0)
    if case == "implausible":
        from dataclasses import replace
        t, f, step = tried[0]
        tried = [(t, f, replace(step, reason="implausible: delay"))]
    step = tried[0][2]
    assert not step.accepted and (step.decided_by == "bic") == (case == "bic gate")
    assert pair_for(tried, untried, current, _PAIRABLE) is None


def _stubbed_loop(monkeypatch, pair_gain, gains=None, unconverged=frozenset()):
    """``diagnose`` with its fits replaced by stubs whose cycle-wise elpd is ``_PAIR_BASE`` plus
    the gains above (a pair's: ``pair_gain``; ``gains`` overrides single effects'), so the
    loop's wiring is what is tested. Fits holding a block named in ``unconverged`` report
    that their sampler did not converge."""
    gains = {**_GAIN, **(gains or {})}
    from types import SimpleNamespace as NS

    import bayeshyst.diagnosis.loop as loop
    from bayeshyst.data import excitation
    from bayeshyst.data.dataset import Dataset
    from bayeshyst.data.record import Record
    from bayeshyst.diagnosis.records import DiagnosisFit
    from bayeshyst.inference.fit import TrackingError

    records = []
    for f in (1.0, 10.0):
        t, u = excitation.sine(f, f * 200, cycles=5)
        records.append(Record(t, u, 0.01 * u, name=f"r{f:g}", metadata={"frequency_hz": f}))
    data = Dataset(tuple(records), name="stub")
    fired = tuple(dataclasses.replace(_test(e, bf), coef=np.full(n, 1e-4))
                  for e, bf, n in (("delay", 400.0, 1), ("rate_dependence", 390.0, 2),
                                   ("creep", 200.0, 3)))

    def fake_fit(data_, model, likelihood, label, st, ckdir, warm=None, disc=None):
        blocks = {b.name for b in getattr(model, "blocks", ())}
        gain = np.zeros(_PAIR_BASE.size)
        if {"delay", "creep"} <= blocks:
            gain = np.asarray(pair_gain)
        elif "delay" in blocks:
            gain = np.asarray(gains["delay"])
        elif "second_order" in blocks:
            gain = np.asarray(gains["rate_dependence"])
        err = TrackingError(None, 1.0, 2.0, 1.0, 2.0, 100)
        fit = NS(model=model, likelihood=likelihood, pointwise_elpd=_PAIR_BASE + gain,
                 posterior=NS(n_units=_PAIR_BASE.size, data=data_, space=NS(names=("k",))),
                 sampling=NS(converged=not blocks & set(unconverged), summary=lambda: ()),
                 overall=err,
                 per_frequency=[err, err], warnings=())
        analysis = NS(tests=fired if not blocks else (), fired=lambda: () if blocks else fired,
                      drivers=None, lines=(), time=[data_.records[0].t], alpha=0.01,
                      structure_left=False)
        return DiagnosisFit(label, fit, analysis)

    monkeypatch.setattr(loop, "diagnosis_fit", fake_fit)
    # the stubs are fits, not posteriors a screen could score: every candidate is sampled
    return loop.diagnose(data, "pi_play(n_operators=2)", max_rounds=2, max_candidates=2,
                         screen=False)


def test_the_loop_fits_the_pair_after_a_round_of_rejections_and_credits_both(monkeypatch):
    # the pair gains on every cycle (the measured delay+creep gains): kept, both named
    gain = [274.0, 689.1, 199.5, 402.2, 159.7, 322.6, 193.0, 347.3, 249.0, 583.2]
    result = _stubbed_loop(monkeypatch, gain)
    assert [(s.effect, s.accepted) for s in result.steps] == [
        ("delay", False), ("rate_dependence", False), ("delay+creep", True)]
    assert result.effects_found == ("delay", "creep")
    assert "delay" in result.final.label and "creep" in result.final.label
    assert "neither having passed alone (delay lost on 1 of 10" in result.steps[2].reason
    assert "effects found: delay, creep" in result.verdict


def test_a_pair_that_does_not_pass_the_gate_is_recorded_and_the_loop_stops(monkeypatch):
    result = _stubbed_loop(monkeypatch, _GAIN["delay"])  # creep adds nothing to the delay
    assert [(s.effect, s.accepted) for s in result.steps][-1] == ("delay+creep", False)
    assert result.effects_found == () and result.final is result.base


# ------------------------------------------------ unconverged fits and unresolved resonances
@pytest.mark.parametrize("converged", [True, False])
def test_a_gate_on_an_unconverged_fit_decides_nothing_and_the_round_goes_on(monkeypatch,
                                                                          converged):
    # oracle: a delay that gains 300 nats on each of 10 cycles passes the 2-se gate when
    # its fit converged; unconverged, the same numbers decide nothing: not kept, not
    # "rejected", the round's next candidate is fitted, and the verdict says so
    everywhere = {"delay": np.full(10, 300.0)}
    result = _stubbed_loop(monkeypatch, _GAIN["delay"], gains=everywhere,
                           unconverged=() if converged else ("delay",))
    first = result.steps[0]
    assert first.effect == "delay"
    if converged:
        assert first.accepted and first.outcome == "accepted"
        assert result.effects_found[:1] == ("delay",)
        return
    assert not first.accepted and first.outcome == "not decided", first.reason
    assert first.reason.startswith("not decided") and "unconverged" in first.reason
    # the next candidate was fitted; the unconverged delay is no pairing partner
    assert [s.effect for s in result.steps[1:]] == ["rate_dependence",
                                                   "rate_dependence+creep"]
    assert "delay" not in result.effects_found
    assert "not decided, because its fit did not converge" in result.verdict
    assert any(w.startswith("delay: not decided") for w in result.warnings)
    assert first.to_dict()["outcome"] == "not decided" and "not decided" in str(first)
    # the outcome is said once: the reason's own prefix is not repeated in the verdict
    rest = first.reason.removeprefix("not decided: ")
    assert first.verdict() == f"not decided ({rest})" and "(not decided" not in str(first)


def _resonance(lo, hi):
    from bayeshyst.inference.sampling_result import ParamSummary

    return ParamSummary("second_order.f_n", "Hz", 0.5 * (lo + hi), 0.25 * (hi - lo), lo, hi)


def _two_rates():
    # records sampled at 50 and 200 Hz: no record carries anything above 100 Hz
    from bayeshyst.data.dataset import Dataset
    from bayeshyst.data.record import Record

    recs = []
    for fs in (50.0, 200.0):
        t = np.arange(200) / fs
        u = np.sin(2 * np.pi * 1.0 * t)
        recs.append(Record(t, u, u.copy(), name=f"r{fs:g}"))
    return Dataset(tuple(recs), name="rates")


@pytest.mark.parametrize("lo, hi, flagged", [(234.0, 260.0, True), (101.0, 150.0, True),
                                             (80.0, 120.0, False), (30.0, 50.0, False)])
def test_a_resonance_is_unresolved_only_when_its_whole_interval_is_above_nyquist(lo, hi,
                                                                               flagged):
    from bayeshyst.diagnosis.verdict import unresolved
    from bayeshyst.inference.sampling_result import ParamSummary

    other = ParamSummary("second_order.zeta", "1", 0.05, 0.01, 0.03, 0.07)
    words = unresolved([_resonance(lo, hi), other], _two_rates())
    assert bool(words) == flagged
    if flagged:
        (w,) = words
        assert "second_order.f_n" in w and "at most 100 Hz" in w and f"{2 * hi:.3g} Hz" in w


def test_a_gate_passed_by_an_unresolved_resonance_is_a_warning_not_a_finding():
    # oracle: 12 cycles gaining 50 nats each pass the gate; the block's f_n interval
    # (234-260 Hz) lies above the 100 Hz Nyquist frequency of the faster record
    from types import SimpleNamespace as NS

    from bayeshyst.diagnosis.candidates import judge
    from bayeshyst.diagnosis.records import DiagnosisSettings

    jitter = 1e-3 * np.sin(np.arange(12))
    for (lo, hi), kept in (((234.0, 260.0), False), ((30.0, 50.0), True)):
        current = _stub_fit(np.full(12, -50.0), 1.0)
        current.posterior.data = _two_rates()
        cand = _stub_fit(np.full(12, 0.0) + jitter, 0.5)
        cand.sampling = NS(converged=True, summary=lambda lo=lo, hi=hi: (_resonance(lo, hi),))
        step = judge(1, _test("rate_dependence", 40.0), current, cand, DiagnosisSettings())
        assert step.accepted == kept, step.reason
        assert step.reason.startswith("unresolved") == (not kept), step.reason


# ------------------------------------------- refused readings: no finding, still structure
def test_a_refused_reading_is_no_finding_but_the_verdict_says_what_it_explained(monkeypatch):
    # oracle: a delay gaining 300 nats on each of 10 cycles passes the gate (d = 3000,
    # se = 0); every reading is made implausible, so nothing is kept, and the verdict
    # names the delay with the gate's numbers instead of saying nothing about it
    import bayeshyst.diagnosis.candidates as candidates

    reason = "delay.d = 0.0334 is outside [0, 0.002] (a test range)"
    monkeypatch.setattr(candidates, "implausible", lambda means, ranges: [reason])
    result = _stubbed_loop(monkeypatch, _GAIN["delay"], gains={"delay": np.full(10, 300.0)})
    first = result.steps[0]
    assert first.effect == "delay" and not first.accepted
    assert first.reason == f"implausible: {reason}"
    assert result.effects_found == () and result.final is result.base
    assert ("delay would explain structure that is left (RMSE 1 -> 1, held-out elpd "
            f"+3000.0 (se 0.0)) but is not credited: implausible: {reason}") in result.verdict
    # a step that did not pass its gate is not named as refused
    rejected = [s.effect for s in result.steps
                if not s.accepted and not s.reason.startswith("implausible")]
    assert rejected and all(f"{e} would explain" not in result.verdict for e in rejected)


def test_only_a_refit_on_top_of_the_shape_correction_that_passed_unties_it_from_the_shape():
    from types import SimpleNamespace as NS

    from bayeshyst.diagnosis.verdict import explained_beyond_shape

    def step(effect, accepted, reason):
        # ``refused`` as DiagnosisStep derives it: not kept, reason implausible/unresolved
        return NS(effect=effect, accepted=accepted,
                  refused=not accepted and reason.startswith(("implausible", "unresolved")))

    steps = [step("delay", False, "implausible: delay.d = 0.012"),  # before the shape
             step("creep", False, "held-out elpd changes by 1.0 (se 2.0)"),
             step("branch shape", True, "held-out elpd improves by 163.0 (se 39.0)"),
             step("delay", False, "implausible: delay.d = 0.033"),
             step("rate_dependence", False, "not decided: ... (implausible: f_n = 2.6)"),
             step("drift", False, "held-out elpd changes by -3.0 (se 2.0)"),
             step("asymmetry", True, "held-out elpd improves by 84.0 (se 22.0)")]
    assert explained_beyond_shape(steps) == {"delay", "asymmetry"}
    assert explained_beyond_shape(steps[:3]) == set()


def test_a_step_is_no_longer_undecided_once_a_later_step_of_its_effect_decided():
    # oracle: round 5's unconverged second-order fit, then round 6's converged refusal
    # (the micromanipulator, d5e35c5); a drift that never converged stays undecided
    from types import SimpleNamespace as NS

    from bayeshyst.diagnosis.records import DiagnosisResult

    def step(effect, decided_by):
        return NS(effect=effect, decided_by=decided_by)

    steps = (step("rate_dependence", "not converged"), step("drift", "not converged"),
             step("delay", "elpd"), step("rate_dependence", "elpd"),
             step("drift", "not converged"))
    undecided = DiagnosisResult.undecided.fget(NS(steps=steps))
    assert undecided == (steps[1], steps[4])
    assert DiagnosisResult.undecided.fget(NS(steps=steps[:3])) == steps[:2]
