"""Feedforward compensation per frequency on plants with a known truth."""

from __future__ import annotations

import numpy as np
import pytest

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.virtual import (
    AR1Noise,
    PreisachHysteresis,
    SecondOrder,
    VirtualActuator,
    hysteresis_percent,
)
from bayeshyst.errors import DataError, ParameterError
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.inverse.compensate import compensate
from bayeshyst.inverse.references import load_reference, reference_signal


def loops(actuator, freqs, *, samples_per_cycle=100, cycles=4, seed=0):
    recs = []
    for f in freqs:
        fs = samples_per_cycle * f
        t = np.arange(cycles * samples_per_cycle) / fs
        u = 75.0 - 75.0 * np.cos(2 * np.pi * f * t)
        recs.append(actuator.record(t, u, rng=seed + int(f), name=f"v{f:g}",
                                    warmup=samples_per_cycle, frequency_hz=f))
    return Dataset(tuple(recs), name="virtual")


HYSTERESIS_ONLY = VirtualActuator().without("creep", "dynamics", "drift", "delay").with_effects(
    noise=AR1Noise(rms_um=0.04, phi=0.0))


def test_generating_model_tracks_below_one_percent_at_1hz():
    data = loops(HYSTERESIS_ONLY, [1.0])
    rec = data[0]
    assert 10.0 < hysteresis_percent(rec.u[100:], rec.y[100:]) < 15.0  # the plant
    res = compensate(data, "preisach_density(n_grid=32)",
                     sampler=SamplerSettings(max_steps=1000, n_walkers=24, seed=2),
                     n_design_draws=16, n_predict_draws=60)
    assert res.plant_kind == "virtual actuator"
    (row,) = res.rows
    assert row.uncompensated_nrmse_percent > 3.0
    assert row.nominal_nrmse_percent < 1.0
    assert row.posterior_nrmse_percent < 1.0
    assert row.robust_nrmse_percent < 1.0
    assert row.model_error_percent < 1e-6
    d = res.to_dict()["per_frequency"][0]
    for key in ("frequency_hz", "uncompensated_nrmse_percent", "nominal_nrmse_percent",
                "posterior_nrmse_percent", "predicted_band_percent", "realised_inside_band"):
        assert key in d
    assert d["predicted_band_percent"][0] <= d["predicted_band_percent"][1]


def test_posterior_plants_bands_and_posterior_command():
    """Plants drawn from the posterior (held out from design and prediction draws).

    They are exchangeable with the prediction draws, so the 90 % band must hold for
    ~90 % of them (binomial, 200 plants: sd 2.1 %). The posterior-mean command sets the
    mean output of ``S`` design draws to the reference: against plants from the
    posterior its mean squared error is the posterior variance plus the Monte-Carlo
    variance of an ``S``-draw mean, ``Var (1 + 1/S)``; the MAP's is the variance plus
    its bias squared. So "never worse on average" means: not worse than the nominal
    command by more than that ``1/S`` and the paired sampling error over plants.
    Plants and prediction draws are measured: each carries a residual series resampled
    from the fit's residual (the same for every command on a plant), whose mean square
    ``r^2`` the comparison with the uncompensated command takes out.
    """
    noisy = HYSTERESIS_ONLY.with_effects(noise=AR1Noise(rms_um=0.6, phi=0.0))
    data = loops(noisy, [1.0], cycles=3)
    n_design = 96
    res = compensate(data, "pi_play(n_operators=4)", plant="posterior",
                     sampler=SamplerSettings(max_steps=1500, n_walkers=24, seed=5),
                     n_design_draws=n_design, n_predict_draws=200, n_plants=200)
    (row,) = res.rows
    assert res.plant_kind == "posterior draw"
    assert 0.9 - 4 * 0.021 <= row.plants_inside_band <= 0.9 + 4 * 0.021
    mse_post, mse_nom = row.curves["nrmse_posterior"] ** 2, row.curves["nrmse_nominal"] ** 2
    diff = mse_post - mse_nom * (1.0 + 1.0 / n_design)
    assert diff.mean() <= 3.0 * diff.std(ddof=1) / np.sqrt(diff.size)
    r2 = row.residual_rms_percent ** 2
    assert 0.0 < r2 < np.mean(row.curves["nrmse_posterior"] ** 2)
    excess = {k: np.mean(row.curves[f"nrmse_{k}"] ** 2) - r2 for k in ("posterior",
                                                                       "uncompensated")}
    assert np.sqrt(max(excess["posterior"], 0.0)) < 0.2 * np.sqrt(excess["uncompensated"])


