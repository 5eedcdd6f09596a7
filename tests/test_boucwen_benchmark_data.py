"""The Bouc-Wen benchmark files, checked against the facts stated in their SOURCE.md.

The oracles are the folder's own description (shapes, 750 Hz, the published test-output
RMS) and the training file's construction (5 identical periods of one multisine).
"""

from __future__ import annotations

import numpy as np
import pytest

from bayeshyst.data import load_bouc_wen_benchmark
from bayeshyst.data.measured import (
    BOUC_WEN_PERIOD_SAMPLES,
    BOUC_WEN_TEST_OUTPUT_RMS_M,
    BOUC_WEN_TRUE_PARAMETERS,
)
from bayeshyst.errors import DataError

pytestmark = pytest.mark.shared_data

#: metres per unit of length, for the units a record's y may be expressed in
_METRES = {"m": 1.0, "mm": 1e-3, "um": 1e-6, "µm": 1e-6, "nm": 1e-9}


@pytest.fixture(scope="module")
def bench(shared_data_dir):
    """The three records by ``which``; skipped when the benchmark folder is absent."""
    if not (shared_data_dir / "boucwen_benchmark").is_dir():
        pytest.skip(f"{shared_data_dir / 'boucwen_benchmark'} not found: the Bouc-Wen "
                    f"benchmark tests need it in the shared data folder")
    out = {}
    for which in ("train", "test_multisine", "test_sweep"):
        data = load_bouc_wen_benchmark(which, root=shared_data_dir)
        assert len(data) == 1 and data.name == f"boucwen_benchmark_{which}"
        out[which] = data[0]
    return out


@pytest.mark.parametrize("which", ["train", "test_multisine", "test_sweep"])
def test_shapes_and_sampling_rate_from_the_file(bench, which):
    rec = bench[which]
    assert rec.n == {"train": 40_960, "test_multisine": 8_192, "test_sweep": 153_000}[which]
    assert rec.name == {"train": "train_multisine"}.get(which, which)
    assert rec.fs == pytest.approx(750.0, rel=1e-12)
    assert rec.t[0] == 0.0 and rec.t[-1] == pytest.approx((rec.n - 1) / 750.0, rel=1e-12)
    meta = rec.metadata
    assert meta["sampling_rate_hz"] == 750.0
    group = "sinesweep" if which == "test_sweep" else "multisine"
    assert meta["sampling_rate_from"] == f"dataset '{group}/fs'"
    assert rec.units["t"] == "s" and rec.units["u"] == "N" and rec.units["y"] in _METRES
    assert meta["noise_free"] is (which != "train")
    assert dict(meta["true_parameters"]) == BOUC_WEN_TRUE_PARAMETERS
    assert meta["true_parameters"]["k_L"] == 5e4 and meta["true_parameters"]["delta"] == -1.1
    if which != "test_sweep":
        assert meta["period_samples"] == 8192
        assert meta["period_s"] == pytest.approx(8192 / 750)
        assert meta["n_periods"] == {"train": 5, "test_multisine": 1}[which]


@pytest.mark.parametrize("which", ["test_multisine", "test_sweep"])
def test_test_output_rms_matches_source(bench, which):
    rec = bench[which]
    # compared in metres whatever working unit the reader converted y to
    rms_m = float(np.sqrt(np.mean(rec.y**2))) * _METRES[rec.units["y"]]
    expected = {"test_multisine": 6.67e-4, "test_sweep": 6.64e-4}[which]
    assert rms_m == pytest.approx(expected, abs=0.005e-4)  # 3 significant digits
    assert rec.metadata["output_rms_m"] == expected == BOUC_WEN_TEST_OUTPUT_RMS_M[which]


def test_training_input_repeats_every_period(bench):
    rec = bench["train"]
    p = BOUC_WEN_PERIOD_SAMPLES
    periods = rec.u.reshape(5, p)
    for k in range(1, 5):
        np.testing.assert_array_equal(periods[k], periods[0])
    # the input is one multisine of RMS 50 N (SOURCE.md)
    assert float(np.sqrt(np.mean(rec.u**2))) == pytest.approx(50.0, rel=1e-3)
    # ... and the output repeats up to the measurement noise (RMS about 8e-6 m, so the
    # difference of two periods is about sqrt(2) x that) once the start-up has passed
    y_m = rec.y * _METRES[rec.units["y"]]
    diff = y_m[3 * p + 500: 4 * p] - y_m[4 * p + 500:]
    assert float(np.sqrt(np.mean(diff**2))) < 2e-5


def test_the_training_multisine_is_classified_with_its_period_and_band(bench):
    # its 5-150 Hz content near the 375 Hz Nyquist inflates the second-difference noise
    # estimate; the exact repetition must still be found (SOURCE.md: 5 x 8 192 samples)
    from bayeshyst.data import label_frequencies

    (rec,) = label_frequencies(bench["train"])
    assert rec.metadata["excitation"] == "multisine" and rec.frequency_hz is None
    assert rec.metadata["period_s"] * 750.0 == pytest.approx(BOUC_WEN_PERIOD_SAMPLES,
                                                              abs=0.05)
    lo, hi = rec.band_hz
    assert 4.5 <= lo <= 5.5 and 145.0 <= hi <= 151.0


def test_bad_which_missing_folder_and_changed_file(tmp_path, bench):
    with pytest.raises(ValueError, match="which: expected one of"):
        load_bouc_wen_benchmark("validation", root=tmp_path)
    with pytest.raises(DataError, match=r"boucwen_benchmark.*expected the measured data folder"):
        load_bouc_wen_benchmark(root=tmp_path)
    # a file that is not the published one (here: any other bytes) is refused by its sha256
    (tmp_path / "boucwen_benchmark").mkdir()
    (tmp_path / "boucwen_benchmark" / "train.h5").write_bytes(b"not the benchmark")
    with pytest.raises(DataError, match=r"train\.h5: expected sha256 a4df68f6"):
        load_bouc_wen_benchmark(root=tmp_path)
    with pytest.raises(DataError, match=r"test\.h5: expected the benchmark file"):
        load_bouc_wen_benchmark("test_sweep", root=tmp_path)
