"""Tests of the excitation generators: frequencies by FFT peak, levels, bands, smoothness."""

from __future__ import annotations

import numpy as np
import pytest

from bayeshyst.data import excitation as ex
from bayeshyst.errors import ParameterError


def _fft_peak_hz(t: np.ndarray, u: np.ndarray) -> float:
    """Frequency of the largest non-DC FFT bin [Hz] (whole periods: no leakage)."""
    spec = np.abs(np.fft.rfft(u - u.mean()))
    return float(np.fft.rfftfreq(u.size, t[1] - t[0])[np.argmax(spec)])


@pytest.mark.parametrize("f", [1.0, 10.0, 50.0, 100.0, 200.0])
def test_sine_frequency_range_and_smooth_start(f):
    fs = 300.0 * f
    t, u = ex.sine(f, fs, cycles=4)
    assert t.size == 4 * 300 + 1 and t[0] == 0.0 and t[1] == pytest.approx(1 / fs)
    assert _fft_peak_hz(t[:-1], u[:-1]) == pytest.approx(f)
    assert u[0] == pytest.approx(0.0, abs=1e-12) and u[-1] == pytest.approx(0.0, abs=1e-9)
    assert u.max() == pytest.approx(150.0) and u.min() == pytest.approx(0.0, abs=1e-12)
    assert abs(u[1] - u[0]) < 1e-3 * 150  # zero slope at the start


def test_sine_options():
    t, u = ex.sine(5.0, 1000.0, duration_s=1.0, offset_v=10.0, amplitude_v=2.0,
                   phase_rad=np.pi / 2)
    assert t[-1] == pytest.approx(1.0)
    assert u[0] == pytest.approx(10.0)
    assert np.ptp(u) == pytest.approx(4.0, rel=1e-4)
    with pytest.raises(ParameterError, match="Nyquist"):
        ex.sine(600.0, 1000.0, cycles=2)
    with pytest.raises(ParameterError, match="exactly one"):
        ex.sine(5.0, 1000.0, cycles=2, duration_s=1.0)
    with pytest.raises(ParameterError, match="exactly one"):
        ex.sine(5.0, 1000.0)
    with pytest.raises(ParameterError, match="amplitude_v"):
        ex.sine(5.0, 1000.0, cycles=2, amplitude_v=-1.0)
    with pytest.raises(ParameterError, match="fs_hz"):
        ex.sine(5.0, float("nan"), cycles=2)


@pytest.mark.parametrize("f", [2.0, 25.0])
def test_triangle_frequency_slope_and_levels(f):
    fs = 400.0 * f
    t, u = ex.triangle(f, fs, cycles=3, offset_v=70.0, amplitude_v=60.0)
    assert _fft_peak_hz(t[:-1], u[:-1]) == pytest.approx(f)
    assert u[0] == pytest.approx(10.0) and u.max() == pytest.approx(130.0)
    rate = np.abs(np.diff(u)) * fs
    np.testing.assert_allclose(rate, 4 * 60.0 * f, rtol=1e-9)  # constant |du/dt|


def test_decaying_sine_nested_reversals():
    t, u = ex.decaying_sine(1.0, 200.0, cycles=8, center_v=75.0, amplitude_v=75.0,
                            final_amplitude_v=7.5)
    assert u[0] == pytest.approx(0.0) and _fft_peak_hz(t[:-1], u[:-1]) == pytest.approx(1.0)
    d = np.diff(u)
    maxima = u[1:-1][(d[:-1] > 0) & (d[1:] <= 0)]
    minima = u[1:-1][(d[:-1] < 0) & (d[1:] >= 0)]
    assert maxima.size == 8 and np.all(np.diff(maxima) < 0)
    assert np.all(np.diff(minima) > 0) and np.all(minima < 75.0) and np.all(maxima > 75.0)
    assert abs(u[-1] - 75.0) == pytest.approx(7.5, rel=1e-9)
    with pytest.raises(ParameterError, match="final_amplitude_v"):
        ex.decaying_sine(1.0, 200.0, cycles=2, amplitude_v=5.0, final_amplitude_v=6.0)


