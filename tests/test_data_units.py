"""Instrument files: headers with units, roles by name, conversion, plausibility, --columns.

Oracle: the numbers written to the file times the unit's factor (s, V, µm), and the
readers' refusals in words where a file is ambiguous or contradicts itself.
"""

from __future__ import annotations

import numpy as np
import pytest

from bayeshyst.cli import main
from bayeshyst.data import load
from bayeshyst.data.units import conversion, plausibility, split_header
from bayeshyst.errors import DataError
from bayeshyst.inverse.references import load_reference


def _write(path, header, columns, delimiter=","):
    rows = "\n".join(delimiter.join(repr(float(v)) for v in row) for row in zip(*columns,
                                                                               strict=True))
    path.write_text(delimiter.join(header) + "\n" + rows + "\n")
    return path


def _signals(n=3000, fs=5000.0):
    t = np.arange(n) / fs
    u = 60 + 50 * np.sin(2 * np.pi * 5 * t)
    y = 0.2 * u + 0.01 * np.sin(2 * np.pi * 7 * t)
    return t, u, y


@pytest.mark.parametrize(("cell", "expected"), [
    ("Time [s]", ("Time", "s")), ("Displacement (nm)", ("Displacement", "nm")),
    ("U/V", ("U", "V")), ("t / ms", ("t", "ms")), ("x [µm]", ("x", "µm")),
    ("in/out", ("in/out", None)), ("t", ("t", None)), ("Force [N]", ("Force", "N")),
])
def test_split_header(cell, expected):
    assert split_header(cell) == expected


def test_conversion_factors_and_labels():
    assert conversion("t", "ms") == (1e-3, "s") and conversion("t", "µs") == (1e-6, "s")
    assert conversion("y", "nm") == (1e-3, "um") and conversion("y", "mm") == (1e3, "um")
    assert conversion("y", "m") == (1e6, "um") and conversion("u", "kV") == (1e3, "V")
    # every dimension with a working unit is converted (a current to A, a force to N)
    assert conversion("u", "mA") == (1e-3, "A") and conversion("y", "kN") == (1e3, "N")
    assert conversion("y", "mm/s") is None  # no working unit for a speed: kept
    # a role takes any dimension (a y in ms becomes s), but the time must be a time
    assert conversion("y", "ms") == (1e-3, "s")
    assert conversion("t", "V") is None and conversion("t", None) is None


def test_an_instrument_export_is_read_and_converted(tmp_path):
    t, u, y = _signals()
    path = _write(tmp_path / "scope.csv",
                  ["Time [ms]", "Voltage [V]", "Displacement [nm]", "Temperature [C]"],
                  [t * 1e3, u, y * 1e3, np.full(t.size, 21.5)])
    (rec,) = load(path)
    np.testing.assert_allclose(rec.t, t, rtol=1e-12)
    np.testing.assert_allclose(rec.u, u, rtol=1e-12)
    np.testing.assert_allclose(rec.y, y, rtol=1e-12)
    assert dict(rec.units) == {"t": "s", "u": "V", "y": "um"} and rec.fs == pytest.approx(5000)
    assert rec.metadata["unit_conversions"] == (
        "column 'Time [ms]' (t): ms -> s, x 0.001",
        "column 'Displacement [nm]' (y): nm -> um, x 0.001")
    assert "ignored_columns" not in rec.metadata  # the temperature is kept, by its name
    np.testing.assert_array_equal(rec.covariates["Temperature [C]"], np.full(t.size, 21.5))
    assert plausibility(load(path)) == []
    # semicolons and slashed units, as some exports write them
    (rec2,) = load(_write(tmp_path / "b.csv", ["t/s", "U/V", "x (um)"], [t, u, y], ";"))
    np.testing.assert_allclose(rec2.y, y, rtol=1e-12)


