"""Record and Dataset: validation at construction, immutability, derived quantities."""

from __future__ import annotations

import copy
import dataclasses
import pickle

import numpy as np
import pytest

from bayeshyst.data.dataset import Dataset, check_fittable
from bayeshyst.data.record import DEFAULT_UNITS, MAGNITUDE_MAX, MIN_SAMPLES, Record, frequency_key
from bayeshyst.errors import DataError


def make(n: int = 10, name: str = "r", f: float | None = 2.0, **kw: object) -> Record:
    t = np.arange(n) * 0.1
    meta = {"frequency_hz": f, "source": "bench.csv"} | dict(kw.pop("metadata", {}))
    return Record(t, np.sin(t), 2 * np.sin(t) + 1, name=name, metadata=meta, **kw)


def test_arrays_are_readonly_float64_copies():
    u = np.arange(5)
    rec = Record(np.arange(5.0), u, u * 1.0)
    assert rec.u.dtype == np.float64 and not rec.u.flags.writeable
    u[0] = 99  # the caller's array is not aliased
    assert rec.u[0] == 0
    with pytest.raises(ValueError):
        rec.t[0] = 1.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        rec.warmup = 1  # type: ignore[misc]


def test_metadata_and_units_are_readonly_and_defaulted():
    rec = make(metadata={"tags": [1, 2], "nested": {"a": [3]}, "gain": np.float32(0.5)})
    assert rec.metadata["tags"] == (1, 2) and rec.metadata["nested"]["a"] == (3,)
    assert type(rec.metadata["gain"]) is float
    with pytest.raises(TypeError):
        rec.metadata["x"] = 1  # type: ignore[index]
    assert dict(rec.units) == dict(DEFAULT_UNITS)
    assert make(units={"y": "nm"}).units == {"t": "s", "u": "V", "y": "nm"}


@pytest.mark.parametrize(
    ("kwargs", "pattern"),
    [
        ({"u": [0, 1, 2]}, r"record 'r' \(source bench\.csv\): column 'u': expected 5 samples"),
        ({"y": [0, 1, np.nan, 3, 4]},
         r"record 'r' \(source bench\.csv\): column 'y', sample index 2 \(0-based\): expected a "
         r"finite value, found nan"),
        ({"u": [0, 1, 2, np.inf, 4]}, r"column 'u', sample index 3 \(0-based\).*found inf"),
        ({"t": [0, 1, 1, 2, 3]},
         r"column 't', sample index 2 \(0-based\): expected strictly increasing time "
         r"\(> 1\.0 at index 1\), found 1\.0 \(duplicate time\)"),
        ({"t": [0, 1, 2, 1.5, 3]}, r"column 't', sample index 3 .*\(decreasing time\)"),
        ({"t": np.zeros((5, 1))}, r"column 't': expected a 1-D array, found shape \(5, 1\)"),
        ({"u": ["a"] * 5}, r"column 'u': expected real numbers, found dtype <U1"),
        ({"warmup": 4}, r"warmup: expected 0 <= warmup <= 3 \(at least 2 scored samples"),
        ({"warmup": -1}, r"warmup: expected 0 <= warmup <= 3"),
        ({"warmup": 1.5}, r"warmup: expected an integer, found 1\.5"),
        ({"warmup": True}, r"warmup: expected an integer, found True"),
        ({"segment": [0, 0, 1.5, 1, 1]},
         r"column 'segment', sample index 2 \(0-based\): expected an integer label, found 1\.5"),
        ({"segment": [0, 1]}, r"column 'segment': expected 5 samples"),
        ({"metadata": {"source": "bench.csv", "frequency_hz": -1}},
         r"metadata 'frequency_hz': expected a positive finite number or None, found -1"),
        ({"metadata": {1: "x"}}, r"record 'r': metadata: expected string keys, found 1"),
        ({"units": {"y": 3}}, r"units: expected str -> str, found 'y': 3"),
        ({"name": ""}, r"record name: expected a non-empty string"),
    ],
)
def test_validation_messages(kwargs, pattern):
    base = {"t": np.arange(5.0), "u": np.zeros(5), "y": np.zeros(5), "name": "r",
            "metadata": {"source": "bench.csv"}}
    with pytest.raises(DataError, match=pattern):
        Record(**(base | kwargs))


