"""Units parsed by pint, working units per dimension, convert_units, --units, plausibility.

Oracles: the numbers written to a file times the factor of its unit (from the SI
definitions: 1 cm = 1e4 um, 1 Oe = 1000/(4 pi) A/m, 1 G = 1e-4 T, ...); the same
arrays and log-posterior for a file and its twin written in other units; the text of
the refusals (file, column, unit); and the samples per cycle / step spread that a
caution must (or must not) report.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from bayeshyst.cli.commands import load_data
from bayeshyst.cli.parser import build_parser
from bayeshyst.data import Dataset, Record, load
from bayeshyst.data.units import UNKNOWN, WORKING_UNITS, convert_units, plausibility
from bayeshyst.errors import DataError
from bayeshyst.inference.posterior import Posterior


def _write(path, header, columns):
    rows = "\n".join(",".join(repr(float(v)) for v in row)
                     for row in zip(*columns, strict=True))
    path.write_text(",".join(header) + "\n" + rows + "\n")
    return path


def _signals(n=400, fs=200.0, f=2.0):
    t = np.arange(n) / fs
    u = 60 + 50 * np.sin(2 * np.pi * f * t)
    y = 0.2 * u + 3 * np.sin(2 * np.pi * f * t + 0.4)
    return t, u, y


# unit written in the header -> (unit of the Record, factor applied to the numbers)
ACCEPTED = [
    ("cm", "um", 1e4), ("mm", "um", 1e3), ("m", "um", 1e6), ("um", "um", 1.0),
    ("µm", "um", 1.0), ("μm", "um", 1.0), ("nm", "um", 1e-3),
    ("kN", "N", 1e3), ("mN", "N", 1e-3), ("N", "N", 1.0),
    ("mT", "T", 1e-3), ("T", "T", 1.0), ("G", "T", 1e-4),
    ("A/m", "A/m", 1.0), ("kA/m", "A/m", 1e3), ("Oe", "A/m", 1000 / (4 * math.pi)),
    ("V", "V", 1.0), ("mV", "V", 1e-3), ("kV", "V", 1e3),
    ("A", "A", 1.0), ("mA", "A", 1e-3), ("Pa", "Pa", 1.0), ("kPa", "Pa", 1e3),
    ("MPa", "Pa", 1e6), ("uC", "C", 1e-6),
    # dimensionless labels and units without a working unit: kept, numbers untouched
    ("%", "%", 1.0), ("-", "-", 1.0), ("1", "1", 1.0), ("counts", "counts", 1.0),
    ("a.u.", "a.u.", 1.0), ("mm/s", "mm/s", 1.0), ("kV/mm", "kV/mm", 1.0),
]
TIMES = [("s", 1.0), ("ms", 1e-3), ("us", 1e-6), ("µs", 1e-6), ("min", 60.0)]
REFUSED = ["blorp", "furlongsperweek", "m^^2", "xyz/V", "3 apples"]


@pytest.mark.parametrize(("unit", "working", "factor"), ACCEPTED)
def test_every_header_unit_is_parsed_and_converted_to_its_working_unit(tmp_path, unit,
                                                                       working, factor):
    t, u, y = _signals()
    (rec,) = load(_write(tmp_path / "d.csv", ["t [s]", "u [V]", f"y [{unit}]"], [t, u, y]))
    assert rec.units["y"] == working
    np.testing.assert_allclose(rec.y, y * factor, rtol=1e-12)
    notes = rec.metadata.get("unit_conversions", ())
    assert (f"column 'y [{unit}]' (y): {unit} -> {working}, x {factor:g}" in notes) == (
        factor != 1.0)


@pytest.mark.parametrize(("unit", "factor"), TIMES)
def test_time_units_are_converted_to_seconds(tmp_path, unit, factor):
    t, u, y = _signals()
    (rec,) = load(_write(tmp_path / "d.csv", [f"Time [{unit}]", "u [V]", "y [um]"],
                         [t / factor, u, y]))
    assert rec.units["t"] == "s"
    np.testing.assert_allclose(rec.t, t, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("unit", REFUSED)
def test_an_unparsable_unit_is_refused_naming_file_column_and_unit(tmp_path, unit):
    t, u, y = _signals()
    path = _write(tmp_path / "odd.csv", ["t [s]", "u [V]", f"Output [{unit}]"], [t, u, y])
    with pytest.raises(DataError) as exc:
        load(path)
    text = str(exc.value)
    assert str(path) in text and f"column 'Output [{unit}]' (y)" in text
    assert f"unknown unit {unit!r}" in text
    # the same unit from the units argument or a sidecar is refused the same way
    plain = _write(tmp_path / "plain.csv", ["t", "u", "y"], [t, u, y])
    with pytest.raises(DataError, match=r"plain\.csv: line 1 \(header\), column 'y', unit "
                       r"declared in the units argument: unknown unit "
                       + re.escape(repr(unit))):
        load(plain, units={"y": unit})


def test_a_time_column_not_in_time_units_is_refused_in_words(tmp_path):
    t, u, y = _signals()
    path = _write(tmp_path / "tv.csv", ["t [V]", "u [V]", "y [um]"], [t, u, y])
    with pytest.raises(DataError, match=r"tv\.csv: line 1 \(header\), column 't \[V\]' "
                                        r"\(t\): the time must have a unit of time .*got 'V'"
                                        r", dimension voltage"):
        load(path)


def test_sidecar_and_argument_units_are_converted_like_header_units(tmp_path):
    import json

    t, u, y = _signals()
    plain = _write(tmp_path / "plain.csv", ["t", "u", "y"], [t * 1e3, u * 1e3, y * 1e3])
    (rec,) = load(plain, units={"t": "ms", "u": "mV", "y": "nm"})
    for got, want in ((rec.t, t), (rec.u, u), (rec.y, y)):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)
    assert dict(rec.units) == {"t": "s", "u": "V", "y": "um"}
    assert rec.metadata["unit_conversions"] == (
        "column 't': ms (the units argument) -> s, x 0.001",
        "column 'u': mV (the units argument) -> V, x 0.001",
        "column 'y': nm (the units argument) -> um, x 0.001")
    side = tmp_path / "side.csv"
    side.write_text(plain.read_text())
    (tmp_path / "side.json").write_text(json.dumps({"units": {"t": "ms", "u": "mV",
                                                              "y": "nm"}}))
    (rec2,) = load(side)
    assert dict(rec2.units) == dict(rec.units)
    np.testing.assert_array_equal(rec2.y, rec.y)
    # a header unit and a declared one agree by pint equality (um and µm are one unit)
    head = _write(tmp_path / "head.csv", ["t [s]", "u [V]", "y [um]"], [t, u, y])
    assert np.array_equal(load(head, units={"y": "µm"})[0].y, y)
    with pytest.raises(DataError, match=r"head\.csv: line 1 \(header\), column 'y \[um\]' "
                                        r"\(y\): the header says 'um', the declared unit of "
                                        r"'y' is 'nm'"):
        load(head, units={"y": "nm"})


def test_a_file_and_its_twin_in_other_units_read_and_score_the_same(tmp_path):
    # an MR damper: displacement input, force output; cm/kN/ms against m/N/s
    t, u, y = _signals(n=600, fs=750.0, f=5.0)
    x_m, f_n = 0.01 * (u - 60) / 50, 1e3 * y   # metres, newtons
    scaled = _write(tmp_path / "scaled.csv", ["t [ms]", "x [cm]", "F [kN]"],
                    [t * 1e3, x_m * 1e2, f_n * 1e-3])
    twin = _write(tmp_path / "twin.csv", ["t [s]", "x [m]", "F [N]"], [t, x_m, f_n])
    a = load(scaled, columns={"u": "x", "y": "F"})[0]
    b = load(twin, columns={"u": "x", "y": "F"})[0]
    assert dict(a.units) == dict(b.units) == {"t": "s", "u": "um", "y": "N"}
    for got, want, exact in ((a.t, b.t, t), (a.u, b.u, x_m * 1e6), (a.y, b.y, f_n)):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(got, exact, rtol=1e-12, atol=1e-15)
    post_a, post_b = Posterior(Dataset([a]), "pi_play"), Posterior(Dataset([b]), "pi_play")
    assert post_a.space.all_names == post_b.space.all_names
    z = post_b.space.sample_prior(np.random.default_rng(0), 6)
    lp_a, lp_b = post_a.log_prob_batch(z), post_b.log_prob_batch(z)
    assert np.isfinite(lp_b).sum() >= 3
    np.testing.assert_allclose(lp_a, lp_b, rtol=1e-9)
    # and the parameters are labelled in the data's units
    assert {p.unit for p in post_a.space.params if p.name == "w"} == {"N/um"}
    # the whole fit: the same seed samples the same posterior from the two files (the
    # arrays differ in the last bits only, which no accept/reject decision resolves)
    from bayeshyst.inference.fit import fit_model
    from bayeshyst.inference.settings import SamplerSettings

    settings = SamplerSettings(seed=5, max_steps=300, first_chunk=100)
    fits = [fit_model(Dataset([r]), "pi_play(n_operators=4)", sampler=settings)
            for r in (a, b)]
    for pa, pb in zip(*(f.sampling.summary() for f in fits), strict=True):
        assert pa.label == pb.label and pa.unit == pb.unit
        assert abs(pa.mean - pb.mean) <= 1e-6 * pb.sd and pa.sd == pytest.approx(pb.sd,
                                                                                  rel=1e-6)


def test_a_file_without_units_is_unknown_and_its_parameters_never_say_um(tmp_path):
    t, u, y = _signals()
    path = _write(tmp_path / "bare.csv", ["t", "u", "y"], [t, 0.01 * u, 1e-3 * y])
    (rec,) = load(path)
    assert dict(rec.units) == {"t": "s", "u": UNKNOWN, "y": UNKNOWN}
    assert rec.metadata["unit_conversions"] == ("column 't': no unit given, s assumed",)
    np.testing.assert_array_equal(rec.y, 1e-3 * y)  # nothing converted
    space = Posterior(Dataset([rec]), "pi_play").space
    units = [p.unit for p in (*space.params, *space.fixed_params)]
    assert units and not any("um" in (unit or "") for unit in units)
    assert {p.unit for p in space.params if p.name in ("w", "noise.sigma")} == {
        "unknown/unknown", "unknown"}
    # a magnet's field in T against a field strength in A/m: the gain is T per A/m
    mag = _write(tmp_path / "magnet.csv", ["t", "H [A/m]", "B [T]"], [t, 1e3 * u, 1e-2 * y])
    (m,) = load(mag, columns={"u": "H [A/m]", "y": "B [T]"})
    w = Posterior(Dataset([m]), "pi_play").space["w"]
    assert w.unit == "T/(A/m)"


def test_the_bundled_demo_data_read_as_volts_and_micrometres():
    from pathlib import Path

    root = Path(__file__).resolve().parents[1] / "data"
    for name in ("virtual_minor_loops.csv", "virtual_multifreq.csv", "virtual_steps.csv"):
        data = load(root / name)
        assert {tuple(sorted(r.units.items())) for r in data} == {
            (("t", "s"), ("u", "V"), ("y", "um"))}, name
        assert all("unit_conversions" not in r.metadata for r in data)
        assert plausibility(data) == [], name


def test_working_units_are_one_frozen_mapping():
    assert WORKING_UNITS["length"] == "um" and WORKING_UNITS["voltage"] == "V"
    assert WORKING_UNITS["magnetic flux density"] == "T"
    assert WORKING_UNITS["magnetic field strength"] == "A/m"
    with pytest.raises(TypeError):
        WORKING_UNITS["length"] = "m"  # type: ignore[index]


# --------------------------------------------------------------------- convert_units
def _record(units, name="r"):
    t, u, y = _signals(n=50)
    return Record(t, u, y, units=units, name=name)


def test_convert_units_round_trips_and_converts_by_pint_factors():
    rec = _record({"t": "s", "u": "V", "y": "um"})
    mm = convert_units(rec, {"t": "ms", "u": "kV", "y": "mm"})
    assert dict(mm.units) == {"t": "ms", "u": "kV", "y": "mm"}
    np.testing.assert_allclose(mm.t, rec.t * 1e3, rtol=1e-15)
    np.testing.assert_allclose(mm.u, rec.u * 1e-3, rtol=1e-15)
    np.testing.assert_allclose(mm.y, rec.y * 1e-3, rtol=1e-15)
    back = convert_units(mm, {"t": "s", "u": "V", "y": "µm"})
    for a in ("t", "u", "y"):
        np.testing.assert_allclose(getattr(back, a), getattr(rec, a), rtol=1e-14)
    assert convert_units(rec, {"y": "um"}) is rec  # nothing to do
    # a Dataset: every record, the name kept; CGS units by their SI definitions
    ds = Dataset([_record({"u": "A/m", "y": "T"}, "a"), _record({"u": "A/m", "y": "T"}, "b")],
                 name="magnet")
    cgs = convert_units(ds, {"u": "Oe", "y": "G"})
    assert cgs.name == "magnet" and [dict(r.units) for r in cgs] == [
        {"t": "s", "u": "Oe", "y": "G"}] * 2
    np.testing.assert_allclose(cgs[0].u, ds[0].u * 4 * math.pi / 1000, rtol=1e-12)
    np.testing.assert_allclose(cgs[1].y, ds[1].y * 1e4, rtol=1e-12)
    # offset units, which pint handles: degC -> K
    hot = convert_units(_record({"y": "degC"}), {"y": "K"})
    np.testing.assert_allclose(hot.y, _record({"y": "degC"}).y + 273.15, rtol=1e-14)


def test_convert_units_refuses_other_dimensions_and_unknown_units():
    rec = _record({"t": "s", "u": "V", "y": "um"}, name="bench")
    with pytest.raises(DataError, match=r"record 'bench', role 'y': cannot convert 'um' "
                                        r"\(length\) to 'N' \(force\): not the same "
                                        r"dimension"):
        convert_units(rec, {"y": "N"})
    with pytest.raises(DataError, match=r"record 'bench', role 't': cannot convert 's' "
                                        r"\(time\) to 'V' \(voltage\)"):
        convert_units(rec, {"t": "V"})
    bare = _record({"u": UNKNOWN, "y": UNKNOWN}, name="bare")
    with pytest.raises(DataError, match=r"record 'bare', role 'y': cannot convert "
                                        r"'unknown' to 'um': one of them is unknown"):
        convert_units(bare, {"y": "um"})
    with pytest.raises(DataError, match=r"record 'bench', role 'u': cannot convert 'V' to "
                                        r"'unknown'"):
        convert_units(rec, {"u": UNKNOWN})
    assert convert_units(bare, {"u": UNKNOWN, "y": UNKNOWN}) is bare
    with pytest.raises(DataError, match=r"unknown role 'x'"):
        convert_units(rec, {"x": "um"})
    with pytest.raises(DataError, match=r"record 'bench', role 'y', target unit: unknown "
                                        r"unit 'blorp'"):
        convert_units(rec, {"y": "blorp"})
    with pytest.raises(DataError, match=r"'counts' to '%'.*label converts only to itself"):
        convert_units(_record({"y": "counts"}), {"y": "%"})


# ---------------------------------------------------------------------------- --units
def test_cli_units_option_is_parsed_and_passed_to_the_reader(tmp_path):
    t, u, y = _signals()
    path = _write(tmp_path / "bh.csv", ["t", "u", "y"], [t, u, y])
    parser = build_parser()
    for command in ("fit", "compensate", "diagnose", "compare", "report"):
        extra = ["--model", "pi_play"] if command in ("fit", "compensate", "diagnose") \
            else ["--models", "pi_play"]
        args = parser.parse_args([command, str(path), *extra, "--units", "u=A/m, y=mT",
                                  "--quiet"])
        assert args.units == {"u": "A/m", "y": "mT"}, command
    args = parser.parse_args(["fit", str(path), "--model", "pi_play", "--quiet",
                              "--units", "u=A/m,y=mT"])
    (rec,) = load_data(args)
    assert rec.units["u"] == "A/m" and rec.units["y"] == "T"
    np.testing.assert_allclose(rec.y, y * 1e-3, rtol=1e-12)
    assert parser.parse_args(["fit", str(path), "--model", "pi_play"]).units is None


@pytest.mark.parametrize(("bad", "message"), [
    ("z=mT", "unknown role 'z'"), ("y", "ROLE=UNIT"), ("y=blorp", "unknown unit 'blorp'"),
    ("y=mT,y=T", "given twice"),
])
def test_cli_units_option_refuses_bad_pairs(tmp_path, capsys, bad, message):
    with pytest.raises(SystemExit) as exc:
        build_parser().parse_args(["fit", str(tmp_path / "d.csv"), "--model", "pi_play",
                                   "--units", bad])
    assert exc.value.code == 2 and message in capsys.readouterr().err


# ------------------------------------------------------------------------ plausibility
def _rec(t, u, y, units, frequency=None, name="r"):
    meta = {} if frequency is None else {"frequency_hz": frequency}
    return Record(t, u, y, units=units, metadata=meta, name=name)


def test_plausibility_is_quiet_on_data_that_are_consistent():
    rng = np.random.default_rng(1)
    # a quasi-static magnet measurement: 300 points at 0.34 Hz, two cycles of H
    t = np.arange(300) / 0.34
    f = 2 / (300 / 0.34)
    h = 8e3 * np.sin(2 * np.pi * f * t)
    magnet = _rec(t, h, 1.2 * np.tanh(h / 3e3), {"t": "s", "u": "A/m", "y": "T"}, f, "magnet")
    # a creep hold: 1 400 s at 3.6 Hz, a step then constant input
    t = np.arange(int(1400 * 3.6)) / 3.6
    step = np.where(t > 5, 100.0, 0.0)
    creep = _rec(t, step, 0.2 * step * (1 + 0.01 * np.log1p(t)), {"t": "s", "u": "V", "y": "um"},
                 name="creep")
    # a B(H) loop of 129 samples, one cycle at 0.05 Hz
    t = np.arange(129) / (0.05 * 128)
    h = 5e3 * np.sin(2 * np.pi * 0.05 * t)
    loop = _rec(t, h, np.tanh(h / 2e3), {"t": "s", "u": "A/m", "y": "T"}, 0.05, "bh")
    # a damper at 750 Hz: displacement in m, force in N, 5 Hz
    t = np.arange(1500) / 750.0
    x = 0.01 * np.sin(2 * np.pi * 5 * t)
    damper = _rec(t, x, 800 * np.tanh(300 * x) + rng.normal(0, 1, t.size),
                  {"t": "s", "u": "m", "y": "N"}, 5.0, "damper")
    assert plausibility(Dataset([magnet, creep, loop, damper])) == []


def test_plausibility_flags_too_few_samples_per_cycle_and_jitter():
    t = np.arange(200) / 50.0
    u = np.sin(2 * np.pi * 10 * t)
    (warning,) = plausibility([_rec(t, u, 2 * u, {"t": "s", "u": "V", "y": "um"}, 10.0, "s")])
    assert warning.startswith("s: 5 samples per cycle of the 10 Hz excitation (step 0.02 s)")
    # jittered steps: uniform +-20 % around 1 ms, sd 11.5 % of the median
    rng = np.random.default_rng(2)
    steps = 1e-3 * (1 + 0.2 * rng.uniform(-1, 1, 999))
    t = np.concatenate([[0.0], np.cumsum(steps)])
    u = np.sin(2 * np.pi * 5 * t)
    (warning,) = plausibility([_rec(t, u, u, {"t": "s", "u": "V", "y": "um"}, 5.0, "j")])
    spread = 100 * np.std(steps) / np.median(steps)
    assert warning.startswith(f"j: irregular sampling: time steps from {steps.min():.4g} to "
                              f"{steps.max():.4g} s (median {np.median(steps):.4g}, sd "
                              f"{spread:.3g} % of it)")
    assert 10 < spread < 13


def test_plausibility_flags_a_frequency_the_time_stamps_contradict():
    # 5 Hz at 5 kHz, written in s but declared ms (read as such): 200 000 Hz sampling
    # looks fine, but the input cycles 1000 x faster than frequency_hz says
    t = np.arange(3000) / 5000.0
    u = np.sin(2 * np.pi * 5 * t)
    rec = _rec(t * 1e-3, u, u, {"t": "s", "u": "V", "y": "um"}, 5.0, "fast")
    (warning,) = plausibility([rec])
    assert "frequency_hz 5 Hz contradicts the sampling" in warning
    assert "its input cycles at 5000 Hz by the time stamps" in warning
    assert "time in s read as ms?" in warning


def test_a_compound_input_unit_is_parenthesised_in_derived_parameter_units():
    # T/A/m would read as T m / A: a unit of the data that has a slash is one factor
    import bayeshyst.models as M
    from bayeshyst.models.base import DataScales

    field = DataScales(-1.0, 1.0, -1.0, 1.0, "A/m", "T")
    piezo = DataScales(-1.0, 1.0, -1.0, 1.0, "V", "um")
    assert M.get("pi_play").param_space(field)["p0"].unit == "T/(A/m)"
    assert M.get("pi_play").param_space(piezo)["p0"].unit == "um/V"
    assert M.get("bouc_wen").param_space(field)["beta"].unit == "1/((A/m) T^(n-1))"
    assert M.get("bouc_wen").param_space(piezo)["beta"].unit == "1/(V um^(n-1))"
    assert M.get("pi_rate").param_space(field)["udot0"].unit == "(A/m)/s"
    assert M.get("mbw").param_space(field)["lam"].unit == "1/(A/m)"


def test_plausibility_flags_a_broadband_input_that_reaches_nyquist(tmp_path):
    # band-limited noise classified from its own spectrum: 2-40 Hz at 1 kHz is quiet,
    # 2-450 Hz (90 % of the 500 Hz Nyquist frequency) is cautioned, naming the numbers
    from bayeshyst.data import label_frequencies

    n, fs = 8000, 1000.0
    rng = np.random.default_rng(4)
    f = np.fft.rfftfreq(n, 1 / fs)
    records = []
    for name, hi in (("low", 40.0), ("high", 450.0)):
        spec = np.fft.rfft(rng.normal(size=n))
        spec[(f < 2.0) | (f > hi)] = 0
        u = np.fft.irfft(spec, n)
        records.append(Record(np.arange(n) / fs, u, 0.3 * u, name=name,
                              units={"t": "s", "u": "V", "y": "um"}))
    data = label_frequencies(Dataset(records, name="d"))
    band = data[1].band_hz
    assert band[1] > 0.8 * 500.0 and data[0].band_hz[1] < 0.8 * 500.0
    (warning,) = plausibility(data)
    assert warning.startswith(f"high: the input's band reaches {band[1]:.4g} Hz, "
                              f"{100 * band[1] / 500.0:.0f} % of the Nyquist frequency 500 Hz")