def test_steps_levels_and_hold_times():
    fs = 50.0
    t, u = ex.steps([0.0, 100.0, 20.0], [1.0, 2.0, 0.5], fs)
    assert t.size == round(3.5 * fs) + 1 and t[-1] == pytest.approx(3.5)
    assert np.all(u[t < 1.0] == 0.0)
    assert np.all(u[(t >= 1.0) & (t < 3.0 - 1e-9)] == 100.0)
    assert np.all(u[t >= 3.0 - 1e-9] == 20.0)
    jumps = np.flatnonzero(np.diff(u)) + 1
    np.testing.assert_allclose(t[jumps], [1.0, 3.0])
    t, u = ex.steps([0.0, 100.0], 2.0, fs)  # one hold for all levels
    assert t[-1] == pytest.approx(4.0) and u[-1] == 100.0
    with pytest.raises(ParameterError, match="hold_s"):
        ex.steps([0.0, 1.0], [1.0, 0.001], fs)
    with pytest.raises(ParameterError, match="levels_v"):
        ex.steps([], 1.0, fs)


def test_multisine_band_periodicity_and_seeds():
    fs, dur, lo, hi = 2000.0, 2.0, 5.0, 80.0
    t, u = ex.multisine(lo, hi, fs, dur, rng=np.random.default_rng(1), offset_v=75.0,
                        amplitude_v=50.0)
    assert t.size == round(fs * dur)
    assert np.max(np.abs(u - 75.0)) == pytest.approx(50.0)
    spec = np.abs(np.fft.rfft(u - 75.0))
    f = np.fft.rfftfreq(u.size, 1 / fs)
    band = (f >= lo - 1e-9) & (f <= hi + 1e-9)
    assert np.all(spec[band] > 0.5 * spec[band].max())  # flat amplitude, every tone present
    assert np.all(spec[~band] < 1e-9 * spec.max())  # nothing outside the band, no leakage
    assert np.count_nonzero(band) == round((hi - lo) * dur) + 1
    same = ex.multisine(lo, hi, fs, dur, rng=1, offset_v=75.0, amplitude_v=50.0)[1]
    np.testing.assert_array_equal(u, same)
    other = ex.multisine(lo, hi, fs, dur, rng=2, offset_v=75.0, amplitude_v=50.0)[1]
    assert not np.allclose(u, other)
    _, sch = ex.multisine(lo, hi, fs, dur, schroeder=True, offset_v=0.0, amplitude_v=1.0)
    # oracle: the explicit sum of cosines with Schroeder phases -pi k (k-1) / K
    tones = np.arange(round(lo * dur), round(hi * dur) + 1) / dur
    idx = np.arange(1, tones.size + 1)
    direct = np.cos(2 * np.pi * np.outer(t, tones) - np.pi * idx * (idx - 1) / tones.size)
    direct = direct.sum(axis=1)
    np.testing.assert_allclose(sch, direct / np.max(np.abs(direct)), atol=1e-9)
    crest = np.max(np.abs(sch)) / np.sqrt(np.mean(sch**2))
    assert crest < 2.0  # Schroeder phases: low crest factor
    with pytest.raises(ParameterError, match="rng"):
        ex.multisine(lo, hi, fs, dur)
    with pytest.raises(ParameterError, match="band"):
        ex.multisine(hi, lo, fs, dur, rng=0)


def test_concatenate_starts_smoothly_from_zero():
    fs = 1000.0
    a = ex.sine(5.0, fs, cycles=2, offset_v=100.0, amplitude_v=20.0)
    b = ex.steps([50.0, 60.0], 0.2, fs)
    t, u = ex.concatenate([a, b], fs, ramp_s=0.1)
    assert u[0] == 0.0 and t[0] == 0.0
    np.testing.assert_allclose(np.diff(t), 1 / fs)
    n_ramp = 100
    assert u.size == 1 + (n_ramp - 1) + a[1].size + (n_ramp - 1) + b[1].size
    np.testing.assert_array_equal(u[n_ramp:n_ramp + a[1].size], a[1])
    bridge = u[: n_ramp + 1]
    assert np.all(np.diff(bridge) >= 0)
    assert np.max(np.abs(np.diff(bridge))) < 2 * 80.0 / n_ramp  # raised cosine, no jump
    np.testing.assert_array_equal(u[-b[1].size:], b[1])
    # no bridge where a segment already starts at the previous value
    _, u2 = ex.concatenate([ex.sine(5.0, fs, cycles=1)], fs)
    assert u2.size == ex.sine(5.0, fs, cycles=1)[1].size
    with pytest.raises(ParameterError, match="sampling"):
        ex.concatenate([ex.sine(5.0, 500.0, cycles=1)], fs)
    with pytest.raises(ParameterError, match="at least one"):
        ex.concatenate([], fs)
