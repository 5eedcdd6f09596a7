"""The verdict rules on constructed cases: ties within 3 nats, the loop position tied with
a time since reversal, plausibility ranges, the experiment that separates two effects."""

from __future__ import annotations

import math

import numpy as np

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
    from bayeshyst.data.record import Dataset, Record
    from bayeshyst.diagnosis.verdict import separates_lags

    def sine(f):
        t, u = excitation.sine(f, 2000.0, cycles=4)
        return Record(t, u, u.copy(), metadata={"frequency_hz": f}, name=f"s{f:g}")

    assert not separates_lags(Dataset((sine(5.0),)))
    assert separates_lags(Dataset((sine(5.0), sine(50.0))))
    t = np.arange(2000) / 1000.0
    u = np.where(t < 1.0, 0.0, 100.0)  # a step, then a hold of a second
    assert separates_lags(Dataset((Record(t, u, u.copy(), name="step"),)))
