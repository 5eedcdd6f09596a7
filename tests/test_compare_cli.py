"""``bayeshyst compare`` end to end: the files, the summary contract, bad input."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

import bayeshyst.models as M
from bayeshyst.cli import main
from bayeshyst.data import Dataset, Record, write_csv
from bayeshyst.models.base import DataScales

RANKING_KEYS = {"model", "elpd_loo", "se", "weight", "nrmse_percent"}
ARGS = ["--models", "pi_play(n_operators=3),duhem", "--steps", "200", "--walkers", "24",
        "--jobs", "2", "--max-refits", "1", "--quiet"]


def _two_frequency_data(sigma=0.05):
    model = M.get("pi_play", n_operators=3)
    r = model.param_space(DataScales(0.0, 150.0, 0.0, 20.0)).fixed["r"]
    theta = {"p0": 0.1, "w": np.array([0.05, 0.03, 0.02]), "r": r}
    recs = []
    for i, f in enumerate((2.0, 20.0)):
        t = np.arange(400) / (80 * f)
        u = 75 - 70 * np.cos(2 * np.pi * f * t)
        y = model.simulate(u, t, theta) + np.random.default_rng(i).normal(0, sigma, t.size)
        recs.append(Record(t=t, u=u, y=y, name=f"r{f:g}", warmup=80,
                           metadata={"frequency_hz": f, "note": "<b>user</b>"}))
    return Dataset(tuple(recs), name="two")


@pytest.fixture(scope="module")
def compared(tmp_path_factory):
    data_path = tmp_path_factory.mktemp("data") / "two.csv"
    write_csv(_two_frequency_data(), data_path)
    out = tmp_path_factory.mktemp("cmp") / "out"
    code = main(["compare", str(data_path), *ARGS, "--out", str(out)])
    return code, out, data_path


def test_compare_writes_every_output(compared):
    code, out, _ = compared
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert [e["frequency_hz"] for e in summary["per_frequency"]] == [2.0, 20.0]
    for entry in summary["per_frequency"]:
        assert entry["best"] == entry["ranking"][0]["model"]
        assert {r["model"] for r in entry["ranking"]} == {"pi_play(n_operators=3)", "duhem"}
        for row in entry["ranking"]:
            assert RANKING_KEYS <= set(row)
            assert row["elpd_loo"] is not None and row["se"] >= 0
            assert 0.0 <= row["weight"] <= 1.0
            # leave-one-frequency-out ran: each model was scored on the held-out frequency
            assert row["elpd_lofo"] is not None
        assert sum(r["weight"] for r in entry["ranking"]) == pytest.approx(1.0, abs=1e-9)
        elpds = [r["elpd_loo"] for r in entry["ranking"]]
        assert elpds == sorted(elpds, reverse=True)
        assert entry["statement"].startswith(f"{entry['frequency_hz']:g} Hz: {entry['best']}")
    assert summary["overall"]["best"] in {"pi_play(n_operators=3)", "duhem"}
    # 2 models x (joint + 2 frequencies + 2 held-out frequencies)
    assert len(summary["fits"]) == 10
    for f in summary["fits"]:
        # both models' linear blocks (PI weights; Duhem f, g) have Normal priors under a
        # Gaussian likelihood: their Gibbs draws are exact, so always accepted
        assert f["move_acceptance"]["gibbs_linear"] == 1.0
        assert all(0.0 <= v <= 1.0 for v in f["move_acceptance"].values())
    # a fit that did not converge is named in the warnings (and only then)
    unconverged = [f["key"] for f in summary["fits"] if f["error"] is None and not f["converged"]]
    warned = [w for w in summary["warnings"] if "did not converge" in w]
    assert bool(warned) is bool(unconverged) and all(k in warned[0] for k in unconverged)
    with open(out / "comparison.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 3 * 2 and {r["frequency_hz"] for r in rows} == {"2.0", "20.0", "all"}
    assert (out / "compare.png").stat().st_size > 10_000
    assert "ranks first" in (out / "comparison.txt").read_text()
    nc = sorted(p.name for p in (out / "posteriors").iterdir())
    assert nc == sorted(summary["files"]["posteriors"]) and len(nc) == 6  # joint + frequency
    assert not [p for p in out.rglob("*") if ".tmp" in p.name]


def test_unconverged_fits_are_named(compared, tmp_path, capsys):
    # 20 steps of which the first 10 adapt the moves (discarded): at most 10 steps x 12
    # walkers x 2 ensembles = 240 draws are kept, fewer than the ESS >= 400 required
    out = tmp_path / "out"
    assert main(["compare", str(compared[2]), "--models", "pi_play(n_operators=3)",
                 "--steps", "20", "--walkers", "12", "--no-lofo", "--max-refits", "0",
                 "--jobs", "1", "--quiet", "--no-figures", "--json", "--out", str(out)]) == 0
    # --json prints summary.json itself (the writer's serialiser), byte for byte
    assert capsys.readouterr().out == (out / "summary.json").read_text()
    summary = json.loads((out / "summary.json").read_text())
    assert [f["converged"] for f in summary["fits"]] == [False] * 3
    (warned,) = [w for w in summary["warnings"] if "did not converge" in w]
    assert all(f["key"] in warned for f in summary["fits"])


def test_pi_model_wins_on_pi_data(compared):
    # data from a 3-operator PI model: the PI model must beat the Duhem model everywhere
    summary = json.loads((compared[1] / "summary.json").read_text())
    for entry in summary["per_frequency"] + [summary["overall"]]:
        assert entry["best"] == "pi_play(n_operators=3)"


# slow (3 min; resume identity stays in the default run through tests/test_sampling.py)
@pytest.mark.slow
def test_rerun_resumes_from_checkpoints_with_identical_numbers(compared):
    _, out, data_path = compared
    before = json.loads((out / "summary.json").read_text())
    ckpts = sorted(p.name for p in (out / "checkpoints").iterdir())
    # one checkpoint per distinct posterior (checkpoints are named by what they fit):
    # per model the joint fit and one per frequency; with two frequencies, leaving one
    # out fits the other one's records, the posterior of that frequency's fit
    assert len(ckpts) == 2 * (1 + 2)
    assert main(["compare", str(data_path), *ARGS, "--out", str(out)]) == 0
    after = json.loads((out / "summary.json").read_text())
    assert after["per_frequency"] == before["per_frequency"]
    assert after["overall"] == before["overall"]
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == ckpts
    # other settings do not trip over the old checkpoints: they get their own files
    other = [a if a != "200" else "150" for a in ARGS]
    assert main(["compare", str(data_path), *other, "--out", str(out)]) == 0
    assert len(list((out / "checkpoints").iterdir())) == 2 * len(ckpts)


@pytest.mark.parametrize("argv, message", [
    (["--models", "pi_plya"], "unknown model 'pi_plya'"),
    (["--models", "pi_play,pi_play"], "listed more than once"),
    (["--models", "pi_play(n_operators=x)"], "must be a literal"),
])
def test_bad_models_exit_2_and_write_nothing(tmp_path, capsys, argv, message):
    data_path = tmp_path / "d.csv"
    write_csv(_two_frequency_data(), data_path)
    out = tmp_path / "out"
    assert main(["compare", str(data_path), "--out", str(out), *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not out.exists()


def test_missing_data_file_exit_2(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["compare", str(tmp_path / "nope.csv"), "--models", "pi_play",
                 "--out", str(out)]) == 2
    assert "nope.csv" in capsys.readouterr().err
    assert not out.exists()


def test_bad_numbers_are_usage_errors(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["compare", "x.csv", "--models", "pi_play", "--jobs", "0"])
    assert exc.value.code == 2
    assert "positive integer" in capsys.readouterr().err


def test_help_lists_compare(capsys):
    with pytest.raises(SystemExit):
        main(["compare", "--help"])
    text = capsys.readouterr().out
    for option in ("--models", "--no-lofo", "--jobs", "--max-refits", "--gp-train"):
        assert option in text
