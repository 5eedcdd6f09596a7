"""The public figure API.

Every public ``*_figure`` function returns a Figure, draws into the caller's figure (or,
for the one-panel evidence figure, the caller's axes) when given one, and refuses a
figure that already has axes; :func:`save_figure` writes PNG atomically. (That only
:mod:`bayeshyst.plotting` imports matplotlib is checked with every other arrow in
``tests/test_architecture.py``.)
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from matplotlib import image as mpimg
from matplotlib.figure import Figure

from bayeshyst import plotting as P
from bayeshyst.diagnosis import diagnose
from bayeshyst.errors import ParameterError
from bayeshyst.inference.fit import fit_model
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.inverse.compensate import compensate
from bayeshyst.selection import compare_models
from tests.test_diagnostics import two_record_fit
from tests.test_study_outputs import _add, _ok_row, _result, _study

MODEL = "pi_play(n_operators=2)"
TINY = SamplerSettings(max_steps=100, first_chunk=100, n_walkers=16, progress=False)


# --------------------------------------------------------------------------- results
@pytest.fixture(scope="module")
def fit():
    return two_record_fit()


@pytest.fixture(scope="module")
def results(fit) -> dict[str, Any]:
    """One (unconverged, quick) result of every analysis the figures draw."""
    post, _ = fit
    data = post.data
    fitted = fit_model(data, MODEL, sampler=TINY)
    study = _study(["d1", "d2"], ("A", "B"))
    rows: list[dict[str, Any]] = []
    pw: dict[str, np.ndarray] = {}
    for ds in ("d1", "d2"):
        for f in (1.0, 10.0):
            for model, value in (("A", -1.0), ("B", -2.0)):
                x = np.full(4, value)
                _add(rows, pw, _ok_row(ds, model, f, 0, x), x)
    return {
        "data": data,
        "comparison": compare_models(data, [MODEL], sampler=TINY, lofo=False, max_refits=0,
                                     draws_per_chain=5, n_jobs=1),
        "diagnosis": diagnose(data, MODEL, effects=("drift",), max_rounds=1, sampler=TINY,
                              n_draws=20, max_refits=0),
        "compensation": compensate(data, MODEL, fit=fitted, reference="sine",
                                   n_design_draws=3, n_predict_draws=10, n_plants=4,
                                   sampler=TINY),
        "study": _result(study, rows, pw),
        "fit": fitted,
    }


def _tested_effect(diagnosis: Any) -> Any:
    return next(t for t in diagnosis.base.analysis.tests if t.skipped is None)


def _calls(fit, results) -> dict[str, Callable[..., Figure]]:
    """Each public ``*_figure`` function with its arguments; ``fig=``/``ax=`` is added by
    the test."""
    post, res = fit
    draws = {"p0": np.linspace(0.0, 1.0, 50), "w[0]": np.linspace(1.0, 3.0, 50) ** 2}
    return {
        "loops_figure": lambda **kw: P.loops_figure(post, res, n_draws=10, **kw),
        "residuals_figure": lambda **kw: P.residuals_figure(post, res, n_draws=10, **kw),
        "trace_figure": lambda **kw: P.trace_figure(res, params=["p0"], **kw),
        "corner_figure": lambda **kw: P.corner_figure(res, params=["p0", "w"], **kw),
        "draws_corner_figure": lambda **kw: P.draws_corner_figure(draws, title="t", **kw),
        "data_overview_figure": lambda **kw: P.data_overview_figure(results["data"], **kw),
        "model_comparison_figure": lambda **kw: P.model_comparison_figure(
            results["comparison"], **kw),
        "compensation_figure": lambda **kw: P.compensation_figure(results["compensation"],
                                                                  y_unit="um", **kw),
        "diagnosis_residuals_figure": lambda **kw: P.diagnosis_residuals_figure(
            results["diagnosis"], **kw),
        "effect_evidence_figure": lambda **kw: P.effect_evidence_figure(
            _tested_effect(results["diagnosis"]), y_unit="um", **kw),
        "best_model_figure": lambda **kw: P.best_model_figure(results["study"], **kw),
        "scores_vs_frequency_figure": lambda **kw: P.scores_vs_frequency_figure(
            results["study"], **kw),
        "uncertainty_figure": lambda **kw: P.uncertainty_figure(results["fit"].budget,
                                                                y_unit="um", **kw),
        "model_loops_figure": lambda **kw: P.model_loops_figure(_loops(results["fit"]),
                                                                y_unit="um", **kw),
    }


def _loops(fitted: Any) -> list[Any]:
    """One frequency's measured loop and the fit's predicted one (what the report
    reads back from the comparison's saved posteriors)."""
    from bayeshyst.selection.predictions import FrequencyLoops, ModelLoop

    rec = fitted.posterior.data[0]
    pred = fitted.posterior.predict(fitted.sampling.draws(20, seed=0))[0]
    lo, hi = np.quantile(pred, [0.05, 0.95], axis=0)
    loop = ModelLoop(MODEL, pred.mean(axis=0), lo, hi, 1.0, True)
    return [FrequencyLoops(rec.frequency_hz or 1.0, rec.name, rec.t, rec.u, rec.y,
                           rec.scored_mask, (loop,), MODEL)]


FIGURE_FUNCTIONS = ["loops_figure", "residuals_figure", "trace_figure", "corner_figure",
                    "draws_corner_figure", "data_overview_figure", "model_comparison_figure",
                    "compensation_figure", "diagnosis_residuals_figure",
                    "effect_evidence_figure", "best_model_figure",
                    "scores_vs_frequency_figure", "uncertainty_figure", "model_loops_figure"]
ONE_PANEL = {"effect_evidence_figure"}  # take ax=, not fig=


def test_every_public_figure_function_is_covered_here(fit, results):
    public = {n for n in P.__all__ if n.endswith("_figure") and n != "save_figure"}
    assert public == set(FIGURE_FUNCTIONS) == set(_calls(fit, results))


@pytest.mark.parametrize("name", FIGURE_FUNCTIONS)
def test_public_figure_functions_return_a_figure_and_draw_into_the_callers(name, fit,
                                                                          results):
    build = _calls(fit, results)[name]
    own = build()
    assert isinstance(own, Figure) and own.axes
    n_axes = len(own.axes)
    assert all(ax.get_figure() is own for ax in own.axes)
    # drawn into the caller's figure (or axes): the artists are there, nothing else made
    mine = Figure(figsize=(5.0, 4.0))
    if name in ONE_PANEL:
        mine.add_subplot(1, 2, 1)
        target = mine.add_subplot(1, 2, 2)
        got = build(ax=target)
        assert got is mine and len(mine.axes) == 2
        assert target.lines and not mine.axes[0].lines
        # the verdict is the axes' title, the caller's figure title is left alone
        assert own.get_suptitle().split("\n")[0] in target.get_title()
        assert mine.get_suptitle() == ""
    else:
        got = build(fig=mine)
        assert got is mine and len(mine.axes) == n_axes
        assert mine.get_layout_engine() is not None  # constrained layout switched on
        assert mine.get_size_inches().tolist() == [5.0, 4.0]  # the caller's size kept
        drawn = [a for ax in mine.axes for a in (*ax.lines, *ax.collections, *ax.patches,
                                                 *ax.texts)]
        assert drawn and all(a.get_figure(root=True) is mine for a in drawn)


@pytest.mark.parametrize("name", ["loops_figure", "trace_figure", "data_overview_figure"])
def test_a_figure_with_axes_already_is_refused(name, fit, results):
    busy = Figure()
    busy.add_subplot()
    with pytest.raises(ParameterError, match="fig must be empty"):
        _calls(fit, results)[name](fig=busy)
    assert len(busy.axes) == 1


def test_save_figure_writes_png_atomically_at_the_figures_resolution(fit, tmp_path):
    post, res = fit
    fig = P.loops_figure(post, res, n_draws=10)
    path = tmp_path / "sub" / "loops.png"
    assert P.save_figure(fig, path) == path
    img = mpimg.imread(path)
    w, h = fig.get_size_inches() * P.DPI
    assert img.shape[:2] == (round(h), round(w))
    assert [p.name for p in path.parent.iterdir()] == ["loops.png"]  # no temporary left
    assert fig.axes  # the caller's figure is left as it was
    with pytest.raises(ParameterError, match="PNG"):
        P.save_figure(fig, tmp_path / "loops.jpg")
    with pytest.raises(ParameterError, match="Figure"):
        P.save_figure("not a figure", tmp_path / "x.png")
    assert not (tmp_path / "loops.jpg").exists() and not (tmp_path / "x.png").exists()
