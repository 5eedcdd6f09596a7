"""Result records in a notebook: to_dataframe on every record, _repr_html_ on the main ones.

Oracle: the numbers of each record's own fields (the ranking's elpd values, the
sampler's parameter summary, a compensation row's errors) must be the DataFrame's, and
the HTML must be a table with the record's first line as its title.
"""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import numpy as np
import pytest

from bayeshyst.data.dataset import Dataset
from bayeshyst.inference.fit import fit_model
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.tables import flat_rows, frame
from tests.synthetic import pi_data

PACKAGE = Path(__file__).resolve().parents[1] / "bayeshyst"
#: records with to_dict that are settings or specifications, not results
NOT_RESULTS = {"SamplerSettings", "ReportSettings", "DiagnosisSettings", "MoveStats",
               "DiscrepancyScales", "Discrepancy", "DatasetSpec", "Study",
               "InitialCondition"}


def _records_with_to_dict() -> list[tuple[str, str]]:
    out = []
    for path in sorted(PACKAGE.rglob("*.py")):
        tree = ast.parse(path.read_text())
        for node in tree.body:
            if isinstance(node, ast.ClassDef) and any(
                    isinstance(m, ast.FunctionDef) and m.name == "to_dict" for m in node.body):
                mod = ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts)
                out.append((mod, node.name))
    return out


def test_every_result_record_has_a_dataframe():
    missing = []
    for mod, name in _records_with_to_dict():
        if name in NOT_RESULTS:
            continue
        cls = getattr(importlib.import_module(mod), name)
        if not callable(getattr(cls, "to_dataframe", None)):
            missing.append(f"{mod}.{name}")
    assert missing == []


def test_flat_rows_split_bands_and_nest_dicts():
    rows = flat_rows([{"a": 1.0, "band": [0.1, 0.2], "m": {"x": 2, "y": "z"},
                       "names": ("p", "q", "r")}])
    assert rows == [{"a": 1.0, "band_lo": 0.1, "band_hi": 0.2, "m.x": 2, "m.y": "z",
                     "names": "p; q; r"}]
    assert list(frame(rows, drop=("a",)).columns) == ["band_lo", "band_hi", "m.x", "m.y",
                                                      "names"]


@pytest.fixture(scope="module")
def fit():
    _, rec, _ = pi_data(n_ops=2, n=900, warmup=100)
    return fit_model(Dataset((rec,), name="bench"), "pi_play(n_operators=2)",
                     sampler=SamplerSettings(seed=1, max_steps=600))


def test_a_fit_shows_its_parameter_table(fit):
    df = fit.to_dataframe()
    summary = fit.sampling.summary(0.9)
    assert list(df["parameter"]) == [p.label for p in summary]
    np.testing.assert_array_equal(df["mean"], [p.mean for p in summary])
    np.testing.assert_array_equal(df["hdi_95"], [p.hdi_hi for p in summary])
    html = fit._repr_html_()
    assert html.startswith("<div><p><b>") and "<table" in html
    assert str(fit).splitlines()[0].split(":")[0] in html


def test_comparison_and_compensation_tables_hold_their_records_numbers(fit):
    from bayeshyst.inverse.compensate import compensate
    from bayeshyst.selection.compare import compare_models

    data = fit.posterior.data
    cmp = compare_models(data, ["pi_play(n_operators=2)", "pi_stop(n_operators=2)"],
                         sampler=SamplerSettings(seed=1, max_steps=600), lofo=False,
                         max_refits=0, n_jobs=1)
    df = cmp.to_dataframe()
    expected = [(fc.label, s.model, s.elpd_loo) for fc in (*cmp.per_frequency, cmp.overall)
                for s in fc.scores]
    assert list(zip(df["frequency"], df["model"], df["elpd_loo"], strict=True)) == expected
    assert "<table" in cmp._repr_html_()
    comp = compensate(data, fit.model, fit=fit, n_design_draws=4, n_predict_draws=10,
                      n_plants=2, sampler=SamplerSettings(seed=1))
    cdf = comp.to_dataframe()
    row = comp.rows[0]
    assert cdf.loc[0, "posterior_nrmse_percent"] == row.posterior_nrmse_percent
    assert (cdf.loc[0, "predicted_band_percent_lo"],
            cdf.loc[0, "predicted_band_percent_hi"]) == row.predicted_band_percent
    assert "curves" not in cdf.columns and "<table" in comp._repr_html_()
