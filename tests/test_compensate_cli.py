"""``bayeshyst compensate`` end to end: the files, the summary contract, bad input."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from bayeshyst.cli import main
from bayeshyst.data import Dataset, write_csv
from bayeshyst.data.virtual import AR1Noise, VirtualActuator

REQUIRED = {"frequency_hz", "uncompensated_nrmse_percent", "nominal_nrmse_percent",
            "posterior_nrmse_percent", "predicted_band_percent", "realised_inside_band"}
RUN = ["--model", "pi_play(n_operators=4)", "--steps", "300", "--walkers", "16", "--quiet"]
PNG = b"\x89PNG\r\n\x1a\n"


def _virtual_data() -> Dataset:
    act = (VirtualActuator().without("creep", "dynamics", "drift", "delay")
           .with_effects(noise=AR1Noise(rms_um=0.04, phi=0.0)))
    recs = []
    for i, f in enumerate((1.0, 20.0)):
        t = np.arange(300) / (100 * f)  # 3 cycles, 100 samples per cycle
        u = 75 - 70 * np.cos(2 * np.pi * f * t)
        recs.append(act.record(t, u, rng=i, name=f"r{f:g}", warmup=100, frequency_hz=f))
    return Dataset(tuple(recs), name="virtual")


@pytest.fixture(scope="module")
def data_csv(tmp_path_factory):
    path = tmp_path_factory.mktemp("data") / "virtual.csv"
    write_csv(_virtual_data(), path)
    return path


@pytest.fixture(scope="module")
def compensated(data_csv, tmp_path_factory):
    out = tmp_path_factory.mktemp("comp") / "out"
    code = main(["compensate", str(data_csv), *RUN, "--out", str(out)])
    return code, out


def test_compensate_writes_every_output(compensated):
    code, out = compensated
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["command"] == "compensate"
    assert summary["model"] == "pi_play"
    # the sidecar carries the simulator's truth: the plant is the virtual actuator
    assert summary["plant_kind"] == "virtual actuator"
    rows = summary["per_frequency"]
    assert [r["frequency_hz"] for r in rows] == [1.0, 20.0]
    for r in rows:
        assert REQUIRED <= set(r)
        lo, hi = r["predicted_band_percent"]
        assert 0 <= lo <= hi
        assert isinstance(r["realised_inside_band"], bool)
        assert r["realised_inside_band"] == (lo <= r["posterior_nrmse_percent"] <= hi)
        # compensation beats driving the actuator with a scaled input
        assert r["posterior_nrmse_percent"] < r["uncompensated_nrmse_percent"]
    # the verdict is the fit's, and a fit that did not converge is a warning
    assert summary["converged"] is summary["fit"]["converged"]
    assert any("NOT converge" in w for w in summary["warnings"]) is not summary["converged"]
    assert summary["files"]["posterior"] == "posterior.nc"
    for name in ("summary.json", "compensation.csv", "compensation.txt", "curves.npz",
                 "posterior.nc", "compensate.png", "checkpoint.h5"):
        assert (out / name).stat().st_size > 0, name
    assert (out / "compensate.png").read_bytes()[:8] == PNG
    with open(out / "compensation.csv", newline="") as fh:
        table = list(csv.DictReader(fh))
    assert [float(r["frequency_hz"]) for r in table] == [1.0, 20.0]
    for r, s in zip(table, rows, strict=True):
        assert float(r["band_lo_percent"]) == pytest.approx(s["predicted_band_percent"][0])
        assert float(r["band_hi_percent"]) == pytest.approx(s["predicted_band_percent"][1])
    assert "feedforward compensation with pi_play" in (out / "compensation.txt").read_text()
    with np.load(out / "curves.npz") as curves:
        assert list(curves["prefixes"]) == ["f1Hz", "f20Hz"]
        for p in ("f1Hz", "f20Hz"):
            n = curves[f"{p}_t"].size
            assert curves[f"{p}_scored"].dtype == bool
            for key in ("y_d", "u_posterior", "y_robust", "band_lo", "band_hi"):
                assert curves[f"{p}_{key}"].shape == (n,)
    assert not [p for p in out.rglob("*") if ".tmp" in p.name]


def test_non_converged_fit_says_so(data_csv, tmp_path):
    # 20 steps of which the first 10 adapt the moves (discarded): at most 10 steps x 12
    # walkers x 2 ensembles = 240 draws are kept, fewer than the ESS >= 400 required,
    # and 10 steps cannot hold 50 autocorrelation times
    out = tmp_path / "out"
    assert main(["compensate", str(data_csv), "--model", "pi_play(n_operators=4)",
                 "--steps", "20", "--walkers", "12", "--design-draws", "8", "--quiet",
                 "--no-figures", "--no-checkpoint", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["converged"] is False and summary["fit"]["converged"] is False
    assert any("NOT converge" in w for w in summary["warnings"])


def test_reference_file_and_json(data_csv, tmp_path, capsys):
    t = np.arange(250) / 500.0  # 2.5 cycles at 2 Hz, starting at rest at the bottom
    y = 5.0 + 7.5 * (1 - np.cos(2 * np.pi * 2.0 * t))
    ref = tmp_path / "ref.csv"
    rows = zip(t.tolist(), y.tolist(), strict=True)
    ref.write_text("t,y\n" + "".join(f"{a!r},{b!r}\n" for a, b in rows))
    out = tmp_path / "out"
    assert main(["compensate", str(data_csv), *RUN, "--reference", str(ref), "--out", str(out),
                 "--json", "--no-figures", "--no-checkpoint"]) == 0
    text = capsys.readouterr().out
    printed = json.loads(text)
    assert printed == json.loads((out / "summary.json").read_text())
    assert text == (out / "summary.json").read_text()  # the writer's serialiser
    assert len(printed["per_frequency"]) == 1
    row = printed["per_frequency"][0]
    assert row["frequency_hz"] is None and row["reference"] == "ref.csv"
    assert REQUIRED <= set(row)
    assert printed["files"]["figures"] == []
    assert not (out / "compensate.png").exists() and not (out / "checkpoint.h5").exists()


def test_bad_reference_file_exit_2_and_write_nothing(data_csv, tmp_path, capsys):
    ref = tmp_path / "bad_ref.csv"
    ref.write_text("t,z\n0,1\n1,2\n")
    out = tmp_path / "out"
    assert main(["compensate", str(data_csv), *RUN, "--reference", str(ref),
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "bad_ref.csv" in err and "'y'" in err and "Traceback" not in err
    assert not (out / "summary.json").exists() and not out.exists()


@pytest.mark.parametrize("argv, message", [
    (["--model", "pi_plya"], "pi_plya"),
    (["--model", "pi_play", "--reference", "sinus"], "sinus"),
])
def test_bad_input_exit_2_and_write_nothing(data_csv, tmp_path, capsys, argv, message):
    out = tmp_path / "out"
    assert main(["compensate", str(data_csv), "--out", str(out), "--quiet", *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not out.exists()


def test_missing_data_file_exit_2(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["compensate", str(tmp_path / "nope.csv"), "--model", "pi_play",
                 "--out", str(out)]) == 2
    assert "nope.csv" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("argv, message", [
    (["--quantile", "1.5"], "(0, 1)"),
    (["--quantile", "0"], "(0, 1)"),
    (["--design-draws", "0"], "positive integer"),
    (["--plant", "virtual"], "invalid choice"),
    (["--discrepancy-transfer", "1.2"], "[0, 1]"),
    (["--discrepancy-transfer", "half"], "[0, 1]"),
])
def test_bad_numbers_are_usage_errors(tmp_path, capsys, argv, message):
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exc:
        main(["compensate", "x.csv", "--model", "pi_play", "--out", str(out), *argv])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_help_lists_compensate(capsys):
    with pytest.raises(SystemExit):
        main(["compensate", "--help"])
    text = capsys.readouterr().out
    for option in ("--model", "--reference", "--design-draws", "--quantile", "--plant"):
        assert option in text


def test_validation_file_supplies_the_residual_and_a_bad_one_writes_nothing(data_csv, tmp_path,
                                                                            capsys):
    out = tmp_path / "out"
    # the training file itself as "validation": the bands carry the same residual, and the
    # summary says where it came from
    assert main(["compensate", str(data_csv), *RUN, "--validation", str(data_csv),
                 "--out", str(out), "--json", "--no-figures", "--no-checkpoint"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["settings"]["residual_from"].startswith("validation records")
    missing = tmp_path / "nope.csv"
    out2 = tmp_path / "out2"
    assert main(["compensate", str(data_csv), *RUN, "--validation", str(missing),
                 "--out", str(out2), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "nope.csv" in err and "Traceback" not in err
    assert not out2.exists()
