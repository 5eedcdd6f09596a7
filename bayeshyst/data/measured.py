"""Loaders for the measured data sets kept in the shared data folder (never copied here).

Three public measurements and one simulated benchmark, each described by a
``SOURCE.md`` in its folder (columns, units, sampling, licence); the loaders follow
those descriptions exactly and copy the provenance into ``Record.metadata``:

* ``piezo_actuator_150V_1Hz`` -- piezoelectric actuator, +-150 V / 1 Hz sine, 5 kHz
  (:func:`load_piezo_actuator_150v`);
* ``piezo_micromanipulator_dbo`` -- flexure micromanipulator with capacitive sensor,
  1 Hz periodic drive, 200 Hz (:func:`load_piezo_micromanipulator`);
* ``mr_damper_utfsm_sine`` -- a magnetorheological **damper** (not a piezo) under
  sinusoidal displacement at 6 frequencies and 5 coil currents
  (:func:`load_mr_damper`). It serves the rate-dependence and model-selection studies:
  a hysteretic force-displacement system with a strong, known frequency dependence;
* ``boucwen_benchmark`` -- the Noël-Schoukens Bouc-Wen hysteresis benchmark, simulated
  with known true parameters: force in, displacement out, 750 Hz, HDF5 files
  (:func:`load_bouc_wen_benchmark`).

The folder is found by :func:`shared_data_root`.
"""

from __future__ import annotations

import hashlib
import math
import os
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any, Literal

import numpy as np

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.hdf5 import read_hdf5
from bayeshyst.data.parsing import read_table
from bayeshyst.data.record import Record
from bayeshyst.data.segment import find_reversals
from bayeshyst.errors import DataError

__all__ = [
    "BOUC_WEN_PARAMETER_UNITS",
    "BOUC_WEN_PERIOD_SAMPLES",
    "BOUC_WEN_SHA256",
    "BOUC_WEN_TEST_OUTPUT_RMS_M",
    "BOUC_WEN_TRUE_PARAMETERS",
    "ENV_VAR",
    "MICROMANIPULATOR_SEGMENT_STARTS",
    "load_bouc_wen_benchmark",
    "load_micromanipulator_reference",
    "load_mr_damper",
    "load_piezo_actuator_150v",
    "load_piezo_micromanipulator",
    "shared_data_root",
]

#: Environment variable that overrides the location of the shared data folder.
ENV_VAR = "BAYESHYST_SHARED_DATA"

PIEZO_150V_DIR = "piezo_actuator_150V_1Hz"
MICROMANIPULATOR_DIR = "piezo_micromanipulator_dbo"
MR_DAMPER_DIR = "mr_damper_utfsm_sine"
BOUC_WEN_DIR = "boucwen_benchmark"

#: 1-based MATLAB segment starts ``si`` marked in ``Step02_ChkCurves.m`` for
#: ``Test_Vi_Do_Di.dat`` (3852, 5052: no inverse compensation; 11152, 11852: with it);
#: the script analyses ``L = 1000`` samples from each start.
MICROMANIPULATOR_SEGMENT_STARTS = (3852, 5052, 11152, 11852)
_MICRO_FS = 200.0  # Hz, "Fs=200" in Step01_GetModel.m

_MR_NAME = re.compile(r"^(?P<amp>\d+(?:x\d+)?)mm(?P<freq>\d+(?:x\d+)?)Hz(?P<cur>\d+(?:x\d+)?)A$")


def shared_data_root() -> Path:
    """Locate the shared measured-data folder.

    Order: the environment variable ``BAYESHYST_SHARED_DATA``; then ``../shared/data``
    beside the repository checkout (the directory containing the ``bayeshyst``
    package).

    Returns
    -------
    Path
        An existing directory.

    Raises
    ------
    DataError
        If the variable points nowhere or the folder is absent.
    """
    env = os.environ.get(ENV_VAR)
    if env:
        root = Path(env).expanduser()
        if not root.is_dir():
            raise DataError(f"{ENV_VAR}={env!r}: expected a directory, found none")
        return root
    repo = Path(__file__).resolve().parents[2]
    root = repo.parent / "shared" / "data"
    if not root.is_dir():
        raise DataError(
            f"shared data folder not found: expected {root} (../shared/data beside the "
            f"checkout {repo}) or the environment variable {ENV_VAR}"
        )
    return root


def _folder(root: str | os.PathLike[str] | None, name: str) -> Path:
    base = shared_data_root() if root is None else Path(root)
    folder = base / name
    if not folder.is_dir():
        raise DataError(f"{folder}: expected the measured data folder {name!r}, found none")
    return folder


