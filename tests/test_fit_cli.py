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
            "rmse", "nrmse_percent", "per_frequency", "runtime_s"}


@pytest.fixture(scope="module")
def data_csv(tmp_path_factory):
    _, rec, _ = pi_data(n_ops=3, n=1500)
    path = tmp_path_factory.mktemp("data") / "pi.csv"
    write_csv(Dataset((rec,), name="pi"), path)
    return path


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
    # the posterior-mean prediction of a well-specified model is at the noise level
    assert summary["rmse"] == pytest.approx(0.05, rel=0.3)
    assert not any(p.name.endswith(".tmp") for p in out.iterdir())
    for name in ["posterior.nc", *summary["files"]["figures"]]:
        assert (out / name).stat().st_size > 0


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
    printed = json.loads(capsys.readouterr().out)
    assert printed["model"] == "pi_stop"
    assert printed == json.loads((tmp_path / "summary.json").read_text())
    assert not (tmp_path / "checkpoint.h5").exists()


@pytest.mark.parametrize(("args", "message"), [
    (["missing.csv", "--model", "pi_play"], "missing.csv"),
    (["DATA", "--model", "pi_plya"], "unknown model 'pi_plya'"),
    (["DATA", "--model", "pi_play", "--likelihood", "cauchy"], "unknown likelihood 'cauchy'"),
    (["DATA", "--model", "pi_play", "--steps", "0"], "positive integer"),
])
def test_bad_input_exits_2_with_one_line_and_writes_nothing(args, message, data_csv, tmp_path):
    out = tmp_path / "out"
    args = [str(data_csv) if a == "DATA" else a for a in args]
    res = subprocess.run([sys.executable, "-m", "bayeshyst.cli", "fit", *args, "--out", str(out),
                          "--quiet"], capture_output=True, text=True, cwd=tmp_path,
                         env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert res.returncode == 2, res.stderr
    assert message in res.stderr and "Traceback" not in res.stderr
    assert not out.exists()


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
