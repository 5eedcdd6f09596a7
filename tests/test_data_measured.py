"""Measured-data loaders, checked against the facts stated in each folder's SOURCE.md."""

from __future__ import annotations

import numpy as np
import pytest

from bayeshyst.data.measured import (
    ENV_VAR,
    load_micromanipulator_reference,
    load_mr_damper,
    load_piezo_actuator_150v,
    load_piezo_micromanipulator,
    shared_data_root,
)
from bayeshyst.data.segment import estimate_frequency, split_cycles
from bayeshyst.errors import DataError

pytestmark = pytest.mark.shared_data


@pytest.fixture(scope="module")
def piezo(shared_data_dir):
    return load_piezo_actuator_150v(shared_data_dir)[0]


@pytest.fixture(scope="module")
def mr(shared_data_dir):
    return load_mr_damper(shared_data_dir)


def test_shared_root_env_var(monkeypatch, tmp_path, shared_data_dir):
    monkeypatch.setenv(ENV_VAR, str(tmp_path))
    assert shared_data_root() == tmp_path
    with pytest.raises(DataError, match=r"piezo_actuator_150V_1Hz.*expected the measured data"):
        load_piezo_actuator_150v()
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "nope"))
    with pytest.raises(DataError, match=f"{ENV_VAR}=.*expected a directory"):
        shared_data_root()


# ------------------------------------------------------------------- piezo 150 V, 1 Hz
def test_piezo_150v_matches_source(piezo):
    assert piezo.n == 50_001
    assert piezo.t[0] == 0.0 and piezo.t[-1] == pytest.approx(10.0)
    assert piezo.dt == pytest.approx(2e-4, rel=1e-6) and piezo.fs == pytest.approx(5000.0)
    assert piezo.y.min() == pytest.approx(-19.7, abs=0.05)
    assert piezo.y.max() == pytest.approx(19.7, abs=0.05)
    assert piezo.u.min() == -150.0 and piezo.u.max() == 150.0
    assert dict(piezo.units) == {"t": "s", "u": "V", "y": "um"}
    meta = piezo.metadata
    assert meta["frequency_hz"] == 1.0 and meta["amplitude"] == 150.0
    assert meta["licence"] == "MIT" and meta["doi"] == "10.1063/5.0146134"
    assert meta["source"].endswith("piezo_actuator_150V_1Hz/hysteresis_v_150_1hz.csv")
    assert meta["excitation_start_s"] == pytest.approx(3.257, abs=1e-3)
    # before the excitation: offset -1.68 um with 0.05 um RMS noise
    rest = piezo.y[: meta["excitation_start_index"]]
    assert rest.mean() == pytest.approx(-1.68, abs=0.02) and rest.std() < 0.06


def test_piezo_150v_warmup_options(shared_data_dir, piezo):
    start = piezo.metadata["excitation_start_index"]
    # default: idle part plus the virgin branch up to the first +150 V peak
    assert piezo.warmup == piezo.metadata["virgin_branch_end_index"] > start
    assert piezo.u[piezo.warmup] == pytest.approx(150.0, abs=0.5)
    assert load_piezo_actuator_150v(shared_data_dir, warmup="excitation")[0].warmup == start
    assert load_piezo_actuator_150v(shared_data_dir, warmup=0)[0].warmup == 0
    with pytest.raises(ValueError, match="warmup"):
        load_piezo_actuator_150v(shared_data_dir, warmup="all")  # type: ignore[arg-type]


def test_piezo_150v_cycles_and_frequency(piezo):
    assert estimate_frequency(piezo) == pytest.approx(1.0, rel=1e-3)
    assert len(split_cycles(piezo)) == 5  # ~6.7 cycles, minus virgin branch and partial ends


# ---------------------------------------------------------------------- micromanipulator
def test_micromanipulator_model_matches_source(shared_data_dir):
    ds = load_piezo_micromanipulator(shared_data_dir, "model")
    rec = ds[0]
    assert rec.n == 8027 and rec.fs == pytest.approx(200.0) and rec.t[1] == 1 / 200
    assert rec.u.min() == pytest.approx(0.0, abs=1e-6) and rec.u.max() == pytest.approx(3.6)
    assert rec.y.min() == pytest.approx(-123.1, abs=0.05)
    assert rec.y.max() == pytest.approx(-73.6, abs=0.05)
    assert rec.units["y"] == "um (uncalibrated)" and rec.frequency_hz == 1.0
    assert rec.warmup == 200 and rec.segment is None
    assert estimate_frequency(rec) == pytest.approx(1.0, rel=1e-3)
    assert 37 <= len(split_cycles(rec)) <= 40  # ~40 cycles