def _provenance(repository: str, commit: str, **extra: Any) -> dict[str, Any]:
    return {"kind": "measured", "licence": "MIT", "repository": repository,
            "commit": commit, **extra}


# ---------------------------------------------------------------- piezo 150 V / 1 Hz
def load_piezo_actuator_150v(
    root: str | os.PathLike[str] | None = None,
    *,
    warmup: int | Literal["virgin", "excitation"] = "virgin",
) -> Dataset:
    """Piezoelectric actuator, +-150 V / 1 Hz sine, displacement in µm, fs = 5 kHz.

    File ``hysteresis_v_150_1hz.csv`` (no header, first column empty): time [s],
    displacement [µm], voltage [V]; 50 001 rows, t = 0...10 s, dt = 0.2 ms. The input
    is 0 V until t ~ 3.257 s, then jumps into a 1 Hz sine of +-150 V (~6.7 cycles).

    Parameters
    ----------
    root : path-like, optional
        The shared data folder (default :func:`shared_data_root`).
    warmup : int or {"virgin", "excitation"}, default "virgin"
        ``"excitation"``: the samples before the input leaves 0 V. ``"virgin"``: those
        plus the initial (virgin) branch up to the first input maximum, which no
        closed-loop hysteresis model reproduces from a blank state. An int is used as
        is (0 scores everything).

    Returns
    -------
    Dataset
        One Record ``"piezo_actuator_150V_1Hz"`` with u [V], y [um],
        ``metadata["frequency_hz"] = 1.0``, ``amplitude = 150.0`` and provenance.
    """
    path = _folder(root, PIEZO_150V_DIR) / "hysteresis_v_150_1hz.csv"
    table = read_table(path, delimiter=",", header=False)
    if len(table.names) < 4:
        raise DataError(f"{path}: expected 4 columns (empty, t, y, u), got {len(table.names)}")
    t = table.floats("col1", label="field 2 of 4 (time)")
    y = table.floats("col2", label="field 3 of 4 (displacement)")
    u = table.floats("col3", label="field 4 of 4 (voltage)")
    moving = np.flatnonzero(u != 0.0)
    if moving.size == 0:
        raise DataError(f"{path}: field 4 (voltage): expected an excitation, got all zeros")
    start = int(moving[0])
    maxima = find_reversals(u, kind="max")
    maxima = maxima[maxima > start]
    virgin_end = int(maxima[0]) if maxima.size else start
    if warmup == "virgin":
        n_warm = virgin_end
    elif warmup == "excitation":
        n_warm = start
    elif isinstance(warmup, int | np.integer) and not isinstance(warmup, bool):
        n_warm = int(warmup)
    else:
        raise ValueError(f"warmup: expected 'virgin', 'excitation' or an int, got {warmup!r}")
    meta = _provenance(
        "https://github.com/chandratue/SmartHysteresis",
        "e7672dabcabbc75341e9ea965d073f68b27e5cda",
        frequency_hz=1.0,
        amplitude=150.0,
        amplitude_unit="V",
        source=str(path),
        copyright="Copyright (c) 2023 chandratue",
        original_path="Data/hysteresis_v_150_1hz.csv",
        paper=("A. Chandra et al., Discovery of sparse hysteresis models for piezoelectric "
               "materials, Appl. Phys. Lett. (2023)"),
        doi="10.1063/5.0146134",
        arxiv="2302.05313",
        measured_by="not stated by the paper or repository",
        sampling_rate_hz=5000.0,
        excitation_start_index=start,
        excitation_start_s=float(t[start]),
        virgin_branch_end_index=virgin_end,
        paper_rows=(35000, 45000),
    )
    rec = Record(t=t, u=u, y=y, warmup=n_warm, metadata=meta, name=PIEZO_150V_DIR)
    return Dataset([rec], name=PIEZO_150V_DIR)


# ------------------------------------------------------------- micromanipulator (DBO)
def _micro_table(root: str | os.PathLike[str] | None, which: str) -> tuple[Path, Any]:
    files = {"model": "Model_Vi_Do.dat", "test": "Test_Vi_Do_Di.dat"}
    if which not in files:
        raise ValueError(f"which: expected 'model' or 'test', got {which!r}")
    path = _folder(root, MICROMANIPULATOR_DIR) / files[which]
    table = read_table(path, delimiter=_detect_ws(path), header=False)
    need = 7 if which == "model" else 11
    if len(table.names) != need:
        raise DataError(f"{path}: expected {need} columns, got {len(table.names)}")
    return path, table


