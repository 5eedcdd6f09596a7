"""Segmentation: reversals, whole cycles, frequency estimation, frequency blocks.

Oracles are synthetic inputs whose turning points, cycle count and frequency are known
in closed form.
"""

from __future__ import annotations

import numpy as np
import pytest

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.data.segment import (
    CycleSplit,
    cycle_labels,
    default_prominence,
    estimate_frequency,
    find_reversals,
    label_frequencies,
    split_by_frequency,
    split_cycles,
)
from bayeshyst.errors import DataError

SPC = 100  # samples per cycle


def sine(cycles: float = 10.25, f: float = 2.0, *, noise: float = 0.0, decay: float | None = None,
         warmup: int = 0, seed: int = 0, phase: float = 0.0) -> Record:
    """u = A(t) sin(2 pi f t + phase), sampled at SPC samples per period."""
    fs = SPC * f
    t = np.arange(round(cycles * SPC)) / fs
    amp = np.ones_like(t) if decay is None else np.exp(-t / decay)
    u = 3.0 * amp * np.sin(2 * np.pi * f * t + phase)
    u = u + noise * np.random.default_rng(seed).standard_normal(t.size)
    return Record(t, u, 0.1 * u, warmup=warmup, name="sine")


# ------------------------------------------------------------------------- reversals
def test_reversals_of_clean_sine_are_exact():
    u = sine().u
    minima = find_reversals(u, kind="min")
    maxima = find_reversals(u, kind="max")
    # sin has maxima at 1/4 + k and minima at 3/4 + k periods; the start is an edge
    np.testing.assert_array_equal(maxima, 25 + SPC * np.arange(10))
    np.testing.assert_array_equal(minima, 75 + SPC * np.arange(10))
    both = find_reversals(u)
    np.testing.assert_array_equal(both, np.sort(np.concatenate([minima, maxima])))


@pytest.mark.parametrize("seed", range(5))
def test_reversals_are_robust_to_noise(seed):
    u = sine(noise=0.15, seed=seed).u  # sigma = 5 % of the amplitude
    minima = find_reversals(u, kind="min")
    assert minima.size == 10
    assert np.max(np.abs(minima - (75 + SPC * np.arange(10)))) <= 15


def test_noisy_ramp_has_no_reversals():
    rng = np.random.default_rng(1)
    u = np.linspace(0, 1, 5000) + 0.01 * rng.standard_normal(5000)
    assert default_prominence(u) > 0.09  # ten noise sigmas dominate 1 % of the range
    assert find_reversals(u).size == 0
    assert find_reversals(np.zeros(10)).size == 0


def test_min_prominence_controls_minor_wiggles():
    t = np.arange(2000) / 1000
    u = np.sin(2 * np.pi * t) + 0.05 * np.sin(2 * np.pi * 40 * t)
    assert find_reversals(u, min_prominence=0.5).size == 4
    assert find_reversals(u, min_prominence=0.01).size > 20
    with pytest.raises(ValueError, match="min_prominence"):
        find_reversals(u, min_prominence=-1)
    with pytest.raises(DataError, match=r"input u, sample index 3 \(0-based\)"):
        find_reversals([0, 1, 2, np.nan])


# ---------------------------------------------------------------------------- cycles
def test_split_cycles_by_reversals_reports_partial_ends():
    split = split_cycles(sine())
    assert isinstance(split, CycleSplit) and split.method == "reversals"
    assert len(split) == 9  # minima at 0.75 ... 9.75 periods
    assert split.cycles[0] == slice(75, 175) and split.cycles[-1] == slice(875, 975)
    assert split.head == slice(0, 75) and split.tail == slice(975, 1025)
    labels = split.labels()
    assert (labels[:75] == -1).all() and (labels[975:] == -1).all()
    assert np.bincount(labels[labels >= 0]).tolist() == [SPC] * 9
    np.testing.assert_array_equal(cycle_labels(sine()), labels)
    text = str(split)
    assert "9 whole cycle(s) by reversals" in text and "head 0:75, tail 975:1025" in text


def test_split_cycles_skips_minima_inside_warmup():
    assert len(split_cycles(sine(warmup=200))) == 7
    assert split_cycles(sine(warmup=200)).cycles[0].start == 275


@pytest.mark.parametrize(("noise", "decay"), [(0.1, None), (0.0, 4.0), (0.05, 4.0)])
def test_cycle_count_with_noise_and_decay(noise, decay):
    # decay 4 s at 2 Hz over 5.1 s: the last cycles have ~30 % of the first amplitude
    split = split_cycles(sine(noise=noise, decay=decay, seed=3))
    assert len(split) == 9
    lengths = [s.stop - s.start for s in split]
    assert max(abs(n - SPC) for n in lengths) <= 25