def test_static_model_on_dynamic_plant_error_grows_and_is_reported():
    plant = VirtualActuator().without("creep", "drift", "delay").with_effects(
        noise=AR1Noise(rms_um=0.04, phi=0.0),
        dynamics=SecondOrder(resonance_hz=500.0, damping=0.2),
        hysteresis=PreisachHysteresis(center_v=75.0, halfwidth_slope=0.0))
    data = loops(plant, [1.0, 50.0, 150.0])
    res = compensate(data, "pi_play(n_operators=8)",
                     sampler=SamplerSettings(max_steps=1000, n_walkers=24, seed=1),
                     n_design_draws=12, n_predict_draws=60)
    low, top = res.rows[0], res.rows[-1]
    assert top.posterior_nrmse_percent > low.posterior_nrmse_percent
    # the static model alone does not predict the growth; the fit's residual shows it
    assert top.posterior_nrmse_percent > top.model_band_percent[1]
    assert top.residual_rms_percent > low.residual_rms_percent
    assert any("grows with frequency" in s for s in res.statements)


def test_reference_shapes():
    ref = reference_signal("sine", 10.0, 1000.0, 2.0, 30.0, cycles=2, warmup_cycles=1)
    assert ref.t.size == 300 and ref.scored.sum() == 200
    assert ref.y_d[0] == pytest.approx(2.0) and ref.y_d.max() == pytest.approx(30.0)
    assert ref.y_d[1] - ref.y_d[0] < 1e-2 * 28  # starts at rest
    tri = reference_signal("triangle", 10.0, 1000.0, 2.0, 30.0)
    assert tri.y_d[50] == pytest.approx(30.0) and tri.y_d[0] == pytest.approx(2.0)
    np.testing.assert_allclose(np.diff(tri.y_d[:50]), 28.0 / 50.0)
    with pytest.raises(ParameterError, match="reference"):
        reference_signal("square", 10.0, 1000.0, 2.0, 30.0)


def test_reference_file_errors_name_the_place(tmp_path):
    good = tmp_path / "ref.csv"
    good.write_text("t,y\n" + "\n".join(f"{k / 100},{np.sin(k / 10)}" for k in range(20)))
    ref = load_reference(good)
    assert ref.kind == "ref.csv" and ref.t.size == 20 and not ref.periodic
    bad = tmp_path / "bad.csv"
    bad.write_text("t,y\n0,1\n0.1,x\n" + "\n".join(f"{k},{k}" for k in range(1, 10)))
    with pytest.raises(DataError, match=r"bad\.csv: row 3"):
        load_reference(bad)
    nocol = tmp_path / "nocol.csv"
    nocol.write_text("t,z\n0,1\n")
    with pytest.raises(DataError, match=r"nocol\.csv.*'y'"):
        load_reference(nocol)
    back = tmp_path / "back.csv"
    back.write_text("t,y\n" + "\n".join(f"{k if k != 5 else 3},{k}" for k in range(12)))
    with pytest.raises(DataError, match=r"back\.csv: column 't', row 7"):
        load_reference(back)


def test_a_validation_record_supplies_the_residual_of_the_bands():
    # oracle: the records the model was fitted on, given as "validation", hold exactly the
    # training residual -- the bands must be the default ones, bit for bit; the records
    # shifted by 1 um add that shift to the residual the bands carry (in quadrature)
    data = loops(HYSTERESIS_ONLY, [1.0])
    sampler = SamplerSettings(max_steps=600, n_walkers=24, seed=4)
    from bayeshyst.data.record import Record
    from bayeshyst.inference.fit import fit_model

    fit = fit_model(data, "pi_play(n_operators=4)", "gaussian", sampler=sampler)
    common = {"fit": fit, "sampler": sampler, "n_design_draws": 8, "n_predict_draws": 40}
    default = compensate(data, "pi_play(n_operators=4)", **common)
    same = compensate(data, "pi_play(n_operators=4)", validation=data, **common)
    assert same.rows[0].predicted_band_percent == default.rows[0].predicted_band_percent
    assert same.settings["residual_from"].startswith("validation records")
    shifted = Dataset(tuple(Record(t=r.t, u=r.u, y=r.y + 1.0, name=r.name, warmup=r.warmup,
                                   metadata=dict(r.metadata)) for r in data))
    row = compensate(data, "pi_play(n_operators=4)", validation=shifted, **common).rows[0]
    shift = 100.0 * 1.0 / np.ptp(row.curves["y_d"])
    expected = np.hypot(default.rows[0].residual_rms_percent, shift)
    assert row.residual_rms_percent == pytest.approx(expected, rel=0.1)
    r0 = data[0]
    short = Record(t=r0.t[:60], u=r0.u[:60], y=r0.y[:60], name="short", warmup=55)
    with pytest.raises(DataError, match="validation short: 5 scored samples"):
        compensate(data, "pi_play(n_operators=4)", validation=short, **common)
