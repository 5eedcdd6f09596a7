"""The open-world driver scan and the spectral-line test against known truths.

Residuals are built directly (no fit): white or AR(1) noise under the null, plus a
known dependence on one driver under the alternative. Oracles: the held-out sums of
squares against an explicit fold-by-fold ridge regression written here; the null
rejection rate against its binomial bound at the nominal level; the driver named
against the one that was planted.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import stats
from scipy.signal import lfilter

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.diagnosis._heldout import _RIDGE, _Grams
from bayeshyst.diagnosis.drivers import driver_blocks, scan_drivers, scan_units
from bayeshyst.diagnosis.spectrum import spectral_lines

FS, F0, NOISE = 2000.0, 10.0, 0.01


def residual_case(seed: int, kind: str = "null", *, phi: float = 0.0, cycles: int = 8):
    """One record: a 10 Hz sine input, a fake model output, a residual with ``kind`` in it.

    ``temperature_c`` rises and falls once over the record (not monotone in time) and
    ``load_n`` is an irrelevant random column.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(int(cycles * FS / F0)) / FS
    u = 75.0 + 75.0 * np.sin(2 * np.pi * F0 * t - np.pi / 2)
    w = 0.1 * u + 0.5 * np.sin(2 * np.pi * F0 * t)
    temp = 20.0 + 9.0 * np.sin(np.pi * t / t[-1])
    r = lfilter([1.0], [1.0, -phi], NOISE * np.sqrt(1 - phi ** 2) * rng.standard_normal(t.size))
    wc = w - w.mean()
    if kind == "temperature":    # a gain of 0.3 %/K
        r = r + 0.003 * (temp - temp.mean()) * wc
    elif kind == "drift":        # a gain that changes linearly with time
        r = r + 0.02 * (t / t[-1] - 0.5) * wc
    elif kind == "shape":        # a branch-shape error: periodic in the phase
        r = r + 2 * NOISE * np.sin(2 * np.pi * 2 * F0 * t)
    elif kind == "line":         # a disturbance at a frequency that is no harmonic
        r = r + 2 * NOISE * np.sin(2 * np.pi * 37.3 * t + 0.4)
    elif kind == "monotone":     # temperature that rises with time drives the gain
        temp = 20.0 + 9.0 * t / t[-1]
        r = r + 0.003 * (temp - temp.mean()) * wc
    rec = Record(t, u, w + r, metadata={"frequency_hz": F0}, name=kind,
                 covariates={"temperature_c": temp, "load_n": rng.standard_normal(t.size)})
    return Dataset((rec,)), [r], [w]