def test_split_cycles_by_period():
    rec = sine(warmup=50)
    split = split_cycles(rec, period=0.5)
    assert split.method == "period" and split.period == 0.5
    assert split.cycles[0] == slice(50, 150) and len(split) == 9  # 50 + 9*100 = 950 <= 1025
    assert split.head == slice(0, 50) and split.tail == slice(950, 1025)
    exact = sine(cycles=10.0)  # the last cycle ends exactly at the record's last slot
    assert len(split_cycles(exact, by="period")) == 10  # period from metadata/estimate
    assert split_cycles(exact, by="period").tail is None
    with pytest.raises(ValueError, match="period"):
        split_cycles(rec, period=-1.0)
    with pytest.raises(ValueError, match="by"):
        split_cycles(rec, by="zeros")  # type: ignore[arg-type]


def test_record_with_no_whole_cycle():
    split = split_cycles(sine(cycles=1.2))
    assert len(split) == 0 and split.head == slice(0, 120) and split.tail is None
    assert (split.labels() == -1).all()


# ------------------------------------------------------------------------- frequency
@pytest.mark.parametrize(
    ("f", "cycles", "noise", "decay", "phase"),
    [(2.0, 10.25, 0.0, None, 0.0), (1.2345, 7.3, 0.0, None, 1.0), (0.37, 4.6, 0.3, None, 2.0),
     (5.0, 12.9, 0.1, 2.0, 0.5), (1.0, 3.3, 0.0, None, -0.7)],
)
def test_frequency_estimate_within_0p1_percent(f, cycles, noise, decay, phase):
    rec = sine(cycles, f, noise=noise, decay=decay, phase=phase, seed=7)
    assert estimate_frequency(rec) == pytest.approx(f, rel=1e-3)


def test_frequency_estimate_with_offset_and_jittered_time():
    t = np.arange(4000) / 200 + 1e-5 * np.random.default_rng(0).standard_normal(4000)
    t = np.sort(t)
    u = 1.8 - 1.8 * np.cos(2 * np.pi * 1.0 * t)  # raised sine 0 ... 3.6 V
    assert estimate_frequency(Record(t, u, u)) == pytest.approx(1.0, rel=1e-3)


def test_frequency_by_reversals_and_errors():
    assert estimate_frequency(sine(), method="reversals") == pytest.approx(2.0, rel=1e-3)
    flat = Record(np.arange(10.0), np.ones(10), np.zeros(10), name="flat")
    with pytest.raises(DataError, match="record 'flat': the input is constant"):
        estimate_frequency(flat)
    with pytest.raises(DataError, match="record 'flat': 0 input reversal"):
        estimate_frequency(flat, method="reversals")


# ----------------------------------------------------------------- frequency blocks
def _two_tone() -> Record:
    fs = 400.0
    t1 = np.arange(1600) / fs  # 4 s at 1 Hz
    t2 = t1[-1] + (1 + np.arange(800)) / fs  # 2 s at 3 Hz
    u = np.concatenate([np.sin(2 * np.pi * 1.0 * t1), np.sin(2 * np.pi * 3.0 * t2)])
    seg = np.repeat([4, 7], [1600, 800])
    t = np.concatenate([t1, t2])
    return Record(t, u, 0.5 * u, segment=seg, warmup=10, name="sweep",
                  metadata={"source": "bench"})


def test_split_by_frequency_from_segments():
    ds = split_by_frequency(_two_tone())
    assert ds.names == ("sweep/0", "sweep/1") and [r.n for r in ds] == [1600, 800]
    assert ds[0].frequency_hz == pytest.approx(1.0, rel=1e-3)
    assert ds[1].frequency_hz == pytest.approx(3.0, rel=1e-3)
    assert ds[1].warmup == 10 and ds[1].metadata["parent_slice"] == (1600, 2400)
    assert ds[1].metadata["source"] == "bench"
    given = split_by_frequency(_two_tone(), segment_frequencies={4: 1.0, 7: 3.0})
    assert given.frequencies == (1.0, 3.0) and list(given.by_frequency()) == [1.0, 3.0]
    unknown = split_by_frequency(_two_tone(), estimate=False)
    assert unknown.frequencies == ()


