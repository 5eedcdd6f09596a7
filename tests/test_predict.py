"""predict: a fit's posterior predictive on records it never saw, and its scores.

Oracles:
- on the fitted records, the prediction is the fit's own posterior predictive: the
  same noise-free simulations (``Posterior.predict``) and the same predictive draws
  (``calibration.predictive_draws``) with the same generator, to the last bit;
- on another record, every score is recomputed here from an independent per-draw
  simulation (``model.simulate`` one draw at a time, the offset added by hand);
- periodic steady state equals the last period of one long simulation of many periods;
  "rest" equals a run from the model's relaxed state at zero input;
- a Gaussian predictor's bands and PIT are the normal quantiles and CDF, and data drawn
  from that Gaussian are covered as a calibrated predictive's are (binomial range) over
  seeds.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import special, stats

from bayeshyst import diagnostics
from bayeshyst.cli import main
from bayeshyst.data import Record, write_csv
from bayeshyst.data.dataset import Dataset
from bayeshyst.errors import DataError, ParameterError
from bayeshyst.inference.calibration import predictive_draws
from bayeshyst.inference.optimize import find_map
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.predict import (
    QUANTILES,
    InitialCondition,
    predict,
    predict_posterior,
    predict_predictor,
)
from bayeshyst.inference.protocols import Prediction
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.saved import load_fit
from bayeshyst.inference.settings import SamplerSettings
from tests.synthetic import pi_data


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    model, rec, theta = pi_data(n_ops=3, n=800, warmup=100)
    post = Posterior(Dataset((rec,), name="train"), model)
    start = find_map(post, seed=0, global_search=False, n_screen=64, n_starts=1)
    res = sample_posterior(post, SamplerSettings(seed=3, max_steps=300, first_chunk=100),
                           start=start)
    out = tmp_path_factory.mktemp("fit")
    idata = diagnostics.to_inference_data(post, res, draws_per_chain=5, n_predictive=10)
    diagnostics.save_netcdf(idata, out / "posterior.nc")
    return model, theta, post, res, out


def _other(model, theta, *, f=5.0, n=1000, amp=60.0, seed=1, offset=0.4, name="other"):
    t = np.arange(n) * 1e-3
    u = 75 + amp * np.sin(2 * np.pi * f * t)
    y = model.simulate(u, t, theta) + offset + np.random.default_rng(seed).normal(0, 0.05, n)
    return Record(t=t, u=u, y=y, name=name, metadata={"frequency_hz": f})


def test_on_the_fitted_record_it_is_the_fits_own_posterior_predictive(fitted):
    _, _, post, res, _ = fitted
    z = res.draws(60, seed=2)
    got = predict_posterior(post, z, post.data, seed=7)
    (rec,) = got.records
    sims = post.predict(z)[0]
    np.testing.assert_array_equal(rec.mean, sims.mean(axis=0))
    np.testing.assert_array_equal(rec.sd, sims.std(axis=0))
    reps = predictive_draws(post, z, np.random.default_rng(7))[0]
    np.testing.assert_array_equal(rec.bands, np.quantile(reps, QUANTILES, axis=0))
    # the scored samples are the fit's: after the record's warm-up
    data_rec = post.data[0]
    assert rec.scored.sum() == data_rec.n_scored and not rec.scored[: data_rec.warmup].any()
    e = data_rec.y[data_rec.warmup:] - sims.mean(axis=0)[data_rec.warmup:]
    assert got.overall.rmse == pytest.approx(np.sqrt(np.mean(e**2)), rel=1e-12)


def test_scores_on_another_record_match_an_independent_simulation(fitted):
    model, theta, post, _res, out = fitted
    fit = load_fit(out)
    rec = _other(model, theta)
    got = fit.predict(rec, n_draws=50, seed=4)
    z = fit.draws(50, seed=4)
    th = fit.posterior.space.unpack(z)
    sims = np.array([model.simulate(rec.u, rec.t, {k: np.asarray(th[k])[i]
                                                   for k in post.model_space.all_names})
                     + float(np.asarray(th["obs.offset"])[i]) for i in range(z.shape[0])])
    mean = sims.mean(axis=0)
    span = float(np.ptp(rec.y))
    e = rec.y - mean
    s = got.per_record[0]
    assert abs(s.rmse - np.sqrt(np.mean(e**2))) <= 1e-9 * span
    assert abs(s.max_error - np.max(np.abs(e))) <= 1e-9 * span
    fit_pct = 100 * (1 - np.linalg.norm(e) / np.linalg.norm(rec.y - rec.y.mean()))
    assert s.fit_percent == pytest.approx(fit_pct, abs=1e-7)
    assert s.nrmse_percent == pytest.approx(100 * s.rmse / span, rel=1e-12)
    # the coverage is the share of samples inside the written bands
    r = got.records[0]
    inside90 = (rec.y >= r.bands[0]) & (rec.y <= r.bands[3])
    assert s.coverage[0.9] == inside90.mean()
    assert got.overall.rmse == s.rmse and rec.group == "5 Hz"
    assert got.source == str(fit.path) and got.n_draws == 50


def test_the_same_seed_gives_the_same_prediction(fitted):
    model, theta, _, _, out = fitted
    fit = load_fit(out)
    rec = _other(model, theta)
    a, b = fit.predict(rec, n_draws=30, seed=5), fit.predict(rec, n_draws=30, seed=5)
    np.testing.assert_array_equal(a.records[0].bands, b.records[0].bands)
    np.testing.assert_array_equal(a.records[0].pit, b.records[0].pit)


def test_periodic_steady_state_is_the_last_period_of_a_long_simulation(fitted):
    model, _theta, post, res, _ = fitted
    # a record of two whole periods of a decaying-then-repeating input: the play
    # operators' state depends on where each period leaves them
    f, n_per = 4.0, 250
    t = np.arange(2 * n_per) * 1e-3
    u = 75 + 50 * np.sin(2 * np.pi * f * t) + 15 * np.sin(2 * np.pi * 3 * f * t + 0.3)
    rec = Record(t=t, u=u, y=np.zeros_like(u) + np.sin(t), name="p",
                 metadata={"frequency_hz": f})
    z = res.draws(5, seed=0)
    got = predict_posterior(post, z, rec, initial=InitialCondition("periodic", periods=3))
    th = post.space.unpack(z)
    reps = 20
    t_long = np.concatenate([t + j * (t[-1] + 1e-3) for j in range(reps)])
    sims = []
    for i in range(z.shape[0]):
        one = {k: np.asarray(th[k])[i] for k in post.model_space.all_names}
        y_long = model.simulate(np.tile(u, reps), t_long, one) + np.asarray(th["obs.offset"])[i]
        sims.append(y_long[-rec.n:])
    span = float(np.ptp(sims))
    np.testing.assert_allclose(got.records[0].mean, np.mean(sims, axis=0), rtol=0,
                               atol=1e-9 * span)
    assert got.records[0].scored.all()  # the earlier periods are the warm-up
    assert got.steady_state_change is not None and got.steady_state_change <= 1e-9 * span


def test_periodic_refuses_a_record_that_is_not_whole_periods(fitted):
    model, theta, post, res, _ = fitted
    z = res.draws(3, seed=0)
    rec = _other(model, theta, f=5.0, n=1100)  # 5.5 periods
    with pytest.raises(DataError, match=r"whole periods.*5\.500 periods"):
        predict_posterior(post, z, rec, initial=InitialCondition.parse("periodic:3"))
    # without a frequency: the seam is checked (a sine cut mid-period has a kink there)
    bare = rec.with_(metadata={})
    with pytest.raises(DataError, match="last sample does not lead into its first"):
        predict_posterior(post, z, bare, initial=InitialCondition.parse("periodic"))
    whole = _other(model, theta, f=5.0, n=1000).with_(metadata={})
    assert predict_posterior(post, z, whole, initial=InitialCondition.parse("periodic"))


def test_rest_starts_from_the_relaxed_state_at_zero_input(fitted):
    model, theta, post, res, _ = fitted
    rec = _other(model, theta)
    z = res.draws(4, seed=1)
    got = predict_posterior(post, z, rec, initial=InitialCondition.parse("rest"))
    th = post.space.unpack(z)
    sims = []
    for i in range(z.shape[0]):
        one = {k: np.asarray(th[k])[i] for k in post.model_space.all_names}
        s0 = model.initial_state(one, 0.0)
        sims.append(model.simulate(rec.u, rec.t, one, state0=s0) + np.asarray(th["obs.offset"])[i])
    np.testing.assert_allclose(got.records[0].mean, np.mean(sims, axis=0), rtol=0, atol=1e-12)
    # and it differs from the relaxed start (the first branch rises from zero input)
    relaxed = predict_posterior(post, z, rec)
    assert np.max(np.abs(relaxed.records[0].mean - got.records[0].mean)) > 0.1


def test_warmup_leaves_its_span_unscored(fitted):
    model, theta, post, res, _ = fitted
    rec = _other(model, theta)
    z = res.draws(10, seed=1)
    got = predict_posterior(post, z, rec, initial=InitialCondition.parse("warmup:0.25"))
    r = got.records[0]
    np.testing.assert_array_equal(r.scored, rec.t >= rec.t[0] + 0.25)
    e = (rec.y - r.mean)[r.scored]
    assert got.overall.rmse == pytest.approx(np.sqrt(np.mean(e**2)), rel=1e-12)
    assert np.isnan(r.pit[~r.scored]).all() and np.isfinite(r.pit[r.scored]).all()
    with pytest.raises(DataError, match="left to score"):
        predict_posterior(post, z, rec, initial=InitialCondition.parse("warmup:5"))


def test_an_input_outside_the_fitted_range_is_a_warning_with_its_share(fitted):
    model, theta, post, res, _ = fitted
    rec = _other(model, theta, amp=80.0)  # the fit saw 75 +- 70 at most
    z = res.draws(5, seed=1)
    got = predict_posterior(post, z, rec)
    lo, hi = post.data[0].u.min(), post.data[0].u.max()
    share = float(np.mean((rec.u < lo) | (rec.u > hi)))
    assert share > 0 and got.records[0].outside_input == pytest.approx(share)
    assert any(f"{100 * share:.1f} % of the scored samples have an input outside" in w
               for w in got.warnings)
    inside = predict_posterior(post, z, _other(model, theta, amp=40.0))
    assert not any("outside the range" in w for w in inside.warnings)


def test_initial_condition_text_and_refusals():
    assert InitialCondition.parse("periodic:5") == InitialCondition("periodic", periods=5)
    assert InitialCondition.parse("warmup:0.5").warmup_s == 0.5
    assert InitialCondition.parse(" rest ").kind == "rest"
    for bad in ("steady", "warmup", "periodic:1", "periodic:x", "rest:3", "warmup:-1"):
        with pytest.raises(ParameterError):
            InitialCondition.parse(bad)


class _Gaussian:
    """A predictor whose predictive is N(mean, sd^2 + noise^2) with known numbers."""

    def __init__(self, mean_of, sd, noise):
        self.mean_of, self.sd, self.noise = mean_of, sd, noise

    def predict_records(self, data):
        return [Prediction(r.name, self.mean_of(r.u), np.full(r.n, self.sd), self.noise)
                for r in data]

    def log_density_units(self, data):  # pragma: no cover - the protocol's other methods
        raise NotImplementedError

    def loo_units(self, data):  # pragma: no cover
        raise NotImplementedError


def test_a_gaussian_predictor_gives_normal_bands_and_calibrated_coverage():
    sd, noise = 0.3, 0.4
    total = np.hypot(sd, noise)
    gp = _Gaussian(lambda u: 0.1 * u, sd, noise)
    t = np.arange(2000) * 1e-3
    u = 10 * np.sin(2 * np.pi * 2 * t)
    misses = 0
    for seed in range(10):
        y = 0.1 * u + np.random.default_rng(seed).normal(0, total, t.size)
        got = predict(gp, Record(t=t, u=u, y=y, name="g", metadata={"frequency_hz": 2.0}))
        r = got.records[0]
        np.testing.assert_allclose(r.bands, 0.1 * u[None, :] + stats.norm.ppf(
            np.asarray(QUANTILES))[:, None] * total, rtol=0, atol=1e-12)
        np.testing.assert_allclose(r.pit, special.ndtr((y - 0.1 * u) / total), atol=1e-15)
        misses += not got.overall.calibrated
    # each check holds 95 % of the time per band: 3 or more misses of 10 has
    # probability < 2 % even if the two bands' misses never coincide (p = 0.1)
    assert misses <= 2
    with pytest.raises(ParameterError, match="no state to set at rest"):
        predict_predictor(gp, Record(t=t, u=u, y=u, name="g"), initial=InitialCondition("rest"))


def test_the_command_writes_predictions_scores_and_summary(fitted, tmp_path, capsys):
    model, theta, _, _, out = fitted
    rec = _other(model, theta)
    path = tmp_path / "other.csv"
    write_csv(Dataset((rec,), name="other"), path)
    dest = tmp_path / "pred"
    code = main(["predict", str(out), str(path), "--out", str(dest), "--draws", "40",
                 "--quiet", "--json"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    assert json.loads((dest / "summary.json").read_text()) == summary
    assert summary["command"] == "predict" and summary["n_draws"] == 40
    assert summary["initial_condition"]["kind"] == "relaxed"
    import pandas as pd

    pred = pd.read_csv(dest / "predictions.csv")
    assert len(pred) == rec.n and {"t", "u", "y", "mean", "lo90", "hi90", "pit"} <= set(pred)
    np.testing.assert_allclose(pred["y"], rec.y, rtol=1e-9)
    e = pred["y"] - pred["mean"]
    assert summary["overall"]["rmse"] == pytest.approx(np.sqrt(np.mean(e**2)), rel=1e-6)
    assert len(summary["files"]["figures"]) == 1
    assert (dest / summary["files"]["figures"][0]).stat().st_size > 10_000


def test_the_command_refuses_bad_input_and_writes_nothing(fitted, tmp_path, capsys):
    model, theta, _, _, out = fitted
    rec = _other(model, theta, n=1100)
    path = tmp_path / "other.csv"
    write_csv(Dataset((rec,), name="other"), path)
    dest = tmp_path / "pred"
    code = main(["predict", str(out), str(path), "--out", str(dest), "--initial",
                 "periodic:3", "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "whole periods" in err and "Traceback" not in err
    assert not dest.exists()
    assert main(["predict", str(out), str(tmp_path / "missing.csv"), "--out", str(dest)]) == 2
    assert not dest.exists()
    with pytest.raises(SystemExit) as exc:
        main(["predict", str(out), str(path), "--initial", "steady"])
    assert exc.value.code == 2


def test_a_record_in_other_units_is_converted_and_one_of_another_dimension_refused(fitted):
    model, theta, post, res, _ = fitted
    rec = _other(model, theta)
    z = res.draws(8, seed=1)
    # the same record in nm and ms: its prediction is the um/s one's, converted back
    nm = rec.with_(t=rec.t * 1e3, y=rec.y * 1e3, units={"t": "ms", "u": "V", "y": "nm"})
    a, b = predict_posterior(post, z, rec, seed=3), predict_posterior(post, z, nm, seed=3)
    np.testing.assert_allclose(b.records[0].mean, a.records[0].mean, rtol=1e-12)
    assert b.overall.rmse == pytest.approx(a.overall.rmse, rel=1e-9)
    assert b.units["y"] == "um" and any("nm -> um" in n or "y nm" in n for n in b.notes)
    force = rec.with_(units={"t": "s", "u": "V", "y": "N"})
    with pytest.raises(DataError, match=r"'other'.*\by\b.*N.*um|'other'.*um.*N"):
        predict_posterior(post, z, force)
    unknown = rec.with_(units={"t": "s", "u": "V", "y": "unknown"})
    with pytest.raises(DataError, match="unknown"):
        predict_posterior(post, z, unknown)


def test_a_gaussian_process_predicts_through_the_predictor_protocol(fitted):
    from bayeshyst.gp import GPHysteresis

    model, theta, post, _, _ = fitted
    gp = GPHysteresis(features="memory", n_train=200, n_restarts_optimizer=0,
                      random_state=0).fit_records(post.data)
    rec = _other(model, theta, amp=50.0)
    got = predict(gp, rec, initial="warmup:0.2")
    (p,) = gp.predict_records(Dataset((rec,), name="x"))
    r = got.records[0]
    np.testing.assert_array_equal(r.mean, p.mean)
    total = np.sqrt(p.std**2 + p.noise_std**2)
    np.testing.assert_allclose(r.bands[3] - r.mean, stats.norm.ppf(0.95) * total, rtol=1e-12)
    e = (rec.y - p.mean)[rec.t >= 0.2]
    assert got.overall.rmse == pytest.approx(np.sqrt(np.mean(e**2)), rel=1e-12)
    assert got.n_draws == 0 and "Gaussian predictive" in got.method


def test_a_broadband_record_gets_its_error_spectrum_per_octave(fitted, tmp_path):
    from bayeshyst.inference.error_spectrum import error_spectrum

    model, theta, post, res, _ = fitted
    fs, n = 1000.0, 4000
    rng = np.random.default_rng(3)
    spec = np.fft.rfft(rng.normal(size=n))
    spec[(np.fft.rfftfreq(n, 1 / fs) < 2) | (np.fft.rfftfreq(n, 1 / fs) > 30)] = 0
    x = np.fft.irfft(spec, n)
    t = np.arange(n) / fs
    u = 75 + 50 * x / np.max(np.abs(x))
    y = model.simulate(u, t, theta) + 0.4 + rng.normal(0, 0.05, n)
    rec = Record(t=t, u=u, y=y, name="rand", warmup=200,
                 metadata={"excitation": "broadband", "band_hz": (2.0, 30.0)})
    got = predict_posterior(post, res.draws(10, seed=0), rec)
    (band, rows), = got.spectra
    assert band.label == rec.group == "band 2-30 Hz"
    # the oracle: the error spectrum of the record's scored samples and the mean
    want = error_spectrum(rec, got.records[0].mean)
    assert rows == want and rows[0].lo_hz == 2.0 and rows[-1].hi_hz == fs / 2
    dest = tmp_path / "p"
    from bayeshyst.outputs.predict_outputs import write_predict_outputs

    summary = write_predict_outputs(got, dest, fit_path="f", data_path="d")
    assert summary["files"]["spectrum"] == "spectrum.csv"
    assert summary["error_spectra"][0]["group"] == "band 2-30 Hz"
    assert "error spectrum of band 2-30 Hz" in str(got)


def test_every_entry_point_refuses_a_bad_request_in_words(fitted):
    model, theta, _, _, out = fitted
    fit = load_fit(out)
    rec = _other(model, theta)
    for bad, match in (({"n_draws": 0}, "n_draws"), ({"n_draws": True}, "n_draws"),
                       ({"n_draws": 2.5}, "n_draws"), ({"initial": "steady"}, "initial"),
                       ({"initial": 3}, "initial")):
        for call in (fit.predict, lambda d, **kw: predict(fit, d, **kw)):
            with pytest.raises(ParameterError, match=match):
                call(rec, **bad)


def test_an_input_alone_is_predicted_and_not_scored(fitted, tmp_path, capsys):
    model, theta, _post, _res, out = fitted
    rec = _other(model, theta)
    path = tmp_path / "command.csv"
    rows = "\n".join(f"{a:.17g},{b:.17g}" for a, b in zip(rec.t, rec.u, strict=True))
    path.write_text("t [s],u [V]\n" + rows + "\n")
    dest = tmp_path / "pred"
    assert main(["predict", str(out), str(path), "--out", str(dest), "--draws", "30",
                 "--quiet", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["overall"] is None and summary["per_group"] == []
    (entry,) = summary["per_record"]
    assert entry["measured"] is False and entry["name"] == "command"
    assert summary["units"]["y"] == "um"  # the fit's: the output is the model's
    import pandas as pd

    pred = pd.read_csv(dest / "predictions.csv")
    assert pred["y"].isna().all() and pred["pit"].isna().all()
    # the mean is the same draws' simulation as for the measured twin of the record
    fit = load_fit(out)
    twin = fit.predict(rec, n_draws=30, seed=0)
    np.testing.assert_allclose(pred["mean"], twin.records[0].mean, rtol=1e-9)
    assert len(summary["files"]["figures"]) == 1
    # fit and the other commands still need the output
    assert main(["fit", str(path), "--model", "pi_play", "--out", str(tmp_path / "f"),
                 "--quiet"]) == 2
    assert "column 'y': missing" in capsys.readouterr().err