def test_heldout_sums_equal_an_explicit_ridge_regression():
    data, r, w = residual_case(0, "temperature")
    blocks = driver_blocks(data, w, [0])
    x = np.column_stack([b.columns for b in blocks])
    units = scan_units(data)
    guard = 5
    grams = _Grams(x, r[0], units, guard)
    cols = np.arange(blocks[0].columns.shape[1], blocks[0].columns.shape[1]
                     + blocks[1].columns.shape[1])
    signs = np.random.default_rng(1).choice((-1.0, 1.0), size=(3, len(units)))
    v_tr, v_te, rr = grams.versions(np.zeros(0, dtype=int), signs)
    fast = grams.sse(cols, v_tr, v_te, rr)
    # the slow way: flip the units, fit on every other fold, score the held-out interiors
    k = grams.fold.shape[0]
    for p, s in enumerate(signs):
        rs = r[0].copy()
        for (a, b), sign in zip(units, s, strict=True):
            rs[a:b] *= sign
        sse = 0.0
        for fold in range(k):
            train = [u for i, u in enumerate(units) if i % k != fold]
            test = [u for i, u in enumerate(units) if i % k == fold]
            idx = np.concatenate([np.arange(a, b) for a, b in train])
            xt = x[idx][:, cols]
            beta = np.linalg.solve(xt.T @ xt + _RIDGE * idx.size * np.eye(cols.size),
                                   xt.T @ rs[idx])
            for a, b in test:
                g = min(guard, (b - a) // 4)
                e = rs[a + g:b - g] - x[a + g:b - g][:, cols] @ beta
                sse += float(e @ e)
        assert fast[p] == pytest.approx(sse, rel=1e-9)


@pytest.mark.parametrize("phi", [0.0, 0.9])
def test_null_rejection_rate_is_at_most_nominal(phi):
    # 60 seeds at level 0.05: P(X >= 8) = 1.0 % for a true rate of 5 %
    alpha, n = 0.05, 60
    fired = [scan_drivers(*residual_case(seed, phi=phi), alpha=alpha, n_permutations=199,
                          seed=seed).found for seed in range(n)]
    bound = stats.binom.ppf(0.99, n, alpha)
    assert sum(fired) <= bound, (sum(fired), bound)


@pytest.mark.parametrize("seed", range(5))
def test_a_temperature_driven_gain_is_traced_to_the_temperature_column(seed):
    scan = scan_drivers(*residual_case(seed, "temperature"), seed=seed)
    assert scan.selected[0].driver == "temperature_c", str(scan)
    assert "load_n" not in [d.driver for d in scan.selected]
    assert scan.explained_percent > 50


@pytest.mark.parametrize("seed", range(3))
def test_a_gain_drift_is_traced_to_time(seed):
    scan = scan_drivers(*residual_case(seed, "drift"), seed=seed)
    assert scan.selected[0].driver == "time", str(scan)


def test_temperature_that_rises_with_time_is_tied_with_time():
    scan = scan_drivers(*residual_case(0, "monotone"))
    first = scan.selected[0]
    assert {first.driver, *first.tied_with} >= {"temperature_c", "time"}, str(scan)
    assert "cannot tell" in scan.summary()


def test_a_branch_shape_error_under_one_sine_is_named_as_the_loop_and_tied():
    # under one periodic input the loop position and the time since the last reversal
    # are one coordinate: the model's shape is named, the tie reported
    scan = scan_drivers(*residual_case(0, "shape"))
    first = scan.selected[0]
    assert first.driver == "loop position", str(scan)
    assert "time since reversal or hold" in first.tied_with, str(scan)


def test_too_few_units_cannot_decide():
    data, r, w = residual_case(0, "temperature", cycles=1)
    rec = data[0]
    short = Dataset((rec.with_(metadata={}),))  # no cycles known: equal blocks
    scan = scan_drivers(short, r, w, alpha=0.001, n_permutations=99)
    assert not scan.decidable and "cannot decide" in scan.summary()
    assert not scan.found
    # nothing was computed, so no number is printed or written (no NaN gains or p-values)
    assert scan.drivers == () and "temperature_c" in scan.note
    assert "nan" not in str(scan).lower() and "nan" not in json.dumps(scan.to_dict()).lower()


def test_same_seed_same_scan():
    case = residual_case(3, "temperature")
    assert scan_drivers(*case, seed=4).to_dict() == scan_drivers(*case, seed=4).to_dict()


# ------------------------------------------------------------------ spectral lines
def test_a_non_harmonic_line_is_found_with_its_frequency_and_amplitude():
    data, r, _ = residual_case(0, "line")
    lines = spectral_lines(data, r)
    assert len(lines) == 1, lines
    assert lines[0].frequency_hz == pytest.approx(37.3, abs=0.1)
    assert lines[0].amplitude == pytest.approx(2 * NOISE, rel=0.1)


def test_harmonics_of_the_excitation_are_not_lines():
    data, r, _ = residual_case(0, "shape")
    assert spectral_lines(data, r) == ()


@pytest.mark.parametrize("phi", [0.0, 0.9])
def test_line_null_rejection_rate_is_at_most_nominal(phi):
    alpha, n = 0.05, 100
    fired = [bool(spectral_lines(*residual_case(seed, phi=phi)[:2], alpha=alpha))
             for seed in range(n)]
    assert sum(fired) <= stats.binom.ppf(0.99, n, alpha), sum(fired)
