"""Readers and writers: exact round trips, sidecars, and the corpus of malformed files."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np
import pytest
import scipy.io
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.io import load, read_csv, read_mat, read_npz
from bayeshyst.data.parsing import read_table, sidecar_path
from bayeshyst.data.record import MAGNITUDE_MAX, RESOLUTION_MIN, SPAN_MIN, Record
from bayeshyst.data.writers import write_csv, write_npz
from bayeshyst.errors import DataError

BAD = Path(__file__).parent / "data" / "bad"


def _record(n: int = 20, name: str = "r", **kw: object) -> Record:
    t = np.arange(n) * 0.01
    u = np.sin(2 * np.pi * t)
    return Record(t, u, 0.5 * u + 0.1, name=name, **kw)


def _bits(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a).tobytes()


def _assert_identical(a: Dataset, b: Dataset) -> None:
    assert a == b
    for ra, rb in zip(a, b, strict=True):
        for col in ("t", "u", "y"):  # bitwise: -0.0 vs 0.0 and last-ulp changes count
            assert _bits(getattr(ra, col)) == _bits(getattr(rb, col))


# ----------------------------------------------------------------------- round trips
_finite = st.floats(min_value=-1e300, max_value=1e300, allow_nan=False, width=64)


@st.composite
def records(draw: st.DrawFn, name: str = "rec") -> Record:
    n = draw(st.integers(4, 40))
    t0 = draw(st.floats(-1e6, 1e6, allow_nan=False))
    steps = draw(st.lists(st.floats(1e-9, 1e3), min_size=n - 1, max_size=n - 1))
    t = t0 + np.concatenate([[0.0], np.cumsum(steps)])
    if not (np.diff(t) > 0).all():  # rounding can merge tiny steps at large t0
        t = t0 + np.arange(n, dtype=float)
    u = np.array(draw(st.lists(_finite, min_size=n, max_size=n)))
    y = np.array(draw(st.lists(_finite, min_size=n, max_size=n)))
    seg = draw(st.none() | st.lists(st.integers(-5, 5), min_size=n, max_size=n))
    meta = {
        "source": "synthetic",
        "frequency_hz": draw(st.none() | st.floats(1e-3, 1e4)),
        "amplitude": draw(_finite),
        "note": draw(st.text(max_size=10)),
        "tags": draw(st.lists(st.integers(), max_size=3)),
    }
    return Record(
        t, u, y, segment=seg, warmup=draw(st.integers(0, n - 2)), metadata=meta,
        # units the readers keep as they are (a working unit, a unit without one,
        # unknown) come back exactly; nm is converted to um (tests/test_units_pint.py)
        units={"y": draw(st.sampled_from(["um", "N", "mm/s", "unknown"]))}, name=name,
    )


@st.composite
def datasets(draw: st.DrawFn) -> Dataset:
    k = draw(st.integers(1, 3))
    return Dataset([draw(records(name=f"rec{i}")) for i in range(k)], name="ds")


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(ds=datasets())
@pytest.mark.parametrize(("writer", "reader", "suffix"), [
    (write_csv, read_csv, ".csv"), (write_npz, read_npz, ".npz"),
])
def test_round_trip_is_exact(tmp_path, writer, reader, suffix, ds):
    # any finite values, constant or beyond what a fit handles: fittable=False
    path = writer(ds, tmp_path / f"data{suffix}")
    _assert_identical(reader(path, fittable=False), ds)
    _assert_identical(load(path, fittable=False), ds)


def test_round_trip_single_record_and_source_default(tmp_path):
    rec = _record(warmup=3, metadata={"frequency_hz": 2.5})
    path = write_csv(rec, tmp_path / "one.csv")
    back = read_csv(path)
    assert len(back) == 1 and back.name == "r"
    assert back[0].metadata["source"] == str(path)  # provenance filled in when absent
    assert back[0].with_(metadata=rec.metadata) == rec


def test_written_files_have_normal_permissions_and_no_temp_left(tmp_path):
    write_csv(_record(), tmp_path / "a.csv")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "a.json"]
    umask = os.umask(0)
    os.umask(umask)
    assert (tmp_path / "a.csv").stat().st_mode & 0o777 == 0o666 & ~umask


def test_failed_write_leaves_nothing(tmp_path):
    bad = _record(metadata={"obj": object()})  # not JSON-serialisable
    with pytest.raises(DataError, match=r"bad\.csv: metadata is not JSON-serialisable"):
        write_csv(bad, tmp_path / "bad.csv")
    assert list(tmp_path.iterdir()) == []


def test_overwrite_is_atomic_and_keeps_old_file_on_failure(tmp_path):
    path = write_csv(_record(), tmp_path / "a.csv")
    before = path.read_bytes()
    with pytest.raises(DataError):
        write_csv(_record(metadata={"obj": object()}), path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "a.json"]


def test_write_refuses_json_suffix(tmp_path):
    with pytest.raises(DataError, match=r"x\.json: a data file cannot have suffix \.json"):
        write_csv(_record(), tmp_path / "x.json")


# --------------------------------------------------------------------------- reading
def test_column_mapping_delimiters_and_ignored_columns(tmp_path):
    rows = "\n".join(f"{k * 0.1}\t{k}\t{2 * k}\t9\tok" for k in range(5))
    path = tmp_path / "m.txt"
    path.write_text("time\tvolt\tdisp\textra\tnote\n" + rows + "\n")
    rec = load(path, columns={"t": "time", "u": "volt", "y": "disp"})[0]
    np.testing.assert_array_equal(rec.y, 2 * np.arange(5.0))
    # a numeric column is kept as a covariate, a text column is left out and listed
    assert rec.metadata["ignored_columns"] == ("note",)
    np.testing.assert_array_equal(rec.covariates["extra"], np.full(5, 9.0))
    ws = tmp_path / "w.txt"
    ws.write_text("t u y\n" + "\n".join(f"  {k}   {k} {k}" for k in range(4)) + "\n")
    assert load(ws)[0].n == 4
    semi = read_csv(BAD / "semicolon.csv")  # detected when not forced to ','
    assert semi[0].n == 4


def test_sidecar_supplies_metadata_units_columns_and_explicit_args_win(tmp_path):
    path = tmp_path / "d.csv"
    path.write_text("time,u,y\n" + "\n".join(f"{k},{k % 2},{k}" for k in range(6)) + "\n")
    sidecar_path(path).write_text(json.dumps({
        "name": "bench", "columns": {"t": "time"}, "warmup": 2,
        "metadata": {"frequency_hz": 3, "temperature_c": 21.5}, "units": {"y": "nm"},
    }))
    ds = read_csv(path)
    rec = ds[0]
    # a sidecar unit is converted like a header unit: nm -> um, noted
    assert ds.name == "bench" and rec.warmup == 2 and rec.units["y"] == "um"
    np.testing.assert_allclose(rec.y, np.arange(6.0) * 1e-3, rtol=1e-15)
    assert rec.metadata["unit_conversions"][-1].endswith("nm (sidecar "
                                                         f"{sidecar_path(path)}, key 'units')"
                                                         " -> um, x 0.001")
    assert rec.frequency_hz == 3.0 and rec.metadata["temperature_c"] == 21.5
    over = read_csv(path, warmup=0, metadata={"frequency_hz": 4.0}, units={"y": "um"}, name="x")
    assert over.name == "x" and over[0].warmup == 0 and over[0].frequency_hz == 4.0
    assert over[0].units["y"] == "um" and over[0].metadata["temperature_c"] == 21.5
    np.testing.assert_array_equal(over[0].y, np.arange(6.0))  # the argument wins


def test_frequency_column_splits_contiguous_blocks(tmp_path):
    lines = ["t,u,y,frequency_hz"]
    for f, n in ((1.0, 6), (2.5, 5), (1.0, 4)):
        lines += [f"{k * 0.1},{k % 3},{k},{f}" for k in range(n)]
    path = tmp_path / "sweep.csv"
    path.write_text("\n".join(lines) + "\n")
    ds = read_csv(path)
    assert [r.n for r in ds] == [6, 5, 4]
    assert [r.frequency_hz for r in ds] == [1.0, 2.5, 1.0]
    assert ds.names == ("sweep@1Hz", "sweep@2.5Hz", "sweep@1Hz#2")
    assert ds.frequencies == (1.0, 2.5)
    assert len(ds.by_frequency()[1.0]) == 2


def test_read_mat_flattens_vectors(tmp_path):
    t = np.arange(6) * 0.1
    scipy.io.savemat(tmp_path / "m.mat", {"t": t[:, None], "u": t[None, :], "y": 2 * t})
    rec = read_mat(tmp_path / "m.mat")[0]
    np.testing.assert_array_equal(rec.u, t)
    assert load(tmp_path / "m.mat")[0] == rec


def test_csv_reader_handles_50k_rows(tmp_path):
    # correctness only: DESIGN.md forbids wall-clock assertions (speed lives in benchmarks/)
    n = 50_000
    t = np.arange(n) / 5000.0
    rec = Record(t, np.sin(t), np.cos(t), name="big")
    assert read_csv(write_csv(rec, tmp_path / "big.csv"))[0] == rec.with_(
        metadata={"source": str(tmp_path / "big.csv")}
    )


def test_read_table_headerless_reports_lines(tmp_path):
    path = tmp_path / "h.dat"
    path.write_text("1\t2\n\n3\tx\n")
    table = read_table(path, header=False)
    assert table.names == ("col0", "col1") and list(table.lines) == [1, 3]
    with pytest.raises(DataError, match=r"h\.dat: line 3, column 'col1': expected a number"):
        table.floats("col1")


# -------------------------------------------------------------------- bad-file corpus
# (file in tests/data/bad, reader options, regex pinning file, column and row)
CORPUS = [
    ("missing_column.csv", {}, r"missing_column\.csv: line 1 \(header\), column 'y': missing"),
    ("non_numeric.csv", {}, r"non_numeric\.csv: line 4, column 'u': expected a number, got 'abc'"),
    ("nan_cell.csv", {}, r"nan_cell\.csv: line 5, column 'y': expected a finite number, got 'nan'"),
    ("inf_cell.csv", {},
     r"inf_cell\.csv: line 3, column 'u': expected a finite number, got '-inf'"),
    ("empty_cell.csv", {}, r"empty_cell\.csv: line 6, column 'u': expected a number, got an empty"),
    ("duplicate_time.csv", {},
     r"duplicate_time\.csv: line 5, column 't': expected time greater than 0\.3 \(line 4\), "
     r"got 0\.3 \(duplicate time\)"),
    ("decreasing_time.csv", {},
     r"decreasing_time\.csv: line 5, column 't': expected time greater than 0\.2 \(line 4\), "
     r"got 0\.15 \(decreasing time\)"),
    ("ragged_row.csv", {},
     r"ragged_row\.csv: line 4, column 4 \(extra field\): ragged row, expected 3 fields .*got 4"),
    ("ragged_short.csv", {},
     r"ragged_short\.csv: line 5, column 'y' \(missing\): ragged row, expected 3 fields.*got 2"),
    ("empty.csv", {}, r"empty\.csv: file is empty; expected a header line"),
    ("blank_lines.csv", {}, r"blank_lines\.csv: file is empty"),
    ("header_only.csv", {}, r"header_only\.csv: line 1: header only, no data rows; expected at"),
    ("wrong_delimiter.csv", {},
     r"wrong_delimiter\.csv: line 1: header 't\|u\|y' splits into one column .*'\|': wrong "
     r"delimiter\?"),
    ("semicolon.csv", {"delimiter": ","},
     r"semicolon\.csv: line 1: header 't;u;y' splits into one column with ','.*';': wrong "),
    ("decimal_comma.csv", {},
     r"decimal_comma\.csv: line 3, column 't': expected a number, got '0,1' \(decimal comma\?"),
    ("too_few_samples.csv", {},
     r"too_few_samples\.csv: rows line 2 to line 4, column 't': too few samples, expected at "
     r"least 4 \(MIN_SAMPLES\), got 3"),
    ("duplicate_header.csv", {},
     r"duplicate_header\.csv: line 1, column 'u': expected unique column names"),
    ("segment_fraction.csv", {},
     r"segment_fraction\.csv: line 3, column 'segment': expected an integer label, got '1\.5'"),
    ("frequency_nonpositive.csv", {},
     r"frequency_nonpositive\.csv: line 2, column 'frequency_hz': expected a positive "
     r"frequency, got 0\.0"),
    ("frequency_block_short.csv", {},
     r"frequency_block_short\.csv: rows line 7 to line 8, column 't': too few samples"),
    ("comment_lines_nan.csv", {},
     r"comment_lines_nan\.csv: line 7, column 'y': expected a finite number, got 'NaN'"),
    ("warmup_too_large.csv", {},
     r"warmup_too_large\.csv: rows line 2 to line 6: warmup: expected an integer in 0\.\.3 .*"
     r"got 9"),
    ("bad_sidecar_syntax.csv", {},
     r"bad_sidecar_syntax\.json: line 3, column 1: invalid JSON sidecar"),
    ("sidecar_wrong_type.csv", {},
     r"sidecar_wrong_type\.json: key 'warmup': expected a non-negative integer, got 'ten'"),
    ("sidecar_units_type.csv", {},
     r"sidecar_units_type\.json: key 'units\.y': expected a string, got 5 \(int\)"),
    ("sidecar_unknown_key.csv", {}, r"sidecar_unknown_key\.json: key 'metdata': unknown key"),
    ("sidecar_record_type.csv", {},
     r"sidecar_record_type\.json: key 'records\[0\]\.warmup': expected a non-negative integer"),
    ("sidecar_not_object.csv", {},
     r"sidecar_not_object\.json: expected a JSON object at top level, got list"),
    ("sidecar_bad_mapping.csv", {},
     r"sidecar_bad_mapping\.csv: line 1 \(header\), column 'volt' \(role 'u'\): missing"),
    ("sidecar_unknown_role.csv", {},
     r"sidecar_unknown_role\.json: key 'columns': unknown column role 'x'"),
    ("sidecar_frequency_type.csv", {},
     r"sidecar_frequency_type\.json: key 'metadata\.frequency_hz': expected a positive number"),
    ("sidecar_records_count.csv", {},
     r"sidecar_records_count\.json: key 'records': expected 1 entries .* got 2"),
    ("missing_column.csv", {"columns": {"y": "u"}},
     r"missing_column\.csv: line 1 \(header\), column 'u': mapped to several roles"),
    ("semicolon.csv", {"columns": {"voltage": "u"}},
     r"semicolon\.csv: columns argument: unknown column role 'voltage'"),
    ("semicolon.csv", {"columns": {"u": "volt"}},
     r"semicolon\.csv: line 1 \(header\), column 'volt' \(role 'u'\): missing"),
]


def test_corpus_has_at_least_22_committed_files():
    assert len(list(BAD.iterdir())) >= 22


@pytest.mark.parametrize(("name", "options", "pattern"), CORPUS,
                         ids=[f"{c[0]}-{i}" for i, c in enumerate(CORPUS)])
def test_bad_file_message(name, options, pattern):
    with pytest.raises(DataError, match=pattern) as info:
        load(BAD / name, **options)
    assert str(BAD) in str(info.value)  # the full path, not just the name


def _npz(path: Path, **arrays: np.ndarray) -> Path:
    np.savez(path, **arrays)
    return path


T5 = np.arange(5) * 0.1


def _make_generated(tmp: Path, name: str) -> Path:
    """Binary fixtures, generated rather than committed."""
    p = tmp / name
    if name == "latin1.csv":
        p.write_bytes(b"t,u,y\n0,1,2\n1,\xe9,3\n")
    elif name == "garbage.csv":
        p.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR")
    elif name == "nul.csv":
        p.write_bytes(b"t,u,y\n0,1\x00,2\n")
    elif name == "latin1_sidecar.csv":
        p.write_text("t,u,y\n0,0,0\n1,1,1\n2,0,0\n3,1,1\n")
        (tmp / "latin1_sidecar.json").write_bytes(b'{"name": "caf\xe9"}')
    elif name == "object.npz":
        _npz(p, t=T5, u=np.array([1, "a", None, 2, 3], dtype=object), y=T5)
    elif name == "missing_key.npz":
        _npz(p, t=T5, u=T5)
    elif name == "length_mismatch.npz":
        _npz(p, t=T5, u=T5[:4], y=T5)
    elif name == "matrix.npz":
        _npz(p, t=T5, u=np.zeros((5, 2)), y=T5)
    elif name == "nan.npz":
        _npz(p, t=T5, u=T5, y=np.array([0, 1, 2, np.nan, 4.0]))
    elif name == "strings.npz":
        _npz(p, t=T5, u=np.array(["a"] * 5), y=T5)
    elif name == "decreasing.npz":
        _npz(p, t=np.array([0, 1, 2, 1.5, 3.0]), u=T5, y=T5)
    elif name == "garbage.npz":
        p.write_bytes(b"PK\x03\x04 this is not really a zip archive")
    elif name == "single.npz":
        with p.open("wb") as fh:
            np.save(fh, T5)
    elif name == "matrix.mat":
        scipy.io.savemat(p, {"t": T5, "u": np.zeros((3, 4)), "y": T5})
    elif name == "missing.mat":
        scipy.io.savemat(p, {"t": T5, "y": T5})
    elif name == "char.mat":
        scipy.io.savemat(p, {"t": T5, "u": "hello", "y": T5})
    elif name == "garbage.mat":
        p.write_bytes(b"MATLAB 5.0 MAT-file, nonsense" + b"\x00" * 8)
    elif name == "v73.mat":  # MATLAB -v7.3 header: HDF5 container, version 0x0200
        p.write_bytes(b"MATLAB 7.3 MAT-file".ljust(116) + bytes(8) + b"\x00\x02IM")
    elif name == "headerless.txt":
        p.write_text("".join(f"  {k}.0  {k}.5  {2 * k}.0\n" for k in range(5)))
    elif name == "data.xlsx":
        p.write_bytes(b"PK")
    elif name == "folder.csv":
        p.mkdir()
    elif name != "missing.csv":
        raise AssertionError(name)
    return p


GENERATED = [
    ("latin1.csv", r"latin1\.csv: line 3, byte offset 14: expected a UTF-8 text file, got "
                   r"undecodable byte 0xe9"),
    ("garbage.csv", r"garbage\.csv: line 1, byte offset 0: expected a UTF-8 text file, got "
                    r"undecodable byte 0x89"),
    ("nul.csv", r"nul\.csv: line 2: expected a text file, got a NUL character"),
    ("latin1_sidecar.csv", r"latin1_sidecar\.json: line 1, byte offset 13: expected a UTF-8 "
                           r"JSON sidecar"),
    ("object.npz", r"object\.npz: array 'u': expected a numeric array, got an object array"),
    ("missing_key.npz", r"missing_key\.npz: arrays in file, array 'y': missing"),
    ("length_mismatch.npz", r"length_mismatch\.npz: array 'u': expected 5 samples \(the length "
                            r"of array 't'\), got 4"),
    ("matrix.npz", r"matrix\.npz: array 'u': expected a vector .* got shape \(5, 2\) \(a 2-D"),
    ("nan.npz", r"nan\.npz: index 3 \(0-based\), array 'y': expected a finite number, got nan"),
    ("strings.npz", r"strings\.npz: array 'u': expected a real numeric array, got dtype <U1"),
    ("decreasing.npz", r"decreasing\.npz: index 3 \(0-based\), array 't': expected time greater "
                       r"than 2\.0 \(index 2 \(0-based\)\), got 1\.5 \(decreasing time\)"),
    ("garbage.npz", r"garbage\.npz: expected a NumPy \.npz archive"),
    ("single.npz", r"single\.npz: expected a \.npz archive of named arrays, got a single \.npy"),
    ("matrix.mat", r"matrix\.mat: variable 'u': expected a vector .* got shape \(3, 4\) \(a 2-D "
                   r"matrix\)"),
    ("missing.mat", r"missing\.mat: variables in file, variable 'u': missing"),
    ("char.mat", r"char\.mat: variable 'u': expected a real numeric array, got dtype <U5"),
    ("garbage.mat", r"garbage\.mat: expected a MATLAB \.mat file"),
    ("v73.mat", r"v73\.mat: MATLAB v7\.3 \(HDF5\) file; expected v7 or older"),
    ("headerless.txt", r"headerless\.txt: line 1 \(header\), column '0\.0': expected a header "
                       r"naming the columns \(t,u,y\), got numbers \(headerless file\?"),
    ("data.xlsx", r"data\.xlsx: unknown file suffix '\.xlsx'; expected one of"),
    ("folder.csv", r"folder\.csv: is a directory; expected a data file"),
    ("missing.csv", r"missing\.csv: no such file"),
]


@pytest.mark.parametrize(("name", "pattern"), GENERATED, ids=[g[0] for g in GENERATED])
def test_generated_bad_file_message(tmp_path, name, pattern):
    path = _make_generated(tmp_path, name)
    with pytest.raises(DataError, match=pattern):
        load(path)


def test_every_error_message_is_one_readable_line():
    for name, options, _ in CORPUS:
        with pytest.raises(DataError) as info:
            load(BAD / name, **options)
        message = str(info.value)
        assert "\n" not in message and "np.float64" not in message
        assert re.search(re.escape(name.rsplit(".", 1)[0]), message)


# ---------------------------------------------------------------------- fittable data
def _sine(u_scale: float = 1.0, y_scale: float = 1.0, y_level: float = 0.0,
          name: str = "s", **kw: object) -> Record:
    """A 10 Hz loop: u 5..145 (V), y = 0.2 u + 1 (um), scaled and shifted."""
    t = np.arange(100) * 1e-3
    u = 75 + 70 * np.sin(2 * np.pi * 10 * t)
    return Record(t, u * u_scale, (0.2 * u + 1) * y_scale + y_level, name=name, **kw)


_RANGE = r"supported range \(max\|x\| <= 1e\+50, peak-to-peak >= 1e-50 and >= 1e-09 max\|x\|\)"


@pytest.mark.parametrize(("data", "pattern"), [
    # the scales of issue 17: both fitted to inf or failed inside the sampler
    (_sine(y_scale=1e200), r"column 'y': largest \|value\| 3e\+201 is outside the " + _RANGE
     + "; express it in a larger unit"),
    (_sine(y_scale=1e-300), r"column 'y': peak-to-peak 2\.8e-299 is outside the " + _RANGE
     + "; express it in a smaller unit"),
    (_sine(u_scale=1e60), r"column 'u': largest \|value\| 1\.45e\+62 is outside"),
    (_sine(u_scale=1e-60), r"column 'u': peak-to-peak 1\.4e-58 is outside"),
    (_sine(y_level=1e13), r"column 'y': peak-to-peak 28 is only 2\.8e-12 of its largest "
                          r"\|value\| 1e\+13, outside the " + _RANGE),
])
@pytest.mark.parametrize(("writer", "suffix"), [(write_csv, ".csv"), (write_npz, ".npz")])
def test_magnitudes_outside_the_supported_range_are_refused(tmp_path, data, pattern, writer,
                                                            suffix):
    path = writer(data, tmp_path / f"scaled{suffix}")
    if suffix == ".npz":
        pattern = pattern.replace("column '", "array '")
    with pytest.raises(DataError, match=re.escape(str(path)) + ": " + pattern):
        load(path)
    # the check is the reader's, not the format's: the values themselves round-trip
    back = load(path, fittable=False)[0]
    for col in ("t", "u", "y"):
        assert _bits(getattr(back, col)) == _bits(getattr(data, col))


def test_magnitudes_at_the_edges_of_the_range_are_read(tmp_path):
    t = np.arange(4.0)
    u = np.array([0.0, 1.0, 0.0, 1.0])
    inside = {
        "top": MAGNITUDE_MAX * np.array([0.5, 1.0, 0.5, 1.0]),
        "span": SPAN_MIN * u,
        "resolution": 5e8 + u,  # span / max = 1 / (5e8 + 1) >= 1e-9
    }
    outside = {
        "top": np.nextafter(MAGNITUDE_MAX, np.inf) * np.array([0.5, 1.0, 0.5, 1.0]),
        "span": np.nextafter(SPAN_MIN, 0) * u,
        "resolution": 2e9 + u,  # span / max = 1 / (2e9 + 1) < 1e-9
    }
    assert RESOLUTION_MIN == 1e-9
    for case, y in inside.items():
        path = write_csv(Record(t, u, y, name=case), tmp_path / f"in_{case}.csv")
        assert load(path)[0].y.tolist() == y.tolist()
        path = write_csv(Record(t, u, outside[case], name=case), tmp_path / f"out_{case}.csv")
        with pytest.raises(DataError, match=r"out_" + case + r"\.csv: column 'y': .*outside"):
            load(path)


def test_a_constant_input_or_output_is_refused_naming_file_and_column(tmp_path):
    t = np.arange(6) * 0.1
    path = tmp_path / "hold.csv"
    path.write_text("time,volt,disp\n" + "".join(f"{x},1.0,{k}\n" for k, x in enumerate(t)))
    with pytest.raises(DataError, match=re.escape(str(path)) + r": column 'volt' \(u\): "
                       r"constant \(1\.0 in every sample\); the input must vary"):
        read_csv(path, columns={"t": "time", "u": "volt", "y": "disp"})
    flat = write_npz(Record(t, np.sin(t), np.full(6, -2.5), name="flat"), tmp_path / "f.npz")
    with pytest.raises(DataError, match=re.escape(str(flat)) + r": array 'y': constant "
                       r"\(-2\.5 in every sample\); the output must vary"):
        load(flat)


def test_constant_is_judged_over_the_whole_file(tmp_path):
    # a hold (constant u) next to a loop is data a joint fit can use
    t = np.arange(10) * 0.1
    hold = Record(t, np.full(10, 3.0), np.linspace(0, 1, 10), name="hold")
    path = write_csv(Dataset([hold, _sine(name="loop")], name="d"), tmp_path / "d.csv")
    assert load(path).names == ("hold", "loop")
    same = Dataset([hold, hold.with_(name="again")], name="d")
    with pytest.raises(DataError, match=r"d2\.csv: column 'u': constant \(3\.0"):
        load(write_csv(same, tmp_path / "d2.csv"))


def test_record_errors_name_the_file_when_the_sidecar_names_another_source(tmp_path):
    # the bundled data's sidecars say "source": "virtual actuator"
    path = write_csv(_sine(metadata={"source": "virtual actuator"}), tmp_path / "v.csv")
    with pytest.raises(DataError, match=re.escape(str(path)) + r": the units argument, role "
                       r"'y': expected a unit string, got 3"):
        load(path, units={"y": 3})
    with pytest.raises(DataError, match=re.escape(str(path)) + r": record 's' .*metadata "
                       r"'frequency_hz': expected a positive finite number"):
        load(path, metadata={"frequency_hz": -1.0})


def test_sidecar_frequency_must_be_finite(tmp_path):
    path = write_csv(_sine(metadata={"frequency_hz": 10.0}), tmp_path / "f.csv")
    side = sidecar_path(path)
    side.write_text(side.read_text().replace("10.0", "Infinity"))
    with pytest.raises(DataError, match=re.escape(str(side)) + r": key 'records\[0\]\.metadata"
                       r"\.frequency_hz': expected a positive number or null, got inf"):
        load(path)


def test_covariates_survive_writing_reading_slicing_and_pickling(tmp_path):
    import pickle

    t = np.arange(40) * 1e-3
    temp = 20 + np.arange(40) * 0.1
    rec = Record(t, np.sin(50 * t), np.cos(50 * t), covariates={"temperature_c": temp},
                 name="r")
    path = tmp_path / "c.csv"
    write_csv(Dataset((rec,)), path)
    back = read_csv(path, fittable=False)[0]
    np.testing.assert_allclose(back.covariates["temperature_c"], temp, rtol=1e-15)
    np.testing.assert_array_equal(rec.slice(10, 20).covariates["temperature_c"], temp[10:20])
    assert pickle.loads(pickle.dumps(rec)) == rec
    assert rec != rec.with_(covariates={"temperature_c": temp + 1})
    with pytest.raises(DataError, match=r"covariate 'x'.*expected 40 samples"):
        rec.with_(covariates={"x": temp[:5]})
    with pytest.raises(DataError, match=r"covariate 'x', sample index 3"):
        bad = temp.copy()
        bad[3] = np.nan
        rec.with_(covariates={"x": bad})