def _detect_ws(path: Path) -> str:
    # the .dat files are tab-separated; fall back to runs of whitespace otherwise
    with path.open("rb") as fh:
        return "\t" if b"\t" in fh.readline() else " "


def load_piezo_micromanipulator(
    root: str | os.PathLike[str] | None = None,
    which: Literal["model", "test"] = "model",
    *,
    warmup: int = 200,
) -> Dataset:
    """Piezoelectric micromanipulator (discrete-backlash-operator study), fs = 200 Hz.

    ``t`` is built as ``k / 200`` s (the files have no time column); u = column 1
    (actuator voltage command [V]); y = column 5 (capacitive sensor output, uncalibrated,
    plotted by the authors as µm, hence unit ``"um (uncalibrated)"``). Columns are
    1-based as in ``SOURCE.md``. The raw sensor value (about -123...-74) is kept; the
    authors subtract its mean before plotting.

    Parameters
    ----------
    root : path-like, optional
        The shared data folder (default :func:`shared_data_root`).
    which : {"model", "test"}, default "model"
        ``"model"``: ``Model_Vi_Do.dat``, identification data, 8 027 samples, 1 Hz
        raised-sine-like drive 0...3.6 V. ``"test"``: ``Test_Vi_Do_Di.dat``, 14 155
        samples of a growing/decaying-amplitude validation run (nested minor loops),
        partly driven through an inverse model. Both get ``frequency_hz = 1.0`` (the
        set's documented input frequency; the spectral estimate agrees within 0.1 %)
        and ``amplitude`` = half the input's peak-to-peak range [V].
    warmup : int, default 200
        Leading samples excluded from scoring; 200 = one 1 Hz period, because both
        files start mid-cycle from an unknown hysteretic state.

    Returns
    -------
    Dataset
        One Record. For ``"test"`` the ``segment`` labels are 0 before the first
        documented start and k = 1...4 from the k-th start of
        :data:`MICROMANIPULATOR_SEGMENT_STARTS` (0-based sample ``si - 1``) up to the
        next; ``metadata["analysis_windows"]`` gives the script's 1000-sample windows
        (0-based, stop exclusive; the last two overlap) and
        ``metadata["window_compensation"]`` whether each ran with the inverse model.
        The reference (desired output, column 9) is available from
        :func:`load_micromanipulator_reference`.
    """
    path, table = _micro_table(root, which)
    u = table.floats("col0", label="field 1 (voltage)")
    y = table.floats("col4", label="field 5 (sensor)")
    t = np.arange(u.size) / _MICRO_FS
    meta = _provenance(
        "https://github.com/yan9a/DiscreteBacklashOperator",
        "79fd060d86cdf69be2388e29bf57b0766c273650",
        source=str(path),
        copyright="Copyright (c) 2019 Yan Naing Aye",
        paper=("Y. N. Aye and W. T. Ang, A Discrete Backlash Operator for Identification "
               "and Compensation of Hysteresis and Non-linearity for Piezoelectric "
               "Micromanipulator, ICSTSD 2018"),
        sampling_rate_hz=_MICRO_FS,
        sensor_note="more negative reading = capacitor plates closer; calibration unknown",
        # the scripts align the sensor one sample late in the test file only
        phase_lag_samples=0 if which == "model" else 1,
    )
    # SOURCE.md: "input frequency 1 Hz (200 samples/cycle)" for the set as a whole
    meta.update(frequency_hz=1.0, amplitude=float(np.ptp(u)) / 2, amplitude_unit="V")
    segment = None
    if which == "test":
        starts = [s - 1 for s in MICROMANIPULATOR_SEGMENT_STARTS]
        segment = np.searchsorted(np.asarray(starts), np.arange(u.size), side="right")
        meta.update(
            segment_starts=tuple(starts),
            analysis_windows=tuple((s, s + 1000) for s in starts),
            window_compensation=("no H inv", "no H inv", "with H inv", "with H inv"),
        )
    units = {"t": "s", "u": "V", "y": "um (uncalibrated)"}
    name = f"{MICROMANIPULATOR_DIR}_{which}"
    rec = Record(t=t, u=u, y=y, segment=segment, warmup=warmup, metadata=meta,
                 units=units, name=name)
    return Dataset([rec], name=name)