def test_micromanipulator_test_segments_and_reference(shared_data_dir):
    rec = load_piezo_micromanipulator(shared_data_dir, "test")[0]
    assert rec.n == 14155
    assert rec.u.min() == pytest.approx(0.17, abs=0.005)
    assert rec.u.max() == pytest.approx(3.51, abs=0.005)
    starts = [3851, 5051, 11151, 11851]  # MATLAB si - 1
    assert rec.metadata["segment_starts"] == tuple(starts)
    assert np.bincount(rec.segment).tolist() == [3851, 1200, 6100, 700, 14155 - 11851]
    assert [int(rec.segment[s]) for s in starts] == [1, 2, 3, 4]
    assert rec.metadata["window_compensation"][2:] == ("with H inv", "with H inv")
    ref = load_micromanipulator_reference(shared_data_dir)
    assert ref.shape == (14155,) and not ref.flags.writeable
    assert ref.min() == pytest.approx(-20.0, abs=0.2) and ref.max() == pytest.approx(20.0, abs=0.2)
    with pytest.raises(ValueError, match="which"):
        load_piezo_micromanipulator(shared_data_dir, "train")  # type: ignore[arg-type]


# ----------------------------------------------------------------------------- MR damper
def test_mr_damper_matrix_matches_source(mr):
    assert len(mr) == 30
    assert mr.frequencies == (0.1, 0.25, 0.5, 1.0, 3.0, 5.0)
    combos = {(r.metadata["amplitude_mm"], r.frequency_hz) for r in mr}
    assert combos == {(2.0, 5.0), (5.0, 3.0), (10.0, 1.0), (25.0, 0.1), (25.0, 0.25), (25.0, 0.5)}
    for r in mr:
        assert r.metadata["current_a"] in (0.0, 0.25, 0.5, 0.75, 1.0)
        assert dict(r.units) == {"t": "s", "u": "mm", "y": "N"}
        expected_dt = 0.001 if r.frequency_hz in (1.0, 3.0) else 0.005
        assert r.dt == pytest.approx(expected_dt, rel=1e-6)
    lengths = [r.n for r in mr]
    assert min(lengths) == 448 and max(lengths) == 19035
    assert mr["10mm1Hz0x25A"].metadata["current_a"] == 0.25
    assert mr["25mm0x1Hz0x75A"].frequency_hz == 0.1


def test_mr_damper_keeps_the_velocity_column_and_it_is_the_first_difference(mr):
    # SOURCE.md: dx/dt is the first difference of the smoothed displacement -- a column the
    # loader does not map to t, u, y is kept as a covariate, not dropped
    for r in mr:
        assert set(r.covariates) == {"velocity_mm_s"}
        v = np.asarray(r.covariates["velocity_mm_s"])
        diff = np.diff(r.u) / r.dt
        assert np.corrcoef(v[1:], diff)[0, 1] > 0.99
        assert np.median(np.abs(v[1:] - diff)) < 0.02 * np.ptp(diff)


def test_mr_damper_physics_facts(mr):
    # peak force grows with coil current: ~+-140-220 N at 0 A, up to ~+-1.5 kN at 1 A
    at_zero = [np.abs(r.y).max() for r in mr if r.metadata["current_a"] == 0.0]
    at_one = [np.abs(r.y).max() for r in mr if r.metadata["current_a"] == 1.0]
    assert 130 < min(at_zero) and max(at_zero) < 260
    assert 1200 < max(at_one) < 1700
    for r in mr:
        # the measured stroke never exceeds the commanded amplitude; smoothing and the press
        # lose 2-3 % at low frequency and ~19 % at 2 mm / 5 Hz
        ratio = np.ptp(r.u) / 2 / r.metadata["amplitude_mm"]
        assert 0.8 < ratio < 1.0


def test_mr_damper_measured_period_is_shorter_than_nominal(mr):
    # Finding, not a loader property: the excitation period in the preprocessed files is
    # 1.5-2.5 % shorter than the nominal frequency in the file name implies, so fixed-period
    # segmentation with the nominal frequency drifts; segment by reversals instead.
    ratios = [estimate_frequency(r) / r.frequency_hz for r in mr]
    assert all(1.01 < q < 1.03 for q in ratios)


def test_mr_damper_filters(shared_data_dir):
    sel = load_mr_damper(shared_data_dir, amplitude_mm=25, frequency_hz=[0.1, 0.5],
                         current_a=0.25)
    assert sel.names == ("25mm0x1Hz0x25A", "25mm0x5Hz0x25A")
    assert sel[0].warmup == round(0.5 / (0.1 * 0.005))
    with pytest.raises(DataError, match=r"no MR-damper test matches .*available"):
        load_mr_damper(shared_data_dir, frequency_hz=7.0)
