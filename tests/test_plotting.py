"""Figures: content checked on the built Figure, files checked on disk (atomic, no leftovers)."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest
from matplotlib import image as mpimg
from matplotlib.figure import Figure
from matplotlib.text import Text
from scipy import stats

from bayeshyst import plotting as P
from bayeshyst.errors import ParameterError
from bayeshyst.inference.convergence import rhat
from bayeshyst.plotting._common import RED
from bayeshyst.plotting.posterior import _ranks
from tests.test_diagnostics import two_record_fit

N_DRAWS = 40


@pytest.fixture(scope="module")
def fit():
    return two_record_fit()


def _texts(fig):
    return [t.get_text() for t in fig.findobj(Text) if t.get_text()]


def _no_nan_text(fig):
    bad = [t for t in _texts(fig) if re.search(r"\bnan\b", t, re.IGNORECASE)]
    assert not bad, bad


def _calls(fit):
    post, res = fit
    n_rec, k = len(post.data), res.space.ndim
    return {
        "loops": (P.plot_loops, P.loops_figure, (post, res), {"n_draws": N_DRAWS}, n_rec),
        "trace": (P.plot_trace, P.trace_figure, (res,), {}, 2 * k),
        "corner": (P.plot_corner, P.corner_figure, (res,), {}, k * (k + 1) // 2),
        "residuals": (P.plot_residuals, P.residuals_figure, (post, res),
                      {"n_draws": N_DRAWS}, 2 * n_rec),
    }


@pytest.mark.parametrize("kind", ["loops", "trace", "corner", "residuals"])
def test_each_plot_writes_a_readable_png(fit, kind, tmp_path):
    public, build, args, kwargs, n_axes = _calls(fit)[kind]
    fig = build(*args, **kwargs)
    assert isinstance(fig, Figure)
    assert len(fig.axes) == n_axes
    _no_nan_text(fig)
    title = fig.get_suptitle()
    assert ("NOT CONVERGED" in title) == (not fit[1].converged)
    path = tmp_path / "figs" / f"{kind}.png"
    assert public(*args, path, **kwargs) == path
    img = mpimg.imread(path)
    assert img.ndim == 3 and img.shape[0] > 200 and img.shape[1] > 200
    assert img.std() > 0  # not blank
    assert [p.name for p in path.parent.iterdir()] == [f"{kind}.png"]


def test_converged_run_has_no_red_banner(fit):
    _, res = fit
    conv = dataclasses.replace(res.convergence, converged=True, reasons=())
    fig = P.trace_figure(dataclasses.replace(res, convergence=conv), params=["p0"])
    assert fig.get_suptitle().startswith(f"{res.model} / {res.likelihood}")
    assert "NOT CONVERGED" not in fig.get_suptitle()
    assert "converged (R-hat max" in fig.get_suptitle()
    conv = dataclasses.replace(res.convergence, converged=False, reasons=("R-hat 1.2 >= 1.01",))
    fig = P.trace_figure(dataclasses.replace(res, convergence=conv), params=["p0"])
    assert fig.get_suptitle().startswith("NOT CONVERGED: R-hat 1.2 >= 1.01")
    assert fig._suptitle.get_color() == RED


def test_loops_show_the_mean_prediction_and_labels(fit):
    post, res = fit
    fig = P.loops_figure(post, res, n_draws=N_DRAWS, seed=2)
    pred = post.predict(res.draws(N_DRAWS, seed=2))
    for ax, rec, p in zip(fig.axes, post.data, pred, strict=True):
        measured, mean = ax.lines[0], ax.lines[1]
        np.testing.assert_array_equal(measured.get_xdata(), rec.u[rec.scored])
        np.testing.assert_allclose(mean.get_ydata(), p[:, rec.scored].mean(axis=0))
        band = ax.collections[0]
        assert len(band.get_paths()) == rec.n_scored - 1
        assert ax.get_xlabel() == "u [V]" and ax.get_ylabel() == "y [µm]"
        assert ax.get_title() == f"{rec.name}, {rec.frequency_hz:g} Hz"


def test_residuals_are_measured_minus_mean_prediction(fit):
    post, res = fit
    fig = P.residuals_figure(post, res, n_draws=N_DRAWS, seed=1)
    pred = post.predict(res.draws(N_DRAWS, seed=1))
    for i, (rec, p) in enumerate(zip(post.data, pred, strict=True)):
        ax_t, ax_u = fig.axes[2 * i], fig.axes[2 * i + 1]
        scored = next(ln for ln in ax_t.lines if ln.get_label() == "scored")
        np.testing.assert_allclose(scored.get_ydata(),
                                   (rec.y - p.mean(axis=0))[rec.scored])
        assert ax_t.get_xlabel() == "t [s]" and ax_u.get_xlabel() == "u [V]"
        assert ax_t.get_ylabel() == "residual [µm]"
        assert ax_t.get_title().startswith(f"{rec.name}: RMS ")


def test_trace_titles_carry_rhat_and_units(fit):
    _, res = fit
    fig = P.trace_figure(res, params=["w[1]", "noise.sigma"])
    assert len(fig.axes) == 4
    j = res.space.labels.index("w[1]")
    x = res.chains[..., j]  # w has an identity transform (Normal prior): z is the value
    n_ens, n_steps, n_walk = x.shape
    r = max(rhat(x.transpose(0, 2, 1).reshape(n_ens * n_walk, n_steps)),
            rhat(x.reshape(n_ens, -1)))
    assert fig.axes[0].get_title() == f"w[1] [µm/V]: R-hat {r:.3f}"
    assert fig.axes[2].get_title().startswith("noise.sigma [µm]: R-hat ")


def test_ranks_match_scipy():
    x = np.random.default_rng(0).normal(size=(3, 50))
    np.testing.assert_array_equal(_ranks(x) + 1,
                                  stats.rankdata(x.ravel(), method="ordinal").reshape(x.shape))


def test_corner_selection_by_name_label_and_limit(fit):
    _, res = fit
    fig = P.corner_figure(res, params=["p0", "w"])  # w expands to w[0], w[1]
    assert len(fig.axes) == 6
    assert fig.axes[-1].get_xlabel() == "w[1] [µm/V]"
    assert len(P.corner_figure(res, params="w[1]").axes) == 1
    fig = P.corner_figure(res, max_params=2)
    assert len(fig.axes) == 3 and "first 2 of 5 elements" in " ".join(fig.get_suptitle().split())
    diag = fig.axes[0]
    assert diag.get_title().startswith("p0: 90% HDI\n[")


@pytest.mark.parametrize("kind", ["trace", "corner"])
def test_bad_parameter_names_write_nothing(fit, kind, tmp_path):
    public, _, args, _, _ = _calls(fit)[kind]
    with pytest.raises(ParameterError, match="'nope' is not a parameter"):
        public(*args, tmp_path / "x.png", params=["p0", "nope"])
    with pytest.raises(ParameterError, match="'r' is fixed"):
        public(*args, tmp_path / "x.png", params=["r"])
    with pytest.raises(ParameterError, match="PNG"):
        public(*args, tmp_path / "x.jpg")
    assert list(tmp_path.iterdir()) == []


def test_failed_write_leaves_no_file(fit, tmp_path, monkeypatch):
    post, res = fit
    path = tmp_path / "loops.png"
    path.write_bytes(b"old figure")

    def broken(self, fname, **kwargs):
        fname.write(b"half a png")
        raise OSError("disk full")

    monkeypatch.setattr(Figure, "savefig", broken)
    with pytest.raises(OSError, match="disk full"):
        P.plot_loops(post, res, path, n_draws=5)
    assert path.read_bytes() == b"old figure"
    assert [p.name for p in tmp_path.iterdir()] == ["loops.png"]


def test_bad_arguments_are_refused(fit, tmp_path):
    post, res = fit
    with pytest.raises(ParameterError, match="prob"):
        P.plot_loops(post, res, tmp_path / "a.png", prob=1.5)
    with pytest.raises(ParameterError, match="n_draws"):
        P.plot_residuals(post, res, tmp_path / "a.png", n_draws=0)
    with pytest.raises(ParameterError, match="max_params"):
        P.plot_trace(res, tmp_path / "a.png", max_params=0)
    with pytest.raises(ParameterError, match="not sampled from this posterior"):
        P.plot_loops(post.fix("noise.sigma", 0.05), res, tmp_path / "a.png")
    assert list(tmp_path.iterdir()) == []


def test_uncertainty_figure_stacks_the_budget_shares_and_draws_the_pit():
    # oracle: the bars are the budget's shares (stacked: each segment starts where the
    # one below ends) and the PIT stairs are the calibration's histograms
    from bayeshyst.inference.calibration import (
        Calibration,
        FrequencyBudget,
        FrequencyCalibration,
    )

    budget = [FrequencyBudget(1.0, 0.04, 0.01, 0.05), FrequencyBudget(50.0, 0.09, 0.0, 0.01)]
    hist = (0.2, 0.05, 0.05, 0.1, 0.1, 0.1, 0.1, 0.05, 0.05, 0.2)
    cal = Calibration([FrequencyCalibration(f, 400, 20.0, {0.5: 0.4, 0.9: 0.8},
                                            {0.5: (0.3, 0.7), 0.9: (0.7, 1.0)}, hist)
                       for f in (1.0, 50.0)], ("a#3", "b#3"), True)
    fig = P.uncertainty_figure(budget, cal, y_unit="um")
    bars, pit = fig.axes
    heights = np.array([p.get_height() for p in bars.patches]).reshape(3, 2)
    bottoms = np.array([p.get_y() for p in bars.patches]).reshape(3, 2)
    shares = np.array([[b.shares[k] for b in budget]
                       for k in ("noise", "parameters", "discrepancy")])
    np.testing.assert_allclose(heights, shares)
    np.testing.assert_allclose(bottoms, np.vstack([np.zeros(2), np.cumsum(shares, 0)[:-1]]))
    stairs = [a for a in pit.patches]
    assert len(stairs) == 2
    np.testing.assert_allclose(stairs[0].get_data().values, hist)
    with pytest.raises(ParameterError):
        P.uncertainty_figure([])