def load_micromanipulator_reference(root: str | os.PathLike[str] | None = None) -> np.ndarray:
    """Desired output (reference) of the micromanipulator test run, column 9.

    Returns
    -------
    numpy.ndarray of float, shape (14155,)
        Read-only; growing/decaying amplitude up to +-20 (sensor units), aligned with
        ``load_piezo_micromanipulator(which="test")``.
    """
    _, table = _micro_table(root, "test")
    ref = table.floats("col8", label="field 9 (reference)")
    ref.flags.writeable = False
    return ref


# --------------------------------------------------------------------------- MR damper
def _number(token: str) -> float:
    return float(token.replace("x", "."))  # file names write the decimal point as 'x'


def _matches(value: float, wanted: float | Iterable[float] | None) -> bool:
    if wanted is None:
        return True
    options = [wanted] if isinstance(wanted, int | float) else list(wanted)
    return any(math.isclose(value, float(w), rel_tol=1e-9) for w in options)


def load_mr_damper(
    root: str | os.PathLike[str] | None = None,
    amplitude_mm: float | Iterable[float] | None = None,
    frequency_hz: float | Iterable[float] | None = None,
    current_a: float | Iterable[float] | None = None,
    *,
    warmup_periods: float = 0.5,
) -> Dataset:
    """MR damper under sinusoidal displacement (UTFSM, MTS press): 30 preprocessed tests.

    Files ``<amp>mm<freq>Hz<current>A.txt`` (``x`` = decimal point), whitespace text
    without header: t [s], x [mm], dx/dt [mm/s], F [N]. Here the **input** u is the
    displacement x [mm] and the **output** y the force F [N]; the velocity column is
    kept as the covariate ``velocity_mm_s`` (the authors' first difference of the
    smoothed x: an MR damper's viscous force follows it, so the diagnosis' driver scan
    and ``aux`` candidate can look at it). The authors smoothed both signals with
    a causal moving average of 1/10 period and removed the mean (``metadata
    ["preprocessing"]``), so harmonics are attenuated and delayed.

    Measured, not documented upstream: in every file the input period is 1.5-2.5 %
    shorter than the nominal frequency implies (e.g. 0.984 s in the "1 Hz" tests), and
    the stroke falls short of the nominal amplitude (2-3 %, ~19 % at 2 mm / 5 Hz). The
    metadata keeps the nominal values from the file name; cut cycles with
    ``split_cycles(record)`` (input reversals), not with the nominal period.

    Parameters
    ----------
    root : path-like, optional
        The shared data folder (default :func:`shared_data_root`).
    amplitude_mm, frequency_hz, current_a : float or iterable of float, optional
        Keep only tests with these displacement amplitudes [mm], frequencies [Hz]
        and coil currents [A] (all when None).
    warmup_periods : float, default 0.5
        Warm-up in excitation periods (rounded to samples): covers the moving-average
        start-up (0.1 period) and lets the hysteretic state forget its unknown start.

    Returns
    -------
    Dataset
        ``"mr_damper_utfsm_sine"``, records named by file stem, ordered by frequency,
        amplitude, current; units ``{"t": "s", "u": "mm", "y": "N"}``; covariate
        ``velocity_mm_s`` [mm/s]; metadata
        ``frequency_hz``, ``amplitude_mm``, ``current_a`` parsed from the name.

    Raises
    ------
    DataError
        If no file matches the filters (the message lists what exists).
    """
    folder = _folder(root, MR_DAMPER_DIR)
    found = []
    for path in sorted(folder.glob("*.txt")):
        m = _MR_NAME.match(path.stem)
        if m is None:
            continue
        amp, freq, cur = (_number(m[g]) for g in ("amp", "freq", "cur"))
        found.append((freq, amp, cur, path))
    chosen = [
        f for f in sorted(found)
        if _matches(f[1], amplitude_mm) and _matches(f[0], frequency_hz)
        and _matches(f[2], current_a)
    ]
    if not chosen:
        have = sorted({(a, f) for f, a, _, _ in found})
        raise DataError(
            f"{folder}: no MR-damper test matches amplitude_mm={amplitude_mm!r}, "
            f"frequency_hz={frequency_hz!r}, current_a={current_a!r}; available "
            f"(amplitude mm, frequency Hz): {have}, currents 0, 0.25, 0.5, 0.75, 1 A"
        )
    records = []
    for freq, amp, cur, path in chosen:
        table = read_table(path, delimiter=" ", header=False)
        if len(table.names) != 4:
            raise DataError(f"{path}: expected 4 columns (t, x, dx/dt, F), got {len(table.names)}")
        t = table.floats("col0", label="field 1 of 4 (t)")
        dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
        meta = _provenance(
            "https://github.com/DanielMaurelE/vRTHS_AMBC_MRdamper",
            "08753ffd7abd5b19053f7e79149c3a68f49bf73c",
            frequency_hz=freq,
            amplitude_mm=amp,
            current_a=cur,
            amplitude=amp,
            amplitude_unit="mm",
            source=str(path),
            copyright="Copyright (c) 2022 mequiroz",
            measured_by="M. Quiroz (UTFSM), MTS universal uniaxial press",
            device="magnetorheological damper (not a piezo actuator)",
            preprocessing=("causal moving average of 1/10 period on x and F, per-current "
                           "segmentation, mean removed (sincronize.m)"),
        )
        records.append(Record(
            t=t,
            u=table.floats("col1", label="field 2 of 4 (x)"),
            y=table.floats("col3", label="field 4 of 4 (F)"),
            covariates={"velocity_mm_s": table.floats("col2", label="field 3 of 4 (dx/dt)")},
            warmup=round(warmup_periods / (freq * dt)),
            metadata=meta,
            units={"t": "s", "u": "mm", "y": "N"},
            name=path.stem,
        ))
    return Dataset(records, name=MR_DAMPER_DIR)


