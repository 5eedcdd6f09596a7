"""The model-averaged feedforward design (bayeshyst.inverse.averaged).

Oracles: a play-PI is linear in its weights, so a mixture of two PIs whose draws are
gains g_A, g_B of one shape, pooled at weights (w_A, w_B), has the mean output of a
single PI with gain w_A g_A + w_B g_B: the averaged command must be that PI's exact
inverse. With the plants drawn from the same mixture as the prediction draws, the
predicted 90 % band holds a plant's error with probability 0.9.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from bayeshyst import models as M
from bayeshyst.errors import ParameterError
from bayeshyst.inverse.averaged import WeightedPosterior, allocate_draws, design_averaged
from bayeshyst.inverse.feedforward import Draws
from bayeshyst.inverse.numerical import invert
from bayeshyst.inverse.references import reference_signal
from bayeshyst.models.base import DataScales


def test_allocate_draws_is_proportional_and_gives_every_member_one():
    rng = np.random.default_rng(0)
    for _ in range(200):
        k = int(rng.integers(1, 6))
        w = rng.dirichlet(np.ones(k))
        total = int(rng.integers(1, 60))
        n = allocate_draws(w, total)
        assert sum(n) == max(total, k) and min(n) >= 1
        if np.all(total * w >= 1):  # no member at the floor: largest remainder, within one
            assert np.all(np.abs(np.array(n) - total * w / w.sum()) < 1.0 + 1e-12)
    assert allocate_draws([0.75, 0.25], 24) == [18, 6]
    with pytest.raises(ParameterError, match="positive"):
        allocate_draws([0.5, 0.0], 10)


def _pi(n_ops=4):
    model = M.get("pi_play", n_operators=n_ops)
    r = model.param_space(DataScales(0.0, 100.0, 0.0, 20.0)).fixed["r"]
    shape = {"p0": 0.12, "w": np.linspace(0.06, 0.02, n_ops), "r": r}
    return model, shape


def _member(model, shape, gains, label, weight, offset=0.0):
    g = np.asarray(gains, float)
    theta = {"p0": shape["p0"] * g, "w": shape["w"][None, :] * g[:, None],
             "r": np.broadcast_to(shape["r"], (g.size, shape["r"].size))}
    return WeightedPosterior(label, model, Draws(theta, np.full(g.size, offset)), weight)


def test_the_averaged_command_inverts_the_weighted_mixture():
    model, shape = _pi()
    ref = reference_signal("sine", 5.0, 2000.0, 2.0, 14.0, cycles=1, warmup_cycles=1)
    a = _member(model, shape, np.full(60, 1.0), "A", 0.75)
    b = _member(model, shape, np.full(60, 1.3), "B", 0.25)
    limits = (-50.0, 200.0)
    row = design_averaged([a, b], ref, plant=None, u_limits=limits, n_design_draws=24,
                          n_predict_draws=20, n_plants=8, seed=1)
    assert row.models == ("A", "B") and row.weights == (0.75, 0.25)
    assert row.design_draws == (18, 6) and row.single_model == "A"
    g = 0.75 * 1.0 + 0.25 * 1.3
    exact = invert(model, ref.y_d, ref.t, {"p0": np.array([shape["p0"] * g]),
                                            "w": shape["w"][None, :] * g,
                                            "r": shape["r"][None, :]},
                   u_limits=limits, periodic=True, scored=ref.scored)
    # the mixture's mean meets the reference, so its error is the inverter's tolerance
    assert row.model_error_percent < 1e-3
    np.testing.assert_allclose(row.curves["u_averaged"], exact.u, rtol=0,
                               atol=1e-6 * np.ptp(exact.u))
    # and that command makes the 3:1 mixture's mean output the reference
    y_mix = 0.75 * model.simulate(exact.u, ref.t, {**shape}) + 0.25 * model.simulate(
        exact.u, ref.t, {"p0": shape["p0"] * 1.3, "w": shape["w"] * 1.3, "r": shape["r"]})
    assert np.max(np.abs(y_mix - ref.y_d)[ref.scored]) < 1e-6 * np.ptp(ref.y_d)


def test_a_plant_from_the_mixture_falls_in_the_predicted_band_nine_times_in_ten():
    # plants and prediction draws come from one mixture: over many designs (seeds) the
    # fraction of plants inside the 90 % band is 0.9 up to the band's own sampling
    # error; with 400 prediction draws and 8 x 60 plants, 0.80-0.97 holds with
    # probability > 0.999 (binomial on 480 plants, plus the quantiles' error)
    model, shape = _pi()
    ref = reference_signal("sine", 5.0, 2000.0, 2.0, 14.0, cycles=1, warmup_cycles=1)
    rng = np.random.default_rng(5)
    inside = []
    for seed in range(8):
        a = _member(model, shape, rng.normal(1.0, 0.03, 300), "A", 0.6, offset=0.0)
        b = _member(model, shape, rng.normal(1.1, 0.05, 300), "B", 0.4, offset=0.1)
        row = design_averaged([a, b], ref, plant=None, u_limits=(-50.0, 200.0),
                              n_design_draws=8, n_predict_draws=400, n_plants=60, seed=seed)
        inside.append(row.plants_inside_band)
    frac = float(np.mean(inside))
    lo, hi = stats.binom.ppf([0.0005, 0.9995], 480, 0.9) / 480
    assert lo - 0.03 <= frac <= hi + 0.03, (frac, lo, hi)


def test_members_with_a_discrepancy_or_too_few_draws_are_refused():
    model, shape = _pi()
    ref = reference_signal("sine", 5.0, 2000.0, 2.0, 14.0, cycles=1, warmup_cycles=1)
    few = _member(model, shape, np.ones(5), "few", 1.0)
    with pytest.raises(ParameterError, match="5 posterior draws"):
        design_averaged([few], ref, plant=None, u_limits=(-50.0, 200.0))
    d = _member(model, shape, np.ones(300), "d", 1.0).draws
    with_delta = WeightedPosterior("disc", model, Draws(d.theta, d.offset, object(),
                                                        np.zeros((300, 2))), 1.0)
    with pytest.raises(ParameterError, match="without a discrepancy"):
        design_averaged([with_delta], ref, plant=None, u_limits=(-50.0, 200.0))
