"""Tests of the virtual actuator against oracles: an independent relay-grid Preisach,
analytic lag and second-order responses, exact drift/delay/noise contributions, the
stated magnitudes, and the bit-for-bit bundle."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest

from bayeshyst.data import excitation as ex
from bayeshyst.data.io import load
from bayeshyst.data.virtual import (
    BUNDLE_FREQUENCIES_HZ,
    EFFECTS,
    STROKE_UM,
    AR1Noise,
    LogCreep,
    PreisachHysteresis,
    SecondOrder,
    SensorDelay,
    ThermalDrift,
    VirtualActuator,
    bundle,
    creep_per_decade,
    hysteresis_only,
    hysteresis_percent,
    loop_width,
)
from bayeshyst.errors import DataError, ParameterError

DATA_DIR = Path(__file__).resolve().parents[1] / "data"
BUNDLE_FILES = ("virtual_multifreq", "virtual_steps", "virtual_minor_loops")


def _path(*extrema: float, per_leg: int = 60) -> np.ndarray:
    """Piecewise-linear input through the given extrema [V]."""
    legs = [np.linspace(a, b, per_leg, endpoint=False) for a, b in itertools.pairwise(extrema)]
    return np.concatenate([*legs, [extrema[-1]]])


def _last_cycle(t, u, y, frequency_hz):
    """Samples of the last whole period (both ends included)."""
    n = round(1.0 / (frequency_hz * (t[1] - t[0])))
    return u[-n - 1:], y[-n - 1:]


# ------------------------------------------------------------------ Preisach oracle
def _density(alpha, beta, p):
    """The relay density of the truth dict, written out independently [um/V^2]."""
    m, r = 0.5 * (alpha + beta), 0.5 * (alpha - beta)
    median = p["halfwidth_v"] * np.exp(p["halfwidth_slope"] * (m - p["center_v"])
                                       / p["center_sd_v"])
    g = np.exp(-0.5 * ((m - p["center_v"]) / p["center_sd_v"]) ** 2) / (
        p["center_sd_v"] * math.sqrt(2 * math.pi))
    s = p["halfwidth_log_sd"]
    ln = np.exp(-0.5 * (np.log(r / median) / s) ** 2) / (r * s * math.sqrt(2 * math.pi))
    return 0.5 * p["mass_um"] * g * ln  # dalpha dbeta = 2 dm dr


def _relay_grid(u, p, h):
    """Slow Preisach: 0/1 relays at the centres of an h-grid, virgin state from below."""
    lo, hi = p["plane_v"]
    c = np.arange(lo + h / 2, hi, h)
    a, b = np.meshgrid(c, c, indexing="ij")
    keep = a > b
    alpha, beta = a[keep], b[keep]
    w = _density(alpha, beta, p) * h * h
    big = w > 1e-14 * w.max()
    alpha, beta, w = alpha[big], beta[big], w[big]
    state = alpha <= 0.0  # virgin actuator brought up to 0 V
    offset = w[state].sum()
    out = np.empty(u.size)
    for k, x in enumerate(u):
        state = (state | (x >= alpha)) & ~(x <= beta)
        out[k] = w[state].sum() - offset
    return out


def test_preisach_core_matches_relay_grid_oracle_and_error_shrinks():
    act = hysteresis_only()
    u = _path(0, 150, 20, 120, 45, 100, 60, 90, 0, 140, 10, 130)
    core = act.static(u) - act.gain_um_per_v * u
    truth = act.truth()["hysteresis"]
    errors = [np.max(np.abs(_relay_grid(u, truth, h) - core)) for h in (2.0, 1.0, 0.5)]
    assert errors[0] > 1.6 * errors[1] > 1.6**2 * errors[2]  # first-order convergence
    assert errors[2] < 0.0015 * STROKE_UM


def test_everett_table_is_the_density_integral():
    hyst = PreisachHysteresis()
    table, lo, step = hyst.everett()
    # E(alpha, lo) - E(alpha', lo) etc.: total mass over the plane, by a direct midpoint sum
    c = np.arange(lo + 0.125, lo + step * (table.shape[0] - 1), 0.25)
    a, b = np.meshgrid(c, c, indexing="ij")
    total = hyst.density(a, b).sum() * 0.25**2
    assert table[-1, 0] == pytest.approx(total, rel=1e-4)
    assert table[-1, 0] == pytest.approx(hyst.mass_um, rel=0.05)  # truncation of the plane
    assert np.all(np.diff(table, axis=0) >= -1e-12)  # E grows with alpha
    assert np.all(np.diff(table, axis=1) <= 1e-12)  # and shrinks with beta


def test_wiping_out_and_return_point_memory():
    act = hysteresis_only()
    tail = _path(130, 40, 110)
    # the minor loop 100 -> 50 -> 100 is wiped out once the input passes 120
    with_minor = act.static(np.concatenate([_path(0, 150, 20, 100, 50, 120), tail]))
    without = act.static(np.concatenate([_path(0, 150, 20, 120), tail]))
    np.testing.assert_allclose(with_minor[-tail.size:], without[-tail.size:], atol=1e-12)
    # return-point memory: closing the minor loop 100 -> 50 -> 100 returns to the same y
    u = _path(0, 150, 20, 100, 50, 100)
    y = act.static(u)
    first = 3 * 60  # the vertex 100 V (each leg has 60 samples)
    assert u[first] == 100.0
    assert y[-1] == pytest.approx(y[first], abs=1e-12)
    # and the output then continues as if the minor loop had never happened
    np.testing.assert_allclose(act.static(_path(0, 150, 20, 100, 50, 100, 130))[-61:],
                               act.static(_path(0, 150, 20, 100, 130))[-61:], atol=1e-12)


def test_minor_loops_are_congruent():
    act = hysteresis_only()
    loop = _path(60, 90, 60)
    shapes = []
    # every history ends with a descent to 60 V from above 90 V
    for history in ((0, 150, 60), (0, 120, 30, 100, 60), (0, 100, 60)):
        y = act.static(np.concatenate([_path(*history), loop]))[-loop.size:]
        shapes.append(y - y[0])
    np.testing.assert_allclose(shapes[1], shapes[0], atol=1e-10)
    np.testing.assert_allclose(shapes[2], shapes[0], atol=1e-10)


def test_loop_is_counter_clockwise_and_asymmetric():
    act = hysteresis_only()
    u = _path(0, 150, 0)
    y = act.static(np.concatenate([u, u]))[u.size:]
    rise, fall = y[:60], y[60:-1][::-1][1:]
    assert np.all(fall[10:50] > rise[11:51])
    # point symmetry about the loop centre would make these widths equal
    width_low = np.interp(37.5, u[60:][::-1], y[60:][::-1]) - np.interp(37.5, u[:61], y[:61])
    width_high = np.interp(112.5, u[60:][::-1], y[60:][::-1]) - np.interp(112.5, u[:61], y[:61])
    assert abs(width_low - width_high) > 0.05 * max(width_low, width_high)


# ------------------------------------------------------------------- magnitudes
def test_default_hysteresis_and_stroke():
    t, u = ex.sine(1.0, 2000.0, cycles=3)
    y = hysteresis_only().simulate(t, u)
    uc, yc = _last_cycle(t, u, y, 1.0)
    assert np.ptp(yc) == pytest.approx(STROKE_UM, rel=0.005)
    assert hysteresis_percent(uc, yc) == pytest.approx(12.0, abs=0.5)
    y = VirtualActuator().simulate(t, u, rng=0)
    assert 10.0 <= hysteresis_percent(*_last_cycle(t, u, y, 1.0)) <= 15.0


def test_creep_per_decade_on_step_and_hold():
    t, u = ex.steps([0.0, 100.0], [1.0, 20.0], 1000.0)
    for act in (hysteresis_only().with_effects("creep"),
                VirtualActuator().without("drift", "noise")):
        c = creep_per_decade(t, act.simulate(t, u), 1.0)
        assert 0.01 <= c <= 0.02
        assert c == pytest.approx(act.creep.per_decade, rel=0.05)


def test_creep_lag_bank_matches_analytic_ramp_response():
    creep = LogCreep()
    act = VirtualActuator(gain_um_per_v=0.3, hysteresis=None, creep=creep, dynamics=None,
                          drift=None, delay=None, noise=None)
    fs, volts = 200.0, 80.0
    t, u = ex.steps([0.0, volts], [0.5, 30.0], fs)
    k = np.flatnonzero(u > 0)[0] - 1  # the ramp runs from t[k] to t[k+1]
    s, ramp = t - t[k], 1.0 / fs

    def rho(x, tau):
        x = np.maximum(x, 0.0)
        return x - tau * (1 - np.exp(-x / tau))

    w = 0.3 * volts * np.clip(s / ramp, 0.0, 1.0)
    expected = w + sum(c * 0.3 * volts * (rho(s, tau) - rho(s - ramp, tau)) / ramp
                       for c, tau in zip(creep.weights, creep.taus_s, strict=True))
    np.testing.assert_allclose(act.simulate(t, u), expected, rtol=1e-9, atol=1e-9)


def test_second_order_step_matches_analytic():
    dyn = SecondOrder(resonance_hz=1500.0, damping=0.07)
    act = VirtualActuator(gain_um_per_v=0.25, hysteresis=None, creep=None, dynamics=dyn,
                          drift=None, delay=None, noise=None)
    fs = 100_000.0
    t, u = ex.steps([0.0, 100.0], [0.001, 0.01], fs)
    k = np.flatnonzero(u > 0)[0] - 1
    wn, z = 2 * np.pi * dyn.resonance_hz, dyn.damping
    wd = wn * math.sqrt(1 - z * z)

    def ramp_response(x):  # integral of the unit step response
        x = np.maximum(x, 0.0)
        return x - 2 * z / wn + np.exp(-z * wn * x) * (
            2 * z / wn * np.cos(wd * x) + (2 * z * z - 1) / wd * np.sin(wd * x))

    d = 1.0 / fs
    expected = 25.0 * (ramp_response(t - t[k]) - ramp_response(t - t[k] - d)) / d
    y = act.simulate(t, u)
    np.testing.assert_allclose(y, expected, rtol=1e-9, atol=1e-9)
    peak = np.max(y) / 25.0 - 1.0
    assert peak == pytest.approx(math.exp(-math.pi * z / math.sqrt(1 - z * z)), rel=0.02)


def test_loop_widens_and_tilts_with_frequency_only_with_dynamics():
    def loop(act, f):
        t, u = ex.sine(f, 400.0 * f, cycles=3)
        return _last_cycle(t, u, act.simulate(t, u), f)

    static = hysteresis_only()
    (_, y1), (_, y200) = loop(static, 1.0), loop(static, 200.0)
    np.testing.assert_allclose(y200, y1, atol=1e-9)  # rate-independent without dynamics
    dyn = static.with_effects("dynamics")
    (w1, s1), (w200, s200) = loop_width(*loop(dyn, 1.0)), loop_width(*loop(dyn, 200.0))
    assert w200 - w1 > 0.005 * STROKE_UM
    assert s200 / s1 > 1.01


def test_drift_adds_exactly_offset_and_gain_ramps():
    drift = ThermalDrift()
    assert 100 * drift.offset_um_per_s / STROKE_UM == pytest.approx(0.05)
    t, u = ex.sine(1.0, 500.0, cycles=10)
    t = t + 3.0  # drift counts from the record start
    base = hysteresis_only()
    y0 = base.simulate(t, u)
    y1 = base.with_effects(drift=drift).simulate(t, u)
    s = t - t[0]
    np.testing.assert_allclose(y1 - y0, drift.gain_per_s * s * y0 + drift.offset_um_per_s * s,
                               atol=1e-12)


@pytest.mark.parametrize("delay_s", [50e-6, 0.37e-3])
def test_delay_shifts_the_output_by_fractional_samples(delay_s):
    fs = 1000.0
    t, u = ex.triangle(2.0, fs, cycles=3)  # vertices fall on samples
    y = hysteresis_only().with_effects(delay=SensorDelay(delay_s)).simulate(t, u)
    # oracle: the rate-independent static map along the delayed path, reversals included
    times = np.concatenate([t, t - delay_s])
    order = np.argsort(times, kind="stable")
    path = np.interp(times[order], t, u)  # held at u[0] before t[0]
    ys = hysteresis_only().static(path)
    expected = np.empty_like(ys)
    expected[order] = ys
    np.testing.assert_allclose(y, expected[t.size:], atol=1e-9)
    assert np.max(np.abs(y - hysteresis_only().simulate(t, u))) > 0.001


def test_ar1_noise_statistics():
    noise = AR1Noise()
    assert 100 * noise.rms_um / STROKE_UM == pytest.approx(0.1)
    n = 100_000
    t = np.arange(n) / 20_000.0
    u = np.full(n, 60.0)
    act = hysteresis_only().with_effects("noise")
    e = act.simulate(t, u, rng=11) - hysteresis_only().simulate(t, u)
    phi, rms = noise.phi, noise.rms_um
    r1 = np.sum(e[1:] * e[:-1]) / np.sum(e * e)
    assert abs(r1 - phi) < 3 * math.sqrt((1 - phi**2) / n)
    se_rms = rms * math.sqrt((1 + phi**2) / (2 * n * (1 - phi**2)))
    assert abs(np.sqrt(np.mean(e**2)) - rms) < 3 * se_rms
    np.testing.assert_allclose(e, noise.sample(n, 11), atol=1e-12)


# -------------------------------------------------------------- switches and seeds
def test_every_effect_switches_off_and_on():
    t, u = ex.sine(20.0, 4000.0, cycles=3)
    full = VirtualActuator()
    y_full = full.simulate(t, u, rng=1)
    assert full.effects == EFFECTS
    for name in EFFECTS:
        act = full.without(name)
        assert name not in act.effects and getattr(act, name) is None
        assert act.with_effects(name) == full
        y = act.simulate(t, u, rng=1)
        assert np.max(np.abs(y - y_full)) > 1e-3, name
    # noise off: deterministic, rng not needed; noise on: exactly the AR(1) draw added
    quiet = full.without("noise")
    np.testing.assert_array_equal(quiet.simulate(t, u), quiet.simulate(t, u, rng=5))
    np.testing.assert_allclose(y_full - quiet.simulate(t, u), full.noise.sample(t.size, 1),
                               atol=1e-12)
    with pytest.raises(ParameterError, match="rng"):
        full.simulate(t, u)
    with pytest.raises(ParameterError, match="unknown effect"):
        full.without("hysterisis")


def test_same_seed_identical_different_seed_differs_only_in_noise():
    t, u = ex.sine(10.0, 2000.0, cycles=3)
    act = VirtualActuator()
    a = act.simulate(t, u, rng=42)
    np.testing.assert_array_equal(a, act.simulate(t, u, rng=np.random.default_rng(42)))
    b = act.simulate(t, u, rng=43)
    assert not np.array_equal(a, b)
    det = act.without("noise").simulate(t, u)
    np.testing.assert_allclose(a - act.noise.sample(t.size, 42), det, atol=1e-12)
    np.testing.assert_allclose(b - act.noise.sample(t.size, 43), det, atol=1e-12)


def test_non_uniform_times_and_bad_input():
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, 2000))
    u = 75 - 75 * np.cos(2 * np.pi * 2.0 * (t - t[0]))
    act = hysteresis_only()
    np.testing.assert_allclose(act.simulate(t, u), act.static(u), atol=1e-3)
    with pytest.raises(DataError, match="increase"):
        act.simulate(t[::-1], u)
    with pytest.raises(DataError, match="finite"):
        act.simulate(t, np.where(t > t[5], np.nan, u))
    with pytest.raises(ParameterError, match="internal_rate_hz"):
        VirtualActuator(internal_rate_hz=10_000.0)
    with pytest.raises(ParameterError, match="damping"):
        SecondOrder(damping=1.5)
    with pytest.raises(ParameterError, match="phi"):
        AR1Noise(phi=1.0)
    with pytest.raises(ParameterError, match="creep"):
        VirtualActuator(creep=0.015)


def test_record_carries_truth_and_frequency():
    t, u = ex.sine(50.0, 10_000.0, cycles=4)
    act = VirtualActuator().without("drift")
    rec = act.record(t, u, rng=0, name="f50", warmup=200, frequency_hz=50.0,
                     metadata={"note": "test"})
    assert rec.frequency_hz == 50.0 and rec.warmup == 200 and rec.name == "f50"
    assert rec.source == "virtual actuator" and rec.metadata["note"] == "test"
    truth = json.loads(json.dumps(act.truth()))
    assert truth["drift"] is None and "drift" not in truth["effects_on"]
    assert truth["dynamics"]["resonance_hz"] == 1500.0
    assert len(truth["creep"]["tau_s"]) >= 6
    assert rec.metadata["truth"]["noise"]["phi"] == 0.8
    np.testing.assert_array_equal(rec.y, act.simulate(t, u, rng=0))


# ------------------------------------------------------------------------ bundle
def test_bundle_regenerates_bit_for_bit(tmp_path):
    written = bundle(tmp_path)
    assert [p.name for p in written] == [f"{s}.csv" for s in BUNDLE_FILES]
    total = 0
    for stem in BUNDLE_FILES:
        for suffix in (".csv", ".json"):
            new, shipped = tmp_path / (stem + suffix), DATA_DIR / (stem + suffix)
            assert new.read_bytes() == shipped.read_bytes(), shipped.name
            total += shipped.stat().st_size
    assert total < 1_000_000


def test_bundle_contents():
    multi = load(DATA_DIR / "virtual_multifreq.csv")
    assert multi.frequencies == BUNDLE_FREQUENCIES_HZ
    for rec in multi:
        per_cycle = rec.fs / rec.frequency_hz
        assert 200 <= per_cycle <= 400 and rec.warmup == round(per_cycle)
        assert 3 <= (rec.n - 1) / per_cycle <= 5
        assert rec.u.min() == 0.0 and rec.u.max() == 150.0
        assert tuple(rec.metadata["truth"]["effects_on"]) == EFFECTS
    steps = load(DATA_DIR / "virtual_steps.csv")[0]
    assert steps.frequency_hz is None and steps.duration >= 10
    t_step = steps.t[np.flatnonzero(np.diff(steps.u) > 50)[0] + 1]
    assert 0.01 <= creep_per_decade(steps.t, steps.y, t_step) <= 0.03  # drift on too
    minor = load(DATA_DIR / "virtual_minor_loops.csv")[0]
    peaks = minor.u[1:-1][(np.diff(minor.u)[:-1] > 0) & (np.diff(minor.u)[1:] <= 0)]
    assert len(peaks) >= 6 and np.all(np.diff(peaks) < 0)