def test_ambiguous_or_contradicting_headers_are_refused_in_words(tmp_path):
    t, u, y = _signals()
    two = _write(tmp_path / "two.csv", ["Time [s]", "Voltage [V]", "Position [um]",
                                        "Output [um]"], [t, u, y, 2 * y])
    with pytest.raises(DataError, match=r"several columns could be 'y': \['Position \[um\]', "
                                        r"'Output \[um\]'\]"):
        load(two)
    # named by the user, with or without its unit
    assert np.allclose(load(two, columns={"y": "Output"})[0].y, 2 * y)
    assert np.allclose(load(two, columns={"y": "Position [um]"})[0].y, y)
    clash = _write(tmp_path / "clash.csv", ["t", "u", "y [nm]"], [t, u, y])
    with pytest.raises(DataError, match=r"the header says 'nm', the declared unit of 'y' "
                                        r"is 'mm'"):
        load(clash, units={"y": "mm"})
    # four columns named nothing a role is called: which is which cannot be guessed
    none = _write(tmp_path / "none.csv", ["a", "b", "c", "d"], [t, u, y, y])
    with pytest.raises(DataError, match=r"column 't': missing"):
        load(none)
    # three: read in their order as t, u, y, and said so
    (rec,) = load(_write(tmp_path / "three.csv", ["a", "b", "c"], [t, u, y]))
    np.testing.assert_array_equal(rec.u, u)
    np.testing.assert_array_equal(rec.y, y)
    assert rec.metadata["column_roles"] == (
        "columns taken in their order as t, u, y: t = 'a', u = 'b', y = 'c' (name them "
        "with --columns t=...,u=...,y=... otherwise)",)


def test_time_in_ms_read_as_seconds_is_flagged(tmp_path):
    # the data contradict themselves: a 5 Hz excitation (frequency_hz) sampled every
    # every "0.2 s" (5000 Hz in ms read as s) -- 1 sample per cycle, and the input
    # cycles once per 200 "s"
    t, u, y = _signals()
    path = _write(tmp_path / "ms.csv", ["time", "volt", "disp"], [t * 1e3, u, y])
    (warning,) = plausibility(load(path, metadata={"frequency_hz": 5.0}))
    assert "1 samples per cycle of the 5 Hz excitation (step 0.2 s)" in warning
    assert "time in ms read as s?" in warning
    # without a frequency, nothing in the data contradicts a 5 Hz sampling
    assert plausibility(load(path)) == []


