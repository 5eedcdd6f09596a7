"""analyses.predict_unseen --quick: fit one record of a rig, predict the others.

Its own file so that the test run's two workers (one file each, ``--dist loadfile``)
share it with the other analyses instead of queueing it behind them. Oracles: the
records each case must predict (the other amplitudes of a current, the benchmark's two
test records), the unit round trip um -> m, and the script's own refusal of an RMSE that
an independent one-draw-at-a-time simulation does not reproduce to 1e-9 of the span.
"""

from __future__ import annotations

import json

import pytest

from analyses import predict_unseen
from tests.test_analyses import _no_nan_or_tmp, _rows


@pytest.mark.shared_data
def test_predict_unseen_fits_one_record_and_predicts_the_others(shared_data_dir, tmp_path):
    out = tmp_path / "out"
    assert predict_unseen.main(["--quick", "--quiet", "--out", str(out)]) == 0
    rows = _rows(out / "predictions.csv")
    summary = json.loads((out / "summary.json").read_text())
    # the MR damper: every other amplitude's record at 0.5 A; the benchmark: both tests
    mr = [r["record"] for r in rows if r["case"] == "mr_damper_0.5A"]
    assert sorted(mr) == sorted(["25mm0x1Hz0x5A", "25mm0x5Hz0x5A", "10mm1Hz0x5A",
                                 "5mm3Hz0x5A", "2mm5Hz0x5A"])
    bw = {r["record"]: r for r in rows if r["case"] == "boucwen_benchmark"}
    assert set(bw) == {"test_multisine", "test_sweep"}
    assert (bw["test_multisine"]["initial"], bw["test_sweep"]["initial"]) == ("periodic",
                                                                              "rest")
    for r in summary["rows"]:
        # each RMSE agrees with an independent one-draw-at-a-time simulation (the script
        # refuses a gap above 1e-9 of the output span; the RMSE is a few % of the span)
        assert r["independent_rmse_error"] <= 1e-9 * r["rmse"]
        assert 0 <= r["coverage_90"] <= 1 and r["expected_90_lo"] <= r["expected_90_hi"]
    # the benchmark's metres: the record's um converted back
    for r in bw.values():
        assert float(r["rmse_m"]) == pytest.approx(1e-6 * float(r["rmse"]), rel=1e-9)
        assert r["unit"] == "um"
    predicted = out / "boucwen_benchmark" / "predict_boucwen_benchmark_test_sweep"
    assert json.loads((predicted / "summary.json").read_text())["initial_condition"][
        "kind"] == "rest"
    _no_nan_or_tmp(out)