def test_split_by_frequency_from_array_and_dataset():
    rec = _two_tone().with_(segment=None)
    freq = np.repeat([1.0, 3.0], [1600, 800])
    ds = split_by_frequency(rec, frequency_hz=freq, warmup=0)
    assert [r.frequency_hz for r in ds] == [1.0, 3.0] and ds[0].warmup == 0
    passed = split_by_frequency(Dataset([rec, _two_tone().with_(name="b")]))
    assert passed.names == ("sweep", "b/0", "b/1")
    assert passed[0].frequency_hz == pytest.approx(1.0, rel=0.2)  # mixed record: dominant tone
    with pytest.raises(ValueError, match="single Record"):
        split_by_frequency(Dataset([rec]), frequency_hz=freq)
    with pytest.raises(DataError, match="frequency_hz: expected 2400 positive"):
        split_by_frequency(rec, frequency_hz=freq[:10])


def test_split_by_frequency_rejects_short_blocks():
    rec = _two_tone()
    seg = rec.segment.copy()
    seg[100:103] = 9
    with pytest.raises(DataError, match=r"record 'sweep': block 1 \(samples 100:103, label 9"):
        split_by_frequency(rec.with_(segment=seg))


# ---------------------------------------------------------------- label_frequencies
def _rec(u, name="r", fs=5000.0, **kw):
    t = np.arange(u.size) / fs
    return Record(t=t, u=u, y=0.2 * u, name=name, **kw)


@pytest.mark.parametrize("noise", [0.0, 0.5])
def test_a_stepped_sine_is_split_into_its_steps_with_their_frequencies(noise):
    # oracle: the steps' frequencies by construction, and the cuts at the steps
    fs, steps = 5000.0, [(10.0, 6), (20.0, 8), (5.0, 4)]
    u = np.concatenate([60 - 50 * np.cos(2 * np.pi * f * np.arange(int(n * fs / f)) / fs)
                        for f, n in steps])
    u = u + np.random.default_rng(1).normal(0, noise, u.size)
    out = label_frequencies(_rec(u, "step"))
    # exact on a clean input; with 1 % input noise the minima that bound a short block's
    # cycles move by ~20 samples, so a 3-cycle block's label is good to 1 %
    np.testing.assert_allclose([r.frequency_hz for r in out], [f for f, _ in steps],
                               rtol=0.01 if noise else 0.0)
    joins = np.cumsum([int(n * fs / f) for f, n in steps])[:-1]
    starts = [r.metadata["parent_slice"][0] for r in out][1:]
    # each later piece starts at its step's first input minimum: within one sample on a
    # clean input, within 5 % of the step's period with noise (a flat minimum's position)
    periods = np.array([fs / f for f, _ in steps[1:]])
    assert np.all(np.abs(np.array(starts) - joins) <= (0.05 * periods if noise else 1))
    # a later piece's warm-up is its first cycle
    warm = np.array([r.warmup for r in out][1:])
    assert np.all(np.abs(warm - periods) <= (0.05 * periods if noise else 1))
    assert sum(r.n for r in out) == u.size  # nothing dropped
    assert {r.metadata["excitation"] for r in out} == {"stepped"}


def test_one_frequency_keeps_the_record_and_a_sweep_is_kept_whole():
    fs = 5000.0
    t = np.arange(int(3 * fs)) / fs
    (sine,) = label_frequencies(_rec(60 - 50 * np.cos(2 * np.pi * 7.3 * t), "sine"))
    assert sine.name == "sine" and sine.frequency_hz == 7.3 and sine.n == t.size
    assert sine.metadata["excitation"] == "periodic"
    # a linear chirp 1 -> 20 Hz repeats nothing: it is one broadband record, not a run of
    # "cycles" labelled with frequencies (issue 58), and its band holds the sweep's span
    f0, rate = 1.0, 19.0 / 3.0
    (chirp,) = label_frequencies(_rec(60 - 50 * np.cos(2 * np.pi * (f0 * t + rate / 2 * t**2)),
                                      "chirp"))
    assert chirp.name == "chirp" and chirp.n == t.size and chirp.frequency_hz is None
    assert chirp.metadata["excitation"] == "broadband"
    lo, hi = chirp.metadata["band_hz"]
    assert lo <= 1.5 and hi >= 19.0
    assert "kept whole" in chirp.metadata["excitation_note"]


def test_labelled_records_pass_and_acyclic_ones_say_why():
    t = np.arange(4000) / 5000.0
    labelled = _rec(60 - 50 * np.cos(2 * np.pi * 3 * t), "l", metadata={"frequency_hz": 3.1})
    ramp = _rec(np.linspace(0, 100, 4000), "ramp")
    out = label_frequencies(Dataset((labelled, ramp), name="d"))
    assert out[0] is labelled and out[0].frequency_hz == 3.1
    assert out[1].frequency_hz is None and "no excitation frequency" in out[1].metadata[
        "frequency_note"]