def test_a_reference_file_with_instrument_units(tmp_path):
    t = np.arange(100) / 1000.0
    y = 5 + 4 * np.sin(2 * np.pi * 10 * t)
    ref = load_reference(_write(tmp_path / "ref.csv", ["Time [ms]", "Position [nm]"],
                                [t * 1e3, y * 1e3]))
    np.testing.assert_allclose(ref.t, t, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(ref.y_d, y, rtol=1e-12)


def test_cli_columns_option(tmp_path, capsys):
    t, u, y = _signals()
    path = _write(tmp_path / "two.csv", ["Time [ms]", "Voltage [V]", "Position [um]",
                                         "Output [um]"], [t * 1e3, u, y, 2 * y])
    out = tmp_path / "fit"
    assert main(["fit", str(path), "--model", "pi_play(n_operators=2)", "--columns",
                 "y=Output", "--steps", "600", "--out", str(out), "--no-figures",
                 "--no-calibration"]) == 0
    err = capsys.readouterr().err
    assert "column 'Time [ms]' (t): ms -> s, x 0.001" in err
    for bad, message in (("z=Output", "unknown role 'z'"), ("y", "ROLE=COLUMN"),
                         ("y=a,y=b", "given twice")):
        with pytest.raises(SystemExit) as exc:
            main(["fit", str(path), "--model", "pi_play", "--columns", bad,
                  "--out", str(tmp_path / "x")])
        assert exc.value.code == 2 and message in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_cli_finds_the_frequencies_a_file_does_not_give(tmp_path, capsys):
    import json

    fs = 5000.0
    steps = [(10.0, 6), (20.0, 8)]
    u = np.concatenate([60 - 50 * np.cos(2 * np.pi * f * np.arange(int(n * fs / f)) / fs)
                        for f, n in steps])
    t = np.arange(u.size) / fs
    y = 0.2 * u + 0.01 * np.sin(2 * np.pi * 3 * t)
    path = _write(tmp_path / "stepped.csv", ["t", "u", "y"], [t, u, y])
    args = ["fit", str(path), "--model", "pi_play(n_operators=2)", "--steps", "600",
            "--no-figures", "--no-calibration"]
    assert main([*args, "--out", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    assert "record 'stepped' has no frequency_hz; found from its input: 10 Hz" in err
    per = json.loads((tmp_path / "a" / "summary.json").read_text())["per_frequency"]
    assert [p["frequency_hz"] for p in per if p["frequency_hz"] is not None] == [10.0, 20.0]
    assert main([*args, "--no-frequency-labels", "--out", str(tmp_path / "b")]) == 0
    per = json.loads((tmp_path / "b" / "summary.json").read_text())["per_frequency"]
    assert all(p["frequency_hz"] is None for p in per)


def test_an_unknown_unit_is_refused_and_other_quantities_stay_labels(tmp_path, capsys):
    t, u, y = _signals()
    # (a furlong is a length pint knows; "furlongs per week" spelled as one word is not)
    odd = _write(tmp_path / "odd.csv", ["Time [s]", "Voltage [V]",
                                        "Displacement [furlongsperweek]"], [t, u, y])
    with pytest.raises(DataError, match=r"odd\.csv: line 1 \(header\), column "
                                        r"'Displacement \[furlongsperweek\]' \(y\): "
                                        r"unknown unit"):
        load(odd)
    assert main(["fit", str(odd), "--model", "pi_play", "--out", str(tmp_path / "o")]) == 2
    assert "unknown unit 'furlongsperweek'" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
    # an MR damper's file: a displacement input is converted to um like any length, a
    # force output is in N already (its working unit): numbers x 1000 and untouched
    force = _write(tmp_path / "force.csv", ["t [ms]", "u [mm]", "y [N]"], [t * 1e3, u, y])
    (rec,) = load(force)
    assert dict(rec.units) == {"t": "s", "u": "um", "y": "N"}
    np.testing.assert_allclose(rec.u, u * 1e3, rtol=1e-15)
    assert np.array_equal(rec.y, y)
    # a unit of a quantity without a working unit stays a label, in pint's spelling
    speed = _write(tmp_path / "speed.csv", ["t", "u [V]", "y [mm / s]"], [t, u, y])
    assert dict(load(speed)[0].units) == {"t": "s", "u": "V", "y": "mm/s"}


def test_an_instrument_file_fits_to_the_posterior_of_its_converted_twin(tmp_path):
    import json

    t, u, y = _signals(n=2000)
    y = y + np.random.default_rng(3).normal(0, 0.02, y.size)
    scope = _write(tmp_path / "scope.csv", ["Time [ms]", "Voltage [mV]", "Position [nm]"],
                   [t * 1e3, u * 1e3, y * 1e3])
    twin = _write(tmp_path / "twin.csv", ["t", "u", "y"], [t, u, y])
    a, b = load(scope)[0], load(twin)[0]
    for x, z in ((a.t, b.t), (a.u, b.u), (a.y, b.y)):
        np.testing.assert_allclose(x, z, rtol=1e-14, atol=1e-15)
    sums = []
    for path in (scope, twin):
        out = tmp_path / path.stem
        assert main(["fit", str(path), "--model", "pi_play(n_operators=2)", "--steps", "600",
                     "--no-figures", "--no-calibration", "--quiet", "--out", str(out)]) == 0
        sums.append(json.loads((out / "summary.json").read_text()))
    for name, p in sums[1]["params"].items():
        q = sums[0]["params"][name]
        assert q["mean"] == pytest.approx(p["mean"], abs=1e-6 * p["sd"]), name
