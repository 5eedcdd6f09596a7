"""load_fit: a saved posterior read back is the posterior that was sampled.

Oracle: the in-memory posterior and draws the file was written from — the reloaded
model, data, parameter draws and predictions must equal them, and the rebuilt
posterior must give the log densities the sampler recorded. Files that are not such a
record (no record, another format, edited data, several posteriors) are refused in words.
"""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from bayeshyst import diagnostics
from bayeshyst import models as M
from bayeshyst.data.dataset import Dataset
from bayeshyst.errors import DataError, ModelError
from bayeshyst.inference.optimize import find_map
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.saved import FIT_ATTR, load_fit
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.models.compose import model_spec
from tests.synthetic import pi_data


def _save(post, path, seed=3):
    start = find_map(post, seed=0, global_search=False, n_screen=64, n_starts=1)
    res = sample_posterior(post, SamplerSettings(seed=seed, max_steps=300, first_chunk=100),
                           start=start)
    idata = diagnostics.to_inference_data(post, res, draws_per_chain=5, n_predictive=10)
    diagnostics.save_netcdf(idata, path)
    return res, idata


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    model, rec, _ = pi_data(n_ops=3, n=800, warmup=100)
    post = Posterior(Dataset((rec,), name="bench"), model)
    out = tmp_path_factory.mktemp("fit")
    res, idata = _save(post, out / "posterior.nc")
    return post, res, idata, out


def test_a_reloaded_fit_is_the_fit_that_was_written(saved):
    post, res, idata, out = saved
    fit = load_fit(out)  # the directory: its posterior.nc
    assert fit.model == post.model and fit.likelihood == post.likelihood.name
    assert fit.posterior.space.names == post.space.names
    assert fit.posterior.space.fixed.keys() == post.space.fixed.keys()
    (a,), (b,) = fit.data, post.data
    np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_array_equal(a.u, b.u)
    np.testing.assert_array_equal(a.y, b.y)
    assert (a.warmup, a.frequency_hz, a.name, dict(a.units)) == (
        b.warmup, b.frequency_hz, b.name, dict(b.units))
    # the draws: the stored physical values, and the same predictions as the original
    n_chain, n_draw = idata.posterior.sizes["chain"], idata.posterior.sizes["draw"]
    assert fit.n_draws == n_chain * n_draw
    for name in post.space.names:
        np.testing.assert_allclose(
            np.asarray(fit.theta[name]).reshape(fit.n_draws, -1),
            idata.posterior[name].values.reshape(fit.n_draws, -1), rtol=1e-12)
    z = fit.draws(20, seed=1)
    for p_new, p_old in zip(fit.posterior.predict(z), post.predict(z), strict=True):
        np.testing.assert_array_equal(p_new, p_old)
    np.testing.assert_allclose(post.log_prob_batch(z), fit.posterior.log_prob_batch(z),
                               rtol=0, atol=1e-9)
    assert fit.max_log_prob_error < 1e-6
    assert fit.converged == res.converged and fit.seed == res.seed
    np.testing.assert_array_equal(fit.draws(20, seed=1), z)  # same seed, same draws
    frame = fit.to_dataframe()
    assert list(frame.columns) == list(post.space.labels) and len(frame) == fit.n_draws
    assert fit.to_dict()["model"] == model_spec(post.model)
    assert "pi_play(n_operators=3)" in str(fit)


def test_a_fit_with_a_discrepancy_and_a_fixed_parameter_reloads(tmp_path):
    model, rec, _ = pi_data(n_ops=2, n=700, warmup=100)
    post = Posterior(rec, model, discrepancy="hsgp").fix("noise.sigma", 0.05)
    _save(post, tmp_path / "x.nc")
    fit = load_fit(tmp_path / "x.nc")
    disc = fit.posterior.discrepancy
    assert disc is not None and disc.size == post.discrepancy.size
    np.testing.assert_array_equal(disc.constraint, post.discrepancy.constraint)
    assert fit.posterior.space.fixed["noise.sigma"] == 0.05
    z = fit.draws(10, seed=0)
    np.testing.assert_array_equal(fit.posterior.discrepancy_coefficients(z),
                                  post.discrepancy_coefficients(z))
    for p_new, p_old in zip(fit.posterior.predict(z), post.predict(z), strict=True):
        np.testing.assert_array_equal(p_new, p_old)


def _edit(path, fn):
    with h5py.File(path, "a") as f:
        fn(f)


