"""Blocks driven by a measured column, a moment in time or a disturbance.

Oracles: the blocks' equations written out here; the MAP of a posterior whose data were
generated with a known temperature coefficient; a saved and reloaded fit that predicts
exactly what the original did (the column travels with it).
"""

from __future__ import annotations

import numpy as np
import pytest

from bayeshyst import diagnostics
from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.errors import DataError, ModelError
from bayeshyst.inference.optimize import find_map
from bayeshyst.inference.posterior import Posterior
from bayeshyst.inference.sampling import sample_posterior
from bayeshyst.inference.saved import load_fit
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.models import get as get_model
from bayeshyst.models.blocks import AuxInput, ChangePoint, Disturbance
from bayeshyst.models.compose import model_spec

PI = "pi_play(n_operators=3)"
TRUE_W = {"p0": np.array(0.1), "w": np.array([0.03, 0.02, 0.01])}


def temperature_record(seed: int = 0, coef: float = 0.006, n: int = 3000) -> Record:
    """A 2 Hz sine through a 3-operator PI whose gain follows the temperature (coef /K)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 1000.0
    u = 75.0 + 75.0 * np.sin(2 * np.pi * 2.0 * t - np.pi / 2)
    temp = 20.0 + 9.0 * np.sin(np.pi * t / t[-1])
    base = get_model(PI)
    proto = Record(t, u, u.copy())
    theta = {**base.param_space(proto).fixed, **TRUE_W}
    y = base.simulate(u, t, theta) * (1.0 + coef * (temp - temp.mean()))
    y = y + 0.003 * rng.standard_normal(n)
    return Record(t, u, y, covariates={"temperature_c": temp, "spare": rng.random(n)},
                  name="temp", warmup=200)


def test_aux_block_follows_its_equation_and_is_nominal_without_the_column():
    blk = AuxInput(column="temperature_c", order=2)
    t = np.linspace(0, 1, 50)
    w = np.sin(7 * t)
    c = 20 + 5 * t ** 2
    theta = {"g": np.array([0.01, -0.002]), "h": np.array([0.3, 0.05]),
             "c_ref": 21.0, "c_scale": 2.0}
    z = (c - 21.0) / 2.0
    expected = w * (1 + 0.01 * z - 0.002 * z ** 2) + 0.3 * z + 0.05 * z ** 2
    out = blk.apply(w, t, theta, covariates={"temperature_c": c}).y
    np.testing.assert_allclose(out, expected, rtol=1e-13)
    np.testing.assert_array_equal(blk.apply(w, t, theta).y, w)  # at c_ref: identity
    with pytest.raises(ModelError, match="temperature_c"):
        blk.apply(w, t, theta, covariates={"other": c})
    with pytest.raises(ModelError, match="column"):
        AuxInput(column="a=b")


def test_change_point_and_disturbance_follow_their_equations():
    t = np.linspace(0, 2, 2001)
    w = np.cos(3 * t)
    out = ChangePoint().apply(w, t, {"t_c": 1.2, "g": 0.04, "h": -0.2, "width": 0.002}).y
    step = 0.5 * (1 + np.tanh((t - 1.2) / 0.004))
    np.testing.assert_allclose(out, w * (1 + 0.04 * step) - 0.2 * step, rtol=1e-13)
    assert out[0] == pytest.approx(w[0]) and out[-1] == pytest.approx(w[-1] * 1.04 - 0.2)
    dist = Disturbance(frequency_hz=37.3).apply(w, t, {"a": 0.1, "b": -0.05}).y
    np.testing.assert_allclose(dist, w + 0.1 * np.sin(2 * np.pi * 37.3 * t)
                               - 0.05 * np.cos(2 * np.pi * 37.3 * t), rtol=1e-13)
    with pytest.raises(ModelError):
        Disturbance(frequency_hz=-1.0)


def test_a_change_point_batch_is_each_row_applied_alone():
    # walkers with repeated and distinct change times (a design's columns repeat their
    # walker's values): every row bit for bit what that row gives on its own
    t = np.linspace(0, 2, 501)
    rng = np.random.default_rng(3)
    tc = np.array([1.2, 1.2, 0.7, 1.2, 0.7, 1.9])
    g, h = rng.normal(0, 0.05, tc.size), rng.normal(0, 0.2, tc.size)
    w = rng.normal(size=(tc.size, t.size))
    theta = {"t_c": tc, "g": g, "h": h, "width": np.full(tc.size, 0.008)}
    out = ChangePoint().apply_batch(w, t, theta).y
    for j in range(tc.size):
        one = ChangePoint().apply(w[j], t, {"t_c": tc[j], "g": g[j], "h": h[j],
                                            "width": 0.008}).y
        np.testing.assert_array_equal(out[j], one)
        step = 0.5 * (1 + np.tanh((t - tc[j]) / 0.016))
        np.testing.assert_allclose(out[j], w[j] * (1 + g[j] * step) + h[j] * step,
                                   rtol=1e-13, atol=1e-15)


def test_spec_strings_rebuild_the_blocks():
    for spec in (f"{PI}+aux(column='temperature_c')", f"{PI}+change_point",
                 f"{PI}+disturbance(frequency_hz=37.3)",
                 f"{PI}+aux(column='temperature_c', order=2)+creep"):
        model = get_model(spec)
        assert get_model(model_spec(model)) == model
    assert get_model(f"{PI}+aux(column='temperature_c')").covariates == ("temperature_c",)


def test_a_record_without_the_column_is_refused_by_name():
    rec = temperature_record()
    bare = Record(rec.t, rec.u, rec.y, name="bare")
    with pytest.raises(DataError, match="temperature_c"):
        Posterior(bare, f"{PI}+aux(column='temperature_c')")


def test_the_map_recovers_the_temperature_coefficient():
    rec = temperature_record()
    post = Posterior(rec, f"{PI}+aux(column='temperature_c')")
    start = find_map(post, seed=0)
    theta = post.space.unpack(start.z)
    scale = post.space.fixed["aux.c_scale"]
    per_kelvin = float(np.asarray(theta["aux.g"]).ravel()[0]) / scale
    assert per_kelvin == pytest.approx(0.006, rel=0.02)


def test_a_saved_fit_with_a_column_reloads_and_predicts_the_same(tmp_path):
    rec = temperature_record(n=1500)
    post = Posterior(Dataset((rec,)), f"{PI}+aux(column='temperature_c')")
    start = find_map(post, seed=0, global_search=False, n_screen=64, n_starts=1)
    res = sample_posterior(post, SamplerSettings(seed=3, max_steps=200, first_chunk=100),
                           start=start)
    idata = diagnostics.to_inference_data(post, res, draws_per_chain=5, n_predictive=10)
    diagnostics.save_netcdf(idata, tmp_path / "x.nc")
    fit = load_fit(tmp_path / "x.nc")
    np.testing.assert_array_equal(fit.data[0].covariates["temperature_c"],
                                  rec.covariates["temperature_c"])
    z = fit.draws(10, seed=0)
    for p_new, p_old in zip(fit.posterior.predict(z), post.predict(z), strict=True):
        np.testing.assert_array_equal(p_new, p_old)