def test_min_samples_and_its_message():
    assert MIN_SAMPLES == 4
    Record(np.arange(4.0), np.zeros(4), np.zeros(4))
    with pytest.raises(DataError, match=r"expected at least 4 samples \(MIN_SAMPLES\), found 3"):
        Record(np.arange(3.0), np.zeros(3), np.zeros(3))


def test_derived_quantities():
    rec = make(n=11, warmup=3)
    assert rec.n == len(rec) == 11
    assert rec.dt == pytest.approx(0.1) and rec.fs == pytest.approx(10.0)
    assert rec.duration == pytest.approx(1.0) and rec.frequency_hz == 2.0
    assert rec.scored == slice(3, 11) and rec.n_scored == 8
    assert rec.scored_mask.sum() == 8 and not rec.scored_mask[:3].any()
    assert rec.stroke == pytest.approx(np.ptp(rec.y))
    assert rec.source == "bench.csv"


def test_dt_is_robust_to_rounding_jitter_and_to_gaps():
    t = np.round(np.arange(1001) * 2e-4, 9) + np.tile([0, 1e-9], 501)[:1001]
    rec = Record(t, np.zeros(1001), np.zeros(1001))
    assert rec.dt == pytest.approx(2e-4, rel=1e-9)  # mean step, not the rounding median
    gappy = np.concatenate([np.arange(100) * 0.01, 5.0 + np.arange(100) * 0.01])
    assert Record(gappy, np.zeros(200), np.zeros(200)).dt == pytest.approx(0.01)


def test_with_and_slice_revalidate_and_keep_metadata():
    rec = make(n=20, warmup=4)
    assert dataclasses.replace(rec, name="b").name == "b"
    changed = rec.with_(warmup=0, units={"y": "nm"})
    assert changed.warmup == 0 and changed.units["y"] == "nm" and rec.warmup == 4
    with pytest.raises(DataError, match="warmup"):
        rec.with_(warmup=19)
    part = rec.slice(5, 15)
    assert part.n == 10 and part.name == "r[5:15]" and part.warmup == 4  # counted anew
    np.testing.assert_array_equal(part.t, rec.t[5:15])
    assert part.metadata == rec.metadata
    assert rec.slice(-6, warmup=0).n == 6
    with pytest.raises(DataError, match=r"record 'r\[0:2\]'"):
        rec.slice(0, 2)


def test_equality_and_str():
    a, b = make(), make()
    assert a == b and a != make(name="other") and a != b.with_(y=b.y + 1e-12)
    assert a != b.with_(segment=np.zeros(10, int))
    text = str(a)
    assert "\n" not in text
    for piece in ("Record 'r'", "n=10", "fs=10 Hz", "f=2 Hz", "warmup=0", "um"):
        assert piece in text
    assert "f=?" in str(make(f=None))
    with pytest.raises(TypeError):
        hash(a)


# ------------------------------------------------------------------------------ Dataset
def test_dataset_validation():
    with pytest.raises(DataError, match=r"dataset 'ds': expected at least one record"):
        Dataset((), name="ds")
    with pytest.raises(DataError, match=r"expected unique record names, found 'r' at positions"):
        Dataset([make(), make()], name="ds")
    with pytest.raises(DataError, match=r"item 1: expected a Record, found int"):
        Dataset([make(), 3], name="ds")  # type: ignore[list-item]