def test_files_that_are_not_a_reloadable_fit_are_refused_in_words(saved, tmp_path):
    _, _, idata, _ = saved
    base = tmp_path / "a.nc"
    diagnostics.save_netcdf(idata, base)

    no_record = tmp_path / "none.nc"
    diagnostics.save_netcdf(idata, no_record)
    _edit(no_record, lambda f: f.attrs.__delitem__(FIT_ATTR))
    with pytest.raises(DataError, match="no 'bayeshyst_fit' record"):
        load_fit(no_record)

    future = tmp_path / "future.nc"
    diagnostics.save_netcdf(idata, future)
    _edit(future, lambda f: f.attrs.__setitem__(
        FIT_ATTR, f.attrs[FIT_ATTR].replace('"format": 1', '"format": 99')))
    with pytest.raises(DataError, match="fit format 99"):
        load_fit(future)

    # the data changed after the fit: the rebuilt posterior is not the sampled one
    edited = tmp_path / "edited.nc"
    diagnostics.save_netcdf(idata, edited)
    def shift(f):
        f["observed_data/y"][...] = f["observed_data/y"][...] + 0.3
    _edit(edited, shift)
    with pytest.raises(DataError, match="differs from the recorded one"):
        load_fit(edited)

    with pytest.raises(DataError, match="holds 4 saved posteriors"):
        load_fit(tmp_path)
    with pytest.raises(DataError, match="no such file"):
        load_fit(tmp_path / "missing")
    assert load_fit(base).n_draws > 0


def test_model_spec_rebuilds_every_registered_model_and_composite():
    for name in M.names():
        model = M.get(name)
        assert M.get(model_spec(model)) == model
    composed = M.get("pi_play(n_operators=7)+second_order+creep")
    assert model_spec(composed) == "pi_play(n_operators=7)+second_order+creep"
    assert M.get(model_spec(composed)) == composed
    assert model_spec(M.get("pi_play")) == "pi_play"  # defaults are left out


def test_model_spec_refuses_a_setting_that_is_not_a_literal():
    import dataclasses

    model = M.get("pi_play")
    field = next(f.name for f in dataclasses.fields(model) if f.init)
    odd = dataclasses.replace(model, **{field: 5})
    object.__setattr__(odd, field, object())
    with pytest.raises(ModelError, match="cannot be written in a spec string"):
        model_spec(odd)


# ------------------------------------------------------------------ bayeshyst invert
def _reference_csv(path, rec, n=1200):
    # a raised-cosine stroke inside the fitted output range, from rest
    lo, hi = np.quantile(rec.y, [0.2, 0.8])
    t = np.arange(n) / 2000.0
    y = lo + (hi - lo) * 0.5 * (1 - np.cos(2 * np.pi * 3.0 * t))
    rows = "".join(f"{float(a)!r},{float(b)!r}\n" for a, b in zip(t, y, strict=True))
    path.write_text("t,y\n" + rows)
    return t, y


def test_invert_cli_gives_the_maps_exact_inverse_and_its_band(saved, tmp_path):
    import pandas as pd

    from bayeshyst.cli import main
    from bayeshyst.inverse.numerical import invert

    post, _, _, out = saved
    t, y = _reference_csv(tmp_path / "ref.csv", post.data[0])
    for objective in ("nominal", "mean"):
        code = main(["invert", str(out), "--reference", str(tmp_path / "ref.csv"),
                     "--objective", objective, "--out", str(tmp_path / objective), "--quiet"])
        assert code == 0
    nominal = pd.read_csv(tmp_path / "nominal" / "command.csv")
    np.testing.assert_allclose(nominal["t"], t, rtol=0, atol=1e-12)
    # oracle: the MAP model, driven by the command, follows the reference
    fit = load_fit(out)
    theta, offset = fit.posterior.model_draws(fit.map_z[None, :])
    y_model = fit.model.run_batch(nominal["u"].to_numpy(), t, theta).y[0] + offset[0]
    assert np.max(np.abs(y_model - y)) < 1e-6 * np.ptp(y)
    # and it is the inverse the library computes from the same MAP
    direct = invert(fit.model, y, t, theta, offset=offset, u_limits=(-1e9, 1e9))
    np.testing.assert_allclose(nominal["u"], direct.u, rtol=0, atol=1e-6 * np.ptp(direct.u))
    import json

    s = json.loads((tmp_path / "mean" / "summary.json").read_text())
    lo, hi = s["predicted_band_percent"]
    assert 0 <= lo <= hi and s["objective"] == "mean" and s["n_design_draws"] == 24
    mean = pd.read_csv(tmp_path / "mean" / "command.csv")
    assert np.all(mean["y_lo"] <= mean["y_mean"] + 1e-12)
    assert np.all(mean["y_mean"] <= mean["y_hi"] + 1e-12)
    # same seed, same command
    assert main(["invert", str(out), "--reference", str(tmp_path / "ref.csv"), "--out",
                 str(tmp_path / "again"), "--quiet"]) == 0
    assert (tmp_path / "again" / "command.csv").read_text() == (
        tmp_path / "mean" / "command.csv").read_text()


