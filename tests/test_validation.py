"""Predicting a record the model was not fitted on (inverse.validation), known truths."""

from __future__ import annotations

import numpy as np
import pytest

from bayeshyst.data import Record
from bayeshyst.errors import ParameterError
from bayeshyst.inference.fit import fit_model
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.inverse.validation import check_transfer
from tests.synthetic import pi_data


def minor_loops(model, theta, *, gain=1.0, shift=0.0, seed=0, sigma=0.05):
    """Nested minor loops of growing amplitude (never in the fitted record) from the truth."""
    t = np.arange(3000) * 1e-3
    u = 75 + (10 + 50 * t / t[-1]) * np.sin(2 * np.pi * 5 * t)
    y = gain * model.simulate(u, t, theta) + 0.4 + shift
    y = y + np.random.default_rng(seed).normal(0.0, sigma, t.size)
    return Record(t=t, u=u, y=y, name="minor", warmup=200, metadata={"frequency_hz": 5.0},
                  segment=(t > 1.5).astype(int))


@pytest.fixture(scope="module")
def fits():
    out = []
    for seed in range(3):
        model, rec, theta = pi_data(n_ops=3, seed=seed)
        fit = fit_model(rec, model, "gaussian", sampler=SamplerSettings(seed=seed))
        out.append((model, theta, fit, seed))
    return out


def test_a_well_specified_model_transfers_to_minor_loops_at_the_nominal_rate(fits):
    """Oracle: data from the fitted model itself, new input, fresh white noise.

    Pooled over 3 seeds x 2 windows (~8 000 samples, nearly independent) a calibrated
    predictive covers 90 % and 50 % with a binomial sd of 0.3 % and 0.6 %; the bars,
    +-2 and +-3 points, are 6 sd (the posterior and the residual bootstrap are
    approximations, not the exact predictive).
    """
    cov90, cov50 = [], []
    for model, theta, fit, seed in fits:
        chk = check_transfer(fit.posterior, fit.sampling.draws(400, seed=0),
                             minor_loops(model, theta, seed=100 + seed), seed=seed)
        assert [w.label for w in chk.windows] == ["minor#0", "minor#1"]
        for w in chk.windows:
            cov90.append(w.coverage[0.9])
            cov50.append(w.coverage[0.5])
            assert abs(w.bias) < 0.02  # sigma 0.05 over ~1 400 samples: sd 0.0013
    assert abs(np.mean(cov90) - 0.9) <= 0.02
    assert abs(np.mean(cov50) - 0.5) <= 0.03


def test_a_plant_that_changed_is_reported_as_not_transferring(fits):
    # oracle: the same plant with 10 % more gain -- a shift of ~1 output unit, 20 noise sd
    model, theta, fit, _ = fits[0]
    chk = check_transfer(fit.posterior, fit.sampling.draws(200, seed=0),
                         minor_loops(model, theta, gain=1.1, seed=7), seed=0)
    assert all(w.coverage[0.9] < w.expected[0.9][0] for w in chk.windows)
    assert all(not w.calibrated for w in chk.windows)
    assert any("does not transfer" in w for w in chk.warnings)
    assert all(w.bias > 0 for w in chk.windows)


def test_a_sensor_zero_that_moved_is_re_estimated_on_the_samples_given(fits):
    # oracle: the fitted plant read by a sensor whose zero moved by 0.5 (10 noise sd):
    # the bands miss it; re-estimated on the first segment they hold on the second
    model, theta, fit, _ = fits[1]
    rec = minor_loops(model, theta, shift=0.5, seed=11)
    z = fit.sampling.draws(300, seed=0)
    raw = check_transfer(fit.posterior, z, rec, seed=0)
    assert all(w.coverage[0.9] < 0.5 and w.bias == pytest.approx(0.5, abs=0.03)
               for w in raw.windows)
    fixed = check_transfer(fit.posterior, z, rec, rezero={"minor": rec.segment == 0}, seed=0)
    (w,) = fixed.windows
    assert w.label == "minor#1" and abs(w.bias) < 0.02
    assert w.expected[0.9][0] - 0.02 <= w.coverage[0.9] <= w.expected[0.9][1] + 0.02
    with pytest.raises(ParameterError, match="boolean mask"):
        check_transfer(fit.posterior, z, rec, rezero={"minor": rec.segment[:5] == 0})


def test_a_reference_gives_the_tracking_error_and_its_band(fits):
    # the "reference" is the noise-free truth: the measured tracking error is the noise
    # alone (RMS sigma), inside the band the fit predicts for it
    model, theta, fit, _ = fits[0]
    rec = minor_loops(model, theta, seed=3)
    truth = model.simulate(rec.u, rec.t, theta) + 0.4
    chk = check_transfer(fit.posterior, fit.sampling.draws(200, seed=0), rec,
                         reference={"minor": truth}, by_segment=False, seed=1)
    (w,) = chk.windows
    span = np.ptp(fit.posterior.data[0].y[fit.posterior.data[0].scored])
    assert w.tracking_percent == pytest.approx(100 * 0.05 / span, rel=0.08)
    assert w.tracking_inside is True
    d = chk.to_dict()
    assert d["windows"][0]["tracking_inside"] is True and d["warnings"] == list(chk.warnings)
    assert list(chk.to_dataframe()["label"]) == ["minor"]
    with pytest.raises(ParameterError, match="no record named"):
        check_transfer(fit.posterior, fit.sampling.draws(20, seed=0), rec,
                       reference={"other": truth})
    with pytest.raises(ParameterError, match="expected 3000 samples"):
        check_transfer(fit.posterior, fit.sampling.draws(20, seed=0), rec,
                       reference={"minor": truth[:10]})


def test_a_residual_learned_on_like_paths_carries_the_transfer_error(fits):
    """Oracle: a plant with a shape error the fit never saw, the same in both halves.

    Constant-amplitude minor loops; the plant adds ``0.15 ((u - 75) / 30)^2`` (three noise
    sd, periodic in the loop) to the fitted model. The fit's own residual knows nothing
    of it and the 90 % band misses; learned on the first half, the residual carries it
    into the second half's band, which then covers at its nominal rate.
    """
    model, theta, fit, _ = fits[2]
    t = np.arange(3000) * 1e-3
    u = 75 + 30 * np.sin(2 * np.pi * 5 * t)
    y = (model.simulate(u, t, theta) + 0.4 + 0.15 * ((u - 75) / 30) ** 2
         + np.random.default_rng(21).normal(0.0, 0.05, t.size))
    first = t < 1.5
    rec = Record(t=t, u=u, y=y, name="shape", warmup=200, metadata={"frequency_hz": 5.0},
                 segment=(~first).astype(int))
    z = fit.sampling.draws(300, seed=0)
    plain = check_transfer(fit.posterior, z, rec, seed=0)
    assert plain.windows[1].coverage[0.9] < plain.windows[1].expected[0.9][0]
    learned = check_transfer(fit.posterior, z, rec, residual_from={"shape": first}, seed=0)
    (w,) = learned.windows
    assert w.label == "shape#1"
    assert w.expected[0.9][0] - 0.03 <= w.coverage[0.9] <= w.expected[0.9][1] + 0.03
    assert w.expected[0.5][0] - 0.03 <= w.coverage[0.5] <= w.expected[0.5][1] + 0.03
    with pytest.raises(ParameterError, match="boolean mask"):
        check_transfer(fit.posterior, z, rec, residual_from={"shape": first.astype(int)})