def test_dataset_access_grouping_and_selection():
    recs = [make(name="a", f=2.0), make(name="b", f=1.0), make(name="c", f=None),
            make(name="d", f=2.0)]
    ds = Dataset(recs, name="sweep")
    assert isinstance(ds.records, tuple) and len(ds) == 4 and list(ds) == recs
    assert ds[1] is recs[1] and ds["d"] is recs[3] and ds[1:3].names == ("b", "c")
    with pytest.raises(KeyError):
        ds["zz"]
    assert ds.frequencies == (1.0, 2.0)
    groups = ds.by_frequency()
    assert list(groups) == [1.0, 2.0, None]
    assert groups[2.0].names == ("a", "d") and groups[2.0].name == "sweep@2Hz"
    assert ds.select(frequency_hz=2.0).names == ("a", "d")
    assert ds.select(frequency_hz=[1.0, 2.0], names=["a", "b"]).names == ("a", "b")
    with pytest.raises(DataError, match=r"no record matches frequency_hz=5.0.*frequencies \[1"):
        ds.select(frequency_hz=5.0)
    both = ds.concat(make(name="e"), Dataset([make(name="f")]), name="all")
    assert both.names == ("a", "b", "c", "d", "e", "f") and both.name == "all"
    with pytest.raises(DataError, match="unique record names"):
        ds.concat(make(name="a"))
    assert Dataset(make()).names == ("r",)


def test_one_frequency_identity_for_grouping_comparing_and_the_study():
    # a file's 10 Hz and a computed 10 + 1e-9 Hz are one frequency; 10.001 Hz is another
    recs = [make(name="file", f=10.0), make(name="computed", f=10.0 + 1e-9),
            make(name="other", f=10.001)]
    ds = Dataset(recs, name="s")
    assert ds.frequencies == (10.0, 10.001)
    groups = ds.by_frequency()
    assert list(groups) == [10.0, 10.001] and groups[10.0].names == ("file", "computed")
    assert recs[0].frequency_hz == recs[1].frequency_hz != recs[2].frequency_hz
    # the metadata keeps what was given
    assert recs[1].metadata["frequency_hz"] == 10.0 + 1e-9
    assert frequency_key(None) is None and frequency_key(123456789.0) == 123457000.0
    # the study's summary and figures use the very same definition
    from bayeshyst.plotting import study as study_figures
    from bayeshyst.study import summary

    assert summary.frequency_key is frequency_key is study_figures.frequency_key


def test_dataset_str_table():
    text = str(Dataset([make(name="first"), make(name="second", f=None)], name="bench"))
    lines = text.splitlines()
    assert lines[0] == "Dataset 'bench': 2 record(s), 20 samples"
    assert lines[1].split() == ["name", "n", "fs", "[Hz]", "f", "[Hz]", "stroke"]
    assert lines[2].split()[:4] == ["first", "10", "10", "2"]
    assert lines[3].split()[3] == "-"


def test_records_and_datasets_pickle_and_copy():
    rec = make(warmup=2, segment=np.arange(10) % 2, metadata={"nested": {"a": [1, 2]}})
    ds = Dataset([rec, make(name="b")], name="d")
    back = pickle.loads(pickle.dumps(ds))
    assert back == ds and not back[0].u.flags.writeable
    assert back[0].metadata["nested"]["a"] == (1, 2)
    assert copy.deepcopy(rec) == rec and copy.copy(rec) == rec


# ------------------------------------------------------------------------ fittable
def test_a_constant_record_is_valid_but_not_fittable():
    rec = Record(np.arange(4.0), np.zeros(4), np.arange(4.0), name="hold")
    assert rec.n == 4  # in memory it is a Record like any other
    with pytest.raises(DataError, match=r"^bench\.csv: column 'u': constant \(0\.0 in every "
                       r"sample\); the input must vary"):
        check_fittable(rec, "bench.csv")
    with pytest.raises(DataError, match=r"^bench\.csv: input 'volt': constant"):
        check_fittable(rec, "bench.csv", {"u": "input 'volt'"})
    # over a Dataset the columns are judged together, as the models' priors see them
    check_fittable(Dataset([rec, rec.with_(name="loop", u=np.arange(4.0))]), "bench.csv")


def test_fittable_checks_the_input_before_the_output():
    t, big = np.arange(4.0), np.array([0.0, 1.0, 0.0, 1.0]) * 10 * MAGNITUDE_MAX
    with pytest.raises(DataError, match=r"column 'u': largest \|value\| 1e\+51 is outside"):
        check_fittable(Record(t, big, big), "f")
    with pytest.raises(DataError, match=r"column 'y': largest \|value\| 1e\+51 is outside"):
        check_fittable(Record(t, big / 1e10, big), "f")
    assert check_fittable(make(), "f") is None