# ------------------------------------------------------------- Bouc-Wen benchmark
#: sha256 of the benchmark files as stated in the folder's SOURCE.md (byte copies of the
#: dynonet repository's files): a changed file would silently move every published score.
BOUC_WEN_SHA256 = {
    "train.h5": "a4df68f6101a22f9fc5032e98b3e773fc108a291378ef9cf69d1b128c7ac44a4",
    "test.h5": "822fe88df38cf41bffbebedb06af8d6c5eb2f808de0e2eefe6d78b215de53016",
}
#: Samples per period of the benchmark's multisines (at 750 Hz).
BOUC_WEN_PERIOD_SAMPLES = 8192
#: The simulated system's parameters (SOURCE.md), SI units in :data:`BOUC_WEN_PARAMETER_UNITS`.
BOUC_WEN_TRUE_PARAMETERS = {
    "m_L": 2.0, "c_L": 10.0, "k_L": 5e4, "alpha": 5e4, "beta": 1e3, "gamma": 0.8,
    "delta": -1.1, "nu": 1.0,
}
BOUC_WEN_PARAMETER_UNITS = {
    "m_L": "kg", "c_L": "N s/m", "k_L": "N/m", "alpha": "N/m", "beta": "1/m",
    "gamma": "-", "delta": "-", "nu": "-",
}
#: RMS of the two official test outputs [m], the scale the literature's RMSE is read on.
BOUC_WEN_TEST_OUTPUT_RMS_M = {"test_multisine": 6.67e-4, "test_sweep": 6.64e-4}

