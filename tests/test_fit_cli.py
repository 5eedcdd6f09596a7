"""``bayeshyst fit`` end to end: outputs, summary contents, bad input, resume."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bayeshyst.cli import main
from bayeshyst.data import Dataset, write_csv
from tests.synthetic import pi_data

ROOT = Path(__file__).resolve().parents[1]

REQUIRED = {"model", "converged", "rhat_max", "ess_min", "tau_max", "n_failed_evals", "params",
            "rmse", "nrmse_percent", "per_frequency", "runtime_s", "map_notes"}


@pytest.fixture(scope="module")
def data_csv(tmp_path_factory):
    _, rec, _ = pi_data(n_ops=3, n=1500)
    path = tmp_path_factory.mktemp("data") / "pi.csv"
    write_csv(Dataset((rec,), name="pi"), path)
    return path


@pytest.fixture(scope="module")
def odd_csvs(tmp_path_factory):
    """The pi record with y scaled past what a fit handles (the scales of issue 17), and
    with a constant input."""
    _, rec, _ = pi_data(n_ops=3, n=1500)
    root = tmp_path_factory.mktemp("odd")
    records = {"BIG": rec.with_(y=rec.y * 1e200), "TINY": rec.with_(y=rec.y * 1e-300),
               "CONST": rec.with_(u=np.ones(rec.n))}
    return {key: write_csv(Dataset((r,), name="pi"), root / f"{key.lower()}.csv")
            for key, r in records.items()}


@pytest.fixture(scope="module")
def fitted(data_csv, tmp_path_factory):
    out = tmp_path_factory.mktemp("fit")
    code = main(["fit", str(data_csv), "--model", "pi_play", "--out", str(out), "--steps", "300",
                 "--seed", "3", "--quiet"])
    return code, out


def test_fit_writes_summary_posterior_and_figures(fitted):
    code, out = fitted
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert REQUIRED <= set(summary)
    assert summary["model"] == "pi_play" and summary["likelihood"] == "gaussian"
    for name in ("p0", "w[0]", "obs.offset", "noise.sigma"):
        p = summary["params"][name]
        assert p["hdi_5"] <= p["mean"] <= p["hdi_95"] and p["sd"] > 0
    assert [f["frequency_hz"] for f in summary["per_frequency"]] == [3.0]
    # pi_play's linear block under a Gaussian likelihood with Normal priors is drawn from
    # its exact conditional: a Gibbs draw is always accepted; the other moves are rates
    assert summary["linear_block"] == ["p0", "w", "obs.offset"]
    assert summary["move_acceptance"]["gibbs_linear"] == 1.0
    assert all(0.0 <= v <= 1.0 for v in summary["move_acceptance"].values())
    assert {"independence", "differential"} <= set(summary["move_acceptance"])
    # the posterior-mean prediction of a well-specified model is at the noise level
    assert summary["rmse"] == pytest.approx(0.05, rel=0.3)
    assert not any(p.name.endswith(".tmp") for p in out.iterdir())
    for name in ["posterior.nc", *summary["files"]["figures"]]:
        assert (out / name).stat().st_size > 0
    # what the CLI wrote reloads as the fit it summarises
    from bayeshyst.inference.saved import load_fit

    saved = load_fit(out)
    assert saved.model.name == "pi_play" and saved.converged == summary["converged"]
    assert saved.to_dataframe()["p0"].mean() == pytest.approx(summary["params"]["p0"]["mean"],
                                                              abs=3 * summary["params"]["p0"]["sd"])


def test_non_converged_run_says_so(data_csv, tmp_path):
    # 20 steps of which the first 10 adapt the moves (discarded): at most 10 steps x 12
    # walkers x 2 ensembles = 240 draws are kept, fewer than the ESS >= 400 required,
    # and 10 steps cannot hold 50 autocorrelation times: the run must say so
    assert main(["fit", str(data_csv), "--model", "pi_play", "--out", str(tmp_path),
                 "--steps", "20", "--walkers", "12", "--seed", "3", "--quiet",
                 "--no-figures", "--no-checkpoint"]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["converged"] is False
    assert summary["convergence_reasons"]
    assert any("NOT converge" in w for w in summary["warnings"])


def test_rerun_resumes_from_the_checkpoint_with_identical_results(fitted, data_csv):
    out = fitted[1]
    first = json.loads((out / "summary.json").read_text())
    assert main(["fit", str(data_csv), "--model", "pi_play", "--out", str(out), "--steps",
                 "300", "--seed", "3", "--quiet", "--no-figures"]) == 0
    again = json.loads((out / "summary.json").read_text())
    assert again["params"] == first["params"]


def test_json_flag_prints_the_summary(data_csv, tmp_path, capsys):
    assert main(["fit", str(data_csv), "--model", "pi_stop", "--out", str(tmp_path), "--steps",
                 "100", "--quiet", "--json", "--no-figures", "--no-checkpoint"]) == 0
    text = capsys.readouterr().out
    printed = json.loads(text)
    assert printed["model"] == "pi_stop"
    assert printed == json.loads((tmp_path / "summary.json").read_text())
    # the same serialiser: what is printed is the file, byte for byte
    assert text == (tmp_path / "summary.json").read_text()
    assert not (tmp_path / "checkpoint.h5").exists()


@pytest.mark.parametrize(("args", "message"), [
    (["missing.csv", "--model", "pi_play"], "missing.csv"),
    (["DATA", "--model", "pi_plya"], "unknown model 'pi_plya'"),
    (["DATA", "--model", "pi_play", "--steps", "0"], "positive integer"),
    # refused where the data are read, naming the file, the column, what was found and
    # the range (they used to end in sd = inf, or in a sampler error and a checkpoint)
    (["BIG", "--model", "pi_play"], ": column 'y': largest |value| 2.67e+201 is outside the "
                                    "supported range (max|x| <= 1e+50, "),
    (["TINY", "--model", "pi_play"], ": column 'y': peak-to-peak 2.08e-299 is outside the "
                                     "supported range ("),
    (["CONST", "--model", "pi_play"], ": column 'u': constant (1.0 in every sample)"),
])
def test_bad_input_exits_2_with_one_line_and_writes_nothing(args, message, data_csv, odd_csvs,
                                                            tmp_path):
    out = tmp_path / "out"
    files = {"DATA": data_csv, **odd_csvs}
    args = [str(files.get(a, a)) for a in args]
    res = subprocess.run([sys.executable, "-m", "bayeshyst.cli", "fit", *args, "--out", str(out),
                          "--quiet"], capture_output=True, text=True, cwd=tmp_path,
                         env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert res.returncode == 2, res.stderr
    assert message in res.stderr and "Traceback" not in res.stderr
    if args[0] in map(str, odd_csvs.values()):  # one line, naming the file first
        assert res.stderr.startswith(f"bayeshyst fit: error: {args[0]}{message}")
        assert res.stderr.strip().count("\n") == 0
    assert not out.exists()


# (u factor, y factor): far apart, up to 1e45 of the supported 1e50
SCALES = [(1.0, 1e-45), (1.0, 1e45), (1e-45, 1e45), (1e40, 1.0)]


@pytest.mark.parametrize(("u_scale", "y_scale"), SCALES)
def test_fit_is_scale_equivariant_over_the_supported_range(u_scale, y_scale, fitted,
                                                            data_csv, tmp_path):
    # the oracle: the same record in other units gives the same posterior in those units,
    # within the Monte Carlo error of the chains (the unscaled run is ``fitted``)
    from bayeshyst.data import load

    rec = load(data_csv)[0]
    path = write_csv(Dataset((rec.with_(u=rec.u * u_scale, y=rec.y * y_scale),), name="pi"),
                     tmp_path / "scaled.csv")
    assert main(["fit", str(path), "--model", "pi_play", "--out", str(tmp_path / "out"),
                 "--steps", "300", "--seed", "3", "--quiet", "--no-figures"]) == 0
    base = json.loads((fitted[1] / "summary.json").read_text())
    scaled = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert not any("written as null" in w for w in scaled["warnings"])
    ess = min(base["ess_min"], scaled["ess_min"])
    gain = y_scale / u_scale
    for label, p in base["params"].items():
        unit = y_scale if label in ("obs.offset", "noise.sigma") else gain  # p0, w: y/u
        got = scaled["params"][label]
        # a mean's MC standard error is sd / sqrt(ESS), a sd's relative one 1/sqrt(2 ESS)
        assert got["mean"] / unit == pytest.approx(p["mean"], abs=3 * p["sd"] / ess**0.5), label
        assert got["sd"] / unit == pytest.approx(p["sd"], rel=3 / (2 * ess) ** 0.5), label
    for key in ("rmse", "max_error"):
        assert scaled[key] / y_scale == pytest.approx(base[key], rel=3 / ess**0.5)
    assert scaled["nrmse_percent"] == pytest.approx(base["nrmse_percent"], rel=3 / ess**0.5)


def test_fit_model_api_matches_truth_on_well_specified_data():
    from bayeshyst.inference.fit import fit_model
    from bayeshyst.inference.settings import SamplerSettings

    model, rec, theta = pi_data(n_ops=2, n=1500)
    fit = fit_model(rec, model, sampler=SamplerSettings(seed=0, max_steps=1000,
                                                        first_chunk=500))
    summary = {s.label: s for s in fit.sampling.summary(0.99)}
    for label, value in (("p0", theta["p0"]), ("w[0]", theta["w"][0]),
                         ("w[1]", theta["w"][1])):
        assert summary[label].hdi_lo <= value <= summary[label].hdi_hi, label
    assert np.isfinite(fit.overall.rmse) and "tracking error" in str(fit)


def test_a_number_that_is_not_finite_is_written_as_null_and_named_in_warnings(tmp_path):
    # what an overflow would leave in a summary (sd = inf and RMSE inf in issue 17)
    import dataclasses

    from bayeshyst.inference.fit import fit_model
    from bayeshyst.inference.settings import SamplerSettings
    from bayeshyst.outputs.files import write_json
    from bayeshyst.outputs.fit_outputs import fit_summary

    model, rec, _ = pi_data(n_ops=2, n=400)
    fit = fit_model(rec, model, sampler=SamplerSettings(seed=0, max_steps=20, first_chunk=20))
    fit = dataclasses.replace(fit, overall=dataclasses.replace(
        fit.overall, rmse=float("inf"), max_error=float("nan")))
    summary = fit_summary(fit)
    assert summary["rmse"] == float("inf")  # the dict keeps the number for Python callers
    assert "not a finite number, written as null: rmse, max_error" in summary["warnings"]

    def refuse(token):
        raise AssertionError(f"{token} in summary.json")

    written = json.loads(write_json(tmp_path / "summary.json", summary).read_text(),
                         parse_constant=refuse)
    assert written["rmse"] is None and written["max_error"] is None
    assert written["warnings"] == summary["warnings"]


def test_fit_checks_calibration_and_writes_the_budget(fitted):
    # the calibration check runs in every CLI fit: the last cycle held out, coverage
    # and PIT per frequency; the budget's shares add up to one
    _, out = fitted
    summary = json.loads((out / "summary.json").read_text())
    cal = summary["calibration"]
    assert cal["held_out"] and cal["per_frequency"]
    (row,) = cal["per_frequency"]
    assert row["frequency_hz"] == 3.0
    assert 0.0 <= row["coverage_50"] <= row["coverage_90"] <= 1.0
    assert sum(row["pit_histogram"]) == pytest.approx(1.0)
    lo, hi = row["expected_90"]
    assert row["calibrated"] == (lo <= row["coverage_90"] <= hi
                                 and row["expected_50"][0] <= row["coverage_50"]
                                 <= row["expected_50"][1])
    (budget,) = summary["uncertainty_budget"]
    assert sum(budget["shares"].values()) == pytest.approx(1.0)
    assert budget["discrepancy_var"] == 0.0 and summary["discrepancy"] is None


def test_fit_with_a_discrepancy_records_it(data_csv, tmp_path):
    out = tmp_path / "disc"
    code = main(["fit", str(data_csv), "--model", "pi_play", "--out", str(out), "--seed", "1",
                 "--discrepancy", "hsgp", "--no-calibration", "--quiet", "--no-figures"])
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    disc = summary["discrepancy"]
    assert disc["kind"] == "hsgp" and disc["basis_functions"] == 32  # 16 x 2, one frequency
    assert {"amplitude", "branch_amplitude", "length"} <= set(disc)
    assert summary["calibration"] is None
    assert "disc.xi" in summary["linear_block"]