def test_invert_cli_bad_input_exits_2_and_writes_nothing(saved, tmp_path, capsys):
    from bayeshyst.cli import main

    _, _, _, out = saved
    (tmp_path / "bad.csv").write_text("when,where\n0,1\n")
    cases = [([str(tmp_path / "nothing"), "--reference", str(tmp_path / "bad.csv")],
              "no such file"),
             ([str(out), "--reference", str(tmp_path / "bad.csv")], "must name columns")]
    for argv, message in cases:
        target = tmp_path / "out"
        assert main(["invert", *argv, "--out", str(target), "--quiet"]) == 2
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err
        assert not target.exists()


def test_invert_cli_designs_at_the_reference_files_temperature(tmp_path):
    # oracle: the library inverse of the saved MAP at the temperature the reference file
    # gives; the same file without that column is designed at nominal conditions, said
    # in a warning, and a text column in the file is ignored
    import json

    import pandas as pd

    from bayeshyst.cli import main
    from bayeshyst.data import Record
    from bayeshyst.inverse.numerical import invert
    from bayeshyst.models import get

    model = get("pi_covariate(n_operators=3)")
    t = np.arange(900) * 1e-3
    u = 75.0 - 60.0 * np.cos(2 * np.pi * 3.0 * t)
    temp = np.linspace(20.0, 30.0, t.size)
    truth = {"p0": 0.15, "w": np.array([0.08, 0.05, 0.03]), "a": 0.01, "b": 0.02,
             "r": np.array([15.0, 45.0, 75.0]), "c0": 25.0}
    y = model.simulate(u, t, truth, covariates={"temperature_c": temp})
    y = y + np.random.default_rng(0).normal(0.0, 0.02, t.size)
    rec = Record(t=t, u=u, y=y, name="warm", warmup=100,
                 covariates={"temperature_c": temp})
    post = Posterior(Dataset((rec,), name="warm"), model)
    out = tmp_path / "fit"
    out.mkdir()
    _save(post, out / "posterior.nc")
    t_ref = np.arange(600) * 1e-3
    y_ref = 10.0 + 12.0 * 0.5 * (1 - np.cos(2 * np.pi * 3.0 * t_ref))
    hot = np.full(t_ref.size, 32.0)
    rows = "".join(f"{float(a)!r},{float(b)!r},{float(c)!r},x\n"
                   for a, b, c in zip(t_ref, y_ref, hot, strict=True))
    (tmp_path / "hot.csv").write_text("t,y,temperature_c,note\n" + rows)
    (tmp_path / "plain.csv").write_text(
        "t,y\n" + "".join(f"{float(a)!r},{float(b)!r}\n"
                           for a, b in zip(t_ref, y_ref, strict=True)))
    for name in ("hot", "plain"):
        assert main(["invert", str(out), "--reference", str(tmp_path / f"{name}.csv"),
                     "--objective", "nominal", "--out", str(tmp_path / name), "--quiet"]) == 0
    fit = load_fit(out)
    theta, offset = fit.posterior.model_draws(fit.map_z[None, :])
    at_hot = invert(fit.model, y_ref, t_ref, theta, offset=offset, u_limits=(-1e9, 1e9),
                    covariates={"temperature_c": hot})
    u_hot = pd.read_csv(tmp_path / "hot" / "command.csv")["u"].to_numpy()
    np.testing.assert_allclose(u_hot, at_hot.u, rtol=0, atol=1e-6 * np.ptp(at_hot.u))
    u_plain = pd.read_csv(tmp_path / "plain" / "command.csv")["u"].to_numpy()
    assert np.max(np.abs(u_plain - u_hot)) > 1e-2 * np.ptp(u_hot)  # 7 K off nominal
    warned = json.loads((tmp_path / "plain" / "summary.json").read_text())["warnings"]
    assert any("temperature_c" in w and "mean conditions" in w for w in warned)
    assert not any("temperature_c" in w for w in json.loads(
        (tmp_path / "hot" / "summary.json").read_text())["warnings"])