_BW_FS = 750.0  # Hz, SOURCE.md; the files' own fs datasets are what the records use
# which -> (file, group, record name, description, number of periods or None)
_BW_RECORDS: dict[str, tuple[str, str, str, str, int | None]] = {
    "train": (
        "train.h5", "multisine", "train_multisine",
        "training data: 5 periods x 8192 samples of one random-phase multisine (5-150 Hz, "
        "RMS 50 N), output with band-limited measurement noise (RMS about 8e-6 m)", 5),
    "test_multisine": (
        "test.h5", "multisine", "test_multisine",
        "official test 1: one steady-state period (8192 samples) of another multisine, "
        "noise-free output; simulate several periods and score the last", 1),
    "test_sweep": (
        "test.h5", "sinesweep", "test_sweep",
        "official test 2: sine sweep, 40 N, about 20 -> 50 Hz at 10 Hz/min, from rest, "
        "noise-free output", None),
}


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def load_bouc_wen_benchmark(
    which: Literal["train", "test_multisine", "test_sweep"] = "train",
    root: str | os.PathLike[str] | None = None,
) -> Dataset:
    """The Noël-Schoukens Bouc-Wen hysteresis benchmark (simulated), force in, displacement out.

    A 1-DOF mass with a Bouc-Wen hysteretic restoring force driven by a force u [N];
    output the displacement y [m]; fs = 750 Hz (read from the files' ``fs`` datasets).
    Files ``train.h5`` and ``test.h5`` of the folder ``boucwen_benchmark`` (byte copies
    from the dynonet repository, checked against the sha256 in its ``SOURCE.md``), read
    with :func:`~bayeshyst.data.hdf5.read_hdf5`. The literature scores free-run
    simulation RMSE [m] on each test record with the model identified on ``"train"``
    only.

    Parameters
    ----------
    which : {"train", "test_multisine", "test_sweep"}, default "train"
        ``"train"``: ``train.h5`` ``multisine/*``, 40 960 samples (5 periods of 8 192,
        with measurement noise; u repeats exactly from period to period), kept whole.
        ``"test_multisine"``: ``test.h5`` ``multisine/*``, 8 192 samples, one
        steady-state period, noise-free. ``"test_sweep"``: ``test.h5``
        ``sinesweep/*``, 153 000 samples from rest, noise-free.
    root : path-like, optional
        The shared data folder (default :func:`shared_data_root`).

    Returns
    -------
    Dataset
        ``"boucwen_benchmark_<which>"`` with one Record ``"train_multisine"``,
        ``"test_multisine"`` or ``"test_sweep"``; units ``{"t": "s", "u": "N", "y":
        "m"}`` as declared to the reader; metadata: ``description``, ``noise_free``,
        ``period_s`` (8192/750 s), ``period_samples`` and ``n_periods`` for the
        multisines, ``true_parameters`` (dict, SI units in ``true_parameter_units``),
        ``test_output_rms_m`` (both published test-output RMS values [m]) and, for a
        test record, ``output_rms_m`` (its own), the sha256 and the provenance.

    Raises
    ------
    ValueError
        If ``which`` is not one of the three names.
    DataError
        If the folder or a file is missing, a file's sha256 differs from SOURCE.md, or
        the file is malformed (:func:`~bayeshyst.data.hdf5.read_hdf5`).
    """
    if which not in _BW_RECORDS:
        raise ValueError(f"which: expected one of {list(_BW_RECORDS)}, got {which!r}")
    filename, group, rec_name, description, n_periods = _BW_RECORDS[which]
    path = _folder(root, BOUC_WEN_DIR) / filename
    if not path.is_file():
        raise DataError(f"{path}: expected the benchmark file {filename!r}, found none")
    found = _sha256(path)
    if found != BOUC_WEN_SHA256[filename]:
        raise DataError(
            f"{path}: expected sha256 {BOUC_WEN_SHA256[filename]} (SOURCE.md), got {found}; "
            f"not the published benchmark file"
        )
    meta = _provenance(
        "https://github.com/forgi86/dynonet",
        "56699401b141065a45403a18977333e0ec8d7303",
        kind="simulated benchmark",
        source=str(path),
        original_path=f"examples/BW/data/Test signals/{filename}",
        copyright="Copyright (c) 2020 Marco Forgione",
        sha256=found,
        benchmark="Bouc-Wen hysteretic benchmark (Noel & Schoukens 2016)",
        paper=("M. Schoukens, J.P. Noel, Three benchmarks addressing open challenges in "
               "nonlinear system identification, IFAC World Congress 2017"),
        doi="10.1016/j.ifacol.2017.08.071",
        dataset_doi="10.4121/12967592",
        device="simulated 1-DOF mass with Bouc-Wen hysteretic restoring force (not a piezo)",
        model=("m_L y'' + c_L y' + k_L y + z = u; z' = alpha y' - beta (gamma |y'| "
               "|z|^(nu-1) z + delta y' |z|^nu)"),
        true_parameters=dict(BOUC_WEN_TRUE_PARAMETERS),
        true_parameter_units=dict(BOUC_WEN_PARAMETER_UNITS),
        test_output_rms_m=dict(BOUC_WEN_TEST_OUTPUT_RMS_M),
        scoring="free-run simulation RMSE [m] per test record, identified on train only",
        description=description,
        benchmark_record=which,
        noise_free=which != "train",
    )
    if n_periods is not None:
        meta.update(period_samples=BOUC_WEN_PERIOD_SAMPLES,
                    period_s=BOUC_WEN_PERIOD_SAMPLES / _BW_FS, n_periods=n_periods)
    if which in BOUC_WEN_TEST_OUTPUT_RMS_M:
        meta["output_rms_m"] = BOUC_WEN_TEST_OUTPUT_RMS_M[which]
    data = read_hdf5(
        path,
        columns={"u": f"{group}/u", "y": f"{group}/y"},
        metadata=meta,
        units={"t": "s", "u": "N", "y": "m"},
        name=f"{BOUC_WEN_DIR}_{which}",
    )
    # the reader names a single record after the file stem; one file holds two records
    return Dataset([data[0].with_(name=rec_name)], name=data.name)
